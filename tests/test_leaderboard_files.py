"""results.json as the leaderboard's StatisticsManager writes it, to the character, for a
finished, a single-route, an unfinished and a crashed run: each expected file is built by
hand below from the leaderboard's rules (docs/design.md §9.1: its code's number
types, its rounding, its order of operations) and compared as text. Also `score` on
Bench2Drive files under Leaderboard rules, and on files that are not results files."""
from __future__ import annotations

import json

import pytest

from harness.scoring.bench2drive import record_keys
from harness.scoring.infractions import KEYS
from harness.scoring.scores import LABELS, rescore_results, results, results_text, route_record
from sumo_scimm.cli import main

VEH = "Agent collided against object with type=vehicle.sumo.car and id=7 at (x=1.0, y=2.0, z=0.0)"
DEV = "Agent deviated from the route at (x=5.0, y=6.0, z=0.0)"
SLOW = "Average speed is 80.0% of the surrounding traffic's one"


def inf(**lists):
    return {k: lists.get(k, []) for k in KEYS}


def completed_route(i: int = 0) -> dict:
    """Completed, one min-speed checkpoint at 80 %: IS = 1 - 0.3 * 0.2 = 0.94, DS 94.0."""
    return route_record(i, f"RouteScenario_{i}_rep0", inf(min_speed_infractions=[SLOW]), 100,
                        {"route_length": 200.0, "duration_game": 0.1, "duration_system": 0.2})


def deviated_route(i: int = 1) -> dict:
    """Deviated at RC 42.5 after a vehicle collision: IS 0.6, DS 25.5."""
    return route_record(i, f"RouteScenario_{i}_rep0", inf(collisions_vehicle=[VEH], route_dev=[DEV]), 42.5,
                        {"route_length": 100.0, "duration_game": 0.2, "duration_system": 0.1})


def crashed_route(i: int) -> dict:
    return route_record(i, f"RouteScenario_{i}_rep0", inf(), 0.0,
                        {"route_length": 150.0, "duration_game": 0.0, "duration_system": 0.0},
                        crash="Simulation crashed")


def _record(i, status, n, lists, scores, meta):
    return {"index": i, "route_id": f"RouteScenario_{i}_rep0", "status": status, "num_infractions": n,
            "infractions": inf(**lists), "scores": scores, "meta": meta}


# the same records written out by hand: the leaderboard's completed RC is the int 100
HAND_COMPLETED = _record(0, "Completed", 1, {"min_speed_infractions": [SLOW]},
                         {"score_route": 100, "score_penalty": 0.94, "score_composed": 94.0},
                         {"route_length": 200.0, "duration_game": 0.1, "duration_system": 0.2})
HAND_DEVIATED = _record(1, "Failed - Agent deviated from the route", 2,
                        {"collisions_vehicle": [VEH], "route_dev": [DEV]},
                        {"score_route": 42.5, "score_penalty": 0.6, "score_composed": 25.5},
                        {"route_length": 100.0, "duration_game": 0.2, "duration_system": 0.1})
HAND_CRASHED = _record(1, "Failed - Simulation crashed", 0, {},
                       {"score_route": 0.0, "score_penalty": 1.0, "score_composed": 0.0},
                       {"route_length": 150.0, "duration_game": 0.0, "duration_system": 0.0})


def _file(records, progress, status, global_record=None, values=None):
    return {"_checkpoint": {"global_record": global_record or {}, "progress": progress, "records": records},
            "entry_status": status, "eligible": status == "Finished", "sensors": ["speed"],
            "values": values or [], "labels": list(LABELS) if global_record else []}


def test_records_are_the_hand_written_ones():
    assert completed_route() == HAND_COMPLETED
    assert deviated_route() == HAND_DEVIATED
    assert crashed_route(1) == HAND_CRASHED


