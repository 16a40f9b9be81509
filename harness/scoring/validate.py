"""The numbers of a results file and of a run folder, checked before they are scored.

A Leaderboard results file (ours, or one written by CARLA's leaderboard) is read by
``sumo-scimm score`` and ``report``; every number they use must be a finite number in its
range, else the file is refused with one line naming the record, the field and the range:

    scores.score_route         RC [%]                  [0, 100]
    scores.score_penalty       IS                      [0, 1]      (recomputed; checked if present)
    scores.score_composed      DS                      [0, 100]    (recomputed; checked if present)
    meta.route_length          route length [m]        [0, 1e7]    (0: a route that failed to load)
    meta.duration_game/_system durations [s]           [0, 1e9]
    outside_route_lanes msg    metres >= 0, percentage [0, 100]
    min_speed_infractions msg  percentage of the traffic's speed >= 0

and a file with no route record is refused (a mean over no route is no score). The
structure itself (``_checkpoint``, ``progress``, lists of messages) is checked by
harness.scoring.scores, which asks ``results_problem`` once it has found records (this
module reads the messages itself, so that it does not import the scorer it guards).

``run_folder_problem`` does the same for what ``report`` reads from an eval run folder:
records.csv with at least one row, finite figures in range (the infraction counts and the
stability metrics >= 0, the latter NaN where undefined), a list of records in results.json
and as many rows as it has records.

``record_line_problem`` checks one line of records.jsonl before ``--resume`` keeps it: a
JSON object (``no_duplicates``: no key twice) with only the fields ``eval`` writes
(harness.scoring.records' RECORD_FIELDS and ``JSONL_FIELDS``), the ones every record has
present, each of its type and in its range, a status a route can have (``ROUTE_STATUSES``),
and a Leaderboard record (``lb``) as the scorer writes and reads it (``lb_problem``: only
its fields, an ``index``, every infraction key a known one holding a list of messages,
every number a finite number in its range, not text) that says what the line's own columns
say (route id, status, DS/RC/IS, infraction counts). Whether the line is a route run of
the resumed run, and the only one of its key, is checked by harness.runs.runner.
"""
from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

from files.compressed import read_text
from harness.scoring.infractions import KEYS
from harness.scoring.records import COUNT_KEYS, RECORD_FIELDS, STABILITY
from harness.scoring.statuses import FAILED, PERFECT, STATUSES

# field -> (low, high, low is open)
SCORE_RANGES = {"score_route": (0.0, 100.0, False), "score_penalty": (0.0, 1.0, False),
                "score_composed": (0.0, 100.0, False)}
# a route of up to 10,000 km, driven for up to 10^9 s (31 years): beyond, a number is damage; the
# leaderboard writes route_length 0 for a route that failed to load ("Simulation crashed")
META_RANGES = {"route_length": (0.0, 1e7, False), "duration_game": (0.0, 1e9, False),
               "duration_system": (0.0, 1e9, False)}
# records.csv columns report reads, with their ranges (stability metrics may be NaN: undefined)
CSV_RANGES = {"ds": (0.0, 100.0, False), "rc": (0.0, 100.0, False), "is": (0.0, 1.0, False),
              "km_driven": (0.0, math.inf, False)}
_SHOWN = 16  # characters of a bad value quoted in a message
_COUNT = (0.0, math.inf, False)  # an infraction count, a stability metric: >= 0


class DuplicateKey(ValueError):
    """A JSON object that names a key twice."""


def no_duplicates(pairs: list[tuple[str, object]]) -> dict:
    """``json.loads``'s object_pairs_hook: the object as a dict; DuplicateKey if a key repeats."""
    out: dict = {}
    for k, v in pairs:
        if k in out:
            raise DuplicateKey(f"key {_shown(k, 40)} appears twice")
        out[k] = v
    return out


def _shown(value, width: int = _SHOWN) -> str:
    """``value`` for a message, cut to ``width`` characters."""
    text = repr(value)
    return text if len(text) <= width else f"{text[:width]}... ({len(text)} characters)"


def _range(lo: float, hi: float, open_lo: bool) -> str:
    return f"{'(' if open_lo else '['}{lo:g}, {hi:g}{']' if math.isfinite(hi) else ')'}"


