"""The ego models the harness can drive, by name: ``carla`` (controller.carla_car, CARLA's
Lincoln MKZ with engine, gearbox, brakes and tyres; the default) and ``kinematic``
(controller.vehicle, the kinematic bicycle PDM-Lite forecasts CARLA's car with).

The CARLA-like car is compiled (numba) and imported when a model is first asked for, so
that the commands that drive no ego (``--help``, ``score``, ``report``, ...) start without
loading the compiler (about 0.5 s)."""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from controller.vehicle import EgoState, EgoVehicle

if TYPE_CHECKING:
    from controller.carla_car import CarlaCar

VEHICLES = ("carla", "kinematic")
DEFAULT_VEHICLE = "carla"


def ego_class(vehicle: str) -> type:
    """The class of the ego model named ``vehicle``."""
    if vehicle == "carla":
        from controller.carla_car import CarlaCar
        return CarlaCar
    if vehicle == "kinematic":
        return EgoVehicle
    raise ValueError(f"unknown vehicle {vehicle!r}: choose one of {', '.join(VEHICLES)}")


def make_ego(vehicle: str, start: EgoState, rng: np.random.Generator) -> CarlaCar | EgoVehicle:
    """The ego model named ``vehicle`` at state ``start``, its actuator noise drawn from ``rng``."""
    return ego_class(vehicle)(start, rng)
