"""A run folder held by one process, bounds on the route runs of a run, and agents that raise
what is not an Exception (docs/design.md §12). Real processes and real libsumo: a second process
holds the folder."""
from __future__ import annotations

import errno
import json
import os
import re
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
from tests.run_folder_helpers import (ENV, SMOKE_ONE, SMOKE_TWO, _cli, _consistent, _leftovers,
                                      _one_line_exit_2, _records)


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
