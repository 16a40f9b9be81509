"""Hostile input and hostile agents on town12_smoke: nothing written outside --out, every
folder held, agents that cannot hang or end a run, damaged files refused with one line
(exit code 2), and one agent instance per worker plus one for the checks."""
from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest
import torch

from harness.common.errors import BadInput
from harness.common.lock import FolderLock
from harness.scoring.infractions import KEYS
from model.checkpoint import load_checkpoint
from scenarios.make import SETS_DIR
from sumo_scimm.cli import main

SMOKE = SETS_DIR / "town12_smoke.xml"
FOLLOW = ["--agent", "route_follower"]


def eval_argv(out: Path, *extra: str, subset: str = "0") -> list[str]:
    return ["eval", "--routes", "town12_smoke", "--routes-subset", subset, "--workers", "1", "--out", str(out),
            *extra]


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert err.startswith("sumo-scimm: error: ")
    return err


def files_under(root: Path) -> set[Path]:
    return {p for p in root.rglob("*")}


@pytest.fixture(scope="module")
def follower_run(tmp_path_factory) -> Path:
    """A finished route_follower run of route 0 (the damaged copies below start from it)."""
    out = tmp_path_factory.mktemp("follower") / "run"
    assert main(eval_argv(out, *FOLLOW)) == 0
    return out


# 1: route ids are file names -------------------------------------------------------------
@pytest.mark.parametrize("rid", ["../../../PWNED", "/tmp/h49x/ABS", "a/b", "x" * 300, ".hidden"])
def test_a_route_id_that_is_not_a_safe_file_name_is_refused_by_every_command(tmp_path, capsys, monkeypatch, rid):
    work = tmp_path / "deep" / "er"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    routes = work / "hostile.xml"
    routes.write_text(SMOKE.read_text().replace('<route id="0"', f'<route id="{rid}"', 1))
    before = files_under(tmp_path)
    for argv in (["routes", "check", str(routes)],
                 ["eval", "--routes", str(routes), *FOLLOW, "--workers", "1", "--out", str(work / "run")],
                 ["collect", "--routes", str(routes), "--workers", "1", "--out", str(work / "data")]):
        assert main(argv) == 2, argv
        shown = capsys.readouterr()
        assert "not a safe file name" in shown.out + shown.err and "Traceback" not in shown.err
    assert files_under(tmp_path) == before  # nothing written anywhere around the run
    assert not Path("/tmp/h49x").exists() and not (tmp_path / "PWNED_rep0.npz").exists()


def test_replay_refuses_a_run_whose_route_run_keys_are_paths(tmp_path, capsys, follower_run):
    run = tmp_path / "ref"
    shutil.copytree(follower_run, run)
    identity = json.loads((run / "run.jsonc").read_text())
    identity["route_runs"] = {"../../../PWNED_rep0": identity["route_runs"]["0_rep0"]}
    (run / "run.jsonc").write_text(json.dumps(identity))
    before = files_under(tmp_path)
    assert main(["replay", "--run", str(run), "--agent", "route_follower", "--out", str(tmp_path / "rep")]) == 2
    assert "not <route id>_rep<k>" in one_error_line(capsys)
    assert files_under(tmp_path) == before


# 2: every command that writes a folder holds it ------------------------------------------
@pytest.mark.parametrize("command", [
    ["replay", "--run", "{run}", "--agent", "route_follower"], ["report", "{run}"],
    ["eval", "--routes", "town12_smoke", *FOLLOW], ["collect", "--routes", "town12_smoke"],
    ["train", "--data", "{run}", "--teacher", "none"], ["reproduce", "--seeds", "1"],
    ["nets", "build", "--town", "town12"]])
def test_a_command_is_refused_on_a_folder_another_command_holds(tmp_path, capsys, follower_run, command):
    out = tmp_path / "held"
    with FolderLock(out):
        argv = [a.replace("{run}", str(follower_run)) for a in command]
        assert main([*argv, "--out", str(out)]) == 2
    assert "in use by another run" in one_error_line(capsys)
    assert not out.exists()  # the holder removed its folder; the refused command wrote nothing


