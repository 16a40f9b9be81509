"""Hazards in the running simulation (docs/design.md §2.3): each route hazard becomes an actor of
its type's class (``make_hazard``; the interface is harness.sim.hazard_actor.HazardActor)
that starts when the ego's route progress reaches its trigger point.

Static things (the obstacle in the lane, the parked car hiding a jaywalker) exist from
the start of the episode, as in the Leaderboard where scenario actors are spawned long
before the ego arrives. Moving things start at the trigger:

- PedestrianCrossing: walkers step onto the crosswalk from the chosen side.
- DynamicObjectCrossing: a walker crosses the road at the site, perpendicular to it.
- ParkedObstacle: a stopped vehicle (SUMO type ``obstacle_*``, class static) in the ego lane.
- HardBreakRoute: a leader appears ``gap`` m ahead in the ego lane and brakes hard at the site.
- ParkingCutIn: a vehicle pulls from the curb (or the left lane) into the ego lane ahead.
- SignalizedJunction: the light of the ego's link is switched to the start of its red
  phase, and cross traffic flows; StopSignJunction: cross traffic flows;
  UnprotectedLeftTurn: oncoming traffic flows.

Walkers and cut-in vehicles are moved by the harness (``moveToXY``) along straight
scripted paths. At the end of its path a walker is removed, as the Leaderboard's
pedestrian scenarios destroy theirs: released to SUMO, a walker that ``moveToXY`` had
mapped onto a vehicle lane walked on along the road and, at the lane's end, SUMO stopped
with "Disconnected walk" (val route 8). The cut-in vehicle drives on ahead of the ego
(``ParkingCutIn._drive_on``). Positions are world frame [m]; s is route arc length [m].
"""
from __future__ import annotations

import math
from typing import ClassVar

import libsumo
import numpy as np
import sumolib

from controller.vehicle import DT
from harness.sim.hazard_actor import (SCENARIO_END, SCENARIO_TIMEOUT, HazardActor, Scripted, _add_person,
                                      _road_sides)
from harness.sim.plan import GlobalPlan, route_lane
from harness.sim.world import PERSON_PREFIX, sumo_angle
from scenarios.hazards import HAZARDS
from scenarios.routefile import Hazard

CURB_MARGIN = 1.2  # walkers start / end this far beyond the road edge [m]
FLOW_TIME = 25.0  # junction traffic keeps coming this long after the trigger [s]
HOLD_TIME = 3.0  # a hard-braking leader stays stopped this long [s]
CUT_IN_SPEED = 6.0  # the cut-in vehicle drives on ahead at this speed [m/s]
RED_HOLD = 6.0  # the switched light stays red this long after the ego could reach it [s]

# hazard type (scenarios.hazards.HAZARDS) -> its actor class, filled by ``actor``
HAZARD_ACTORS: dict[str, type[HazardActor]] = {}


def actor(cls: type[HazardActor]) -> type[HazardActor]:
    """Register ``cls`` as the actor of the hazard type of its name (class decorator)."""
    if cls.__name__ not in HAZARDS:
        raise ValueError(f"actor class {cls.__name__}: no hazard type of that name in scenarios.hazards.HAZARDS")
    HAZARD_ACTORS[cls.__name__] = cls
    return cls


@actor
class PedestrianCrossing(HazardActor):
    """Walkers cross the crosswalk ``crossing`` from the ``direction`` side."""

    def _start(self, ego_s: float, ego_speed: float) -> None:
        p = self.hazard.params
        lane = self.net.getLane(p["crossing"] + "_0")
        a, b = (np.asarray(q[:2], dtype=float) for q in (lane.getShape()[0], lane.getShape()[-1]))
        x, y, yaw = self.plan.path.pose(self.site_s)
        right = (math.sin(yaw), -math.cos(yaw))
        a_right = np.dot(a - (x, y), right) > np.dot(b - (x, y), right)
        start, end = (a, b) if a_right == (p["direction"] == "right") else (b, a)
        u = (end - start) / max(np.hypot(*(end - start)), 1e-6)
        for k in range(int(p["walkers"])):
            pid = f"{PERSON_PREFIX}_{self.tag}_{k}"
            side = np.array([-u[1], u[0]]) * (k - (int(p["walkers"]) - 1) / 2) * 0.8
            p0 = start - u * (CURB_MARGIN + 0.7 * k) + side
            p1 = end + u * CURB_MARGIN + side
            _add_person(pid, self.plan.path.legs[0].edge, *p0)
            self.scripted.append(Scripted(pid, p0, p1, float(p["speed"]), person=True))


