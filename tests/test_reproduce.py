"""``sumo-scimm reproduce`` end to end on the four town12_smoke routes (collect, the three
teachers, three students for one epoch, their closed-loop evaluations in real libsumo on the
evaluation set and on a second set (one of those routes), Tables 2-4 against both
references, the claims, the ranking and the figures), its resume, a later part adding a
seed (``--seeds 1-1``) whose tables pool both seeds, a third part in an empty folder given
only the earlier parts' records, and its refusals of bad input."""
from __future__ import annotations

import csv
import gzip
import json
import shutil

import pytest

from sumo_scimm.cli import main
from tests.run_folder_helpers import one_smoke_route

SMOKE = ["--train-routes", "town12_smoke", "--val-routes", "town12_smoke", "--eval-routes", "town12_smoke"]


@pytest.mark.slow
def test_reproduce_runs_every_stage_and_resumes_without_redoing_them(tmp_path, capsys):
    arms = ["baseline", "control", "scimm"]  # both references and a teacher arm
    out = tmp_path / "rep"
    # the second set: smoke route 3 alone, in a file whose stem (the set's label) is town12_smoke
    (tmp_path / "second").mkdir()
    second = one_smoke_route(tmp_path / "second", "3", "town12_smoke")
    argv = ["reproduce", "--seeds", "1", "--workers", "2", "--epochs", "1", "--out", str(out), *SMOKE,
            "--arms", ",".join(reversed(arms)), "--second-routes", str(second)]
    assert main(argv) == 0
    stages = json.loads((out / "stages.json").read_text())
    assert "train 3 students s0-0" in stages  # side by side, one stage
    for arm in arms:
        assert f"eval {arm} s0" in stages
        assert f"eval {arm} s0 on town12_smoke" in stages
        assert (out / "models" / f"{arm}_s0" / "student.pt").is_file()
        for run, n in ((out / "runs" / f"{arm}_s0", 4), (out / "runs" / "town12_smoke" / f"{arm}_s0", 1)):
            with open(run / "records.csv", newline="") as f:
                assert len(list(csv.DictReader(f))) == n  # one record per route of the set
    assert not (out / "models" / "fixed_s0").exists(), "an arm left out of --arms is not trained"
    for tables in (out / "tables", out / "tables" / "town12_smoke"):
        rows = list(csv.DictReader(open(tables / "table3.csv")))
        assert [r["arm"] for r in rows] == arms  # in the fixed order, the baseline first
        assert rows[0]["DS change %"] in ("0.0", "nan")
        assert (tables / "table4_common.md").is_file()
        claims = list(csv.DictReader(open(tables / "claims.csv")))
        assert {r["DS"] for r in claims} <= {"reproduced", "not reproduced", "undecided", "no interval"}
        assert "| hazard | n | " + " | ".join(arms) + " |" in (tables / "hazard_ds.md").read_text()
        rows = list(csv.DictReader(open(tables / "table3_vs_control.csv")))
        assert [r["arm"] for r in rows] == ["control", "baseline", "scimm"]
        assert {(r["arm"], r["against"]) for r in claims} == {("control", "baseline"), ("scimm", "baseline"),
                                                             ("scimm", "control")}
    assert "town12_smoke (second evaluation) rank" in (out / "tables" / "ranking.md").read_text()
    # both sets' records are kept, the second set's under its own name: neither overwrites the other
    for label, n in (("town12_smoke", 4), ("town12_smoke_second", 1)):
        with gzip.open(out / "records" / label / "scimm_s0" / "records.csv.gz", "rt", newline="") as f:
            assert len(list(csv.DictReader(f))) == n
    assert (out / "tables" / "table2.csv").is_file()
    assert (out / "fig4_mode_posterior.png").stat().st_size > 0
    assert (out / "fig5_waypoint_overlay.png").is_file()
    assert (out / "loss_curves_seed0.png").stat().st_size > 0
    # the replay: every arm's student on the expert's inputs, rows and table named by arm
    with open(out / "replay" / "s0" / "replay.csv") as f:
        replayed = list(csv.DictReader(f))
    assert [r["agent"] for r in replayed[:3]] == arms and len(replayed) == 3 * 4
    assert all(r["message"] == "" for r in replayed)
    assert "| scimm |" in (out / "replay" / "s0" / "table.md").read_text()
    readme = (out / "README.md").read_text()
    assert "| arm | seed | train s | eval town12_smoke s | eval town12_smoke s |" in readme
    assert "Total: " in readme
    # a second run finds every output and trains nothing again
    weights = (out / "models" / "scimm_s0" / "student.pt").stat().st_mtime_ns
    capsys.readouterr()
    assert main(argv) == 0
    assert (out / "models" / "scimm_s0" / "student.pt").stat().st_mtime_ns == weights
    log = capsys.readouterr().err
    assert "== eval scimm s0" in log, "the stage lines are on stderr"
    assert "== eval scimm s0 on town12_smoke" in log
    assert "== train" not in log
    assert "== replay" not in log, "a finished replay is not redone"
    # a later part adds seed 1 of two arms to the same folder: the tables pool seeds 0 and 1
    assert main(["reproduce", "--seeds", "1-1", "--workers", "2", "--epochs", "1", "--out", str(out), *SMOKE,
                 "--arms", "baseline,scimm", "--second-routes", "none"]) == 0
    assert (out / "models" / "scimm_s1" / "student.pt").is_file()
    assert not (out / "models" / "scimm_s2").exists() and not (out / "models" / "control_s1").exists()
    rows = {r["arm"]: r for r in csv.DictReader(open(out / "tables" / "table3.csv"))}
    assert (rows["baseline"]["runs"], rows["scimm"]["runs"], rows["scimm"]["DS seeds"]) == ("2", "2", "2")
    assert "(2 seeds: seeds 0, 1; arms baseline, scimm)" in (out / "README.md").read_text()
    # a third part on another machine: an empty folder given only the records of the first
    # two (as a repository keeps them) collects again, runs seed 2 and pools seeds 0-2
    other = tmp_path / "other"
    shutil.copytree(out / "records", other / "records")
    assert main(["reproduce", "--seeds", "2-2", "--workers", "2", "--epochs", "1", "--out", str(other), *SMOKE,
                 "--arms", "baseline,scimm", "--second-routes", "none"]) == 0
    assert not (other / "models" / "scimm_s0" / "student.pt").exists(), "an earlier seed is not trained again"
    rows = {r["arm"]: r for r in csv.DictReader(open(other / "tables" / "table3.csv"))}
    assert (rows["baseline"]["runs"], rows["scimm"]["runs"], rows["scimm"]["DS seeds"]) == ("3", "3", "3")
    assert "(3 seeds: seeds 0, 1, 2; arms baseline, scimm)" in (other / "README.md").read_text()
    assert (other / "fig5_waypoint_overlay.png").is_file(), "Fig. 5 drawn from the seed run here"
    for seed in range(3):
        assert (other / "records" / "town12_smoke" / f"scimm_s{seed}" / "records.csv.gz").is_file()
        assert (other / "records" / "replay" / f"s{seed}.md").is_file()
    assert (other / "records" / "data" / "train.run.jsonc").is_file()