def number_problem(value, bounds: tuple[float, float, bool], text_ok: bool = False) -> str | None:
    """None if ``value`` is a finite number inside ``bounds`` (low, high, low is open),
    else what is wrong with it. ``text_ok``: a number written as text counts."""
    lo, hi, open_lo = bounds
    kinds = (int, float, str) if text_ok else (int, float)
    if isinstance(value, bool) or not isinstance(value, kinds):
        return f"is {_shown(value)}, not a number"
    try:
        v = float(value)
    except (ValueError, OverflowError):
        return f"is {_shown(value)}, not a finite number"
    if not math.isfinite(v):
        return f"is {_shown(value)}, not a finite number"
    if v < lo or (open_lo and v == lo) or v > hi:
        return f"is {_shown(value)}, outside {_range(lo, hi, open_lo)}"
    return None


def outside_lanes(message: str) -> tuple[float, float]:
    """(metres, percentage) of 'Agent went outside its route lanes for about {m} meters ({q}% ...'."""
    tokens = message.split()
    return float(tokens[8]), float(tokens[10].lstrip("(").rstrip("%"))


def min_speed_percent(message: str) -> float:
    """p of 'Average speed is {p}% of the surrounding traffic's one'."""
    return float(message.split()[3].rstrip("%"))


def _message_problem(key: str, message) -> str | None:
    """What is wrong with the numbers of one infraction message (None if nothing)."""
    if not isinstance(message, str):
        return f"a message of {key} is {_shown(message)}, not text"
    try:
        if key == "outside_route_lanes":
            metres, pct = outside_lanes(message)
            what = ("metres" if number_problem(metres, (0.0, math.inf, False)) else
                    "percentage" if number_problem(pct, (0.0, 100.0, False)) else None)
        elif key == "min_speed_infractions":
            what = "percentage" if number_problem(min_speed_percent(message), (0.0, math.inf, False)) else None
        else:
            return None
    except (ValueError, IndexError, OverflowError):
        what = "numbers"
    return f"{key} message {_shown(message, 72)} has no valid {what}" if what else None


def record_problem(record) -> str | None:
    """What is wrong with the numbers of one Leaderboard route record (None if nothing)."""
    if not isinstance(record, dict):
        return f"is {_shown(record)}, not a record"
    infractions = record.get("infractions")
    if not isinstance(infractions, dict) or not all(isinstance(v, list) for v in infractions.values()):
        return None  # the scorer names what is wrong with the lists
    if not isinstance(record.get("status"), str) or "route_id" not in record:
        return "has no status text or no route_id"
    scores, meta = record.get("scores"), record.get("meta")
    if not isinstance(scores, dict) or not isinstance(meta, dict):
        return "has no 'scores' or no 'meta' object"
    if "score_route" not in scores:
        return "scores.score_route is missing"
    for key, bounds in SCORE_RANGES.items():
        if key in scores:
            bad = number_problem(scores[key], bounds, text_ok=True)
            if bad:
                return f"scores.{key} {bad}"
    for key, bounds in META_RANGES.items():
        if key not in meta:
            return f"meta.{key} is missing"
        bad = number_problem(meta[key], bounds)
        if bad:
            return f"meta.{key} {bad}"
    for key, messages in infractions.items():
        for m in messages:
            bad = _message_problem(key, m)
            if bad:
                return bad
    return None


def results_problem(data: dict) -> str | None:
    """What is wrong with the records of a Leaderboard results dict whose structure
    harness.scoring.scores has accepted (None if nothing)."""
    records = data["_checkpoint"]["records"]
    if not records:
        return "holds no route record: nothing to score (finish the run, or pass another results file)"
    for i, r in enumerate(records):
        bad = record_problem(r)
        if bad:
            rid = r.get("route_id", "?") if isinstance(r, dict) else "?"
            return f"record {i} (route {_shown(rid, 40)}) {bad}: the file is damaged"
    return None