@actor
class DynamicObjectCrossing(HazardActor):
    """A walker crosses the road at the site, perpendicular to it, from the ``direction``
    side; with ``blocker=parked_car`` a harness-only parked car stands before the site."""

    def setup(self) -> None:
        if self.hazard.params["blocker"] != "parked_car":
            return
        x, y, yaw = self.plan.path.pose(self.site_s - 6.0)
        right, _ = _road_sides(self.plan, self.net, self.site_s)
        off = right - 0.4  # on the sidewalk / shoulder, its inner edge ~0.7 m clear of the ego's side
        self.props.append((x + math.sin(yaw) * off, y - math.cos(yaw) * off, yaw, 4.6, 1.9))

    def _start(self, ego_s: float, ego_speed: float) -> None:
        p = self.hazard.params
        x, y, yaw = self.plan.path.pose(self.site_s)
        right, left = _road_sides(self.plan, self.net, self.site_s)
        r = np.array([math.sin(yaw), -math.cos(yaw)])
        sign = 1.0 if p["direction"] == "right" else -1.0
        p0 = np.array([x, y]) + sign * r * ((right if sign > 0 else left) + CURB_MARGIN)
        p1 = np.array([x, y]) - sign * r * ((left if sign > 0 else right) + CURB_MARGIN)
        pid = f"{PERSON_PREFIX}_{self.tag}"
        _add_person(pid, self.plan.path.legs[0].edge, *p0)
        self.scripted.append(Scripted(pid, p0, p1, float(p["speed"]), person=True))


@actor
class ParkedObstacle(HazardActor):
    """A stopped vehicle of type ``obstacle_<variant>`` in the ego lane at the site; its
    lane is kept free of background traffic. When the scenario times out (240 s after the
    trigger with the ego not yet 10 m past the site), the obstacle is removed and the ego
    may drive on, as the Leaderboard's obstacle scenarios destroy their actors when they
    end."""

    def __init__(self, hazard: Hazard, plan: GlobalPlan, net: sumolib.net.Net, rng: np.random.Generator,
                 n: int):
        super().__init__(hazard, plan, net, rng, n)
        self.cleared_lane: str | None = None  # lane kept free of background traffic
        self.obstacle: str | None = None  # the obstacle's SUMO id while it stands

    def quiet_span(self) -> tuple[float, float]:
        """100 m before to 150 m past the obstacle."""
        return self.site_s - 100.0, self.site_s + 150.0

    def setup(self) -> None:
        loc = route_lane(self.plan, self.net, self.site_s)
        if loc is None:
            return
        edge, lane, pos = loc
        vt = f"obstacle_{self.hazard.params['variant']}"
        vid = f"{self.tag}_obstacle"
        libsumo.route.add(f"r_{vid}", [edge])
        libsumo.vehicle.add(vid, f"r_{vid}", typeID=vt, departLane=str(lane),
                            departPos=f"{pos:.2f}", departSpeed="0")
        libsumo.vehicle.setSpeedMode(vid, 0)
        libsumo.vehicle.setLaneChangeMode(vid, 0)
        libsumo.vehicle.setSpeed(vid, 0.0)
        self.cleared_lane = f"{edge}_{lane}"
        self.obstacle = vid

    def _tick(self, ego_s: float, time: float, ego_speed: float) -> None:
        """Remove the obstacle once the scenario has timed out."""
        if (self.obstacle is not None and ego_s < self.site_s + SCENARIO_END
                and time - self.t0 > SCENARIO_TIMEOUT):
            libsumo.vehicle.remove(self.obstacle)
            self.obstacle = None

    def update(self, ego_s: float, time: float, ego_speed: float) -> None:
        """The obstacle's lane cleared every tick, before and after the trigger."""
        if self.cleared_lane is not None:
            self._clear_lane()
        super().update(ego_s, time, ego_speed)

    def _clear_lane(self) -> None:
        """Remove background vehicles from the obstacle's lane, as the Leaderboard's
        obstacle scenarios do (RemoveRoadLane): SUMO traffic cannot pass the obstacle
        and would queue behind it for good, with the ego behind them."""
        for vid in libsumo.lane.getLastStepVehicleIDs(self.cleared_lane):
            if vid.startswith(("bg", "bub")):
                libsumo.vehicle.remove(vid)


