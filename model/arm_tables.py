"""The tables of ``sumo-scimm reproduce`` that compare its arms (model.reproduce):

- Tables 3 and 4 with seed-paired 95 % intervals against each reference arm (the baseline,
  then the loss-matched control), on every route and on the routes every run completed
  (harness.scoring.report; the files of the first reference have no suffix, the others
  ``_vs_<reference>``);
- the paper's claims (``paper_claims``: teacher arm higher DS, lower Collision/km, lower each
  Table 4 metric of harness.scoring.stability.METRICS), one verdict each from an arm's
  seed-paired difference from a reference and its p, Holm-corrected over the table
  (``verdict``), with the paper's size beside ours (``size_agreement``);
- the DS of each hazard type, the arms side by side (``hazard_ds``);
- the arms ranked by mean DS on each evaluation set, the sets side by side (``ranking``);
- the stage wall times, one row per stage and per arm and seed (``stage_table``, ``train_seconds``).
"""
from __future__ import annotations

import csv
import io
import math
import os
import re
import shutil
import tempfile
from pathlib import Path

from harness.scoring import stability
from harness.scoring.paired import ALPHA, holm
from harness.scoring.report import fig, tables

# the paper's Table 3 claims on a teacher arm against a reference: (column, label, better
# direction, the paper's values of its arms stability.PAPER_ARMS)
TABLE3_CLAIMS = (("DS", "DS higher", "higher", (58.70, 71.82, 75.11)),
                 ("Collision/km", "Collision/km lower", "lower", (5.055, 2.042, 1.908)))
REPRODUCED, NOT_REPRODUCED, UNDECIDED, NO_INTERVAL = "reproduced", "not reproduced", "undecided", "no interval"
AGREES, DIFFERS = "agrees", "differs"


def paper_claims() -> tuple[tuple[str, str, str, tuple | None], ...]:
    """The paper's claims on a teacher arm against a reference, (column, label, better
    direction, the paper's values of stability.PAPER_ARMS or None): TABLE3_CLAIMS, then every
    stability metric of the paper's Table 4 (harness.scoring.stability.METRICS, shown in
    TABLE4) in its better direction."""
    table4 = tuple((m.key, f"{m.label} {m.better}", m.better, m.paper)
                   for m in stability.METRICS if m.shows == stability.TABLE4)
    return (*TABLE3_CLAIMS, *table4)


def verdict(diff: float, p_holm: float, better: str, alpha: float = ALPHA) -> str:
    """A paper claim's verdict from an arm's difference from a reference (arm - reference)
    and its Holm-adjusted p over the family of claims: ``reproduced`` if p_holm < alpha and
    the difference lies on the side ``better`` ("higher" or "lower") says, ``not reproduced``
    if p_holm < alpha on the other side, ``undecided`` otherwise, ``no interval`` if the
    difference or p is not finite."""
    if better not in ("higher", "lower"):
        raise ValueError(f"better must be 'higher' or 'lower', got {better!r}")
    if not (math.isfinite(diff) and math.isfinite(p_holm)):
        return NO_INTERVAL
    if p_holm >= alpha or diff == 0:
        return UNDECIDED
    return REPRODUCED if (diff > 0) == (better == "higher") else NOT_REPRODUCED


def paper_change(paper: tuple | None, arm: str, ref: str) -> float:
    """The paper's relative change of a figure, 100 (x_arm - x_ref) / |x_ref| [%], from its
    values of stability.PAPER_ARMS; NaN if the paper has no such pair or value."""
    arms = stability.PAPER_ARMS
    if paper is None or arm not in arms or ref not in arms:
        return math.nan
    x, x_ref = paper[arms.index(arm)], paper[arms.index(ref)]
    return 100.0 * (x - x_ref) / abs(x_ref)


def size_agreement(paper: float, low: float, high: float) -> str:
    """Whether the paper's relative change ``paper`` [%] lies in our 95 % interval [low,
    high] of the relative change (AGREES, DIFFERS), "" where either is not finite. The
    relative change is compared because the absolute scales of CARLA and our SUMO town differ."""
    if not all(math.isfinite(v) for v in (paper, low, high)):
        return ""
    return AGREES if low <= paper <= high else DIFFERS


