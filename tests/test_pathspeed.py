"""Path-speed observation and its inverse (scimm.pathspeed, paper eq. 2-3)."""
from __future__ import annotations

import math

import numpy as np

from scimm import pathspeed as ps


def test_label_speeds_are_waypoint_distances_over_a_quarter_second():
    # ego at 0; 1 m forward, 1 m forward, then 1 m left, then standing: 4, 4, 4, 0 ... m/s
    w = np.zeros((10, 2))
    w[0], w[1], w[2:] = (1, 0), (2, 0), (2, 1)
    np.testing.assert_array_equal(ps.label_speeds(w), [4, 4, 4, 0, 0, 0, 0, 0, 0, 0])


def test_round_trip_is_exact_on_quadratic_headings_and_linear_speeds():
    rng = np.random.default_rng(0)
    B = 50
    x = np.stack([rng.uniform(-0.5, 0.5, B), rng.uniform(-0.15, 0.15, B), rng.uniform(-0.01, 0.01, B),
                  rng.uniform(3, 12, B), rng.uniform(-1, 1, B)], axis=-1)  # v + a tau > 0 on 0..2.5 s
    path = ps.state_path(x)
    # speed waypoints of the linear profile along a straight line: w(tau) = v tau + a tau^2 / 2
    tau = ps.SPEED_TAU
    dist = x[:, 3:4] * tau + 0.5 * x[:, 4:5] * tau ** 2
    heading = rng.uniform(-math.pi, math.pi, (B, 1))
    wps = np.stack([dist * np.cos(heading), dist * np.sin(heading)], axis=-1)
    z = ps.observe(path, wps)
    np.testing.assert_allclose(z, x, rtol=0, atol=1e-10)  # only float rounding (unwrap, pinv)
    np.testing.assert_allclose(ps.state_path(z), path, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ps.state_speeds(z), ps.label_speeds(wps), rtol=0, atol=1e-10)
    dp, dv = ps.residuals(path, wps, z)
    assert dp.max() < 1e-9
    assert dv.max() < 1e-10


def arc(radius: float, left: bool = True) -> np.ndarray:
    """20 points on a circle of ``radius`` [m] at arc length 0..19 m, starting at the ego
    heading forward (ego frame)."""
    th = np.arange(20) / radius
    y = radius * (1 - np.cos(th))
    return np.stack([radius * np.sin(th), y if left else -y], axis=-1)


def test_ninety_degree_arc_turn_is_held():
    # 90 deg within the 19 m path: R = 19 / (pi / 2) = 12.1 m; also R = 8 m (137 deg) and a right turn.
    for radius, left in ((19 / (math.pi / 2), True), (8.0, True), (12.1, False)):
        path = arc(radius, left)
        z = ps.observe(path, np.zeros((10, 2)))
        sign = 1 if left else -1
        # the chord k -> k+1 of a circle points along the tangent at its midpoint: heading (k + 1/2) / R exactly
        np.testing.assert_allclose(z[:3], [0.0, sign / radius, 0.0], atol=1e-12)
        # the inverse steps 1 m per chord; the true chord is 2 R sin(1 / 2R) = 1 - 1/(24 R^2) m,
        # so the end point is off by at most 19 / (24 R^2) m (2.1e-3 at R = 12.1, 1.3e-2 at R = 8 m)
        dp, _ = ps.residuals(path, np.zeros((10, 2)), z)
        assert dp < 19 / (24 * radius ** 2) + 1e-12


