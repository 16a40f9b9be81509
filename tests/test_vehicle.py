"""The ego vehicle model, PID controllers and contact test: hand-checked values."""
from __future__ import annotations

import math

import numpy as np
import pytest

from controller.pid import LateralPID, PID, SpeedPID
from controller.vehicle import DT, EgoState, EgoVehicle, Control, bicycle_step, next_speed
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
    # by hand from the fitted constants (LF -0.090769015, LR 1.4178275, full lock 0.36848336 rad):
    # delta = -0.5 x 0.36848336 = -0.18424168 rad (to the right), L = LF + LR = 1.327058485,
    # beta = atan(LR / L tan(delta)) = -0.1965314791; x = 10 cos(beta) 0.05, y = 10 sin(beta) 0.05,
    # yaw = 10 / LR sin(beta) 0.05. abs 1e-10: the literals are rounded to 10 decimals
    assert r.yaw == pytest.approx(-0.0688619600, abs=1e-10)
    assert (r.x, r.y) == pytest.approx((0.4903748849, -0.0976343806), abs=1e-10)
    assert r.yaw < 0  # clockwise
    assert r.y < 0  # to the right


def test_bicycle_yaw_wraps_into_minus_pi_to_pi():
    # yaw 3.1 turning left at full lock, 10 m/s: delta = 0.36848336, beta = atan(1.4178275 /
    # 1.327058485 tan(delta)) = 0.3912607316, yaw = 3.1 + 10 / 1.4178275 sin(beta) 0.05 =
    # 3.2344853922, past pi: wrapped to 3.2344853922 - 2 pi = -3.0486999150
    s = bicycle_step(EgoState(0.0, 0.0, 3.1, 10.0), -1.0, 10.0)
    assert s.yaw == pytest.approx(-3.0486999150, abs=1e-10)  # 10 decimals


def test_steering_lag_moves_a_third_of_the_way_per_tick():
    # first-order lag, time constant 0.1 s: alpha = dt / (0.1 + dt) = 0.05 / 0.15 = 1/3 per tick;
    # from 0 towards 1: 1/3, then 1/3 + 1/3 (1 - 1/3) = 5/9
    car = EgoVehicle(EgoState(0.0, 0.0, 0.0, 5.0), np.random.default_rng(0), noise=False)
    car.step(Control(1.0, 0.0, 0.0))
    assert car.steer_applied == pytest.approx(1 / 3, abs=1e-15)  # float rounding only
    car.step(Control(1.0, 0.0, 0.0))
    assert car.steer_applied == pytest.approx(5 / 9, abs=1e-15)


def test_applied_steer_never_exceeds_full_lock_with_noise():
    # full right command plus noise (std 0.01): the lagged steer reaches the clip at 1.0
    # (half the noise draws push past it) and stays within it
    car = EgoVehicle(EgoState(0.0, 0.0, 0.0, 5.0), np.random.default_rng(1))
    applied = []
    for _ in range(200):
        car.step(Control(1.0, 0.0, 0.0))
        applied.append(car.steer_applied)
    assert max(applied) == 1.0


@pytest.mark.parametrize("brake, v_after", [(0.5, 5.0), (0.51, None)])
def test_brake_engages_strictly_above_one_half(brake, v_after):
    # throttle 0 is inside the 0.3 dead band: without braking the speed is kept exactly
    car = EgoVehicle(EgoState(0.0, 0.0, 0.0, 5.0), np.random.default_rng(0), noise=False)
    s = car.step(Control(0.0, 0.0, brake))
    if v_after is not None:
        assert s.v == v_after
    else:
        assert s.v < 5.0


def test_throttle_dead_band_ends_at_0_3():
    assert next_speed(5.0, 0.2999, False) == 5.0  # inside the band: speed kept
    assert next_speed(5.0, 0.3, False) != 5.0  # 0.3 itself is outside it: the polynomial applies


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


def test_lateral_pid_derivative_is_the_newest_minus_the_previous_error():
    # target at 9 deg to the left: error -9/90 = -0.1. First step (no derivative, window [-0.1]):
    # (Kp + Ki)(-0.1) = (3.118357247806046 + 0.6406067986034124)(-0.1) = -0.3758964046.
    # Then straight ahead, error 0: Kp 0 + Kd (0 - (-0.1)) + Ki mean(-0.1, 0)
    # = 0.13782508892 - 0.03203033993 = 0.1057947490. abs 1e-10: literals rounded to 10 decimals
    pid = LateralPID()
    a = math.radians(9.0)
    assert pid.steer_to(math.cos(a), math.sin(a)) == pytest.approx(-0.3758964046, abs=1e-10)
    assert pid.steer_to(1.0, 0.0) == pytest.approx(0.1057947490, abs=1e-10)


def test_lateral_pid_integral_is_the_mean_of_the_last_six_errors():
    # seven steps: six at error +0.1 (target 9 deg to the right), then one at 0. The window
    # keeps the last 6 errors (five 0.1 and one 0): Ki 0.5 / 6 = 0.0533838999; derivative
    # Kd (0 - 0.1) = -0.1378250889; P 0: out = -0.0844411890
    pid = LateralPID()
    a = math.radians(-9.0)
    for _ in range(6):
        pid.steer_to(math.cos(a), math.sin(a))
    assert pid.steer_to(1.0, 0.0) == pytest.approx(-0.0844411890, abs=1e-10)  # 10 decimals


def test_lateral_pid_output_is_clipped_to_plus_minus_one():
    # target 90 deg to the right: error 1, (Kp + Ki) x 1 = 3.759 unclipped
    assert LateralPID().steer_to(0.0, -1.0) == 1.0
    assert LateralPID().steer_to(0.0, 1.0) == -1.0


def test_lateral_pid_lookahead_is_clamped_to_2_4_and_10_5_metres():
    # 0.1 m per index, clip(0.9755 v[km/h] + 1.915, 24, 105): at rest 1.915 -> 24 -> 2.4 m;
    # at 40 m/s (144 km/h) 142.39 -> 105 -> 10.5 m. abs 1e-12: 24 x 0.1 is not exactly 2.4
    assert LateralPID.lookahead(0.0) == pytest.approx(2.4, abs=1e-12)
    assert LateralPID.lookahead(40.0) == pytest.approx(10.5, abs=1e-12)


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


def test_oriented_box_contacts_separated_only_by_the_other_boxs_axis():
    # a 2 x 2 box at 45 deg beside the ego's front-left corner (2.45, 1.05). On the ego's axes
    # neither centre separates (x: 3.0 < 2.45 + sqrt 2; y: 2.2 < 1.05 + sqrt 2). On the box's
    # diagonal axis (1, 1)/sqrt 2 the ego reaches 2.45/sqrt 2 + 1.05/sqrt 2, so the gap is
    # (x - 2.45 + y - 1.05)/sqrt 2 against the box's half size 1:
    # (3.0, 2.2): (0.55 + 1.15)/sqrt 2 = 1.20 > 1, apart; (2.8, 2.0): (0.35 + 0.95)/sqrt 2 = 0.92 < 1, touching
    ego = (0.0, 0.0, 0.0, 4.9, 2.1)
    got = overlaps(ego, np.array([[3.0, 2.2], [2.8, 2.0]]), np.full(2, math.pi / 4), np.array([[2.0, 2.0]] * 2))
    assert got.tolist() == [False, True]


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
