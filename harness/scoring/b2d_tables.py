"""Bench2Drive's figures of several arms for ``sumo-scimm report`` (harness.scoring.report):

- ``b2d``: per arm, DS, Success Rate, Driving Efficiency and Driving Smoothness
  (harness.scoring.bench2drive), each the mean over the arm's runs, with a 95 % interval
  from a bootstrap over its route runs (2000 resamples, seeded; an arm's runs pooled);
- ``per_hazard``: per hazard type (a route's first hazard), each arm's success rate and
  mean DS over the route runs of that type, with their number.

Read from each run folder's records.jsonl. Records of a run made before a figure was in
them get it from what the folder holds: the success from the Leaderboard record, the
smoothness from the route's log, the efficiency from its minimum-speed messages if the run
was made with ``--rules b2d`` (its run.jsonc or run.json says; other rules log only the
checkpoints below 100 %, so it is left undefined); the hazard type is then unknown.
"""
from __future__ import annotations

import json
import math
import zipfile
from pathlib import Path

import numpy as np

from files.compressed import read_text, stored
from harness.common.errors import BadInput
from harness.scoring.bench2drive import mean_of, metric_info, route_efficiency, route_smoothness, success

BOOTSTRAP, SEED = 2000, 0
COLUMNS = (("DS", "driving score"), ("SR", "success rate [%]"), ("efficiency", "driving efficiency [%]"),
           ("smoothness", "driving smoothness [%]"))


RUN_FILES = ("run.jsonc", "run.json")  # what the run is (harness.runs.provenance), newer name first


def _rules(folder: Path) -> dict[str, str]:
    """{route run key: rules} from the run's identity file ({} if it has none)."""
    for name in RUN_FILES:
        try:
            runs = json.loads((folder / name).read_text())
            runs = runs.get("route_runs", runs)  # the oldest layout: the route runs alone
            return {k: r.get("rules", "") for k, r in runs.items() if isinstance(r, dict)}
        except (OSError, ValueError, AttributeError):
            continue
    return {}


def route_figures(folder: Path) -> list[dict]:
    """Per route run of a finished run folder: {"key", "hazard", "DS", "success", "efficiency",
    "smoothness"} (efficiency in %, None where the route has no checkpoint; smoothness in
    [0, 1], None below 3 ticks). BadInput for a file that cannot be read, a line that is not
    a route record (but a torn last line, cut short while it was written), a hazard type that
    is not text, or a file without a route record: the tables would miss its routes."""
    path = folder / "records.jsonl"
    try:
        text = read_text(path)
    except OSError as exc:
        raise BadInput(f"{path}: cannot be read ({type(exc).__name__}: {exc})") from None
    except UnicodeDecodeError as exc:
        raise BadInput(f"{path}: cannot be read ({type(exc).__name__}: {exc}): the file is damaged; move "
                       "records.jsonl away to report Tables 3 and 4 alone, or evaluate the run again") from None
    lines = text.split("\n")
    out, rules = [], None
    fix = ("delete that line and run 'sumo-scimm eval ... --resume' (its route runs again), or move "
           "records.jsonl away to report Tables 3 and 4 alone")
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            r = json.loads(line)
        except (json.JSONDecodeError, RecursionError) as exc:
            if i == len(lines) - 1:  # no newline after it
                continue  # a torn last line, cut short while it was written (as the runner reads it)
            raise BadInput(f"{path} line {i + 1} is not a JSON record ({type(exc).__name__}): the file is "
                           f"damaged; {fix}") from None
        missing = next((k for k in ("key", "lb") if k not in r), None) if isinstance(r, dict) else None
        if not isinstance(r, dict) or missing:
            what = f"has no {missing!r}" if isinstance(r, dict) else "is not a record"
            raise BadInput(f"{path} line {i + 1} {what}: the file is damaged; {fix}")
        if "hazard" in r and r["hazard"] is not None and not isinstance(r["hazard"], str):
            raise BadInput(f"{path} line {i + 1}: hazard is {str(r['hazard'])[:40]!r}, not a hazard type: the file "
                           f"is damaged; {fix}")
        try:
            if "efficiency" in r:
                eff = r["efficiency"]
            else:
                rules = _rules(folder) if rules is None else rules
                eff = (route_efficiency(r["lb"]["infractions"].get("min_speed_infractions", []))
                       if rules.get(r["key"]) == "b2d" else None)
            smooth = r["smoothness"] if "smoothness" in r else _smoothness_from_log(folder, r["key"])
            hazard = (r["hazard"] or "(no hazard)") if "hazard" in r else "unknown"
            out.append({"key": r["key"], "hazard": hazard, "DS": float(r["ds"]),
                        "success": success(r["lb"]), "efficiency": eff, "smoothness": smooth})
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise BadInput(f"{path}: not a records.jsonl of 'sumo-scimm eval' ({type(exc).__name__}: {exc})") from None
    if not out:
        raise BadInput(f"{path} holds no route record: the file is damaged; run 'sumo-scimm eval ... --resume' "
                       "to run its routes again, or move records.jsonl away to report Tables 3 and 4 alone")
    return out


