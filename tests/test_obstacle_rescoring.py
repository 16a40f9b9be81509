"""docs/results/decisive/obstacle_cars.md: the decisive run's DS with a ParkedObstacle's
parked or accident car scored as a vehicle (x 0.6), as `eval` scores it now, where the run
scored it as a static obstacle (x 0.65), and the route runs a timed-out ParkedObstacle
ended, which `eval` now lets go on. The run's driving does not depend on how a hit is
scored, so the committed results files rescored give exactly what the run would have
scored: each such hit's message moves from ``collisions_layout`` to ``collisions_vehicle``
(harness.scoring.infractions.scored_class decides which) and the record is rescored
(harness.scoring.scores.rescore). A route run that failed after its ParkedObstacle's
scenario timeout would now have driven on past the removed obstacle: what it would have
scored cannot be rescored, only bounded, by the run completing with the infractions it had
(DS = 100 x its IS). The file must equal what this module builds;
``python -m tests.test_obstacle_rescoring > docs/results/decisive/obstacle_cars.md``
writes it again.
"""
from __future__ import annotations

import gzip
import json
import re
from pathlib import Path

import numpy as np

from harness.scoring.infractions import scored_class
from harness.scoring.paired import mde, t_interval
from harness.scoring.scores import rescore
from harness.sim.world import STATIC, VEHICLE
from scenarios import set_path
from scenarios.routefile import read_routes

ROOT = Path(__file__).resolve().parents[1]
RECORDS = ROOT / "docs" / "results" / "decisive"
FILE = RECORDS / "obstacle_cars.md"
ARMS = ("baseline", "control", "fixed", "scimm")
PAIRS = (("scimm", "baseline"), ("fixed", "baseline"), ("scimm", "control"), ("fixed", "control"),
         ("scimm", "fixed"))
ACTOR = re.compile(r"id=(\S+) at ")


def _rescored(record: dict, spans: list) -> tuple[dict, int]:
    """The record with its obstacle-car hits moved to the vehicle list, rescored; the hits moved."""
    inf = {k: list(v) for k, v in record["infractions"].items()}
    layout, moved = [], 0
    for m in inf["collisions_layout"]:
        cls, type_id = scored_class(ACTOR.search(m).group(1), STATIC, spans)
        if cls == VEHICLE:
            inf["collisions_vehicle"].append(m.replace("type=static.prop.obstacle", f"type={type_id}"))
            moved += 1
        else:
            layout.append(m)
    inf["collisions_layout"] = layout
    return rescore({**record, "infractions": inf})[0], moved


def _mean_ds(route_set: str) -> tuple[dict, dict, dict]:
    """{(arm, seed): (mean DS as run, rescored, bound)} over the set's route runs (bound: the
    largest rise of the seed's mean DS from its runs that failed after an obstacle timeout),
    and per arm the hits moved and those failed runs."""
    spans = {r.id: [(h.type, 0.0, 0.0, h.params) for h in r.hazards] for r in read_routes(set_path(route_set))[1]}
    out, moved, failed = {}, dict.fromkeys(ARMS, 0), dict.fromkeys(ARMS, 0)
    for arm in ARMS:
        for folder in RECORDS.joinpath(route_set).glob(f"{arm}_s*"):
            data = json.loads(gzip.open(folder / "results.json.gz", "rt").read())["_checkpoint"]
            total, old, new, rise = data["progress"][1], 0.0, 0.0, 0.0
            for record in data["records"]:
                hazards = spans[record["route_id"].split("_")[1]]
                again, n = _rescored(record, hazards)
                old += record["scores"]["score_composed"]
                new += again["scores"]["score_composed"]
                moved[arm] += n
                if (record["infractions"]["scenario_timeouts"] and record["status"].startswith("Failed")
                        and any(kind == "ParkedObstacle" for kind, *_ in hazards)):
                    failed[arm] += 1
                    rise += 100 * record["scores"]["score_penalty"] - record["scores"]["score_composed"]
            out[arm, int(folder.name.rsplit("_s", 1)[1])] = (old / total, new / total, rise / total)
    return out, moved, failed


