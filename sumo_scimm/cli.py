"""The ``sumo-scimm`` command line: one subcommand per stage of the data flow (SPEC §1).

``main(argv) -> int`` is importable and testable. Bad input (unknown town or set,
malformed file, bad option, an output path that cannot be created or written) prints one
line ``sumo-scimm: error: ...`` naming the problem and the fix, and returns 2; no
traceback, no partial output.
"""
from __future__ import annotations

import os

# Before anything imports NumPy: no transparent huge pages for its large arrays. On this
# 2-core VM (THP "madvise", defrag "madvise") the IMM ran at a median of 122k frames per
# CPU-second with them and 156k without, 6 alternating fresh processes each (docs/teacher.md);
# the closed loop and the training did not move. Workers and the bench's IMM process
# inherit it; a value the user set is kept.
os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")

import argparse  # noqa: E402
import importlib  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402
import zipfile  # noqa: E402
from pathlib import Path  # noqa: E402

from sumo_scimm import world_commands as world_cli  # noqa: E402
from harness.loop.agent import DEFAULT_AGENT  # noqa: E402
from harness.common.atomic import write_atomic  # noqa: E402
from harness.loop.episode import AGENT_TIMEOUT  # noqa: E402
from harness.common.errors import BadInput  # noqa: F401,E402 - also imported from here by users and tests

EXIT_BAD_INPUT = 2
# Modules of later stages with a ``register(subparsers)`` adding their subcommands.
STAGE_CLIS = ("scimm.cli", "model.cli", "model.reproduce", "model.bench_cli")


class Terminated(KeyboardInterrupt):
    """SIGTERM (a scheduler's or ``kill``'s stop), raised in the main thread so a run ends as
    after a Ctrl-C: workers stopped, the records written so far complete, resumable."""


def _raise_terminated(signum, frame) -> None:
    raise Terminated()


def seed_arg(text: str) -> int:
    """argparse type of every --seed: an integer >= 0 (numpy's SeedSequence takes no negative)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"invalid seed {value}: must be >= 0")
    return value


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line (and exit code 2)."""

    def error(self, message: str) -> None:  # noqa: D401 - argparse API
        raise BadInput(f"{message} (see '{self.prog} --help')")


# --- eval -------------------------------------------------------------------------------
def _subset(spec: str | None, ids: list[str]) -> list[str]:
    """Route ids selected by --routes-subset: "3", "0-9", "1,4,7" or a mix."""
    if not spec:
        return ids
    chosen: list[str] = []
    for part in spec.split(","):
        part = part.strip()
        if "-" in part and all(p.strip().isdigit() for p in part.split("-", 1)):
            a, b = (int(p) for p in part.split("-", 1))
            chosen += [i for i in ids if i.isdigit() and a <= int(i) <= b]
        elif part in ids:
            chosen.append(part)
        else:
            raise BadInput(f"--routes-subset: no route {part!r} in the set")
    return [i for i in ids if i in set(chosen)]


def _check_run_options(args: argparse.Namespace) -> None:
    """Numbers and backend of eval / collect, checked before anything is read or written."""
    if args.workers is not None and args.workers < 1:
        raise BadInput(f"--workers {args.workers}: must be >= 1")
    if args.repetitions < 1:
        raise BadInput(f"--repetitions {args.repetitions}: must be >= 1")
    timeout = getattr(args, "agent_timeout", None)
    if timeout is not None and not (math.isfinite(timeout) and timeout > 0):
        raise BadInput(f"--agent-timeout {timeout}: must be a positive number of seconds")
    check_backend(args)


def check_backend(args: argparse.Namespace) -> None:
    """BadInput unless ``--backend`` / ``--address`` make sense and Ray is installed if asked for."""
    if args.address and args.backend != "ray":
        raise BadInput("--address needs --backend ray")
    if args.backend == "ray":
        from harness.runs.ray_backend import BackendError, check_available
        try:
            check_available()
        except BackendError as exc:
            raise BadInput(str(exc)) from None


def _run(jobs: list, out: Path, args: argparse.Namespace, **kwargs) -> list[dict]:
    """harness.runs.runner.run_eval on the chosen backend; a Ray that cannot be reached is bad input."""
    from harness.runs.ray_backend import BackendError
    from harness.runs.runner import run_eval
    try:
        return run_eval(jobs, out, args.workers, args.resume, backend=args.backend, address=args.address, **kwargs)
    except BackendError as exc:
        raise BadInput(str(exc)) from None