def run_folder_problem(folder: Path) -> str | None:
    """What makes an eval run folder unfit for ``report`` (None if nothing, or if its files
    are missing or not JSON/CSV at all: the report's own checks name those): a results.json
    whose records are damaged, a records.csv without rows, with a figure that is not a
    finite number in its range, or with another number of rows than results.json's records."""
    res, rec = Path(folder) / "results.json", Path(folder) / "records.csv"
    try:
        data = json.loads(read_text(res))
        records = data["_checkpoint"]["records"]
        rows = list(csv.DictReader(io.StringIO(read_text(rec), newline="")))
    except (OSError, ValueError, KeyError, TypeError, UnicodeDecodeError, csv.Error):
        return None
    if not isinstance(records, list):
        return f"{res}: _checkpoint.records is {_shown(records)}, not a list of route records: the file is damaged"
    if not rows:
        return (f"{rec} has no route row: the run folder is damaged (run 'sumo-scimm eval ... --resume' to "
                "write it again)")
    bad = results_problem(data)
    if bad:
        return f"{res}: {bad}"
    for i, row in enumerate(rows):
        for key, bounds in _csv_ranges().items():
            if key in row and not (key in STABILITY and row[key].strip().lower() in ("nan", "")):
                bad = number_problem(row[key], bounds, text_ok=True)
                if bad:
                    return f"{rec}: row {i + 1} {key} {bad}: the run folder is damaged"
    if len(rows) != len(records):
        return (f"{rec} has {len(rows)} rows but {res.name} {len(records)} records: the run folder is damaged "
                "(run 'sumo-scimm eval ... --resume' to write both again)")
    return None


def _csv_ranges() -> dict[str, tuple[float, float, bool]]:
    """Every records.csv column report reads, with its range."""
    return {**CSV_RANGES, **dict.fromkeys((*COUNT_KEYS, *STABILITY), _COUNT)}


# records.jsonl: its fields beyond records.csv's (harness.scoring.records), the fields every
# record has, and the checks of the ones a record may have besides
JSONL_FIELDS = ("episode_status", "hazard", "efficiency", "smoothness", "lb")
_REQUIRED = ("key", "route_id", "repetition", "status", "ds", "rc", "is", "seed", "lb")
_OPTIONAL_TEXT = ("town", "message", "episode_status", "hazard")
_OPTIONAL_NUMBERS = {"outside_lanes_pct": (0.0, 100.0, False), "collisions_per_km": _COUNT,
                     "km_driven": _COUNT, "length": (0.0, 1e7, False), "game_time": (0.0, 1e9, False),
                     "wall_time": (0.0, 1e9, False), "steps": _COUNT, "efficiency": _COUNT,
                     "smoothness": (0.0, 1.0, False)}


# a Leaderboard route record as eval writes it (harness.scoring.scores.route_record), with
# Bench2Drive's keys under --rules b2d (harness.scoring.scores.B2D_KEYS)
LB_FIELDS = ("index", "route_id", "status", "num_infractions", "infractions", "scores", "meta")
LB_B2D_FIELDS = ("scenario_name", "weather_id", "save_name", "town_name")
# the statuses of a route record (harness.scoring.scores.route_status): Perfect, Completed,
# Failed, or "Failed - <message>" of a route-ending infraction or a crash
ROUTE_STATUSES = frozenset({PERFECT, FAILED, *STATUSES})


