"""Telling the user's stop from an agent that raises KeyboardInterrupt or SystemExit itself.

A Ctrl-C reaches a process as SIGINT, whose Python handler raises KeyboardInterrupt in the
main thread (``sumo-scimm`` turns SIGTERM into a KeyboardInterrupt subclass the same way);
an agent can raise the same exceptions from ``run_step``. The first must stop the run, the
second only ends the agent's route as "Failed - Agent crashed". ``watch_stops`` wraps the
Python handlers of SIGINT and SIGTERM so that every delivered stop is counted; an exception
that escapes the agent while the count stays what it was when the route started came from
the agent.

Worker processes ignore SIGINT and leave SIGTERM at its default (the parent ends them), so
there nothing is wrapped and every such exception is the agent's.
"""
from __future__ import annotations

import signal
import threading

_stops = 0  # stops delivered to this process through a wrapped handler


class _Counted:
    """A signal handler that counts the signal, then runs the handler it wraps."""

    def __init__(self, handler):
        self.handler = handler

    def __call__(self, signum, frame):
        global _stops
        _stops += 1
        return self.handler(signum, frame)


def watch_stops() -> int:
    """Count the SIGINT and SIGTERM delivered from now on (main thread, Python handlers;
    once wrapped, a handler is not wrapped again); returns the count so far."""
    if threading.current_thread() is threading.main_thread():
        for k in (signal.SIGINT, signal.SIGTERM):
            handler = signal.getsignal(k)
            if callable(handler) and not isinstance(handler, _Counted):
                signal.signal(k, _Counted(handler))
    return _stops


def is_stop(exc: BaseException, since: int) -> bool:
    """Whether ``exc`` (not an Exception: a KeyboardInterrupt, SystemExit, ...) is the
    user's stop: a SIGINT or SIGTERM was delivered after ``watch_stops`` returned ``since``
    (an agent that turns the interruption into another such exception still stops)."""
    return not isinstance(exc, Exception) and _stops != since
