"""The path state "plan" (scimm.planref): the teacher's offset from the expert's previous plan."""
from __future__ import annotations

import numpy as np
import pytest

from scimm import pathspeed as ps
from scimm import planref
from scimm.modes import IMMConfig
from scimm.teacher import run_imm
from tests import drives


def _teach(path, speed_wps, pose, method):
    """(z (T, 5), path teacher (T, 20, 2), mu (T, 5)) of one episode with path_state "plan"."""
    z = ps.observe(path, speed_wps)
    z[:, :3] = planref.plan_change(path, pose)[0]
    s = np.zeros((1, len(z), 16))
    x, mu = run_imm(z[None], s, method, IMMConfig(path_state="plan"), pose[None])
    return z, planref.teacher_path(path, x[0, :, :3], z[:, :3]), mu[0]


@pytest.mark.parametrize("method", ["fixed", "scimm", "smoother"])
def test_a_plan_that_lies_still_on_the_road_is_its_own_teacher(method):
    """R = 20 m at 8 m/s: every frame's plan is the same circle seen from 2 m further on, so
    the plan changes by nothing and the path teacher is the plan itself. Tolerance: plan_t-1
    is read by arc length along its 1 m chords, each 1 - 1/(24 R^2) m long, so the read point
    lies up to a few 1e-4 m past a vertex, a few 1e-6 m inside the circle (5.2e-6 m measured),
    a change the filter follows only in part (the teacher 2.1e-5 m from the plan at 19 m, at
    most, measured)."""
    a = drives.record(drives.circle(20.0), np.full(400, 8.0))
    pose = np.stack([a["x"], a["y"], a["yaw"]], axis=-1)
    z, teacher, _ = _teach(a["path"], a["speed_wps"], pose, method)
    assert np.abs(z[:, :3]).max() < 1e-5
    assert np.abs(teacher - a["path"]).max() < 5e-5


def _replanned(T=40, switch=10, shift=0.5):
    """A straight drive along +x at 2 m a frame (8 m/s) whose plan is the line y = 0 until
    frame ``switch`` and from then on the line y = ``shift`` (points 1..19; point 0 is the ego)."""
    pose = np.stack([2.0 * np.arange(T), np.zeros(T), np.zeros(T)], axis=-1)
    path = np.zeros((T, 20, 2))
    path[:, :, 0] = ps.PATH_S
    path[switch:, 1:, 1] = shift
    speed_wps = np.zeros((T, 10, 2))
    speed_wps[:, :, 0] = 2.0 * np.arange(1, 11)
    return path, speed_wps, pose


@pytest.mark.parametrize("method", ["fixed", "scimm"])
def test_a_replanned_path_is_followed_within_two_frames_and_moves_as_the_plan_does(method):
    """The plan moves 0.5 m left once. The path teacher at 10 m ahead moves most of the way in
    the first frame (a jump this size is likely only in the modes with large path noise), is
    within 1 mm of the new plan from the next frame on, overshoots it by less than 0.5 mm
    (the modes' states differ after the jump and their mixing moves the fused path by
    3.0e-4 m in the Fixed-IMM, 1e-7 m in SC-IMM), and its world movement summed over the
    drive (table2.moved_metrics) is within 0.1 % of the plan's (1.0001 x, 0.9995 x measured)."""
    from scimm.table2 import moved_metrics
    path, speed_wps, pose = _replanned()
    z, teacher, _ = _teach(path, speed_wps, pose, method)
    np.testing.assert_allclose(z[10, :3], [0.5, 0.0, 0.0], rtol=0, atol=1e-12)  # the change, exactly
    y10 = teacher[:, 10, 1]
    assert np.all(y10[:10] == 0.0)
    assert 0.25 < y10[10] < 0.5
    assert np.abs(y10[11:] - 0.5).max() < 1e-3 and y10.max() < 0.5 + 5e-4
    speeds = ps.label_speeds(speed_wps)
    moved_teacher = np.nansum(moved_metrics(teacher, speeds, pose)["lat_delta_moved"])
    moved_plan = np.nansum(moved_metrics(path, speeds, pose)["lat_delta_moved"])
    assert abs(moved_teacher / moved_plan - 1) <= 1e-3


def test_point_0_stays_at_the_ego_and_point_1_is_already_filtered():
    """The plan moves 0.5 m left at frame 10 (points 1..19; point 0 is the ego). The teacher's
    point 0 is the ego, (0, 0) exactly, in every frame. Point 1 is filtered (FIRST = 1): at
    frame 10 it lies between the old plan (0) and the new one (0.5), short of the new one
    (0.49376 measured with the Fixed-IMM); an unfiltered point 1 would be the plan, 0.5 exactly."""
    path, speed_wps, pose = _replanned()
    _, teacher, _ = _teach(path, speed_wps, pose, "fixed")
    assert np.all(teacher[:, 0] == 0.0)
    assert 0.25 < teacher[10, 1, 1] < 0.5 - 1e-3


def test_the_predict_input_rebases_onto_the_previous_plan_and_carries_along_it():
    """Frame 1's input: x' = C (x - z_0) with C the carry by d_1, written out: c0' = e0 + e1 d
    + e2 d^2, c1' = e1 + 2 e2 d, c2' = e2 for e = x - z_0; the speeds untouched."""
    z = np.array([[0.3, -0.02, 0.001], [0.05, 0.0, 0.0]])
    d = np.array([0.0, 2.5])
    C, u = planref.known_input(z[None], d[None])
    x = np.array([0.1, 0.01, -0.002, 7.0, -1.0])
    got = C[0, 1] @ x + u[0, 1]
    e0, e1, e2 = x[:3] - z[0]
    np.testing.assert_allclose(got, [e0 + e1 * 2.5 + e2 * 6.25, e1 + 2 * e2 * 2.5, e2, 7.0, -1.0], rtol=0, atol=1e-15)


def test_a_path_state_other_than_ego_or_plan_is_refused():
    with pytest.raises(ValueError, match="path_state"):
        IMMConfig(path_state="world")
