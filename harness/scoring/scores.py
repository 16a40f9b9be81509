"""Leaderboard scoring as pure functions: infraction lists -> route record -> global
record -> results JSON (docs/design.md §9.1). Works the same on our runs and on
a results file written by CARLA's leaderboard, because it reads only what such a file
holds: the message lists, the route scores and the meta.

Rules: ``lb2.0`` (default), ``lb2.1`` (additive weights, IS = prod(1 - q) / (1 + S)),
``b2d`` (Bench2Drive: like 2.0 but minimum-speed messages carry no penalty).

The arithmetic is the leaderboard's StatisticsManager's, step by step, so every number is
the same float and is written the same way: penalties multiplied (or summed, 2.1) event by
event in the order of its criteria; Python ``round`` to 6 decimals for scores, 3 for
standard deviations and per-km rates; means accumulated as sum(score / N); the meta sums
not rounded; a completed route's ``score_route`` the integer 100 and a single run's
standard deviations the integer 0, as its code writes them. While a run is unfinished the
file has no global record (``{}``) and no values, as the leaderboard's; a run with a
"Simulation crashed" route is "Crashed" and not eligible.
"""
from __future__ import annotations

import json
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
# the leaderboard applies the events in the order of its criteria: outside lanes, collisions,
# red lights, stop signs, minimum speed, then the scenarios' criteria (float products and
# sums depend on the order in their last bit)
EVENT_ORDER = ("outside_route_lanes", "collisions_layout", "collisions_pedestrian", "collisions_vehicle",
               "red_light", "stop_infraction", "min_speed_infractions", "scenario_timeouts",
               "yield_emergency_vehicle_infractions")
LABELS = ["Avg. driving score", "Avg. route completion", "Avg. infraction penalty", "Collisions with pedestrians",
          "Collisions with vehicles", "Collisions with layout", "Red lights infractions", "Stop sign infractions",
          "Off-road infractions", "Route deviations", "Route timeouts", "Agent blocked",
          "Yield emergency vehicles infractions", "Scenario timeouts", "Min speed infractions"]
_VALUE_KEYS = ["collisions_pedestrian", "collisions_vehicle", "collisions_layout", "red_light", "stop_infraction",
               "outside_route_lanes", "route_dev", "route_timeout", "vehicle_blocked",
               "yield_emergency_vehicle_infractions", "scenario_timeouts", "min_speed_infractions"]
# Bench2Drive's route records carry these too (its StatisticsManager's key order: after
# route_id, and town_name last)
B2D_KEYS = ("scenario_name", "weather_id", "save_name", "town_name")
SIMULATION_CRASHED, SENSORS_INVALID = "Simulation crashed", "Agent's sensors were invalid"
NOT_RESULTS = ("not a Leaderboard results file: pass the --checkpoint file of the leaderboard or the "
               "results.json of a 'sumo-scimm eval' run")


class ScoreError(ValueError):
    """A results file that is not Leaderboard-shaped (the message is one complete sentence)."""


def min_speed_percent(message: str) -> float:
    """p from 'Average speed is {p}% of the surrounding traffic's one'."""
    return float(message.split()[3].rstrip("%"))


def outside_lanes(message: str) -> tuple[float, float]:
    """(metres, percentage) from 'Agent went outside its route lanes for about {m} meters ({q}% ...'."""
    tokens = message.split()
    return float(tokens[8]), float(tokens[10].lstrip("(").rstrip("%"))


def infraction_penalty(infractions: dict[str, list[str]], rules: str = "lb2.0",
                       outside_pct: float | None = None) -> float:
    """IS of one route (unrounded) from its infraction lists, event by event as the
    leaderboard computes it. ``outside_pct``: the outside-lanes percentage unrounded (the
    event's value; the message holds it to 2 decimals), else read from the message."""
    if rules not in RULES:
        raise ScoreError(f"unknown rules {rules!r} (known: {', '.join(RULES)})")
    penalty, added = 1.0, 0  # added: lb2.1's sum of weights
    for key in EVENT_ORDER:
        for m in infractions.get(key, []):
            if key == "outside_route_lanes":
                q = outside_lanes(m)[1] if outside_pct is None else outside_pct
                penalty *= 1 - q / 100
            elif key == "min_speed_infractions":
                if rules == "lb2.0":
                    penalty *= 1 - (1 - MIN_SPEED_BASE) * (1 - min_speed_percent(m) / 100)
                elif rules == "lb2.1":
                    added += MIN_SPEED_WEIGHT * (1 - min_speed_percent(m) / 100)
            elif rules == "lb2.1":
                added += WEIGHT[key]
            else:
                penalty *= PENALTY[key]
    if rules == "lb2.1":
        penalty *= 1 / (1 + added)
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


def _scores(rc: float, penalty: float) -> dict:
    """The record's scores; rc keeps its type (the leaderboard's 100 of a completed route is an int)."""
    return {"score_route": round(rc, 6), "score_penalty": round(penalty, 6),
            "score_composed": round(max(rc * penalty, 0.0), 6)}


