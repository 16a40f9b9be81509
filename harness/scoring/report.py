"""``sumo-scimm report``: the paper's Table 3 (DS, RC, IS, Collision/km) and Table 4 (the
stability metrics of harness.scoring.stability) for several arms, as CSV and Markdown.

An arm is one run folder of ``sumo-scimm eval`` or several (its seeds, in seed order: ``report
baseline=runs/b_s0,runs/b_s1 scimm=runs/s_s0,runs/s_s1``; a bare folder is an arm of one
run named after the folder). The i-th folder of every arm is seed index i, and arms are
paired by seed index (a seed fixes a student's initialisation and data order in every arm).
The first arm given to ``compare`` is its reference (called "the baseline" below);
``sumo-scimm report`` (model.arm_tables) calls it once per reference arm, 'baseline' and
then 'control' where they run, else the first arm. For each figure (of a run: over its routes; Collision/km:
summed collisions over summed km):

- each arm's value: the mean over its runs, with a 95 % interval: Student t over the runs'
  figures with two or more runs, the percentile bootstrap over routes with one;
- each arm's difference from the baseline and its relative change, ``100 (x - x_baseline) /
  |x_baseline|`` % (the paper's), over the n seeds both arms have: with n >= 2 the mean of
  the per-seed differences with its Student t interval (n - 1 degrees of freedom), its
  two-sided p and the minimum detectable effect at 80 % power (harness.scoring.paired; the
  change's interval is the difference's over the baseline's mean on those seeds); with one
  seed, the route-paired bootstrap of that seed's two runs (every draw resamples the routes
  once for both: "one seed: route-to-route interval only") and its bootstrap p;
- the same tables again on the routes that every compared run completed (status Perfect or
  Completed), so arms are compared where all of them drove the whole route.

A figure is computed on the routes that are in every compared run and where it is defined
in every one of them (a stability metric is NaN for an agent that predicts nothing, or a
route without a moving tick), so the arms' figures are always over the same routes. The
bootstrap is seeded (BOOT_SEED): the same run folders give the same files.

Records of a run made before a stability column existed get it from the run's logs
(``logs/<key>.npz``), so older run folders can be compared by the current definitions.
"""
from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

import numpy as np

from files.compressed import read_text, stored
from harness.scoring import stability as stab
from harness.scoring.paired import bootstrap_p, mde, t_interval
from harness.scoring.statuses import COMPLETED, PERFECT

TABLE3 = (("DS", "driving score"), ("RC", "route completion [%]"), ("IS", "infraction penalty"),
          ("Collision/km", "collisions per km driven"))


def stability_figures(shows: str | None = None) -> tuple[tuple[str, str], ...]:
    """(column, heading) of the stability metrics (harness.scoring.stability.METRICS) that
    show in ``shows`` (stability.TABLE4: the main Table 4; stability.OTHER: its other
    readings); None: every metric, headed by its column (the CSV of Table 4)."""
    if shows is None:
        return tuple((m.key, m.key) for m in stab.METRICS)
    return tuple((m.key, m.heading) for m in stab.METRICS if m.shows == shows)


def stability_columns() -> tuple[str, ...]:
    """The records.csv columns of the stability metrics, in the registry's order."""
    return tuple(m.key for m in stab.METRICS)


COLLISIONS = ("collisions_layout", "collisions_pedestrian", "collisions_vehicle")
BOOTSTRAP, BOOT_SEED = 2000, 0  # resamples; seed of the route and run draws


ONE_SEED = "one seed: route-to-route interval only"
ARM_INTERVAL = ("Each arm: the mean over its runs (seeds) of the figure over the routes, with a 95 % interval: "
                "Student t over the runs' figures with two or more seeds, the bootstrap over routes with one.")
DIFF_INTERVAL = ("95 % interval from the per-seed differences (arm - reference on the same seed index), Student t "
                 "with n - 1 degrees of freedom over the n seeds both arms have; with one seed, the route-paired "
                 f"bootstrap ({ONE_SEED}).")


class ReportError(ValueError):
    pass


