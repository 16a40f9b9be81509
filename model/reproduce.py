"""``sumo-scimm reproduce``: the paper's whole experiment on a CPU, one stage after another.

    collect train + val (expert) -> teachers (fixed, scimm, smoother) -> the baseline /
    control / fixed / scimm / smoother students of every seed asked, trained two at a time
    side by side (model.side_by_side) -> for each seed: evaluate each student on
    town12_short and on the second set town12_second -> every seed's students fed the
    expert's inputs on town12_short (replay) -> Table 2, Tables 3-4 with seed-paired
    intervals (route-paired with one seed) against the baseline and against the
    loss-matched control, the paper's claims, DS per hazard type, the arms' ranking on both
    sets, the replay table, Fig. 4, Fig. 5, loss curves

Every stage is the function behind the subcommand a user would run by hand (its command
line is printed), and each skips work whose outputs exist (collect and eval resume; a
teacher with a manifest, a training with a checkpoint are not redone), so an interrupted
reproduce resumes where it stopped. The trainings side by side are one stage (one torch
thread each, printed as ``sumo-scimm train ... --threads 1`` commands, each of which gives
the same student alone); a long run in parts (``--seeds 0-1``, ``--seeds 2-3``, ...) shows
tables after each part. Stage wall times go to ``OUT/stages.json``; the tables
to ``OUT/tables`` (the second set's to ``OUT/tables/<set>``, model.arm_tables), figures and
a summary to ``OUT/README.md``; what a repository keeps of the run to ``OUT/records``
(model.run_records), from which a part on another machine takes the earlier parts' seeds.
"""
from __future__ import annotations

import json
import logging
import re
import shutil
import time
from collections.abc import Callable
from pathlib import Path

import pandas as pd

from files.atomic import write_atomic
from harness.common.errors import BadInput
from harness.runs.evaluate import Backend
from model.run_records import archive_records, restore_records, second_label

# (arm, teacher of `sumo-scimm train`): the baseline (expert labels only), the loss-matched
# control (the expert's own labels given the teacher terms' weight, a constant mode target),
# the paper's two teacher arms, and the offline IMM smoother's (a teacher the paper does not have)
ARMS = (("baseline", "none"), ("control", "control"), ("fixed", "fixed"), ("scimm", "scimm"),
        ("smoother", "smoother"))
EVAL_SET = "town12_short"
SECOND_SET = "town12_second"  # a second evaluation set, never used for a choice
log = logging.getLogger(__name__)


def select_arms(text: str | None) -> tuple[str, ...]:
    """The arms of ``--arms a,b,...`` in ARMS order (None: all); BadInput for an unknown name."""
    names = [a for a, _ in ARMS]
    if text is None:
        return tuple(names)
    asked = [t.strip() for t in text.split(",")]
    bad = [a for a in asked if a not in names]
    if bad:
        raise BadInput(f"--arms: unknown arm {bad[0]!r} (arms: {', '.join(names)}; e.g. --arms baseline,scimm)")
    twice = next((a for i, a in enumerate(asked) if a in asked[:i]), None)
    if twice:
        raise BadInput(f"--arms {text!r}: arm {twice!r} is named twice (name each arm once, "
                       "e.g. --arms baseline,scimm)")
    return tuple(a for a in names if a in asked)


MAX_SEED = 2 ** 64 - 1  # the largest seed a training takes (torch.manual_seed)
MAX_SEEDS = 1000  # seeds in one reproduce; a longer experiment runs in parts


