"""Temporal-stability metrics of a route run (docs/design.md §9.3, the paper's Table 4).

The paper gives no formulas; these are this project's, per 20 Hz tick t (dt = 0.05 s), over
MOVING ticks only: the ego speed v (the log's ``v``, the speed at the end of the tick) is
above MOVING_SPEED = 0.1 m/s at t and at t-1. A car that stands has no jerk and repeats its
prediction, so an arm that stands longer would otherwise look smoother. Each metric is a
mean over the route's moving ticks (NaN if it has none, or if the agent predicts nothing);
tables then average routes.

- steering jerk: mean_t |steer_t - 2 steer_{t-1} + steer_{t-2}| / dt^2 of the commanded
  steer  [1/s^2]                                                    ``steering_jerk_moving``
- longitudinal jerk: the same on u = throttle - brake  [1/s^2]  ``longitudinal_jerk_moving``
- curvature variation: mean_t mean_k |kappa_t(k) - kappa_{t-1}(k)|, kappa(k) the signed
  three-point (Menger) curvature 2 ((b - a) x (c - b)) / (|b - a| |c - b| |c - a|) at each
  interior point b of a predicted trajectory, a and c its neighbours  [1/m]:
  on the ego (0, 0) followed by the 10 speed waypoints (9 interior points; the reading
  with the paper's magnitudes, 0.029-0.043)                   ``curvature_variation_wps``
  and on the 20 path points (18 interior points)               ``curvature_variation_path``;
  a curvature is undefined (left out of the mean over k) where a side at its point is
  shorter than MIN_SIDE (a trajectory that ends at the ego: no direction to bend).
  A third reading, kept from the first Table 4: kappa = 2 c2 / (1 + c1^2)^(3/2) at s = 0
  of the quadratic fit y(s) = c0 + c1 s + c2 s^2 of the path  ``curvature_variation_quadratic``
- speed variation: mean_t sum_k |v^_t(tau_k) - v^_{t-1}(tau_k)|, v^(tau_k) =
  |W_k - W_{k-1}| / 0.25 s the speeds of the predicted speed waypoints W (W_0 the ego,
  paper eq. 12's phi), in km/h (the paper's magnitudes, 3.2-4.7)  ``speed_variation_kmh``
  and in m/s (= km/h / 3.6)                                          ``speed_variation_ms``
- the share of standing ticks (v <= MOVING_SPEED) of the route  [0..1]  ``standing_share``

The first Table 4's readings over every tick, standing ones included, stay in the record
under their old names with their old meaning: ``steering_jerk``, ``longitudinal_jerk``,
``curvature_variation`` (the quadratic reading) and ``speed_variation`` [m/s].
"""
from __future__ import annotations

import math

import numpy as np

from controller.vehicle import DT

SPEED_WP_DT = 0.25  # spacing of the predicted speed waypoints [s]
MOVING_SPEED = 0.1  # a tick moves when the ego is faster than this at it and the tick before [m/s]
MIN_SIDE = 0.01  # shortest side of a three-point curvature [m]; below, the bend has no direction
KMH_PER_MS = 3.6

# the metrics of one route run, in the order of the record's columns (harness.scoring.records)
MOVING_METRICS = ("steering_jerk_moving", "longitudinal_jerk_moving", "curvature_variation_wps",
                  "curvature_variation_path", "curvature_variation_quadratic", "speed_variation_kmh",
                  "speed_variation_ms", "standing_share")
ALL_TICK_METRICS = ("steering_jerk", "longitudinal_jerk", "curvature_variation", "speed_variation")