def check_agent(name: str, config: str | None) -> tuple[str, str | None]:
    """(agent, config) to run, checked: BadInput unless the agent loads and accepts its
    config (``--agent-config``, a file). ``--agent PATH.pt`` names a student checkpoint
    (SPEC §3): it is ``--agent student --agent-config PATH.pt``."""
    from harness.loop.agent import AgentLoadError, load_agent
    if name.endswith(".pt") and ":" not in name:
        if not Path(name).is_file():
            raise BadInput(f"--agent {name!r}: no such checkpoint file")
        if config and Path(config).resolve() != Path(name).resolve():
            raise BadInput(f"--agent {name!r} is a checkpoint: drop --agent-config {config!r}")
        name, config = "student", name
    if config and not Path(config).is_file():
        raise BadInput(f"--agent-config {config!r} does not exist")
    try:
        load_agent(name).check_config(config)
    except (AgentLoadError, ValueError, OSError) as exc:
        raise BadInput(str(exc)) from None
    return name, config


def _eval(args: argparse.Namespace) -> int:
    from harness.loop.agent import load_agent
    from harness.runs.runner import Job, route_seed, rss_summary
    from scenarios import resolve_set
    from scenarios.check import check_file
    from scenarios.routefile import read_routes
    _check_run_options(args)
    path = resolve_set(args.routes)
    _, problems = check_file(path)
    if problems:
        raise BadInput(f"{path}: {problems[0]} (run 'sumo-scimm routes check {path}')")
    args.agent, args.agent_config = check_agent(args.agent, args.agent_config)
    _, all_routes = read_routes(path)
    keep = set(_subset(args.routes_subset, [r.id for r in all_routes]))
    routes = [r for r in all_routes if r.id in keep]
    if not routes:
        raise BadInput(f"--routes-subset {args.routes_subset!r} selects no route of {path.name}")
    out = Path(args.out) if args.out else Path("runs") / f"{path.stem}_{args.agent.replace(':', '.')}"
    if not args.resume and (out / "records.jsonl").exists() and (out / "records.jsonl").stat().st_size:
        raise BadInput(f"{out} already holds a run: add --resume to finish it, or choose another --out")
    # a route's seed depends on its place in the whole set, not in the subset, so that
    # --routes-subset reruns a route exactly as the full run drove it
    place = {r.id: i for i, r in enumerate(all_routes)}
    jobs = [Job(k, r, rep, args.agent, args.agent_config, route_seed(args.seed, rep * len(all_routes) + place[r.id]),
                str(out / "logs"), args.rules, agent_timeout=args.agent_timeout)
            for k, (rep, r) in enumerate((rep, r) for rep in range(args.repetitions) for r in routes)]
    checkpoint = Path(args.checkpoint) if args.checkpoint else out / "results.json"
    sensors = [s["type"] for s in load_agent(args.agent).sensors()]
    records = _run(jobs, out, args, checkpoint=checkpoint, sensors=sensors)
    g = json.loads(checkpoint.read_text())["_checkpoint"]["global_record"]
    statuses: dict[str, int] = {}
    for r in records:
        statuses[r["status"]] = statuses.get(r["status"], 0) + 1
    m = g["scores_mean"]
    print(f"{len(records)} routes -> {out}: DS {m['score_composed']:.2f}, RC {m['score_route']:.2f}, "
          f"IS {m['score_penalty']:.3f}; " + ", ".join(f"{k} {v}" for k, v in sorted(statuses.items())))
    mem = rss_summary(out)
    if mem is not None:
        print(f"worker memory: {mem['workers']} processes, up to {mem['max_routes_per_worker']} routes each; "
              f"RSS after first route {mem['first_mb']:.0f} MB, peak {mem['peak_mb']:.0f} MB, "
              f"growth {mem['growth_mb']:+.1f} MB (trend {mem['slope_mb_per_100']:+.2f} MB per 100 routes)")
    return 0


def _render(args: argparse.Namespace) -> int:
    from harness.loop.render import render_route
    from harness.runs.runner import route_seed
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
    res, png = render_route(routes[k], args.agent, args.agent_config, route_seed(args.seed, k), Path(args.out))
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
    from harness.scoring.scores import ScoreError, rescore_results
    path = Path(args.results)
    if not path.is_file():
        raise BadInput(f"{path}: no such results file")
    try:
        data = json.loads(path.read_text())
        out = rescore_results(data, args.rules)
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise BadInput(f"{path}: not JSON ({exc})") from None
    except (ScoreError, KeyError, TypeError, ValueError, IndexError, AttributeError, OverflowError) as exc:
        raise BadInput(f"{path}: not a Leaderboard results file ({exc})") from None
    text = json.dumps(out, indent=2) + "\n"
    if args.out:
        write_atomic(Path(args.out), text)
        g = out["_checkpoint"]["global_record"]["scores_mean"]
        print(f"{args.out}: DS {g['score_composed']}, RC {g['score_route']}, IS {g['score_penalty']}")
    else:
        sys.stdout.write(text)
    return 0


