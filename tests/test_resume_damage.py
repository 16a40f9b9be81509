"""Damaged files of a run folder met by ``eval --resume`` and ``train curves``: a records.jsonl
line that is JSON and has every field but is not what ``eval`` writes (a record twice, a
route run not in the run, an infraction that is not a list, no Leaderboard index, a score
written as text, NaN, an unknown infraction key or status, a score or count that its
Leaderboard record contradicts), a run.jsonc naming an ego model that is not a text, a
history.json whose chosen epoch is not a number. Each gives one line naming the file (and
the line), exit code 2, no traceback, before anything runs: the folder is left byte for
byte as it was. A damaged workers.jsonl line (memory samples only) does not stop the run: it
is left out of the memory line, with one note."""
from __future__ import annotations

import gzip
import json
import shutil
from pathlib import Path

import pytest

from harness.scoring.validate import lb_problem
from model.curves import load_history
from tests.run_folder_helpers import SMOKE_TWO, _cli, _one_line_exit_2, finished_run, tree

DECISIVE = Path(__file__).resolve().parents[1] / "docs" / "results" / "decisive"


@pytest.fixture(scope="module")
def two_route_run(tmp_path_factory) -> Path:
    """A finished run of smoke routes 0 and 1."""
    return finished_run(tmp_path_factory, SMOKE_TWO)


def _copy(run: Path, tmp_path: Path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(run, out)
    return out


def _edit_lb(change):
    """A damage of line 1: ``change(lb)`` on its Leaderboard record."""
    def damage(lines: list[str]) -> list[str]:
        rec = json.loads(lines[0])
        change(rec["lb"])
        return [json.dumps(rec), *lines[1:]]
    return damage


def _edit(**fields):
    """A damage of line 1: its fields set to ``fields``."""
    return lambda lines: [json.dumps({**json.loads(lines[0]), **fields}), *lines[1:]]


def _foreign(lines: list[str]) -> list[str]:
    """Line 1 again as a consistent record of route 9, which the run does not have."""
    rec = json.loads(lines[0])
    rec.update(key="9_rep0", route_id="9")
    rec["lb"]["route_id"] = "RouteScenario_9_rep0"
    return [*lines, json.dumps(rec)]


@pytest.mark.parametrize("damage, line, words", [
    (lambda lines: [*lines, lines[0]], 3, ["repeats the record of route run 0_rep0 of line 1"]),
    (_foreign, 3, ["route run 9_rep0, which is not in this run", "run.jsonc"]),
    (_edit_lb(lambda lb: lb["infractions"].update(collisions_vehicle=5)), 1,
     ["infractions.collisions_vehicle is 5, not a list of messages"]),
    (_edit_lb(lambda lb: lb["infractions"].update(red_light=[7])), 1,
     ["infractions.red_light", "not a list of messages"]),
    (_edit_lb(lambda lb: lb.pop("index")), 1, ["has no 'index'"]),
    (_edit_lb(lambda lb: lb.update(index=1)), 1, ["Leaderboard index 1", "has index 0"]),
    (_edit_lb(lambda lb: lb["scores"].update(score_route="50")), 1, ["scores.score_route is '50', not a number"]),
    (_edit_lb(lambda lb: lb["meta"].update(route_length=float("nan"))), 1, ["meta.route_length is nan"]),
    (lambda lines: [lines[0].replace('"lb": {', '"lb": {"x": NaN, '), *lines[1:]], 1, ["unknown field 'x'"]),
    (_edit_lb(lambda lb: lb.update(infractions={"bogus": []})), 1, ["infractions has an unknown key 'bogus'"]),
    (_edit_lb(lambda lb: lb["infractions"].pop("route_dev")), 1, ["infractions has no 'route_dev' list"]),
    (_edit(status="Bogus status"), 1, ["status 'Bogus status' is not a route status"]),
    (_edit_lb(lambda lb: lb.update(status="Bogus status")), 1, ["status 'Bogus status' is not a route status"]),
    (_edit(ds=50.0), 1, ["ds 50.0 is not its Leaderboard record's score_composed"]),
    (_edit(collisions_vehicle=0), 1, ["collisions_vehicle 0 is not the number"]),
    (_edit(seed=5), 1, ["has seed 5"]),
])
def test_resume_refuses_a_damaged_records_line_before_running(two_route_run, tmp_path, damage, line, words):
    """Each damage is refused before a route runs or a file is written: kept, it would make
    the scorer fail (KeyError, TypeError, ValueError) after the tables were rewritten, or be
    scored."""
    out = _copy(two_route_run, tmp_path)
    path = out / "records.jsonl"
    path.write_text("\n".join(damage(path.read_text().splitlines())) + "\n")
    before = tree(out)
    code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])
    _one_line_exit_2(code, printed, f"{path} line {line} ", *words, "the file is damaged; delete that line")
    assert tree(out) == before


