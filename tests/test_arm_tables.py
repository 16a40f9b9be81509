"""The arm tables of ``sumo-scimm reproduce`` (model.arm_tables): claim verdicts from
hand-made intervals, the ranking of arms on two sets, the claims table from hand-made
Table 3/4 rows, DS per hazard side by side, the stage-time table, and the ``--arms`` choice."""
from __future__ import annotations

import csv
import math

import pytest

from harness.common.errors import BadInput
from model.arm_tables import (AGREES, DIFFERS, NO_INTERVAL, NOT_REPRODUCED, REPRODUCED, UNDECIDED, claims, eval_stage,
                              hazard_ds, paper_change, paper_claims, ranking, references, size_agreement, stage_table,
                              train_seconds, train_stage, verdict)
from model.reproduce import SECOND_SET, select_arms


@pytest.mark.parametrize("diff, p_holm, better, expected", [
    (2.0, 0.01, "higher", REPRODUCED),  # DS up, significant after Holm
    (-2.0, 0.01, "higher", NOT_REPRODUCED),  # DS down
    (2.0, 0.2, "higher", UNDECIDED),
    (-0.5, 0.049, "lower", REPRODUCED),  # Collision/km down
    (0.5, 0.0, "lower", NOT_REPRODUCED),
    (-0.5, 0.05, "lower", UNDECIDED),  # p at alpha does not reject
    (0.0, 0.0, "higher", UNDECIDED),  # no difference has no side
    (math.nan, 0.01, "higher", NO_INTERVAL),
    (1.0, math.nan, "lower", NO_INTERVAL),
])
def test_verdict_reads_the_holm_adjusted_p_and_the_side_of_zero(diff, p_holm, better, expected):
    assert verdict(diff, p_holm, better) == expected


def test_verdict_refuses_an_unknown_direction():
    with pytest.raises(ValueError, match="higher"):
        verdict(1.0, 0.01, "up")


def test_claims_are_the_papers_six_in_its_directions():
    assert [(k, b) for k, _, b, _ in paper_claims()] == [
        ("DS", "higher"), ("Collision/km", "lower"), ("steering_jerk_moving", "lower"),
        ("longitudinal_jerk_moving", "lower"), ("curvature_variation_wps", "lower"), ("speed_variation_kmh", "lower")]


def test_the_papers_relative_change_and_whether_our_interval_holds_it():
    ds = paper_claims()[0][3]
    # SC-IMM against the baseline in the paper: 100 (75.11 - 58.70) / 58.70 = +27.956 %
    assert paper_change(ds, "scimm", "baseline") == pytest.approx(27.956, abs=1e-3)
    assert math.isnan(paper_change(ds, "scimm", "control"))  # the paper has no loss-matched control
    assert size_agreement(27.956, -10.0, 30.0) == AGREES
    assert size_agreement(27.956, -10.0, 20.0) == DIFFERS
    assert size_agreement(math.nan, -10.0, 20.0) == ""


def _row(arm: str, diff: float, low: float, high: float, p: float = 0.5) -> dict:
    """A Table 3 + 4 CSV row whose every figure has the same difference, interval, change
    interval (the difference's, in %) and p."""
    row = {"arm": arm}
    for key, *_ in paper_claims():
        row.update({f"{key} diff": diff, f"{key} diff ci95_low": low, f"{key} diff ci95_high": high,
                    f"{key} change % ci95_low": low, f"{key} change % ci95_high": high, f"{key} diff p": p,
                    f"{key} diff mde80": 2.0, f"{key} seeds": 3})
    return row


