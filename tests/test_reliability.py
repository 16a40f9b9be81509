"""Faults in real runs, interrupted runs, determinism and bad input (SPEC §12).

Already covered in test_closed_loop.py and not repeated here: an agent that raises or
returns NaN, a worker killed with SIGKILL, SIGKILL of the whole run then --resume,
--workers 1 vs 2. Bad route files and billion laughs: test_check.py.
"""
from __future__ import annotations

import contextlib
import csv
import io
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
from hypothesis import example, given, settings, strategies as st

from controller.vehicle import Control
from sumo_scimm.cli import main
from harness.loop.route_follower import RouteFollower
from harness.runs.evaluate import MAX_ROUTE_RUNS
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


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["sigint", "sigterm"])
def test_a_ctrl_c_or_sigterm_while_a_route_is_written_lands_after_its_files(signum):
    """The runner writes a route's record, worker line, records.csv and results.json under
    atomic.signals_held: a SIGINT (or a SIGTERM, which ``sumo-scimm`` turns into a
    Terminated exception) that arrives in between is raised only after the block (before,
    a Ctrl-C there left a record in records.jsonl that records.csv lacked)."""
    from harness.common.atomic import signals_held
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
from harness.common.atomic import savez_atomic
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
    assert "sumo-scimm: terminated (SIGTERM)" in err, err
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
    assert "sumo-scimm: interrupted" in err
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


# --- bad input ---------------------------------------------------------------------------
def _cli(argv: list[str]) -> tuple[int, str]:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        code = main(argv)
    return code, buf.getvalue()


def _not_int(s: str) -> bool:
    try:
        int(s)
    except ValueError:
        return True
    return False


def _not_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return True
    return False


