"""Interacting Multiple Model filter, batched over sequences with NumPy (paper eq. 4-7).

Symbols (Bar-Shalom, Li & Kirubarajan 2001, ch. 11; notes imm.md §1):

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
    4. xbar^j  = F_j x0^j,   Pbar^j = F_j P0^j F_j^T + Q_j          predict
    5. S_j = Pbar^j + R = C_j C_j^T (Cholesky),  K_j = Pbar^j S_j^-1 = I - R S_j^-1,
       nu_j = z - xbar^j,  x^j = xbar^j + K_j nu_j
       P^j = (I - K_j) Pbar^j (I - K_j)^T + K_j R K_j^T   Joseph form: stays PSD for any gain
    6. log L_j = -1/2 (|C_j^-1 nu_j|^2 + 2 sum log diag C_j + n log 2 pi)
    7. log mu^j = log cbar_j + log L_j - logsumexp_j(...)            log space: no underflow
    8. x = sum_j mu^j x^j,  P = sum_j mu^j [P^j + (x^j - x)(x^j - x)^T]   fused output

A frame whose measurement has a NaN skips 5-7 (x^j = xbar^j, P^j = Pbar^j, mu = cbar).

Speed (``sumo-scimm bench``). Tiny per-sequence 5 x 5 matrix operations are slow in NumPy, long
vector operations are fast, so every array keeps the batch axis B last and contiguous
(x (M, n, B), P (M, n, n, B)); products of per-sequence matrices are einsums whose inner loop
runs over B, products with a shared matrix (F_j, R) are single BLAS calls over all sequences,
and the 5 x 5 Cholesky factor and its triangular inverse are unrolled row by row over B.
Step 3 takes the spread about the previous fused mean xf instead of x0^j:
sum_i w_ij (P^i + d_i d_i^T) - (x0^j - xf)(x0^j - xf)^T with d_i = x^i - xf, the same
matrix; the subtraction only cancels at the scale of the spread between modes, not of x.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

LOG_2PI = math.log(2 * math.pi)


@dataclass(frozen=True)
class IMMResult:
    """Posterior of every frame: fused x (B,T,n), P (B,T,n,n), mode probabilities mu (B,T,M),
    mode-matched means x_modes (B,T,M,n), and the one-step predictive log-likelihood
    loglik (B,T) = log p(z_t | z_<t) (0 on a frame without measurement)."""

    x: np.ndarray
    P: np.ndarray
    mu: np.ndarray
    x_modes: np.ndarray
    loglik: np.ndarray


def _logsumexp(a: np.ndarray, axis: int) -> np.ndarray:
    """logsumexp over one axis; a slice that is all -inf gives -inf."""
    m = np.max(a, axis=axis, keepdims=True)
    m[~np.isfinite(m)] = 0.0
    return np.squeeze(m, axis) + np.log(np.sum(np.exp(a - m), axis=axis))


def _cholesky(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower Cholesky factor C of the SPD stack S (M, n, n, B), reading its lower triangle,
    column by column; returns C and 1 / diag(C) (M, n, B)."""
    n = S.shape[1]
    C = np.zeros_like(S)
    inv_d = np.empty((S.shape[0], n, S.shape[3]))
    for j in range(n):
        s = S[:, j:, j] - np.einsum("mikb,mkb->mib", C[:, j:, :j], C[:, j, :j]) if j else S[:, j:, j]
        d = np.sqrt(s[:, 0])
        C[:, j, j] = d
        np.divide(1.0, d, out=inv_d[:, j])
        np.multiply(s[:, 1:], inv_d[:, j, None], out=C[:, j + 1:, j])
    return C, inv_d


def _tri_inverse(C: np.ndarray, inv_d: np.ndarray) -> np.ndarray:
    """Inverse of the lower-triangular stack C (M, n, n, B), row by row (forward substitution)."""
    n = C.shape[1]
    W = np.zeros_like(C)
    for i in range(n):
        W[:, i, i] = inv_d[:, i]
        if i:
            s = np.einsum("mkb,mkjb->mjb", C[:, i, :i], W[:, :i, :i])
            np.multiply(s, -inv_d[:, i, None], out=W[:, i, :i])
    return W


