"""IMM throughput for ``sumo-scimm bench`` (SPEC §11): frames per second of the batched
5-mode / 5-state IMM in one process, beside filterpy's IMMEstimator on the same
sequences (if filterpy is installed; it is a test-only dependency), and their agreement."""
from __future__ import annotations

import time

import numpy as np

from scimm.imm import imm_filter


def _system(rng: np.random.Generator, m: int = 5, n: int = 5):
    F = np.eye(n) + 0.05 * rng.normal(size=(m, n, n))
    Q = np.stack([0.05 * np.eye(n) * (j + 1) for j in range(m)])
    R = 0.2 * np.eye(n)
    Pi = np.full((m, m), 0.02) + np.eye(m) * (1 - 0.02 * m)
    Pi[0, 1] += 0.01
    Pi[0, 0] -= 0.01  # not symmetric
    return F, Q, R, Pi, np.full(m, 1.0 / m), np.stack([np.eye(n)] * m)


def run_imm_bench(batch: int = 2000, frames: int = 50, filterpy_sequences: int = 20) -> dict:
    rng = np.random.default_rng(0)
    F, Q, R, Pi, mu0, P0 = _system(rng)
    z = np.cumsum(rng.normal(size=(batch, frames, 5)), axis=1)
    x0 = np.zeros((batch, 5, 5))
    imm_filter(z[:10], F, Q, R, x0[:10], P0, Pi, mu0)  # warm-up
    t0 = time.perf_counter()
    res = imm_filter(z, F, Q, R, x0, P0, Pi, mu0)
    ours = batch * frames / (time.perf_counter() - t0)
    out = {"imm_frames_per_s": round(ours), "imm_target": 100_000}
    try:
        from filterpy.kalman import IMMEstimator, KalmanFilter
    except ImportError:
        out.update(filterpy_frames_per_s=None, imm_over_filterpy=None, max_abs_diff=None)
        return out
    t0 = time.perf_counter()
    worst = 0.0
    for b in range(filterpy_sequences):
        filters = []
        for j in range(5):
            kf = KalmanFilter(dim_x=5, dim_z=5)
            kf.F, kf.Q, kf.R, kf.H, kf.x, kf.P = F[j], Q[j], R, np.eye(5), x0[b, j].copy(), P0[j].copy()
            filters.append(kf)
        imm = IMMEstimator(filters, mu0.copy(), Pi)
        for t in range(frames):
            imm.predict()
            imm.update(z[b, t])
            worst = max(worst, float(np.max(np.abs(np.ravel(imm.mu) - res.mu[b, t]))))
    theirs = filterpy_sequences * frames / (time.perf_counter() - t0)
    out.update(filterpy_frames_per_s=round(theirs), imm_over_filterpy=round(ours / theirs, 1),
               max_abs_diff=worst)
    return out


def format_imm_bench(r: dict) -> str:
    lines = ["teacher (5-mode, 5-state IMM, one process):",
             f"  IMM                   {r['imm_frames_per_s']:10d} frames/s  (target >= {r['imm_target']})"]
    if r.get("filterpy_frames_per_s"):
        lines.append(f"  filterpy IMMEstimator {r['filterpy_frames_per_s']:10d} frames/s  "
                     f"-> {r['imm_over_filterpy']} x (target >= 30 x); max |mu diff| {r['max_abs_diff']:.1e}")
    else:
        lines.append("  filterpy IMMEstimator  not installed (pip install filterpy) - no reference")
    return "\n".join(lines)
