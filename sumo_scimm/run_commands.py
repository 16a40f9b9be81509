"""``sumo-scimm eval``, ``render``, ``score``, ``report``, ``collect`` and ``data``: the
closed loop's subcommands (docs/design.md §3, §5, §9). Each parses its options, calls the stage
function (harness.runs.evaluate, harness.loop.render, harness.scoring) and prints the result."""
from __future__ import annotations

import argparse
import gzip
import json
import math
import sys
import zipfile
from pathlib import Path

from files.atomic import write_atomic
from files.compressed import read_text, stored
from harness.common.errors import BadInput
from harness.loop.deadline import AGENT_TIMEOUT
from sumo_scimm.options import add_agent_options, add_backend_options, add_vehicle_option, backend_of, out_arg, seed_arg

RULES = ("lb2.0", "lb2.1", "b2d")


def _eval(args: argparse.Namespace) -> int:
    from harness.runs.evaluate import evaluate
    res = evaluate(args.routes, args.agent, args.agent_config, Path(args.out) if args.out else None,
                   subset=args.routes_subset, repetitions=args.repetitions, seed=args.seed, resume=args.resume,
                   checkpoint=Path(args.checkpoint) if args.checkpoint else None, rules=args.rules,
                   agent_timeout=args.agent_timeout, backend=backend_of(args), vehicle=args.vehicle)
    from harness.scoring.outputs import success_rate
    m = res.global_record["scores_mean"]
    print(f"{len(res.records)} routes -> {res.out}: DS {m['score_composed']:.2f}, RC {m['score_route']:.2f}, "
          f"IS {m['score_penalty']:.3f}, SR {success_rate(res.records):.1f} %; "
          + ", ".join(f"{k} {v}" for k, v in res.statuses().items()))
    mem = res.memory
    if mem is not None:
        print(f"worker memory: {mem['workers']} processes, up to {mem['max_routes_per_worker']} routes each; "
              f"RSS after first route {mem['first_mb']:.0f} MB, peak {mem['peak_mb']:.0f} MB, "
              f"growth {mem['growth_mb']:+.1f} MB ({memory_trend(mem['slope_mb_per_100'])})")
    return 0


def memory_trend(slope_mb_per_100: float) -> str:
    """The eval line's worker-memory trend: a least-squares slope needs a worker that ran at
    least 3 routes (harness.runs.runner.rss_summary), else there is none to print."""
    if math.isfinite(slope_mb_per_100):
        return f"trend {slope_mb_per_100:+.2f} MB per 100 routes"
    return "no trend: no worker ran 3 routes"


def _render(args: argparse.Namespace) -> int:
    from harness.loop.agent import check_agent
    from harness.loop.render import render_route
    from harness.runs.jobs import route_seed
    from scenarios import resolve_set
    from scenarios.routefile import read_routes
    if args.runs:
        return _render_overlay(args)
    if not args.routes:
        raise BadInput("render needs --routes SET (to drive the route), or --runs DIR... (to draw the "
                       "waypoint overlay of eval runs)")
    path = resolve_set(args.routes)
    _, routes = read_routes(path)
    ids = [r.id for r in routes]
    if args.route not in ids:
        raise BadInput(f"route {args.route!r} is not in {path.name} (ids {ids[0]}..{ids[-1]})")
    if not args.out.endswith(".mp4"):
        raise BadInput(f"--out {args.out!r} must end in .mp4 (a PNG of the path is written beside it)")
    args.agent, args.agent_config = check_agent(args.agent, args.agent_config)
    k = ids.index(args.route)
    res, png = render_route(routes[k], args.agent, args.agent_config, route_seed(args.seed, k), Path(args.out),
                            vehicle=args.vehicle)
    print(f"route {args.route}: {res.status}, RC {res.rc:.2f}, {res.game_time:.1f} s -> {args.out}, {png}")
    return 0


def _render_overlay(args: argparse.Namespace) -> int:
    """Paper Fig. 5 from eval run folders: each run's consecutive predicted paths of route
    --route (repetition 0) near the point where the first run steered hardest."""
    from harness.scoring.figures import waypoint_overlay
    if not args.out.lower().endswith(".png"):
        raise BadInput(f"--out {args.out!r} must end in .png for the waypoint overlay of --runs")
    folders = [Path(d) for d in args.runs]
    key = f"{args.route}_rep0"
    for f in folders:
        if not (f / "logs" / f"{key}.npz").is_file():
            raise BadInput(f"{f}: no log of route {args.route} (logs/{key}.npz); pass run folders of "
                           "'sumo-scimm eval' that drove it")
    names = [f.name for f in folders]
    runs = {(f.name if names.count(f.name) == 1 else str(f)): f for f in folders}
    out = waypoint_overlay(runs, key, Path(args.out))
    print(f"route {args.route}: waypoint overlay of {', '.join(runs)} -> {out}")
    return 0


