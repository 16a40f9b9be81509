"""Contacts between the ego and other actors: oriented-box overlap by the separating-axis
test, our own rather than SUMO's collision detection (docs/design.md §3: SUMO
misses collisions of moveToXY-driven vehicles and of vehicles with persons).

Boxes are centre (x, y) [m], yaw [rad], length along the heading and width [m], world frame.
"""
from __future__ import annotations

import numpy as np


def overlaps(ego: tuple[float, float, float, float, float], xy: np.ndarray, yaw: np.ndarray,
             size: np.ndarray) -> np.ndarray:
    """(K,) bool: which of K boxes overlap the ego box (x, y, yaw, length, width).

    Two rectangles are disjoint iff their projections on one of the four edge normals
    (two per box) are disjoint: |d . u| > r_ego(u) + r_other(u).
    """
    ex, ey, eyaw, el, ew = ego
    out = np.zeros(len(xy), dtype=bool)
    if len(xy) == 0:
        return out
    d = np.asarray(xy, dtype=float) - (ex, ey)  # (K, 2)
    # boxes whose circumcircles do not meet cannot overlap: test only the others
    reach = np.hypot(el, ew) / 2 + np.hypot(size[:, 0], size[:, 1]) / 2
    near = np.flatnonzero(np.hypot(d[:, 0], d[:, 1]) <= reach)
    if len(near) == 0:
        return out
    d, yaw, size = d[near], np.asarray(yaw)[near], np.asarray(size, dtype=float)[near]
    ea = np.array([[np.cos(eyaw), np.sin(eyaw)], [-np.sin(eyaw), np.cos(eyaw)]])  # (2, 2) ego axes
    oa = np.stack([np.stack([np.cos(yaw), np.sin(yaw)], -1),
                   np.stack([-np.sin(yaw), np.cos(yaw)], -1)], axis=1)  # (K, 2, 2) other axes
    half_e = np.array([el, ew]) / 2
    half_o = np.asarray(size, dtype=float) / 2  # (K, 2)
    separated = np.zeros(len(near), dtype=bool)
    for k in range(2):  # the ego's axes
        u = ea[k]
        r_o = np.einsum("kj,kj->k", np.abs(oa @ u), half_o)
        separated |= np.abs(d @ u) > half_e[k] + r_o
    for k in range(2):  # the other boxes' axes
        u = oa[:, k, :]  # (K, 2)
        r_e = np.abs(u @ ea.T) @ half_e
        separated |= np.abs(np.einsum("kj,kj->k", d, u)) > r_e + half_o[:, k]
    out[near] = ~separated
    return out
