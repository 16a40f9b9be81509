"""Contacts between the ego and other actors: oriented-box overlap by the separating-axis
test, our own rather than SUMO's collision detection (docs/design.md §3: SUMO
misses collisions of moveToXY-driven vehicles and of vehicles with persons).

Boxes are centre (x, y) [m], yaw [rad], length along the heading and width [m], world frame.
"""
from __future__ import annotations

import math

import numba
import numpy as np

_F = numba.float64


# explicit signature: compiled (or loaded from numba's cache) on import; arrays of any layout
@numba.njit(numba.int64[:](_F, _F, _F, _F, _F[:, :], _F[:, :]), cache=True)
def _circles_meet(ex: float, ey: float, el: float, ew: float, xy: np.ndarray, size: np.ndarray) -> np.ndarray:
    """Indices of the K boxes (centres xy (K, 2), sizes (K, 2) [m]) whose circumcircle
    meets the ego's (centre ex, ey, length el, width ew [m]): hypot(d) <= hypot(el, ew) / 2
    + hypot(length, width) / 2. One compiled pass over the boxes: the doubles of the
    NumPy expression with ``np.hypot`` (libm's hypot), operation by operation."""
    reach_ego = math.hypot(el, ew) / 2
    out = np.empty(xy.shape[0], dtype=np.int64)
    n = 0
    for k in range(xy.shape[0]):
        if math.hypot(xy[k, 0] - ex, xy[k, 1] - ey) <= reach_ego + math.hypot(size[k, 0], size[k, 1]) / 2:
            out[n] = k
            n += 1
    return out[:n]


def overlaps(ego: tuple[float, float, float, float, float], xy: np.ndarray, yaw: np.ndarray,
             size: np.ndarray) -> np.ndarray:
    """(K,) bool: which of K boxes overlap the ego box (x, y, yaw, length, width).

    Two rectangles are disjoint iff their projections on one of the four edge normals
    (two per box) are disjoint: |d . u| > r_ego(u) + r_other(u). Only boxes whose
    circumcircles meet the ego's are tested (the others cannot overlap it).
    """
    ex, ey, eyaw, el, ew = ego
    out = np.zeros(len(xy), dtype=bool)
    if len(xy) == 0:
        return out
    xy, size = np.asarray(xy, dtype=float), np.asarray(size, dtype=float)
    near = _circles_meet(ex, ey, el, ew, xy, size)
    if len(near) == 0:
        return out
    d, yaw, size = xy[near] - (ex, ey), np.asarray(yaw)[near], size[near]
    ea = np.array([[np.cos(eyaw), np.sin(eyaw)], [-np.sin(eyaw), np.cos(eyaw)]])  # (2, 2) ego axes
    oa = np.stack([np.stack([np.cos(yaw), np.sin(yaw)], -1),
                   np.stack([-np.sin(yaw), np.cos(yaw)], -1)], axis=1)  # (K, 2, 2) other axes
    half_e = np.array([el, ew]) / 2
    half_o = size / 2  # (K, 2)
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
