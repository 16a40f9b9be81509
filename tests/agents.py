"""Agents for tests: misbehaving on purpose, loaded as ``tests.agents:<Class>``."""
from __future__ import annotations

import os
import signal

from controller.vehicle import Control
from harness.loop.route_follower import RouteFollower
from harness.loop.agent import AutonomousAgent
from harness.expert.driver import Expert


class SteerRight(AutonomousAgent):
    """A constant right steer (0.15, a 24 m circle) at about 5 m/s: must leave the road."""

    def sensors(self):
        return [{"type": "speed", "id": "speed"}]

    def run_step(self, input_data, timestamp):
        return Control(steer=0.15, throttle=0.6 if input_data["speed"] < 5 else 0.0)


class Standstill(AutonomousAgent):
    def run_step(self, input_data, timestamp):
        return Control(brake=1.0)


class FaultyFollower(RouteFollower):
    """Follows the route, but on route 1 raises, on route 2 returns NaN, and on route 3
    (when FAULTY_KILL is set) kills its own worker process with SIGKILL, after 2 s."""

    def run_step(self, input_data, timestamp):
        control = super().run_step(input_data, timestamp)
        if timestamp > 2.0:
            rid = self.plan.route_id
            if rid == "1":
                raise RuntimeError("agent bug on purpose")
            if rid == "2":
                return Control(steer=float("nan"), throttle=0.5)
            if rid == "3" and os.environ.get("FAULTY_KILL"):
                os.kill(os.getpid(), signal.SIGKILL)
        return control


def _progress_s(agent) -> float:
    """Route arc length [m] at the agent's own nearest route point."""
    return float(agent.plan.s[agent.index])


class LightStopper(RouteFollower):
    """Follows the route and stands before the stop line while the route's light is red
    or yellow (privileged: reads the light states)."""

    def sensors(self):
        return super().sensors() + [{"type": "world", "id": "world"}]

    def run_step(self, input_data, timestamp):
        control = super().run_step(input_data, timestamp)
        _, lights, _ = input_data["world"]
        s = _progress_s(self)
        passages = [p for p in self.plan.passages if p.tls]
        for p, state in zip(passages, lights):
            if state in (0, 1, 2, 3) and 0.0 < p.s_in - s < 12.0:  # r, R, y, Y
                return Control(steer=control.steer, brake=1.0)
        return control


class StopSignStopper(RouteFollower):
    """Follows the route and stops for 1 s with its front near the line at stop signs."""

    def setup(self, config):
        super().setup(config)
        self.waited: dict[str, float] = {}

    def run_step(self, input_data, timestamp):
        control = super().run_step(input_data, timestamp)
        s, v = _progress_s(self), input_data["speed"]
        for p in self.plan.passages:
            if p.state in ("s", "w") and 0.0 < p.s_in - s < 5.0 and self.waited.get(p.junction, 0.0) < 1.0:
                if v < 0.05:
                    self.waited[p.junction] = self.waited.get(p.junction, 0.0) + 0.05
                return Control(steer=control.steer, brake=1.0)
        return control


class BevExpert(Expert):
    """The expert, also asking for the BEV and keeping every BEV it was given, by game time
    (ms) and ego pose."""

    seen: dict = {}

    def sensors(self):
        return super().sensors() + [{"type": "bev", "id": "bev"}]

    def run_step(self, input_data, timestamp):
        BevExpert.seen[(round(timestamp * 1000), *input_data["pose"])] = input_data["bev"].copy()
        return super().run_step(input_data, timestamp)


class NeedsArguments(AutonomousAgent):
    """Cannot be built as the harness builds an agent (without arguments)."""

    def __init__(self, config):
        super().__init__()
        self.config = config

    def run_step(self, input_data, timestamp):
        return Control(brake=1.0)
