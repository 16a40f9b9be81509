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


def path_curvature(path: np.ndarray) -> np.ndarray:
    """(T,) curvature at s = 0 of the quadratic fit of each path (T, N, 2) [1/m]."""
    p = np.asarray(path, dtype=float)
    seg = np.hypot(*np.diff(p, axis=1).transpose(2, 0, 1))
    s = np.concatenate([np.zeros((len(p), 1)), np.cumsum(seg, axis=1)], axis=1)  # (T, N)
    out = np.full(len(p), np.nan)
    for t in range(len(p)):
        if not np.isfinite(p[t]).all() or s[t, -1] < 1e-6:
            continue
        c2, c1, _ = np.polyfit(s[t], p[t, :, 1], 2)
        out[t] = 2 * c2 / (1 + c1 ** 2) ** 1.5
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
