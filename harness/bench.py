"""``sumo-scimm bench``: performance figures of the closed loop, each beside its reference
measured in the same run (SPEC §11). Never a timed test: numbers to read, not to assert.

- harness step: wall time per 0.05 s tick of the full loop (agent, vehicle model, SUMO
  mirroring, hazards, traffic, contacts, criteria, log) with the reference agent;
- bare libsumo step: the same net, background traffic, hazard set-up and ego trajectory
  (replayed with moveToXY from the harness log), only ``simulationStep`` and the traffic
  top-up per tick: what SUMO itself costs;
- BEV render: one 64 x 64 x 9 frame, averaged over many frames of a real snapshot.
"""
from __future__ import annotations

import json
import math
import time

import libsumo
import numpy as np

from harness.bev import BevRenderer
from harness.episode import run_episode
from harness.hazard_actors import HazardActor
from harness.plan import build_plan
from harness.runner import route_seed
from harness.traffic import BackgroundTraffic
from harness.world import World
from controller.vehicle import EgoState
from scenarios import resolve_set
from scenarios.routefile import read_routes
from sumo_nets import load_net


def _bare_step_ms(route, seed: int, log) -> float:
    """Per-tick cost [ms] of libsumo alone, replaying the ego of a harness log."""
    net = load_net(route.town)
    plan = build_plan(route, net)
    ss = np.random.SeedSequence(seed)
    rng_traffic, rng_hazard, _ = (np.random.default_rng(s) for s in ss.spawn(3))
    world = World(route.town, int(ss.generate_state(1)[0] % (2**31 - 1)))
    try:
        world.add_ego(route.edges, net.getLane(plan.path.legs[0].lane_in).getIndex(), route.depart_pos)
        for k, h in enumerate(route.hazards):
            HazardActor(h, plan, net, rng_hazard, k).setup()
        traffic = BackgroundTraffic(net, plan, rng_traffic)
        traffic.populate()
        xs, ys, yaws, vs = (np.asarray(log.columns[c]) for c in ("x", "y", "yaw", "v"))
        t0 = time.perf_counter()
        for k in range(len(xs)):
            world.move_ego(EgoState(xs[k], ys[k], yaws[k], vs[k]))
            traffic.update()
            world.step()
        return 1000 * (time.perf_counter() - t0) / max(len(xs), 1)
    finally:
        world.close()


def run_bench(routes_name: str = "town12_smoke", n_routes: int = 4, bev_frames: int = 2000,
              agent: str = "route_follower", agent_config: str | None = None) -> dict:
    """Measure and return the figures (one process, one core) with ``agent`` driving."""
    _, routes = read_routes(resolve_set(routes_name))
    routes = routes[:n_routes]
    harness_ms, bare_ms, snaps = [], [], []
    for k, route in enumerate(routes):
        seed = route_seed(0, k)

        def keep(f):
            if f.tick % 50 == 0:
                snaps.append((f.ego, f.snap, f.plan, f.lights, f.props))

        res = run_episode(route, agent, agent_config, seed, on_frame=keep)
        # the frame callback costs a list append every 50th tick: negligible
        harness_ms.append(1000 * res.loop_time / max(res.steps, 1))
        bare_ms.append(_bare_step_ms(route, seed, res.log))
    renderer = BevRenderer.for_town(routes[0].town)
    t0 = time.perf_counter()
    for i in range(bev_frames):
        ego, snap, plan, lights, props = snaps[i % len(snaps)]
        renderer.render(ego, snap, plan, lights, props)
    bev_ms = 1000 * (time.perf_counter() - t0) / bev_frames
    h, b = float(np.mean(harness_ms)), float(np.mean(bare_ms))
    return {"routes": f"{routes_name} (first {len(routes)})", "agent": agent,
            "harness_step_ms": round(h, 3), "bare_libsumo_step_ms": round(b, 3),
            "harness_over_bare": round(h / b, 2) if b > 0 else math.nan,
            "bev_render_ms": round(bev_ms, 4), "bev_target_ms": 0.5}


def format_bench(r: dict) -> str:
    return "\n".join([
        f"closed loop on {r['routes']}, agent {r['agent']}, one process:",
        f"  harness step          {r['harness_step_ms']:8.3f} ms/tick",
        f"  bare libsumo step     {r['bare_libsumo_step_ms']:8.3f} ms/tick  (same traffic, ego replayed)",
        f"  harness / bare        {r['harness_over_bare']:8.2f} x",
        f"  BEV render            {r['bev_render_ms']:8.4f} ms/frame  (target <= {r['bev_target_ms']} ms)",
    ])


def bench_json(r: dict) -> str:
    return json.dumps(r, indent=2)
