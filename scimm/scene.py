"""Scene conditioning of the IMM (paper eq. 8-9): per frame, the transition matrix and the
process noise follow the scene cues s_t.

    Pi_t[i, :] = softmax_j(log Pi0[i, j] + A_t[i, j])      (paper eq. 8)
    Q_t^j      = gamma_t^j Q0^j                            (paper eq. 9)

A_t (B,T,M,M) are logit adjustments and gamma_t (B,T,M) > 0 noise scales, both functions of
the cues (scimm.modes). Rows of Pi_t sum to 1 by construction; a row-constant offset in
A_t changes nothing; structural zeros of Pi0 (log 0 = -inf) stay exactly 0. Pi_t and Q_t
built from s_t govern the step t-1 -> t.
"""
from __future__ import annotations

import numpy as np


def conditioned(Pi0: np.ndarray, Q0: np.ndarray, A: np.ndarray, gamma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Pi_t (B,T,M,M), Q_t (B,T,M,n,n)) from Pi0 (M,M), Q0 (M,n,n), A (B,T,M,M), gamma (B,T,M)."""
    with np.errstate(divide="ignore"):
        logits = np.log(np.asarray(Pi0, dtype=float)) + np.asarray(A, dtype=float)  # paper eq. 8
    m = np.max(logits, axis=-1, keepdims=True)
    e = np.exp(logits - m)
    Pi = e / e.sum(axis=-1, keepdims=True)
    Q = np.asarray(gamma, dtype=float)[..., None, None] * np.asarray(Q0, dtype=float)  # paper eq. 9
    return Pi, Q
