"""The Ray backend (docs/design.md §10): on a local Ray with 2 CPUs, the same records and
logs as the local backend on town12_smoke, one process per route, the same crash records,
and an unreachable cluster is bad input; a two-node cluster started with docs/cluster.md's
commands (token authentication on) gives the local backend's records too."""
from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
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


def _assert_same_route_runs(local, ray, keys: list[str]) -> None:
    """The two run folders hold records (wall clock aside) and logs equal route by route."""
    a, b = _records(local), _records(ray)
    assert sorted(a) == keys
    assert sorted(b) == keys
    for key in keys:
        assert _without_wall_clock(a[key]) == _without_wall_clock(b[key]), key
        with np.load(local / "logs" / f"{key}.npz") as la, np.load(ray / "logs" / f"{key}.npz") as lb:
            assert sorted(la.files) == sorted(lb.files)
            for f in la.files:
                np.testing.assert_array_equal(la[f], lb[f], err_msg=f"{key}:{f}")


def test_ray_records_and_logs_equal_the_local_backends(tmp_path, capsys):
    local, ray = tmp_path / "local", tmp_path / "ray"
    common = ["eval", "--routes", "town12_smoke", "--agent", "route_follower", "--workers", "2"]
    assert main([*common, "--out", str(local)]) == 0
    assert main([*common, "--backend", "ray", "--out", str(ray)]) == 0
    _assert_same_route_runs(local, ray, KEYS)
    results = json.loads((ray / "results.json").read_text())
    assert results["entry_status"] == "Finished"
    assert results["_checkpoint"]["progress"] == [4, 4]
    # max_calls=1: every route ran in a process of its own
    pids = [json.loads(line)["pid"] for line in (ray / "workers.jsonl").read_text().splitlines()]
    assert len(pids) == 4
    assert len(set(pids)) == 4


def test_ray_records_agent_crashes_and_a_dead_worker_as_the_local_backend_does(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("FAULTY_KILL", "1")  # the local Ray, and so its workers, inherit it
    out = tmp_path / "run"
    assert main(["eval", "--routes", "town12_smoke", "--agent", "tests.agents:FaultyFollower",
                 "--workers", "2", "--backend", "ray", "--out", str(out)]) == 0
    recs = {r["route_id"]: r for r in _records(out).values()}
    assert sorted(r["key"] for r in recs.values()) == KEYS
    assert recs["0"]["episode_status"] == "Completed"
    assert recs["1"]["status"] == "Failed - Agent crashed"
    assert "on purpose" in recs["1"]["message"]
    assert recs["2"]["status"] == "Failed - Agent crashed"
    assert "non-finite" in recs["2"]["message"]
    dead = recs["3"]
    assert dead["status"] == "Failed - Simulation crashed"
    assert dead["message"].startswith("worker process died (")
    assert not (out / "logs" / "3_rep0.npz").exists()  # nothing came back from the dead worker


def test_unreachable_cluster_is_bad_input_and_writes_nothing(tmp_path):
    out = tmp_path / "run"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        code = main(["eval", "--routes", "town12_smoke", "--backend", "ray", "--address", "127.0.0.1:1",
                     "--out", str(out)])
    lines = [ln for ln in buf.getvalue().splitlines() if ln.strip()]
    assert code == 2, buf.getvalue()
    assert len(lines) == 1, buf.getvalue()
    assert "no Ray cluster answers there" in lines[0], buf.getvalue()
    assert not out.exists()


# --- a two-node cluster, as docs/cluster.md starts one -------------------------------------

CLI = "import sys; from sumo_scimm.cli import main; sys.exit(main(sys.argv[1:]))"  # what `sumo-scimm` runs
ALIVE_NODES = """import json, sys, time
import ray
ray.init(address=sys.argv[1], log_to_driver=False, logging_level="WARNING")
deadline = time.monotonic() + float(sys.argv[3])
while True:
    alive = sorted(n["NodeID"] for n in ray.nodes() if n["Alive"])
    if len(alive) >= int(sys.argv[2]) or time.monotonic() > deadline:
        break
    time.sleep(0.2)
print(json.dumps(alive))
"""
RAY_START_TIMEOUT = 120  # s for one `ray start` (a node starts in about 5 s)
DRIVER_TIMEOUT = 300  # s for the eval on the cluster (about 20 s)


def _ray_cli() -> str:
    here = Path(sys.executable).with_name("ray")
    return str(here) if here.exists() else shutil.which("ray") or pytest.skip("no `ray` command")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env(home: Path, **extra: str) -> dict[str, str]:
    """This process's environment, with its own home (so no ~/.ray/auth_token is shared by
    accident) and no Ray settings but ``extra``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    home.mkdir(parents=True, exist_ok=True)
    return {**env, "HOME": str(home), "RAY_USAGE_STATS_ENABLED": "0", **extra}


def _stop(groups: list[int]) -> None:
    """SIGKILL the processes of these process groups and their descendants (Ray runs each
    task worker in a group of its own, under its node's raylet)."""
    procs = {}  # pid -> (ppid, pgid)
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, ValueError, IndexError):
            fields = stat.read_text().rsplit(")", 1)[1].split()
            procs[int(stat.parent.name)] = (int(fields[1]), int(fields[2]))
    doomed = {pid for pid, (_, pgid) in procs.items() if pgid in groups}
    while True:
        more = {pid for pid, (ppid, _) in procs.items() if ppid in doomed} - doomed
        if not more:
            break
        doomed |= more
    for pgid in groups:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(pgid, signal.SIGKILL)
    for pid in doomed:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, signal.SIGKILL)
    deadline = time.monotonic() + 10  # gone (or a zombie) before the next test starts
    while time.monotonic() < deadline and any(_running(pid) for pid in doomed):
        time.sleep(0.1)


