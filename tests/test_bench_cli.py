"""``sumo-scimm bench`` as a user runs it, on one town12_smoke route with the shipped SC-IMM
student: every figure of docs/design.md §11 is printed and written as JSON beside its reference.
The figures themselves are never asserted (they depend on the machine's load); that they
were measured is: finite, positive, and the bare replay stepped the episode's traffic."""
from __future__ import annotations

import json
import math

import pytest

from sumo_scimm.cli import main

pytestmark = pytest.mark.slow  # each test runs the bench end to end (about 30 s)


def test_bench_prints_and_writes_every_figure_beside_its_reference(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench", "--routes-count", "1", "--agent", "scimm", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    r = json.loads(out.read_text())
    loop, imm, student = r["closed_loop"], r["teacher"], r["student"]
    measured = [loop["harness_step_ms"], loop["bare_libsumo_step_ms"], loop["bare_inference_ms"],
                loop["bev_render_ms"], imm["imm_frames_per_s"], imm["filterpy_frames_per_s"],
                student["train_samples_per_s"], student["infer_ms_per_frame"], r["collect"]["collect_sim_s_per_wall_s"]]
    assert all(math.isfinite(v) and v > 0 for v in measured), measured
    assert loop["replay_same_traffic"] is True, "the bare replay drove other traffic than the episode"
    assert loop["agent"] == "scimm"
    # the inference counts on the ticks that ran the network (a student skips repeated inputs)
    assert 0.0 < loop["network_share"] <= 1.0
    # the ratio comes from the unrounded figures, the JSON holds the times rounded to 1 us
    # (0.5 us off at most) and the share to 0.001 (< 1 us of inference): recomputed from
    # those it moves by < 0.3 % (a ~2 ms step over a >= 0.7 ms sum), plus its own rounding
    # to 0.01 (e.g. 1.97 stored, 1.98 recomputed)
    ratio = loop["harness_step_ms"] / (loop["bare_libsumo_step_ms"] + loop["network_share"] * loop["bare_inference_ms"])
    assert abs(loop["harness_over_bare_plus_inference"] - ratio) <= 0.005 * ratio + 0.005
    # for reading: the same replay with the network run between steps (same traffic, checked
    # above), and the ratio over it from the same rounded figures, same tolerance
    between = loop["bare_libsumo_network_between_ms"]
    assert math.isfinite(between)
    assert between > 0
    ratio = loop["harness_step_ms"] / (between + loop["network_share"] * loop["bare_inference_ms"])
    assert abs(loop["harness_over_network_between_plus_inference"] - ratio) <= 0.005 * ratio + 0.005
    # the floor: SUMO and the network alternating (the network on the agent's share of
    # ticks), over the same reference. Recomputed from the stored figures, the time moves by
    # the roundings of SUMO's time (0.0005), the share (0.0005 x the call) and the call
    # (0.0005 x the share <= 0.0005), plus its own (0.0005); the ratio as above
    call = loop["network_between_call_ms"]
    floor = between + loop["network_share"] * call
    assert call > 0
    assert abs(loop["sumo_and_network_alternating_ms"] - floor) <= 0.0015 + 0.0005 * call
    ratio = floor / (loop["bare_libsumo_step_ms"] + loop["network_share"] * loop["bare_inference_ms"])
    assert abs(loop["floor_over_bare_plus_inference"] - ratio) <= 0.005 * ratio + 0.005
    # for reading: the same replay with a memory read between steps instead of the network,
    # its traffic checked with the others (replay_same_traffic above)
    sweep = loop["bare_libsumo_memory_sweep_ms"]
    assert math.isfinite(sweep) and sweep > 0
    assert "MB memory read between steps" in printed
    # the references are timed route by route, right after each episode; the figures are the routes' means
    per = loop["per_route"]
    assert (len(per["harness_step_ms"]) == len(per["bare_libsumo_step_ms"]) == len(per["bare_inference_ms"])
            == len(per["bare_libsumo_network_between_ms"]) == len(per["bare_libsumo_memory_sweep_ms"]) == 1)
    assert abs(loop["bare_inference_ms"] - per["bare_inference_ms"][0]) <= 0.001
    # --rounds (3 by default): the figures are those of the median round by the ratio, taken
    # whole (its own figures, never mixed with another round's); every round is kept
    rounds = loop["rounds"]
    assert len(rounds) == 3
    assert loop["harness_over_bare_plus_inference"] == sorted(x["harness_over_bare_plus_inference"] for x in rounds)[1]
    chosen = rounds[loop["round_chosen"]]
    assert chosen, "the chosen round is empty"
    assert all(chosen[k] == loop[k] for k in chosen), [k for k in chosen if chosen[k] != loop[k]]
    # the IMM: the median of 3 fresh processes, all of them listed
    runs = imm["imm_frames_per_s_runs"]
    assert len(runs) == 3
    assert imm["imm_frames_per_s"] == sorted(runs)[1]
    assert "the median of 3 rounds" in printed
    assert "the median of 3 fresh processes" in printed
    for line in ("harness / (bare + inference)", "with the network run between steps", "the floor of the ratio", "BEV render", "collect (expert", "IMM", "filterpy",
                 "student training", "student inference"):
        assert line in printed
    assert "eval" not in r  # the whole town12_short evaluation only with --eval
    # the machine the figures belong to, printed and written
    m = r["machine"]
    assert m["cpu"], m
    assert m["cores"] >= 1, m
    assert m["torch_cpu_capability"], m
    assert m["libsumo"] == "1.28.0", m
    assert f"machine: {m['cpu']}, {m['cores']} cores" in printed


def test_bench_soak_and_reproduce_figures(tmp_path, capsys):
    """--soak N runs whole passes over --routes until N route runs (4 smoke routes: 2 passes
    for N = 5) and reports their worker memory; --reproduce reads a reproduce run's stage
    times and each arm and seed's; a folder without stages.json is one line, exit 2."""
    (tmp_path / "rep").mkdir()
    stages = {"collect": 600.0, "train scimm s0": 1000.5, "eval scimm s0": 200.0, "train baseline s0": 150.0,
              "train 4 students s1-2": 800.0, "eval scimm s1": 100.0, "eval fixed s2": 120.0, "eval expert s1": 90.0}
    (tmp_path / "rep" / "stages.json").write_text(json.dumps(stages))
    out = tmp_path / "bench.json"
    argv = ["bench", "--routes-count", "1", "--rounds", "1", "--agent", "route_follower", "--soak", "5", "--reproduce",
            str(tmp_path / "rep"), "--json", str(out)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    r = json.loads(out.read_text())
    assert r["soak"]["route_runs"] == 8
    assert r["soak"]["repetitions"] == 2
    assert r["soak"]["rss"]["peak_mb"] > 0
    assert r["reproduce"]["reproduce_wall_s"] == 3060.5
    assert "51.0 min" in printed
    # per seed: 3060.5 s over the seeds 0, 1 and 2 = 1020.2 s, 17.0 min; three arms (scimm,
    # baseline, fixed; the expert is none): the three-arm target, 60 min
    assert (r["reproduce"]["seeds"], r["reproduce"]["arms"]) == (3, 3)
    assert r["reproduce"]["reproduce_seed_s"] == 1020.2
    assert r["reproduce"]["reproduce_target_s"] == 3600.0
    assert "3 seeds of 3 arms: 17.0 min a seed (target <= 60 min)" in printed
    # an arm and seed: its training plus its evaluation (none recorded: the training alone); a
    # training side by side counts its share of the stage: 800 s / 4 students = 200 s; the
    # expert's evaluation is no arm and seed, even of a seed whose students trained side by side
    assert r["reproduce"]["reproduce_arm_seed_s"] == {"scimm s0": 1200.5, "baseline s0": 150.0, "scimm s1": 300.0,
                                                      "fixed s2": 320.0}
    line = next(ln for ln in printed.splitlines() if "arm and seed scimm s0" in ln)
    assert line.split()[5:7] == ["20.0", "min,"], line
    assert "soak" in printed
    assert main(["bench", "--reproduce", str(tmp_path)]) == 2


def test_reproduce_targets_follow_the_arm_count(tmp_path):
    """Four or five arms take the five-arm target (75 min a seed); six have none."""
    from sumo_scimm.bench.figures import reproduce_figure
    arms = ["baseline", "control", "fixed", "scimm", "smoother", "other"]
    for n, target in ((4, 4500.0), (5, 4500.0), (6, None)):
        stages = {f"train {a} s0": 60.0 for a in arms[:n]} | {"collect train": 600.0}
        (tmp_path / "stages.json").write_text(json.dumps(stages))
        r = reproduce_figure(str(tmp_path))
        assert (r["arms"], r["seeds"], r["reproduce_target_s"]) == (n, 1, target)
        assert r["reproduce_seed_s"] == 600.0 + 60.0 * n


def test_one_arm_and_seed_is_trained_evaluated_and_set_beside_the_reproduce_runs_student(tmp_path):
    """arm_seed_figure on a reproduce-shaped folder (a small cached training set with SC-IMM
    and Fixed-IMM teachers, a validation set, the shipped SC-IMM student as the run's own
    seed-0 student): it trains both arms' students side by side with the default recipe, times
    that and each evaluation, and scores the SC-IMM one and the run's own on the validation
    routes (here one smoke route for every set, to stay short)."""
    import shutil

    from model.agent import SHIPPED
    from sumo_scimm.bench.figures import arm_seed_figure
    from tests.run_folder_helpers import one_smoke_route
    from tests.test_model import fake_dataset, write_teacher
    from tests.test_train import fake_val
    data = tmp_path / "rep" / "data"
    fake_dataset(data / "train")
    write_teacher(data / "train", "scimm")
    write_teacher(data / "train", "fixed")
    shutil.move(data / "train" / "cache", data / "cache")
    fake_val(data / "val", data / "cache")
    before = tmp_path / "rep" / "models" / "scimm_s0"
    before.mkdir(parents=True)
    shutil.copy(SHIPPED / "scimm" / "student.pt", before / "student.pt")
    (before / "history.json").write_text(json.dumps({"chosen_val": {"loss": 9.5}}))
    one = str(one_smoke_route(tmp_path))
    r = arm_seed_figure(str(tmp_path / "rep"), 2, routes=one, val_routes=one)
    assert (r["arm"], r["arms"], r["seed"], r["arm_routes"], r["arm_workers"]) == (
        "scimm", ["scimm", "fixed"], 0, one, 2)
    assert r["arm_seed_s"] == pytest.approx((r["arm_train_s"] + sum(r["arm_eval_s"])) / 2, abs=0.11)
    assert r["arm_train_s"] > 0 and min(r["arm_eval_s"]) > 0 and len(r["arm_eval_s"]) == 2
    assert r["arm_seed_target_s"] == 300.0
    assert r["arm_steps"] == 16 and r["arm_chosen_epoch"] in range(1, 9)  # 8 epochs of 2 batches
    assert math.isfinite(r["arm_val_loss"]) and 0.0 <= r["arm_val_ds"] <= 100.0
    assert r["before"] == str(before) and r["before_val_loss"] == 9.5 and 0.0 <= r["before_val_ds"] <= 100.0
