"""``sumo-scimm report DIR...``: the paper's Table 3 (DS, RC, IS, Collision/km) and
Table 4 (steering jerk, longitudinal jerk, curvature variation, speed variation) for
several run folders, each row with its relative change against the first run,
``100 * (x - x_first) / |x_first|`` %, as CSV and Markdown.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

TABLE3 = (("DS", "driving score"), ("RC", "route completion"), ("IS", "infraction penalty"),
          ("Collision/km", "collisions per km driven"))
TABLE4 = (("steering_jerk", "steering jerk [1/s^2]"), ("longitudinal_jerk", "longitudinal jerk [1/s^2]"),
          ("curvature_variation", "curvature variation [1/m]"), ("speed_variation", "speed variation [m/s]"))


class ReportError(ValueError):
    pass


def load_run(folder: Path) -> dict[str, float]:
    """Table figures of one run folder (results.json and records.csv)."""
    res, rec = folder / "results.json", folder / "records.csv"
    if not res.is_file() or not rec.is_file():
        raise ReportError(f"{folder} is not a run folder (needs results.json and records.csv from 'sumo-scimm eval')")
    try:
        g = json.loads(res.read_text())["_checkpoint"]["global_record"]["scores_mean"]
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ReportError(f"{res}: not a Leaderboard results file ({exc})") from None
    with open(rec, newline="") as f:
        rows = list(csv.DictReader(f))
    km = sum(float(r["km_driven"]) for r in rows)
    coll = sum(int(r[k]) for r in rows for k in ("collisions_layout", "collisions_pedestrian", "collisions_vehicle"))
    out = {"DS": g["score_composed"], "RC": g["score_route"], "IS": g["score_penalty"],
           "Collision/km": coll / km if km > 0 else math.nan}
    for key, _ in TABLE4:
        vals = np.array([float(r[key]) for r in rows], dtype=float)
        out[key] = float(np.nanmean(vals)) if np.isfinite(vals).any() else math.nan
    return out


def _change(x: float, base: float) -> float:
    return 100.0 * (x - base) / abs(base) if base not in (0.0,) and math.isfinite(base) else math.nan


def table(runs: dict[str, dict[str, float]], columns) -> list[dict]:
    names = list(runs)
    base = runs[names[0]]
    rows = []
    for name in names:
        row = {"run": name}
        for key, _ in columns:
            row[key] = runs[name][key]
            row[f"{key} change %"] = _change(runs[name][key], base[key])
        rows.append(row)
    return rows


def markdown(rows: list[dict], columns, title: str) -> str:
    head = "| run | " + " | ".join(f"{k} (change)" for k, _ in columns) + " |"
    lines = [f"### {title}", "", head, "|" + " --- |" * (len(columns) + 1)]
    for r in rows:
        cells = []
        for key, _ in columns:
            v, c = r[key], r[f"{key} change %"]
            cells.append(f"{v:.3f}" + ("" if r is rows[0] or not math.isfinite(c) else f" ({c:+.1f} %)"))
        lines.append(f"| {r['run']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_report(folders: list[Path], out: Path) -> str:
    runs = {}
    for f in folders:
        name = f.name or str(f)
        while name in runs:
            name += "'"
        runs[name] = load_run(f)
    out.mkdir(parents=True, exist_ok=True)
    text = []
    for cols, stem, title in ((TABLE3, "table3", "Table 3: closed-loop driving performance"),
                              (TABLE4, "table4", "Table 4: temporal stability")):
        rows = table(runs, cols)
        with open(out / f"{stem}.csv", "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
        md = markdown(rows, cols, title)
        (out / f"{stem}.md").write_text(md + "\n")
        text.append(md)
    return "\n\n".join(text)
