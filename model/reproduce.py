"""``sumo-scimm reproduce``: the paper's whole experiment on a CPU, one stage after another.

    collect train + val (expert) -> teachers (fixed, scimm, smoother) -> for each seed: train
    baseline / fixed / scimm / smoother students -> evaluate each on town12_short -> Table 2,
    Tables 3-4 (mean over seeds, 95 % intervals, change against the baseline), Fig. 4, Fig. 5

Every stage is the function behind the subcommand a user would run by hand (its command
line is printed), and each skips work whose outputs exist (collect and eval resume; a
teacher with a manifest, a training with a checkpoint are not redone), so an interrupted
reproduce resumes where it stopped. Stage wall times go to ``OUT/stages.json``; the tables,
figures and a summary to ``OUT/README.md``.
"""
from __future__ import annotations

import json
import logging
import shutil
import time
from collections.abc import Callable
from pathlib import Path

import pandas as pd

from harness.common.atomic import write_atomic
from harness.common.errors import BadInput
from harness.runs.evaluate import Backend

# (arm, teacher of `sumo-scimm train`): the paper's three students, the first the baseline,
# then the offline IMM smoother's (a teacher the paper does not have)
ARMS = (("baseline", "none"), ("fixed", "fixed"), ("scimm", "scimm"), ("smoother", "smoother"))
EVAL_SET = "town12_short"
log = logging.getLogger(__name__)


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


def reproduce(out: Path, seeds: int, repetitions: int, epochs: int | None, backend: Backend = Backend(),
              sets: tuple[str, str, str] = ("train", "val", EVAL_SET)) -> str:
    """Run (or finish) the experiment in ``out``; returns the Markdown summary. ``backend``:
    where the collect and eval stages run; ``sets``: the training, validation and evaluation
    route sets (the paper's by default)."""
    from harness.runs.evaluate import collect, evaluate
    from harness.scoring.figures import waypoint_overlay
    from harness.scoring.report import write_arm_report
    from model.train import TrainConfig, train
    from scimm.stage import dataset_episodes, make_teachers, write_tables
    from scimm.teacher import METHODS as TEACHERS, is_complete
    out.mkdir(parents=True, exist_ok=True)
    st = Stages(out)
    train_dir, val_dir = out / "data" / "train", out / "data" / "val"
    w = f"--workers {backend.workers}"
    train_set, val_set, eval_set = sets
    st.run("collect train", f"collect --routes {train_set} --out {train_dir} {w} --repetitions {repetitions} --resume",
           lambda: collect(train_set, train_dir, repetitions=repetitions, resume=True, backend=backend))
    st.run("collect val", f"collect --routes {val_set} --out {val_dir} {w} --resume",
           lambda: collect(val_set, val_dir, resume=True, backend=backend))
    _, episodes = dataset_episodes(train_dir)
    for method in TEACHERS:
        if not is_complete(train_dir, method):
            st.run(f"teacher {method}", f"teacher --data {train_dir} --method {method}",
                   lambda method=method: make_teachers(train_dir, episodes, (method,)))
    runs: dict[str, list[Path]] = {arm: [] for arm, _ in ARMS}
    for seed in range(seeds):
        for arm, teacher in ARMS:
            model_dir = out / "models" / f"{arm}_s{seed}"
            ckpt = model_dir / "student.pt"
            if not ckpt.is_file():
                cfg = TrainConfig(data=train_dir, out=model_dir, teacher=teacher, val=val_dir, seed=seed,
                                  cache_dir=out / "data" / "cache", **({"epochs": epochs} if epochs else {}))
                st.run(f"train {arm} s{seed}", f"train --data {train_dir} --val {val_dir} --teacher {teacher} "
                       f"--seed {seed} --out {model_dir} --epochs {cfg.epochs}", lambda cfg=cfg: train(cfg))
            run_dir = out / "runs" / f"{arm}_s{seed}"
            st.run(f"eval {arm} s{seed}", f"eval --routes {eval_set} --agent {ckpt} {w} --seed {seed} "
                   f"--out {run_dir} --resume",
                   lambda ckpt=ckpt, run_dir=run_dir, seed=seed: evaluate(
                       eval_set, "student", str(ckpt), run_dir, seed=seed, resume=True, backend=backend))
            runs[arm].append(run_dir)

    tables = out / "tables"
    tables.mkdir(exist_ok=True)
    if not (train_dir / "teacher" / "table2.csv").is_file():
        st.run("table 2", f"teacher --data {train_dir} --method all", lambda: write_tables(train_dir, episodes))
    shutil.copy(train_dir / "teacher" / "table2.csv", tables / "table2.csv")
    table34 = write_arm_report(runs, tables)
    figs = _figures(out, train_dir, runs, st, waypoint_overlay)
    text = _summary(out, seeds, st.times, table34, figs)
    (out / "README.md").write_text(text)
    return text


def _figures(out: Path, train_dir: Path, runs: dict[str, list[Path]], st: Stages, overlay) -> list[str]:
    """Fig. 4 on the first episode with an obstacle bypass (Avoidance and Recovery show
    there), Fig. 5 on the route where the seed-0 baseline's path curvature varied most."""
    index = pd.read_csv(train_dir / "index.csv")
    bypass = index[index["situation"] == "bypass"]
    episode = str(bypass["episode"].iloc[0] if len(bypass) else index["episode"].iloc[0])
    fig4 = out / "fig4_mode_posterior.png"
    from scimm.plot import plot_posterior
    st.run("fig 4", f"teacher plot --data {train_dir} --episode {episode} --out {fig4}",
           lambda: plot_posterior(train_dir / "episodes" / f"{episode}.npz", fig4, method="scimm"))
    base = pd.read_csv(runs["baseline"][0] / "records.csv")
    key = str(base.loc[base["curvature_variation"].idxmax(), "key"])
    fig5 = overlay({"baseline": runs["baseline"][0], "scimm": runs["scimm"][0]}, key,
                   out / "fig5_waypoint_overlay.png")
    return [f"![Fig. 4, episode {episode}]({fig4.name})", f"![Fig. 5, route {key}]({fig5.name})"]


def _summary(out: Path, seeds: int, times: dict[str, float], table34: str, figs: list[str]) -> str:
    t2 = pd.read_csv(out / "tables" / "table2.csv")
    lines = [f"# sumo-scimm reproduce ({seeds} seed{'s' if seeds > 1 else ''})", "",
             "## Table 2: teacher signals (training set)", "", _markdown(t2), "",
             table34, "", "## Figures", "", *figs, "", "## Stage wall times [s]", "",
             "| stage | wall s |", "| --- | --- |",
             *(f"| {k} | {v:.0f} |" for k, v in times.items()),
             f"| total | {sum(times.values()):.0f} |", ""]
    return "\n".join(lines)


def _markdown(df: pd.DataFrame) -> str:
    cell = lambda v: f"{v:.4f}" if isinstance(v, float) else str(v)  # noqa: E731
    rows = ["| " + " | ".join(map(str, df.columns)) + " |", "|" + " --- |" * len(df.columns)]
    rows += ["| " + " | ".join(cell(v) for v in r) + " |" for r in df.itertuples(index=False)]
    return "\n".join(rows)