def test_finished_run_file_is_the_leaderboards_to_the_character():
    # N = 2. means accumulate score / N: DS 94/2 + 25.5/2 = 59.75, RC 50 + 21.25 = 71.25,
    # IS 0.47 + 0.3 = 0.77; std (N - 1 = 1): 34.25 * sqrt 2 = 48.437, 28.75 * sqrt 2 = 40.659,
    # 0.17 * sqrt 2 = 0.24; km = 0.2 + 0.0425 = 0.2425: 1 / 0.2425 = 4.124 per km; no
    # outside-lanes message: 0.0 (a float, "0.0"); meta sums NOT rounded: 0.1 + 0.2 is
    # 0.30000000000000004 in binary floating point
    g = {"index": -1, "route_id": -1, "status": "Failed",
         "infractions": {**{k: 0.0 for k in KEYS}, "collisions_vehicle": 4.124, "min_speed_infractions": 4.124,
                         "route_dev": 4.124},
         "scores_mean": {"score_composed": 59.75, "score_route": 71.25, "score_penalty": 0.77},
         "scores_std_dev": {"score_composed": 48.437, "score_route": 40.659, "score_penalty": 0.24},
         "meta": {"total_length": 300.0, "duration_game": 0.30000000000000004,
                  "duration_system": 0.30000000000000004,
                  "exceptions": [["RouteScenario_1_rep0", 1, "Failed - Agent deviated from the route"]]}}
    values = ["59.75", "71.25", "0.77", "0.0", "4.124", "0.0", "0.0", "0.0", "0.0", "4.124", "0.0", "0.0", "0.0",
              "0.0", "4.124"]
    expected = _file([HAND_COMPLETED, HAND_DEVIATED], [2, 2], "Finished", g, values)
    text = results_text(results([completed_route(), deviated_route()], 2, ["speed"], finished=True))
    assert text == json.dumps(expected, indent=4)
    assert '"score_route": 100,' in text and '"outside_route_lanes": 0.0,' in text and '"0.0"' in text


def test_single_route_run_has_integer_zero_standard_deviations():
    g = {"index": -1, "route_id": -1, "status": "Completed",
         "infractions": {**{k: 0.0 for k in KEYS}, "min_speed_infractions": 5.0},  # 1 / 0.2 km
         "scores_mean": {"score_composed": 94.0, "score_route": 100.0, "score_penalty": 0.94},
         "scores_std_dev": {"score_composed": 0, "score_route": 0, "score_penalty": 0},
         "meta": {"total_length": 200.0, "duration_game": 0.1, "duration_system": 0.2, "exceptions": []}}
    values = ["94.0", "100.0", "0.94", *["0.0"] * 11, "5.0"]
    expected = _file([HAND_COMPLETED], [1, 1], "Finished", g, values)
    assert results_text(results([completed_route()], 1, ["speed"], finished=True)) == json.dumps(expected, indent=4)


def test_unfinished_run_file_has_no_global_record_values_or_labels():
    expected = _file([HAND_COMPLETED], [1, 3], "Started")
    text = results_text(results([completed_route()], 3, ["speed"], finished=False))
    assert text == json.dumps(expected, indent=4)
    assert '"global_record": {},' in text and '"values": [],' in text and '"eligible": false' in text


def test_crashed_run_is_crashed_and_not_eligible():
    # unfinished: as the leaderboard leaves the file when the simulation crashes (it stops there)
    expected = _file([HAND_COMPLETED, HAND_CRASHED], [2, 3], "Crashed")
    text = results_text(results([completed_route(), crashed_route(1)], 3, ["speed"], finished=False))
    assert text == json.dumps(expected, indent=4)
    # every route run: the global record, and still Crashed (compute_global_statistics' rule)
    # N = 3: DS 94/3 + 0/3 + 25.5/3 = 39.833333, RC 33.333333 + 0 + 14.166667 = 47.5,
    # IS 0.313333 + 0.333333 + 0.2 = 0.846667; std (N - 1 = 2): below; km = 0.2 + 0 + 0.0425
    deviated = {**HAND_DEVIATED, "index": 2, "route_id": "RouteScenario_2_rep0"}
    g = {"index": -1, "route_id": -1, "status": "Failed",
         "infractions": {**{k: 0.0 for k in KEYS}, "collisions_vehicle": 4.124, "min_speed_infractions": 4.124,
                         "route_dev": 4.124},
         "scores_mean": {"score_composed": 39.833333, "score_route": 47.5, "score_penalty": 0.846667},
         "scores_std_dev": {"score_composed": 48.612, "score_route": 50.187, "score_penalty": 0.216},
         "meta": {"total_length": 450.0, "duration_game": 0.30000000000000004,
                  "duration_system": 0.30000000000000004,
                  "exceptions": [["RouteScenario_1_rep0", 1, "Failed - Simulation crashed"],
                                 ["RouteScenario_2_rep0", 2, "Failed - Agent deviated from the route"]]}}
    values = ["39.833333", "47.5", "0.846667", "0.0", "4.124", "0.0", "0.0", "0.0", "0.0", "4.124", "0.0", "0.0",
              "0.0", "0.0", "4.124"]
    expected = _file([HAND_COMPLETED, HAND_CRASHED, deviated], [3, 3], "Crashed", g, values)
    text = results_text(results([completed_route(), crashed_route(1), deviated_route(2)], 3, ["speed"], finished=True))
    assert text == json.dumps(expected, indent=4)


