"""Nearest driving lane of world points, for the outside-route-lanes rule.

Every lane cars may use (junction-internal lanes included) is sampled every ``STEP``
metres; a k-d tree answers, for many points at once, the nearest sample: its distance
(an upper bound of the distance to the lane centre line by at most STEP / 2 along the
lane, i.e. < 1 cm laterally for a point 1 m off), the lane's width, heading and whether
it lies inside a junction.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.spatial import cKDTree

from sumo_nets import load_net

STEP = 0.25  # sampling of lane centre lines [m]


@dataclass(frozen=True)
class NearestLane:
    dist: np.ndarray  # (T,) distance to the nearest lane centre sample [m]
    width: np.ndarray  # (T,) that lane's width [m]
    heading: np.ndarray  # (T,) its heading there [rad, CCW from +x]
    junction: np.ndarray  # (T,) bool: the lane is junction-internal
    lane: np.ndarray  # (T,) int: index of the lane in LaneIndex.ids


class LaneIndex:
    def __init__(self, town: str):
        pts, width, heading, junction, lane = [], [], [], [], []
        self.ids: list[str] = []
        for edge in load_net(town).getEdges(withInternal=True):
            if edge.getFunction() not in ("", "internal"):
                continue
            for ln in edge.getLanes():
                if not ln.allows("passenger"):
                    continue
                shape = np.asarray(ln.getShape(), dtype=float)[:, :2]
                seg = np.diff(shape, axis=0)
                lengths = np.hypot(seg[:, 0], seg[:, 1])
                for (a, d, n) in zip(shape[:-1], seg, lengths):
                    if n < 1e-9:
                        continue
                    k = max(1, int(np.ceil(n / STEP)))
                    t = np.arange(k) / k
                    pts.append(a + t[:, None] * d)
                    heading.append(np.full(k, np.arctan2(d[1], d[0])))
                    width.append(np.full(k, ln.getWidth()))
                    junction.append(np.full(k, edge.getFunction() == "internal"))
                    lane.append(np.full(k, len(self.ids)))
                self.ids.append(ln.getID())
        self.pts = np.vstack(pts)
        self.width, self.heading = np.concatenate(width), np.concatenate(heading)
        self.junction, self.lane = np.concatenate(junction), np.concatenate(lane)
        self.tree = cKDTree(self.pts)

    @classmethod
    @lru_cache(maxsize=4)
    def for_town(cls, town: str) -> "LaneIndex":
        return cls(town)

    def nearest(self, xy: np.ndarray) -> NearestLane:
        d, k = self.tree.query(np.asarray(xy, dtype=float).reshape(-1, 2))
        return NearestLane(d, self.width[k], self.heading[k], self.junction[k], self.lane[k])
