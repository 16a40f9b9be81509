"""Temporal-stability metrics of a route run (docs/design.md §9.3, the paper's Table 4), one entry
each in METRICS.

The paper gives no formulas; these are this project's, per 20 Hz tick t (dt = 0.05 s), over
MOVING ticks only: the ego speed v (the log's ``v``, the speed at the end of the tick) is
above MOVING_SPEED = 0.1 m/s at t and at t-1. A car that stands has no jerk and repeats its
prediction, so an arm that stands longer would otherwise look smoother. Each metric is a
mean over the route's moving ticks (NaN if it has none, or if the agent predicts nothing);
tables then average routes.

METRICS is the one table of them: each entry's record column, function, label, unit,
better direction, where it shows (the paper's Table 4 and its claims, Table 4's other
readings, or the CSV only) and its formula and reason for the docs table
(``docs_table``, the table of docs/scoring.md). ``stability`` computes every entry;
records.csv, ``sumo-scimm report``'s Table 4 and the claims of ``reproduce`` are made from it.
A curvature is undefined (left out of the mean over k) where a side at its point is shorter
than MIN_SIDE (a trajectory that ends at the ego: no direction to bend).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from controller.vehicle import DT

SPEED_WP_DT = 0.25  # spacing of the predicted speed waypoints [s]
MOVING_SPEED = 0.1  # a tick moves when the ego is faster than this at it and the tick before [m/s]
MIN_SIDE = 0.01  # shortest side of a three-point curvature [m]; below, the bend has no direction
KMH_PER_MS = 3.6

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


class RouteSignals:
    """The arrays of one route run's log that the metrics read, each made once: ``v`` [m/s],
    ``steer``, ``u`` = throttle - brake (T,), ``moving`` (T,) bool, ``path`` (T, 20, 2) and
    ``wps`` (T, 10, 2) [m, ego frame], and the per-tick changes several metrics share."""

    def __init__(self, log: dict):
        self.v = np.asarray(log["v"], dtype=float)
        self.moving = moving_ticks(self.v)
        self.steer = np.asarray(log["steer"], dtype=float)
        self.u = np.asarray(log["throttle"], dtype=float) - np.asarray(log["brake"], dtype=float)
        self.path = _predictions(log["pred_path"], (20, 2), len(self.v))
        self.wps = _predictions(log["pred_speed_wps"], (10, 2), len(self.v))

    @cached_property
    def quadratic_change(self) -> np.ndarray:
        """(T,) |kappa_t - kappa_{t-1}| of the quadratic-fit path curvature [1/m]."""
        return np.abs(np.diff(path_curvature(self.path), prepend=np.nan))

    @cached_property
    def speed_change(self) -> np.ndarray:
        """(T,) sum_k |v^_t(tau_k) - v^_{t-1}(tau_k)| of the speed waypoints [m/s]."""
        return _speed_change(self.wps)

    def on_moving(self, x: np.ndarray) -> float:
        return masked_mean(x, self.moving)

    def on_every(self, x: np.ndarray) -> float:
        return masked_mean(x, np.ones(len(x), dtype=bool))


TABLE4, OTHER, CSV_ONLY = "table4", "other", "csv"  # where a metric shows (Metric.shows)
PAPER_ARMS = ("baseline", "fixed", "scimm")  # the arms of the paper's Tables 3 and 4, in their order


@dataclass(frozen=True)
class Metric:
    """One stability metric of a route run.

    key: its records.csv column; compute: its value from a route's RouteSignals; label and
    unit: its Table 4 heading ``label [unit]`` (unit "" for a number without one); better:
    "lower" or "higher", the direction the paper calls better ("" for none); shows: TABLE4
    (the paper's Table 4: a column of the main table and one of the paper's claims), OTHER
    (Table 4's other readings) or CSV_ONLY (table4.csv only); formula and why: its row of
    the docs table ("" keeps it out of that table); paper: the paper's Table 4 values of its
    baseline, Fixed-IMM and SC-IMM arms (PAPER_ARMS), None where the paper has none."""
    key: str
    compute: Callable[[RouteSignals], float]
    label: str
    unit: str
    better: str
    shows: str
    formula: str = ""
    why: str = ""
    paper: tuple[float, float, float] | None = None

    @property
    def heading(self) -> str:
        return f"{self.label} [{self.unit}]" if self.unit else self.label


# every metric of one route run, in the order of the record's columns (harness.scoring.records)
METRICS = (
    Metric("steering_jerk_moving", lambda s: s.on_moving(second_differences(s.steer)),
           "steering jerk", "1/s^2", "lower", TABLE4,
           "mean_t \\|steer_t - 2 steer_{t-1} + steer_{t-2}\\| / dt^2, commanded steer",
           "the paper's \"change of the control command\"", (19.11, 17.84, 16.13)),
    Metric("longitudinal_jerk_moving", lambda s: s.on_moving(second_differences(s.u)),
           "longitudinal jerk", "1/s^2", "lower", TABLE4,
           "the same on u = throttle - brake",
           "one signed longitudinal command, as a brake pedal is a negative throttle", (44.01, 40.80, 38.96)),
    Metric("curvature_variation_wps", lambda s: s.on_moving(frame_change(menger_curvature(with_ego(s.wps)))),
           "curvature variation", "1/m", "lower", TABLE4,
           "mean_t mean_k \\|kappa_t(k) - kappa_{t-1}(k)\\|, kappa(k) = 2 ((b - a) x (c - b)) / (\\|b - a\\| "
           "\\|c - b\\| \\|c - a\\|) the signed three-point (Menger) curvature at each interior point b of the "
           "ego (0, 0) followed by the 10 predicted speed waypoints",
           "the predicted trajectory itself (where the car is to be at 0.25..2.5 s); the reading with the "
           "paper's magnitudes", (0.0430, 0.0337, 0.0289)),
    Metric("curvature_variation_path", lambda s: s.on_moving(frame_change(menger_curvature(s.path))),
           "path curvature variation", "1/m", "lower", OTHER,
           "the same on the 20 predicted path points (0..19 m)",
           "the geometric path alone, where speed does not enter"),
    Metric("curvature_variation_quadratic", lambda s: s.on_moving(s.quadratic_change),
           "quadratic curvature variation", "1/m", "lower", OTHER,
           "mean_t \\|kappa_t - kappa_{t-1}\\|, kappa = 2 c2 / (1 + c1^2)^1.5 at s = 0 of the quadratic fit "
           "y(s) = c0 + c1 s + c2 s^2 of the path",
           "the first Table 4's reading, kept for comparison: one number per path"),
    Metric("speed_variation_kmh", lambda s: s.on_moving(s.speed_change * KMH_PER_MS),
           "speed variation", "km/h", "lower", TABLE4,
           "mean_t sum_k \\|v^_t(tau_k) - v^_{t-1}(tau_k)\\|, v^(tau_k) = \\|W_k - W_{k-1}\\| / 0.25 s "
           "(W_0 the ego) the speeds of the predicted waypoints",
           "the paper's magnitudes (3.2-4.7) match km/h", (4.662, 3.200, 3.317)),
    Metric("speed_variation_ms", lambda s: s.on_moving(s.speed_change),
           "speed variation", "m/s", "lower", OTHER,
           "the same in m/s (= km/h / 3.6)", "SI, and the first Table 4's unit"),
    Metric("standing_share", lambda s: float(np.mean(s.v <= MOVING_SPEED)) if len(s.v) else math.nan,
           "standing share", "", "", OTHER,
           "share of the route's ticks at v <= 0.1 m/s (0..1)",
           "beside the metrics: how much of a route the average leaves out"),
    # the first Table 4's readings, over every tick, standing ones included (table4.csv only)
    Metric("steering_jerk", lambda s: second_difference(s.steer), "steering jerk, every tick", "1/s^2", "lower",
           CSV_ONLY),
    Metric("longitudinal_jerk", lambda s: second_difference(s.u), "longitudinal jerk, every tick", "1/s^2",
           "lower", CSV_ONLY),
    Metric("curvature_variation", lambda s: s.on_every(s.quadratic_change),
           "quadratic curvature variation, every tick", "1/m", "lower", CSV_ONLY),
    Metric("speed_variation", lambda s: s.on_every(s.speed_change), "speed variation, every tick", "m/s",
           "lower", CSV_ONLY),
)


def stability(log: dict) -> dict[str, float]:
    """Every metric of METRICS of one route run from its log arrays:
    ``v`` [m/s], ``steer``, ``throttle``, ``brake`` (T,), ``pred_path`` (T, 20, 2) and
    ``pred_speed_wps`` (T, 10, 2) [m], ego frame (NaN rows: no prediction)."""
    signals = RouteSignals(log)
    return {m.key: m.compute(signals) for m in METRICS}


def docs_table() -> str:
    """The Markdown table of the metrics of docs/scoring.md: column, formula, unit, why, one
    row per metric with a formula."""
    lines = ["| column | formula | unit | better | why this reading |", "| --- | --- | --- | --- | --- |"]
    lines += [f"| `{m.key}` | {m.formula} | {m.unit or '-'} | {m.better or '-'} | {m.why} |"
              for m in METRICS if m.formula]
    return "\n".join(lines)