def test_a_route_that_failed_to_load_has_length_0_and_is_rescored():
    """The leaderboard writes route_length 0 for a route whose scenario failed to load (its
    route length is reset between routes): a file with one is read, not refused."""
    unloaded = {**HAND_CRASHED, "meta": {**HAND_CRASHED["meta"], "route_length": 0}}
    out = rescore_results(_file([HAND_COMPLETED, unloaded], [2, 2], "Crashed"))
    assert [r["scores"]["score_composed"] for r in out["_checkpoint"]["records"]] == [94.0, 0.0]
    assert out["_checkpoint"]["records"][1]["meta"]["route_length"] == 0


def test_crashed_run_standard_deviations_by_hand():
    # DS: (54.166667^2 + 39.833333^2 + 14.333333^2) / 2 = (2934.03 + 1586.69 + 205.44) / 2 = 2363.08
    ds = ((94 - 39.833333) ** 2 + 39.833333 ** 2 + (25.5 - 39.833333) ** 2) / 2
    assert round(ds, 2) == 2363.08 and round(ds ** 0.5, 3) == 48.612
    # RC: (52.5^2 + 47.5^2 + 5^2) / 2 = (2756.25 + 2256.25 + 25) / 2 = 2518.75
    rc = ((100 - 47.5) ** 2 + 47.5 ** 2 + (42.5 - 47.5) ** 2) / 2
    assert rc == pytest.approx(2518.75) and round(rc ** 0.5, 3) == 50.187


def test_outside_lanes_penalty_uses_the_unrounded_percentage():
    # 12.3456789 m of 299.7 m: 4.119346... %, the message says 4.12 %; with a vehicle
    # collision (0.6) and a stop (0.8): IS = 0.48 * 0.95880654 = 0.46022714 (DS 46.022714),
    # where the message's 4.12 % gives 0.48 * 0.9588 = 0.460224
    msg = "Agent went outside its route lanes for about 12.346 meters (4.12% of the completed route)"
    lists = inf(outside_route_lanes=[msg], collisions_vehicle=[VEH],
                stop_infraction=["Agent ran a stop with id=h3 at (x=1.0, y=2.0, z=0.0)"])
    meta = {"route_length": 300.0, "duration_game": 30.05, "duration_system": 4.5}
    exact = route_record(0, "RouteScenario_0_rep0", lists, 100, meta, outside_pct=12.3456789 / 299.7 * 100)
    assert exact["scores"] == {"score_route": 100, "score_penalty": 0.460227, "score_composed": 46.022714}
    from_message = route_record(0, "RouteScenario_0_rep0", lists, 100, meta)
    assert from_message["scores"]["score_penalty"] == 0.460224


def test_bench2drive_records_carry_its_keys_in_its_order():
    rec = route_record(0, "RouteScenario_3_rep0", inf(min_speed_infractions=[SLOW]), 100,
                       {"route_length": 200.0, "duration_game": 0.1, "duration_system": 0.2}, "b2d",
                       b2d=record_keys("3", 0, "town12", "ParkedObstacle_1"))
    assert list(rec) == ["index", "route_id", "scenario_name", "weather_id", "save_name", "status", "num_infractions",
                         "infractions", "scores", "meta", "town_name"]
    assert (rec["scenario_name"], rec["weather_id"], rec["save_name"], rec["town_name"]) == \
        ("ParkedObstacle_1", None, "RouteScenario_3_rep0_town12_ParkedObstacle_1", "town12")
    assert rec["scores"]["score_penalty"] == 1.0  # no minimum-speed penalty under Bench2Drive's rules


def _b2d_file() -> dict:
    """A Bench2Drive endpoint record: every checkpoint logged, 1200 % among them, no penalty."""
    speeds = ["Average speed is 1200.0% of the surrounding traffic's one", "Average speed is 100.0% of the "
              "surrounding traffic's one", "Average speed is 50.0% of the surrounding traffic's one"]
    rec = _record(0, "Completed", 3, {"min_speed_infractions": speeds},
                  {"score_route": 100, "score_penalty": 1.0, "score_composed": 100.0},
                  {"route_length": 200.0, "duration_game": 30.0, "duration_system": 9.0})
    return _file([rec], [1, 1], "Finished", {"scores_mean": {}}, ["100.0"])


