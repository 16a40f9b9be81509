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
    5. S_j = Pbar^j + R,  K_j = Pbar^j S_j^-1,  nu_j = z - xbar^j
       x^j = xbar^j + K_j nu_j
       P^j = (I - K_j) Pbar^j (I - K_j)^T + K_j R K_j^T   Joseph form: stays PSD for any gain
    6. log L_j = -1/2 (|C_j^-1 nu_j|^2 + 2 sum log diag C_j + n log 2 pi),  S_j = C_j C_j^T
    7. log mu^j = log cbar_j + log L_j - logsumexp_j(...)            log space: no underflow
    8. x = sum_j mu^j x^j,  P = sum_j mu^j [P^j + (x^j - x)(x^j - x)^T]   fused output

A frame whose measurement has a NaN skips 5-7 (x^j = xbar^j, mu = cbar).
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
    loglik (B,T) = log p(z_t | z_<t)."""

    x: np.ndarray
    P: np.ndarray
    mu: np.ndarray
    x_modes: np.ndarray
    loglik: np.ndarray


def _logsumexp(a: np.ndarray, axis: int) -> np.ndarray:
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    return np.squeeze(m, axis) + np.log(np.sum(np.exp(a - m), axis=axis))


def _sym(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + np.swapaxes(P, -1, -2))


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
        log_pi = np.log(Pi)
        log_mu = np.broadcast_to(np.log(np.asarray(mu0, dtype=float)), (B, M)).copy()
    x = np.array(np.broadcast_to(x0, (B, M, n)), dtype=float)
    P = np.array(np.broadcast_to(P0, (B, M, n, n)), dtype=float)
    Ft = np.swapaxes(F, -1, -2)
    eye = np.eye(n)
    out_x, out_P = np.empty((B, T, n)), np.empty((B, T, n, n))
    out_mu, out_xm, out_ll = np.empty((B, T, M)), np.empty((B, T, M, n)), np.empty((B, T))
    for t in range(T):
        lp = log_pi if log_pi.ndim == 2 else log_pi[:, t]  # (M,M) or (B,M,M)
        # 1-2: mixing in log space
        a = log_mu[:, :, None] + lp  # (B, i, j)
        log_cbar = _logsumexp(a, axis=1)  # (B, j)
        W = np.exp(a - np.where(np.isfinite(log_cbar), log_cbar, 0.0)[:, None, :])  # (B, i, j)
        Wt = np.swapaxes(W, 1, 2)  # (B, j, i)
        # 3: mixed initial conditions, spread about x0^j
        xm = Wt @ x  # (B, j, n)
        d = x[:, None, :, :] - xm[:, :, None, :]  # (B, j, i, n)
        Pm = (Wt @ P.reshape(B, M, n * n)).reshape(B, M, n, n) + np.swapaxes(d * Wt[..., None], -1, -2) @ d
        # 4: predict
        xbar = (F[None] @ xm[..., None])[..., 0]  # (B, M, n)
        Qt = Q if Q.ndim == 3 else Q[:, t]
        Pbar = _sym(F[None] @ Pm @ Ft[None] + Qt)
        # 5-6: update (H = I) and log-likelihoods from the Cholesky factor of S
        S = Pbar + R
        C = np.linalg.cholesky(S)
        Cinv = np.linalg.inv(C)
        Sinv = np.swapaxes(Cinv, -1, -2) @ Cinv
        K = Pbar @ Sinv
        zt = z[:, t]
        seen = ~np.isnan(zt).any(axis=1)  # (B,)
        nu = np.where(seen[:, None, None], zt[:, None, :] - xbar, 0.0)
        x_new = xbar + (K @ nu[..., None])[..., 0]
        IK = eye - K
        P_new = _sym(IK @ Pbar @ np.swapaxes(IK, -1, -2) + K @ R @ np.swapaxes(K, -1, -2))
        e = (Cinv @ nu[..., None])[..., 0]
        log_l = -0.5 * (np.sum(e * e, axis=-1) + 2 * np.sum(np.log(np.diagonal(C, axis1=-2, axis2=-1)), axis=-1)
                        + n * LOG_2PI)
        # 7: posterior mode probabilities
        a_post = log_cbar + log_l
        ll = _logsumexp(a_post, axis=1)
        log_mu = np.where(seen[:, None], a_post - ll[:, None], log_cbar)
        x = np.where(seen[:, None, None], x_new, xbar)
        P = np.where(seen[:, None, None, None], P_new, Pbar)
        # 8: fused output
        mu = np.exp(log_mu)
        xf = np.sum(mu[..., None] * x, axis=1)
        dx = x - xf[:, None, :]
        Pf = np.sum(mu[..., None, None] * (P + dx[..., :, None] * dx[..., None, :]), axis=1)
        out_x[:, t], out_P[:, t], out_mu[:, t], out_xm[:, t] = xf, _sym(Pf), mu, x
        out_ll[:, t] = np.where(seen, ll, 0.0)
    return IMMResult(out_x, out_P, out_mu, out_xm, out_ll)


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