def _running(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def _run(cmd: list[str], env: dict, timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def two_node_cluster(tmp_path):
    """docs/cluster.md's commands on one machine: the head generates its token and starts
    with RAY_AUTH_MODE=token; a second node joins with RAY_AUTH_MODE=token and the token in
    RAY_AUTH_TOKEN (a home of its own: no token file). Each node has 1 CPU and a temporary
    folder of its own, so they are two Ray nodes. Yields (address, the joining side's
    environment, the alive node ids). Teardown stops this cluster's processes, even on failure:
    each `ray start` runs in a process group of its own, which its node's processes keep;
    killing those and their children is `ray stop --force` for this cluster only (`ray stop`
    would stop every Ray on the machine)."""
    ray_cli = _ray_cli()
    port = _free_port()
    address = f"127.0.0.1:{port}"
    groups: list[int] = []
    temps = [tempfile.mkdtemp(prefix="ssr-", dir="/tmp") for _ in range(2)]  # short: Ray's socket paths
    head_env = _env(tmp_path / "head_home", RAY_AUTH_MODE="token")

    def start(args: list[str], env: dict) -> None:
        proc = subprocess.Popen([ray_cli, "start", *args], env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True, start_new_session=True)
        groups.append(proc.pid)
        out, _ = proc.communicate(timeout=RAY_START_TIMEOUT)
        assert proc.returncode == 0, f"ray start {' '.join(args)}:\n{out}"

    try:
        gen = _run([ray_cli, "get-auth-token", "--generate"], head_env, 60)
        token = gen.stdout.strip()
        assert gen.returncode == 0, gen.stderr
        assert token, gen.stderr
        assert (tmp_path / "head_home" / ".ray" / "auth_token").read_text().strip() == token
        # --node-ip-address: every connection of the test's cluster stays on loopback
        start(["--head", "--port", str(port), "--node-ip-address", "127.0.0.1", "--num-cpus", "1",
               "--temp-dir", temps[0]], head_env)
        node_env = _env(tmp_path / "node_home", RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=token)
        start(["--address", address, "--node-ip-address", "127.0.0.1", "--num-cpus", "1", "--temp-dir", temps[1]],
              node_env)
        alive = _run([sys.executable, "-c", ALIVE_NODES, address, "2", "60"], node_env, 120)
        assert alive.returncode == 0, alive.stderr
        nodes = json.loads(alive.stdout.strip().splitlines()[-1])
        assert len(nodes) == 2, f"the second node did not join: {nodes}"
        yield address, node_env, nodes
    finally:
        _stop(groups)
        for d in temps:
            shutil.rmtree(d, ignore_errors=True)


@pytest.mark.slow
def test_two_node_cluster_from_the_docs_gives_the_local_backends_records(tmp_path, two_node_cluster):
    address, env, nodes = two_node_cluster
    routes = ["eval", "--routes", "town12_smoke", "--routes-subset", "0,1", "--agent", "route_follower"]
    keys = ["0_rep0", "1_rep0"]
    # a driver without the token is told so at once, in one line, and writes nothing
    t0 = time.monotonic()
    bare = _run([sys.executable, "-c", CLI, *routes, "--backend", "ray", "--address", address,
                 "--out", str(tmp_path / "no_token")], _env(tmp_path / "bare_home"), 60)
    lines = [ln for ln in (bare.stdout + bare.stderr).splitlines() if ln.strip()]
    assert bare.returncode == 2, lines
    assert len(lines) == 1, lines
    assert "RAY_AUTH_MODE=token" in lines[0], lines
    assert time.monotonic() - t0 < 30
    assert not (tmp_path / "no_token").exists()
    # with it, the routes run on both nodes (1 CPU each, 2 tasks at once: one on each) ...
    ray_out = tmp_path / "cluster"
    run = _run([sys.executable, "-c", CLI, *routes, "--backend", "ray", "--address", address,
                "--out", str(ray_out)], env, DRIVER_TIMEOUT)
    assert run.returncode == 0, run.stdout + run.stderr
    workers = [json.loads(line) for line in (ray_out / "workers.jsonl").read_text().splitlines()]
    assert sorted(w["key"] for w in workers) == keys
    assert sorted(w["node"] for w in workers) == nodes, workers
    # ... with the local backend's records, logs and route runs (seeds, routes, agent)
    local = tmp_path / "local"
    assert main([*routes, "--workers", "2", "--out", str(local)]) == 0
    _assert_same_route_runs(local, ray_out, keys)
    runs = [json.loads((out / "run.jsonc").read_text())["route_runs"] for out in (local, ray_out)]
    assert runs[0] == runs[1]
