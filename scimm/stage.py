"""The teacher stage as functions: a dataset folder in, teacher labels and the paper's
Table 2 files out (SPEC §6). ``sumo-scimm teacher`` and ``sumo-scimm reproduce`` call them.

    DIR/teacher/<method>/          labels of each method (scimm.teacher's file contract)
    DIR/teacher/table2.csv         paper Table 2, groups = dominant SC-IMM mode
    DIR/teacher/mode_meaning.csv   frames of each labelled situation whose dominant mode means it
    DIR/teacher/fit_residuals.csv  fit residual of the observation per dominant mode (SPEC §6.1)
"""
from __future__ import annotations

import logging
from pathlib import Path

import pandas as pd
from tqdm import tqdm

from harness.common.atomic import write_atomic
from harness.common.errors import BadInput
from scimm import teacher as tch
from scimm.modes import IMMConfig

log = logging.getLogger(__name__)


def dataset_episodes(data: str | Path | None) -> tuple[Path, list[Path]]:
    """(folder, its episode files) of a dataset made by ``sumo-scimm collect``; BadInput if none."""
    if not data:
        raise BadInput("--data DIR is required (a dataset folder made by 'sumo-scimm collect')")
    folder = Path(data)
    files = tch.episode_files(folder) if (folder / "episodes").is_dir() else []
    if not files:
        raise BadInput(f"{folder} is not a dataset folder (no episodes/*.npz; make one with 'sumo-scimm collect')")
    return folder, files


def make_teachers(folder: Path, files: list[Path], methods: tuple[str, ...]) -> dict[str, Path]:
    """Run each teacher of ``methods`` over the episodes and write its folder; returns them."""
    cfg = IMMConfig()
    written = {}
    for method in methods:
        with tqdm(total=len(files), desc=f"teacher {method}", unit="episode", disable=None) as bar:
            labels = tch.teach(files, method, cfg, progress=bar.update)
        written[method] = tch.write_teacher(folder, method, labels, cfg, files)
        log.info("%s: %d episodes -> %s", method, len(labels), written[method])
    return written


def write_tables(folder: Path, files: list[Path]) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """Table 2, the mode-meaning check and the fit residuals of a dataset whose fixed and
    scimm teachers are complete, written under ``folder/teacher``; returns the three tables."""
    from scimm.table2 import evaluate
    table, meaning, residuals = evaluate(folder, files)
    for name, df in (("table2", table), ("mode_meaning", meaning), ("fit_residuals", residuals)):
        write_atomic(folder / "teacher" / f"{name}.csv", lambda tmp, df=df: df.to_csv(tmp, index=False))
    return table, meaning, residuals
