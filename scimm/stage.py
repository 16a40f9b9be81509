"""The teacher stage as functions: a dataset folder in, teacher labels and the paper's
Table 2 files out (docs/design.md §6). ``sumo-scimm teacher`` and ``sumo-scimm reproduce`` call them.

    DIR/teacher/<method>/          labels of each method (scimm.teacher's file contract)
    DIR/teacher/table2.csv         paper Table 2, groups = dominant SC-IMM mode
    DIR/teacher/table2_moving.csv  the same over the frames where the expert moved
    DIR/teacher/mode_meaning.csv   frames of each labelled situation whose dominant mode means it
    DIR/teacher/fit_residuals.csv  fit residual of the observation per dominant mode (docs/design.md §6.1)
    DIR/teacher/lag.csv            alignment offset of v(0) and c0 per mode and teacher (scimm.lag)
    DIR/teacher/standstill.csv     teacher speed where the expert stands; mode switches per minute
    DIR/teacher/stops_starts.csv   label speeds 1.25 s and 2.5 s ahead at red lights and starts (scimm.lag)
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from files.atomic import write_atomic
from harness.common.errors import BadInput
from harness.common.progress import progress
from scimm import pathspeed
from scimm import teacher as tch
from scimm.lag import lag_tables, stops_starts
from scimm.modes import IMMConfig
from scimm.table2 import fit_residuals, mode_meaning, situations, table2

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


def make_teachers(folder: Path, files: list[Path], methods: tuple[str, ...],
                  path_state: str = IMMConfig.path_state) -> dict[str, Path]:
    """Run each teacher of ``methods`` over the episodes with the path state ``path_state``
    ("plan" or "ego", scimm.modes.IMMConfig; default the config's) and write its folder;
    returns them."""
    cfg = IMMConfig(path_state=path_state)
    written = {}
    for method in methods:
        with progress(total=len(files), desc=f"teacher {method}", unit="episode") as bar:
            labels = tch.teach(files, method, cfg, progress=bar.update)
        written[method] = tch.write_teacher(folder, method, labels, cfg, files)
        log.info("%s: %d episodes -> %s", method, len(labels), written[method])
    return written


def write_tables(folder: Path, files: list[Path]) -> dict[str, pd.DataFrame]:
    """Table 2, the mode-meaning check, the fit residuals and the lag figures of a dataset
    whose teachers (``teacher.METHODS``) are complete, each written to
    ``folder/teacher/<name>.csv``; returns them by name (``evaluate`` below)."""
    tables = evaluate(folder, files, tch.METHODS)
    for name, df in tables.items():
        write_atomic(folder / "teacher" / f"{name}.csv", lambda tmp, df=df: df.to_csv(tmp, index=False))
    return tables


def evaluate(data: Path, files: list[Path], methods: tuple[str, ...] = tch.METHODS) -> dict[str, pd.DataFrame]:
    """{"table2", "table2_moving", "mode_meaning", "fit_residuals", "lag", "standstill", "stops_starts"}: Table 2, the
    mode-meaning table, the fit residuals per mode (scimm.table2) and the lag figures
    (scimm.lag) of the episode files against their written teachers
    ``data/teacher/<method>/`` (scimm.teacher file contract; ``methods`` must include scimm,
    whose posterior groups the frames); each file is read once."""
    from harness.expert.dataset import read_episode  # pulls OpenCV and the nets: imported where used
    episodes, sits, fits = [], [], []
    for f in files:
        a = read_episode(f, {**tch.INPUT_ROWS, "v": (), "target_speed": ()})
        ep = {"raw": {"path": a["path"], "speed": pathspeed.label_speeds(a["speed_wps"])},
              "pose": np.stack([a["x"], a["y"], a["yaw"]], axis=-1), "v": a["v"],
              "light": a["flag_light"], "travel": np.linalg.norm(a["speed_wps"][:, -1], axis=-1)}
        ep.update({m: tch.load_teacher(data, m, f.stem) for m in methods})
        sits.append(situations(a))
        fits.append({"path": a["path"], "speed_wps": a["speed_wps"], "mu": ep["scimm"]["mu"]})
        episodes.append(ep)
    mus = {m: [ep[m]["mu"] for ep in episodes] for m in methods}
    align, still = lag_tables(episodes, methods)
    return {"table2": table2(episodes, ("raw", *methods)),
            "table2_moving": table2(episodes, ("raw", *methods), moving_only=True), "mode_meaning": mode_meaning(sits, mus),
            "fit_residuals": fit_residuals(fits), "lag": align, "standstill": still,
            "stops_starts": stops_starts(episodes, methods)}
