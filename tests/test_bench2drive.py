"""Bench2Drive's Success Rate, Driving Efficiency and Driving Smoothness, and its
metric_info.json, on short synthetic drives with every expected value worked out by hand
from Bench2Drive's definitions (docs/design.md §9.2)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from harness.scoring.bench2drive import (comfortable, mean_of, metric_info, route_efficiency, route_smoothness,
                                         success, success_rate, write_metric_info)
from harness.scoring.infractions import KEYS

DT = 0.05


def speed(p):
    return f"Average speed is {p}% of the surrounding traffic's one"


def rec(status, **lists):
    return {"status": status, "infractions": {k: lists.get(k, []) for k in KEYS}}


def test_success_is_completed_without_any_infraction_but_minimum_speed():
    assert success(rec("Perfect"))
    assert success(rec("Completed", min_speed_infractions=[speed(30.0), speed(30.0)]))
    assert not success(rec("Completed", outside_route_lanes=["Agent went outside its route lanes for about 0.1 "
                                                             "meters (0.0% of the completed route)"]))
    assert not success(rec("Completed", stop_infraction=["Agent ran a stop with id=1 at (x=0.0, y=0.0, z=0.0)"]))
    assert not success(rec("Failed - Agent got blocked"))
    # over the planned route runs: 2 successes of 5 planned (one never ran) = 40 %
    records = [rec("Perfect"), rec("Completed"), rec("Failed"), rec("Completed", red_light=["x"])]
    assert success_rate(records, 5) == 40.0


def test_efficiency_is_the_mean_checkpoint_value_up_to_1000_percent():
    # (50 + 150) / 2 = 100; 1200 % is left out
    assert route_efficiency([speed(50.0), speed(150.0), speed(1200.0)]) == 100.0
    assert route_efficiency([]) is None
    assert route_efficiency([speed(1200.0)]) is None  # Bench2Drive's tool divides by zero here
    # over routes: those without a value are left out, not counted as 0
    assert mean_of([100.0, None, 60.0, float("nan")]) == 80.0
    assert math.isnan(mean_of([None]))


def _straight(n: int, accel: float, yaw: float, v0: float = 5.0) -> dict:
    """Positions integrated as the ego is (new speed times dt along the heading)."""
    v = v0 + accel * DT * np.arange(1, n + 1)
    v[0] = v0 + accel * DT
    s = np.cumsum(v * DT)
    return {"x": 10.0 + s * math.cos(yaw), "y": -3.0 + s * math.sin(yaw), "yaw": np.full(n, yaw), "v": v}


def test_metric_info_of_a_straight_drive_under_constant_acceleration():
    # 1.5 m/s^2 along 30 deg: acceleration (1.5 cos 30, 1.5 sin 30) = (1.2990, 0.75) at
    # every tick (the first two, without two displacements before them, repeat the third);
    # no rotation
    info = metric_info(_straight(30, 1.5, math.radians(30)))
    assert set(info) == {"acceleration", "angular_velocity", "forward_vector", "right_vector", "location", "rotation"}
    np.testing.assert_array_equal(info["acceleration"], np.tile([1.299, 0.75, 0.0], (30, 1)))
    np.testing.assert_array_equal(info["angular_velocity"], np.zeros((30, 3)))
    np.testing.assert_array_equal(info["forward_vector"][0], [0.866025, 0.5, 0.0])
    np.testing.assert_array_equal(info["right_vector"][0], [0.5, -0.866025, 0.0])  # the car's right side
    np.testing.assert_array_equal(info["rotation"][0], [0.0, 0.0, 30.0])
    assert route_smoothness(info) == 1.0  # 1.5 m/s^2 < 2.40, no jerk, no rotation


def test_metric_info_of_a_steady_turn_in_degrees_per_second():
    # 10 m/s on a 100 m circle, counter-clockwise: yaw rate 0.1 rad/s = 5.7296 deg/s; the
    # centre's acceleration V^2 / R = 1 m/s^2 points left, so along the right vector it
    # is -1 (within 1e-3: the acceleration from the chords before tick k points a tick
    # behind its heading, 0.005 rad, and the chord shortens the arc by 2e-6 relative)
    n, w, r = 40, 0.1, 100.0
    th = w * DT * np.arange(n)
    log = {"x": r * np.sin(th), "y": r * (1 - np.cos(th)), "yaw": th, "v": np.full(n, w * r)}
    info = metric_info(log)
    np.testing.assert_array_equal(info["angular_velocity"][:, 2], np.full(n, 5.7296))
    lat = np.einsum("ij,ij->i", info["acceleration"][:, :2], info["right_vector"][:, :2])
    np.testing.assert_allclose(lat, -1.0, atol=1e-3)
    # Bench2Drive compares deg/s with nuPlan's 0.95 rad/s bound: this gentle turn fails it
    assert route_smoothness(info) == 0.0


def test_yaw_rate_unwrap_by_2_pi_on_degrees_per_second():
    # Bench2Drive unwraps the deg/s yaw rate with steps of 2 pi as if it were an angle: after
    # a first sample of 0, a steady 5.7296 deg/s reads 5.7296 - 6.2832 = -0.5536, inside
    # 0.95, so a chunk that starts straight and then turns passes; one that starts turning fails
    rates = np.r_[0.0, np.full(19, 5.7296)]
    seg = _segment(20, np.zeros(20))
    assert comfortable({**seg, "angular_velocity": np.stack([np.zeros(20), np.zeros(20), rates], 1)})
    assert not comfortable({**seg, "angular_velocity": np.stack([np.zeros(20), np.zeros(20), rates[::-1]], 1)})


def _segment(n: int, lon: np.ndarray, yaw_rate: float = 0.0) -> dict:
    """n samples heading along +x: acceleration (lon, 0), yaw rate [deg/s]."""
    z = np.zeros(n)
    return {"acceleration": np.stack([lon, z, z], 1), "angular_velocity": np.stack([z, z, np.full(n, yaw_rate)], 1),
            "forward_vector": np.tile([1.0, 0.0, 0.0], (n, 1)), "right_vector": np.tile([0.0, -1.0, 0.0], (n, 1)),
            "location": np.zeros((n, 3)), "rotation": np.zeros((n, 3))}


def test_smoothness_counts_comfortable_one_second_chunks():
    # chunk 1: 2.0 m/s^2 (inside (-4.05, 2.40)) -> comfortable; chunk 2: -5.0 m/s^2 -> not;
    # chunk 3: no acceleration but 1 deg/s of yaw rate (> 0.95) -> not; 7 samples left over
    # are dropped: 1 of 3 chunks
    parts = [_segment(20, np.full(20, 2.0)), _segment(20, np.full(20, -5.0)), _segment(20, np.zeros(20), 1.0),
             _segment(7, np.zeros(7))]
    info = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    assert route_smoothness(info) == pytest.approx(1 / 3)
    assert route_smoothness(_segment(10, np.full(10, 1.0))) == 1.0  # <= 20 samples: one chunk
    assert route_smoothness(_segment(2, np.zeros(2))) is None  # too short for the filter


def _lateral(n: int, lat: float) -> dict:
    """n samples heading along +x with a steady lateral acceleration ``lat`` [m/s^2] along
    the right vector (0, -1): acceleration (0, -lat)."""
    seg = _segment(n, np.zeros(n))
    return {**seg, "acceleration": np.tile([0.0, -lat, 0.0], (n, 1))}


def test_comfort_bounds_of_the_longitudinal_and_lateral_acceleration():
    """nuPlan's open bounds [m/s^2]: longitudinal (-4.05, 2.40), lateral (-4.89, 4.89); a
    steady value is its own filtered value (to ~1e-15, far inside the 0.01 m/s^2 margins)."""
    assert comfortable(_segment(20, np.full(20, 2.39)))
    assert not comfortable(_segment(20, np.full(20, 2.41)))
    assert comfortable(_segment(20, np.full(20, -4.04)))
    assert not comfortable(_segment(20, np.full(20, -4.06)))
    for sign in (1.0, -1.0):
        assert comfortable(_lateral(20, sign * 4.88))
        assert not comfortable(_lateral(20, sign * 4.90))


def test_efficiency_keeps_a_checkpoint_of_exactly_1000_percent():
    """Bench2Drive skips values > 1000 only: (1000 + 0) / 2 = 500."""
    assert route_efficiency([speed(1000.0), speed(0.0)]) == 500.0


def test_jerk_takes_bench2drives_0_1_s_spacing():
    # a ramp of the longitudinal acceleration, 0.45 m/s^2 per 0.05 s tick = 9 m/s^3; the
    # Savitzky-Golay derivative is exact on a line and reads 0.45 / 0.1 = 4.5 > 4.13: fails
    assert not comfortable(_segment(10, -2.0 + 0.45 * np.arange(10)))
    # 5 m/s^3 over 20 ticks (-3.0 to 1.75 m/s^2) reads 2.5 < 4.13: passes, where nuPlan's
    # 4.13 m/s^3 at the true spacing would fail it
    assert comfortable(_segment(20, -3.0 + 0.25 * np.arange(20)))


def _oracle_smoothness(info: dict) -> float:
    """Bench2Drive's loop, written out: each 20-sample chunk filtered on its own with scipy's
    savgol_filter (window 7, order 2, spacing 0.1 s), the six bounds checked on it."""
    from scipy.signal import savgol_filter
    n = len(info["location"])
    ok = []
    for lo in range(0, n - 20 + 1, 20):
        acc = info["acceleration"][lo:lo + 20, :2]
        fwd, right = info["forward_vector"][lo:lo + 20, :2], info["right_vector"][lo:lo + 20, :2]
        h = info["angular_velocity"][lo:lo + 20, 2]
        h = h - 2 * math.pi * np.r_[0.0, np.cumsum(np.round(np.diff(h) / (2 * math.pi)))]
        lon, lat = (savgol_filter((acc * v).sum(1), 7, 2) for v in (fwd, right))
        mag = savgol_filter(np.hypot(acc[:, 0], acc[:, 1]), 7, 2)
        rate = savgol_filter(h, 7, 2)
        jerk, lon_jerk = (savgol_filter(s, 7, 2, deriv=1, delta=0.1) for s in (mag, lon))
        ok.append(all([np.all((lon > -4.05) & (lon < 2.40)), np.all(np.abs(lat) < 4.89), np.all(np.abs(jerk) < 8.37),
                       np.all(np.abs(lon_jerk) < 4.13), np.all(np.abs(rate) < 0.95)]))
    return sum(ok) / len(ok)


@pytest.mark.parametrize("deriv", [0, 1])
def test_the_savitzky_golay_matrix_is_scipys_filter(deriv):
    """The matrix of every length from 3 samples (the window shrinks below 7, even lengths
    included) to 40 is scipy's savgol_filter of the unit vectors, to float64 rounding (entries
    up to 10 per second for the derivative; 3.6e-14 apart at most)."""
    from scipy.signal import savgol_filter

    from harness.scoring.bench2drive import _savgol_matrix
    for n in range(3, 41):
        ref = savgol_filter(np.eye(n), min(7, n), 2, deriv=deriv, delta=0.1, axis=0)
        np.testing.assert_allclose(_savgol_matrix(n, deriv), ref, rtol=0, atol=1e-12, err_msg=str(n))


def test_smoothness_of_every_chunk_at_once_equals_the_chunk_by_chunk_filter():
    # 200 seeded drives of 21-400 ticks whose speed and heading wander at random (up to
    # 0.06 m/s and 0.0008 rad a tick), about half of their chunks comfortable: the chunks
    # filtered together (one matrix per filter) read as Bench2Drive's chunk-by-chunk loop
    rng = np.random.default_rng(0)
    shares = []
    for _ in range(200):
        n = int(rng.integers(21, 400))
        v = np.clip(8 + np.cumsum(rng.normal(0, 0.06 * rng.random(), n)), 0, None)
        yaw = np.cumsum(rng.normal(0, 0.0008 * rng.random(), n))
        info = metric_info({"x": np.cumsum(v * DT * np.cos(yaw)), "y": np.cumsum(v * DT * np.sin(yaw)),
                            "yaw": yaw, "v": v})
        shares.append(_oracle_smoothness(info))
        assert route_smoothness(info) == shares[-1]
    assert 0.3 < np.mean(shares) < 0.7  # both outcomes are exercised


def test_metric_info_file_is_what_bench2drives_tool_reads(tmp_path):
    info = metric_info(_straight(3, 1.0, 0.0))
    path = tmp_path / "b2d" / "RouteScenario_0_rep0_town12" / "metric_info.json"
    write_metric_info(path, info)
    data = json.loads(path.read_text())
    assert list(data) == ["0", "1", "2"]
    assert list(data["1"]) == ["acceleration", "angular_velocity", "forward_vector", "right_vector", "location",
                               "rotation"]
    assert data["1"]["acceleration"] == [1.0, 0.0, 0.0] and data["0"]["rotation"] == [0.0, 0.0, 0.0]


def _run_folder(path, routes):
    """A run folder's records.jsonl: (hazard, status, ds, efficiency, smoothness, lists) per route."""
    path.mkdir(parents=True)
    lines = [json.dumps({"key": f"{i}_rep0", "hazard": h, "ds": ds, "efficiency": eff, "smoothness": sm,
                         "lb": rec(status, **lists)}) for i, (h, status, ds, eff, sm, lists) in enumerate(routes)]
    (path / "records.jsonl").write_text("\n".join(lines) + "\n")
    return path


