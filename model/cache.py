"""Pre-rendered, bit-packed BEVs and labels of a dataset, built once and shared by trainings.

Rendering a stored frame costs about 1 ms (harness.expert.dataset.Episode.bev), as much as a
training step spends on a sample, so every frame is rendered once into a cache:

- the student sees the BEV binarised (``binarize``: a pixel is on when its value is >=
  BEV_THRESHOLD), so each of the 9 x 64 x 64 pixels is one bit: 4,608 bytes per frame
  (about 300 MB per view for 67k frames). The agent binarises its live BEV with the same
  function, so closed loop and training see the same input. Traffic lights: red (255) and
  yellow (128) both become "on", as the expert stops for either.
- view 0 is the frame as recorded; views 1.. are augmented: the viewpoint moved ``shift`` m
  to the left and turned ``rot`` rad (Episode.bev / Episode.labels), drawn uniformly from
  +-MAX_SHIFT, +-MAX_ROT with a generator seeded by (AUG_SEED, episode name), so the cache
  is the same whoever builds it and however many workers render it.
- labels (path, speed waypoints, target point) of every view, in that view's ego frame
  (x forward, y left) [m], the augmentation (shift, rot) of every view, the ego speed and
  the expert's stop-sign flag (model.train's data balance).

Cache file: ``CACHE_DIR/<dataset hash[:16]>_v<views>_c<CACHE_VERSION>.npz`` (written whole or not at
all, files.atomic). The dataset hash covers every episode file's name and bytes.
"""
from __future__ import annotations

import hashlib
import multiprocessing as mp
import zlib
from pathlib import Path

import numpy as np

from files.atomic import write_atomic
from harness.common.progress import progress
from scimm.teacher import episode_files

BEV_SHAPE = (9, 64, 64)  # harness.sensors.bev: (channels, rows, columns)
BEV_THRESHOLD = 64  # uint8 level at and above which a BEV pixel is "on"
PACKED_BYTES = int(np.prod(BEV_SHAPE)) // 8
AUG_SEED = 0  # fixed: the cache (and so the augmented views) is shared by every training
MAX_SHIFT = 1.0  # [m] lateral viewpoint shift, uniform in +-MAX_SHIFT
MAX_ROT = np.deg2rad(10.0)  # [rad] viewpoint rotation, uniform in +-MAX_ROT
CACHE_VERSION = 3  # bump when the cache layout or the rendering changes


def binarize(bev: np.ndarray) -> np.ndarray:
    """(..., 9, 64, 64) uint8 BEV -> bool of the same shape (on at >= BEV_THRESHOLD)."""
    return bev >= BEV_THRESHOLD


def pack(bev: np.ndarray) -> np.ndarray:
    """(..., 9, 64, 64) uint8 BEV -> (..., 4608) uint8 bits."""
    b = binarize(bev)
    return np.packbits(b.reshape(*b.shape[:-3], -1), axis=-1)


def unpack(packed: np.ndarray) -> np.ndarray:
    """(..., 4608) uint8 bits -> (..., 9, 64, 64) uint8 in {0, 1}."""
    return np.unpackbits(packed, axis=-1).reshape(*packed.shape[:-1], *BEV_SHAPE)


def dataset_hash(folder: Path) -> str:
    """sha256 hex over every episode file's name and bytes, in name order."""
    h = hashlib.sha256()
    for f in episode_files(folder):
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def augmentation(stem: str, n_frames: int, views: int) -> np.ndarray:
    """(n_frames, views, 2) (shift [m], rot [rad]) per frame and view; view 0 is (0, 0)."""
    rng = np.random.default_rng([AUG_SEED, zlib.crc32(stem.encode())])
    aug = np.zeros((n_frames, views, 2))
    for v in range(1, views):
        aug[:, v, 0] = rng.uniform(-MAX_SHIFT, MAX_SHIFT, n_frames)
        aug[:, v, 1] = rng.uniform(-MAX_ROT, MAX_ROT, n_frames)
    return aug


def render_episode(path: str, views: int) -> dict[str, np.ndarray]:
    """Packed BEVs and labels of every frame and view of one episode file."""
    from harness.expert.dataset import Episode  # pulls OpenCV and the nets: only where rendering happens
    ep = Episode(Path(path))
    n = len(ep)
    aug = augmentation(ep.path.stem, n, views)
    out = {"bev": np.zeros((n, views, PACKED_BYTES), np.uint8), "aug": aug,
           "path": np.zeros((n, views, 20, 2), np.float32), "speed_wps": np.zeros((n, views, 10, 2), np.float32),
           "target_point": np.zeros((n, views, 2), np.float32), "speed": ep.a["v"].astype(np.float32),
           "stop": ep.a["flag_stop"].astype(bool)}
    for k in range(n):
        for v in range(views):
            shift, rot = float(aug[k, v, 0]), float(aug[k, v, 1])
            out["bev"][k, v] = pack(ep.bev(k, shift, rot))
            for name, arr in ep.labels(k, shift, rot).items():
                out[name][k, v] = arr
    return out


def cache_path(folder: Path, cache_dir: Path, views: int, digest: str | None = None) -> Path:
    digest = digest or dataset_hash(folder)
    return Path(cache_dir) / f"{digest[:16]}_v{views}_c{CACHE_VERSION}.npz"


def build_cache(folder: Path, cache_dir: Path, views: int, workers: int = 2, digest: str | None = None) -> Path:
    """Render every frame of the dataset in ``folder`` (``views`` views each) into the cache
    unless it is there; returns the cache file."""
    folder = Path(folder)
    out = cache_path(folder, cache_dir, views, digest)
    if out.is_file():
        return out
    files = episode_files(folder)
    parts = []
    jobs = [(str(f), views) for f in files]
    desc = f"BEV cache {folder.name} ({views} view{'s' * (views > 1)})"
    if workers > 1:
        with mp.get_context("spawn").Pool(workers) as pool:
            for part in progress(pool.imap(_render_job, jobs), total=len(jobs), desc=desc, unit="episode"):
                parts.append(part)
    else:
        parts = [_render_job(j) for j in progress(jobs, desc=desc, unit="episode")]
    arrays = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]} if parts else {}
    arrays["episode"] = np.concatenate([np.full(len(p["speed"]), i, np.int32) for i, p in enumerate(parts)])
    arrays["frame"] = np.concatenate([np.arange(len(p["speed"]), dtype=np.int32) for p in parts])
    arrays["stems"] = np.array([f.stem for f in files])
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, lambda tmp: _savez(tmp, arrays), shared=True)  # other workers may build it too
    return out


def _savez(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """``np.savez`` to exactly ``path`` (given a file name, numpy would append ``.npz``)."""
    with open(path, "wb") as f:
        np.savez(f, **arrays)


def _render_job(job: tuple[str, int]) -> dict[str, np.ndarray]:
    return render_episode(*job)


def load_cache(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}