def _report(args: argparse.Namespace) -> int:
    from harness.scoring.report import ReportError, write_report
    try:
        print(write_report([Path(d) for d in args.runs], Path(args.out)))
    except ReportError as exc:
        raise BadInput(str(exc)) from None
    return 0


def _collect(args: argparse.Namespace) -> int:
    from harness.expert.dataset import build_index, describe
    from harness.runs.runner import Job, route_seed
    from scenarios import resolve_set
    from scenarios.check import check_file
    from scenarios.routefile import read_routes
    _check_run_options(args)
    path = resolve_set(args.routes).resolve()
    _, problems = check_file(path)
    if problems:
        raise BadInput(f"{path}: {problems[0]} (run 'sumo-scimm routes check {path}')")
    out = Path(args.out)
    if not args.resume and (out / "records.jsonl").exists() and (out / "records.jsonl").stat().st_size:
        raise BadInput(f"{out} already holds a collection: add --resume to finish it, or choose another --out")
    _, routes = read_routes(path)
    jobs = [Job(k, r, rep, "expert", None, route_seed(args.seed, k), str(out / "logs"),
                collect_dir=str(out / "episodes"), route_file=str(path))
            for k, (rep, r) in enumerate((rep, r) for rep in range(args.repetitions) for r in routes)]
    _run(jobs, out, args, sensors=["pose", "speed", "world"])
    print(describe(build_index(out)))
    return 0


def _data_show(args: argparse.Namespace) -> int:
    import pandas as pd
    from harness.expert.dataset import build_index, describe
    folder = Path(args.dir)
    if not (folder / "episodes").is_dir():
        raise BadInput(f"{folder} is not a dataset folder (no episodes/; make one with 'sumo-scimm collect')")
    if not any((folder / "episodes").glob("*.npz")):
        raise BadInput(f"{folder}/episodes holds no episode: finish the collection with 'sumo-scimm collect ... "
                       "--resume'")
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


