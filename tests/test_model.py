"""The student: loss terms of paper eq. 10-13 on tiny batches with hand-computed values,
the teacher-file contract, augmentation of teacher labels, determinism of training,
model checkpoints (round trip and refusals)."""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from sumo_scimm.cli import BadInput, main
from harness.expert.dataset import Episode
from model import cache as bevcache
from model.checkpoint import load_checkpoint, save_checkpoint, weights_digest
from model.data import StudentData, move
from model.loss import BASELINE, LossWeights, mode_loss, origin_loss, phi, scimm_loss, total_loss
from model.network import MODES, NetConfig, Student


# --- loss terms ---------------------------------------------------------------------------
def test_phi_is_the_distance_between_consecutive_waypoints_over_a_quarter_second():
    wps = torch.tensor([[[0.3, 0.4], [0.3, 0.4], [0.9, 1.2]]])  # steps 0.5 m, 0 m, 1.0 m
    np.testing.assert_array_equal(phi(wps, torch.zeros(1, 2)).numpy(), [[2.0, 0.0, 4.0]])
    # from an origin at (1, 0): the first step is sqrt(0.7^2 + 0.4^2) = sqrt(0.65) m
    got = phi(wps, torch.tensor([[1.0, 0.0]]))[0, 0].item()
    assert got == pytest.approx(math.sqrt(0.65) / 0.25, rel=1e-6)  # float32 rounding


def _pred(path=None, wps=None, logits=None):
    return {"path": torch.zeros(1, 20, 2) if path is None else path,
            "speed_wps": torch.zeros(1, 10, 2) if wps is None else wps,
            "mode_logits": torch.zeros(1, 5) if logits is None else logits}


def test_origin_loss_sums_x_y_and_averages_over_points():
    path = torch.zeros(1, 20, 2)
    path[0, 7] = torch.tensor([3.0, 4.0])  # one point 5 m off: 25 / 20 points
    wps = torch.zeros(1, 10, 2)
    wps[:, :, 0] = 1.0  # every waypoint 1 m off: 1 / point
    terms = origin_loss(_pred(), {"path": path, "speed_wps": wps})
    assert terms["path"].item() == pytest.approx(1.25, abs=1e-7)
    assert terms["speed_wps"].item() == pytest.approx(1.0, abs=1e-7)


def test_scimm_loss_compares_path_to_teacher_and_phi_of_the_waypoints_to_the_speed_teacher():
    wps = torch.zeros(1, 10, 2)
    wps[0, :, 0] = 0.5 * torch.arange(1, 11)  # 0.5 m per 0.25 s: phi = 2 m/s everywhere
    teacher_path = torch.zeros(1, 20, 2)
    teacher_path[0, :, 1] = 1.0  # 1 m to the left everywhere: 1 m^2 per point
    teacher_speed = torch.full((1, 10), 2.0)
    teacher_speed[0, 9] = 5.0  # one speed 3 m/s off: 9 / 10 speeds
    batch = {"teacher_path": teacher_path, "teacher_speed": teacher_speed, "origin": torch.zeros(1, 2)}
    terms = scimm_loss(_pred(wps=wps), batch)
    assert terms["teacher_path"].item() == pytest.approx(1.0, abs=1e-7)
    assert terms["teacher_speed"].item() == pytest.approx(0.9, abs=1e-6)


def test_mode_loss_is_kl_of_teacher_to_prediction():
    # uniform prediction (zero logits): KL = sum mu log mu + log 5
    one_hot = torch.tensor([[1.0, 0.0, 0.0, 0.0, 0.0]])
    assert mode_loss(torch.zeros(1, 5), one_hot).item() == pytest.approx(math.log(5), abs=1e-6)
    half = torch.tensor([[0.5, 0.5, 0.0, 0.0, 0.0]])
    assert mode_loss(torch.zeros(1, 5), half).item() == pytest.approx(math.log(2.5), abs=1e-6)


def test_mode_loss_is_zero_when_the_prediction_equals_the_teacher_posterior():
    mu = torch.tensor([[0.4, 0.3, 0.1, 0.15, 0.05]])
    logits = torch.log(mu) + 7.0  # softmax is shift-invariant
    assert mode_loss(logits, mu).item() == pytest.approx(0.0, abs=1e-6)  # float32 log/exp rounding
    assert len(MODES) == 5