def _csv_text(rows: list[dict]) -> str:
    """CSV rows as the text of a .csv file (a header from the first row's columns)."""
    buf = io.StringIO(newline="")
    w = csv.DictWriter(buf, fieldnames=list(rows[0]))
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def _table_files(stem: str, csv_rows: list[dict], md: str) -> dict[str, str]:
    """{file name: text} of a table: ``stem.csv`` (if it has rows) and ``stem.md``."""
    return {**({f"{stem}.csv": _csv_text(csv_rows)} if csv_rows else {}), f"{stem}.md": md + "\n"}


def write_all(out: Path, files: dict[str, str]) -> None:
    """Write every file of {name: text} into ``out``, all or none: each is written into a
    temporary folder in ``out`` first, and only when all are there are they renamed into
    place (stops held meanwhile: files.atomic.signals_held). A write that fails (a full
    disk) leaves ``out`` as it was and raises an OSError naming the file meant; only a
    rename that fails (a folder in the way of a table) can leave the tables before it
    renamed."""
    from files.atomic import signals_held
    out.mkdir(parents=True, exist_ok=True)
    try:
        stage = Path(tempfile.mkdtemp(prefix=".tables.tmp", dir=out))
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror or str(exc), str(out)) from exc
    name = ""
    try:
        for name, text in files.items():
            with open(stage / name, "w", newline="") as fh:
                fh.write(text)
        with signals_held():
            for name in files:
                os.replace(stage / name, out / name)
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror or str(exc), str(out / name)) from exc
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def references(arms: list[str]) -> list[str]:
    """The reference arms present: the baseline and the loss-matched control, in this order
    (the first arm if neither runs)."""
    refs = [a for a in ("baseline", "control") if a in arms]
    return refs or arms[:1]


def paired_tables(runs: dict[str, list[Path]], seeds: dict[str, list[int]] | None = None
                  ) -> tuple[str, dict[str, dict[str, list[dict]]], dict[str, str]]:
    """Tables 3 and 4 against every reference (module docstring): their Markdown, {reference:
    {table stem: CSV rows}} and their files {name: text}; nothing is written. ``seeds``:
    each arm's seed index of each run (default: the run's place in its list); arms are
    paired by it."""
    texts, rows, files = [], {}, {}
    for i, ref in enumerate(references(list(runs))):
        ordered = {ref: runs[ref], **{a: f for a, f in runs.items() if a != ref}}
        suffix = "" if i == 0 else f"_vs_{ref}"
        texts.append(f"## Against the {ref} (seed-paired intervals: arm - {ref})")
        rows[ref] = {}
        for stem, csv_rows, md in tables(ordered, seeds=seeds):
            files.update(_table_files(f"{stem}{suffix}", csv_rows, md))
            texts.append(md)
            rows[ref][stem] = csv_rows
    return "\n\n".join(texts), rows, files


