"""Paper Table 2 (docs/design.md §6.5): frame-to-frame variation of the raw expert labels and of the
teacher labels, grouped by the dominant SC-IMM mode; and the mode-meaning check.

Every metric is computed the same way for every row, from a label sequence of one episode:
path (T, 20, 2) [m, ego frame] at s_k = 0..19 m and speeds (T, 10) [m/s] at tau_k =
0.25..2.5 s (scimm.pathspeed: the raw expert's speeds are those of paper eq. 12). Metric
value at frame t compares frame t with t-1 (and t-2); frames without those are NaN.

    speed_delta    mean_k |v_t(tau_k) - v_t-1(tau_k)|                       [m/s]
    speed_jerk     |v_t(0) - 2 v_t-1(0) + v_t-2(0)| / dt^2                  [m/s^3]
    lat_delta      mean_k |y_t(s_k) - y_t-1(s_k)|                           [m]
    heading_delta  mean_k |psi_t(s_k) - psi_t-1(s_k)|                       [rad]
    lat_jerk       |a_lat,t - a_lat,t-1| / dt,  a_lat = v(0)^2 kappa(0)     [m/s^3]

with dt = 0.25 s. A label has no value at tau = 0 or a heading at a point, so, the same for
all rows: v(0) is the first label speed (the mean over the first 0.25 s), psi(s_k) the
heading of the chord from point k to k+1 (19 values), kappa(0) = (psi(s_1) - psi(s_0)) / 1 m.
Groups: the argmax of the SC-IMM posterior of the frame (Avoidance and Recovery merged),
the same grouping for the three rows; a group's value is the mean over its frames.

Each frame's labels are in its own ego frame, so the deltas also measure the ego's own
motion between frames (its yaw, its sideways drift, the 0.25 s the speed window slides).
``moved_metrics`` adds the three deltas with frame t-1's labels first moved into frame t
(columns ``*_moved``, from the ego poses of the episode files): a label that stays put in
the world then scores 0 (docs/teacher.md, "Caveats"). ``from_raw`` adds how far each
row's labels are from the raw expert's at the same frame (``*_from_raw``).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from scimm import pathspeed
from scimm.ego import interp_rows, previous_in_current
from scimm.modes import AVOID, DECEL, MODES, RECOVER, TURN

DT = 0.25  # frame period [s]
STOOD_SPEED = 0.1  # [m/s]: at or below, the expert stands (as scimm.lag)
METRICS = ("speed_delta", "speed_jerk", "lat_delta", "heading_delta", "lat_jerk")
DISPLAY = {"speed_delta": "Speed delta [m/s]", "speed_jerk": "Speed jerk [m/s^3]", "lat_delta": "Lat delta [m]",
           "heading_delta": "Heading delta [rad]", "lat_jerk": "Lat jerk [m/s^3]"}
GROUPS = ("Cruise", "Turn", "Deceleration", "Avoidance/Recovery")
ROWS = ("raw", "fixed", "scimm", "smoother")
ROW_NAMES = {"raw": "Original Raw Expert", "fixed": "Fixed-IMM", "scimm": "SC-IMM", "smoother": "IMM smoother"}
# situation of harness.expert.dataset -> the modes that mean it (the mode-meaning check)
MEANING = {"junction_turn": (TURN,), "stopping": (DECEL,), "bypass": (AVOID, RECOVER)}


def frame_metrics(path: np.ndarray, speed: np.ndarray, dt: float = DT) -> dict[str, np.ndarray]:
    """The five metrics (T,) of one label sequence: path (T, 20, 2) [m], speed (T, 10) [m/s]."""
    path, speed = np.asarray(path, dtype=float), np.asarray(speed, dtype=float)
    T = len(speed)
    psi = pathspeed.chord_headings(path)  # (T, 19)
    v0 = speed[:, 0]
    a_lat = v0 ** 2 * (psi[:, 1] - psi[:, 0]) / pathspeed.PATH_STEP
    out = {m: np.full(T, np.nan) for m in METRICS}
    if T >= 2:
        out["speed_delta"][1:] = np.mean(np.abs(np.diff(speed, axis=0)), axis=1)
        out["lat_delta"][1:] = np.mean(np.abs(np.diff(path[..., 1], axis=0)), axis=1)
        out["heading_delta"][1:] = np.mean(np.abs(np.diff(psi, axis=0)), axis=1)
        out["lat_jerk"][1:] = np.abs(np.diff(a_lat)) / dt
    if T >= 3:
        out["speed_jerk"][2:] = np.abs(v0[2:] - 2 * v0[1:-1] + v0[:-2]) / dt ** 2
    return out


# the delta metrics with frame t-1's labels first moved into frame t (``moved_metrics``)
MOVED = ("speed_delta_moved", "lat_delta_moved", "heading_delta_moved")
DISPLAY.update({"speed_delta_moved": "Speed delta, moved", "lat_delta_moved": "Lat delta, moved",
                "heading_delta_moved": "Heading delta, moved"})


# how far a row's labels are from the raw expert's at the same frame (``from_raw``)
FROM_RAW = ("speed_from_raw", "lat_from_raw")
DISPLAY.update({"speed_from_raw": "Speed from raw", "lat_from_raw": "Lat from raw"})


def from_raw(path: np.ndarray, speed: np.ndarray, raw_path: np.ndarray, raw_speed: np.ndarray) -> dict[str, np.ndarray]:
    """Per frame, how far labels are from the raw expert labels of the same frame:
    speed_from_raw = mean_k |v(tau_k) - v_raw(tau_k)| [m/s], lat_from_raw = mean_k
    |y(s_k) - y_raw(s_k)| [m] (shapes as ``frame_metrics``). A teacher that lags the
    expert's braking, or cuts its bends, shows here; the raw row scores 0."""
    return {"speed_from_raw": np.mean(np.abs(np.asarray(speed, float) - raw_speed), axis=1),
            "lat_from_raw": np.mean(np.abs(np.asarray(path, float)[..., 1] - np.asarray(raw_path, float)[..., 1]),
                                    axis=1)}


