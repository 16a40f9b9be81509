"""The agent API, mirroring the CARLA Leaderboard's ``AutonomousAgent`` (docs/design.md §3).

Call order per route: ``set_global_plan(plan)``, ``setup(config)``, ``sensors()`` once
(validated before the route starts), ``run_step(input_data, timestamp)`` every 0.05 s
tick, ``destroy()`` at the end (also after a crash). The agent never gets a simulator
handle: everything it sees comes through ``input_data`` keyed by its sensors' ids.

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

import importlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controller.vehicle import Control
from harness.common.errors import BadInput

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
        """The route to drive (harness.sim.plan.GlobalPlan: dense and sparse points, world frame)."""
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
    ids = set()
    for spec in specs:
        if not isinstance(spec, dict) or "type" not in spec or "id" not in spec:
            raise SensorConfigurationInvalid(f"sensor {spec!r} needs a 'type' and an 'id'")
        if spec["type"] not in SENSOR_TYPES:
            raise SensorConfigurationInvalid(
                f"sensor {spec['id']!r} has unknown type {spec['type']!r} (known: {', '.join(SENSOR_TYPES)})")
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


def load_agent(name: str) -> AutonomousAgent:
    """Instantiate an agent by CLI name or ``module:Class`` (imported, never via sys.path edits)."""
    module_name, _, cls_name = resolve_agent(name).partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise AgentLoadError(f"agent {name!r}: cannot import {module_name!r} ({exc})") from None
    except Exception as exc:  # noqa: BLE001 - an error in the user's module is reported, not raised
        raise AgentLoadError(f"agent {name!r}: importing {module_name!r} failed "
                             f"({type(exc).__name__}: {exc})") from None
    cls = getattr(module, cls_name, None)
    if cls is None or not isinstance(cls, type):
        raise AgentLoadError(f"agent {name!r}: {module_name!r} has no class {cls_name!r}")
    if not issubclass(cls, AutonomousAgent):
        raise AgentLoadError(f"agent {name!r}: {cls_name} does not subclass harness.loop.agent.AutonomousAgent")
    try:
        return cls()
    except Exception as exc:  # noqa: BLE001
        raise AgentLoadError(f"agent {name!r}: {cls_name}() failed ({type(exc).__name__}: {exc}); "
                             "an agent is built without arguments (its config goes to setup())") from None


def check_agent(name: str, config: str | None) -> tuple[str, str | None]:
    """(agent, config) to run, checked: BadInput unless the agent loads and accepts its
    config (``--agent-config``, a file). ``--agent PATH.pt`` names a student checkpoint
    (docs/design.md §3): it is ``--agent student --agent-config PATH.pt``."""
    if name.endswith(".pt") and ":" not in name:
        if not Path(name).is_file():
            raise BadInput(f"--agent {name!r}: no such checkpoint file")
        if config and Path(config).resolve() != Path(name).resolve():
            raise BadInput(f"--agent {name!r} is a checkpoint: drop --agent-config {config!r}")
        name, config = "student", name
    if config and not Path(config).is_file():
        raise BadInput(f"--agent-config {config!r} does not exist")
    try:
        load_agent(name).check_config(config)
    except (AgentLoadError, ValueError, OSError) as exc:
        raise BadInput(str(exc)) from None
    return name, config


def split_output(out) -> tuple[Control, Prediction | None]:
    """Normalise run_step's return value to (Control, Prediction or None); raises TypeError."""
    if isinstance(out, Control):
        return out, None
    if isinstance(out, tuple) and len(out) == 2 and isinstance(out[0], Control):
        if out[1] is not None and not isinstance(out[1], Prediction):
            raise TypeError("run_step's second value must be a harness.loop.agent.Prediction")
        return out[0], out[1]
    raise TypeError(f"run_step returned {type(out).__name__}, expected Control or (Control, Prediction)")
