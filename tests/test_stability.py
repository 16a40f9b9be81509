"""The temporal-stability metrics (harness.scoring.stability, the paper's Table 4), with values
derived by hand and np.polyfit as the oracle of the batched quadratic fits."""
import math
import warnings

import numpy as np
import pytest

from harness.scoring.records import STABILITY
from harness.scoring.stability import (frame_change, menger_curvature, moving_ticks, path_curvature,
                                       quadratic_fits, second_difference, second_differences, stability,
                                       waypoint_speeds)


def test_the_batched_fit_recovers_exact_quadratics():
    s = np.tile(np.arange(20.0), (2, 1))
    y = np.stack([0.5 - 0.2 * s[0] + 0.03 * s[0] ** 2, -1.0 + 0.0 * s[1] - 0.01 * s[1] ** 2])
    # exact data: only rounding separates the fit from the coefficients (values ~1, 1e-12 is
    # far above the 1e-15 rounding of 20 points and far below any coefficient)
    np.testing.assert_allclose(quadratic_fits(s, y), [[0.03, -0.2, 0.5], [-0.01, 0.0, -1.0]], rtol=0, atol=1e-12)


def _quadratic_in_arc_length(c1: float, c2: float, n: int = 20) -> np.ndarray:
    """Points 1 m of chord apart whose lateral offset is c1 s + c2 s^2 at chord length s."""
    s = np.arange(n, dtype=float)
    y = c1 * s + c2 * s ** 2
    x = np.concatenate([[0.0], np.cumsum(np.sqrt(1.0 - np.diff(y) ** 2))])  # each chord 1 m long
    return np.stack([x, y], axis=1)


def test_the_curvature_is_that_of_the_fitted_quadratic_at_the_ego():
    paths = np.stack([_quadratic_in_arc_length(0.3, 0.01), _quadratic_in_arc_length(0.0, -0.02),
                      _quadratic_in_arc_length(0.5, 0.0)])
    # kappa = 2 c2 / (1 + c1^2)^1.5 by hand: 0.02 / 1.09^1.5, -0.04, 0
    expected = [0.02 / 1.09 ** 1.5, -0.04, 0.0]
    np.testing.assert_allclose(path_curvature(paths), expected, rtol=0, atol=1e-12)


def test_a_path_without_length_or_with_a_nan_point_has_no_curvature():
    standing = np.zeros((20, 2))
    broken = _quadratic_in_arc_length(0.1, 0.01)
    broken[5, 1] = np.nan
    kappa = path_curvature(np.stack([standing, broken, _quadratic_in_arc_length(0.0, 0.0)]))
    assert np.isnan(kappa[0])
    assert np.isnan(kappa[1])
    assert kappa[2] == pytest.approx(0.0, abs=1e-12)


