"""Leaderboard scoring as pure functions: infraction lists -> route record -> global
record -> results JSON (notes leaderboard2.md §5-§6). Works the same on our runs and on
a results file written by CARLA's leaderboard, because it reads only what such a file
holds: the message lists, the route scores and the meta.

Rules: ``lb2.0`` (default), ``lb2.1`` (additive weights, IS = prod(1 - q) / (1 + S)),
``b2d`` (Bench2Drive: like 2.0 but minimum-speed messages carry no penalty).
Rounding as the leaderboard: Python ``round`` to 6 decimals for scores, 3 for standard
deviations, meta and per-km rates.
"""
from __future__ import annotations

import math

from harness.scoring.infractions import KEYS
from harness.scoring.statuses import COMPLETED, ENDING_INFRACTIONS, FAILED, PERFECT, failed

RULES = ("lb2.0", "lb2.1", "b2d")
# multiplicative penalty per event, Leaderboard 2.0
PENALTY = {"collisions_pedestrian": 0.5, "collisions_vehicle": 0.6, "collisions_layout": 0.65,
           "red_light": 0.7, "stop_infraction": 0.8, "scenario_timeouts": 0.7,
           "yield_emergency_vehicle_infractions": 0.7}
MIN_SPEED_BASE = 0.7  # min-speed factor at 0 % of the traffic's speed (lb2.0)
# additive weights, Leaderboard 2.1
WEIGHT = {"collisions_pedestrian": 1.0, "collisions_vehicle": 0.7, "collisions_layout": 0.6,
          "red_light": 0.4, "stop_infraction": 0.25, "scenario_timeouts": 0.4,
          "yield_emergency_vehicle_infractions": 0.4}
MIN_SPEED_WEIGHT = 0.4
LABELS = ["Avg. driving score", "Avg. route completion", "Avg. infraction penalty", "Collisions with pedestrians",
          "Collisions with vehicles", "Collisions with layout", "Red lights infractions", "Stop sign infractions",
          "Off-road infractions", "Route deviations", "Route timeouts", "Agent blocked",
          "Yield emergency vehicles infractions", "Scenario timeouts", "Min speed infractions"]
_VALUE_KEYS = ["collisions_pedestrian", "collisions_vehicle", "collisions_layout", "red_light", "stop_infraction",
               "outside_route_lanes", "route_dev", "route_timeout", "vehicle_blocked",
               "yield_emergency_vehicle_infractions", "scenario_timeouts", "min_speed_infractions"]


class ScoreError(ValueError):
    """A results file that is not Leaderboard-shaped."""


def min_speed_percent(message: str) -> float:
    """p from 'Average speed is {p}% of the surrounding traffic's one'."""
    return float(message.split()[3].rstrip("%"))


def outside_lanes(message: str) -> tuple[float, float]:
    """(metres, percentage) from 'Agent went outside its route lanes for about {m} meters ({q}% ...'."""
    tokens = message.split()
    return float(tokens[8]), float(tokens[10].lstrip("(").rstrip("%"))


def infraction_penalty(infractions: dict[str, list[str]], rules: str = "lb2.0") -> float:
    """IS of one route (unrounded) from its infraction lists."""
    if rules not in RULES:
        raise ScoreError(f"unknown rules {rules!r} (known: {', '.join(RULES)})")
    outside = 1.0
    for m in infractions.get("outside_route_lanes", []):
        outside *= 1.0 - outside_lanes(m)[1] / 100.0
    if rules == "lb2.1":
        s = sum(WEIGHT[k] * len(infractions.get(k, [])) for k in WEIGHT)
        s += sum(MIN_SPEED_WEIGHT * (1 - min_speed_percent(m) / 100.0)
                 for m in infractions.get("min_speed_infractions", []))
        return outside / (1.0 + s)
    penalty = outside
    for k, factor in PENALTY.items():
        penalty *= factor ** len(infractions.get(k, []))
    if rules == "lb2.0":
        for m in infractions.get("min_speed_infractions", []):
            penalty *= 1.0 - (1.0 - MIN_SPEED_BASE) * (1.0 - min_speed_percent(m) / 100.0)
    return penalty


def route_status(score_route: float, infractions: dict[str, list[str]], crash: str = "") -> str:
    """Leaderboard status text of a route: Perfect / Completed / Failed[ - message]. The
    message is that of the route-ending infraction present (harness.scoring.statuses), else
    the caller's crash message."""
    n = sum(len(v) for v in infractions.values())
    if score_route >= 100:
        return PERFECT if n == 0 else COMPLETED
    msg = crash
    for ending in ENDING_INFRACTIONS:  # in order of precedence: the last present wins
        if infractions.get(ending.infraction):
            msg = ending.message
    return failed(msg)


