"""A run's records folder round trip: the committed records of docs/results/decisive (the
twenty-seed run of docs/results.md) restored into an empty output folder (as a later part
of a long run does on another machine) are found by ``reproduce``'s pooling, give ``report``
the same tables as the records themselves, and are archived again byte for byte; the seeds
a part runs itself are not restored."""
from __future__ import annotations

import filecmp
import shutil
from pathlib import Path

from model.reproduce import EVAL_SET, SECOND_SET, pooled_runs
from model.run_records import archive_records, restore_records
from sumo_scimm.cli import main

RECORDS = Path(__file__).resolve().parents[1] / "docs" / "results" / "decisive"
ARMS = ("baseline", "control", "fixed", "scimm")
SEEDS = 20


def _restored(tmp_path: Path, skip: range) -> tuple[Path, dict[str, Path], list[Path]]:
    out = tmp_path / "out"
    shutil.copytree(RECORDS, out / "records")  # with the committed replay tables of seeds 0 and 16
    folders = {EVAL_SET: out / "runs", SECOND_SET: out / "runs" / SECOND_SET}
    return out, folders, restore_records(out, folders, skip)


def test_restored_records_pool_report_and_archive_as_the_committed_ones(tmp_path):
    out, folders, restored = _restored(tmp_path, range(1, SEEDS))
    assert len(restored) == 2 * len(ARMS)  # every arm's seed 0 on both sets
    for label, folder in folders.items():
        runs, seeds = pooled_runs(folder, ARMS)
        assert list(runs) == list(ARMS) and all(s == [0] for s in seeds.values())
        for arm in ARMS:  # the compressed files as they were committed, nothing decompressed
            assert sorted(p.name for p in (folder / f"{arm}_s0").iterdir()) == ["records.csv.gz", "results.json.gz"]
    assert filecmp.cmp(out / "stages.json", RECORDS / "stages.json", shallow=False)
    assert filecmp.cmp(out / "models" / "scimm_s0" / "manifest.json", RECORDS / "models" / "scimm_s0.json",
                       shallow=False)
    assert filecmp.cmp(out / "replay" / "s0" / "table.md", RECORDS / "replay" / "s0.md", shallow=False)
    assert not (out / "replay" / "s16").exists()  # seed 16 is not restored: the part runs it
    # report reads the restored folders exactly as it reads the committed ones
    for label in (EVAL_SET, SECOND_SET):
        a, b = tmp_path / f"a_{label}", tmp_path / f"b_{label}"
        assert main(["report", *(f"{arm}={folders[label] / f'{arm}_s0'}" for arm in ARMS), "--out", str(a)]) == 0
        assert main(["report", *(f"{arm}={RECORDS / label / f'{arm}_s0'}" for arm in ARMS), "--out", str(b)]) == 0
        assert (a / "table3.md").read_text() == (b / "table3.md").read_text()
    # archived again: the same bytes as committed
    shutil.rmtree(out / "records")
    dest = archive_records(out, {label: pooled_runs(folder, ARMS)[0] for label, folder in folders.items()})
    for label in (EVAL_SET, SECOND_SET):
        for arm in ARMS:
            cmp = filecmp.dircmp(dest / label / f"{arm}_s0", RECORDS / label / f"{arm}_s0")
            assert cmp.left_only == cmp.right_only == [] and filecmp.cmpfiles(
                dest / label / f"{arm}_s0", RECORDS / label / f"{arm}_s0", cmp.common, shallow=False)[1:] == ([], [])
    assert filecmp.cmp(dest / "models" / "baseline_s0.json", RECORDS / "models" / "baseline_s0.json", shallow=False)
    assert filecmp.cmp(dest / "replay" / "s0.md", RECORDS / "replay" / "s0.md", shallow=False)


def test_a_part_does_not_restore_its_own_seeds_nor_overwrite_a_run_folder(tmp_path):
    out, folders, restored = _restored(tmp_path, range(0, SEEDS))
    assert restored == [] and not (out / "runs").exists() and not (out / "models").exists()
    assert not (out / "replay" / "s0").exists()
    own = out / "runs" / "scimm_s0"  # an evaluation the output folder already holds, plain files
    own.mkdir(parents=True)
    (own / "records.csv").write_text("key\n")
    (own / "results.json").write_text("{}")
    restored = restore_records(out, folders, range(5, 6))
    assert own not in restored and sorted(p.name for p in own.iterdir()) == ["records.csv", "results.json"]
    assert len(restored) == 2 * len(ARMS) * (SEEDS - 1) - 1  # every seed but 5, but the folder it holds