def test_total_loss_weights_the_terms_and_the_baseline_needs_no_teacher():
    path = torch.zeros(1, 20, 2)
    path[0, :, 0] = 1.0  # 1 m^2 per point
    batch = {"path": path, "speed_wps": torch.zeros(1, 10, 2)}
    base = total_loss(_pred(), batch, BASELINE)
    assert set(base) == {"path", "speed_wps", "loss"}
    assert base["loss"].item() == pytest.approx(1.0)
    full = dict(batch, teacher_path=torch.zeros(1, 20, 2), teacher_speed=torch.full((1, 10), 1.0),
                origin=torch.zeros(1, 2), mu=torch.tensor([[1.0, 0.0, 0.0, 0.0, 0.0]]))
    w = LossWeights(origin=2.0, scimm=0.5, mode=0.1)
    terms = total_loss(_pred(), full, w)
    # 2 * (1 + 0) + 0.5 * (0 + 1) + 0.1 * log 5
    assert terms["loss"].item() == pytest.approx(2.0 + 0.5 + 0.1 * math.log(5), abs=1e-6)


def test_loss_weights_refuse_negative_values():
    with pytest.raises(ValueError):
        LossWeights(scimm=-1.0)


# --- network ------------------------------------------------------------------------------
def test_student_outputs_cumulative_points_and_five_mode_logits():
    torch.manual_seed(0)
    m = Student(NetConfig()).eval()
    out = m(torch.zeros(3, 9, 64, 64), torch.zeros(3, 2), torch.zeros(3))
    assert out["path"].shape == (3, 20, 2)
    assert out["speed_wps"].shape == (3, 10, 2)
    assert out["mode_logits"].shape == (3, 5)
    x = torch.cat([m.target_in(torch.zeros(3, 1, 2)), m.speed_in(torch.zeros(3, 1, 1)), m.queries.expand(3, -1, -1)], 1)
    for block in m.blocks:
        x = block(x, m.bev(torch.zeros(3, 9, 64, 64)))
    increments = m.path_head(m.norm(x[:, 2:22]))
    torch.testing.assert_close(out["path"], torch.cumsum(increments, 1))


def test_a_student_without_speed_input_gives_the_same_outputs_at_every_speed():
    torch.manual_seed(0)
    m = Student(NetConfig(speed_input=False)).eval()
    bev, tp = (torch.rand(2, 9, 64, 64) > 0.9).float(), torch.tensor([[12.0, 1.0], [20.0, -3.0]])
    on = Student(NetConfig(speed_input=True)).eval()
    on.load_state_dict(m.state_dict())  # the same weights with the speed input on
    with torch.no_grad():
        slow, fast = m(bev, tp, torch.zeros(2)), m(bev, tp, torch.tensor([4.0, 11.0]))
        on_fast, on_zero = on(bev, tp, torch.tensor([4.0, 11.0])), on(bev, tp, torch.zeros(2))
    for k in ("path", "speed_wps", "mode_logits"):
        torch.testing.assert_close(slow[k], fast[k], rtol=0, atol=0)
        torch.testing.assert_close(on_zero[k], fast[k], rtol=0, atol=0)  # the token sees 0 m/s
    # with the input on the same weights answer the speed: the flag is what removes it
    assert not torch.allclose(on_fast["speed_wps"], fast["speed_wps"])


def test_a_checkpoint_saved_before_the_speed_flag_loads_with_the_speed_input_on(tmp_path):
    torch.manual_seed(0)
    f = save_checkpoint(tmp_path / "student.pt", Student(NetConfig()), {})
    blob = torch.load(f, weights_only=True)
    del blob["config"]["speed_input"]
    torch.save(blob, f)
    assert load_checkpoint(f)[0].cfg.speed_input is True


# --- data: teacher files, augmentation -----------------------------------------------------
DECISIVE_MODELS = Path(__file__).resolve().parents[1] / "docs" / "results" / "decisive" / "models"
N_FRAMES = 256  # two batches of 128


