"""``sumo-scimm nets ...`` and ``sumo-scimm routes ...``: the towns and the route sets
(docs/design.md §2), registered by ``sumo_scimm.cli``. Bad input raises ``harness.common.errors.BadInput``."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from harness.common.errors import BadInput
from harness.common.lock import FolderLock
from harness.common.progress import progress
from sumo_scimm.options import EXIT_BAD_INPUT, out_arg, seed_arg


# --- nets -------------------------------------------------------------------------------
def _nets_build(args: argparse.Namespace) -> int:
    import sumo_nets
    towns = [sumo_nets.check_town(args.town)] if args.town else list(sumo_nets.TOWNS)
    if args.seed is not None and len(towns) != 1:
        raise BadInput("--seed needs --town (each town has its own default seed)")
    out = Path(args.out) if args.out else sumo_nets.NETS_DIR
    with FolderLock(out):  # one command per output folder (harness.common.lock)
        bar = progress(towns, desc="netconvert", unit="town")
        for town in bar:
            path = sumo_nets.build(town, args.seed, out)
            bar.write(f"{town}: {path}")  # above the bar on a terminal
    return 0


def _nets_show(args: argparse.Namespace) -> int:
    import sumo_nets
    from sumo_nets.stats import format_stats, net_stats
    towns = [sumo_nets.check_town(args.town)] if args.town else list(sumo_nets.TOWNS)
    rows = {t: net_stats(sumo_nets.net_path(t)) for t in towns}
    print(json.dumps(rows, indent=2) if args.json else format_stats(rows))
    return 0


# --- routes -----------------------------------------------------------------------------
def _routes_make(args: argparse.Namespace) -> int:
    from scenarios import SETS, set_path
    from scenarios.make import make_set
    from scenarios.routefile import write_routes
    if args.set not in SETS:
        raise BadInput(f"unknown set {args.set!r} (buildable: {', '.join(SETS)})")
    spec = SETS[args.set]
    total = sum(n for _, n in spec.towns)
    with progress(total=total, desc=f"routes {args.set}", unit="route") as bar:
        routes = make_set(args.set, args.seed, progress=bar.update)
    meta = {"set": args.set, "seed": str(spec.seed if args.seed is None else args.seed),
            "min_length": f"{spec.length[0]:g}", "max_length": f"{spec.length[1]:g}"}
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)  # as eval's, report's and replay's --out
    out = write_routes(Path(args.out) if args.out else set_path(args.set), meta, routes)
    print(f"{len(routes)} routes -> {out}")
    return 0


def _routes_check(args: argparse.Namespace) -> int:
    from scenarios.check import check_file, problem_line
    path = Path(args.file)
    n, problems = check_file(path)
    for p in problems:
        print(problem_line(path, p))
    if problems:
        return EXIT_BAD_INPUT
    print(f"{path}: {n} routes OK")
    return 0


def _routes_show(args: argparse.Namespace) -> int:
    from scenarios import resolve_set
    from scenarios.show import show_set
    print(show_set(resolve_set(args.name)))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``nets build|show`` and ``routes make|check|show``."""
    nets = sub.add_parser("nets", help="build or describe the town networks")
    nsub = nets.add_subparsers(dest="action", required=True, parser_class=type(nets))
    b = nsub.add_parser("build", help="rebuild town nets with netconvert (seeded, reproducible)")
    b.add_argument("--town", help="one town (default: all)")
    b.add_argument("--seed", type=seed_arg, help="builder seed (default: the town's own)")
    b.add_argument("--out", type=out_arg, help="output folder (default: the package's nets folder)")
    b.set_defaults(func=_nets_build)
    s = nsub.add_parser("show", help="size, junctions, road length, curved share, crossings")
    s.add_argument("--town", help="one town (default: all)")
    s.add_argument("--json", action="store_true", help="print JSON instead of a table")
    s.set_defaults(func=_nets_show)

    routes = sub.add_parser("routes", help="build, check or list route sets")
    rsub = routes.add_subparsers(dest="action", required=True, parser_class=type(routes))
    m = rsub.add_parser("make", help="build a route set from its seeded builder")
    m.add_argument("--set", required=True, help="set name (town12_short, town12_smoke, train, val, town12_second)")
    m.add_argument("--seed", type=seed_arg, help="builder seed (default: the set's own)")
    m.add_argument("--out", type=out_arg, help="output file (default: scenarios/<set>.xml)")
    m.set_defaults(func=_routes_make)
    c = rsub.add_parser("check", help="validate a route file: one line per bad route, exit 2")
    c.add_argument("file")
    c.set_defaults(func=_routes_check)
    w = rsub.add_parser("show", help="table of a route set: id, town, length, hazards")
    w.add_argument("name", help="set name or route file")
    w.set_defaults(func=_routes_show)
