"""``sumo-scimm routes check`` and other bad input: one line naming the route and the
reason, exit code 2, no traceback (docs/design.md §2.2, §12)."""
from __future__ import annotations

import contextlib
import io

from hypothesis import given, settings, strategies as st

from sumo_scimm.cli import main
from scenarios import set_path

SMOKE = set_path("town12_smoke").read_text()


def _run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out + err


def _bad(tmp_path, text):
    p = tmp_path / "bad.xml"
    p.write_text(text)
    return str(p)


def _one_line(output: str) -> str:
    lines = [ln for ln in output.splitlines() if ln.strip()]
    assert len(lines) == 1, output
    assert "Traceback" not in output
    return lines[0]


def test_valid_file_passes(capsys):
    code, out = _run(capsys, "routes", "check", str(set_path("town12_smoke")))
    assert code == 0, out
    assert "4 routes OK" in out


def test_malformed_xml(tmp_path, capsys):
    code, out = _run(capsys, "routes", "check", _bad(tmp_path, SMOKE[: len(SMOKE) // 2]))
    assert code == 2
    assert "malformed XML" in _one_line(out)


def test_unknown_town(tmp_path, capsys):
    text = SMOKE.replace('<route id="2" town="town12">', '<route id="2" town="town99">')
    code, out = _run(capsys, "routes", "check", _bad(tmp_path, text))
    line = _one_line(out)
    assert code == 2, out
    assert "route 2:" in line
    assert "unknown town 'town99'" in line


def test_disconnected_route(tmp_path, capsys):
    # route 1 drives h33_h32 h32_h22; replace its second edge by one far away
    text = SMOKE.replace('edges="h33_h32 h32_h22"', 'edges="h33_h32 d00_d01"')
    assert text != SMOKE
    code, out = _run(capsys, "routes", "check", _bad(tmp_path, text))
    line = _one_line(out)
    assert code == 2, out
    assert "route 1:" in line
    assert "not connected" in line


def test_unknown_hazard_type(tmp_path, capsys):
    text = SMOKE.replace('type="ParkedObstacle"', 'type="FlyingSaucer"')
    code, out = _run(capsys, "routes", "check", _bad(tmp_path, text))
    line = _one_line(out)
    assert code == 2, out
    assert "route 3:" in line
    assert "unknown hazard type 'FlyingSaucer'" in line


def test_length_outside_set_bounds(tmp_path, capsys):
    text = SMOKE.replace('max_length="220"', 'max_length="150"')
    code, out = _run(capsys, "routes", "check", _bad(tmp_path, text))
    lines = out.splitlines()
    assert code == 2, out
    assert len(lines) == 2, out  # routes 0 and 2 (164.5 and 159.25 m) are longer than 150 m
    assert "route 0: length 164.5 m" in lines[0]
    assert "route 2: length 159.2 m" in lines[1]
    assert all("is outside the set's bounds [120, 150] m" in ln for ln in lines)


def test_entity_expansion_is_refused(tmp_path, capsys):
    bomb = ('<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY a "aaaaaaaaaa">'
            '<!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;"><!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;">]>\n'
            '<routes><route id="&c;" town="town12"/></routes>\n')
    path = _bad(tmp_path, bomb)
    code, out = _run(capsys, "routes", "check", path)
    assert code == 2, out
    assert "refused" in _one_line(out)
    code, out = _run(capsys, "eval", "--routes", path, "--out", str(tmp_path / "run"))  # the same problem, from eval
    assert code == 2, out
    assert _one_line(out).count(str(path)) == 2  # named once, then in the 'routes check' command it suggests


def test_missing_file_and_unknown_set_and_town(capsys, tmp_path, monkeypatch):
    code, out = _run(capsys, "routes", "check", str(tmp_path / "nope.xml"))
    assert code == 2, out
    assert _one_line(out) == f"{tmp_path / 'nope.xml'}: no such route file"  # the file named once
    monkeypatch.chdir(tmp_path)
    assert _run(capsys, "routes", "check", "./nope.xml")[1].strip() == "nope.xml: no such route file"
    code, out = _run(capsys, "routes", "show", "town13_short")
    assert code == 2, out
    assert "unknown route set 'town13_short'" in _one_line(out)
    code, out = _run(capsys, "nets", "show", "--town", "town99")
    assert code == 2, out
    assert "unknown town 'town99'" in _one_line(out)
    code, out = _run(capsys, "routes", "make", "--set", "nonsense")
    assert code == 2, out
    assert "unknown set 'nonsense'" in _one_line(out)


def test_bad_option_is_one_line(capsys):
    code, out = _run(capsys, "nets", "build", "--seed", "abc")
    assert code == 2, out
    assert "invalid int value" in _one_line(out)


@settings(max_examples=40, deadline=None)
@given(cut=st.integers(min_value=0, max_value=len(SMOKE) - 1), junk=st.text(max_size=20))
def test_any_damaged_file_gives_lines_and_exit_2_never_a_traceback(tmp_path_factory, cut, junk):
    """Truncate the smoke file anywhere and append junk: check never raises; a file cut
    before its closing tag fails with exit 2, and every line it prints names the file."""
    p = tmp_path_factory.mktemp("fuzz") / "f.xml"
    p.write_text(SMOKE[:cut] + junk)
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        code = main(["routes", "check", str(p)])
    if "</routes>" not in SMOKE[:cut]:
        assert code == 2
    lines = buf.getvalue().splitlines()
    assert lines, "check printed nothing"
    assert all(ln.startswith(str(p)) or ln.startswith("sumo-scimm: error") for ln in lines), buf.getvalue()
    assert "Traceback" not in buf.getvalue()
