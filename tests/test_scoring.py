"""Leaderboard scoring from infraction lists, against values worked out by hand from the
rules (docs/design.md §9.1), and `sumo-scimm score` on a CARLA-style file."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from sumo_scimm.cli import main
from harness.scoring.infractions import KEYS
from harness.scoring.scores import global_record, infraction_penalty, rescore_results, route_record, route_status

PED = "Agent collided against object with type=walker.pedestrian.0001 and id=12 at (x=1.0, y=2.0, z=0.0)"
VEH = "Agent collided against object with type=vehicle.tesla.model3 and id=13 at (x=1.0, y=2.0, z=0.0)"
LAYOUT = "Agent collided against object with type=static.prop.mesh and id=14 at (x=1.0, y=2.0, z=0.0)"
RED = "Agent ran a red light 77 at (x=3.0, y=4.0, z=0.0)"
STOP = "Agent ran a stop with id=88 at (x=3.0, y=4.0, z=0.0)"
TIMEOUT = "Agent timed out a scenario"
YIELD = "Agent failed to yield to an emergency vehicle"


def speed(p):
    return f"Average speed is {p}% of the surrounding traffic's one"


def outside(m, q):
    return f"Agent went outside its route lanes for about {m} meters ({q}% of the completed route)"


def inf(**lists):
    return {k: lists.get(k, []) for k in KEYS}


@pytest.mark.parametrize("key,msg,factor", [
    ("collisions_pedestrian", PED, 0.5), ("collisions_vehicle", VEH, 0.6), ("collisions_layout", LAYOUT, 0.65),
    ("red_light", RED, 0.7), ("stop_infraction", STOP, 0.8), ("scenario_timeouts", TIMEOUT, 0.7),
    ("yield_emergency_vehicle_infractions", YIELD, 0.7)])
def test_each_penalty_alone(key, msg, factor):
    assert infraction_penalty(inf(**{key: [msg]})) == pytest.approx(factor, abs=1e-12)
    assert infraction_penalty(inf(**{key: [msg, msg]})) == pytest.approx(factor ** 2, abs=1e-12)


def test_penalties_combine_by_product_and_ds_is_rc_times_is():
    # 0.5 * 0.7 * 0.8 = 0.28; DS = 80 * 0.28 = 22.4
    r = route_record(0, "RouteScenario_0_rep0", inf(collisions_pedestrian=[PED], red_light=[RED],
                                                     stop_infraction=[STOP]), 80.0,
                     {"route_length": 300.0, "duration_game": 60.0, "duration_system": 5.0})
    assert r["scores"] == {"score_route": 80.0, "score_penalty": 0.28, "score_composed": 22.4}
    assert r["num_infractions"] == 3


def test_min_speed_formula_and_each_checkpoint_counts():
    # 1 - 0.3 (1 - p/100): p = 50 -> 0.85, p = 80 -> 0.94; the duplicated final checkpoint
    # (two identical messages) is applied twice: 0.82 * 0.82
    assert infraction_penalty(inf(min_speed_infractions=[speed(50.0)])) == pytest.approx(0.85)
    assert infraction_penalty(inf(min_speed_infractions=[speed(50.0), speed(80.0)])) == pytest.approx(0.85 * 0.94)
    assert infraction_penalty(inf(min_speed_infractions=[speed(40.0), speed(40.0)])) == pytest.approx(0.6724)


def test_outside_lanes_factor():
    assert infraction_penalty(inf(outside_route_lanes=[outside(12.5, 12.5)])) == pytest.approx(0.875)


def test_lb21_is_additive_and_b2d_ignores_min_speed():
    two = inf(collisions_pedestrian=[PED], red_light=[RED])
    assert infraction_penalty(two, "lb2.1") == pytest.approx(1 / (1 + 1.0 + 0.4))
    with_out = inf(collisions_pedestrian=[PED], red_light=[RED], outside_route_lanes=[outside(30.0, 10.0)])
    assert infraction_penalty(with_out, "lb2.1") == pytest.approx(0.9 / 2.4)
    slow = inf(min_speed_infractions=[speed(50.0)])
    assert infraction_penalty(slow, "lb2.1") == pytest.approx(1 / (1 + 0.4 * 0.5))
    assert infraction_penalty(slow, "b2d") == 1.0


def test_route_completion_is_divided_before_it_is_scaled_as_the_leaderboards():
    """A straight 63.154 m route of 65 points (np.linspace): point 10 lies at 9.8678125 m, and
    9.8678125 / 63.154 x 100 is 15.625 exactly, which rounds to 15.62 (ties to even), as the
    leaderboard's ``x / max_dist * 100`` gives; 100 x 9.8678125 / 63.154 is
    15.625000000000002 and would round to 15.63."""
    from types import SimpleNamespace
    from harness.scoring.criteria import RouteCompletion
    s = np.linspace(0.0, 63.154, 65)
    rc = RouteCompletion(SimpleNamespace(s=s, length=float(s[-1]), xy=np.stack([s, np.zeros(65)], 1),
                                         yaw=np.zeros(65)))
    for x in np.arange(0.5, 10.6, 1.0):  # to just past point 10
        assert rc.update(float(x), 0.0) is None
    assert rc.rc == 15.62


def test_status_texts():
    assert route_status(100.0, inf()) == "Perfect"
    assert route_status(100.0, inf(min_speed_infractions=[speed(90.0)])) == "Completed"
    assert route_status(60.0, inf(route_dev=["Agent deviated from the route at (x=1.0, y=1.0, z=0.0)"])) == \
        "Failed - Agent deviated from the route"
    # the later message overwrites the caller's crash message
    assert route_status(10.0, inf(route_timeout=["Route timeout."]), "Agent crashed") == "Failed - Agent timed out"
    assert route_status(10.0, inf(), "Agent crashed") == "Failed - Agent crashed"
    assert route_status(10.0, inf()) == "Failed"


def _record(i, rc, infractions, length=1000.0):
    return route_record(i, f"RouteScenario_{i}_rep0", infractions, rc,
                        {"route_length": length, "duration_game": 10.0, "duration_system": 1.0})


def test_global_record_unrun_routes_count_as_zero_and_std_dev_rule():
    recs = [_record(0, 100.0, inf()), _record(1, 50.0, inf(), length=500.0)]
    g = global_record(recs, total=4)
    # means over N = 4 planned runs: DS (100 + 50) / 4 = 37.5
    assert g["scores_mean"] == {"score_composed": 37.5, "score_route": 37.5, "score_penalty": 0.5}
    # sqrt(((100 - 37.5)^2 + (50 - 37.5)^2) / (4 - 1)) = sqrt(4062.5 / 3) = 36.799
    assert g["scores_std_dev"]["score_composed"] == 36.799
    # sqrt(((1 - 0.5)^2 * 2) / 3) = 0.408
    assert g["scores_std_dev"]["score_penalty"] == 0.408
    assert global_record(recs[:1], total=1)["scores_std_dev"]["score_composed"] == 0.0


def test_per_km_rates_and_the_outside_lanes_kilometre_special_case():
    # km driven = 1000 m * 100 % + 500 m * 50 % = 1.25 km; 1 pedestrian collision -> 0.8 / km
    recs = [_record(0, 100.0, inf(collisions_pedestrian=[PED], outside_route_lanes=[outside(150.0, 15.0)])),
            _record(1, 50.0, inf(outside_route_lanes=[outside(30.0, 12.0)]), length=500.0)]
    g = global_record(recs, total=2)
    assert g["infractions"]["collisions_pedestrian"] == 0.8
    assert g["infractions"]["red_light"] == 0.0
    # outside lanes: metres of each route's first message / 1000, summed, NOT divided by km
    assert g["infractions"]["outside_route_lanes"] == 0.18
    assert g["status"] == "Failed"  # route 1 ended at RC 50: "Failed" whatever the other route did
    assert g["meta"]["exceptions"] == [["RouteScenario_1_rep0", 1, "Failed"]]


def _carla_file():
    """A results file as CARLA's leaderboard writes it (values worked out by hand below)."""
    def rec(i, rc, infractions, status, length, scores):
        return {"index": i, "route_id": f"RouteScenario_{i}_rep0", "status": status,
                "num_infractions": sum(len(v) for v in infractions.values()),
                "infractions": inf(**infractions), "scores": scores,
                "meta": {"route_length": length, "duration_game": 100.0, "duration_system": 50.0}}
    records = [
        rec(0, 100.0, {"collisions_vehicle": [VEH], "min_speed_infractions": [speed(62.5), speed(62.5)]},
            "Completed", 2000.0, {"score_route": 100.0, "score_penalty": 0.0, "score_composed": 0.0}),
        rec(1, 42.5, {"red_light": [RED], "route_dev": ["Agent deviated from the route at (x=1.0, y=2.0, z=0.0)"],
                      "outside_route_lanes": [outside(20.0, 8.0)]},
            "Failed - Agent deviated from the route", 1000.0,
            {"score_route": 42.5, "score_penalty": 0.0, "score_composed": 0.0}),
    ]
    return {"_checkpoint": {"global_record": {}, "progress": [2, 3], "records": records},
            "entry_status": "Finished", "eligible": True, "sensors": ["carla_camera"], "values": [], "labels": []}


