"""Leaderboard rules on synthetic logs and fake straight plans, no SUMO: infraction
detection (collisions, outside lanes, red lights), the route-ending criteria (InRoute,
RouteCompletion, Blocked) and the scoring's Leaderboard 2.1 weights and global-record
rules (docs/design.md §9.1). Every expected value is worked out by hand in its comment;
positions [m], times [s], speeds [m/s]."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from harness.scoring.criteria import Blocked, InRoute, RouteCompletion
from harness.scoring.infractions import KEYS, collisions, outside_lanes, red_lights
from harness.scoring.scores import global_record, infraction_penalty, rescore, route_record
from harness.sim.world import PEDESTRIAN, VEHICLE

DEVIATED, BLOCKED = "Failed - Agent deviated from the route", "Failed - Agent got blocked"


def _plan(n: int = 101) -> SimpleNamespace:
    """A straight dense route along +x, points 1 m apart: point k at (k, 0), s = k."""
    return SimpleNamespace(xy=np.column_stack([np.arange(n, dtype=float), np.zeros(n)]), yaw=np.zeros(n),
                           s=np.arange(n, dtype=float), length=float(n - 1))


# --- collisions ----------------------------------------------------------------------------
def test_collisions_five_seconds_five_metres_same_actor_and_contact_tick():
    """Ego at x = k m, t = 0.05 k s, 20 m/s. Contact tick c is log row c - 1 (ticks count
    from 1). (11, a) -> row 10, x = 10: counted. (12, b) -> x = 11, 1 m from the last one:
    skipped (5 m). (17, b) -> x = 16, 6 m away, another actor: counted. (30, b pedestrian) ->
    x = 29, same actor 0.65 s after: skipped (5 s). (200, b) -> x = 199, 9.15 s after: counted."""
    n = 200
    k = np.arange(n)
    log = {"t": 0.05 * k, "x": k.astype(float), "y": np.zeros(n), "v": np.full(n, 20.0),
           "contact_tick": np.array([11, 12, 17, 30, 200]), "contact_actor": np.array(["a", "b", "b", "b", "b"]),
           "contact_class": np.array([VEHICLE, VEHICLE, VEHICLE, PEDESTRIAN, PEDESTRIAN])}
    out = collisions(log)
    msg = "Agent collided against object with type={} and id={} at (x={}, y=0.0, z=0.0)"
    assert out["collisions_vehicle"] == [msg.format("vehicle.sumo.car", "a", 10.0),
                                         msg.format("vehicle.sumo.car", "b", 16.0)]
    assert out["collisions_pedestrian"] == [msg.format("walker.pedestrian.sumo", "b", 199.0)]
    assert out["collisions_layout"] == []


# --- outside lanes -------------------------------------------------------------------------
class _Lanes:
    """A fake LaneIndex: the nearest lane is 3.5 m wide, centred on y = 0 (dist = |y|),
    heading 0 (along the route); ``junction(x)`` says where it is a junction lane."""

    def __init__(self, junction=lambda x: np.zeros(len(x), bool)):
        self.junction = junction

    def nearest(self, xy):
        n = len(xy)
        return SimpleNamespace(dist=np.abs(xy[:, 1]), width=np.full(n, 3.5), heading=np.zeros(n),
                               junction=self.junction(xy[:, 0]))


def _drive(y_off=0.0, yaw_off=0.0, step=1.0, lo=20.0, hi=30.0):
    """Ego at x = step k + 0.5 for x < 100, off by y_off [m] and yaw_off [rad] for lo < x < hi."""
    x = np.arange(0.5, 100.0, step)
    bad = (x > lo) & (x < hi)
    return {"x": x, "y": np.where(bad, y_off, 0.0), "yaw": np.where(bad, yaw_off, 0.0), "route_index": np.floor(x)}


def test_outside_lanes_metres_and_percentage_of_the_completed_route():
    """Tick k (x = k + 0.5) passes point k: 1 m per tick, 99 m over ticks 1..99. At y = 3 m
    (> 3.5 / 2 + 0.5 = 2.25) for x in (20, 30), ticks 20..29: 10 m, 10 / 99 * 100 = 10.1010 %."""
    values = {}
    out = outside_lanes(_drive(y_off=3.0), _plan(), _Lanes(), [], values)
    assert out == ["Agent went outside its route lanes for about 10.0 meters (10.1% of the completed route)"]
    assert values["outside_route_lanes"] == pytest.approx(1000 / 99, rel=1e-12)  # float division order


def test_outside_lanes_margin_is_half_a_metre_beyond_the_half_width():
    """Outside means farther than 3.5 / 2 + 0.5 = 2.25 m from the lane centre."""
    assert outside_lanes(_drive(y_off=2.24), _plan(), _Lanes(), []) == []
    assert outside_lanes(_drive(y_off=2.26), _plan(), _Lanes(), []) == [
        "Agent went outside its route lanes for about 10.0 meters (10.1% of the completed route)"]


def test_wrong_way_from_120_degrees_off_the_lane_except_in_junctions():
    """In the lane but heading 121 deg off its direction counts as outside (10 m, 10.1 %);
    119 deg does not; 121 deg on a junction lane does not."""
    msg = "Agent went outside its route lanes for about 10.0 meters (10.1% of the completed route)"
    assert outside_lanes(_drive(yaw_off=math.radians(-121)), _plan(), _Lanes(), []) == [msg]
    assert outside_lanes(_drive(yaw_off=math.radians(121)), _plan(), _Lanes(), []) == [msg]
    assert outside_lanes(_drive(yaw_off=math.radians(-119)), _plan(), _Lanes(), []) == []
    junction = _Lanes(lambda x: (x > 15) & (x < 35))
    assert outside_lanes(_drive(yaw_off=math.radians(-121)), _plan(), junction, []) == []


def test_outside_lanes_passes_up_to_three_points_per_tick():
    """3 m per tick (x = 3k + 0.5): each tick passes the next 3 points (window i+1..i+3), 99 m
    over ticks 1..33; outside (y = 3) at x = 30.5 .. 57.5, 10 ticks: 30 m, 30.30 %."""
    out = outside_lanes(_drive(y_off=3.0, step=3.0, lo=30.0, hi=60.0), _plan(), _Lanes(), [])
    assert out == ["Agent went outside its route lanes for about 30.0 meters (30.3% of the completed route)"]


# --- red lights ----------------------------------------------------------------------------
def _light(width: float):
    """One red light on the route: a single lane of ``width`` ending at (0, 0) heading +x,
    so its stop line is x = 0, |y| <= 0.6 width, and its centre (0, 0)."""
    lane = SimpleNamespace(allows=lambda c: True, getShape=lambda: [(-50.0, 0.0), (0.0, 0.0)], getWidth=lambda: width)
    net = SimpleNamespace(getEdge=lambda e: SimpleNamespace(getLanes=lambda: [lane]))
    plan = SimpleNamespace(passages=[SimpleNamespace(tls="J1", link=3, from_edge="E0")])
    return plan, net


def _pass(y: float, x_end: float = 10.0) -> dict:
    """Ego heading +x at y [m], x = -20 .. x_end in 0.5 m steps, the light red ('r') throughout."""
    x = np.arange(-20.0, x_end + 0.25, 0.5)
    return {"t": 0.05 * np.arange(len(x)), "x": x, "y": np.full(len(x), y), "yaw": np.zeros(len(x)),
            "tls": np.zeros((len(x), 1), int)}


def test_red_light_is_the_tail_crossing_the_stop_line_within_15_m():
    """The ego's tail segment, 0.8 * 2.45 = 1.96 m to 2.45 + 1 = 3.45 m behind its centre,
    crosses x = 0 at x = 2.0 .. 3.0: one message (not one per tick), at the line's centre.
    Stopping with the centre at x = 1.5 (nose 3.95 m past the line) is no run. Stop-line
    half width 0.6 * 3.2 = 1.92 m: y = 1.9 runs it, y = 1.95 passes beside it. A 30 m wide lane
    (half width 18 m): at y = 14.5 the centre is 14.64 .. 14.81 m away at the crossing (< 15 m,
    counted); at y = 15 it is farther than 15 m (skipped)."""
    msg = ["Agent ran a red light J1:3 at (x=0.0, y=0.0, z=0.0)"]
    assert red_lights(_pass(0.0), *_light(3.2)) == msg
    assert red_lights(_pass(0.0, x_end=1.5), *_light(3.2)) == []
    assert red_lights(_pass(1.9), *_light(3.2)) == msg
    assert red_lights(_pass(1.95), *_light(3.2)) == []
    assert red_lights(_pass(14.5), *_light(30.0)) == msg
    assert red_lights(_pass(15.0), *_light(30.0)) == []


# --- route-ending criteria -----------------------------------------------------------------
def test_route_completion_needs_rc_above_99_and_the_end_within_10_m():
    """101-point plan, 100 m. At x = 99.5 the ego passed point 99: RC 99.0, not > 99, though
    0.5 m from the end. At (100.5, 9.9), 9.91 m from the end (100, 0): Completed, RC 100;
    at (100.5, 10.1), 10.11 m: not. A 3 m plan past point 1: RC 1 / 3 = 33.33 (2 decimals)."""
    for y_end, status in ((9.9, "Completed"), (10.1, None)):
        rc = RouteCompletion(_plan())
        for k in range(100):
            assert rc.update(k + 0.5, 0.0) is None
        assert rc.rc == 99.0
        assert rc.update(100.5, y_end) == status
        assert rc.rc == 100.0
    short = RouteCompletion(_plan(4))
    short.update(1.5, 0.0)
    assert short.rc == 33.33


def _in_route(y: float, metres: int, start: int = 10):
    """InRoute on the 101-point plan: y = 0 up to x = start, then ``metres`` 1 m steps at y;
    (the first status, x at it) or (None, None)."""
    r = InRoute(_plan())
    for k in range(start + 1):
        assert r.update(float(k), 0.0) is None
    for k in range(start + 1, start + 1 + metres):
        if (out := r.update(float(k), y)) is not None:
            return out, k
    return None, None


def test_in_route_deviation_at_30_m_and_30_percent_farther_than_15_m():
    """Nearest point 29.99 m away: on; 30.0 m: deviated at once. 15 m off for 30 m of advance:
    30 / 100 is not > 30 %; for 31 m it is (at x = 41); 14.99 m off does not count at all."""
    assert _in_route(29.99, 1) == (None, None)
    assert _in_route(30.0, 1) == (DEVIATED, 11)
    assert _in_route(15.0, 30) == (None, None)
    assert _in_route(15.0, 31) == (DEVIATED, 41)
    assert _in_route(14.99, 60) == (None, None)


def test_in_route_looks_six_points_ahead_and_a_tie_goes_to_the_later_point():
    """From index 0 the window is points 0..5: at (5, 29.99) point 5 is 29.99 m away (on); at
    (6, 29.99) the nearest, point 5, is sqrt(1 + 29.99^2) = 30.006 m (deviated). On an
    11-point (10 m) plan at y = 15, x = 2.5 is equally far from points 2 and 3: the later, 3 m
    off-route (3 / 10, not > 30 %); then x = 3.5 ties 3 and 4: 4 m, 40 % -> deviated."""
    assert InRoute(_plan()).update(5.0, 29.99) is None
    assert InRoute(_plan()).update(6.0, 29.99) == DEVIATED
    r = InRoute(_plan(11))
    assert r.update(2.5, 15.0) is None
    assert r.update(3.5, 15.0) == DEVIATED


def test_blocked_below_0_1_m_s_for_more_than_180_s_and_paused_by_a_scenario_timeout():
    """0.1 m/s is moving (restarts the timer at 100 s); 0.09 m/s is not: 280.0 - 100 = 180 s is
    not more than 180, 280.05 is. Paused for 300 s (0.05 s ticks), nothing ends the route, and the
    timer restarts: blocked only after 300 + 180 s."""
    b = Blocked()
    assert b.update(0.1, 0.0) is None and b.update(0.1, 100.0) is None
    assert b.update(0.09, 280.0) is None
    assert b.update(0.09, 280.05) == BLOCKED
    b = Blocked()
    assert all(b.update(0.0, 0.05 * k, paused=True) is None for k in range(6001))
    assert b.update(0.0, 480.0) is None
    assert b.update(0.0, 480.05) == BLOCKED


# --- scoring -------------------------------------------------------------------------------
VEH = "Agent collided against object with type=vehicle.tesla.model3 and id=13 at (x=1.0, y=2.0, z=0.0)"
PED = "Agent collided against object with type=walker.pedestrian.0001 and id=12 at (x=1.0, y=2.0, z=0.0)"
LAYOUT = "Agent collided against object with type=static.prop.mesh and id=14 at (x=1.0, y=2.0, z=0.0)"
STOP = "Agent ran a stop with id=88 at (x=3.0, y=4.0, z=0.0)"


def _inf(**lists):
    return {k: lists.get(k, []) for k in KEYS}


def _record(i, rc, infractions, rules="lb2.0"):
    return route_record(i, f"RouteScenario_{i}_rep0", infractions, rc,
                        {"route_length": 500.0, "duration_game": 10.0, "duration_system": 1.0}, rules)


@pytest.mark.parametrize("key,msg,expected", [
    ("collisions_vehicle", VEH, 1 / 1.7), ("collisions_layout", LAYOUT, 1 / 1.6), ("stop_infraction", STOP, 0.8),
    ("scenario_timeouts", "Agent timed out a scenario", 1 / 1.4),
    ("yield_emergency_vehicle_infractions", "Agent failed to yield to an emergency vehicle", 1 / 1.4)])
def test_lb21_weight_of_each_infraction(key, msg, expected):
    """Leaderboard 2.1: IS = 1 / (1 + w): vehicle 0.7, layout 0.6, stop 0.25 (1 / 1.25 = 0.8),
    scenario timeout and yield 0.4 (relative 1e-12: 1 + w is rounded in binary)."""
    assert infraction_penalty(_inf(**{key: [msg]}), "lb2.1") == pytest.approx(expected, rel=1e-12)


def test_per_km_rates_divide_by_at_least_a_metre():
    """A 500 m route at RC 0 drove 0 km; the divisor is floored at 0.001 km: 1 / 0.001 = 1000."""
    g = global_record([_record(0, 0.0, _inf(collisions_pedestrian=[PED]))], total=1)
    assert g["infractions"]["collisions_pedestrian"] == 1000.0


def test_rescoring_a_completed_route_recomputes_its_status():
    """A Bench2Drive record at RC 100 with only a 100 % minimum-speed message is "Completed";
    under lb2.0 the message is dropped, so it is "Perfect"."""
    rec = _record(0, 100, _inf(min_speed_infractions=["Average speed is 100.0% of the surrounding traffic's one"]),
                  "b2d")
    assert rec["status"] == "Completed"
    out, dropped = rescore(rec, "lb2.0")
    assert (out["status"], dropped) == ("Perfect", 1)


def test_global_status_is_failed_whatever_comes_after_a_failed_route():
    recs = [_record(0, 50.0, _inf()), _record(1, 100, _inf(stop_infraction=[STOP]))]
    assert [r["status"] for r in recs] == ["Failed", "Completed"]
    assert global_record(recs, total=2)["status"] == "Failed"


def test_global_outside_lanes_reads_the_first_message_of_a_route():
    """Two messages, 30 m and 50 m: the global value is the first one's 30 m = 0.03 km."""
    out = [f"Agent went outside its route lanes for about {m} meters ({q}% of the completed route)"
           for m, q in ((30.0, 3.0), (50.0, 5.0))]
    g = global_record([_record(0, 100, _inf(outside_route_lanes=out))], total=1)
    assert g["infractions"]["outside_route_lanes"] == 0.03
