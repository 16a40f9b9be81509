"""A run folder held by one process, outputs that cannot be written, and agents that raise
what is not an Exception (SPEC §12).

Real processes, real libsumo and real file-system errors: a second process holds the
folder; ENOSPC comes from the kernel, through a link to /dev/full at a temporary file's
name or a tmpfs of a few hundred kB filled up (where this user may mount one); a read-only
folder is a read-only tmpfs mounted there (root ignores file modes) or, for other users,
mode 555.
"""
from __future__ import annotations

import contextlib
import csv
import errno
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from harness.common.errors import BadInput
from harness.common.lock import LOCK_NAME, FolderLock
from harness.loop.route_follower import RouteFollower
from sumo_scimm.cli import main

ROOT = Path(__file__).resolve().parents[1]
SMOKE_ONE = ["eval", "--routes", "town12_smoke", "--routes-subset", "0", "--agent", "route_follower",
             "--workers", "1"]
SMOKE_TWO = [*SMOKE_ONE[:4], "0-1", *SMOKE_ONE[5:]]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def _cli(argv: list[str]) -> tuple[int, str]:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        code = main(argv)
    return code, buf.getvalue()


def _one_line_exit_2(code: int, printed: str, *words: str) -> str:
    lines = [ln for ln in printed.splitlines() if ln.strip()]
    assert code == 2, printed
    assert len(lines) == 1, printed
    assert lines[0].startswith("sumo-scimm: error: "), printed
    assert "Traceback" not in printed
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


def _records(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "records.jsonl").read_text().splitlines()]


def _leftovers(out: Path) -> list[Path]:
    """Temporary files and lock files left in a folder tree."""
    return [p for p in out.rglob("*") if p.name.endswith((".tmp", ".tmp.npz")) or p.name == LOCK_NAME]


def _consistent(out: Path) -> list[str]:
    """records.jsonl, records.csv and results.json list the same route runs; returns them."""
    keys = [r["key"] for r in _records(out)]
    with open(out / "records.csv", newline="") as f:
        assert sorted(r["key"] for r in csv.DictReader(f)) == sorted(keys)
    data = json.loads((out / "results.json").read_text())
    assert len(data["_checkpoint"]["records"]) == len(keys)
    return keys


def _without_wall_clock(rec: dict) -> dict:
    rec = dict(rec)
    rec.pop("wall_time")
    rec["lb"] = {**rec["lb"], "meta": {**rec["lb"]["meta"], "duration_system": None}}
    return rec


# --- one process per run folder ------------------------------------------------------------
HOLDER = """
import sys
from pathlib import Path
from harness.common.lock import FolderLock
with FolderLock(Path(sys.argv[1])):
    print("held", flush=True)
    sys.stdin.readline()
"""


def _hold(folder: Path) -> subprocess.Popen:
    """Another process that holds ``folder`` until its stdin closes."""
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, env=ENV)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_held_folder_is_refused_naming_its_holder_whose_lock_is_taken_over_once_it_died(tmp_path):
    folder = tmp_path / "run"
    holder = _hold(folder)
    try:
        with pytest.raises(BadInput, match=rf"in use by another run \(pid {holder.pid}, lock run.lock\)"):
            with FolderLock(folder):
                pass
        assert (folder / LOCK_NAME).read_text() == f"{holder.pid}\n"
    finally:
        holder.kill()  # SIGKILL: no clean-up of its own
        holder.wait()
    # the file still names the dead process, but the kernel released its lock
    assert (folder / LOCK_NAME).read_text() == f"{holder.pid}\n"
    with FolderLock(folder):
        assert (folder / LOCK_NAME).read_text() == f"{os.getpid()}\n"
    assert not (folder / LOCK_NAME).exists()
    # a holder that ends normally removes its lock file
    holder = _hold(folder)
    holder.communicate("\n", timeout=30)
    assert list(folder.iterdir()) == []