def _score(args: argparse.Namespace) -> int:
    from harness.scoring.scores import NOT_RESULTS, ScoreError, rescore_results, results_text
    path = Path(args.results)
    if stored(path) is None:
        raise BadInput(f"{path}: no such results file")
    notes: list[str] = []
    try:
        data = json.loads(read_text(path))  # plain or gzip-compressed (files.compressed)
        out = rescore_results(data, args.rules, notes)
        text = results_text(out) + "\n"  # numbers checked finite (harness.scoring.validate); others: ValueError
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise BadInput(f"{path}: not JSON ({exc})") from None
    except gzip.BadGzipFile as exc:  # a damaged .gz (files.compressed)
        raise BadInput(f"{path}: not a readable gzip file ({exc})") from None
    except ScoreError as exc:  # one complete sentence
        raise BadInput(f"{path}: {exc}") from None
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, OverflowError) as exc:
        raise BadInput(f"{path}: {NOT_RESULTS} ({type(exc).__name__}: {exc})") from None
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)  # as eval's, report's and replay's --out
        write_atomic(Path(args.out), text)
        g = out["_checkpoint"]["global_record"]
        done, total = out["_checkpoint"]["progress"][:2]
        print(f"{args.out}: DS {g['scores_mean']['score_composed']}, RC {g['scores_mean']['score_route']}, "
              f"IS {g['scores_mean']['score_penalty']}" if g else
              f"{args.out}: {done} of {total} route runs, {out['entry_status']}: route scores only (the "
              "leaderboard writes the global record when every route has run)")
    else:
        sys.stdout.write(text)
    return 0


def _report(args: argparse.Namespace) -> int:
    from harness.common.lock import FolderLock
    from harness.scoring.b2d_tables import without_records
    from harness.scoring.report import ReportError, parse_arms
    from model.arm_tables import write_set_tables  # the tables of 'sumo-scimm reproduce'
    try:
        arms = parse_arms(args.runs)
        with FolderLock(Path(args.out)):
            print(write_set_tables(arms, Path(args.out))[0])
    except ReportError as exc:
        raise BadInput(str(exc)) from None
    short = without_records(arms)
    if short:  # an archive that keeps records.csv and results.json alone
        print(f"note: no records.jsonl in {short[0]}" + (f" and {len(short) - 1} more" if len(short) > 1 else "")
              + ": Bench2Drive's tables and the DS per hazard type need it and were not written", file=sys.stderr)
    return 0


def _collect(args: argparse.Namespace) -> int:
    from harness.expert.dataset import describe
    from harness.runs.evaluate import collect
    index = collect(args.routes, Path(args.out), repetitions=args.repetitions, seed=args.seed, resume=args.resume,
                    backend=backend_of(args), vehicle=args.vehicle)
    print(describe(index))
    return 0


def _data_show(args: argparse.Namespace) -> int:
    import pandas as pd

    from harness.expert.dataset import build_index, describe, episode_files
    folder = Path(args.dir)
    if not (folder / "episodes").is_dir():
        raise BadInput(f"{folder} is not a dataset folder (no episodes/; make one with 'sumo-scimm collect')")
    if not any((folder / "episodes").glob("*.npz")):
        raise BadInput(f"{folder}/episodes holds no episode: finish the collection with 'sumo-scimm collect ... "
                       "--resume'")
    episode_files(folder)  # BadInput if an episode has no record (a stopped collection)
    path = folder / "index.csv"
    try:  # the index collect wrote, or one read from the episodes (show writes nothing)
        index = pd.read_csv(path) if path.is_file() else build_index(folder, write=False)
        text = describe(index)
    except (ValueError, KeyError, OSError, pd.errors.ParserError, zipfile.BadZipFile) as exc:
        fix = (f"{path} is damaged: delete it (data show then reads the episodes)" if path.is_file() else
               f"an episode file in {folder}/episodes is damaged: collect the dataset again into a new folder")
        raise BadInput(f"{fix} ({type(exc).__name__}: {exc})") from None
    print(text)
    return 0


