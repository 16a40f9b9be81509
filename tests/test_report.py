"""Tables 3-4 of several arms (harness.scoring.report), on hand-made run folders whose figures
are worked out by hand: means with intervals, route-paired differences, seed-level
resampling, the common-routes tables, and older records completed from their logs."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from harness.scoring.records import STABILITY
from harness.scoring.report import (ReportError, arm_figures, compare, completed_keys, fig, parse_arms, route_rows,
                                    write_report)
from harness.scoring.stability import stability

COLS = ["key", "status", "ds", "rc", "is", "collisions_layout", "collisions_pedestrian", "collisions_vehicle",
        "km_driven", *STABILITY]


def _run(folder: Path, rows: list[tuple], columns=COLS) -> Path:
    """rows: (key, ds, vehicle collisions, km, steering jerk (moving), status)."""
    folder.mkdir(parents=True)
    with open(folder / "records.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(columns)
        for key, ds, coll, km, sj, *status in rows:
            stab = {k: 1.0 for k in STABILITY} | {"steering_jerk_moving": sj}
            rec = {"key": key, "status": status[0] if status else "Completed", "ds": ds, "rc": 100.0,
                   "is": ds / 100, "collisions_layout": 0, "collisions_pedestrian": 0, "collisions_vehicle": coll,
                   "km_driven": km, **stab}
            w.writerow([rec[c] for c in columns])
    mean = {"score_composed": sum(r[1] for r in rows) / len(rows), "score_route": 100.0, "score_penalty": 1.0}
    (folder / "results.json").write_text(json.dumps({"_checkpoint": {"global_record": {"scores_mean": mean}},
                                                     "entry_status": "Finished"}))
    return folder


def test_mean_over_seeds_interval_and_change_against_the_baseline(tmp_path):
    b0 = _run(tmp_path / "b0", [("0_rep0", 40.0, 1, 0.3, 2.0), ("1_rep0", 60.0, 0, 0.3, 4.0)])
    b1 = _run(tmp_path / "b1", [("0_rep0", 50.0, 0, 0.3, 2.0), ("1_rep0", 70.0, 1, 0.3, 4.0)])
    s0 = _run(tmp_path / "s0", [("0_rep0", 66.0, 0, 0.3, 1.0), ("1_rep0", 66.0, 0, 0.3, 1.0)])
    f = arm_figures([b0, b1], n_boot=500)
    # DS: seed means 50 and 60 -> 55; collisions: 1 per 0.6 km in each seed -> 1.667 /km
    assert f["DS"][0] == pytest.approx(55.0)
    assert f["Collision/km"][0] == pytest.approx(1 / 0.6)
    assert f["steering_jerk_moving"][0] == pytest.approx(3.0)
    # two seeds: 55 +- t_{0.975, 1} sd / sqrt(2), sd = sqrt(50), t_{0.975, 1} = tan(0.475 pi) = 12.7062
    # (the t distribution with 1 degree of freedom is Cauchy's): 55 +- 63.531
    assert f["DS"][1:] == pytest.approx((55 - 63.531, 55 + 63.531), abs=1e-3)
    # one seed whose routes agree: the interval collapses to the value
    g = arm_figures([s0], n_boot=200)
    assert g["DS"] == pytest.approx((66.0, 66.0, 66.0))
    text = write_report({"baseline": [b0, b1], "scimm": [s0]}, tmp_path / "tables", n_boot=200)
    rows = list(csv.DictReader(open(tmp_path / "tables" / "table3.csv")))
    # scimm has seed 0 only: it is paired with the baseline's seed 0 (DS 50), route-paired;
    # change as the paper computes it: 100 (66 - 50) / 50 = +32 %; steering jerk 100 (1 - 3) / 3
    assert float(rows[1]["DS change %"]) == pytest.approx(32.0)
    assert float(rows[1]["DS diff"]) == pytest.approx(16.0)
    assert rows[1]["DS seeds"] == "1" and rows[1]["DS diff mde80"] == "nan"
    rows4 = list(csv.DictReader(open(tmp_path / "tables" / "table4.csv")))
    assert float(rows4[1]["steering_jerk_moving change %"]) == pytest.approx(-200 / 3)
    assert "(+32.0 % [" in text
    for stem in ("table3", "table4", "table3_common", "table4_common"):
        assert (tmp_path / "tables" / f"{stem}.md").is_file()
    # figures keep 4 significant digits: the baseline's DS reads 55, its steering jerk 3
    assert "| baseline | 2 | 55 [" in text
    assert "| scimm | 1 | 66 [66, 66] |" in text
    assert "| scimm | 1 (one seed: route-to-route interval only) | +16 [" in text


def test_a_route_paired_difference_has_no_spread_when_every_route_moves_alike(tmp_path):
    # routes differ widely (DS 20..80) but the second arm is 5 points above on every route:
    # each arm's interval is wide, the paired difference is 5 in every draw
    routes = [(f"{i}_rep0", ds, 0, 0.3, ds / 10) for i, ds in enumerate([20.0, 35.0, 50.0, 65.0, 80.0])]
    a = _run(tmp_path / "a", routes)
    b = _run(tmp_path / "b", [(k, ds + 5, c, km, sj + 1) for k, ds, c, km, sj in routes])
    res = compare({"a": [route_rows(a)], "b": [route_rows(b)]}, [("DS", ""), ("steering_jerk_moving", "")],
                  n_boot=300)
    assert res["b"]["DS"]["value"] == pytest.approx(55.0)  # (25 + 40 + 55 + 70 + 85) / 5
    assert res["b"]["DS"]["high"] - res["b"]["DS"]["low"] > 20  # the unpaired interval
    assert (res["b"]["DS"]["diff"], res["b"]["DS"]["diff_low"], res["b"]["DS"]["diff_high"]) == pytest.approx((5, 5, 5))
    assert res["b"]["steering_jerk_moving"]["diff_low"] == pytest.approx(1.0)
    assert res["a"]["DS"]["diff"] == 0.0 and res["a"]["DS"]["routes"] == 5
    # the relative change of each draw, 100 * 5 / (its baseline mean), lies between the
    # change at the largest possible baseline mean (80) and at the smallest (20)
    assert 100 * 5 / 80 <= res["b"]["DS"]["change_low"] <= res["b"]["DS"]["change"] <= res["b"]["DS"]["change_high"] <= 25


def test_arms_are_paired_by_seed_and_the_interval_is_the_t_interval_of_the_seed_differences(tmp_path):
    routes = [("0_rep0", 50.0, 0, 0.3, 1.0), ("1_rep0", 50.0, 0, 0.3, 1.0)]

    def seed(name: str, ds: float) -> dict:
        return route_rows(_run(tmp_path / name, [(k, ds, c, km, sj) for k, _, c, km, sj in routes]))

    res = compare({"base": [seed("b0", 50.0), seed("b1", 50.0)], "arm": [seed("a0", 60.0), seed("a1", 40.0)]},
                  [("DS", "")], n_boot=50)
    d = res["arm"]["DS"]
    # per-seed differences +10 and -10: mean 0, sd sqrt(200), se 10; t_{0.975, 1} = tan(0.475 pi)
    # = 12.7062 (1 degree of freedom: Cauchy), t_{0.8, 1} = tan(0.3 pi) = 1.37638; t = 0 -> p = 1
    assert (d["diff"], d["diff_low"], d["diff_high"]) == pytest.approx((0.0, -127.062, 127.062), abs=1e-3)
    assert (d["p"], d["seeds"]) == (pytest.approx(1.0), 2)
    assert d["mde"] == pytest.approx((12.7062 + 1.37638) * 10, abs=1e-3)
    # a seed effect both arms share (seed 1 is 20 points up for both) cancels in the pairs
    res = compare({"base": [seed("c0", 50.0), seed("c1", 70.0)], "arm": [seed("e0", 55.0), seed("e1", 75.0)]},
                  [("DS", "")], n_boot=50)
    d = res["arm"]["DS"]
    assert (d["diff"], d["diff_low"], d["diff_high"], d["p"], d["mde"]) == pytest.approx((5, 5, 5, 0, 0))
    assert d["change"] == pytest.approx(100 * 5 / 60)
    # seeds given by name pair the runs whatever their order in the list
    res = compare({"base": [seed("f0", 50.0), seed("f1", 70.0)], "arm": [seed("g1", 75.0), seed("g0", 55.0)]},
                  [("DS", "")], n_boot=50, seeds={"base": [0, 1], "arm": [1, 0]})
    assert res["arm"]["DS"]["diff_high"] == pytest.approx(5.0)


def test_the_common_routes_table_keeps_the_routes_every_run_completed(tmp_path):
    a = _run(tmp_path / "a", [("0_rep0", 80.0, 0, 0.3, 1.0), ("1_rep0", 10.0, 0, 0.1, 9.0, "Failed - Agent timed out"),
                              ("2_rep0", 60.0, 1, 0.3, 2.0)])
    b = _run(tmp_path / "b", [("0_rep0", 90.0, 0, 0.3, 1.0), ("1_rep0", 70.0, 0, 0.3, 1.0),
                              ("2_rep0", 50.0, 0, 0.3, 2.0, "Perfect")])
    assert completed_keys([route_rows(a), route_rows(b)]) == ["0_rep0", "2_rep0"]
    write_report({"a": [a], "b": [b]}, tmp_path / "t", n_boot=100)
    every = {r["arm"]: r for r in csv.DictReader(open(tmp_path / "t" / "table3.csv"))}
    common = {r["arm"]: r for r in csv.DictReader(open(tmp_path / "t" / "table3_common.csv"))}
    assert float(every["a"]["DS"]) == pytest.approx(50.0)  # (80 + 10 + 60) / 3
    assert float(common["a"]["DS"]) == pytest.approx(70.0)  # (80 + 60) / 2
    assert float(common["b"]["DS diff"]) == pytest.approx(0.0)  # (90 + 50) / 2 - 70
    assert float(common["a"]["Collision/km"]) == pytest.approx(1 / 0.6)
    assert common["a"]["DS routes"] == "2"
    assert "the 2 routes every run completed" in (tmp_path / "t" / "table3_common.md").read_text()


def test_a_metric_undefined_in_one_run_leaves_that_route_out_for_every_arm(tmp_path):
    a = _run(tmp_path / "a", [("0_rep0", 50.0, 0, 0.3, 2.0), ("1_rep0", 50.0, 0, 0.3, 4.0)])
    b = _run(tmp_path / "b", [("0_rep0", 50.0, 0, 0.3, float("nan")), ("1_rep0", 50.0, 0, 0.3, 6.0)])
    res = compare({"a": [route_rows(a)], "b": [route_rows(b)]}, [("steering_jerk_moving", "")], n_boot=50)
    assert res["a"]["steering_jerk_moving"]["value"] == 4.0  # route 1 only, not (2 + 4) / 2
    assert res["b"]["steering_jerk_moving"]["diff"] == 2.0
    assert res["b"]["steering_jerk_moving"]["routes"] == 1


def test_arms_are_named_folders_or_name_equals_folders():
    arms = parse_arms(["runs/b0", "scimm=runs/s0,runs/s1", "runs/x/b0"])
    assert arms == {"b0": [Path("runs/b0")], "scimm": [Path("runs/s0"), Path("runs/s1")], "b0'": [Path("runs/x/b0")]}
    with pytest.raises(ReportError, match="NAME=DIR"):
        parse_arms(["scimm=runs/s0,"])
    with pytest.raises(ReportError, match="NAME=DIR"):
        parse_arms(["=runs/s0"])


def test_records_without_the_new_columns_get_them_from_the_logs(tmp_path):
    old = ["key", "status", "ds", "rc", "is", "collisions_layout", "collisions_pedestrian", "collisions_vehicle",
           "km_driven", "steering_jerk", "longitudinal_jerk", "curvature_variation", "speed_variation"]
    run = _run(tmp_path / "old", [("0_rep0", 50.0, 0, 0.3, 1.0)], columns=old)
    (run / "logs").mkdir()
    log = {"v": np.array([0.0, 1.0, 1.0, 1.0]), "steer": np.array([0.0, 0.1, 0.0, 0.0]),
           "throttle": np.full(4, 0.5), "brake": np.zeros(4), "pred_path": np.zeros((4, 20, 2), np.float32),
           "pred_speed_wps": np.zeros((4, 10, 2), np.float32)}
    np.savez_compressed(run / "logs" / "0_rep0.npz", **log)
    rows = route_rows(run)
    # moving ticks 2 and 3: |0 - 0.2 + 0| and |0 - 0 + 0.1| -> 0.15 / dt^2 = 60
    assert rows["0_rep0"]["steering_jerk_moving"] == pytest.approx(60.0)
    assert rows["0_rep0"]["steering_jerk"] == 1.0  # a column the records have is read, not recomputed
    assert rows["0_rep0"]["standing_share"] == stability(log)["standing_share"] == 0.25
    (run / "logs" / "0_rep0.npz").unlink()
    with pytest.raises(ReportError, match="evaluate the run again"):
        route_rows(run)


def test_small_figures_keep_their_significant_digits():
    assert fig(0.000312345) == "0.0003123"
    assert fig(54.9712) == "54.97"


def _add_column(run: Path, column: str, values: dict[str, float]) -> None:
    """Append a column to a run's records.csv, ``values`` by route key."""
    with open(run / "records.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    with open(run / "records.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=[*rows[0], column])
        w.writeheader()
        w.writerows({**r, column: values[r["key"]]} for r in rows)


