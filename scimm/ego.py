"""Ego-motion compensation of the path-speed state (docs/design.md §6.2): the state of frame t-1,
written in frame t-1's ego frame, carried into frame t's ego frame with the recorded pose
change, a known input of the IMM's predict step (scimm.imm, step 3b).

The path of a state is psi(s) = c0 + c1 s + c2 s^2, the heading [rad] of the path at arc
length s [m] from the ego, in the ego frame (scimm.pathspeed). Between two frames the ego
drives an arc of length d [m] along the path and turns by dyaw [rad]. The same path, seen
from the new ego, is the old one from arc length d on, turned by -dyaw:

    psi_t(s) = psi_t-1(s + d) - dyaw

which, expanded, is linear in the state with d known:

    c0' = c0 + c1 d + c2 d^2 - dyaw
    c1' = c1 + 2 c2 d                    x' = C x + u,  u = (-dyaw, 0, 0, 0, 0)
    c2' = c2

The speed profile v(tau) = v + a tau is in time, not in the ego frame; the 0.25 s step
v' = v + a dt is each mode's transition F_j (scimm.modes), so C leaves v and a alone.

d comes from the two recorded positions: the chord |p_t - p_t-1| lengthened to the arc of
a circle that turns by dyaw over it, d = chord * (dyaw / 2) / sin(dyaw / 2) (exact on a
circle; +0.04 % at dyaw = 0.1 rad). A car standing still gives C = I, u = 0.

``previous_in_current`` writes frame t-1's path points in frame t's ego frame with the
recorded poses, and ``interp_rows`` reads such paths at given arc lengths (scimm.table2's
moved metrics, scimm.planref's plan change).
"""
from __future__ import annotations

import numpy as np

N_STATE = 5


def pose_change(x: np.ndarray, y: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(d (T,) arc driven [m], dyaw (T,) turn [rad, wrapped to [-pi, pi)]) from frame t-1 to
    frame t of world poses x, y [m], yaw [rad] (T,); both 0 at frame 0."""
    x, y, yaw = (np.asarray(a, dtype=float) for a in (x, y, yaw))
    d, dyaw = np.zeros(len(x)), np.zeros(len(x))
    if len(x) > 1:
        dyaw[1:] = (np.diff(yaw) + np.pi) % (2 * np.pi) - np.pi
        half = 0.5 * dyaw[1:]
        arc_over_chord = np.ones_like(half)
        turning = np.abs(half) > 1e-12
        arc_over_chord[turning] = half[turning] / np.sin(half[turning])
        d[1:] = np.hypot(np.diff(x), np.diff(y)) * arc_over_chord
    return d, dyaw


def carry_inputs(d: np.ndarray, dyaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(C (..., 5, 5), u (..., 5)) of the docstring's x' = C x + u for arcs d [m] and turns
    dyaw [rad] of any shape (...)."""
    d, dyaw = np.asarray(d, dtype=float), np.asarray(dyaw, dtype=float)
    C = np.broadcast_to(np.eye(N_STATE), d.shape + (N_STATE, N_STATE)).copy()
    C[..., 0, 1] = d
    C[..., 0, 2] = d ** 2
    C[..., 1, 2] = 2.0 * d
    u = np.zeros(d.shape + (N_STATE,))
    u[..., 0] = -dyaw
    return C, u


def carry(x: np.ndarray, d: np.ndarray, dyaw: np.ndarray) -> np.ndarray:
    """States x (..., 5) carried by arcs d and turns dyaw (...): C x + u."""
    C, u = carry_inputs(d, dyaw)
    return np.einsum("...ab,...b->...a", C, np.asarray(x, dtype=float)) + u


def previous_in_current(path: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """(T-1, K, 2): frame t-1's points path[t-1] (K, 2) [m, ego frame of t-1] written in frame
    t's ego frame, for t = 1..T-1, with the recorded world poses (T, 3) (x, y [m], yaw [rad])."""
    path, pose = np.asarray(path, dtype=float), np.asarray(pose, dtype=float)
    dxy = pose[:-1, None, :2] - pose[1:, None, :2]  # (T-1, 1, 2) old ego minus new ego, world
    c, s = np.cos(pose[:-1, 2:3]), np.sin(pose[:-1, 2:3])  # frame t-1 -> world
    px, py = path[:-1, :, 0], path[:-1, :, 1]
    wx, wy = c * px - s * py + dxy[..., 0], s * px + c * py + dxy[..., 1]  # relative to the new ego
    c, s = np.cos(pose[1:, 2:3]), np.sin(pose[1:, 2:3])  # world -> frame t
    return np.stack([c * wx + s * wy, -s * wx + c * wy], axis=-1)


def interp_rows(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """np.interp row by row, vectorised: x (R, K) at increasing xp (R, N) with values fp (R, N)."""
    R, N = xp.shape
    i = np.clip(_searchsorted_rows(xp, x), 1, N - 1)
    rows = np.arange(R)[:, None]
    x0, x1, f0, f1 = xp[rows, i - 1], xp[rows, i], fp[rows, i - 1], fp[rows, i]
    w = np.divide(x - x0, x1 - x0, out=np.zeros_like(x), where=x1 > x0)
    return f0 + np.clip(w, 0.0, 1.0) * (f1 - f0)


def _searchsorted_rows(xp: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Per row r, np.searchsorted(xp[r], x[r]): rows shifted apart so one search serves all."""
    R = len(xp)
    span = max(float(np.nanmax(np.abs(xp))) if xp.size else 0.0, float(np.nanmax(np.abs(x))) if x.size else 0.0)
    shift = (2.0 * span + 1.0) * np.arange(R)[:, None]
    flat = np.searchsorted((xp + shift).ravel(), (x + shift).ravel()).reshape(x.shape)
    return flat - xp.shape[1] * np.arange(R)[:, None]