def test_claims_table_marks_each_arm_against_each_reference_once_with_holm_over_the_table():
    rows = {"baseline": {"table3": [_row("baseline", 0, 0, 0), _row("control", 1.0, 0.5, 1.5, 0.04),
                                    _row("scimm", 30.0, 10.0, 50.0, 0.001)], "table4": []},
            "control": {"table3": [_row("control", 0, 0, 0), _row("baseline", -1.0, -1.5, -0.5),
                                   _row("scimm", -0.2, -1.0, 0.6, 0.3)], "table4": []}}
    out, md = claims(rows)
    # baseline against control is control against baseline reversed: left out
    assert [(r["arm"], r["against"]) for r in out] == [("control", "baseline"), ("scimm", "baseline"),
                                                        ("scimm", "control")]
    # the family: 3 pairs x 6 claims = 18 p; Holm multiplies the six 0.001 by 18..13 (running
    # maximum 0.018), the six 0.04 by 12..7 (0.48), the six 0.3 by 6..1 (capped at 1)
    assert out[1]["DS p holm"] == pytest.approx(0.018) and out[0]["DS p holm"] == pytest.approx(0.48)
    assert out[2]["DS p holm"] == pytest.approx(1.0)
    assert out[1]["DS"] == REPRODUCED and out[1]["Collision/km"] == NOT_REPRODUCED  # +30: DS up, collisions up
    assert out[0]["DS"] == UNDECIDED  # p 0.04 alone, 0.48 in the family
    assert out[2]["DS"] == UNDECIDED and out[2]["speed_variation_kmh"] == UNDECIDED
    # the paper's +28.0 % DS lies in [10, 50] %; its -62.3 % Collision/km does not
    assert out[1]["DS size"] == AGREES and out[1]["Collision/km size"] == DIFFERS and out[0]["DS size"] == ""
    assert ("| scimm | baseline | +30 [10, 50], MDE 2, p 0.018: reproduced; paper +28.0 %, ours [+10.0, +50.0] %: "
            "size agrees |") in md
    assert "Family: the 18 claims of this table" in md
    common = {ref: {f"{k}_common": v for k, v in stems.items()} for ref, stems in rows.items()}
    out_common, md_common = claims(common, common=True)
    assert out_common == out and "(the routes every run completed;" in md_common


def test_ranking_puts_the_sets_side_by_side_in_the_first_sets_order():
    md = ranking({"town12_short": {"baseline": 44.5, "fixed": 51.5, "scimm": 54.0},
                  "town12_second": {"baseline": 52.6, "fixed": 53.9, "scimm": 53.5}})
    lines = md.splitlines()
    assert lines[2] == "| arm | town12_short DS | town12_short rank | town12_second DS | town12_second rank |"
    assert lines[4:] == ["| scimm | 54.00 | 1 | 53.50 | 2 |", "| fixed | 51.50 | 2 | 53.90 | 1 |",
                         "| baseline | 44.50 | 3 | 52.60 | 3 |"]


def test_ranking_shares_a_rank_on_a_tie_and_marks_a_missing_arm():
    md = ranking({"a": {"x": 50.0, "y": 50.0, "z": 40.0}, "b": {"x": 10.0, "z": 20.0}})
    assert md.splitlines()[4:] == ["| x | 50.00 | 1 | 10.00 | 2 |", "| y | 50.00 | 1 | - | - |",
                                   "| z | 40.00 | 3 | 20.00 | 1 |"]


def test_hazard_ds_puts_the_arms_side_by_side():
    per_hazard = [{"hazard": "StopSignJunction", "baseline SR": 10.0, "baseline DS": 41.25, "baseline n": 12,
                   "scimm SR": 50.0, "scimm DS": 60.0, "scimm n": 12},
                  {"hazard": "unknown", "baseline SR": math.nan, "baseline DS": math.nan, "baseline n": 0,
                   "scimm SR": 0.0, "scimm DS": 5.0, "scimm n": 3}]
    assert hazard_ds(per_hazard, ["baseline", "scimm"]).splitlines()[2:] == [
        "| hazard | n | baseline | scimm |", "| --- | --- | --- | --- |",
        "| StopSignJunction | 12 | 41.2 | 60.0 |", "| unknown | 0/3 | - | 5.0 |"]


def test_stage_table_has_a_row_per_arm_and_seed_and_the_total():
    times = {"collect train": 300.0, "teacher scimm": 7.0, "train baseline s0": 400.0, "eval baseline s0": 200.0,
             eval_stage("baseline", 0, SECOND_SET): 150.0, "train scimm s0": 380.0, "eval scimm s0": 180.0,
             "fig 4": 3.0}
    md = stage_table(times, ["baseline", "scimm"], [0], "town12_short", SECOND_SET)
    assert "| collect train | 300 |" in md and "| fig 4 | 3 |" in md and "| train scimm s0 |" not in md
    assert "| arm | seed | train s | eval town12_short s | eval town12_second s |" in md
    assert "| baseline | 0 | 400 | 200 | 150 |" in md
    assert "| scimm | 0 | 380 | 180 | - |" in md  # its second-set evaluation has not run
    assert "Total: 1620 s (27.0 min)" in md