# 3: a run folder removed and made again mid-run -----------------------------------------
def test_a_run_folder_replaced_mid_run_gets_no_file_of_the_old_run(tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    monkeypatch.setenv("RUN_DIR", str(out))
    monkeypatch.setenv("CHECK_PID", str(os.getpid()))
    assert main(eval_argv(out, "--agent", "tests.hostile_agents:ReplacesRunFolder", subset="0,1")) == 2
    assert "removed or replaced" in one_error_line(capsys)
    assert sorted(p.name for p in out.iterdir()) == ["other_run.txt"]


# 4: a results file of another run is never replaced -------------------------------------
def test_a_results_file_of_another_run_is_not_overwritten(tmp_path, capsys, follower_run):
    shared = tmp_path / "results.json"
    shutil.copy(follower_run / "results.json", shared)
    text = shared.read_text()
    assert main(eval_argv(tmp_path / "b", *FOLLOW, "--checkpoint", str(shared), subset="1")) == 2
    assert "already holds a results file" in one_error_line(capsys)
    other = tmp_path / "c"
    other.mkdir()
    shutil.copy(follower_run / "results.json", other / "results.json")
    assert main(eval_argv(other, *FOLLOW, subset="1")) == 2
    one_error_line(capsys)
    assert shared.read_text() == text == (other / "results.json").read_text()


# 5: a symlinked lock file is not followed -------------------------------------------------
def test_a_symlinked_run_lock_is_refused_and_its_target_kept(tmp_path, capsys):
    target = tmp_path / "precious.txt"
    target.write_text("keep me\n")
    out = tmp_path / "run"
    out.mkdir()
    (out / "run.lock").symlink_to(target)
    assert main(eval_argv(out, *FOLLOW)) == 2
    assert "symbolic link" in one_error_line(capsys)
    assert target.read_text() == "keep me\n"


# 6: --workers is bounded ------------------------------------------------------------------
@pytest.mark.parametrize("command", ["eval", "collect"])
def test_workers_beyond_two_per_core_are_refused(tmp_path, capsys, command):
    argv = ["--routes", "town12_smoke", "--workers", "100000", "--out", str(tmp_path / "x")]
    assert main([command, *argv]) == 2
    assert "at most" in one_error_line(capsys)
    assert not (tmp_path / "x").exists()


# 7: an agent that ends the process or raises KeyboardInterrupt while it is built ---------
@pytest.mark.parametrize("agent,code", [("tests.hostile_agents:ExitInInit", "0"),
                                        ("tests.hostile_agents:ExitInInit", "3"),
                                        ("tests.agent_exits_at_import:Agent", "0"),
                                        ("tests.hostile_agents:InterruptInInit", "0")])
def test_an_agent_that_exits_or_interrupts_while_built_is_one_line_naming_it(tmp_path, capsys, monkeypatch,
                                                                             agent, code):
    monkeypatch.setenv("EXIT_CODE", code)
    assert main(eval_argv(tmp_path / "run", "--agent", agent)) == 2
    assert f"agent {agent!r}" in one_error_line(capsys)
    assert not (tmp_path / "run").exists()


# 8 and "one agent, built once": sensors() checked after setup(), before any route --------
@pytest.mark.parametrize("agent,words", [("SensorsRaise", "no sensors today"), ("Sensors42", "returned 42"),
                                         ("SensorWithoutType", "needs a 'type'")])
def test_a_bad_sensors_spec_is_refused_before_the_first_route(tmp_path, capsys, agent, words):
    assert main(eval_argv(tmp_path / "run", "--agent", f"tests.hostile_agents:{agent}")) == 2
    err = one_error_line(capsys)
    assert "sensors()" in err and words in err
    assert not (tmp_path / "run").exists()


def test_sensors_that_fail_in_a_worker_fail_the_route_and_the_run_goes_on(tmp_path, monkeypatch):
    monkeypatch.setenv("CHECK_PID", str(os.getpid()))
    out = tmp_path / "run"
    assert main(eval_argv(out, "--agent", "tests.hostile_agents:SensorsFailInWorker", subset="0,1")) == 0
    recs = [json.loads(line) for line in (out / "records.jsonl").read_text().splitlines()]
    assert [r["status"] for r in recs] == ["Failed - Agent couldn't be set up"] * 2


def test_sensors_are_asked_after_setup_and_a_one_import_agent_runs(tmp_path):
    assert main(eval_argv(tmp_path / "a", "--agent", "tests.hostile_agents:SensorsAfterSetup")) == 0
    assert main(eval_argv(tmp_path / "b", "--agent", "tests.one_import_agent:Walker")) == 0
    (rec,) = [json.loads(line) for line in (tmp_path / "b" / "records.jsonl").read_text().splitlines()]
    assert rec["steps"] > 0 and rec["episode_status"] != "Failed - Agent crashed"


def test_the_agent_is_built_once_per_worker_and_once_for_the_checks(tmp_path, monkeypatch):
    count = tmp_path / "built.txt"
    monkeypatch.setenv("AGENT_COUNT", str(count))
    argv = ["eval", "--routes", "town12_smoke", "--workers", "2", "--agent", "tests.hostile_agents:Counted",
            "--out", str(tmp_path / "run")]
    assert main(argv) == 0
    pids = count.read_text().split()
    assert len(pids) == 2 + 1 and pids[0] == str(os.getpid())  # the checks, then one per worker


def test_replay_builds_the_agent_once_for_its_checks_and_once_in_its_worker(tmp_path, monkeypatch, follower_run):
    """--workers 1 replays in one worker process (watched by this one, as eval's)."""
    count = tmp_path / "built.txt"
    monkeypatch.setenv("AGENT_COUNT", str(count))
    assert main(["replay", "--run", str(follower_run), "--agent", "tests.hostile_agents:Counted", "--workers", "1",
                 "--out", str(tmp_path / "rep")]) == 0
    pids = count.read_text().split()
    assert len(pids) == 2 and pids[0] == str(os.getpid()) != pids[1]


# 9: hanging agents -------------------------------------------------------------------------
TIMEOUT = 2.0  # --agent-timeout of these runs [s]


def test_agents_hanging_in_any_way_end_their_routes_and_the_run_goes_on(tmp_path, monkeypatch):
    """Route 0 ignores SIGALRM, 1 cancels the alarm, 2 swallows the interruption, 3 hangs in
    setup; repetition 1 of the routes hangs the same way. Each hung route is recorded
    within --agent-timeout + 10 s of its start (the parent's watchdog)."""
    monkeypatch.setenv("CHECK_PID", str(os.getpid()))
    for rid, how in zip("0123", ("ignore", "cancel", "swallow", "setup")):
        monkeypatch.setenv(f"HANG_{rid}", how)
    out = tmp_path / "run"
    t0 = time.monotonic()
    assert main(["eval", "--routes", "town12_smoke", "--workers", "2", "--agent", "tests.hostile_agents:Hang",
                 "--agent-timeout", str(TIMEOUT), "--out", str(out)]) == 0
    wall = time.monotonic() - t0
    recs = [json.loads(line) for line in (out / "records.jsonl").read_text().splitlines()]
    assert sorted(r["route_id"] for r in recs) == list("0123")
    assert all(r["status"] == "Failed - Agent crashed" for r in recs)
    # two workers, four hung routes: two rounds, each within the timeout + 10 s (start-up included)
    assert wall < 2 * (TIMEOUT + 10) + 10, wall


@pytest.mark.parametrize("agent,env", [("HangInInit", {}), ("Hang", {"HANG_0": "sensors"}),
                                       ("Hang", {"HANG_0": "destroy"})])
def test_an_agent_hanging_outside_run_step_ends_its_route_in_time(tmp_path, monkeypatch, agent, env):
    monkeypatch.setenv("CHECK_PID", str(os.getpid()))
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    out = tmp_path / "run"
    t0 = time.monotonic()
    assert main(eval_argv(out, "--agent", f"tests.hostile_agents:{agent}", "--agent-timeout", str(TIMEOUT))) == 0
    assert time.monotonic() - t0 < TIMEOUT + 10 + 8  # + 8 s: starting the worker and driving route 0
    (rec,) = [json.loads(line) for line in (out / "records.jsonl").read_text().splitlines()]
    assert rec["status"] == "Failed - Agent crashed" and "took longer than 2s" in rec["message"]


def test_a_ray_task_whose_agent_hangs_ends_and_the_run_goes_on(tmp_path, monkeypatch):
    """Under --backend ray the task's own watch thread ends its process: the route is
    recorded as its worker's death, the run goes on."""
    pytest.importorskip("ray", reason="ray is not installed")
    monkeypatch.setenv("CHECK_PID", str(os.getpid()))
    monkeypatch.setenv("HANG_0", "ignore")
    out = tmp_path / "run"
    assert main(eval_argv(out, "--agent", "tests.hostile_agents:Hang", "--agent-timeout", str(TIMEOUT),
                          "--backend", "ray", subset="0,1")) == 0
    recs = {r["key"]: r for r in map(json.loads, (out / "records.jsonl").read_text().splitlines())}
    assert recs["0_rep0"]["status"] == "Failed - Simulation crashed"
    assert "worker process died" in recs["0_rep0"]["message"]
    assert recs["1_rep0"]["status"] != "Failed - Simulation crashed"


def test_replay_ends_an_agent_hanging_in_run_step_and_keeps_the_other_agents_rows(tmp_path):
    """Route 0 of a two-route reference: the hanging agent ignores SIGALRM and sleeps in
    run_step. The replay, run as its own process (a hang fails the test by the subprocess
    timeout instead of hanging it), ends within --agent-timeout + 10 s for the hung route
    plus 30 s for the rest (start-up, checks, replaying the two routes: about 15 s on 2
    cores); the hung agent's row of route 0 says so, every other row has metrics."""
    ref, rep = tmp_path / "ref", tmp_path / "rep"
    assert main(eval_argv(ref, *FOLLOW, subset="0,1")) == 0
    script = ("import os, sys; os.environ['CHECK_PID'] = str(os.getpid()); from sumo_scimm.cli import main; "
              "sys.exit(main(sys.argv[1:]))")
    argv = ["replay", "--run", str(ref), "--agent", "tests.hostile_agents:Hang", "--agent", "route_follower",
            "--workers", "2", "--agent-timeout", str(TIMEOUT), "--out", str(rep)]
    env = {**os.environ, "HANG_0": "ignore", "PYTHONPATH": str(Path(__file__).resolve().parent.parent)}
    t0 = time.monotonic()
    done = subprocess.run([sys.executable, "-c", script, *argv], env=env, capture_output=True, text=True,
                          timeout=TIMEOUT + 10 + 30)
    wall = time.monotonic() - t0
    assert done.returncode == 0, done.stderr[-2000:]
    rows = {(r["key"], r["agent"]): r for r in csv.DictReader(open(rep / "replay.csv"))}
    assert sorted(rows) == [(k, a) for k in ("0_rep0", "1_rep0")
                            for a in ("route_follower", "tests.hostile_agents:Hang")]
    hung = rows["0_rep0", "tests.hostile_agents:Hang"]
    assert "took longer than 2s" in hung["message"] and hung["steering_jerk_moving"] == "nan"
    for key, agent in rows:
        if (key, agent) != ("0_rep0", "tests.hostile_agents:Hang"):
            assert rows[key, agent]["message"] == "" and float(rows[key, agent]["steering_jerk_moving"]) >= 0
    assert int(hung["ticks"]) == int(rows["0_rep0", "route_follower"]["ticks"]) > 0
    assert wall < TIMEOUT + 10 + 30, wall


# 10: --resume on a damaged records.jsonl -------------------------------------------------
@pytest.mark.parametrize("damage,words", [
    (lambda line: line.replace('"ds": ', '"ds": "abc", "x": ', 1), "unknown field"),
    (lambda line: line.replace('"ds": ', '"ds": 0, "ds": ', 1), "appears twice"),
    (lambda line: json.dumps({**json.loads(line), "ds": "abc"}), "'abc', not a number"),
    (lambda line: json.dumps({**json.loads(line), "ds": 1e9}), "outside [0, 100]"),
    (lambda line: json.dumps({**json.loads(line), "collisions_vehicle": -1}), "collisions_vehicle")])
def test_resume_refuses_a_damaged_records_line_with_one_line(tmp_path, capsys, follower_run, damage, words):
    out = tmp_path / "run"
    shutil.copytree(follower_run, out)
    path = out / "records.jsonl"
    path.write_text(damage(path.read_text().splitlines()[0]) + "\n")
    text = path.read_text()
    assert main(eval_argv(out, *FOLLOW, "--resume")) == 2
    err = one_error_line(capsys)
    assert "line 1" in err and words in err
    assert path.read_text() == text


# 11: report on negative figures ------------------------------------------------------------
@pytest.mark.parametrize("column", ["collisions_vehicle", "steering_jerk_moving"])
def test_report_refuses_negative_counts_and_jerks(tmp_path, capsys, follower_run, column):
    run = tmp_path / "run"
    shutil.copytree(follower_run, run)
    head, row = (run / "records.csv").read_text().splitlines()
    cells = row.split(",")
    cells[head.split(",").index(column)] = "-5"
    (run / "records.csv").write_text(head + "\n" + ",".join(cells) + "\n")
    assert main(["report", str(run), "--out", str(tmp_path / "rep")]) == 2
    assert column in one_error_line(capsys)


def test_report_refuses_records_that_are_not_a_list(tmp_path, capsys, follower_run):
    run = tmp_path / "run"
    shutil.copytree(follower_run, run)
    data = json.loads((run / "results.json").read_text())
    data["_checkpoint"]["records"] = "x"
    (run / "results.json").write_text(json.dumps(data))
    assert main(["report", str(run), "--out", str(tmp_path / "rep")]) == 2
    assert "not a list" in one_error_line(capsys)


# 12: a damaged checkpoint ------------------------------------------------------------------
SCIMM = Path(__file__).resolve().parent.parent / "model" / "checkpoints" / "scimm"


def test_a_checkpoint_with_flipped_bits_is_refused_by_its_crc(tmp_path):
    """200 sign bits of the largest tensor flipped in place: the zip's CRC no longer matches."""
    path = tmp_path / "student.pt"
    shutil.copy(SCIMM / "student.pt", path)
    with zipfile.ZipFile(path) as z:
        info = max((i for i in z.infolist() if "/data/" in i.filename), key=lambda i: i.file_size)
    data = bytearray(path.read_bytes())
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    for k in range(200):  # little-endian float32: the sign bit is bit 7 of byte 3
        data[start + 4 * k + 3] ^= 0x80
    path.write_bytes(bytes(data))
    with pytest.raises(BadInput, match="CRC"):
        load_checkpoint(path)


def test_a_checkpoint_whose_weights_differ_from_its_manifest_hash_is_refused(tmp_path):
    """The same change written as a valid archive (CRCs right): the content hash catches it."""
    blob = torch.load(SCIMM / "student.pt", map_location="cpu", weights_only=True)
    name = max(blob["state_dict"], key=lambda k: blob["state_dict"][k].numel())
    blob["state_dict"][name].view(-1)[:200] *= -1
    torch.save(blob, tmp_path / "student.pt")
    shutil.copy(SCIMM / "manifest.json", tmp_path / "manifest.json")
    with pytest.raises(BadInput, match="weights_sha256"):
        load_checkpoint(tmp_path / "student.pt")
    load_checkpoint(SCIMM / "student.pt")  # the shipped one passes


# 13: the minor ones -------------------------------------------------------------------------
def test_a_malformed_prediction_is_the_agents_crash_and_a_destroy_error_is_recorded(tmp_path, monkeypatch):
    monkeypatch.setenv("CHECK_PID", str(os.getpid()))
    assert main(eval_argv(tmp_path / "a", "--agent", "tests.hostile_agents:BadPrediction")) == 0
    (rec,) = [json.loads(line) for line in (tmp_path / "a" / "records.jsonl").read_text().splitlines()]
    assert rec["status"] == "Failed - Agent crashed" and "(20, 2)" in rec["message"]
    assert main(eval_argv(tmp_path / "b", "--agent", "tests.hostile_agents:DestroyRaises")) == 0
    (rec,) = [json.loads(line) for line in (tmp_path / "b" / "records.jsonl").read_text().splitlines()]
    assert "destroy() raised RuntimeError: destroy failed on purpose" in rec["message"]


def test_episodes_without_a_record_are_refused_by_data_show_and_the_teacher(tmp_path, capsys):
    out = tmp_path / "data"
    assert main(["collect", "--routes", "town12_smoke", "--workers", "1", "--out", str(out)]) == 0
    capsys.readouterr()
    lines = (out / "records.jsonl").read_text().splitlines()
    (out / "records.jsonl").write_text("\n".join(lines[:-1]) + "\n")  # as if killed before the last record
    (out / "index.csv").unlink()
    assert main(["data", "show", str(out)]) == 2
    assert "has no record" in one_error_line(capsys)
    from scimm.teacher import episode_files
    with pytest.raises(BadInput, match="has no record"):
        episode_files(out)


def test_a_set_seed_that_is_not_an_integer_and_an_empty_out_are_refused(tmp_path, capsys):
    routes = tmp_path / "nan.xml"
    routes.write_text(SMOKE.read_text().replace("<routes ", '<routes seed="nan" ', 1))
    assert main(["routes", "check", str(routes)]) != 0
    assert main(["eval", "--routes", str(routes), *FOLLOW, "--out", str(tmp_path / "r")]) == 2
    assert "seed" in one_error_line(capsys)
    assert main(["eval", "--routes", "town12_smoke", *FOLLOW, "--out", ""]) == 2
    assert "empty" in one_error_line(capsys)


@pytest.mark.parametrize("argv", [
    ["reproduce"], ["routes", "make", "--set", "town12_smoke", "--seed", "5"], ["nets", "build", "--town", "town01"],
    ["train", "--data", "d", "--val", "v", "--teacher", "none"], ["train", "curves", "--runs", "a=b"],
    ["render", "--routes", "town12_smoke", "--route", "0"], ["score", "results.json"],
    ["teacher", "plot", "--data", "d", "--episode", "0_rep0"]], ids=lambda a: " ".join(a[:2]))
def test_an_empty_out_is_refused_by_every_command_before_it_writes(tmp_path, capsys, monkeypatch, argv):
    """An unset shell variable (--out "$DIR") must not name the current folder, or fall back
    to a shipped file (routes make's route set, nets build's town)."""
    monkeypatch.chdir(tmp_path)
    assert main([*argv, "--out", ""]) == 2
    line = one_error_line(capsys)
    assert "--out" in line and "is empty: give a path" in line, line
    assert list(tmp_path.iterdir()) == []


# the leaderboard's merge_statistics.py reads every infraction key of every record --------
def _merge_statistics_global_counts(records: list[dict]) -> dict[str, int]:
    """What the leaderboard's StatisticsManager.compute_global_statistics does with the
    records merge_statistics.py passes it: ``len(record['infractions'][key])`` for each of
    its infraction keys (a KeyError on a record that lacks one)."""
    return {key: sum(len(r["infractions"][key]) for r in records) for key in KEYS}


def test_score_refuses_a_record_without_an_infraction_key_that_merge_statistics_needs(tmp_path, capsys,
                                                                                      follower_run):
    data = json.loads((follower_run / "results.json").read_text())
    _merge_statistics_global_counts(data["_checkpoint"]["records"])  # what score accepts, merge reads
    del data["_checkpoint"]["records"][0]["infractions"]["red_light"]
    with pytest.raises(KeyError):
        _merge_statistics_global_counts(data["_checkpoint"]["records"])
    path = tmp_path / "results.json"
    path.write_text(json.dumps(data))
    assert main(["score", str(path)]) == 2
    assert "'red_light'" in one_error_line(capsys)


# 14: an agent's process-wide changes ---------------------------------------------------------
def _smoke_eval(out: Path, agent: str, *extra: str) -> subprocess.Popen:
    """``eval`` of town12_smoke with a hostile agent, in its own process group."""
    return subprocess.Popen([sys.executable, "-m", "sumo_scimm.cli", "eval", "--routes", "town12_smoke",
                             "--agent", f"tests.hostile_agents:{agent}", "--workers", "1", "--out", str(out), *extra],
                            start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})


