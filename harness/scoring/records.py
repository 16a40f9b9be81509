"""The record schema: the columns of ``records.csv``, one row per route run (docs/design.md §9).

A record is written by ``harness.runs.runner`` and read by ``harness.scoring.outputs`` and
``harness.scoring.report``; this module is the one place its columns are named.

    key, route, route_id, repetition, town
                                        which route run: key = <route>_rep<k>, route the
                                        route's id in its route file, route_id the
                                        Leaderboard's (results.json: RouteScenario_<route>_rep<k>)
    status, ds, rc, is                  Leaderboard status and scores
    <infraction>                        the number of each Leaderboard infraction but
                                        outside_route_lanes (COUNT_KEYS)
    outside_lanes_pct                   share of the route driven outside the lanes [%]
    collisions_per_km, km_driven        collisions per driven km; km driven (RC x length)
    length, duration_game, duration_system, steps
                                        route length [m], simulated and wall time [s] (the
                                        Leaderboard's names), ticks
    <stability>                         one column per metric of harness.scoring.stability.METRICS,
                                        in its order (STABILITY; docs/scoring.md has the table)
    seed, message                       the route run's seed; the failure message, if any

records.jsonl, one strict JSON line per route run (``record_line``: an undefined figure is
null there, NaN in records.csv), has these, with the route's id as ``route_id``, the times
as ``game_time`` and ``wall_time`` and the Leaderboard's route id in ``lb``, and also:
episode_status (how the episode ended), hazard (the
route's first hazard type), efficiency and smoothness (Bench2Drive's, [%] and [0, 1], null
where undefined; harness.scoring.bench2drive) and lb (the Leaderboard record).
"""
from __future__ import annotations

import json
import math

from harness.scoring.infractions import KEYS
from harness.scoring.stability import METRICS

STABILITY = tuple(m.key for m in METRICS)
COUNT_KEYS = tuple(k for k in KEYS if k != "outside_route_lanes")
RECORD_FIELDS = ("key", "route_id", "repetition", "town", "status", "ds", "rc", "is", *COUNT_KEYS,
                 "outside_lanes_pct", "collisions_per_km", "km_driven", "length", "game_time", "wall_time",
                 "steps", *STABILITY, "seed", "message")
# records.csv's header: RECORD_FIELDS with the Leaderboard's names (``csv_row``)
CSV_NAMES = {"route_id": "route", "game_time": "duration_game", "wall_time": "duration_system"}
CSV_FIELDS = tuple(x for k in RECORD_FIELDS for x in ((CSV_NAMES[k], "route_id") if k == "route_id"
                                                       else (CSV_NAMES.get(k, k),)))


def csv_row(record: dict) -> dict:
    """A record as a row of records.csv (CSV_FIELDS): the Leaderboard's route id beside ours,
    its names for the times."""
    row = {CSV_NAMES.get(k, k): v for k, v in record.items()}
    lb = record.get("lb") or {}
    row["route_id"] = lb.get("route_id", f"RouteScenario_{record['route_id']}_rep{record['repetition']}")
    return row
# the columns a number may be missing from (undefined: no km driven, too few ticks): NaN in
# memory and in records.csv, null in records.jsonl
UNDEFINED_OK = ("collisions_per_km", *STABILITY)


def record_line(record: dict) -> str:
    """One line of records.jsonl: ``record`` as strict JSON (NaN and infinities as null)."""
    return json.dumps(_nulled(record), allow_nan=False) + "\n"


def parse_record(line: str, object_pairs_hook=None) -> dict:
    """A record from a line of records.jsonl (null back to NaN in UNDEFINED_OK's columns;
    a line of older runs with bare NaN reads too); json.JSONDecodeError if it is not JSON.
    ``object_pairs_hook``: as json.loads's (e.g. one refusing a key given twice)."""
    rec = json.loads(line, object_pairs_hook=object_pairs_hook)
    if isinstance(rec, dict):
        for k in UNDEFINED_OK:
            if k in rec and rec[k] is None:
                rec[k] = math.nan
    return rec


def _nulled(value):
    """``value`` with every non-finite float, at any depth, replaced by None."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _nulled(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_nulled(v) for v in value]
    return value
