"""The interface of a route hazard in the running simulation, and what its kinds share.

``HazardActor`` is what the episode drives: built once per route hazard before the first
step, ``setup()`` places its static parts, ``update(ego_s, time, ego_speed)`` runs every
tick (it starts the hazard when the ego's route progress reaches the trigger point, then
advances it), ``timeout_active`` tells the Blocked criterion whether the hazard's scenario
timeout runs, ``quiet_span`` where the route bubble spawns nothing, ``walking()`` the
walkers' scripted speeds. One subclass per hazard type (harness.sim.hazards) fills in
``setup``, ``_start`` (at the trigger) and ``_tick`` (every tick after it).

``Scripted`` moves a walker or a vehicle along a straight path with ``moveToXY``.
Positions are world frame [m]; s is route arc length [m].
"""
from __future__ import annotations

import math

import libsumo
import numpy as np
import sumolib

from controller.vehicle import DT
from harness.sim.plan import GlobalPlan, route_lane
from harness.sim.world import sumo_angle
from scenarios.hazards import HAZARDS
from scenarios.routefile import Hazard

# moveToXY for walkers: bit 1 (place exactly, off-lane too) + bit 2 (ignore permissions).
# With keepRoute 0 or 2, SUMO 1.28 segfaulted in simulationStep when a walker was moved
# across a crosswalk (town12_short route 29); 6 does not.
PERSON_KEEP_ROUTE = 6
# Scenario timeouts (docs/design.md §9.1): hazards that can block the ego get 240 s
# from their trigger to their own end (the ego this far past the site)
SCENARIO_TIMEOUT = 240.0  # [s]
SCENARIO_END = 10.0  # [m]


def _road_sides(plan: GlobalPlan, net: sumolib.net.Net, s: float) -> tuple[float, float]:
    """Distances [m] from the route centre to the right and left outer road borders at s
    (sidewalks included, the opposite direction's edge included)."""
    loc = route_lane(plan, net, s)  # the lane the route is on at s (it may change lanes along an edge)
    if loc is None:
        return 5.0, 5.0
    edge, i = net.getEdge(loc[0]), loc[1]
    widths = [ln.getWidth() for ln in edge.getLanes()]
    right = widths[i] / 2 + sum(widths[:i])
    left = widths[i] / 2 + sum(widths[i + 1:])
    rev = f"{edge.getToNode().getID()}_{edge.getFromNode().getID()}"
    if net.hasEdge(rev):
        left += sum(ln.getWidth() for ln in net.getEdge(rev).getLanes())
    return right, left


class Scripted:
    """An actor moved by the harness from p0 to p1 (world frame [m]) at a constant speed [m/s]."""

    def __init__(self, aid: str, p0: np.ndarray, p1: np.ndarray, speed: float, person: bool):
        self.id, self.p0, self.p1, self.speed, self.person = aid, p0, p1, speed, person
        self.dist = 0.0
        self.total = float(np.hypot(*(p1 - p0)))
        self.yaw = math.atan2(*(p1 - p0)[::-1])

    def place(self) -> bool:
        """Move one step along the path; False once the end is reached."""
        f = min(self.dist / self.total, 1.0) if self.total > 0 else 1.0
        x, y = self.p0 + f * (self.p1 - self.p0)
        if self.person:
            libsumo.person.moveToXY(self.id, "", x, y, sumo_angle(self.yaw), keepRoute=PERSON_KEEP_ROUTE)
        else:
            fx, fy = x + math.cos(self.yaw) * 2.3, y + math.sin(self.yaw) * 2.3
            # the last placement maps the vehicle back onto its route's lane (keepRoute 1),
            # so that SUMO drives it on after release; off-lane (2) it would stand still
            libsumo.vehicle.moveToXY(self.id, "", -1, fx, fy, sumo_angle(self.yaw), keepRoute=1 if f >= 1.0 else 2)
            libsumo.vehicle.setSpeed(self.id, self.speed)
        self.dist += self.speed * DT
        return f < 1.0


def _add_person(pid: str, edge: str, x: float, y: float) -> None:
    """A walker standing at world (x, y) [m], waiting for the harness to move it."""
    libsumo.person.add(pid, edge, 0.0)
    libsumo.person.appendWaitingStage(pid, 10_000.0)
    libsumo.person.moveToXY(pid, edge, x, y, keepRoute=PERSON_KEEP_ROUTE)


class HazardActor:
    """One hazard of a route in the running simulation (a subclass per hazard type).

    ``trigger_s`` is the route arc length [m] of the trigger point, ``site_s`` that of the
    site (``distance`` m further); ``t0`` the simulation time [s] it started at.
    """

    def __init__(self, hazard: Hazard, plan: GlobalPlan, net: sumolib.net.Net, rng: np.random.Generator,
                 n: int):
        """``hazard`` is the route file's scenario, ``n`` its index in the route (actor ids
        carry it); ``rng`` draws whatever the hazard randomises (shared by a route's hazards)."""
        self.hazard, self.plan, self.net, self.rng, self.n = hazard, plan, net, rng, n
        self.trigger_s, _ = plan.path.project(hazard.trigger[0], hazard.trigger[1])
        self.site_s = self.trigger_s + float(hazard.params["distance"])
        self.started = False
        self.t0 = 0.0
        self.scripted: list[Scripted] = []
        self.props: list[tuple[float, float, float, float, float]] = []  # x, y, yaw, length, width

    @property
    def tag(self) -> str:
        """Prefix of the ids of this hazard's SUMO actors."""
        return f"hz{self.n}"

    def timeout_active(self, ego_s: float, time: float) -> bool:
        """Whether this hazard's 240 s scenario timeout is running (Leaderboard: the
        blocked check is off meanwhile): started, not passed, not yet timed out."""
        return (self.started and HAZARDS[self.hazard.type].timeout
                and ego_s < self.site_s + SCENARIO_END and time - self.t0 <= SCENARIO_TIMEOUT)

    def quiet_span(self) -> tuple[float, float] | None:
        """Route interval [m] where the route bubble spawns no vehicle, or None."""
        return None

    def walking(self) -> dict[str, float]:
        """Scripted walking speed [m/s] of each of this hazard's walkers on the road, by id."""
        return {a.id: a.speed for a in self.scripted if a.person}

    # --- lifecycle -------------------------------------------------------------------
    def setup(self) -> None:
        """Place the static parts (called once before the first step)."""

    def update(self, ego_s: float, time: float, ego_speed: float) -> None:
        """One tick at ego route progress ego_s [m], simulation time [s] and ego speed
        [m/s]: start at the trigger, then advance the scripted actors and the rest."""
        if not self.started:
            if ego_s >= self.trigger_s:
                self.started, self.t0 = True, time
                self._start(ego_s, ego_speed)
            return
        for a in list(self.scripted):
            if not a.place():
                self.scripted.remove(a)
                self._arrived(a)
        self._tick(ego_s, time, ego_speed)

    # --- filled in per type ------------------------------------------------------------
    def _start(self, ego_s: float, ego_speed: float) -> None:
        """What happens at the trigger."""

    def _arrived(self, a: Scripted) -> None:
        """A scripted actor reached the end of its path: a walker has crossed and is
        removed, as the Leaderboard's pedestrian scenarios destroy theirs."""
        libsumo.person.remove(a.id)

    def _tick(self, ego_s: float, time: float, ego_speed: float) -> None:
        """Every tick after the trigger, after the scripted actors moved."""
