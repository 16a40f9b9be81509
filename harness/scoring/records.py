"""The record schema: the columns of ``records.csv``, one row per route run (SPEC §9).

A record is written by ``harness.runs.runner`` and read by ``harness.scoring.outputs`` and
``harness.scoring.report``; this module is the one place its columns are named.

    key, route_id, repetition, town     which route run (key = <route>_rep<k>)
    status, ds, rc, is                  Leaderboard status and scores
    <infraction>                        the number of each Leaderboard infraction but
                                        outside_route_lanes (COUNT_KEYS)
    outside_lanes_pct                   share of the route driven outside the lanes [%]
    collisions_per_km, km_driven        collisions per driven km; km driven (RC x length)
    length, game_time, wall_time, steps route length [m], simulated and wall time [s], ticks
    <stability>                         one column per metric of harness.scoring.stability.METRICS,
                                        in its order (STABILITY; docs/scoring.md has the table)
    seed, message                       the route run's seed; the failure message, if any

records.jsonl has these and also: episode_status (how the episode ended), hazard (the
route's first hazard type), efficiency and smoothness (Bench2Drive's, [%] and [0, 1], null
where undefined; harness.scoring.bench2drive) and lb (the Leaderboard record).
"""
from __future__ import annotations

from harness.scoring.infractions import KEYS
from harness.scoring.stability import METRICS

STABILITY = tuple(m.key for m in METRICS)
COUNT_KEYS = tuple(k for k in KEYS if k != "outside_route_lanes")
RECORD_FIELDS = ("key", "route_id", "repetition", "town", "status", "ds", "rc", "is", *COUNT_KEYS,
                 "outside_lanes_pct", "collisions_per_km", "km_driven", "length", "game_time", "wall_time",
                 "steps", *STABILITY, "seed", "message")