def test_leaderboard_rules_drop_the_checkpoints_bench2drive_logs_at_100_percent_or_more(tmp_path, capsys):
    notes: list[str] = []
    out = rescore_results(_b2d_file(), "lb2.0", notes)
    r = out["_checkpoint"]["records"][0]
    # only the 50 % checkpoint stays: IS = 1 - 0.3 * 0.5 = 0.85, never above 1
    assert r["infractions"]["min_speed_infractions"] == ["Average speed is 50.0% of the surrounding traffic's one"]
    assert r["scores"] == {"score_route": 100, "score_penalty": 0.85, "score_composed": 85.0}
    assert (r["num_infractions"], r["status"]) == (1, "Completed")
    assert len(notes) == 1 and "2 minimum-speed messages at >= 100 % dropped" in notes[0]
    # lb2.1: 0.4 * 0.5 = 0.2 -> IS 1 / 1.2
    assert rescore_results(_b2d_file(), "lb2.1")["_checkpoint"]["records"][0]["scores"]["score_penalty"] == 0.833333
    # b2d keeps them all, no penalty
    b2d = rescore_results(_b2d_file(), "b2d")["_checkpoint"]["records"][0]
    assert len(b2d["infractions"]["min_speed_infractions"]) == 3 and b2d["scores"]["score_penalty"] == 1.0
    src = tmp_path / "b2d.json"
    src.write_text(json.dumps(_b2d_file()))
    assert main(["score", str(src), "--out", str(tmp_path / "lb.json")]) == 0
    err = capsys.readouterr().err
    assert "note: 2 minimum-speed messages at >= 100 % dropped" in err


def test_score_of_an_unfinished_file_keeps_no_global_record(tmp_path, capsys):
    src = tmp_path / "partial.json"
    src.write_text(results_text(results([completed_route()], 3, ["speed"], finished=False)))
    assert main(["score", str(src), "--out", str(tmp_path / "out.json")]) == 0
    assert "1 of 3 route runs, Started: route scores only" in capsys.readouterr().out
    assert json.loads((tmp_path / "out.json").read_text()) == json.loads(src.read_text())


@pytest.mark.parametrize("content", ['{"hello": 1}', '{"_checkpoint": {"records": []}}', "[1, 2]",
                                     '{"route_runs": {"0_rep0": {"seed": 1}}}'])
def test_a_file_that_is_not_a_results_file_is_said_so_once(tmp_path, capsys, content):
    bad = tmp_path / "x.json"
    bad.write_text(content)
    assert main(["score", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("not a Leaderboard results file") == 1, err
    assert "results.json of a 'sumo-scimm eval' run" in err and len(err.splitlines()) == 1


def _job(rules: str):
    from harness.runs.jobs import Job
    from scenarios.routefile import Hazard, Route
    hazard = Hazard("ParkedObstacle_1", "ParkedObstacle", (0.0, 0.0, 0.0, 0.0), {"distance": "40"})
    route = Route("7", "town12", ((0.0, 0.0, 0.0), (100.0, 0.0, 0.0)), (hazard,), ("e1",), 0.0, 100.0, 100.0)
    return Job(3, route, 0, "expert", None, 1, "/nonexistent/logs", rules)


@pytest.mark.parametrize("rules", ["lb2.0", "b2d"])
def test_route_record_of_a_run(rules):
    """A completed route's Leaderboard record has the int 100 (the CSV keeps 100.0); the
    outside-lanes penalty comes from the unrounded value; Bench2Drive's keys only under b2d."""
    from harness.runs.jobs import make_record
    msg = "Agent went outside its route lanes for about 12.346 meters (4.12% of the completed route)"
    r = make_record(_job(rules), "Completed", 100.0, 100.0, 20.0, 2.0, 400, "", inf(outside_route_lanes=[msg]), {},
                    rules, outside_pct=4.1193, efficiency=87.5, smoothness=0.25)
    assert r["lb"]["scores"] == {"score_route": 100, "score_penalty": 0.958807, "score_composed": 95.8807}
    assert (r["rc"], r["ds"], r["outside_lanes_pct"]) == (100.0, 95.8807, 4.12)
    assert (r["hazard"], r["efficiency"], r["smoothness"]) == ("ParkedObstacle", 87.5, 0.25)
    if rules == "b2d":
        assert r["lb"]["save_name"] == "RouteScenario_7_rep0_town12_ParkedObstacle_1"
        assert list(r["lb"])[2:5] == ["scenario_name", "weather_id", "save_name"] and list(r["lb"])[-1] == "town_name"
    else:
        assert not set(r["lb"]) & {"scenario_name", "weather_id", "save_name", "town_name"}
