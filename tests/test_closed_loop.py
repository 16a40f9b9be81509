"""The closed loop in real libsumo: no lane glue, SUMO traffic respects the ego, hazards
in the BEV, failures recorded per route, resume, determinism (docs/design.md §3, §12)."""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import libsumo
import numpy as np
import pytest

from controller.vehicle import LENGTH, EgoState
from harness.sensors import bev as B
from sumo_scimm.cli import main
from harness.loop.episode import run_episode
from harness.sim.plan import build_plan
from harness.sim.stop_signs import stop_passages
from harness.scoring.scores import rescore_results
from harness.sim.world import World
from scenarios import set_path
from scenarios.routefile import read_routes
from sumo_nets import load_net

SMOKE = read_routes(set_path("town12_smoke"))[1]


def _records(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "records.jsonl").read_text().splitlines()]


def test_steering_right_leaves_the_drivable_area():
    res = run_episode(SMOKE[3], "tests.agents:SteerRight", None, seed=1)
    net = load_net("town12")
    x, y = res.log.columns["x"], res.log.columns["y"]
    outside = 0
    for k in range(0, len(x), 10):
        lanes = [(ln, d) for ln, d in net.getNeighboringLanes(x[k], y[k], 10.0) if ln.allows("passenger")]
        if all(d > ln.getWidth() / 2 + 0.5 for ln, d in lanes):  # Leaderboard's outside-lane rule
            outside += 1
    assert outside > 0, "the ego never left the road: something glues it to the lanes"
    assert res.status == "Failed - Agent deviated from the route"


def test_sumo_vehicle_behind_a_standing_ego_stops_without_passing_through():
    route = SMOKE[3]  # starts on a 2-lane downtown edge
    plan = build_plan(route, load_net("town12"))
    world = World("town12", 5)
    try:
        lane = load_net("town12").getLane(plan.path.legs[0].lane_in)
        world.add_ego(route.edges, lane.getIndex(), route.depart_pos)
        x, y, yaw = plan.path.pose(0.0)
        ego = EgoState(x, y, yaw, 0.0)
        libsumo.route.add("follow", [route.edges[0]])
        libsumo.vehicle.add("follower", "follow", typeID="background", departLane=str(lane.getIndex()),
                            departPos="0", departSpeed="max")
        libsumo.vehicle.setLaneChangeMode("follower", 0)  # no overtaking: it must stop
        gaps = []
        for _ in range(int(30 / 0.05)):
            world.move_ego(ego)
            world.step()
            if "follower" in libsumo.vehicle.getIDList():
                fx, fy = libsumo.vehicle.getPosition("follower")  # its front bumper
                along = (fx - x) * math.cos(yaw) + (fy - y) * math.sin(yaw)
                gaps.append(-LENGTH / 2 - along)  # ego rear minus follower front [m]
        assert len(gaps) > 100
        assert min(gaps) > 0.0, "the follower drove into the standing ego"
        assert libsumo.vehicle.getSpeed("follower") < 0.1
    finally:
        world.close()


def test_pedestrian_crossing_in_front_is_seen_in_the_bev():
    route = SMOKE[2]
    assert route.hazards[0].type == "PedestrianCrossing"
    renderer = B.BevRenderer.for_town("town12")
    seen = []

    def on_frame(f):
        ahead = [k for k, i in enumerate(f.snap.ids) if i.startswith("ped_hz")]
        if not ahead:
            return
        bev = renderer.render(f.ego, f.snap, f.plan, f.lights, f.props, f.stops)
        # walker pixels in a corridor ahead of the ego (+-6 m wide, 2..30 m ahead)
        corridor = bev[B.WALKERS, B.EGO_ROW - 40:B.EGO_ROW - 3, 24:41]
        seen.append(int((corridor > 0).sum()))

    res = run_episode(route, "route_follower", None, seed=2, on_frame=on_frame)
    assert res.status == "Completed"
    assert max(seen) > 0, "the crossing walker never showed in the BEV ahead of the ego"


