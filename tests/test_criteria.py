"""The Leaderboard's criteria in real libsumo: the episode runs, then detection reads its log,
as in `sumo-scimm eval` (red light, stop sign, vehicle and pedestrian collisions, route
deviation, blocked, minimum speed, outside lanes); the route timeout's budget by hand on a
straight plan."""
from __future__ import annotations

from types import SimpleNamespace

import libsumo
import numpy as np
import pytest

from controller.vehicle import LENGTH, WIDTH, EgoState
from harness.sim.contacts import overlaps
from harness.loop.episode import run_episode
from harness.scoring.criteria import RouteTimeout
from harness.scoring.infractions import collisions, detect
from harness.scoring.statuses import FAILED_TIMEOUT
from harness.sim.hazards import make_hazard
from harness.sim.plan import build_plan
from harness.sim.world import World
from scenarios import set_path
from scenarios.routefile import read_routes
from sumo_nets import load_net

SMOKE = read_routes(set_path("town12_smoke"))[1]  # 0 light, 1 stop sign, 2 crosswalk, 3 obstacle


def _run(route, agent, seed=0, config=None):
    res = run_episode(route, agent, config, seed)
    ev = detect(res.log.arrays(), res.plan, route, load_net(route.town), res.status)
    return res, ev


def test_red_light_run_and_respected():
    _, ev = _run(SMOKE[0], "route_follower")
    assert len(ev["red_light"]) == 1
    assert ev["red_light"][0].startswith("Agent ran a red light ")
    res, ev = _run(SMOKE[0], "tests.agents:LightStopper")
    assert res.status == "Completed"
    assert ev["red_light"] == []


def test_stop_sign_rolled_and_respected():
    _, ev = _run(SMOKE[1], "route_follower")
    assert len(ev["stop_infraction"]) == 1
    assert ev["stop_infraction"][0].startswith("Agent ran a stop with id=")
    res, ev = _run(SMOKE[1], "tests.agents:StopSignStopper")
    assert res.status == "Completed"
    assert ev["stop_infraction"] == []


def test_pedestrian_hit_while_moving_is_counted_once():
    _, ev = _run(SMOKE[2], "route_follower")
    assert len(ev["collisions_pedestrian"]) == 1
    assert "type=walker." in ev["collisions_pedestrian"][0]


def test_touched_by_a_vehicle_while_standing_is_not_counted():
    """A SUMO vehicle that ignores the ego (speed mode 0) drives into it while it stands."""
    route = SMOKE[3]
    net = load_net("town12")
    plan = build_plan(route, net)
    world = World("town12", 7)
    x, y, yaw = plan.path.pose(0.0)
    ego = EgoState(x, y, yaw, 0.0)
    log = {k: [] for k in ("t", "x", "y", "v")}
    ticks, actors, classes = [], [], []
    try:
        lane = net.getLane(plan.path.legs[0].lane_in)
        world.add_ego(route.edges, lane.getIndex(), route.depart_pos)
        libsumo.route.add("ram", [route.edges[0]])
        libsumo.vehicle.add("rammer", "ram", typeID="background", departLane=str(lane.getIndex()),
                            departPos="0", departSpeed="5")
        libsumo.vehicle.setSpeedMode("rammer", 0)
        libsumo.vehicle.setLaneChangeMode("rammer", 0)
        libsumo.vehicle.setSpeed("rammer", 5.0)
        for k in range(600):
            world.move_ego(ego)
            world.step()
            snap = world.snapshot()
            for j in np.flatnonzero(overlaps((x, y, yaw, LENGTH, WIDTH), snap.xy, snap.yaw, snap.size)):
                ticks.append(k + 1), actors.append(snap.ids[j]), classes.append(int(snap.cls[j]))
            for key, val in zip(("t", "x", "y", "v"), (world.time, x, y, 0.0)):
                log[key].append(val)
    finally:
        world.close()
    assert "rammer" in actors, "the rammer never touched the ego"
    arrays = {k: np.asarray(v) for k, v in log.items()}
    arrays.update(contact_tick=np.asarray(ticks), contact_actor=np.asarray(actors),
                  contact_class=np.asarray(classes))
    assert collisions(arrays)["collisions_vehicle"] == []
    arrays["v"] = np.full(len(arrays["t"]), 1.0)  # the same contacts while moving do count, once
    assert len(collisions(arrays)["collisions_vehicle"]) == 1


def test_leaving_the_road_and_staying_in_lane():
    res, ev = _run(SMOKE[3], "tests.agents:SteerRight")
    assert len(ev["outside_route_lanes"]) == 1
    assert ev["outside_route_lanes"][0].startswith("Agent went outside its route lanes for about ")
    assert res.status == "Failed - Agent deviated from the route"
    assert len(ev["route_dev"]) == 1
    assert ev["route_dev"][0].startswith("Agent deviated from the route at (x=")
    _, ev = _run(SMOKE[3], "route_follower")
    assert ev["outside_route_lanes"] == []
    assert ev["route_dev"] == []


def test_standing_still_past_the_blocked_limit():
    res, ev = _run(SMOKE[1], "tests.agents:Standstill")
    assert res.status == "Failed - Agent got blocked"
    assert res.game_time == pytest.approx(180.0, abs=0.1)
    assert len(ev["vehicle_blocked"]) == 1
    assert ev["route_dev"] == []
    res, ev = _run(SMOKE[1], "route_follower")
    assert ev["vehicle_blocked"] == []


