"""The geometry of a route: from a SUMO edge list to a dense centre line along the lanes.

A route is a list of consecutive SUMO edges plus a start position on the first edge
(``depart_pos``) and an end position on the last (``arrival_pos``), both metres along
the lane. :func:`trace` picks the lanes the route drives (no lane change unless the next
turn needs one), follows the junction-internal lanes between edges, blends a needed
lane change over the middle of an edge, and resamples the result every metre. Its
length is the route length "measured along the SUMO lanes" (docs/design.md §2.2).

Frames and units: SUMO world frame (x east, y north), metres; ``s`` is the arc length
along the route from its start [m]; yaw is the heading [rad] from +x, counter-clockwise.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import sumolib

SPACING = 1.0  # dense route spacing [m], as the Leaderboard's 1 m route
LANE_CHANGE = 40.0  # longest stretch [m] over which a needed lane change is blended


class RouteError(ValueError):
    """A route that cannot be traced on its net (unknown or unconnected edges, bad positions)."""


@dataclass(frozen=True)
class Leg:
    """One edge of the route: the lanes it enters and leaves on, its span in route s [m]."""

    edge: str
    lane_in: str
    lane_out: str
    s0: float
    s1: float


@dataclass(frozen=True)
class Passage:
    """One junction the route drives through, between route s ``s_in`` and ``s_out`` [m]."""

    junction: str
    kind: str  # SUMO junction type: traffic_light, priority_stop, allway_stop, priority, ...
    direction: str  # SUMO link direction: s (straight), r, l, R, L, t
    state: str  # SUMO link state: M/m (major/minor), s (stop), w (all-way stop), o (signal)
    tls: str  # id of the traffic light program, "" if none
    link: int  # index of the route's link in that program's state string, -1 if none
    from_edge: str
    to_edge: str
    s_in: float
    s_out: float


@dataclass(frozen=True)
class RoutePath:
    """A traced route: dense points every ``SPACING`` metres and what lies along them."""

    xy: np.ndarray  # (N, 2) world frame [m]
    s: np.ndarray  # (N,) arc length from the route start [m]
    legs: tuple[Leg, ...]
    passages: tuple[Passage, ...]

    @property
    def length(self) -> float:
        """Route length along the lanes [m]."""
        return float(self.s[-1])

    def pose(self, s: float) -> tuple[float, float, float]:
        """World (x, y, yaw) of the route at arc length s [m], clipped to the route."""
        s = min(max(s, 0.0), self.length)
        x = float(np.interp(s, self.s, self.xy[:, 0]))
        y = float(np.interp(s, self.s, self.xy[:, 1]))
        i = min(int(np.searchsorted(self.s, s, side="right")), len(self.s) - 1)
        i = max(i, 1)
        dx, dy = self.xy[i] - self.xy[i - 1]
        return x, y, math.atan2(dy, dx)

    def project(self, x: float, y: float, s_lo: float = 0.0,
                s_hi: float = math.inf) -> tuple[float, float]:
        """Nearest route point to world (x, y) within [s_lo, s_hi]: (s [m], distance [m])."""
        sel = (self.s >= s_lo) & (self.s <= s_hi)
        idx = np.flatnonzero(sel)
        if len(idx) == 0:
            return math.nan, math.inf
        d = np.hypot(self.xy[idx, 0] - x, self.xy[idx, 1] - y)
        k = int(np.argmin(d))
        return float(self.s[idx[k]]), float(d[k])

    def heading_change(self, s0: float, s1: float) -> float:
        """Total absolute heading change [rad] of the route between s0 and s1."""
        sel = (self.s >= s0) & (self.s <= s1)
        seg = np.diff(self.xy[sel], axis=0)
        if len(seg) < 2:
            return 0.0
        h = np.arctan2(seg[:, 1], seg[:, 0])
        return float(np.abs((np.diff(h) + math.pi) % (2 * math.pi) - math.pi).sum())


def _arclen(pts: np.ndarray) -> np.ndarray:
    return np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))))


def _at(pts: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Points at arc lengths s along polyline pts."""
    cum = _arclen(pts)
    return np.stack([np.interp(s, cum, pts[:, 0]), np.interp(s, cum, pts[:, 1])], axis=1)


