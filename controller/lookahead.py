"""SimLingo's lookahead point, compiled: the point of the path resampled every ``step``
metres at which the summed distance between resampled points first reaches the lookahead.

It is what ``controller.simlingo.resample_path`` followed by ``LateralPID.target``
computes, in one pass that stops at the point (the NumPy pair builds the whole
resampled path, about 200 points, for one of them): the same operations on the same
doubles in the same order, so the point is equal bit for bit
(tests/test_student_controller.py checks it against the NumPy pair on random paths). The
pair costs about 30 us a tick standalone, most of it the fixed cost of its NumPy calls,
and twice that inside the closed loop; this costs about 2 us (docs/scale.md).

Replicated exactly:

- ``np.cumsum`` of the segment lengths: sequential sums of ``hypot`` (libm's, as NumPy's);
- ``np.arange(step, L + 1e-9, step)``: ceil((stop - start) / step) values, the first
  ``step``, the second ``step + step``, then ``step + i * (2 step - step)``;
- ``np.interp`` with slopes precomputed (it does so when the path is shorter than the
  samples): for x in [xp[j], xp[j+1]), slope * (x - xp[j]) + fp[j]; fp[j] when x == xp[j];
  fp[-1] from the last knot on; a NaN from a zero-length segment retried from the right
  knot, then fp[j] if both knots hold the same value;
- ``searchsorted`` (side left): the first point whose summed distance is >= the lookahead,
  the last point if none is.
"""
from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, error_model="numpy")
def _interp(slope: float, s: float, s0: float, s1: float, f0: float, f1: float) -> float:
    """np.interp's value at s in [s0, s1) with knot values f0, f1 and its slope."""
    v = slope * (s - s0) + f0
    if math.isnan(v):
        v = slope * (s - s1) + f1
        if math.isnan(v) and f0 == f1:
            v = f0
    return v


# an explicit signature: compiled (or loaded from numba's cache) when this module is imported,
# not in a closed loop's first tick; error_model numpy: x / 0 gives inf or nan, as in NumPy
@numba.njit(numba.types.UniTuple(numba.float64, 2)(numba.float64[:, :], numba.float64, numba.float64),
            cache=True, error_model="numpy")
def _lookahead_point(path: np.ndarray, lookahead: float, step: float) -> tuple[float, float]:
    n = path.shape[0] + 1  # the ego origin, then the path
    px, py, cum = np.empty(n), np.empty(n), np.empty(n)
    px[0] = py[0] = cum[0] = 0.0
    for i in range(1, n):
        px[i], py[i] = path[i - 1, 0], path[i - 1, 1]
        cum[i] = cum[i - 1] + math.hypot(px[i] - px[i - 1], py[i] - py[i - 1])
    end = cum[n - 1]  # the path's length [m]
    if not math.isfinite(end):
        raise ValueError("non-finite path")
    if end < step:  # resample_path gives the path's last point alone
        return px[n - 1], py[n - 1]
    delta = (step + step) - step  # np.arange's increment
    count = int(math.ceil((end + 1e-9 - step) / step))  # np.arange's length
    sx, sy = np.empty(n - 1), np.empty(n - 1)  # np.interp's slopes
    for j in range(n - 1):
        sx[j] = (px[j + 1] - px[j]) / (cum[j + 1] - cum[j])
        sy[j] = (py[j + 1] - py[j]) / (cum[j + 1] - cum[j])
    total, qx, qy, j = 0.0, 0.0, 0.0, 0
    for i in range(count):
        s = step if i == 0 else (step + step if i == 1 else step + i * delta)
        if s >= end:
            x, y = px[n - 1], py[n - 1]
        else:
            while cum[j + 1] <= s:  # the knot interval [cum[j], cum[j+1]) holding s
                j += 1
            if s == cum[j]:
                x, y = px[j], py[j]
            else:
                x = _interp(sx[j], s, cum[j], cum[j + 1], px[j], px[j + 1])
                y = _interp(sy[j], s, cum[j], cum[j + 1], py[j], py[j + 1])
        total += math.hypot(x - qx, y - qy)  # summed distance between resampled points
        qx, qy = x, y
        if total >= lookahead:
            return x, y
    return qx, qy


def lookahead_point(path: np.ndarray, lookahead: float, step: float) -> tuple[float, float]:
    """(x, y) [m], ego frame: the lookahead point of ``path`` (N, 2) [m] (ego frame, from
    the ego onwards, the ego origin prepended) resampled every ``step`` m, for a lookahead
    distance [m]. Raises ValueError for a non-finite path."""
    return _lookahead_point(np.asarray(path, dtype=np.float64), float(lookahead), float(step))
