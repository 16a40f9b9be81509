"""The student's training: the loss-matched control arm, early stopping on the validation
set (the chosen epoch's weights saved), the teacher and mode weights as options, the
history beside the checkpoint and the loss-curve figure. Trainings here are real torch
trainings of a few steps on the small cached datasets of tests/test_model.py."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from harness.runs import provenance
from model import cache as bevcache
from model.checkpoint import load_checkpoint
from model.curves import Curves, draw_loss_curves, load_history, plot_loss_curves
from model.data import CONTROL_MU, TEACHERS, StudentData, move
from model.loss import LossWeights, phi
from sumo_scimm.cli import main
from tests.test_model import fake_dataset, write_teacher

VIEW_KEYS = ("bev", "aug", "path", "speed_wps", "target_point")  # arrays with a view axis


def fake_val(root, cache_dir, n_frames=128, seed=7):
    """A validation dataset folder (one view, as training's validation loads it) whose
    cache sits in ``cache_dir``."""
    rng = np.random.default_rng(seed)
    (root / "episodes").mkdir(parents=True)
    for stem in ("v_rep0", "w_rep0"):
        (root / "episodes" / f"{stem}.npz").write_bytes(stem.encode())
    bev = (rng.random((n_frames, 1, *bevcache.BEV_SHAPE)) < 0.2).astype(np.uint8) * 255
    half = n_frames // 2
    arrays = {"bev": bevcache.pack(bev), "aug": np.zeros((n_frames, 1, 2)),
              "path": rng.normal(size=(n_frames, 1, 20, 2)).astype(np.float32),
              "speed_wps": rng.normal(size=(n_frames, 1, 10, 2)).astype(np.float32),
              "target_point": rng.normal(size=(n_frames, 1, 2)).astype(np.float32),
              "speed": rng.uniform(0, 8, n_frames).astype(np.float32), "stop": np.zeros(n_frames, bool),
              "episode": np.repeat(np.arange(2, dtype=np.int32), half),
              "frame": np.tile(np.arange(half, dtype=np.int32), 2), "stems": np.array(["v_rep0", "w_rep0"])}
    path = bevcache.cache_path(root, cache_dir, 1)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **arrays)
    return root


@pytest.fixture
def sets(tmp_path):
    """(training folder with a scimm teacher, validation folder); one cache folder."""
    train_dir = tmp_path / "train"
    fake_dataset(train_dir)
    write_teacher(train_dir, "scimm")
    return train_dir, fake_val(tmp_path / "val", train_dir / "cache")


def _train(train_dir, out, val=None, **kw):
    from model.train import TrainConfig, train
    return train(TrainConfig(data=train_dir, out=out, val=val, cache_dir=train_dir / "cache", threads=1, **kw))


# --- the control arm ---------------------------------------------------------------------------
def test_the_control_teacher_is_the_experts_own_labels_in_the_augmented_frame(tmp_path):
    """No teacher folder at all: the control reads none. In views 1 (shifted and turned) and 0."""
    arrays = fake_dataset(tmp_path)
    data = StudentData.load(tmp_path, tmp_path / "cache", 2, teacher="control")
    idx, view = np.array([0, 5, 200, 17]), np.array([1, 1, 0, 1])
    b = data.batch(idx, view, np.array([0.0, 10.0, 0.0, 0.0]))
    assert not (tmp_path / "teacher").exists()
    assert np.abs(arrays["aug"][idx, view]).max() > 0.01  # the views are really moved
    torch.testing.assert_close(b["teacher_path"], b["path"], rtol=0, atol=0)
    np.testing.assert_array_equal(b["path"].numpy(), arrays["path"][idx, view])
    torch.testing.assert_close(b["teacher_speed"], phi(b["speed_wps"], b["origin"]), rtol=0, atol=0)
    shift, rot = arrays["aug"][idx, view, 0], arrays["aug"][idx, view, 1]
    np.testing.assert_allclose(b["origin"].numpy(), move(np.zeros((4, 2)), shift, rot), atol=1e-6)
    # phi of the expert's waypoints by hand, frame 200 (view 0: origin (0, 0))
    w = arrays["speed_wps"][200, 0].astype(np.float64)
    steps = np.diff(np.vstack([[0.0, 0.0], w]), axis=0)
    np.testing.assert_allclose(b["teacher_speed"][2].numpy(), np.hypot(*steps.T) / 0.25, rtol=1e-6)
    np.testing.assert_array_equal(b["mu"].numpy(), np.full((4, 5), 0.2, np.float32))
    assert CONTROL_MU == 0.2
    assert "control" in TEACHERS


def test_a_control_training_weighs_the_teacher_terms_as_a_teacher_arm_does(sets, tmp_path):
    train_dir, _ = sets
    w = LossWeights(scimm=0.5, mode=0.3)
    _, m = load_checkpoint(_train(train_dir, tmp_path / "ctl", teacher="control", epochs=1, max_steps=1, weights=w))
    assert m["teacher"] == "control"
    assert m["loss_weights"] == {"origin": 1.0, "scimm": 0.5, "mode": 0.3}
    t = m["final_train"]
    # one batch: teacher_path is the path term itself; the mode term against the uniform
    # target is KL >= 0; the total is eq. 10 with these weights
    assert t["teacher_path"] == pytest.approx(t["path"], rel=1e-6)
    assert t["mode"] >= 0
    assert t["loss"] == pytest.approx(t["path"] + t["speed_wps"] + 0.5 * (t["teacher_path"] + t["teacher_speed"])
                                      + 0.3 * t["mode"], rel=1e-5)
    _, base = load_checkpoint(_train(train_dir, tmp_path / "base", teacher="none", epochs=1, max_steps=1, weights=w))
    assert base["loss_weights"] == {"origin": 1.0, "scimm": 0.0, "mode": 0.0}  # the baseline ignores them


# --- early stopping -----------------------------------------------------------------------------
def test_the_saved_weights_are_the_best_validation_epochs(sets, tmp_path):
    """A real training of 4 epochs (patience larger): the chosen epoch is the first minimum
    of the validation L_origin, and the saved weights give that loss again."""
    from model.train import estimate_loss
    train_dir, val_dir = sets
    ckpt = _train(train_dir, tmp_path / "s", val=val_dir, teacher="scimm", epochs=4, patience=4, seed=1)
    model, m = load_checkpoint(ckpt)
    losses = [r["val"]["loss"] for r in m["history"]]
    assert len(losses) == 4 and m["stop_reason"] == "epochs"
    assert m["chosen_epoch"] == int(np.argmin(losses)) + 1
    val = StudentData.load(val_dir, train_dir / "cache", 1)
    torch.set_num_threads(1)
    again = estimate_loss(model, val)
    # the same weights and inputs in eval mode: equal up to float32 summation order
    assert again["loss"] == pytest.approx(m["chosen_val"]["loss"], rel=1e-6)
    assert m["chosen_val"]["loss"] == min(losses)
    for r in m["history"]:
        assert set(r) >= {"epoch", "step", "lr", "train", "val", "seconds", "val_seconds"}
    # 8 steps, all in the 200-step warm-up: the lr of step 8 is 1e-3 * 8 / 200
    assert [r["step"] for r in m["history"]][-1] == 8
    assert m["history"][-1]["lr"] == pytest.approx(4e-5, rel=1e-12)
    history = json.loads((tmp_path / "s" / "history.json").read_text())
    assert history["history"] == m["history"]
    assert history["chosen_epoch"] == m["chosen_epoch"] and history["teacher"] == "scimm"


def test_training_stops_after_patience_epochs_without_a_new_best(sets, tmp_path, monkeypatch):
    """Validation losses 3, 2, 2.5, 2 (a tie is no new best), 1: with patience 2 the training
    stops after epoch 4 and saves the weights it had after epoch 2."""
    import model.train as mt
    losses, seen = iter([3.0, 2.0, 2.5, 2.0, 1.0]), []

    def fake_estimate(model, data, batch=256):
        seen.append({k: v.detach().clone() for k, v in model.state_dict().items()})
        v = next(losses)
        return {"path": v, "speed_wps": 0.0, "loss": v}

    monkeypatch.setattr(mt, "estimate_loss", fake_estimate)
    train_dir, val_dir = sets
    model, m = load_checkpoint(_train(train_dir, tmp_path / "p", val=val_dir, epochs=5, patience=2))
    assert (m["chosen_epoch"], m["stop_reason"], m["epochs_run"], len(seen)) == (2, "patience", 4, 4)
    assert m["chosen_val"]["loss"] == 2.0 and m["epochs"] == 5 and m["patience"] == 2
    for k, v in model.state_dict().items():
        torch.testing.assert_close(v, seen[1][k], rtol=0, atol=0, msg=k)
    assert not all(torch.equal(v, seen[3][k]) for k, v in model.state_dict().items())


def test_by_default_every_epoch_runs_and_the_best_is_saved(sets, tmp_path, monkeypatch):
    """Validation losses rising after epoch 1 (1, 2, 3, 4): no early stop by default, all
    four epochs run and epoch 1 is saved; --epoch-steps 1 gives one step per epoch."""
    import model.train as mt
    losses = iter([1.0, 2.0, 3.0, 4.0])
    monkeypatch.setattr(mt, "estimate_loss", lambda model, data, batch=256: dict(path=(v := next(losses)),
                                                                                   speed_wps=0.0, loss=v))
    train_dir, val_dir = sets
    _, m = load_checkpoint(_train(train_dir, tmp_path / "d", val=val_dir, epochs=4, epoch_steps=1))
    assert (m["chosen_epoch"], m["stop_reason"], m["epochs_run"], m["patience"]) == (1, "epochs", 4, None)
    assert [r["step"] for r in m["history"]] == [1, 2, 3, 4] and m["epoch_steps"] == 1
    assert m["net"]["speed_input"] is False  # the manifest says what the network sees
    # --epoch-steps 0: an epoch is every whole batch of the balanced draw (2 on this dataset, as the default)
    losses = iter([1.0, 2.0])  # the validation losses of this second training
    _, m0 = load_checkpoint(_train(train_dir, tmp_path / "w", val=val_dir, epochs=2, epoch_steps=0))
    assert [r["step"] for r in m0["history"]] == [2, 4]


def test_without_a_validation_set_the_last_epoch_is_saved(sets, tmp_path):
    train_dir, _ = sets
    _, m = load_checkpoint(_train(train_dir, tmp_path / "n", epochs=2))
    assert (m["chosen_epoch"], m["stop_reason"], m["epochs_run"]) == (2, "no_val", 2)
    assert m["chosen_val"] is None


def test_early_stopping_is_deterministic_for_a_seed(sets, tmp_path):
    train_dir, val_dir = sets
    kw = dict(val=val_dir, teacher="control", epochs=3, seed=2, patience=1)  # patience 1: an early stop may happen
    a, ma = load_checkpoint(_train(train_dir, tmp_path / "a", **kw))
    b, mb = load_checkpoint(_train(train_dir, tmp_path / "b", **kw))
    for (k, va), vb in zip(a.state_dict().items(), b.state_dict().values()):
        torch.testing.assert_close(va, vb, rtol=0, atol=0, msg=k)
    assert ma["chosen_epoch"] == mb["chosen_epoch"]
    assert [r["val"] for r in ma["history"]] == [r["val"] for r in mb["history"]]


def test_the_nan_fill_of_new_tensors_changes_no_weight(sets, tmp_path, monkeypatch):
    """Training runs with torch's NaN fill of new tensors off (model.train.FILL_UNINITIALIZED):
    a kernel reading memory it never wrote would make the two trainings differ (NaN in one,
    old data in the other); they are equal bit for bit, validation losses included."""
    import model.train as train_mod
    train_dir, val_dir = sets
    kw = dict(val=val_dir, teacher="scimm", epochs=2, seed=4)
    a, ma = load_checkpoint(_train(train_dir, tmp_path / "off", **kw))
    before = torch.utils.deterministic.fill_uninitialized_memory
    monkeypatch.setattr(train_mod, "FILL_UNINITIALIZED", True)
    try:
        b, mb = load_checkpoint(_train(train_dir, tmp_path / "on", **kw))
        assert torch.utils.deterministic.fill_uninitialized_memory is True  # the setting took
    finally:
        torch.utils.deterministic.fill_uninitialized_memory = before
    for (k, va), vb in zip(a.state_dict().items(), b.state_dict().values()):
        torch.testing.assert_close(va, vb, rtol=0, atol=0, msg=k)
    assert [r["val"] for r in ma["history"]] == [r["val"] for r in mb["history"]]


# --- weight average -----------------------------------------------------------------------------
def test_the_weight_average_follows_its_warm_up_formula():
    """decay 0.9, weights 0 at the start, then 1, 1, 3 after steps 0, 1, 2: d = min(0.9,
    (1 + t) / (10 + t)) = 0.1, 2/11, 0.25; the average 0.9, then 2/11 * 0.9 + 9/11 = 0.98182,
    then 0.25 * 0.98182 + 0.75 * 3 = 2.49545."""
    from model.network import NetConfig, Student
    from model.train import Ema
    model = Student(NetConfig())
    with torch.no_grad():
        for p in model.parameters():
            p.zero_()
    ema = Ema(model, 0.9)
    expected = []
    for w in (1.0, 1.0, 3.0):
        with torch.no_grad():
            for p in model.parameters():
                p.fill_(w)
        ema.update(model)
        expected.append(next(ema.model.parameters()).flatten()[0].item())
    assert expected == pytest.approx([0.9, 0.9 * 2 / 11 + 9 / 11, 0.25 * (0.9 * 2 / 11 + 9 / 11) + 2.25], rel=1e-6)
    assert all(not p.requires_grad for p in ema.model.parameters())
    # past the warm-up (step 10,000: (1 + t) / (10 + t) > 0.9) d is the decay: weights 5
    before, ema.t = next(ema.model.parameters()).flatten()[0].item(), 10_000
    with torch.no_grad():
        for p in model.parameters():
            p.fill_(5.0)
    ema.update(model)
    assert next(ema.model.parameters()).flatten()[0].item() == pytest.approx(0.9 * before + 0.5, rel=1e-6)


def test_the_optimizer_steps_at_the_peak_learning_rate_given(sets, tmp_path, monkeypatch):
    """--lr 3e-3, 4 steps (2 epochs of 2), all inside the 200-step warm-up: 3e-3 * (t + 1) / 200
    at step t, read from the optimizer itself after each step."""
    import model.train as mt
    seen, real = [], mt.train_step

    def spy(model, opt, b, weights, lr):
        terms = real(model, opt, b, weights, lr)
        seen.append(opt.param_groups[0]["lr"])
        return terms

    monkeypatch.setattr(mt, "train_step", spy)
    train_dir, _ = sets
    _train(train_dir, tmp_path / "l", epochs=2, lr=0.003)
    assert seen == pytest.approx([1.5e-5, 3e-5, 4.5e-5, 6e-5], rel=1e-12)


def test_with_a_weight_average_the_average_is_validated_and_saved(sets, tmp_path):
    """The saved weights give the chosen epoch's validation loss again, and they are not the
    raw weights a training without the average saves (same seed, same draws)."""
    from model.train import estimate_loss
    train_dir, val_dir = sets
    kw = dict(val=val_dir, teacher="scimm", epochs=2, seed=3, batch=64)
    avg, m = load_checkpoint(_train(train_dir, tmp_path / "e", ema=0.9, **kw))
    raw, m_raw = load_checkpoint(_train(train_dir, tmp_path / "r", **kw))
    assert (m["ema"], m["batch"], m_raw["ema"]) == (0.9, 64, 0.0)
    assert [r["step"] for r in m["history"]] == [r["step"] for r in m_raw["history"]]
    torch.set_num_threads(1)
    again = estimate_loss(avg, StudentData.load(val_dir, train_dir / "cache", 1))
    assert again["loss"] == pytest.approx(m["chosen_val"]["loss"], rel=1e-6)  # float32 summation order
    assert m["chosen_val"] != m_raw["chosen_val"]
    assert not all(torch.equal(a, b) for a, b in zip(avg.state_dict().values(), raw.state_dict().values()))


# --- command line -------------------------------------------------------------------------------
def test_the_cli_defaults_are_the_trainings():
    from model.train import BATCH, EMA, EPOCH_STEPS, EPOCHS, LR, PATIENCE, THREADS
    from sumo_scimm import model_commands as mc
    assert (mc.EPOCHS, mc.EPOCH_STEPS, mc.PATIENCE, mc.BATCH, mc.EMA, mc.LR, mc.THREADS) == (
        EPOCHS, EPOCH_STEPS, PATIENCE, BATCH, EMA, LR, THREADS)
    assert mc.TEACHERS == ("none", *TEACHERS)
    assert (mc.TEACHER_WEIGHT, mc.MODE_WEIGHT) == (LossWeights().scimm, LossWeights().mode)


@pytest.mark.parametrize("args, message", [
    (["--teacher", "scimm", "--teacher-weight", "-1"], "invalid weight '-1'"),
    (["--teacher", "scimm", "--teacher-weight", "nan"], "invalid weight 'nan'"),
    (["--teacher", "control", "--mode-weight", "inf"], "invalid weight 'inf'"),
    (["--teacher", "control", "--mode-weight", "x"], "invalid weight 'x'"),
    (["--teacher-weight", "0.5"], "--teacher-weight: the baseline (--teacher none) has no teacher terms"),
    (["--mode-weight", "0.5"], "--mode-weight: the baseline (--teacher none) has no teacher terms"),
    (["--patience", "0"], "--patience must be >= 1"),
    (["--epoch-steps", "-1"], "--epoch-steps must be >= 0"),
    (["--batch", "0"], "--batch must be >= 1"),
    (["--ema", "1"], "--ema must be in [0, 1)"),
    (["--ema", "-0.5"], "--ema must be in [0, 1)"),
    (["--lr", "0"], "--lr must be in (2e-05, 1)"),
    (["--lr", "nan"], "--lr must be in (2e-05, 1)"),
    (["--threads", "0"], "--threads must be >= 1"),
])
def test_bad_weights_and_patience_are_one_line_and_write_nothing(tmp_path, capsys, args, message):
    fake_dataset(tmp_path / "data")
    out = tmp_path / "model"
    assert main(["train", "--data", str(tmp_path / "data"), "--out", str(out), *args]) == 2
    err = capsys.readouterr().err
    assert message in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not out.exists()


def test_train_cli_control_with_weights_records_them(sets, tmp_path, capsys):
    train_dir, val_dir = sets
    out = tmp_path / "m"
    assert main(["train", "--data", str(train_dir), "--val", str(val_dir), "--teacher", "control",
                 "--teacher-weight", "0.25", "--mode-weight", "0", "--epochs", "1", "--out", str(out),
                 "--cache", str(train_dir / "cache"), "--lr", "0.003"]) == 0
    m = json.loads((out / "manifest.json").read_text())
    assert m["loss_weights"] == {"origin": 1.0, "scimm": 0.25, "mode": 0.0}
    assert m["machine"] == provenance.machine()  # which CPU trained it: the records of a run in parts say
    # the peak learning rate: 2 steps into the 200-step warm-up, 3e-3 * 2 / 200
    assert m["schedule"]["lr"] == 0.003 and m["history"][-1]["step"] == 2
    assert m["history"][-1]["lr"] == pytest.approx(3e-5, rel=1e-12)
    assert "mode" not in m["final_train"]  # a zero weight: the term is not computed
    assert (m["chosen_epoch"], m["stop_reason"]) == (1, "epochs")
    assert str(out / "student.pt") in capsys.readouterr().out


# --- loss curves --------------------------------------------------------------------------------
def _history(path, val_path, chosen=None):
    records = [{"epoch": e, "step": 10 * e, "train": {"loss": 5.0 - e}, "val": {"path": v, "speed_wps": v / 2,
                                                                            "loss": 1.5 * v}}
               for e, v in enumerate(val_path, start=1)]
    path.mkdir(parents=True)
    body = {"history": records, **({"chosen_epoch": chosen} if chosen else {})}
    (path / ("history.json" if chosen else "manifest.json")).write_text(json.dumps(body))
    return path


def test_loss_curves_ring_the_chosen_epoch_and_write_a_png(tmp_path):
    a = _history(tmp_path / "a", [3.0, 2.0, 1.0, 1.5, 1.8], chosen=3)  # minimum at epoch 3
    b = _history(tmp_path / "b", [2.0, 1.0, 0.5])  # a manifest without chosen_epoch: the last epoch
    curves = {"scimm": load_history(a), "baseline": load_history(b)}
    assert curves["scimm"] == Curves([1, 2, 3, 4, 5], {"path": [3.0, 2.0, 1.0, 1.5, 1.8],
                                                       "speed_wps": [1.5, 1.0, 0.5, 0.75, 0.9]},
                                     {"loss": [4.0, 3.0, 2.0, 1.0, 0.0]}, 3)
    assert curves["baseline"].chosen_epoch == 3
    fig = draw_loss_curves(curves)
    rings = {(ax.get_title(), line.get_gid()): (list(line.get_xdata()), list(line.get_ydata()))
             for ax in fig.axes for line in ax.get_lines() if (line.get_gid() or "").startswith("chosen:")}
    assert rings[("validation path loss [m^2]", "chosen:scimm")] == ([3], [1.0])
    assert rings[("validation speed-waypoint loss [m^2]", "chosen:scimm")] == ([3], [0.5])
    assert rings[("training loss (eq. 10, the arm's weights)", "chosen:scimm")] == ([3], [2.0])
    assert rings[("validation path loss [m^2]", "chosen:baseline")] == ([3], [0.5])
    out = plot_loss_curves({"scimm": a, "baseline": b / "manifest.json"}, tmp_path / "fig" / "curves.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_train_curves_cli_draws_trained_folders_and_refuses_bad_runs(sets, tmp_path, capsys):
    train_dir, val_dir = sets
    _train(train_dir, tmp_path / "s", val=val_dir, teacher="scimm", epochs=2, max_steps=3)
    out = tmp_path / "c.png"
    assert main(["train", "curves", "--runs", f"scimm={tmp_path / 's'}", "--out", str(out)]) == 0
    assert out.read_bytes()[:4] == b"\x89PNG"
    capsys.readouterr()
    for runs, message in ((["scimm"], "expected ARM=DIR"), ([f"a={tmp_path / 'nope'}"], "no training history")):
        bad = tmp_path / "bad.png"
        assert main(["train", "curves", "--runs", *runs, "--out", str(bad)]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1
        assert not bad.exists()
    assert main(["train", "curves", "--runs", f"a={tmp_path / 's'}", "--out", str(tmp_path / "c.jpg")]) == 2
    assert math.isfinite(json.loads((tmp_path / "s" / "history.json").read_text())["history"][0]["lr"])
