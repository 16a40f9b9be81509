"""The agent API, mirroring the CARLA Leaderboard's ``AutonomousAgent`` (docs/design.md §3).

A user's agent module needs one import: ``from harness.loop.agent import AutonomousAgent,
Control, Prediction``.

Life of an agent: it is built without arguments once for the checks (``check_agent``:
``check_config(config)``, then the calls of a route below on the first route's plan, its
``sensors()`` validated after ``setup()``; a failure is one line before any route runs),
and once per worker process, which drives all its routes with that instance (``agent_for``;
an instance whose route ended in an agent failure is built again). Call order per route:
``set_global_plan(plan)``, ``setup(config)``, ``sensors()`` once (validated before the
route starts), ``run_step(input_data, timestamp)`` every 0.05 s tick, ``destroy()`` at the
end (also after a crash). The agent never gets a simulator handle: everything it sees
comes through ``input_data`` keyed by its sensors' ids.

Every agent call runs under a deadline (``agent_call``): in a worker the parent process
reads it and kills a worker whose agent call runs past it (harness.runs.workers), so an
agent that hangs in any call, ignores or cancels the alarm, or swallows the interruption
cannot hang a run.

Sensors an agent may declare (``{"type": ..., "id": ...}``):

| type | value in ``input_data[id]`` |
| --- | --- |
| ``speed`` | ego speed [m/s] |
| ``pose`` | world (x, y, yaw): m, m, rad CCW from +x (as GNSS + compass) |
| ``target_point`` | next sparse route point >= 7.5 m ahead (past the route end: 7.5 m ahead on |
|  | its straight run-on, harness.sim.plan), ego frame (x fwd, y left) [m] |
| ``command`` | RoadOption of the route at the ego (1 left, 2 right, 3 straight, 4 follow lane) |
| ``bev`` | ego-centred BEV raster, uint8 (C, H, W) (harness.sensors.bev) |
| ``world`` | privileged, for the expert: ``(snapshot, lights, props)``: every actor within |
|  | 50 m (harness.sim.world.Snapshot), the state of each route light (harness.sim.world.TLS_CODES |
|  | index, in the order of the plan's light passages), harness-only static boxes |

``run_step`` returns a :class:`Control`, or ``(Control, Prediction)`` to report the
waypoints it predicted (used for stability metrics and plots).
"""
from __future__ import annotations

import contextlib
import copy
import importlib
import math
import numbers
import os
import signal
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controller.vehicle import Control
from harness.common.errors import BadInput
from harness.common.stops import is_stop, watch_stops

__all__ = ["AutonomousAgent", "Control", "Prediction", "SensorConfigurationInvalid", "SENSOR_TYPES"]

SENSOR_TYPES = ("speed", "pose", "target_point", "command", "bev", "world")


class SensorConfigurationInvalid(ValueError):
    """An agent declared sensors the harness cannot give (named as in the Leaderboard)."""


class AgentLoadError(ValueError):
    """An agent name that cannot be resolved or loaded."""


@dataclass(frozen=True)
class Prediction:
    """What a learned agent predicted this step, in the ego frame (x forward, y left) [m].

    path: (20, 2) path points at arc length 0..19 m; speed_wps: (10, 2) future positions
    at 0.25..2.5 s. Either may be None.
    """

    path: np.ndarray | None = None
    speed_wps: np.ndarray | None = None


class AutonomousAgent:
    """Base class of every agent. Subclasses override sensors() and run_step()."""

    def __init__(self) -> None:
        self.plan = None
        self.config: str | None = None

    def set_global_plan(self, plan) -> None:
        """The route to drive (harness.sim.plan.GlobalPlan: dense and sparse points, world frame):
        the agent's own copy, so nothing the agent does to it moves the route the harness scores."""
        self.plan = plan

    def setup(self, config: str | None) -> None:
        """Called once per route with the --agent-config value (a path or None)."""
        self.config = config

    def check_config(self, config: str | None) -> None:
        """Called once by the CLI before any route runs: raise ValueError or OSError with a
        one-line reason if ``config`` cannot work (e.g. a missing checkpoint)."""

    def sensors(self) -> list[dict]:
        return []

    def run_step(self, input_data: dict, timestamp: float):
        raise NotImplementedError  # abstract: every agent defines it

    def destroy(self) -> None:
        """Release resources; called at the end of every route, also after a crash."""


