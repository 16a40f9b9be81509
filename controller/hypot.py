"""CPython 3.11's ``math.hypot(x, y)``, compiled (numba), equal to it bit for bit.

Compiled code that calls ``math.hypot`` gets libm's hypot, which differs from CPython's in
the last bit on 0.06-0.6 % of arguments, depending on their range: a model compiled with it
would no longer give the doubles of its own source run by CPython. ``hypot`` here follows
CPython 3.11's algorithm for two coordinates (``vector_norm`` in its mathmodule.c): both
scaled by a power of two so that the larger lies in [0.5, 1), each square summed exactly as
three parts (Veltkamp's split), the square root, then one correction step; arguments below
the normal range are divided by the larger instead. tests/test_carla_car.py compares it
with ``math.hypot`` on 400,000 random pairs and the special values.

numba keeps compiled code per module, keyed on that module's file: controller.carla_car's
cached code holds this function, so after an edit here, delete controller/__pycache__'s
``*.nbi`` and ``*.nbc`` files (or touch carla_car.py) to have it compiled again.
"""
from __future__ import annotations

import math

import numba

_jit = numba.njit(cache=True, error_model="numpy")
SPLITTER = 134217729.0  # 2^27 + 1: Veltkamp's split of a double into two 26-bit halves


@_jit
def _split(v: float) -> tuple[float, float]:
    """(hi, lo) with hi + lo = v exactly and each of 26 significant bits at most."""
    t = v * SPLITTER
    hi = t - (t - v)
    return hi, v - hi


@_jit
def _add(total: float, error: float, x: float) -> tuple[float, float]:
    """total + x rounded, and ``error`` plus what that rounding lost (|total| >= |x|)."""
    s = total + x
    return s, error + ((total - s) + x)


@_jit
def hypot(x: float, y: float) -> float:
    """sqrt(x^2 + y^2) as CPython 3.11's ``math.hypot(x, y)`` computes it, bit for bit."""
    a, b = abs(x), abs(y)
    m = 0.0  # the larger, a NaN passed over
    if a > m:
        m = a
    if b > m:
        m = b
    if math.isinf(m):
        return m
    if math.isnan(a) or math.isnan(b):
        return math.nan
    if m == 0.0:
        return m
    exponent = math.frexp(m)[1]
    if exponent < -1023:  # below the normal range: 2^-exponent would overflow
        total, error = 1.0, 0.0
        for v in (a / m, b / m):
            total, error = _add(total, error, v * v)
        return m * math.sqrt(total - 1.0 + error)
    scale = math.ldexp(1.0, -exponent)
    total, e1, e2, e3 = 1.0, 0.0, 0.0, 0.0  # the sum starts at 1 so that no part is lost
    for v in (a * scale, b * scale):
        hi, lo = _split(v)  # v^2 = hi^2 + 2 hi lo + lo^2, each exact
        total, e1 = _add(total, e1, hi * hi)
        total, e2 = _add(total, e2, 2.0 * hi * lo)
        e3 += lo * lo
    h = math.sqrt(total - 1.0 + (e1 + e2 + e3))
    hi, lo = _split(h)  # the correction: the residual sum - h^2, to first order
    total, e1 = _add(total, e1, -hi * hi)
    total, e2 = _add(total, e2, -2.0 * hi * lo)
    total, e3 = _add(total, e3, -lo * lo)
    h += (total - 1.0 + (e1 + e2 + e3)) / (2.0 * h)
    return h / scale
