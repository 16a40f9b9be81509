"""The global plan of a route: the dense 1 m route with speed limits and commands, its
sparse points for the target point, and the progress rule of the Leaderboard.

Frames: world = SUMO (x east, y north) [m]; ego frame x forward, y left [m].
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import sumolib

from scenarios.geometry import Leg, Passage, RoutePath
from scenarios.routefile import Route
from scenarios.check import check_route

# CARLA RoadOption values (what SimLingo-style models take as a command)
LEFT, RIGHT, STRAIGHT, LANEFOLLOW = 1, 2, 3, 4
_DIRECTION_TO_OPTION = {"l": LEFT, "L": LEFT, "t": LEFT, "r": RIGHT, "R": RIGHT, "s": STRAIGHT}
SPARSE_STEP = 50.0  # sparse points at least every 50 m, as CARLA's route downsampling [m]
TARGET_MIN = 7.5  # the target point is the next sparse point at least this far ahead [m]
END_PAD = 20.0  # the route sensors (BEV ROUTE channel, target point) run on this far past the end [m]


@dataclass(frozen=True)
class GlobalPlan:
    """Dense route (1 m), per-point heading, speed limit [m/s] and RoadOption, sparse points."""

    route_id: str
    town: str
    xy: np.ndarray  # (N, 2) world [m]
    s: np.ndarray  # (N,) arc length [m]
    yaw: np.ndarray  # (N,) route heading [rad, CCW from +x]
    speed_limit: np.ndarray  # (N,) [m/s]
    command: np.ndarray  # (N,) RoadOption
    sparse: np.ndarray  # (K,) indices of the sparse points into the dense route
    passages: tuple[Passage, ...]
    path: RoutePath

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def target_xy(self, progress: int) -> np.ndarray:
        """Target point (2,) world [m]: the first sparse point >= TARGET_MIN past dense index
        ``progress``; near the end, the point TARGET_MIN ahead on the straight run-on past
        the last point (``shown_xy``), so the target never comes closer than TARGET_MIN."""
        j = int(self._sparse_s.searchsorted(self.s[progress] + TARGET_MIN))  # s is non-decreasing
        if j < len(self.sparse):
            return self.xy[int(self.sparse[j])]
        extra = min(self.s[progress] + TARGET_MIN - self.length, END_PAD)
        return self.xy[-1] + extra * self._end_heading

    @cached_property
    def _sparse_s(self) -> np.ndarray:
        """(K,) arc length of the sparse points [m]."""
        return self.s[self.sparse]

    @cached_property
    def _end_heading(self) -> np.ndarray:
        """(2,) unit vector of the route's last heading, world frame."""
        return np.array([math.cos(self.yaw[-1]), math.sin(self.yaw[-1])])

    @cached_property
    def shown_xy(self) -> np.ndarray:
        """(N + 20, 2) world [m]: the dense route and, 1 m apart, END_PAD m straight on past
        its last point along the last heading. The route sensors show this, so the end of a
        route never looks like a place to stop (PDM-Lite pads its dense route past the end
        the same way); route completion and every criterion use the route itself."""
        k = np.arange(1.0, END_PAD + 0.5)[:, None]
        return np.vstack([self.xy, self.xy[-1] + k * self._end_heading])


def build_plan(route: Route, net: sumolib.net.Net) -> GlobalPlan:
    """Trace a route (scenarios.check) and annotate its dense points."""
    path = check_route(route)
    xy, s = path.xy, path.s
    d = np.diff(xy, axis=0)
    yaw = np.arctan2(d[:, 1], d[:, 0])
    yaw = np.append(yaw, yaw[-1])
    limit = np.zeros(len(s))
    for g in path.legs:
        limit[(s >= g.s0 - 1e-6)] = net.getEdge(g.edge).getSpeed()
    command = np.full(len(s), LANEFOLLOW, dtype=np.int8)
    marks = [0]
    for p in path.passages:
        command[(s >= p.s_in - 5.0) & (s <= p.s_out)] = _DIRECTION_TO_OPTION.get(p.direction, LANEFOLLOW)
        marks += [int(np.searchsorted(s, p.s_in)), int(np.searchsorted(s, p.s_out))]
    for k in np.arange(SPARSE_STEP, path.length, SPARSE_STEP):
        marks.append(int(np.searchsorted(s, k)))
    marks.append(len(s) - 1)
    sparse = np.unique(np.clip(marks, 0, len(s) - 1))
    return GlobalPlan(route.id, route.town, xy, s, yaw, limit, command, sparse, path.passages, path)


