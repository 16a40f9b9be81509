"""Seeded builders of the four towns (docs/design.md §2.1), loosely after CARLA's Town01/02/07/12.

Each builder takes a ``numpy.random.Generator`` that jitters junction positions and road
bends, and returns a :class:`~sumo_nets.plain.PlainNet`. Layout is by hand (which roads
exist, their class, which junctions have lights or stop signs); the seed only moves
things by a few metres, so every seed gives the same kind of town.

- town01: small town, one lane each way, lights at 8 chosen junctions (4-way and T), the rest priority.
- town02: residential, narrow 30 km/h streets, all-way and two-way stop junctions.
- town07: rural, long curved roads (arcs, S-bends), a small village, stop signs only.
- town12: 2.3 km x 2.2 km: a skewed multi-lane downtown grid with lights, a residential
  stop-sign district, curved rural outskirts, an arterial on the east and south.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

from sumo_nets.plain import ARTERIAL, DOWNTOWN, RESIDENTIAL, RURAL, TOWN, PlainNet, RoadClass


def _grid(net: PlainNet, prefix: str, xs: Iterable[float], ys: Iterable[float],
          rng: np.random.Generator, jitter: float,
          shear: float = 0.0) -> dict[tuple[int, int], str]:
    """Nodes on a grid, named ``{prefix}{i}{j}``, each moved by up to ``jitter`` metres.

    ``shear`` tilts the columns: x += shear * (y - ys[0]), giving skewed junctions.
    """
    ids = {}
    ys = list(ys)
    for i, x in enumerate(xs):
        for j, y in enumerate(ys):
            dx, dy = rng.uniform(-jitter, jitter, size=2)
            ids[i, j] = net.node(f"{prefix}{i}{j}", x + shear * (y - ys[0]) + dx, y + dy)
    return ids


def _grid_roads(net: PlainNet, ids: dict[tuple[int, int], str], cls: Callable[[int, int, int, int], RoadClass],
                skip: set[tuple[tuple[int, int], tuple[int, int]]], rng: np.random.Generator,
                bend_share: float = 0.0, bend: tuple[float, float] = (0.0, 0.0)) -> None:
    """Connect grid neighbours, leaving out the pairs in ``skip``.

    A share ``bend_share`` of the roads get an arc with sagitta drawn from ``bend`` [m],
    on a random side.
    """
    for (i, j) in sorted(ids):
        for (k, l) in ((i + 1, j), (i, j + 1)):
            if (k, l) not in ids or ((i, j), (k, l)) in skip:
                continue
            sag = 0.0
            if rng.uniform() < bend_share:
                sag = rng.uniform(*bend) * rng.choice((-1.0, 1.0))
            net.road(ids[i, j], ids[k, l], cls(i, j, k, l), bend=sag)


def _types_by_degree(net: PlainNet, nodes: Iterable[str], four: str, three: str) -> None:
    """Give 4-way junctions type ``four`` and T junctions type ``three``."""
    for nid in nodes:
        d = net.degree(nid)
        if d >= 4:
            net.set_kind(nid, four)
        elif d == 3:
            net.set_kind(nid, three)


def town01(rng: np.random.Generator) -> PlainNet:
    """Small town, ~540 m x 380 m: one lane each way, lights at 8 chosen junctions (4-way and T)."""
    net = PlainNet("town01")
    xs, ys = (0, 130, 270, 400, 540), (0, 120, 250, 380)
    g = _grid(net, "n", xs, ys, rng, jitter=4.0)
    skip = {((1, 0), (2, 0)), ((3, 1), (3, 2)), ((1, 2), (2, 2)), ((2, 1), (3, 1))}
    side = {1, 3}  # quieter 30 km/h side streets on these columns
    _grid_roads(net, g, lambda i, j, k, l: RESIDENTIAL if (i == k and i in side) else TOWN,
                skip, rng, bend_share=0.2, bend=(4.0, 9.0))
    _types_by_degree(net, [g[1, 1], g[2, 1], g[3, 2], g[1, 2], g[2, 2], g[1, 3], g[3, 0], g[0, 1]],
                     "traffic_light", "traffic_light")
    return net


def town02(rng: np.random.Generator) -> PlainNet:
    """Residential, ~330 m x 290 m: narrow 30 km/h streets, stop junctions."""
    net = PlainNet("town02")
    xs, ys = (0, 110, 220, 330), (0, 100, 200, 290)
    g = _grid(net, "n", xs, ys, rng, jitter=5.0)
    skip = {((1, 2), (2, 2)), ((2, 0), (2, 1))}
    # row j == 1 is the through road (higher priority), so its junctions are two-way stops
    _grid_roads(net, g, lambda i, j, k, l: TOWN if (j == l == 1) else RESIDENTIAL,
                skip, rng, bend_share=0.3, bend=(4.0, 8.0))
    for (i, j), nid in g.items():
        d = net.degree(nid)
        if d >= 3:
            net.set_kind(nid, "priority_stop" if j == 1 else "allway_stop")
    return net


def town07(rng: np.random.Generator) -> PlainNet:
    """Rural, ~1.5 km x 1.0 km: a curved loop with S-bends around a small village."""
    net = PlainNet("town07")
    j = lambda s: rng.uniform(-s, s)  # noqa: E731 - small jitter helper
    ring = [(0, 0), (500, -40), (1000, 60), (1350, 400), (1200, 900), (650, 1000),
            (150, 850), (-150, 400)]
    r = [net.node(f"r{i}", x + j(10), y + j(10)) for i, (x, y) in enumerate(ring)]
    shapes = [(35, 0), (0, 18), (-40, 0), (0, 22), (30, 0), (0, 15), (-45, 0), (0, 20)]
    for i in range(len(r)):
        bend, wiggle = shapes[i]
        net.road(r[i], r[(i + 1) % len(r)], RURAL, bend=bend + j(5), wiggle=wiggle + j(3))
    v = _grid(net, "v", (520, 640, 760), (380, 500), rng, jitter=3.0)
    _grid_roads(net, v, lambda *_: RESIDENTIAL, set(), rng)
    net.road(r[1], v[1, 0], RURAL, bend=25 + j(5))
    net.road(r[7], v[0, 0], RURAL, wiggle=25 + j(4))
    net.road(r[5], v[1, 1], RURAL, bend=-30 + j(5))
    net.road(r[3], v[2, 1], RURAL, wiggle=-20 + j(4))
    net.road(r[6], v[0, 1], RURAL, bend=-40 + j(8), wiggle=12)  # a winding road into the village
    for nid in list(r) + list(v.values()):
        if net.degree(nid) >= 3:
            net.set_kind(nid, "allway_stop" if nid.startswith("v") and net.degree(nid) >= 4
                         else "priority_stop")
    return net


def town12(rng: np.random.Generator) -> PlainNet:
    """Large map, ~2.3 km x 2.2 km, four districts joined by arterials and rural roads."""
    net = PlainNet("town12")
    j = lambda s: rng.uniform(-s, s)  # noqa: E731 - small jitter helper

    # Downtown: 6 x 6 multi-lane grid, columns sheared (skewed junctions), lights at every
    # junction of 3 or more roads at this point (corners d00, d50, d55, linked below, stay priority).
    d = _grid(net, "d", (900, 1020, 1160, 1270, 1400, 1520), (900, 1020, 1150, 1270, 1390, 1510),
              rng, jitter=6.0, shear=0.1)
    _grid_roads(net, d, lambda *_: DOWNTOWN, {((2, 2), (3, 2)), ((2, 3), (3, 3)), ((4, 4), (4, 5))},
                rng)
    for nid in d.values():
        if net.degree(nid) >= 3:
            net.set_kind(nid, "traffic_light")

    # Residential district (west): 30 km/h, stop signs at its junctions of 3 or more roads at
    # this point (corners linked later stay priority), some curved streets, a collector row.
    h = _grid(net, "h", (220, 350, 480, 610, 740), (920, 1040, 1170, 1300, 1430), rng, jitter=8.0)
    _grid_roads(net, h, lambda i, jj, k, l: TOWN if jj == l == 2 else RESIDENTIAL,
                {((1, 0), (2, 0)), ((3, 3), (3, 4)), ((0, 1), (1, 1))}, rng,
                bend_share=0.35, bend=(6.0, 14.0))
    for (i, jj), nid in h.items():
        if net.degree(nid) >= 3:
            net.set_kind(nid, "priority_stop" if jj == 2 or net.degree(nid) == 3 else "allway_stop")
    for hy, dy in ((0, 0), (2, 2), (4, 4)):  # residential -> downtown links
        net.road(h[4, hy], d[0, dy], TOWN, bend=j(6))

    # Arterial: a curved north-south road in the east and an east-west road in the south.
    a = [net.node(f"a{i}", x + j(10), y + j(10)) for i, (x, y) in
         enumerate([(1800, 350), (1780, 900), (1850, 1270), (1790, 1700), (1700, 2150)])]
    s = [net.node(f"s{i}", x + j(10), y + j(10)) for i, (x, y) in
         enumerate([(250, 450), (800, 420), (1300, 380)])]
    for p, q, bend in ((a[0], a[1], 25), (a[1], a[2], -20), (a[2], a[3], 30), (a[3], a[4], -25),
                       (s[0], s[1], 20), (s[1], s[2], -25), (s[2], a[0], 20)):
        net.road(p, q, ARTERIAL, bend=bend + j(5))
    net.road(d[5, 0], a[1], DOWNTOWN, bend=j(5))
    net.road(d[5, 3], a[2], DOWNTOWN, bend=j(5))
    net.road(d[5, 5], a[3], DOWNTOWN, bend=20 + j(5))
    net.road(s[1], d[0, 0], TOWN, bend=30 + j(5))
    net.road(s[2], d[3, 0], TOWN, bend=-25 + j(5))
    for nid in a[:4] + s[1:]:
        net.set_kind(nid, "traffic_light")

    # Rural outskirts: long curved 60 km/h roads, stop signs where they meet.
    n = [net.node(f"n{i}", x + j(15), y + j(15)) for i, (x, y) in
         enumerate([(200, 1900), (700, 2200), (1250, 2050), (2250, 600), (2300, 1300),
                    (2200, 1950), (600, 60), (1500, 40), (50, 1200)])]
    rural = [(h[0, 4], n[0], 0, 30), (n[0], n[1], 40, 0), (h[3, 4], n[1], 0, -25),
             (d[2, 5], n[2], -35, 12), (n[1], n[2], 0, 30), (n[2], a[4], 45, 0),
             (a[0], n[3], 0, 28), (n[3], n[4], 60, 0), (n[4], a[2], -30, 15), (n[4], n[5], 0, -35),
             (n[5], a[4], 40, 0), (s[0], n[6], -30, 20), (n[6], n[7], 0, 40), (n[7], s[2], 35, 0),
             (n[7], a[0], 0, -22), (s[0], n[8], 50, 25), (n[8], h[0, 2], 0, 20), (n[8], n[0], 60, 0),
             (n[6], s[1], 0, 18)]
    for p, q, bend, wiggle in rural:
        net.road(p, q, RURAL, bend=bend + j(5), wiggle=wiggle + j(3))
    for nid in n + [a[4], s[0]]:
        if net.degree(nid) >= 3:
            net.set_kind(nid, "allway_stop" if net.degree(nid) >= 4 else "priority_stop")
    return net


TOWNS: dict[str, Callable[[np.random.Generator], PlainNet]] = {
    "town01": town01, "town02": town02, "town07": town07, "town12": town12,
}
DEFAULT_SEEDS = {"town01": 1, "town02": 2, "town07": 7, "town12": 12}