def test_an_agent_whose_atexit_function_hangs_cannot_hang_the_end_of_a_run(tmp_path):
    """The worker's agent registers an atexit function that never returns: the run still
    ends (the worker is killed EXIT_GRACE = 5 s after it was told to stop), whole, and no
    process of it is left."""
    from tests.test_reliability import _live_in_group
    out = tmp_path / "run"
    proc = _smoke_eval(out, "AtexitHang", "--routes-subset", "0")
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert json.loads((out / "results.json").read_text())["entry_status"] == "Finished"
    deadline = time.time() + 15
    while _live_in_group(proc.pid) and time.time() < deadline:
        time.sleep(0.1)
    assert not _live_in_group(proc.pid), "the worker outlived the run"


def test_sigterm_ends_a_run_whose_agent_ignores_sigterm(tmp_path):
    """The worker's agent ignores SIGTERM: a SIGTERM to the run ends it all the same (the
    worker is killed after EXIT_GRACE), exit 143 with its one line, no process left."""
    from tests.test_reliability import _live_in_group
    out = tmp_path / "run"
    proc = _smoke_eval(out, "IgnoresTerm")
    rec, deadline = out / "records.jsonl", time.time() + 180
    while time.time() < deadline and not (rec.exists() and rec.read_text().count("\n") >= 1):
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert "sumo-scimm: terminated (SIGTERM)" in err and "Traceback" not in err, err
    deadline = time.time() + 15
    while _live_in_group(proc.pid) and time.time() < deadline:
        time.sleep(0.1)
    assert not _live_in_group(proc.pid), "the worker outlived the run"