def claims(rows: dict[str, dict[str, list[dict]]], common: bool = False) -> tuple[list[dict], str]:
    """The verdict of every paper claim (``paper_claims``) for every arm against every
    reference, from Tables 3 and 4 of ``paired_tables`` (on every route, or with ``common``
    on the routes every run completed). The family of the Holm correction is every claim of
    the table (arms x references x claims). CSV rows and a Markdown table whose cells read
    ``difference [95 % interval], MDE, Holm p: verdict``, then the paper's relative change and
    whether it lies in our interval of the relative change where the paper has the pair."""
    where = "the routes every run completed" if common else "every route"
    family = paper_claims()
    refs, found = list(rows), []
    for ref, stems in rows.items():
        by_arm: dict[str, dict] = {}
        for stem in ("table3_common", "table4_common") if common else ("table3", "table4"):
            for r in stems[stem]:
                by_arm.setdefault(r["arm"], {}).update(r)
        found += [(arm, ref, r) for arm, r in by_arm.items()
                  if arm != ref and arm not in refs[:refs.index(ref)]]  # a reference against a later one: the reverse
    adjusted = iter(holm([float(r[f"{key} diff p"]) for _, _, r in found for key, *_ in family]))
    out, lines = [], [f"### The paper's claims ({where}; arm - reference, seed-paired 95 % interval, MDE at 80 % "
                      "power, Holm-adjusted p)", "",
                      "| arm | against | " + " | ".join(label for _, label, *_ in family) + " |",
                      "|" + " --- |" * (len(family) + 2)]
    for arm, ref, r in found:
        row, cells = {"arm": arm, "against": ref}, []
        for key, _, better, paper in family:
            d, lo, hi, m = (float(r[f"{key} {c}"]) for c in ("diff", "diff ci95_low", "diff ci95_high", "diff mde80"))
            p, p_holm = float(r[f"{key} diff p"]), next(adjusted)
            v = verdict(d, p_holm, better)
            pc = paper_change(paper, arm, ref)
            cl, ch = float(r[f"{key} change % ci95_low"]), float(r[f"{key} change % ci95_high"])
            size = size_agreement(pc, cl, ch)
            row.update({f"{key} diff": d, f"{key} diff ci95_low": lo, f"{key} diff ci95_high": hi, f"{key} mde80": m,
                        f"{key} seeds": r[f"{key} seeds"], f"{key} p": p, f"{key} p holm": p_holm, key: v,
                        f"{key} paper change %": pc, f"{key} size": size})
            cell = v if not math.isfinite(d) else (
                f"{d:+.4g} [{fig(lo)}, {fig(hi)}]" + (f", MDE {fig(m)}" if math.isfinite(m) else "")
                + f", p {p_holm:.2g}: {v}")
            if size:
                cell += f"; paper {pc:+.1f} %, ours [{cl:+.1f}, {ch:+.1f}] %: size {size}"
            cells.append(cell)
        out.append(row)
        lines.append(f"| {arm} | {ref} | " + " | ".join(cells) + " |")
    lines += ["", f"Family: the {len(found) * len(family)} claims of this table, Holm's correction at alpha "
              f"{ALPHA} (p: the Holm-adjusted p). {REPRODUCED}: adjusted p < {ALPHA} in the paper's direction; "
              f"{NOT_REPRODUCED}: adjusted p < {ALPHA} against it; {UNDECIDED}: neither. Size: the paper's "
              f"relative change against our 95 % interval of it ({AGREES}: inside). MDE: the smallest "
              "difference these seeds detect with 80 % power (none with one seed: route-to-route interval only)."]
    return out, "\n".join(lines)


