"""``sumo-scimm teacher ...``: the teacher stage's subcommands (docs/design.md §6).

    sumo-scimm teacher --data DIR [--method fixed|scimm|smoother|all] [--path-state plan|ego]
        writes DIR/teacher/<method>/ (scimm.teacher), then, when every method's folder is
        complete, prints paper Table 2 (also DIR/teacher/table2.csv), the mode-meaning
        check (also DIR/teacher/mode_meaning.csv), the fit residual of the observation per
        mode (also DIR/teacher/fit_residuals.csv; docs/design.md §6.1) and the lag figures (also
        DIR/teacher/lag.csv and standstill.csv; scimm.lag).
    sumo-scimm teacher plot --data DIR --episode E --out FILE.png
        paper Fig. 4 for episode E (its file stem, e.g. 12_rep0).
"""
from __future__ import annotations

import argparse
from pathlib import Path

from harness.common.errors import BadInput
from scimm import teacher as tch
from scimm.modes import IMMConfig
from scimm.stage import dataset_episodes, make_teachers, write_tables
from sumo_scimm.options import out_arg

METHOD_CHOICES = (*tch.METHODS, "all")


def _teacher(args: argparse.Namespace) -> int:
    from scimm.lag import format_lag, format_stops_starts
    from scimm.table2 import format_meaning, format_residuals, format_table2
    from harness.common.lock import FolderLock
    folder, files = dataset_episodes(args.data)
    with FolderLock(folder):  # no collect (or other teacher) writes into the dataset meanwhile
        make_teachers(folder, files, tch.METHODS if args.method == "all" else (args.method,), args.path_state)
        if not all(tch.is_complete(folder, m) for m in tch.METHODS):
            print(f"Table 2 needs every teacher ({', '.join(tch.METHODS)}): run with --method all")
            return 0
        tables = write_tables(folder, files)
    table, meaning, residuals = tables["table2"], tables["mode_meaning"], tables["fit_residuals"]
    print(f"Table 2 ({len(files)} episodes; groups = dominant SC-IMM mode) -> {folder / 'teacher' / 'table2.csv'}")
    print(format_table2(table))
    print(f"\nTable 2 over the frames where the expert moved (a standing frame has every delta 0) -> "
          f"{folder / 'teacher' / 'table2_moving.csv'}")
    print(format_table2(tables["table2_moving"]))
    print("\nMode meaning: frames of each situation whose dominant mode means it")
    print(format_meaning(meaning))
    print("\nFit residual of the observation z (paper eq. 2-3) against the expert's labels, per dominant "
          f"SC-IMM mode -> {folder / 'teacher' / 'fit_residuals.csv'}")
    print(format_residuals(residuals))
    print("\nLag against the expert: the frame offset that best aligns the teacher's v(0) and c0 with the "
          f"expert's (> 0 = late), per dominant SC-IMM mode -> {folder / 'teacher' / 'lag.csv'}; the teacher's "
          f"v(0) where the expert has stood >= 0.5 s, and mode switches -> {folder / 'teacher' / 'standstill.csv'}")
    print(format_lag(tables["lag"], tables["standstill"]))
    print("\nStops and starts: label speeds ahead [m/s] where the expert brakes for a red light and where it "
          f"starts off, and the teacher's excess over the expert's -> {folder / 'teacher' / 'stops_starts.csv'}")
    print(format_stops_starts(tables["stops_starts"]))
    return 0


def _plot(args: argparse.Namespace) -> int:
    from scimm.plot import plot_posterior
    folder, files = dataset_episodes(args.data)
    match = [f for f in files if f.stem == args.episode]
    if not match:
        stems = [f.stem for f in files]
        raise BadInput(f"no episode {args.episode!r} in {folder}/episodes (e.g. {', '.join(stems[:3])})")
    if not args.out.lower().endswith(".png"):
        raise BadInput(f"--out {args.out!r} must end in .png")
    if not Path(args.out).resolve().parent.is_dir():
        raise BadInput(f"--out {args.out!r}: folder does not exist")
    print(plot_posterior(match[0], Path(args.out), method=args.method))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``teacher`` and ``teacher plot``."""
    t = sub.add_parser("teacher", help="SC-IMM teacher signals of a dataset, Table 2; 'teacher plot' for Fig. 4")
    t.add_argument("--data", help="dataset folder (of 'sumo-scimm collect')")
    t.add_argument("--method", default="all", choices=METHOD_CHOICES,
                   help="teacher to compute (default all: fixed, scimm and smoother)")
    t.add_argument("--path-state", default=IMMConfig.path_state, choices=("plan", "ego"),
                   help="the IMM's path state: plan (default), the teacher's offset from the expert's previous "
                        "plan; ego, the heading quadratic of each frame's path in its ego frame (docs/teacher.md)")
    t.set_defaults(func=_teacher)
    tsub = t.add_subparsers(dest="teacher_action", parser_class=type(t), metavar="{plot}")
    p = tsub.add_parser("plot", help="paper Fig. 4: BEV of a few frames and the mode posterior over time")
    p.add_argument("--data", required=True, help="dataset folder")
    p.add_argument("--episode", required=True, help="episode file stem, e.g. 12_rep0")
    p.add_argument("--out", type=out_arg, required=True, help="figure file (.png)")
    p.add_argument("--method", default="scimm", choices=tch.METHODS, help="posterior to plot (default scimm)")
    p.set_defaults(func=_plot)