@pytest.mark.parametrize("extra, message", [
    (["--seeds", "0"], "--seeds must be >= 1"),
    (["--eval-routes", "no_such_set"], "unknown route set 'no_such_set'"),
    (["--address", "127.0.0.1:6379"], "--address needs --backend ray"),
    (["--arms", "scimm,imm"], "--arms: unknown arm 'imm'"),
    (["--second-routes", "no_such_set"], "unknown route set 'no_such_set'"),
    (["--arms", "scimm,baseline,scimm"], "--arms 'scimm,baseline,scimm': arm 'scimm' is named twice"),
    (["--seeds", "0-99999999999999999999"], "a seed is at most"),  # once: the collect stage started
    (["--seeds", "99999999999999999999"], "at most 1000 in one reproduce"),
    (["--seeds", "5-2000"], "asks for 1996 seeds, at most 1000 in one reproduce"),
])
def test_reproduce_refuses_bad_input_before_writing_anything(tmp_path, capsys, extra, message):
    out = tmp_path / "rep"
    assert main(["reproduce", "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err
    assert "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists()


def _duplicate_route_id(folder):
    path = one_smoke_route(folder, "3", "dup")
    text = path.read_text()
    head, route = text.split("\n", 2)[:2], text.split("\n", 2)[2].removesuffix("</routes>\n")
    path.write_text("\n".join(head) + "\n" + route + route + "</routes>\n")
    return path, "route 3: duplicate route id"


def _unknown_encoding(folder):
    path = one_smoke_route(folder, "3", "badenc")
    path.write_text(path.read_text().replace('encoding="UTF-8"', 'encoding="bogus-enc"', 1))
    return path, ""


def _not_xml(folder):
    path = folder / "binary.xml"
    path.write_bytes(bytes(range(256)))
    return path, ""


@pytest.mark.parametrize("option", ["--train-routes", "--val-routes", "--eval-routes", "--second-routes"])
@pytest.mark.parametrize("make", [_duplicate_route_id, _unknown_encoding, _not_xml])
def test_reproduce_checks_every_route_file_before_the_first_stage(tmp_path, capsys, option, make):
    """As 'routes check' does (and eval before a route runs): before, a bad --val-routes or
    --eval-routes was found only at its stage, hours after the collect stage started."""
    path, words = make(tmp_path)
    out = tmp_path / "rep"
    assert main(["reproduce", "--out", str(out), option, str(path)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith(f"sumo-scimm: error: {option}: {path}"), err
    assert words in err and f"routes check {path}" in err, err
    assert not out.exists()
