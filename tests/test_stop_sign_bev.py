"""A stop sign is drawn in the BEV until the ego has made its stop (harness.sim.stop_signs):
the state by hand, the criterion reading the same state, and the closed loop, its log and the
dataset drawing it (real libsumo, the expert on town12_smoke's stop-sign route)."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from controller.vehicle import EgoState
from harness.expert.dataset import Episode
from harness.expert.driver import Expert
from harness.runs.jobs import Job, run_job
from harness.scoring.infractions import stop_signs
from harness.sensors import bev as B
from harness.sim.plan import build_plan
from harness.sim.stop_signs import (STOP_AFTER, STOP_BEFORE, STOP_SPEED, StopTracker, stop_history,
                                    stop_passages)
from harness.sim.world import Snapshot
from scenarios import set_path
from scenarios.routefile import read_routes
from sumo_nets import load_net

SMOKE = read_routes(set_path("town12_smoke"))[1]
STOP_ROUTE = SMOKE[1]  # town12_smoke's stop-sign route: one stop-sign passage (docs/world.md)


# the BEV's stop state at each agent tick of a whole log (the closed loop's StopTracker must agree)
def drawn_per_tick(s: np.ndarray, v: np.ndarray, s_in: np.ndarray) -> np.ndarray:
    """(T + 1, P) bool: whether each stop line is drawn at each of the T + 1 agent ticks
    around T logged ticks: row 0 before the first (all drawn), row k after tick k - 1."""
    drawn = stop_history(s, v, s_in).drawn
    return np.vstack([np.ones((1, drawn.shape[1]), bool), drawn])


def test_the_zone_and_speed_constants_are_the_documented_ones():
    assert (STOP_BEFORE, STOP_AFTER, STOP_SPEED) == (6.0, 1.0, 0.1)  # docs/scoring.md


def test_a_stop_line_is_drawn_until_the_first_tick_standing_in_its_zone():
    # stop line at 100 m: its zone is 94..101 m. Standing at 90 m (before the zone) does not
    # count; rolling through the zone does not; the first tick below 0.1 m/s in it (tick 6) does
    s = np.array([80.0, 90.0, 95.0, 96.0, 98.0, 100.0, 100.0, 100.5, 101.5, 120.0])
    v = np.array([5.0, 0.0, 3.0, 2.0, 1.0, 0.5, 0.05, 1.0, 3.0, 5.0])
    h = stop_history(s, v, np.array([100.0]))
    assert h.reached[:, 0].tolist() == [False, False, True, True, True, True, True, True, True, True]
    assert h.stopped[:, 0].tolist() == [False] * 6 + [True] * 4
    assert h.left[:, 0].tolist() == [False] * 8 + [True] * 2
    # the BEV of the tick after tick k: drawn through tick 5, gone from the tick after tick 6 on
    assert drawn_per_tick(s, v, np.array([100.0]))[:, 0].tolist() == [True] * 7 + [False] * 4


def test_a_stop_line_run_through_is_drawn_until_the_ego_leaves_its_zone():
    s = np.array([90.0, 95.0, 99.0, 101.0, 102.0, 110.0])
    v = np.full(6, 5.0)
    h = stop_history(s, v, np.array([100.0]))
    assert not h.stopped.any()
    assert h.left[:, 0].tolist() == [False] * 4 + [True] * 2  # 101.0 is the zone's last metre, 102.0 past it
    assert drawn_per_tick(s, v, np.array([100.0]))[:, 0].tolist() == [True] * 5 + [False] * 2


def test_zone_edges_and_the_speed_threshold_are_exact():
    s_in = np.array([100.0])
    one = lambda s, v: stop_history(np.array([s]), np.array([v]), s_in)  # noqa: E731
    assert one(94.0, 0.0).stopped[0, 0] and one(101.0, 0.0).stopped[0, 0]  # both edges in the zone
    assert not one(93.99, 0.0).stopped[0, 0] and not one(101.01, 0.0).stopped[0, 0]
    assert not one(100.0, 0.1).stopped[0, 0] and one(100.0, 0.0999).stopped[0, 0]  # strictly below 0.1 m/s
    assert not one(101.0, 5.0).left[0, 0] and one(101.0001, 5.0).left[0, 0]


def test_two_stop_lines_are_followed_apart_and_the_tracker_equals_the_history():
    s_in = np.array([100.0, 140.0])
    s = np.array([90.0, 96.0, 96.0, 110.0, 135.0, 139.0, 141.5, 150.0])
    v = np.array([5.0, 1.0, 0.0, 6.0, 6.0, 4.0, 5.0, 6.0])  # stops at the first, runs the second
    expected = np.array([[1, 1], [1, 1], [1, 1], [0, 1], [0, 1], [0, 1], [0, 1], [0, 0], [0, 0]], bool)
    np.testing.assert_array_equal(drawn_per_tick(s, v, s_in), expected)
    plan = SimpleNamespace(passages=[SimpleNamespace(state=st, s_in=x) for st, x in
                                     (("s", 100.0), ("M", 120.0), ("w", 140.0))])  # "M": not a stop sign
    tracker = StopTracker(plan)
    seen = [tracker.drawn]
    for sk, vk in zip(s, v):
        tracker.update(sk, vk)
        seen.append(tracker.drawn)
    np.testing.assert_array_equal(np.array(seen), expected)


def test_the_criterion_reads_the_same_state():
    plan = build_plan(STOP_ROUTE, load_net(STOP_ROUTE.town))
    (p,) = stop_passages(plan)
    s = np.array([p.s_in - 20, p.s_in - 3, p.s_in - 1, p.s_in + 5])
    log = {"route_index": np.searchsorted(plan.s, s).astype(float), "t": np.arange(4) * 0.05}
    assert stop_signs({**log, "v": np.array([5.0, 0.0, 2.0, 5.0])}, plan) == []  # stood in the zone
    ran = stop_signs({**log, "v": np.array([5.0, 2.0, 2.0, 5.0])}, plan)
    assert len(ran) == 1 and ran[0].startswith(f"Agent ran a stop with id={p.junction} at ")
    assert stop_signs({**log, "v": np.array([0.0, 2.0, 2.0, 5.0])}, plan) == ran  # stood before the zone only
    early = {k: a[:3] for k, a in log.items()}  # never left the zone: no verdict
    assert stop_signs({**early, "v": np.array([5.0, 2.0, 2.0])}, plan) == []


def test_the_renderer_draws_exactly_the_stop_lines_it_is_told_and_redraws_on_a_change(monkeypatch):
    plan = build_plan(STOP_ROUTE, load_net(STOP_ROUTE.town))
    (p,) = stop_passages(plan)
    x, y, yaw = plan.path.pose(p.s_in - 15.0)  # 15 m before the stop line
    ego = EgoState(x, y, yaw, 3.0)
    snap = Snapshot([], np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, 2)), np.zeros(0, int), math.nan)
    renderer = B.BevRenderer.for_town(STOP_ROUTE.town)
    calls = []
    draw = renderer.draw
    monkeypatch.setattr(renderer, "draw", lambda *a: calls.append(1) or draw(*a))
    on, off = renderer.render(ego, snap, plan, [], [], (True,)), renderer.render(ego, snap, plan, [], [], (False,))
    assert len(calls) == 2, "a changed stop state reused the last frame"
    rows = np.nonzero(on[B.STOPS])[0]
    # the line lies 15 m ahead: row 48 - 15 / 0.75 = 28, drawn 2 px thick (a lane end is
    # perpendicular to the route here, so +-2 rows)
    assert len(rows) > 0 and abs(rows.mean() - (B.EGO_ROW - 15.0 / B.RES)) <= 2.0
    assert not off[B.STOPS].any()  # and no line of the junction's other approaches
    np.testing.assert_array_equal(np.delete(on, B.STOPS, 0), np.delete(off, B.STOPS, 0))
    with pytest.raises(ValueError, match="stop states"):
        renderer.draw(ego, snap, plan, [], [], ())


class StopBevExpert(Expert):
    """The expert, also asking for the BEV and keeping every BEV it was given, in tick order."""

    bevs: list = []

    def sensors(self):
        return super().sensors() + [{"type": "bev", "id": "bev"}]

    def run_step(self, input_data, timestamp):
        StopBevExpert.bevs.append(input_data["bev"].copy())
        return super().run_step(input_data, timestamp)


def test_the_expert_stops_at_the_sign_and_then_the_bev_draws_it_no_more(tmp_path):
    StopBevExpert.bevs.clear()
    (tmp_path / "logs").mkdir()
    (tmp_path / "ep").mkdir()
    job = Job(1, STOP_ROUTE, 0, "tests.test_stop_sign_bev:StopBevExpert", None, 3, str(tmp_path / "logs"),
              collect_dir=str(tmp_path / "ep"), route_file=str(set_path("town12_smoke")))
    record = run_job(job)
    assert record["episode_status"] == "Completed", record
    assert record["stop_infraction"] == 0
    with np.load(tmp_path / "logs" / "1_rep0.npz") as z:
        log = {k: z[k] for k in z.files}
    bevs = StopBevExpert.bevs
    assert len(bevs) == len(log["scene_stops"]) == len(log["v"])
    plan = build_plan(STOP_ROUTE, load_net(STOP_ROUTE.town))
    (p,) = stop_passages(plan)
    s_ego = plan.s[log["route_index"].astype(int)]
    assert stop_signs(log, plan) == []
    # the closed loop's state is the criterion's state on its own log, tick by tick
    expected = drawn_per_tick(s_ego, log["v"], np.array([p.s_in]))[:-1]
    np.testing.assert_array_equal(log["scene_stops"].astype(bool), expected)
    stop = int(np.flatnonzero(~expected[:, 0])[0])  # the first BEV after the ego stood in the zone
    assert log["v"][stop - 1] < STOP_SPEED and s_ego[stop - 1] >= p.s_in - STOP_BEFORE
    drawn = [int((b[B.STOPS] > 0).sum()) for b in bevs]
    assert all(n > 0 for n in drawn[stop - 20:stop]), "the stop line was missing while the ego approached it"
    assert not any(drawn[stop:]), "a stop line was drawn after the stop was made"
    # the dataset keeps the state: its frames render the BEV the expert got at the next tick
    episode = Episode(tmp_path / "ep" / "1_rep0.npz")
    assert set(episode.a["stops"][:, 0].tolist()) == {0, 1}
    for k in range(len(episode)):
        tick = int(round(episode.a["t"][k] / 0.05))  # frame k holds the state after tick `tick`
        np.testing.assert_array_equal(episode.bev(k), bevs[tick], err_msg=f"frame {k}")


def test_an_episode_without_the_stop_state_names_the_fix(tmp_path):
    from harness.common.errors import BadInput
    episode = Episode.__new__(Episode)
    episode.a, episode.path = {"t": np.zeros(1)}, tmp_path / "old.npz"
    with pytest.raises(BadInput, match="collect the dataset again"):
        episode.bev(0)


def test_replay_refuses_a_log_from_before_the_stop_state_was_kept(tmp_path, capsys):
    from sumo_scimm.cli import main
    from tests.test_replay import _bare_run
    old = {k: np.zeros(1) for k in ("t", "v", "steer", "scene_t", "scene_ego", "scene_progress", "scene_lights",
                                    "scene_offset", "scene_xy", "scene_yaw", "scene_size", "scene_cls", "scene_props")}
    run = _bare_run(tmp_path, old)
    assert main(["replay", "--run", str(run), "--agent", "scimm", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no stop-sign state" in err[0] and "evaluate the reference again" in err[0], err
    assert not (tmp_path / "out").exists()
