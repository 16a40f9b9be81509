"""``sumo-scimm bench``: every performance figure of SPEC §11, each beside its reference
measured in the same run, printed as a table and optionally written as JSON.

- closed loop (``harness.runs.bench``): harness step with the chosen agent against bare libsumo
  stepping of the same traffic with the ego replayed, plus, for a student, its bare
  inference (its own checkpoint's ``predict`` on inputs recorded in the same episodes, one
  thread), and, for reading, the libsumo replay with that network run between steps and
  the ratio's floor (SUMO and the network alternating, nothing else); BEV render;
- teacher (``scimm.bench``): batched IMM frames per second on one core against filterpy's
  IMMEstimator on the same sequences, and the largest difference between them;
- student (``model.bench``): training samples per second on 2 threads, inference ms per
  frame at batch 1 on one thread;
- collect (``harness.runs.bench.collect_rate``): simulated seconds per wall second of one worker
  recording the expert as ``sumo-scimm collect`` does;
- with ``--eval``: wall time of a whole ``town12_short`` evaluation on 2 workers with the
  agent, and the worker memory (RSS) over it.

The closed-loop figures and the IMM's are the median of ``--rounds`` passes (fresh
processes for the IMM), every pass printed and written beside it.

The run prints and writes the machine it ran on (CPU model, cores, torch's kernels,
versions). Figures are for reading, never asserted in a test; they depend on the machine
and its load.
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import tempfile
import time
from pathlib import Path

from harness.loop.agent import DEFAULT_AGENT
from harness.common.atomic import write_atomic

EVAL_TARGET_S, OVERHEAD_TARGET, RSS_TARGET_MB, REPRODUCE_TARGET_S = 180.0, 2.0, 800.0, 3600.0


def _eval_figures(agent: str, agent_config: str | None, workers: int, routes: str = "town12_short",
                  repetitions: int = 1) -> dict:
    """Wall time and worker memory of ``sumo-scimm eval`` on ``routes`` (``repetitions``
    passes) with ``workers`` workers, in a temporary run folder."""
    from sumo_scimm.cli import main
    from harness.runs.runner import rss_summary
    with tempfile.TemporaryDirectory(prefix="sumo-scimm-bench-") as tmp:
        argv = ["eval", "--routes", routes, "--agent", agent, "--workers", str(workers), "--out", tmp + "/run",
                "--repetitions", str(repetitions)]
        t0 = time.perf_counter()
        if main(argv + (["--agent-config", agent_config] if agent_config else [])) != 0:
            raise RuntimeError(f"the {routes} evaluation failed")
        wall = time.perf_counter() - t0
        rss = rss_summary(Path(tmp) / "run")
        return {"eval_wall_s": round(wall, 1), "eval_workers": workers, "eval_target_s": EVAL_TARGET_S,
                "rss": rss, "rss_target_mb": RSS_TARGET_MB, "routes": routes, "repetitions": repetitions,
                "route_runs": len((Path(tmp) / "run" / "records.jsonl").read_text().splitlines())}


def _reproduce_figure(folder: str) -> dict:
    """The stage wall times a finished ``sumo-scimm reproduce`` recorded in FOLDER/stages.json
    (measured when it ran, not now: reproduce takes about an hour)."""
    from harness.common.errors import BadInput
    path = Path(folder) / "stages.json"
    try:
        times = json.loads(path.read_text())
        total = float(sum(times.values()))
    except (OSError, ValueError, TypeError, AttributeError) as exc:
        raise BadInput(f"--reproduce {folder}: no readable stages.json of 'sumo-scimm reproduce' ({exc})") from None
    return {"reproduce_dir": str(folder), "reproduce_wall_s": round(total, 1), "stages": len(times),
            "reproduce_target_s": REPRODUCE_TARGET_S}


def machine() -> dict:
    """What the figures were measured on: CPU model, cores, the kernels torch picked, and the
    versions that set the per-tick cost (torch trains the student, ONNX Runtime runs it in
    the closed loop). Figures of two runs compare only on the same kind of machine (and a
    student's records only on the same CPU type: docs/reliability.md)."""
    import importlib.metadata
    import os
    import platform

    import torch
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), cpu)
    except OSError:  # not Linux
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "torch": torch.__version__,
            "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
            "onnxruntime": importlib.metadata.version("onnxruntime"),  # the student's runtime (model.runtime)
            "libsumo": importlib.metadata.version("libsumo"), "numpy": importlib.metadata.version("numpy"),
            "python": platform.python_version()}