def test_a_new_stability_metric_is_one_registry_entry_that_reaches_table4_and_the_claims(tmp_path, monkeypatch):
    from harness.scoring import stability as stab
    from model.arm_tables import paper_claims, write_set_tables
    new = stab.Metric("steer_rate_moving", lambda s: s.on_moving(np.abs(np.diff(s.steer, prepend=np.nan))),
                      "steer rate", "1/tick", "lower", stab.TABLE4)
    monkeypatch.setattr(stab, "METRICS", (*stab.METRICS, new))
    # its function runs with the others: moving ticks 2 and 3 of steer 0, 0.1, 0, 0 -> (0.1 + 0) / 2
    log = {"v": np.array([0.0, 1.0, 1.0, 1.0]), "steer": np.array([0.0, 0.1, 0.0, 0.0]),
           "throttle": np.zeros(4), "brake": np.zeros(4), "pred_path": np.zeros((0, 20, 2)),
           "pred_speed_wps": np.zeros((0, 10, 2))}
    assert stability(log)["steer_rate_moving"] == pytest.approx(0.05)
    assert paper_claims()[-1] == ("steer_rate_moving", "steer rate lower", "lower", None)
    runs = {}
    for arm, rate in (("baseline", 2.0), ("scimm", 1.0)):
        runs[arm] = [_run(tmp_path / f"{arm}{s}", [("0_rep0", 50.0, 0, 0.3, 1.0), ("1_rep0", 60.0, 0, 0.3, 1.0)])
                     for s in (0, 1)]
        for s, run in enumerate(runs[arm]):
            _add_column(run, "steer_rate_moving", {"0_rep0": rate + s, "1_rep0": rate + s})
    text = write_report(runs, tmp_path / "report", n_boot=50)
    assert "| arm | runs | steering jerk [1/s^2] | longitudinal jerk [1/s^2] | curvature variation [1/m] | " \
           "speed variation [km/h] | steer rate [1/tick] |" in text
    rows = list(csv.DictReader(open(tmp_path / "report" / "table4.csv")))
    assert float(rows[1]["steer_rate_moving diff"]) == pytest.approx(-1.0)  # seeds 1, 2 against 2, 3
    md, _ = write_set_tables(runs, tmp_path / "tables")
    assert "steer rate lower |" in md.splitlines()[2]
    claim = list(csv.DictReader(open(tmp_path / "tables" / "claims.csv")))[0]
    assert float(claim["steer_rate_moving diff"]) == pytest.approx(-1.0)


