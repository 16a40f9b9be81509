"""Outputs that cannot be written (docs/design.md §12): checked before the first route; a write that
fails stops the run with one line, leaves no temporary file, and --resume finishes it.

Real file-system errors: ENOSPC comes from the kernel, through a link to /dev/full at a
temporary file's name or a tmpfs of a few hundred kB filled up (where this user may mount
one); a read-only folder is a read-only tmpfs mounted there (root ignores file modes) or,
for other users, mode 555."""
from __future__ import annotations

import contextlib
import errno
import io
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from tests.run_folder_helpers import (SMOKE_ONE, SMOKE_TWO, _cli, _consistent, _leftovers, _one_line_exit_2,
                                      _records, _without_wall_clock)


# --- outputs that cannot be written ----------------------------------------------------------
@contextlib.contextmanager
def _read_only(folder: Path):
    """``folder`` (created) made read-only for this process: mode 555, or for root a
    read-only tmpfs mounted over it; skips the test where neither is possible."""
    folder.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        folder.chmod(0o555)
        try:
            yield folder
        finally:
            folder.chmod(0o755)
        return
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(folder)],
                             capture_output=True, text=True)
    if mounted.returncode:
        pytest.skip(f"cannot mount a read-only tmpfs here: {mounted.stderr.strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], check=True)


def test_unwritable_outputs_are_refused_before_the_first_route(tmp_path):
    """A read-only run folder, logs folder or results-file folder, a results path whose
    folder is missing or that is a folder: one line naming it, exit 2, and no route runs."""
    with _read_only(tmp_path / "ro") as ro:
        code, printed = _cli([*SMOKE_ONE, "--out", str(ro / "run")])
        _one_line_exit_2(code, printed, str(ro / "run"), "cannot create or write")
        out = tmp_path / "run"
        code, printed = _cli([*SMOKE_ONE, "--out", str(out), "--checkpoint", str(ro / "results.json")])
        _one_line_exit_2(code, printed, f"--checkpoint folder {ro}", "cannot write there")
        assert not out.exists()
    out = tmp_path / "run"
    with _read_only(out / "logs") as logs:
        code, printed = _cli([*SMOKE_ONE, "--out", str(out)])
        _one_line_exit_2(code, printed, f"output folder {logs}", "cannot write there")
    assert [p.name for p in out.iterdir()] == ["logs"]  # no record, no lock left
    cases = ((tmp_path / "nowhere" / "results.json", "its folder does not exist"), (tmp_path, "is not a file"))
    for checkpoint, words in cases:
        code, printed = _cli([*SMOKE_ONE, "--out", str(out), "--checkpoint", str(checkpoint)])
        _one_line_exit_2(code, printed, str(checkpoint), words)
    assert [p.name for p in out.iterdir()] == ["logs"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes read-only files")
def test_a_read_only_results_file_is_refused_before_the_first_route(tmp_path):
    checkpoint = tmp_path / "results.json"
    checkpoint.write_text("{}")
    checkpoint.chmod(0o444)
    code, printed = _cli([*SMOKE_ONE, "--out", str(tmp_path / "run"), "--checkpoint", str(checkpoint)])
    _one_line_exit_2(code, printed, str(checkpoint), "read-only")
    assert not (tmp_path / "run").exists()


def test_a_write_that_fails_removes_its_temporary_file_and_names_the_file_meant(tmp_path):
    """ENOSPC from the kernel: the temporary name links to /dev/full."""
    from files.atomic import savez_atomic, write_atomic
    log = tmp_path / "0_rep0.npz"
    (tmp_path / "0_rep0.npz.tmp.npz").symlink_to("/dev/full")
    with pytest.raises(OSError) as caught:
        savez_atomic(log, x=np.arange(10.0))
    assert (caught.value.errno, caught.value.filename) == (errno.ENOSPC, str(log))
    table = tmp_path / "records.csv"
    (tmp_path / "records.csv.tmp").symlink_to("/dev/full")
    with pytest.raises(OSError) as caught:
        write_atomic(table, "key\n")
    assert (caught.value.errno, caught.value.filename) == (errno.ENOSPC, str(table))
    assert list(tmp_path.iterdir()) == []


def test_a_record_line_cut_by_a_full_disk_is_removed_again(tmp_path):
    """runner._append: the part of a line written before the disk filled is cut off, so the
    file ends after its last whole record."""
    from harness.runs.runner import _append
    path = tmp_path / "records.jsonl"
    path.write_bytes(b'{"key": "0_rep0"}\n')

    class FillsAfter5Bytes(io.FileIO):
        def write(self, data):
            if self.tell() >= 18 + 5:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return super().write(bytes(data)[:5])
    with FillsAfter5Bytes(path, "ab") as f:
        with pytest.raises(OSError) as caught:
            _append(f, '{"key": "1_rep0"}\n', path, sync=True)
    assert (caught.value.errno, caught.value.filename) == (errno.ENOSPC, str(path))
    assert path.read_bytes() == b'{"key": "0_rep0"}\n'


@pytest.fixture(scope="module")
def clean_run(tmp_path_factory) -> Path:
    """Routes 0 and 1 of the smoke set run without a fault."""
    out = tmp_path_factory.mktemp("clean") / "run"
    code, printed = _cli([*SMOKE_TWO, "--out", str(out)])
    assert code == 0, printed
    return out


@pytest.fixture(scope="module")
def uninterrupted(clean_run) -> dict[str, dict]:
    """The records of ``clean_run`` (wall clock left out)."""
    return {r["key"]: _without_wall_clock(r) for r in _records(clean_run)}


@pytest.mark.slow
def test_a_full_disk_stops_the_run_and_resume_gives_the_uninterrupted_records(tmp_path, uninterrupted):
    """ENOSPC in the worker (route 1's log) and then in the parent (records.csv): each
    stops the run with one line naming the file, exit 2; no route is recorded as crashed,
    no temporary file stays, and --resume ends with the records of an uninterrupted run."""
    out = tmp_path / "run"
    (out / "logs").mkdir(parents=True)
    (out / "logs" / "1_rep0.npz.tmp.npz").symlink_to("/dev/full")  # where route 1's log is written first
    code, printed = _cli([*SMOKE_TWO, "--out", str(out)])
    _one_line_exit_2(code, printed, f"cannot write {out / 'logs' / '1_rep0.npz'} (No space left on device)",
                     "--resume")
    assert _consistent(out) == ["0_rep0"]  # route 1 is no record
    assert not _leftovers(out)

    (out / "records.csv.tmp").symlink_to("/dev/full")  # the table rewritten after route 1
    code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])
    _one_line_exit_2(code, printed, f"cannot write {out / 'records.csv'} (No space left on device)")
    assert [r["key"] for r in _records(out)] == ["0_rep0", "1_rep0"]  # its line was whole: kept
    assert not _leftovers(out)

    code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])  # the cause removed
    assert code == 0, printed
    assert _consistent(out) == ["0_rep0", "1_rep0"]
    assert {r["key"]: _without_wall_clock(r) for r in _records(out)} == uninterrupted
    assert not _leftovers(out)