def moved_metrics(path: np.ndarray, speed: np.ndarray, pose: np.ndarray) -> dict[str, np.ndarray]:
    """Speed, Lat and Heading delta of a label sequence with the ego's own motion taken out:
    frame t-1's labels are moved into frame t before the comparison, so a label that stays
    put in the world scores 0 whatever the ego does (``frame_metrics`` compares each frame's
    labels in its own ego frame, and so also measures the ego's yaw and sideways motion).

    path (T, 20, 2) [m] and speed (T, 10) [m/s] as in ``frame_metrics``; pose (T, 3): the
    ego's world x, y [m] and yaw [rad] at each frame. With d = the distance between the two
    ego positions [m] (the arc driven in 0.25 s, to within 0.5 % at a 10 m radius):

        lat_delta_moved      mean_k |y_t(s_k) - y'_t-1(s_k + d)|           [m]
        heading_delta_moved  mean_k |psi_t(s_k) - psi'_t-1(s_k + d)|        [rad]
        speed_delta_moved    mean_k |v_t(tau_k) - v_t-1(tau_k + 0.25 s)|    [m/s], k = 0..8

    where ' marks frame t-1's path in frame t's ego frame, read by linear interpolation
    along it at arc length s_k + d; only the points with s_k + d inside frame t-1's 19 m
    count. Frame 0 is NaN."""
    path, speed, pose = (np.asarray(a, dtype=float) for a in (path, speed, pose))
    T = len(speed)
    out = {m: np.full(T, np.nan) for m in MOVED}
    if T < 2:
        return out
    out["speed_delta_moved"][1:] = np.mean(np.abs(speed[1:, :-1] - speed[:-1, 1:]), axis=1)
    dyaw = pose[:-1, 2] - pose[1:, 2]  # (T-1,) rotation from frame t-1 to frame t
    old = previous_in_current(path, pose)  # (T-1, 20, 2)
    d = np.hypot(*(pose[1:, :2] - pose[:-1, :2]).T)  # (T-1,)
    seg = np.hypot(*np.diff(path[:-1], axis=1).transpose(2, 0, 1))  # (T-1, 19) chord lengths of t-1
    cum = np.concatenate([np.zeros((T - 1, 1)), np.cumsum(seg, axis=1)], axis=1)  # (T-1, 20)
    want = pathspeed.PATH_S[None, :] + d[:, None]  # (T-1, 20) arc length on t-1's path
    inside = want <= cum[:, -1:]
    y_old = interp_rows(want, cum, old[..., 1])
    out["lat_delta_moved"][1:] = _masked_mean(np.abs(path[1:, :, 1] - y_old), inside)
    psi_new = pathspeed.chord_headings(path[1:])  # (T-1, 19) at s_k + 0.5
    psi_old = pathspeed.chord_headings(path[:-1]) + dyaw[:, None]  # in frame t's axes
    mid = 0.5 * (cum[:, 1:] + cum[:, :-1])  # chord midpoints of t-1 [m]
    want_mid = pathspeed.CHORD_S[None, :] + d[:, None]
    inside_mid = (want_mid >= mid[:, :1]) & (want_mid <= mid[:, -1:])
    turned = np.abs(psi_new - interp_rows(want_mid, mid, psi_old))
    out["heading_delta_moved"][1:] = _masked_mean(np.abs((turned + np.pi) % (2 * np.pi) - np.pi), inside_mid)
    return out


