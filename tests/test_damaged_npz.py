"""Damaged episode and log .npz files (empty, cut short, random bytes, an array missing, of
another shape or length, or of Python objects): every command that reads them gives one line
naming the file, the problem and the fix, exit code 2, no traceback, and writes nothing."""
from __future__ import annotations

import io
import shutil
from pathlib import Path

import numpy as np
import pytest

from tests.run_folder_helpers import SMOKE_ONE, _cli, _one_line_exit_2, finished_run, one_smoke_route


def _rewrite(path: Path, change) -> None:
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    change(arrays)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    path.write_bytes(buf.getvalue())


def _set(key, value):
    return lambda a: a.__setitem__(key, value(a[key]))


DAMAGE = {
    "cut": lambda p: p.write_bytes(p.read_bytes()[:len(p.read_bytes()) // 2]),
    "empty": lambda p: p.write_bytes(b""),
    "garbage": lambda p: p.write_bytes(np.random.default_rng(0).bytes(5000)),
    "no_path": lambda p: _rewrite(p, lambda a: a.pop("path")),
    "path_shape": lambda p: _rewrite(p, _set("path", lambda v: v[:, :5])),
    "x_short": lambda p: _rewrite(p, _set("x", lambda v: v[:10])),
    "x_objects": lambda p: _rewrite(p, _set("x", lambda v: v.astype(object))),
}
WORDS = {"cut": "damaged", "empty": "it is empty", "garbage": "not an .npz file", "no_path": "no 'path' array",
         "path_shape": "expected (N, 20, 2)", "x_short": "'x' has 10", "x_objects": "Python objects"}
LOG_DAMAGE = {k: DAMAGE[k] for k in ("cut", "empty", "garbage")}
LOG_DAMAGE["short"] = lambda p: _rewrite(p, lambda a: a.update({k: v[:3] for k, v in a.items() if v.ndim}))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("collect")
    out = tmp / "data"
    code, printed = _cli(["collect", "--routes", str(one_smoke_route(tmp, "0")), "--workers", "1", "--out", str(out)])
    assert code == 0, printed
    return out


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    return finished_run(tmp_path_factory, SMOKE_ONE)


def _damaged(folder: Path, tmp_path: Path, sub: str, damage: str, table=DAMAGE) -> tuple[Path, Path]:
    copy = tmp_path / folder.name
    shutil.copytree(folder, copy)
    (copy / "index.csv").unlink(missing_ok=True)
    (copy / "teacher").exists() and shutil.rmtree(copy / "teacher")
    f = copy / sub / "0_rep0.npz"
    table[damage](f)
    return copy, f


@pytest.mark.parametrize("damage", DAMAGE)
def test_teacher_names_a_damaged_episode(dataset, tmp_path, damage):
    data, f = _damaged(dataset, tmp_path, "episodes", damage)
    code, printed = _cli(["teacher", "--data", str(data), "--method", "scimm"])
    _one_line_exit_2(code, printed, str(f), WORDS[damage], "collect the dataset again")
    assert not (data / "teacher" / "scimm" / "manifest.json").exists()


@pytest.mark.parametrize("damage", ["empty", "x_short", "x_objects"])
def test_data_show_names_a_damaged_episode(dataset, tmp_path, damage):
    data, f = _damaged(dataset, tmp_path, "episodes", damage)
    code, printed = _cli(["data", "show", str(data)])
    _one_line_exit_2(code, printed, str(f), WORDS[damage])
    assert not (data / "index.csv").exists()


def test_teacher_plot_names_a_damaged_episode(dataset, tmp_path):
    data, f = _damaged(dataset, tmp_path, "episodes", "empty")
    out = tmp_path / "fig4.png"
    code, printed = _cli(["teacher", "plot", "--data", str(data), "--episode", "0_rep0", "--out", str(out)])
    _one_line_exit_2(code, printed, str(f), "it is empty")
    assert not out.exists()


@pytest.mark.parametrize("damage", ["empty", "path_shape"])
def test_train_names_a_damaged_episode_its_cache_workers_met(dataset, tmp_path, damage):
    data, f = _damaged(dataset, tmp_path, "episodes", damage)
    out = tmp_path / "student"
    code, printed = _cli(["train", "--data", str(data), "--teacher", "none", "--epochs", "1", "--epoch-steps", "2",
                          "--batch", "8", "--cache", str(tmp_path / "cache"), "--out", str(out)])
    _one_line_exit_2(code, printed, str(f), WORDS[damage])
    assert not out.exists()
    assert not list((tmp_path / "cache").glob("*.npz")) if (tmp_path / "cache").exists() else True


@pytest.mark.parametrize("damage", LOG_DAMAGE)
def test_replay_names_a_damaged_reference_log_before_it_starts(run, tmp_path, damage):
    ref, f = _damaged(run, tmp_path, "logs", damage, LOG_DAMAGE)
    out = tmp_path / "replay"
    code, printed = _cli(["replay", "--run", str(ref), "--agent", "route_follower", "--workers", "1",
                          "--out", str(out)])
    _one_line_exit_2(code, printed, str(f), "evaluate the reference again")
    assert not out.exists()


@pytest.mark.parametrize("damage", ["cut", "empty", "garbage"])
def test_render_names_a_damaged_log(run, tmp_path, damage):
    ref, f = _damaged(run, tmp_path, "logs", damage, LOG_DAMAGE)
    out = tmp_path / "fig5.png"
    code, printed = _cli(["render", "--route", "0", "--runs", str(run), str(ref), "--out", str(out)])
    _one_line_exit_2(code, printed, str(f), "damaged")
    assert not out.exists()
