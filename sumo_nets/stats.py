"""Summary figures of a built net (``sumo-scimm nets show``).

Road length counts each direction of a road once (an edge is one direction), measured
along its first driving lane. An edge is *curved* when its driving lane turns by
>= 15 deg in total along its length (sum of absolute heading changes between shape
segments, so an S-bend counts although its ends are parallel).
"""
from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import numpy as np
import sumolib

CURVED_DEG = 15.0  # total heading change [deg] from which an edge counts as curved


def heading_change(shape: list[tuple[float, float]]) -> float:
    """Total absolute heading change [rad] along a polyline (world frame)."""
    pts = np.asarray(shape, dtype=float)[:, :2]
    seg = np.diff(pts, axis=0)
    seg = seg[np.hypot(seg[:, 0], seg[:, 1]) > 1e-6]
    if len(seg) < 2:
        return 0.0
    h = np.arctan2(seg[:, 1], seg[:, 0])
    dh = (np.diff(h) + math.pi) % (2 * math.pi) - math.pi
    return float(np.abs(dh).sum())


def driving_lane(edge: sumolib.net.edge.Edge) -> sumolib.net.lane.Lane | None:
    """The rightmost lane of an edge that passenger cars may use, or None."""
    for lane in edge.getLanes():
        if lane.allows("passenger"):
            return lane
    return None


def net_stats(path: Path) -> dict:
    """Figures of one net: extent [m], junctions by type, road km, curved share, crossings."""
    net = sumolib.net.readNet(str(path), withInternal=True)
    (x0, y0), (x1, y1) = net.getBBoxXY()
    kinds = Counter(n.getType() for n in net.getNodes() if n.getType() != "internal")
    road = curved = sidewalk = 0.0
    crossings = 0
    for e in net.getEdges(withInternal=True):
        fn = e.getFunction()
        if fn == "crossing":
            crossings += 1
        if fn:
            continue
        lane = driving_lane(e)
        if lane is None:
            continue
        length = lane.getLength()
        road += length
        if math.degrees(heading_change(lane.getShape())) >= CURVED_DEG:
            curved += length
        if any(ln.allows("pedestrian") and not ln.allows("passenger") for ln in e.getLanes()):
            sidewalk += length
    return {
        "width_m": round(x1 - x0, 1), "height_m": round(y1 - y0, 1),
        "junctions": dict(sorted(kinds.items())),
        "traffic_lights": kinds.get("traffic_light", 0),
        "stop_junctions": kinds.get("priority_stop", 0) + kinds.get("allway_stop", 0),
        "road_km": round(road / 1000, 2),
        "curved_share": round(curved / road, 3) if road else float("nan"),
        "sidewalk_share": round(sidewalk / road, 3) if road else float("nan"),
        "crossings": crossings,
    }


def format_stats(rows: dict[str, dict]) -> str:
    """A plain-text table, one town a line."""
    head = f"{'town':8} {'size [m]':>13} {'road km':>8} {'curved':>7} {'sidewalk':>8} {'crossings':>9}  junctions"
    out = [head]
    for town, s in rows.items():
        kinds = ", ".join(f"{k} {v}" for k, v in s["junctions"].items())
        out.append(f"{town:8} {s['width_m']:6.0f}x{s['height_m']:<6.0f} {s['road_km']:8.2f} "
                   f"{s['curved_share']:7.1%} {s['sidewalk_share']:8.1%} {s['crossings']:9d}  {kinds}")
    return "\n".join(out)
