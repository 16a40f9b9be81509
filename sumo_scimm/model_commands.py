"""``sumo-scimm train`` and ``sumo-scimm reproduce``: the student's subcommands (docs/design.md §7, §8)."""
from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

from harness.common.errors import BadInput
from harness.common.lock import FolderLock
from sumo_scimm.options import add_backend_options, add_vehicle_option, backend_of, out_arg

# = model.train.EPOCHS, EPOCH_STEPS, PATIENCE, BATCH, EMA, LR, THREADS, ("none", *model.data.TEACHERS),
# model.loss.LossWeights()'s
# scimm and mode (a test checks); importing model.train here would load torch for every
# sumo-scimm command
EPOCHS = 8
EPOCH_STEPS = 400
PATIENCE = None
BATCH = 128
EMA = 0.0
LR = 1e-3
THREADS = 2
TEACHERS = ("none", "control", "fixed", "scimm", "smoother")
TEACHER_WEIGHT, MODE_WEIGHT = 1.0, 0.1
EVAL_SET = "town12_short"  # = model.reproduce.EVAL_SET
SECOND_SET = "town12_second"  # = model.reproduce.SECOND_SET


def _weight(text: str) -> float:
    """argparse type of --teacher-weight and --mode-weight: a finite number >= 0."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"invalid weight {text!r}: must be a finite number >= 0")
    return value


def _train(args: argparse.Namespace) -> int:
    if not args.data or not args.out:
        raise BadInput("train needs --data DIR and --out DIR (or 'train curves' to plot trainings)")
    given = [f"--{n}-weight" for n in ("teacher", "mode") if getattr(args, f"{n}_weight") is not None]
    if args.teacher == "none" and given:
        raise BadInput(f"{' and '.join(given)}: the baseline (--teacher none) has no teacher terms to weigh; "
                       "drop the option or choose a --teacher")
    from model.loss import LossWeights
    from model.train import TrainConfig, train  # torch is imported only when training
    weights = LossWeights(scimm=TEACHER_WEIGHT if args.teacher_weight is None else args.teacher_weight,
                          mode=MODE_WEIGHT if args.mode_weight is None else args.mode_weight)
    cfg = TrainConfig(data=Path(args.data), out=Path(args.out), teacher=args.teacher,
                      val=Path(args.val) if args.val else None, seed=args.seed, epochs=args.epochs,
                      epoch_steps=args.epoch_steps, patience=args.patience, batch=args.batch, ema=args.ema, lr=args.lr,
                      threads=args.threads,
                      cache_dir=Path(args.cache) if args.cache else None, weights=weights)
    with FolderLock(cfg.out):  # one command per output folder (harness.common.lock)
        print(f"model checkpoint: {train(cfg)}")
    return 0


def _curves(args: argparse.Namespace) -> int:
    from model.curves import plot_loss_curves
    runs: dict[str, Path] = {}
    for item in args.runs:
        arm, sep, folder = item.partition("=")
        if not sep or not arm or not folder or arm in runs:
            raise BadInput(f"--runs {item!r}: expected ARM=DIR with a new arm name, e.g. scimm=runs/student_scimm")
        runs[arm] = Path(folder)
    if not args.out.lower().endswith(".png"):
        raise BadInput(f"--out {args.out!r} must end in .png")
    print(plot_loss_curves(runs, Path(args.out)))
    return 0


def _checked_route_file(option: str, name: str) -> None:
    """BadInput unless route set or file ``name`` (of ``option``) passes 'sumo-scimm routes
    check', as eval checks its --routes before a route runs (harness.runs.evaluate)."""
    from harness.runs.evaluate import _route_set
    from scenarios import UnknownSet
    try:
        _route_set(name)
    except (UnknownSet, BadInput) as exc:
        raise BadInput(f"{option}: {exc}") from None