def validate_sensors(specs: list[dict]) -> None:
    """Raise SensorConfigurationInvalid naming the first bad sensor spec."""
    if not isinstance(specs, (list, tuple)):
        raise SensorConfigurationInvalid(f"sensors() returned {_shown(specs)}, not a list of "
                                         "{'type': ..., 'id': ...} dicts")
    ids = set()
    for spec in specs:
        if not isinstance(spec, dict) or "type" not in spec or "id" not in spec:
            raise SensorConfigurationInvalid(f"sensor {spec!r} needs a 'type' and an 'id'")
        if spec["type"] not in SENSOR_TYPES:
            raise SensorConfigurationInvalid(
                f"sensor {_shown(spec['id'])} has unknown type {spec['type']!r} (known: {', '.join(SENSOR_TYPES)})")
        if not isinstance(spec["id"], str) or not isinstance(spec["type"], str):
            raise SensorConfigurationInvalid(f"sensor {_shown(spec)}: its 'type' and 'id' must be text")
        if spec["id"] in ids:
            raise SensorConfigurationInvalid(f"sensor id {spec['id']!r} is used twice")
        ids.add(spec["id"])


# Agents shipped with the harness, by CLI name.
BUILTIN_AGENTS = {
    "route_follower": "harness.loop.route_follower:RouteFollower",
    "expert": "harness.expert.driver:Expert",
    "student": "model.agent:StudentAgent",  # --agent-config MODEL_CHECKPOINT (student.pt)
    # the shipped students (model/checkpoints/<name>, made by sumo-scimm reproduce)
    "baseline": "model.agent:BaselineStudent",
    "control": "model.agent:ControlStudent",
    "fixed": "model.agent:FixedStudent",
    "scimm": "model.agent:ScimmStudent",
    "smoother": "model.agent:SmootherStudent",
}
DEFAULT_AGENT = "scimm"  # the shipped SC-IMM student (model/checkpoints/scimm)


def resolve_agent(name: str) -> str:
    """``module:Class`` for a built-in name or a ``module:Class`` string; raises AgentLoadError."""
    target = BUILTIN_AGENTS.get(name, name)
    if ":" not in target:
        raise AgentLoadError(f"unknown agent {name!r} (built-in: {', '.join(BUILTIN_AGENTS)}; "
                             f"or give module:Class)")
    return target


def _shown(value, width: int = 40) -> str:
    """``value`` for a message: its repr, cut to ``width`` characters."""
    text = repr(value)
    return text if len(text) <= width else f"{text[:width]}... ({len(text)} characters)"


def exception_text(exc: BaseException) -> str:
    """``str(exc)``, or a note where making it fails (an agent's exception whose ``__str__``
    raises, even SystemExit): the text of an agent's failure never fails the harness."""
    try:
        return str(exc)
    except BaseException:  # noqa: BLE001 - whatever the agent's __str__ does
        return "(its message could not be made: its __str__ raised)"


def _reason(exc: BaseException) -> str:
    """``Type: first line of the message`` of an exception, cut to one readable line."""
    text = exception_text(exc).strip()
    text = text.splitlines()[0] if text else ""
    return f"{type(exc).__name__}: {text[:160]}" if text else type(exc).__name__


def load_agent(name: str) -> AutonomousAgent:
    """Instantiate an agent by CLI name or ``module:Class`` (imported, never via sys.path
    edits). Whatever its module or constructor raises (SystemExit and KeyboardInterrupt
    included, unless the user's own Ctrl-C or SIGTERM arrived: harness.common.stops) is an
    AgentLoadError naming the agent."""
    module_name, _, cls_name = resolve_agent(name).partition(":")
    stops = watch_stops()
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise AgentLoadError(f"agent {name!r}: cannot import {module_name!r} ({exc})") from None
    except BaseException as exc:  # noqa: BLE001 - an error in the user's module is reported, not raised
        if is_stop(exc, stops):
            raise
        raise AgentLoadError(f"agent {name!r}: importing {module_name!r} failed ({_reason(exc)})") from None
    cls = getattr(module, cls_name, None)
    if cls is None or not isinstance(cls, type):
        raise AgentLoadError(f"agent {name!r}: {module_name!r} has no class {cls_name!r}")
    if not issubclass(cls, AutonomousAgent):
        raise AgentLoadError(f"agent {name!r}: {cls_name} does not subclass harness.loop.agent.AutonomousAgent")
    try:
        return cls()
    except BaseException as exc:  # noqa: BLE001
        if is_stop(exc, stops):
            raise
        raise AgentLoadError(f"agent {name!r}: {cls_name}() failed ({_reason(exc)}); "
                             "an agent is built without arguments (its config goes to setup())") from None