def test_resume_of_an_intact_folder_passes_the_record_checks(two_route_run, tmp_path):
    out = _copy(two_route_run, tmp_path)
    code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])
    assert code == 0, printed
    assert "2 routes ->" in printed and "note:" not in printed, printed


def test_the_committed_leaderboard_records_pass_the_resume_check():
    """The check is as strict as eval writes records, not stricter: every route record of the
    committed twenty-seed run passes it."""
    files = sorted(DECISIVE.rglob("results.json.gz"))
    assert files
    for f in files[:8]:
        for rec in json.loads(gzip.decompress(f.read_bytes()))["_checkpoint"]["records"]:
            assert lb_problem(rec) is None, (f, rec.get("route_id"))


@pytest.mark.parametrize("extra", [
    '{"key": "0_rep0"}\n',
    '{"key": "0_rep0", "host": "node1", "pid": 1, "routes": 1, "rss_mb": "big"}\n',
    '{"key": "0_rep0", "host": ["node1"], "pid": 1, "routes": 1, "rss_mb": 300.0}\n',
])
def test_a_damaged_workers_line_is_left_out_of_the_memory_line(two_route_run, tmp_path, extra):
    """Before: a KeyError or TypeError after every route had run and every file was written."""
    out = _copy(two_route_run, tmp_path)
    with open(out / "workers.jsonl", "a") as f:
        f.write(extra)
    code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])
    assert code == 0 and "Traceback" not in printed, printed
    assert f"note: {out / 'workers.jsonl'}: 1 damaged line left out of the worker memory figures" in printed
    assert "2 routes ->" in printed and "worker memory: 1 processes" in printed, printed


def test_a_rerun_counts_only_the_memory_samples_of_the_routes_it_keeps(two_route_run, tmp_path):
    """records.jsonl emptied: both routes run again, in a new worker; the old worker's samples
    are not counted as a second process."""
    out = _copy(two_route_run, tmp_path)
    (out / "records.jsonl").write_text("")
    old = {json.loads(line)["pid"] for line in (out / "workers.jsonl").read_text().splitlines()}
    code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])
    assert code == 0, printed
    assert "worker memory: 1 processes" in printed, printed
    pids = {json.loads(line)["pid"] for line in (out / "workers.jsonl").read_text().splitlines()}
    assert len(pids) == 1 and not pids & old


@pytest.mark.parametrize("vehicle", [["carla", "kinematic"], {"name": "carla"}, 5])
def test_resume_of_a_run_json_naming_no_ego_model_is_one_line(two_route_run, tmp_path, vehicle):
    out = _copy(two_route_run, tmp_path)
    data = json.loads((out / "run.jsonc").read_text())
    data["route_runs"]["0_rep0"]["vehicle"] = vehicle
    (out / "run.jsonc").write_text(json.dumps(data))
    before = tree(out)
    code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])
    _one_line_exit_2(code, printed, f"{out / 'run.jsonc'} is damaged", "route_runs.0_rep0.vehicle",
                     "start the run afresh")
    assert tree(out) == before


@pytest.mark.parametrize("chosen", ["x", "3", [3], True, 2.5, {"epoch": 3}])
def test_train_curves_with_a_chosen_epoch_that_is_not_a_number_is_one_line(tmp_path, chosen):
    run = tmp_path / "h"
    run.mkdir()
    history = [{"epoch": e, "train": {"loss": 1.0 / e}, "val": {"path": 1.0, "speed_wps": 0.5}} for e in (1, 2, 3)]
    (run / "history.json").write_text(json.dumps({"history": history, "chosen_epoch": chosen}))
    before = tree(tmp_path)
    code, printed = _cli(["train", "curves", "--runs", f"a={run}", "--out", str(tmp_path / "o.png")])
    _one_line_exit_2(code, printed, f"{run / 'history.json'}: chosen_epoch is", "not an epoch number")
    assert tree(tmp_path) == before
    (run / "history.json").write_text(json.dumps({"history": history, "chosen_epoch": 2.0}))
    assert load_history(run).chosen_epoch == 2  # a whole number written as a float is that epoch