def test_a_run_folder_kept_gzip_compressed_gives_the_same_tables_through_the_command(tmp_path):
    from files.compressed import gzip_copy
    from sumo_scimm.cli import main
    rows_b = [("0_rep0", 40.0, 1, 0.3, 2.0), ("1_rep0", 60.0, 0, 0.3, 4.0), ("2_rep0", 55.0, 0, 0.2, 3.0)]
    rows_s = [("0_rep0", 66.0, 0, 0.3, 1.0), ("1_rep0", 61.0, 0, 0.3, 1.5), ("2_rep0", 50.0, 1, 0.2, 2.5)]
    plain = {"baseline": _run(tmp_path / "b", rows_b), "scimm": _run(tmp_path / "s", rows_s)}
    packed = {}
    for arm, folder in plain.items():
        (tmp_path / "gz" / arm).mkdir(parents=True)
        for name in ("records.csv", "results.json"):
            gzip_copy(folder / name, tmp_path / "gz" / arm / f"{name}.gz")
            first = (tmp_path / "gz" / arm / f"{name}.gz").read_bytes()
            gzip_copy(folder / name, tmp_path / "gz" / arm / f"{name}.gz")  # no time stamp: same bytes
            assert (tmp_path / "gz" / arm / f"{name}.gz").read_bytes() == first
        packed[arm] = tmp_path / "gz" / arm
    assert main(["report", *(f"{a}={d}" for a, d in plain.items()), "--out", str(tmp_path / "t1")]) == 0
    assert main(["report", *(f"{a}={d}" for a, d in packed.items()), "--out", str(tmp_path / "t2")]) == 0
    made = sorted(p.name for p in (tmp_path / "t1").iterdir())
    assert "claims.md" in made and "table3.md" in made
    assert made == sorted(p.name for p in (tmp_path / "t2").iterdir())
    for name in made:
        assert (tmp_path / "t1" / name).read_text() == (tmp_path / "t2" / name).read_text(), name


def test_report_names_run_folders_without_records_jsonl(tmp_path, capsys):
    """The committed records keep records.csv and results.json alone: report writes Tables
    3-4 from them and says which tables it could not make (no Bench2Drive tables)."""
    from sumo_scimm.cli import main
    runs = Path(__file__).resolve().parents[1] / "docs" / "results" / "decisive" / "town12_short"
    assert main(["report", f"baseline={runs / 'baseline_s0'}", f"scimm={runs / 'scimm_s0'}",
                 "--out", str(tmp_path / "rep")]) == 0
    err = capsys.readouterr().err
    assert f"note: no records.jsonl in {runs / 'baseline_s0'} and 1 more: Bench2Drive's tables" in err
    assert (tmp_path / "rep" / "table3.md").is_file() and not (tmp_path / "rep" / "b2d.md").exists()