def test_report_tables_of_bench2drives_figures_and_per_hazard(tmp_path):
    from harness.scoring.b2d_tables import b2d_tables
    red = {"red_light": ["Agent ran a red light 1 at (x=0.0, y=0.0, z=0.0)"]}
    a = _run_folder(tmp_path / "a", [("ParkedObstacle", "Completed", 100.0, 90.0, 1.0, {}),
                                     ("ParkedObstacle", "Completed", 70.0, 110.0, 0.5, red),
                                     ("SignalizedJunction", "Failed - Agent got blocked", 10.0, None, 0.0, {}),
                                     ("SignalizedJunction", "Perfect", 100.0, 100.0, None, {})])
    b = _run_folder(tmp_path / "b", [("ParkedObstacle", "Perfect", 100.0, 95.0, 1.0, {})])
    (main, main_rows, _), (hazard, hazard_rows, md) = b2d_tables({"A": [a], "B": [b]})
    assert (main, hazard) == ("b2d", "per_hazard")
    # A: DS (100 + 70 + 10 + 100) / 4 = 70; SR 2 of 4 = 50 %; efficiency (90 + 110 + 100) / 3
    # = 100 (the route without a checkpoint left out); smoothness (1 + 0.5 + 0) / 3 = 50 %
    ra = main_rows[0]
    assert (ra["arm"], ra["runs"], ra["route_runs"]) == ("A", 1, 4)
    assert (ra["DS"], ra["SR"], ra["efficiency"], ra["smoothness"]) == (70.0, 50.0, 100.0, 50.0)
    assert ra["SR ci95_low"] <= 50.0 <= ra["SR ci95_high"]
    # per hazard: ParkedObstacle A 1 of 2 (DS 85), B 1 of 1; SignalizedJunction A 1 of 2 (DS 55), B none
    rows = {r["hazard"]: r for r in hazard_rows}
    parked = rows["ParkedObstacle"]
    assert (parked["A SR"], parked["A DS"], parked["A n"]) == (50.0, 85.0, 2)
    assert (rows["ParkedObstacle"]["B SR"], rows["ParkedObstacle"]["B n"]) == (100.0, 1)
    assert (rows["SignalizedJunction"]["A SR"], rows["SignalizedJunction"]["A DS"]) == (50.0, 55.0)
    assert rows["SignalizedJunction"]["B n"] == 0 and math.isnan(rows["SignalizedJunction"]["B SR"])
    assert "| SignalizedJunction | 50.0 | 55.0 | 2 | - | - | 0 |" in md


