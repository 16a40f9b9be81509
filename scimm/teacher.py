"""Teacher signals of a dataset (docs/design.md §6.4, paper §III.2): run the Fixed-IMM or the SC-IMM over
every episode and write the path teacher P^T, speed teacher V^T and mode posterior mu^T.

Per episode: observations z_t = pathspeed.observe(labels of frame t) (paper eq. 2-3); cues
s_t (scimm.cues) give A(s_t), gamma(s_t) (scimm.modes; Fixed-IMM: A = 0, gamma = 1), turned
into Pi_t, Q_t by scimm.scene.conditioned (paper eq. 8-9; Pi_t, Q_t govern the step t-1 -> t);
the recorded poses give the ego's motion from frame t-1 to t, the known input that carries
the state into frame t's ego frame (scimm.ego, docs/design.md §6.2); scimm.imm.imm_filter gives the
fused state x_t^T (paper eq. 7) and mu_t; the teacher labels are
pathspeed.state_path(x_t^T) and pathspeed.state_speeds(x_t^T). Every mode starts at the
first observation with covariance P0. With ``IMMConfig.path_state == "plan"`` the path part
of z_t is instead the change of the expert's plan from frame t-1's, the known input rebases
and carries the state along that plan, and the path teacher is the plan moved by the
filter's correction (scimm.planref).

Methods: ``fixed`` (Fixed-IMM), ``scimm`` (SC-IMM), ``smoother`` (the SC-IMM forward pass
followed by the fixed-interval IMM smoother, scimm.smoother: a non-causal offline teacher
that the paper does not have; its x_t^T and mu_t use every frame of the episode).

Episodes are batched: sorted by length, in groups of ``BATCH`` padded at the end with NaN
observations (a NaN frame is a missing measurement and never influences earlier frames).

File contract (read by the student, model/):
``DIR/teacher/<method>/<episode stem>.npz`` with float32 ``path`` (T, 20, 2) [m, ego frame],
``speed`` (T, 10) [m/s] at tau = 0.25, ..., 2.5 s, ``mu`` (T, 5) in ``modes.MODES`` order,
row k = frame k of the episode; then ``DIR/teacher/<method>/manifest.json`` (method,
parameters, dataset hash, episode count, created), written last and atomically: its
presence means the folder is complete.
"""
from __future__ import annotations

import datetime
import hashlib
import json
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from files.atomic import write_atomic
from scimm import pathspeed, planref
from scimm.cues import _SOURCE as CUE_SOURCES, CUES, cue_vector
from scimm.ego import carry_inputs, pose_change
from scimm.imm import imm_filter
from scimm.modes import IMMConfig, fixed_adjustment, scene_adjustment
from scimm.scene import conditioned
from scimm.smoother import imm_smooth

METHODS = ("fixed", "scimm", "smoother")
# what load_inputs reads of an episode, one row per frame (harness.common.npz.check_rows)
INPUT_ROWS = {"x": (), "y": (), "yaw": (), "path": (20, 2), "speed_wps": (10, 2),
              **{k: () for name in CUES for k in CUE_SOURCES[name]}}
BATCH = 16  # episodes per IMM batch


def episode_files(data: Path) -> list[Path]:
    """The dataset's episode files, sorted by name; BadInput if one has no record
    (harness.expert.dataset.episode_files)."""
    from harness.expert.dataset import episode_files as recorded
    return recorded(Path(data))


def dataset_fingerprint(files: Sequence[Path]) -> str:
    """sha1 over the episode names and sizes: changes when the dataset is re-collected (a
    cheap check written to the teacher manifest as ``dataset_hash``; the student's cache
    and manifest hash the files' bytes, model.cache.dataset_hash)."""
    h = hashlib.sha1()
    for f in files:
        h.update(f"{f.name}:{f.stat().st_size};".encode())
    return h.hexdigest()


