"""Scene cue vector s_t of docs/design.md §6.3 / paper Table 1, from a dataset episode's arrays.

One row per frame, one column per cue, in ``CUES`` order (raw values, dataset units; see
docs/dataset.md for their definitions and frames). ``scimm.modes`` turns them into the
transition adjustment A(s_t) and noise scales gamma_j(s_t) of paper eq. 8-9.

    group        cue                  unit / values
    navigation   command              CARLA RoadOption at the ego: 1 left, 2 right, 3 straight, 4 follow lane
                 next_command         RoadOption of the next junction
                 junction             1 inside a junction of the route
    path         curvature            route curvature at the ego, left positive [1/m]
                 curvature_change     curvature 10 m ahead minus here [1/m]
                 lateral_offset       ego distance from the route centre line, left positive [m]
                 lateral_change       change of it since the previous frame [m]
    speed        ego_speed            [m/s]
                 target_speed         the expert's target speed [m/s]
                 speed_drop           max(0, ego speed - target) [m/s]
    hazard       vehicle              1 if a vehicle (or the leader) set the target speed
                 walker               1 if a walker set it
                 light                1 if a red/yellow light set it
                 stop                 1 if a stop sign set it
    recovery     changed_route        1 while the expert's path is shifted from the route (bypass)
                 recovery             1 while that shift is shrinking (returning to the lane)
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

CUES = ("command", "next_command", "junction",
        "curvature", "curvature_change", "lateral_offset", "lateral_change",
        "ego_speed", "target_speed", "speed_drop",
        "vehicle", "walker", "light", "stop",
        "changed_route", "recovery")

# cue -> dataset array(s) it is read from (several = logical or of hazard flags)
_SOURCE = {"command": ("command",), "next_command": ("next_command",), "junction": ("cue_junction",),
           "curvature": ("cue_curvature",), "curvature_change": ("cue_curvature_change",),
           "lateral_offset": ("cue_lateral_offset",), "lateral_change": ("cue_lateral_change",),
           "ego_speed": ("cue_speed",), "target_speed": ("cue_target_speed",), "speed_drop": ("cue_speed_drop",),
           "vehicle": ("flag_vehicle", "flag_leader"), "walker": ("flag_walker",), "light": ("flag_light",),
           "stop": ("flag_stop",), "changed_route": ("cue_changed_route",), "recovery": ("cue_recovery",)}


def cue_vector(arrays: Mapping[str, np.ndarray]) -> np.ndarray:
    """(T, 16) float64 cue matrix s_t, columns in ``CUES`` order, from an episode's arrays
    (``harness.expert.dataset.Episode.a`` or an ``np.load`` of the episode file)."""
    cols = []
    for name in CUES:
        parts = [np.asarray(arrays[k], dtype=float) for k in _SOURCE[name]]
        cols.append(np.maximum.reduce(parts) if len(parts) > 1 else parts[0])
    return np.stack(cols, axis=-1)


def column(s: np.ndarray, name: str) -> np.ndarray:
    """The column (...,) of cue ``name`` in cue matrices s (..., 16)."""
    return s[..., CUES.index(name)]
