"""Bench2Drive's figures (docs/design.md §9.2): Success Rate, Driving Efficiency and
Driving Smoothness, and the per-route ``metric_info.json`` its
``tools/efficiency_smoothness_benchmark.py`` reads.

Success (``tools/merge_route_json.py``): status Completed or Perfect and every infraction
list but ``min_speed_infractions`` empty. Bench2Drive divides by its 220 routes; we divide
by the planned route runs of the run (``progress[1]``).

Efficiency: per route, the mean of the minimum-speed checkpoint values (% of the
surrounding traffic's speed) at most 1000 %, over every checkpoint as Bench2Drive logs them
(20 per route, whatever the value); then the mean over the routes that have one.

Smoothness ("comfortness"): per route, the share of consecutive 20-sample chunks (1 s at
20 Hz; an incomplete last chunk dropped; a route of <= 20 samples is one chunk) in which
every sample passes nuPlan's six comfort bounds after a Savitzky-Golay filter; then the
mean over routes. Computed as Bench2Drive's tool computes it, quirks included (its
published numbers are made so): the yaw rate is CARLA's angular velocity in deg/s compared
with bounds nuPlan states in rad/s, its "yaw acceleration" is the smoothed yaw rate, and
jerks take a 0.1 s sample spacing where the samples are 0.05 s apart.

metric_info.json: one entry per tick (20 Hz, keys "0", "1", ...), as Bench2Drive's agents
log it from CARLA's getters: acceleration [m/s^2] and angular_velocity [deg/s] (world frame,
from the logged pose by finite differences: velocity = displacement per tick, the
acceleration its change per tick), forward_vector and right_vector (unit), location [m],
rotation [roll, pitch, yaw] [deg]. Our world frame is SUMO's (x east, y north, yaw
counter-clockwise) where CARLA's is left-handed: the tool uses only dot products with
the car's own vectors and the size of the yaw rate, so its figures do not depend on it.
"""
from __future__ import annotations

import functools
import json
import math
import re
from pathlib import Path

import numpy as np

from controller.vehicle import DT
from files.atomic import write_atomic
from harness.scoring.statuses import COMPLETED, PERFECT

EFFICIENCY_CAP = 1000.0  # checkpoint values above this are left out [%]
CHUNK = 20  # samples per smoothness segment
WINDOW, ORDER, DELTA = 7, 2, 0.1  # Savitzky-Golay window [samples], polynomial order, spacing [s]
# nuPlan's ego_is_comfortable bounds, open intervals: m/s^2, m/s^3, and the yaw ones
# (nuPlan's rad/s^2 and rad/s, compared with deg/s values as Bench2Drive does)
LON_ACCEL = (-4.05, 2.40)
LAT_ACCEL = 4.89
JERK = 8.37
LON_JERK = 4.13
YAW_ACCEL = 1.93  # bounds the smoothed yaw rate too, as Bench2Drive does: never the deciding bound
YAW_RATE = 0.95
FIELDS = ("acceleration", "angular_velocity", "forward_vector", "right_vector", "location", "rotation")
_DIGITS = {"acceleration": 4, "angular_velocity": 4, "forward_vector": 6, "right_vector": 6, "location": 3,
           "rotation": 4}
_PERCENT = re.compile(r"\b\d+\.?\d*%")


def success(record: dict) -> bool:
    """Bench2Drive's success of one Leaderboard route record."""
    if record["status"] not in (COMPLETED, PERFECT):
        return False
    return all(not v for k, v in record["infractions"].items() if k != "min_speed_infractions")


def success_rate(records: list[dict], total: int) -> float:
    """Share of successful route runs among ``total`` planned ones (never-run ones fail) [%]."""
    return 100.0 * sum(success(r) for r in records) / total if total > 0 else math.nan


