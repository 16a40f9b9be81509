"""What if the minimum-speed reference waited with the ego? Rescore a finished run.

    python docs/experiments/reference_what_if.py RUN_DIR [ROUTE_SET]

RUN_DIR is an ``eval`` run folder (records.jsonl and logs/); ROUTE_SET the set it ran
(default town12_short). For every route the logged background speed (the reference of
Leaderboard 2.0's MinimumSpeedRouteTest, docs/scoring.md) is replaced, on the ticks where
the ego stands (below 0.1 m/s), by ``alpha`` times itself, and the route is rescored with
the same minimum-speed rule (harness.infractions.min_speed) and the same other
infractions. alpha 0 is a reference that stands exactly when the ego stands: more
favourable than CARLA's BackgroundActivity, whose opposite lanes drive on while the ego
waits (docs/expert.md). The first line checks that alpha = 1 (the logged reference)
gives the run's own minimum-speed messages. Analysis only: it changes no record.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from harness.infractions import min_speed
from harness.plan import build_plan
from harness.scoring import infraction_penalty
from scenarios import set_path
from scenarios.routefile import read_routes
from sumo_nets import load_net

STANDING = 0.1  # [m/s]
ALPHAS = (1.0, 0.5, 0.25, 0.0)


def what_if(run: Path, route_set: str) -> dict[float, np.ndarray]:
    """DS per route [0-100] for each alpha in ALPHAS; checks alpha 1 against the records."""
    routes = {r.id: r for r in read_routes(set_path(route_set))[1]}
    ds: dict[float, list[float]] = {a: [] for a in ALPHAS}
    for rec in map(json.loads, (run / "records.jsonl").read_text().splitlines()):
        log = dict(np.load(run / "logs" / f"{rec['key']}.npz"))
        route = routes[rec["route_id"]]
        plan = build_plan(route, load_net(route.town))
        infractions = rec["lb"]["infractions"]
        standing = log["v"] < STANDING
        for alpha in ALPHAS:
            bg = log["bg_speed"].copy()
            bg[standing] *= alpha
            messages = min_speed({**log, "bg_speed": bg}, plan, "lb2.0", rec["status"] == "Completed")
            if alpha == 1.0 and messages != infractions["min_speed_infractions"]:
                raise SystemExit(f"route {rec['key']}: the logged reference does not give the run's messages "
                                 "(a run of another version, or other rules than lb2.0)")
            ds[alpha].append(rec["rc"] * infraction_penalty({**infractions, "min_speed_infractions": messages}))
    return {a: np.array(v) for a, v in ds.items()}


if __name__ == "__main__":
    if len(sys.argv) not in (2, 3):
        raise SystemExit(__doc__.split("\n\n")[1])
    result = what_if(Path(sys.argv[1]), sys.argv[2] if len(sys.argv) == 3 else "town12_short")
    print(f"{len(result[1.0])} routes; alpha 1 (the logged reference) reproduces every minimum-speed message")
    print("reference while the ego stands | mean DS | routes with DS >= 90 | routes with DS >= 95")
    for alpha, ds in result.items():
        print(f"{alpha:>4.2f} x logged | {ds.mean():6.2f} | {np.mean(ds >= 90):4.0%} | {np.mean(ds >= 95):4.0%}")