def _cut(pts: np.ndarray, s0: float, s1: float) -> np.ndarray:
    """The part of polyline pts between arc lengths s0 and s1, ends included."""
    cum = _arclen(pts)
    inner = pts[(cum > s0) & (cum < s1)]
    return np.vstack([_at(pts, np.array([s0])), inner, _at(pts, np.array([s1]))])


def _shape(lane: sumolib.net.lane.Lane) -> np.ndarray:
    return np.asarray(lane.getShape(), dtype=float)[:, :2]


def _blend(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Centre line that starts on lane a and ends on lane b (same edge), smoothly.

    Both lanes are sampled at the same fractions of their length; the weight of b rises
    with a smoothstep over at most ``LANE_CHANGE`` metres around the middle.
    """
    la, lb = _arclen(a)[-1], _arclen(b)[-1]
    n = max(2, int(math.ceil(min(la, lb) / SPACING)) + 1)
    f = np.linspace(0.0, 1.0, n)
    pa, pb = _at(a, f * la), _at(b, f * lb)
    half = min(LANE_CHANGE, 0.8 * la) / (2 * la)
    u = np.clip((f - (0.5 - half)) / (2 * half), 0.0, 1.0)
    w = (u * u * (3 - 2 * u))[:, None]
    return (1 - w) * pa + w * pb


def _driving(lane: sumolib.net.lane.Lane) -> bool:
    return lane.allows("passenger")


def _choose(conns: list, entry: int | None) -> sumolib.net.connection.Connection:
    """The connection to use: stay in the entry lane if it can; else rightmost for right
    turns and straight on, leftmost for left turns."""
    if entry is not None:
        for c in conns:
            if c.getFromLane().getIndex() == entry:
                return c
    left = conns[0].getDirection() in ("l", "L", "t")
    key = lambda c: c.getFromLane().getIndex()  # noqa: E731
    return max(conns, key=key) if left else min(conns, key=key)


def _via_chain(net: sumolib.net.Net, conn) -> list[sumolib.net.lane.Lane]:
    """Junction-internal lanes of a connection, in driving order."""
    lanes, via = [], conn.getViaLaneID()
    while via:
        lane = net.getLane(via)
        lanes.append(lane)
        nxt = [o for o in lane.getOutgoing() if o.getToLane().getEdge().getID() == conn.getTo().getID()
               or o.getViaLaneID()]
        via = nxt[0].getViaLaneID() if nxt else ""
    return lanes


def trace(net: sumolib.net.Net, edges: list[str], depart_pos: float,
          arrival_pos: float) -> RoutePath:
    """Trace a route on a net loaded with ``withInternal=True``.

    depart_pos, arrival_pos: metres along the lane shapes of the first and last edge;
    ``arrival_pos=math.inf`` means the end of the last edge.
    Raises RouteError naming the first problem (unknown edge, edges not connected for
    cars, positions outside the lane).
    """
    objs = _edges(net, edges)
    conns = _connections(objs)
    lanes_in, lanes_out = _end_lanes(objs, conns)
    pieces, legs, passages = [], [], []
    s = 0.0
    for i, e in enumerate(objs):
        a, b = _shape(lanes_in[i]), _shape(lanes_out[i])
        pts = a if lanes_in[i] is lanes_out[i] else _blend(a, b)
        total = _arclen(pts)[-1]
        lo = depart_pos if i == 0 else 0.0
        hi = min(arrival_pos, total) if i == len(objs) - 1 else total
        if i == 0 and not 0.0 <= lo < total:
            raise RouteError(f"depart_pos {depart_pos:.2f} is outside edge {e.getID()} ({total:.1f} m)")
        if i == len(objs) - 1 and not lo < hi <= total + 1e-6:
            raise RouteError(f"arrival_pos {arrival_pos:.2f} is outside edge {e.getID()} ({total:.1f} m)")
        part = _cut(pts, lo, min(hi, total))
        length = _arclen(part)[-1]
        legs.append(Leg(e.getID(), lanes_in[i].getID(), lanes_out[i].getID(), s, s + length))
        pieces.append(part)
        s += length
        if i < len(conns):
            c = conns[i]
            inner = [_shape(ln) for ln in _via_chain(net, c)]
            s_in = s
            for p in inner:
                pieces.append(p)
                s += _arclen(p)[-1]
            node = c.getJunction() or e.getToNode()
            passages.append(Passage(node.getID(), node.getType(), c.getDirection(), c.getState(),
                                    c.getTLSID() or "", c.getTLLinkIndex() if c.getTLSID() else -1,
                                    e.getID(), objs[i + 1].getID(), s_in, s))
    return _resample(pieces, legs, passages, s)


def _edges(net: sumolib.net.Net, edges: list[str]) -> list[sumolib.net.edge.Edge]:
    """The net's edges of a route, each checked to be a road (not internal, not a crossing)."""
    if not edges:
        raise RouteError("the route has no edges")
    objs = []
    for e in edges:
        if not net.hasEdge(e) or net.getEdge(e).getFunction():
            raise RouteError(f"edge {e!r} is not a road of this town")
        objs.append(net.getEdge(e))
    return objs


def _connections(objs: list) -> list[sumolib.net.connection.Connection]:
    """The car connection used between each pair of consecutive edges, staying in the
    lane the last one entered on where it can (``_choose``)."""
    conns = []
    entry = None
    for a, b in zip(objs, objs[1:]):
        cs = [c for c in a.getConnections(b) if _driving(c.getFromLane()) and _driving(c.getToLane())]
        if not cs:
            raise RouteError(f"edges {a.getID()} and {b.getID()} are not connected")
        c = _choose(cs, entry)
        conns.append(c)
        entry = c.getToLane().getIndex()
    return conns


def _end_lanes(objs: list, conns: list) -> tuple[list, list]:
    """The lane of each edge at its start and at its end (those of the connections)."""
    lanes_in, lanes_out = [], []
    for i, e in enumerate(objs):
        out = conns[i].getFromLane() if i < len(conns) else None
        inn = conns[i - 1].getToLane() if i > 0 else out
        if inn is None:  # one-edge route
            inn = next((ln for ln in e.getLanes() if _driving(ln)), None)
            if inn is None:
                raise RouteError(f"edge {e.getID()} has no lane for cars")
        lanes_in.append(inn)
        lanes_out.append(out if out is not None else inn)
    return lanes_in, lanes_out


def _resample(pieces: list[np.ndarray], legs: list[Leg], passages: list[Passage], s: float) -> RoutePath:
    """The route from its polyline pieces (lanes and junction lanes, in order) resampled
    every SPACING m; legs and passages carry route s measured on the pieces, s is their
    total length [m]."""
    raw = np.vstack(pieces)
    keep = np.concatenate(([True], np.hypot(*np.diff(raw, axis=0).T) > 1e-9))
    raw = raw[keep]
    cum = _arclen(raw)
    n = max(2, int(math.ceil(cum[-1] / SPACING)) + 1)
    dense_s = np.linspace(0.0, cum[-1], n)
    # the junction gaps between lane ends are tiny; scale the s of legs and passages
    # to the resampled polyline so that everything shares one arc length
    scale = cum[-1] / s if s > 0 else 1.0
    legs = [Leg(g.edge, g.lane_in, g.lane_out, float(g.s0 * scale), float(g.s1 * scale)) for g in legs]
    passages = [Passage(**{**p.__dict__, "s_in": float(p.s_in * scale), "s_out": float(p.s_out * scale)})
                for p in passages]
    return RoutePath(_at(raw, dense_s), dense_s, tuple(legs), tuple(passages))