def parse_seeds(text: str) -> range:
    """The seeds of ``--seeds``: ``K`` is seeds 0..K-1 (1 <= K <= MAX_SEEDS), ``A-B`` seeds A
    to B (0 <= A <= B <= MAX_SEED, at most MAX_SEEDS of them); BadInput otherwise."""
    m = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", text)
    if not m:
        raise BadInput(f"--seeds: expected K (seeds 0..K-1) or A-B (seeds A to B), got {text!r} (e.g. --seeds 3-5)")
    shown = text.strip()[:60]
    if any(g and len(g.lstrip("0")) > len(str(MAX_SEED)) for g in m.groups()):  # not read as a number at all
        raise BadInput(f"--seeds {shown!r}: a seed is at most {MAX_SEED} (2**64 - 1, the largest a training takes)")
    first, last = int(m[1]), None if m[2] is None else int(m[2])  # digits only: whole numbers >= 0
    if last is None:
        if first < 1:
            raise BadInput(f"--seeds must be >= 1 (got {first})")
        seeds = range(first)
    elif last < first:
        raise BadInput(f"--seeds {text!r}: the range ends before it starts (e.g. --seeds {last}-{first})")
    elif last > MAX_SEED:
        raise BadInput(f"--seeds {shown!r}: a seed is at most {MAX_SEED} (2**64 - 1, the largest a training takes)")
    else:
        seeds = range(first, last + 1)
    count = seeds.stop - seeds.start  # len() overflows past sys.maxsize
    if count > MAX_SEEDS:
        raise BadInput(f"--seeds {shown!r} asks for {count} seeds, at most {MAX_SEEDS} in one reproduce: run a "
                       f"long experiment in parts (e.g. --seeds 0-9, then --seeds 10-19)")
    return seeds


def pooled_runs(folder: Path, arms: tuple[str, ...]) -> tuple[dict[str, list[Path]], dict[str, list[int]]]:
    """Every finished evaluation of every arm in ``folder`` (``<arm>_s<seed>``, seeds of every
    earlier part of the experiment included), by seed: ({arm: run folders}, {arm: seeds}),
    each in seed order. An unfinished run folder is left out, with a warning."""
    from harness.scoring.report import ReportError, check_run
    runs: dict[str, list[Path]] = {a: [] for a in arms}
    seeds: dict[str, list[int]] = {a: [] for a in arms}
    found = sorted((int(m[2]), m[1], d) for d in folder.glob("*_s*")
                   if (m := re.fullmatch(r"(.+)_s(\d+)", d.name)) and m[1] in arms)
    for seed, arm, run in found:
        try:
            check_run(run)
        except ReportError as exc:
            log.warning("left out of the tables: %s", exc)
            continue
        runs[arm].append(run)
        seeds[arm].append(seed)
    return {a: r for a, r in runs.items() if r}, {a: k for a, k in seeds.items() if k}


class Stages:
    """Runs named stages in order and records their wall times [s] in ``stages.json``."""

    def __init__(self, out: Path):
        self.file = out / "stages.json"
        self.times: dict[str, float] = json.loads(self.file.read_text()) if self.file.is_file() else {}

    def run(self, name: str, command: str, fn: Callable[[], object]):
        """Run ``fn`` (the stage ``sumo-scimm command`` would run) as stage ``name``; a stage
        that fails with bad input names itself and the command that repeats it."""
        log.info("== %s: sumo-scimm %s", name, command)
        t0 = time.perf_counter()
        try:
            result = fn()
        except BadInput as exc:
            raise BadInput(f"stage {name!r} failed: {exc} (command: sumo-scimm {command}); "
                           "fix it and run reproduce again: finished stages are kept") from None
        # a stage that found its outputs keeps the time it took when it ran
        self.times[name] = max(self.times.get(name, 0.0), round(time.perf_counter() - t0, 1))
        write_atomic(self.file, json.dumps(self.times, indent=1) + "\n")
        return result


