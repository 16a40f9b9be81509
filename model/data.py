"""Training samples: a ``collect`` folder's cached BEVs and labels, plus optional teacher files.

Teacher file contract (written by ``sumo-scimm teacher``)::

    DIR/teacher/<method>/<episode stem>.npz   float32 path (T, 20, 2) ego frame [m],
                                              speed (T, 10) [m/s] at tau 0.25..2.5 s,
                                              mu (T, 5) [Cruise, Turn, Deceleration, Avoidance, Recovery]
    DIR/teacher/<method>/manifest.json        present = the method's files are complete

Row k is frame k of ``DIR/episodes/<stem>.npz``. A baseline (no teacher) never opens
``DIR/teacher``.

The loss-matched control (teacher ``control``) has no files either: its "teacher" is the
expert itself, built per batch in the sample's label frame, so it differs from a teacher
arm only in the content of the targets: teacher_path = the expert path, teacher_speed =
phi(expert speed waypoints, origin) (paper eq. 12, model.loss.phi), mu = uniform 1/5. The
uniform posterior is the constant that carries no information (the largest entropy; no
frame is told any mode), needs no teacher to compute, and is reached by constant logits,
so the mode head can satisfy it without shaping the shared representation.

Augmentation and teachers: a sample is either view 0 (as recorded) or an augmented view
(model.cache: viewpoint shifted ``shift`` m left and turned ``rot`` rad). The expert labels
of each view come from the cache; the path teacher is moved by the same rigid transform
(``move``, the transform of harness.expert.dataset.Episode.labels); the speed teacher and the mode
posterior do not depend on the viewpoint and are kept. The speeds of eq. 12 start from
``origin`` = move((0, 0)), the ego's true position in the view's frame, so phi of the
expert's own speed waypoints stays its true speed profile under augmentation.

Route-end augmentation (``cut``): the harness's routes end, the recorded episodes do not
show it (an episode stops about 10 m before the end and its last 2.5 s are dropped), so a
student never saw the ROUTE channel end ahead of it nor a close target point, and stops
there. A cut sample has the ROUTE channel erased beyond ``cut`` metres ahead and, if the
target point is farther, the target point moved onto the expert path at ``cut`` metres;
its labels are unchanged (the expert drives on).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from harness.sensors.bev import EGO_ROW, RES, ROUTE
from harness.common.errors import BadInput
from harness.common.npz import read_npz
from model import cache as bevcache
from model.loss import phi
from scimm.teacher import episode_files

TEACHER_METHODS = ("fixed", "scimm", "smoother")  # teachers with files (DIR/teacher/<method>)
CONTROL = "control"  # the loss-matched control: the expert's own labels as the teacher
TEACHERS = (CONTROL, *TEACHER_METHODS)  # what a training's --teacher accepts besides none
CONTROL_MU = 1.0 / 5  # the control's mode target, every one of the five modes


def move(points: np.ndarray, shift: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """Points (B, ..., 2) of an ego frame expressed in that frame moved ``shift`` (B,) m to
    the left and turned ``rot`` (B,) rad: p' = R(-rot) (p - (0, shift))."""
    extra = (slice(None),) + (None,) * (points.ndim - 2)
    c, s = np.cos(rot)[extra], np.sin(rot)[extra]
    x, y = points[..., 0], points[..., 1] - shift[extra]
    return np.stack([c * x + s * y, -s * x + c * y], axis=-1)


def check_dataset(folder: Path) -> list[Path]:
    """The folder's episode files; BadInput if it is not a non-empty collect folder."""
    files = episode_files(folder)
    if not files:
        raise BadInput(f"{folder} holds no episodes (expected {folder}/episodes/*.npz; make them with "
                       f"'sumo-scimm collect --routes train --out {folder}')")
    return files


def check_teacher(folder: Path, method: str) -> Path:
    """The method's teacher folder; BadInput unless it is complete (has manifest.json)."""
    tdir = Path(folder) / "teacher" / method
    if not (tdir / "manifest.json").is_file():
        raise BadInput(f"no complete '{method}' teacher in {tdir} (manifest.json missing): run "
                       f"'sumo-scimm teacher --data {folder}' first")
    return tdir


def load_teacher(folder: Path, method: str, stems: list[str], lengths: list[int]) -> dict[str, np.ndarray]:
    """Teacher arrays of every frame, in cache order: path (N, 20, 2), speed (N, 10), mu (N, 5)."""
    tdir = check_teacher(folder, method)
    parts: dict[str, list] = {"path": [], "speed": [], "mu": []}
    shapes = {"path": (20, 2), "speed": (10,), "mu": (5,)}
    for stem, n in zip(stems, lengths):
        f = tdir / f"{stem}.npz"
        arrays = read_npz(f, "teacher file", "rerun 'sumo-scimm teacher'", tuple(shapes))
        for k, shape in shapes.items():
            if arrays[k].dtype.kind not in "biuf":
                raise BadInput(f"teacher file {f}: '{k}' holds {arrays[k].dtype} values, not numbers: "
                               "rerun 'sumo-scimm teacher'")
            arrays[k] = arrays[k].astype(np.float32)
            if arrays[k].shape != (n, *shape) or not np.isfinite(arrays[k]).all():
                raise BadInput(f"teacher file {f}: '{k}' has shape {arrays[k].shape} or non-finite values, "
                               f"expected {(n, *shape)} finite (one row per frame): rerun 'sumo-scimm teacher'")
            parts[k].append(arrays[k])
    return {k: np.concatenate(v) for k, v in parts.items()}