def test_an_agent_message_with_undecodable_bytes_is_recorded_and_the_run_goes_on(tmp_path, monkeypatch):
    """An agent error naming a file whose name holds the byte 0xff (a lone surrogate in
    Python): the route is the agent's crash, every file is written (the byte as \\udcff)
    and the next route runs."""
    monkeypatch.setenv("CHECK_PID", str(os.getpid()))
    out = tmp_path / "run"
    assert main(eval_argv(out, "--agent", "tests.hostile_agents:UndecodableMessage", subset="0,1")) == 0
    rows = list(csv.DictReader((out / "records.csv").open(encoding="utf-8")))
    assert [r["status"] for r in rows] == ["Failed - Agent crashed"] * 2
    assert "/tmp/weights-\\udcff.bin" in rows[0]["message"]
    assert json.loads((out / "results.json").read_text())["entry_status"] == "Finished"


def test_an_agent_that_changes_its_working_folder_does_not_stop_a_run_with_a_relative_out(tmp_path, monkeypatch):
    monkeypatch.setenv("CHECK_PID", str(os.getpid()))
    monkeypatch.setenv("AGENT_FOLDER", str(tmp_path / "elsewhere"))
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path)
    assert main(eval_argv(Path("rel"), "--agent", "tests.hostile_agents:ChangesFolder", subset="0,1")) == 0
    assert sorted(p.name for p in (tmp_path / "rel" / "logs").iterdir()) == ["0_rep0.npz", "1_rep0.npz"]
    assert not any((tmp_path / "elsewhere").iterdir())


