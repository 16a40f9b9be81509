"""The ego models the harness can drive, by name: ``carla`` (controller.carla_car, CARLA's
Lincoln MKZ with engine, gearbox, brakes and tyres; the default) and ``kinematic``
(controller.vehicle, the kinematic bicycle PDM-Lite forecasts CARLA's car with)."""
from __future__ import annotations

import numpy as np

from controller.carla_car import CarlaCar
from controller.vehicle import EgoState, EgoVehicle

VEHICLES = {"carla": CarlaCar, "kinematic": EgoVehicle}
DEFAULT_VEHICLE = "carla"


def make_ego(vehicle: str, start: EgoState, rng: np.random.Generator) -> CarlaCar | EgoVehicle:
    """The ego model named ``vehicle`` at state ``start``, its actuator noise drawn from ``rng``."""
    if vehicle not in VEHICLES:
        raise ValueError(f"unknown vehicle {vehicle!r}: choose one of {', '.join(VEHICLES)}")
    return VEHICLES[vehicle](start, rng)