@actor
class HardBreakRoute(HazardActor):
    """A leader inserted ``gap`` m ahead of the ego at the trigger starts braking at ``decel``
    [m/s^2] when it reaches the site, stands HOLD_TIME s, then drives on."""

    def __init__(self, hazard: Hazard, plan: GlobalPlan, net: sumolib.net.Net, rng: np.random.Generator,
                 n: int):
        super().__init__(hazard, plan, net, rng, n)
        self.leader = f"{self.tag}_leader"
        self.leader_tries = 0
        self.leader_on_road = False
        self.brake_state = "drive"  # drive -> brake -> done
        self.t_brake = 0.0  # simulation time [s] the leader is expected to stand still

    def _start(self, ego_s: float, ego_speed: float) -> None:
        self._add_leader(ego_s, ego_speed)

    def _add_leader(self, ego_s: float, ego_speed: float) -> None:
        """Insert the leader ``gap`` m ahead of the ego, in the route's lane (not yet if
        that point lies inside a junction)."""
        loc = route_lane(self.plan, self.net, ego_s + float(self.hazard.params["gap"]))
        if loc is None:
            return
        edge, lane, pos = loc
        legs = [g.edge for g in self.plan.path.legs]
        vid = self.leader
        self.leader_tries += 1
        route_id = f"r_{vid}_{self.leader_tries}"
        libsumo.route.add(route_id, legs[legs.index(edge):])
        # at the ego's speed; a retry (SUMO found no safe gap for that speed, often behind
        # traffic already ahead of the ego) at the highest speed that is safe there
        speed = f"{max(ego_speed, 3.0):.2f}" if self.leader_tries == 1 else "max"
        try:
            libsumo.vehicle.add(vid, route_id, typeID="hazard", departLane=str(lane),
                                departPos=f"{pos:.2f}", departSpeed=speed)
        except libsumo.TraCIException:
            # an ego faster than the leader's own desired speed (a student can be): SUMO
            # refuses that departure speed, so the leader starts at its desired speed
            libsumo.vehicle.add(vid, route_id, typeID="hazard", departLane=str(lane),
                                departPos=f"{pos:.2f}", departSpeed="desired")
        libsumo.vehicle.setLaneChangeMode(vid, 0)

    def _tick(self, ego_s: float, time: float, ego_speed: float) -> None:
        vid = self.leader
        if vid not in libsumo.vehicle.getIDList():
            if not self.leader_on_road:
                # not inserted yet: ``gap`` m ahead of the ego lay inside a junction, or SUMO
                # found no safe gap there and would insert it later, wherever the ego is by
                # then (beside it, route 50): place it ``gap`` m ahead of the ego now
                if vid in libsumo.simulation.getPendingVehicles():
                    libsumo.vehicle.remove(vid)
                self._add_leader(ego_s, ego_speed)
            return
        self.leader_on_road = True
        if self.brake_state == "drive":
            x, y = libsumo.vehicle.getPosition(vid)
            s, d = self.plan.path.project(x, y, self.trigger_s)
            if d < 5.0 and s >= self.site_s:
                v = libsumo.vehicle.getSpeed(vid)
                decel = float(self.hazard.params["decel"])
                libsumo.vehicle.setDecel(vid, decel)  # setSpeed(0) brakes at the type's decel
                libsumo.vehicle.setSpeed(vid, 0.0)
                self.brake_state, self.t_brake = "brake", time + v / decel
        elif self.brake_state == "brake" and time >= self.t_brake + HOLD_TIME:
            libsumo.vehicle.setSpeed(vid, -1)
            self.brake_state = "done"