def fake_dataset(root, n_frames=N_FRAMES, seed=0):
    """A dataset folder with two dummy episode files and a ready cache (no rendering)."""
    rng = np.random.default_rng(seed)
    (root / "episodes").mkdir(parents=True)
    for stem in ("a_rep0", "b_rep0"):
        (root / "episodes" / f"{stem}.npz").write_bytes(stem.encode())
    views = 2
    bev = (rng.random((n_frames, views, *bevcache.BEV_SHAPE)) < 0.2).astype(np.uint8) * 255
    half = n_frames // 2
    arrays = {"bev": bevcache.pack(bev), "aug": np.zeros((n_frames, views, 2)),
              "path": rng.normal(size=(n_frames, views, 20, 2)).astype(np.float32),
              "speed_wps": rng.normal(size=(n_frames, views, 10, 2)).astype(np.float32),
              "target_point": rng.normal(size=(n_frames, views, 2)).astype(np.float32),
              "speed": rng.uniform(0, 8, n_frames).astype(np.float32), "stop": np.zeros(n_frames, bool),
              "episode": np.repeat(np.arange(2, dtype=np.int32), half),
              "frame": np.tile(np.arange(half, dtype=np.int32), 2), "stems": np.array(["a_rep0", "b_rep0"])}
    arrays["aug"][:, 1] = np.stack([rng.uniform(-1, 1, n_frames), rng.uniform(-0.2, 0.2, n_frames)], 1)
    cache = bevcache.cache_path(root, root / "cache", views)
    cache.parent.mkdir()
    np.savez(cache, **arrays)
    return arrays


