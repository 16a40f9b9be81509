"""``sumo-scimm bench``: every performance figure of docs/design.md §11 beside its reference from the
same run (the modules beside this one), printed as a table and optionally written as JSON. Figures are for reading, never asserted in a test."""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from files.atomic import write_atomic
from harness.common.errors import BadInput
from harness.loop.agent import DEFAULT_AGENT, check_agent
from sumo_scimm.bench.figures import (ARM_SEED_TARGET_S, EVAL_TARGET_S, OVERHEAD_TARGET,
                                      RSS_TARGET_MB)
from sumo_scimm.options import add_vehicle_option


def _print_loop(loop: dict) -> None:
    """The closed-loop figures: the harness step against bare libsumo (+ the network)."""
    from sumo_scimm.bench.closed_loop import SWEEP_BYTES, format_bench
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
    if "bare_libsumo_memory_sweep_ms" in loop:  # for reading: what cooling the caches alone costs SUMO
        sweep, bare = loop["bare_libsumo_memory_sweep_ms"], loop["bare_libsumo_step_ms"]
        print(f"  for reading: bare libsumo step with a {SWEEP_BYTES >> 20} MB memory read between steps, no network "
              f"{sweep:.3f} ms/tick ({sweep / bare:.2f} x bare; with the network between steps "
              f"{loop['bare_libsumo_network_between_ms'] / bare:.2f} x)")


def _print_memory(label: str, e: dict) -> None:
    rss = e["rss"] or {}
    if label == "eval":
        print(f"town12_short eval      {e['eval_wall_s']:8.1f} s on {e['eval_workers']} workers "
              f"(target <= {EVAL_TARGET_S:g} s)")
        if rss:
            print(f"worker memory          peak {rss['peak_mb']:.0f} MB, growth {rss['growth_mb']:+.1f} MB over "
                  f"{rss['max_routes_per_worker']} routes (target <= {RSS_TARGET_MB:g} MB, flat)")
        return
    print(f"worker memory, soak    {e['route_runs']} route runs of {e['routes']} on {e['eval_workers']} workers "
          f"({e['eval_wall_s']:.0f} s): peak {rss.get('peak_mb', math.nan):.0f} MB, growth "
          f"{rss.get('growth_mb', math.nan):+.1f} MB, trend {rss.get('slope_mb_per_100', math.nan):+.2f} MB "
          f"per 100 routes (target <= {RSS_TARGET_MB:g} MB, flat over 500)")


