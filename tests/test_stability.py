"""The temporal-stability metrics (harness.scoring.stability, the paper's Table 4), with values
derived by hand and np.polyfit as the oracle of the batched quadratic fits."""
import warnings

import numpy as np
import pytest

from harness.scoring.stability import path_curvature, quadratic_fits, second_difference, stability, waypoint_speeds


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


def test_the_four_metrics_of_a_three_tick_log():
    log = {
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