@actor
class ParkingCutIn(HazardActor):
    """At the trigger a vehicle pulls from the curb (``source=parking``) or the left lane
    into the ego lane before the site, then drives on ahead of the ego."""

    def __init__(self, hazard: Hazard, plan: GlobalPlan, net: sumolib.net.Net, rng: np.random.Generator,
                 n: int):
        super().__init__(hazard, plan, net, rng, n)
        self.cruise: tuple[str, float] | None = None  # the vehicle driven on along the route: (id, s [m])

    def _start(self, ego_s: float, ego_speed: float) -> None:
        loc = route_lane(self.plan, self.net, self.site_s)
        if loc is None:
            return
        edge, lane, _ = loc
        x0, y0, yaw0 = self.plan.path.pose(self.site_s - 4.0)
        x1, y1, _ = self.plan.path.pose(self.site_s + 10.0)
        r = np.array([math.sin(yaw0), -math.cos(yaw0)])
        right, _ = _road_sides(self.plan, self.net, self.site_s)
        off = (right - 0.8) if self.hazard.params["source"] == "parking" else -3.3
        p0 = np.array([x0, y0]) + r * off
        legs = [g.edge for g in self.plan.path.legs]
        vid = f"{self.tag}_cutin"
        libsumo.route.add(f"r_{vid}", legs[legs.index(edge):])
        libsumo.vehicle.add(vid, f"r_{vid}", typeID="hazard", departLane=str(lane), departPos="0",
                            departSpeed="0")
        libsumo.vehicle.setSpeedMode(vid, 0)
        libsumo.vehicle.setLaneChangeMode(vid, 0)
        self.scripted.append(Scripted(vid, p0, np.array([x1, y1]), 4.0, person=False))

    def _arrived(self, a: Scripted) -> None:
        """The cut-in is done: the vehicle drives on ahead of the ego from 10 m past the site."""
        self.cruise = (a.id, self.site_s + 10.0)

    def _tick(self, ego_s: float, time: float, ego_speed: float) -> None:
        if self.cruise is not None:
            self._drive_on()

    def _drive_on(self) -> None:
        """Move the cut-in vehicle along the route at CUT_IN_SPEED, then remove it.

        It stays harness-driven: released to SUMO after a moveToXY cut-in, a vehicle keeps
        the one-edge route moveToXY gave it and can stop for good in front of the ego."""
        vid, s = self.cruise
        s += CUT_IN_SPEED * DT
        if s >= self.plan.length or vid not in libsumo.vehicle.getIDList():
            if vid in libsumo.vehicle.getIDList():
                libsumo.vehicle.remove(vid)
            self.cruise = None
            return
        x, y, yaw = self.plan.path.pose(s)
        libsumo.vehicle.moveToXY(vid, "", -1, x + math.cos(yaw) * 2.3, y + math.sin(yaw) * 2.3,
                                 sumo_angle(yaw), keepRoute=2)
        libsumo.vehicle.setSpeed(vid, CUT_IN_SPEED)
        self.cruise = (vid, s)