def reproduce(out: Path, seeds: int | range, repetitions: int, epochs: int | None, backend: Backend = Backend(),
              sets: tuple[str, str, str] = ("train", "val", EVAL_SET), arms: tuple[str, ...] | None = None,
              second: str | None = SECOND_SET, vehicle: str = "carla") -> str:
    """Run (or finish) the experiment in ``out``; returns the Markdown summary. ``seeds``:
    the seeds to run (an int K: 0..K-1); the tables pool every seed whose evaluations are in
    ``out``, so an experiment can be run in parts (``--seeds 0-2``, then ``--seeds 3-5``).
    ``backend``: where the collect and eval stages run; ``sets``: the training, validation
    and evaluation route sets (the paper's by default); ``arms``: the arms to run (names of
    ARMS, default all); ``second``: a second evaluation set every student is evaluated on too
    (None: none);
    ``vehicle``: the ego model of every drive (controller.ego)."""
    seeds = range(seeds) if isinstance(seeds, int) else seeds
    from model.train import TrainConfig
    from scimm.stage import dataset_episodes, make_teachers
    from scimm.teacher import METHODS as TEACHERS, is_complete
    arms = tuple(arms or select_arms(None))
    teacher = dict(ARMS)
    for arm in arms:  # a teacher name train does not know: refused before any stage runs
        try:
            TrainConfig(data=out, out=out, teacher=teacher[arm])
        except BadInput as exc:
            raise BadInput(f"arm {arm!r}: {exc} (leave it out with --arms)") from None
    out.mkdir(parents=True, exist_ok=True)
    label2 = None if second is None else Path(second).stem
    folders = {Path(sets[2]).stem: out / "runs",
               **({second_label(Path(sets[2]).stem, label2): out / "runs" / label2} if label2 else {})}
    restore_records(out, folders, seeds)  # the seeds of earlier parts, from their committed records
    st = Stages(out)
    train_dir, val_dir = out / "data" / "train", out / "data" / "val"
    _collect(st, sets, train_dir, val_dir, repetitions, backend, vehicle)
    _, episodes = dataset_episodes(train_dir)
    for method in TEACHERS:
        if not is_complete(train_dir, method):
            st.run(f"teacher {method}", f"teacher --data {train_dir} --method {method}",
                   lambda method=method: make_teachers(train_dir, episodes, (method,)))
    ckpts = _train(st, out, arms, teacher, seeds, epochs, train_dir, val_dir)
    for seed in seeds:
        for arm in arms:
            ckpt = ckpts[arm, seed]
            _eval(st, ckpt, sets[2], out / "runs" / f"{arm}_s{seed}", arm, seed, None, backend, vehicle)
            if second is not None:
                _eval(st, ckpt, second, out / "runs" / label2 / f"{arm}_s{seed}", arm, seed, label2, backend, vehicle)
        if len(arms) > 1:
            _replay(st, out, arms, seed, sets[2], backend, vehicle)
    pooled = pooled_runs(out / "runs", arms)
    pooled2 = pooled_runs(out / "runs" / label2, arms) if second is not None else None
    every = sorted({k for ks in pooled[1].values() for k in ks})
    replays = [f"### Seed {k}\n\n" + (out / "replay" / f"s{k}" / "table.md").read_text()
               for k in every if len(arms) > 1 and (out / "replay" / f"s{k}" / "table.md").is_file()]
    return _tables_and_summary(out, st, every, train_dir, episodes, pooled, pooled2, sets[2], label2, replays)


def _collect(st: Stages, sets: tuple[str, str, str], train_dir: Path, val_dir: Path, repetitions: int,
             backend: Backend, vehicle: str) -> None:
    from harness.runs.evaluate import collect
    w = f"--workers {backend.workers} --vehicle {vehicle}"
    train_set, val_set, _ = sets
    st.run("collect train", f"collect --routes {train_set} --out {train_dir} {w} --repetitions {repetitions} --resume",
           lambda: collect(train_set, train_dir, repetitions=repetitions, resume=True, backend=backend,
                           vehicle=vehicle))
    st.run("collect val", f"collect --routes {val_set} --out {val_dir} {w} --resume",
           lambda: collect(val_set, val_dir, resume=True, backend=backend, vehicle=vehicle))


def _train(st: Stages, out: Path, arms: tuple[str, ...], teacher: dict[str, str], seeds: range,
           epochs: int | None, train_dir: Path, val_dir: Path) -> dict[tuple[str, int], Path]:
    """The checkpoint of every arm's student of every seed, {(arm, seed): file}; those not
    yet trained are trained side by side (model.side_by_side: SIDE_BY_SIDE at a time, one
    torch thread each) as stage ``train N students sA-B``."""
    from model.arm_tables import train_stage
    from model.side_by_side import SIDE_BY_SIDE, THREADS_EACH, train_side_by_side
    from model.train import TrainConfig
    ckpts = {(arm, seed): out / "models" / f"{arm}_s{seed}" / "student.pt" for seed in seeds for arm in arms}
    todo = {key: TrainConfig(data=train_dir, out=ckpt.parent, teacher=teacher[key[0]], val=val_dir, seed=key[1],
                             cache_dir=out / "data" / "cache", threads=THREADS_EACH,
                             **({"epochs": epochs} if epochs else {}))
            for key, ckpt in ckpts.items() if not ckpt.is_file()}
    for cfg in todo.values():
        log.info("   sumo-scimm train --data %s --val %s --teacher %s --seed %d --out %s --epochs %d --threads %d",
                 train_dir, val_dir, cfg.teacher, cfg.seed, cfg.out, cfg.epochs, cfg.threads)
    if todo:
        st.run(train_stage(len(todo), seeds),
               f"train, the {len(todo)} commands above, {SIDE_BY_SIDE} at a time",
               lambda: train_side_by_side(list(todo.values())))
    return ckpts