@dataclass
class StudentData:
    """Every frame of one dataset, ready to batch. ``views`` = 1 (no augmentation) or more."""

    arrays: dict[str, np.ndarray]  # model.cache arrays
    teacher: dict[str, np.ndarray] | None
    digest: str  # dataset hash
    folder: Path
    control: bool = False  # teacher targets from the expert's own labels (CONTROL)

    @classmethod
    def load(cls, folder: Path, cache_dir: Path, views: int, teacher: str | None = None,
             workers: int = 2) -> "StudentData":
        """Build or load the cache; load the teacher files if ``teacher`` names a method
        of TEACHER_METHODS (CONTROL opens none)."""
        folder = Path(folder)
        check_dataset(folder)
        control = teacher == CONTROL
        teacher = None if control else teacher
        if teacher is not None:
            check_teacher(folder, teacher)  # before minutes of rendering
        digest = bevcache.dataset_hash(folder)
        arrays = bevcache.load_cache(bevcache.build_cache(folder, cache_dir, views, workers, digest))
        t = None
        if teacher is not None:
            stems = [str(s) for s in arrays["stems"]]
            lengths = np.bincount(arrays["episode"], minlength=len(stems)).tolist()
            t = load_teacher(folder, teacher, stems, lengths)
        return cls(arrays, t, digest, folder, control)

    def __len__(self) -> int:
        return len(self.arrays["speed"])

    @property
    def views(self) -> int:
        return self.arrays["bev"].shape[1]

    def staying(self) -> np.ndarray:
        """(N,) bool: the ego stands (< 0.1 m/s) and is still within 0.5 m 2.5 s later."""
        final = np.hypot(*self.arrays["speed_wps"][:, 0, -1].T)
        return (self.arrays["speed"] < 0.1) & (final < 0.5)

    def departing(self) -> np.ndarray:
        """(N,) bool: the ego stands (< 0.1 m/s) and has moved 0.5 m or more 2.5 s later."""
        return (self.arrays["speed"] < 0.1) & ~self.staying()

    def stop_sign(self) -> np.ndarray:
        """(N,) bool: the expert's stop-sign cause is active (its ``flag_stop``)."""
        return self.arrays["stop"]

    def batch(self, idx: np.ndarray, view: np.ndarray, cut: np.ndarray | None = None) -> dict[str, torch.Tensor]:
        """Samples idx (B,) seen from view (B,), route cut at cut (B,) m ahead (0 = no cut):
        model inputs, expert labels, teacher labels.

        bev (B, 9, 64, 64) float {0, 1} (channels-last memory); target_point (B, 2), path
        (B, 20, 2), speed_wps (B, 10, 2), origin (B, 2) [m] in the view's ego frame; speed (B,) [m/s]; with a
        teacher (or the control) also teacher_path (B, 20, 2) [m], teacher_speed (B, 10) [m/s], mu (B, 5).
        """
        a = self.arrays
        bev = bevcache.unpack(a["bev"][idx, view])  # (B, 9, 64, 64)
        tp = a["target_point"][idx, view].copy()  # (B, 2)
        for i in np.flatnonzero(cut) if cut is not None else ():
            bev[i, ROUTE, :max(0, int(np.ceil(EGO_ROW - cut[i] / RES)))] = 0  # rows more than cut m ahead
            if np.hypot(*tp[i]) > cut[i]:
                tp[i] = a["path"][idx[i], view[i], min(int(round(cut[i])), 19)]  # path points are 1 m apart
        # channels-last memory, the layout model.network.BevEncoder runs on; changed on the
        # uint8 array, where it costs least
        bev_t = torch.from_numpy(bev).contiguous(memory_format=torch.channels_last).float()
        out = {"bev": bev_t, "speed": torch.from_numpy(a["speed"][idx]),
               "target_point": torch.from_numpy(tp)}
        for k in ("path", "speed_wps"):
            out[k] = torch.from_numpy(a[k][idx, view])
        shift, rot = a["aug"][idx, view, 0], a["aug"][idx, view, 1]
        out["origin"] = torch.from_numpy(move(np.zeros((len(idx), 2)), shift, rot).astype(np.float32))
        if self.control:  # the expert's own labels, in the same (augmented) frame
            out["teacher_path"] = out["path"].clone()
            out["teacher_speed"] = phi(out["speed_wps"], out["origin"])  # the expert's own speeds
            out["mu"] = torch.full((len(idx), 5), CONTROL_MU)
        elif self.teacher is not None:
            out["teacher_path"] = torch.from_numpy(move(self.teacher["path"][idx], shift, rot).astype(np.float32))
            out["teacher_speed"] = torch.from_numpy(self.teacher["speed"][idx])
            out["mu"] = torch.from_numpy(self.teacher["mu"][idx])
        return out

