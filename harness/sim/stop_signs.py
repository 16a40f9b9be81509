"""Which of a route's stop signs the ego has satisfied: one state for the stop-sign criterion
and for the BEV.

A stop-sign passage is a junction the route drives through on a stop (``s``) or all-way stop
(``w``) link (``stop_passages``); its stop line is the end of the approach lane, at route arc
length ``s_in``. Its zone runs along the route from ``s_in - STOP_BEFORE`` to
``s_in + STOP_AFTER`` (the Leaderboard's 4 m look-ahead plus the trigger box, docs/scoring.md).
The ego's position is the arc length of its route index (``plan.s[route_index]``), as every
route criterion reads it. From the run's logged ticks (arc length s [m], speed v [m/s]), one
passage is

- reached once a tick lies in the zone;
- satisfied (stopped) once a tick in the zone has v < STOP_SPEED;
- left once a tick lies past the zone (s > s_in + STOP_AFTER).

The criterion (harness.scoring.infractions.stop_signs) reads the state after the last tick: a
passage reached and left but never satisfied is a stop infraction; one never left has no
verdict. The BEV (harness.sensors.bev, channel STOPS) draws a passage's stop line while it is
neither satisfied nor left: the line of a stop still to be made, never one already made (a
single-frame driver cannot otherwise tell that it has stopped). This is Roach's rule (the
CARLA BEV agent draws its target stop sign until its stop criterion marks the stop completed),
with this project's zone and speed. The closed loop keeps the state tick by tick
(``StopTracker``, fed the numbers the log records); ``stop_history`` computes the same from a
whole log.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

STOP_BEFORE, STOP_AFTER, STOP_SPEED = 6.0, 1.0, 0.1  # stop zone around the stop line [m], [m/s]
STOP_STATES = ("s", "w")  # SUMO link states of a stop sign and an all-way stop


def stop_passages(plan) -> list:
    """The passages of a plan (harness.sim.plan.GlobalPlan) on a stop-sign link, in route order."""
    return [p for p in plan.passages if p.state in STOP_STATES]


def in_zone(s, s_in):
    """Whether arc length s [m] lies in the stop zone of the stop line at s_in [m] (broadcasts)."""
    return (s >= s_in - STOP_BEFORE) & (s <= s_in + STOP_AFTER)


def stops_there(s, v, s_in):
    """Whether a tick at arc length s [m] and speed v [m/s] satisfies the stop at s_in (broadcasts)."""
    return in_zone(s, s_in) & (v < STOP_SPEED)


def past_zone(s, s_in):
    """Whether arc length s [m] lies past the stop zone of the stop line at s_in [m] (broadcasts)."""
    return s > s_in + STOP_AFTER


@dataclass(frozen=True)
class StopHistory:
    """The state of P stop passages after each of T ticks: (T, P) bool, row k after tick k."""

    reached: np.ndarray
    stopped: np.ndarray
    left: np.ndarray

    @property
    def drawn(self) -> np.ndarray:
        """(T, P) bool: whether each stop line is drawn in the BEV the agent gets at the tick
        after tick k (neither satisfied nor left by tick k)."""
        return ~(self.stopped | self.left)


def stop_history(s: np.ndarray, v: np.ndarray, s_in: np.ndarray) -> StopHistory:
    """The state after each tick of ticks at arc lengths s (T,) [m] and speeds v (T,) [m/s],
    for stop lines at arc lengths s_in (P,) [m]."""
    s = np.asarray(s, dtype=float)[:, None]
    v = np.asarray(v, dtype=float)[:, None]
    s_in = np.asarray(s_in, dtype=float).reshape(1, -1)
    since = lambda a: np.logical_or.accumulate(a, axis=0)  # noqa: E731 - true from the first tick on
    return StopHistory(since(in_zone(s, s_in)), since(stops_there(s, v, s_in)), since(past_zone(s, s_in)))


class StopTracker:
    """The stop-sign state of a route run in progress (the closed loop's copy of
    ``stop_history``): ``update`` once a tick with the numbers the log records."""

    def __init__(self, plan):
        self.s_in = np.array([p.s_in for p in stop_passages(plan)], dtype=float)
        self.stopped = np.zeros(len(self.s_in), bool)
        self.left = np.zeros(len(self.s_in), bool)
        self.drawn: tuple[bool, ...] = (True,) * len(self.s_in)  # what the next BEV draws

    def update(self, s: float, v: float) -> None:
        """One logged tick: the ego at route arc length s [m] with speed v [m/s]."""
        if not len(self.s_in):
            return
        self.stopped |= stops_there(s, v, self.s_in)
        self.left |= past_zone(s, self.s_in)
        self.drawn = tuple((~(self.stopped | self.left)).tolist())