@pytest.mark.slow
def test_a_full_disk_on_the_ray_driver_stops_the_run_too(tmp_path):
    """With --backend ray the driver writes the task's log: ENOSPC there stops the run the
    same way (one line, exit 2, no record, no temporary file)."""
    pytest.importorskip("ray", reason="ray is not installed")
    out = tmp_path / "run"
    (out / "logs").mkdir(parents=True)
    (out / "logs" / "0_rep0.npz.tmp").symlink_to("/dev/full")  # files.atomic.write_atomic's name
    code, printed = _cli([*SMOKE_ONE, "--backend", "ray", "--out", str(out)])
    _one_line_exit_2(code, printed, f"cannot write {out / 'logs' / '0_rep0.npz'} (No space left on device)")
    assert (out / "records.jsonl").read_text() == ""
    assert not _leftovers(out)


def _pages(folder: Path) -> int:
    """Bytes the files of ``folder`` take on a tmpfs (whole 4 KiB pages)."""
    return sum(-(-p.stat().st_size // 4096) * 4096 for p in folder.rglob("*") if p.is_file())


@pytest.mark.slow
def test_a_tiny_file_system_that_fills_up_mid_run_then_resume(tmp_path, clean_run, uninterrupted):
    """A real full disk: the run folder on a tmpfs whose free space is what the finished
    run takes less half of route 1's log, so a write fails by route 1's log at the latest.
    Wherever it fails, the run stops with one line naming a file of the run, exit 2, and
    leaves only whole files; once space is freed, --resume ends with the records of an
    uninterrupted run."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(disk)], capture_output=True,
                             text=True)
    if mounted.returncode:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.strip()}")
    try:
        free = _pages(clean_run) - (clean_run / "logs" / "1_rep0.npz").stat().st_size // 2
        filler = disk / "filler"
        filler.write_bytes(b"\0" * (shutil.disk_usage(disk).free - free))
        out = disk / "run"
        code, printed = _cli([*SMOKE_TWO, "--out", str(out)])
        line = _one_line_exit_2(code, printed, f"cannot write {out}", "(No space left on device)", "--resume")
        assert "Simulation crashed" not in line
        if (out / "records.csv").exists():
            assert len(_consistent(out)) < 2
        assert not _leftovers(out)
        filler.unlink()
        code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])
        assert code == 0, printed
        assert _consistent(out) == ["0_rep0", "1_rep0"]
        assert {r["key"]: _without_wall_clock(r) for r in _records(out)} == uninterrupted
    finally:
        subprocess.run(["umount", str(disk)], check=True)
