"""Seeded background traffic and sidewalk pedestrians around a route (docs/design.md §2.3).

Vehicles start on drivable edges within ``NEAR`` metres of the route, each with a random
destination among those edges (SUMO's router finds the way); whenever one arrives a new
one is spawned, so the count stays about constant. Pedestrians walk along the sidewalk
of such edges. All choices come from the generator passed in; SUMO's own randomness
(speed deviation) from the simulation seed, so an episode is reproducible.
"""
from __future__ import annotations

import math

import libsumo
import numpy as np
import sumolib

from harness.sim.plan import GlobalPlan, route_lane
from harness.sim.world import PERSON_PREFIX

NEAR = 200.0  # background actors live on edges within this distance of the route [m]
KEEP_CLEAR = 40.0  # no background vehicle starts this close to the ego's start [m]
VEHICLES_PER_KM = 60  # background vehicles per km of route (300 m -> 18)
PERSONS_PER_KM = 40  # sidewalk pedestrians per km of route


def _near_edges(net: sumolib.net.Net, plan: GlobalPlan) -> list[sumolib.net.edge.Edge]:
    pts = plan.xy[::10]
    out = []
    for e in net.getEdges(withInternal=False):
        if e.getFunction() or not any(ln.allows("passenger") for ln in e.getLanes()):
            continue
        shape = np.asarray(e.getShape())[:, :2]
        d = np.min(np.hypot(shape[:, None, 0] - pts[None, :, 0], shape[:, None, 1] - pts[None, :, 1]))
        if d < NEAR:
            out.append(e)
    return sorted(out, key=lambda e: e.getID())


class BackgroundTraffic:
    """Keeps a seeded population of background vehicles and pedestrians near the route."""

    def __init__(self, net: sumolib.net.Net, plan: GlobalPlan, rng: np.random.Generator):
        self.rng, self.plan = rng, plan
        self.edges = _near_edges(net, plan)
        self.start = plan.xy[0]
        self.n_vehicles = max(4, int(VEHICLES_PER_KM * plan.length / 1000))
        self.n_persons = max(4, int(PERSONS_PER_KM * plan.length / 1000))
        self.count = 0
        self.alive: set[str] = set()
        self.persons: set[str] = set()

    def _spawn_vehicle(self) -> None:
        e = self.edges[int(self.rng.integers(len(self.edges)))]
        dest = self.edges[int(self.rng.integers(len(self.edges)))]
        length = e.getLength()
        pos = float(self.rng.uniform(0.0, max(length - 5.0, 1.0)))
        x, y = sumolib.geomhelper.positionAtShapeOffset(e.getShape(), pos)
        self.count += 1
        if np.hypot(x - self.start[0], y - self.start[1]) < KEEP_CLEAR or dest is e:
            return
        route = libsumo.simulation.findRoute(e.getID(), dest.getID(), vType="background")
        if not route.edges:
            return
        vid = f"bg{self.count}"
        libsumo.route.add(f"r_{vid}", list(route.edges))
        libsumo.vehicle.add(vid, f"r_{vid}", typeID="background", departPos=f"{pos:.2f}",
                            departLane="best", departSpeed="max")
        self.alive.add(vid)

    def _spawn_person(self) -> None:
        e = self.edges[int(self.rng.integers(len(self.edges)))]
        length = e.getLength()
        a, b = sorted(self.rng.uniform(0.0, length, size=2))
        if b - a < 5.0:
            return
        forward = bool(self.rng.integers(2))
        self.count += 1
        pid = f"{PERSON_PREFIX}_bg{self.count}"
        libsumo.person.add(pid, e.getID(), float(a if forward else b))
        libsumo.person.appendWalkingStage(pid, [e.getID()], float(b if forward else a))
        self.persons.add(pid)

    def populate(self) -> None:
        """Spawn the initial population (call before the first step)."""
        for _ in range(self.n_vehicles):
            self._spawn_vehicle()
        for _ in range(self.n_persons):
            self._spawn_person()

    def update(self) -> None:
        """Replace vehicles and pedestrians that arrived during the last step."""
        gone = [v for v in libsumo.simulation.getArrivedIDList() if v in self.alive]
        for v in gone:
            self.alive.discard(v)
            self._spawn_vehicle()
        if len(self.persons) and libsumo.simulation.getArrivedPersonNumber():
            present = set(libsumo.person.getIDList())
            for p in sorted(self.persons - present):
                self.persons.discard(p)
                self._spawn_person()


