"""Bad input found by hypothesis: every invalid option value of eval and collect, and every
damaged results file, is one line and exit 2, and writes nothing."""
from __future__ import annotations

import contextlib
import io
import json
import math

import pytest
from hypothesis import example, given, settings, strategies as st

from harness.runs.evaluate import MAX_ROUTE_RUNS
from sumo_scimm.cli import main


def _cli(argv: list[str]) -> tuple[int, str]:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        code = main(argv)
    return code, buf.getvalue()


def _not_int(s: str) -> bool:
    try:
        int(s)
    except ValueError:
        return True
    return False


def _not_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return True
    return False


_text = st.text(min_size=1, max_size=12)
_letters = st.text(alphabet="abcxyz_-:. ", min_size=1, max_size=10)
BAD_OPTIONS = st.one_of(
    st.tuples(st.sampled_from(["--workers", "--repetitions"]),
              st.one_of(st.integers(max_value=0).map(str), _text.filter(_not_int))),
    # more route runs than a run may hold (4 routes in the smoke set); refused at once
    st.tuples(st.just("--repetitions"), st.integers(min_value=MAX_ROUTE_RUNS // 4 + 1).map(str)),
    st.tuples(st.just("--seed"), st.one_of(st.integers(max_value=-1).map(str), _text.filter(_not_int))),
    st.tuples(st.just("--agent-timeout"),
              st.one_of(st.floats(max_value=0.0).map(repr), st.sampled_from(["nan", "inf", "-inf"]),
                        _text.filter(_not_float))),
    st.tuples(st.just("--routes-subset"),
              st.one_of(st.integers(min_value=4).map(str),  # the smoke set has routes 0-3
                        st.tuples(st.integers(4, 99), st.integers(4, 99)).map(lambda t: f"{t[0]}-{t[1]}"),
                        st.integers(4, 10**6).map(lambda i: f"0,{i}"),
                        st.tuples(st.integers(1, 3), st.integers(0, 3)).filter(lambda t: t[0] > t[1])
                        .map(lambda t: f"{t[0]}-{t[1]}"),  # reversed
                        st.integers(4, 10**400).map(lambda i: f"0,2-{i}"),  # a range is no escape
                        _letters)),  # the empty subset and " , " included
    st.tuples(st.just("--agent"), st.one_of(st.from_regex(r"zz[a-z]{1,8}", fullmatch=True),
                                            st.from_regex(r"zz[a-z]{1,8}:[A-Z][a-z]{1,6}", fullmatch=True),
                                            st.from_regex(r"harness\.agent:[A-Z][a-z]{1,6}X", fullmatch=True))),
    st.tuples(st.just("--backend"), _text.filter(lambda s: s not in ("local", "ray"))),
    st.tuples(st.just("--address"), st.from_regex(r"[a-z0-9.]{1,12}:[0-9]{1,5}", fullmatch=True)),  # no --backend ray
)
_EMPTY_SUBSETS = [("--routes-subset", v) for v in ("", ",", " , ")]


@settings(max_examples=60, deadline=None)
@given(option=BAD_OPTIONS, command=st.sampled_from(["eval", "collect"]))
@example(option=_EMPTY_SUBSETS[0], command="eval")  # once ran every route
@example(option=_EMPTY_SUBSETS[2], command="eval")
@example(option=("--repetitions", "1000000000"), command="eval")  # once built its job list for ever
@example(option=("--repetitions", "9" * 300), command="collect")
def test_bad_cli_values_are_one_line_exit_2_and_write_nothing(tmp_path_factory, option, command):
    name, value = option
    if command == "collect" and name in ("--agent", "--agent-timeout", "--routes-subset"):
        command = "eval"  # eval-only options
    out = tmp_path_factory.mktemp("bad") / "out"
    code, printed = _cli([command, "--routes", "town12_smoke", "--out", str(out), f"{name}={value}"])
    lines = [ln for ln in printed.splitlines() if ln.strip()]
    assert code == 2, printed
    assert len(lines) == 1, printed
    assert lines[0].startswith("sumo-scimm: error: "), printed
    assert "Traceback" not in printed
    assert len(lines[0]) < 300, printed  # a long number is cut
    assert not out.exists()


@pytest.mark.parametrize("argv", [
    ["nets", "build", "--town", "town12"], ["routes", "make", "--set", "town12_smoke"],
    ["eval", "--routes", "town12_smoke"], ["render", "--routes", "town12_smoke", "--route", "0", "--out", "x.mp4"],
    ["collect", "--routes", "town12_smoke", "--out", "x"]])
def test_negative_seed_is_refused_by_every_command(argv, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, printed = _cli([*argv, "--seed=-1"])
    lines = [ln for ln in printed.splitlines() if ln.strip()]
    assert code == 2, printed
    assert len(lines) == 1, printed
    assert "invalid seed -1: must be >= 0" in lines[0], printed
    assert not list(tmp_path.iterdir())


def _valid_results() -> dict:
    from tests.test_scoring import _carla_file
    return _carla_file()


_json = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
                     lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
                     max_leaves=12)


def _paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, prefix + (i,))


_ALL_PATHS = [p for p in _paths(_valid_results()) if p]


@settings(max_examples=120, deadline=None)
@given(where=st.sampled_from(_ALL_PATHS), value=_json, drop=st.booleans(), raw=st.one_of(st.none(), _text))
@example(where=("_checkpoint", "progress", 1), value=math.inf, drop=False, raw=None)  # int(inf) overflows
@example(where=("_checkpoint",), value=None, drop=False, raw="[" * 100_000)  # too deep for json
def test_score_of_a_damaged_results_file_is_a_clean_exit(tmp_path_factory, where, value, drop, raw):
    """Replace (or drop) any one field of a Leaderboard results file, or write junk: score
    either rescoring it (exit 0, complete JSON written) or one line and exit 2 with no
    output file; never a traceback."""
    data = _valid_results()
    if raw is not None:
        text = raw
    else:
        parent = data
        for k in where[:-1]:
            parent = parent[k]
        if drop and isinstance(parent, dict):
            del parent[where[-1]]
        else:
            parent[where[-1]] = value
        text = json.dumps(data)
    d = tmp_path_factory.mktemp("score")
    src, dst = d / "results.json", d / "rescored.json"
    src.write_text(text)
    code, printed = _cli(["score", str(src), "--out", str(dst)])
    assert "Traceback" not in printed
    assert code in (0, 2), printed
    if code == 2:
        lines = [ln for ln in printed.splitlines() if ln.strip()]
        assert len(lines) == 1, printed
        assert lines[0].startswith("sumo-scimm: error: "), printed
        assert not dst.exists()
    else:
        json.loads(dst.read_text())
    assert not list(d.glob("*.tmp"))
