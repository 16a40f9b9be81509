"""The ego vehicle model, PID controllers and contact test: hand-checked values."""
from __future__ import annotations

import math

import numpy as np
import pytest

from controller.pid import LateralPID, PID, SpeedPID
from controller.vehicle import DT, LF, LR, EgoState, EgoVehicle, Control, bicycle_step, next_speed
from harness.sim.contacts import overlaps


def test_speed_model_matches_the_fitted_polynomials():
    # docs/design.md §8.4: full throttle at 10 km/h -> +1.22 km/h per
    # tick; braking at 30 km/h -> -1.68 km/h per tick
    assert (next_speed(10 / 3.6, 1.0, False) * 3.6 - 10) == pytest.approx(1.22, abs=0.005)
    assert (30 - next_speed(30 / 3.6, 0.0, True) * 3.6) == pytest.approx(1.68, abs=0.005)
    assert next_speed(5.0, 0.2, False) == 5.0  # below the 0.3 dead band the speed is kept
    assert next_speed(0.0, 0.0, True) == 0.0  # no reversing


def test_bicycle_goes_straight_without_steer_and_turns_right_with_positive_steer():
    s = bicycle_step(EgoState(0.0, 0.0, 0.0, 10.0), 0.0, 10.0)
    assert (s.x, s.y, s.yaw) == pytest.approx((10.0 * DT, 0.0, 0.0))
    r = bicycle_step(EgoState(0.0, 0.0, 0.0, 10.0), 0.5, 10.0)
    # the other textbook form of the kinematic bicycle (centre of gravity LR ahead of the rear
    # axle): slip angle tan(beta) = LR / L tan(delta), yaw rate v cos(beta) tan(delta) / L,
    # velocity along yaw + beta; half lock = 0.5 x 0.36848336 rad of wheel angle, to the right
    delta, wheelbase = -0.5 * 0.36848336, LF + LR
    beta = math.atan(LR / wheelbase * math.tan(delta))
    assert r.yaw == pytest.approx(10.0 * math.cos(beta) * math.tan(delta) / wheelbase * DT, rel=1e-12)
    assert (r.x, r.y) == pytest.approx((10.0 * math.cos(beta) * DT, 10.0 * math.sin(beta) * DT), rel=1e-12)
    assert r.yaw < 0  # clockwise
    assert r.y < 0  # to the right


def test_actuation_noise_is_seeded():
    a = EgoVehicle(EgoState(0, 0, 0, 5.0), np.random.default_rng(3))
    b = EgoVehicle(EgoState(0, 0, 0, 5.0), np.random.default_rng(3))
    c = EgoVehicle(EgoState(0, 0, 0, 5.0), np.random.default_rng(4))
    for _ in range(50):
        sa, sb, sc = a.step(Control(0.1, 0.5, 0.0)), b.step(Control(0.1, 0.5, 0.0)), c.step(Control(0.1, 0.5, 0.0))
    assert sa == sb  # the same seed, the same noise
    # another seed, other noise (the noise is there)
    assert sc.x != sa.x
    assert sc.yaw != sa.yaw


def test_pid_window_is_prefilled_with_zeros():
    pid = PID(1.0, 1.0, 1.0, n=4)
    # e = 2: P 2 + I mean(0, 0, 0, 2) = 0.5 + D (2 - 0) = 2 -> 4.5
    assert pid.step(2.0) == pytest.approx(4.5)


def test_lateral_pid_zero_on_a_straight_path_and_signs():
    straight = np.stack([np.arange(1, 20, dtype=float), np.zeros(19)], 1)
    assert LateralPID().step(straight, 5.0) == 0.0
    right = np.stack([np.arange(1, 20, dtype=float), -0.2 * np.arange(1, 20)], 1)
    left = right * [1, -1]
    assert LateralPID().step(right, 5.0) > 0 > LateralPID().step(left, 5.0)
    # first step: error e = atan2(0.2, 1) in deg / 90 (lookahead 2.4 m lands on a point of the
    # line, whose angle is the line's); no derivative, I = mean([e]) = e
    e = math.degrees(math.atan(0.2)) / 90
    assert LateralPID().step(right, 5.0) == pytest.approx(min(1.0, (3.118357247806046 + 0.6406067986034124) * e))


def test_speed_pid_brake_rule():
    assert SpeedPID().step(0.3, 0.0) == (0.0, 1.0)  # desired < 0.4 m/s
    assert SpeedPID().step(5.0, 5.6) == (0.0, 1.0)  # 12 % too fast
    throttle, brake = SpeedPID().step(5.0, 5.4)  # 8 % too fast: no brake, no throttle need
    assert brake == 0.0
    assert throttle == 0.0
    throttle, brake = SpeedPID().step(6.0, 4.0)  # error clipped to 1 m/s: 1.75 + 1/20 + 2 -> 1
    assert (throttle, brake) == (1.0, 0.0)


def test_oriented_box_contacts():
    ego = (0.0, 0.0, 0.0, 4.9, 2.1)
    xy = np.array([[5.0, 0.0], [4.8, 0.0], [0.0, 2.1], [0.0, 2.0], [0.0, 0.0]])
    size = np.array([[5.0, 2.0]] * 5)
    yaw = np.zeros(5)
    # half lengths 2.45 + 2.5 = 4.95 < 5.0; half widths 1.05 + 1.0 = 2.05 < 2.1
    assert overlaps(ego, xy, yaw, size).tolist() == [False, True, False, True, True]
    # a 2x2 box rotated 45 deg with its centre 2.45 + sqrt(2) + 0.01 ahead just misses
    assert not overlaps(ego, np.array([[2.45 + math.sqrt(2) + 0.01, 0.0]]), np.array([math.pi / 4]),
                        np.array([[2.0, 2.0]]))[0]
    assert overlaps(ego, np.array([[2.45 + math.sqrt(2) - 0.01, 0.0]]), np.array([math.pi / 4]),
                    np.array([[2.0, 2.0]]))[0]


def test_only_boxes_whose_circumcircles_meet_the_egos_are_tested_as_numpy_selects_them():
    from harness.sim.contacts import _circles_meet
    rng = np.random.default_rng(5)
    for _ in range(500):
        ex, ey, el, ew = *rng.uniform(-3000.0, 3000.0, 2), *rng.uniform(0.5, 12.0, 2)
        k = int(rng.integers(0, 30))
        table = np.column_stack([np.array([ex, ey]) + rng.normal(0.0, 8.0, size=(k, 2)), rng.uniform(0.3, 12.0, (k, 2))])
        xy, size = table[:, :2], table[:, 2:]  # strided views, as a Snapshot's
        d = xy - (ex, ey)
        want = np.flatnonzero(np.hypot(d[:, 0], d[:, 1]) <= np.hypot(el, ew) / 2 + np.hypot(size[:, 0], size[:, 1]) / 2)
        np.testing.assert_array_equal(_circles_meet(ex, ey, el, ew, xy, size), want)
    # circumcircles that touch (radius 2.5 each, of 4 x 3 m boxes; centres 5 m apart) are tested
    box = np.array([[4.0, 3.0]])
    assert _circles_meet(0.0, 0.0, 4.0, 3.0, np.array([[3.0, 4.0]]), box).tolist() == [0]
    assert _circles_meet(0.0, 0.0, 4.0, 3.0, np.array([[3.0, 4.0 + 1e-9]]), box).tolist() == []