def test_an_agent_cannot_move_the_route_it_is_scored_on(tmp_path, monkeypatch):
    """The agent edits its plan's arc lengths to say the route is driven, then stands: its
    plan is its own copy, so the route is not completed (it stands: blocked after 180 s)."""
    monkeypatch.setenv("CHECK_PID", str(os.getpid()))
    out = tmp_path / "run"
    assert main(eval_argv(out, "--agent", "tests.hostile_agents:EditsThePlan")) == 0
    (rec,) = [json.loads(line) for line in (out / "records.jsonl").read_text().splitlines()]
    assert rec["status"] == "Failed - Agent got blocked" and rec["rc"] == 0.0, rec


@pytest.mark.parametrize("encoding", ["bogus-enc", "shift_jis", "utf-32", "rot13", "idna", "punycode"])
def test_a_route_file_declaring_an_encoding_python_cannot_decode_is_one_line(tmp_path, capsys, encoding):
    routes = tmp_path / "enc.xml"
    routes.write_text(SMOKE.read_text().replace('encoding="UTF-8"', f'encoding="{encoding}"', 1))
    assert f'encoding="{encoding}"' in routes.read_text()
    assert main(["routes", "check", str(routes)]) == 2
    err = capsys.readouterr()
    lines = (err.out + err.err).strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in lines[0] and "save it as UTF-8" in lines[0], lines
    assert main(["eval", "--routes", str(routes), *FOLLOW, "--out", str(tmp_path / "r")]) == 2
    assert "save it as UTF-8" in one_error_line(capsys)
    assert not (tmp_path / "r").exists()


