"""Route-set builders (docs/design.md §2.2): seeded random walks on a town, hazards placed where
the route has room for them, hazard types balanced across the set.

A set is built town by town. For each town the builder draws candidate routes (a
random walk over the net from a random start position, cut so that its length along
the lanes hits a target drawn from the set's target range), finds every hazard site on
each (scenarios.hazards.find_sites), then fills the set's routes one by one: each gets
the hazard type the set has least of so far among those some remaining candidate can
host (counts divided by the set's type weights; or the set's required type), and with
probability ``second`` a second hazard of another type at least ``SEPARATION`` metres
away. Everything is drawn from one ``numpy.random.Generator`` seeded by the set's seed,
so a rebuild is byte-identical.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import sumolib

from sumo_nets import load_net
from scenarios.geometry import RouteError, RoutePath, trace
from scenarios.hazards import HAZARDS, Site, find_sites
from scenarios.routefile import Hazard, Route, read_routes

SETS_DIR = Path(__file__).resolve().parent
SEPARATION = 60.0  # minimum distance [m] between two hazard sites of one route
TRIGGER_MIN = 5.0  # a trigger lies at least this far [m] after the route start
STRAIGHT_DEG = 35.0  # a mid-block site turns less than this over +-20 m [deg]
CANDIDATES_PER_ROUTE = 20  # random walks drawn per route wanted


@dataclass(frozen=True)
class SetSpec:
    """How one route set is built."""

    towns: tuple[tuple[str, int], ...]  # (town, number of routes)
    length: tuple[float, float]  # accepted length along the lanes [m] (routes check)
    target: tuple[float, float]  # range the builder draws route lengths from [m]
    seed: int
    second: float = 0.5  # probability of a second hazard on a route
    required: tuple[str, ...] = ()  # hazard type of route k, for the first routes
    exclude: tuple[str, ...] = ()  # sets whose (start edge, end edge) pairs are not reused
    weights: tuple[tuple[str, float], ...] = ()  # hazard types balanced to these shares (default 1)

    def weight(self, kind: str) -> float:
        return dict(self.weights).get(kind, 1.0)


SETS: dict[str, SetSpec] = {
    # the evaluation set: 100 routes, 300 m +- 10 %, every route with a hazard
    "town12_short": SetSpec((("town12", 100),), (270.0, 330.0), (285.0, 315.0), seed=1200),
    # CI's smoke set: a light, a stop sign, a pedestrian and an obstacle bypass
    "town12_smoke": SetSpec((("town12", 4),), (120.0, 220.0), (140.0, 180.0), seed=1201, second=0.0,
                            required=("SignalizedJunction", "StopSignJunction", "PedestrianCrossing",
                                      "ParkedObstacle")),
    # expert data for training, never sharing start and end edge with an evaluation route.
    # ParkedObstacle weighs 3: it stands for three Leaderboard scenarios (Accident,
    # ConstructionObstacle, ParkedObstacle), and the obstacle bypass is the rarest
    # situation in the data (weighted, it reaches >= 2 % of the frames; 1.2 % unweighted)
    "train": SetSpec((("town01", 40), ("town02", 40), ("town07", 40), ("town12", 80)),
                     (270.0, 330.0), (285.0, 315.0), seed=1202, exclude=("town12_short",),
                     weights=(("ParkedObstacle", 3.0),)),
    # model selection, town12, disjoint from evaluation and training
    "val": SetSpec((("town12", 30),), (270.0, 330.0), (285.0, 315.0), seed=1203,
                   exclude=("town12_short", "train")),
    # a second evaluation set, town12_short's recipe with another seed: never used for a choice
    "town12_second": SetSpec((("town12", 100),), (270.0, 330.0), (285.0, 315.0), seed=1204,
                             exclude=("town12_short", "train", "val")),
}

def set_path(name: str) -> Path:
    """Where route set ``name`` lives (``scenarios/<name>.xml``)."""
    return SETS_DIR / f"{name}.xml"


def _drivable(edge: sumolib.net.edge.Edge) -> bool:
    return not edge.getFunction() and any(ln.allows("passenger") for ln in edge.getLanes())


def _lane_length(edge: sumolib.net.edge.Edge) -> float:
    return next(ln.getLength() for ln in edge.getLanes() if ln.allows("passenger"))


@dataclass(frozen=True)
class Walk:
    """A candidate route: its edges, start and end positions on the lanes [m], its path."""

    edges: tuple[str, ...]
    depart: float
    arrival: float
    path: RoutePath


def random_walk(net: sumolib.net.Net, rng: np.random.Generator, starts: list[str],
                target: float) -> Walk | None:
    """A route of length ``target`` [m] (to 1 cm) from a random start, or None if the walk
    got stuck. Never takes an edge twice and never turns back onto the reverse edge.
    """
    edge = net.getEdge(starts[int(rng.integers(len(starts)))])
    depart = round(float(rng.uniform(0.0, max(0.0, _lane_length(edge) - 10.0))), 2)
    edges, approx = [edge.getID()], _lane_length(edge) - depart
    while approx < target + 40.0:
        back = f"{edge.getToNode().getID()}_{edge.getFromNode().getID()}"
        outs = sorted(o.getID() for o, conns in edge.getOutgoing().items()
                      if _drivable(o) and o.getID() != back and o.getID() not in edges
                      and any(c.getFromLane().allows("passenger") for c in conns))
        if not outs:
            return None
        edge = net.getEdge(outs[int(rng.integers(len(outs)))])
        edges.append(edge.getID())
        approx += _lane_length(edge) + 10.0
    try:
        full = trace(net, edges, depart, math.inf)
    except RouteError:
        return None
    last = full.legs[-1]
    start = depart if len(edges) == 1 else 0.0  # lane position where the last leg begins
    arrival = round(start + (last.s1 - last.s0) - (full.length - target), 2)
    if arrival < start + 1.0:
        return None
    return Walk(tuple(edges), depart, arrival, trace(net, edges, depart, arrival))


def _waypoints(path: RoutePath) -> tuple[tuple[float, float, float], ...]:
    """Leaderboard keypoints: start, the middle of every inner edge, end (z = 0)."""
    ss = [0.0] + [(g.s0 + g.s1) / 2 for g in path.legs[1:-1]] + [path.length]
    return tuple((round(x, 2), round(y, 2), 0.0) for x, y, _ in (path.pose(s) for s in ss))


def _draw(kind: str, site: Site, path: RoutePath, rng: np.random.Generator) -> tuple[float, dict] | None:
    """Site position [m] and parameters of one hazard of type ``kind`` at ``site``, or None."""
    lo_d, hi_d = HAZARDS[kind].distance
    d = float(rng.uniform(lo_d, hi_d))
    lo = max(site.s_lo, d + TRIGGER_MIN)
    if lo > site.s_hi:
        return None
    s = float(rng.uniform(lo, site.s_hi))
    if site.s_hi > site.s_lo and math.degrees(path.heading_change(s - 20, s + 20)) > STRAIGHT_DEG:
        return None
    p = HAZARDS[kind].draw(rng, dict(site.fixed))
    params = {"distance": f"{d:.1f}", **p}
    ordered = {q.name: params[q.name] for q in HAZARDS[kind].params}
    return s, ordered


def _hazard(kind: str, n: int, s: float, params: dict, path: RoutePath) -> Hazard:
    x, y, yaw = path.pose(s - float(params["distance"]))
    return Hazard(f"{kind}_{n}", kind, (round(x, 2), round(y, 2), 0.0, round(math.degrees(yaw), 2)), params)


def _pairs(names: tuple[str, ...]) -> set[tuple[str, str]]:
    pairs = set()
    for name in names:
        for r in read_routes(set_path(name))[1]:
            pairs.add((r.edges[0], r.edges[-1]))
    return pairs


def make_set(name: str, seed: int | None = None, progress=None) -> list[Route]:
    """Build the routes of set ``name`` (see SETS); ``progress`` is called once per route."""
    spec = SETS[name]
    rng = np.random.default_rng(spec.seed if seed is None else seed)
    banned = _pairs(spec.exclude)
    routes: list[Route] = []
    counts: Counter[str] = Counter()
    for town, n_routes in spec.towns:
        net = load_net(town)
        starts = sorted(e.getID() for e in net.getEdges(withInternal=False) if _drivable(e))
        cands = []
        for _ in range(n_routes * CANDIDATES_PER_ROUTE):
            walk = random_walk(net, rng, starts, float(rng.uniform(*spec.target)))
            if walk is None or (walk.edges[0], walk.edges[-1]) in banned:
                continue
            cands.append((walk, find_sites(net, walk.path)))
        used_pairs: set[tuple[str, str]] = set()
        for k in range(n_routes):
            pool = [c for c in cands if (c[0].edges[0], c[0].edges[-1]) not in used_pairs]
            offered = {s.kind for _, sites in pool for s in sites}
            if not pool or not offered:
                raise RuntimeError(f"{name}: ran out of candidate routes in {town}")
            want = (spec.required[len(routes)] if len(routes) < len(spec.required)
                    else min(sorted(offered), key=lambda t: counts[t] / spec.weight(t)))
            hosts = [c for c in pool if any(s.kind == want for s in c[1])]
            for _ in range(50):
                walk, sites = hosts[int(rng.integers(len(hosts)))]
                path = walk.path
                options = [s for s in sites if s.kind == want]
                first = _draw(want, options[int(rng.integers(len(options)))], path, rng)
                if first is not None:
                    break
            else:
                raise RuntimeError(f"{name}: could not place {want} in {town}")
            chosen = [(want, *first)]
            if rng.uniform() < spec.second:
                others = sorted({s.kind for s in sites} - {want}, key=lambda t: (counts[t] / spec.weight(t), t))
                for kind in others[:2]:
                    site = [s for s in sites if s.kind == kind][0]
                    extra = _draw(kind, site, path, rng)
                    if extra and abs(extra[0] - first[0]) >= SEPARATION:
                        chosen.append((kind, *extra))
                        break
            chosen.sort(key=lambda h: h[1])
            hazards = tuple(_hazard(kind, i + 1, s, p, path) for i, (kind, s, p) in enumerate(chosen))
            counts.update(h.type for h in hazards)
            used_pairs.add((walk.edges[0], walk.edges[-1]))
            routes.append(Route(str(len(routes)), town, _waypoints(path), hazards, walk.edges,
                                walk.depart, walk.arrival, round(path.length, 2)))
            if progress:
                progress()
    return routes
