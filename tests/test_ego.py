"""Ego-motion compensation of the path-speed state (scimm.ego)."""
from __future__ import annotations

import math

import numpy as np

from scimm import pathspeed as ps
from scimm.ego import carry, carry_inputs, interp_rows, pose_change


def test_pose_change_on_a_circle_is_the_arc_and_the_turn():
    # 2 m of arc a frame on R = 10 m: chord 2 R sin(0.1), turn 0.2 rad; the arc comes back exactly
    R, arc = 10.0, 2.0
    s = arc * np.arange(4)
    d, dyaw = pose_change(R * np.sin(s / R), R * (1 - np.cos(s / R)), s / R)
    np.testing.assert_allclose(d, [0, arc, arc, arc], rtol=0, atol=1e-12)
    np.testing.assert_allclose(dyaw, [0, 0.2, 0.2, 0.2], rtol=0, atol=1e-12)
    # the yaw wraps: from 3.1 rad to -3.1 rad is a left turn of 2 pi - 6.2 rad
    _, w = pose_change(np.array([0.0, 0.0]), np.array([0.0, 0.0]), np.array([3.1, -3.1]))
    np.testing.assert_allclose(w[1], 2 * math.pi - 6.2, rtol=0, atol=1e-12)
    d0, w0 = pose_change(np.zeros(3), np.zeros(3), np.zeros(3))  # standing: nothing moves
    assert (d0 == 0).all()
    assert (w0 == 0).all()


def test_carried_state_draws_the_same_world_path_from_the_new_ego():
    """A path drawn by a state (scimm.pathspeed.state_path), the ego moved 3 m along it and
    turned by an arbitrary dyaw: the carried state's path is the old path from its point 3
    on, in the new ego frame (the 1 m chords line up, so exactly, to rounding)."""
    x = np.array([0.05, 0.04, -0.001, 7.0, -0.5])
    old = ps.state_path(x)  # (20, 2) in the old ego frame
    d, dyaw = 3.0, 0.13
    new_pos = old[3]
    c, s = math.cos(dyaw), math.sin(dyaw)
    rel = old[3:] - new_pos
    expected = np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]], axis=-1)
    moved = carry(x, d, dyaw)
    np.testing.assert_allclose(ps.state_path(moved)[:17], expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(moved[3:], x[3:])  # the speed profile is the modes' business


def test_carry_inputs_are_the_documented_matrix():
    C, u = carry_inputs(np.array([2.0]), np.array([0.1]))
    expected = np.eye(5)
    expected[0, 1:3] = [2.0, 4.0]
    expected[1, 2] = 4.0
    np.testing.assert_array_equal(C[0], expected)
    np.testing.assert_array_equal(u[0], [-0.1, 0, 0, 0, 0])


def test_interp_rows_is_np_interp_row_by_row_and_holds_the_end_values_outside():
    """Oracle: np.interp on each row, which holds fp's first and last values outside xp.
    Rows of 6 increasing xp in 0..~10 with x from 3 m below the first to 3 m past the last;
    1e-12: the two evaluate the line through the neighbours in a different order (rounding
    of values up to ~10)."""
    rng = np.random.default_rng(0)
    xp = np.cumsum(rng.uniform(0.5, 2.0, (4, 6)), axis=1)
    fp = rng.normal(size=(4, 6))
    x = np.sort(rng.uniform(xp[:, :1] - 3.0, xp[:, -1:] + 3.0, (4, 15)), axis=1)
    assert (x[:, :1] < xp[:, :1]).any() and (x[:, -1:] > xp[:, -1:]).any()  # both ends are passed
    expected = np.stack([np.interp(x[r], xp[r], fp[r]) for r in range(4)])
    np.testing.assert_allclose(interp_rows(x, xp, fp), expected, rtol=0, atol=1e-12)