def route_record(index: int, route_id: str, infractions: dict[str, list[str]], rc: float,
                 meta: dict, rules: str = "lb2.0", crash: str = "", outside_pct: float | None = None,
                 b2d: dict | None = None) -> dict:
    """A Leaderboard results record. rc in [0, 100] (the int 100 for a completed route, as
    the leaderboard has it); meta: route_length [m], duration_game [s], duration_system [s];
    crash: the caller's failure message; outside_pct: the unrounded outside-lanes
    percentage; b2d: Bench2Drive's extra keys (B2D_KEYS), placed where its records have them."""
    inf = {k: list(infractions.get(k, [])) for k in KEYS}
    penalty = infraction_penalty(inf, rules, outside_pct)
    rec: dict = {"index": index, "route_id": route_id}
    if b2d is not None:
        rec.update({k: b2d[k] for k in B2D_KEYS[:3]})
    rec.update({
        "status": route_status(rc, inf, crash), "num_infractions": sum(len(v) for v in inf.values()),
        "infractions": inf, "scores": _scores(rc, penalty),
        "meta": {"route_length": round(meta["route_length"], 3), "duration_game": round(meta["duration_game"], 3),
                 "duration_system": round(meta["duration_system"], 3)}})
    if b2d is not None:
        rec["town_name"] = b2d["town_name"]
    return rec


def rescore(record: dict, rules: str = "lb2.0") -> tuple[dict, int]:
    """The same record with its scores recomputed from its infraction lists and RC, and how
    many minimum-speed messages were dropped: under lb2.0 / lb2.1 those at >= 100 %, which
    the leaderboard never logs (Bench2Drive logs every checkpoint; its files would otherwise
    score a factor above 1). A route with RC 100 gets its Perfect / Completed status again
    from the lists that remain."""
    rid = record.get("route_id", "?") if isinstance(record, dict) else "?"
    try:
        inf, rc = record["infractions"], record["scores"]["score_route"]
    except (KeyError, TypeError) as exc:
        raise ScoreError(f"record {rid} has no {exc}: {NOT_RESULTS}") from None
    if not isinstance(inf, dict) or not all(isinstance(v, list) for v in inf.values()):
        raise ScoreError(f"record {rid}: 'infractions' must map each key to a list of messages")
    missing = [k for k in KEYS if k not in inf]
    if missing:  # the leaderboard's merge_statistics.py and StatisticsManager read every key
        raise ScoreError(f"record {rid}: 'infractions' has no {missing[0]!r} list (the leaderboard writes every "
                         f"infraction key, an empty list when none): {NOT_RESULTS}")
    if isinstance(rc, bool) or not isinstance(rc, (int, float)):
        rc = float(rc)  # a number written as text
    dropped = 0
    if rules != "b2d" and inf.get("min_speed_infractions"):
        kept = [m for m in inf["min_speed_infractions"] if min_speed_percent(m) < 100]
        dropped = len(inf["min_speed_infractions"]) - len(kept)
        inf = {**inf, "min_speed_infractions": kept}
    out = dict(record)
    out["infractions"] = inf
    out["scores"] = _scores(rc, infraction_penalty(inf, rules))
    out["num_infractions"] = sum(len(v) for v in inf.values())
    if rc >= 100:
        out["status"] = route_status(rc, inf)
    return out, dropped


def infraction_value(record: dict, key: str) -> float:
    """What a route adds to the global ``key`` before the per-km division: its message count,
    or for outside_route_lanes the metres of its first message in km (the leaderboard reads
    the 9th word)."""
    messages = record["infractions"].get(key, [])
    if key == "outside_route_lanes":
        return float(messages[0].split(" ")[8]) / 1000 if messages else 0.0
    return len(messages)


def global_record(records: list[dict], total: int) -> dict:
    """The global record over ``total`` >= 1 planned route runs (never-run ones count as 0),
    computed as the leaderboard's compute_global_statistics does, operation by operation."""
    means = {"score_composed": 0, "score_route": 0, "score_penalty": 0}
    meta: dict = {"total_length": 0, "duration_game": 0, "duration_system": 0, "exceptions": []}
    status = PERFECT
    for r in records:
        for k in ("score_route", "score_penalty", "score_composed"):
            means[k] += r["scores"][k] / total  # paper eq. 14: DS, RC and IS are means over the routes
        for k, m in (("total_length", "route_length"), ("duration_game", "duration_game"),
                     ("duration_system", "duration_system")):
            meta[k] += r["meta"][m]
        result = FAILED if FAILED in r["status"] else r["status"]
        if result == FAILED:
            meta["exceptions"].append([r["route_id"], r["index"], r["status"]])
            status = FAILED
        elif status == PERFECT and result != PERFECT:
            status = result
    means = {k: round(v, 6) for k, v in means.items()}
    std: dict = {k: 0 for k in means}
    if total != 1:
        for r in records:
            for k in std:
                std[k] += math.pow(r["scores"][k] - means[k], 2)
        std = {k: round(math.sqrt(v / float(total - 1)), 3) for k, v in std.items()}
    km, infractions = 0, {k: 0 for k in KEYS}
    for r in records:
        km += r["meta"]["route_length"] / 1000 * r["scores"]["score_route"] / 100
        for k in KEYS:
            infractions[k] += infraction_value(r, k)
    km = max(km, 0.001)
    for k in KEYS:
        if k != "outside_route_lanes":  # total km outside the lanes, not per km (a leaderboard quirk)
            infractions[k] /= km
        infractions[k] = round(infractions[k], 3)
    return {"index": -1, "route_id": -1, "status": status, "infractions": infractions,
            "scores_mean": means, "scores_std_dev": std, "meta": meta}