_text = st.text(min_size=1, max_size=12)
_letters = st.text(alphabet="abcxyz_-:. ", min_size=1, max_size=10)
BAD_OPTIONS = st.one_of(
    st.tuples(st.sampled_from(["--workers", "--repetitions"]),
              st.one_of(st.integers(max_value=0).map(str), _text.filter(_not_int))),
    # more route runs than a run may hold (4 routes in the smoke set); refused at once
    st.tuples(st.just("--repetitions"), st.integers(min_value=MAX_ROUTE_RUNS // 4 + 1).map(str)),
    st.tuples(st.just("--seed"), st.one_of(st.integers(max_value=-1).map(str), _text.filter(_not_int))),
    st.tuples(st.just("--agent-timeout"),
              st.one_of(st.floats(max_value=0.0).map(repr), st.sampled_from(["nan", "inf", "-inf"]),
                        _text.filter(_not_float))),
    st.tuples(st.just("--routes-subset"),
              st.one_of(st.integers(min_value=4).map(str),  # the smoke set has routes 0-3
                        st.tuples(st.integers(4, 99), st.integers(4, 99)).map(lambda t: f"{t[0]}-{t[1]}"),
                        st.integers(4, 10**6).map(lambda i: f"0,{i}"),
                        st.tuples(st.integers(1, 3), st.integers(0, 3)).filter(lambda t: t[0] > t[1])
                        .map(lambda t: f"{t[0]}-{t[1]}"),  # reversed
                        st.integers(4, 10**400).map(lambda i: f"0,2-{i}"),  # a range is no escape
                        _letters)),  # the empty subset and " , " included
    st.tuples(st.just("--agent"), st.one_of(st.from_regex(r"zz[a-z]{1,8}", fullmatch=True),
                                            st.from_regex(r"zz[a-z]{1,8}:[A-Z][a-z]{1,6}", fullmatch=True),
                                            st.from_regex(r"harness\.agent:[A-Z][a-z]{1,6}X", fullmatch=True))),
    st.tuples(st.just("--backend"), _text.filter(lambda s: s not in ("local", "ray"))),
    st.tuples(st.just("--address"), st.from_regex(r"[a-z0-9.]{1,12}:[0-9]{1,5}", fullmatch=True)),  # no --backend ray
)
_EMPTY_SUBSETS = [("--routes-subset", v) for v in ("", ",", " , ")]


@settings(max_examples=60, deadline=None)
@given(option=BAD_OPTIONS, command=st.sampled_from(["eval", "collect"]))
@example(option=_EMPTY_SUBSETS[0], command="eval")  # once ran every route
@example(option=_EMPTY_SUBSETS[2], command="eval")
@example(option=("--repetitions", "1000000000"), command="eval")  # once built its job list for ever
@example(option=("--repetitions", "9" * 300), command="collect")
def test_bad_cli_values_are_one_line_exit_2_and_write_nothing(tmp_path_factory, option, command):
    name, value = option
    if command == "collect" and name in ("--agent", "--agent-timeout", "--routes-subset"):
        command = "eval"  # eval-only options
    out = tmp_path_factory.mktemp("bad") / "out"
    code, printed = _cli([command, "--routes", "town12_smoke", "--out", str(out), f"{name}={value}"])
    lines = [ln for ln in printed.splitlines() if ln.strip()]
    assert code == 2, printed
    assert len(lines) == 1, printed
    assert lines[0].startswith("sumo-scimm: error: "), printed
    assert "Traceback" not in printed
    assert len(lines[0]) < 300, printed  # a long number is cut
    assert not out.exists()


@pytest.mark.parametrize("argv", [
    ["nets", "build", "--town", "town12"], ["routes", "make", "--set", "town12_smoke"],
    ["eval", "--routes", "town12_smoke"], ["render", "--routes", "town12_smoke", "--route", "0", "--out", "x.mp4"],
    ["collect", "--routes", "town12_smoke", "--out", "x"]])
def test_negative_seed_is_refused_by_every_command(argv, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, printed = _cli([*argv, "--seed=-1"])
    lines = [ln for ln in printed.splitlines() if ln.strip()]
    assert code == 2, printed
    assert len(lines) == 1, printed
    assert "invalid seed -1: must be >= 0" in lines[0], printed
    assert not list(tmp_path.iterdir())


def _valid_results() -> dict:
    from tests.test_scoring import _carla_file
    return _carla_file()


_json = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
                     lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
                     max_leaves=12)


def _paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, prefix + (i,))


_ALL_PATHS = [p for p in _paths(_valid_results()) if p]


@settings(max_examples=120, deadline=None)
@given(where=st.sampled_from(_ALL_PATHS), value=_json, drop=st.booleans(), raw=st.one_of(st.none(), _text))
@example(where=("_checkpoint", "progress", 1), value=math.inf, drop=False, raw=None)  # int(inf) overflows
@example(where=("_checkpoint",), value=None, drop=False, raw="[" * 100_000)  # too deep for json
def test_score_of_a_damaged_results_file_is_a_clean_exit(tmp_path_factory, where, value, drop, raw):
    """Replace (or drop) any one field of a Leaderboard results file, or write junk: score
    either rescoring it (exit 0, complete JSON written) or one line and exit 2 with no
    output file; never a traceback."""
    data = _valid_results()
    if raw is not None:
        text = raw
    else:
        parent = data
        for k in where[:-1]:
            parent = parent[k]
        if drop and isinstance(parent, dict):
            del parent[where[-1]]
        else:
            parent[where[-1]] = value
        text = json.dumps(data)
    d = tmp_path_factory.mktemp("score")
    src, dst = d / "results.json", d / "rescored.json"
    src.write_text(text)
    code, printed = _cli(["score", str(src), "--out", str(dst)])
    assert "Traceback" not in printed
    assert code in (0, 2), printed
    if code == 2:
        lines = [ln for ln in printed.splitlines() if ln.strip()]
        assert len(lines) == 1, printed
        assert lines[0].startswith("sumo-scimm: error: "), printed
        assert not dst.exists()
    else:
        json.loads(dst.read_text())
    assert not list(d.glob("*.tmp"))
