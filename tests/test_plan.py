"""The global plan: its route sensors near the end of a route (the run-on past the last
point), and the lane the route is in along an edge."""
from __future__ import annotations

import math

import numpy as np

from harness.sim.plan import build_plan, route_lane
from scenarios import set_path
from scenarios.routefile import read_routes
from sumo_nets import load_net

ROUTES = read_routes(set_path("town12_smoke"))[1]
ROUTE = ROUTES[0]


def test_the_target_point_stays_target_min_ahead_on_the_run_on_near_the_end():
    plan = build_plan(ROUTE, load_net(ROUTE.town))
    heading = np.array([math.cos(plan.yaw[-1]), math.sin(plan.yaw[-1])])
    last = len(plan.s) - 1
    # at the last point: TARGET_MIN = 7.5 m straight on past it
    np.testing.assert_allclose(plan.target_xy(last), plan.xy[-1] + 7.5 * heading, atol=1e-9)
    # 3 points before the end (route 0's dense points are 0.99699 m apart: 2.99097 m before
    # it): 7.5 - 2.99097 = 4.50903 m past the end
    np.testing.assert_allclose(plan.target_xy(last - 3), plan.xy[-1] + 4.50903 * heading, atol=1e-5)  # 5 decimals
    # far from the end: a sparse route point, at least TARGET_MIN ahead
    tp = plan.target_xy(0)
    j = int(np.flatnonzero((plan.xy == tp).all(axis=1))[0])
    assert j in set(plan.sparse.tolist())
    assert plan.s[j] >= 7.5


def test_the_shown_route_is_the_route_then_a_straight_run_on():
    plan = build_plan(ROUTE, load_net(ROUTE.town))
    shown = plan.shown_xy
    n = len(plan.xy)
    np.testing.assert_array_equal(shown[:n], plan.xy)
    assert len(shown) == n + 20  # END_PAD: 20 m of 1 m steps
    steps = np.diff(shown[n - 1:], axis=0)
    heading = np.array([math.cos(plan.yaw[-1]), math.sin(plan.yaw[-1])])
    np.testing.assert_allclose(steps, np.tile(heading, (len(steps), 1)), atol=1e-9)  # 1 m steps straight on


def test_commands_run_from_5_m_before_a_passage_to_its_exit_and_limits_are_the_edges():
    """Route 0: dense points 0.99699 m apart, a left turn through s = 28.85..50.85 m and a
    right turn through 149.39..162.60 m. From s_in - 5 m (23.85: point 24 at 23.93; point 23
    is at 22.93) to s_out (point 51 at 50.85): LEFT (1); 144.39 (point 145) to 162.60
    (point 163): RIGHT (2); LANEFOLLOW (4) elsewhere. Route 2 (0.99529 m apart) goes straight
    through 83.93..98.66: STRAIGHT (3) on points 80 (79.62) to 99 (98.53). Speed limits:
    route 0 runs on 50 km/h edges (13.89 m/s in the town12 net), route 2 on 30 km/h (8.33)."""
    plan = build_plan(ROUTE, load_net(ROUTE.town))
    assert plan.command.tolist() == [4] * 24 + [1] * 28 + [4] * 93 + [2] * 19 + [4] * 2
    assert plan.speed_limit.tolist() == [13.89] * 166
    straight = build_plan(ROUTES[2], load_net(ROUTES[2].town))
    assert straight.command.tolist() == [4] * 80 + [3] * 20 + [4] * 61
    assert straight.speed_limit.tolist() == [8.33] * 161


def test_a_hazard_is_placed_in_the_lane_the_route_is_in(short_routes):
    """Route 50 changes from lane 1 to lane 2 along edge d45_d55: a vehicle placed at
    route s goes to the lane the route is in there, not to the lane it entered the edge on."""
    route = next(r for r in short_routes if r.id == "50")
    net = load_net("town12")
    plan = build_plan(route, net)
    leg = next(g for g in plan.path.legs if g.lane_in != g.lane_out)
    lanes = {net.getLane(leg.lane_in).getIndex(), net.getLane(leg.lane_out).getIndex()}
    assert len(lanes) == 2
    for s, lane_id in ((leg.s0 + 1.0, leg.lane_in), (leg.s1 - 1.0, leg.lane_out)):
        edge, index, _ = route_lane(plan, net, s)
        assert (edge, index) == (leg.edge, net.getLane(lane_id).getIndex())


def test_a_hazards_road_sides_are_measured_from_the_lane_the_route_is_in(short_routes):
    """On route 50's lane change (lane 1 -> 2 of d45_d55), the road's right border lies one
    lane further right of the route at the end of the edge than at its start."""
    from harness.sim.hazards import _road_sides
    route = next(r for r in short_routes if r.id == "50")
    net = load_net("town12")
    plan = build_plan(route, net)
    leg = next(g for g in plan.path.legs if g.lane_in != g.lane_out)
    lanes = net.getEdge(leg.edge).getLanes()
    for s, lane_id in ((leg.s0 + 1.0, leg.lane_in), (leg.s1 - 1.0, leg.lane_out)):
        i = net.getLane(lane_id).getIndex()
        right, _ = _road_sides(plan, net, s)
        # lanes are indexed from the right: the route lane's half width plus every lane right of it
        assert right == sum(ln.getWidth() for ln in lanes[:i]) + lanes[i].getWidth() / 2