def test_the_batched_fit_agrees_with_polyfit_also_when_rank_deficient():
    rng = np.random.default_rng(3)
    paths = np.cumsum(rng.normal([1.0, 0.0], [0.3, 0.2], size=(200, 20, 2)), axis=1)
    paths[:20, :12] = 0.0  # only 9 distinct points
    paths[20:30, :10] = 0.0  # two distinct points: rank 2, polyfit's minimum-norm solution
    paths[20:30, 10:] = paths[20:30, 10:11]
    seg = np.hypot(*np.diff(paths, axis=1).transpose(2, 0, 1))
    s = np.concatenate([np.zeros((len(paths), 1)), np.cumsum(seg, axis=1)], axis=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", np.exceptions.RankWarning)
        oracle = np.array([np.polyfit(s[t], paths[t, :, 1], 2) for t in range(len(paths))])
    # two backward-stable solvers differ by rounding times the condition number (below 18 for
    # the full-rank fits here; the rank-2 ones are the minimum-norm solution in both): measured
    # at most 1.1e-15 on these fits, so 1e-12 leaves room for other LAPACK builds
    np.testing.assert_allclose(quadratic_fits(s, paths[:, :, 1]), oracle, rtol=0, atol=1e-12)


def test_second_difference_and_waypoint_speeds_by_hand():
    assert second_difference([0.0, 1.0, 4.0, 9.0]) == pytest.approx(2.0 / 0.05 ** 2)  # u = t^2: 800
    assert np.isnan(second_difference([1.0, 2.0]))
    wps = np.array([[[1.0, 0.0], [2.0, 0.0], [2.0, 1.0]]])  # 1 m per 0.25 s: 4 m/s each
    np.testing.assert_allclose(waypoint_speeds(wps), [[4.0, 4.0, 4.0]])


def test_the_all_tick_metrics_of_a_three_tick_log():
    log = {
        "v": np.array([0.0, 0.0, 0.0]),  # standing throughout: the old readings count every tick
        "steer": np.array([0.0, 0.1, 0.0]),  # |0 - 0.2 + 0| / dt^2 = 80
        "throttle": np.array([0.5, 0.5, 0.0]),
        "brake": np.array([0.0, 0.0, 0.5]),  # u = 0.5, 0.5, -0.5: |-0.5 - 1 + 0.5| / dt^2 = 400
        "pred_path": np.stack([_quadratic_in_arc_length(0.0, 0.0), _quadratic_in_arc_length(0.0, 0.01),
                               _quadratic_in_arc_length(0.0, 0.0)]),  # kappa 0, 0.02, 0
        "pred_speed_wps": np.array([[[1.0, 0.0], [2.0, 0.0]], [[1.0, 0.0], [3.0, 0.0]], [[1.0, 0.0], [3.0, 0.0]]]),
    }  # speeds (4, 4), (4, 8), (4, 8): changes 4 and 0
    out = stability(log)
    assert out["steering_jerk"] == pytest.approx(80.0)
    assert out["longitudinal_jerk"] == pytest.approx(400.0)
    assert out["curvature_variation"] == pytest.approx(0.02, abs=1e-12)
    assert out["speed_variation"] == pytest.approx(2.0)
    # standing throughout: no moving tick, so every moving-tick metric is undefined
    assert all(math.isnan(out[k]) for k in ("steering_jerk_moving", "longitudinal_jerk_moving",
                                            "curvature_variation_wps", "speed_variation_kmh"))
    assert out["standing_share"] == 1.0


def _arc(radius: float, n: int, step: float, turn: float = 0.0) -> np.ndarray:
    """n points 'step' metres of arc apart on a left circle of this radius through the ego,
    heading x at the ego, the first at arc length step (or at 0 when turn is set: then the
    circle is first rotated by 'turn' radians about the ego)."""
    s = np.arange(n) * step + (0.0 if turn else step)
    pts = np.stack([radius * np.sin(s / radius), radius * (1 - np.cos(s / radius))], axis=1)
    c, si = math.cos(turn), math.sin(turn)
    return pts @ np.array([[c, si], [-si, c]])


def test_three_point_curvature_of_a_circle_and_a_line():
    # points on a 10 m circle, unevenly spaced: each three-point curvature is 1/R = 0.1
    s = np.array([0.0, 1.0, 3.0, 3.5, 7.0])
    circle = np.stack([10 * np.sin(s / 10), 10 * (1 - np.cos(s / 10))], axis=1)
    # rounding of sides ~1 m and areas ~0.01 m^2 in float64: 1e-12 is 1e-11 relative
    np.testing.assert_allclose(menger_curvature(circle[None]), [[0.1, 0.1, 0.1]], rtol=0, atol=1e-12)
    # mirrored (a right turn): -0.1; a straight line: 0
    np.testing.assert_allclose(menger_curvature(circle[None] * [1, -1]), [[-0.1] * 3], rtol=0, atol=1e-12)
    line = np.stack([np.arange(4.0), np.zeros(4)], axis=1)
    assert menger_curvature(line[None]).tolist() == [[0.0, 0.0]]
    # a right angle with 3 m and 4 m legs: 2 |3 x 4| / (3 * 4 * 5) = 0.4
    corner = np.array([[[0.0, 0.0], [3.0, 0.0], [3.0, 4.0]]])
    assert menger_curvature(corner)[0, 0] == pytest.approx(0.4, abs=1e-15)


def test_three_point_curvature_is_undefined_at_points_closer_than_min_side():
    # MIN_SIDE is 1 cm (module docstring: a 5 mm side has no direction to bend)
    wps = np.array([[[0.0, 0.0], [0.005, 0.0], [1.0, 0.1], [2.0, 0.0]],
                    [[0.0, 0.0], [0.02, 0.0], [1.0, 0.1], [2.0, 0.0]]])
    k = menger_curvature(wps)
    assert math.isnan(k[0, 0])  # its side from the first point is 5 mm
    assert math.isfinite(k[0, 1])
    assert math.isfinite(k[1, 0])  # a 2 cm side
    assert np.isnan(menger_curvature(np.zeros((1, 3, 2)))).all()  # a prediction that stands


def test_a_constant_curvature_trajectory_gives_zero_curvature_variation():
    # 6 moving ticks, every prediction on the same 20 m circle (kappa 0.05), the path points
    # 1 m and the speed waypoints 1.25 m of arc apart (5 m/s), turned a little each tick:
    # the trajectory turns in the ego frame, its curvature stays
    n = 6
    path = np.stack([_arc(20.0, 20, 1.0, turn=0.01 * (t + 1)) for t in range(n)])
    wps = np.stack([_arc(20.0, 10, 1.25, turn=0.0) for _ in range(n)])
    log = {"v": np.full(n, 5.0), "steer": np.zeros(n), "throttle": np.zeros(n), "brake": np.zeros(n),
           "pred_path": path, "pred_speed_wps": wps}
    out = stability(log)
    # curvatures of 0.05 to rounding (1e-15 relative): their changes are below 1e-13
    assert out["curvature_variation_wps"] == pytest.approx(0.0, abs=1e-13)
    assert out["curvature_variation_path"] == pytest.approx(0.0, abs=1e-13)
    # each waypoint 1.25 m of arc (chord 2 R sin(s / 2R) = 1.24987 m) from the last: 5.0 m/s
    # in every slot at every tick, so the speed variation is 0 too
    assert out["speed_variation_kmh"] == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(menger_curvature(np.concatenate([np.zeros((n, 1, 2)), wps], 1)), 0.05,
                               rtol=0, atol=1e-12)


def test_curvature_variation_of_a_bending_trajectory_by_hand():
    # ticks 0-2 moving; the speed-waypoint trajectory is a straight line (kappa 0 at its 3
    # interior points with the ego), then a 10 m circle (0.1), then straight again:
    # per tick mean_k |change| = -, 0.1, 0.1 -> mean over moving ticks 1 and 2 = 0.1
    straight = np.stack([np.arange(1.0, 4.0), np.zeros(3)], axis=1)
    bent = _arc(10.0, 3, 1.0)
    log = {"v": np.full(3, 4.0), "steer": np.zeros(3), "throttle": np.zeros(3), "brake": np.zeros(3),
           "pred_path": np.full((3, 20, 2), np.nan), "pred_speed_wps": np.stack([straight, bent, straight])}
    out = stability(log)
    assert out["curvature_variation_wps"] == pytest.approx(0.1, abs=1e-12)
    assert math.isnan(out["curvature_variation_path"])  # no path predicted


def test_moving_ticks_and_the_standing_share():
    v = np.array([0.0, 0.05, 0.2, 0.3, 0.1, 0.5, 0.6])
    # t moves when v_t > 0.1 and v_{t-1} > 0.1: ticks 3 and 6 (0.1 itself stands)
    assert moving_ticks(v).tolist() == [False, False, False, True, False, False, True]
    out = stability({"v": v, "steer": np.zeros(7), "throttle": np.zeros(7), "brake": np.zeros(7),
                     "pred_path": np.zeros((0, 20, 2)), "pred_speed_wps": np.zeros((0, 10, 2))})
    assert out["standing_share"] == pytest.approx(3 / 7)  # 0.0, 0.05 and 0.1
    assert out["steering_jerk_moving"] == 0.0
    assert math.isnan(out["speed_variation_kmh"])  # nothing predicted


def test_a_tick_at_0_15_m_s_after_one_at_0_15_moves():
    # moving means faster than 0.1 m/s at the tick and the one before
    assert moving_ticks(np.array([0.15, 0.15, 0.11, 0.1])).tolist() == [False, True, True, False]


def test_path_and_quadratic_curvature_variations_leave_a_standing_tick_out():
    """v = 4, 4, 4, 0: ticks 1 and 2 move, tick 3 stands. Predictions straight, bent, bent,
    straight: the change is the bend at tick 1, 0 at tick 2, and the bend again at the standing
    tick 3, so the moving-only mean is bend / 2 (every tick would give 2 bend / 3).
    Path (three-point): a 10 m circle, 0.1 at every interior point -> 0.05.
    Quadratic: y = 0.01 s^2, kappa = 2 c2 = 0.02 -> 0.01. 1e-12: rounding of the fits."""
    v, z = np.array([4.0, 4.0, 4.0, 0.0]), np.zeros(4)
    line = np.stack([np.arange(20.0), np.zeros(20)], axis=1)
    circle = _arc(10.0, 20, 1.0)
    out = stability({"v": v, "steer": z, "throttle": z, "brake": z, "pred_speed_wps": np.full((4, 10, 2), np.nan),
                     "pred_path": np.stack([line, circle, circle, line])})
    assert out["curvature_variation_path"] == pytest.approx(0.05, abs=1e-12)
    bent = _quadratic_in_arc_length(0.0, 0.01)
    out = stability({"v": v, "steer": z, "throttle": z, "brake": z, "pred_speed_wps": np.full((4, 10, 2), np.nan),
                     "pred_path": np.stack([line, bent, bent, line])})
    assert out["curvature_variation_quadratic"] == pytest.approx(0.01, abs=1e-12)


def test_jerk_of_a_known_sequence_counts_moving_ticks_only():
    v = np.array([0.0, 0.0, 1.0, 2.0, 3.0, 3.0, 0.0])
    steer = np.array([0.3, -0.3, 0.0, 0.1, 0.1, 0.0, 0.5])
    throttle = np.array([0.0, 0.0, 0.5, 0.5, 0.2, 0.0, 0.0])
    brake = np.array([1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    # moving ticks: 3, 4, 5 (tick 2 follows a standing tick, tick 6 stands)
    # steer second differences: t3 |0.1 - 0 + (-0.3)| = 0.2; t4 |0.1 - 0.2 + 0| = 0.1;
    # t5 |0 - 0.2 + 0.1| = 0.1 -> mean 0.4 / 3 / dt^2 = 53.33; tick 2's |0 + 0.6 + 0.3| = 0.9
    # and tick 6's |0.5 - 0 + 0.1| = 0.6 are the standing ones left out
    # u = throttle - brake = -1, -1, 0.5, 0.5, 0.2, 0, -1: t3 |0.5 - 1 - 1| = 1.5;
    # t4 |0.2 - 1 + 0.5| = 0.3; t5 |0 - 0.4 + 0.5| = 0.1 -> 1.9 / 3 / dt^2 = 253.33
    out = stability({"v": v, "steer": steer, "throttle": throttle, "brake": brake,
                     "pred_path": np.zeros((0, 20, 2)), "pred_speed_wps": np.zeros((0, 10, 2))})
    assert out["steering_jerk_moving"] == pytest.approx(0.4 / 3 / 0.05 ** 2)
    assert out["longitudinal_jerk_moving"] == pytest.approx(1.9 / 3 / 0.05 ** 2)
    # the all-tick reading keeps every tick: (0.9 + 0.2 + 0.1 + 0.1 + 0.6) / 5 / dt^2
    assert out["steering_jerk"] == pytest.approx(1.9 / 5 / 0.05 ** 2)
    np.testing.assert_allclose(second_differences(steer)[2:] * 0.05 ** 2, [0.9, 0.2, 0.1, 0.1, 0.6], atol=1e-15)


def test_speed_variation_in_kmh_is_3_6_times_that_in_ms():
    # speeds of three waypoints per tick: (4, 4, 4), (4, 8, 4), (4, 8, 8) m/s;
    # changes: tick 1 |0| + |4| + |0| = 4, tick 2 0 + 0 + 4 = 4 -> 4 m/s = 14.4 km/h
    wps = np.array([[[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]],
                    [[1.0, 0.0], [3.0, 0.0], [4.0, 0.0]],
                    [[1.0, 0.0], [3.0, 0.0], [5.0, 0.0]]])
    log = {"v": np.full(3, 4.0), "steer": np.zeros(3), "throttle": np.zeros(3), "brake": np.zeros(3),
           "pred_path": np.full((3, 20, 2), np.nan), "pred_speed_wps": wps}
    out = stability(log)
    assert out["speed_variation_ms"] == pytest.approx(4.0)
    assert out["speed_variation_kmh"] == pytest.approx(14.4)
    assert out["speed_variation_kmh"] == pytest.approx(3.6 * out["speed_variation_ms"], rel=1e-15)


def test_frame_change_means_over_the_points_defined_at_both_ticks():
    q = np.array([[0.0, 1.0, np.nan], [0.5, 2.0, 3.0], [np.nan, np.nan, 3.0]])
    # tick 1: (0.5 + 1.0) / 2; tick 2: |3 - 3| / 1
    out = frame_change(q)
    assert math.isnan(out[0])
    assert out[1:].tolist() == [0.75, 0.0]


def test_every_stability_metric_is_a_record_column():
    out = stability({"v": np.ones(3), "steer": np.zeros(3), "throttle": np.zeros(3), "brake": np.zeros(3),
                     "pred_path": np.zeros((0, 20, 2)), "pred_speed_wps": np.zeros((0, 10, 2))})
    assert tuple(out) == STABILITY


def test_the_docs_table_of_the_metrics_is_the_registrys():
    """docs/scoring.md shows the table ``docs_table`` makes from METRICS, row for row."""
    from pathlib import Path

    from harness.scoring.stability import METRICS, docs_table
    table = docs_table()
    assert table in (Path(__file__).parents[1] / "docs" / "scoring.md").read_text()
    assert len(table.splitlines()) == 2 + sum(bool(m.formula) for m in METRICS)
