"""The five driving modes and every number of the IMM and its scene conditioning (docs/design.md §6.2-6.3,
paper §III.2-3, eq. 8-9), in one readable config.

State and observation (scimm.pathspeed, paper eq. 3), frame period dt = 0.25 s:

    x = [c0, c1, c2, v, a]   path heading at the ego [rad], curvature [1/m], half curvature
                             rate [1/m^2] (path_state "ego"; "plan": below), speed [m/s],
                             acceleration [m/s^2]; H = I.

Modes, in this order (index 0..4), each a linear transition F_j and base process noise Q0_j:

    0 Cruise        lane keeping: path coefficients nearly constant, acceleration fades
                    (a' = 0.7 a), small path noise.
    1 Turn          junction or curve: curvature c1 and its rate c2 change fast (large noise
                    on c0..c2); acceleration fades fast (a' = 0.2 a): through a turn the
                    speed changes show as noise on v, the profile stays nearly flat.
    2 Deceleration  slowing or standing: acceleration persists (a' = 0.75 a), noise on v and
                    a (braking sets in and eases off); path nearly constant.
    3 Avoidance     bypass or evasive move: the path heading c0 and curvature jump (large
                    noise on c0, c1); acceleration fades (a' = 0.45 a).
    4 Recovery      back to the lane after a deviation: heading and curvature decay to the
                    lane's (c0' = 0.85 c0, c1' = 0.85 c1), moderate path noise; speed as
                    Avoidance.

Scene conditioning (paper eq. 8-9): the cues s_t (scimm.cues) are mapped to features
f(s_t) in [0, 1] (``features``); then

    b_t[j]     = sum_f f_t W_A[f, j]            the cues' logit bonus for entering mode j
                                                (cf. input-driven transitions, docs/design.md §6.3)
    A_t[i, j]  = b_t[j] + stay_gain max(b_t[j], 0) [i = j]
                                                the same for every previous mode i, plus a
                                                bonus for staying in a mode the cues support
    gamma_t^j  = exp(sum_f f_t W_gamma[f, j])   process-noise scale of mode j (> 0)

With ``path_state="ego"`` the modes' states live in the ego frame of their frame; the
predict step first carries them into the current frame with the ego's recorded motion
(scimm.ego), the same for every mode, so F_j only says how the path and the speed profile
themselves change. With ``path_state="plan"`` (the default) c0, c1, c2 are instead the
teacher's lateral offset quadratic from the expert's previous plan [m, -, 1/m], rebased
and carried along that plan (scimm.planref); v and a are as above.

Fixed-IMM is A = 0, gamma = 1 (``fixed_adjustment``). Every number was chosen on the `val`
dataset only (docs/teacher.md).
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
    """Every number of the five-mode IMM (units: state order [rad, 1/m, 1/m^2, m/s, m/s^2]).

    Chosen on the `val` dataset only (docs/teacher.md, "How the numbers were chosen"). Every
    standard deviation below is a per-frame size estimated from the labels' per-situation
    statistics, times 1.9: a Kalman gain depends only on the ratios of Q, R and P, so the
    common factor leaves each mode's filter as it was, and flattens the mode likelihoods
    (their log ratios shrink by 1.9^2). With it the cue prior of eq. 8 holds a mode through the single-frame
    jolts of the labels (a path re-anchored, a target speed switching). With every noise at
    1 x and the cue weights at a fifth of W_A, SC-IMM's dominant mode changed 19.9 times a
    minute on `val`, 16.6 of them with no change of the cue-preferred mode; the noise x 2
    alone brought that to 13.2 (the Fixed-IMM's from 26.5 to 19.3).
    """

    # The speed entries (the acceleration decays in F, the v and a columns of Q0 and R) were
    # chosen together on `val` (docs/teacher.md, "How the numbers were chosen"): a line
    # v + a tau that follows the expert's v(0) without delay moves its far end with every
    # change of slope, so Speed delta (same tau, frame to frame) and the lag pull apart; on
    # `val` the values below keep every teacher's Speed delta at most 0.93 x the labels' in
    # every mode group, v(0) aligned at offset 0 and standing where the expert stands, with
    # the least lag into stops and out of them found (SC-IMM 1.25 s ahead: +0.29 m/s braking
    # for a red light, -0.37 starting off)
    # F_j: (path decay, acceleration decay) per mode; 1 = random walk / constant acceleration
    F: np.ndarray = field(default_factory=lambda: np.stack([
        _transition(1.0, 0.7),   # Cruise: acceleration fades (30 % a frame): the profile flattens
        _transition(1.0, 0.2),   # Turn: acceleration fades fast; a speed change shows in v's noise
        #   (the profile's slope through a junction is what moves its far end frame to frame)
        _transition(1.0, 0.75),  # Deceleration: acceleration persists through a braking
        #   (not constant: the Fixed-IMM, often in Deceleration through a junction, would carry
        #   a constant acceleration into the far speeds there)
        _transition(1.0, 0.45),  # Avoidance: acceleration fades
        _transition(0.85, 0.45),  # Recovery: heading and curvature back to the lane, 15 % a frame
    ]))
    # Q0_j: base process noise, standard deviations of the one-frame change, x 1.9
    # (path: what the fitted c0, c1, c2 change by from one frame to the next in each
    # situation; the ego's own motion is not in it, the predict step carries it)
    Q0: np.ndarray = field(default_factory=lambda: np.stack([
        _diag(0.0095, 0.0038, 0.00019, 0.15, 0.21),  # Cruise: quiet path, steady speed
        _diag(0.076, 0.028, 0.0015, 0.46, 0.34),     # Turn: curvature comes and goes; slowing into the turn
        _diag(0.0095, 0.0038, 0.00019, 0.23, 0.29),  # Deceleration: braking sets in and eases off
        _diag(0.11, 0.038, 0.0019, 0.44, 0.25),      # Avoidance: heading and curvature jump (a bypass starts)
        _diag(0.057, 0.019, 0.00095, 0.44, 0.25),    # Recovery: path between Cruise and Avoidance, speed as Avoidance
    ]))
    # R: how far the fitted z is from a smooth trajectory, x 1.9. Path: half the share of
    # the fit residual in c0, c1, c2 first estimated: the closer the teacher follows z, the
    # less its path moves in the world from frame to frame (the predict step carries a
    # curvature error into the heading, by c1 d + c2 d^2 over the d = 1-4 m driven; with
    # the full share the Cruise Lat delta with the motion taken out was 11.6 x the labels'
    # on `val`, with half 6.6 x). Speed: the labels are the expert's own future, so the
    # speed "noise" is only the straight line's misfit: 0.17 m/s and 0.22 m/s^2 (0.32 and
    # 0.42 after the x 1.9) keep the teachers' v(0) aligned with the expert's (offset 0
    # frames; 1.3 m/s against Q of 0.1-0.2 m/s lagged it one or two) and standing (<= 0.3
    # m/s) in >= 95 % of the `val` frames where the expert has stood 0.5 s (87 % with 1.3 m/s)
    R: np.ndarray = field(default_factory=lambda: _diag(0.019, 0.0048, 0.00029, 0.32, 0.42))
    # P0: initial covariance of every mode (about one observation's uncertainty, x 1.9)
    P0: np.ndarray = field(default_factory=lambda: _diag(0.095, 0.038, 0.0019, 1.9, 1.9))
    # Pi0[i, j] = P(mode j | previous mode i): sticky (0.97 stay: without cues a mode lasts
    # 33 frames, 8 s, on average; with 0.90 or 0.95 the Fixed-IMM's Cruise speed teacher
    # changed more from frame to frame than the labels on `val`); Avoidance tends to
    # Recovery, Recovery to Cruise
    Pi0: np.ndarray = field(default_factory=lambda: np.array([
        [0.97, 0.0075, 0.0075, 0.0075, 0.0075],
        [0.012, 0.97, 0.006, 0.006, 0.006],
        [0.012, 0.006, 0.97, 0.006, 0.006],
        [0.006, 0.006, 0.006, 0.97, 0.012],
        [0.012, 0.006, 0.006, 0.006, 0.97],
    ]))
    mu0: np.ndarray = field(default_factory=lambda: np.array([0.6, 0.1, 0.1, 0.1, 0.1]))
    # Path state: "plan", the teacher's lateral offset from the expert's previous plan
    # (scimm.planref), whose path states are in [m, -, 1/m] and use the plan_* noise below
    # in place of the path entries of Q0, R and P0; or "ego", the quadratic heading of each
    # frame's path in its ego frame (scimm.pathspeed, paper eq. 2-3), whose path moves in the
    # world up to 17 x as much as the expert's on the training set (docs/teacher.md)
    path_state: str = "plan"
    # plan_Q0_path[j]: sd of mode j's one-frame change of the offset quadratic, x 1.9: the RMS
    # plan change per frame (z_path) on `val` where SC-IMM's dominant mode is j (Cruise 0.0017
    # m, Turn 0.013, Deceleration 0.0028, Avoidance 0.006, Recovery 0.009), rounded up;
    # Avoidance takes Recovery's (both follow a re-planned bypass)
    plan_Q0_path: np.ndarray = field(default_factory=lambda: 1.9 * np.array([
        [0.002, 0.0005, 0.00003],  # Cruise: the plan lies still
        [0.013, 0.0024, 0.0001],   # Turn: re-planned through the junction
        [0.003, 0.0012, 0.00007],  # Deceleration
        [0.010, 0.0020, 0.0001],   # Avoidance: the bypass is re-planned
        [0.010, 0.0020, 0.0001],   # Recovery: as Avoidance
    ]))
    # plan_R_path: sd of the fitted plan change, x 1.9: c0 half of Deceleration's Q, c1 and c2
    # about two fifths and a third of it (0.0005, 0.000025 against 0.0012, 0.00007; the teacher
    # follows a lasting change within a few frames); with R twice this the Fixed-IMM's Cruise
    # path moved 1.14 x the plans' in the world on `val`, with this 1.07 x (docs/teacher.md)
    plan_R_path: np.ndarray = field(default_factory=lambda: 1.9 * np.array([0.0015, 0.0005, 0.000025]))
    # plan_P0_path: the first frame's teacher is the plan itself, known to about 3 R
    plan_P0_path: np.ndarray = field(default_factory=lambda: 1.9 * np.array([0.0045, 0.0015, 0.000075]))
    # Feature scales: where each feature reaches 1
    curvature_scale: float = 0.08          # [1/m], a 12.5 m radius
    curvature_change_scale: float = 0.08   # [1/m] over the next 10 m
    lateral_offset_scale: float = 1.0      # [m]
    lateral_change_scale: float = 0.25     # [m per frame]
    speed_drop_scale: float = 2.0          # [m/s] above the target
    stop_target_speed: float = 2.0         # [m/s]: stop_target = 1 - target / this, >= 0
    # extra logit for staying in mode j, per unit of its cue bonus: A[j, j] += 2 max(b_j, 0)
    # (a mode its cues support is left only when they stop supporting it; halves the
    # switches that a flickering cue, e.g. a target speed near the stop threshold, causes;
    # chosen with the speed settings above: SC-IMM switches 0.45 x as often as the
    # Fixed-IMM on `val`; 3.5 gives 0.43 x and every other target figure within 0.005)
    stay_gain: float = 2.0
    # W_A[f, j]: logit bonus for entering mode j when feature f is 1 (columns in MODES
    # order). Five times the relative sizes of docs/teacher.md: the cues must outweigh the
    # likelihood of a single frame (x 1: SC-IMM's dominant mode agreed with the
    # cue-preferred one in 69 % of the `val` frames, x 4: 86 %)
    W_A: np.ndarray = field(default_factory=lambda: np.array([
        # Cruise Turn  Decel  Avoid  Recover
        [0.0, 20.0, 0.0, 0.0, 0.0],   # turn_command: left/right command inside a junction
        [0.0, 10.0, 0.0, 0.0, 0.0],   # curvature
        [0.0, 5.0, 0.0, 0.0, 0.0],    # curvature_change
        [0.0, 0.0, 0.0, 2.5, 5.0],    # lateral_offset: off the centre line
        [0.0, 0.0, 0.0, 5.0, 0.0],    # lateral_change: moving sideways
        [0.0, 0.0, 10.0, 0.0, 0.0],   # speed_drop: above the target speed
        [0.0, 0.0, 15.0, 0.0, 0.0],   # stop_target: target speed near zero
        [0.0, 0.0, 2.5, 2.5, 0.0],    # vehicle hazard
        [0.0, 0.0, 2.0, 2.5, 0.0],    # walker hazard (a walker beside a bypass: still Avoidance)
        [0.0, 0.0, 5.0, 0.0, 0.0],    # light_or_stop hazard
        [0.0, 0.0, 0.0, 22.0, 0.0],   # changed_route: path shifted (bypass); beats a stop target
        [0.0, 0.0, 0.0, -10.0, 15.0],  # recovery: the shift is shrinking
        [10.0, 0.0, 0.0, 0.0, 0.0],   # calm: no other feature active
    ]))
    # W_gamma[f, j]: log noise scale of mode j when feature f is 1 (exp(1) = 2.7x)
    W_gamma: np.ndarray = field(default_factory=lambda: np.array([
        [0.0, 0.0, 0.0, 0.0, 0.0],   # turn_command (no extra noise: Turn's own is large; a scale
        #   of exp(0.5) let the profile through a junction move more from frame to frame, SC-IMM's
        #   Turn Speed delta 0.87 x the labels' on `val` against 0.85 x without)
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
                  "W_A": (len(FEATURES), M), "W_gamma": (len(FEATURES), M),
                  "plan_Q0_path": (M, 3), "plan_R_path": (3,), "plan_P0_path": (3,)}
        for name, shape in shapes.items():
            if np.shape(getattr(self, name)) != shape:
                raise ValueError(f"IMMConfig.{name} must have shape {shape}, got {np.shape(getattr(self, name))}")
        if self.path_state not in ("ego", "plan"):
            raise ValueError(f"IMMConfig.path_state must be 'ego' or 'plan', got {self.path_state!r}")
        if not np.allclose(self.Pi0.sum(axis=1), 1.0) or (self.Pi0 < 0).any():
            raise ValueError("IMMConfig.Pi0 rows must be probabilities summing to 1 (row = previous mode)")
        if not np.isclose(self.mu0.sum(), 1.0) or (self.mu0 < 0).any():
            raise ValueError("IMMConfig.mu0 must be probabilities summing to 1")

    def noise(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Q0 (5, 5, 5), R (5, 5), P0 (5, 5)) of the configured path state: the plan_* path
        noise in place of Q0's, R's and P0's path block when path_state is "plan"."""
        if self.path_state == "ego":
            return self.Q0, self.R, self.P0
        Q0, R, P0 = self.Q0.copy(), self.R.copy(), self.P0.copy()
        Q0[:, :3, :3] = np.stack([np.diag(np.square(sd)) for sd in self.plan_Q0_path])
        R[:3, :3] = np.diag(np.square(self.plan_R_path))
        P0[:3, :3] = np.diag(np.square(self.plan_P0_path))
        return Q0, R, P0

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
    cue matrices s (..., 16): A[i, j] = b_j + stay_gain max(b_j, 0) [i = j] (module
    docstring)."""
    f = features(s, cfg)
    bonus = f @ cfg.W_A  # (..., 5): bonus for entering mode j
    A = np.broadcast_to(bonus[..., None, :], bonus.shape[:-1] + (5, 5)).copy()
    i = np.arange(5)
    A[..., i, i] += cfg.stay_gain * np.maximum(bonus, 0.0)  # staying in a mode its cues support
    gamma = np.exp(f @ cfg.W_gamma)
    return A, gamma


def fixed_adjustment(shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-IMM: A = 0 (..., 5, 5) and gamma = 1 (..., 5) for leading shape ``shape``."""
    return np.zeros(shape + (5, 5)), np.ones(shape + (5,))