def _bare_inference(agent_name: str, agent_config: str | None):
    """For a student agent: (a function timing its own network call (binarised BEV, target
    point, speed in; path and speed waypoints out: ``infer`` after ``binarize``, what
    ``predict`` runs on a tick whose inputs are new) on recorded sensor inputs, with its
    checkpoint and thread setting, ms per call; a function giving a call that runs that
    network once on the next of such inputs, for ``run_bench``'s ``network_between``);
    else (None, None)."""
    from harness.loop.agent import load_agent
    from model.agent import StudentAgent
    from model.cache import binarize
    agent = load_agent(agent_name)
    if not isinstance(agent, StudentAgent):
        return None, None

    def network_between(inputs: list[dict]):
        agent.setup(agent_config)  # the checkpoint, in ONNX Runtime on INFERENCE_THREADS threads
        frames = [(d["bev"], d["target_point"], float(d["speed"])) for d in inputs]
        calls = itertools.count()

        def call():  # what infer_ms times: binarise, then the network
            bev, tp, speed = frames[next(calls) % len(frames)]
            agent.infer(binarize(bev), tp, speed)
        return call

    def infer_ms(inputs: list[dict], calls: int = 500, warmup: int = 20) -> float:
        agent.setup(agent_config)
        frames = [(d["bev"], d["target_point"], float(d["speed"])) for d in inputs]
        for i in range(warmup):
            bev, tp, speed = frames[i % len(frames)]
            agent.infer(binarize(bev), tp, speed)
        t0 = time.perf_counter()
        for i in range(calls):
            bev, tp, speed = frames[i % len(frames)]
            agent.infer(binarize(bev), tp, speed)
        return 1000 * (time.perf_counter() - t0) / calls
    return infer_ms, network_between


