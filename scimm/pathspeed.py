"""Path-speed observation of a frame's labels and its inverse (paper eq. 2-3, docs/design.md §6.1).

The paper fits the future path with a quadratic ``y(s) = c0 + c1 s + c2 s^2`` and the speed
profile with ``v(tau) = v_ref + a_ref tau``, giving the observation
``z = [c0, c1, c2, v_ref, a_ref]`` (paper eq. 3). A lateral offset ``y`` as a function of the
forward coordinate cannot follow a junction turn (at 90 deg the path runs along the ego's
y axis and ``y(x)`` is not a function; a quadratic ``y(s)`` in arc length bends back at
90 deg too). We therefore keep the paper's quadratic, but in the path *heading* as a
function of arc length:

    psi(s) = c0 + c1 s + c2 s^2       [rad], s = arc length along the path [m]   (paper eq. 2)
    p(s)   = integral_0^s (cos psi, sin psi) ds'   ego frame (x forward, y left), p(0) = 0

so c0 is the path's initial heading in the ego frame [rad], c1 its curvature at the ego
[1/m] and c2 half its curvature rate [1/m^2]. For small angles y(s) = c0 s + c1 s^2/2 +
c2 s^3/3 (the paper's lateral quadratic integrated once); a circular arc (a junction turn of
any angle) is exactly ``psi = c0 + c1 s``. The dataset's path always starts at the ego
(p(0) = (0, 0), docs/dataset.md), so no offset term is lost.

Discretisation (the same in the fit and the inverse, so the round trip is exact):
the 20 path points are at s = 0, 1, ..., 19 m; the chord from point k to k+1 has length
1 m and heading psi(k + 1/2) (exact for a circular arc, whose chord points along the
tangent at its midpoint; the chord is 1 - 1/(24 R^2) m long, a 0.26 % shortfall at R = 4 m).

Speeds: the speed waypoints w_k (k = 1..10, at tau_k = 0.25 k s, ego frame, w_0 = the ego
at 0) give the label speeds of paper eq. 12, ``V_k = |w_k - w_{k-1}| / 0.25 s`` [m/s]: the mean
speed over (tau_k - 0.25, tau_k]. For a linear profile that mean is v(tau_k - 0.125), so
the fit and the inverse use those midpoint times; ``v_ref`` is then the speed at tau = 0
(now), ``a_ref`` the acceleration [m/s^2]. The speed teacher V^T[k] (k = 0..9, named "at
tau = 0.25 (k+1) s") is the same interval mean, comparable with eq. 12 of a prediction.

The speed fit is weighted, interval k by exp(-(tau_k - 0.125 s) / SPEED_WEIGHT_TAU): a real
profile is not a line (a stop within the 2.5 s bends it), and an unweighted line through
all ten speeds reads at tau = 0 part of what comes later; on the `val` dataset its v(0)
matched the expert's one frame (0.25 s) *ahead* better than the same frame. With a 0.6 s
weight the fitted v(0) matches the expert's v(0) of the same frame (mean |difference|
0.092 m/s, 0.153 one frame ahead); with 1 s it was 0.135 against 0.145, too close for a
teacher without delay (the IMM smoother, which then read one frame early), for an RMS fit
residual of 0.281 m/s over the ten speeds (0.239 with 1 s, 0.216 unweighted). A linear
profile is still fitted exactly. The price is the profile ahead: the line follows the next
second more and the rest less (docs/teacher.md, "Lag").

All functions are batched over any leading axes (frames, episodes).
"""
from __future__ import annotations

import numpy as np

N_PATH = 20          # path points at arc length 0, 1, ..., 19 m
PATH_STEP = 1.0      # arc length between path points [m]
N_SPEED = 10         # speed samples, tau = 0.25, 0.5, ..., 2.5 s
SPEED_DT = 0.25      # time between speed waypoints [s]
PATH_S = PATH_STEP * np.arange(N_PATH)                     # (20,) arc length of path points [m]
CHORD_S = PATH_S[:-1] + 0.5 * PATH_STEP                    # (19,) chord midpoints [m]
SPEED_TAU = SPEED_DT * np.arange(1, N_SPEED + 1)           # (10,) end of each speed interval [s]
SPEED_MID = SPEED_TAU - 0.5 * SPEED_DT                     # (10,) interval midpoints [s]
SPEED_WEIGHT_TAU = 0.6  # [s]: weight exp(-SPEED_MID / this) of each speed in the fit (docstring)
STATE_NAMES = ("c0", "c1", "c2", "v", "a")
STATE_UNITS = ("rad", "1/m", "1/m^2", "m/s", "m/s^2")

