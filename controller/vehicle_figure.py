"""The figure of docs/vehicle.md: full throttle, braking and a lane change, CARLA's car
(controller.carla_car) beside the kinematic bicycle (controller.vehicle), the same
commands for both, actuator noise off.

    python -m controller.vehicle_figure docs/results/vehicle/vehicle.png
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from controller.ego import ego_class
from controller.vehicle import DT, Control, EgoState


def _drive(name: str, v0: float, controls) -> np.ndarray:
    """(T, 5) rows t, x, y, yaw, v of model ``name`` from speed v0 under ``controls(k, v)``."""
    ego = ego_class(name)(EgoState(0.0, 0.0, 0.0, v0), np.random.default_rng(0), noise=False)
    rows, s = [(0.0, 0.0, 0.0, 0.0, v0)], ego.state
    for k in range(1, 10_000):
        c = controls(k, s.v)
        if c is None:
            break
        s = ego.step(c)
        rows.append((k * DT, s.x, s.y, s.yaw, s.v))
    return np.array(rows)


def _throttle(k: int, v: float) -> Control | None:
    return Control(0.0, 1.0, 0.0) if k * DT <= 20.0 else None


def _brake_from_50(name: str) -> np.ndarray:
    """Full throttle to 50 km/h, then full brake to a stop: the braking part, t from 0."""
    state = {"braking_at": None}

    def controls(k, v):
        if state["braking_at"] is None and v >= 50 / 3.6:
            state["braking_at"] = k
        if state["braking_at"] is None:
            return Control(0.0, 1.0, 0.0)
        return Control(0.0, 0.0, 1.0) if v > 0.01 or k == state["braking_at"] else None
    rows = _drive(name, 0.0, controls)
    i = state["braking_at"] - 1
    out = rows[i:].copy()
    out[:, 0] -= out[0, 0]
    out[:, 1] -= out[0, 1]
    return out


def _lane_change(k: int, v: float) -> Control | None:
    """At 50 km/h: steer 0.05 left for 1.5 s, 0.05 right for 1.5 s, straight for 2 s; a
    speed-holding throttle (proportional) keeps near 50 km/h."""
    t = k * DT
    if t > 5.0:
        return None
    steer = -0.05 if t <= 1.5 else 0.05 if t <= 3.0 else 0.0
    return Control(steer, min(max(0.3 + 0.5 * (50 / 3.6 - v), 0.0), 1.0), 0.0)


def plot(out: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.8))
    for name, style in (("carla", "-"), ("kinematic", "--")):
        a = _drive(name, 0.0, _throttle)
        ax[0].plot(a[:, 0], a[:, 4] * 3.6, style, label=name)
        b = _brake_from_50(name)
        ax[1].plot(b[:, 0], b[:, 4] * 3.6, style, label=f"{name}: {b[-1, 1]:.1f} m")
        c = _drive(name, 50 / 3.6, _lane_change)
        ax[2].plot(c[:, 1], c[:, 2], style, label=name)
    ax[0].set(title="full throttle from rest", xlabel="t [s]", ylabel="speed [km/h]")
    ax[1].set(title="full brake from 50 km/h", xlabel="t [s]", ylabel="speed [km/h]")
    ax[2].set(title="lane change at 50 km/h: steer 0.05 left, right", xlabel="x [m]", ylabel="y [m]")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend()
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    return out


if __name__ == "__main__":
    print(plot(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/results/vehicle/vehicle.png")))
