"""Fixed-interval IMM smoother: a Kim-type Rauch-Tung-Striebel backward pass over a stored
IMM forward pass (docs/design.md §6.2; Kim 1994 for the mode probabilities), batched over
sequences with NumPy. Non-causal: frame t's estimate uses every frame of the sequence.

Input: the forward filter's mode-matched posteriors x_k^j, P_k^j and mode probabilities
mu_k^j of every frame (scimm.imm.imm_filter(..., keep_P_modes=True)), and what drove each
forward step k -> k+1: Pi = Pi_{k+1}, Q^i = Q_{k+1}^i, the known input C = C_{k+1},
u = u_{k+1} (scimm.imm step 3b; C = I, u = 0 without one). Mode i's transition from frame
k is x_{k+1} = A_i x_k + F_i u + w, A_i = F_i C, w ~ N(0, Q^i).

At the last frame N the smoothed values are the filtered ones. For k = N-1 .. 0, for every
pair (j = mode at k, i = mode at k+1):

    xp_ji = A_i x_k^j + F_i u,          Pp_ji = A_i P_k^j A_i^T + Q^i        pair prediction
    G_ji  = P_k^j A_i^T Pp_ji^-1                                            smoother gain
    xs_ji = x_k^j + G_ji (xs_{k+1}^i - xp_ji)
    Ps_ji = P_k^j + G_ji (Ps_{k+1}^i - Pp_ji) G_ji^T                         RTS step

mode probabilities (Kim's approximation; exact for the discrete chain alone):

    cbar^i  = sum_j Pi_ji mu_k^j                    the forward predicted probability
    q_ji    = mu_k^j Pi_ji mus_{k+1}^i / cbar^i     P(mode j at k, mode i at k+1 | all frames)
    mus_k^j = sum_i q_ji,   w_i|j = q_ji / mus_k^j

and the collapse over i (the spread about the new mean, as in the IMM's mixing):

    xs_k^j = sum_i w_i|j xs_ji,   Ps_k^j = sum_i w_i|j [Ps_ji + (xs_ji - xs_k^j)(xs_ji - xs_k^j)^T]
    xs_k   = sum_j mus_k^j xs_k^j, Ps_k   = sum_j mus_k^j [Ps_k^j + (xs_k^j - xs_k)(xs_k^j - xs_k)^T]

The divisions are done in log space. sum_j mus_k^j = sum_i mus_{k+1}^i = 1 without any
renormalisation (sum_j mu_k^j Pi_ji = cbar^i). With one mode, q = w = 1 and the pass is the
RTS smoother. A mode with mus_k^j = 0 keeps its filtered x_k^j, P_k^j (weight 0). A
sequence shorter than the batch (NaN-padded at the end) is smoothed from its own last
frame: the padded frames do not reach back into it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scimm.imm import IMMResult


@dataclass(frozen=True)
class SmootherResult:
    """Smoothed fused x (B,T,n), P (B,T,n,n) and mode probabilities mu (B,T,M)."""

    x: np.ndarray
    P: np.ndarray
    mu: np.ndarray


def _per_frame(a: np.ndarray, B: int, T: int, ndim: int) -> np.ndarray:
    """An input given once (ndim dims) or per frame (B, T, ...) as a (B, T, ...) view."""
    a = np.asarray(a, dtype=float)
    return np.broadcast_to(a, (B, T) + a.shape[-ndim:]) if a.ndim == ndim else a


def imm_smooth(fwd: IMMResult, F: np.ndarray, Q: np.ndarray, Pi: np.ndarray,
               carry: np.ndarray | None = None, shift: np.ndarray | None = None,
               lengths: np.ndarray | None = None) -> SmootherResult:
    """The backward pass of the module docstring over the forward pass ``fwd`` (which must
    hold P_modes). F (M,n,n); Q (M,n,n) or (B,T,M,n,n); Pi (M,M) or (B,T,M,M); carry
    (B,T,n,n) and shift (B,T,n) as given to imm_filter (or neither); lengths (B,) real
    frames per sequence (default all T)."""
    if fwd.P_modes is None:
        raise ValueError("the smoother needs the mode covariances: imm_filter(..., keep_P_modes=True)")
    B, T, M, n = fwd.x_modes.shape
    F = np.asarray(F, dtype=float)
    Q, Pi = _per_frame(Q, B, T, 3), _per_frame(Pi, B, T, 2)
    if carry is None:
        carry, shift = np.broadcast_to(np.eye(n), (B, T, n, n)), np.zeros((B, T, n))
    last = np.full(B, T - 1) if lengths is None else np.asarray(lengths) - 1
    xs_m, Ps_m = fwd.x_modes.copy(), fwd.P_modes.copy()  # (B,T,M,n), (B,T,M,n,n)
    with np.errstate(divide="ignore"):
        log_mus = np.log(fwd.mu)  # (B,T,M); row k is overwritten by the smoothed values
        log_mu = np.log(fwd.mu)
        log_pi = np.log(Pi)
    for k in range(T - 2, -1, -1):
        xs, Ps, lm = _step(xs_m[:, k], Ps_m[:, k], log_mu[:, k], xs_m[:, k + 1], Ps_m[:, k + 1],
                           log_mus[:, k + 1], F, Q[:, k + 1], log_pi[:, k + 1], carry[:, k + 1], shift[:, k + 1])
        inside = k < last  # frames after a sequence's end keep their filtered values
        xs_m[inside, k], Ps_m[inside, k], log_mus[inside, k] = xs[inside], Ps[inside], lm[inside]
    mus = np.exp(log_mus)
    x = np.einsum("btm,btmn->btn", mus, xs_m)
    d = xs_m - x[:, :, None]
    P = np.einsum("btm,btmac->btac", mus, Ps_m + d[..., :, None] * d[..., None, :])
    return SmootherResult(x, 0.5 * (P + np.swapaxes(P, -1, -2)), mus)


def _step(x, P, log_mu, xs1, Ps1, log_mus1, F, Q1, log_pi1, C1, u1):
    """One backward step for every sequence: frame k's filtered x (B,M,n), P (B,M,n,n),
    log mu (B,M) and frame k+1's smoothed xs1, Ps1, log mus1, with F (M,n,n), Q1 (B,M,n,n),
    log Pi1 (B,M,M), C1 (B,n,n), u1 (B,n) of the step k -> k+1. Returns frame k's smoothed
    (xs (B,M,n), Ps (B,M,n,n), log mus (B,M)); axes j (mode at k) before i (mode at k+1)."""
    A = F[None] @ C1[:, None]  # (B, i, n, n): A_i = F_i C
    xp = np.einsum("bian,bjn->bjia", A, x) + np.einsum("ian,bn->bia", F, u1)[:, None]  # (B, j, i, n)
    AP = A[:, None] @ P[:, :, None]  # (B, j, i, n, n): A_i P^j
    Pp = AP @ np.swapaxes(A, -1, -2)[:, None] + Q1[:, None]
    Pp = 0.5 * (Pp + np.swapaxes(Pp, -1, -2))
    G = np.swapaxes(np.linalg.solve(Pp, AP), -1, -2)  # P^j A_i^T Pp^-1 (Pp symmetric)
    xs_ji = x[:, :, None] + np.einsum("bjiac,bjic->bjia", G, xs1[:, None] - xp)
    Ps_ji = P[:, :, None] + G @ (Ps1[:, None] - Pp) @ np.swapaxes(G, -1, -2)
    # mode probabilities in log space; a = log(mu^j Pi_ji), (B, j, i)
    a = log_mu[:, :, None] + log_pi1
    log_cbar = _logsumexp(a, axis=1)  # (B, i)
    with np.errstate(invalid="ignore"):
        log_q = a + (log_mus1 - log_cbar)[:, None, :]
    log_q = np.where(np.isfinite(log_cbar)[:, None, :], log_q, -np.inf)  # unreachable i: q = 0
    log_mus = _logsumexp(log_q, axis=2)  # (B, j)
    alive = np.isfinite(log_mus)
    w = np.exp(log_q - np.where(alive, log_mus, 0.0)[:, :, None])  # w_i|j
    xs = np.einsum("bji,bjia->bja", w, xs_ji)
    d = xs_ji - xs[:, :, None]
    Ps = np.einsum("bji,bjiac->bjac", w, Ps_ji + d[..., :, None] * d[..., None, :])
    Ps = 0.5 * (Ps + np.swapaxes(Ps, -1, -2))
    xs = np.where(alive[..., None], xs, x)
    Ps = np.where(alive[..., None, None], Ps, P)
    return xs, Ps, log_mus


def _logsumexp(a: np.ndarray, axis: int) -> np.ndarray:
    """log sum exp over axis; -inf for an all -inf slice."""
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    with np.errstate(divide="ignore"):
        return np.squeeze(m, axis) + np.log(np.sum(np.exp(a - m), axis=axis))