def leg_at(plan: GlobalPlan, s: float) -> Leg | None:
    """The route leg (edge) that route s [m] lies on, None inside a junction."""
    for g in plan.path.legs:
        if g.s0 - 1e-6 <= s <= g.s1 + 1e-6:
            return g
    return None


def route_lane(plan: GlobalPlan, net: sumolib.net.Net, s: float) -> tuple[str, int, float] | None:
    """(edge, lane index, position along the lane [m]) of route s, if s lies on an edge.

    The lane is the edge's lane nearest to the route there: a route that changes lanes
    along an edge enters it on ``lane_in`` and leaves on ``lane_out``."""
    g = leg_at(plan, s)
    if g is None:
        return None
    x, y, _ = plan.path.pose(s)
    lanes = net.getEdge(g.edge).getLanes()
    # the bubble asks about once a second: pick the lane by a numpy distance to its centre
    # line (cheap), then let sumolib project onto that one lane
    lane = min(lanes, key=lambda ln: _point_distance(ln.getShape(), x, y)) if len(lanes) > 1 else lanes[0]
    pos, _ = lane.getClosestLanePosAndDist((x, y))
    return g.edge, lane.getIndex(), float(pos)


def _point_distance(shape: list, x: float, y: float) -> float:
    """Distance [m] from (x, y) to a polyline (list of (x, y) points)."""
    p = np.asarray(shape, dtype=float)[:, :2]
    a, d = p[:-1], p[1:] - p[:-1]
    t = np.clip(((x - a[:, 0]) * d[:, 0] + (y - a[:, 1]) * d[:, 1]) / np.maximum((d * d).sum(1), 1e-12), 0.0, 1.0)
    return float(np.min(np.hypot(a[:, 0] + t * d[:, 0] - x, a[:, 1] + t * d[:, 1] - y)))


def to_ego(points: np.ndarray, x: float, y: float, yaw: float) -> np.ndarray:
    """World points (N, 2) -> ego frame (x forward, y left) of a pose (x, y, yaw)."""
    c, s = math.cos(yaw), math.sin(yaw)
    if np.shape(points) == (2,):  # one point (the target point, every tick): the same arithmetic on floats
        dx, dy = float(points[0]) - x, float(points[1]) - y
        return np.array([c * dx + s * dy, -s * dx + c * dy])
    d = np.asarray(points, dtype=float) - (x, y)
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)


class Progress:
    """Monotone index into the dense route with the Leaderboard's passed-point rule.

    A point k counts as passed when (ego - point) . forward(k) > 0; each update looks at
    points i .. i + window - 1 and moves i to the furthest passed one (docs/design.md
    §9.1; RouteCompletionTest uses a window of 3).
    """

    def __init__(self, plan: GlobalPlan, window: int = 3):
        self.plan, self.window, self.index = plan, window, 0
        # (x, y, forward x, forward y) per dense point, as Python floats: the window is 3-4
        # points, where a plain loop costs a sixth of numpy's per-call overhead
        self._pts = np.column_stack([plan.xy, np.cos(plan.yaw), np.sin(plan.yaw)]).tolist()

    def update(self, x: float, y: float) -> int:
        i = self.index
        for k in range(min(i + self.window, len(self._pts)) - 1, i, -1):  # the furthest passed
            px, py, fx, fy = self._pts[k]
            if (x - px) * fx + (y - py) * fy > 0:
                self.index = k
                break
        return self.index
