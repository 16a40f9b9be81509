"""docs/results.md is rebuilt from the records the repository keeps of the run it reports
(docs/results/decisive).

Every table of the page sits between ``<!-- sumo-scimm report: SET/FILE -->`` (or
``SET[ARM,ARM]/FILE``) and ``<!-- end -->`` and must equal, character for character, the
file FILE that ``sumo-scimm report`` writes from the committed records of evaluation set
SET: every arm, or only the arms in brackets, in the order of ``sumo-scimm reproduce``,
each arm's seeds in seed order, as reproduce pairs them. Every other number of the page
with a decimal point must appear in those rebuilt tables, in the stage-time table
``reproduce`` prints from the committed stages.json, or in a committed JSON, CSV or
Markdown file of the run (the students' manifests, Table 2, the replay tables): a figure
typed by hand that no committed file holds fails.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from model.arm_tables import stage_table
from model.reproduce import ARMS, EVAL_SET
from sumo_scimm.cli import main

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "results.md"
RECORDS = ROOT / "docs" / "results" / "decisive"
TABLE = re.compile(r"<!-- sumo-scimm report: ([\w.-]+(?:\[[\w,]+\])?)/(\S+?) -->\n(.*?)\n<!-- end -->", re.S)
SELECTION = re.compile(r"([\w.-]+)(?:\[([\w,]+)\])?")
DECIMAL = re.compile(r"(?<![\w.])[-+]?\d+\.\d+(?!\.\d|\w)")  # a version such as 0.2.0 is not a figure


def _arms(route_set: Path, only: set[str] | None = None) -> list[str]:
    """``NAME=DIR,DIR...`` for every arm (or every arm in ``only``) with committed runs of
    ``route_set``."""
    out = []
    for arm, _ in ARMS:
        if only is not None and arm not in only:
            continue
        runs = sorted(route_set.glob(f"{arm}_s*"), key=lambda d: int(d.name.rsplit("_s", 1)[1]))
        if runs:
            out.append(f"{arm}=" + ",".join(str(d) for d in runs))
    return out


@pytest.fixture(scope="module")
def rebuilt(tmp_path_factory) -> dict[str, Path]:
    """{SET or SET[ARM,ARM] of the page's tables, and every evaluation set: the folder
    ``sumo-scimm report`` wrote from its committed records}."""
    sets = sorted(d.name for d in RECORDS.iterdir() if d.is_dir() and d.name not in ("models", "replay", "data"))
    assert sets, f"no committed records under {RECORDS}"
    out = {}
    for selection in sorted(set(sets) | {s for s, _, _ in TABLE.findall(PAGE.read_text())}):
        route_set, only = SELECTION.fullmatch(selection).groups()
        assert route_set in sets, f"{selection}: no committed records of this set"
        folder = tmp_path_factory.mktemp(route_set)
        assert main(["report", *_arms(RECORDS / route_set, set(only.split(",")) if only else None),
                     "--out", str(folder)]) == 0
        out[selection] = folder
    return out


def test_every_table_of_the_results_page_is_what_report_writes_from_the_committed_records(rebuilt):
    text = PAGE.read_text()
    tables = TABLE.findall(text)
    assert len(tables) >= 2, "the results page shows no rebuilt table"
    for route_set, name, shown in tables:
        assert route_set in rebuilt, f"{route_set}: no committed records of this set"
        made = (rebuilt[route_set] / name).read_text().rstrip("\n")
        assert shown == made, f"the table {route_set}/{name} differs from what report writes from the records"


def test_every_other_figure_of_the_results_page_is_in_a_rebuilt_table_or_a_committed_file(rebuilt):
    files = [f for folder in rebuilt.values() for f in folder.glob("*.md")]
    files += [f for pattern in ("*.json", "*.csv", "*.md") for f in RECORDS.rglob(pattern)]
    known = "\n".join(f.read_text() for f in files) + "\n"
    seeds = sorted({int(d.name.rsplit("_s", 1)[1]) for d in RECORDS.glob("*/*_s*") if d.is_dir()})
    second = next((s for s in rebuilt if s != EVAL_SET and "[" not in s), None)
    known += stage_table(json.loads((RECORDS / "stages.json").read_text()), [a for a, _ in ARMS], seeds,
                         EVAL_SET, second)
    prose = TABLE.sub("", PAGE.read_text())
    figures = set(DECIMAL.findall(prose))
    assert figures, "the page's prose quotes no figure (nothing to check)"
    in_files = set(DECIMAL.findall(known))
    unknown = sorted(f for f in figures if f not in in_files and f.lstrip("+") not in in_files)
    assert not unknown, f"figures of docs/results.md that no committed file holds: {unknown}"
