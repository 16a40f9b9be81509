"""The decisive run's committed records (docs/results/decisive, docs/preregistration.md) are
whole and paired: the seeds present are 0..n-1, each has the four pre-registered arms on
both evaluation sets, each a finished run, every student of a seed was trained on the same
training and validation data (its manifest's hashes) with the seed it is filed under, and
``sumo-scimm report`` pools them with one run per seed for every arm."""
from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import pytest

from harness.scoring.report import check_run
from sumo_scimm.cli import main

RECORDS = Path(__file__).resolve().parents[1] / "docs" / "results" / "decisive"
ARMS = ("baseline", "control", "fixed", "scimm")  # docs/preregistration.md, "Arms, seeds, sets"
SETS = ("town12_short", "town12_second")


def _seeds(folder: Path) -> dict[str, list[int]]:
    found: dict[str, list[int]] = {}
    for run in folder.iterdir():
        m = re.fullmatch(r"(.+)_s(\d+)", run.name)
        assert m, f"{run}: not an <arm>_s<seed> folder"
        found.setdefault(m[1], []).append(int(m[2]))
    return {arm: sorted(s) for arm, s in found.items()}


def test_every_seed_has_the_four_arms_on_both_sets_each_run_finished():
    seeds = _seeds(RECORDS / SETS[0])
    assert sorted(seeds) == sorted(ARMS)
    every = seeds[ARMS[0]]
    assert every and all(s == every for s in seeds.values())
    assert every == list(range(len(every))), "the parts run the seeds in order, from seed 0"
    for route_set in SETS:
        assert _seeds(RECORDS / route_set) == seeds
        for arm in ARMS:
            for seed in every:
                check_run(RECORDS / route_set / f"{arm}_s{seed}")  # ReportError if unfinished or damaged


def test_the_students_of_a_seed_share_their_data_and_carry_their_seed():
    by_seed: dict[int, set] = {}
    for path in sorted((RECORDS / "models").glob("*.json")):
        arm, seed = re.fullmatch(r"(.+)_s(\d+)", path.stem).groups()
        m = json.loads(path.read_text())
        assert arm in ARMS and m["seed"] == int(seed)
        by_seed.setdefault(int(seed), set()).add((m["data_hash"], m["val_hash"]))
    assert sorted(by_seed) == _seeds(RECORDS / SETS[0])[ARMS[0]]
    assert all(len(hashes) == 1 for hashes in by_seed.values()), f"a seed's arms saw other data: {by_seed}"


@pytest.mark.parametrize("route_set", SETS)
def test_report_pools_one_run_per_seed_for_every_arm(route_set, tmp_path):
    seeds = _seeds(RECORDS / route_set)
    argv = [f"{arm}=" + ",".join(str(RECORDS / route_set / f"{arm}_s{s}") for s in seeds[arm]) for arm in ARMS]
    assert main(["report", *argv, "--out", str(tmp_path)]) == 0
    with open(tmp_path / "table3.csv", newline="") as f:
        rows = {r["arm"]: r for r in csv.DictReader(f)}
    assert list(rows) == list(ARMS)
    assert all(rows[a]["runs"] == str(len(seeds[a])) for a in ARMS)
