"""Seeded background traffic and sidewalk pedestrians around a route (SPEC §2.3).

Vehicles start on drivable edges within ``NEAR`` metres of the route, each with a random
destination among those edges (SUMO's router finds the way); whenever one arrives a new
one is spawned, so the count stays about constant. Pedestrians walk along the sidewalk
of such edges. All choices come from the generator passed in; SUMO's own randomness
(speed deviation) from the simulation seed, so an episode is reproducible.
"""
from __future__ import annotations

import libsumo
import numpy as np
import sumolib

from harness.plan import GlobalPlan
from harness.world import PERSON_PREFIX

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
