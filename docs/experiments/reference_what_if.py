"""What if the minimum-speed reference slowed down with the ego? Rescore a finished run.

    python docs/experiments/reference_what_if.py RUN_DIR [ROUTE_SET]

RUN_DIR is an ``eval`` run folder (records.jsonl and logs/); ROUTE_SET the set it ran
(default town12_short). Each variant replaces the logged background speed (the reference
of Leaderboard 2.0's MinimumSpeedRouteTest, docs/scoring.md) on some ticks and rescores
every route with the same minimum-speed rule (harness.scoring.infractions.min_speed) and the same
other infractions:

- ``alpha x while standing``: on the ticks where the ego stands (below 0.1 m/s) the
  reference is alpha times the logged one; alpha 0 is a reference that stands exactly
  when the ego stands;
- ``capped below v``: on the ticks where the ego drives slower than v [m/s] the reference
  is at most the ego's speed (it never outruns a slow ego).

Both are bounds, not models: CARLA's BackgroundActivity slows the vehicles ahead only
once they are r_min ahead, and its opposite lanes drive on (docs/expert.md).

- ``BA model ...``: a kinematic model of the Leaderboard 2.0 BackgroundActivity (BA),
  driven by the logged ego (session 18; rules and constants read in the
  ``background_activity.py`` of Bench2Drive's scenario_runner copy). Every BA vehicle's
  desired speed is the ego's speed limit times a percentage. Road mode: per lane of the
  ego's direction, 2 vehicles ahead and 2 behind (first placed 15 and 30 m away); ahead
  at distance d, ``clip((r_max - d) / (r_max - r_min), 0, 1)`` with r_min = 30 m and
  r_max = 45 m, both + 1.7 m per m/s of ego speed; behind, ``min(1 + d / 15 m, 2)``,
  queueing behind the ego. Opposite lanes: a source 80 m ahead of the ego spawns a
  vehicle at rest whenever the last one is over 40 m from it; they drive at the limit
  and are removed 80 m behind the ego. Junction mode, from 30 m + 1.5 m per m/s before a
  junction until the ego leaves it: the road vehicles drive at 100 % (the vehicles ahead
  tethered again, x 1.5, once 45 m past the junction's exit, or not: two variants), and
  no opposite vehicle is spawned. Vehicles reach their desired speed with a 1 s lag (at
  most +3 / -6 m/s^2) and keep 10 m to the vehicle in front. Left out, so the model errs
  both ways: the junction's entry sources (vehicles that cross on green and, leaving into
  other roads, stand and count as 0), lights and stop signs for the road vehicles (the
  opposite ones ignore them in BA too), lane changes; behind vehicles queue behind the
  ego in every lane (kind to the ego). No variant is a bound on what CARLA would give.

The check on the first line: the logged reference gives the run's own minimum-speed
messages on every route. Analysis only: it changes no record.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Callable

import numpy as np

from harness.scoring.infractions import min_speed
from harness.sim.plan import build_plan, leg_at
from harness.scoring.scores import infraction_penalty
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


BA_SPACING = 15.0  # road vehicles spawned this far apart [m] (_road_spawn_dist)
BA_RADIUS = (30.0, 45.0)  # r_min, r_max with the ego standing [m] (2 and 3 x the spacing)
BA_RADIUS_GROWTH = 1.7  # [m per m/s of ego speed] (_radius_increase_ratio)
BA_DETECTION = (30.0, 1.5)  # junction mode from this far before a junction [m, + m per m/s]
BA_EXIT = 45.0  # in junction mode a route vehicle is tethered again this far past the exit [m]
BA_OPPOSITE = (80.0, 40.0, 80.0)  # opposite source ahead, spawn spacing, removal behind [m]
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


def _follow(v: float, desired: float, gap: float, v_front: float, dt: float) -> float:
    """One tick of a BA vehicle: towards its desired speed with a lag, never closer than
    BA_GAP to the vehicle in front (gap [m] to it, v_front its speed)."""
    a = min(max((desired - v) / BA_LAG, -BA_DECEL), BA_ACCEL)
    v_safe = max(v_front + (gap - BA_GAP) / BA_LAG, 0.0)
    return max(min(v + a * dt, v_safe), 0.0)


def _junction_mode(plan, s: float, v_e: float, until: float | None) -> float | None:
    """BackgroundActivity's junction mode at route s [m]: it starts once the ego is within
    the detection distance of a junction and lasts until the ego leaves that junction.
    Returns the route s where it ends, None in road mode (until: the previous tick's)."""
    if until is not None and s <= until:
        return until
    detect = BA_DETECTION[0] + BA_DETECTION[1] * v_e
    return next((p.s_out for p in plan.passages if p.s_in - detect <= s <= p.s_out), None)


def _ba_model(opposite: bool, junctions: bool, retether: bool = True) -> Callable[..., np.ndarray]:
    """The BackgroundActivity model above. opposite: with the opposite lanes' vehicles;
    junctions: with the junction mode (else road mode everywhere); retether: in junction
    mode the vehicles ahead are tethered again BA_EXIT past the junction (else they stay
    at 100 % until the junction mode ends, as BackgroundActivity leaves a vehicle that was
    already past the junction when the mode began)."""
    def bg(log: dict, plan, net) -> np.ndarray:
        idx = log["route_index"].astype(int)
        s_ego, limit = plan.s[idx], plan.speed_limit[idx]
        dt = float(log["t"][1] - log["t"][0]) if len(idx) > 1 else 0.05
        ahead = [[BA_SPACING, 0.0], [2 * BA_SPACING, 0.0]]  # [distance ahead of the ego, speed], nearest first
        behind = [[BA_SPACING, 0.0], [2 * BA_SPACING, 0.0]]  # [distance behind the ego, speed], nearest first
        oncoming: list[list[float]] = []  # [distance ahead of the ego, speed] of one opposite lane, oldest first
        lanes, until = (1, 1), None
        out = np.empty(len(s_ego))
        for k in range(len(s_ego)):
            v_e, lim = float(log["v"][k]), float(limit[k])
            ds = s_ego[k] - s_ego[k - 1] if k else 0.0
            lanes = _lanes(plan, net, float(s_ego[k])) or lanes
            until = _junction_mode(plan, float(s_ego[k]), v_e, until) if junctions else None
            mode = until is not None
            r_min, r_max = (r + BA_RADIUS_GROWTH * v_e for r in BA_RADIUS)
            for j in (1, 0):  # the farther vehicle first: it is the nearer one's leader
                d, v = ahead[j]
                tether = (r_max - d) / (r_max - r_min)
                if mode:  # free until BA_EXIT past the junction, then tethered x 1.5
                    tether = 1.0 if not retether or s_ego[k] + d < until + BA_EXIT else 1.5 * tether
                want = lim * min(max(tether, 0.0), 1.0)
                gap, v_front = (ahead[1][0] - d, ahead[1][1]) if j == 0 else (1e9, 0.0)
                v = _follow(v, want, gap, v_front, dt)
                ahead[j] = [d + v * dt - ds, v]
            for j in (0, 1):  # the nearer vehicle first: it is the farther one's leader
                d, v = behind[j]
                want = lim if mode else lim * min(1.0 + d / BA_SPACING, 2.0)
                gap, v_front = (d, v_e) if j == 0 else (d - behind[0][0], behind[0][1])
                v = _follow(v, want, gap, v_front, dt)
                behind[j] = [d - v * dt + ds, v]
            if opposite:  # spawned at rest by a source BA_OPPOSITE[0] ahead, none in junction mode
                for j, (d, v) in enumerate(oncoming):
                    gap, v_front = (d - oncoming[j - 1][0], oncoming[j - 1][1]) if j else (1e9, 0.0)
                    v = _follow(v, lim, gap, v_front, dt)
                    oncoming[j] = [d - v * dt - ds, v]
                oncoming = [o for o in oncoming if o[0] > -BA_OPPOSITE[2]]
                if not mode and (not oncoming or BA_OPPOSITE[0] - oncoming[-1][0] > BA_OPPOSITE[1]):
                    oncoming.append([BA_OPPOSITE[0], 0.0])
            same = lanes[0] * (sum(v for _, v in ahead) + sum(v for _, v in behind))
            other = lanes[1] * sum(v for _, v in oncoming)
            out[k] = (same + other) / (4 * lanes[0] + len(oncoming) * lanes[1])
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
    "BA model: road mode only": _ba_model(opposite=True, junctions=False),
    "BA model: junction mode, vehicles ahead free": _ba_model(opposite=True, junctions=True, retether=False),
    "BA model: junction mode, re-tethered past the exit": _ba_model(opposite=True, junctions=True),
    "BA model: the same, no opposite lanes": _ba_model(opposite=False, junctions=True),
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