def add_backend_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--backend", default="local", choices=("local", "ray"),
                   help="local worker processes, or Ray tasks (needs the 'ray' extra; see docs/scale.md)")
    p.add_argument("--address", help="Ray cluster to join (host:port of its head, ray://host:port, or auto); "
                   "default: a local Ray on --workers CPUs")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="sumo-scimm", description="Closed-loop driving benchmark on SUMO with "
                "Leaderboard 2.0 scoring and SC-IMM teacher signals.")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    world_cli.register(sub)  # nets, routes
    e = sub.add_parser("eval", help="drive a route set with an agent in closed loop")
    e.add_argument("--routes", required=True, help="route set name (e.g. town12_short) or route file")
    e.add_argument("--routes-subset", help="route ids to run: '3', '0-9', '1,4,7'")
    e.add_argument("--repetitions", type=int, default=1, help="runs per route (default 1)")
    e.add_argument("--agent", default=DEFAULT_AGENT,
                   help=f"agent name, module:Class, or a student checkpoint (.pt) (default {DEFAULT_AGENT})")
    e.add_argument("--agent-config", help="file passed to the agent's setup()")
    e.add_argument("--workers", type=int, default=None,
                   help="worker processes, one libsumo each (default: number of cores; with --backend ray, "
                        "every CPU of the Ray cluster)")
    e.add_argument("--out", help="run folder (default runs/<set>_<agent>)")
    e.add_argument("--resume", action="store_true", help="finish an interrupted run in --out")
    e.add_argument("--seed", type=seed_arg, default=0, help="run seed; each route derives its own (default 0)")
    e.add_argument("--checkpoint", help="Leaderboard results JSON (default <out>/results.json)")
    e.add_argument("--rules", default="lb2.0", choices=("lb2.0", "lb2.1", "b2d"),
                   help="scoring rules (default lb2.0)")
    e.add_argument("--agent-timeout", type=float, default=AGENT_TIMEOUT,
                   help=f"seconds one run_step may take before the route ends as 'Failed - Agent crashed' "
                        f"(default {AGENT_TIMEOUT:g})")
    add_backend_options(e)
    e.set_defaults(func=_eval)

    r = sub.add_parser("render", help="video of the BEV while an agent drives one route, and a path PNG; "
                       "or, with --runs, the waypoint overlay of eval runs (paper Fig. 5)")
    r.add_argument("--routes", help="route set name or route file (to drive the route)")
    r.add_argument("--route", required=True, help="route id")
    r.add_argument("--runs", nargs="+", metavar="DIR",
                   help="eval run folders: draw their predicted paths on --route (Fig. 5, --out F.png) "
                        "instead of driving it")
    r.add_argument("--agent", default=DEFAULT_AGENT,
                   help=f"agent name, module:Class, or a student checkpoint (.pt) (default {DEFAULT_AGENT})")
    r.add_argument("--agent-config", help="file passed to the agent's setup()")
    r.add_argument("--out", required=True, help="video file (.mp4; the path PNG goes beside it), or with "
                   "--runs the figure (.png)")
    r.add_argument("--seed", type=seed_arg, default=0, help="run seed, as in eval (default 0)")
    r.set_defaults(func=_render)

    sc = sub.add_parser("score", help="recompute the scores of a Leaderboard results JSON (ours or CARLA's)")
    sc.add_argument("results", help="results JSON (the leaderboard's --checkpoint file)")
    sc.add_argument("--rules", default="lb2.0", choices=("lb2.0", "lb2.1", "b2d"), help="default lb2.0")
    sc.add_argument("--out", help="write the rescored JSON here (default: print it)")
    sc.set_defaults(func=_score)

    rp = sub.add_parser("report", help="the paper's Tables 3 and 4 for several run folders")
    rp.add_argument("runs", nargs="+", help="run folders of 'sumo-scimm eval'; the first is the baseline")
    rp.add_argument("--out", default="report", help="folder for table3/table4 .csv and .md (default report)")
    rp.set_defaults(func=_report)

    co = sub.add_parser("collect", help="drive the expert over a route set and record a dataset at 4 Hz")
    co.add_argument("--routes", required=True, help="route set name or route file (e.g. train)")
    co.add_argument("--out", required=True, help="dataset folder")
    co.add_argument("--workers", type=int, default=None,
                    help="worker processes (default: cores; with --backend ray, every CPU of the cluster)")
    co.add_argument("--repetitions", type=int, default=1, help="runs per route, each with its own seed (default 1)")
    co.add_argument("--seed", type=seed_arg, default=0, help="run seed (default 0)")
    co.add_argument("--resume", action="store_true", help="finish an interrupted collection")
    add_backend_options(co)
    co.set_defaults(func=_collect)

    da = sub.add_parser("data", help="describe a dataset")
    dsub = da.add_subparsers(dest="action", required=True, parser_class=_Parser)
    dshow = dsub.add_parser("show", help="frames, hours, share of frames per situation, per town")
    dshow.add_argument("dir")
    dshow.set_defaults(func=_data_show)

    # Later stages add their own subcommands (teacher, train, reproduce, bench): the CLI is the one
    # place that sees every stage, so it imports them here by name and nowhere else.
    for name in STAGE_CLIS:
        importlib.import_module(name).register(sub)
    return p


_depth = 0  # how many main() calls are running: reproduce and bench run their stages through main


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the process exit code. A Ctrl-C or SIGTERM ends the outermost
    call (a stage run by reproduce passes it on rather than failing as a stage)."""
    from scenarios import UnknownSet
    from scenarios.routefile import RouteFileError
    from sumo_nets import UnknownTown
    global _depth
    outer = _depth == 0
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _raise_terminated) if in_main else None
    _depth += 1
    try:
        args = build_parser().parse_args(argv)
        return args.func(args)
    except (BadInput, UnknownTown, UnknownSet, RouteFileError) as exc:
        print(f"sumo-scimm: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:  # a path the command cannot create, read or write (a run's own failures are records)
        where = f": {exc.filename}" if exc.filename else ""
        print(f"sumo-scimm: error: {exc.strerror or exc}{where} (check the path: its folder must exist or "
              "be creatable, and be writable)", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt as exc:
        if not outer:
            raise
        if isinstance(exc, Terminated):
            print("sumo-scimm: terminated (SIGTERM)", file=sys.stderr)
            return 128 + signal.SIGTERM
        print("sumo-scimm: interrupted", file=sys.stderr)
        return 130
    finally:
        _depth -= 1
        if in_main and previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    # run through the imported module, which reproduce and bench call too (one _depth)
    from sumo_scimm.cli import main as _main
    sys.exit(_main())