def load_inputs(file: Path, path_state: str = IMMConfig.path_state
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(z (T, 5) observations, s (T, 16) cues, pose (T, 3) world x, y [m], yaw [rad], the
    expert's path (T, 20, 2) [m, ego frame]) of one episode file. z's path part is that of
    ``path_state`` (scimm.modes.IMMConfig): the heading quadratic of each path ("ego") or
    the change of the plan from the previous frame's ("plan", scimm.planref)."""
    from harness.expert.dataset import read_episode  # pulls OpenCV and the nets: imported where used
    a = read_episode(file, INPUT_ROWS)
    pose = np.stack([a["x"], a["y"], a["yaw"]], axis=-1).astype(float)
    z = pathspeed.observe(a["path"], a["speed_wps"])
    if path_state == "plan":
        z[:, :3] = planref.plan_change(a["path"], pose)[0]
    return z, cue_vector(a), pose, np.asarray(a["path"], dtype=float)


def run_imm(z: np.ndarray, s: np.ndarray, method: str, cfg: IMMConfig, pose: np.ndarray | None = None,
            lengths: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Fused states x^T (B, T, 5) and mode posteriors mu (B, T, 5) of B padded sequences:
    observations z (B, T, 5) (NaN rows = missing), cues s (B, T, 16), ego poses (B, T, 3)
    (world x, y [m], yaw [rad]; None = no ego-motion compensation) and the real frames per
    sequence, lengths (B,) (the smoother starts each backward pass there; default T)."""
    B, T, _ = z.shape
    if method in ("scimm", "smoother"):
        A, gamma = scene_adjustment(s, cfg)
    elif method == "fixed":
        A, gamma = fixed_adjustment((B, T))
    else:
        raise ValueError(f"unknown method {method!r} (one of {', '.join(METHODS)})")
    Q0, R, P0 = cfg.noise()
    Pi, Q = conditioned(cfg.Pi0, Q0, A, gamma)
    first = np.nan_to_num(z[:, 0])
    x0 = np.broadcast_to(first[:, None, :], (B, 5, 5)).copy()
    P0 = np.broadcast_to(P0, (5, 5, 5)).copy()
    move = {}
    if pose is not None:
        d, dyaw = (np.array(v) for v in zip(*(pose_change(*p.T) for p in np.asarray(pose, dtype=float))))
        if cfg.path_state == "plan":
            move = dict(zip(("carry", "shift"), planref.known_input(z[..., :3], d)))
        else:
            move = dict(zip(("carry", "shift"), carry_inputs(d, dyaw)))
    res = imm_filter(z, cfg.F, Q, R, x0, P0, Pi, cfg.mu0, keep_P_modes=method == "smoother", **move)
    if method == "smoother":
        sm = imm_smooth(res, cfg.F, Q, Pi, lengths=lengths, **move)
        return sm.x, sm.mu
    return res.x, res.mu


def teach(files: Sequence[Path], method: str, cfg: IMMConfig,
          progress: Callable[[int], None] | None = None) -> dict[str, dict[str, np.ndarray]]:
    """Teacher labels {episode stem: {"path", "speed", "mu"}} (float32, contract shapes) of
    the episode files, computed in length-sorted batches; ``progress(n)`` after each batch."""
    inputs = {f.stem: load_inputs(f, cfg.path_state) for f in files}
    stems = sorted(inputs, key=lambda k: len(inputs[k][0]))
    out = {}
    for lo in range(0, len(stems), BATCH):
        group = stems[lo:lo + BATCH]
        T = max(len(inputs[k][0]) for k in group)
        z = np.full((len(group), T, 5), np.nan)
        s = np.zeros((len(group), T, inputs[group[0]][1].shape[1]))
        pose = np.zeros((len(group), T, 3))
        lengths = np.array([len(inputs[k][0]) for k in group])
        for b, k in enumerate(group):
            n = lengths[b]
            z[b, :n], s[b, :n], pose[b, :n] = inputs[k][:3]
            pose[b, n:] = pose[b, n - 1] if n else 0.0  # padding stands still
        x, mu = run_imm(z, s, method, cfg, pose, lengths)
        for b, k in enumerate(group):
            n = len(inputs[k][0])
            if cfg.path_state == "plan":
                path = planref.teacher_path(inputs[k][3], x[b, :n, :3], z[b, :n, :3])
            else:
                path = pathspeed.state_path(x[b, :n])
            out[k] = {"path": path.astype(np.float32),
                      "speed": pathspeed.state_speeds(x[b, :n]).astype(np.float32),
                      "mu": mu[b, :n].astype(np.float32)}
        if progress:
            progress(len(group))
    return out


def write_teacher(data: Path, method: str, labels: dict[str, dict[str, np.ndarray]], cfg: IMMConfig,
                  files: Sequence[Path]) -> Path:
    """Write ``DIR/teacher/<method>/`` (one npz per episode, then manifest.json last)."""
    folder = Path(data) / "teacher" / method
    folder.mkdir(parents=True, exist_ok=True)
    manifest = folder / "manifest.json"
    if manifest.exists():
        manifest.unlink()  # the folder is incomplete until the new manifest is written
    for stem, arrays in labels.items():
        def write(tmp: Path, arrays=arrays) -> None:
            with open(tmp, "wb") as fh:
                np.savez(fh, **arrays)
        write_atomic(folder / f"{stem}.npz", write)
    meta = {"method": method, "modes": ["Cruise", "Turn", "Deceleration", "Avoidance", "Recovery"],
            "ego_motion_compensated": True, "causal": method != "smoother",
            "episodes": len(files), "dataset_hash": dataset_fingerprint(files),
            "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "parameters": cfg.as_dict()}
    write_atomic(manifest, json.dumps(meta, indent=1))
    return folder


def is_complete(data: Path, method: str) -> bool:
    """True if ``DIR/teacher/<method>/manifest.json`` exists (the folder is complete)."""
    return (Path(data) / "teacher" / method / "manifest.json").is_file()


def load_teacher(data: Path, method: str, stem: str) -> dict[str, np.ndarray]:
    """The teacher arrays of one episode (contract shapes)."""
    from harness.common.npz import read_npz
    return read_npz(Path(data) / "teacher" / method / f"{stem}.npz", "teacher file",
                    f"run 'sumo-scimm teacher --data {data} --method {method}' again")

