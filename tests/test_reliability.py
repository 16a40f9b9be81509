"""Faults in real runs, interrupted runs, determinism and bad input (docs/design.md §12).

Already covered in test_closed_loop.py and not repeated here: an agent that raises or
returns NaN, a worker killed with SIGKILL, SIGKILL of the whole run then --resume,
--workers 1 vs 2. Bad route files and billion laughs: test_check.py.
"""
from __future__ import annotations

import csv
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

from controller.vehicle import Control
from sumo_scimm.cli import main
from harness.loop.route_follower import RouteFollower
from harness.runs.runner import rss_summary

ROOT = Path(__file__).resolve().parents[1]
KEYS = ["0_rep0", "1_rep0", "2_rep0", "3_rep0"]


class Saboteur(RouteFollower):
    """Follows the route; after 2 s of game time, on route 0 it loads a corrupt net into
    libsumo (the path is its --agent-config) and drives on, so SUMO fails under the
    harness; on route 1 it returns an infinite throttle; on route 2 it sleeps 60 s."""

    def setup(self, config):
        super().setup(None)  # the follower's own defaults; config is the corrupt net's path
        self.corrupt_net = config

    def run_step(self, input_data, timestamp):
        control = super().run_step(input_data, timestamp)
        if timestamp > 2.0:
            rid = self.plan.route_id
            if rid == "0" and self.corrupt_net:
                try:
                    libsumo.load(["-n", self.corrupt_net, "--no-step-log", "true"])
                except libsumo.TraCIException:
                    pass  # SUMO has dropped its network: the harness's next step fails
                self.corrupt_net = None
            elif rid == "1":
                return Control(steer=control.steer, throttle=math.inf)
            elif rid == "2":
                time.sleep(60.0)
        return control


def _records(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "records.jsonl").read_text().splitlines()]


