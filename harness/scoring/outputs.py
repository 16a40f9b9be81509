"""The files of a run folder, written from the route records (atomically, every time).

    records.csv    one row per route run: status, DS, RC, IS, every infraction count,
                   outside-lanes %, Collision/km, km driven, times, stability metrics
                   (harness.scoring.records.CSV_FIELDS)
    summary.csv    per metric: the mean over route runs with a 95 % bootstrap interval
                   (2000 resamples of the routes, seeded: same records -> same file),
                   among them Bench2Drive's success rate [%], and the Leaderboard's
                   per-km infraction rates with theirs; rounded as results.json rounds
                   (rates 3 decimals, the rest 6)
    results.json   the Leaderboard 2.0 results file (``--checkpoint``), see harness.scoring.scores:
                   its records in route-run order, written as the leaderboard writes it
"""
from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Callable

import numpy as np

from files.atomic import write_atomic
from harness.scoring.bench2drive import success
from harness.scoring.infractions import KEYS
from harness.scoring.records import CSV_FIELDS, STABILITY, csv_row
from harness.scoring.scores import infraction_value, results, results_text

BOOTSTRAP = 2000  # resamples
BOOTSTRAP_SEED = 0
SCORE_DECIMALS, RATE_DECIMALS = 6, 3  # as results.json rounds scores and per-km rates
# the leaderboard's names of our sensor types, where it has one (its sensors_to_icons);
# the others keep ours in results.json's "sensors" (docs/scoring.md)
LEADERBOARD_SENSORS = {"speed": "carla_speedometer"}
COLLISION_KEYS = ("collisions_layout", "collisions_pedestrian", "collisions_vehicle")


def _sorted(records: list[dict]) -> list[dict]:
    return sorted(records, key=lambda r: (r["repetition"], int(r["route_id"]) if str(r["route_id"]).isdigit()
                                          else 0, str(r["route_id"])))


def _write_csv(path: Path, fieldnames, rows) -> None:
    """A CSV file with these columns (other keys of the row dicts left out), written whole,
    in UTF-8; text that is not (an agent's message holding undecodable bytes, which Python
    keeps as lone surrogates) is written with backslash escapes."""
    def write(tmp: Path) -> None:
        with open(tmp, "w", newline="", encoding="utf-8", errors="backslashreplace") as f:
            w = csv.DictWriter(f, fieldnames=fieldnames, extrasaction="ignore")
            w.writeheader()
            w.writerows(rows)
    write_atomic(path, write)


def write_records_csv(records: list[dict], path: Path) -> None:
    _write_csv(path, CSV_FIELDS, (csv_row({k: (v.splitlines()[0] if isinstance(v, str) and v else v)
                                           for k, v in r.items()}) for r in _sorted(records)))


def bootstrap(stat: Callable[[np.ndarray], np.ndarray], n: int,
              rng: np.random.Generator) -> tuple[float, float, float]:
    """(value, 2.5 %, 97.5 %) of a statistic of n route runs, the routes resampled with
    replacement BOOTSTRAP times. ``stat(idx)`` gives the statistic of each row of route
    indices ``idx`` (R, n): the value is that of the routes as they are (one row 0..n-1),
    the interval the percentiles of the finite resample values. The resamples are drawn one
    at a time, ``rng.integers(n, size=n)`` each."""
    value = float(stat(np.arange(n)[None])[0])
    if n < 2:
        return value, math.nan, math.nan
    draws = stat(np.stack([rng.integers(n, size=n) for _ in range(BOOTSTRAP)]))
    draws = draws[np.isfinite(draws)]
    if len(draws) == 0:
        return value, math.nan, math.nan
    return value, float(np.percentile(draws, 2.5)), float(np.percentile(draws, 97.5))