def write_teacher(root, method="scimm", rows=N_FRAMES // 2, manifest=True, seed=1):
    rng = np.random.default_rng(seed)
    tdir = root / "teacher" / method
    tdir.mkdir(parents=True)
    for stem in ("a_rep0", "b_rep0"):
        np.savez(tdir / f"{stem}.npz", path=rng.normal(size=(rows, 20, 2)).astype(np.float32),
                 speed=rng.uniform(0, 8, (rows, 10)).astype(np.float32),
                 mu=rng.dirichlet(np.ones(5), rows).astype(np.float32))
    if manifest:
        (tdir / "manifest.json").write_text("{}")


def test_move_is_the_transform_of_the_dataset_labels():
    rng = np.random.default_rng(3)
    ep = Episode.__new__(Episode)  # labels() only reads the arrays
    ep.a = {"path": rng.normal(size=(4, 20, 2)), "speed_wps": rng.normal(size=(4, 10, 2)),
            "target_point": rng.normal(size=(4, 2))}
    shift, rot = np.array([0.7, -0.3, 0.0, 1.0]), np.array([0.1, -0.2, 0.3, 0.0])
    moved = move(ep.a["path"], shift, rot)
    for k in range(4):
        np.testing.assert_allclose(moved[k], ep.labels(k, shift[k], rot[k])["path"], atol=1e-12)


def test_teacher_labels_follow_the_augmentation_and_speed_and_mu_do_not(tmp_path):
    arrays = fake_dataset(tmp_path)
    write_teacher(tmp_path)
    data = StudentData.load(tmp_path, tmp_path / "cache", 2, teacher="scimm")
    idx, view = np.array([0, 5, 200]), np.array([1, 1, 0])
    b = data.batch(idx, view)
    shift, rot = arrays["aug"][idx, view, 0], arrays["aug"][idx, view, 1]
    np.testing.assert_allclose(b["teacher_path"].numpy(), move(data.teacher["path"][idx], shift, rot), atol=1e-6)
    np.testing.assert_array_equal(b["teacher_path"][2].numpy(), data.teacher["path"][200])  # view 0: unmoved
    np.testing.assert_array_equal(b["teacher_speed"].numpy(), data.teacher["speed"][idx])
    np.testing.assert_array_equal(b["mu"].numpy(), data.teacher["mu"][idx])
    np.testing.assert_allclose(b["origin"].numpy(), move(np.zeros((3, 2)), shift, rot), atol=1e-6)
    np.testing.assert_array_equal(b["origin"][2].numpy(), [0.0, 0.0])
    np.testing.assert_array_equal(b["bev"].numpy(), bevcache.unpack(arrays["bev"][idx, view]))


def test_a_teacher_without_manifest_or_with_wrong_rows_is_refused(tmp_path):
    fake_dataset(tmp_path)
    write_teacher(tmp_path, "fixed", manifest=False)
    with pytest.raises(BadInput, match="manifest.json"):
        StudentData.load(tmp_path, tmp_path / "cache", 2, teacher="fixed")
    write_teacher(tmp_path, "scimm", rows=N_FRAMES // 2 - 1)
    with pytest.raises(BadInput, match="one row per frame"):
        StudentData.load(tmp_path, tmp_path / "cache", 2, teacher="scimm")


def test_the_baseline_never_reads_teacher_files(tmp_path, monkeypatch):
    fake_dataset(tmp_path)
    write_teacher(tmp_path, "scimm")
    for f in (tmp_path / "teacher" / "scimm").glob("*.npz"):
        f.write_bytes(b"corrupt")  # a teacher arm would fail on these
    opened = []
    real_load = np.load
    monkeypatch.setattr(np, "load", lambda f, *a, **k: (opened.append(str(f)), real_load(f, *a, **k))[1])
    data = StudentData.load(tmp_path, tmp_path / "cache", 2, teacher=None)
    b = data.batch(np.arange(4), np.ones(4, int))
    assert data.teacher is None
    assert "teacher_path" not in b
    assert opened, "np.load was never called: the check saw nothing"
    assert not [f for f in opened if "teacher" in f]
    with pytest.raises(BadInput, match="teacher file .* is damaged"):
        StudentData.load(tmp_path, tmp_path / "cache", 2, teacher="scimm")


# --- training: determinism, checkpoint ---------------------------------------------------------
def _train(tmp_path, out, seed, teacher="none"):
    from model.train import TrainConfig, train
    return train(TrainConfig(data=tmp_path, out=tmp_path / out, teacher=teacher, seed=seed, epochs=1,
                             max_steps=2, cache_dir=tmp_path / "cache", threads=1))


@pytest.fixture
def trained(tmp_path):
    fake_dataset(tmp_path)
    write_teacher(tmp_path, "scimm")
    return tmp_path


def test_two_training_steps_are_deterministic_for_a_seed(trained):
    a, _ = load_checkpoint(_train(trained, "a", seed=3, teacher="scimm"))
    b, manifest = load_checkpoint(_train(trained, "b", seed=3, teacher="scimm"))
    c, _ = load_checkpoint(_train(trained, "c", seed=4, teacher="scimm"))
    for (k, va), vb, vc in zip(a.state_dict().items(), b.state_dict().values(), c.state_dict().values()):
        torch.testing.assert_close(va, vb, rtol=0, atol=0, msg=k)
    assert any(not torch.equal(va, vc) for va, vc in zip(a.state_dict().values(), c.state_dict().values()))
    assert manifest["teacher"] == "scimm"
    assert manifest["seed"] == 3
    assert manifest["steps"] == 2
    assert manifest["data_hash"] == bevcache.dataset_hash(trained)
    assert {"teacher_path", "teacher_speed", "mode", "loss"} <= set(manifest["final_train"])
    assert manifest["git_commit"]


def test_a_model_checkpoint_round_trips(tmp_path):
    torch.manual_seed(0)
    m = Student(NetConfig()).eval()
    path = save_checkpoint(tmp_path / "student.pt", m, {"seed": 1, "teacher": "none"})
    loaded, manifest = load_checkpoint(path)
    x = (torch.rand(2, 9, 64, 64) > 0.5).float(), torch.randn(2, 2), torch.rand(2)
    with torch.no_grad():
        for k in ("path", "speed_wps", "mode_logits"):
            torch.testing.assert_close(loaded(*x)[k], m(*x)[k], rtol=0, atol=0)
    assert manifest == {"seed": 1, "teacher": "none", "weights_sha256": weights_digest(m.state_dict())}
    assert (tmp_path / "manifest.json").is_file()
    assert load_checkpoint(tmp_path)[1] == manifest  # a training --out folder works too


@pytest.mark.parametrize("speed_input", [False, True])
def test_the_agent_onnx_network_gives_the_eager_outputs_to_rounding(speed_input):
    """ONNX Runtime computes the torch module's function in float32 with other kernels
    (fused, reassociated sums), so outputs may differ by rounding only. Outputs reach 12-18 m,
    where one float32 ulp is 0.95-1.9e-6 m; over a few hundred inputs, for a fresh network
    and for a trained SC-IMM student, differences were a few 1e-6 m (up to 4.8e-6 m, after
    the cumulative sum of 20 rounded increments). 2e-5 m leaves room for other CPUs'
    kernels, while the graph errors tried on this test's network move them 100 times more
    (a LayerNorm eps of 1e-6 instead of 1e-5 in the first block: 1.6e-2 m; 1e-4 added to
    one bias of the path head: 2.0e-3 m)."""
    from model.runtime import OnnxNetwork
    torch.manual_seed(0)
    m = Student(NetConfig(speed_input=speed_input)).eval()
    net = OnnxNetwork(m)
    assert net.takes_speed is speed_input
    g = torch.Generator().manual_seed(1)
    worst = 0.0
    with torch.inference_mode():
        for _ in range(20):
            x = (torch.rand(1, 9, 64, 64, generator=g) > 0.8).float(), torch.randn(1, 2, generator=g) * 10, \
                torch.rand(1, generator=g) * 10
            path, speed_wps = net(x[0][0].numpy(), x[1][0].numpy(), float(x[2][0]))
            eager = m(*x)
            assert path.shape == (20, 2)
            assert speed_wps.shape == (10, 2)
            np.testing.assert_allclose(path, eager["path"][0].double().numpy(), rtol=0, atol=2e-5)
            np.testing.assert_allclose(speed_wps, eager["speed_wps"][0].double().numpy(), rtol=0, atol=2e-5)
            worst = max(worst, float(np.abs(eager["path"][0].numpy()).max()))
            again = net(x[0][0].numpy(), x[1][0].numpy(), float(x[2][0]))
            np.testing.assert_array_equal(again[0], path)  # deterministic: same inputs, same outputs
            np.testing.assert_array_equal(again[1], speed_wps)
    assert worst > 5.0  # the comparison is not between near-zero outputs


class _RunsCode:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.makedirs, (self.marker,))


def test_a_model_checkpoint_holding_code_is_refused(tmp_path):
    marker = str(tmp_path / "pwned")
    torch.save({"format": "sumo-scimm-student/1", "state_dict": {}, "config": {}, "manifest": _RunsCode(marker)},
               tmp_path / "evil.pt")
    with pytest.raises(BadInput, match="refused"):
        load_checkpoint(tmp_path / "evil.pt")
    assert not os.path.exists(marker)


def test_a_missing_or_corrupt_model_checkpoint_is_one_line_of_bad_input(tmp_path):
    with pytest.raises(BadInput, match="not found"):
        load_checkpoint(tmp_path / "nope.pt")
    (tmp_path / "junk.pt").write_bytes(b"\x00not a torch file" * 10)
    with pytest.raises(BadInput, match="not a torch file") as exc:
        load_checkpoint(tmp_path / "junk.pt")
    assert "\n" not in str(exc.value)
    torch.save({"format": "other"}, tmp_path / "other.pt")
    with pytest.raises(BadInput, match="not a sumo-scimm-student"):
        load_checkpoint(tmp_path / "other.pt")


def test_train_cli_bad_input_exits_2_with_one_line(tmp_path, capsys):
    assert main(["train", "--data", str(tmp_path / "none"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("sumo-scimm: error:")
    assert err.count("\n") == 1
    assert "no episodes" in err
    assert not (tmp_path / "o").exists()


def test_cli_default_epochs_is_the_training_default():
    from model.reproduce import EVAL_SET
    from model.train import EPOCHS
    from sumo_scimm import model_commands
    assert model_commands.EPOCHS == EPOCHS
    assert model_commands.EVAL_SET == EVAL_SET


# --- data balance and route-end augmentation ---------------------------------------------------
def test_a_route_cut_erases_the_route_ahead_and_pulls_the_target_point_onto_the_path(tmp_path):
    arrays = fake_dataset(tmp_path)
    arrays["target_point"][3, 0] = (25.0, 2.0)  # farther than the cut
    arrays["target_point"][4, 0] = (6.0, 0.0)  # closer than the cut
    np.savez(bevcache.cache_path(tmp_path, tmp_path / "cache", 2), **arrays)
    data = StudentData.load(tmp_path, tmp_path / "cache", 2)
    idx, view = np.array([3, 4, 5]), np.zeros(3, int)
    b = data.batch(idx, view, np.array([10.0, 10.0, 0.0]))
    full = bevcache.unpack(arrays["bev"][idx, view])
    # 10 m ahead = 13.3 rows above the ego row 48: rows 0..34 are more than 10 m ahead
    assert not b["bev"][:2, 3, :35].any()
    np.testing.assert_array_equal(b["bev"][:2, 3, 35:].numpy(), full[:2, 3, 35:])
    np.testing.assert_array_equal(b["bev"][:, [0, 1, 2, 4, 5, 6, 7, 8]].numpy(), full[:, [0, 1, 2, 4, 5, 6, 7, 8]])
    np.testing.assert_array_equal(b["bev"][2].numpy(), full[2])  # no cut
    np.testing.assert_array_equal(b["target_point"][0].numpy(), arrays["path"][3, 0, 10])
    np.testing.assert_array_equal(b["target_point"][1].numpy(), [6.0, 0.0])
    np.testing.assert_array_equal(b["path"].numpy(), arrays["path"][idx, view])  # labels unchanged
    assert b["bev"].is_contiguous(memory_format=torch.channels_last)  # the layout the encoder runs on


def test_the_bev_encoder_on_channels_last_memory_gives_the_outputs_and_gradients_of_plain_memory():
    """The encoder runs its convolutions on channels-last memory (a speed choice); the same
    layers on (B, C, H, W) memory give the same outputs and parameter gradients up to float32
    summation order (measured: 3e-6 relative at most), so the layout changes no training."""
    torch.manual_seed(0)
    m = Student(NetConfig())
    bev, tp = (torch.rand(16, 9, 64, 64) > 0.8).float(), torch.randn(16, 2) * 10

    def outputs_and_grads():
        m.zero_grad()
        out = m(bev, tp, torch.zeros(16))
        (out["path"].square().mean() + out["speed_wps"].square().mean() + out["mode_logits"].square().mean()).backward()
        return out, {k: p.grad.clone() for k, p in m.named_parameters() if p.grad is not None}

    fast, fast_grads = outputs_and_grads()
    enc = m.bev
    enc.forward = lambda b: enc.cnn(b).flatten(2).transpose(1, 2) + enc.pos  # (B, C, H, W) memory throughout
    plain, plain_grads = outputs_and_grads()
    assert bev.is_contiguous() and enc.cnn(bev).is_contiguous()
    assert set(fast_grads) == set(plain_grads) and "bev.cnn.0.weight" in fast_grads
    for k in ("path", "speed_wps", "mode_logits"):
        torch.testing.assert_close(fast[k], plain[k], rtol=1e-5, atol=1e-5)
    for k, g in plain_grads.items():
        torch.testing.assert_close(fast_grads[k], g, rtol=1e-4, atol=1e-4 * g.abs().max().item() + 1e-12, msg=k)


def test_an_epoch_draws_moving_frames_once_thins_waits_drops_stop_sign_waits_repeats_starts(tmp_path):
    from model.train import epoch_plan
    arrays = fake_dataset(tmp_path)
    arrays["speed"][:130] = 0.0
    arrays["speed_wps"][:120, 0] = 0.01  # 0..119 still within 0.5 m after 2.5 s: staying
    arrays["speed_wps"][120:130, 0, :, 0] = np.linspace(0.1, 2.0, 10)  # 120..129 start off (2 m)
    arrays["stop"][100:120] = True  # 100..119 wait at a stop sign
    arrays["speed"][130:] = 5.0
    np.savez(bevcache.cache_path(tmp_path, tmp_path / "cache", 2), **arrays)
    data = StudentData.load(tmp_path, tmp_path / "cache", 2)
    np.testing.assert_array_equal(np.flatnonzero(data.staying()), np.arange(120))
    np.testing.assert_array_equal(np.flatnonzero(data.departing()), np.arange(120, 130))
    order, views, cuts = epoch_plan(data, np.random.default_rng(0))
    counts = np.bincount(order, minlength=N_FRAMES)
    assert (counts[130:] == 1).all()  # moving frames: once
    assert (counts[120:130] == 3).all()  # starting off: DEPART_REPEAT = 3 times
    assert (counts[100:120] == 0).all()  # stop-sign waits: never
    assert counts[:100].max() <= 1
    # KEEP_STAY = 0.15 of them: the epoch's first draw is rng.random(256), frame k kept where
    # it is < 0.15; with default_rng(0), 15 of frames 0..99 (0.14: 14, 0.16: 16, 0.25: 22)
    assert int(counts[:100].sum()) == 15
    assert set(np.unique(views)) <= {0, 1}
    assert ((cuts == 0) | ((cuts >= 4) & (cuts <= 30))).all()


def test_a_standing_frame_stays_below_0_5_m_of_travel_in_2_5_s_and_departs_at_0_5(tmp_path):
    # frames 0-1 stand (speed 0); the last speed waypoint (2.5 s ahead) is 0.49 m or 0.50 m away
    arrays = fake_dataset(tmp_path)
    arrays["speed"][:2] = 0.0
    arrays["speed"][2:] = 5.0
    arrays["speed_wps"][:2, 0, -1] = [[0.49, 0.0], [0.0, 0.50]]
    np.savez(bevcache.cache_path(tmp_path, tmp_path / "cache", 2), **arrays)
    data = StudentData.load(tmp_path, tmp_path / "cache", 2)
    assert np.flatnonzero(data.staying()).tolist() == [0]
    assert np.flatnonzero(data.departing()).tolist() == [1]


@pytest.mark.parametrize("option,value,message", [("--seed", "-1", "--seed must be >= 0"),
                                                  ("--epochs", "0", "--epochs must be >= 1")])
def test_bad_training_options_are_one_line_and_write_nothing(tmp_path, capsys, option, value, message):
    fake_dataset(tmp_path / "data")
    out = tmp_path / "model"
    assert main(["train", "--data", str(tmp_path / "data"), "--out", str(out), option, value]) == 2
    err = capsys.readouterr().err
    assert message in err
    assert "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_eval_refuses_a_corrupt_checkpoint_before_any_route_runs(tmp_path, capsys):
    bad = tmp_path / "student.pt"
    bad.write_bytes(b"not a torch file")
    out = tmp_path / "run"
    assert main(["eval", "--routes", "town12_smoke", "--agent", "student", "--agent-config", str(bad),
                 "--workers", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"model checkpoint {bad}" in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("arm, teacher", [("baseline", "none"), ("control", "control"), ("fixed", "fixed"),
                                          ("scimm", "scimm"), ("smoother", "smoother")])
def test_the_shipped_students_load_safely_and_say_how_they_were_made(arm, teacher):
    """model/checkpoints/<arm>: small, loadable with weights_only, with the manifest of the
    training that made it (seed 0 of `sumo-scimm reproduce`, model/checkpoints/README.md):
    the default schedule, run whole, its best epoch on `val` saved; the four arms of the
    twenty-seed run are that run's seed-0 students, weight for weight, and the smoother's
    was trained on the same data as they were."""
    from model.agent import SHIPPED
    from model.train import EPOCH_STEPS, EPOCHS
    path = SHIPPED / arm / "student.pt"
    assert path.stat().st_size < 1_000_000
    model, manifest = load_checkpoint(path)
    assert manifest["teacher"] == teacher
    assert manifest["seed"] == 0
    if arm != "smoother":  # not an arm of the run
        run = json.loads((DECISIVE_MODELS / f"{arm}_s0.json").read_text())
        assert manifest["weights_sha256"] == run["weights_sha256"]
    _, scimm = load_checkpoint(SHIPPED / "scimm" / "student.pt")  # one dataset for all five
    assert (manifest["data_hash"], manifest["val_hash"]) == (scimm["data_hash"], scimm["val_hash"])
    assert (manifest["epochs"], manifest["epoch_steps"], manifest["patience"]) == (EPOCHS, EPOCH_STEPS, None)
    assert (manifest["epochs_run"], manifest["stop_reason"]) == (EPOCHS, "epochs")
    losses = [r["val"]["loss"] for r in manifest["history"]]
    assert manifest["chosen_val"]["loss"] == min(losses) == losses[manifest["chosen_epoch"] - 1]
    assert json.loads((SHIPPED / arm / "manifest.json").read_text()) == manifest


def test_the_default_agent_is_the_shipped_scimm_student():
    from harness.loop.agent import DEFAULT_AGENT, load_agent
    assert DEFAULT_AGENT == "scimm"
    load_agent(DEFAULT_AGENT).check_config(None)  # finds model/checkpoints/scimm/student.pt
