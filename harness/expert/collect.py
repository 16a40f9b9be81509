"""``sumo-scimm collect``: the expert drives a route set and every episode is recorded at
4 Hz (every 5th tick, as PDM-Lite) for the teacher and the student (docs/design.md §5).

One file per route run, ``episodes/<route>_rep<k>.npz``, holding per frame (F frames):

    t, x, y, yaw, v, acc, steer, throttle, brake    ego state (world frame) and control
    actor_offset (F+1,), actor_xy, actor_yaw, actor_speed, actor_size, actor_cls
                                                    the scene the BEV renderer draws (ragged)
    lights (F, P), props (F, Q, 5)                  route light states, harness-only boxes
    stops (F, S) uint8                              1 while the BEV draws each route stop sign
    target_point (F, 2)                             ego frame (x forward, y left) [m]
    command, next_command (F,)                      CARLA RoadOption
    path (F, 20, 2)                                 label: the expert's path at 0..19 m of arc
    speed_wps (F, 10, 2)                            label: ego positions 0.25..2.5 s ahead
    target_speed (F,), flag_* (F,)                  the expert's target and hazard flags
    cue_* (F,)                                      the scene cues of docs/design.md §6.3 (docs/dataset.md)
    route_file, route_id, town                      to rebuild the plan
    vehicle                                         the ego model that drove it (controller.ego)

Frames are kept only when the whole 2.5 s future exists (the last 2.5 s are dropped).
The run folder also gets the usual records/results files and ``index.csv``, one row per
frame, for pandas.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from controller.vehicle import DT
from files.atomic import savez_atomic
from harness.sim.plan import _DIRECTION_TO_OPTION, LANEFOLLOW, to_ego

FRAME_EVERY = 5  # ticks per recorded frame (20 Hz -> 4 Hz)
N_PATH, N_SPEED = 20, 10  # path points at 0..19 m; speed waypoints at 0.25..2.5 s
SPEED_WP_TICKS = 5  # 0.25 s between speed waypoints
FLAGS = ("vehicle", "leader", "walker", "light", "stop", "junction", "obstacle")


def _resample_path(pts_ego: np.ndarray) -> np.ndarray:
    """(20, 2) points at arc length 0, 1, ..., 19 m along origin + pts (ego frame)."""
    ahead = pts_ego[pts_ego[:, 0] > 0.0]
    p = np.vstack([[0.0, 0.0], ahead]) if len(ahead) else np.array([[0.0, 0.0], [1.0, 0.0]])  # straight on
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
    q = np.arange(N_PATH, dtype=float)
    if cum[-1] < q[-1]:  # extend straight beyond the known path
        d = p[-1] - p[-2] if len(p) > 1 else np.array([1.0, 0.0])
        d = d / max(np.hypot(*d), 1e-9)
        extra = p[-1] + np.outer(np.arange(1, int(q[-1] - cum[-1]) + 2), d)
        p = np.vstack([p, extra])
        cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
    return np.stack([np.interp(q, cum, p[:, 0]), np.interp(q, cum, p[:, 1])], axis=1)


def _curvature(plan, s: float) -> float:
    """Route curvature [1/m] at arc length s (heading change over +-3 m / 6 m), left positive."""
    i0 = int(np.clip(np.searchsorted(plan.s, s - 3.0), 0, len(plan.s) - 1))
    i1 = int(np.clip(np.searchsorted(plan.s, s + 3.0), 0, len(plan.s) - 1))
    if i1 <= i0:
        return 0.0
    dyaw = (plan.yaw[i1] - plan.yaw[i0] + math.pi) % (2 * math.pi) - math.pi
    return float(dyaw / max(plan.s[i1] - plan.s[i0], 1e-6))


class Recorder:
    """Collects a run's ticks (``on_frame``) and turns them into the episode arrays."""

    def __init__(self):
        self.ticks: list[tuple] = []
        self.frames: list[dict] = []
        self.plan = None

    def on_frame(self, f) -> None:
        e, c = f.ego, f.control
        self.plan = f.plan
        self.ticks.append((f.tick, e.x, e.y, e.yaw, e.v, c.steer, c.throttle, c.brake))
        if f.tick % FRAME_EVERY:
            return
        agent, plan = f.agent, f.plan
        offset = getattr(agent, "offset", None)
        i = int(getattr(agent, "index", 0))
        # the expert's path (the route, shifted sideways while bypassing), from the ego on
        left = np.stack([-np.sin(plan.yaw), np.cos(plan.yaw)], 1)
        path_world = plan.xy + (offset[:, None] * left if offset is not None else 0.0)
        i = int(np.argmin(np.hypot(*(path_world[max(i - 5, 0):i + 30] - (e.x, e.y)).T))) + max(i - 5, 0)
        pts = to_ego(path_world[max(i - 1, 0):i + 30], e.x, e.y, e.yaw)
        s = float(plan.s[i])
        passages_ahead = [p for p in plan.passages if p.s_out >= s]
        nxt = next((p for p in passages_ahead if p.s_in > s), None)
        in_junction = any(p.s_in <= s <= p.s_out for p in plan.passages)
        flags = getattr(agent, "flags", {}) or {}
        target = float(getattr(agent, "target_speed", math.nan))
        lat = float(to_ego(plan.xy[i:i + 1], e.x, e.y, e.yaw)[0, 1] * -1.0)  # ego left of route: +
        off_i = float(offset[i]) if offset is not None else 0.0
        off_next = float(offset[min(i + 5, len(offset) - 1)]) if offset is not None else 0.0
        snap = f.snap
        self.frames.append({
            "tick": f.tick, "path": _resample_path(pts),
            "target_point": to_ego(plan.target_xy(i), e.x, e.y, e.yaw),
            "command": int(plan.command[i]),
            "next_command": _DIRECTION_TO_OPTION.get(nxt.direction, LANEFOLLOW) if nxt else LANEFOLLOW,
            "target_speed": target, **{f"flag_{k}": bool(flags.get(k, False)) for k in FLAGS},
            "cue_junction": float(in_junction), "cue_curvature": _curvature(plan, s),
            "cue_curvature_change": _curvature(plan, s + 10.0) - _curvature(plan, s),
            "cue_lateral_offset": lat, "cue_speed": e.v, "cue_target_speed": target,
            "cue_speed_drop": max(0.0, e.v - target) if math.isfinite(target) else 0.0,
            "cue_changed_route": float(abs(off_i) > 0.2),
            "cue_recovery": float(abs(off_i) > 0.2 and abs(off_next) < abs(off_i)),
            "actor_xy": snap.xy.copy(), "actor_yaw": snap.yaw.copy(), "actor_speed": snap.speed.copy(),
            "actor_size": snap.size.copy(), "actor_cls": snap.cls.copy(),
            "lights": list(f.lights), "props": [tuple(p) for p in f.props], "stops": list(f.stops),
        })

    def arrays(self) -> dict[str, np.ndarray]:
        """Episode arrays; frames without a full 2.5 s future are dropped."""
        tk = np.array(self.ticks, dtype=float).reshape(-1, 8)
        by_tick = {int(t): k for k, t in enumerate(tk[:, 0])}
        keep = [fr for fr in self.frames if fr["tick"] + N_SPEED * SPEED_WP_TICKS in by_tick]
        out: dict[str, np.ndarray] = {}
        rows = np.array([by_tick[fr["tick"]] for fr in keep], dtype=int)
        for name, col in (("t", None), ("x", 1), ("y", 2), ("yaw", 3), ("v", 4), ("steer", 5),
                          ("throttle", 6), ("brake", 7)):
            out[name] = tk[rows, col] if col is not None else tk[rows, 0] * DT
        prev = np.maximum(rows - 1, 0)
        out["acc"] = (tk[rows, 4] - tk[prev, 4]) / DT
        wps = np.zeros((len(keep), N_SPEED, 2))
        for j, r in enumerate(rows):
            fut = tk[[r + SPEED_WP_TICKS * (k + 1) for k in range(N_SPEED)]]
            wps[j] = to_ego(fut[:, 1:3], tk[r, 1], tk[r, 2], tk[r, 3])
        out["speed_wps"] = wps
        out["path"] = np.array([fr["path"] for fr in keep]).reshape(-1, N_PATH, 2)
        out["target_point"] = np.array([fr["target_point"] for fr in keep]).reshape(-1, 2)
        cues = [k for k in (keep[0] if keep else {}) if k.startswith("cue_")]
        for key in ["command", "next_command", "target_speed"] + [f"flag_{k}" for k in FLAGS] + cues:
            out[key] = np.array([fr[key] for fr in keep])
        lat = np.array([fr["cue_lateral_offset"] for fr in keep])
        out["cue_lateral_change"] = np.diff(lat, prepend=lat[:1]) if len(lat) else lat
        counts = [len(fr["actor_xy"]) for fr in keep]
        out["actor_offset"] = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        for key, shape in (("actor_xy", (0, 2)), ("actor_yaw", (0,)), ("actor_speed", (0,)),
                           ("actor_size", (0, 2)), ("actor_cls", (0,))):
            out[key] = np.concatenate([fr[key] for fr in keep]) if keep else np.zeros(shape)
        out["lights"] = np.array([fr["lights"] for fr in keep], dtype=np.int8).reshape(len(keep), -1)
        out["stops"] = np.array([fr["stops"] for fr in keep], dtype=np.uint8).reshape(len(keep), -1)
        n_props = max([len(fr["props"]) for fr in keep], default=0)
        props = np.full((len(keep), n_props, 5), np.nan)
        for j, fr in enumerate(keep):
            if fr["props"]:
                props[j, :len(fr["props"])] = fr["props"]
        out["props"] = props
        return out


def save_episode(path: Path, arrays: dict, route_file: str, route_id: str, town: str, record: dict,
                 vehicle: str) -> None:
    savez_atomic(path, **arrays, route_file=np.array(route_file), route_id=np.array(route_id),
                 town=np.array(town), ds=np.array(record["ds"]), status=np.array(record["status"]),
                 vehicle=np.array(vehicle))
