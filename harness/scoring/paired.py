"""Seed-level statistics of arm comparisons (docs/scoring.md, "Seeds and intervals").

A seed index fixes a student's initialisation and data order for every arm, so arms are
paired by seed: the difference of two arms is the mean over seeds of the per-seed
differences d_s = x_arm,s - x_ref,s, each x the figure of one run over the routes.

- ``t_interval``: mean(d) +- t_{1-alpha/2, n-1} sd(d) / sqrt(n), sd with divisor n - 1, and
  the two-sided p of t = mean(d) / (sd(d) / sqrt(n)) with n - 1 degrees of freedom;
- ``mde``: the minimum detectable effect of a two-sided paired t test at level alpha with
  power 1 - beta, (t_{1-alpha/2, n-1} + t_{1-beta, n-1}) sd(d) / sqrt(n) (the usual
  t-based approximation of the noncentral t's power);
- ``holm``: Holm's step-down adjusted p-values of a family of tests.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

ALPHA, POWER = 0.05, 0.80  # two-sided level of every interval and test; power of the MDE


def t_interval(d: np.ndarray, alpha: float = ALPHA) -> tuple[float, float, float, float]:
    """(mean, low, high, p) of the paired differences ``d`` (n >= 2 finite values): the
    Student t interval at level 1 - alpha and the two-sided p of mean(d) = 0; for d with
    no spread, the interval is the point and p is 0 (1 if the mean is 0 too)."""
    d = np.asarray(d, dtype=float)
    n, mean = len(d), float(np.mean(d))
    if n < 2:
        raise ValueError(f"a paired t interval needs two or more seeds, got {n}")
    se = float(np.std(d, ddof=1)) / math.sqrt(n)
    if se == 0:
        return mean, mean, mean, (1.0 if mean == 0 else 0.0)
    half = float(stats.t.ppf(1 - alpha / 2, n - 1)) * se
    p = float(2 * stats.t.sf(abs(mean) / se, n - 1))
    return mean, mean - half, mean + half, p


def mde(d: np.ndarray, alpha: float = ALPHA, power: float = POWER) -> float:
    """The smallest true mean difference a two-sided paired t test at level ``alpha`` finds
    with probability ``power`` for the n seeds of ``d``, given their spread:
    (t_{1-alpha/2, n-1} + t_{power, n-1}) sd(d) / sqrt(n) [the unit of d]; NaN for n < 2."""
    d = np.asarray(d, dtype=float)
    n = len(d)
    if n < 2:
        return math.nan
    t = float(stats.t.ppf(1 - alpha / 2, n - 1) + stats.t.ppf(power, n - 1))
    return t * float(np.std(d, ddof=1)) / math.sqrt(n)


def holm(p: list[float]) -> list[float]:
    """Holm's adjusted p-values of a family, in the order given: the k-th smallest p
    (k = 1..m) times m - k + 1, made non-decreasing in that order, capped at 1; a NaN p is
    not a test of the family and stays NaN. A test is rejected at level alpha when its
    adjusted p is below alpha (the same decisions as Holm's step-down procedure)."""
    vals = np.asarray(p, dtype=float)
    tests = np.flatnonzero(np.isfinite(vals))
    out = np.full(len(vals), np.nan)
    m, running = len(tests), 0.0
    for k, i in enumerate(tests[np.argsort(vals[tests], kind="stable")]):
        running = max(running, min(1.0, (m - k) * vals[i]))
        out[i] = running
    return out.tolist()


def bootstrap_p(draws: np.ndarray) -> float:
    """Two-sided p of a bootstrap distribution of a difference: twice the smaller share of
    draws at or beyond 0 on either side, at most 1 (NaN without a finite draw)."""
    x = np.asarray(draws, dtype=float)
    x = x[np.isfinite(x)]
    if not len(x):
        return math.nan
    return float(min(1.0, 2 * min(np.mean(x <= 0), np.mean(x >= 0))))