class _JunctionFlow(HazardActor):
    """Traffic at junction ``junction``: from the trigger on, for FLOW_TIME s, ``flow``
    vehicles per minute from every incoming edge whose traffic crosses the ego's path
    (``ONCOMING`` False) or meets it head-on (True)."""

    ONCOMING: ClassVar[bool] = False

    def __init__(self, hazard: Hazard, plan: GlobalPlan, net: sumolib.net.Net, rng: np.random.Generator,
                 n: int):
        super().__init__(hazard, plan, net, rng, n)
        self.spawned = 0
        self.flow_next = 0.0  # simulation time [s] of the next vehicles

    def _tick(self, ego_s: float, time: float, ego_speed: float) -> None:
        if time - self.t0 <= FLOW_TIME and time >= self.flow_next:
            self._spawn_flow()
            self.flow_next = time + 60.0 / float(self.hazard.params["flow"])

    def _approaches(self) -> list[str]:
        """Incoming edges whose traffic crosses (or, ONCOMING, meets) the ego's path."""
        pas = next((q for q in self.plan.passages if q.junction == self.hazard.params["junction"]), None)
        if pas is None:
            return []
        node = self.net.getNode(pas.junction)
        mine = self.net.getEdge(pas.from_edge)

        def heading(e):
            sh = e.getShape()
            return math.atan2(sh[-1][1] - sh[-2][1], sh[-1][0] - sh[-2][0])

        h0 = heading(mine)
        out = []
        for e in sorted(node.getIncoming(), key=lambda e: e.getID()):
            if e.getID() == pas.from_edge or e.getFunction():
                continue
            d = abs((heading(e) - h0 + math.pi) % (2 * math.pi) - math.pi)
            oncoming = d > math.radians(135)
            if self.ONCOMING == oncoming:
                out.append(e.getID())
        return out

    def _spawn_flow(self) -> None:
        """One vehicle on each approach, 45-60 m before the junction, going straight on."""
        for edge_id in self._approaches():
            e = self.net.getEdge(edge_id)
            straight = [c.getTo().getID() for c in e.getOutgoing() for c in e.getConnections(c)
                        if c.getDirection() == "s" and c.getFromLane().allows("passenger")]
            outs = straight or [o.getID() for o in e.getOutgoing() if not o.getFunction()]
            if not outs:
                continue
            self.spawned += 1
            vid = f"{self.tag}_flow{self.spawned}"
            libsumo.route.add(f"r_{vid}", [edge_id, outs[0]])
            pos = max(0.0, e.getLength() - 45.0 - float(self.rng.uniform(0, 15)))
            libsumo.vehicle.add(vid, f"r_{vid}", typeID="hazard", departLane="best",
                                departPos=f"{pos:.2f}", departSpeed="max")


@actor
class SignalizedJunction(_JunctionFlow):
    """Cross traffic, and the ego's light switched to red at the trigger."""

    def _start(self, ego_s: float, ego_speed: float) -> None:
        self._switch_to_red(ego_s, ego_speed)

    def _switch_to_red(self, ego_s: float, ego_speed: float) -> None:
        """Turn the ego's light red now, for as long as the ego needs to reach it plus
        RED_HOLD seconds: a red light the ego must stop at, not a half-minute wait."""
        pas = next((q for q in self.plan.passages if q.junction == self.hazard.params["junction"] and q.tls), None)
        if pas is None:
            return
        logic = libsumo.trafficlight.getAllProgramLogics(pas.tls)[0]
        states = [ph.state for ph in logic.phases]
        for k, st in enumerate(states):
            if st[pas.link] in "rR" and states[k - 1][pas.link] in "yY":
                libsumo.trafficlight.setPhase(pas.tls, k)
                arrive = max(pas.s_in - ego_s, 0.0) / max(ego_speed, 3.0)
                libsumo.trafficlight.setPhaseDuration(pas.tls, min(arrive + RED_HOLD, logic.phases[k].duration))
                return


@actor
class StopSignJunction(_JunctionFlow):
    """Cross traffic at a stop-sign junction."""


@actor
class UnprotectedLeftTurn(_JunctionFlow):
    """Oncoming traffic at the junction where the ego turns left."""

    ONCOMING = True


def make_hazard(hazard: Hazard, plan: GlobalPlan, net: sumolib.net.Net, rng: np.random.Generator,
                n: int) -> HazardActor:
    """The actor of hazard ``n`` of a route, of its type's class; ValueError for an
    unknown type."""
    cls = HAZARD_ACTORS.get(hazard.type)
    if cls is None:
        raise ValueError(f"hazard {hazard.name!r}: unknown type {hazard.type!r} (known: {', '.join(HAZARD_ACTORS)})")
    return cls(hazard, plan, net, rng, n)