def route_record(index: int, route_id: str, infractions: dict[str, list[str]], rc: float,
                 meta: dict, rules: str = "lb2.0", crash: str = "") -> dict:
    """A Leaderboard results record. rc in [0, 100]; meta: route_length [m],
    duration_game [s], duration_system [s]; crash: the caller's failure message."""
    inf = {k: list(infractions.get(k, [])) for k in KEYS}
    penalty = infraction_penalty(inf, rules)
    return {
        "index": index, "route_id": route_id, "status": route_status(rc, inf, crash),
        "num_infractions": sum(len(v) for v in inf.values()), "infractions": inf,
        "scores": {"score_route": round(rc, 6), "score_penalty": round(penalty, 6),
                   "score_composed": round(max(rc * penalty, 0.0), 6)},
        "meta": {"route_length": round(meta["route_length"], 3), "duration_game": round(meta["duration_game"], 3),
                 "duration_system": round(meta["duration_system"], 3)},
    }


def rescore(record: dict, rules: str = "lb2.0") -> dict:
    """The same record with its scores recomputed from its infraction lists and RC."""
    try:
        inf, rc = record["infractions"], float(record["scores"]["score_route"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ScoreError(f"record {record.get('route_id', '?')}: missing {exc}") from None
    if not isinstance(inf, dict) or not all(isinstance(v, list) for v in inf.values()):
        raise ScoreError(f"record {record.get('route_id', '?')}: 'infractions' must map each key to a list of messages")
    penalty = infraction_penalty(inf, rules)
    out = dict(record)
    out["scores"] = {"score_route": round(rc, 6), "score_penalty": round(penalty, 6),
                     "score_composed": round(max(rc * penalty, 0.0), 6)}
    out["num_infractions"] = sum(len(v) for v in inf.values())
    return out


def global_record(records: list[dict], total: int) -> dict:
    """The global record over ``total`` planned route runs (never-run ones count as 0)."""
    n = max(total, 1)
    keys = ("score_composed", "score_route", "score_penalty")
    # paper eq. 14: DS, RC and IS are means over the routes
    means = {k: round(sum(r["scores"][k] for r in records) / n, 6) for k in keys}
    std = {k: 0.0 if n == 1 else round(math.sqrt(sum((r["scores"][k] - means[k]) ** 2 for r in records)
                                                 / (n - 1)), 3) for k in keys}
    km = max(sum(r["meta"]["route_length"] / 1000 * r["scores"]["score_route"] / 100 for r in records), 0.001)
    infractions = {}
    for k in KEYS:
        if k == "outside_route_lanes":  # total km outside the lanes, not per km (a leaderboard quirk)
            infractions[k] = round(sum(outside_lanes(r["infractions"][k][0])[0] / 1000
                                       for r in records if r["infractions"].get(k)), 3)
        else:
            infractions[k] = round(sum(len(r["infractions"].get(k, [])) for r in records) / km, 3)
    status, exceptions = PERFECT, []
    for r in records:
        if FAILED in r["status"]:
            status = FAILED
            exceptions.append([r["route_id"], r["index"], r["status"]])
        elif r["status"] == COMPLETED and status == PERFECT:
            status = COMPLETED
    meta = {"total_length": round(sum(r["meta"]["route_length"] for r in records), 3),
            "duration_game": round(sum(r["meta"]["duration_game"] for r in records), 3),
            "duration_system": round(sum(r["meta"]["duration_system"] for r in records), 3),
            "exceptions": exceptions}
    return {"index": -1, "route_id": -1, "status": status, "infractions": infractions,
            "scores_mean": means, "scores_std_dev": std, "meta": meta}


def results(records: list[dict], total: int, sensors: list[str], finished: bool) -> dict:
    """A Leaderboard-2.0-shaped results JSON (the evaluator's --checkpoint file)."""
    g = global_record(records, total)
    values = [g["scores_mean"]["score_composed"], g["scores_mean"]["score_route"],
              g["scores_mean"]["score_penalty"]] + [g["infractions"][k] for k in _VALUE_KEYS]
    return {"_checkpoint": {"global_record": g, "progress": [len(records), total], "records": records},
            "entry_status": "Finished" if finished else "Started", "eligible": finished,
            "sensors": sensors, "values": [str(v) for v in values], "labels": LABELS}


def rescore_results(data: dict, rules: str = "lb2.0") -> dict:
    """Recompute every record and the global record of a Leaderboard-shaped results dict."""
    try:
        cp = data["_checkpoint"]
        records, progress = cp["records"], cp["progress"]
        total = int(progress[1])
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise ScoreError(f"not a Leaderboard results file (missing {exc})") from None
    if not isinstance(records, list):
        raise ScoreError("not a Leaderboard results file (_checkpoint.records is not a list)")
    if len(records) > total:  # the Leaderboard's validation marks such a file Invalid
        raise ScoreError(f"{len(records)} records for {total} planned route runs (progress [done, {total}]): "
                         "records of another run were merged in")
    new = [rescore(r, rules) for r in records]
    out = results(new, total, data.get("sensors", []), data.get("entry_status") == "Finished")
    out["entry_status"] = data.get("entry_status", out["entry_status"])
    out["eligible"] = data.get("eligible", out["eligible"])
    return out