def _add_eval(sub: argparse._SubParsersAction) -> None:
    e = sub.add_parser("eval", help="drive a route set with an agent in closed loop")
    e.add_argument("--routes", required=True, help="route set name (e.g. town12_short) or route file")
    e.add_argument("--routes-subset", help="route ids to run: '3', '0-9', '1,4,7'")
    e.add_argument("--repetitions", type=int, default=1, help="runs per route (default 1)")
    add_agent_options(e)
    e.add_argument("--workers", type=int, default=None,
                   help="worker processes, one libsumo each (default: number of cores; with --backend ray, "
                        "every CPU of the Ray cluster)")
    e.add_argument("--out", type=out_arg, help="run folder (default runs/<set>_<agent>)")
    e.add_argument("--resume", action="store_true", help="finish an interrupted run in --out")
    e.add_argument("--seed", type=seed_arg, default=0, help="run seed; each route derives its own (default 0)")
    e.add_argument("--checkpoint", help="Leaderboard results JSON (default <out>/results.json)")
    e.add_argument("--rules", default="lb2.0", choices=RULES, help="scoring rules (default lb2.0)")
    e.add_argument("--agent-timeout", type=float, default=AGENT_TIMEOUT,
                   help=f"seconds one agent call (run_step, setup, ...) may take before the route ends as "
                        f"'Failed - Agent crashed' (on Ray: 'Failed - Simulation crashed') (default {AGENT_TIMEOUT:g})")
    add_vehicle_option(e)
    add_backend_options(e)
    e.set_defaults(func=_eval)


def register(sub: argparse._SubParsersAction) -> None:
    """Add eval, render, score, report, collect and data."""
    _add_eval(sub)
    r = sub.add_parser("render", help="video of the BEV while an agent drives one route, and a path PNG; "
                       "or, with --runs, the waypoint overlay of eval runs (paper Fig. 5)")
    r.add_argument("--routes", help="route set name or route file (to drive the route)")
    r.add_argument("--route", required=True, help="route id")
    r.add_argument("--runs", nargs="+", metavar="DIR",
                   help="eval run folders: draw their predicted paths on --route (Fig. 5, --out F.png) "
                        "instead of driving it")
    add_agent_options(r)
    r.add_argument("--out", type=out_arg, required=True, help="video file (.mp4; the path PNG goes beside it), or with "
                   "--runs the figure (.png)")
    r.add_argument("--seed", type=seed_arg, default=0, help="run seed, as in eval (default 0)")
    add_vehicle_option(r)
    r.set_defaults(func=_render)

    sc = sub.add_parser("score", help="recompute the scores of a Leaderboard results JSON (ours or CARLA's)")
    sc.add_argument("results", help="results JSON (the leaderboard's --checkpoint file), plain or .gz")
    sc.add_argument("--rules", default="lb2.0", choices=RULES, help="default lb2.0")
    sc.add_argument("--out", type=out_arg, help="write the rescored JSON here (default: print it)")
    sc.set_defaults(func=_score)

    rp = sub.add_parser("report", help="the paper's Tables 3 and 4 for several arms, with seed-paired intervals")
    rp.add_argument("runs", nargs="+", metavar="ARM",
                    help="run folder of 'sumo-scimm eval' (its records.csv and results.json plain or .gz), "
                         "or NAME=DIR[,DIR...] for an arm of several runs (seeds, in seed order: the i-th "
                         "folder of every arm is paired with the i-th of the others); the reference arms are "
                         "'baseline' and 'control' when present, else the first arm")
    rp.add_argument("--out", type=out_arg, default="report",
                    help="folder for the tables as .csv and .md: table3, table4 (and _common, _vs_control), "
                         "claims (the paper's claims, Holm-corrected), hazard_ds, b2d, per_hazard "
                         "(default report)")
    rp.set_defaults(func=_report)

    co = sub.add_parser("collect", help="drive the expert over a route set and record a dataset at 4 Hz")
    co.add_argument("--routes", required=True, help="route set name or route file (e.g. train)")
    co.add_argument("--out", type=out_arg, required=True, help="dataset folder")
    co.add_argument("--workers", type=int, default=None,
                    help="worker processes (default: cores; with --backend ray, every CPU of the cluster)")
    co.add_argument("--repetitions", type=int, default=1, help="runs per route, each with its own seed (default 1)")
    co.add_argument("--seed", type=seed_arg, default=0, help="run seed (default 0)")
    co.add_argument("--resume", action="store_true", help="finish an interrupted collection")
    add_vehicle_option(co)
    add_backend_options(co)
    co.set_defaults(func=_collect)

    da = sub.add_parser("data", help="describe a dataset")
    dsub = da.add_subparsers(dest="action", required=True, parser_class=type(da))
    dshow = dsub.add_parser("show", help="frames, hours, share of frames per situation, per town")
    dshow.add_argument("dir")
    dshow.set_defaults(func=_data_show)
