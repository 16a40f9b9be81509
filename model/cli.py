"""``sumo-scimm train ...`` subcommands (registered by ``sumo_scimm.cli``)."""
from __future__ import annotations

import argparse
from pathlib import Path

# = model.train.EPOCHS (tests/test_model.py checks); importing model.train here would load
# torch for every sumo-scimm command
EPOCHS = 5


def _train(args: argparse.Namespace) -> int:
    from model.train import TrainConfig, train  # torch is imported only when training
    cfg = TrainConfig(data=Path(args.data), out=Path(args.out), teacher=args.teacher,
                      val=Path(args.val) if args.val else None, seed=args.seed, epochs=args.epochs,
                      cache_dir=Path(args.cache) if args.cache else None)
    path = train(cfg)
    print(f"model checkpoint: {path}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add this stage's subcommands to the ``sumo-scimm`` parser."""
    tr = sub.add_parser("train", help="train the student on a collected dataset (SPEC §7)",
                        description="Train the student (BEV + target point + speed -> path and speed "
                        "waypoints) on a 'collect' folder, optionally with teacher labels.")
    tr.add_argument("--data", required=True, help="training dataset folder (from 'sumo-scimm collect')")
    tr.add_argument("--teacher", choices=("none", "fixed", "scimm"), default="none",
                    help="teacher labels from DATA/teacher/<method> (default none = baseline)")
    tr.add_argument("--val", help="validation dataset folder; its L_origin is reported after every epoch")
    tr.add_argument("--seed", type=int, default=0, help="seed of weights, sample order, views (default 0)")
    tr.add_argument("--epochs", type=int, default=EPOCHS, help=f"passes over the data (default {EPOCHS})")
    tr.add_argument("--out", required=True, help="output folder: student.pt and manifest.json")
    tr.add_argument("--cache", help="BEV cache folder (default DATA/cache), shared by trainings on the same data")
    tr.set_defaults(func=_train)
