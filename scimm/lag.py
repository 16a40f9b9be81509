"""Lag figures of the teachers against the expert (docs/teacher.md, "Lag"): does a teacher
label say what the expert does at the same frame, or what it did a few frames earlier?

A single-frame student cannot see a lag, so a lagging label is label noise. Per teacher:

    alignment offset  per group of the dominant SC-IMM mode (as Table 2), for v(0) (the
                      first label speed, the mean over the next 0.25 s [m/s]) and c0 (the
                      path heading at the ego, the fitted quadratic's constant [rad],
                      scimm.pathspeed.path_coefficients): the offset k in OFFSETS [frames]
                      that minimises the mean |teacher_t - expert_(t-k)| over the group's
                      frames t. k > 0: the teacher says at t what the expert said k frames
                      earlier (a lag); 0: aligned.
    standstill        frames where the expert has stood for >= 0.5 s (its recorded speed
                      <= STOOD_SPEED at this frame and the 2 before, 4 Hz): the share whose
                      teacher v(0) <= STANDSTILL_OK, and the mean teacher v(0) there. The raw
                      labels' own figures are the reference (the expert may pull away within
                      the next 0.25 s).
    switches          changes of the dominant mode (argmax of the posterior) per minute of
                      driving, over all frames.
    stops and starts  the label speeds 1.25 s and 2.5 s ahead (k = 5 and 10 of the 10
                      label speeds) against the expert's, in two kinds of frames: braking
                      for a red light (recorded speed > MOVING_SPEED with the expert's
                      red-light cause active) and starting off (recorded speed
                      <= STOOD_SPEED and >= DEPART_TRAVEL m travelled in the next 2.5 s).
                      A causal teacher that lags brakes later than the expert in the first
                      (label above the expert's) and starts later in the second (below).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from scimm import pathspeed
from scimm.table2 import GROUPS, ROW_NAMES, STOOD_SPEED, group_of  # STOOD_SPEED: "standing" [m/s]

DT = 0.25  # frame period [s]
OFFSETS = tuple(range(-4, 5))  # frames tried for the alignment
STOOD_FRAMES = 3  # this frame and the 2 before: 0.5 s at 4 Hz
STANDSTILL_OK = 0.3  # [m/s]: a teacher v(0) at most this counts as standing
MOVING_SPEED = 0.5  # [m/s]: "moving" for the red-light frames
DEPART_TRAVEL = 0.5  # [m] in 2.5 s: "starts off" (as the student's data balance, model.data)
AHEAD = {"1.25 s": 4, "2.5 s": 9}  # label speed index of the horizons compared


def signals(path: np.ndarray, speed: np.ndarray) -> dict[str, np.ndarray]:
    """{"v0": (T,) first label speed [m/s], "c0": (T,) path heading at the ego [rad]} of a
    label sequence: path (T, 20, 2) [m], speed (T, 10) [m/s]."""
    return {"v0": np.asarray(speed, dtype=float)[:, 0], "c0": pathspeed.path_coefficients(path)[:, 0]}


def offset_errors(teacher: np.ndarray, expert: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """(len(OFFSETS), len(GROUPS), 2) sums of |teacher_t - expert_(t-k)| and frame counts,
    per offset k and group of frame t, of one episode's (T,) series."""
    out = np.zeros((len(OFFSETS), len(GROUPS), 2))
    T = len(teacher)
    for a, k in enumerate(OFFSETS):
        t = np.arange(max(k, 0), min(T, T + k))  # frames whose t - k exists
        if not len(t):
            continue
        diff = np.abs(teacher[t] - expert[t - k])
        out[a, :, 0] = np.bincount(groups[t], weights=diff, minlength=len(GROUPS))
        out[a, :, 1] = np.bincount(groups[t], minlength=len(GROUPS))
    return out


def stood(v: np.ndarray) -> np.ndarray:
    """(T,) True where the recorded speed v (T,) [m/s] is <= STOOD_SPEED at the frame and
    the STOOD_FRAMES - 1 before it."""
    still = np.asarray(v, dtype=float) <= STOOD_SPEED
    run = np.zeros(len(still), dtype=int)
    for t, s in enumerate(still):
        run[t] = run[t - 1] + 1 if s and t else int(s)
    return run >= STOOD_FRAMES


def switches(mu: np.ndarray) -> int:
    """Changes of the dominant mode in posteriors mu (T, 5)."""
    dom = np.argmax(mu, axis=-1)
    return int(np.count_nonzero(dom[1:] != dom[:-1]))