_HEADING_BASIS = np.stack([np.ones_like(CHORD_S), CHORD_S, CHORD_S ** 2], axis=-1)   # (19, 3)
_SPEED_BASIS = np.stack([np.ones_like(SPEED_MID), SPEED_MID], axis=-1)               # (10, 2)
_HEADING_PINV = np.linalg.pinv(_HEADING_BASIS)                                       # (3, 19)
_SPEED_SQRT_W = np.exp(-0.5 * SPEED_MID / SPEED_WEIGHT_TAU)                          # (10,) sqrt of the weights
_SPEED_PINV = np.linalg.pinv(_SPEED_BASIS * _SPEED_SQRT_W[:, None]) * _SPEED_SQRT_W  # (2, 10) weighted LS


def label_speeds(speed_wps: np.ndarray) -> np.ndarray:
    """(..., 10) label speeds [m/s] of paper eq. 12 from speed waypoints (..., 10, 2) [m, ego
    frame]: the distance between consecutive waypoints (the first from the ego) over 0.25 s."""
    w = np.asarray(speed_wps, dtype=float)
    prev = np.concatenate([np.zeros_like(w[..., :1, :]), w[..., :-1, :]], axis=-2)
    return np.linalg.norm(w - prev, axis=-1) / SPEED_DT


def chord_headings(path: np.ndarray) -> np.ndarray:
    """(..., 19) heading [rad] of each chord of a path (..., 20, 2) in the ego frame,
    unwrapped along the path (continuous through turns beyond +-pi)."""
    d = np.diff(np.asarray(path, dtype=float), axis=-2)
    return np.unwrap(np.arctan2(d[..., 1], d[..., 0]), axis=-1)


def path_coefficients(path: np.ndarray) -> np.ndarray:
    """[c0, c1, c2] (..., 3) of the heading quadratic fitted (least squares) to a path
    (..., 20, 2) [m, ego frame]; exact for a path made by ``state_path``."""
    return chord_headings(path) @ _HEADING_PINV.T


def observe(path: np.ndarray, speed_wps: np.ndarray) -> np.ndarray:
    """Observation z (..., 5) = [c0, c1, c2, v_ref, a_ref] (paper eq. 3) by least squares
    (the speeds weighted, module docstring) from the path (..., 20, 2) and speed waypoints
    (..., 10, 2), ego frame [m]."""
    c = path_coefficients(path)  # (..., 3)
    va = label_speeds(speed_wps) @ _SPEED_PINV.T  # (..., 2)
    return np.concatenate([c, va], axis=-1)


def heading_at(x: np.ndarray, s: np.ndarray) -> np.ndarray:
    """psi(s) = c0 + c1 s + c2 s^2 [rad] of states x (..., 5) at arc lengths s (K,) [m] -> (..., K)."""
    x = np.asarray(x, dtype=float)
    return x[..., 0:1] + x[..., 1:2] * s + x[..., 2:3] * s ** 2  # paper eq. 2 (heading form)


def state_path(x: np.ndarray) -> np.ndarray:
    """(..., 20, 2) path points [m, ego frame] at s = 0..19 m of states x (..., 5)."""
    psi = heading_at(x, CHORD_S)
    steps = PATH_STEP * np.stack([np.cos(psi), np.sin(psi)], axis=-1)  # (..., 19, 2)
    start = np.zeros(steps.shape[:-2] + (1, 2))
    return np.concatenate([start, np.cumsum(steps, axis=-2)], axis=-2)


def state_speeds(x: np.ndarray) -> np.ndarray:
    """(..., 10) speed teacher [m/s]: mean speed over each 0.25 s interval ending at
    tau = 0.25..2.5 s, max(0, v(tau - 0.125)) = max(0, v + a (tau - 0.125)) of states x (..., 5).
    Label speeds are distances over time (paper eq. 12), never negative: a profile reaching
    zero inside the horizon is a stop, and stays at zero."""
    x = np.asarray(x, dtype=float)
    return np.maximum(x[..., 3:4] + x[..., 4:5] * SPEED_MID, 0.0)  # paper eq. 2 (speed), clamped at a stop


def residuals(path: np.ndarray, speed_wps: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fit residuals of observation z (..., 5) against its labels: (max point distance of the
    20 path points [m], RMS speed error over the 10 label speeds [m/s]), each (...,)."""
    dp = np.linalg.norm(state_path(z) - np.asarray(path, dtype=float), axis=-1).max(axis=-1)
    dv = np.sqrt(np.mean((state_speeds(z) - label_speeds(speed_wps)) ** 2, axis=-1))
    return dp, dv