def route_efficiency(messages: list[str]) -> float | None:
    """Mean of a route's minimum-speed checkpoint values <= 1000 % (the first number followed
    by '%' in each message); None without one (such a route is left out)."""
    values = [float(m.group().rstrip("%")) for m in map(_PERCENT.search, messages) if m is not None]
    values = [v for v in values if v <= EFFICIENCY_CAP]
    return sum(values) / len(values) if values else None


def mean_of(values: list[float | None]) -> float:
    """Mean of the routes' values, those without one (None, NaN) left out; NaN if none has one."""
    vals = [float(v) for v in values if v is not None and math.isfinite(v)]
    return sum(vals) / len(vals) if vals else math.nan


# --- metric_info.json ----------------------------------------------------------------------
def metric_info(log: dict) -> dict[str, np.ndarray]:
    """Bench2Drive's per-tick ego state from an episode log (x, y, yaw per 0.05 s tick):
    {field: (n, 3) array}, rounded as written to the file (FIELDS, units in the module
    docstring). Velocity of tick k = (p_k - p_{k-1}) / dt, acceleration = its change per tick,
    yaw rate = the wrapped heading change per tick; the first ticks, which have no previous
    one, repeat the first value defined (no step that the filter would read as a jerk)."""
    x, y, yaw = (np.asarray(log[k], dtype=float) for k in ("x", "y", "yaw"))
    n = len(x)
    acc = np.zeros((n, 3))
    if n >= 3:
        vel = np.stack([np.diff(x), np.diff(y)], 1) / DT  # ticks 1..n-1
        acc[2:, :2] = np.diff(vel, axis=0) / DT
        acc[:2] = acc[2]
    rate = np.zeros((n, 3))
    if n >= 2:
        rate[1:, 2] = np.degrees((np.diff(yaw) + math.pi) % (2 * math.pi) - math.pi) / DT
        rate[0] = rate[1]
    zero = np.zeros(n)
    out = {"acceleration": acc, "angular_velocity": rate,
           "forward_vector": np.stack([np.cos(yaw), np.sin(yaw), zero], 1),
           "right_vector": np.stack([np.sin(yaw), -np.cos(yaw), zero], 1),
           "location": np.stack([x, y, zero], 1), "rotation": np.stack([zero, zero, np.degrees(yaw)], 1)}
    return {k: np.round(a.reshape(n, 3), _DIGITS[k]) + 0.0 for k, a in out.items()}  # + 0.0: no -0.0


def write_metric_info(path: Path, info: dict[str, np.ndarray]) -> None:
    """``path`` (…/<save_name>/metric_info.json) as Bench2Drive's agents write it: {step: {field: [x, y, z]}}."""
    n = len(info["location"])
    data = {str(k): {f: info[f][k].tolist() for f in FIELDS} for k in range(n)}
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, json.dumps(data))


# --- smoothness ----------------------------------------------------------------------------
def _unwrap(h: np.ndarray) -> np.ndarray:
    """nuPlan's phase unwrap (steps of 2 pi) along the last axis, applied as Bench2Drive
    applies it, to deg/s values."""
    adjust = np.zeros_like(h)
    adjust[..., 1:] = np.cumsum(np.round(np.diff(h, axis=-1) / (2 * math.pi)), axis=-1)
    return h - 2 * math.pi * adjust


@functools.lru_cache(maxsize=None)
def _savgol_matrix(n: int, deriv: int) -> np.ndarray:
    """(n, n) matrix S with S @ x = scipy's savgol_filter(x, min(WINDOW, n), ORDER, deriv,
    delta=DELTA) for any x of n samples (mode 'interp', the default Bench2Drive keeps;
    tests/test_bench2drive.py holds the two equal to 1e-12).

    Row i is the least-squares polynomial of degree ORDER through a window of w = min(WINDOW,
    n) samples, its deriv-th derivative read at sample i, per DELTA**deriv: the window
    centred on i, or, within w // 2 samples of an end, the first or last w samples (the
    'interp' edges). Written out in numpy: importing scipy.signal costs a worker 0.6 s."""
    w, half = min(WINDOW, n), min(WINDOW, n) // 2
    S = np.zeros((n, n))
    for i in range(n):
        start = 0 if i < half else n - w if i >= n - half else i - half
        t = np.arange(start, start + w) - i  # sample offsets from i
        fit = np.linalg.pinv(np.vander(t, ORDER + 1, increasing=True))  # (ORDER + 1, w): x -> coefficients
        S[i, start:start + w] = fit[deriv] * math.factorial(deriv) / DELTA ** deriv
    return S