def _eval(st: Stages, ckpt: Path, route_set: str, run_dir: Path, arm: str, seed: int, on: str | None,
          backend: Backend, vehicle: str) -> Path:
    """``run_dir``: the student ``ckpt`` evaluated (or its evaluation finished) on ``route_set``."""
    from harness.runs.evaluate import evaluate
    from model.arm_tables import eval_stage
    st.run(eval_stage(arm, seed, on), f"eval --routes {route_set} --agent {ckpt} --workers {backend.workers} "
           f"--seed {seed} --out {run_dir} --vehicle {vehicle} --resume",
           lambda: evaluate(route_set, "student", str(ckpt), run_dir, seed=seed, resume=True, backend=backend,
                            vehicle=vehicle))
    return run_dir


def _replay(st: Stages, out: Path, arms: tuple[str, ...], seed: int, route_set: str, backend: Backend,
            vehicle: str) -> str:
    """Every arm's seed-``seed`` student fed the identical inputs of the expert's run on
    ``route_set`` (seed 0, evaluated once), compared with the first arm route-paired
    (harness.runs.replay: output stability without the exposure of each arm's own drive);
    returns the Markdown table of ``OUT/replay/s<seed>`` (made again when the arms changed)."""
    from harness.runs.evaluate import evaluate
    from harness.runs.replay import replay
    ref = out / "runs" / "expert_s0"
    st.run("eval expert s0", f"eval --routes {route_set} --agent expert --workers {backend.workers} --seed 0 "
           f"--out {ref} --vehicle {vehicle} --resume",
           lambda: evaluate(route_set, "expert", None, ref, seed=0, resume=True, backend=backend, vehicle=vehicle))
    rdir = out / "replay" / f"s{seed}"
    made = rdir / "replay.json"  # written last
    done = made.is_file() and json.loads(made.read_text()).get("labels") == list(arms)
    if not done:
        shutil.rmtree(rdir, ignore_errors=True)  # an interrupted replay, or one of other arms, starts again
        ckpts = [str(out / "models" / f"{arm}_s{seed}" / "student.pt") for arm in arms]
        st.run(f"replay s{seed}", f"replay --run {ref} {' '.join(f'--agent {c}' for c in ckpts)} "
               f"--workers {backend.workers} --out {rdir}",
               lambda: replay(ref, ckpts, rdir, routes=route_set, workers=backend.workers, labels=list(arms)))
    return (rdir / "table.md").read_text()


def _tables_and_summary(out: Path, st: Stages, seeds: list[int], train_dir: Path, episodes,
                        pooled: tuple[dict[str, list[Path]], dict[str, list[int]]],
                        pooled2: tuple[dict[str, list[Path]], dict[str, list[int]]] | None, main: str,
                        label2: str | None, replays: list[str]) -> str:
    """Table 2, every arm table of both sets (model.arm_tables) from the runs of every seed
    present (``pooled_runs``), the ranking, the figures and ``OUT/README.md``; returns its text."""
    from model.arm_tables import ranking, write_set_tables
    from scimm.stage import write_tables
    tables = out / "tables"
    tables.mkdir(exist_ok=True)
    if not (train_dir / "teacher" / "table2.csv").is_file():
        st.run("table 2", f"teacher --data {train_dir} --method all", lambda: write_tables(train_dir, episodes))
    shutil.copy(train_dir / "teacher" / "table2.csv", tables / "table2.csv")
    runs = pooled[0]
    text, ds = write_set_tables(runs, tables, pooled[1])
    parts = [f"## Tables 3-4 on {main}", "", text]
    if pooled2 is not None:
        label = label2 if label2 != main else f"{label2} (second evaluation)"
        text2, ds2 = write_set_tables(pooled2[0], tables / str(label2), pooled2[1])
        rank = ranking({main: ds, label: ds2})
        (tables / "ranking.md").write_text(rank + "\n")
        parts += ["", f"## Tables 3-4 on the second set, {label}", "", text2, "", rank]
    if replays:
        parts += ["", f"## Replay: every student fed the expert's inputs on {main}", "", *replays]
    second = {second_label(Path(main).stem, str(label2)): pooled2[0]} if pooled2 is not None else {}
    archive_records(out, {Path(main).stem: pooled[0], **second})
    figs = _figures(out, train_dir, runs, seeds, st)
    text = _summary(out, seeds, st.times, "\n".join(parts), figs, list(runs), main, label2)
    (out / "README.md").write_text(text)
    return text