def test_bench2drive_rules_log_every_minimum_speed_checkpoint():
    """A 100 m route, 1 m per tick, the ego at 50 % of the traffic's speed up to tick 50 and
    150 % after. Leaderboard 2.0: 4 checkpoints of 25 m, closed when more than 25 m were
    driven since the last (ticks 26, 52, 78, and at the end), only those below 100 % logged.
    Bench2Drive: 20 of 5 m (closed every 6 ticks), every one logged, the last twice."""
    from types import SimpleNamespace

    from harness.scoring.infractions import min_speed
    plan = SimpleNamespace(s=np.arange(101.0), length=100.0)
    k = np.arange(101)
    log = {"t": k * DT, "route_index": k.astype(float), "bg_speed": np.full(101, 10.0),
           "v": np.where(k <= 50, 5.0, 15.0)}
    # ticks 0-25: 50 %; ticks 26-51: (25 x 5 + 15) / (26 x 10) = 53.85 %; then 150 %
    assert min_speed(log, plan, "lb2.0", ended_normally=True) == [speed(50.0), speed(53.85)]
    b2d = min_speed(log, plan, "b2d", ended_normally=True)
    # ticks 0-47: 8 chunks at 50 %; 48-53: (3 x 5 + 3 x 15) / 60 = 100 %; 54-95: 7 at 150 %;
    # 96-100 at 150 %, twice (the leaderboard's double terminate)
    assert b2d == [speed(50.0)] * 8 + [speed(100.0)] + [speed(150.0)] * 9
    assert route_efficiency(b2d) == pytest.approx(1850 / 18)


