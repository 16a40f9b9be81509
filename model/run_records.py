"""What a ``reproduce`` run keeps in a repository, and the run folders a later part of the
run rebuilds from it.

``OUT/records`` (written by ``archive_records`` after every part)::

    <set>/<arm>_s<seed>/records.csv.gz, results.json.gz   every finished evaluation, gzip-compressed
                                                          (files.compressed: the same bytes for the
                                                          same records); a second evaluation
                                                          set named as the evaluation set is
                                                          kept as <set>_second (second_label)
    models/<arm>_s<seed>.json   each student's manifest (its training and validation data's
                                hashes, the software's commit, the loss history)
    replay/s<seed>.md           the seed's replay table
    data/<train|val>.run.jsonc  the run configuration of the expert's collections
    stages.json                 the stages' wall times [s]

``sumo-scimm report ARM=OUT/records/SET/ARM_s0,ARM_s1 ...`` reads the evaluations as they are.

A long run goes in parts (``--seeds 0-1``, then ``--seeds 2-4``, ...), not necessarily on
one machine. For a part on another machine, copy the records of the earlier parts to
``OUT/records`` of an empty OUT: ``restore_records`` (which ``reproduce`` calls before any
stage) puts every evaluation of a seed the part does not run back in its run folder as the
compressed files (which ``report`` and the tables read), each manifest and replay table in
its place and the stage times in ``OUT/stages.json``, so the part's tables pool every seed.
It never overwrites a file that exists. A restored run folder has no per-route logs: the
figures drawn from logs (Fig. 5) use a seed the part ran.
"""
from __future__ import annotations

import re
import shutil
from pathlib import Path

from files.compressed import gzip_copy, stored

ARCHIVED = ("records.csv", "results.json")  # what ``report`` reads of a run folder (harness.scoring.report)
COLLECTIONS = ("train", "val")  # OUT/data/<name>: the expert's collections


def archive_records(out: Path, runs: dict[str, dict[str, list[Path]]]) -> Path:
    """Write ``OUT/records`` (the layout above) for the evaluations ``runs`` ({set label:
    {arm: run folders}}), with the manifests of their students, the replay tables and
    collection configurations found in OUT, and ``OUT/stages.json``; returns the folder.
    A run folder holding only the compressed files (restored) is archived as it is."""
    dest = out / "records"
    dest.mkdir(exist_ok=True)
    if (out / "stages.json").is_file():
        shutil.copyfile(out / "stages.json", dest / "stages.json")
    for route_set, arms in runs.items():
        for folders in arms.values():
            for run in folders:
                (dest / route_set / run.name).mkdir(parents=True, exist_ok=True)
                for name in ARCHIVED:
                    _pack(run / name, dest / route_set / run.name / f"{name}.gz")
                manifest = out / "models" / run.name / "manifest.json"
                if manifest.is_file():
                    (dest / "models").mkdir(parents=True, exist_ok=True)
                    shutil.copyfile(manifest, dest / "models" / f"{run.name}.json")
    for table in sorted((out / "replay").glob("s*/table.md")):
        (dest / "replay").mkdir(exist_ok=True)
        shutil.copyfile(table, dest / "replay" / f"{table.parent.name}.md")
    for name in COLLECTIONS:
        config = out / "data" / name / "run.jsonc"
        if config.is_file():
            (dest / "data").mkdir(exist_ok=True)
            shutil.copyfile(config, dest / "data" / f"{name}.run.jsonc")
    return dest


def second_label(main: str, second: str) -> str:
    """The folder name under ``OUT/records`` of the second evaluation set, whose label is
    ``second`` (its file's stem): the label itself, or ``<second>_second`` when it equals the
    evaluation set's label ``main``, so neither set's records overwrite the other's."""
    return f"{second}_second" if second == main else second


def restore_records(out: Path, run_folders: dict[str, Path], skip_seeds: range) -> list[Path]:
    """Rebuild from ``OUT/records`` what the tables of a part read: for every evaluation of
    set label L (``run_folders``: {L: the folder its runs go to, e.g. OUT/runs}) of a seed
    not in ``skip_seeds`` (the part's own, which it evaluates anew), the run folder with the
    compressed records; each student's ``models/<arm>_s<seed>/manifest.json``; each seed's
    ``replay/s<seed>/table.md``; ``stages.json``. Existing files are kept. Returns the run
    folders restored."""
    src = out / "records"
    if not src.is_dir():
        return []
    _copy_new(src / "stages.json", out / "stages.json")

    def earlier(path: Path) -> bool:  # an entry of a seed of an earlier part
        return _seed(path) is not None and _seed(path) not in skip_seeds

    restored = []
    for label, folder in run_folders.items():
        for saved in sorted(p for p in (src / label).glob("*_s*") if p.is_dir() and earlier(p)):
            run = folder / saved.name
            if not all((saved / f"{n}.gz").is_file() for n in ARCHIVED) or any(stored(run / n) for n in ARCHIVED):
                continue  # an incomplete record, or an evaluation this output folder already holds
            for name in ARCHIVED:
                _copy_new(saved / f"{name}.gz", run / f"{name}.gz")
            restored.append(run)
    for manifest in filter(earlier, sorted((src / "models").glob("*_s*.json"))):
        _copy_new(manifest, out / "models" / manifest.stem / "manifest.json")
    for table in filter(earlier, sorted((src / "replay").glob("s*.md"))):
        _copy_new(table, out / "replay" / table.stem / "table.md")
    return restored


def _seed(path: Path) -> int | None:
    """The seed a records entry is of: ``<arm>_s<seed>`` (a run folder or a manifest) or
    ``s<seed>`` (a replay table); None for another name."""
    m = re.fullmatch(r"(?:.+_)?s(\d+)", path.stem if path.suffix in (".json", ".md") else path.name)
    return int(m[1]) if m else None


def _pack(src: Path, dest: Path) -> None:
    """``src`` gzip-compressed to ``dest``; when only ``src.gz`` exists, its bytes."""
    found = stored(src)
    if found is None:
        raise FileNotFoundError(2, "No such file (nor a .gz of it)", str(src))
    if found == src:
        gzip_copy(src, dest)
    else:
        shutil.copyfile(found, dest)


def _copy_new(src: Path, dest: Path) -> None:
    """Copy ``src`` to ``dest`` unless ``src`` is missing or ``dest`` exists."""
    if src.is_file() and not dest.exists():
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dest)
