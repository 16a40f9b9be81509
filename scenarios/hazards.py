"""Hazard types of the route sets (SPEC §2.3) and where a route offers room for them.

Every hazard in a route file is a Leaderboard-2.0-style ``<scenario name type>`` with a
``trigger_point`` and parameters as child elements ``<param value="..."/>``. The
``distance`` parameter, common to all types, is the distance [m] along the route from the
trigger point to the hazard's site (the crosswalk, the obstacle, the junction entry...):
the harness starts the hazard when the ego's route progress reaches the trigger point.

``type`` is one of the eight names below; each stands for the CARLA Leaderboard 2.0
scenario class(es) in ``carla`` (variants are parameters here, separate classes there).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

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
class HazardType:
    name: str
    carla: str  # the CARLA Leaderboard 2.0 scenario class(es) it stands for
    doc: str
    params: tuple[Param, ...]


def _distance(lo: float, hi: float) -> Param:
    return Param("distance", "float", lo, hi, doc="route distance from trigger point to site [m]")


FLOW = Param("flow", "int", 4, 30, doc="cross or oncoming vehicles per minute while active")
JUNCTION = Param("junction", "id", doc="SUMO junction id on the route")

HAZARDS: dict[str, HazardType] = {h.name: h for h in (
    HazardType("PedestrianCrossing", "PedestrianCrossing",
               "walkers cross a crosswalk on the route as the ego approaches", (
                   _distance(15, 35), Param("crossing", "id", doc="SUMO crossing edge id"),
                   Param("walkers", "int", 1, 4, doc="number of walkers"),
                   Param("direction", "choice", choices=("right", "left"), doc="side they start from"),
                   Param("speed", "float", 0.5, 2.0, doc="walking speed [m/s]"))),
    HazardType("DynamicObjectCrossing", "DynamicObjectCrossing",
               "a jaywalker steps out mid-block, possibly from behind a parked car", (
                   _distance(10, 30),
                   Param("direction", "choice", choices=("right", "left"), doc="side it comes from"),
                   Param("blocker", "choice", choices=("parked_car", "none"), doc="what hides it"),
                   Param("speed", "float", 0.8, 3.0, doc="walking speed [m/s]"))),
    HazardType("ParkedObstacle", "ParkedObstacle, Accident, ConstructionObstacle (+TwoWays)",
               "a static obstacle blocks the ego lane; bypass through the neighbour or oncoming lane", (
                   _distance(25, 70),
                   Param("variant", "choice", choices=("parked_car", "accident", "construction")),
                   Param("bypass", "choice", choices=("neighbour", "oncoming"),
                         doc="the free lane to pass through"),
                   Param("lane", "id", doc="SUMO lane id the obstacle stands on"))),
    HazardType("HardBreakRoute", "HardBreakRoute",
               "a vehicle ahead in the ego lane brakes hard at the site", (
                   _distance(25, 70), Param("gap", "float", 10, 40, doc="leader's lead at trigger [m]"),
                   Param("decel", "float", 3, 9, doc="leader's braking [m/s^2]"))),
    HazardType("ParkingCutIn", "ParkingCutIn, StaticCutIn",
               "a vehicle cuts in front of the ego from a parking spot or the neighbour lane", (
                   _distance(12, 35),
                   Param("source", "choice", choices=("parking", "lane")),
                   Param("direction", "choice", choices=("right", "left"), doc="side it comes from"))),
    HazardType("SignalizedJunction", "SignalizedJunctionRightTurn, OppositeVehicleRunningRedLight",
               "a junction with traffic lights and cross traffic", (_distance(25, 70), JUNCTION, FLOW)),
    HazardType("StopSignJunction", "NonSignalizedJunctionRightTurn, PriorityAtJunction",
               "a stop-sign junction with cross traffic: stop, then go when clear",
               (_distance(25, 70), JUNCTION, FLOW)),
    HazardType("UnprotectedLeftTurn", "SignalizedJunctionLeftTurn, NonSignalizedJunctionLeftTurn",
               "a left turn that must yield to oncoming traffic", (_distance(25, 70), JUNCTION, FLOW)),
)}


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


@dataclass(frozen=True)
class Site:
    """Room for a hazard on a route: its site may lie anywhere in [s_lo, s_hi] (route s, m)."""

    kind: str
    s_lo: float
    s_hi: float
    fixed: tuple[tuple[str, str], ...] = ()  # parameters the site decides (junction id, lane...)


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


def find_sites(net: sumolib.net.Net, path: RoutePath) -> list[Site]:
    """Every place on a traced route where a hazard of some type fits."""
    sites: list[Site] = []
    for p in path.passages:
        if p.kind == "traffic_light" and p.direction in ("s", "r"):
            sites.append(Site("SignalizedJunction", p.s_in, p.s_in, (("junction", p.junction),)))
        if p.state in ("s", "w"):
            sites.append(Site("StopSignJunction", p.s_in, p.s_in, (("junction", p.junction),)))
        if p.direction == "l" and _oncoming(net, p.junction, p.from_edge):
            sites.append(Site("UnprotectedLeftTurn", p.s_in, p.s_in, (("junction", p.junction),)))
        for cid in _crossings(net, p.junction):
            crossing = net.getEdge(cid)
            crossed = {c.getID() for c in crossing.getCrossingEdges()}
            if p.to_edge in crossed or p.from_edge in crossed:
                shape = crossing.getLanes()[0].getShape()
                cx = (shape[0][0] + shape[-1][0]) / 2
                cy = (shape[0][1] + shape[-1][1]) / 2
                s, d = path.project(cx, cy, p.s_in - 15, p.s_out + 15)
                if d < 6.0:
                    sites.append(Site("PedestrianCrossing", s, s, (("crossing", cid),)))
    for leg in path.legs:
        lo, hi = leg.s0 + (JUNCTION_CLEAR if leg.s0 > 0 else 0.0), leg.s1 - JUNCTION_CLEAR
        hi = min(hi, path.length - END_CLEAR)
        if hi <= lo or leg.lane_in != leg.lane_out:
            continue
        edge = net.getEdge(leg.edge)
        driving = [ln.getIndex() for ln in edge.getLanes() if ln.allows("passenger")]
        idx = int(leg.lane_in.rsplit("_", 1)[1])
        rightmost, has_left = idx == min(driving), idx + 1 in driving
        reverse = f"{edge.getToNode().getID()}_{edge.getFromNode().getID()}"
        sites.append(Site("DynamicObjectCrossing", lo, hi))
        if has_left or net.hasEdge(reverse):
            sites.append(Site("ParkedObstacle", lo, hi, (("bypass", "neighbour" if has_left else "oncoming"),
                                                         ("lane", leg.lane_in))))
        if rightmost or has_left:
            sites.append(Site("ParkingCutIn", lo, hi, (("source", "parking" if rightmost else "lane"),)))
    if path.length > 2 * END_CLEAR + 20:
        sites.append(Site("HardBreakRoute", 40.0, path.length - END_CLEAR))
    return sites


def _crossings(net: sumolib.net.Net, junction: str) -> list[str]:
    """Crossing edge ids of a junction (SUMO names them ``:<junction>_c<k>``)."""
    prefix = f":{junction}_c"
    lanes = net.getNode(junction).getInternal()  # the junction's intLanes, crossings included
    return sorted({ln.rsplit("_", 1)[0] for ln in lanes if ln.startswith(prefix)})