def test_min_speed_final_checkpoint_is_emitted_twice_on_a_normal_end(tmp_path):
    """An agent at 3 m/s (traffic: ~70 % of 50 km/h) gets min-speed messages (a checkpoint
    where the nearby traffic happened to be slower gives none), and the final checkpoint
    twice: the leaderboard's terminate runs twice on a normal route end."""
    cfg = tmp_path / "slow.json"
    cfg.write_text('{"speed": 3.0}')
    res, ev = _run(SMOKE[3], "route_follower", config=str(cfg))
    msgs = ev["min_speed_infractions"]
    assert res.status == "Completed"
    assert 2 <= len(msgs) <= 5, msgs
    assert msgs[-1] == msgs[-2]
    pct = [float(m.split()[3].rstrip("%")) for m in msgs]
    assert all(p < 100 for p in pct)
    assert all(m.startswith("Average speed is ") and m.endswith("% of the surrounding traffic's one") for m in msgs)


def test_route_timeout_budget_by_hand():
    """RouteTimeout's budget: 300 s plus, for every metre the route index passes, 1 m /
    (0.1 x the speed limit at the point reached). On a straight 100 m plan at 10 m/s for
    its first 50 points and 5 m/s after: 300 + 50 / 1 + 50 / 0.5 = 450 s once the ego has
    passed the end; before it moves, 300 s."""
    n = 101
    plan = SimpleNamespace(xy=np.column_stack([np.arange(n, dtype=float), np.zeros(n)]), yaw=np.zeros(n),
                           s=np.arange(n, dtype=float), speed_limit=np.where(np.arange(n) <= 50, 10.0, 5.0))
    still = RouteTimeout(plan)
    assert still.update(-1.0, 0.0, 300.0) is None and still.update(-1.0, 0.0, 300.01) == FAILED_TIMEOUT
    moving = RouteTimeout(plan)
    for k in range(n):  # 1 m a step, always inside the Leaderboard's window of 4 points
        assert moving.update(k + 0.5, 0.0, 0.0) is None
    assert moving.budget == 450.0
    assert moving.update(100.5, 0.0, 450.0) is None and moving.update(100.5, 0.0, 450.01) == FAILED_TIMEOUT


def test_a_parked_or_accident_car_is_a_vehicle_collision_a_construction_site_is_layout():
    """The Leaderboard's ParkedObstacle and Accident spawn ``vehicle.*`` actors (x 0.6 when
    hit), its construction site props (x 0.65). Three contacts 10 s and 20 m apart, so
    each counts: the construction obstacle (hazard 0), the accident's car (hazard 1) and a
    harness prop."""
    n = 600
    log = {"t": np.arange(n) * 0.05, "x": np.arange(n) * 0.1, "y": np.zeros(n), "v": np.full(n, 2.0),
           "contact_tick": np.array([1, 201, 401]), "contact_actor": np.array(["hz0_obstacle", "hz1_obstacle", "prop0"]),
           "contact_class": np.array([2, 2, 2])}
    spans = [("ParkedObstacle", 0.0, 30.0, {"variant": "construction"}),
             ("ParkedObstacle", 50.0, 80.0, {"variant": "accident"})]
    ev = collisions(log, spans)
    assert ev["collisions_vehicle"] == ["Agent collided against object with type=vehicle.sumo.accident and "
                                        "id=hz1_obstacle at (x=20.0, y=0.0, z=0.0)"]
    assert [m.split(" and ")[1] for m in ev["collisions_layout"]] == ["id=hz0_obstacle at (x=0.0, y=0.0, z=0.0)",
                                                                      "id=prop0 at (x=40.0, y=0.0, z=0.0)"]
    assert ev["collisions_pedestrian"] == []


def test_the_route_follower_hits_the_parked_car_a_vehicle_collision():
    route = SMOKE[3]  # ParkedObstacle, variant parked_car; the route follower ignores it
    assert route.hazards[0].params["variant"] == "parked_car"
    res, ev = _run(route, "route_follower")
    assert [m.split(" at ")[0] for m in ev["collisions_vehicle"]] == [
        "Agent collided against object with type=vehicle.sumo.parked_car and id=hz0_obstacle"]
    assert ev["collisions_layout"] == []


def test_a_timed_out_obstacle_is_removed_and_a_passed_one_stays():
    """The Leaderboard destroys an obstacle scenario's actors when it ends: 240 s after the
    trigger (strictly more) with the ego not yet 10 m past the site, the obstacle goes; an
    ego already 10 m past the site has ended the scenario itself and the obstacle stays."""
    route = SMOKE[3]
    net = load_net("town12")
    plan = build_plan(route, net)
    for ego_past, removed in ((-20.0, True), (10.0, False)):
        world = World("town12", 7)
        try:
            hz = make_hazard(route.hazards[0], plan, net, np.random.default_rng(0), 0)
            hz.setup()
            world.step()
            assert "hz0_obstacle" in libsumo.vehicle.getIDList()
            hz.update(hz.trigger_s, 1.0, 5.0)  # the trigger: t0 = 1 s
            hz.update(hz.site_s + ego_past, 1.0 + 240.0, 0.0)  # 240 s: not yet
            assert "hz0_obstacle" in libsumo.vehicle.getIDList()
            hz.update(hz.site_s + ego_past, 1.0 + 240.05, 0.0)
            assert ("hz0_obstacle" not in libsumo.vehicle.getIDList()) == removed
            hz.update(hz.site_s + ego_past, 1.0 + 240.10, 0.0)  # and once only
        finally:
            world.close()