BUBBLE_AHEAD = (55.0, 70.0, 85.0)  # route distance ahead of the ego where leaders appear [m]
BUBBLE_BEHIND = (-40.0, -55.0)  # ... and followers (outside the BEV: 36 m ahead, 12 m behind)
BUBBLE_ONCOMING = (60.0, 80.0)  # ... and oncoming vehicles on the reverse edges
BUBBLE_REFRESH = 1.0  # [s] between bubble top-ups
BUBBLE_RADIUS = 100.0  # a bubble vehicle farther than this from the ego is replaced [m]


class RouteBubble:
    """Background vehicles kept around the ego on its route, like the Leaderboard's
    BackgroundActivity (vehicles ahead and behind in the ego's lanes, oncoming traffic):
    they drive with the ego, wait at its lights, and make the minimum-speed reference.

    Every BUBBLE_REFRESH s, missing vehicles are spawned on the route ahead of the ego,
    behind it, and on the reverse edges ahead, all outside the BEV; a spawn that SUMO
    cannot insert at once (no space) is dropped.
    """

    def __init__(self, net: sumolib.net.Net, plan: GlobalPlan, quiet: tuple[tuple[float, float], ...] = ()):
        """quiet: route intervals [m] where no bubble vehicle is spawned (around obstacles,
        whose bypass needs a gap in the oncoming lane, as the Leaderboard's scenarios ask
        their BackgroundActivity for)."""
        self.net, self.plan, self.quiet = net, plan, quiet  # deterministic: no draws
        self.members: dict[str, str] = {}  # id -> role (ahead, behind, oncoming)
        self.count = 0
        self.next_time = 0.0

    def _spawn_on_route(self, s: float, role: str) -> None:
        if not 0.0 <= s <= self.plan.length or any(a <= s <= b for a, b in self.quiet):
            return
        loc = route_lane(self.plan, self.net, s)
        if loc is not None:
            edge, lane, pos = loc
            edges = [h.edge for h in self.plan.path.legs]
            self._add(edges[edges.index(edge):], lane, pos, role)

    def _spawn_oncoming(self, s: float) -> None:
        if any(a <= s <= b for a, b in self.quiet):
            return
        for g in self.plan.path.legs:
            if g.s0 <= s <= g.s1:
                edge = self.net.getEdge(g.edge)
                rev = f"{edge.getToNode().getID()}_{edge.getFromNode().getID()}"
                if not self.net.hasEdge(rev):
                    return
                lane = next((ln for ln in self.net.getEdge(rev).getLanes() if ln.allows("passenger")), None)
                x, y, _ = self.plan.path.pose(s)
                pos, _ = lane.getClosestLanePosAndDist((x, y))
                self._add([rev], lane.getIndex(), float(pos), "oncoming")
                return

    def _add(self, edges: list[str], lane: int, pos: float, role: str) -> None:
        self.count += 1
        vid = f"bub{self.count}"
        libsumo.route.add(f"r_{vid}", edges)
        libsumo.vehicle.add(vid, f"r_{vid}", typeID="background", departLane=str(lane),
                            departPos=f"{pos:.2f}", departSpeed="max")
        self.members[vid] = role

    def update(self, ego_s: float, ego_xy: tuple[float, float], time: float) -> None:
        """Drop bubble vehicles that left or could not be inserted, spawn missing ones."""
        if time < self.next_time:
            return
        self.next_time = time + BUBBLE_REFRESH
        pending = set(libsumo.simulation.getPendingVehicles())
        alive = set(libsumo.vehicle.getIDList())
        for vid, role in list(self.members.items()):
            if vid in pending:
                libsumo.vehicle.remove(vid)
                del self.members[vid]
            elif vid not in alive:
                del self.members[vid]
            else:
                x, y = libsumo.vehicle.getPosition(vid)
                if math.hypot(x - ego_xy[0], y - ego_xy[1]) > BUBBLE_RADIUS:
                    libsumo.vehicle.remove(vid)
                    del self.members[vid]
        roles = list(self.members.values())
        for k, d in enumerate(BUBBLE_AHEAD):
            if roles.count("ahead") <= k:
                self._spawn_on_route(ego_s + d, "ahead")
        for k, d in enumerate(BUBBLE_BEHIND):
            if roles.count("behind") <= k:
                self._spawn_on_route(ego_s + d, "behind")
        for k, d in enumerate(BUBBLE_ONCOMING):
            if roles.count("oncoming") <= k:
                self._spawn_oncoming(ego_s + d)
