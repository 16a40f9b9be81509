"""``sumo-scimm report`` on run folders whose records.jsonl is damaged: every file of every
run folder (results.json, records.csv, records.jsonl) is read and checked before a table is
written, so a damaged one gives one line naming the file and the fix, exit code 2, no
traceback, and no table: --out is left as it was (not made, or holding only what it held)."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from tests.run_folder_helpers import SMOKE_ONE, _cli, _one_line_exit_2, finished_run


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    return finished_run(tmp_path_factory, SMOKE_ONE)


def _first(folder: Path) -> dict:
    return json.loads((folder / "records.jsonl").read_text().splitlines()[0])


def _random_bytes(folder: Path) -> None:
    (folder / "records.jsonl").write_bytes(bytes(range(128, 256)) * 20)  # not UTF-8


def _without_lb(folder: Path) -> None:
    (folder / "records.jsonl").write_text('{"key": "0_rep0"}\n')  # a line without its Leaderboard record


def _hazard_a_number(folder: Path) -> None:
    (folder / "records.jsonl").write_text(json.dumps({**_first(folder), "hazard": 5}) + "\n")


def _garbage_line_inside(folder: Path) -> None:
    good = json.dumps(_first(folder))
    (folder / "records.jsonl").write_text(f"{good}\nnot a record\n{good}\n")


def _no_line(folder: Path) -> None:
    (folder / "records.jsonl").write_text("\n")


@pytest.mark.parametrize("damage, words", [
    (_random_bytes, ["records.jsonl: cannot be read", "UnicodeDecodeError", "move records.jsonl away"]),
    (_without_lb, ["records.jsonl line 1 has no 'lb'", "damaged", "--resume"]),
    (_hazard_a_number, ["records.jsonl line 1: hazard is '5', not a hazard type", "damaged"]),
    (_garbage_line_inside, ["records.jsonl line 2 is not a JSON record", "damaged"]),
    (_no_line, ["records.jsonl holds no route record", "damaged", "move records.jsonl away"]),
])
def test_report_refuses_a_damaged_records_jsonl_before_writing_a_table(run, tmp_path, damage, words):
    """Two arms, the second one damaged: the first one's tables could be made, but no file is
    written until every input has been read and checked."""
    bad = tmp_path / "bad"
    shutil.copytree(run, bad)
    damage(bad)
    out = tmp_path / "report"
    code, printed = _cli(["report", f"baseline={run}", f"scimm={bad}", "--out", str(out)])
    _one_line_exit_2(code, printed, str(bad / "records.jsonl"), *words)
    assert not out.exists(), sorted(p.name for p in out.rglob("*"))
    # an --out that holds files already: left as it was, no table added or replaced
    out.mkdir()
    (out / "table3.md").write_text("earlier\n")
    code, printed = _cli(["report", f"baseline={run}", f"scimm={bad}", "--out", str(out)])
    _one_line_exit_2(code, printed, str(bad / "records.jsonl"))
    assert [p.name for p in out.iterdir()] == ["table3.md"]
    assert (out / "table3.md").read_text() == "earlier\n"


def test_a_report_of_good_folders_writes_every_table_and_no_temporary_folder(run, tmp_path):
    out = tmp_path / "report"
    code, printed = _cli(["report", f"baseline={run}", f"scimm={run}", "--out", str(out)])
    assert code == 0, printed
    made = sorted(p.name for p in out.iterdir())
    assert {"table3.csv", "table3.md", "table4_common.md", "b2d.csv", "per_hazard.csv", "hazard_ds.md",
            "claims.md"} <= set(made), made
    assert all(p.is_file() and ".tmp" not in p.name for p in out.iterdir()), made
