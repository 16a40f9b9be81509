"""Jobs on spawned worker processes whose agent calls cannot hang the parent (docs/reliability.md).

Both ``eval`` (harness.runs.runner) and ``replay`` (harness.runs.replay) run their jobs here.
Each worker runs ``task(job)`` for one job after another and sends back its result. Every
agent call in a worker publishes its deadline and its caller's number
(harness.loop.agent.agent_call); the parent reads them every WATCH_EVERY s and kills a
worker whose agent call runs KILL_AFTER s past its deadline, whatever the agent did with
the in-process alarm. A worker that is killed so, or dies (kill -9, a segfault), is
reported through ``lost``, which may hand back a job to run in its place; a new worker
takes over and the others go on. A worker still running EXIT_GRACE s after it was told to
stop (no jobs left: an agent's ``atexit`` function that hangs; or an interruption: an
agent that ignores SIGTERM) is killed.
"""
from __future__ import annotations

import atexit
import multiprocessing as mp
import os
import signal
import sys
import time
from multiprocessing.connection import wait
from typing import Callable

from harness.loop.agent import watch_agent_calls
from harness.runs.jobs import KILL_AFTER, WATCH_EVERY

EXIT_GRACE = 5.0  # [s] a worker told to stop has this long before it is killed

HUNG = "hung"  # ``lost``'s reason for a worker killed past its agent call's deadline


def _worker(conn, deadline, caller, task) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the parent, which ends its workers
    watch_agent_calls(deadline, caller)
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):  # the parent is gone
            return
        if job is None:  # the run is over: this worker's files are written and its results sent
            _exit_now()
        try:
            out = task(job)
        except OSError as exc:  # an output it cannot write stops the run: tell the parent
            try:
                conn.send(_portable(exc))
            except OSError:
                pass
            return
        try:
            conn.send(out)
        except OSError:  # the parent is gone (killed): nobody to report to
            return


def _exit_now() -> None:
    """End this worker without the interpreter's teardown of its modules, which the run
    would wait for (the parent joins each worker at the end of the run): with torch, ONNX
    Runtime and libsumo loaded it takes about 0.9 s. Every file a job writes is written whole
    before its result is sent (files.atomic) and SUMO is closed after each route; the
    functions registered with ``atexit`` (an agent's, say) still run, and the output is
    flushed. Those functions get EXIT_GRACE s: then SIGALRM's default action ends the
    process, with or without a parent to kill it."""
    signal.signal(signal.SIGALRM, signal.SIG_DFL)
    signal.alarm(int(EXIT_GRACE))
    atexit._run_exitfuncs()  # what the interpreter's exit would call first (a few ms here)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


def _portable(exc: OSError) -> OSError:
    """A plain OSError of the same kind, path and text (any OSError subclass pickles so)."""
    if exc.errno is None:
        return OSError(str(exc))
    return OSError(exc.errno, exc.strerror or os.strerror(exc.errno), exc.filename)


def run_workers(jobs: list, workers: int, task: Callable, emit: Callable, lost: Callable) -> None:
    """Run ``task(job)`` (a module-level function) for every job on ``workers`` spawned
    processes; ``emit(job, result)`` as each ends. ``lost(job, reason, caller)`` when a
    worker ended without a result: ``reason`` HUNG (killed KILL_AFTER s past its agent
    call's deadline) or the worker's exit code; ``caller``: the ``caller`` number of the
    agent call it was in (harness.loop.agent.agent_call), None outside one. ``lost`` returns
    a job to run in the lost one's place, or None. An OSError a task raises (an output it
    cannot write) is raised here. Interrupted (Ctrl-C), it ends its workers."""
    ctx = mp.get_context("spawn")
    pending = list(reversed(jobs))
    slots: dict = {}  # connection -> (process, job or None)
    shared: dict = {}  # connection -> the worker's (agent-call deadline, caller number)

    def start_worker() -> None:
        parent, child = ctx.Pipe()
        deadline, caller = ctx.RawValue("d", 0.0), ctx.RawValue("i", -1)
        p = ctx.Process(target=_worker, args=(child, deadline, caller, task), daemon=True)
        p.start()
        child.close()
        slots[parent] = (p, None)
        shared[parent] = (deadline, caller)

    def end(conn, job, reason) -> None:
        """The worker of ``conn`` is gone: its job goes to ``lost``, a new worker takes over."""
        p = slots.pop(conn)[0]
        deadline, caller = shared.pop(conn)
        if job is not None:
            again = lost(job, reason, caller.value if deadline.value else None)
            if again is not None:
                pending.append(again)
        if pending:
            start_worker()

    def end_hung_workers() -> None:
        now = time.monotonic()
        for conn, (p, job) in list(slots.items()):
            due = shared[conn][0].value
            if job is None or not due or now < due + KILL_AFTER:
                continue
            p.kill()
            p.join()
            end(conn, job, HUNG)

    try:
        for _ in range(min(workers, len(jobs))):
            start_worker()
        while slots:
            for conn, (p, job) in list(slots.items()):
                if job is None:
                    if pending:
                        nxt = pending.pop()
                        conn.send(nxt)
                        slots[conn] = (p, nxt)
                    else:
                        conn.send(None)
                        _stop(p, terminate=False)
                        del slots[conn], shared[conn]
            if not slots:
                break
            ready = wait(list(slots) + [p.sentinel for p, _ in slots.values()], timeout=WATCH_EVERY)
            if not ready:
                end_hung_workers()
                continue
            for conn, (p, job) in list(slots.items()):
                if conn in ready:
                    try:
                        out = conn.recv()
                    except (EOFError, OSError):
                        out = None
                    if isinstance(out, OSError):  # the worker could not write its job's files
                        raise out
                    if out is not None:
                        emit(job, out)
                        slots[conn] = (p, None)
                        continue
                if p.sentinel in ready or not p.is_alive():
                    p.join()
                    end(conn, job, p.exitcode)
            end_hung_workers()
    finally:
        for p, _ in slots.values():  # only after an interruption or an error
            _stop(p, terminate=True)


def _stop(p, terminate: bool) -> None:
    """Wait for worker ``p`` to end (SIGTERM first if ``terminate``), at most EXIT_GRACE s,
    then kill it."""
    if terminate:
        p.terminate()
    p.join(EXIT_GRACE)
    if p.is_alive():
        p.kill()
        p.join()