def _mix(log_mu: np.ndarray, log_pi_t: np.ndarray, ZD: np.ndarray, n: int) -> tuple:
    """Steps 1-3. log_mu (M, B); log_pi_t[j, i] = log Pi_ij, (M, M, 1) or (M, M, B);
    ZD (M, n*n + n, B) holds P^i + d_i d_i^T then d_i = x^i - xf for each mode i.
    Returns log cbar (M, B), x0^j - xf (M, n, B) and P0^j (M, n, n, B)."""
    M, _, B = ZD.shape
    a = log_mu[None, :, :] + log_pi_t  # (j, i, B): log(Pi_ij mu^i)
    log_cbar = _logsumexp(a, axis=1)  # paper eq. 4, in log space
    a -= np.where(np.isfinite(log_cbar), log_cbar, 0.0)[:, None, :]  # a dead mode j mixes nothing
    w = np.exp(a, out=a)  # w[j, i] = w_ij
    mixed = np.einsum("jib,ieb->jeb", w, ZD)
    ym = mixed[:, n * n:]
    Pm = mixed[:, :n * n].reshape(M, n, n, B)
    Pm -= ym[:, :, None] * ym[:, None, :]
    return log_cbar, ym, Pm


def _predict(F: np.ndarray, xm: np.ndarray, Pm: np.ndarray, Q_t: np.ndarray) -> tuple:
    """Step 4 with F (M, n, n) as one BLAS call per mode over all sequences; Pbar symmetric."""
    M, n, _, B = Pm.shape
    FP = (F @ Pm.reshape(M, n, n * B)).reshape(M, n, n, B)
    FPt = np.ascontiguousarray(FP.transpose(0, 2, 1, 3)).reshape(M, n, n * B)
    Pb = (F @ FPt).reshape(M, n, n, B)  # (F P F^T)^T
    Pbar = Pb + Pb.transpose(0, 2, 1, 3)
    Pbar *= 0.5
    Pbar += Q_t
    return F @ xm, Pbar


def _update(xbar: np.ndarray, Pbar: np.ndarray, R: np.ndarray, nu: np.ndarray) -> tuple:
    """Steps 5-6 for H = I: posterior x (M, n, B), Joseph-form P (M, n, n, B) and log L (M, B)."""
    M, n, _, B = Pbar.shape
    C, inv_d = _cholesky(Pbar + R[None, :, :, None])
    W = _tri_inverse(C, inv_d)  # C^-1
    WT = np.ascontiguousarray(W.transpose(0, 2, 1, 3))
    e = np.einsum("makb,mkb->mab", W, nu)  # C^-1 nu
    # paper eq. 5 in log space: log det S = 2 sum log diag C
    log_l = np.sum(np.log(inv_d), axis=1) - 0.5 * (np.einsum("mab,mab->mb", e, e) + n * LOG_2PI)
    V1 = np.empty((M, n, 2 * n, B))  # [(I - K) Pbar | K R]
    V2 = np.empty((M, n, 2 * n, B))  # [I - K | K]
    IK, K = V2[:, :, :n], V2[:, :, n:]
    RWT = (R @ WT.reshape(M, n, n * B)).reshape(M, n, n, B)  # R C^-T
    np.einsum("makb,mckb->macb", RWT, WT, out=IK)  # I - K = R S^-1 = R C^-T C^-1
    np.subtract(np.eye(n)[None, :, :, None], IK, out=K)  # K = Pbar S^-1
    np.einsum("makb,mckb->macb", IK, Pbar, out=V1[:, :, :n])  # Pbar is symmetric
    np.matmul(R.T, K, out=V1[:, :, n:])  # (K R)[a, c] = sum_k R[k, c] K[a, k]
    P = np.einsum("makb,mckb->macb", V1, V2)  # (I-K) Pbar (I-K)^T + K R K^T
    x = xbar + np.einsum("makb,mkb->mab", K, nu)
    return x, P, log_l


def _fuse(mu: np.ndarray, x: np.ndarray, P: np.ndarray, ZD: np.ndarray) -> np.ndarray:
    """Step 8's mean xf (n, B) from mu (M, B), x (M, n, B); fills ZD (M, n*n + n, B) with
    P^j + d_j d_j^T and d_j = x^j - xf, which give the fused P and the next frame's mixing."""
    M, n, B = x.shape
    Zc, dx = ZD[:, :n * n].reshape(M, n, n, B), ZD[:, n * n:]
    xf = np.einsum("mb,mnb->nb", mu, x)  # paper eq. 7
    np.subtract(x, xf, out=dx)
    np.multiply(dx[:, :, None], dx[:, None, :], out=Zc)
    np.add(Zc, P, out=Zc)
    return xf


_CHUNK = 32  # frames of per-frame Pi and Q moved to the batch-last layout at once


def _frames_batch_last(Pi: np.ndarray, Q: np.ndarray, t: int) -> tuple:
    """log Pi and Q of frames t .. t + _CHUNK - 1 with the batch axis last: (k, j, i, B) with
    [j, i] = log Pi_ij, and (k, M, n, n, B); None for an argument that is shared by all frames.
    Gathering one frame at a time would read a (B,T,...) array with a stride of T frames."""
    log_pi = Q_t = None
    if Pi.ndim == 4:
        with np.errstate(divide="ignore"):
            log_pi = np.log(np.ascontiguousarray(Pi[:, t:t + _CHUNK].transpose(1, 3, 2, 0)))
    if Q.ndim == 5:
        Q_t = np.ascontiguousarray(Q[:, t:t + _CHUNK].transpose(1, 2, 3, 4, 0))
    return log_pi, Q_t


