"""The scene each tick's agent saw, kept in the episode log so that a run can be replayed:
the BEV re-rendered bit for bit, the other sensors rebuilt from the same numbers
(harness.runs.replay).

Per tick t (T ticks; the state BEFORE the tick's step, as the agent got it, where the log's
``x, y, yaw, v`` columns hold the state after it), arrays of ``logs/<route>_rep<k>.npz``:

    scene_t (T,)                 the timestamp run_step got [s of simulation]
    scene_ego (T, 4)             ego x, y [m], yaw [rad], v [m/s], world frame
    scene_progress (T,)          dense route index the target point and command come from
    scene_lights (T, P) int8     state of each route light (harness.sim.world.TLS_CODES index)
    scene_stops (T, S) uint8     1 while the BEV draws each route stop sign (the route's stop-sign
                                 passages in order, harness.sim.stop_signs), 0 once the ego has
                                 stopped in its zone or left it
    scene_offset (T+1,)          actors of tick t: rows scene_offset[t]:scene_offset[t+1] of
    scene_xy (N, 2), scene_yaw (N,), scene_size (N, 2), scene_cls (N,) int8
                                 centre [m], yaw [rad], length and width [m], class of every
                                 actor within 50 m (harness.sim.world.Snapshot; ids and speeds,
                                 which the BEV does not draw, are not kept)
    scene_props (Q, 5)           harness-only static boxes x, y, yaw, length, width (whole route)

Floats are kept as float64, the dtype the renderer computes in, so a re-rendered BEV equals
the closed-loop one bit for bit (tests/test_replay.py). About 1 KB a tick before compression
with 30 actors near the ego.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from controller.vehicle import EgoState
from harness.sim.world import Snapshot

SCENE_KEYS = ("scene_t", "scene_ego", "scene_progress", "scene_lights", "scene_offset", "scene_xy", "scene_yaw",
              "scene_size", "scene_cls", "scene_props", "scene_stops")


@dataclass
class SceneLog:
    """The scenes of an episode in progress (``add`` once a tick, ``arrays`` at the end)."""

    ticks: list[tuple] = field(default_factory=list)  # (timestamp, x, y, yaw, v, progress)
    lights: list[list[int]] = field(default_factory=list)
    stops: list[tuple[bool, ...]] = field(default_factory=list)
    actors: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=list)
    props: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))

    def add(self, timestamp: float, ego: EgoState, progress: int, snap: Snapshot, lights: list[int],
            props: np.ndarray, stops: tuple[bool, ...]) -> None:
        """The scene of one tick: what the agent was given at ``timestamp`` [s]; ``props``
        (Q, 5) the route's static boxes; ``stops`` which route stop signs the BEV draws."""
        self.ticks.append((timestamp, ego.x, ego.y, ego.yaw, ego.v, progress))
        self.lights.append(list(lights))
        self.stops.append(tuple(stops))
        self.actors.append((snap.xy, snap.yaw, snap.size, snap.cls))
        self.props = props

    def arrays(self) -> dict[str, np.ndarray]:
        """The ``scene_*`` arrays of the module docstring."""
        n = len(self.ticks)
        tk = np.array(self.ticks, dtype=float).reshape(n, 6)
        counts = [len(a[0]) for a in self.actors]
        cat = (lambda i, shape, dtype: np.concatenate([np.asarray(a[i], dtype=dtype).reshape(-1, *shape)  # noqa: E731
                                                        for a in self.actors]) if n else np.zeros((0, *shape), dtype))
        return {"scene_t": tk[:, 0], "scene_ego": tk[:, 1:5], "scene_progress": tk[:, 5].astype(np.int32),
                "scene_lights": np.array(self.lights, dtype=np.int8).reshape(n, -1) if n else np.zeros((0, 0), np.int8),
                "scene_stops": np.array(self.stops, dtype=np.uint8).reshape(n, -1) if n else np.zeros((0, 0), np.uint8),
                "scene_offset": np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
                "scene_xy": cat(0, (2,), float), "scene_yaw": cat(1, (), float), "scene_size": cat(2, (2,), float),
                "scene_cls": cat(3, (), np.int8), "scene_props": np.asarray(self.props, dtype=float).reshape(-1, 5)}


@dataclass(frozen=True)
class TickScene:
    """What the agent was given at one tick, rebuilt from a log (``scene_at``)."""

    timestamp: float  # [s]
    ego: EgoState  # world frame
    progress: int  # dense route index
    snap: Snapshot
    lights: list[int]
    props: list[tuple]
    stops: tuple[bool, ...]  # whether each route stop sign is drawn


def has_scene(log: dict) -> bool:
    """Whether a log's arrays hold the scenes (logs of runs from before they were kept do not,
    nor those from before the stop-sign state was kept: no ``scene_stops``)."""
    return all(k in log for k in SCENE_KEYS)


def scene_at(log: dict, t: int) -> TickScene:
    """The scene of tick t of a log's arrays (``has_scene(log)``)."""
    lo, hi = int(log["scene_offset"][t]), int(log["scene_offset"][t + 1])
    n = hi - lo
    snap = Snapshot([""] * n, log["scene_xy"][lo:hi], log["scene_yaw"][lo:hi], np.full(n, np.nan),
                    log["scene_size"][lo:hi], log["scene_cls"][lo:hi].astype(int), math.nan)
    x, y, yaw, v = (float(c) for c in log["scene_ego"][t])
    return TickScene(float(log["scene_t"][t]), EgoState(x, y, yaw, v), int(log["scene_progress"][t]), snap,
                     [int(s) for s in log["scene_lights"][t]], [tuple(p) for p in log["scene_props"]],
                     tuple(bool(s) for s in log["scene_stops"][t]))