def _whole(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def lb_problem(lb) -> str | None:
    """What is wrong with the Leaderboard record ``lb`` of a records.jsonl line, read as
    strictly as eval writes it (None if nothing): only LB_FIELDS (and Bench2Drive's), all
    present; ``index`` and ``num_infractions`` whole numbers, the latter the number of
    messages; a status of ROUTE_STATUSES; ``infractions`` every key of the Leaderboard's,
    each a list of texts; ``scores`` and ``meta`` finite numbers (not text) in their ranges;
    then ``record_problem`` (the numbers in the messages)."""
    if not isinstance(lb, dict):
        return f"is {_shown(lb)}, not a record"
    unknown = sorted(set(lb) - set(LB_FIELDS) - set(LB_B2D_FIELDS))
    if unknown:
        return f"has an unknown field {_shown(unknown[0], 40)}"
    missing = [k for k in LB_FIELDS if k not in lb]
    if missing:
        return f"has no {missing[0]!r}"
    for k in ("index", "num_infractions"):
        if not _whole(lb[k]):
            return f"{k} is {_shown(lb[k])}, not a whole number >= 0"
    for k in ("route_id", *(b for b in LB_B2D_FIELDS if b in lb)):
        v = lb[k]  # Bench2Drive's scenario_name and weather_id may be null, its weather_id a number
        if not (isinstance(v, str) or (k in LB_B2D_FIELDS[:2] and v is None) or (k == "weather_id" and _whole(v))):
            return f"{k} is {_shown(v)}, not text"
    if lb["status"] not in ROUTE_STATUSES:
        return f"status {_shown(lb['status'], 40)} is not a route status"
    inf = lb["infractions"]
    if not isinstance(inf, dict):
        return f"infractions is {_shown(inf)}, not a table of infraction lists"
    for k, messages in inf.items():
        if k not in KEYS:
            return f"infractions has an unknown key {_shown(k, 40)}"
        if not isinstance(messages, list) or not all(isinstance(m, str) for m in messages):
            return f"infractions.{k} is {_shown(messages)}, not a list of messages"
    absent = [k for k in KEYS if k not in inf]
    if absent:
        return f"infractions has no {absent[0]!r} list"
    n = sum(len(v) for v in inf.values())
    if lb["num_infractions"] != n:
        return f"num_infractions is {lb['num_infractions']}, but it lists {n} infractions"
    for part, ranges in (("scores", SCORE_RANGES), ("meta", META_RANGES)):
        table = lb[part]
        if not isinstance(table, dict):
            return f"{part} is {_shown(table)}, not a table"
        extra = sorted(set(table) - set(ranges))
        if extra:
            return f"{part} has an unknown field {_shown(extra[0], 40)}"
        for k, bounds in ranges.items():
            if k not in table:
                return f"{part}.{k} is missing"
            bad = number_problem(table[k], bounds)
            if bad:
                return f"{part}.{k} {bad}"
    return record_problem(lb)


def _lb_mismatch(rec: dict) -> str | None:
    """Which of the line's own columns says otherwise than its (valid) Leaderboard record."""
    lb = rec["lb"]
    if lb["route_id"] != f"RouteScenario_{rec['key']}":
        return f"lb.route_id {_shown(lb['route_id'], 40)} is not RouteScenario_{rec['key']}"
    if rec["status"] != lb["status"]:
        return f"status {_shown(rec['status'], 40)} is not its Leaderboard record's {lb['status']!r}"
    for k, lb_key in (("ds", "score_composed"), ("rc", "score_route"), ("is", "score_penalty")):
        if not math.isclose(rec[k], lb["scores"][lb_key], rel_tol=0.0, abs_tol=1e-6):
            return f"{k} {rec[k]!r} is not its Leaderboard record's {lb_key} {lb['scores'][lb_key]!r}"
    for k in COUNT_KEYS:
        if k in rec and rec[k] != len(lb["infractions"][k]):
            return f"{k} {rec[k]!r} is not the number of its Leaderboard record's {k} ({len(lb['infractions'][k])})"
    return None


def _undefined(value) -> bool:
    """A number recorded as undefined: null, or NaN."""
    return value is None or (isinstance(value, float) and math.isnan(value))


def record_line_problem(rec) -> str | None:
    """What is wrong with one parsed line of records.jsonl (None if nothing)."""
    if not isinstance(rec, dict):
        return f"is {_shown(rec)}, not a record"
    known = set(RECORD_FIELDS) | set(JSONL_FIELDS)
    unknown = sorted(set(rec) - known)
    if unknown:
        return f"has an unknown field {_shown(unknown[0], 40)}"
    missing = [k for k in _REQUIRED if k not in rec]
    if missing:
        return f"has no {missing[0]!r}"
    for k in ("key", "route_id", "status", *(t for t in _OPTIONAL_TEXT if t in rec)):
        if not isinstance(rec[k], str):
            return f"{k} is {_shown(rec[k])}, not text"
    for k in ("repetition", "seed", *(c for c in COUNT_KEYS if c in rec)):
        if isinstance(rec[k], bool) or not isinstance(rec[k], int) or rec[k] < 0:
            return f"{k} is {_shown(rec[k])}, not a whole number >= 0"
    if rec["key"] != f"{rec['route_id']}_rep{rec['repetition']}":
        return f"key {_shown(rec['key'], 40)} is not <route_id>_rep<repetition>"
    ranges = {"ds": SCORE_RANGES["score_composed"], "rc": SCORE_RANGES["score_route"],
              "is": SCORE_RANGES["score_penalty"], **_OPTIONAL_NUMBERS, **dict.fromkeys(STABILITY, _COUNT)}
    for k, bounds in ranges.items():
        if k not in rec or (k not in ("ds", "rc", "is") and _undefined(rec[k])):
            continue
        bad = number_problem(rec[k], bounds)
        if bad:
            return f"{k} {bad}"
    if rec["status"] not in ROUTE_STATUSES:
        return f"status {_shown(rec['status'], 40)} is not a route status"
    if "episode_status" in rec and rec["episode_status"] not in STATUSES:
        return f"episode_status {_shown(rec['episode_status'], 40)} is not how an episode ends"
    bad = lb_problem(rec["lb"])
    if bad:
        return f"lb (its Leaderboard record) {bad}"
    return _lb_mismatch(rec)