def test_without_flock_a_live_holders_pid_refuses_and_a_dead_ones_is_taken_over(tmp_path, monkeypatch):
    """On a file system without flock (ENOLCK) the pid in the lock file decides."""
    import fcntl

    def no_flock(fd, op):
        raise OSError(errno.ENOLCK, os.strerror(errno.ENOLCK))
    folder = tmp_path / "run"
    folder.mkdir()
    alive = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.readline()"], stdin=subprocess.PIPE)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    monkeypatch.setattr(fcntl, "flock", no_flock)
    try:
        (folder / LOCK_NAME).write_text(f"{alive.pid}\n")
        with pytest.raises(BadInput, match=f"pid {alive.pid}"):
            with FolderLock(folder):
                pass
    finally:
        alive.kill()
        alive.wait()
    (folder / LOCK_NAME).write_text(f"{dead.pid}\n")
    with FolderLock(folder):
        assert (folder / LOCK_NAME).read_text() == f"{os.getpid()}\n"


def test_the_folders_a_lock_made_are_removed_when_the_command_stops_on_bad_input(tmp_path):
    with pytest.raises(BadInput, match="refused"):
        with FolderLock(tmp_path / "a" / "b" / "c"):
            assert (tmp_path / "a" / "b" / "c" / LOCK_NAME).is_file()
            raise BadInput("refused")
    assert list(tmp_path.iterdir()) == []


def test_eval_collect_and_resume_on_a_held_folder_exit_2_naming_the_holder(tmp_path):
    out = tmp_path / "run"
    holder = _hold(out)
    try:
        for argv in ([*SMOKE_ONE, "--out", str(out)], [*SMOKE_ONE, "--out", str(out), "--resume"],
                     ["collect", "--routes", "town12_smoke", "--out", str(out)]):
            code, printed = _cli(argv)
            _one_line_exit_2(code, printed, str(out), f"pid {holder.pid}", "in use by another run")
        assert [p.name for p in out.iterdir()] == [LOCK_NAME]
    finally:
        holder.kill()
        holder.wait()


@pytest.mark.slow
def test_two_evals_on_one_folder_the_second_is_refused_and_resumes_once_the_first_is_killed(tmp_path):
    """Two real ``eval`` processes: while the first runs, a second one and a --resume are
    refused; after kill -9 of the first (its whole process group), --resume takes its lock
    over and finishes the run, every route once."""
    out = tmp_path / "run"
    first = subprocess.Popen([sys.executable, "-m", "sumo_scimm.cli", *SMOKE_TWO, "--out", str(out)],
                             start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ENV)
    try:
        lock, deadline = out / LOCK_NAME, time.time() + 120
        while time.time() < deadline and not (lock.is_file() and lock.read_text() == f"{first.pid}\n"):
            time.sleep(0.05)
        assert lock.read_text() == f"{first.pid}\n"
        for extra in ([], ["--resume"]):
            code, printed = _cli([*SMOKE_TWO, "--out", str(out), *extra])
            _one_line_exit_2(code, printed, f"pid {first.pid}")
    finally:
        os.killpg(first.pid, signal.SIGKILL)
        first.wait()
    code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])
    assert code == 0, printed
    assert sorted(_consistent(out)) == ["0_rep0", "1_rep0"]
    assert not _leftovers(out)


# --- how many route runs --------------------------------------------------------------------
def test_routes_subset_selects_in_set_order_and_refuses_every_part_that_selects_nothing():
    from harness.runs.evaluate import select_routes
    ids = ["0", "1", "2", "3", "a"]
    assert select_routes(None, ids) == ids
    assert select_routes("3,0-1, a", ids) == ["0", "1", "3", "a"]
    assert select_routes("1-1,1", ids) == ["1"]
    for spec, words in (("", "names no route"), (" , ", "names no route"), ("3-1", "reversed (write 1-3)"),
                        ("0,5-9", "range '5-9' holds no route"), ("0,7", "no route '7'"),
                        ("0," + "9" * 5000, "no route '9999999999999999... (5000 characters)'")):
        with pytest.raises(BadInput, match=re.escape(words)):
            select_routes(spec, ids)


