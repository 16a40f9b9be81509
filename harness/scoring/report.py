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
        data = json.loads(res.read_text())
        g = data["_checkpoint"]["global_record"]["scores_mean"]
        out = {"DS": float(g["score_composed"]), "RC": float(g["score_route"]), "IS": float(g["score_penalty"])}
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, ValueError) as exc:
        raise ReportError(f"{res}: not a Leaderboard results file ({type(exc).__name__}: {exc})") from None
    if data.get("entry_status") != "Finished":  # DS counts routes not run as 0; the records hold only those run
        prog = data["_checkpoint"].get("progress")
        done = f"{prog[0]} of {prog[1]} route runs" if isinstance(prog, list) and len(prog) >= 2 else "progress unknown"
        raise ReportError(f"{folder}: the run is not finished ({done}): finish it with "
                          "'sumo-scimm eval ... --resume', or leave it out")
    rows = _records(rec)
    km = sum(r["km_driven"] for r in rows)
    coll = sum(r[k] for r in rows for k in COLLISIONS)
    out["Collision/km"] = coll / km if km > 0 else math.nan
    for key, _ in TABLE4:
        vals = np.array([r[key] for r in rows], dtype=float)
        out[key] = float(np.nanmean(vals)) if np.isfinite(vals).any() else math.nan
    return out


COLLISIONS = ("collisions_layout", "collisions_pedestrian", "collisions_vehicle")


def _records(path: Path) -> list[dict]:
    """The rows of a run's records.csv with the table's columns as numbers; ReportError if
    a column is missing or a value is not a number."""
    numeric = ("ds", "rc", "is", "km_driven", *COLLISIONS, *(k for k, _ in TABLE4))
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
        return [{**r, **{k: float(r[k]) for k in numeric}} for r in rows]
    except (KeyError, TypeError, ValueError, UnicodeDecodeError, csv.Error) as exc:
        raise ReportError(f"{path}: not a records.csv of 'sumo-scimm eval' ({type(exc).__name__}: {exc})") from None


def fig(x: float) -> str:
    """A table figure to 4 significant digits, so 0.00031 1/m reads as such, not 0.000."""
    return f"{x:.4g}"


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
            cells.append(fig(v) + ("" if r is rows[0] or not math.isfinite(c) else f" ({c:+.1f} %)"))
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


# --- several seeds per arm (sumo-scimm reproduce) ---------------------------------------
def _route_rows(folder: Path) -> dict[str, dict[str, float]]:
    """records.csv of a run as {route key: figures}, for the seed-and-route bootstrap."""
    load_run(folder)  # checks the folder
    return {r["key"]: {"DS": r["ds"], "RC": r["rc"], "IS": r["is"], "coll": sum(r[k] for k in COLLISIONS),
                       "km": r["km_driven"], **{k: r[k] for k, _ in TABLE4}} for r in _records(folder / "records.csv")}


def _figures(rows: list[dict[str, float]]) -> dict[str, float]:
    """Table 3 and 4 figures of a list of route rows (means; collisions per km over the sum)."""
    out = {k: float(np.mean([r[k] for r in rows])) for k in ("DS", "RC", "IS")}
    km = sum(r["km"] for r in rows)
    out["Collision/km"] = sum(r["coll"] for r in rows) / km if km > 0 else math.nan
    for key, _ in TABLE4:
        vals = np.array([r[key] for r in rows], dtype=float)
        out[key] = float(np.nanmean(vals)) if np.isfinite(vals).any() else math.nan
    return out


def arm_figures(folders: list[Path], n_boot: int = 2000, seed: int = 0) -> dict[str, tuple[float, float, float]]:
    """Mean over seeds (one run folder per seed) of every table figure, with a 95 % interval
    from a two-level bootstrap: resample the seeds, then the routes (the same routes for
    every seed of a draw). With one seed it is the bootstrap over routes.
    Returns {figure: (mean, low, high)}."""
    runs = [_route_rows(f) for f in folders]
    keys = sorted(set.intersection(*(set(r) for r in runs)))
    if not keys:
        raise ReportError(f"no route is in every run of {', '.join(map(str, folders))}")
    per_seed = [_figures([r[k] for k in keys]) for r in runs]
    rng = np.random.default_rng(seed)
    draws: dict[str, list[float]] = {k: [] for k in per_seed[0]}
    for _ in range(n_boot):
        seeds = rng.integers(0, len(runs), len(runs))
        routes = [keys[i] for i in rng.integers(0, len(keys), len(keys))]
        figs = [_figures([runs[s][k] for k in routes]) for s in seeds]
        for k in draws:
            draws[k].append(float(np.mean([f[k] for f in figs])))
    return {k: (float(np.mean([f[k] for f in per_seed])), float(np.nanpercentile(draws[k], 2.5)),
                float(np.nanpercentile(draws[k], 97.5))) for k in draws}


def write_arm_report(arms: dict[str, list[Path]], out: Path, n_boot: int = 2000) -> str:
    """Tables 3 and 4 for arms with several seeds each (the first arm is the baseline the
    relative change is computed against, as the paper does): CSV and Markdown in ``out``."""
    figs = {name: arm_figures(folders, n_boot) for name, folders in arms.items()}
    base = figs[next(iter(figs))]
    out.mkdir(parents=True, exist_ok=True)
    text = []
    for cols, stem, title in ((TABLE3, "table3", "Table 3: closed-loop driving performance"),
                              (TABLE4, "table4", "Table 4: temporal stability")):
        rows = []
        for name, f in figs.items():
            row: dict = {"arm": name, "seeds": len(arms[name])}
            for key, _ in cols:
                m, lo, hi = f[key]
                row.update({key: m, f"{key} ci95_low": lo, f"{key} ci95_high": hi,
                            f"{key} change %": _change(m, base[key][0])})
            rows.append(row)
        with open(out / f"{stem}.csv", "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
        lines = [f"### {title} (mean over seeds, 95 % interval, change against {rows[0]['arm']})", "",
                 "| arm | seeds | " + " | ".join(k for k, _ in cols) + " |", "|" + " --- |" * (len(cols) + 2)]
        for r in rows:
            cells = [f"{fig(r[k])} [{fig(r[k + ' ci95_low'])}, {fig(r[k + ' ci95_high'])}]"
                     + ("" if r is rows[0] or not math.isfinite(r[k + ' change %']) else f" ({r[k + ' change %']:+.1f} %)")
                     for k, _ in cols]
            lines.append(f"| {r['arm']} | {r['seeds']} | " + " | ".join(cells) + " |")
        md = "\n".join(lines)
        (out / f"{stem}.md").write_text(md + "\n")
        text.append(md)
    return "\n\n".join(text)
