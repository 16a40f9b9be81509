"""Every number read from a route file or a results file is checked (docs/design.md §12): a value
that is not a finite number in its range is one line naming the attribute or field, exit
code 2, never a traceback, never a score. Fuzzed with hypothesis against an oracle written
here from the documented ranges (scenarios.routefile, harness.scoring.validate)."""
from __future__ import annotations

import contextlib
import io
import json
import math
import re
from xml.sax.saxutils import quoteattr

from hypothesis import example, given, settings, strategies as st

from scenarios import set_path
from sumo_scimm.cli import main

SMOKE = set_path("town12_smoke").read_text()

# (element, attribute) -> (low, high, low is open): the ranges scenarios.routefile documents
ROUTE_NUMBERS = {
    ("position", "x"): (-1e7, 1e7, False), ("position", "y"): (-1e7, 1e7, False),
    ("position", "z"): (-1e7, 1e7, False),
    ("trigger_point", "x"): (-1e7, 1e7, False), ("trigger_point", "y"): (-1e7, 1e7, False),
    ("trigger_point", "z"): (-1e7, 1e7, False), ("trigger_point", "yaw"): (-360.0, 360.0, False),
    ("sumo", "depart_pos"): (0.0, 1e7, False), ("sumo", "arrival_pos"): (0.0, 1e7, False),
    ("sumo", "length"): (0.0, 1e7, True),
    ("routes", "min_length"): (0.0, 1e7, False), ("routes", "max_length"): (0.0, 1e7, False),
}
# attributes whose empty value means "absent" (z 0, no length, no bound), as before
EMPTY_IS_ABSENT = {("position", "z"), ("sumo", "length"), ("routes", "min_length"), ("routes", "max_length")}


def _cli(argv: list[str]) -> tuple[int, str]:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        code = main(argv)
    return code, buf.getvalue()


def _in_range(raw: str, bounds: tuple[float, float, bool]) -> bool:
    """The oracle: ``raw`` reads as a finite number inside ``bounds``."""
    lo, hi, open_lo = bounds
    try:
        v = float(raw)
    except (ValueError, OverflowError):
        return False
    return math.isfinite(v) and (lo < v if open_lo else lo <= v) and v <= hi


def _with_value(element: str, attr: str, raw: str) -> str:
    """The smoke set with ``attr`` of the first ``<element>`` set to ``raw`` (added if absent)."""
    tag = re.search(rf"<{element}\b[^>]*>", SMOKE)
    old = tag.group(0)
    value = quoteattr(raw)
    if re.search(rf'\s{attr}="[^"]*"', old):
        new = re.sub(rf'(\s){attr}="[^"]*"', lambda m: f"{m.group(1)}{attr}={value}", old, count=1)
    else:
        new = old.replace(f"<{element}", f"<{element} {attr}={value}", 1)
    return SMOKE[:tag.start()] + new + SMOKE[tag.end():]


_printable = st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=12)
BAD_TEXT = st.one_of(
    st.sampled_from(["nan", "NaN", "inf", "-inf", "1e400", "-1e400", "abc", "1,5", "0x10", "--1", "1e", "."]),
    _printable.filter(lambda s: not _in_range(s, (-math.inf, math.inf, False))),
    st.integers(10**7 + 1, 10**400).map(str),  # beyond every range; 300 digits in a message are cut
    st.integers(-10**400, -1).map(str),  # below the positions' and lengths' ranges
    st.floats(allow_nan=False, allow_infinity=False).map(repr),  # anything: the oracle decides
)


@settings(max_examples=80, deadline=None)
@given(where=st.sampled_from(sorted(ROUTE_NUMBERS)), raw=BAD_TEXT, command=st.sampled_from(["check", "eval"]))
@example(where=("sumo", "length"), raw="abc", command="eval")  # once a 17-line traceback, exit 1
@example(where=("trigger_point", "z"), raw="abc", command="check")  # the same
@example(where=("position", "x"), raw="9" * 300, command="check")  # once 300 digits in the message
@example(where=("routes", "min_length"), raw="nan", command="check")
def test_a_bad_number_in_a_route_file_is_one_line_naming_it(tmp_path_factory, where, raw, command):
    element, attr = where
    bad = not _in_range(raw, ROUTE_NUMBERS[where]) and not (raw.strip() == "" and where in EMPTY_IS_ABSENT)
    if command == "eval" and not bad:
        command = "check"  # a good value would drive the routes
    d = tmp_path_factory.mktemp("routes")
    path = d / "routes.xml"
    path.write_text(_with_value(element, attr, raw))
    out = d / "run"
    argv = (["routes", "check", str(path)] if command == "check"
            else ["eval", "--routes", str(path), "--agent", "route_follower", "--out", str(out)])
    code, printed = _cli(argv)
    lines = [ln for ln in printed.splitlines() if ln.strip()]
    assert "Traceback" not in printed
    assert code in (0, 2), printed
    if bad:
        assert code == 2, printed
        assert len(lines) == 1, printed  # only route 0 (or the set) is touched
        assert f"<{element}> {attr}=" in lines[0], printed
        assert len(lines[0]) < 2 * len(str(path)) + 200, printed  # a long value is cut
    assert not out.exists()