def _smoothness_from_log(folder: Path, key: str) -> float | None:
    log = folder / "logs" / f"{key}.npz"
    if not log.is_file():
        return None
    try:
        with np.load(log, allow_pickle=False) as z:
            return route_smoothness(metric_info({k: z[k] for k in ("x", "y", "yaw", "v")}))
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise BadInput(f"{log}: not a log of 'sumo-scimm eval' ({type(exc).__name__}: {exc})") from None


def figures(routes: list[dict]) -> dict[str, float]:
    """The four figures of a list of route runs: DS mean, SR [%], efficiency [%] (mean over
    routes with a value), smoothness [%] (likewise)."""
    if not routes:
        return {k: math.nan for k, _ in COLUMNS}
    smooth = mean_of([r["smoothness"] for r in routes])
    return {"DS": float(np.mean([r["DS"] for r in routes])),
            "SR": 100.0 * sum(r["success"] for r in routes) / len(routes),
            "efficiency": mean_of([r["efficiency"] for r in routes]), "smoothness": 100.0 * smooth}


def _interval(routes: list[dict], rng: np.random.Generator) -> dict[str, tuple[float, float]]:
    """95 % percentile interval of each figure over route runs resampled with replacement."""
    if len(routes) < 2:
        return {k: (math.nan, math.nan) for k, _ in COLUMNS}
    draws = [figures([routes[i] for i in rng.integers(len(routes), size=len(routes))]) for _ in range(BOOTSTRAP)]
    out = {}
    for k, _ in COLUMNS:
        vals = np.array([d[k] for d in draws], dtype=float)
        vals = vals[np.isfinite(vals)]
        out[k] = (float(np.percentile(vals, 2.5)), float(np.percentile(vals, 97.5))) if len(vals) else (math.nan,) * 2
    return out


def _fmt(x: float) -> str:
    return f"{x:.1f}" if math.isfinite(x) else "-"


def without_records(arms: dict[str, list[Path]]) -> list[Path]:
    """The run folders of {arm: run folders} with no records.jsonl (plain or .gz; a table
    written by hand, an archive that keeps records.csv alone): the tables below need it."""
    return [f for folders in arms.values() for f in folders if not stored(f / "records.jsonl")]


def b2d_tables(arms: dict[str, list[Path]]) -> list[tuple[str, list[dict], str]]:
    """[(file stem, CSV rows, Markdown)] of the two tables (module docstring) for {arm: run
    folders}; none when a folder has no records.jsonl (``without_records``)."""
    if without_records(arms):
        return []
    runs = {name: [route_figures(f) for f in folders] for name, folders in arms.items()}
    rng = np.random.default_rng(SEED)
    rows, lines = [], ["### Bench2Drive's figures (mean over an arm's runs; 95 % interval over its route runs)", "",
                       "| arm | runs | route runs | " + " | ".join(label for _, label in COLUMNS) + " |",
                       "|" + " --- |" * (len(COLUMNS) + 3)]
    for name, per_run in runs.items():
        pooled = [r for run in per_run for r in run]
        means = {k: float(np.mean([figures(run)[k] for run in per_run])) for k, _ in COLUMNS}
        ci = _interval(pooled, rng)
        row = {"arm": name, "runs": len(per_run), "route_runs": len(pooled)}
        for k, _ in COLUMNS:
            row.update({k: means[k], f"{k} ci95_low": ci[k][0], f"{k} ci95_high": ci[k][1]})
        rows.append(row)
        cells = [f"{_fmt(means[k])} [{_fmt(ci[k][0])}, {_fmt(ci[k][1])}]" for k, _ in COLUMNS]
        lines.append(f"| {name} | {len(per_run)} | {len(pooled)} | " + " | ".join(cells) + " |")
    hazards = sorted({r["hazard"] for per_run in runs.values() for run in per_run for r in run})
    hrows, hlines = [], ["### Success rate [%] and DS per hazard type (route runs of an arm's runs pooled)", "",
                         "| hazard | " + " | ".join(f"{n} SR | {n} DS | {n} n" for n in runs) + " |",
                         "|" + " --- |" * (1 + 3 * len(runs))]
    for h in hazards:
        row, cells = {"hazard": h}, []
        for name, per_run in runs.items():
            of_type = [r for run in per_run for r in run if r["hazard"] == h]
            f = figures(of_type)
            row.update({f"{name} SR": f["SR"], f"{name} DS": f["DS"], f"{name} n": len(of_type)})
            cells += [_fmt(f["SR"]), _fmt(f["DS"]), str(len(of_type))]
        hrows.append(row)
        hlines.append(f"| {h} | " + " | ".join(cells) + " |")
    return [("b2d", rows, "\n".join(lines)), ("per_hazard", hrows, "\n".join(hlines))]


__all__ = ["b2d_tables", "figures", "route_figures"]