@pytest.mark.parametrize("length, messages", [(142.0, 19), (164.0, 20)])
def test_bench2drive_checkpoints_number_19_or_20_with_the_route_length(length, messages):
    """Route points 1 m apart, the ego on every one in turn. A checkpoint of length / 20
    closes at the first point more than that past the last closing point: 142 m gives
    7.1 m, closed every 8 m, 17 times up to 136 m (the next would need 143.1 m); 164 m
    gives 8.2 m, closed every 9 m, 18 times up to 162 m. Then the final checkpoint twice
    (> 95 % at the end, the double terminate): 19 and 20 messages, as town12_smoke's
    routes 1 (142.295 m) and 0 (164.503 m) get under b2d."""
    from types import SimpleNamespace

    from harness.scoring.infractions import min_speed
    n = int(length) + 1
    plan = SimpleNamespace(s=np.arange(float(n)), length=length)
    k = np.arange(n)
    log = {"t": k * DT, "route_index": k.astype(float), "bg_speed": np.full(n, 10.0), "v": np.full(n, 5.0)}
    assert min_speed(log, plan, "b2d", ended_normally=True) == [speed(50.0)] * messages


@pytest.mark.parametrize("rules, expected", [("b2d", 100.0), ("lb2.0", None)])
def test_older_records_get_efficiency_only_from_a_bench2drive_run(tmp_path, rules, expected):
    """Records from before the efficiency was in them: from the minimum-speed messages when
    the run's identity file says b2d (every checkpoint logged); else undefined, since
    Leaderboard rules log only the checkpoints below 100 %."""
    from harness.scoring.b2d_tables import route_figures
    tmp_path.joinpath("records.jsonl").write_text(json.dumps(
        {"key": "0_rep0", "ds": 100.0, "smoothness": 1.0,
         "lb": rec("Completed", min_speed_infractions=[speed(50.0), speed(150.0)])}) + "\n")
    tmp_path.joinpath("run.json").write_text(json.dumps({"route_runs": {"0_rep0": {"rules": rules}}}))
    (fig,) = route_figures(tmp_path)
    assert (fig["efficiency"], fig["hazard"], fig["success"]) == (expected, "unknown", True)