_built: dict[tuple[str, int], AutonomousAgent] = {}  # this process's agents by (name, slot) (agent_for)


def agent_for(name: str, slot: int = 0) -> AutonomousAgent:
    """This process's instance of agent ``name`` in place ``slot``, built on first use: a
    worker drives all its routes with one instance (``setup`` starts each route afresh).
    Several agents stepped side by side (a replay) each take their own slot, so two that
    share a name (two ``--agent PATH.pt`` are both the agent ``student``, each with its
    checkpoint) never share an instance, its network or its controller's state."""
    agent = _built.get((name, slot))
    if agent is None:
        agent = _built[(name, slot)] = load_agent(name)
    return agent


def forget_agent(name: str, slot: int = 0) -> None:
    """Drop this process's instance of ``name`` in ``slot`` (after it failed): the next
    route builds one."""
    _built.pop((name, slot), None)


# The deadline of the agent call running in this process, shared with the parent that
# watches it (harness.runs.workers): a monotonic time [s], 0.0 while no agent call runs;
# and the number of its caller (``agent_call``'s ``caller``: which of several agents).
_deadline = None
_caller = None


def watch_agent_calls(shared, caller=None) -> None:
    """Publish every agent call's deadline in ``shared`` (a multiprocessing double) and,
    given ``caller`` (a multiprocessing int), the number of its caller."""
    global _deadline, _caller
    _deadline, _caller = shared, caller


@contextlib.contextmanager
def agent_call(timeout: float, caller: int = 0):
    """Run the block (one call into the agent) under a deadline ``timeout`` [s of wall
    time] that the watching parent enforces; without a watcher the block runs as is.
    ``caller``: which agent calls (replay's agents by their place), for the parent."""
    shared = _deadline
    if shared is None:
        yield
        return
    if _caller is not None:
        _caller.value = caller
    shared.value = time.monotonic() + timeout
    try:
        yield
    finally:
        shared.value = 0.0


HARD_GRACE = 10.0  # [s] after its deadline, a check the alarm could not end ends the process


class CheckTimeout(BaseException):
    """An agent call of the checks ran past its deadline (a BaseException: an agent's
    ``except Exception`` does not swallow it)."""


def _on_check_alarm(signum, frame) -> None:
    raise CheckTimeout()


@contextlib.contextmanager
def _check_deadline(name: str, timeout: float):
    """The checks' agent calls under ``timeout`` [s]: a SIGALRM interrupts them (main
    thread); an agent that ignores, cancels or swallows it is ended with the process, one
    line and exit code 2, ``HARD_GRACE`` s later."""
    def hard_stop() -> None:
        os.write(2, f"sumo-scimm: error: agent {name!r}: its checks did not return within {timeout:g} s "
                    "(it hangs in its module, constructor, setup(), sensors() or destroy()); fix the agent\n".encode())
        os._exit(2)
    timer = threading.Timer(timeout + HARD_GRACE, hard_stop)
    timer.daemon = True
    timer.start()
    alarm = threading.current_thread() is threading.main_thread() and hasattr(signal, "setitimer")
    previous = signal.signal(signal.SIGALRM, _on_check_alarm) if alarm else None
    if alarm:
        signal.setitimer(signal.ITIMER_REAL, timeout)
    try:
        yield
    finally:
        timer.cancel()
        if alarm:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)


def check_agent(name: str, config: str | None, plan=None, timeout: float = 60.0) -> tuple[str, str | None]:
    """(agent, config) to run, checked: BadInput unless the agent loads and accepts its
    config (``--agent-config``, a file). ``--agent PATH.pt`` names a student checkpoint
    (docs/closed_loop.md): it is ``--agent student --agent-config PATH.pt``. With a route's ``plan``
    the agent also goes through a route's calls (``check_agent_setup``)."""
    return check_agent_setup(name, config, plan, timeout)[:2]