def test_a_walker_that_has_crossed_is_gone_not_left_to_sumo():
    """Crossing walkers move on a straight line at their speed, which the world view reports,
    and leave the simulation at its end. Left
    to SUMO, those that moveToXY had mapped onto a vehicle lane walked on along the road
    (at right angles to the crossing) until SUMO stopped with "Disconnected walk"."""
    route = SMOKE[2]
    assert route.hazards[0].type == "PedestrianCrossing"
    track: dict[str, list] = {}
    speeds: list[float] = []
    present_at_end = []

    def on_frame(f):
        for k, i in enumerate(f.snap.ids):
            if i.startswith("ped_hz"):
                track.setdefault(i, []).append(f.snap.xy[k].copy())
                speeds.append(float(f.snap.speed[k]))
        present_at_end[:] = [i for i in libsumo.person.getIDList() if i.startswith("ped_hz")]

    res = run_episode(route, "route_follower", None, seed=2, on_frame=on_frame)
    assert res.status == "Completed"
    assert len(track) == int(route.hazards[0].params["walkers"])
    assert present_at_end == []
    # the world view reports the walking speed (SUMO says 0 for a walker moved by moveToXY)
    assert speeds, "no walker was ever seen"
    assert set(speeds) == {float(route.hazards[0].params["speed"])}
    for pid, pts in track.items():
        pts = np.array(pts)
        u = (pts[-1] - pts[0]) / np.linalg.norm(pts[-1] - pts[0])
        off_line = np.abs((pts[:, 0] - pts[0, 0]) * u[1] - (pts[:, 1] - pts[0, 1]) * u[0])
        # the crossing is 1.44 m/s x ~12 s; SUMO reports positions to ~1 mm
        assert off_line.max() < 0.05, f"{pid} left its crossing line by {off_line.max():.2f} m"