def entry_status(records: list[dict], finished: bool) -> str:
    """The file's entry_status: Finished (all route runs done) or Started, unless a route
    says the simulation crashed (Crashed) or the sensors were invalid (Rejected); the last
    such route wins, as in the leaderboard. The leaderboard stops at such a route; our runs
    go on, and the status stays."""
    status = "Finished" if finished else "Started"
    for r in records:
        if SIMULATION_CRASHED in r["status"]:
            status = "Crashed"
        elif SENSORS_INVALID in r["status"]:
            status = "Rejected"
    return status


def results(records: list[dict], total: int, sensors: list[str], finished: bool) -> dict:
    """A Leaderboard-2.0-shaped results JSON (the evaluator's --checkpoint file). Unfinished:
    no global record, values or labels yet, as the leaderboard writes it between routes."""
    status = entry_status(records, finished)
    g: dict = {}
    values: list[str] = []
    if finished:
        g = global_record(records, total)
        values = [str(v) for v in (g["scores_mean"]["score_composed"], g["scores_mean"]["score_route"],
                                   g["scores_mean"]["score_penalty"], *(g["infractions"][k] for k in _VALUE_KEYS))]
    return {"_checkpoint": {"global_record": g, "progress": [len(records), total], "records": records},
            "entry_status": status, "eligible": status == "Finished", "sensors": sensors, "values": values,
            "labels": list(LABELS) if finished else []}


def results_text(result: dict) -> str:
    """The file's text, as the leaderboard's save_dict writes it (indent 4, no final newline);
    a NaN or infinity is refused (ValueError): JSON has none."""
    return json.dumps(result, indent=4, allow_nan=False)


def rescore_results(data: dict, rules: str = "lb2.0", notes: list[str] | None = None) -> dict:
    """Recompute every record and the global record of a Leaderboard-shaped results dict.
    The global record is recomputed where the file has one (or says Finished); a file of an
    unfinished or crashed run without one keeps none. ``notes`` gets one sentence per thing
    done that the file did not ask for (minimum-speed messages dropped under lb2.0 / lb2.1)."""
    cp = data.get("_checkpoint") if isinstance(data, dict) else None
    if not isinstance(cp, dict) or "records" not in cp or "progress" not in cp:
        raise ScoreError(f"{NOT_RESULTS} (no '_checkpoint' with 'progress' and 'records')")
    records, progress = cp["records"], cp["progress"]
    try:
        total = int(progress[1])
    except (TypeError, ValueError, IndexError, KeyError, OverflowError):
        raise ScoreError(f"{NOT_RESULTS} ('_checkpoint.progress' is {str(progress)[:40]}, "
                         "not [done, planned])") from None
    if not isinstance(records, list):
        raise ScoreError(f"{NOT_RESULTS} ('_checkpoint.records' is not a list)")
    if total < 1:
        raise ScoreError(f"progress {str(progress)[:40]}: no planned route run to score")
    done = progress[0]
    if isinstance(done, bool) or not isinstance(done, int) or not 0 <= done <= total or len(progress) != 2:
        raise ScoreError(f"{NOT_RESULTS} ('_checkpoint.progress' is {str(progress)[:40]}, not [done, planned] "
                         "route runs)")
    if len(records) > total:  # the Leaderboard's validation marks such a file Invalid
        raise ScoreError(f"{len(records)} records for {total} planned route runs (progress [done, {total}]): "
                         "records of another run were merged in")
    from harness.scoring.validate import results_problem  # every number finite and in its range
    if (problem := results_problem(data)) is not None:
        raise ScoreError(problem)
    new, dropped = [], 0
    for r in records:
        rec, n = rescore(r, rules)
        new.append(rec)
        dropped += n
    if dropped and notes is not None:
        notes.append(f"{dropped} minimum-speed messages at >= 100 % dropped (Bench2Drive logs every checkpoint; "
                     f"the leaderboard logs only those below 100 %), so {rules} scores them as the leaderboard "
                     "would; the checkpoints stay Bench2Drive's (20 per route, not 4)")
    has_global = bool(cp.get("global_record")) or data.get("entry_status") == "Finished"
    out = results(new, total, data.get("sensors", []), has_global)
    out["_checkpoint"]["progress"] = [done, total]
    out["entry_status"] = data.get("entry_status", out["entry_status"])
    out["eligible"] = data.get("eligible", out["eligible"])
    return out