def test_score_reproduces_a_carla_results_file(tmp_path, capsys):
    src = tmp_path / "simulation_results.json"
    src.write_text(json.dumps(_carla_file()))
    out = tmp_path / "rescored.json"
    assert main(["score", str(src), "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    r0, r1 = data["_checkpoint"]["records"]
    # route 0: vehicle 0.6, min speed 62.5 % twice: (1 - 0.3 * 0.375)^2 = 0.8875^2 = 0.78765625
    assert r0["scores"]["score_penalty"] == round(0.6 * 0.78765625, 6) == 0.472594
    assert r0["scores"]["score_composed"] == 47.259375
    # route 1: red 0.7, outside 8 % -> 0.92: IS = 0.644; DS = 42.5 * 0.644 = 27.37
    assert r1["scores"]["score_penalty"] == 0.644
    assert r1["scores"]["score_composed"] == 27.37
    g = data["_checkpoint"]["global_record"]
    # 3 planned routes, 2 run: DS mean = (47.259375 + 27.37) / 3 = 24.876458
    assert g["scores_mean"]["score_composed"] == 24.876458
    assert g["scores_mean"]["score_route"] == 47.5
    # km = 2.0 + 0.425 = 2.425: 1 vehicle collision / 2.425 = 0.412; 3 min-speed... 2 / 2.425 = 0.825
    assert g["infractions"]["collisions_vehicle"] == 0.412
    assert g["infractions"]["min_speed_infractions"] == 0.825
    assert g["infractions"]["red_light"] == 0.412
    assert g["infractions"]["route_dev"] == 0.412
    assert g["infractions"]["outside_route_lanes"] == 0.02  # 20 m -> 0.02 km, not per km
    assert g["status"] == "Failed"
    assert g["meta"]["exceptions"] == [["RouteScenario_1_rep0", 1, "Failed - Agent deviated from the route"]]
    assert data["values"][:3] == ["24.876458", "47.5", "0.372198"]
    assert data["labels"][0] == "Avg. driving score"
    assert len(data["values"]) == len(data["labels"]) == 15


def test_score_rejects_what_is_not_a_results_file(tmp_path, capsys):
    bad = tmp_path / "x.json"
    bad.write_text('{"hello": 1}')
    assert main(["score", str(bad)]) == 2
    assert "not a Leaderboard results file" in capsys.readouterr().err
    bad.write_text("{nope")
    assert main(["score", str(bad)]) == 2
    # an infraction "list" that is a string would count its characters as messages
    bad.write_text(json.dumps({"_checkpoint": {"progress": [1, 1], "records": [
        {"route_id": "r", "infractions": {"red_light": "abc"}, "scores": {"score_route": 100}}]}}))
    assert main(["score", str(bad)]) == 2
    assert "must map each key to a list" in capsys.readouterr().err


def test_rescoring_is_idempotent():
    data = rescore_results(_carla_file())
    assert rescore_results(data) == data
    assert not math.isnan(data["_checkpoint"]["global_record"]["scores_mean"]["score_penalty"])


def test_summary_does_not_depend_on_the_order_routes_finished_in():
    """Workers finish routes in an order that changes from run to run; summary.csv (values and
    bootstrap intervals) must not: a bootstrap drawing the records in arrival order would give
    other intervals on each run."""
    from harness.scoring.outputs import summary_rows
    from harness.scoring.records import STABILITY
    rng = np.random.default_rng(3)
    records = [{"route_id": str(i), "repetition": 0, "ds": float(rng.uniform(0, 100)),
                "rc": float(rng.uniform(50, 100)), "is": float(rng.uniform(0, 1)),
                "collisions_layout": 0, "collisions_pedestrian": int(i % 7 == 0), "collisions_vehicle": int(i % 5 == 0),
                "km_driven": float(rng.uniform(0.1, 1.0)), **{k: float(rng.uniform(0, 10)) for k in STABILITY},
                "lb": {"status": "Completed" if i % 3 else "Failed", "infractions": inf()}}
               for i in range(40)]
    result = {"_checkpoint": {"global_record": {"infractions": {}}}}
    in_order = summary_rows(records, result)
    shuffled = [records[i] for i in rng.permutation(len(records))]
    assert summary_rows(shuffled, result) == in_order
    assert summary_rows(records[::-1], result) == in_order
    assert in_order[0]["ci95_low"] < in_order[0]["value"] < in_order[0]["ci95_high"]


def test_summary_intervals_equal_a_bootstrap_taken_one_resample_at_a_time(monkeypatch):
    """summary.csv's values and intervals, computed over all resamples at once, equal to the
    last bit those of the plain bootstrap: per metric, 2000 resamples drawn one after another
    from one generator (seed 0), the statistic of each taken from the resampled records with
    np.nanmean, Python sums and the success rule, the non-finite ones dropped, then the
    2.5 and 97.5 percentiles. Records with NaN and infinite stability values and routes with
    no km (Collision/km NaN, in some resamples or all), in sets of 1 route (no interval), 2, 7
    and 30."""
    from harness.scoring import outputs
    from harness.scoring.bench2drive import success
    from harness.scoring.records import STABILITY
    monkeypatch.setattr(outputs, "_round", lambda x, digits: x)  # compare unrounded
    collision_keys = ("collisions_layout", "collisions_pedestrian", "collisions_vehicle")

    def mean_of(key):
        def stat(rs):
            vals = np.array([r[key] for r in rs], dtype=float)
            return float(np.nanmean(vals)) if np.isfinite(vals).any() else math.nan
        return stat

    def per_km(rs):
        km = sum(r["km_driven"] for r in rs)
        return sum(r[k] for r in rs for k in collision_keys) / km if km > 0 else math.nan

    def oracle(records):
        records = sorted(records, key=lambda r: (r["repetition"], int(r["route_id"])))
        rng = np.random.default_rng(0)
        stats = [mean_of("ds"), mean_of("rc"), mean_of("is"),
                 lambda rs: 100.0 * sum(success(r["lb"]) for r in rs) / len(rs), per_km,
                 *[mean_of(k) for k in STABILITY]]
        out = []
        for stat in stats:
            value, n = stat(records), len(records)
            if n < 2:
                out.append((value, math.nan, math.nan))
                continue
            draws = np.array([stat([records[i] for i in rng.integers(n, size=n)]) for _ in range(2000)])
            draws = draws[np.isfinite(draws)]
            out.append((value, float(np.percentile(draws, 2.5)), float(np.percentile(draws, 97.5)))
                       if len(draws) else (value, math.nan, math.nan))
        return out

    def same(a, b):
        return a == b or (math.isnan(a) and math.isnan(b))

    rng = np.random.default_rng(11)
    for n in (1, 2, 7, 30):
        records = [{"route_id": str(i), "repetition": int(rng.integers(2)), "ds": float(rng.uniform(0, 100)),
                    "rc": float(rng.uniform(0, 100)), "is": float(rng.uniform(0, 1)),
                    **{k: int(rng.integers(3)) for k in collision_keys},
                    "km_driven": float(rng.choice([0.0, rng.uniform(0.01, 2.0)])),
                    **{k: float(rng.choice([math.nan, math.inf, rng.uniform(0, 10), rng.uniform(0, 10)]))
                       for k in STABILITY},
                    "lb": {"status": str(rng.choice(["Perfect", "Completed", "Failed - Agent got blocked"])),
                           "infractions": inf()}}
                   for i in range(n)]
        rows = outputs.summary_rows(records, {"_checkpoint": {"global_record": {}}})
        expected = oracle(records)
        assert len(rows) == len(expected) == 5 + len(STABILITY)
        for row, (value, lo, hi) in zip(rows, expected):
            assert same(row["value"], value) and same(row["ci95_low"], lo) and same(row["ci95_high"], hi), row


def test_summary_has_bench2drives_success_rate():
    """Success: Completed / Perfect with no infraction but minimum speed (Bench2Drive's
    merge_route_json.py): two of these four route runs, 50 %."""
    from harness.scoring.outputs import summary_rows
    from harness.scoring.records import STABILITY

    def rec(status, **lists):
        return {"route_id": "0", "repetition": 0, "ds": 50.0, "rc": 50.0, "is": 1.0, "collisions_layout": 0,
                "collisions_pedestrian": 0, "collisions_vehicle": 0, "km_driven": 0.1,
                **dict.fromkeys(STABILITY, 0.0), "lb": {"status": status, "infractions": inf(**lists)}}
    records = [rec("Perfect"), rec("Completed", min_speed_infractions=[speed(40.0)]),
               rec("Completed", outside_route_lanes=[outside(0.5, 0.01)]), rec("Failed - Agent got blocked")]
    rows = {r["metric"]: r for r in summary_rows(records, {"_checkpoint": {"global_record": {}}})}
    assert rows["success_rate (%)"]["value"] == 50.0
