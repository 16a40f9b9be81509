"""Students trained side by side (model.side_by_side): real torch trainings of a few steps
on the small cached datasets of tests/test_model.py, in spawned processes, against the
same trainings run alone in this process."""
from __future__ import annotations

import json
from dataclasses import replace

import pytest
import torch

from harness.common.errors import BadInput
from model.checkpoint import load_checkpoint
from model.side_by_side import LOG_NAME, THREADS_EACH, train_side_by_side
from model.train import TrainConfig, train
from tests.test_train import sets  # noqa: F401 - the fixture


def _cfg(train_dir, val_dir, out, **kw) -> TrainConfig:
    return TrainConfig(data=train_dir, out=out, val=val_dir, cache_dir=train_dir / "cache", epochs=2,
                       epoch_steps=3, **kw)


class _Bar:
    """Stands in for the progress bar (harness.common.progress): records the progress counted."""

    n, total = 0, None

    def __init__(self, total=None, **_):
        _Bar.n, _Bar.total = 0, total

    def update(self, k):
        _Bar.n += k
        self.n = _Bar.n

    def close(self):
        pass


def test_students_side_by_side_have_the_weights_of_one_thread_trainings_alone(sets, tmp_path,  # noqa: F811
                                                                               monkeypatch):
    """Three trainings, two at a time (one waits for a free process): each checkpoint equals
    weight for weight the same config trained alone here on THREADS_EACH thread, in the
    order given; each writes its epoch lines to its train.log; the progress bar counts
    every step of every training."""
    import model.side_by_side as sbs
    monkeypatch.setattr(sbs, "progress", _Bar)
    train_dir, val_dir = sets
    cfgs = [_cfg(train_dir, val_dir, tmp_path / "side" / name, teacher=teacher, seed=seed)
            for name, teacher, seed in (("a", "scimm", 0), ("b", "none", 1), ("c", "control", 0))]
    ckpts = train_side_by_side(cfgs, processes=2)
    # 2 epochs of 2 steps each (two whole batches of 256 frames), 3 trainings
    assert _Bar.n == 12 and _Bar.total == 18  # the total is epochs x epoch_steps; this small set runs fewer
    assert ckpts == [c.out / "student.pt" for c in cfgs]
    torch_threads = torch.get_num_threads()
    try:
        for cfg, ckpt in zip(cfgs, ckpts):
            alone = train(TrainConfig(**{**cfg.__dict__, "out": tmp_path / "alone" / cfg.out.name,
                                         "threads": THREADS_EACH}))
            side, m = load_checkpoint(ckpt)
            ref, m_ref = load_checkpoint(alone)
            assert m["threads"] == 1 and m["teacher"] == cfg.teacher and m["seed"] == cfg.seed
            for (name, p), q in zip(side.state_dict().items(), ref.state_dict().values()):
                assert torch.equal(p, q), name
            assert m["chosen_val"] == m_ref["chosen_val"]
            log = (cfg.out / LOG_NAME).read_text()
            assert "epoch 2: train" in log and "chosen epoch" in log
            # 256 frames: two whole batches of 128 an epoch, below the 3 steps asked
            assert json.loads((cfg.out / "history.json").read_text())["history"][-1]["step"] == 4
    finally:
        torch.set_num_threads(torch_threads)


def test_a_failing_training_raises_its_error_after_the_others_finish(sets, tmp_path):  # noqa: F811
    """A config whose data has fewer frames than one batch: its BadInput reaches the caller,
    and the other training still saves its checkpoint."""
    train_dir, val_dir = sets
    good = _cfg(train_dir, val_dir, tmp_path / "good")
    bad = _cfg(train_dir, val_dir, tmp_path / "bad", batch=100_000)
    with pytest.raises(BadInput, match="fewer than one batch of 100000"):
        train_side_by_side([bad, good], processes=2)
    assert (tmp_path / "good" / "student.pt").is_file()
    assert "BadInput" in (tmp_path / "bad" / LOG_NAME).read_text()


def test_nothing_to_train_starts_no_process():
    assert train_side_by_side([]) == []


def test_a_stop_while_training_ends_every_training_process(sets, tmp_path, monkeypatch):  # noqa: F811
    """A Ctrl-C (or the SIGTERM the CLI turns into an exception) reaching the parent while it
    waits: the exception goes on to the caller, the training processes are ended at once
    (no student saved, no process left)."""
    import multiprocessing as mp

    import model.side_by_side as sbs
    train_dir, val_dir = sets
    cfgs = [replace(_cfg(train_dir, val_dir, tmp_path / name), epochs=50) for name in ("a", "b")]

    def stop(_seconds):
        raise KeyboardInterrupt

    monkeypatch.setattr(sbs, "sleep", stop)  # the parent's wait between polls
    with pytest.raises(KeyboardInterrupt):
        train_side_by_side(cfgs, processes=2)
    assert mp.active_children() == []
    assert not any((c.out / "student.pt").exists() for c in cfgs)
