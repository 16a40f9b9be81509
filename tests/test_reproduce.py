"""``sumo-scimm reproduce`` end to end on the four town12_smoke routes (collect, the three
teachers, four students for one epoch, four closed-loop evaluations in real libsumo,
Tables 2-4 and the figures), its resume, and its refusals of bad input."""
from __future__ import annotations

import csv
import json

import pytest

from sumo_scimm.cli import main

SMOKE = ["--train-routes", "town12_smoke", "--val-routes", "town12_smoke", "--eval-routes", "town12_smoke"]


@pytest.mark.slow
def test_reproduce_runs_every_stage_and_resumes_without_redoing_them(tmp_path, capsys):
    out = tmp_path / "rep"
    argv = ["reproduce", "--seeds", "1", "--workers", "2", "--epochs", "1", "--out", str(out), *SMOKE]
    assert main(argv) == 0
    stages = json.loads((out / "stages.json").read_text())
    for arm in ("baseline", "fixed", "scimm", "smoother"):
        assert f"train {arm} s0" in stages
        assert f"eval {arm} s0" in stages
        assert (out / "models" / f"{arm}_s0" / "student.pt").is_file()
        with open(out / "runs" / f"{arm}_s0" / "records.csv", newline="") as f:
            assert len(list(csv.DictReader(f))) == 4  # one record per smoke route
    rows = list(csv.DictReader(open(out / "tables" / "table3.csv")))
    assert [r["arm"] for r in rows] == ["baseline", "fixed", "scimm", "smoother"]
    assert rows[0]["DS change %"] in ("0.0", "nan")
    assert (out / "tables" / "table4.md").is_file()
    assert (out / "tables" / "table2.csv").is_file()
    assert (out / "fig4_mode_posterior.png").stat().st_size > 0
    assert (out / "fig5_waypoint_overlay.png").is_file()
    assert "| total |" in (out / "README.md").read_text()
    # a second run finds every output and trains nothing again
    weights = (out / "models" / "scimm_s0" / "student.pt").stat().st_mtime_ns
    capsys.readouterr()
    assert main(argv) == 0
    assert (out / "models" / "scimm_s0" / "student.pt").stat().st_mtime_ns == weights
    log = capsys.readouterr().err
    assert "== eval scimm s0" in log, "the stage lines are on stderr"
    assert "== train" not in log


@pytest.mark.parametrize("extra, message", [
    (["--seeds", "0"], "--seeds must be >= 1"),
    (["--eval-routes", "no_such_set"], "unknown route set 'no_such_set'"),
    (["--address", "127.0.0.1:6379"], "--address needs --backend ray"),
])
def test_reproduce_refuses_bad_input_before_writing_anything(tmp_path, capsys, extra, message):
    out = tmp_path / "rep"
    assert main(["reproduce", "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err
    assert "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists()