def moving_ticks(v: np.ndarray) -> np.ndarray:
    """(T,) bool: tick t moves, v_t > MOVING_SPEED and v_{t-1} > MOVING_SPEED (tick 0 never)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(len(v), dtype=bool)
    out[1:] = (v[1:] > MOVING_SPEED) & (v[:-1] > MOVING_SPEED)
    return out


def second_differences(u: np.ndarray, dt: float = DT) -> np.ndarray:
    """(T,) |u_t - 2 u_{t-1} + u_{t-2}| / dt^2 per tick, NaN for t < 2 [unit of u / s^2]."""
    u = np.asarray(u, dtype=float)
    out = np.full(len(u), np.nan)
    out[2:] = np.abs(u[2:] - 2 * u[1:-1] + u[:-2]) / dt ** 2
    return out


def second_difference(u: np.ndarray, dt: float = DT) -> float:
    """mean_t |u_t - 2 u_{t-1} + u_{t-2}| / dt^2 over every tick (the all-tick jerk)."""
    u = np.asarray(u, dtype=float)
    if len(u) < 3:
        return float("nan")
    return float(np.mean(np.abs(u[2:] - 2 * u[1:-1] + u[:-2])) / dt ** 2)


def masked_mean(x: np.ndarray, mask: np.ndarray) -> float:
    """Mean of the finite x where mask is true; NaN if there is none."""
    x = np.asarray(x, dtype=float)[np.asarray(mask, dtype=bool)]
    x = x[np.isfinite(x)]
    return float(x.mean()) if len(x) else math.nan


def menger_curvature(points: np.ndarray) -> np.ndarray:
    """(T, N-2) signed three-point curvature [1/m] at the interior points of each polyline
    of ``points`` (T, N, 2), left turns positive: 2 ((b - a) x (c - b)) / (|b - a| |c - b|
    |c - a|), the inverse radius of the circle through a, b, c (0 on a straight line). NaN
    where a side at b is shorter than MIN_SIDE or a point is not finite."""
    p = np.asarray(points, dtype=float)
    a, b, c = p[:, :-2], p[:, 1:-1], p[:, 2:]
    ab, bc, ac = b - a, c - b, c - a
    lab, lbc, lac = (np.hypot(d[..., 0], d[..., 1]) for d in (ab, bc, ac))
    cross = ab[..., 0] * bc[..., 1] - ab[..., 1] * bc[..., 0]
    ok = (lab >= MIN_SIDE) & (lbc >= MIN_SIDE)  # then |c - a| > 0 unless c folds back onto a
    ok &= lac > 0
    out = np.full(cross.shape, np.nan)
    np.divide(2 * cross, lab * lbc * lac, out=out, where=ok)
    return out


def with_ego(speed_wps: np.ndarray) -> np.ndarray:
    """(T, K+1, 2): the ego (0, 0) followed by the K speed waypoints (T, K, 2), ego frame [m]."""
    w = np.asarray(speed_wps, dtype=float)
    return np.concatenate([np.zeros((len(w), 1, 2)), w], axis=1)


def frame_change(q: np.ndarray) -> np.ndarray:
    """(T,) mean_k |q_t(k) - q_{t-1}(k)| over the k defined at both ticks, NaN at t = 0 and
    where no k is; q (T, K)."""
    q = np.asarray(q, dtype=float)
    out = np.full(len(q), np.nan)
    if len(q) > 1:
        d = np.abs(np.diff(q, axis=0))
        n = np.isfinite(d).sum(axis=1)
        s = np.where(np.isfinite(d), d, 0.0).sum(axis=1)
        np.divide(s, n, out=out[1:], where=n > 0)
    return out


def quadratic_fits(s: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(T, 3) least-squares coefficients (c2, c1, c0) of y = c0 + c1 s + c2 s^2 for each row
    of s, y (T, N): ``np.polyfit(s[t], y[t], 2)`` for all rows at once (one batched SVD
    instead of T LAPACK calls: ~0.1 s a route less). The same method as polyfit: columns of
    the Vandermonde matrix scaled to unit norm, singular values at or below N eps times the
    largest dropped (the minimum-norm solution of a rank-deficient fit); it agrees with
    polyfit to rounding (tests/test_stability.py)."""
    vander = np.stack([s * s, s, np.ones_like(s)], axis=-1)  # (T, N, 3)
    scale = np.sqrt((vander * vander).sum(axis=1))  # (T, 3) column norms
    u, sv, vt = np.linalg.svd(vander / scale[:, None, :], full_matrices=False)
    keep = sv > s.shape[1] * np.finfo(float).eps * sv[:, :1]
    inv = np.divide(1.0, sv, out=np.zeros_like(sv), where=keep)  # (T, 3)
    uty = np.einsum("tnk,tn->tk", u, y)  # (T, 3)
    return np.einsum("tkj,tk->tj", vt, inv * uty) / scale


