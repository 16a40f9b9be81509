"""``sumo-scimm train`` and ``sumo-scimm reproduce``: the student's subcommands (SPEC §7, §8)."""
from __future__ import annotations

import argparse
import os
from pathlib import Path

from harness.common.errors import BadInput
from sumo_scimm.options import add_backend_options, backend_of

# = model.train.EPOCHS (a test checks); importing model.train here would load torch for every
# sumo-scimm command
EPOCHS = 5
EVAL_SET = "town12_short"  # = model.reproduce.EVAL_SET


def _train(args: argparse.Namespace) -> int:
    from model.train import TrainConfig, train  # torch is imported only when training
    cfg = TrainConfig(data=Path(args.data), out=Path(args.out), teacher=args.teacher,
                      val=Path(args.val) if args.val else None, seed=args.seed, epochs=args.epochs,
                      cache_dir=Path(args.cache) if args.cache else None)
    print(f"model checkpoint: {train(cfg)}")
    return 0


def _reproduce(args: argparse.Namespace) -> int:
    from model.reproduce import reproduce
    from scenarios import UnknownSet, resolve_set
    for name in ("seeds", "workers", "repetitions"):
        if getattr(args, name) < 1:
            raise BadInput(f"--{name} must be >= 1 (got {getattr(args, name)})")
    if args.epochs is not None and args.epochs < 1:
        raise BadInput(f"--epochs must be >= 1 (got {args.epochs})")
    backend = backend_of(args)
    backend.check()
    sets = (args.train_routes, args.val_routes, args.eval_routes)
    for name in sets:
        try:
            resolve_set(name)
        except UnknownSet as exc:
            raise BadInput(str(exc)) from None
    print(reproduce(Path(args.out), args.seeds, args.repetitions, args.epochs, backend, sets))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``train`` and ``reproduce``."""
    tr = sub.add_parser("train", help="train the student on a collected dataset (SPEC §7)",
                        description="Train the student (BEV + target point + speed -> path and speed "
                        "waypoints) on a 'collect' folder, optionally with teacher labels.")
    tr.add_argument("--data", required=True, help="training dataset folder (from 'sumo-scimm collect')")
    tr.add_argument("--teacher", choices=("none", "fixed", "scimm", "smoother"), default="none",
                    help="teacher labels from DATA/teacher/<method> (default none = baseline)")
    tr.add_argument("--val", help="validation dataset folder; its L_origin is reported after every epoch")
    tr.add_argument("--seed", type=int, default=0, help="seed of weights, sample order, views (default 0)")
    tr.add_argument("--epochs", type=int, default=EPOCHS, help=f"passes over the data (default {EPOCHS})")
    tr.add_argument("--out", required=True, help="output folder: student.pt and manifest.json")
    tr.add_argument("--cache", help="BEV cache folder (default DATA/cache), shared by trainings on the same data")
    tr.set_defaults(func=_train)

    r = sub.add_parser("reproduce", help="the paper's whole experiment: collect, teachers, train, eval, tables",
                       description="Collect -> teachers -> train baseline/fixed/scimm/smoother per seed -> eval on "
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