def _reproduce(args: argparse.Namespace) -> int:
    from model.reproduce import parse_seeds, reproduce, select_arms
    seeds = parse_seeds(args.seeds)
    for name in ("workers", "repetitions"):
        if getattr(args, name) < 1:
            raise BadInput(f"--{name} must be >= 1 (got {getattr(args, name)})")
    if args.epochs is not None and args.epochs < 1:
        raise BadInput(f"--epochs must be >= 1 (got {args.epochs})")
    backend = backend_of(args)
    backend.check()
    arms = select_arms(args.arms)
    sets = (args.train_routes, args.val_routes, args.eval_routes)
    second = None if args.second_routes == "none" else args.second_routes
    options = ("--train-routes", "--val-routes", "--eval-routes", "--second-routes")
    for option, name in zip(options, (*sets, second)):  # every route file, before the first stage
        if name is not None:
            _checked_route_file(option, name)
    with FolderLock(Path(args.out)):
        print(reproduce(Path(args.out), seeds, args.repetitions, args.epochs, backend, sets, arms, second,
                        args.vehicle))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``train`` and ``reproduce``."""
    tr = sub.add_parser("train", help="train the student on a collected dataset (docs/design.md §7); 'train curves' "
                        "plots loss curves",
                        description="Train the student (BEV + target point + speed -> path and speed "
                        "waypoints) on a 'collect' folder, optionally with teacher labels.")
    tr.add_argument("--data", help="training dataset folder (from 'sumo-scimm collect'); required")
    tr.add_argument("--teacher", choices=TEACHERS, default="none",
                    help="teacher labels from DATA/teacher/<method>; control: the expert's own labels in the "
                    "teacher terms (loss-matched control, no files) (default none = baseline)")
    tr.add_argument("--val", help="validation dataset folder: its L_origin after every epoch chooses the epoch "
                    "saved; without it the last epoch is saved")
    tr.add_argument("--seed", type=int, default=0, help="seed of weights, sample order, views (default 0)")
    tr.add_argument("--epochs", type=int, default=EPOCHS,
                    help=f"epochs; the learning-rate schedule spans them, the best on --val is saved "
                    f"(default {EPOCHS})")
    tr.add_argument("--epoch-steps", type=int, default=EPOCH_STEPS,
                    help=f"optimizer steps (of --batch samples) per epoch; 0 = a whole pass of the balanced draw "
                    f"(default {EPOCH_STEPS})")
    tr.add_argument("--patience", type=int, default=PATIENCE,
                    help="with --val: stop after P epochs without a new best validation loss (default: never, "
                    "the whole schedule runs)")
    tr.add_argument("--teacher-weight", type=_weight, metavar="L",
                    help=f"lambda_scimm of eq. 10, the teacher terms' weight (default {TEACHER_WEIGHT}; "
                    "not with --teacher none)")
    tr.add_argument("--mode-weight", type=_weight, metavar="M",
                    help=f"lambda_mode of eq. 10, the mode term's weight (default {MODE_WEIGHT}; "
                    "not with --teacher none)")
    tr.add_argument("--batch", type=int, default=BATCH, help=f"samples per optimizer step (default {BATCH})")
    tr.add_argument("--lr", type=float, default=LR,
                    help=f"peak learning rate of the warm-up and cosine schedule (default {LR:g})")
    tr.add_argument("--ema", type=float, default=EMA,
                    help=f"decay of the weight average that is validated and saved, e.g. 0.99; 0 = the raw "
                    f"weights (default {EMA:g})")
    tr.add_argument("--threads", type=int, default=THREADS,
                    help=f"torch threads; a training is deterministic at a given thread count ('reproduce' "
                    f"trains with 1, two students at a time) (default {THREADS})")
    tr.add_argument("--out", type=out_arg, help="output folder: student.pt, manifest.json and history.json; required")
    tr.add_argument("--cache", help="BEV cache folder (default DATA/cache), shared by trainings on the same data")
    tr.set_defaults(func=_train)
    trsub = tr.add_subparsers(dest="train_action", parser_class=type(tr), metavar="{curves}")
    c = trsub.add_parser("curves", help="loss curves of trained students, one figure (validation path and "
                         "speed losses, training loss, the chosen epoch ringed)")
    c.add_argument("--runs", nargs="+", required=True, metavar="ARM=DIR",
                   help="arm name and training folder (its history.json), e.g. baseline=runs/b scimm=runs/s")
    c.add_argument("--out", type=out_arg, required=True, help="figure file (.png)")
    c.set_defaults(func=_curves)

    r = sub.add_parser("reproduce", help="the paper's whole experiment: collect, teachers, train, eval, tables",
                       description="Collect -> teachers -> train baseline/control/fixed/scimm/smoother of every "
                       "seed, two at a time side by side -> "
                       f"eval on {EVAL_SET} and {SECOND_SET} -> Tables 2-4 against the baseline and the control, "
                       "Fig. 4-5. Resumes: finished stages are skipped.")
    r.add_argument("--seeds", default="1", help="training/evaluation seeds per arm: K for seeds 0..K-1, or A-B "
                   "for seeds A to B, added to the seeds already in --out (at most 1000 at once); the tables pool "
                   "every seed present (default 1)")
    r.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="simulation processes (default: cores)")
    r.add_argument("--repetitions", type=int, default=1,
                   help="expert drives of each training route (default 1; 2 gives > 100k frames)")
    r.add_argument("--epochs", type=int, help="training epochs (default: sumo-scimm train's)")
    r.add_argument("--out", type=out_arg, default="runs/reproduce", help="output folder (default runs/reproduce)")
    add_backend_options(r)  # for the collect and eval stages; training runs here
    add_vehicle_option(r)
    # other route sets (e.g. town12_smoke everywhere): to try the pipeline in minutes, not for results
    r.add_argument("--train-routes", default="train", help="training route set (default train)")
    r.add_argument("--val-routes", default="val", help="validation route set (default val)")
    r.add_argument("--eval-routes", default=EVAL_SET, help=f"evaluation route set (default {EVAL_SET})")
    r.add_argument("--arms", help="comma-separated arms to run, of baseline, control, fixed, scimm, smoother "
                   "(default all five)")
    r.add_argument("--second-routes", default=SECOND_SET,
                   help=f"second evaluation set every student also drives (default {SECOND_SET}; none: skip)")
    r.set_defaults(func=_reproduce)
