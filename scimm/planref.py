"""The teacher's path as an offset from the expert's previous plan (``path_state="plan"``,
the default of scimm.modes.IMMConfig).

The path state ``ego`` (scimm.pathspeed) is the quadratic heading fitted to each frame's
path in that frame's ego frame. A three-number fit over a window that slides 1-4 m a
frame changes as it slides, even where the expert's plan lies still on the road, so the
teacher's path moves in the world more than the plan does (docs/teacher.md). Here the
paper's quadratic (eq. 2) describes instead how the plan changes:

    y(s) = c0 + c1 s + c2 s^2     lateral offset [m] at arc length s [m] from a reference path

and the reference is the expert's plan of the frame before:

    z_t[:3]   the quadratic fitted (least squares) to the offsets of plan_t's points 1..19 from
              plan_t-1, moved into frame t and read at arc length s_k + d along it (d = the arc
              the ego drove, scimm.ego.pose_change); points beyond plan_t-1's end and point 0
              (the ego, which joins the plan within its first metre) do not count; z_0 = 0.
    x_t[:3]   the teacher's offset from plan_t-1, in the same coordinates.

Predict (docs/design.md §6.2, a known input): the state is rebased onto plan_t-1 (x - z_t-1: plan_t-1
is plan_t-2 plus z_t-1) and carried d along it, x' = C_t (x - z_t-1), i.e. the carry C_t of
scimm.ego with no turn (an offset from a path does not turn with the ego) and the shift
u_t = -C_t z_t-1. The teacher's path is then the plan plus the filter's correction along its
normals:

    P^T_t(s_k) = plan_t(s_k) + (y_x(s_k) - y_z(s_k)) n_t(s_k),   k = 1..19; P^T_t(0) = the ego.

With one mode and gain K the teacher at a point of the road is P^T_t = (1 - K) P^T_t-1 + K
plan_t: an exponential average of the expert's plans over time, which never moves further
than the plans move (up to the part of each change that a quadratic cannot hold, which
passes through unfiltered). The speed states are those of scimm.pathspeed, unchanged.
"""
from __future__ import annotations

import numpy as np

from scimm.ego import carry_inputs, interp_rows, pose_change, previous_in_current
from scimm.pathspeed import PATH_S

FIRST = 1  # path points 0..FIRST-1 (the ego and its join to the plan) are not filtered
_BASIS = np.stack([np.ones_like(PATH_S), PATH_S, PATH_S ** 2], axis=-1)  # (20, 3) of y(s), paper eq. 2


def offsets_of(c: np.ndarray) -> np.ndarray:
    """y(s_k) (..., 20) [m] of quadratics c (..., 3) at the path's arc lengths s_k = 0..19 m."""
    return np.asarray(c, dtype=float) @ _BASIS.T


def normals(path: np.ndarray) -> np.ndarray:
    """(..., 20, 2) unit left normals of paths (..., 20, 2) at their points (central
    differences along the path; one-sided at the ends)."""
    g = np.gradient(np.asarray(path, dtype=float), axis=-2)
    t = g / np.maximum(np.linalg.norm(g, axis=-1, keepdims=True), 1e-12)
    return np.stack([-t[..., 1], t[..., 0]], axis=-1)


def plan_change(path: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(z_path (T, 3) [m, -, 1/m], d (T,) [m]) of one episode: the quadratic offset of each
    frame's plan from the previous frame's (module docstring; row 0 is 0) and the arc the ego
    drove since the previous frame. path (T, 20, 2) [m, ego frame]; pose (T, 3) world x, y
    [m], yaw [rad]."""
    path, pose = np.asarray(path, dtype=float), np.asarray(pose, dtype=float)
    T = len(path)
    d, _ = pose_change(*pose.T)
    z = np.zeros((T, 3))
    if T < 2:
        return z, d
    old = previous_in_current(path, pose)  # (T-1, 20, 2) plan_t-1 in frame t
    cum = np.concatenate([np.zeros((T - 1, 1)), np.cumsum(np.linalg.norm(np.diff(old, axis=1), axis=-1), axis=1)], 1)
    want = PATH_S[None, :] + d[1:, None]  # (T-1, 20) arc length along plan_t-1
    ref = np.stack([interp_rows(want, cum, old[..., i]) for i in range(2)], axis=-1)
    heading = np.unwrap(np.arctan2(*np.diff(old, axis=1).transpose(2, 0, 1)[::-1]), axis=1)  # (T-1, 19)
    mid = 0.5 * (cum[:, 1:] + cum[:, :-1])
    h = interp_rows(want, mid, heading)
    off = (path[1:, :, 0] - ref[..., 0]) * -np.sin(h) + (path[1:, :, 1] - ref[..., 1]) * np.cos(h)
    w = (want <= cum[:, -1:]).astype(float)
    w[:, :FIRST] = 0.0
    AtA = np.einsum("tk,ki,kj->tij", w, _BASIS, _BASIS)
    Atb = np.einsum("tk,ki,tk->ti", w, _BASIS, off)
    ok = np.linalg.matrix_rank(AtA) == 3  # a plan_t-1 shorter than 3 points ahead: no change seen
    z[1:][ok] = np.linalg.solve(AtA[ok], Atb[ok][..., None])[..., 0]
    return z, d


def known_input(z_path: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(C (..., T, 5, 5), u (..., T, 5)) of the predict step x' = C_t x + u_t for plan-change
    observations z_path (..., T, 3) (NaN = a missing frame, no rebase) and arcs d (..., T) [m]:
    C_t = scimm.ego's carry by d_t with no turn, u_t = -C_t z_t-1 on the path states."""
    d = np.asarray(d, dtype=float)
    C, u = carry_inputs(d, np.zeros_like(d))
    prev = np.nan_to_num(np.asarray(z_path, dtype=float)[..., :-1, :])
    u[..., 1:, :3] = -np.einsum("...ij,...j->...i", C[..., 1:, :3, :3], prev)
    return C, u


def teacher_path(path: np.ndarray, x_path: np.ndarray, z_path: np.ndarray) -> np.ndarray:
    """(..., 20, 2) path teacher [m, ego frame]: the plans path (..., 20, 2) moved along their
    normals by the filter's correction y_x - y_z of states x_path (..., 3) over observations
    z_path (..., 3); point 0 stays at the ego."""
    corr = offsets_of(x_path) - offsets_of(z_path)
    corr[..., :FIRST] = 0.0
    return np.asarray(path, dtype=float) + corr[..., None] * normals(path)