def _all_inside(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(C,) bool: every sample of each row of x (C, n) strictly inside (lo, hi)."""
    return np.all((x > lo) & (x < hi), axis=-1)


def _comfortable_chunks(seg: dict[str, np.ndarray]) -> np.ndarray:
    """(C,) bool: whether every sample of each of C segments of n >= 3 samples (arrays
    (C, n, 3)) passes the six comfort bounds, each segment filtered on its own."""
    acc = seg["acceleration"][..., :2]
    n = acc.shape[1]
    smooth, slope = _savgol_matrix(n, 0), _savgol_matrix(n, 1)
    lon = np.einsum("cij,cij->ci", acc, seg["forward_vector"][..., :2])
    lat = np.einsum("cij,cij->ci", acc, seg["right_vector"][..., :2])
    mag = np.hypot(acc[..., 0], acc[..., 1])
    yaw_rate = _unwrap(seg["angular_velocity"][..., 2]) @ smooth.T
    lon, lat, mag = lon @ smooth.T, lat @ smooth.T, mag @ smooth.T
    jerk, lon_jerk = mag @ slope.T, lon @ slope.T
    return (_all_inside(lon, *LON_ACCEL) & _all_inside(lat, -LAT_ACCEL, LAT_ACCEL) & _all_inside(jerk, -JERK, JERK)
            & _all_inside(lon_jerk, -LON_JERK, LON_JERK) & _all_inside(yaw_rate, -YAW_ACCEL, YAW_ACCEL)
            & _all_inside(yaw_rate, -YAW_RATE, YAW_RATE))


def comfortable(seg: dict[str, np.ndarray]) -> bool:
    """Whether every sample of a segment (>= 3 samples) passes the six comfort bounds."""
    return bool(_comfortable_chunks({k: a[None] for k, a in seg.items()})[0])


def route_smoothness(info: dict[str, np.ndarray]) -> float | None:
    """Share of a route's comfortable 20-sample chunks (1.0 or 0.0 for a route of <= 20
    samples); None below 3 samples (Bench2Drive's tool stops on such a route). The chunks
    are filtered together, each on its own, as Bench2Drive filters them one by one."""
    n = len(info["location"])
    if n < ORDER + 1:
        return None
    if n <= CHUNK:
        return 1.0 if comfortable(info) else 0.0
    c = (n - CHUNK) // CHUNK + 1  # whole chunks; the samples after the last are not read
    chunks = _comfortable_chunks({k: a[:c * CHUNK].reshape(c, CHUNK, -1) for k, a in info.items()})
    return float(chunks.sum()) / c


# --- Bench2Drive's record keys -------------------------------------------------------------
def record_keys(route_id: str, repetition: int, town: str, scenario: str | None) -> dict:
    """Bench2Drive's extra record keys for a route run: its first scenario's name, no weather
    (null), the town, and save_name (the folder of its metric_info.json): Bench2Drive's
    ``<route>_<town>_<scenario>_<weather>_<start time>`` without the weather and the time,
    so that the same run gives the same files."""
    name = f"RouteScenario_{route_id}_rep{repetition}_{town}" + (f"_{scenario}" if scenario else "")
    return {"scenario_name": scenario, "weather_id": None, "save_name": name, "town_name": town}


__all__ = ["success", "success_rate", "route_efficiency", "mean_of", "metric_info", "write_metric_info",
           "comfortable", "route_smoothness", "record_keys"]
