"""Agents that misbehave as an attacker's would, loaded as ``tests.hostile_agents:<Class>``.

The ones that hang do so only in a worker process (``os.getpid()`` differs from
``CHECK_PID``, the test process's pid, where the agent's checks run), so that the checks
pass and the hang meets the parent's watchdog."""
from __future__ import annotations

import os
import shutil
import signal
import sys
import time

import numpy as np

from harness.loop.agent import AutonomousAgent, Control, Prediction
from harness.loop.route_follower import RouteFollower


def in_worker() -> bool:
    return str(os.getpid()) != os.environ.get("CHECK_PID")


def _hang() -> None:
    """Sleep, swallowing every interruption, for far longer than any deadline of a test."""
    end = time.monotonic() + 120
    while time.monotonic() < end:
        try:
            time.sleep(end - time.monotonic())
        except BaseException:  # noqa: BLE001 - on purpose
            pass


class ExitInInit(AutonomousAgent):
    def __init__(self):
        sys.exit(int(os.environ.get("EXIT_CODE", "0")))


class InterruptInInit(AutonomousAgent):
    def __init__(self):
        raise KeyboardInterrupt


class SensorsRaise(RouteFollower):
    def sensors(self):
        raise RuntimeError("no sensors today")


class Sensors42(RouteFollower):
    def sensors(self):
        return 42


class SensorWithoutType(RouteFollower):
    def sensors(self):
        return [{"id": "speed"}]


class SensorsFailInWorker(RouteFollower):
    """Passes the checks; its sensors() raise on every route in a worker."""

    def sensors(self):
        if in_worker():
            raise RuntimeError("sensors broke in the worker")
        return super().sensors()


class SensorsAfterSetup(RouteFollower):
    """Its sensors depend on what setup() did (valid only after it, the documented order)."""

    def setup(self, config):
        super().setup(config)
        self.ready = True

    def sensors(self):
        return super().sensors() if getattr(self, "ready", False) else "setup() first"


class Counted(RouteFollower):
    """Appends a line to the file named by AGENT_COUNT at every construction."""

    def __init__(self):
        super().__init__()
        with open(os.environ["AGENT_COUNT"], "a") as f:
            f.write(f"{os.getpid()}\n")


class BadPrediction(RouteFollower):
    def run_step(self, input_data, timestamp):
        return super().run_step(input_data, timestamp), Prediction(path=np.zeros((3, 3)))


class DestroyRaises(RouteFollower):
    """Passes the checks; its destroy() raises in a worker."""

    def destroy(self):
        if in_worker():
            raise RuntimeError("destroy failed on purpose")


class Hang(RouteFollower):
    """In a worker, hangs on route ``HANG_<route id>``'s call: ``ignore`` (SIGALRM ignored,
    then sleeps in run_step), ``cancel`` (the alarm cancelled), ``swallow`` (every
    interruption swallowed), ``setup``, ``sensors``, ``destroy``."""

    def _how(self) -> str:
        return os.environ.get(f"HANG_{self.plan.route_id}", "") if in_worker() else ""

    def setup(self, config):
        super().setup(config)
        if self._how() == "setup":
            _hang()

    def sensors(self):
        if self._how() == "sensors":
            _hang()
        return super().sensors()

    def run_step(self, input_data, timestamp):
        how = self._how()
        if how == "ignore":
            signal.signal(signal.SIGALRM, signal.SIG_IGN)
            time.sleep(120)
        elif how == "cancel":
            signal.setitimer(signal.ITIMER_REAL, 0)
            time.sleep(120)
        elif how == "swallow":
            _hang()
        return super().run_step(input_data, timestamp)

    def destroy(self):
        if self._how() == "destroy":
            _hang()


class HangInInit(RouteFollower):
    def __init__(self):
        super().__init__()
        if in_worker():
            _hang()


class ReplacesRunFolder(RouteFollower):
    """On route 1, in a worker, removes the run folder RUN_DIR and makes a new one there."""

    def setup(self, config):
        super().setup(config)
        if self.plan.route_id == "1" and in_worker():
            folder = os.environ["RUN_DIR"]
            shutil.rmtree(folder)
            os.makedirs(folder)
            with open(os.path.join(folder, "other_run.txt"), "w") as f:
                f.write("another run's folder\n")


class UndecodableMessage(RouteFollower):
    """Raises, in a worker, with a file name that holds a byte that is not UTF-8 (Python
    keeps it as the lone surrogate U+DCFF)."""

    def run_step(self, input_data, timestamp):
        if in_worker():
            name = os.fsdecode(b"/tmp/weights-\xff.bin")
            raise FileNotFoundError(f"no weights at {name}")
        return super().run_step(input_data, timestamp)


class ChangesFolder(RouteFollower):
    """Changes the worker's working folder in setup, as an agent that loads its files
    relative to its own folder does."""

    def setup(self, config):
        super().setup(config)
        if in_worker():
            os.chdir(os.environ["AGENT_FOLDER"])


class EditsThePlan(RouteFollower):
    """Tries to move the route's end to its start and mark it driven, then stands."""

    def setup(self, config):
        super().setup(config)
        if in_worker():
            self.plan.s[:] = self.plan.s[-1]

    def run_step(self, input_data, timestamp):
        return Control(0.0, 0.0, 1.0)


def in_spawned_worker() -> bool:
    """In a worker process that a run spawned (for agents run by a ``sumo-scimm`` started
    as a subprocess, whose pid the test cannot name in CHECK_PID)."""
    import multiprocessing
    return multiprocessing.parent_process() is not None


class AtexitHang(RouteFollower):
    """Registers, in a worker, an ``atexit`` function that never returns."""

    def setup(self, config):
        super().setup(config)
        if in_spawned_worker():
            import atexit
            atexit.register(_hang)


class IgnoresTerm(RouteFollower):
    """Ignores SIGTERM in a worker (as a library that installs its own handler may), and
    drives slowly enough to be stopped mid-run."""

    def setup(self, config):
        super().setup(config)
        if in_spawned_worker():
            signal.signal(signal.SIGTERM, signal.SIG_IGN)

    def run_step(self, input_data, timestamp):
        time.sleep(0.01)
        return super().run_step(input_data, timestamp)


class _Unprintable(RuntimeError):
    def __str__(self):
        raise SystemExit(7)


class _AlwaysFinite(Control):
    def is_finite(self) -> bool:
        return True


class Garbage(RouteFollower):
    """From its second step in a worker, per route: 0 a Prediction of strings of the right
    shape; 1 an exception whose ``__str__`` raises SystemExit; 2 a NaN Control whose own
    ``is_finite`` says it is finite; 3 a Control of strings."""

    def run_step(self, input_data, timestamp):
        control = super().run_step(input_data, timestamp)
        if not in_worker() or timestamp < 0.1:
            return control
        rid = self.plan.route_id
        if rid == "0":
            return control, Prediction(path=np.full((20, 2), "a"))
        if rid == "1":
            raise _Unprintable()
        if rid == "2":
            return _AlwaysFinite(float("nan"), 0.5, 0.0)
        return Control("left", 0.5, 0.0)
