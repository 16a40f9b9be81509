"""SimLingo's waypoint controller: predicted path + speed waypoints -> Control (docs/design.md §8).

Stepped once per 0.05 s tick (docs/design.md §8.2; our own implementation):

- Lateral: the path (ego frame, x forward, y left) with the ego origin prepended is
  resampled every PATH_STEP = 0.1 m of arc length (linear interpolation; SimLingo uses a
  monotone cubic, which on 1 m-spaced points moves the lookahead point by millimetres) and
  fed to the PDM-Lite lateral PID (controller.pid.LateralPID: lookahead clip(0.9755 v[km/h]
  + 1.915, 24, 105) samples = 2.4 .. 10.5 m, Kp 3.1184, Ki 0.6406, Kd 1.3783, window 6);
  the lookahead point in one compiled pass (controller.lookahead, equal to
  ``LateralPID.target(resample_path(path), speed)`` bit for bit). Steer rounded to 3
  decimals; **positive steer turns right** (controller.vehicle.Control), so a path bending
  left (y > 0) gives a negative steer.
- Longitudinal: desired speed = 2 ||w(0.25 s) - w(0.75 s)|| [m/s] from the speed
  waypoints; SimLingo's speed PID (controller.pid.SpeedPID: Kp 1.75, Ki 1.0, Kd 2.0,
  window 20, error clipped to [0, 1] m/s) with its brake rule: brake when the desired speed
  is below 0.4 m/s or speed / desired > 1.1.
- Creep: after more than STUCK_TICKS consecutive ticks below 0.1 m/s, CREEP_TICKS ticks of
  throttle >= CREEP_THROTTLE with the brake released, then the count restarts.
"""
from __future__ import annotations

import numpy as np

from controller.lookahead import lookahead_point
from controller.pid import LateralPID, SpeedPID
from controller.vehicle import Control

PATH_STEP = 0.1  # resampling step of the path [m]
STUCK_SPEED = 0.1  # [m/s] below this the ego counts as standing
STUCK_TICKS = 800  # 40 s at 20 Hz
CREEP_TICKS = 15  # 0.75 s
CREEP_THROTTLE = 0.4  # minimum throttle while creeping [-]


def resample_path(path: np.ndarray, step: float = PATH_STEP) -> np.ndarray:
    """(N, 2) path [m] -> points every ``step`` m of arc length from ``step`` on, measured
    from the ego origin (prepended); a degenerate path (no length) -> its last point."""
    # the closed loop runs controller.lookahead, which replicates this and LateralPID.target
    p = np.asarray(path, dtype=float)
    pts = np.empty((len(p) + 1, 2))
    pts[0], pts[1:] = 0.0, p
    d = pts[1:] - pts[:-1]
    cum = np.empty(len(pts))  # arc length at each point [m]
    cum[0] = 0.0
    np.hypot(d[:, 0], d[:, 1]).cumsum(out=cum[1:])
    if cum[-1] < step:
        return pts[-1:]
    s = np.arange(step, cum[-1] + 1e-9, step)
    out = np.empty((len(s), 2))
    out[:, 0] = np.interp(s, cum, pts[:, 0])
    out[:, 1] = np.interp(s, cum, pts[:, 1])
    return out


def desired_speed(speed_wps: np.ndarray) -> float:
    """2 x distance between the 0.25 s and 0.75 s speed waypoints (10, 2) [m] -> [m/s]."""
    return 2.0 * float(np.hypot(*(speed_wps[0] - speed_wps[2])))


class SimLingoController:
    """Stateful (PID windows, stuck counter): one instance per route."""

    def __init__(self) -> None:
        self.lateral = LateralPID()
        self.longitudinal = SpeedPID()
        self.stuck = 0  # consecutive ticks below STUCK_SPEED
        self.creep = 0  # creep ticks left

    def step(self, path: np.ndarray, speed_wps: np.ndarray, speed: float) -> Control:
        """Control for path (20, 2) and speed waypoints (10, 2) in the ego frame (x forward,
        y left) [m] at ego speed [m/s]."""
        # LateralPID.target(resample_path(path), speed), in one compiled pass (controller.lookahead)
        tx, ty = lookahead_point(path, self.lateral.lookahead(speed), PATH_STEP)
        steer = round(self.lateral.steer_to(tx, ty), 3)
        throttle, brake = self.longitudinal.step(desired_speed(speed_wps), speed)
        self.stuck = self.stuck + 1 if speed < STUCK_SPEED else 0
        if self.stuck > STUCK_TICKS:
            self.creep, self.stuck = CREEP_TICKS, 0
        if self.creep > 0:
            self.creep -= 1
            throttle, brake = max(throttle, CREEP_THROTTLE), 0.0
        return Control(steer, throttle, brake)