def _bench(args: argparse.Namespace) -> int:
    from harness.runs.bench import BenchError, collect_rate, format_bench, run_bench
    from sumo_scimm.cli import check_agent
    from harness.common.errors import BadInput
    from model.bench import format_student_bench, run_student_bench
    from scimm.bench import format_imm_bench, run_imm_bench
    if args.routes_count < 1 or args.workers < 1 or args.rounds < 1:
        raise BadInput("--routes-count, --workers and --rounds must be >= 1")
    args.agent, args.agent_config = check_agent(args.agent, args.agent_config)
    if args.json and not Path(args.json).resolve().parent.is_dir():
        raise BadInput(f"--json {args.json!r}: no folder {Path(args.json).parent} to write it in")
    if args.soak < 0:
        raise BadInput(f"--soak {args.soak}: must be >= 0 route runs")
    reproduce = _reproduce_figure(args.reproduce) if args.reproduce else None
    m = machine()
    print(f"machine: {m['cpu']}, {m['cores']} cores; torch {m['torch']} ({m['torch_cpu_capability']} kernels), "
          f"onnxruntime {m['onnxruntime']}, libsumo {m['libsumo']}, numpy {m['numpy']}, Python {m['python']}")
    infer_ms, network_between = _bare_inference(args.agent, args.agent_config)
    try:
        loop = run_bench(args.routes, args.routes_count, agent=args.agent, agent_config=args.agent_config,
                         bare_inference=infer_ms, network_between=network_between, rounds=args.rounds)
    except BenchError as exc:  # the agent's setup failed: its config is the user's input
        raise BadInput(f"bench: {exc}") from None
    r: dict = {"machine": m, "closed_loop": loop}
    r["collect"] = collect_rate(args.routes, args.routes_count)
    r["teacher"] = run_imm_bench(repeats=args.rounds)
    r["student"] = run_student_bench()
    loop = r["closed_loop"]
    infer = loop.setdefault("bare_inference_ms", 0.0)  # 0 for a rule-based agent
    share = loop.setdefault("network_share", 0.0)
    loop.setdefault("harness_over_bare_plus_inference", loop["harness_over_bare"])
    print(format_bench(loop))
    print(f"  harness / (bare + inference) {loop['harness_over_bare_plus_inference']:.2f} x  "
          f"(inference {infer:.2f} ms, run on {share:.0%} of ticks; target <= {OVERHEAD_TARGET:g} x)")
    if len(loop["rounds"]) > 1:
        ratio = "harness_over_bare_plus_inference" if infer else "harness_over_bare"
        print(f"  the median of {len(loop['rounds'])} rounds (round {loop['round_chosen'] + 1}); each round's ratio: "
              + ", ".join(f"{x[ratio]:.2f}" for x in loop["rounds"]))
    if "bare_libsumo_network_between_ms" in loop:  # for reading: what SUMO costs with the network between steps
        print(f"  for reading: bare libsumo step with the network run between steps "
              f"{loop['bare_libsumo_network_between_ms']:.3f} ms/tick; harness / (that + inference) "
              f"{loop['harness_over_network_between_plus_inference']:.2f} x (docs/scale.md)")
        print(f"  for reading: SUMO and the network alternating, nothing else "
              f"{loop['sumo_and_network_alternating_ms']:.3f} ms/tick (network {loop['network_between_call_ms']:.2f} ms "
              f"a call); over (bare + inference) {loop['floor_over_bare_plus_inference']:.2f} x: the floor of the ratio")
    c = r["collect"]
    print(f"collect (expert, 4 Hz episode files), one worker on {c['collect_routes']}: "
          f"{c['collect_sim_s_per_wall_s']:.1f} simulated s per wall s (target >= {c['collect_target']:g})")
    print(format_imm_bench(r["teacher"]))
    print(format_student_bench(r["student"]))
    if args.eval:
        r["eval"] = _eval_figures(args.agent, args.agent_config, args.workers)
        e, rss = r["eval"], r["eval"]["rss"] or {}
        print(f"town12_short eval      {e['eval_wall_s']:8.1f} s on {e['eval_workers']} workers "
              f"(target <= {EVAL_TARGET_S:g} s)")
        if rss:
            print(f"worker memory          peak {rss['peak_mb']:.0f} MB, growth {rss['growth_mb']:+.1f} MB over "
                  f"{rss['max_routes_per_worker']} routes (target <= {RSS_TARGET_MB:g} MB, flat)")
    if args.soak:
        from scenarios import resolve_set
        from scenarios.routefile import read_routes
        n_set = len(read_routes(resolve_set(args.routes))[1])
        r["soak"] = _eval_figures(args.agent, args.agent_config, args.workers, args.routes, -(-args.soak // n_set))
        s, rss = r["soak"], r["soak"]["rss"] or {}
        print(f"worker memory, soak    {s['route_runs']} route runs of {args.routes} on {s['eval_workers']} workers "
              f"({s['eval_wall_s']:.0f} s): peak {rss.get('peak_mb', math.nan):.0f} MB, growth "
              f"{rss.get('growth_mb', math.nan):+.1f} MB, trend {rss.get('slope_mb_per_100', math.nan):+.2f} MB "
              f"per 100 routes (target <= {RSS_TARGET_MB:g} MB, flat over 500)")
    if reproduce:
        r["reproduce"] = reproduce
        print(f"reproduce              {reproduce['reproduce_wall_s'] / 60:8.1f} min, {reproduce['stages']} stages, "
              f"from {reproduce['reproduce_dir']}/stages.json as measured when it ran "
              f"(target <= {REPRODUCE_TARGET_S / 60:g} min)")
    if args.json:
        write_atomic(Path(args.json), json.dumps(r, indent=2) + "\n")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``sumo-scimm bench``."""
    bn = sub.add_parser("bench", help="performance figures beside their references (SPEC §11)")
    bn.add_argument("--routes", default="town12_smoke", help="route set of the per-tick figures (default town12_smoke)")
    bn.add_argument("--routes-count", type=int, default=4, help="routes of the set to run (default 4)")
    bn.add_argument("--agent", default=DEFAULT_AGENT,
                    help=f"agent of the closed-loop figures (default {DEFAULT_AGENT}, the shipped SC-IMM student)")
    bn.add_argument("--agent-config", help="the agent's config (a student's checkpoint)")
    bn.add_argument("--rounds", type=int, default=3,
                    help="passes of the closed-loop figures and fresh processes of the IMM figure; the median "
                         "is reported, every pass beside it (default 3)")
    bn.add_argument("--eval", action="store_true", help="also time a whole town12_short evaluation")
    bn.add_argument("--workers", type=int, default=2, help="workers of the --eval run (default 2)")
    bn.add_argument("--soak", type=int, default=0, metavar="N",
                    help="also run at least N route runs of --routes (whole passes over the set) on --workers "
                         "and report worker memory over them (SPEC §11: --soak 500 --routes town12_short, "
                         "about 4 min per 100 routes with the student)")
    bn.add_argument("--reproduce", metavar="DIR",
                    help="also print the wall time a finished 'sumo-scimm reproduce --out DIR' recorded")
    bn.add_argument("--json", help="also write the figures as JSON to this file")
    bn.set_defaults(func=_bench)