def _figures(out: Path, train_dir: Path, runs: dict[str, list[Path]], seeds: list[int], st: Stages) -> list[str]:
    """Fig. 4 on the first episode with an obstacle bypass (Avoidance and Recovery show
    there), Fig. 5 on the route where the reference arm's (the first arm's) first seed's path
    curvature varied most, against SC-IMM (or the last arm), the loss curves of every seed."""
    from harness.scoring.figures import waypoint_overlay
    from scimm.plot import plot_posterior
    index = pd.read_csv(train_dir / "index.csv")
    bypass = index[index["situation"] == "bypass"]
    episode = str(bypass["episode"].iloc[0] if len(bypass) else index["episode"].iloc[0])
    fig4 = out / "fig4_mode_posterior.png"
    st.run("fig 4", f"teacher plot --data {train_dir} --episode {episode} --out {fig4}",
           lambda: plot_posterior(train_dir / "episodes" / f"{episode}.npz", fig4, method="scimm"))
    figs = [f"![Fig. 4, episode {episode}]({fig4.name})"]
    first, other = next(iter(runs)), ("scimm" if "scimm" in runs else list(runs)[-1])
    # Fig. 5 needs the routes' logs: the first seed whose two runs ran here (not restored)
    pair = next(((a, b) for a in runs[first] for b in runs[other]
                 if a.name[len(first):] == b.name[len(other):] and (a / "records.csv").is_file()
                 and (b / "records.csv").is_file()), None)
    if other != first and pair is not None:
        base = pd.read_csv(pair[0] / "records.csv")
        key = str(base.loc[base["curvature_variation"].idxmax(), "key"])
        fig5 = waypoint_overlay({first: pair[0], other: pair[1]}, key, out / "fig5_waypoint_overlay.png")
        figs.append(f"![Fig. 5, route {key}]({fig5.name})")
    from model.curves import plot_loss_curves
    for seed in seeds:
        models = {arm: out / "models" / f"{arm}_s{seed}" for arm in runs}
        made = plot_loss_curves({arm: m for arm, m in models.items() if m.is_dir()},
                                out / f"loss_curves_seed{seed}.png")
        figs.append(f"![Loss curves, seed {seed}]({Path(made).name})")
    return figs


def _summary(out: Path, seeds: list[int], times: dict[str, float], arm_tables: str, figs: list[str],
             arms: list[str], main: str, second: str | None) -> str:
    from model.arm_tables import stage_table
    t2 = pd.read_csv(out / "tables" / "table2.csv")
    named = f"seed {seeds[0]}" if len(seeds) == 1 else f"seeds {', '.join(map(str, seeds))}"
    lines = [f"# sumo-scimm reproduce ({len(seeds)} seed{'s' if len(seeds) > 1 else ''}: {named}; "
             f"arms {', '.join(arms)})", "",
             "## Table 2: teacher signals (training set)", "", _markdown(t2), "",
             arm_tables, "", "## Figures", "", *figs, "", "## Stage wall times [s]", "",
             stage_table(times, arms, seeds, main, second), ""]
    return "\n".join(lines)


def _markdown(df: pd.DataFrame) -> str:
    cell = lambda v: f"{v:.4f}" if isinstance(v, float) else str(v)  # noqa: E731
    rows = ["| " + " | ".join(map(str, df.columns)) + " |", "|" + " --- |" * len(df.columns)]
    rows += ["| " + " | ".join(cell(v) for v in r) + " |" for r in df.itertuples(index=False)]
    return "\n".join(rows)
