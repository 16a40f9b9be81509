"""Hazard types of the route sets (docs/design.md §2.3) and where a route offers room for them.

Every hazard in a route file is a Leaderboard-2.0-style ``<scenario name type>`` with a
``trigger_point`` and parameters as child elements ``<param value="..."/>``. The
``distance`` parameter, common to all types, is the distance [m] along the route from the
trigger point to the hazard's site (the crosswalk, the obstacle, the junction entry...):
the harness starts the hazard when the ego's route progress reaches the trigger point.

``type`` is one of the eight names below; each stands for the CARLA Leaderboard 2.0
scenario class(es) in ``carla`` (variants are parameters here, separate classes there).

``HAZARDS`` is the one registry of hazard types: an entry says everything the earlier
stages and the scoring need (parameters, sites, the builder's draw, scenario timeout,
TwoWays); the simulation registers one actor class per entry (harness.sim.hazards). A new
type is one ``HazardType`` here and one actor class there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import sumolib

from scenarios.geometry import RoutePath


@dataclass(frozen=True)
class Param:
    """One hazard parameter: a number in [lo, hi], or one of ``choices``, or a SUMO id."""

    name: str
    kind: str  # "float", "int", "choice" or "id"
    lo: float = -math.inf
    hi: float = math.inf
    choices: tuple[str, ...] = ()
    doc: str = ""

    def check(self, raw: str) -> str | None:
        """None if ``raw`` is a valid value, else the reason."""
        if self.kind == "choice":
            return None if raw in self.choices else f"{self.name}={raw!r} is not one of {', '.join(self.choices)}"
        if self.kind == "id":
            return None if raw.strip() else f"{self.name} is empty"
        try:
            v = int(raw) if self.kind == "int" else float(raw)
        except ValueError:
            return f"{self.name}={raw!r} is not a{'n integer' if self.kind == 'int' else ' number'}"
        if not self.lo <= v <= self.hi:
            return f"{self.name}={raw} is outside [{self.lo:g}, {self.hi:g}]"
        return None


@dataclass(frozen=True)
class Site:
    """Room for a hazard on a route: its site may lie anywhere in [s_lo, s_hi] (route s, m)."""

    kind: str
    s_lo: float
    s_hi: float
    fixed: tuple[tuple[str, str], ...] = ()  # parameters the site decides (junction id, lane...)


Draw = Callable[[np.random.Generator, dict], dict]  # (rng, the site's fixed params) -> drawn params
Finder = Callable[[sumolib.net.Net, RoutePath], list[Site]]  # (net, route) -> the type's sites


@dataclass(frozen=True)
class HazardType:
    """What a hazard type is, for every stage: its parameters (and their validation), where
    a route has room for it, how the route-set builder draws it, and how the Leaderboard
    scores it. The simulation's actor class registers under ``name``
    (harness.sim.hazards)."""

    name: str
    carla: str  # the CARLA Leaderboard 2.0 scenario class(es) it stands for
    doc: str
    params: tuple[Param, ...]
    sites: Finder  # every place on a traced route where it fits
    distance: tuple[float, float]  # the builder draws ``distance`` [m] from this range
    draw: Draw  # the builder's draw of the other parameters (inside their valid ranges)
    timeout: bool = False  # a Leaderboard scenario timeout applies (it can hold the ego)
    two_ways: tuple[str, str] | None = None  # (param, value) making it a TwoWays scenario:
    # the Leaderboard switches the wrong-lane check off near it


def _distance(lo: float, hi: float) -> Param:
    return Param("distance", "float", lo, hi, doc="route distance from trigger point to site [m]")


FLOW = Param("flow", "int", 4, 30, doc="cross or oncoming vehicles per minute while active")
JUNCTION = Param("junction", "id", doc="SUMO junction id on the route")
JUNCTION_CLEAR = 25.0  # mid-block sites keep this far from junctions [m]
END_CLEAR = 25.0  # ...and from the route end [m]


def _oncoming(net: sumolib.net.Net, node_id: str, from_edge: str) -> bool:
    """Whether some approach of the junction faces the ego's (within 45 deg of opposite)."""
    node = net.getNode(node_id)
    mine = net.getEdge(from_edge).getLanes()[-1].getShape()
    h0 = math.atan2(mine[-1][1] - mine[-2][1], mine[-1][0] - mine[-2][0])
    for e in node.getIncoming():
        if e.getID() == from_edge or e.getFunction():
            continue
        sh = e.getLanes()[-1].getShape()
        h = math.atan2(sh[-1][1] - sh[-2][1], sh[-1][0] - sh[-2][0])
        if abs((h - h0 + math.pi) % (2 * math.pi) - math.pi) > math.radians(135):
            return True
    return False


def _crossings(net: sumolib.net.Net, junction: str) -> list[str]:
    """Crossing edge ids of a junction (SUMO names them ``:<junction>_c<k>``)."""
    prefix = f":{junction}_c"
    lanes = net.getNode(junction).getInternal()  # the junction's intLanes, crossings included
    return sorted({ln.rsplit("_", 1)[0] for ln in lanes if ln.startswith(prefix)})


