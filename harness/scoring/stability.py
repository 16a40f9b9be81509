"""Temporal-stability metrics of a route run (SPEC §9, the paper's Table 4).

With dt = 0.05 s the tick and t running over consecutive ticks:
- steering jerk: mean_t |steer_t - 2 steer_{t-1} + steer_{t-2}| / dt^2  [1/s^2]
- longitudinal jerk: the same on u = throttle - brake  [1/s^2]
- curvature variation: mean_t |kappa_t - kappa_{t-1}|, kappa = curvature at s = 0 of the
  quadratic fit y(s) = c0 + c1 s + c2 s^2 of the predicted path (ego frame, s = arc
  length): kappa = 2 c2 / (1 + c1^2)^(3/2)  [1/m]
- speed variation: mean_t sum_k |v_t(tau_k) - v_{t-1}(tau_k)| over the predicted speeds,
  v(tau_k) = |W_k - W_{k-1}| / 0.25 s with W_0 the origin (paper eq. 12's phi)  [m/s]
The last two need the agent's predictions; NaN for an agent that predicts nothing.
"""
from __future__ import annotations

import numpy as np

from controller.vehicle import DT

SPEED_WP_DT = 0.25  # spacing of the predicted speed waypoints [s]


def second_difference(u: np.ndarray, dt: float = DT) -> float:
    u = np.asarray(u, dtype=float)
    if len(u) < 3:
        return float("nan")
    return float(np.mean(np.abs(u[2:] - 2 * u[1:-1] + u[:-2])) / dt ** 2)


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
    path with a non-finite point or no length."""
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
    """(T, K) speeds from (T, K, 2) speed waypoints at 0.25 s spacing [m/s]."""
    w = np.asarray(wps, dtype=float)
    prev = np.concatenate([np.zeros((len(w), 1, 2)), w[:, :-1]], axis=1)
    return np.hypot(*(w - prev).transpose(2, 0, 1)) / SPEED_WP_DT


def stability(log: dict) -> dict[str, float]:
    """The four metrics of one route run from its log arrays."""
    out = {"steering_jerk": second_difference(log["steer"]),
           "longitudinal_jerk": second_difference(np.asarray(log["throttle"]) - np.asarray(log["brake"]))}
    kappa = path_curvature(log["pred_path"]) if len(log["pred_path"]) else np.zeros(0)
    dk = np.abs(np.diff(kappa))
    out["curvature_variation"] = float(np.nanmean(dk)) if np.isfinite(dk).any() else float("nan")
    v = waypoint_speeds(log["pred_speed_wps"]) if len(log["pred_speed_wps"]) else np.zeros((0, 10))
    dv = np.abs(np.diff(v, axis=0)).sum(axis=1) if len(v) > 1 else np.zeros(0)
    out["speed_variation"] = float(np.nanmean(dv)) if np.isfinite(dv).any() else float("nan")
    return out
