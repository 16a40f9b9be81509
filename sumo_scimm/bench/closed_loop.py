"""``sumo-scimm bench``: performance figures of the closed loop, each beside its reference
measured in the same run (docs/design.md §11). Never a timed test: numbers to read, not to assert.

- harness step: wall time per 0.05 s tick of the full loop (agent, vehicle model, SUMO
  mirroring, hazards, traffic, contacts, criteria, log) with the chosen agent;
- bare libsumo step: the same SUMO work without the harness: the episode's
  ``harness.loop.episode.Scene`` (same net, seed, hazards, background traffic and route bubble)
  replaying the ego of the harness log, timed over ``Scene.advance`` (moveToXY, the hazard
  and traffic top-ups, ``simulationStep``). The replay checks that it reproduced the
  episode's traffic (the background speed of every tick equals the log's);
- bare inference (a learned agent): ``bare_inference(inputs)`` given by the caller, timing
  the agent's own network call on the sensor inputs of sampled ticks of an episode, right
  after it; it counts on the share of ticks that ran the network (``network_share``: a student skips
  ticks whose inputs repeat the previous tick's, model.agent), so the overhead ratio is
  harness step / (bare libsumo step + network share x bare inference);
- bare libsumo step with the network between steps (a learned agent, for reading, not a
  target): the same replay with ``network_between(inputs)()``, the agent's network call on
  the recorded inputs, run untimed before every step (the loop runs it on the network
  share of ticks, and its own work on the others). SUMO's step then costs more than back
  to back (2-3x in docs/scale.md): its caches cool, partly with the time spent elsewhere
  alone, partly from the network's own use of them. This figure is the SUMO cost any
  closed loop with this network pays on the measured host; the overhead ratio over it
  shows what the harness's own work adds;
- the floor (a learned agent, for reading): in that replay the network calls are timed
  too. SUMO's step plus the network on the agent's share of ticks is what a closed loop
  costs whose own work (sensor inputs, BEV, controller, criteria, log) were free; over the
  overhead ratio's reference it is the lowest ratio a harness could reach on that host
  (the replay runs the network before every step, the loop on its share of ticks, so
  SUMO's part of the floor is for the network on every tick: the true floor may sit a
  little lower);
- bare libsumo step with a memory sweep between steps (a learned agent, for reading): the
  same replay with a read of SWEEP_BYTES between steps (4 MB, twice the 2 MB per-core L2
  cache of a recent Intel Xeon), no network: what cooling the caches alone costs SUMO's
  step, beside what the network between steps costs it;
- rounds: the figures above are timed in ``rounds`` whole passes over the routes and
  reported from the median pass by the overhead ratio, with every pass's figures beside
  it (on a shared host one pass can move the ratio by up to a fifth between runs);
- BEV render: one 64 x 64 x 9 frame, averaged over many frames of real snapshots;
- collect: simulated seconds per wall second of one worker recording the expert (target
  >= 20, ``collect_target``): ``run_job`` as ``sumo-scimm collect`` runs it, episode file
  and log saved.
"""
from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

from harness.sensors.bev import BevRenderer
from harness.loop.episode import EpisodeLog, Scene, background_roads, run_episode, sensor_inputs
from harness.sim.plan import build_plan
from harness.runs.jobs import Job, route_seed, run_job
from harness.sim.world import World
from controller.ego import DEFAULT_VEHICLE
from controller.vehicle import EgoState
from scenarios import resolve_set
from scenarios.routefile import Route, read_routes
from sumo_nets import load_net

SAMPLE_EVERY = 50  # ticks between the frames kept for the BEV and inference figures
SWEEP_BYTES = 4 << 20  # the memory read between steps in the cache-sweep replay [bytes]