# --- where each type fits --------------------------------------------------------------
def _crosswalk_sites(net: sumolib.net.Net, path: RoutePath) -> list[Site]:
    """Crosswalks the route crosses at a junction: the site is the crosswalk's middle."""
    out = []
    for p in path.passages:
        for cid in _crossings(net, p.junction):
            crossing = net.getEdge(cid)
            crossed = {c.getID() for c in crossing.getCrossingEdges()}
            if p.to_edge in crossed or p.from_edge in crossed:
                shape = crossing.getLanes()[0].getShape()
                cx = (shape[0][0] + shape[-1][0]) / 2
                cy = (shape[0][1] + shape[-1][1]) / 2
                s, d = path.project(cx, cy, p.s_in - 15, p.s_out + 15)
                if d < 6.0:
                    out.append(Site("PedestrianCrossing", s, s, (("crossing", cid),)))
    return out


def _junction_sites(kind: str, fits: Callable[[sumolib.net.Net, object], bool]) -> Finder:
    """The junction entries of the route where ``fits(net, passage)``."""
    def find(net: sumolib.net.Net, path: RoutePath) -> list[Site]:
        return [Site(kind, p.s_in, p.s_in, (("junction", p.junction),)) for p in path.passages if fits(net, p)]
    return find


def _mid_block_sites(kind: str, fixed: Callable[[sumolib.net.Net, object], tuple | None]) -> Finder:
    """Straight single-lane stretches of the route clear of junctions and the route end,
    where ``fixed(net, leg)`` is not None (the parameters the stretch decides)."""
    def find(net: sumolib.net.Net, path: RoutePath) -> list[Site]:
        out = []
        for leg in path.legs:
            lo, hi = leg.s0 + (JUNCTION_CLEAR if leg.s0 > 0 else 0.0), leg.s1 - JUNCTION_CLEAR
            hi = min(hi, path.length - END_CLEAR)
            if hi <= lo or leg.lane_in != leg.lane_out:
                continue
            f = fixed(net, leg)
            if f is not None:
                out.append(Site(kind, lo, hi, f))
        return out
    return find


def _lanes(net: sumolib.net.Net, leg) -> tuple[bool, bool, bool]:
    """(the leg's lane is the rightmost car lane, a car lane lies left of it, the reverse edge exists)."""
    edge = net.getEdge(leg.edge)
    driving = [ln.getIndex() for ln in edge.getLanes() if ln.allows("passenger")]
    idx = int(leg.lane_in.rsplit("_", 1)[1])
    reverse = f"{edge.getToNode().getID()}_{edge.getFromNode().getID()}"
    return idx == min(driving), idx + 1 in driving, net.hasEdge(reverse)


def _obstacle_fixed(net: sumolib.net.Net, leg) -> tuple | None:
    _, has_left, reverse = _lanes(net, leg)
    if not (has_left or reverse):
        return None
    return ("bypass", "neighbour" if has_left else "oncoming"), ("lane", leg.lane_in)


def _cut_in_fixed(net: sumolib.net.Net, leg) -> tuple | None:
    rightmost, has_left, _ = _lanes(net, leg)
    return (("source", "parking" if rightmost else "lane"),) if rightmost or has_left else None


def _hard_break_sites(net: sumolib.net.Net, path: RoutePath) -> list[Site]:
    """Anywhere from 40 m on to END_CLEAR before the end, on a long enough route."""
    return [Site("HardBreakRoute", 40.0, path.length - END_CLEAR)] if path.length > 2 * END_CLEAR + 20 else []


# --- how the route-set builder draws each type's parameters ----------------------------
def _draw_walkers(rng: np.random.Generator, p: dict) -> dict:
    return p | {"walkers": str(int(rng.integers(1, 4))), "direction": str(rng.choice(["right", "left"])),
                "speed": f"{rng.uniform(0.9, 1.5):.2f}"}


def _draw_jaywalker(rng: np.random.Generator, p: dict) -> dict:
    side = str(rng.choice(["right", "right", "left"]))
    return p | {"direction": side, "blocker": str(rng.choice(["parked_car", "none"])) if side == "right" else "none",
                "speed": f"{rng.uniform(1.2, 2.5):.2f}"}


def _draw_obstacle(rng: np.random.Generator, p: dict) -> dict:
    return {"variant": str(rng.choice(["parked_car", "accident", "construction"])), **p}


def _draw_leader(rng: np.random.Generator, p: dict) -> dict:
    return p | {"gap": f"{rng.uniform(15, 30):.1f}", "decel": f"{rng.uniform(5, 8):.1f}"}


def _draw_cut_in(rng: np.random.Generator, p: dict) -> dict:
    return p | {"direction": "right" if p["source"] == "parking" else "left"}


def _draw_flow(rng: np.random.Generator, p: dict) -> dict:
    return p | {"flow": str(int(rng.integers(8, 21)))}