# --- results files -----------------------------------------------------------------------------
def _results() -> dict:
    from tests.test_scoring import _carla_file
    return _carla_file()


# (group, field) -> (low, high, low is open): harness.scoring.validate's ranges
RESULT_NUMBERS = {("scores", "score_route"): (0.0, 100.0, False), ("scores", "score_penalty"): (0.0, 1.0, False),
                  ("scores", "score_composed"): (0.0, 100.0, False), ("meta", "route_length"): (0.0, 1e7, False),
                  ("meta", "duration_game"): (0.0, 1e9, False), ("meta", "duration_system"): (0.0, 1e9, False)}
VALUES = st.one_of(st.floats(), st.integers(-10**400, 10**400), st.sampled_from([True, None, "abc", [], {}]),
                   st.floats(0, 100))


def _is_valid(value, bounds) -> bool:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return _in_range(repr(float(value)), bounds)
    except OverflowError:
        return False


def _no_constants(text: str) -> dict:
    """json.loads that refuses NaN and Infinity (not JSON)."""
    def refuse(name):
        raise ValueError(f"{name} in the output")
    return json.loads(text, parse_constant=refuse)


@settings(max_examples=100, deadline=None)
@given(where=st.sampled_from(sorted(RESULT_NUMBERS)), value=VALUES, record=st.integers(0, 1))
@example(where=("scores", "score_route"), value=-50, record=0)  # once RC 62.5
@example(where=("scores", "score_route"), value=math.nan, record=0)  # once "DS nan" and NaN in the JSON
@example(where=("meta", "route_length"), value=None, record=1)
def test_a_bad_number_in_a_results_file_is_one_line_naming_the_field(tmp_path_factory, where, value, record):
    group, field = where
    data = _results()
    data["_checkpoint"]["records"][record][group][field] = value
    d = tmp_path_factory.mktemp("score")
    src, dst = d / "results.json", d / "rescored.json"
    src.write_text(json.dumps(data))  # NaN and Infinity written as Python's json does
    code, printed = _cli(["score", str(src), "--out", str(dst)])
    assert "Traceback" not in printed
    if _is_valid(value, RESULT_NUMBERS[where]):
        assert code == 0, printed
        _no_constants(dst.read_text())
    else:
        lines = [ln for ln in printed.splitlines() if ln.strip()]
        assert code == 2, printed
        assert len(lines) == 1, printed
        assert f"record {record} " in lines[0] and f"{group}.{field} " in lines[0], printed
        assert len(lines[0]) < len(str(src)) + 200, printed
        assert not dst.exists()


def _outside(metres: str, pct: str) -> str:
    return f"Agent went outside its route lanes for about {metres} meters ({pct}% of the completed route)"


NUMBER_TEXT = st.one_of(st.floats().map(repr), st.sampled_from(["nan", "inf", "-1", "abc", "1e400", "150"]))


@settings(max_examples=60, deadline=None)
@given(key=st.sampled_from(["outside_metres", "outside_pct", "min_speed"]), raw=NUMBER_TEXT)
@example(key="min_speed", raw="nan")
@example(key="outside_pct", raw="150")
def test_a_bad_number_in_an_infraction_message_is_one_line(tmp_path_factory, key, raw):
    data = _results()
    infractions = data["_checkpoint"]["records"][0]["infractions"]
    if key == "min_speed":
        infractions["min_speed_infractions"] = [f"Average speed is {raw}% of the surrounding traffic's one"]
        good = _in_range(raw, (0.0, math.inf, False))
    else:
        metres, pct = (raw, "2.5") if key == "outside_metres" else ("20.0", raw)
        infractions["outside_route_lanes"] = [_outside(metres, pct)]
        good = _in_range(metres, (0.0, math.inf, False)) and _in_range(pct, (0.0, 100.0, False))
    d = tmp_path_factory.mktemp("score")
    src, dst = d / "results.json", d / "rescored.json"
    src.write_text(json.dumps(data))
    code, printed = _cli(["score", str(src), "--out", str(dst)])
    assert "Traceback" not in printed
    assert code == (0 if good else 2), printed
    if good:
        _no_constants(dst.read_text())
    else:
        assert "has no valid" in printed, printed
        assert not dst.exists()


def test_a_results_file_without_records_is_not_scored(tmp_path):
    """Before, 0 records scored DS 0.0 without a word."""
    data = _results()
    data["_checkpoint"]["records"] = []
    src = tmp_path / "results.json"
    src.write_text(json.dumps(data))
    code, printed = _cli(["score", str(src)])
    assert code == 2, printed
    assert printed.strip() == (f"sumo-scimm: error: {src}: holds no route record: nothing to score (finish the "
                               "run, or pass another results file)")
