"""``sumo-scimm reproduce``: the paper's whole experiment on a CPU, one stage after another.

    collect train + val (expert) -> teachers (fixed, scimm) -> for each seed: train
    baseline / fixed / scimm students -> evaluate each on town12_short -> Table 2,
    Tables 3-4 (mean over seeds, 95 % intervals, change against the baseline), Fig. 4, Fig. 5

Every stage is the CLI subcommand a user would run by hand, called in-process, and each
skips work whose outputs exist (collect and eval run with ``--resume``; a teacher with a
manifest, a training with a checkpoint are not redone), so an interrupted reproduce
resumes where it stopped. Stage wall times go to ``OUT/stages.json``; the tables,
figures and a summary to ``OUT/README.md``.
"""
from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import pandas as pd

from harness.common.atomic import write_atomic

# (arm, teacher of `sumo-scimm train`): the paper's three students; the first is the baseline
ARMS = (("baseline", "none"), ("fixed", "fixed"), ("scimm", "scimm"))
EVAL_SET = "town12_short"


class Stages:
    """Runs named stages in order and records their wall times [s] in ``stages.json``."""

    def __init__(self, out: Path):
        self.file = out / "stages.json"
        self.times: dict[str, float] = json.loads(self.file.read_text()) if self.file.is_file() else {}

    def run(self, name: str, argv: list[str]) -> None:
        from sumo_scimm.cli import main
        from harness.common.errors import BadInput
        print(f"== {name}: sumo-scimm {' '.join(argv)}", flush=True)
        t0 = time.perf_counter()
        if main(argv) != 0:
            raise BadInput(f"stage {name!r} failed (command: sumo-scimm {' '.join(argv)}); "
                           "fix it and run reproduce again: finished stages are kept")
        # a stage that found its outputs keeps the time it took when it ran
        self.times[name] = max(self.times.get(name, 0.0), round(time.perf_counter() - t0, 1))
        write_atomic(self.file, json.dumps(self.times, indent=1) + "\n")


def reproduce(out: Path, seeds: int, workers: int, repetitions: int, epochs: int | None,
              backend: tuple[str, ...] = (), sets: tuple[str, str, str] = ("train", "val", EVAL_SET)) -> str:
    """Run (or finish) the experiment in ``out``; returns the Markdown summary. ``backend``:
    extra options of the collect and eval stages (``--backend ray [--address A]``); ``sets``:
    the training, validation and evaluation route sets (the paper's by default)."""
    from harness.scoring.figures import waypoint_overlay
    from harness.scoring.report import write_arm_report
    from scimm.teacher import is_complete
    out.mkdir(parents=True, exist_ok=True)
    st = Stages(out)
    train_dir, val_dir = out / "data" / "train", out / "data" / "val"
    w = ["--workers", str(workers), *backend]
    train_set, val_set, eval_set = sets
    st.run("collect train", ["collect", "--routes", train_set, "--out", str(train_dir), *w,
                             "--repetitions", str(repetitions), "--resume"])
    st.run("collect val", ["collect", "--routes", val_set, "--out", str(val_dir), *w, "--resume"])
    for method in ("fixed", "scimm"):
        if not is_complete(train_dir, method):
            st.run(f"teacher {method}", ["teacher", "--data", str(train_dir), "--method", method])
    runs: dict[str, list[Path]] = {arm: [] for arm, _ in ARMS}
    for seed in range(seeds):
        for arm, teacher in ARMS:
            model_dir = out / "models" / f"{arm}_s{seed}"
            ckpt = model_dir / "student.pt"
            if not ckpt.is_file():
                argv = ["train", "--data", str(train_dir), "--val", str(val_dir), "--teacher", teacher,
                        "--seed", str(seed), "--out", str(model_dir), "--cache", str(out / "data" / "cache")]
                st.run(f"train {arm} s{seed}", argv + (["--epochs", str(epochs)] if epochs else []))
            run_dir = out / "runs" / f"{arm}_s{seed}"
            st.run(f"eval {arm} s{seed}", ["eval", "--routes", eval_set, "--agent", "student",
                                           "--agent-config", str(ckpt), *w, "--seed", str(seed),
                                           "--out", str(run_dir), "--resume"])
            runs[arm].append(run_dir)

    tables = out / "tables"
    tables.mkdir(exist_ok=True)
    # Table 2 is written by `sumo-scimm teacher` (method all); run it once over both teachers
    if not (train_dir / "teacher" / "table2.csv").is_file():
        st.run("table 2", ["teacher", "--data", str(train_dir), "--method", "all"])
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
    st.run("fig 4", ["teacher", "plot", "--data", str(train_dir), "--episode", episode, "--out", str(fig4)])
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


def _reproduce(args: argparse.Namespace) -> int:
    from sumo_scimm.cli import check_backend
    from harness.common.errors import BadInput
    from scenarios import UnknownSet, resolve_set
    for name in ("seeds", "workers", "repetitions"):
        if getattr(args, name) < 1:
            raise BadInput(f"--{name} must be >= 1 (got {getattr(args, name)})")
    if args.epochs is not None and args.epochs < 1:
        raise BadInput(f"--epochs must be >= 1 (got {args.epochs})")
    check_backend(args)
    backend = ("--backend", args.backend) + (("--address", args.address) if args.address else ())
    sets = (args.train_routes, args.val_routes, args.eval_routes)
    for name in sets:
        try:
            resolve_set(name)
        except UnknownSet as exc:
            raise BadInput(str(exc)) from None
    print(reproduce(Path(args.out), args.seeds, args.workers, args.repetitions, args.epochs, backend, sets))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``sumo-scimm reproduce``."""
    import os

    from sumo_scimm.cli import add_backend_options
    r = sub.add_parser("reproduce", help="the paper's whole experiment: collect, teachers, train, eval, tables",
                       description="Collect -> teachers -> train baseline/fixed/scimm per seed -> eval on "
                       f"{EVAL_SET} -> Tables 2-4, Fig. 4-5. Resumes: finished stages are skipped.")
    r.add_argument("--seeds", type=int, default=1, help="training/evaluation seeds per arm (default 1)")
    r.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="simulation processes (default: cores)")
    r.add_argument("--repetitions", type=int, default=1,
                   help="expert drives of each training route (default 1; 2 gives > 100k frames)")
    r.add_argument("--epochs", type=int, help="training epochs (default: sumo-scimm train's)")
    r.add_argument("--out", default="runs/reproduce", help="output folder (default runs/reproduce)")
    add_backend_options(r)  # for the collect and eval stages; training runs here
    # other route sets (e.g. town12_smoke everywhere): to try the pipeline in minutes, not for results
    r.add_argument("--train-routes", default="train", help="training route set (default train)")
    r.add_argument("--val-routes", default="val", help="validation route set (default val)")
    r.add_argument("--eval-routes", default=EVAL_SET, help=f"evaluation route set (default {EVAL_SET})")
    r.set_defaults(func=_reproduce)
