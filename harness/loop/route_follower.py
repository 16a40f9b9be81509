"""The reference agent: follows the route at a fixed speed, blind to everything else.

Lateral PID (PDM-Lite gains, speed-dependent lookahead) on the dense route; SimLingo's
speed PID towards a fixed target speed; no hazard logic at all, so it runs red lights,
stop signs and into obstacles. It is the harness's test agent and the yardstick any
learned agent should beat. ``--agent-config`` may name a JSON file ``{"speed": 6.0}``.
"""
from __future__ import annotations

import json

import numpy as np

from controller.pid import LateralPID, SpeedPID
from controller.vehicle import Control
from harness.loop.agent import AutonomousAgent
from harness.sim.plan import to_ego

TARGET_SPEED = 6.0  # [m/s] (21.6 km/h): below every speed limit of our towns
SEARCH = 30  # dense points (1 m) searched ahead for the nearest route point


class RouteFollower(AutonomousAgent):
    def setup(self, config: str | None) -> None:
        super().setup(config)
        self.speed = TARGET_SPEED
        if config:
            with open(config) as f:
                self.speed = float(json.load(f).get("speed", TARGET_SPEED))
        self.lateral, self.longitudinal = LateralPID(), SpeedPID()
        self.index = 0

    def sensors(self) -> list[dict]:
        return [{"type": "pose", "id": "pose"}, {"type": "speed", "id": "speed"}]

    def run_step(self, input_data: dict, timestamp: float) -> Control:
        x, y, yaw = input_data["pose"]
        v = float(input_data["speed"])
        xy = self.plan.xy
        j = min(self.index + SEARCH, len(xy))
        self.index += int(np.argmin(np.hypot(*(xy[self.index:j] - (x, y)).T)))
        ahead = to_ego(xy[self.index:self.index + 20], x, y, yaw)
        ahead = ahead[ahead[:, 0] > 0.0] if (ahead[:, 0] > 0.0).any() else ahead[-1:]
        steer = self.lateral.step(ahead, v)
        throttle, brake = self.longitudinal.step(self.speed, v)
        return Control(round(steer, 3), throttle, brake)