def test_an_error_message_is_one_line_however_many_lines_or_characters_it_holds():
    """Line breaks become ' | '; past 600 characters the message keeps its first 300 and last
    250 (where the fix is): 5,007 characters -> 300 + the cut's note + 250."""
    from sumo_scimm.cli import one_line
    assert one_line("cannot import x (first\n  second\r\nthird)\n") == "cannot import x (first | second | third)"
    long = "x" * 5000 + " fix it"
    out = one_line(long)
    assert out == "x" * 300 + " ... (4457 characters left out) ... " + "x" * 243 + " fix it"
    assert one_line("y" * 600) == "y" * 600


def test_render_replaces_its_video_whole_and_draws_a_route_that_failed_at_once(tmp_path, monkeypatch):
    """The video goes in under its name only once whole (an earlier file at that path is
    kept until then, no partial file is left); an agent that fails on its first tick still
    gets its path picture (the route alone)."""
    video = tmp_path / "r.mp4"
    video.write_bytes(b"an earlier video")
    assert main(["render", "--routes", "town12_smoke", "--route", "1", "--agent", "tests.agents:FaultyFollower",
                 "--out", str(video)]) == 0
    assert video.read_bytes()[4:8] == b"ftyp" and video.stat().st_size > 10_000  # an MP4, replaced
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.mp4", "r.png"]
    monkeypatch.delenv("CHECK_PID", raising=False)  # so the agent raises at its first tick
    assert main(["render", "--routes", "town12_smoke", "--route", "0", "--agent",
                 "tests.hostile_agents:UndecodableMessage", "--out", str(tmp_path / "f.mp4")]) == 0
    assert (tmp_path / "f.png").stat().st_size > 0
    assert not [p for p in tmp_path.iterdir() if ".part" in p.name]


