"""Synthetic drives with exact labels, for the teacher tests: an ego that follows a world
path (a dense polyline) with a given arc length per 20 Hz tick, recorded at 4 Hz the way
harness.expert.collect records the expert (pose; the path ahead at 0..19 m of arc, ego
frame; the ego's own positions 0.25..2.5 s later, ego frame; the scene cues), so the labels
of consecutive frames describe the same world motion exactly.
"""
from __future__ import annotations

import numpy as np

TICK = 0.05  # [s], 20 Hz
EVERY = 5  # ticks per frame (4 Hz)
FUTURE = 50  # ticks of the 2.5 s label future
STEP = 0.05  # spacing of the world path polyline [m]


def circle(radius: float):
    """Pose (x, y, heading) at arc lengths s [m] of a left circle of ``radius`` [m] from
    (0, 0) heading +x, exactly."""
    return lambda s: (radius * np.sin(s / radius), radius * (1 - np.cos(s / radius)), s / radius)


def polyline(path: np.ndarray):
    """Pose (x, y, heading) at arc lengths s [m] along a dense polyline (K, 2) [m]: positions
    interpolated, heading that of the chord at s."""
    seg = np.hypot(*np.diff(path, axis=0).T)
    s_path = np.concatenate([[0.0], np.cumsum(seg)])
    heading = np.unwrap(np.arctan2(*np.diff(path, axis=0)[:, ::-1].T))
    mid = 0.5 * (s_path[1:] + s_path[:-1])
    return lambda s: (np.interp(s, s_path, path[:, 0]), np.interp(s, s_path, path[:, 1]), np.interp(s, mid, heading))


def lane_change(length: float, start: float, width: float, ramp: float, hold: float):
    """(path pose function, offset function) of a straight drive along +x that moves
    ``width`` m left over ``ramp`` m from x = ``start`` (a cosine ramp), holds for ``hold`` m
    and moves back over ``ramp`` m (an obstacle bypass); the route is the line y = 0."""
    def y_of(x):
        up = np.clip((x - start) / ramp, 0, 1)
        down = np.clip((x - start - ramp - hold) / ramp, 0, 1)
        return width * 0.5 * ((1 - np.cos(np.pi * up)) - (1 - np.cos(np.pi * down)))
    x = np.arange(0.0, length, STEP)
    path = polyline(np.stack([x, y_of(x)], axis=-1))
    s_path = np.concatenate([[0.0], np.cumsum(np.hypot(STEP, np.diff(y_of(x))))])
    return path, lambda s: y_of(np.interp(s, s_path, x))


def straight(length: float):
    """Pose function of a straight road along +x."""
    return lambda s: (np.asarray(s, dtype=float), np.zeros_like(s, dtype=float), np.zeros_like(s, dtype=float))


def speed_ticks(profile: list[tuple[float, float]], v0: float) -> np.ndarray:
    """(N,) speed [m/s] per tick from segments (duration [s], acceleration [m/s^2]),
    starting at v0 and never below 0."""
    v, out = v0, []
    for dur, acc in profile:
        for _ in range(int(round(dur / TICK))):
            out.append(v)
            v = max(0.0, v + acc * TICK)
    return np.array(out)


def record(at, v_tick: np.ndarray, offset=None, target_speed: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Episode arrays (the fields scimm reads) of an ego driving the path ``at`` (arc length
    s [m] -> world x, y [m], heading [rad]; ``circle`` or ``polyline``) at speeds v_tick (N,)
    [m/s] per tick; ``offset`` (arc length -> the path's lateral offset from the route [m],
    for the cues changed_route, recovery, lateral_offset; default 0); ``target_speed`` (N,)
    the expert's target per tick (default the speed)."""
    s_tick = np.concatenate([[0.0], np.cumsum(v_tick[:-1] * TICK)])
    frames = np.arange(0, len(v_tick) - FUTURE, EVERY)
    px, py, yaw = at(s_tick[frames])
    c, s_ = np.cos(yaw)[:, None], np.sin(yaw)[:, None]

    def ego(wx, wy):
        dx, dy = wx - px[:, None], wy - py[:, None]
        return np.stack([c * dx + s_ * dy, -s_ * dx + c * dy], axis=-1)

    ahead = s_tick[frames][:, None] + np.arange(20.0)[None, :]
    path_lab = ego(*at(ahead)[:2])
    fut = frames[:, None] + EVERY * np.arange(1, 11)[None, :]
    wps = ego(*at(s_tick[fut])[:2])
    T = len(frames)
    off = np.zeros(T) if offset is None else offset(s_tick[frames])
    off_next = np.zeros(T) if offset is None else offset(s_tick[frames] + 5.0)
    ds = 0.5
    curvature = (at(s_tick[frames] + ds)[2] - at(s_tick[frames] - ds)[2]) / (2 * ds)
    target = (v_tick if target_speed is None else target_speed)[frames]
    v = v_tick[frames]
    a = {"x": px, "y": py, "yaw": yaw, "v": v, "t": frames * TICK, "path": path_lab, "speed_wps": wps,
         "command": np.full(T, 4), "next_command": np.full(T, 3), "target_speed": target,
         "cue_junction": np.zeros(T), "cue_curvature": curvature,
         "cue_curvature_change": np.zeros(T), "cue_lateral_offset": off,
         "cue_lateral_change": np.diff(off, prepend=off[:1]), "cue_speed": v, "cue_target_speed": target,
         "cue_speed_drop": np.maximum(0.0, v - target),
         "cue_changed_route": (np.abs(off) > 0.2).astype(float),
         "cue_recovery": ((np.abs(off) > 0.2) & (np.abs(off_next) < np.abs(off))).astype(float)}
    for k in ("vehicle", "leader", "walker", "light", "stop", "junction", "obstacle"):
        a[f"flag_{k}"] = np.zeros(T, dtype=bool)
    return a
