"""The run folder's files as the leaderboard's and Bench2Drive's tools read them: strict
JSON lines, records.csv with the Leaderboard's route id and time names, summary.csv
rounded as results.json with every interval filled, the leaderboard's sensor names, a
crashed route's length as a driven one's, and the memory line of a short run."""
from __future__ import annotations

import csv
import json
import math

import pytest

from harness.runs.jobs import Job, crash_record
from harness.scoring.outputs import summary_rows
from harness.scoring.records import CSV_FIELDS, parse_record, record_line
from harness.scoring.scores import results
from scenarios import set_path
from scenarios.routefile import read_routes
from sumo_scimm.run_commands import memory_trend
from tests.run_folder_helpers import SMOKE_TWO, _cli


def _strict(line: str) -> dict:
    """json.loads that refuses NaN and infinities, as strict JSON parsers do."""
    def refuse(constant: str):
        raise ValueError(f"not JSON: {constant}")
    return json.loads(line, parse_constant=refuse)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """Routes 0 and 1 of town12_smoke driven by the route follower on one worker."""
    out = tmp_path_factory.mktemp("run") / "run"
    code, printed = _cli([*SMOKE_TWO, "--out", str(out)])
    assert code == 0, printed
    return out, printed


def test_records_jsonl_is_strict_json_with_null_for_an_undefined_figure(run):
    out, _ = run
    lines = (out / "records.jsonl").read_text().splitlines()
    records = [_strict(line) for line in lines]
    # the route follower predicts no waypoints: their curvature variation is undefined
    assert all(r["curvature_variation_wps"] is None for r in records)
    assert all(math.isnan(parse_record(line)["curvature_variation_wps"]) for line in lines)


def test_a_record_line_turns_every_non_finite_number_into_null_and_back():
    rec = {"key": "0_rep0", "speed_variation": math.nan, "collisions_per_km": math.inf, "ds": 1.5,
           "lb": {"meta": {"route_length": -math.inf}}, "efficiency": None}
    line = record_line(rec)
    assert _strict(line) == {"key": "0_rep0", "speed_variation": None, "collisions_per_km": None, "ds": 1.5,
                             "lb": {"meta": {"route_length": None}}, "efficiency": None}
    back = parse_record(line)
    assert math.isnan(back["speed_variation"]) and math.isnan(back["collisions_per_km"])
    assert back["efficiency"] is None  # null where undefined, in memory too


def test_records_csv_has_the_leaderboards_route_id_beside_ours_and_its_time_names(run):
    out, _ = run
    with open(out / "records.csv", newline="") as f:
        reader = csv.DictReader(f)
        rows = list(reader)
    assert tuple(reader.fieldnames) == CSV_FIELDS
    assert reader.fieldnames[:4] == ["key", "route", "route_id", "repetition"]
    assert {"duration_game", "duration_system"} <= set(reader.fieldnames)
    assert not {"game_time", "wall_time"} & set(reader.fieldnames)
    lb = json.loads((out / "results.json").read_text())["_checkpoint"]["records"]
    assert [(r["key"], r["route"], r["route_id"]) for r in rows] == [
        ("0_rep0", "0", "RouteScenario_0_rep0"), ("1_rep0", "1", "RouteScenario_1_rep0")]
    assert [r["route_id"] for r in rows] == [r["route_id"] for r in lb]
    assert [float(r["duration_game"]) for r in rows] == [r["meta"]["duration_game"] for r in lb]


def test_summary_csv_is_rounded_as_results_json_names_units_and_leaves_no_cell_empty(run):
    out, _ = run
    with open(out / "summary.csv", newline="") as f:
        rows = {r["metric"]: r for r in csv.DictReader(f)}
    assert "success_rate (%)" in rows and "success_rate" not in rows
    assert all(v != "" for r in rows.values() for v in r.values())
    g = json.loads((out / "results.json").read_text())["_checkpoint"]["global_record"]
    assert float(rows["driving_score"]["value"]) == g["scores_mean"]["score_composed"]
    for name, r in rows.items():
        digits = 3 if "per km" in name or name.endswith("(km)") or name == "collisions_per_km" else 6
        for cell in (r["value"], r["ci95_low"], r["ci95_high"]):
            assert cell == "nan" or float(cell) == round(float(cell), digits), (name, cell)


def test_the_per_km_intervals_are_the_leaderboards_rates_over_resampled_routes():
    """Two 1 km routes driven whole, one with no minimum-speed message and one with two:
    the rate is 2 / 2 km = 1 per km, and a resample holds route A twice (0 per km), A and B
    (1) or B twice (2), so its 2.5 % and 97.5 % points are 0 and 2; no outside-lanes
    message anywhere, so that row reads 0 km with interval [0, 0]."""
    from harness.scoring.infractions import KEYS
    from harness.scoring.records import STABILITY

    def route(i: int, slow: int) -> dict:
        inf = {k: [] for k in KEYS}
        inf["min_speed_infractions"] = ["Average speed is 50.0% of the surrounding traffic's one"] * slow
        lb = {"index": i, "route_id": f"RouteScenario_{i}_rep0", "status": "Completed", "infractions": inf,
              "scores": {"score_route": 100, "score_penalty": 1.0, "score_composed": 100.0},
              "meta": {"route_length": 1000.0, "duration_game": 1.0, "duration_system": 1.0}}
        return {"route_id": str(i), "repetition": 0, "ds": 100.0, "rc": 100.0, "is": 1.0, "km_driven": 1.0,
                "collisions_layout": 0, "collisions_pedestrian": 0, "collisions_vehicle": 0, "lb": lb,
                **{k: 0.0 for k in STABILITY}}

    records = [route(0, 0), route(1, 2)]
    rows = {r["metric"]: r for r in summary_rows(records, results([r["lb"] for r in records], 2, [], True))}
    slow = rows["min_speed_infractions (per km)"]
    assert (slow["value"], slow["ci95_low"], slow["ci95_high"]) == (1.0, 0.0, 2.0)
    lanes = rows["outside_route_lanes (km)"]
    assert (lanes["value"], lanes["ci95_low"], lanes["ci95_high"]) == (0.0, 0.0, 0.0)


def test_results_json_names_the_speedometer_as_the_leaderboard_does(run):
    out, _ = run
    # the route follower declares pose and speed: the leaderboard's name for the speedometer
    assert json.loads((out / "results.json").read_text())["sensors"] == ["pose", "carla_speedometer"]


def test_a_crashed_route_has_the_traced_length_of_a_driven_one(run):
    """Route 1's file says 142.3 m (to the cm); traced, as the episode's plan has it, 142.295 m."""
    out, _ = run
    driven = next(_strict(x) for x in (out / "records.jsonl").read_text().splitlines() if x.startswith('{"key": "1_'))
    route = next(r for r in read_routes(set_path("town12_smoke"))[1] if r.id == "1")
    assert route.length == 142.3
    crashed = crash_record(Job(1, route, 0, "route_follower", None, 0, str(out / "logs")), "worker died")
    assert crashed["status"] == "Failed - Simulation crashed"
    assert crashed["lb"]["meta"]["route_length"] == driven["lb"]["meta"]["route_length"] == 142.295
    assert crashed["length"] == driven["length"]


def test_the_memory_line_of_workers_with_two_routes_says_there_is_no_trend(run):
    _, printed = run
    line = next(x for x in printed.splitlines() if x.startswith("worker memory"))
    assert "nan" not in line
    assert line.endswith("(no trend: no worker ran 3 routes)")
    assert memory_trend(12.834) == "trend +12.83 MB per 100 routes"
