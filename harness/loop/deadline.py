"""The per-step deadline of ``run_step``, as the Leaderboard's agent watchdog keeps it.

A step that runs past ``timeout`` seconds of wall time raises :class:`AgentTimeout` with
the Leaderboard's message; the episode ends the route as "Failed - Agent crashed". Where a
SIGALRM timer is available (the main thread of a POSIX process) it interrupts the agent;
elsewhere, or if the agent swallows the interruption, the duration is checked when the
step returns. Every call also runs under ``agent_call`` (harness.loop.agent), whose
deadline a watching parent process enforces on a worker that does not return at all.
"""
from __future__ import annotations

import signal
import threading
import time as wallclock

from harness.loop.agent import agent_call

# Wall-clock limit of one run_step call [s]. The Leaderboard's agent watchdog uses its
# --timeout (60 s by default in 1.0); real agents take milliseconds, a learned one its
# first call included, so 60 s only catches a hung agent.
AGENT_TIMEOUT = 60.0


class AgentTimeout(RuntimeError):
    """``run_step`` ran past the per-step deadline."""


_armed_timeout: float | None = None  # the deadline [s] while a step runs under the alarm


def _timeout_error(timeout: float) -> AgentTimeout:
    return AgentTimeout(f"Agent took longer than {timeout:g}s to send its command")  # the Leaderboard's words


def _on_alarm(signum, frame) -> None:
    if _armed_timeout is not None:  # a signal arriving after the step ended is ignored
        raise _timeout_error(_armed_timeout)


def deadline_alarm() -> bool:
    """Whether a SIGALRM timer can interrupt ``run_step`` here (the main thread, a platform
    with ``setitimer``); if so, installs the handler, once per route before its first step
    (reading the handler back every step cost 1-2 % of a tick: ``signal.getsignal``
    builds an enum). An agent that installs its own SIGALRM handler loses the
    interruption, not the deadline: the duration is checked when the step returns."""
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "setitimer"):
        return False
    signal.signal(signal.SIGALRM, _on_alarm)
    return True


def step_with_deadline(agent, inputs: dict, timestamp: float, timeout: float, alarm: bool, caller: int = 0):
    """``agent.run_step(inputs, timestamp)``, ended after ``timeout`` s of wall time
    (``caller``: the agent's number for the watching parent, harness.loop.agent.agent_call).

    With ``alarm`` (``deadline_alarm()``) a SIGALRM timer interrupts the agent, as the
    Leaderboard's watchdog interrupts its main thread (a sleeping or looping agent stops
    there; one inside a long C call, when it returns). Without it, or if the agent
    swallowed the interruption, the step's duration is checked when it returns."""
    global _armed_timeout
    t0 = wallclock.perf_counter()
    if alarm:
        _armed_timeout = timeout
        signal.setitimer(signal.ITIMER_REAL, timeout)
    try:
        with agent_call(timeout, caller):
            out = agent.run_step(inputs, timestamp)
    finally:
        if alarm:
            _armed_timeout = None
            signal.setitimer(signal.ITIMER_REAL, 0)
    if wallclock.perf_counter() - t0 > timeout:
        raise _timeout_error(timeout)
    return out