def lag_tables(episodes: Sequence[dict], methods: Sequence[str]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(alignment per group and method, standstill and switches per row) of episodes, each
    {"raw": {"path", "speed"}, <method>: {"path", "speed", "mu"}, "v": (T,) recorded speed},
    grouped by ``episodes[k]["scimm"]["mu"]``."""
    acc = {(m, s): np.zeros((len(OFFSETS), len(GROUPS), 2)) for m in methods for s in ("v0", "c0")}
    still = {r: [] for r in ("raw", *methods)}
    n_switch, frames = {m: 0 for m in methods}, 0
    for ep in episodes:
        g = group_of(ep["scimm"]["mu"])
        raw = signals(ep["raw"]["path"], ep["raw"]["speed"])
        here = stood(ep["v"])
        still["raw"].append(raw["v0"][here])
        frames += len(g)
        for m in methods:
            sig = signals(ep[m]["path"], ep[m]["speed"])
            for s in ("v0", "c0"):
                acc[(m, s)] += offset_errors(sig[s], raw[s], g)
            still[m].append(sig["v0"][here])
            n_switch[m] += switches(ep[m]["mu"])
    lines = []
    for gi, gname in enumerate(GROUPS):
        for m in methods:
            line = {"mode": gname, "method": ROW_NAMES[m], "frames": int(acc[(m, "v0")][OFFSETS.index(0), gi, 1])}
            for s in ("v0", "c0"):
                total, count = acc[(m, s)][:, gi, 0], acc[(m, s)][:, gi, 1]
                mae = np.divide(total, count, out=np.full(len(OFFSETS), np.nan), where=count > 0)
                line[f"{s}_offset"] = int(OFFSETS[int(np.nanargmin(mae))]) if np.isfinite(mae).any() else np.nan
                line[f"{s}_mae"] = float(mae[OFFSETS.index(0)])
            lines.append(line)
    align = pd.DataFrame(lines)
    minutes = frames * DT / 60.0
    rows = []
    for r, vals in still.items():
        v = np.concatenate(vals) if vals else np.zeros(0)
        rows.append({"method": ROW_NAMES[r], "stood_frames": len(v),
                     "standing_share": float(np.mean(v <= STANDSTILL_OK)) if len(v) else np.nan,
                     "stood_mean_v0": float(np.mean(v)) if len(v) else np.nan,
                     "switches_per_min": n_switch[r] / minutes if r in n_switch and minutes else np.nan})
    return align, pd.DataFrame(rows)


def stops_starts(episodes: Sequence[dict], methods: Sequence[str]) -> pd.DataFrame:
    """Per situation (``red light``, ``start``) and row (raw, then ``methods``): frames, the
    mean label speed [m/s] at each horizon of AHEAD and, for a teacher, its mean excess over
    the expert's. Episodes as lag_tables, plus "light" (T,) bool, the expert's red-light
    cause, and "travel" (T,) [m], its distance to the last speed waypoint (2.5 s ahead)."""
    rows = []
    for name in ("red light", "start"):
        picks = []
        for ep in episodes:
            v = np.asarray(ep["v"], dtype=float)
            picks.append(ep["light"] & (v > MOVING_SPEED) if name == "red light"
                         else (v <= STOOD_SPEED) & (ep["travel"] >= DEPART_TRAVEL))
        def chosen(r: str) -> np.ndarray:  # (frames, 10) label speeds of row r in the picked frames
            return np.concatenate([ep[r]["speed"][p] for ep, p in zip(episodes, picks)] or [np.zeros((0, 10))])
        raw = chosen("raw")
        for r in ("raw", *methods):
            lab = raw if r == "raw" else chosen(r)
            row = {"situation": name, "method": ROW_NAMES[r], "frames": len(lab)}
            for h, k in AHEAD.items():
                row[f"v_{h}"] = float(lab[:, k].mean()) if len(lab) else np.nan
                row[f"excess_{h}"] = float((lab[:, k] - raw[:, k]).mean()) if len(lab) else np.nan
            rows.append(row)
    return pd.DataFrame(rows)


def format_stops_starts(df: pd.DataFrame) -> str:
    """stops_starts as aligned text."""
    lines = [f"{'Situation':10} {'Method':20} {'frames':>7} {'v 1.25 s':>9} {'excess':>8} {'v 2.5 s':>8} {'excess':>8}"]
    for _, r in df.iterrows():
        lines.append(f"{r['situation']:10} {r['method']:20} {r['frames']:7d} {r['v_1.25 s']:9.2f} "
                     f"{r['excess_1.25 s']:+8.2f} {r['v_2.5 s']:8.2f} {r['excess_2.5 s']:+8.2f}")
    return "\n".join(lines)


def format_lag(align: pd.DataFrame, still: pd.DataFrame) -> str:
    """Both lag tables as aligned text."""
    lines = [f"{'Mode':19} {'Method':20} {'frames':>7} {'v(0) offset':>11} {'v(0) MAE':>9} "
             f"{'c0 offset':>9} {'c0 MAE':>9}"]
    for _, r in align.iterrows():
        lines.append(f"{r['mode']:19} {r['method']:20} {r['frames']:7d} {r['v0_offset']:11} "
                     f"{r['v0_mae']:9.4f} {r['c0_offset']:9} {r['c0_mae']:9.5f}")
    lines += ["", f"{'Method':20} {'stood >= 0.5 s':>14} {'v(0) <= 0.3 m/s':>16} {'mean v(0)':>10} "
              f"{'mode switches/min':>18}"]
    for _, r in still.iterrows():
        sw = "" if np.isnan(r["switches_per_min"]) else f"{r['switches_per_min']:.2f}"
        lines.append(f"{r['method']:20} {r['stood_frames']:14d} {100 * r['standing_share']:15.1f}% "
                     f"{r['stood_mean_v0']:10.3f} {sw:>18}")
    return "\n".join(lines)