def _interval(d: np.ndarray) -> str:
    mean, lo, hi, p = t_interval(d)
    return f"{mean:+.4g} [{lo:.4g}, {hi:.4g}], MDE {mde(d):.4g}, p {p:.3g}"


def build() -> str:
    lines = ["# The run's DS with a parked or accident car scored as a vehicle", "",
             "Built by `tests/test_obstacle_rescoring.py` from the committed `results.json.gz`",
             "files (docs/results.md, \"Scoring after the run\"). Each seed's DS is the mean over",
             "its route runs; a comparison is the seed-paired Student t interval (t with n - 1",
             "degrees of freedom), its MDE at 80 % power and its two-sided p, before Holm's",
             "correction.", ""]
    for route_set in ("town12_short", "town12_second"):
        ds, moved, failed = _mean_ds(route_set)
        lines += [f"## `{route_set}`", "", "| arm | hits moved | mean DS as run | rescored | change | runs with an obstacle "
                  "failed after a scenario timeout | their largest rise of the mean DS |", "| --- | --- | --- | --- | --- | --- | --- |"]
        for arm in ARMS:
            old, new, rise = (np.mean([v[k] for (a, _), v in ds.items() if a == arm]) for k in (0, 1, 2))
            lines.append(f"| {arm} | {moved[arm]} | {old:.4g} | {new:.4g} | {new - old:+.3g} | {failed[arm]} | "
                         f"+{rise:.2g} |")
        lines += ["", "| comparison | as run | rescored |", "| --- | --- | --- |"]
        for a, b in PAIRS:
            seeds = sorted(s for (arm, s) in ds if arm == a and (b, s) in ds)
            d = [np.array([ds[a, s][k] - ds[b, s][k] for s in seeds]) for k in (0, 1)]
            lines.append(f"| DS {a} - {b} | {_interval(d[0])} | {_interval(d[1])} |")
        lines.append("")
    return "\n".join(lines)


def test_the_committed_obstacle_car_rescoring_is_what_the_records_give():
    assert FILE.read_text() == build(), f"{FILE} differs from what the committed records give"


def test_the_rescoring_moves_only_parked_and_accident_car_hits():
    """Hazard 0 a construction site, hazard 1 an accident: one hit on each and one on a
    harness prop; only the accident's moves, and the route's IS becomes 0.65 x 0.6 x 0.65
    = 0.2535 (it was 0.65^3 = 0.274625)."""
    spans = [("ParkedObstacle", 0.0, 0.0, {"variant": "construction"}),
             ("ParkedObstacle", 0.0, 0.0, {"variant": "accident"})]
    hit = "Agent collided against object with type=static.prop.obstacle and id={} at (x=0.0, y=0.0, z=0.0)"
    empty = {k: [] for k in ("collisions_pedestrian", "collisions_vehicle", "red_light", "stop_infraction",
                             "outside_route_lanes", "min_speed_infractions", "yield_emergency_vehicle_infractions",
                             "scenario_timeouts", "route_dev", "vehicle_blocked", "route_timeout")}
    record = {"route_id": "RouteScenario_0_rep0", "scores": {"score_route": 100.0},
              "infractions": {**empty, "collisions_layout": [hit.format(i) for i in ("hz0_obstacle", "hz1_obstacle",
                                                                                     "prop3")]}}
    again, moved = _rescored(record, spans)
    assert moved == 1
    assert again["infractions"]["collisions_vehicle"] == [hit.format("hz1_obstacle").replace(
        "static.prop.obstacle", "vehicle.sumo.accident")]
    assert len(again["infractions"]["collisions_layout"]) == 2
    assert again["scores"]["score_penalty"] == 0.2535
    assert again["scores"]["score_composed"] == 25.35


if __name__ == "__main__":
    print(build(), end="")