def test_too_many_route_runs_are_refused_before_a_job_is_made(tmp_path):
    """Once, --repetitions 1000000000 built its job list for ever."""
    from harness.runs.evaluate import MAX_ROUTE_RUNS
    code, printed = _cli([*SMOKE_ONE, "--repetitions", str(MAX_ROUTE_RUNS + 1), "--out", str(tmp_path / "a")])
    _one_line_exit_2(code, printed, f"--repetitions {MAX_ROUTE_RUNS + 1}", f"at most {MAX_ROUTE_RUNS} route runs")
    code, printed = _cli(["collect", "--routes", "town12_smoke", "--repetitions", str(MAX_ROUTE_RUNS // 4 + 1),
                          "--out", str(tmp_path / "b")])
    n = MAX_ROUTE_RUNS // 4 + 1
    _one_line_exit_2(code, printed, f"{n} x 4 routes = {4 * n} route runs")
    assert list(tmp_path.iterdir()) == []


# --- outputs that cannot be written ----------------------------------------------------------
@contextlib.contextmanager
def _read_only(folder: Path):
    """``folder`` (created) made read-only for this process: mode 555, or for root a
    read-only tmpfs mounted over it; skips the test where neither is possible."""
    folder.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        folder.chmod(0o555)
        try:
            yield folder
        finally:
            folder.chmod(0o755)
        return
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(folder)],
                             capture_output=True, text=True)
    if mounted.returncode:
        pytest.skip(f"cannot mount a read-only tmpfs here: {mounted.stderr.strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], check=True)


def test_unwritable_outputs_are_refused_before_the_first_route(tmp_path):
    """A read-only run folder, logs folder or results-file folder, a results path whose
    folder is missing or that is a folder: one line naming it, exit 2, and no route runs."""
    with _read_only(tmp_path / "ro") as ro:
        code, printed = _cli([*SMOKE_ONE, "--out", str(ro / "run")])
        _one_line_exit_2(code, printed, str(ro / "run"), "cannot create or write")
        out = tmp_path / "run"
        code, printed = _cli([*SMOKE_ONE, "--out", str(out), "--checkpoint", str(ro / "results.json")])
        _one_line_exit_2(code, printed, f"--checkpoint folder {ro}", "cannot write there")
        assert not out.exists()
    out = tmp_path / "run"
    with _read_only(out / "logs") as logs:
        code, printed = _cli([*SMOKE_ONE, "--out", str(out)])
        _one_line_exit_2(code, printed, f"output folder {logs}", "cannot write there")
    assert [p.name for p in out.iterdir()] == ["logs"]  # no record, no lock left
    cases = ((tmp_path / "nowhere" / "results.json", "its folder does not exist"), (tmp_path, "is not a file"))
    for checkpoint, words in cases:
        code, printed = _cli([*SMOKE_ONE, "--out", str(out), "--checkpoint", str(checkpoint)])
        _one_line_exit_2(code, printed, str(checkpoint), words)
    assert [p.name for p in out.iterdir()] == ["logs"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes read-only files")
def test_a_read_only_results_file_is_refused_before_the_first_route(tmp_path):
    checkpoint = tmp_path / "results.json"
    checkpoint.write_text("{}")
    checkpoint.chmod(0o444)
    code, printed = _cli([*SMOKE_ONE, "--out", str(tmp_path / "run"), "--checkpoint", str(checkpoint)])
    _one_line_exit_2(code, printed, str(checkpoint), "read-only")
    assert not (tmp_path / "run").exists()


def test_a_write_that_fails_removes_its_temporary_file_and_names_the_file_meant(tmp_path):
    """ENOSPC from the kernel: the temporary name links to /dev/full."""
    from harness.common.atomic import savez_atomic, write_atomic
    log = tmp_path / "0_rep0.npz"
    (tmp_path / "0_rep0.npz.tmp.npz").symlink_to("/dev/full")
    with pytest.raises(OSError) as caught:
        savez_atomic(log, x=np.arange(10.0))
    assert (caught.value.errno, caught.value.filename) == (errno.ENOSPC, str(log))
    table = tmp_path / "records.csv"
    (tmp_path / "records.csv.tmp").symlink_to("/dev/full")
    with pytest.raises(OSError) as caught:
        write_atomic(table, "key\n")
    assert (caught.value.errno, caught.value.filename) == (errno.ENOSPC, str(table))
    assert list(tmp_path.iterdir()) == []


def test_a_record_line_cut_by_a_full_disk_is_removed_again(tmp_path):
    """runner._append: the part of a line written before the disk filled is cut off, so the
    file ends after its last whole record."""
    from harness.runs.runner import _append
    path = tmp_path / "records.jsonl"
    path.write_bytes(b'{"key": "0_rep0"}\n')

    class FillsAfter5Bytes(io.FileIO):
        def write(self, data):
            if self.tell() >= 18 + 5:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return super().write(bytes(data)[:5])
    with FillsAfter5Bytes(path, "ab") as f:
        with pytest.raises(OSError) as caught:
            _append(f, '{"key": "1_rep0"}\n', path, sync=True)
    assert (caught.value.errno, caught.value.filename) == (errno.ENOSPC, str(path))
    assert path.read_bytes() == b'{"key": "0_rep0"}\n'


@pytest.fixture(scope="module")
def clean_run(tmp_path_factory) -> Path:
    """Routes 0 and 1 of the smoke set run without a fault."""
    out = tmp_path_factory.mktemp("clean") / "run"
    code, printed = _cli([*SMOKE_TWO, "--out", str(out)])
    assert code == 0, printed
    return out


@pytest.fixture(scope="module")
def uninterrupted(clean_run) -> dict[str, dict]:
    """The records of ``clean_run`` (wall clock left out)."""
    return {r["key"]: _without_wall_clock(r) for r in _records(clean_run)}


@pytest.mark.slow
def test_a_full_disk_stops_the_run_and_resume_gives_the_uninterrupted_records(tmp_path, uninterrupted):
    """ENOSPC in the worker (route 1's log) and then in the parent (records.csv): each
    stops the run with one line naming the file, exit 2; no route is recorded as crashed,
    no temporary file stays, and --resume ends with the records of an uninterrupted run."""
    out = tmp_path / "run"
    (out / "logs").mkdir(parents=True)
    (out / "logs" / "1_rep0.npz.tmp.npz").symlink_to("/dev/full")  # where route 1's log is written first
    code, printed = _cli([*SMOKE_TWO, "--out", str(out)])
    _one_line_exit_2(code, printed, f"cannot write {out / 'logs' / '1_rep0.npz'} (No space left on device)",
                     "--resume")
    assert _consistent(out) == ["0_rep0"]  # route 1 is no record
    assert not _leftovers(out)

    (out / "records.csv.tmp").symlink_to("/dev/full")  # the table rewritten after route 1
    code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])
    _one_line_exit_2(code, printed, f"cannot write {out / 'records.csv'} (No space left on device)")
    assert [r["key"] for r in _records(out)] == ["0_rep0", "1_rep0"]  # its line was whole: kept
    assert not _leftovers(out)

    code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])  # the cause removed
    assert code == 0, printed
    assert _consistent(out) == ["0_rep0", "1_rep0"]
    assert {r["key"]: _without_wall_clock(r) for r in _records(out)} == uninterrupted
    assert not _leftovers(out)


