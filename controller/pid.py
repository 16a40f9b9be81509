"""PID controllers of the field's waypoint agents, stepped once per 0.05 s tick.

All run at 20 Hz with per-sample differences and window means (no dt scaling), so the
gains are only valid at that rate (docs/design.md §8.1).

- :class:`PID` (TransFuser / SimLingo speed PID): a FIFO of the last ``n`` errors,
  pre-filled with zeros; integral = mean of the FIFO, derivative = newest - previous.
- :class:`LateralPID` (PDM-Lite / SimLingo lateral PID): the error list starts empty and
  keeps the last ``n``; derivative 0 on the first sample; output clipped to [-1, 1].
  Its error is the angle to a lookahead point on the path, in degrees / 90, positive
  when the point lies to the right (CARLA steer sign).
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

# PDM-Lite / SimLingo lateral PID (docs/design.md §8.2), Bayesian-optimised at 20 Hz
LAT_KP, LAT_KI, LAT_KD, LAT_N = 3.118357247806046, 0.6406067986034124, 1.3782508892109167, 6
# lookahead index on a 0.1 m path: clip(a * v[km/h] + b, 24, 105) -> 2.4 m ... 10.5 m
LOOK_A, LOOK_B, LOOK_MIN, LOOK_MAX = 0.9755321901954155, 1.9152884533402488, 24, 105
# SimLingo speed PID (docs/design.md §8.2)
SPEED_KP, SPEED_KI, SPEED_KD, SPEED_N = 1.75, 1.0, 2.0, 20


class PID:
    """PID with a zero-prefilled error window: out = Kp e + Ki mean(window) + Kd (e - e_prev)."""

    def __init__(self, kp: float, ki: float, kd: float, n: int):
        self.kp, self.ki, self.kd = kp, ki, kd
        self.window = deque([0.0] * n, maxlen=n)

    def step(self, error: float) -> float:
        self.window.append(error)
        derivative = self.window[-1] - self.window[-2] if len(self.window) > 1 else 0.0
        return self.kp * error + self.ki * sum(self.window) / len(self.window) + self.kd * derivative


class LateralPID:
    """Steer from a path: angle to a speed-dependent lookahead point, PID, clipped to [-1, 1]."""

    def __init__(self, kp: float = LAT_KP, ki: float = LAT_KI, kd: float = LAT_KD, n: int = LAT_N):
        self.kp, self.ki, self.kd = kp, ki, kd
        self.errors: deque[float] = deque(maxlen=n)

    @staticmethod
    def lookahead(speed: float) -> float:
        """Lookahead distance [m] along the path at ego speed [m/s]: 2.4 m ... 10.5 m."""
        return min(max(LOOK_A * speed * 3.6 + LOOK_B, LOOK_MIN), LOOK_MAX) * 0.1

    def step(self, path_ego: np.ndarray, speed: float) -> float:
        """Steer in [-1, 1] (positive = right) for a path in the ego frame (x fwd, y left) [m]:
        ``steer_to`` the ``target`` point."""
        return self.steer_to(*self.target(path_ego, speed))

    def target(self, path_ego: np.ndarray, speed: float) -> tuple[float, float]:
        """The lookahead point (x, y) [m] of a path (N, 2) of points from the ego onwards,
        ego frame: the first point whose distance along the path, from the ego origin
        through every point (the sum of the segment lengths), reaches the lookahead
        distance at this speed; the last point if the path is shorter."""
        pts = np.asarray(path_ego, dtype=float)
        d = pts.copy()  # segment vectors from the ego origin on: d[0] = pts[0] - (0, 0)
        d[1:] -= pts[:-1]
        cum = np.hypot(d[:, 0], d[:, 1])
        cum.cumsum(out=cum)  # arc length at each point [m]
        k = int(cum.searchsorted(self.lookahead(speed)))
        tx, ty = pts[min(k, len(pts) - 1)]
        return float(tx), float(ty)

    def steer_to(self, tx: float, ty: float) -> float:
        """Steer in [-1, 1] (positive = right) towards the lookahead point (tx, ty) [m], ego
        frame (x fwd, y left): the PID on its angle."""
        angle_left = math.atan2(ty, tx)  # CCW angle to the target in the ego frame
        error = -math.degrees(angle_left) / 90.0  # positive = target to the right
        derivative = error - self.errors[-1] if self.errors else 0.0
        self.errors.append(error)
        out = self.kp * error + self.kd * derivative + self.ki * sum(self.errors) / len(self.errors)
        return min(max(out, -1.0), 1.0)


class SpeedPID:
    """Throttle and brake for a desired speed (SimLingo rule): brake if the desired speed is
    below 0.4 m/s or the ego is more than 10 % too fast; else a PID on the speed error
    clipped to [0, 1] m/s, throttle clipped to [0, 1]."""

    BRAKE_SPEED = 0.4  # desired speed [m/s] below which the controller brakes
    BRAKE_RATIO = 1.1  # speed / desired above which it brakes
    CLIP_DELTA = 1.0  # speed error clip [m/s]

    def __init__(self):
        self.pid = PID(SPEED_KP, SPEED_KI, SPEED_KD, SPEED_N)

    def step(self, desired: float, speed: float) -> tuple[float, float]:
        """(throttle, brake) for desired and current speed [m/s]."""
        brake = desired < self.BRAKE_SPEED or (desired > 0 and speed / desired > self.BRAKE_RATIO)
        delta = min(max(desired - speed, 0.0), self.CLIP_DELTA)
        throttle = min(max(self.pid.step(delta), 0.0), 1.0)
        return (0.0, 1.0) if brake else (throttle, 0.0)
