"""Route-ending criteria of the CARLA Leaderboard 2.0, evaluated every tick
(docs/design.md §9.1; constants as in the leaderboard).

Each criterion keeps its own monotone index into the 1 m dense route (window rules of
docs/design.md §9.1) and answers ``update(...) -> status or None``; the first non-None ends the route.
The status texts are those of harness.scoring.statuses.
"""
from __future__ import annotations

import numpy as np

from harness.scoring.statuses import COMPLETED, FAILED_BLOCKED, FAILED_DEVIATION, FAILED_TIMEOUT
from harness.sim.plan import GlobalPlan, Progress


class RouteCompletion:
    """RC = cum_dist[i] / length * 100 (2 decimals; in the leaderboard's order of operations,
    which decides the last digit at a tie); success when RC > 99 and the ego is within 10 m
    of the last dense point, and then RC = 100."""

    DONE_RC, DONE_DIST = 99.0, 10.0

    def __init__(self, plan: GlobalPlan):
        self.plan, self.progress = plan, Progress(plan, window=3)
        self.rc, self._length = 0.0, plan.length

    def update(self, x: float, y: float) -> str | None:
        i = self.progress.update(x, y)
        self.rc = _round2(float(self.plan.s[i]) / self._length * 100.0)
        end = self.plan.xy[-1]
        if self.rc > self.DONE_RC and np.hypot(x - end[0], y - end[1]) < self.DONE_DIST:
            self.rc = 100.0
            return COMPLETED
        return None


def _round2(v: float) -> float:
    """v rounded to 2 decimals as NumPy rounds a float64 (times 100, to the nearest integer,
    ties to even, divided by 100), which is how RC was rounded when it was a NumPy scalar;
    Python's ``round(v, 2)`` rounds the decimal value and can differ in the last digit."""
    return round(v * 100.0) / 100.0


class InRoute:
    """Deviation: nearest dense point in i..i+5 (2D); >= 30 m ends the route; advancing
    while >= 15 m away adds to the off-route distance, > 30 % of the route ends it."""

    MAX_DIST, SAFE_DIST, MAX_SHARE, WINDOW = 30.0, 15.0, 0.30, 6

    def __init__(self, plan: GlobalPlan):
        self.plan, self.index, self.out = plan, 0, 0.0
        self._x, self._y = plan.xy[:, 0].copy(), plan.xy[:, 1].copy()  # contiguous columns

    def update(self, x: float, y: float) -> str | None:
        i = self.index
        d = np.hypot(self._x[i:i + self.WINDOW] - x, self._y[i:i + self.WINDOW] - y).tolist()
        k = len(d) - 1 - d[::-1].index(min(d))  # the nearest point; ties go to the later one
        if d[k] >= self.MAX_DIST:
            return FAILED_DEVIATION
        if k > 0:
            if d[k] >= self.SAFE_DIST:
                self.out += float(self.plan.s[i + k] - self.plan.s[i])
            self.index = i + k
        if self.out / self.plan.length > self.MAX_SHARE:
            return FAILED_DEVIATION
        return None


class Blocked:
    """Speed < 0.1 m/s for more than 180 s (Leaderboard 2.0) ends the route. The check is
    off while a scenario timeout runs (``paused``), and its timer restarts after."""

    SPEED, MAX_TIME = 0.1, 180.0

    def __init__(self, max_time: float = MAX_TIME):
        self.max_time, self.since = max_time, 0.0

    def update(self, speed: float, time: float, paused: bool = False) -> str | None:
        if speed >= self.SPEED or paused:
            self.since = time
        elif time - self.since > self.max_time:
            return FAILED_BLOCKED
        return None


class RouteTimeout:
    """Budget 300 s, growing by d / (0.1 v_limit) as the route index advances (window
    i..i+3); ends the route when game time exceeds it."""

    BASE, FACTOR = 300.0, 0.1

    def __init__(self, plan: GlobalPlan):
        self.plan, self.progress, self.budget = plan, Progress(plan, window=4), self.BASE

    def update(self, x: float, y: float, time: float) -> str | None:
        i0 = self.progress.index
        i1 = self.progress.update(x, y)
        if i1 > i0:
            ds = np.diff(self.plan.s[i0:i1 + 1])
            self.budget += float(np.sum(ds / (self.FACTOR * self.plan.speed_limit[i0 + 1:i1 + 1])))
        return FAILED_TIMEOUT if time > self.budget else None
