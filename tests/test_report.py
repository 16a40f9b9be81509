"""Tables 3-4 over several seeds per arm (harness.scoring.report.write_arm_report), on hand-made
run folders whose figures are worked out by hand."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from harness.scoring.report import TABLE4, arm_figures, fig, write_arm_report

COLS = ["key", "ds", "rc", "is", "collisions_layout", "collisions_pedestrian", "collisions_vehicle",
        "km_driven"] + [k for k, _ in TABLE4]


def _run(folder: Path, rows: list[tuple]) -> Path:
    """rows: (key, ds, rc, is, vehicle collisions, km, steering jerk)."""
    folder.mkdir(parents=True)
    with open(folder / "records.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLS)
        for key, ds, rc, is_, coll, km, sj in rows:
            w.writerow([key, ds, rc, is_, 0, 0, coll, km, sj, 1.0, 0.001, 0.5])
    mean = {"score_composed": sum(r[1] for r in rows) / len(rows), "score_route": 100.0, "score_penalty": 1.0}
    (folder / "results.json").write_text(json.dumps({"_checkpoint": {"global_record": {"scores_mean": mean}},
                                                     "entry_status": "Finished"}))
    return folder


def test_mean_over_seeds_interval_and_change_against_the_baseline(tmp_path):
    b0 = _run(tmp_path / "b0", [("0_rep0", 40.0, 100, 0.4, 1, 0.3, 2.0), ("1_rep0", 60.0, 100, 0.6, 0, 0.3, 4.0)])
    b1 = _run(tmp_path / "b1", [("0_rep0", 50.0, 100, 0.5, 0, 0.3, 2.0), ("1_rep0", 70.0, 100, 0.7, 1, 0.3, 4.0)])
    s0 = _run(tmp_path / "s0", [("0_rep0", 66.0, 100, 0.66, 0, 0.3, 1.0), ("1_rep0", 66.0, 100, 0.66, 0, 0.3, 1.0)])
    f = arm_figures([b0, b1], n_boot=500)
    # DS: seed means 50 and 60 -> 55; collisions: 1 per 0.6 km in each seed -> 1.667 /km
    assert f["DS"][0] == pytest.approx(55.0)
    assert f["Collision/km"][0] == pytest.approx(1 / 0.6)
    assert f["steering_jerk"][0] == pytest.approx(3.0)
    # any resample of seeds and routes averages values between the smallest and largest route
    assert 40.0 <= f["DS"][1] <= 55.0 <= f["DS"][2] <= 70.0
    # one seed whose routes agree: the interval collapses to the value
    g = arm_figures([s0], n_boot=200)
    assert g["DS"] == pytest.approx((66.0, 66.0, 66.0))
    text = write_arm_report({"baseline": [b0, b1], "scimm": [s0]}, tmp_path / "tables", n_boot=200)
    rows = list(csv.DictReader(open(tmp_path / "tables" / "table3.csv")))
    # change as the paper computes it: 100 (66 - 55) / 55 = +20 %; steering jerk 100 (1 - 3) / 3
    assert float(rows[1]["DS change %"]) == pytest.approx(20.0)
    rows4 = list(csv.DictReader(open(tmp_path / "tables" / "table4.csv")))
    assert float(rows4[1]["steering_jerk change %"]) == pytest.approx(-200 / 3)
    assert "(+20.0 %)" in text
    assert (tmp_path / "tables" / "table3.md").is_file()
    # figures keep 4 significant digits: the baseline's DS reads 55, its steering jerk 3
    assert "| baseline | 2 | 55 [" in text
    assert "| scimm | 1 | 66 [66, 66] (+20.0 %)" in text


def test_small_figures_keep_their_significant_digits():
    assert fig(0.000312345) == "0.0003123"
    assert fig(54.9712) == "54.97"
    assert fig(100.0) == "100"
