"""World points and oriented boxes -> BEV pixel coordinates, compiled (``harness.sensors.bev``).

Per frame the BEV turns the route near the ego, the red and yellow stop lines and the
corners of every actor's box into pixels (x 16, for OpenCV's 4-bit subpixel shift). In
NumPy that is some 25 calls on a few hundred points, 60 us a frame standalone; each
function here is one call. The arithmetic is NumPy's, operation by operation in the same
order on the same doubles, so the pixels are equal bit for bit (tests/test_bev_pixels.py
checks both against the NumPy code they replaced on random points and boxes and on 7,334
recorded frames):

    box corner   x = (cx + cos(yaw) * (sx l/2)) - sin(yaw) * (sy w/2)
                 y = (cy + sin(yaw) * (sx l/2)) + cos(yaw) * (sy w/2),   (sx, sy) the
                 corner's signs: (1, 1), (1, -1), (-1, -1), (-1, 1)
    pixel        column = rint(16 (SIZE/2 - ((-s) dx + c dy) / RES))
                 row    = rint(16 (EGO_ROW - (c dx + s dy) / RES)),
                 (dx, dy) the point minus the ego's position, c, s the cosine and sine
                 of the ego's yaw (world frame, metres).

The boxes' cosines and sines come in from NumPy (``np.cos``, ``np.sin``), so the corners
use the very values NumPy's would.
"""
from __future__ import annotations

import math

import numba
import numpy as np

_SIGNS = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, -1.0], [-1.0, 1.0]])  # corner signs (along, across)


@numba.njit(cache=True)
def _pixel(dx: float, dy: float, c: float, s: float, half: float, ego_row: float, res: float) -> tuple[int, int]:
    u = half - ((-s) * dx + c * dy) / res  # left [m] -> column
    v = ego_row - (c * dx + s * dy) / res  # forward [m] -> row
    return np.int32(np.rint(u * 16.0)), np.int32(np.rint(v * 16.0))


# explicit signatures: compiled (or loaded from numba's cache) when this module is imported,
# not in a closed loop's first tick; arrays of any layout
_F = numba.float64


@numba.njit(numba.int32[:, :](_F[:, :], _F, _F, _F, _F, _F, _F, _F), cache=True)
def points_to_pixels(pts: np.ndarray, ex: float, ey: float, c: float, s: float,
                     half: float, ego_row: float, res: float) -> np.ndarray:
    """(N, 2) world points [m] -> (N, 2) int32 pixels x 16 for an ego at (ex, ey) with
    yaw cosine c and sine s; half = SIZE / 2 and ego_row the ego's pixel, res [m / px]."""
    out = np.empty((pts.shape[0], 2), dtype=np.int32)
    for i in range(pts.shape[0]):
        out[i, 0], out[i, 1] = _pixel(pts[i, 0] - ex, pts[i, 1] - ey, c, s, half, ego_row, res)
    return out


@numba.njit(numba.int32[:, :, :](_F[:, :], _F[:], _F[:], _F[:, :], _F, _F, _F, _F, _F, _F, _F), cache=True)
def boxes_to_pixels(xy: np.ndarray, cos: np.ndarray, sin: np.ndarray, size: np.ndarray,
                    ex: float, ey: float, c: float, s: float,
                    half: float, ego_row: float, res: float) -> np.ndarray:
    """(K, 4, 2) int32 pixels x 16 of the corners of K boxes: centres xy (K, 2) [m], the
    cosine and sine (K,) of their yaws, sizes (K, 2) length and width [m]; the ego and
    raster as in ``points_to_pixels``."""
    out = np.empty((xy.shape[0], 4, 2), dtype=np.int32)
    for k in range(xy.shape[0]):
        hl, hw = size[k, 0] / 2, size[k, 1] / 2
        for j in range(4):
            along, across = _SIGNS[j, 0] * hl, _SIGNS[j, 1] * hw
            x = (xy[k, 0] + cos[k] * along) - sin[k] * across
            y = (xy[k, 1] + sin[k] * along) + cos[k] * across
            out[k, j, 0], out[k, j, 1] = _pixel(x - ex, y - ey, c, s, half, ego_row, res)
    return out


@numba.njit(_F[:, :](_F[:, :], _F, _F, _F), cache=True)
def points_within(pts: np.ndarray, x: float, y: float, radius: float) -> np.ndarray:
    """The (N, 2) world points [m] closer than ``radius`` [m] to (x, y), in order: NumPy's
    ``pts[np.hypot(pts[:, 0] - x, pts[:, 1] - y) < radius]`` (libm's hypot, as NumPy's)."""
    keep = np.empty(pts.shape[0], dtype=np.bool_)
    n = 0
    for i in range(pts.shape[0]):
        keep[i] = math.hypot(pts[i, 0] - x, pts[i, 1] - y) < radius
        n += keep[i]
    out = np.empty((n, 2))
    j = 0
    for i in range(pts.shape[0]):
        if keep[i]:
            out[j, 0], out[j, 1] = pts[i, 0], pts[i, 1]
            j += 1
    return out
