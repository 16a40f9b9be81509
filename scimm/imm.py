"""Interacting Multiple Model filter, batched over sequences with NumPy (paper eq. 4-7).

Symbols (Bar-Shalom, Li & Kirubarajan 2001, ch. 11; docs/design.md §6.2):

    B sequences, T frames, M modes, n states; the measurement is the state: H = I (n x n).
    x^j, P^j      mode-matched posterior mean (n,) and covariance (n, n) of mode j
    mu^j          posterior mode probability, kept as log mu
    Pi[i, j]      P(mode j at t | mode i at t-1): rows sum to 1 (row = previous mode)
    F_j, Q_j      mode j's transition and process noise; R the measurement noise

One cycle per frame t, frame 0 included, starting from the given (x0, P0, mu0):

    1. cbar_j  = sum_i Pi_ij mu^i                       predicted mode probability
    2. w_ij    = Pi_ij mu^i / cbar_j                     mixing weights (sum_i w_ij = 1)
    3. x0^j    = sum_i w_ij x^i
       P0^j    = sum_i w_ij [P^i + (x^i - x0^j)(x^i - x0^j)^T]   spread about x0^j
    3b. x0^j  <- C_t x0^j + u_t,   P0^j <- C_t P0^j C_t^T           known input (optional)
    4. xbar^j  = F_j x0^j,   Pbar^j = F_j P0^j F_j^T + Q_j          predict
    5. S_j = Pbar^j + R = C_j C_j^T (Cholesky),  K_j = Pbar^j S_j^-1 = I - R S_j^-1,
       nu_j = z - xbar^j,  x^j = xbar^j + K_j nu_j
       P^j = (I - K_j) Pbar^j (I - K_j)^T + K_j R K_j^T   Joseph form: stays PSD for any gain
    6. log L_j = -1/2 (|C_j^-1 nu_j|^2 + 2 sum log diag C_j + n log 2 pi)
    7. log mu^j = log cbar_j + log L_j - logsumexp_j(...)            log space: no underflow
    8. x = sum_j mu^j x^j,  P = sum_j mu^j [P^j + (x^j - x)(x^j - x)^T]   fused output

A frame whose measurement has a NaN skips 5-7 (x^j = xbar^j, P^j = Pbar^j, mu = cbar).

Step 3b is a known input shared by every mode (docs/design.md §6.2): the state of frame t-1 carried
into frame t's coordinates by a per-frame matrix C_t and offset u_t (the teacher's ego
motion, scimm.ego). Mode j's transition is then x_t = F_j C_t x_t-1 + F_j u_t + w, still
linear: filterpy's KalmanFilter with F = F_j C_t, B = F_j and control u_t is the same
filter. Carrying the mixed x0^j equals carrying every x^i before mixing, because C_t is the
same for all modes (the spread terms transform as C_t d d^T C_t^T). Without C, u (or with
C = I, u = 0) the step is skipped and the filter is the plain IMM.

Speed (``sumo-scimm bench``). Tiny per-sequence 5 x 5 matrix operations are slow in NumPy, long
vector operations are fast, so every array keeps the batch axis last and each matrix entry is
one contiguous row over modes and sequences ("entry-major"): x (n, M, B), P (n, n, M, B), which
the update views as (n, n, L) over L = M * B lanes. Products of two per-lane matrices are
einsums whose inner loop runs over the lanes; products with a shared matrix (F_j, R) are BLAS
calls over all lanes; the Cholesky factor C and C^-T are built entry by entry, each entry one
contiguous row of lanes (a NumPy call on a contiguous row costs a fraction of one on a strided
block); the symmetric products S^-1 and the Joseph P are computed on their lower triangle and
mirrored, so every P^j and the fused P are exactly symmetric; every frame reuses the same few
buffers. (About 1.3x the speed of the previous batch-last version on the bench workload.)
Step 3 takes the spread about the previous fused mean xf instead of x0^j:
sum_i w_ij (P^i + d_i d_i^T) - (x0^j - xf)(x0^j - xf)^T with d_i = x^i - xf, the same
matrix; the subtraction only cancels at the scale of the spread between modes, not of x.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

LOG_2PI = math.log(2 * math.pi)
_FLOOR = np.finfo(float).min  # the shift of an all -inf slice in _log_normalise


@dataclass(frozen=True)
class IMMResult:
    """Posterior of every frame: fused x (B,T,n), P (B,T,n,n), mode probabilities mu (B,T,M),
    mode-matched means x_modes (B,T,M,n), the one-step predictive log-likelihood
    loglik (B,T) = log p(z_t | z_<t) (0 on a frame without measurement), and the
    mode-matched covariances P_modes (B,T,M,n,n) when ``imm_filter(..., keep_P_modes=True)``
    (the smoother's input, scimm.smoother)."""

    x: np.ndarray
    P: np.ndarray
    mu: np.ndarray
    x_modes: np.ndarray
    loglik: np.ndarray
    P_modes: np.ndarray | None = None  # (B,T,M,n,n) mode-matched covariances, if asked for


def _log_normalise(a: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """(logsumexp of a over axis, exp(a - logsumexp)); a slice that is all -inf gives -inf and
    zeros."""
    m = np.maximum(np.max(a, axis=axis, keepdims=True), _FLOOR)
    e = np.exp(a - m)
    s = np.sum(e, axis=axis, keepdims=True)  # >= 1 (the maximum gives exp(0)) unless all -inf
    e /= np.maximum(s, 1.0)
    with np.errstate(divide="ignore"):
        return np.squeeze(m, axis) + np.log(np.squeeze(s, axis)), e


def _mirror_lower(X: np.ndarray, rows: tuple[np.ndarray, np.ndarray]) -> None:
    """Copy the strict lower triangle of the contiguous stack X (n, n, L) onto its upper
    triangle; rows = (flat rows a * n + c, their mirrors c * n + a) for c < a."""
    flat = X.reshape(X.shape[0] * X.shape[1], -1)
    flat[rows[1]] = flat[rows[0]]


def _cholesky(S: np.ndarray, inv_d: np.ndarray, tmp: np.ndarray) -> None:
    """In place: the lower triangle of the SPD stack S (n, n, L) becomes its Cholesky factor C,
    column by column, C_ij = (S_ij - sum_{k<j} C_ik C_jk) / C_jj, each entry one contiguous row
    of L lanes (the strict upper triangle is left as it was); inv_d (n, L) <- 1 / diag C."""
    n = S.shape[0]
    for j in range(n):
        for i in range(j, n):
            s = S[i, j]
            for k in range(j):
                s -= np.multiply(S[i, k], S[j, k], out=tmp)
            if i == j:
                np.divide(1.0, np.sqrt(s, out=s), out=inv_d[j])
            else:
                s *= inv_d[j]


def _inverse_transpose(C: np.ndarray, inv_d: np.ndarray, U: np.ndarray, tmp: np.ndarray) -> None:
    """U <- C^-T (upper triangular) for the lower triangle C of (n, n, L), by forward
    substitution row by row of W = C^-1: W_ii = 1 / C_ii, W_ij = -(sum_{j<=k<i} C_ik W_kj) / C_ii,
    stored as U_ji. U's strict lower triangle must be zero; it is never written."""
    n = C.shape[0]
    for i in range(n):
        U[i, i] = inv_d[i]
        for j in range(i):
            u = np.multiply(C[i, j], U[j, j], out=U[j, i])
            for k in range(j + 1, i):
                u += np.multiply(C[i, k], U[j, k], out=tmp)
            u *= inv_d[i]
            np.negative(u, out=u)


class _Buffers:
    """Arrays reused every frame, matrices entry-major: (n, n, M, B), seen by the update as
    (n, n, L = M * B). A few share memory with one that is not in use at that step."""

    def __init__(self, M: int, n: int, B: int, R: np.ndarray):
        L = M * B
        self.R = R
        self.ZD = np.empty((n * n + n, M, B))  # per mode i: P^i + d_i d_i^T, then d_i = x^i - xf
        self.Pbar = np.empty((n, n, M, B))
        self.S = np.empty((n, n, L))  # S = Pbar + R, then its Cholesky factor C (lower triangle)
        self.U = np.zeros((n, n, L))  # C^-T; its strict lower triangle stays 0
        self.inv_d = np.empty((n, L))  # 1 / diag C
        self.lane = np.empty(L)  # scratch row
        self.G = np.empty((n, n, L))  # S^-1
        self.V1 = np.empty((n, 2 * n, L))  # [(I - K) Pbar | K R]
        self.V2 = np.empty((n, 2 * n, L))  # [I - K | K]
        self.mixed = self.V1.reshape(-1)[:(n * n + n) * L].reshape(n * n + n, M, B)  # mixing -> predict
        self.outer = self.G.reshape(n, n, M, B)  # outer products in the mixing and the fusion
        self.FP = self.G.reshape(n, n, M, B)  # F P in the predict
        self.Pb = self.S.reshape(n, n, M, B)  # F P F^T / 2 in the predict
        lower = [(a, c) for a in range(n) for c in range(a)]
        self.mirror = (np.array([a * n + c for a, c in lower], dtype=np.intp),
                       np.array([c * n + a for a, c in lower], dtype=np.intp))


def _mix(log_mu: np.ndarray, log_pi_t: np.ndarray, buf: _Buffers) -> tuple:
    """Steps 1-3. log_mu (M, B); log_pi_t[j, i] = log Pi_ij, (M, M, 1) or (M, M, B).
    Returns log cbar (M, B), x0^j - xf (n, M, B) and P0^j (n, n, M, B) (views of buf.mixed),
    both exactly symmetric as every P^i + d_i d_i^T is."""
    n, _, M, B = buf.outer.shape
    a = log_mu[None, :, :] + log_pi_t  # (j, i, B): log(Pi_ij mu^i)
    log_cbar, w = _log_normalise(a, axis=1)  # paper eq. 4, in log space; w[j, i] = w_ij
    np.einsum("jib,eib->ejb", w, buf.ZD, out=buf.mixed)
    ym, Pm = buf.mixed[n * n:], buf.mixed[:n * n].reshape(n, n, M, B)
    np.einsum("amb,cmb->acmb", ym, ym, out=buf.outer)
    Pm -= buf.outer
    return log_cbar, ym, Pm


def _predict(F: np.ndarray, F_half: np.ndarray, xm: np.ndarray, Pm: np.ndarray, Q_t: np.ndarray,
             buf: _Buffers) -> np.ndarray:
    """Step 4: returns xbar (n, M, B) and writes Pbar (n, n, M, B) into buf.Pbar; F_j is one
    BLAS call per mode over all sequences. Pb = F P (F / 2)^T is half of F P F^T exactly
    (a power of two), so Pbar = Pb + Pb^T + Q = (F P F^T + its transpose) / 2 + Q."""
    FP, Pb = buf.FP, buf.Pb
    for m in range(F.shape[0]):
        np.matmul(F[m], Pm[:, :, m].transpose(1, 0, 2), out=FP[:, :, m].transpose(1, 0, 2))  # F P
        np.matmul(F_half[m], FP[:, :, m], out=Pb[:, :, m])  # [a, d] = sum_c F[d, c] (F P)[a, c] / 2
    np.add(Pb, Pb.transpose(1, 0, 2, 3), out=buf.Pbar)
    buf.Pbar += Q_t
    return np.einsum("mak,kmb->amb", F, xm)


def _update(xbar: np.ndarray, nu: np.ndarray, buf: _Buffers, P: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Steps 5-6 for H = I over L lanes: xbar, nu (n, L); writes the Joseph-form P (n, n, L)
    and x (n, L); returns log L (L,)."""
    n, L = nu.shape
    R = buf.R
    Pbar, S, U, G, inv_d = buf.Pbar.reshape(n, n, L), buf.S, buf.U, buf.G, buf.inv_d
    for a in range(n):  # S = Pbar + R, lower triangle (all the Cholesky reads)
        for c in range(a + 1):
            np.add(Pbar[a, c], R[a, c], out=S[a, c])
    _cholesky(S, inv_d, buf.lane)
    _inverse_transpose(S, inv_d, U, buf.lane)
    e = np.einsum("kal,kl->al", U, nu)  # C^-1 nu
    # paper eq. 5 in log space: -log det S / 2 = -sum log diag C = log prod (1 / diag C)
    log_l = np.log(np.prod(inv_d, axis=0)) - 0.5 * (np.einsum("al,al->l", e, e) + n * LOG_2PI)
    for a in range(n):  # S^-1 = C^-T C^-1: G[a, c] = sum_k U[a, k] U[c, k] over k >= a >= c
        np.einsum("kl,ckl->cl", U[a, a:], U[:a + 1, a:], out=G[a, :a + 1])
    _mirror_lower(G, buf.mirror)
    V1, V2 = buf.V1, buf.V2
    IK, K = V2[:, :n], V2[:, n:]
    np.matmul(R, G.reshape(n, n * L), out=IK.reshape(n, n * L))  # I - K = R S^-1
    np.negative(IK, out=K)  # K = I - R S^-1 = Pbar S^-1
    for a in range(n):
        K[a, a] += 1.0
    np.einsum("akl,ckl->acl", IK, Pbar, out=V1[:, :n])  # Pbar is symmetric
    np.matmul(R.T, K, out=V1[:, n:])  # (K R)[a, c] = sum_k R[k, c] K[a, k]
    for a in range(n):  # (I-K) Pbar (I-K)^T + K R K^T = V1 V2^T, lower triangle
        np.einsum("kl,ckl->cl", V1[a], V2[:a + 1], out=P[a, :a + 1])
    _mirror_lower(P, buf.mirror)
    np.einsum("akl,kl->al", K, nu, out=x)
    x += xbar
    return log_l


def _carry(C: np.ndarray, u: np.ndarray, xm: np.ndarray, Pm: np.ndarray, buf: _Buffers) -> np.ndarray:
    """Step 3b for per-sequence C (n, n, B) and u (n, B): returns C x0^j + u (n, M, B) and
    overwrites Pm (n, n, M, B) with C P0^j C^T (its symmetry is restored by the predict,
    which symmetrises F P F^T)."""
    np.einsum("acb,cdmb->admb", C, Pm, out=buf.outer)  # C P
    np.einsum("admb,edb->aemb", buf.outer, C, out=Pm)  # (C P) C^T
    return np.einsum("acb,cmb->amb", C, xm) + u[:, None]


def _fuse(mu: np.ndarray, x: np.ndarray, buf: _Buffers) -> np.ndarray:
    """Step 8's mean xf (n, B) from mu (M, B) and x (n, M, B); turns buf.ZD's P^j into
    P^j + d_j d_j^T and stores d_j = x^j - xf, which give the fused P and the next mixing."""
    n, M, B = x.shape
    dx = buf.ZD[n * n:]
    xf = np.einsum("mb,nmb->nb", mu, x)  # paper eq. 7
    np.subtract(x, xf[:, None], out=dx)
    np.einsum("amb,cmb->acmb", dx, dx, out=buf.outer)
    buf.ZD[:n * n] += buf.outer.reshape(n * n, M, B)
    return xf


_CHUNK = 32  # frames of a per-frame Pi whose logarithm is taken at once


def _log_pi_batch_last(Pi: np.ndarray, t: int) -> np.ndarray:
    """log Pi of frames t .. t + _CHUNK - 1 of a per-frame Pi (B,T,M,M) as (k, j, i, B) with
    [j, i] = log Pi_ij. (A per-frame Q is read one frame at a time, where it is added: a
    strided read is cheaper there than a copy; np.log of a strided frame is not.)"""
    with np.errstate(divide="ignore"):
        return np.log(np.ascontiguousarray(Pi[:, t:t + _CHUNK].transpose(1, 3, 2, 0)))


def imm_filter(z: np.ndarray, F: np.ndarray, Q: np.ndarray, R: np.ndarray, x0: np.ndarray,
               P0: np.ndarray, Pi: np.ndarray, mu0: np.ndarray, carry: np.ndarray | None = None,
               shift: np.ndarray | None = None, keep_P_modes: bool = False) -> IMMResult:
    """Run the IMM over B sequences of T frames.

    z (B,T,n) measurements (NaN = missing); F (M,n,n); Q (M,n,n) or per frame (B,T,M,n,n);
    R (n,n); x0 (B,M,n) initial mode means; P0 (M,n,n); Pi (M,M) row-stochastic (row =
    previous mode) or per frame (B,T,M,M); mu0 (M,). Optional known input of step 3b:
    carry C (B,T,n,n) and shift u (B,T,n), both or neither; C[:, t], u[:, t] take frame
    t-1's state into frame t (at t = 0 they act on x0). keep_P_modes: also return the
    mode-matched covariances. float64 throughout. (One function for the whole frame loop,
    longer than most: it holds the reused buffers and the order of steps 1-8 in one view.)
    """
    z = np.asarray(z, dtype=float)
    B, T, n = z.shape
    F, R = np.asarray(F, dtype=float), np.asarray(R, dtype=float)
    M = F.shape[0]
    Q, Pi = np.asarray(Q, dtype=float), np.asarray(Pi, dtype=float)
    _check(z, F, Q, R, x0, P0, Pi, mu0)
    carry_T, shift_T = _known_input(carry, shift, B, T, n)
    with np.errstate(divide="ignore"):  # structural zeros of Pi are -inf logits, on purpose
        log_mu = np.repeat(np.log(np.asarray(mu0, dtype=float))[:, None], B, axis=1)  # (M, B)
        log_pi_fixed = np.log(Pi).T[:, :, None] if Pi.ndim == 2 else None  # [j, i] = log Pi_ij
    Q_fixed = Q.transpose(1, 2, 0)[..., None] if Q.ndim == 3 else None  # (n, n, M, 1)
    zT = np.ascontiguousarray(np.transpose(z, (1, 2, 0)))  # (T, n, B)
    seen_all = ~np.isnan(zT).any(axis=1)  # (T, B)
    all_seen = seen_all.all(axis=1)  # (T,)
    F_half = 0.5 * F  # exact: a power of two
    buf = _Buffers(M, n, B, R)
    P_modes = buf.ZD[:n * n].reshape(n, n, M, B)
    P_modes[...] = np.asarray(P0, dtype=float).transpose(1, 2, 0)[..., None]
    x0_t = np.ascontiguousarray(np.transpose(np.asarray(x0, dtype=float), (2, 1, 0)))  # (n, M, B)
    out_x, out_P = np.empty((T, n, B)), np.empty((T, n, n, B))
    out_mu, out_xm, out_ll = np.empty((T, M, B)), np.empty((T, n, M, B)), np.empty((T, B))
    out_Pm = np.empty((T, n, n, M, B)) if keep_P_modes else None
    xf = _fuse(np.exp(log_mu), x0_t, buf)
    for t in range(T):
        if log_pi_fixed is None and t % _CHUNK == 0:
            log_pi_chunk = _log_pi_batch_last(Pi, t)
        log_pi_t = log_pi_fixed if log_pi_fixed is not None else log_pi_chunk[t % _CHUNK]
        log_cbar, ym, Pm = _mix(log_mu, log_pi_t, buf)
        Q_t = Q_fixed if Q_fixed is not None else Q[:, t].transpose(2, 3, 1, 0)  # (n, n, M, B) view
        xm = xf[:, None] + ym  # x0^j
        if carry_T is not None:
            xm = _carry(carry_T[t], shift_T[t], xm, Pm, buf)
        xbar = _predict(F, F_half, xm, Pm, Q_t, buf)
        seen, x = seen_all[t], out_xm[t]  # x^j is written in place into the output
        nu = np.subtract((zT[t] if all_seen[t] else np.where(seen, zT[t], 0.0))[:, None], xbar)
        log_l = _update(xbar.reshape(n, -1), nu.reshape(n, -1), buf,
                        P_modes.reshape(n, n, -1), x.reshape(n, -1)).reshape(M, B)
        a = log_cbar + log_l
        ll, mu = _log_normalise(a, axis=0)
        log_mu = a - ll  # paper eq. 6, in log space
        if not all_seen[t]:
            log_mu = np.where(seen, log_mu, log_cbar)
            mu = np.where(seen, mu, np.exp(log_cbar))
            x[...] = np.where(seen, x, xbar)
            np.copyto(P_modes, buf.Pbar, where=~seen)
            _mirror_lower(P_modes.reshape(n, n, -1), buf.mirror)  # Pbar is symmetric if Q is
        out_mu[t] = mu
        if out_Pm is not None:
            out_Pm[t] = P_modes
        out_x[t] = xf = _fuse(mu, x, buf)
        # every P^j + d_j d_j^T is exactly symmetric, so the fused P is too
        np.einsum("mb,emb->eb", mu, buf.ZD[:n * n], out=out_P[t].reshape(n * n, B))
        out_ll[t] = np.where(seen, ll, 0.0)
    return IMMResult(np.ascontiguousarray(out_x.transpose(2, 0, 1)),
                     np.ascontiguousarray(out_P.transpose(3, 0, 1, 2)),
                     np.ascontiguousarray(out_mu.transpose(2, 0, 1)),
                     np.ascontiguousarray(out_xm.transpose(3, 0, 2, 1)),
                     np.ascontiguousarray(out_ll.T),
                     None if out_Pm is None else np.ascontiguousarray(out_Pm.transpose(4, 0, 3, 1, 2)))


def _known_input(carry, shift, B: int, T: int, n: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Step 3b's inputs entry-major, (carry (T, n, n, B), shift (T, n, B)), or (None, None)."""
    if (carry is None) != (shift is None):
        raise ValueError("carry and shift go together: give both or neither")
    if carry is None:
        return None, None
    if np.shape(carry) != (B, T, n, n) or np.shape(shift) != (B, T, n):
        raise ValueError(f"carry must be (B, T, n, n) = ({B}, {T}, {n}, {n}) and shift (B, T, n), "
                         f"got {np.shape(carry)} and {np.shape(shift)}")
    return (np.ascontiguousarray(np.transpose(np.asarray(carry, dtype=float), (1, 2, 3, 0))),
            np.ascontiguousarray(np.transpose(np.asarray(shift, dtype=float), (1, 2, 0))))


def _check(z, F, Q, R, x0, P0, Pi, mu0) -> None:
    B, T, n = z.shape
    M = F.shape[0]
    if F.shape != (M, n, n):
        raise ValueError(f"F must be (M, n, n) = ({M}, {n}, {n}), got {F.shape}")
    if Q.shape not in ((M, n, n), (B, T, M, n, n)):
        raise ValueError(f"Q must be (M, n, n) or (B, T, M, n, n), got {Q.shape}")
    if R.shape != (n, n):
        raise ValueError(f"R must be ({n}, {n}), got {R.shape}")
    if np.shape(x0) != (B, M, n) or np.shape(P0) != (M, n, n) or np.shape(mu0) != (M,):
        raise ValueError("x0 must be (B, M, n), P0 (M, n, n), mu0 (M,)")
    if Pi.shape not in ((M, M), (B, T, M, M)):
        raise ValueError(f"Pi must be (M, M) or (B, T, M, M), got {Pi.shape}")
    if not np.allclose(Pi.sum(axis=-1), 1.0, atol=1e-9) or (Pi < 0).any():
        raise ValueError("Pi rows must be probabilities summing to 1 (row = previous mode)")
    if not math.isclose(float(np.sum(mu0)), 1.0, abs_tol=1e-9):
        raise ValueError("mu0 must sum to 1")