def _memory_sweep(n_bytes: int = SWEEP_BYTES) -> Callable[[], object]:
    """A call that reads ``n_bytes`` of memory (a float64 sum): it evicts what SUMO's step
    left in caches smaller than that and does little else."""
    block = np.ones(n_bytes // 8)
    return block.sum


def _bare_step_ms(route: Route, seed: int, log: EpisodeLog,
                  between: Callable[[], object] | None = None) -> tuple[float, bool, float]:
    """(per-tick cost [ms] of SUMO and its traffic alone, replaying the ego of a harness
    log; whether the replay reproduced the episode's traffic; per-call cost [ms] of
    ``between``, nan without it).

    ``between()``, if given, runs before every step, timed apart from it (the agent's
    network: what sits between two steps in a closed loop)."""
    net = load_net(route.town)
    plan = build_plan(route, net)
    ss = np.random.SeedSequence(seed)  # the generators and SUMO seed of run_episode
    rng_traffic, rng_hazard, _ = (np.random.default_rng(s) for s in ss.spawn(3))
    world = World(route.town, int(ss.generate_state(1)[0] % (2**31 - 1)), background_roads(route, net))
    try:
        scene = Scene(route, net, plan, world, rng_traffic, rng_hazard)
        scene.start(EgoState(*plan.path.pose(0.0), 0.0))
        xs, ys, yaws, vs, bg = (log.columns[c] for c in ("x", "y", "yaw", "v", "bg_speed"))
        progress = [0] + log.columns["route_index"][:-1]  # the route index each tick started from
        busy, between_busy, same = 0.0, 0.0, True
        for k in range(len(xs)):
            s, ego_s = EgoState(xs[k], ys[k], yaws[k], vs[k]), float(plan.s[progress[k]])
            if between is not None:
                t0 = time.perf_counter()
                between()
                between_busy += time.perf_counter() - t0
            t0 = time.perf_counter()
            scene.advance(s, ego_s)
            busy += time.perf_counter() - t0
            now = world.snapshot().background_speed
            same = same and (now == bg[k] or (math.isnan(now) and math.isnan(bg[k])))
        ticks = max(len(xs), 1)
        return 1000 * busy / ticks, same, 1000 * between_busy / ticks if between is not None else math.nan
    finally:
        world.close()


class BenchError(RuntimeError):
    """A route of the benchmark drove no tick: there is nothing to time."""


def run_bench(routes_name: str = "town12_smoke", n_routes: int = 4, bev_frames: int = 2000,
              agent: str = "route_follower", agent_config: str | None = None,
              bare_inference: Callable[[list[dict]], float] | None = None,
              network_between: Callable[[list[dict]], Callable[[], object]] | None = None,
              rounds: int = 1, vehicle: str = DEFAULT_VEHICLE) -> dict:
    """Measure and return the figures (one process, one core) with ``agent`` driving ego
    model ``vehicle`` (controller.ego).

    ``bare_inference(inputs) -> ms``: the agent's inference alone on a list of its sensor
    inputs (dicts as ``run_step`` gets them) from sampled ticks of an episode.
    ``network_between(inputs) -> call``: a function running the agent's network once, on
    the next of those inputs (for the replay with the network between steps).

    The references are timed route by route, right after the route's episode: a shared
    host's speed can move between two levels within minutes (docs/scale.md), and a
    reference timed minutes away from the step it divides can land on the other level.
    The figures of a round are means over the routes; ``per_route`` keeps each route's.
    With ``rounds`` > 1 the whole measurement runs that many times and the figures are
    those of the median round by the overhead ratio (each round's ratio divides figures
    of that round only: the round is chosen whole, never figure by figure); ``rounds``
    lists every round's, ``round_chosen`` the index of the one reported."""
    _, routes = read_routes(resolve_set(routes_name))
    routes = routes[:n_routes]
    results, snaps = [], []
    for _ in range(rounds):
        results.append(_round(routes, f"{routes_name} (first {len(routes)})", agent, agent_config,
                              bare_inference, network_between, snaps, vehicle))
    key = "harness_over_bare_plus_inference" if "harness_over_bare_plus_inference" in results[0] else "harness_over_bare"
    out = sorted(results, key=lambda r: r[key])[rounds // 2]  # the median (of an even count, the higher middle)
    out["replay_same_traffic"] = all(r["replay_same_traffic"] for r in results)
    out["rounds"] = [{k: r[k] for k in _ROUND_KEYS if k in r} for r in results]
    out["round_chosen"] = results.index(out)
    renderer = BevRenderer.for_town(routes[0].town)
    t0 = time.perf_counter()
    for i in range(bev_frames):
        ego, snap, plan, lights, props, stops = snaps[i % len(snaps)]
        renderer.draw(ego, snap, plan, lights, props, stops)  # a drawing: render could reuse its last frame
    out["bev_render_ms"] = round(1000 * (time.perf_counter() - t0) / bev_frames, 4)
    out["bev_target_ms"] = 0.5
    return out


# what ``rounds`` keeps of each round
_ROUND_KEYS = ("harness_step_ms", "bare_libsumo_step_ms", "bare_inference_ms", "network_share",
               "harness_over_bare", "harness_over_bare_plus_inference", "sumo_and_network_alternating_ms",
               "floor_over_bare_plus_inference", "bare_libsumo_memory_sweep_ms")


def _round(routes: list[Route], label: str, agent: str, agent_config: str | None,
           bare_inference: Callable[[list[dict]], float] | None,
           network_between: Callable[[list[dict]], Callable[[], object]] | None, snaps: list,
           vehicle: str = DEFAULT_VEHICLE) -> dict:
    """One pass of ``run_bench``'s closed-loop figures over ``routes``: means over the
    routes, each route's in ``per_route``; appends the sampled frames (ego, snapshot, plan,
    lights, props, stops) to ``snaps`` for the BEV figure."""
    per = [_time_route(route, route_seed(0, k), agent, agent_config, bare_inference, network_between, snaps,
                       vehicle) for k, route in enumerate(routes)]

    def col(key: str) -> list[float]:  # a figure over the routes that have it
        return [r[key] for r in per if key in r]

    harness_ms, bare_ms, shares, infer_ms = (col(k) for k in ("harness_step_ms", "bare_libsumo_step_ms",
                                                              "network_share", "bare_inference_ms"))
    # the replay with the network between steps: SUMO, network
    between_ms, between_net_ms = col("bare_libsumo_network_between_ms"), col("network_between_call_ms")
    same = [ok for r in per for ok in r["same"]]
    h, b = float(np.mean(harness_ms)), float(np.mean(bare_ms))
    out = {"routes": label, "agent": agent, "harness_step_ms": round(h, 3), "bare_libsumo_step_ms": round(b, 3),
           "harness_over_bare": round(h / b, 2) if b > 0 else math.nan, "replay_same_traffic": all(same)}
    out["per_route"] = {"harness_step_ms": [round(v, 3) for v in harness_ms],
                        "bare_libsumo_step_ms": [round(v, 3) for v in bare_ms]}
    if bare_inference is not None and infer_ms:
        share = float(np.mean(shares)) if shares else 1.0  # per-route mean, as the harness step
        out["per_route"]["bare_inference_ms"] = [round(v, 3) for v in infer_ms]
        out["bare_inference_ms"] = round(float(np.mean(infer_ms)), 3)
        out["network_share"] = round(share, 3)
        out["harness_over_bare_plus_inference"] = round(h / (b + share * out["bare_inference_ms"]), 2)
        if between_ms:
            bn = float(np.mean(between_ms))
            out["bare_libsumo_network_between_ms"] = round(bn, 3)
            out["per_route"]["bare_libsumo_network_between_ms"] = [round(v, 3) for v in between_ms]
            out["harness_over_network_between_plus_inference"] = round(h / (bn + share * out["bare_inference_ms"]), 2)
            # the floor: a loop that only steps SUMO and runs the network (on the same share of
            # ticks as the agent), its own work nil, over the same reference as the harness step
            nn = float(np.mean(between_net_ms))
            out["network_between_call_ms"] = round(nn, 3)
            out["per_route"]["network_between_call_ms"] = [round(v, 3) for v in between_net_ms]
            out["sumo_and_network_alternating_ms"] = round(bn + share * nn, 3)
            out["floor_over_bare_plus_inference"] = round((bn + share * nn) / (b + share * out["bare_inference_ms"]), 2)
        sweep_ms = col("bare_libsumo_memory_sweep_ms")
        if sweep_ms:
            out["bare_libsumo_memory_sweep_ms"] = round(float(np.mean(sweep_ms)), 3)
            out["per_route"]["bare_libsumo_memory_sweep_ms"] = [round(v, 3) for v in sweep_ms]
    return out


def _time_route(route: Route, seed: int, agent: str, agent_config: str | None,
                bare_inference: Callable[[list[dict]], float] | None,
                network_between: Callable[[list[dict]], Callable[[], object]] | None, snaps: list,
                vehicle: str = DEFAULT_VEHICLE) -> dict:
    """The figures of one route [ms], each timed right after its episode: the harness step,
    the bare libsumo step, and for a learned agent the bare inference, the replay with the
    network between steps and the network call there; ``network_share`` when the agent
    counts its network calls; ``same``: whether each replay reproduced the episode's traffic.
    Appends the sampled frames to ``snaps``."""
    kept, driver = [], {}

    def keep(f):
        driver["agent"] = f.agent
        if f.tick % SAMPLE_EVERY == 0:
            kept.append(f)

    res = run_episode(route, agent, agent_config, seed, on_frame=keep, vehicle=vehicle)
    if not res.steps:  # nothing to time: the agent could not be set up, or SUMO failed at once
        raise BenchError(f"route {route.id}: {res.status} before its first tick ({res.message.splitlines()[0]})")
    # the frame callback costs a dict write and, every SAMPLE_EVERY-th tick, a list append: negligible
    out = {"harness_step_ms": 1000 * res.loop_time / max(res.steps, 1)}
    a = driver.get("agent")
    if getattr(a, "frames", 0):  # a student: the ticks that ran its network
        out["network_share"] = a.network_calls / a.frames
    ms, ok, _ = _bare_step_ms(route, seed, res.log)
    out["bare_libsumo_step_ms"], out["same"] = ms, [ok]
    bev = BevRenderer.for_town(route.town)
    inputs = []
    for f in kept:  # what the agent sees on the next tick (its progress: this tick's route index)
        snaps.append((f.ego, f.snap, f.plan, f.lights, f.props, f.stops))
        progress = res.log.columns["route_index"][f.tick - 1]
        inputs.append(sensor_inputs(f.agent.sensors(), f.ego, f.plan, progress, f.snap,
                                    (f.snap, f.lights, f.props),
                                    lambda f=f: bev.render(f.ego, f.snap, f.plan, f.lights, f.props, f.stops)))
    if bare_inference is not None and inputs:  # right after the episode, as the libsumo replay
        out["bare_inference_ms"] = bare_inference(inputs)
    if network_between is not None and inputs:
        ms, ok, net_ms = _bare_step_ms(route, seed, res.log, between=network_between(inputs))
        out["bare_libsumo_network_between_ms"], out["network_between_call_ms"] = ms, net_ms
        out["same"].append(ok)
        ms, ok, _ = _bare_step_ms(route, seed, res.log, between=_memory_sweep())
        out["bare_libsumo_memory_sweep_ms"] = ms
        out["same"].append(ok)
    return out


def collect_rate(routes_name: str = "town12_smoke", n_routes: int = 4) -> dict:
    """The expert recorded as ``sumo-scimm collect`` records it (4 Hz episode files, logs),
    the routes one after another in this process: simulated seconds per wall second of
    one worker (each route's ``run_job``: simulation, recording, scoring, files). The first
    route runs once untimed first: a worker loads the net and the BEV's layers once."""
    path = resolve_set(routes_name)
    _, routes = read_routes(path)
    routes = routes[:n_routes]
    sim = wall = 0.0
    with tempfile.TemporaryDirectory(prefix="sumo-scimm-collect-") as tmp:
        logs, episodes = Path(tmp, "logs"), Path(tmp, "episodes")
        logs.mkdir()
        episodes.mkdir()
        jobs = [Job(k, route, 0, "expert", None, route_seed(0, k), str(logs), collect_dir=str(episodes),
                    route_file=str(path)) for k, route in enumerate(routes)]
        run_job(jobs[0])  # warm-up
        for job in jobs:
            t0 = time.perf_counter()
            record = run_job(job)
            wall += time.perf_counter() - t0
            sim += record["game_time"]
    return {"collect_routes": f"{routes_name} (first {len(routes)})", "collect_sim_s": round(sim, 1),
            "collect_sim_s_per_wall_s": round(sim / wall, 1), "collect_target": 20.0}


def format_bench(r: dict) -> str:
    return "\n".join([
        f"closed loop on {r['routes']}, agent {r['agent']}, one process:",
        f"  harness step          {r['harness_step_ms']:8.3f} ms/tick",
        f"  bare libsumo step     {r['bare_libsumo_step_ms']:8.3f} ms/tick  (ego replayed; same traffic: "
        f"{'yes' if r['replay_same_traffic'] else 'NO'})",
        f"  harness / bare        {r['harness_over_bare']:8.2f} x",
        f"  BEV render            {r['bev_render_ms']:8.4f} ms/frame  (target <= {r['bev_target_ms']} ms)",
    ])