def _junction(name: str, carla: str, doc: str, fits, timeout: bool) -> HazardType:
    """A junction hazard: traffic at a junction of the route, ``flow`` vehicles a minute."""
    return HazardType(name, carla, doc, (_distance(25, 70), JUNCTION, FLOW), _junction_sites(name, fits),
                      (35, 55), _draw_flow, timeout=timeout)


# The registry: one entry per hazard type.
HAZARDS: dict[str, HazardType] = {h.name: h for h in (
    HazardType("PedestrianCrossing", "PedestrianCrossing",
               "walkers cross a crosswalk on the route as the ego approaches", (
                   _distance(15, 35), Param("crossing", "id", doc="SUMO crossing edge id"),
                   Param("walkers", "int", 1, 4, doc="number of walkers"),
                   Param("direction", "choice", choices=("right", "left"), doc="side they start from"),
                   Param("speed", "float", 0.5, 2.0, doc="walking speed [m/s]")),
               _crosswalk_sites, (18, 30), _draw_walkers),
    HazardType("DynamicObjectCrossing", "DynamicObjectCrossing",
               "a jaywalker steps out mid-block, possibly from behind a parked car", (
                   _distance(10, 30),
                   Param("direction", "choice", choices=("right", "left"), doc="side it comes from"),
                   Param("blocker", "choice", choices=("parked_car", "none"), doc="what hides it"),
                   Param("speed", "float", 0.8, 3.0, doc="walking speed [m/s]")),
               _mid_block_sites("DynamicObjectCrossing", lambda net, leg: ()), (12, 22), _draw_jaywalker),
    HazardType("ParkedObstacle", "ParkedObstacle, Accident, ConstructionObstacle (+TwoWays)",
               "a static obstacle blocks the ego lane; bypass through the neighbour or oncoming lane", (
                   _distance(25, 70),
                   Param("variant", "choice", choices=("parked_car", "accident", "construction")),
                   Param("bypass", "choice", choices=("neighbour", "oncoming"),
                         doc="the free lane to pass through"),
                   Param("lane", "id", doc="SUMO lane id the obstacle stands on")),
               _mid_block_sites("ParkedObstacle", _obstacle_fixed), (35, 55), _draw_obstacle,
               timeout=True, two_ways=("bypass", "oncoming")),
    HazardType("HardBreakRoute", "HardBreakRoute",
               "a vehicle ahead in the ego lane brakes hard at the site", (
                   _distance(25, 70), Param("gap", "float", 10, 40, doc="leader's lead at trigger [m]"),
                   Param("decel", "float", 3, 9, doc="leader's braking [m/s^2]")),
               _hard_break_sites, (35, 55), _draw_leader),
    HazardType("ParkingCutIn", "ParkingCutIn, StaticCutIn",
               "a vehicle cuts in front of the ego from a parking spot or the neighbour lane", (
                   _distance(12, 35),
                   Param("source", "choice", choices=("parking", "lane")),
                   Param("direction", "choice", choices=("right", "left"), doc="side it comes from")),
               _mid_block_sites("ParkingCutIn", _cut_in_fixed), (15, 28), _draw_cut_in),
    _junction("SignalizedJunction", "SignalizedJunctionRightTurn, OppositeVehicleRunningRedLight",
              "a junction with traffic lights and cross traffic",
              lambda net, p: p.kind == "traffic_light" and p.direction in ("s", "r"), timeout=True),
    _junction("StopSignJunction", "NonSignalizedJunctionRightTurn, PriorityAtJunction",
              "a stop-sign junction with cross traffic: stop, then go when clear",
              lambda net, p: p.state in ("s", "w"), timeout=False),
    _junction("UnprotectedLeftTurn", "SignalizedJunctionLeftTurn, NonSignalizedJunctionLeftTurn",
              "a left turn that must yield to oncoming traffic",
              lambda net, p: p.direction == "l" and _oncoming(net, p.junction, p.from_edge), timeout=True),
)}


def two_ways(kind: str, params: dict[str, str]) -> bool:
    """Whether a hazard is a TwoWays scenario (the ego passes it in the oncoming lane)."""
    tw = HAZARDS[kind].two_ways
    return tw is not None and params.get(tw[0]) == tw[1]


def check_params(kind: str, params: dict[str, str]) -> str | None:
    """None if the hazard type and its parameters are valid, else the reason."""
    if kind not in HAZARDS:
        return f"unknown hazard type {kind!r} (known: {', '.join(HAZARDS)})"
    spec = HAZARDS[kind]
    names = {p.name for p in spec.params}
    for p in spec.params:
        if p.name not in params:
            return f"{kind}: missing parameter {p.name!r}"
        reason = p.check(params[p.name])
        if reason:
            return f"{kind}: {reason}"
    extra = sorted(set(params) - names)
    return f"{kind}: unknown parameter {extra[0]!r}" if extra else None


def find_sites(net: sumolib.net.Net, path: RoutePath) -> list[Site]:
    """Every place on a traced route where a hazard of some type fits (each type's sites in
    route order)."""
    return [site for h in HAZARDS.values() for site in h.sites(net, path)]
