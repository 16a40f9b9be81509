"""The global plan's route sensors near the end of a route: the run-on past the last point."""
from __future__ import annotations

import math

import numpy as np

from harness.plan import END_PAD, TARGET_MIN, build_plan
from scenarios import set_path
from scenarios.routefile import read_routes
from sumo_nets import load_net

ROUTE = read_routes(set_path("town12_smoke"))[1][0]


def test_the_target_point_stays_target_min_ahead_on_the_run_on_near_the_end():
    plan = build_plan(ROUTE, load_net(ROUTE.town))
    heading = np.array([math.cos(plan.yaw[-1]), math.sin(plan.yaw[-1])])
    last = len(plan.s) - 1
    # at the last point: TARGET_MIN straight on past it
    np.testing.assert_allclose(plan.target_xy(last), plan.xy[-1] + TARGET_MIN * heading, atol=1e-9)
    # 3 m before the end (dense points are 1 m apart): 4.5 m past the end
    k = int(np.searchsorted(plan.s, plan.length - 3.0))
    extra = plan.s[k] + TARGET_MIN - plan.length
    np.testing.assert_allclose(plan.target_xy(k), plan.xy[-1] + extra * heading, atol=1e-9)
    # far from the end: a sparse route point, at least TARGET_MIN ahead
    tp = plan.target_xy(0)
    j = int(np.flatnonzero((plan.xy == tp).all(axis=1))[0])
    assert j in set(plan.sparse.tolist()) and plan.s[j] >= TARGET_MIN


def test_the_shown_route_is_the_route_then_a_straight_run_on():
    plan = build_plan(ROUTE, load_net(ROUTE.town))
    shown = plan.shown_xy
    n = len(plan.xy)
    np.testing.assert_array_equal(shown[:n], plan.xy)
    assert len(shown) == n + int(END_PAD)
    steps = np.diff(shown[n - 1:], axis=0)
    heading = np.array([math.cos(plan.yaw[-1]), math.sin(plan.yaw[-1])])
    np.testing.assert_allclose(steps, np.tile(heading, (len(steps), 1)), atol=1e-9)  # 1 m steps straight on