@pytest.mark.slow
def test_a_full_disk_on_the_ray_driver_stops_the_run_too(tmp_path):
    """With --backend ray the driver writes the task's log: ENOSPC there stops the run the
    same way (one line, exit 2, no record, no temporary file)."""
    pytest.importorskip("ray", reason="ray is not installed")
    out = tmp_path / "run"
    (out / "logs").mkdir(parents=True)
    (out / "logs" / "0_rep0.npz.tmp").symlink_to("/dev/full")  # harness.common.atomic.write_atomic's name
    code, printed = _cli([*SMOKE_ONE, "--backend", "ray", "--out", str(out)])
    _one_line_exit_2(code, printed, f"cannot write {out / 'logs' / '0_rep0.npz'} (No space left on device)")
    assert (out / "records.jsonl").read_text() == ""
    assert not _leftovers(out)


def _pages(folder: Path) -> int:
    """Bytes the files of ``folder`` take on a tmpfs (whole 4 KiB pages)."""
    return sum(-(-p.stat().st_size // 4096) * 4096 for p in folder.rglob("*") if p.is_file())


@pytest.mark.slow
def test_a_tiny_file_system_that_fills_up_mid_run_then_resume(tmp_path, clean_run, uninterrupted):
    """A real full disk: the run folder on a tmpfs whose free space is what the finished
    run takes less half of route 1's log, so a write fails by route 1's log at the latest.
    Wherever it fails, the run stops with one line naming a file of the run, exit 2, and
    leaves only whole files; once space is freed, --resume ends with the records of an
    uninterrupted run."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(disk)], capture_output=True,
                             text=True)
    if mounted.returncode:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.strip()}")
    try:
        free = _pages(clean_run) - (clean_run / "logs" / "1_rep0.npz").stat().st_size // 2
        filler = disk / "filler"
        filler.write_bytes(b"\0" * (shutil.disk_usage(disk).free - free))
        out = disk / "run"
        code, printed = _cli([*SMOKE_TWO, "--out", str(out)])
        line = _one_line_exit_2(code, printed, f"cannot write {out}", "(No space left on device)", "--resume")
        assert "Simulation crashed" not in line
        if (out / "records.csv").exists():
            assert len(_consistent(out)) < 2
        assert not _leftovers(out)
        filler.unlink()
        code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])
        assert code == 0, printed
        assert _consistent(out) == ["0_rep0", "1_rep0"]
        assert {r["key"]: _without_wall_clock(r) for r in _records(out)} == uninterrupted
    finally:
        subprocess.run(["umount", str(disk)], check=True)


# --- agents that raise what is not an Exception ----------------------------------------------
class Raiser(RouteFollower):
    """Follows the route; from 1.02 s of game time on (between two ticks) raises from
    run_step what is not an Exception: SystemExit on route 0, KeyboardInterrupt on route 1,
    GeneratorExit on route 2."""

    def run_step(self, input_data, timestamp):
        control = super().run_step(input_data, timestamp)
        if timestamp > 1.02:
            raise {"0": SystemExit(3), "1": KeyboardInterrupt("raised by the agent"), "2": GeneratorExit()}[
                self.plan.route_id]
        return control


class RealCtrlC(RouteFollower):
    """Follows the route; after 0.5 s its process gets a SIGINT, as from the user's Ctrl-C."""

    def run_step(self, input_data, timestamp):
        if timestamp > 0.5:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5.0)  # the handler raises here
        return super().run_step(input_data, timestamp)


def test_system_exit_keyboard_interrupt_and_generator_exit_of_an_agent_fail_only_its_route(tmp_path):
    out = tmp_path / "run"
    code, printed = _cli(["eval", "--routes", "town12_smoke", "--routes-subset", "0-2", "--agent",
                          "tests.test_run_folder:Raiser", "--workers", "1", "--out", str(out)])
    assert code == 0, printed
    assert "Traceback" not in printed
    recs = {r["route_id"]: r for r in _records(out)}
    assert {k: (r["status"], r["message"]) for k, r in recs.items()} == {
        "0": ("Failed - Agent crashed", "SystemExit: 3"),
        "1": ("Failed - Agent crashed", "KeyboardInterrupt: raised by the agent"),
        "2": ("Failed - Agent crashed", "GeneratorExit: ")}
    for r in recs.values():
        # the first tick past 1 s of game time raised: 20 ticks of 0.05 s driven, and logged
        assert r["steps"] == 20, r
        with np.load(out / "logs" / f"{r['key']}.npz") as log:
            assert len(log["x"]) == 20
    pids = {json.loads(line)["pid"] for line in (out / "workers.jsonl").read_text().splitlines()}
    assert len(pids) == 1  # one worker ran the three routes: none died


def test_in_the_main_process_a_real_ctrl_c_stops_but_an_agents_keyboard_interrupt_fails_its_route():
    """The same route in this process (as ``render`` drives it): KeyboardInterrupt raised by
    the agent ends the route as "Failed - Agent crashed"; a SIGINT delivered to the process
    while run_step runs goes on as the user's stop."""
    from harness.loop.episode import run_episode
    from scenarios import set_path
    from scenarios.routefile import read_routes
    route = read_routes(set_path("town12_smoke"))[1][1]
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)  # also where SIGINT is ignored
    try:
        res = run_episode(route, "tests.test_run_folder:Raiser", None, 0)
        assert (res.status, res.message) == ("Failed - Agent crashed", "KeyboardInterrupt: raised by the agent")
        with pytest.raises(KeyboardInterrupt):
            run_episode(route, "tests.test_run_folder:RealCtrlC", None, 0)
    finally:
        signal.signal(signal.SIGINT, inherited)
