"""Agents for tests: misbehaving on purpose, loaded as ``tests.agents:<Class>``."""
from __future__ import annotations

import os
import signal

from controller.vehicle import Control
from harness.route_follower import RouteFollower
from harness.agent import AutonomousAgent


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