def test_bev_places_an_actor_where_it_is(tmp_path):
    from harness.sim.world import Snapshot
    route = SMOKE[0]
    plan = build_plan(route, load_net("town12"))
    x, y, yaw = plan.path.pose(0.0)
    ego = EgoState(x, y, yaw, 0.0)
    # a 4 m x 2 m vehicle 15 m straight ahead of the ego
    ax, ay = x + 15 * math.cos(yaw), y + 15 * math.sin(yaw)
    snap = Snapshot(["v"], np.array([[ax, ay]]), np.array([yaw]), np.zeros(1), np.array([[4.0, 2.0]]),
                    np.array([0]), math.nan)
    img = B.BevRenderer.for_town("town12").render(ego, snap, plan, [], [], [True] * len(stop_passages(plan)))
    rows, cols = np.nonzero(img[B.VEHICLES] > 128)
    # expected centre: row 48 - 15 / 0.75 = 28, column 32 (64 / 2); box 4 m = 5.3 px tall;
    # cv2.fillPoly also fills the pixels its edges pass through: up to 1 px more per side
    assert rows.mean() == pytest.approx(B.EGO_ROW - 15 / B.RES, abs=0.75)
    assert cols.mean() == pytest.approx(B.SIZE / 2, abs=0.75)
    assert 4.0 / B.RES - 1 <= rows.max() - rows.min() + 1 <= 4.0 / B.RES + 2
    assert img[B.ROAD, B.EGO_ROW, B.SIZE // 2] == 255  # the ego stands on the road
    assert img[B.ROUTE, B.EGO_ROW - 5, B.SIZE // 2] > 0  # ... on its route


def test_a_repeated_scene_gets_its_last_frame_and_any_change_is_drawn_anew(monkeypatch):
    from harness.sim.world import Snapshot
    plan = build_plan(SMOKE[0], load_net("town12"))
    x, y, yaw = plan.path.pose(0.0)
    renderer = B.BevRenderer.for_town("town12")
    drawn = []
    draw = renderer.draw
    monkeypatch.setattr(renderer, "draw", lambda *a: drawn.append(1) or draw(*a))

    def scene(ahead=15.0, cls=0, ego_yaw=yaw, props=(), lights=(), route_plan=plan, stops=None):
        ax, ay = x + ahead * math.cos(yaw), y + ahead * math.sin(yaw)
        snap = Snapshot(["v"], np.array([[ax, ay]]), np.array([yaw]), np.zeros(1), np.array([[4.0, 2.0]]),
                        np.array([cls]), math.nan)
        stops = [True] * len(stop_passages(route_plan)) if stops is None else stops
        return EgoState(x, y, ego_yaw, 0.0), snap, route_plan, list(lights), list(props), stops

    first = renderer.render(*scene())
    again = renderer.render(*scene())  # equal inputs in new objects: no new drawing
    assert len(drawn) == 1, "equal inputs were drawn again"
    assert np.array_equal(again, first)
    assert again is not first, "the kept frame itself was handed out"
    again[:] = 0  # the caller owns what it gets: the kept frame is not touched
    assert np.array_equal(renderer.render(*scene()), first), "the caller's write reached the kept frame"
    assert len(drawn) == 1
    changes = [scene(ahead=10.0), scene(cls=B.STATIC), scene(ego_yaw=yaw + 0.3),
               scene(props=[(x + 8 * math.cos(yaw), y + 8 * math.sin(yaw), yaw, 4.6, 1.9)]),
               scene(lights=[0, 0]),  # the route's two lights red
               scene(route_plan=build_plan(SMOKE[3], load_net("town12")))]  # another route
    for inputs in changes:  # each differs from the scene in one thing
        assert np.array_equal(renderer.render(*scene()), first)
        n = len(drawn)
        out = renderer.render(*inputs)
        assert len(drawn) == n + 1
        assert np.array_equal(out, draw(*inputs))
        assert not np.array_equal(out, first)  # each change shows in the picture


@pytest.mark.slow
def test_smoke_run_on_two_workers_and_determinism(tmp_path, capsys):
    """The CI smoke run (town12_smoke on 2 workers), and the same run on 1 worker gives the
    same records and logs (wall time aside)."""
    two, one = tmp_path / "two", tmp_path / "one"
    assert main(["eval", "--routes", "town12_smoke", "--agent", "expert", "--workers", "2", "--out", str(two)]) == 0
    assert main(["eval", "--routes", "town12_smoke", "--agent", "expert", "--workers", "1", "--out", str(one)]) == 0
    recs = {r["key"]: r for r in _records(two)}
    assert sorted(recs) == ["0_rep0", "1_rep0", "2_rep0", "3_rep0"]
    assert all(r["episode_status"] == "Completed" and r["rc"] == 100.0 for r in recs.values())
    assert (two / "records.csv").read_text().count("\n") == 5
    assert (two / "summary.csv").is_file()
    written = json.loads((two / "results.json").read_text())
    assert written["entry_status"] == "Finished"
    assert written["_checkpoint"]["progress"] == [4, 4]
    assert rescore_results(written) == written  # the global record equals what `score` recomputes
    other = {r["key"]: r for r in _records(one)}
    for key, r in recs.items():
        a, b = dict(r), dict(other[key])
        for rec in (a, b):
            rec.pop("wall_time")
            rec["lb"] = {**rec["lb"], "meta": {**rec["lb"]["meta"], "duration_system": None}}
        assert a == b
        la, lb = np.load(two / "logs" / f"{key}.npz"), np.load(one / "logs" / f"{key}.npz")
        assert sorted(la.files) == sorted(lb.files)
        for f in la.files:
            np.testing.assert_array_equal(la[f], lb[f], err_msg=f"{key}:{f}")
    capsys.readouterr()
    assert main(["report", str(two), str(one), "--out", str(tmp_path / "report")]) == 0
    printed = capsys.readouterr().out
    assert "Table 3" in printed
    assert "Table 4" in printed
    assert "| two |" in printed
    assert "| one |" in printed
    assert (tmp_path / "report" / "table3.csv").is_file()
    assert (tmp_path / "report" / "table4.md").is_file()


def test_agent_crash_and_nan_fail_their_route_and_the_run_goes_on(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["eval", "--routes", "town12_smoke", "--agent", "tests.agents:FaultyFollower",
                 "--workers", "2", "--out", str(out)]) == 0
    recs = {r["route_id"]: r for r in _records(out)}
    assert recs["0"]["episode_status"] == "Completed"
    assert recs["3"]["episode_status"] == "Completed"
    assert recs["1"]["status"] == "Failed - Agent crashed"
    assert "on purpose" in recs["1"]["message"]
    assert recs["2"]["status"] == "Failed - Agent crashed"
    assert "non-finite" in recs["2"]["message"]


def test_killed_worker_is_recorded_and_the_run_completes(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("FAULTY_KILL", "1")  # inherited by the spawned workers
    out = tmp_path / "run"
    assert main(["eval", "--routes", "town12_smoke", "--agent", "tests.agents:FaultyFollower",
                 "--workers", "2", "--out", str(out)]) == 0
    recs = _records(out)
    assert sorted(r["route_id"] for r in recs) == ["0", "1", "2", "3"]
    dead = [r for r in recs if r["route_id"] == "3"][0]
    assert dead["status"] == "Failed - Simulation crashed"
    assert "exit code -9" in dead["message"]
    assert [r for r in recs if r["route_id"] == "0"][0]["episode_status"] == "Completed"


@pytest.mark.slow
def test_resume_after_a_killed_run_neither_repeats_nor_loses_a_route(tmp_path, capsys):
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "sumo_scimm.cli", "eval", "--routes", "town12_smoke", "--agent", "expert",
           "--workers", "1", "--out", str(out)]
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    rec = out / "records.jsonl"
    deadline = time.time() + 120
    while time.time() < deadline and not (rec.exists() and rec.read_text().count("\n") >= 1):
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)  # the parent and its worker, mid-run
    proc.wait()
    first = _records(out)
    assert 1 <= len(first) < 4
    assert main(["eval", "--routes", "town12_smoke", "--agent", "expert", "--workers", "2", "--out", str(out),
                 "--resume"]) == 0
    final = _records(out)
    assert sorted(r["key"] for r in final) == ["0_rep0", "1_rep0", "2_rep0", "3_rep0"]
    assert final[:len(first)] == first  # the routes run before the kill were kept, not redone


def test_existing_run_needs_resume(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "records.jsonl").write_text('{"key": "0_rep0"}\n')
    code = main(["eval", "--routes", "town12_smoke", "--out", str(out)])
    assert code == 2
    assert "--resume" in capsys.readouterr().err


@pytest.mark.parametrize("rid", ["40", "50"])
def test_the_hard_braking_leader_appears_gap_ahead_of_the_ego(short_routes, rid):
    """The leader enters the ego's lane about ``gap`` m ahead of it, as soon as there is such
    a place. The two hard cases: on route 40, gap m past the trigger lies inside a junction
    (a leader placed there is never spawned); on route 50, SUMO can defer the insertion, and
    a deferred leader appears 1.5 s later beside the ego, in the lane the route has left."""
    from harness.runs.jobs import route_seed

    idx = next(i for i, r in enumerate(short_routes) if r.id == rid)
    route = short_routes[idx]
    gap = float(route.hazards[0].params["gap"])
    first = []

    def on_frame(f):
        if first:
            return
        for k, i in enumerate(f.snap.ids):
            if i.endswith("_leader"):
                s_leader, off = f.plan.path.project(*f.snap.xy[k])
                s_ego, _ = f.plan.path.project(f.ego.x, f.ego.y)
                first.append((s_leader - s_ego, off))

    res = run_episode(route, "expert", None, route_seed(0, idx), on_frame=on_frame)
    assert res.status == "Completed"
    assert first, "the leader never appeared"
    ahead, off = first[0]
    # its front is placed gap m ahead of the ego's centre, so its centre (4.6 m long) 2.3 m
    # less; by the first frame that sees it, either has driven up to one tick (0.7 m at
    # 14 m/s), and its projection onto the route, 1.7 m off it, may move by 0.1 m. Measured:
    # gap - 2.21 (route 40), gap - 2.92 (route 50: the ego drove 0.6 m more than the leader).
    # It is on the lane nearest the route (route 50 is mid-way through a lane change there: 1.7 m)
    assert gap - 3.1 < ahead < gap - 1.6, (ahead, off)
    assert off < 2.0, (ahead, off)


def test_bev_rendering_starts_no_helper_threads():
    """A worker is one process per core: rendering must not leave OpenCV pool threads
    behind (they spin between frames, taking CPU from the other workers). Counted in a
    fresh interpreter, before and after 20 frames, from /proc (Linux)."""
    if not Path("/proc/self/task").is_dir():
        pytest.skip("needs /proc to count threads")
    if (os.cpu_count() or 1) < 2:
        pytest.skip("OpenCV starts no pool threads on one core: nothing to tell apart")
    code = """
import math, os, numpy as np
from controller.vehicle import EgoState
from harness.sensors import bev as B
from harness.sim.plan import build_plan
from harness.sim.stop_signs import stop_passages
from harness.sim.world import Snapshot
from scenarios import set_path
from scenarios.routefile import read_routes
from sumo_nets import load_net
route = read_routes(set_path("town12_smoke"))[1][0]
plan = build_plan(route, load_net("town12"))
renderer = B.BevRenderer.for_town("town12")
snap = Snapshot([], np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, 2)), np.zeros(0, int), math.nan)
before = len(os.listdir("/proc/self/task"))
for k in range(20):
    x, y, yaw = plan.path.pose(2.0 * k)
    renderer.render(EgoState(x, y, yaw, 0.0), snap, plan, [], [], [True] * len(stop_passages(plan)))
print(before, len(os.listdir("/proc/self/task")))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    before, after = map(int, out.stdout.split())
    assert after == before, f"rendering left {after - before} helper thread(s) running"
