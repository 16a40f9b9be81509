"""The Ray backend (SPEC §10, issue #9): on a local Ray with 2 CPUs, the same records and
logs as the local backend on town12_smoke, one process per route, the same crash records,
and an unreachable cluster is bad input."""
from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from sumo_scimm.cli import main
from tests.test_reliability import _without_wall_clock

pytest.importorskip("ray", reason="ray is not installed (pip install 'sumo-scimm[ray]'): "
                                  "the Ray backend cannot be tested")

KEYS = ["0_rep0", "1_rep0", "2_rep0", "3_rep0"]


def _records(out: Path) -> dict[str, dict]:
    recs = [json.loads(line) for line in (out / "records.jsonl").read_text().splitlines()]
    return {r["key"]: r for r in recs}


def test_ray_records_and_logs_equal_the_local_backends(tmp_path, capsys):
    local, ray = tmp_path / "local", tmp_path / "ray"
    common = ["eval", "--routes", "town12_smoke", "--agent", "route_follower", "--workers", "2"]
    assert main([*common, "--out", str(local)]) == 0
    assert main([*common, "--backend", "ray", "--out", str(ray)]) == 0
    a, b = _records(local), _records(ray)
    assert sorted(a) == sorted(b) == KEYS
    for key in KEYS:
        assert _without_wall_clock(a[key]) == _without_wall_clock(b[key]), key
        with np.load(local / "logs" / f"{key}.npz") as la, np.load(ray / "logs" / f"{key}.npz") as lb:
            assert sorted(la.files) == sorted(lb.files)
            for f in la.files:
                np.testing.assert_array_equal(la[f], lb[f], err_msg=f"{key}:{f}")
    results = json.loads((ray / "results.json").read_text())
    assert results["entry_status"] == "Finished" and results["_checkpoint"]["progress"] == [4, 4]
    # max_calls=1: every route ran in a process of its own
    pids = [json.loads(line)["pid"] for line in (ray / "workers.jsonl").read_text().splitlines()]
    assert len(pids) == 4 and len(set(pids)) == 4


def test_ray_records_agent_crashes_and_a_dead_worker_as_the_local_backend_does(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("FAULTY_KILL", "1")  # the local Ray, and so its workers, inherit it
    out = tmp_path / "run"
    assert main(["eval", "--routes", "town12_smoke", "--agent", "tests.agents:FaultyFollower",
                 "--workers", "2", "--backend", "ray", "--out", str(out)]) == 0
    recs = {r["route_id"]: r for r in _records(out).values()}
    assert sorted(r["key"] for r in recs.values()) == KEYS
    assert recs["0"]["episode_status"] == "Completed"
    assert recs["1"]["status"] == "Failed - Agent crashed" and "on purpose" in recs["1"]["message"]
    assert recs["2"]["status"] == "Failed - Agent crashed" and "non-finite" in recs["2"]["message"]
    dead = recs["3"]
    assert dead["status"] == "Failed - Simulation crashed" and dead["message"].startswith("worker process died (")
    assert not (out / "logs" / "3_rep0.npz").exists()  # nothing came back from the dead worker


def test_unreachable_cluster_is_bad_input_and_writes_nothing(tmp_path):
    out = tmp_path / "run"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        code = main(["eval", "--routes", "town12_smoke", "--backend", "ray", "--address", "127.0.0.1:1",
                     "--out", str(out)])
    lines = [ln for ln in buf.getvalue().splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and "no Ray cluster answers there" in lines[0], buf.getvalue()
    assert not out.exists()