def path_curvature(path: np.ndarray) -> np.ndarray:
    """(T,) curvature at s = 0 of the quadratic fit of each path (T, N, 2) [1/m]; NaN for a
    path with a non-finite point or no length. The curvature of the graph of y over arc
    length s: it equals the path's only while the path stays near the x axis (docs/scoring.md)."""
    p = np.asarray(path, dtype=float)
    seg = np.hypot(*np.diff(p, axis=1).transpose(2, 0, 1))
    s = np.concatenate([np.zeros((len(p), 1)), np.cumsum(seg, axis=1)], axis=1)  # (T, N)
    out = np.full(len(p), np.nan)
    ok = np.isfinite(p).all(axis=(1, 2)) & (s[:, -1] >= 1e-6)
    if ok.any():
        c2, c1, _ = quadratic_fits(s[ok], p[ok, :, 1]).T
        out[ok] = 2 * c2 / (1 + c1 ** 2) ** 1.5
    return out


def waypoint_speeds(wps: np.ndarray) -> np.ndarray:
    """(T, K) speeds from (T, K, 2) speed waypoints at 0.25 s spacing, the first from the ego [m/s]."""
    w = np.asarray(wps, dtype=float)
    prev = np.concatenate([np.zeros((len(w), 1, 2)), w[:, :-1]], axis=1)
    return np.hypot(*(w - prev).transpose(2, 0, 1)) / SPEED_WP_DT


def _speed_change(wps: np.ndarray) -> np.ndarray:
    """(T,) sum_k |v^_t(tau_k) - v^_{t-1}(tau_k)| [m/s], NaN at t = 0 and without a prediction."""
    v = waypoint_speeds(wps)
    out = np.full(len(v), np.nan)
    if len(v) > 1:
        out[1:] = np.abs(np.diff(v, axis=0)).sum(axis=1)
    return out


def _predictions(arr, shape: tuple, n: int) -> np.ndarray:
    """The (n, *shape) predictions of a log; all NaN (nothing predicted) if it holds none."""
    a = np.asarray(arr, dtype=float)
    return a if len(a) else np.full((n, *shape), np.nan)


def stability(log: dict) -> dict[str, float]:
    """Every metric of one route run (MOVING_METRICS, then ALL_TICK_METRICS) from its log
    arrays: ``v`` [m/s], ``steer``, ``throttle``, ``brake`` (T,), ``pred_path`` (T, 20, 2)
    and ``pred_speed_wps`` (T, 10, 2) [m], ego frame (NaN rows: no prediction)."""
    v = np.asarray(log["v"], dtype=float)
    moving = moving_ticks(v)
    steer = np.asarray(log["steer"], dtype=float)
    u = np.asarray(log["throttle"], dtype=float) - np.asarray(log["brake"], dtype=float)
    path = _predictions(log["pred_path"], (20, 2), len(v))
    wps = _predictions(log["pred_speed_wps"], (10, 2), len(v))
    quad = np.abs(np.diff(path_curvature(path), prepend=np.nan))
    dv = _speed_change(wps)
    out = {"steering_jerk_moving": masked_mean(second_differences(steer), moving),
           "longitudinal_jerk_moving": masked_mean(second_differences(u), moving),
           "curvature_variation_wps": masked_mean(frame_change(menger_curvature(with_ego(wps))), moving),
           "curvature_variation_path": masked_mean(frame_change(menger_curvature(path)), moving),
           "curvature_variation_quadratic": masked_mean(quad, moving),
           "speed_variation_kmh": masked_mean(dv * KMH_PER_MS, moving),
           "speed_variation_ms": masked_mean(dv, moving),
           "standing_share": float(np.mean(v <= MOVING_SPEED)) if len(v) else math.nan,
           # the first Table 4's readings, over every tick
           "steering_jerk": second_difference(steer),
           "longitudinal_jerk": second_difference(u),
           "curvature_variation": masked_mean(quad, np.ones(len(quad), dtype=bool)),
           "speed_variation": masked_mean(dv, np.ones(len(dv), dtype=bool))}
    return out