def test_junction_turn_with_straight_approach_and_exit_is_held_better_than_a_lateral_quadratic():
    # 4 m straight, 13 chords on R = 8 m (93 deg), then straight: a typical junction turn
    s = np.arange(20.0)
    kappa = np.where((s >= 4) & (s < 4 + 8 * math.pi / 2), 1 / 8, 0.0)
    psi = np.concatenate([[0.0], np.cumsum(kappa[:-1])])  # heading after each 1 m step
    steps = np.stack([np.cos(psi[:-1] + kappa[:-1] / 2), np.sin(psi[:-1] + kappa[:-1] / 2)], -1)
    path = np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    z = ps.observe(path, np.zeros((10, 2)))
    dp, _ = ps.residuals(path, np.zeros((10, 2)), z)
    # the lateral quadratic y(x) of the paper, by least squares, for comparison
    coef = np.polyfit(path[:, 0], path[:, 1], 2)
    dq = np.abs(np.polyval(coef, path[:, 0]) - path[:, 1]).max()
    # measured 0.26 m vs 3.1 m (y(x) cannot follow the exit, which runs along the y axis);
    # bound 0.5 m: well inside a lane's half width (1.75 m), where the label stays in its lane
    assert dp < 0.5
    assert dp < dq / 4


def test_speed_teacher_is_clamped_at_a_stop():
    x = np.array([2.0, 0, 0, 2.0, -2.0])  # reaches 0 at tau = 1 s
    v = ps.state_speeds(x)
    np.testing.assert_allclose(v, np.maximum(2.0 - 2.0 * (ps.SPEED_TAU - 0.125), 0.0))
    assert v[-1] == 0.0
    assert v[0] == 2.0 - 2.0 * 0.125


def test_weighted_speed_fit_reads_the_speed_now_in_a_stop():
    """Braking from 6 m/s at -4 m/s^2 to a stop after 1.5 s, then standing: the label
    speeds are interval means of that profile. The weighted line's v(0) (scimm.pathspeed
    docstring) is nearer the first label speed than numpy's unweighted line through all ten
    (measured 0.32 m/s off against 0.78)."""
    tau = np.linspace(0, 2.5, 2501)
    v = np.maximum(6.0 - 4.0 * tau, 0.0)
    dist = np.concatenate([[0.0], np.cumsum((v[1:] + v[:-1]) / 2 * np.diff(tau))])
    wps = np.stack([np.interp(ps.SPEED_TAU, tau, dist), np.zeros(10)], axis=-1)
    labels = ps.label_speeds(wps)
    z = ps.observe(np.stack([np.arange(20.0), np.zeros(20)], -1), wps)
    slope, icpt = np.polyfit(ps.SPEED_MID, labels, 1)
    weighted = abs(z[3] + z[4] * ps.SPEED_MID[0] - labels[0])
    plain = abs(icpt + slope * ps.SPEED_MID[0] - labels[0])
    assert weighted < 0.5 * plain


def test_speed_fit_weights_each_interval_by_exp_of_minus_its_midpoint_over_0_6_s():
    """Labels 5.5, 4.5, ..., 0.5, 0, 0, 0, 0 m/s at the midpoints 0.125, 0.375, ..., 2.375 s.
    Oracle: np.polyfit(mid, labels, 1, w=np.exp(-mid / 1.2)) (polyfit's w multiplies the
    unsquared residual, so it is the square root of the weight exp(-mid / 0.6)) gives
    v0 = 5.764034340, a = -3.406929745 (a 0.66 s weight: 5.727). 1e-8: the literals' last
    digit; the two least-squares solvers agree to about 1e-12."""
    labels = np.array([5.5, 4.5, 3.5, 2.5, 1.5, 0.5, 0, 0, 0, 0])
    wps = np.stack([np.cumsum(0.25 * labels), np.zeros(10)], axis=-1)  # straight, 0.25 s x speed apart
    z = ps.observe(np.stack([np.arange(20.0), np.zeros(20)], -1), wps)
    np.testing.assert_allclose(z[3:], [5.764034340, -3.406929745], rtol=0, atol=1e-8)


def test_path_residual_is_the_largest_point_distance():
    # the straight state path (z = 0) against labels that are 1 m off at one of the 20 points:
    # dp is that 1 m (max), not the mean over the points (0.05 m)
    path = np.stack([np.arange(20.0), np.zeros(20)], -1)
    path[7, 1] = 1.0
    dp, _ = ps.residuals(path, np.zeros((10, 2)), np.zeros(5))
    assert dp == 1.0