def check_agent_setup(name: str, config: str | None, plan=None,
                      timeout: float = 60.0) -> tuple[str, str | None, list[dict]]:
    """(agent, config, sensor specs): the agent built once, ``check_config(config)``, and
    with a route's ``plan`` (harness.sim.plan.GlobalPlan) ``set_global_plan``, ``setup``,
    ``sensors()`` validated, ``destroy()``; each call within ``timeout`` [s]. Any failure
    is BadInput naming the agent and the call (specs [] without a plan). The instance is
    not kept: each process that drives routes builds its own (``agent_for``)."""
    if name.endswith(".pt") and ":" not in name:
        if not Path(name).is_file():
            raise BadInput(f"--agent {name!r}: no such checkpoint file")
        if config and Path(config).resolve() != Path(name).resolve():
            raise BadInput(f"--agent {name!r} is a checkpoint: drop --agent-config {config!r}")
        name, config = "student", name
    if config and not Path(config).is_file():
        raise BadInput(f"--agent-config {config!r} does not exist")
    stops, step = watch_stops(), "loading it"
    try:
        with _check_deadline(name, timeout):
            agent = load_agent(name)
            step = "check_config()"
            agent.check_config(config)
            specs: list[dict] = []
            if plan is not None:
                step = "setup()"
                agent.set_global_plan(copy.deepcopy(plan))
                agent.setup(config)
                step = "sensors()"
                specs = agent.sensors()
                validate_sensors(specs)
                step = "destroy()"
                agent.destroy()
    except (AgentLoadError, SensorConfigurationInvalid) as exc:
        raise BadInput(str(exc) if step == "loading it" else f"agent {name!r}: {step}: {exc}") from None
    except CheckTimeout:
        raise BadInput(f"agent {name!r}: {step} did not return within {timeout:g} s (--agent-timeout): "
                       "fix the agent, or raise --agent-timeout") from None
    except BadInput:
        raise
    except BaseException as exc:  # noqa: BLE001 - the agent's failure, one line naming it
        if is_stop(exc, stops):
            raise
        if isinstance(exc, (ValueError, OSError)) and step == "check_config()":
            raise BadInput(str(exc)) from None
        raise BadInput(f"agent {name!r}: {step} failed ({_reason(exc)})") from None
    return name, config, [dict(s) for s in specs]


_PRED_SHAPES = {"path": (20, 2), "speed_wps": (10, 2)}


def split_output(out) -> tuple[Control, Prediction | None]:
    """Normalise run_step's return value to (Control, Prediction or None), checked here, not
    by the agent's own objects: TypeError unless the Control's three fields are numbers and
    a Prediction's arrays numbers of the shapes it documents; ValueError for a Control that
    is not finite (the agent's crash, never the harness's)."""
    if isinstance(out, Control):
        out = (out, None)
    if not (isinstance(out, tuple) and len(out) == 2 and isinstance(out[0], Control)):
        raise TypeError(f"run_step returned {type(out).__name__}, expected Control or (Control, Prediction)")
    control, pred = out
    values = (control.steer, control.throttle, control.brake)
    if not all(type(v) is float or isinstance(v, numbers.Real) for v in values):  # float: the common case, cheap
        raise TypeError(f"Control fields must be numbers, got {', '.join(type(v).__name__ for v in values)}")
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"non-finite control {control}")
    if pred is not None and not isinstance(pred, Prediction):
        raise TypeError("run_step's second value must be a harness.loop.agent.Prediction")
    if pred is not None:
        for field, shape in _PRED_SHAPES.items():
            value = getattr(pred, field)
            if value is not None and getattr(value, "shape", None) != shape and np.shape(value) != shape:
                raise TypeError(f"Prediction.{field} has shape {np.shape(value)}, expected {shape} "
                                "(ego frame, metres)")
            dtype = getattr(value, "dtype", None) if value is not None else None
            if value is not None and (dtype if dtype is not None else np.asarray(value).dtype).kind not in "biuf":
                raise TypeError(f"Prediction.{field} holds {np.asarray(value).dtype} values, not numbers")
    return control, pred