def _masked_mean(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Row means of values (R, K) over the entries where mask is True; NaN for an empty row."""
    n = mask.sum(axis=1)
    total = np.where(mask, values, 0.0).sum(axis=1)
    return np.divide(total, n, out=np.full(len(n), np.nan), where=n > 0)


def group_of(mu: np.ndarray) -> np.ndarray:
    """(T,) group index into ``GROUPS`` of posteriors mu (T, 5): argmax, Avoidance/Recovery merged."""
    return np.minimum(np.argmax(mu, axis=-1), len(GROUPS) - 1)


def table2(episodes: Sequence[dict[str, dict[str, np.ndarray]]], rows: Sequence[str] = ROWS,
           moving_only: bool = False) -> pd.DataFrame:
    """Table 2 from episodes, each {row name: {"path", "speed"}} plus "scimm" holding "mu",
    and optionally "pose" (T, 3) world x, y [m], yaw [rad] for the ``MOVED`` columns (NaN
    without it); the ``FROM_RAW`` columns compare each row with the "raw" one (NaN without
    it). Returns one line per (group, row): group, method, frames, the metric means.

    ``moving_only``: only the frames where the expert moved (the episode's "v" [m/s] above
    STOOD_SPEED at the frame or at one of the two before it, the frames its metrics read).
    A standing frame has every delta 0; the paper does not say whether its groups hold
    them, so the table is given both ways (docs/teacher.md)."""
    per_row: dict[str, list[pd.DataFrame]] = {r: [] for r in rows}
    for ep in episodes:
        g = group_of(ep["scimm"]["mu"])
        if moving_only:
            v = ep["v"] > STOOD_SPEED
            moved = v.copy()
            moved[1:] |= v[:-1]  # t-1
            moved[2:] |= v[:-2]  # t-2
            g = np.where(moved, g, -1)
        for r in rows:
            df = pd.DataFrame(frame_metrics(ep[r]["path"], ep[r]["speed"]))
            if "pose" in ep:
                df = df.assign(**moved_metrics(ep[r]["path"], ep[r]["speed"], ep["pose"]))
            if "raw" in ep:
                df = df.assign(**from_raw(ep[r]["path"], ep[r]["speed"], ep["raw"]["path"], ep["raw"]["speed"]))
            df["group"] = g
            per_row[r].append(df)
    lines = []
    for gi, gname in enumerate(GROUPS):
        for r in rows:
            df = pd.concat(per_row[r], ignore_index=True)
            sel = df[df["group"] == gi]
            line = {"mode": gname, "method": ROW_NAMES[r], "frames": len(sel)}
            line.update({m: float(sel[m].mean()) if m in sel and sel[m].notna().any() else np.nan
                         for m in (*METRICS, *MOVED, *FROM_RAW)})
            lines.append(line)
    return pd.DataFrame(lines, columns=["mode", "method", "frames", *METRICS, *MOVED, *FROM_RAW])


def format_table2(table: pd.DataFrame) -> str:
    """Table 2 as aligned text, paper layout (then the ``MOVED`` and ``FROM_RAW`` columns,
    when computed)."""
    cols = [*METRICS, *(m for m in (*MOVED, *FROM_RAW) if m in table and table[m].notna().any())]
    head = f"{'Mode':19} {'Method':20} {'frames':>7} " + " ".join(f"{DISPLAY[m]:>20}" for m in cols)
    lines = [head]
    for _, r in table.iterrows():
        lines.append(f"{r['mode']:19} {r['method']:20} {r['frames']:7d} "
                     + " ".join(f"{r[m]:20.4g}" for m in cols))
    return "\n".join(lines)


RESIDUALS = ("path_mean", "path_p95", "path_max", "speed_mean", "speed_p95")


def fit_residuals(episodes: Sequence[dict[str, np.ndarray]]) -> pd.DataFrame:
    """How well the observation z (paper eq. 2-3, scimm.pathspeed) represents each frame's
    expert labels, per group of the dominant SC-IMM mode (docs/design.md §6.1: the residual per mode).

    episodes: each {"path" (T, 20, 2), "speed_wps" (T, 10, 2), "mu" (T, 5) SC-IMM posteriors}.
    Per frame, ``pathspeed.residuals``: the largest distance between a label path point and
    the path of z [m], and the RMS difference of the 10 label speeds and the speeds of z
    [m/s]. Returns one line per group: mode, frames, mean / 95th percentile / max of the path
    residual, mean / 95th percentile of the speed residual (NaN for a group with no frame)."""
    dp, dv, g = [], [], []
    for ep in episodes:
        z = pathspeed.observe(ep["path"], ep["speed_wps"])
        p, v = pathspeed.residuals(ep["path"], ep["speed_wps"], z)
        dp.append(p)
        dv.append(v)
        g.append(group_of(ep["mu"]))
    dp, dv, g = (np.concatenate(a) if a else np.zeros(0) for a in (dp, dv, g))
    lines = []
    for gi, gname in enumerate(GROUPS):
        p, v = dp[g == gi], dv[g == gi]
        stats = ((np.mean(p), np.percentile(p, 95), np.max(p), np.mean(v), np.percentile(v, 95))
                 if len(p) else (np.nan,) * len(RESIDUALS))
        lines.append({"mode": gname, "frames": len(p), **dict(zip(RESIDUALS, map(float, stats)))})
    return pd.DataFrame(lines, columns=["mode", "frames", *RESIDUALS])


def format_residuals(table: pd.DataFrame) -> str:
    """The fit residuals per group as aligned text."""
    lines = [f"{'Mode':19} {'frames':>7} {'path mean [m]':>14} {'p95':>8} {'max':>8} "
             f"{'speed mean [m/s]':>17} {'p95':>8}"]
    for _, r in table.iterrows():
        lines.append(f"{r['mode']:19} {r['frames']:7d} {r['path_mean']:14.4f} {r['path_p95']:8.4f} "
                     f"{r['path_max']:8.4f} {r['speed_mean']:17.4f} {r['speed_p95']:8.4f}")
    return "\n".join(lines)


def mode_meaning(situations: Sequence[np.ndarray], mus: dict[str, Sequence[np.ndarray]]) -> pd.DataFrame:
    """Share of frames of each situation in ``MEANING`` whose dominant mode means it.

    situations: per episode (T,) situation names; mus: {method: per episode (T, 5) posteriors}.
    Returns one line per situation: situation, expected modes, frames, and a share per method."""
    sit = np.concatenate(situations)
    lines = []
    for name, modes in MEANING.items():
        sel = sit == name
        line = {"situation": name, "modes": "/".join(MODES[m] for m in modes), "frames": int(sel.sum())}
        for method, seq in mus.items():
            dom = np.argmax(np.concatenate(seq), axis=-1)
            line[method] = float(np.isin(dom[sel], modes).mean()) if sel.any() else np.nan
        lines.append(line)
    return pd.DataFrame(lines)


def format_meaning(table: pd.DataFrame) -> str:
    """The mode-meaning check as text: one line per situation, shares in percent per method."""
    methods = [c for c in table.columns if c not in ("situation", "modes", "frames")]
    lines = [f"{'situation':14} {'dominant mode should be':24} {'frames':>7} "
             + " ".join(f"{ROW_NAMES.get(m, m):>16}" for m in methods)]
    for _, r in table.iterrows():
        lines.append(f"{r['situation']:14} {r['modes']:24} {r['frames']:7d} "
                     + " ".join(f"{100 * r[m]:15.1f}%" for m in methods))
    return "\n".join(lines)


def situations(a) -> np.ndarray:
    """(T,) situation name of every frame of an episode's arrays (harness.expert.dataset.situation)."""
    from harness.expert.dataset import situation
    df = pd.DataFrame({"cue_junction": a["cue_junction"], "command": a["command"],
                       "target_speed": a["target_speed"], "v": a["v"], "cue_changed_route": a["cue_changed_route"]})
    return df.apply(situation, axis=1).to_numpy(dtype=str) if len(df) else np.array([], dtype=str)