def test_a_training_side_by_side_counts_its_share_of_the_stage():
    # seeds 1-2 of two arms trained side by side in one 1,000 s stage: 250 s each; seed 0's
    # own stage stays its own; a seed no stage trained has none
    times = {"train scimm s0": 380.0, train_stage(4, range(1, 3)): 1000.0, "eval scimm s1": 180.0}
    assert train_stage(4, range(1, 3)) == "train 4 students s1-2"
    assert [train_seconds(times, "scimm", k) for k in (0, 1, 2, 3)] == [380.0, 250.0, 250.0, None]
    md = stage_table(times, ["baseline", "scimm"], [1], "town12_short", None)
    assert "| train 4 students s1-2 | 1000 |" in md
    assert "| baseline | 1 | 250 | - |" in md and "| scimm | 1 | 250 | 180 |" in md


def test_references_are_baseline_then_control_else_the_first_arm():
    assert references(["baseline", "control", "scimm"]) == ["baseline", "control"]
    assert references(["control", "fixed"]) == ["control"]
    assert references(["fixed", "scimm"]) == ["fixed"]


def test_arms_are_chosen_in_their_fixed_order_and_an_unknown_name_is_refused():
    assert select_arms(None) == ("baseline", "control", "fixed", "scimm", "smoother")
    assert select_arms("scimm, baseline") == ("baseline", "scimm")
    with pytest.raises(BadInput, match="unknown arm 'imm'"):
        select_arms("baseline,imm")


def test_cli_second_set_is_the_reproduce_default():
    from sumo_scimm import model_commands
    assert model_commands.SECOND_SET == SECOND_SET


def test_seeds_are_a_count_from_0_or_a_range():
    from model.reproduce import parse_seeds
    assert parse_seeds("3") == range(0, 3)
    assert parse_seeds("3-5") == range(3, 6)
    assert parse_seeds("4-4") == range(4, 5)
    for bad, message in (("0", "--seeds must be >= 1"), ("5-3", "ends before it starts"), ("a-b", "expected K"),
                         ("-2", "expected K"), ("1,2", "expected K")):
        with pytest.raises(BadInput, match=message):
            parse_seeds(bad)


def test_the_tables_pool_every_seed_present_and_pair_the_arms_by_seed(tmp_path):
    """Seeds 0 and 1 run first, seed 2 added later (its scimm evaluation unfinished): the
    tables pool seeds 0-2 of the baseline and 0-1 of scimm, paired by seed. DS of each run's two
    routes: baseline 50, 60, 70 by seed; scimm 56, 64 (a stray folder of another arm and the
    expert's run are not arms). Differences seed by seed: +6, +4: mean 5, sd sqrt(2), t_{0.975, 1}
    = 12.7062 (Cauchy) -> 5 +- 12.7062 sqrt(2) / sqrt(2) = 5 +- 12.7062."""
    from model.arm_tables import write_set_tables
    from model.reproduce import pooled_runs
    from tests.test_report import _run
    runs = tmp_path / "runs"
    for arm, dss in (("baseline", (50.0, 60.0, 70.0)), ("scimm", (56.0, 64.0))):
        for seed, ds in enumerate(dss):
            _run(runs / f"{arm}_s{seed}", [("0_rep0", ds, 0, 0.3, 1.0), ("1_rep0", ds, 0, 0.3, 1.0)])
    _run(runs / "expert_s0", [("0_rep0", 90.0, 0, 0.3, 1.0)])
    (runs / "scimm_s2").mkdir()  # an evaluation that has not finished
    pooled, seeds = pooled_runs(runs, ("baseline", "scimm"))
    assert seeds == {"baseline": [0, 1, 2], "scimm": [0, 1]}
    assert pooled["scimm"] == [runs / "scimm_s0", runs / "scimm_s1"]
    write_set_tables(pooled, tmp_path / "tables", seeds)
    row = {r["arm"]: r for r in csv.DictReader(open(tmp_path / "tables" / "table3.csv"))}["scimm"]
    assert float(row["DS"]) == 60.0 and row["DS seeds"] == "2"
    assert (float(row["DS diff"]), float(row["DS diff ci95_low"]), float(row["DS diff ci95_high"])) == \
        pytest.approx((5.0, 5 - 12.7062, 5 + 12.7062), abs=1e-3)
