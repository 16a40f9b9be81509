"""Replay (harness.runs.replay, harness.loop.scene_log): the BEV re-rendered from a run's log
equals the closed-loop BEV bit for bit, a run replayed with its own agent gives back
the outputs it logged, and students named by their checkpoint files are replayed each on
its own. Real libsumo and the shipped SC-IMM student (ONNX Runtime)."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from harness.loop.episode import run_episode
from harness.loop.scene_log import scene_at
from harness.runs.replay import route_digest
from harness.sensors.bev import VEHICLES, WALKERS, BevRenderer
from harness.sim.plan import build_plan
from model.agent import SHIPPED, ScimmStudent
from scenarios import set_path
from scenarios.routefile import read_routes
from sumo_nets import load_net
from sumo_scimm.cli import main

SMOKE_ROUTE = "2"  # town12_smoke's shortest route for the student (about 600 ticks), a pedestrian crossing


class BevRecordingStudent(ScimmStudent):
    """The shipped SC-IMM student, keeping every BEV it is given."""

    def setup(self, config):
        super().setup(config)
        self.bevs = []

    def run_step(self, input_data, timestamp):
        self.bevs.append(input_data["bev"].copy())
        return super().run_step(input_data, timestamp)


def _route(rid: str):
    return next(r for r in read_routes(set_path("town12_smoke"))[1] if r.id == rid)


def test_the_replayed_bev_equals_the_closed_loop_bev_bit_for_bit():
    route = _route(SMOKE_ROUTE)
    seen = {}
    res = run_episode(route, "tests.test_replay:BevRecordingStudent", None, seed=11,
                      on_frame=lambda f: seen.setdefault("agent", f.agent))
    log = res.log.arrays()
    bevs = seen["agent"].bevs
    assert res.status.startswith("Completed") or res.status == "Perfect", res.message
    assert len(bevs) == len(log["scene_t"]) == len(log["steer"]) == res.steps
    # a renderer of its own (nothing cached from the run), drawing every frame anew
    renderer, plan = BevRenderer(route.town), build_plan(route, load_net(route.town))
    differing = [t for t in range(len(bevs)) if not np.array_equal(_draw(renderer, log, t, plan), bevs[t])]
    assert differing == []
    # the frames hold what the log's actors draw: other vehicles and the crossing pedestrians
    assert any(b[VEHICLES].any() for b in bevs) and any(b[WALKERS].any() for b in bevs)
    # the scene of tick t is the state after tick t-1 (the log's x, y, yaw, v), the first the start
    after = np.stack([log["x"], log["y"], log["yaw"], log["v"]], axis=1)
    np.testing.assert_array_equal(log["scene_ego"][1:], after[:-1])
    assert log["scene_ego"][0, 3] == 0.0
    np.testing.assert_array_equal(log["scene_lights"][1:], log["tls"][:-1])


def _draw(renderer: BevRenderer, log: dict, t: int, plan) -> np.ndarray:
    """The BEV of tick t drawn anew from the log's scene."""
    sc = scene_at(log, t)
    return renderer.draw(sc.ego, sc.snap, plan, sc.lights, sc.props, sc.stops)


def test_a_run_replayed_with_its_own_agent_gives_back_its_logged_outputs(tmp_path, capsys):
    run, rep = tmp_path / "run", tmp_path / "replay"
    assert main(["eval", "--routes", "town12_smoke", "--routes-subset", SMOKE_ROUTE, "--agent", "scimm",
                 "--workers", "1", "--out", str(run)]) == 0
    assert main(["replay", "--run", str(run), "--agent", "scimm", "--agent", "baseline", "--workers", "1",
                 "--out", str(rep)]) == 0
    key = f"{SMOKE_ROUTE}_rep0"
    log = np.load(run / "logs" / f"{key}.npz")
    out = np.load(rep / "outputs" / f"{key}.npz")
    # the same network inputs bit for bit give the same network outputs; ONNX Runtime on one
    # thread is deterministic on one machine, so the tolerance (the runtime's rounding, 2e-5 m
    # between runtimes, docs/student.md) is there for nothing but another build of it
    np.testing.assert_allclose(out["a0_pred_path"], log["pred_path"], rtol=0, atol=2e-5)
    np.testing.assert_allclose(out["a0_pred_speed_wps"], log["pred_speed_wps"], rtol=0, atol=2e-5)
    for k in ("steer", "throttle", "brake"):
        np.testing.assert_allclose(out[f"a0_{k}"], log[k], rtol=0, atol=1e-5, err_msg=k)
    # the baseline got the same inputs and answered otherwise
    assert not np.allclose(out["a1_pred_path"], log["pred_path"], atol=1e-3)
    rows = {r["agent"]: r for r in csv.DictReader(open(rep / "replay.csv"))}
    record = next(csv.DictReader(open(run / "records.csv")))
    for k in ("steering_jerk_moving", "curvature_variation_wps", "speed_variation_kmh", "standing_share"):
        assert float(rows["scimm"][k]) == pytest.approx(float(record[k]), rel=1e-6), k
    table = (rep / "table.md").read_text()
    assert "| scimm | 1 |" in table and "| baseline | " in table
    assert json.loads((rep / "replay.json").read_text())["agents"] == ["scimm", "baseline"]
    # the same two students named by their checkpoint files (both are the agent 'student'):
    # each keeps its own network and controller, so the outputs are those of the replay by name
    by_path = tmp_path / "replay_by_path"
    ckpts = [str(SHIPPED / arm / "student.pt") for arm in ("scimm", "baseline")]
    assert main(["replay", "--run", str(run), "--agent", ckpts[0], "--agent", ckpts[1], "--workers", "1",
                 "--out", str(by_path)]) == 0
    again = np.load(by_path / "outputs" / f"{key}.npz")
    for name in out.files:
        np.testing.assert_array_equal(again[name], out[name], err_msg=name)


def _bare_run(tmp_path: Path, log: dict | None) -> Path:
    """A run folder of town12_smoke route 0 with a hand-made log (no closed loop)."""
    run = tmp_path / "run"
    (run / "logs").mkdir(parents=True)
    route = _route("0")
    (run / "run.json").write_text(json.dumps({"route_runs": {"0_rep0": {"route": route_digest(route)}}}))
    if log is not None:
        np.savez(run / "logs" / "0_rep0.npz", **log)
    return run


@pytest.mark.parametrize("agents, words", [(["expert"], "world"), (["scimm", "scimm"], "twice"),
                                           (["nope"], "unknown agent")])
def test_replay_refuses_agents_it_cannot_feed(tmp_path, capsys, agents, words):
    run = _bare_run(tmp_path, None)
    argv = ["replay", "--run", str(run), "--out", str(tmp_path / "out")]
    for a in agents:
        argv += ["--agent", a]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
    assert not (tmp_path / "out").exists()


def test_replay_refuses_a_log_without_scene_state(tmp_path, capsys):
    run = _bare_run(tmp_path, {"t": np.zeros(3), "v": np.zeros(3), "steer": np.zeros(3)})
    assert main(["replay", "--run", str(run), "--agent", "scimm", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no scene state" in err[0] and "evaluate the reference again" in err[0], err
    assert not (tmp_path / "out").exists()
    (run / "run.json").write_text(json.dumps({"route_runs": {"0_rep0": {"route": "0" * 16}}}))
    assert main(["replay", "--run", str(run), "--agent", "scimm", "--out", str(tmp_path / "out")]) == 2
    assert "--routes" in capsys.readouterr().err


def test_bench_checks_its_replay_reference_before_running(tmp_path, capsys):
    assert main(["bench", "--replay", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no logs/" in err[0], err