def _mean_of(values: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """The mean over the routes of each resample with NaN values left out, as np.nanmean
    takes it; NaN where no value is finite."""
    def stat(idx: np.ndarray) -> np.ndarray:
        drawn = values[idx]
        nan = np.isnan(drawn)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.sum(np.where(nan, 0.0, drawn), axis=1) / np.sum(~nan, axis=1)
        return np.where(np.isfinite(drawn).any(axis=1), mean, math.nan)
    return stat


def _percent_of(flags: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """The share [%] of the resample's route runs whose flag is set (success_rate)."""
    def stat(idx: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return 100.0 * flags[idx].sum(axis=1) / idx.shape[1]
    return stat


def _rate_of(counts: np.ndarray, km: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """Summed ``counts`` over summed ``km`` of each resample, NaN where no km: Collision/km as
    summed collisions over summed completed km, not a mean of per-route rates. The km are
    summed one route after another (as Python's ``sum`` adds them)."""
    def stat(idx: np.ndarray) -> np.ndarray:
        total = np.cumsum(km[idx], axis=1)[:, -1] if idx.shape[1] else np.zeros(len(idx))
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(total > 0, counts[idx].sum(axis=1) / total, math.nan)
    return stat


def success_rate(records: list[dict]) -> float:
    """Bench2Drive's success rate of route runs [%] (harness.scoring.bench2drive.success)."""
    return 100.0 * sum(success(r["lb"]) for r in records) / len(records) if records else math.nan


def summary_rows(records: list[dict], result: dict) -> list[dict]:
    """summary.csv's rows. The records are put in route order first: workers finish routes in
    an order that changes from run to run, and the bootstrap draws records by position."""
    records = _sorted(records)
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    n = len(records)

    def column(key: str) -> np.ndarray:
        return np.array([r[key] for r in records], dtype=float)

    successes = np.array([success(r["lb"]) for r in records], dtype=np.int64)
    collisions = np.array([sum(r[k] for k in COLLISION_KEYS) for r in records], dtype=np.int64)
    rows = []
    for name, stat in [("driving_score", _mean_of(column("ds"))), ("route_completion", _mean_of(column("rc"))),
                       ("infraction_penalty", _mean_of(column("is"))),
                       ("success_rate (%)", _percent_of(successes)),
                       ("collisions_per_km", _rate_of(collisions, column("km_driven"))),
                       *[(k, _mean_of(column(k))) for k in STABILITY]]:
        v, lo, hi = bootstrap(stat, n, rng)
        digits = RATE_DECIMALS if name == "collisions_per_km" else SCORE_DECIMALS
        rows.append({"metric": name, "value": _round(v, digits), "ci95_low": _round(lo, digits),
                     "ci95_high": _round(hi, digits), "routes": n})
    rates = result["_checkpoint"]["global_record"].get("infractions", {})
    intervals = _rate_intervals(records, rng) if rates else {}
    for k, v in rates.items():
        unit = "km" if k == "outside_route_lanes" else "per km"
        lo, hi = intervals.get(k, (math.nan, math.nan))
        rows.append({"metric": f"{k} ({unit})", "value": v, "ci95_low": _round(lo, RATE_DECIMALS),
                     "ci95_high": _round(hi, RATE_DECIMALS), "routes": n})
    return rows


def _round(x: float, digits: int) -> float:
    return round(x, digits) if math.isfinite(x) else x


def _rate_intervals(records: list[dict], rng: np.random.Generator) -> dict[str, tuple[float, float]]:
    """2.5 % and 97.5 % of each Leaderboard per-km infraction rate (results.json's global
    infractions: summed counts over summed km driven, at least 1 m; outside_route_lanes in
    km, undivided) over BOOTSTRAP resamples of the routes; NaN below 2 routes."""
    if len(records) < 2:
        return {}
    lb = [r["lb"] for r in records]
    km = np.array([r["meta"]["route_length"] / 1000 * r["scores"]["score_route"] / 100 for r in lb])
    idx = rng.integers(len(lb), size=(BOOTSTRAP, len(lb)))
    km_drawn = np.maximum(km[idx].sum(axis=1), 0.001)
    out = {}
    for k in KEYS:
        drawn = np.array([infraction_value(r, k) for r in lb], dtype=float)[idx].sum(axis=1)
        if k != "outside_route_lanes":
            drawn = drawn / km_drawn
        out[k] = (float(np.percentile(drawn, 2.5)), float(np.percentile(drawn, 97.5)))
    return out


def write_outputs(records: list[dict], total: int, out: Path, checkpoint: Path, sensors: list[str],
                  finished: bool, summary: bool = True) -> dict:
    """Write records.csv, results.json (at ``checkpoint``) and, if asked, summary.csv."""
    write_records_csv(records, out / "records.csv")
    lb = sorted((r["lb"] for r in records), key=lambda r: r["index"])
    result = results(lb, total, [LEADERBOARD_SENSORS.get(s, s) for s in sensors], finished)
    write_atomic(checkpoint, results_text(result))  # as the leaderboard writes it; no NaN
    if summary and records:
        _write_csv(out / "summary.csv", ["metric", "value", "ci95_low", "ci95_high", "routes"],
                   summary_rows(records, result))
    return result


__all__ = ["write_outputs", "write_records_csv", "summary_rows", "success_rate", "bootstrap"]
