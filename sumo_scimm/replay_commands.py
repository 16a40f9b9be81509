"""``sumo-scimm replay``: several agents fed the identical inputs of a reference run, their
output stability compared route-paired (harness.runs.replay, docs/design.md §9)."""
from __future__ import annotations

import argparse
from pathlib import Path

from harness.loop.deadline import AGENT_TIMEOUT
from sumo_scimm.options import out_arg


def _replay(args: argparse.Namespace) -> int:
    from harness.runs.replay import replay
    from harness.runs.evaluate import check_workers
    check_workers(args.workers)
    md = replay(Path(args.run), args.agent, Path(args.out), routes=args.routes, subset=args.routes_subset,
                workers=args.workers, agent_timeout=args.agent_timeout)
    print(md)
    print(f"-> {args.out}/replay.csv, table.csv, table.md, outputs/")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``sumo-scimm replay``."""
    rp = sub.add_parser("replay", help="feed agents the identical inputs of a reference run and compare the "
                        "stability of their outputs")
    rp.add_argument("--run", required=True, help="reference run folder of 'sumo-scimm eval' (any agent's)")
    rp.add_argument("--agent", action="append", required=True,
                    help="agent to replay (name, module:Class or a student checkpoint .pt); repeat for several, "
                         "the first is the one the others are compared with")
    rp.add_argument("--out", type=out_arg, required=True,
                    help="output folder (replay.csv, table.csv|md, replay.json, outputs/)")
    rp.add_argument("--routes", help="route set or file the reference drove (default: found among the shipped "
                    "sets by the routes' hashes in its run.jsonc)")
    rp.add_argument("--routes-subset", help="route ids to replay: '3', '0-9', '1,4,7' (default all)")
    rp.add_argument("--workers", type=int, default=None, help="worker processes (default: number of cores)")
    rp.add_argument("--agent-timeout", type=float, default=AGENT_TIMEOUT,
                    help=f"seconds one agent call (run_step, setup, ...) may take before the agent's row of the "
                         f"route is a failure (default {AGENT_TIMEOUT:g})")
    rp.set_defaults(func=_replay)