def test_a_gzip_bomb_is_refused_after_reading_at_most_the_limit(tmp_path, capsys, monkeypatch):
    """A .gz that would decompress past MAX_TEXT (here lowered to 1 MB; 2 MB of spaces in
    2 kB) is one line, without decompressing the rest."""
    import gzip
    from files import compressed
    monkeypatch.setattr(compressed, "MAX_TEXT", 2**20)
    bomb = tmp_path / "results.json.gz"
    bomb.write_bytes(gzip.compress(b" " * 2**21))
    assert bomb.stat().st_size < 5000
    assert main(["score", str(bomb)]) == 2
    assert "decompresses to more than 1 MB" in one_error_line(capsys)


def test_agent_garbage_is_the_agents_crash_not_the_simulations(tmp_path, monkeypatch):
    """Checked by the harness, not by the agent's own objects: a Prediction of strings, an
    exception that cannot be printed, a NaN Control that says it is finite, a Control of
    strings: each route is 'Failed - Agent crashed' with the reason, and the run goes on."""
    monkeypatch.setenv("CHECK_PID", str(os.getpid()))
    out = tmp_path / "run"
    assert main(["eval", "--routes", "town12_smoke", "--workers", "1", "--agent", "tests.hostile_agents:Garbage",
                 "--out", str(out)]) == 0
    recs = {r["route_id"]: r for r in map(json.loads, (out / "records.jsonl").read_text().splitlines())}
    assert {k: r["status"] for k, r in recs.items()} == dict.fromkeys("0123", "Failed - Agent crashed")
    assert "Prediction.path holds <U1 values, not numbers" in recs["0"]["message"]
    assert "_Unprintable: (its message could not be made" in recs["1"]["message"]
    assert "non-finite control" in recs["2"]["message"]
    assert "Control fields must be numbers, got str, float, float" in recs["3"]["message"]