def _outputs_parse(out: Path) -> list[dict]:
    """Every output file of a run folder parses; returns the records."""
    recs = _records(out)
    for line in (out / "workers.jsonl").read_text().splitlines():
        assert {"key", "pid", "rss_mb"} <= set(json.loads(line))
    with open(out / "records.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert sorted(r["key"] for r in rows) == sorted(r["key"] for r in recs)
    results = json.loads((out / "results.json").read_text())
    assert len(results["_checkpoint"]["records"]) == len(recs)
    if (out / "summary.csv").exists():
        with open(out / "summary.csv", newline="") as f:
            assert list(csv.DictReader(f))
    assert not list(out.rglob("*.tmp"))
    assert not list(out.rglob("*.tmp.npz"))
    for log in (out / "logs").glob("*.npz"):
        with np.load(log) as z:
            assert "x" in z.files
    return recs


def _live_in_group(pgid: int) -> list[int]:
    """Processes of a process group that are still running (not zombies waiting for init)."""
    live = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()  # after "pid (comm)"
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            live.append(int(stat.parent.name))
    return live


def _without_wall_clock(rec: dict) -> dict:
    rec = dict(rec)
    rec.pop("wall_time")
    rec["lb"] = {**rec["lb"], "meta": {**rec["lb"]["meta"], "duration_system": None}}
    return rec


@pytest.mark.slow
def test_libsumo_error_inf_control_and_deadline_each_fail_their_route(tmp_path, capsys):
    """One worker runs all four routes: SUMO breaks on route 0, the agent returns inf on 1
    and sleeps past a 1 s deadline on 2; each is recorded with its reason, and the same
    worker then drives route 3 to the end (libsumo recovers after an error)."""
    net = (ROOT / "sumo_nets" / "nets" / "town12.net.xml").read_text()
    corrupt = tmp_path / "corrupt.net.xml"
    corrupt.write_text(net[: len(net) // 3])  # cut mid-element: not well-formed XML
    out = tmp_path / "run"
    assert main(["eval", "--routes", "town12_smoke", "--agent", "tests.test_reliability:Saboteur",
                 "--agent-config", str(corrupt), "--agent-timeout", "1", "--workers", "1",
                 "--out", str(out)]) == 0
    recs = {r["route_id"]: r for r in _outputs_parse(out)}
    assert sorted(r["key"] for r in recs.values()) == KEYS  # exactly one record each
    sim = recs["0"]
    assert sim["status"] == "Failed - Simulation crashed"
    assert sim["message"].startswith("FatalTraCIError: A network was not yet constructed")
    assert recs["1"]["status"] == "Failed - Agent crashed"
    assert "non-finite control" in recs["1"]["message"]
    assert recs["1"]["message"].count("inf") == 1
    late = recs["2"]
    assert late["status"] == "Failed - Agent crashed"
    assert late["message"] == "AgentTimeout: Agent took longer than 1s to send its command"
    assert late["wall_time"] < 60.0  # interrupted, not waited out
    # it hung on its first step after 2 s of SUMO time, the route's game time being the
    # ticks run: within 2 ticks (0.1 s) of 2 s
    assert abs(late["game_time"] - 2.0) <= 0.1
    assert recs["3"]["episode_status"] == "Completed"
    pids = {json.loads(line)["pid"] for line in (out / "workers.jsonl").read_text().splitlines()}
    assert len(pids) == 1  # no worker died: the failures were recorded inside it


def test_agent_setup_failure_is_recorded_as_such(tmp_path):
    """An agent whose setup raises ends before the first tick: "Failed - Agent couldn't be
    set up" with the reason, RC 0, an empty log (not a harness crash)."""
    from harness.runs.jobs import Job, run_job
    from scenarios import set_path
    from scenarios.routefile import read_routes
    config = tmp_path / "follower.json"
    config.write_text("{not json")
    route = read_routes(set_path("town12_smoke"))[1][0]
    rec = run_job(Job(0, route, 0, "route_follower", str(config), 5, str(tmp_path)))
    assert rec["status"] == "Failed - Agent couldn't be set up"
    assert rec["message"].startswith("JSONDecodeError")
    assert rec["rc"] == 0.0
    assert rec["steps"] == 0
    with np.load(tmp_path / "0_rep0.npz") as log:
        assert len(log["x"]) == 0
        assert log["tls"].shape == (0, 0)


def test_a_worker_that_ends_with_the_run_runs_its_agents_atexit_functions(tmp_path, monkeypatch):
    """A worker ends without the interpreter's teardown (harness.runs.workers), but what an
    agent registered with ``atexit`` still runs there: the agent of tests/exit_agent.py writes
    one line from the worker, with the ticks it drove (the route's steps)."""
    exit_file = tmp_path / "exit.txt"
    monkeypatch.setenv("AGENT_EXIT_FILE", str(exit_file))
    out = tmp_path / "run"
    assert main(["eval", "--routes", "town12_smoke", "--routes-subset", "0", "--workers", "1", "--out", str(out),
                 "--agent", "tests.exit_agent:WritesAtExit"]) == 0
    (rec,) = _outputs_parse(out)
    (worker,) = {json.loads(line)["pid"] for line in (out / "workers.jsonl").read_text().splitlines()}
    assert exit_file.read_text() == f"{worker} drove {rec['steps']} ticks\n"


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["sigint", "sigterm"])
def test_a_ctrl_c_or_sigterm_while_a_route_is_written_lands_after_its_files(signum):
    """The runner writes a route's record, worker line, records.csv and results.json under
    atomic.signals_held: a SIGINT (or a SIGTERM, which ``sumo-scimm`` turns into a
    Terminated exception) that arrives in between is raised only after the block (before,
    a Ctrl-C there left a record in records.jsonl that records.csv lacked)."""
    from files.atomic import signals_held
    from sumo_scimm.cli import Terminated, _raise_terminated
    done = []
    # Python's own Ctrl-C handler, also when this test runs where SIGINT is ignored
    handler, raised = ((signal.default_int_handler, KeyboardInterrupt) if signum == signal.SIGINT
                       else (_raise_terminated, Terminated))
    inherited = signal.signal(signum, handler)
    try:
        with pytest.raises(raised):
            with signals_held():
                os.kill(os.getpid(), signum)
                time.sleep(0.05)  # a delivered signal would raise here
                done.append("written")
        assert done == ["written"]
        assert signal.getsignal(signum) is handler  # restored
    finally:
        signal.signal(signum, inherited)


def test_a_worker_ended_while_it_writes_a_file_leaves_no_temporary_file(tmp_path):
    """A worker is ended by its parent with SIGTERM (default action); one that arrives
    while it writes a route log lands after the rename: the log is whole and no
    ``.tmp.npz`` is left (one left behind would mean a signal cut a write before its rename)."""
    code = f"""
import os, signal, sys
import numpy as np
from pathlib import Path
from files.atomic import savez_atomic
path = Path({str(tmp_path)!r}) / "0_rep0.npz"
write = np.savez_compressed
def stopped_midway(file, **arrays):  # the parent's SIGTERM arrives while the file is written
    os.kill(os.getpid(), signal.SIGTERM)
    write(file, **arrays)
np.savez_compressed = stopped_midway
savez_atomic(path, x=np.arange(1_000_000.0))
print("survived")  # not reached: the held SIGTERM ends the process after the rename
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == -signal.SIGTERM, proc.stderr
    assert "survived" not in proc.stdout, proc.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["0_rep0.npz"]
    with np.load(tmp_path / "0_rep0.npz") as z:
        np.testing.assert_array_equal(z["x"], np.arange(1_000_000.0))


def _stop_a_smoke_eval(out: Path, stop) -> tuple[int, str, list[dict]]:
    """Start ``eval`` on town12_smoke (2 workers, its own process group), call ``stop(proc)``
    once a route is recorded; returns the exit code, stderr and the records then, after
    checking that no worker outlived the parent."""
    cmd = [sys.executable, "-m", "sumo_scimm.cli", "eval", "--routes", "town12_smoke", "--agent", "route_follower",
           "--workers", "2", "--out", str(out)]
    # Ctrl-C as in a terminal: SIGINT at its default even when this test itself runs in a
    # background job, where the shell starts every process with SIGINT ignored
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    rec = out / "records.jsonl"
    deadline = time.time() + 180
    while time.time() < deadline and not (rec.exists() and rec.read_text().count("\n") >= 1):
        time.sleep(0.05)
    stop(proc)
    _, err = proc.communicate(timeout=60)
    deadline = time.time() + 30  # a worker mid-route is ended by its parent, not waited for
    while _live_in_group(proc.pid) and time.time() < deadline:
        time.sleep(0.1)
    assert not _live_in_group(proc.pid), "a worker process outlived the stopped run"
    return proc.returncode, err, _outputs_parse(out)


@pytest.mark.slow
def test_sigterm_ends_the_workers_and_the_run_resumes(tmp_path):
    """``kill PID`` (SIGTERM to the parent alone, as a scheduler stops a job) mid-run: the
    parent ends its workers and exits 143 with one line, no traceback from it or from a
    worker; every file parses and --resume finishes the run."""
    out = tmp_path / "run"
    code, err, first = _stop_a_smoke_eval(out, lambda proc: proc.send_signal(signal.SIGTERM))
    assert code == 143, err
    assert "sumo-scimm: terminated (SIGTERM); the same command with --resume goes on from here" in err, err
    assert "Traceback" not in err, err
    assert 1 <= len(first) < 4
    assert main(["eval", "--routes", "town12_smoke", "--agent", "route_follower", "--workers", "2",
                 "--out", str(out), "--resume"]) == 0
    assert sorted(r["key"] for r in _outputs_parse(out)) == KEYS


def test_a_stop_inside_a_reproduce_stage_ends_reproduce_as_stopped_not_as_a_failed_stage(tmp_path, monkeypatch, capsys):
    """reproduce runs each stage in-process: a SIGTERM (or Ctrl-C) that lands in a stage
    ends the whole command with 143 (130), not with 'stage failed' and exit 2."""
    import harness.runs.evaluate as evaluate
    import sumo_scimm.cli as cli

    def stopped(*args, **kwargs):
        raise cli.Terminated()
    monkeypatch.setattr(evaluate, "collect", stopped)
    assert main(["reproduce", "--out", str(tmp_path / "r"), "--seeds", "1"]) == 143
    err = capsys.readouterr().err
    assert "sumo-scimm: terminated (SIGTERM)" in err
    assert "failed" not in err


@pytest.mark.slow
def test_sigint_then_resume_finishes_the_run_as_an_uninterrupted_one(tmp_path, capsys):
    """Ctrl-C (SIGINT to the whole process group) mid-run: the parent ends its workers and
    exits 130; every file parses; --resume runs only the missing routes, and the records
    equal those of an uninterrupted run with the same seed."""
    out = tmp_path / "run"
    code, err, first = _stop_a_smoke_eval(out, lambda proc: os.killpg(proc.pid, signal.SIGINT))
    assert code == 130, err
    assert "sumo-scimm: interrupted; the same command with --resume goes on from here" in err
    assert "Traceback" not in err
    assert 1 <= len(first) < 4
    assert main(["eval", "--routes", "town12_smoke", "--agent", "route_follower", "--workers", "2",
                 "--out", str(out), "--resume"]) == 0
    final = _outputs_parse(out)
    assert sorted(r["key"] for r in final) == KEYS
    assert final[:len(first)] == first

    clean = tmp_path / "clean"
    assert main(["eval", "--routes", "town12_smoke", "--agent", "route_follower", "--workers", "1",
                 "--out", str(clean)]) == 0
    again = {r["key"]: _without_wall_clock(r) for r in _records(clean)}
    assert {r["key"]: _without_wall_clock(r) for r in final} == again
    # ... and the seed matters: another run seed drives route 0 differently
    other = tmp_path / "seed1"
    assert main(["eval", "--routes", "town12_smoke", "--routes-subset", "0", "--agent", "route_follower",
                 "--workers", "1", "--seed", "1", "--out", str(other)]) == 0
    with np.load(clean / "logs" / "0_rep0.npz") as a, np.load(other / "logs" / "0_rep0.npz") as b:
        n = min(len(a["x"]), len(b["x"]))
        assert not np.array_equal(a["x"][:n], b["x"][:n])
    # ... while --routes-subset reruns a route exactly as the full run drove it (its seed
    # comes from its place in the whole set)
    alone = tmp_path / "alone"
    assert main(["eval", "--routes", "town12_smoke", "--routes-subset", "2", "--agent", "route_follower",
                 "--workers", "1", "--out", str(alone)]) == 0
    with np.load(clean / "logs" / "2_rep0.npz") as a, np.load(alone / "logs" / "2_rep0.npz") as b:
        assert sorted(a.files) == sorted(b.files)
        for name in a.files:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)  # NaN == NaN here


def test_rss_summary_from_worker_samples(tmp_path):
    """Growth is last - first per worker (largest over workers); the trend is the
    least-squares slope, worked out by hand for two workers."""
    rows = [("a", 1, 1, 300.0), ("a", 1, 2, 302.0), ("a", 1, 3, 304.0),  # +2 MB/route -> 200 MB/100
            ("a", 2, 1, 310.0), ("a", 2, 2, 305.0)]  # growth -5, fewer than 3 samples: no trend
    (tmp_path / "workers.jsonl").write_text("".join(
        json.dumps({"key": f"{pid}_{n}", "host": h, "pid": pid, "routes": n, "rss_mb": mb}) + "\n"
        for h, pid, n, mb in rows) + '{"key": "torn')
    s = rss_summary(tmp_path)
    assert s == {"routes": 5, "workers": 2, "max_routes_per_worker": 3, "first_mb": 310.0, "peak_mb": 310.0,
                 "growth_mb": 4.0, "slope_mb_per_100": 200.0}
    assert rss_summary(tmp_path / "nowhere") is None
