"""The five driving modes and every number of the IMM and its scene conditioning (SPEC §6.2-6.3,
paper §III.2-3, eq. 8-9), in one readable config.

State and observation (scimm.pathspeed, paper eq. 3), frame period dt = 0.25 s:

    x = [c0, c1, c2, v, a]   path heading at the ego [rad], curvature [1/m], half curvature
                             rate [1/m^2], speed [m/s], acceleration [m/s^2]; H = I.

Modes, in this order (index 0..4), each a linear transition F_j and base process noise Q0_j:

    0 Cruise        lane keeping: path coefficients nearly constant, acceleration fades
                    (a' = 0.85 a), small path noise.
    1 Turn          junction or curve: curvature c1 and its rate c2 change fast (large noise
                    on c0..c2); speed as Cruise with a little more noise.
    2 Deceleration  slowing or standing: constant acceleration (a' = a, v' = v + a dt), noise
                    on v rather than a (steady braking); path nearly constant.
    3 Avoidance     bypass or evasive move: the path heading c0 and curvature jump (large
                    noise on c0, c1); speed as Cruise.
    4 Recovery      back to the lane after a deviation: heading and curvature decay to the
                    lane's (c0' = 0.85 c0, c1' = 0.85 c1), moderate path noise.

Scene conditioning (paper eq. 8-9): the cues s_t (scimm.cues) are mapped to features
f(s_t) in [0, 1] (``features``); then

    A_t[i, j]  = sum_f f_t W_A[f, j]            a logit bonus for entering mode j (the same for
                                                every previous mode i; cf. input-driven
                                                transitions, notes imm.md §4)
    gamma_t^j  = exp(sum_f f_t W_gamma[f, j])   process-noise scale of mode j (> 0)

Fixed-IMM is A = 0, gamma = 1 (``fixed_adjustment``). Weights were tuned on the tuning
episodes only (docs/teacher.md).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from scimm.cues import column

MODES = ("Cruise", "Turn", "Deceleration", "Avoidance", "Recovery")
CRUISE, TURN, DECEL, AVOID, RECOVER = range(5)
DT = 0.25  # frame period [s] (4 Hz recording)

# Feature names of f(s_t), each in [0, 1]; scales say where a feature saturates.
FEATURES = ("turn_command", "curvature", "curvature_change", "lateral_offset", "lateral_change",
            "speed_drop", "stop_target", "vehicle", "walker", "light_or_stop",
            "changed_route", "recovery", "calm")


def _diag(*sd: float) -> np.ndarray:
    """Diagonal covariance from standard deviations in state order [rad, 1/m, 1/m^2, m/s, m/s^2]."""
    return np.diag(np.square(sd))


def _transition(path_decay: float, acc_decay: float) -> np.ndarray:
    """F (5, 5): c0, c1 multiplied by path_decay, c2 kept, v' = v + a dt, a' = acc_decay a."""
    F = np.eye(5)
    F[0, 0] = F[1, 1] = path_decay
    F[3, 4] = DT
    F[4, 4] = acc_decay
    return F


@dataclass(frozen=True)
class IMMConfig:
    """Every number of the five-mode IMM (units: state order [rad, 1/m, 1/m^2, m/s, m/s^2])."""

    # F_j: (path decay, acceleration decay) per mode; 1 = random walk / constant acceleration
    F: np.ndarray = field(default_factory=lambda: np.stack([
        _transition(1.0, 0.85),   # Cruise: acceleration fades (15 % per frame)
        _transition(1.0, 0.85),   # Turn
        _transition(1.0, 1.0),    # Deceleration: constant acceleration
        _transition(1.0, 0.85),   # Avoidance
        _transition(0.85, 0.85),  # Recovery: heading/curvature back to the lane, 15 % per frame
    ]))
    # Q0_j: base process noise per frame (standard deviations of the one-frame change)
    Q0: np.ndarray = field(default_factory=lambda: np.stack([
        _diag(0.005, 0.002, 0.0001, 0.10, 0.17),   # Cruise: quiet path
        _diag(0.04, 0.015, 0.0008, 0.20, 0.34),    # Turn: curvature changes quickly
        _diag(0.005, 0.002, 0.0001, 0.20, 0.10),   # Deceleration: speed changes, steady acceleration
        _diag(0.06, 0.02, 0.0010, 0.10, 0.17),     # Avoidance: heading jumps
        _diag(0.03, 0.01, 0.0005, 0.10, 0.17),     # Recovery
    ]))
    # R: observation noise of the fitted z (label noise: the speeds are position differences)
    R: np.ndarray = field(default_factory=lambda: _diag(0.02, 0.005, 0.0003, 1.3, 0.8))
    # P0: initial covariance of every mode (about one observation's uncertainty)
    P0: np.ndarray = field(default_factory=lambda: _diag(0.05, 0.02, 0.001, 1.0, 1.0))
    # Pi0[i, j] = P(mode j | previous mode i): sticky (0.90 stay); Avoidance tends to
    # Recovery, Recovery to Cruise
    Pi0: np.ndarray = field(default_factory=lambda: np.array([
        [0.90, 0.025, 0.025, 0.025, 0.025],
        [0.04, 0.90, 0.02, 0.02, 0.02],
        [0.04, 0.02, 0.90, 0.02, 0.02],
        [0.02, 0.02, 0.02, 0.90, 0.04],
        [0.04, 0.02, 0.02, 0.02, 0.90],
    ]))
    mu0: np.ndarray = field(default_factory=lambda: np.array([0.6, 0.1, 0.1, 0.1, 0.1]))
    # Feature scales: where each feature reaches 1
    curvature_scale: float = 0.08          # [1/m], a 12.5 m radius
    curvature_change_scale: float = 0.08   # [1/m] over the next 10 m
    lateral_offset_scale: float = 1.0      # [m]
    lateral_change_scale: float = 0.25     # [m per frame]
    speed_drop_scale: float = 2.0          # [m/s] above the target
    stop_target_speed: float = 2.0         # [m/s]: stop_target = 1 - target / this, >= 0
    # W_A[f, j]: logit bonus for entering mode j when feature f is 1 (columns in MODES order)
    W_A: np.ndarray = field(default_factory=lambda: np.array([
        # Cruise Turn  Decel  Avoid  Recover
        [0.0, 4.0, 0.0, 0.0, 0.0],   # turn_command: left/right command inside a junction
        [0.0, 2.0, 0.0, 0.0, 0.0],   # curvature
        [0.0, 1.0, 0.0, 0.0, 0.0],   # curvature_change
        [0.0, 0.0, 0.0, 0.5, 1.0],   # lateral_offset: off the centre line
        [0.0, 0.0, 0.0, 1.0, 0.0],   # lateral_change: moving sideways
        [0.0, 0.0, 2.0, 0.0, 0.0],   # speed_drop: above the target speed
        [0.0, 0.0, 3.0, 0.0, 0.0],   # stop_target: target speed near zero
        [0.0, 0.0, 0.5, 0.5, 0.0],   # vehicle hazard
        [0.0, 0.0, 0.5, 0.5, 0.0],   # walker hazard
        [0.0, 0.0, 1.0, 0.0, 0.0],   # light_or_stop hazard
        [0.0, 0.0, 0.0, 3.0, 0.0],   # changed_route: path shifted (bypass)
        [0.0, 0.0, 0.0, -2.0, 3.0],  # recovery: the shift is shrinking
        [2.0, 0.0, 0.0, 0.0, 0.0],   # calm: no other feature active
    ]))
    # W_gamma[f, j]: log noise scale of mode j when feature f is 1 (exp(1) = 2.7x)
    W_gamma: np.ndarray = field(default_factory=lambda: np.array([
        [0.0, 0.5, 0.0, 0.0, 0.0],   # turn_command
        [0.0, 0.0, 0.0, 0.0, 0.0],   # curvature
        [0.0, 0.0, 0.0, 0.0, 0.0],   # curvature_change
        [0.0, 0.0, 0.0, 0.0, 0.0],   # lateral_offset
        [0.0, 0.0, 0.0, 0.0, 0.0],   # lateral_change
        [0.0, 0.0, 0.5, 0.0, 0.0],   # speed_drop: abrupt slowing
        [0.0, 0.0, 0.0, 0.0, 0.0],   # stop_target
        [0.0, 0.0, 0.3, 0.5, 0.0],   # vehicle hazard
        [0.0, 0.0, 0.3, 0.5, 0.0],   # walker hazard
        [0.0, 0.0, 0.3, 0.0, 0.0],   # light_or_stop hazard
        [0.0, 0.0, 0.0, 0.5, 0.0],   # changed_route
        [0.0, 0.0, 0.0, 0.0, 0.0],   # recovery
        [0.0, 0.0, 0.0, 0.0, 0.0],   # calm
    ]))

    def __post_init__(self) -> None:
        M, n = len(MODES), 5
        shapes = {"F": (M, n, n), "Q0": (M, n, n), "R": (n, n), "P0": (n, n), "Pi0": (M, M), "mu0": (M,),
                  "W_A": (len(FEATURES), M), "W_gamma": (len(FEATURES), M)}
        for name, shape in shapes.items():
            if np.shape(getattr(self, name)) != shape:
                raise ValueError(f"IMMConfig.{name} must have shape {shape}, got {np.shape(getattr(self, name))}")
        if not np.allclose(self.Pi0.sum(axis=1), 1.0) or (self.Pi0 < 0).any():
            raise ValueError("IMMConfig.Pi0 rows must be probabilities summing to 1 (row = previous mode)")
        if not np.isclose(self.mu0.sum(), 1.0) or (self.mu0 < 0).any():
            raise ValueError("IMMConfig.mu0 must be probabilities summing to 1")

    def as_dict(self) -> dict:
        """Every parameter as plain lists/floats (for the teacher manifest)."""
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in self.__dict__.items()}


def features(s: np.ndarray, cfg: IMMConfig) -> np.ndarray:
    """Features f(s_t) (..., 13) in [0, 1], ``FEATURES`` order, from cue matrices s (..., 16)."""
    def clip(v):
        return np.clip(v, 0.0, 1.0)
    command = column(s, "command")
    f = {
        "turn_command": column(s, "junction") * np.isin(command, (1, 2)),
        "curvature": clip(np.abs(column(s, "curvature")) / cfg.curvature_scale),
        "curvature_change": clip(np.abs(column(s, "curvature_change")) / cfg.curvature_change_scale),
        "lateral_offset": clip(np.abs(column(s, "lateral_offset")) / cfg.lateral_offset_scale),
        "lateral_change": clip(np.abs(column(s, "lateral_change")) / cfg.lateral_change_scale),
        "speed_drop": clip(column(s, "speed_drop") / cfg.speed_drop_scale),
        "stop_target": clip(1.0 - column(s, "target_speed") / cfg.stop_target_speed),
        "vehicle": clip(column(s, "vehicle")),
        "walker": clip(column(s, "walker")),
        "light_or_stop": clip(np.maximum(column(s, "light"), column(s, "stop"))),
        "changed_route": clip(column(s, "changed_route")),
        "recovery": clip(column(s, "recovery")),
    }
    f["calm"] = 1.0 - np.max(np.stack(list(f.values()), axis=-1), axis=-1)
    return np.stack([f[name] for name in FEATURES], axis=-1).astype(float)


def scene_adjustment(s: np.ndarray, cfg: IMMConfig) -> tuple[np.ndarray, np.ndarray]:
    """(A (..., 5, 5) logit adjustments, gamma (..., 5) noise scales) of paper eq. 8-9 from
    cue matrices s (..., 16). Row i of A is the same for every previous mode i."""
    f = features(s, cfg)
    bonus = f @ cfg.W_A  # (..., 5): bonus for entering mode j
    A = np.broadcast_to(bonus[..., None, :], bonus.shape[:-1] + (5, 5)).copy()
    gamma = np.exp(f @ cfg.W_gamma)
    return A, gamma


def fixed_adjustment(shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-IMM: A = 0 (..., 5, 5) and gamma = 1 (..., 5) for leading shape ``shape``."""
    return np.zeros(shape + (5, 5)), np.ones(shape + (5,))
