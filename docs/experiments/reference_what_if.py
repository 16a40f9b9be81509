"""What if the minimum-speed reference slowed down with the ego? Rescore a finished run.

    python docs/experiments/reference_what_if.py RUN_DIR [ROUTE_SET]

RUN_DIR is an ``eval`` run folder (records.jsonl and logs/); ROUTE_SET the set it ran
(default town12_short). Each variant replaces the logged background speed (the reference
of Leaderboard 2.0's MinimumSpeedRouteTest, docs/scoring.md) on some ticks and rescores
every route with the same minimum-speed rule (harness.infractions.min_speed) and the same
other infractions:

- ``alpha x while standing``: on the ticks where the ego stands (below 0.1 m/s) the
  reference is alpha times the logged one; alpha 0 is a reference that stands exactly
  when the ego stands;
- ``capped below v``: on the ticks where the ego drives slower than v [m/s] the reference
  is at most the ego's speed (it never outruns a slow ego).

Both are bounds, not models: CARLA's BackgroundActivity slows the vehicles ahead only
once they are r_min ahead, and its opposite lanes drive on (docs/expert.md).

- ``BA model ...``: a kinematic model of the Leaderboard 2.0 BackgroundActivity's road
  mode, driven by the logged ego (session 18; constants from scenario_runner's
  ``background_activity.py`` in Bench2Drive's and carla_garage's copies). Per lane of
  the ego's direction, 2 vehicles ahead and 2 behind (spawned 15 m apart); every BA
  vehicle's desired speed is the ego's speed limit times a percentage: ahead at distance
  d, ``clip((r_max - d) / (r_max - r_min), 0, 1)`` with r_min = 30 m and r_max = 45 m,
  both + 1.7 m per m/s of ego speed; behind, ``min(1 + d / 15 m, 2)``, queueing behind
  the ego; on each opposite lane 4 vehicles (a source 80 m ahead spawns every 40 m, they
  are removed 80 m behind) at 100 %. Vehicles reach their desired speed with a 1 s lag
  (at most +3 / -6 m/s^2) and keep 10 m to the vehicle in front. Variants: opposite
  lanes at the limit; opposite lanes standing while the ego stands (as at a shared red
  phase); no opposite lanes. Left out, so the model errs both ways: the junction mode
  (cross traffic that drives on; vehicles leaving into other roads, which stand and count
  as 0; no new opposite vehicles), lights and stop signs for the BA vehicles (which would
  slow them), lane changes; behind vehicles queue behind the ego in every lane (kind to
  the ego). Neither variant is a strict bound on what CARLA would give.

The check on the first line: the logged reference gives the run's own minimum-speed
messages on every route. Analysis only: it changes no record.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Callable

import numpy as np

from harness.infractions import min_speed
from harness.plan import build_plan, leg_at
from harness.scoring import infraction_penalty
from scenarios import set_path
from scenarios.routefile import read_routes
from sumo_nets import load_net

STANDING = 0.1  # [m/s]


def _scaled_while_standing(alpha: float) -> Callable[[dict], np.ndarray]:
    def bg(log: dict) -> np.ndarray:
        out = log["bg_speed"].copy()
        out[log["v"] < STANDING] *= alpha
        return out
    return bg


def _capped_below(v: float) -> Callable[[dict], np.ndarray]:
    def bg(log: dict) -> np.ndarray:
        slow = log["v"] < v
        out = log["bg_speed"].copy()
        out[slow] = np.minimum(out[slow], log["v"][slow])
        return out
    return bg


DT = 0.05  # [s] per logged tick
BA_SPACING = 15.0  # road vehicles spawned this far apart [m] (_road_spawn_dist)
BA_RADIUS = (30.0, 45.0)  # r_min, r_max with the ego standing [m] (2 and 3 x the spacing)
BA_RADIUS_GROWTH = 1.7  # [m per m/s of ego speed] (_radius_increase_ratio)
BA_OPPOSITE_PER_LANE = 4  # a source 80 m ahead spawning every 40 m, removal 80 m behind
BA_LAG, BA_ACCEL, BA_DECEL, BA_GAP = 1.0, 3.0, 6.0, 10.0  # [s], [m/s^2], [m/s^2], [m]


def _lanes(plan, net, s: float) -> tuple[int, int] | None:
    """(car lanes in the ego's direction, car lanes in the opposite one) at route s, None
    inside a junction."""
    g = leg_at(plan, s)
    if g is None:
        return None
    edge = net.getEdge(g.edge)
    rev = f"{edge.getToNode().getID()}_{edge.getFromNode().getID()}"
    opposite = sum(ln.allows("passenger") for ln in net.getEdge(rev).getLanes()) if net.hasEdge(rev) else 0
    return sum(ln.allows("passenger") for ln in edge.getLanes()), opposite


def _follow(v: float, desired: float, gap: float, v_front: float) -> float:
    """One tick of a BA vehicle: towards its desired speed with a lag, never closer than
    BA_GAP to the vehicle in front (gap [m] to it, v_front its speed)."""
    a = min(max((desired - v) / BA_LAG, -BA_DECEL), BA_ACCEL)
    v_safe = max(v_front + (gap - BA_GAP) / BA_LAG, 0.0)
    return max(min(v + a * DT, v_safe), 0.0)


def _ba_model(opposite: str) -> Callable[..., np.ndarray]:
    """The BackgroundActivity model above; opposite: 'limit', 'stand with the ego' or 'none'."""
    def bg(log: dict, plan, net) -> np.ndarray:
        s_ego = plan.s[log["route_index"].astype(int)]
        limit = plan.speed_limit[log["route_index"].astype(int)]
        ahead = [[BA_SPACING, 0.0], [2 * BA_SPACING, 0.0]]  # [distance ahead of the ego, speed], nearest first
        behind = [[BA_SPACING, 0.0], [2 * BA_SPACING, 0.0]]  # [distance behind the ego, speed], nearest first
        lanes = (1, 1)
        out = np.empty(len(s_ego))
        for k in range(len(s_ego)):
            v_e, lim = float(log["v"][k]), float(limit[k])
            ds = s_ego[k] - s_ego[k - 1] if k else 0.0
            lanes = _lanes(plan, net, float(s_ego[k])) or lanes
            r_min, r_max = (r + BA_RADIUS_GROWTH * v_e for r in BA_RADIUS)
            for j in (1, 0):  # the farther vehicle first: it is the nearer one's leader
                d, v = ahead[j]
                want = lim * min(max((r_max - d) / (r_max - r_min), 0.0), 1.0)
                gap, v_front = (ahead[1][0] - d, ahead[1][1]) if j == 0 else (1e9, 0.0)
                v = _follow(v, want, gap, v_front)
                ahead[j] = [d + v * DT - ds, v]
            for j in (0, 1):  # the nearer vehicle first: it is the farther one's leader
                d, v = behind[j]
                want = lim * min(1.0 + d / BA_SPACING, 2.0)
                gap, v_front = (d, v_e) if j == 0 else (d - behind[0][0], behind[0][1])
                v = _follow(v, want, gap, v_front)
                behind[j] = [d - v * DT + ds, v]
            same = sum(v for _, v in ahead) + sum(v for _, v in behind)
            n_opp = lanes[1] * BA_OPPOSITE_PER_LANE if opposite != "none" else 0
            v_opp = 0.0 if opposite == "stand with the ego" and v_e < STANDING else lim
            out[k] = (lanes[0] * same + n_opp * v_opp) / (4 * lanes[0] + n_opp)
        return out
    return bg


def _logged(fn: Callable[[dict], np.ndarray]) -> Callable[..., np.ndarray]:
    return lambda log, plan, net: fn(log)


VARIANTS = {
    "as logged": _logged(_scaled_while_standing(1.0)),
    "0.5 x while standing": _logged(_scaled_while_standing(0.5)),
    "0.25 x while standing": _logged(_scaled_while_standing(0.25)),
    "0 while standing": _logged(_scaled_while_standing(0.0)),
    "capped below 3 m/s": _logged(_capped_below(3.0)),
    "capped below 6 m/s": _logged(_capped_below(6.0)),
    "BA model: opposite lanes at the limit": _ba_model("limit"),
    "BA model: opposite lanes stand with the ego": _ba_model("stand with the ego"),
    "BA model: no opposite lanes": _ba_model("none"),
}


def what_if(run: Path, route_set: str) -> dict[str, np.ndarray]:
    """DS per route [0-100] for each variant; checks "as logged" against the records."""
    routes = {r.id: r for r in read_routes(set_path(route_set))[1]}
    ds: dict[str, list[float]] = {name: [] for name in VARIANTS}
    for rec in map(json.loads, (run / "records.jsonl").read_text().splitlines()):
        log = dict(np.load(run / "logs" / f"{rec['key']}.npz"))
        route = routes[rec["route_id"]]
        net = load_net(route.town)
        plan = build_plan(route, net)
        infractions = rec["lb"]["infractions"]
        for name, reference in VARIANTS.items():
            messages = min_speed({**log, "bg_speed": reference(log, plan, net)}, plan, "lb2.0",
                                 rec["status"] == "Completed")
            if name == "as logged" and messages != infractions["min_speed_infractions"]:
                raise SystemExit(f"route {rec['key']}: the logged reference does not give the run's messages "
                                 "(a run of another version, or other rules than lb2.0)")
            ds[name].append(rec["rc"] * infraction_penalty({**infractions, "min_speed_infractions": messages}))
    return {name: np.array(v) for name, v in ds.items()}


if __name__ == "__main__":
    if len(sys.argv) not in (2, 3):
        raise SystemExit(__doc__.split("\n\n")[1])
    result = what_if(Path(sys.argv[1]), sys.argv[2] if len(sys.argv) == 3 else "town12_short")
    print(f"{len(result['as logged'])} routes; the logged reference reproduces every minimum-speed message")
    print("reference | mean DS | routes with DS >= 90 | routes with DS >= 95")
    for name, ds in result.items():
        print(f"{name} | {ds.mean():.2f} | {np.mean(ds >= 90):.0%} | {np.mean(ds >= 95):.0%}")
