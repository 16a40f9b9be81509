"""Pure geometry of the town builders and the net statistics, checked by hand."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sumo_nets.plain import PlainNet, RURAL, curve
from sumo_nets.stats import heading_change


def test_straight_road_has_no_interior_points():
    assert curve((0, 0), (100, 0)) == ()


def test_arc_has_the_requested_sagitta_and_stays_on_its_circle():
    # chord 100 m along x, sagitta 10 m to the left (+y): radius = (50^2 + 10^2) / 20 = 130 m,
    # centre at (50, 10 - 130) = (50, -120)
    pts = np.array(curve((0, 0), (100, 0), bend=10.0, step=5.0))
    assert np.max(pts[:, 1]) == pytest.approx(10.0, abs=1e-9)  # n = 20 points include t = 0.5
    r = np.hypot(pts[:, 0] - 50.0, pts[:, 1] + 120.0)
    np.testing.assert_allclose(r, 130.0, atol=1e-9)


def test_negative_bend_bulges_right():
    pts = np.array(curve((0, 0), (100, 0), bend=-10.0, step=5.0))
    assert np.min(pts[:, 1]) == pytest.approx(-10.0, abs=1e-9)


def test_wiggle_is_one_sine_period():
    # offset at t = 1/4 is +A (left), at t = 3/4 is -A
    pts = np.array(curve((0, 0), (0, 80), wiggle=5.0, step=10.0))  # heading north: left is -x
    assert pts[1] == pytest.approx((-5.0, 20.0))
    assert pts[5] == pytest.approx((5.0, 60.0))


def test_heading_change_counts_both_turns_of_an_s_bend():
    # east, then north-east (+45 deg), then east again (-45 deg): 90 deg in total
    shape = [(0, 0), (10, 0), (20, 10), (30, 10)]
    assert heading_change(shape) == pytest.approx(math.pi / 2)


def test_heading_change_wraps_across_pi():
    # heading 170 deg then -170 deg is a 20 deg turn, not 340
    a, b = math.radians(170), math.radians(-170)
    shape = [(0, 0), (math.cos(a), math.sin(a)), (math.cos(a) + math.cos(b), math.sin(a) + math.sin(b))]
    assert heading_change(shape) == pytest.approx(math.radians(20))


def test_plain_net_refuses_bad_input():
    net = PlainNet("x")
    net.node("a", 0, 0)
    with pytest.raises(ValueError, match="defined twice"):
        net.node("a", 1, 1)
    with pytest.raises(ValueError, match="junction type"):
        net.node("b", 1, 1, kind="roundabout_of_doom")
    with pytest.raises(ValueError, match="unknown node"):
        net.road("a", "zz", RURAL)