def imm_filter(z: np.ndarray, F: np.ndarray, Q: np.ndarray, R: np.ndarray, x0: np.ndarray,
               P0: np.ndarray, Pi: np.ndarray, mu0: np.ndarray) -> IMMResult:
    """Run the IMM over B sequences of T frames.

    z (B,T,n) measurements (NaN = missing); F (M,n,n); Q (M,n,n) or per frame (B,T,M,n,n);
    R (n,n); x0 (B,M,n) initial mode means; P0 (M,n,n); Pi (M,M) row-stochastic (row =
    previous mode) or per frame (B,T,M,M); mu0 (M,). float64 throughout.
    """
    z = np.asarray(z, dtype=float)
    B, T, n = z.shape
    F, R = np.asarray(F, dtype=float), np.asarray(R, dtype=float)
    M = F.shape[0]
    Q, Pi = np.asarray(Q, dtype=float), np.asarray(Pi, dtype=float)
    _check(z, F, Q, R, x0, P0, Pi, mu0)
    with np.errstate(divide="ignore"):  # structural zeros of Pi are -inf logits, on purpose
        log_mu = np.repeat(np.log(np.asarray(mu0, dtype=float))[:, None], B, axis=1)  # (M, B)
        log_pi_fixed = np.log(Pi).T[:, :, None] if Pi.ndim == 2 else None  # [j, i] = log Pi_ij
    Q_fixed = Q[..., None] if Q.ndim == 3 else None
    zT = np.ascontiguousarray(np.transpose(z, (1, 2, 0)))  # (T, n, B)
    x = np.ascontiguousarray(np.transpose(np.asarray(x0, dtype=float), (1, 2, 0)))  # (M, n, B)
    P = np.repeat(np.asarray(P0, dtype=float)[..., None], B, axis=3)  # (M, n, n, B)
    out_x, out_P = np.empty((T, n, B)), np.empty((T, n, n, B))
    out_mu, out_xm, out_ll = np.empty((T, M, B)), np.empty((T, M, n, B)), np.empty((T, B))
    ZD = np.empty((M, n * n + n, B))  # per mode i: P^i + d_i d_i^T (n*n), then d_i = x^i - xf (n)
    xf = _fuse(np.exp(log_mu), x, P, ZD)
    for t in range(T):
        if t % _CHUNK == 0:  # per-frame Pi and Q, batch axis last, a few frames at a time
            log_pi_chunk, Q_chunk = _frames_batch_last(Pi, Q, t)
        log_pi_t = log_pi_fixed if log_pi_fixed is not None else log_pi_chunk[t % _CHUNK]
        log_cbar, ym, Pm = _mix(log_mu, log_pi_t, ZD, n)
        Q_t = Q_fixed if Q_fixed is not None else Q_chunk[t % _CHUNK]
        xbar, Pbar = _predict(F, xf + ym, Pm, Q_t)
        seen = ~np.isnan(zT[t]).any(axis=0)  # (B,)
        everything_seen = bool(seen.all())
        nu = np.subtract(zT[t] if everything_seen else np.where(seen, zT[t], 0.0), xbar)
        x, P, log_l = _update(xbar, Pbar, R, nu)
        a = log_cbar + log_l
        ll = _logsumexp(a, axis=0)
        log_mu = a - ll  # paper eq. 6, in log space
        if not everything_seen:
            log_mu = np.where(seen, log_mu, log_cbar)
            x, P = np.where(seen, x, xbar), np.where(seen, P, Pbar)
        mu = np.exp(log_mu)
        out_x[t] = xf = _fuse(mu, x, P, ZD)
        Pf = np.einsum("mb,meb->eb", mu, ZD[:, :n * n]).reshape(n, n, B)
        np.add(Pf, Pf.transpose(1, 0, 2), out=out_P[t])
        out_P[t] *= 0.5
        out_mu[t], out_xm[t], out_ll[t] = mu, x, np.where(seen, ll, 0.0)
    return IMMResult(np.ascontiguousarray(out_x.transpose(2, 0, 1)),
                     np.ascontiguousarray(out_P.transpose(3, 0, 1, 2)),
                     np.ascontiguousarray(out_mu.transpose(2, 0, 1)),
                     np.ascontiguousarray(out_xm.transpose(3, 0, 1, 2)),
                     np.ascontiguousarray(out_ll.T))


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
