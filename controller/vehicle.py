"""The ego vehicle model: a kinematic bicycle with throttle/brake speed dynamics.

The harness integrates the ego itself (SUMO only mirrors the result, docs/design.md §3), so the
agent's own steering errors show: nothing pulls the ego back to a lane centre.

Model (constants fitted for CARLA's default car in the PDM-Lite / World-on-Rails
kinematic bicycle model, docs/design.md §8.4; our own implementation):

    delta = -STEER_TO_WHEEL * steer                   front wheel angle [rad], CCW-positive (steer > 0 = right)
    beta  = atan(LR / (LF + LR) * tan(delta))         slip angle at the centre [rad]
    x    += v cos(yaw + beta) dt,  y += v sin(yaw + beta) dt
    yaw  += (v / LR) sin(beta) dt

Speed per step, in km/h as fitted: braking -> a 7th-order polynomial of v with no
constant term (about -9 m/s^2 at 30 km/h); throttle < 0.3 -> speed kept (rolling);
else a polynomial in (v, throttle) (about +6.8 m/s^2 at full throttle from 10 km/h).

Conventions. ``Control.steer`` in [-1, 1], **positive turns right** (the CARLA /
Leaderboard convention every agent in the field uses); throttle in [0, 1]; brake in
[0, 1], braking when brake > 0.5 (the fitted model has a binary brake). State in the
SUMO world frame: x east, y north [m], yaw [rad] counter-clockwise from +x, v [m/s].

Actuation imperfection (docs/design.md §8.4; docs/closed_loop.md, "One tick"): the applied steer follows the command with a
first-order lag (time constant STEER_LAG) plus seeded Gaussian noise (STEER_NOISE),
and throttle gets seeded noise (THROTTLE_NOISE), so even a perfect agent's trajectory
is slightly imperfect.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DT = 0.05  # simulation step [s] (20 Hz, as the CARLA leaderboard)
LENGTH = 4.9  # ego length [m]
WIDTH = 2.1  # ego width [m]

STEER_TO_WHEEL = 0.36848336  # front wheel angle at full lock [rad]
LF = -0.090769015  # fitted "front wheel base" [m] (not geometric)
LR = 1.4178275  # fitted "rear wheel base" [m]
THROTTLE_DEADBAND = 0.3  # below this throttle the speed is kept [-]

# speed polynomials, km/h per 0.05 s step (docs/design.md §8.4)
_BRAKE = np.array([9.31711370e-03, 8.20967431e-02, -2.83832427e-03, 5.06587474e-05,
                   -4.90357228e-07, 2.44419284e-09, -4.91381935e-12])
_THROTTLE = np.array([9.63873001e-01, 4.37535692e-04, -3.80192912e-01, 1.74950069e+00,
                      9.16787414e-02, -7.05461530e-02, -1.05996152e-03, 6.71079346e-04])

STEER_LAG = 0.1  # time constant of the steering actuator [s]
STEER_NOISE = 0.01  # std of steering noise [-] per step
THROTTLE_NOISE = 0.02  # std of throttle noise [-] per step


def _clip(v: float, lo: float, hi: float) -> float:
    """Scalar clip (numpy's clip costs microseconds per call on the per-tick path)."""
    return float(min(max(v, lo), hi))


@dataclass(frozen=True)
class Control:
    """An agent's command: steer in [-1, 1] (positive = right), throttle and brake in [0, 1]."""

    steer: float = 0.0
    throttle: float = 0.0
    brake: float = 0.0

    def is_finite(self) -> bool:
        return all(math.isfinite(v) for v in (self.steer, self.throttle, self.brake))

    def clipped(self) -> "Control":
        return Control(_clip(self.steer, -1.0, 1.0), _clip(self.throttle, 0.0, 1.0), _clip(self.brake, 0.0, 1.0))


@dataclass(frozen=True)
class EgoState:
    """Ego pose and speed in the world frame: x, y [m], yaw [rad, CCW from +x], v [m/s]."""

    x: float
    y: float
    yaw: float
    v: float


def next_speed(v: float, throttle: float, brake: bool) -> float:
    """Speed [m/s] after one 0.05 s step from speed v [m/s] (fitted model, km/h inside)."""
    k = v * 3.6
    if brake:
        powers = k ** np.arange(1, 8)
        k_next = float(_BRAKE @ powers)
    elif throttle < THROTTLE_DEADBAND:
        k_next = k
    else:
        t = throttle
        feats = np.array([k, k * k, t, t * t, k * t, k * t * t, k * k * t, k * k * t * t])
        k_next = float(_THROTTLE @ feats)
    return max(k_next, 0.0) / 3.6


def bicycle_step(s: EgoState, steer: float, v_next: float, dt: float = DT) -> EgoState:
    """Pose after one step with the applied steer (positive = right) and new speed."""
    delta = -STEER_TO_WHEEL * steer  # CCW-positive wheel angle: right steer turns clockwise
    beta = math.atan(LR / (LF + LR) * math.tan(delta))
    x = s.x + v_next * math.cos(s.yaw + beta) * dt
    y = s.y + v_next * math.sin(s.yaw + beta) * dt
    yaw = s.yaw + v_next / LR * math.sin(beta) * dt
    yaw = (yaw + math.pi) % (2 * math.pi) - math.pi
    return EgoState(x, y, yaw, v_next)


class EgoVehicle:
    """The ego: state, steering actuator with lag, seeded actuation noise."""

    def __init__(self, start: EgoState, rng: np.random.Generator, noise: bool = True):
        self.state = start
        self.rng = rng
        self.noise = noise
        self.steer_applied = 0.0

    def step(self, control: Control, dt: float = DT) -> EgoState:
        """Apply one control for dt seconds; returns the new state."""
        c = control.clipped()
        steer_cmd, throttle = c.steer, c.throttle
        if self.noise:
            steer_cmd += float(self.rng.normal(0.0, STEER_NOISE))
            throttle = _clip(throttle + self.rng.normal(0.0, THROTTLE_NOISE), 0.0, 1.0)
        alpha = dt / (STEER_LAG + dt)
        self.steer_applied += alpha * (steer_cmd - self.steer_applied)
        self.steer_applied = _clip(self.steer_applied, -1.0, 1.0)
        v_next = next_speed(self.state.v, throttle, c.brake > 0.5)
        self.state = bicycle_step(self.state, self.steer_applied, v_next, dt)
        return self.state