def hazard_ds(per_hazard: list[dict], arms: list[str]) -> str:
    """DS per hazard type (a route's first hazard), the arms side by side, from the rows of
    the ``per_hazard`` table of harness.scoring.b2d_tables; ``n``: route runs of the type per arm."""
    lines = ["### DS per hazard type (route runs of an arm's seeds pooled)", "",
             "| hazard | n | " + " | ".join(arms) + " |", "|" + " --- |" * (len(arms) + 2)]
    for r in per_hazard:
        counts = sorted({r[f"{a} n"] for a in arms})
        n = str(counts[0]) if len(counts) == 1 else "/".join(str(r[f"{a} n"]) for a in arms)
        cells = [f"{r[f'{a} DS']:.1f}" if math.isfinite(r[f"{a} DS"]) else "-" for a in arms]
        lines.append(f"| {r['hazard']} | {n} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def ranking(ds: dict[str, dict[str, float]]) -> str:
    """The arms ranked by mean DS on each evaluation set, the sets side by side: ``ds`` is
    {set: {arm: mean DS}}; rank 1 is the highest DS, equal DS share the better rank; rows in
    the first set's order of rank (then name), an arm missing on a set shows ``-``."""
    sets = list(ds)
    arms = sorted({a for v in ds.values() for a in v}, key=lambda a: (-ds[sets[0]].get(a, -math.inf), a))
    lines = ["### Arms ranked by mean DS on each evaluation set", "",
             "| arm | " + " | ".join(f"{s} DS | {s} rank" for s in sets) + " |", "|" + " --- |" * (2 * len(sets) + 1)]
    for arm in arms:
        cells = []
        for s in sets:
            if arm in ds[s] and math.isfinite(ds[s][arm]):
                rank = 1 + sum(v > ds[s][arm] for v in ds[s].values() if math.isfinite(v))
                cells += [f"{ds[s][arm]:.2f}", str(rank)]
            else:
                cells += ["-", "-"]
        lines.append(f"| {arm} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def stage_table(times: dict[str, float], arms: list[str], seeds: list[int], main: str, second: str | None) -> str:
    """Stage wall times [s] as Markdown: the shared stages (collect, teachers, trainings side
    by side, tables, figures) one a row, then one row per arm and seed with its training
    (``train_seconds``) and its evaluation on the main set (``main``) and the second
    (``second``, None: none), then the total of every stage in ``times``."""
    sets = [(main, None)] + ([(second, second)] if second else [])
    per_arm = {f"train {a} s{k}" for a in arms for k in seeds}
    per_arm |= {eval_stage(a, k, on) for a in arms for k in seeds for _, on in sets}
    lines = ["| stage | wall s |", "| --- | --- |"]
    lines += [f"| {k} | {v:.0f} |" for k, v in times.items() if k not in per_arm]
    lines += ["", "| arm | seed | train s | " + " | ".join(f"eval {label} s" for label, _ in sets) + " |",
              "|" + " --- |" * (len(sets) + 3)]
    cell = lambda name: f"{times[name]:.0f}" if name in times else "-"  # noqa: E731
    for a in arms:
        for k in seeds:
            evals = [cell(eval_stage(a, k, on)) for _, on in sets]
            t = train_seconds(times, a, k)
            lines.append(f"| {a} | {k} | {'-' if t is None else f'{t:.0f}'} | " + " | ".join(evals) + " |")
    total = sum(times.values())
    lines += ["", f"Total: {total:.0f} s ({total / 60:.1f} min), every stage of stages.json (a stage "
              "found finished keeps the time it took when it ran; a training side by side is "
              "its stage's time over the students the stage trained)."]
    return "\n".join(lines)


def train_stage(n: int, seeds: range) -> str:
    """The stage name of ``n`` students of seeds ``seeds`` trained side by side."""
    return f"train {n} students s{seeds[0]}-{seeds[-1]}"


_SIDE_BY_SIDE = re.compile(r"train (\d+) students s(\d+)-(\d+)")


def train_seconds(times: dict[str, float], arm: str, seed: int) -> float | None:
    """Wall time [s] of arm ``arm``'s seed-``seed`` training in a stages.json: its own stage
    (``train <arm> s<seed>``, one training at a time), else its share of the latest stage
    that trained the students of its seed side by side (the stage's time over its
    students); None if neither is there."""
    if f"train {arm} s{seed}" in times:
        return times[f"train {arm} s{seed}"]
    shares = [t / int(m[1]) for name, t in times.items()
              if (m := _SIDE_BY_SIDE.fullmatch(name)) and int(m[2]) <= seed <= int(m[3]) and int(m[1]) > 0]
    return shares[-1] if shares else None


def eval_stage(arm: str, seed: int, on: str | None = None) -> str:
    """The stage name of arm ``arm``'s seed-``seed`` evaluation: on the main evaluation set
    (``on`` None) or on the second set named ``on``."""
    return f"eval {arm} s{seed}" + (f" on {on}" if on else "")


def write_set_tables(runs: dict[str, list[Path]], out: Path,
                     seeds: dict[str, list[int]] | None = None) -> tuple[str, dict[str, float]]:
    """Every table of the module docstring for the arms' runs on one evaluation set, written
    to ``out`` (``table{3,4}[_common][_vs_control]``, ``b2d``, ``per_hazard``,
    ``claims[_common]`` as .csv and .md, ``hazard_ds`` as .md); returns their Markdown and {arm:
    mean DS} (Table 3's). ``seeds``: each arm's seed index of each run (``paired_tables``).
    Every file of every run folder (results.json, records.csv, records.jsonl) is read and
    checked before anything is written, and the tables are written all or none
    (``write_all``): a damaged folder is refused (ReportError, BadInput) with ``out`` as it was."""
    from harness.scoring.b2d_tables import b2d_tables
    from harness.scoring.report import check_run
    for folders in runs.values():
        for folder in folders:
            check_run(folder)  # results.json and records.csv, before the slower steps below
    extra = b2d_tables(runs)  # reads and checks every records.jsonl
    text, rows, files = paired_tables(runs, seeds)
    parts = [text]
    for stem, csv_rows, md in extra:
        files.update(_table_files(stem, csv_rows, md))
    for i, common in enumerate((False, True)):
        claim_rows, claim_md = claims(rows, common)
        if claim_rows:
            files.update(_table_files("claims_common" if common else "claims", claim_rows, claim_md))
            parts.insert(i, claim_md)
    per_hazard = next((r for stem, r, _ in extra if stem == "per_hazard"), None)
    if per_hazard:
        md = hazard_ds(per_hazard, list(runs))
        files["hazard_ds.md"] = md + "\n"
        parts.append(md)
    parts += [md for stem, _, md in extra if stem == "b2d"]
    first = next(iter(rows.values()))["table3"]
    write_all(out, files)
    return "\n\n".join(parts), {r["arm"]: float(r["DS"]) for r in first}
