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
once they are r_min (33 m + 1.8 m per m/s of ego speed) ahead, and its opposite lanes
drive on (docs/expert.md). The check on the first line: the logged reference gives the
run's own minimum-speed messages on every route. Analysis only: it changes no record.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Callable

import numpy as np

from harness.infractions import min_speed
from harness.plan import build_plan
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


VARIANTS = {
    "as logged": _scaled_while_standing(1.0),
    "0.5 x while standing": _scaled_while_standing(0.5),
    "0.25 x while standing": _scaled_while_standing(0.25),
    "0 while standing": _scaled_while_standing(0.0),
    "capped below 3 m/s": _capped_below(3.0),
    "capped below 6 m/s": _capped_below(6.0),
}


def what_if(run: Path, route_set: str) -> dict[str, np.ndarray]:
    """DS per route [0-100] for each variant; checks "as logged" against the records."""
    routes = {r.id: r for r in read_routes(set_path(route_set))[1]}
    ds: dict[str, list[float]] = {name: [] for name in VARIANTS}
    for rec in map(json.loads, (run / "records.jsonl").read_text().splitlines()):
        log = dict(np.load(run / "logs" / f"{rec['key']}.npz"))
        route = routes[rec["route_id"]]
        plan = build_plan(route, load_net(route.town))
        infractions = rec["lb"]["infractions"]
        for name, reference in VARIANTS.items():
            messages = min_speed({**log, "bg_speed": reference(log)}, plan, "lb2.0", rec["status"] == "Completed")
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