# --- reading run folders -----------------------------------------------------------------
def check_run(folder: Path) -> None:
    """ReportError unless ``folder`` is a finished run folder (results.json and records.csv,
    each plain or gzip-compressed: files.compressed)."""
    res, rec = folder / "results.json", folder / "records.csv"
    if stored(res) is None or stored(rec) is None:
        raise ReportError(f"{folder} is not a run folder (needs results.json and records.csv from 'sumo-scimm eval')")
    try:
        data = json.loads(read_text(res))
        prog = data["_checkpoint"].get("progress")
    except (OSError, json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ReportError(f"{res}: not a Leaderboard results file ({type(exc).__name__}: {exc})") from None
    # every route run done: Finished, or Crashed (a route's simulation crashed; the run went on)
    if data.get("entry_status") not in ("Finished", "Crashed") or not data["_checkpoint"].get("global_record"):
        done = f"{prog[0]} of {prog[1]} route runs" if isinstance(prog, list) and len(prog) >= 2 else "progress unknown"
        raise ReportError(f"{folder}: the run is not finished ({done}): finish it with "
                          "'sumo-scimm eval ... --resume', or leave it out")
    try:
        data["_checkpoint"]["global_record"]["scores_mean"]["score_composed"]
    except (KeyError, TypeError) as exc:
        raise ReportError(f"{res}: not a Leaderboard results file ({type(exc).__name__}: {exc})") from None
    from harness.scoring.validate import run_folder_problem  # a damaged folder: one line, not a table of nan
    damaged = run_folder_problem(folder)
    if damaged:
        raise ReportError(damaged)


def route_rows(folder: Path) -> dict[str, dict]:
    """A finished run's records as {route key: {"DS", "RC", "IS", "coll", "km", "status",
    <stability column>...}}; ReportError if a column is missing or not a number."""
    check_run(folder)
    path = folder / "records.csv"
    try:
        reader = csv.DictReader(io.StringIO(read_text(path), newline=""))
        rows = list(reader)
        header = set(reader.fieldnames or ())
        columns = stability_columns()
        missing = [k for k in columns if k not in header]
        out = {}
        for r in rows:
            values = {k: float(r[k]) for k in columns if k in header}
            if missing:
                values = {**_from_log(folder, r["key"], path, missing[0]), **values}
            out[r["key"]] = {"DS": float(r["ds"]), "RC": float(r["rc"]), "IS": float(r["is"]),
                             "coll": sum(float(r[k]) for k in COLLISIONS), "km": float(r["km_driven"]),
                             "status": r["status"], **values}
        return out
    except (OSError, KeyError, TypeError, ValueError, UnicodeDecodeError, csv.Error) as exc:
        raise ReportError(f"{path}: not a records.csv of 'sumo-scimm eval' ({type(exc).__name__}: {exc})") from None


def _from_log(folder: Path, key: str, path: Path, missing: str) -> dict[str, float]:
    """The stability metrics of route run ``key`` computed from its log (records.csv from
    before the column existed)."""
    log = folder / "logs" / f"{key}.npz"
    if not log.is_file():
        raise ReportError(f"{path} has no column {missing!r} and there is no log {log} to compute it "
                          "from: evaluate the run again with this sumo-scimm")
    try:
        with np.load(log, allow_pickle=False) as z:
            return stab.stability({k: z[k] for k in ("v", "steer", "throttle", "brake", "pred_path", "pred_speed_wps")})
    except (OSError, ValueError, KeyError) as exc:
        raise ReportError(f"{log}: not a log of 'sumo-scimm eval' ({type(exc).__name__}: {exc})") from None


def parse_arms(specs: list[str]) -> dict[str, list[Path]]:
    """``NAME=DIR[,DIR...]`` or ``DIR`` per item -> {arm name: run folders}, in order; a
    bare folder is named after it (a repeated name gets a prime)."""
    arms: dict[str, list[Path]] = {}
    for spec in specs:
        name, sep, dirs = spec.partition("=")
        if sep and not (name and dirs and all(dirs.split(","))):
            raise ReportError(f"{spec!r}: an arm is NAME=DIR[,DIR...] or a run folder")
        folders = [Path(d) for d in dirs.split(",")] if sep else [Path(spec)]
        name = name if sep else (folders[0].name or spec)
        while name in arms:
            name += "'"
        arms[name] = folders
    if not arms:
        raise ReportError("no run folder given")
    return arms


# --- figures and their bootstrap ------------------------------------------------------------
def _values(runs: list[dict[str, dict]], keys: list[str], figure: str) -> np.ndarray:
    """(S, R) per-route values (Collision/km: (2, S, R) collisions and km) of S runs, R keys."""
    if figure == "Collision/km":
        return np.array([[[run[k]["coll"] for k in keys] for run in runs], [[run[k]["km"] for k in keys] for run in runs]])
    return np.array([[run[k][figure] for k in keys] for run in runs], dtype=float)


def _stat(vals: np.ndarray, figure: str, routes: np.ndarray) -> np.ndarray:
    """The figure of every run for every route draw: routes (B, R) indices -> (S, B)."""
    if figure == "Collision/km":
        coll, km = vals[0][:, routes].sum(axis=2), vals[1][:, routes].sum(axis=2)
        return np.divide(coll, km, out=np.full(coll.shape, np.nan), where=km > 0)
    return vals[:, routes].mean(axis=2)


def compare(arms: dict[str, list[dict[str, dict]]], figures, keys: list[str] | None = None,
            n_boot: int = BOOTSTRAP, seed: int = BOOT_SEED,
            seeds: dict[str, list] | None = None) -> dict[str, dict[str, dict]]:
    """{arm: {figure: {"value", "low", "high", "diff", "diff_low", "diff_high", "change",
    "change_low", "change_high", "p", "mde", "seeds", "routes"}}} for arms given as lists of
    route rows (one dict per run, module docstring); the first arm is the baseline (its
    differences are 0, its p and mde NaN). ``keys``: the routes to use (default: those in
    every run). ``seeds``: each arm's seed index of each run (default: the run's place in
    its list); an arm is paired with the baseline on the seeds both have (``seeds``: how
    many): two or more, the seed-paired t interval, p and minimum detectable effect
    (harness.scoring.paired); one, the route-paired bootstrap of that seed's two runs (one
    seed: route-to-route interval only; mde NaN)."""
    runs = [r for rs in arms.values() for r in rs]
    common = set.intersection(*(set(r) for r in runs))
    keys = sorted(common if keys is None else common & set(keys))
    seeds = {name: list(seeds[name]) if seeds else list(range(len(rs))) for name, rs in arms.items()}
    out: dict[str, dict[str, dict]] = {name: {} for name in arms}
    for f_index, (figure, _) in enumerate(figures):
        use = [k for k in keys if figure == "Collision/km" or all(math.isfinite(r[k][figure]) for r in runs)]
        for name in arms:
            out[name][figure] = {"routes": len(use)}
        if not use:
            for name in arms:
                out[name][figure].update(dict.fromkeys(FIELDS, math.nan), seeds=0)
            continue
        rng = np.random.default_rng([seed, f_index])
        routes = rng.integers(0, len(use), size=(n_boot, len(use)))  # one route draw for every arm
        everything = np.arange(len(use))[None]
        per_seed, per_draw, draws = {}, {}, {}
        for name, rs in arms.items():
            vals = _values(rs, use, figure)
            per_seed[name] = _stat(vals, figure, everything)[:, 0]  # (S,) each run over every route
            per_draw[name] = _stat(vals, figure, routes)  # (S, B)
            picks = rng.integers(0, len(rs), size=(n_boot, len(rs)))  # the arm's runs, resampled per draw
            draws[name] = per_draw[name][picks, np.arange(n_boot)[:, None]].mean(axis=1)  # (B,)
        base = next(iter(arms))
        for name in arms:
            value = float(per_seed[name].mean())
            if len(per_seed[name]) > 1:
                _, low, high, _ = t_interval(per_seed[name])
            else:
                low, high = _pct(draws[name], 2.5), _pct(draws[name], 97.5)
            out[name][figure].update(value=value, low=low, high=high,
                                     **_difference(per_seed, per_draw, seeds, name, base))
    return out


FIELDS = ("value", "low", "high", "diff", "diff_low", "diff_high", "change", "change_low", "change_high", "p", "mde")


def _difference(per_seed: dict, per_draw: dict, seeds: dict, name: str, base: str) -> dict:
    """The difference fields of arm ``name`` against ``base`` (``compare``) from each arm's
    per-seed values (S,) and per-route-draw values (S, B)."""
    pairs = [(i, seeds[base].index(s)) for i, s in enumerate(seeds[name]) if s in seeds[base]]
    nan = dict.fromkeys(("diff", "diff_low", "diff_high", "change", "change_low", "change_high", "p", "mde"), math.nan)
    if not pairs:
        return {**nan, "seeds": 0}
    ia, ib = (np.array(x) for x in zip(*pairs))
    ref = float(per_seed[base][ib].mean())
    if name == base:
        zero = 0.0 if ref != 0 else math.nan  # no relative change from a zero baseline
        return {**nan, "diff": 0.0, "diff_low": 0.0, "diff_high": 0.0, "change": zero, "change_low": zero,
                "change_high": zero, "seeds": len(pairs)}
    if len(pairs) > 1:
        d = per_seed[name][ia] - per_seed[base][ib]
        diff, lo, hi, p = t_interval(d)
        scale = 100.0 / abs(ref) if ref != 0 else math.nan
        return {"diff": diff, "diff_low": lo, "diff_high": hi, "change": diff * scale, "change_low": lo * scale,
                "change_high": hi * scale, "p": p, "mde": mde(d), "seeds": len(pairs)}
    d = per_draw[name][ia[0]] - per_draw[base][ib[0]]  # (B,) one seed: route-paired draws
    with np.errstate(divide="ignore", invalid="ignore"):
        c = 100.0 * d / np.abs(per_draw[base][ib[0]])
    diff = float(per_seed[name][ia[0]] - per_seed[base][ib[0]])
    return {"diff": diff, "diff_low": _pct(d, 2.5), "diff_high": _pct(d, 97.5),
            "change": 100.0 * diff / abs(ref) if ref != 0 else math.nan,
            "change_low": _pct(c, 2.5), "change_high": _pct(c, 97.5), "p": bootstrap_p(d), "mde": math.nan,
            "seeds": 1}


def _pct(x: np.ndarray, q: float) -> float:
    x = x[np.isfinite(x)]
    return float(np.percentile(x, q)) if len(x) else math.nan


def completed_keys(runs: list[dict[str, dict]]) -> list[str]:
    """The routes that every run completed (status Perfect or Completed)."""
    return sorted(k for k in set.intersection(*(set(r) for r in runs))
                  if all(r[k]["status"] in (PERFECT, COMPLETED) for r in runs))


# --- tables ----------------------------------------------------------------------------------
def fig(x: float) -> str:
    """A table figure to 4 significant digits, so 0.00031 1/m reads as such, not 0.000."""
    return f"{x:.4g}"


def _interval(lo: float, hi: float) -> str:
    return f"[{fig(lo)}, {fig(hi)}]" if math.isfinite(lo) and math.isfinite(hi) else "[-]"


def csv_rows(result: dict, arms: dict, figures) -> list[dict]:
    """One CSV row per arm: runs, then per figure its value, interval, difference and change."""
    rows = []
    for name, figs in result.items():
        row: dict = {"arm": name, "runs": len(arms[name])}
        for key, _ in figures:
            f = figs[key]
            row.update({key: f["value"], f"{key} ci95_low": f["low"], f"{key} ci95_high": f["high"],
                        f"{key} diff": f["diff"], f"{key} diff ci95_low": f["diff_low"],
                        f"{key} diff ci95_high": f["diff_high"], f"{key} change %": f["change"],
                        f"{key} change % ci95_low": f["change_low"], f"{key} change % ci95_high": f["change_high"],
                        f"{key} diff p": f["p"], f"{key} diff mde80": f["mde"], f"{key} seeds": f["seeds"],
                        f"{key} routes": f["routes"]})
        rows.append(row)
    return rows


def markdown(result: dict, arms: dict, figures, title: str) -> str:
    """Two Markdown tables: each arm's mean with its interval, then each arm's difference from
    the first with its paired interval and relative change; a line says on how many routes."""
    names = list(result)
    head = " | ".join(label for _, label in figures)
    lines = [f"### {title}", "", f"| arm | runs | {head} |", "|" + " --- |" * (len(figures) + 2)]
    for name in names:
        cells = [f"{fig(result[name][k]['value'])} {_interval(result[name][k]['low'], result[name][k]['high'])}"
                 if math.isfinite(result[name][k]["value"]) else "-" for k, _ in figures]
        lines.append(f"| {name} | {len(arms[name])} | " + " | ".join(cells) + " |")
    lines += ["", ARM_INTERVAL]
    if len(names) > 1:
        lines += ["", f"Difference from {names[0]}, its relative change and, with two or more seeds, the minimum "
                  f"detectable effect (MDE) at 80 % power: {DIFF_INTERVAL}", "",
                  f"| arm | seeds paired | {head} |", "|" + " --- |" * (len(figures) + 2)]
        for name in names[1:]:
            cells = []
            for k, _ in figures:
                f = result[name][k]
                change = f" ({f['change']:+.1f} % {_interval(f['change_low'], f['change_high'])})" \
                    if math.isfinite(f["change"]) else ""
                size = f", MDE {fig(f['mde'])}" if math.isfinite(f["mde"]) else ""
                cells.append(f"{f['diff']:+.4g} {_interval(f['diff_low'], f['diff_high'])}{change}{size}"
                             if math.isfinite(f["diff"]) else "-")
            n = max(result[name][k]["seeds"] for k, _ in figures)
            lines.append(f"| {name} | {n}{' (' + ONE_SEED + ')' if n == 1 else ''} | " + " | ".join(cells) + " |")
    counts = sorted({result[names[0]][k]["routes"] for k, _ in figures})
    per = "; ".join(f"{label}: {result[names[0]][k]['routes']}" for k, label in figures)
    lines += ["", f"Routes: {counts[0]}" if len(counts) == 1 else f"Routes per column: {per}"]
    return "\n".join(lines)


def _write_csv(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def tables(arms: dict[str, list[Path]], n_boot: int = BOOTSTRAP,
           seeds: dict[str, list] | None = None) -> list[tuple[str, list[dict], str]]:
    """[(file stem, CSV rows, Markdown)] of Tables 3 and 4, on every route and on the routes
    every run completed; ``seeds``: each arm's seed index of each folder (``compare``);
    ReportError for a folder that is not a finished run."""
    loaded = {name: [route_rows(f) for f in folders] for name, folders in arms.items()}
    everyone = [r for rs in loaded.values() for r in rs]
    if not set.intersection(*(set(r) for r in everyone)):
        raise ReportError(f"no route is in every run of {', '.join(str(f) for fs in arms.values() for f in fs)}")
    done = completed_keys(everyone)
    out = []
    for suffix, keys, where in (("", None, "every route"), ("_common", done, f"the {len(done)} routes every run completed")):
        t3 = compare(loaded, TABLE3, keys, n_boot, seeds=seeds)
        t4 = compare(loaded, stability_figures(), keys, n_boot, seeds=seeds)
        md4 = (markdown(t4, arms, stability_figures(stab.TABLE4), f"Table 4: temporal stability on moving ticks ({where})")
               + "\n\n" + markdown(t4, arms, stability_figures(stab.OTHER), f"Table 4, other readings ({where})"))
        out += [(f"table3{suffix}", csv_rows(t3, arms, TABLE3),
                 markdown(t3, arms, TABLE3, f"Table 3: closed-loop driving performance ({where})")),
                (f"table4{suffix}", csv_rows(t4, arms, stability_figures()), md4)]
    return out


def write_report(arms: dict[str, list[Path]] | list[Path], out: Path, n_boot: int = BOOTSTRAP) -> str:
    """Tables 3 and 4 (module docstring) as ``out/table{3,4}[_common].{csv,md}``; returns the
    Markdown. ``arms``: {name: run folders}, or a list of run folders (an arm each). Nothing
    is written when a folder is refused."""
    if not isinstance(arms, dict):
        arms = parse_arms([str(f) for f in arms])
    from harness.scoring.b2d_tables import b2d_tables  # Bench2Drive's SR, efficiency, smoothness; per hazard
    made = tables(arms, n_boot) + b2d_tables(arms)
    out.mkdir(parents=True, exist_ok=True)
    for stem, rows, md in made:
        _write_csv(out / f"{stem}.csv", rows)
        (out / f"{stem}.md").write_text(md + "\n")
    return "\n\n".join(md for _, _, md in made)


def arm_figures(folders: list[Path], n_boot: int = BOOTSTRAP, seed: int = BOOT_SEED) -> dict[str, tuple[float, float, float]]:
    """{figure: (mean over the runs, 2.5 %, 97.5 %)} of one arm's runs (its seeds), every
    figure of Tables 3 and 4 (the arm's interval of the module docstring)."""
    result = compare({"arm": [route_rows(f) for f in folders]}, (*TABLE3, *stability_figures()), None, n_boot, seed)["arm"]
    return {k: (v["value"], v["low"], v["high"]) for k, v in result.items()}