def _bench(args: argparse.Namespace) -> int:
    from sumo_scimm.bench.closed_loop import BenchError, collect_rate, run_bench
    from sumo_scimm.bench.student import format_student_bench, run_student_bench
    from sumo_scimm.bench.figures import (arm_seed_figure, bare_inference, check_arm_folder, eval_figures, machine,
                                          reproduce_figure)
    from sumo_scimm.bench.imm import format_imm_bench, run_imm_bench
    if args.routes_count < 1 or args.workers < 1 or args.rounds < 1:
        raise BadInput("--routes-count, --workers and --rounds must be >= 1")
    args.agent, args.agent_config = check_agent(args.agent, args.agent_config)
    if args.json and not Path(args.json).resolve().parent.is_dir():
        raise BadInput(f"--json {args.json!r}: no folder {Path(args.json).parent} to write it in")
    if args.soak < 0:
        raise BadInput(f"--soak {args.soak}: must be >= 0 route runs")
    reproduce = reproduce_figure(args.reproduce) if args.reproduce else None
    if args.arm:
        check_arm_folder(args.arm)
    if args.replay:  # checked before anything runs
        from harness.runs.replay import REPLAY_AGENTS, plan_replay
        plan_replay(Path(args.replay), list(REPLAY_AGENTS), None)
    m = machine()
    print(f"machine: {m['cpu']}, {m['cores']} cores; torch {m['torch']} ({m['torch_cpu_capability']} kernels), "
          f"onnxruntime {m['onnxruntime']}, libsumo {m['libsumo']}, numpy {m['numpy']}, Python {m['python']}")
    infer_ms, network_between = bare_inference(args.agent, args.agent_config)
    try:
        loop = run_bench(args.routes, args.routes_count, agent=args.agent, agent_config=args.agent_config,
                         bare_inference=infer_ms, network_between=network_between, rounds=args.rounds,
                         vehicle=args.vehicle)
    except BenchError as exc:  # the agent's setup failed: its config is the user's input
        raise BadInput(f"bench: {exc}") from None
    r: dict = {"machine": m, "closed_loop": loop, "collect": collect_rate(args.routes, args.routes_count),
               "teacher": run_imm_bench(repeats=args.rounds), "student": run_student_bench()}
    _print_loop(loop)
    c = r["collect"]
    print(f"collect (expert, 4 Hz episode files), one worker on {c['collect_routes']}: "
          f"{c['collect_sim_s_per_wall_s']:.1f} simulated s per wall s (target >= {c['collect_target']:g})")
    print(format_imm_bench(r["teacher"]))
    print(format_student_bench(r["student"]))
    if args.eval:
        r["eval"] = eval_figures(args.agent, args.agent_config, args.workers, vehicle=args.vehicle)
        _print_memory("eval", r["eval"])
    if args.soak:
        from scenarios import resolve_set
        from scenarios.routefile import read_routes
        n_set = len(read_routes(resolve_set(args.routes))[1])
        r["soak"] = eval_figures(args.agent, args.agent_config, args.workers, args.routes, -(-args.soak // n_set),
                                 args.vehicle)
        _print_memory("soak", r["soak"])
    if reproduce:
        r["reproduce"] = reproduce
        target = reproduce["reproduce_target_s"]
        print(f"reproduce              {reproduce['reproduce_wall_s'] / 60:8.1f} min, {reproduce['stages']} stages, "
              f"from {reproduce['reproduce_dir']}/stages.json as measured when it ran; "
              f"{reproduce['seeds']} seeds of {reproduce['arms']} arms: {reproduce['reproduce_seed_s'] / 60:.1f} min a "
              "seed " + (f"(target <= {target / 60:g} min)" if target else "(no target above 5 arms)"))
        for name, t in reproduce["reproduce_arm_seed_s"].items():
            print(f"  arm and seed {name:12s} {t / 60:5.1f} min, training plus town12_short evaluation "
                  f"(target <= {ARM_SEED_TARGET_S / 60:g} min)")
    if args.arm:
        r["arm_seed"] = a = arm_seed_figure(args.arm, args.workers, args.vehicle)
        evals = " and ".join(f"{t:.0f}" for t in a["arm_eval_s"])
        print(f"arm and seed, now       {a['arm_seed_s'] / 60:8.1f} min: {' and '.join(a['arms'])} of seed {a['seed']} "
              f"trained side by side {a['arm_train_s']:.0f} s ({a['arm_steps']} steps each; {a['arm']}'s validation "
              f"L_origin {a['arm_val_loss']:.3f} at epoch {a['arm_chosen_epoch']}) + {a['arm_routes']} on "
              f"{a['arm_workers']} workers {evals} s, over {len(a['arms'])} (target <= {ARM_SEED_TARGET_S / 60:g} min)")
        print(f"  this recipe on val      L_origin {a['arm_val_loss']:.3f}, DS {a['arm_val_ds']:.2f} (one student)")
        if "before" in a:
            print(f"  {a['before']} on val  L_origin {a['before_val_loss']:.3f}, DS {a['before_val_ds']:.2f}")
    if args.replay:
        from harness.runs.replay import replay_figure
        r["replay"] = p = replay_figure(Path(args.replay), args.workers)
        print(f"replay                 {p['replay_wall_s']:8.1f} s: {p['replay_routes']} routes x {p['replay_agents']} "
              f"agents, {p['replay_ticks']} ticks, on {p['replay_workers']} workers "
              f"(target <= {p['replay_target_s']:g} s for 100 routes)")
    if args.json:
        write_atomic(Path(args.json), json.dumps(r, indent=2) + "\n")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``sumo-scimm bench``."""
    bn = sub.add_parser("bench", help="performance figures beside their references (docs/design.md §11)")
    bn.add_argument("--routes", default="town12_smoke", help="route set of the per-tick figures (default town12_smoke)")
    bn.add_argument("--routes-count", type=int, default=4, help="routes of the set to run (default 4)")
    bn.add_argument("--agent", default=DEFAULT_AGENT,
                    help=f"agent of the closed-loop figures (default {DEFAULT_AGENT}, the shipped SC-IMM student)")
    bn.add_argument("--agent-config", help="the agent's config (a student's checkpoint)")
    bn.add_argument("--rounds", type=int, default=3,
                    help="passes of the closed-loop figures and fresh processes of the IMM figure; the median "
                         "is reported, every pass beside it (default 3)")
    bn.add_argument("--eval", action="store_true", help="also time a whole town12_short evaluation")
    bn.add_argument("--workers", type=int, default=2,
                    help="workers of the --eval, --soak, --arm and --replay runs (default 2)")
    bn.add_argument("--soak", type=int, default=0, metavar="N",
                    help="also run at least N route runs of --routes (whole passes over the set) on --workers "
                         "and report worker memory over them (docs/design.md §11: --soak 500 --routes town12_short, "
                         "about 1-2 min per 100 routes with the student)")
    bn.add_argument("--reproduce", metavar="DIR",
                    help="also print the wall time a finished 'sumo-scimm reproduce --out DIR' recorded")
    bn.add_argument("--arm", metavar="DIR",
                    help="also time one arm and seed now, as reproduce runs it (the SC-IMM and Fixed-IMM students of "
                         "seed 0 trained side by side on the data of 'sumo-scimm reproduce --out DIR', then each on "
                         "town12_short on --workers: the time over two; then, not timed, the SC-IMM one and the "
                         "reproduce run's on val; about 12 min timed and 3 min untimed)")
    bn.add_argument("--replay", metavar="DIR",
                    help="also time 'sumo-scimm replay' of the eval run DIR (its every route) with three of the "
                         "shipped students (baseline, fixed, scimm) on --workers (docs/design.md §11: an expert run of "
                         "town12_short)")
    bn.add_argument("--json", help="also write the figures as JSON to this file")
    add_vehicle_option(bn)
    bn.set_defaults(func=_bench)
