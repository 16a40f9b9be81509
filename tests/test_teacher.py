"""Teacher signals (scimm.teacher, scimm.modes, scimm.cues), Table 2 metrics (scimm.table2)
and the ``teacher`` CLI. Complements tests/test_imm.py with the scene-conditioned items of
docs/design.md §6.2 (simplex, covariances, A = 0 and gamma = 1, batching) on the project's own five-mode config."""
from __future__ import annotations

import hashlib
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sumo_scimm.cli import main
from scimm import pathspeed as ps
from scimm.cues import CUES, cue_vector
from scimm.imm import imm_filter
from scimm.modes import AVOID, DECEL, MODES, RECOVER, TURN, IMMConfig, scene_adjustment
from scimm.scene import conditioned
from scimm.table2 import GROUPS, fit_residuals, frame_metrics, mode_meaning, table2
from scimm.teacher import run_imm

ROOT = Path(__file__).resolve().parents[1]

CUE_ARRAYS = ("command", "next_command", "cue_junction", "cue_curvature", "cue_curvature_change",
              "cue_lateral_offset", "cue_lateral_change", "cue_speed", "cue_target_speed", "cue_speed_drop",
              "flag_vehicle", "flag_leader", "flag_walker", "flag_light", "flag_stop",
              "cue_changed_route", "cue_recovery")


def synthetic_episode(T: int, turn: slice = slice(0, 0), seed: int = 0) -> dict[str, np.ndarray]:
    """Arrays of a made-up episode: straight driving at ~8 m/s with small label noise, and
    a left junction turn over frames ``turn``: command 1 inside a junction, the curvature at
    the ego rising to 0.12/m and back (a triangle), as when driving through the turn."""
    rng = np.random.default_rng(seed)
    x = np.zeros((T, 5))
    x[:, 1] = 0.0
    n = len(range(T)[turn])
    kappa = 0.12 * (1 - np.abs(np.linspace(-1, 1, n))) if n else np.zeros(0)
    x[turn, 1] = kappa
    x[:, 3] = 8.0
    x[:, :3] += rng.normal(0, [0.01, 0.002, 0.0001], (T, 3))
    speeds = ps.state_speeds(x) + rng.normal(0, 0.05, (T, 10))
    dist = np.cumsum(speeds * ps.SPEED_DT, axis=1)
    a = {"path": ps.state_path(x), "speed_wps": np.stack([dist, np.zeros_like(dist)], -1),
         "v": np.full(T, 8.0), "target_speed": np.full(T, 8.0),  # the ego pose: 2 m a frame along x
         "x": 2.0 * np.arange(T), "y": np.zeros(T), "yaw": np.zeros(T)}
    for k in CUE_ARRAYS:
        a[k] = np.zeros(T, dtype=bool if k.startswith("flag") else float)
    a["command"] = np.full(T, 4)
    a["next_command"] = np.full(T, 3)
    a["command"][turn] = 1
    a["cue_junction"][turn] = 1.0
    a["cue_curvature"][turn] = kappa
    a["cue_speed"] = a["v"].copy()
    a["cue_target_speed"] = a["target_speed"].copy()
    return a


def test_cue_vector_reads_the_dataset_cues_in_order():
    a = synthetic_episode(6, turn=slice(2, 4))
    a["flag_leader"][5] = True  # a leader counts as a vehicle hazard
    s = cue_vector(a)
    assert s.shape == (6, len(CUES)) == (6, 16)
    np.testing.assert_array_equal(s[:, CUES.index("command")], [4, 4, 1, 1, 4, 4])
    np.testing.assert_array_equal(s[:, CUES.index("junction")], [0, 0, 1, 1, 0, 0])
    np.testing.assert_array_equal(s[:, CUES.index("vehicle")], [0, 0, 0, 0, 0, 1])


def test_zero_weights_and_fixed_method_are_the_fixed_imm_exactly():
    a = synthetic_episode(40, turn=slice(10, 25))
    z, s = ps.observe(a["path"], a["speed_wps"])[None], cue_vector(a)[None]
    cfg = IMMConfig()
    Q0, R, P0 = cfg.noise()  # of the default path state
    x_fixed, mu_fixed = run_imm(z, s, "fixed", cfg)
    # the plain IMM with constant Pi0, Q0 (A = 0, gamma = 1 not even built)
    x0 = np.broadcast_to(z[:, 0][:, None], (1, 5, 5))
    plain = imm_filter(z, cfg.F, Q0, R, x0, np.broadcast_to(P0, (5, 5, 5)), cfg.Pi0, cfg.mu0)
    # softmax(log Pi0) re-normalises Pi0: equal to rounding, 1e-12 is far above it
    np.testing.assert_allclose(x_fixed, plain.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(mu_fixed, plain.mu, rtol=0, atol=1e-12)
    zero = IMMConfig(W_A=np.zeros_like(cfg.W_A), W_gamma=np.zeros_like(cfg.W_gamma))
    x_zero, mu_zero = run_imm(z, s, "scimm", zero)  # SC-IMM with A = 0, gamma = 1
    np.testing.assert_array_equal(x_zero, x_fixed)
    np.testing.assert_array_equal(mu_zero, mu_fixed)


def test_scene_adjustment_is_stochastic_and_keeps_structural_zeros():
    a = synthetic_episode(30, turn=slice(5, 20))
    cfg = IMMConfig()
    Q0, R, P0 = cfg.noise()  # of the default path state
    Pi0 = cfg.Pi0.copy()
    Pi0[CRUISE_ROW := 0, RECOVER] = 0.0  # Cruise never goes straight to Recovery
    Pi0[0] /= Pi0[0].sum()
    A, gamma = scene_adjustment(cue_vector(a)[None], cfg)
    A[..., RECOVER] += 50.0  # even a huge finite bonus
    Pi, Q = conditioned(Pi0, Q0, A, gamma)
    assert (Pi[..., CRUISE_ROW, RECOVER] == 0.0).all()
    np.testing.assert_allclose(Pi.sum(axis=-1), 1.0, rtol=0, atol=1e-12)
    assert (gamma > 0).all()
    np.testing.assert_allclose(Q, gamma[..., None, None] * Q0, rtol=0, atol=0)


def test_common_gamma_on_identical_modes_is_a_kalman_filter_with_scaled_noise():
    rng = np.random.default_rng(3)
    cfg = IMMConfig()
    Q0, R, P0 = cfg.noise()  # of the default path state
    T = 30
    z = rng.normal(size=(1, T, 5))
    # well-conditioned unit-scale matrices: the reduction is structural, not about our units
    F = np.broadcast_to(cfg.F[DECEL], (5, 5, 5))
    Q0 = np.broadcast_to((lambda a: a @ a.T + 0.1 * np.eye(5))(0.3 * rng.normal(size=(5, 5))), (5, 5, 5))
    R, P0 = 0.5 * np.eye(5), np.eye(5)
    g = rng.uniform(0.5, 3.0, (1, T))  # the same gamma for every mode, varying in time
    A = rng.normal(size=(1, T, 5, 5))  # any transitions: the modes cannot be told apart
    Pi, Q = conditioned(cfg.Pi0, Q0, A, np.repeat(g[..., None], 5, axis=-1))
    x0 = np.broadcast_to(z[:, 0][:, None], (1, 5, 5))
    res = imm_filter(z, F, Q, R, x0, np.broadcast_to(P0, (5, 5, 5)), Pi, cfg.mu0)
    x, P = z[0, 0].copy(), P0.copy()  # the Kalman filter, written out
    for t in range(T):
        x, P = F[0] @ x, F[0] @ P @ F[0].T + g[0, t] * Q0[0]
        K = P @ np.linalg.inv(P + R)
        x, P = x + K @ (z[0, t] - x), (np.eye(5) - K) @ P
        np.testing.assert_allclose(res.x[0, t], x, rtol=0, atol=1e-12)  # Joseph vs simple form: rounding only
    np.testing.assert_allclose(res.mu[0, -1], cfg.mu0 @ np.linalg.multi_dot(list(Pi[0])), atol=1e-12)


def test_scene_conditioned_posterior_is_a_distribution_and_mode_permutation_permutes_it():
    rng = np.random.default_rng(4)
    a = synthetic_episode(60, turn=slice(20, 40))
    cfg = IMMConfig()
    Q0, R, P0 = cfg.noise()  # of the default path state
    z = ps.observe(a["path"], a["speed_wps"])[None]
    A, gamma = scene_adjustment(cue_vector(a)[None], cfg)
    Pi, Q = conditioned(cfg.Pi0, Q0, A, gamma)
    x0 = np.broadcast_to(z[:, 0][:, None], (1, 5, 5))
    P0 = np.broadcast_to(P0, (5, 5, 5))
    res = imm_filter(z, cfg.F, Q, R, x0, P0, Pi, cfg.mu0)
    assert (res.mu >= 0).all()
    np.testing.assert_allclose(res.mu.sum(-1), 1.0, rtol=0, atol=1e-12)
    assert (np.linalg.eigvalsh(res.P) > -1e-10 * np.trace(res.P, axis1=-2, axis2=-1)[..., None]).all()
    p = rng.permutation(5)
    per = imm_filter(z, cfg.F[p], Q[:, :, p], R, x0, P0, Pi[..., p, :][..., :, p], cfg.mu0[p])
    np.testing.assert_allclose(per.mu, res.mu[..., p], rtol=0, atol=1e-12)
    np.testing.assert_allclose(per.x, res.x, rtol=0, atol=1e-10)  # same sum, other order


def test_turn_cues_make_turn_the_dominant_mode():
    a = synthetic_episode(60, turn=slice(20, 40))
    s, z = cue_vector(a)[None], ps.observe(a["path"], a["speed_wps"])[None]
    _, mu = run_imm(z, s, "scimm", IMMConfig())
    _, mu_fixed = run_imm(z, s, "fixed", IMMConfig())
    dom, dom_fixed = mu[0].argmax(-1), mu_fixed[0].argmax(-1)
    # the turn cues lift Turn on the turn frames (the very first has curvature 0 yet)
    assert (dom[21:40] == TURN).mean() >= 0.9 > (dom_fixed[21:40] == TURN).mean()
    assert (dom[45:] != TURN).all()


def test_frame_metrics_on_a_hand_computed_sequence():
    # three straight paths moving left 0.1 then 0.2 m; speeds 1, 2, 4 m/s everywhere
    path = np.zeros((3, 20, 2))
    path[..., 0] = np.arange(20)
    path[1, :, 1], path[2, :, 1] = 0.1, 0.3
    speed = np.array([1.0, 2.0, 4.0])[:, None] * np.ones((3, 10))
    m = frame_metrics(path, speed)
    np.testing.assert_allclose(m["speed_delta"], [np.nan, 1.0, 2.0])
    np.testing.assert_allclose(m["speed_jerk"], [np.nan, np.nan, abs(4 - 2 * 2 + 1) / 0.25 ** 2])  # 16
    np.testing.assert_allclose(m["lat_delta"], [np.nan, 0.1, 0.2], atol=1e-15)
    np.testing.assert_allclose(m["heading_delta"], [np.nan, 0.0, 0.0])
    np.testing.assert_allclose(m["lat_jerk"], [np.nan, 0.0, 0.0])
    # straight at 2 m/s, then the chord headings 0.05 + 0.1 k (curvature 0.1/m): a_lat 0 -> 2^2 0.1
    bent = path[:2].copy()
    psi = 0.1 * (np.arange(19) + 0.5)
    bent[1] = np.concatenate([[[0, 0]], np.cumsum(np.stack([np.cos(psi), np.sin(psi)], -1), 0)])
    m = frame_metrics(bent, 2.0 * np.ones((2, 10)))
    np.testing.assert_allclose(m["heading_delta"][1], 0.1 * 9.5)  # mean of 0.1 (k + 1/2), k = 0..18
    np.testing.assert_allclose(m["lat_jerk"][1], 0.4 / 0.25)


def test_table2_groups_by_the_scimm_mode_with_avoidance_and_recovery_merged():
    path = np.zeros((4, 20, 2))
    speed = np.array([0.0, 1.0, 1.0, 4.0])[:, None] * np.ones((4, 10))
    mu = np.eye(5)[[TURN, TURN, AVOID, RECOVER]]
    ep = {"raw": {"path": path, "speed": speed}, "scimm": {"path": path, "speed": speed, "mu": mu}}
    t = table2([ep], rows=("raw", "scimm")).set_index(["mode", "method"])
    # Turn frames 0, 1: speed delta defined at frame 1 only (1.0); A/R frames 2, 3: deltas 0 and 3
    assert t.loc[("Turn", "SC-IMM"), "speed_delta"] == 1.0
    assert t.loc[("Avoidance/Recovery", "Original Raw Expert"), "speed_delta"] == 1.5
    assert t.loc[("Avoidance/Recovery", "SC-IMM"), "frames"] == 2
    assert t.loc[("Avoidance/Recovery", "SC-IMM"), "speed_jerk"] == np.mean([1.0, 3.0]) / 0.0625
    assert math.isnan(t.loc[("Cruise", "SC-IMM"), "speed_delta"])


def test_table2_moving_only_leaves_out_frames_whose_three_frames_all_stood():
    """Deceleration frames 0-5 with the expert's speed v = 0, 0, 0, 0, 2, 2 [m/s] and label
    speeds equal to v. Moving frames (v > 0.1 at t, t-1 or t-2): 4 and 5. All frames: speed
    deltas (frame 1 on) 0, 0, 0, 2, 0 -> mean 0.4; moving only: frames 4, 5 -> (2 + 0) / 2 = 1.
    Speed jerk, moving only: frame 4 |2 - 0 + 0| / dt^2 = 32, frame 5 |2 - 4 + 0| / dt^2 = 32."""
    v = np.array([0.0, 0.0, 0.0, 0.0, 2.0, 2.0])
    path = np.zeros((6, 20, 2))
    speed = v[:, None] * np.ones((6, 10))
    ep = {"raw": {"path": path, "speed": speed}, "scimm": {"path": path, "speed": speed, "mu": np.eye(5)[[DECEL] * 6]},
          "v": v}
    every = table2([ep], rows=("raw",)).set_index(["mode", "method"]).loc[("Deceleration", "Original Raw Expert")]
    moving = table2([ep], rows=("raw",), moving_only=True).set_index(["mode", "method"]).loc[
        ("Deceleration", "Original Raw Expert")]
    assert (every["frames"], moving["frames"]) == (6, 2)
    assert every["speed_delta"] == 0.4 and moving["speed_delta"] == 1.0
    assert moving["speed_jerk"] == 32.0


def test_mode_meaning_counts_the_matching_dominant_modes():
    sit = np.array(["junction_turn", "junction_turn", "stopping", "bypass", "bypass", "cruise"])
    mu = np.eye(5)[[TURN, 0, DECEL, RECOVER, TURN, 0]]
    t = mode_meaning([sit], {"scimm": [mu]}).set_index("situation")
    assert t.loc["junction_turn", "scimm"] == 0.5
    assert t.loc["stopping", "scimm"] == 1.0
    assert t.loc["bypass", "scimm"] == 0.5
    assert t.loc["bypass", "modes"] == "Avoidance/Recovery"


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    folder = tmp_path_factory.mktemp("data")
    (folder / "episodes").mkdir()
    for stem, T in (("0_rep0", 23), ("1_rep0", 41), ("2_rep0", 7)):
        np.savez(folder / "episodes" / f"{stem}.npz", **synthetic_episode(T, turn=slice(5, 15), seed=T))
    return folder


def test_teacher_cli_writes_the_contract_files(dataset, capsys):
    assert main(["teacher", "--data", str(dataset), "--method", "all"]) == 0
    out = capsys.readouterr().out
    assert "Original Raw Expert" in out
    assert "junction_turn" in out
    for method in ("fixed", "scimm", "smoother"):
        folder = dataset / "teacher" / method
        for stem, T in (("0_rep0", 23), ("1_rep0", 41), ("2_rep0", 7)):
            with np.load(folder / f"{stem}.npz") as f:
                assert f["path"].shape == (T, 20, 2)
                assert f["path"].dtype == np.float32
                assert f["speed"].shape == (T, 10)
                assert f["speed"].dtype == np.float32
                assert f["mu"].shape == (T, 5)
                assert f["mu"].dtype == np.float32
                np.testing.assert_allclose(f["mu"].sum(-1), 1.0, atol=1e-6)  # float32 rounding
        meta = json.loads((folder / "manifest.json").read_text())
        assert meta["method"] == method
        assert meta["episodes"] == 3
        assert meta["modes"] == list(MODES)
        assert not list(folder.glob("*.tmp"))
    table = pd.read_csv(dataset / "teacher" / "table2.csv")
    assert len(table) == 4 * 4
    assert set(table["method"]) == {"Original Raw Expert", "Fixed-IMM", "SC-IMM", "IMM smoother"}
    assert "Lag against the expert" in out
    lag = pd.read_csv(dataset / "teacher" / "lag.csv")
    assert len(lag) == 4 * 3
    still = pd.read_csv(dataset / "teacher" / "standstill.csv")
    stops = pd.read_csv(dataset / "teacher" / "stops_starts.csv")
    assert list(stops["situation"]) == ["red light"] * 4 + ["start"] * 4 and "Stops and starts" in out
    assert list(still["method"]) == ["Original Raw Expert", "Fixed-IMM", "SC-IMM", "IMM smoother"]
    res = pd.read_csv(dataset / "teacher" / "fit_residuals.csv")
    assert "Fit residual" in out
    assert list(res["mode"]) == list(GROUPS)
    assert res["frames"].sum() == 23 + 41 + 7 == table[table["method"] == "SC-IMM"]["frames"].sum()


def _teacher_digest(folder: Path) -> str:
    """sha256 of SC-IMM's fused states and mode posteriors on episode 1_rep0 of ``folder``."""
    x, mu = run_imm(*_inputs(folder), "scimm", IMMConfig())
    assert np.isfinite(mu).all() and mu.std() > 0  # not a trivial constant output
    return hashlib.sha256(x.tobytes() + mu.tobytes()).hexdigest()


def test_teacher_is_deterministic_across_processes(dataset):
    """The same inputs give the same bits in a fresh interpreter (its own hash seed, thread
    pool and allocations), not only twice in one process."""
    code = f"from tests.test_teacher import _teacher_digest; print(_teacher_digest(Path({str(dataset)!r})))"
    fresh = subprocess.run([sys.executable, "-c", "from pathlib import Path; " + code], cwd=ROOT,
                           capture_output=True, text=True, check=True, timeout=120)
    assert fresh.stdout.strip() == _teacher_digest(dataset)


def _inputs(folder):
    with np.load(folder / "episodes" / "1_rep0.npz") as a:
        return ps.observe(a["path"], a["speed_wps"])[None], cue_vector(a)[None]


@pytest.mark.parametrize("argv, message", [
    (["teacher"], "--data DIR is required"),
    (["teacher", "--data", "/nonexistent"], "not a dataset folder"),
    (["teacher", "--data", ".", "--method", "kalman"], "invalid choice"),
    (["teacher", "plot", "--data", "/nonexistent", "--episode", "0_rep0", "--out", "x.png"], "not a dataset folder"),
    (["teacher", "plot", "--data", "DATA", "--episode", "9_rep9", "--out", "x.png"], "no episode '9_rep9'"),
    (["teacher", "plot", "--data", "DATA", "--episode", "0_rep0", "--out", "x.jpg"], "must end in .png"),
    (["teacher", "plot", "--data", "DATA", "--episode", "0_rep0"], "--out"),
])
def test_teacher_cli_bad_input_is_one_line_and_exit_2(argv, message, dataset, capsys):
    argv = [str(dataset) if a == "DATA" else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("sumo-scimm: error: ")
    assert message in err
    assert err.count("\n") == 1


def test_fit_residuals_are_zero_for_representable_labels_and_grouped_by_dominant_mode():
    """docs/design.md §6.1's residual per mode. Cruise frames: labels made from states (an arc with a
    curvature rate; a linear speed profile), which z represents exactly. Turn frames: a
    path with a 90 deg kink (no quadratic heading follows a step) and a speed step, whose
    RMS residual is checked against numpy's own weighted least-squares line (np.polyfit,
    whose w multiplies the residuals: the square roots of scimm.pathspeed's weights)."""
    x = np.array([[0.02, 0.05, -0.001, 6.0, -1.0], [0.0, -0.03, 0.0005, 3.0, 0.5], [0.1, 0.0, 0.0, 8.0, 0.0]])
    tau = ps.SPEED_TAU
    along = x[:, 3:4] * tau + 0.5 * x[:, 4:5] * tau ** 2  # distance driven by tau [m]: speeds stay > 0
    cruise = {"path": ps.state_path(x), "speed_wps": np.stack([along, np.zeros_like(along)], axis=-1),
              "mu": np.tile([0.9, 0.1, 0.0, 0.0, 0.0], (3, 1))}
    kink = np.concatenate([np.stack([np.arange(10.0), np.zeros(10)], -1),
                           np.stack([np.full(10, 9.0), np.arange(1.0, 11.0)], -1)])  # 90 deg left at 9 m
    v = np.array([4.0, 4, 4, 4, 4, 6, 6, 6, 6, 6])
    wps = np.stack([np.cumsum(v * ps.SPEED_DT), np.zeros(10)], axis=-1)
    turn = {"path": np.stack([kink, kink]), "speed_wps": np.stack([wps, wps]),
            "mu": np.array([[0.1, 0.6, 0.1, 0.1, 0.1], [0.0, 0.5, 0.0, 0.4, 0.1]])}
    table = fit_residuals([cruise, turn]).set_index("mode")
    assert list(table.index) == list(GROUPS)
    assert table.loc["Cruise", "frames"] == 3
    assert table.loc["Turn", "frames"] == 2
    # an exact round trip
    assert table.loc["Cruise", "path_max"] < 1e-9
    assert table.loc["Cruise", "speed_p95"] < 1e-9
    slope, icpt = np.polyfit(ps.SPEED_MID, v, 1, w=np.exp(-0.5 * ps.SPEED_MID / ps.SPEED_WEIGHT_TAU))
    rms = np.sqrt(np.mean((icpt + slope * ps.SPEED_MID - v) ** 2))
    np.testing.assert_allclose(table.loc["Turn", ["speed_mean", "speed_p95"]].to_numpy(float), rms, rtol=1e-9)
    # the kink's heading jumps by pi/2 between chords 8 and 9; the best quadratic misses
    # the corner by metres (1.90 m here; > 1 m leaves room for any least-squares solver)
    assert table.loc["Turn", "path_mean"] > 1.0
    assert table.loc["Turn", "path_mean"] == table.loc["Turn", "path_max"]
    assert table.loc["Deceleration", "frames"] == 0
    assert np.isnan(table.loc["Deceleration", "path_mean"])


def test_moved_metrics_take_out_the_egos_own_motion():
    """A world-fixed road (20 m straight, a 90 deg arc of radius 10 m, straight again, its
    vertices 1 m apart) seen from an ego that advances one vertex a frame: every frame's
    labels are the same road, so the moved deltas are 0 (to rounding), while the plain
    ones see the arc come into view. A label shifted 0.1 m sideways in one frame then
    scores exactly 0.1 m at that frame and the next."""
    from scimm.table2 import moved_metrics
    R, theta = 10.0, 2 * np.arcsin(0.05)  # chord of 1 m on the arc
    arc = [(20 + R * np.sin(j * theta), R - R * np.cos(j * theta)) for j in range(1, int((np.pi / 2) / theta) + 1)]
    end, last = np.array(arc[-1]), theta * len(arc)
    after = [end + k * np.array([np.cos(last), np.sin(last)]) for k in range(1, 25)]
    road = np.array([(float(i), 0.0) for i in range(21)] + arc + after)
    T = 30
    heading = np.arctan2(*np.diff(road, axis=0)[:, ::-1].T)
    pose = np.array([(road[i, 0], road[i, 1], heading[i]) for i in range(T)])
    c, s = np.cos(pose[:, 2])[:, None], np.sin(pose[:, 2])[:, None]
    rel = np.stack([road[i:i + 20] - road[i] for i in range(T)])  # (T, 20, 2) world offsets
    path = np.stack([c * rel[..., 0] + s * rel[..., 1], -s * rel[..., 0] + c * rel[..., 1]], axis=-1)
    speed = 5 + np.sin(np.arange(T)[:, None] + np.arange(10)[None, :])  # v_t(k) = v_t-1(k + 1)
    moved, plain = moved_metrics(path, speed, pose), frame_metrics(path, speed)
    for m in ("lat_delta_moved", "heading_delta_moved", "speed_delta_moved"):
        assert np.isnan(moved[m][0]), m
        assert np.nanmax(moved[m]) < 1e-9, m
    assert np.nanmax(plain["lat_delta"]) > 0.5
    assert np.nanmax(plain["heading_delta"]) > 0.05
    assert np.nanmin(plain["speed_delta"]) > 0.1
    path[12, :, 1] += 0.1  # one frame's label moved sideways (in its own ego frame)
    lat = moved_metrics(path, speed, pose)["lat_delta_moved"]
    np.testing.assert_allclose(lat[[12, 13]], 0.1, atol=1e-9)
    assert np.nanmax(np.delete(lat, [12, 13])) < 1e-9


def test_table2_says_how_far_each_row_is_from_the_raw_labels():
    """Two frames; the teacher's speeds are the raw ones + 0.5 m/s at frame 1 only, its path
    0.2 m to the left at both: from-raw speed 0 and 0.5 (mean 0.25), lat 0.2; raw scores 0."""
    path = np.zeros((2, 20, 2))
    path[..., 0] = np.arange(20)
    speed = np.full((2, 10), 3.0)
    t_path, t_speed = path.copy(), speed.copy()
    t_path[..., 1] += 0.2
    t_speed[1] += 0.5
    ep = {"raw": {"path": path, "speed": speed},
          "scimm": {"path": t_path, "speed": t_speed, "mu": np.eye(5)[[0, 0]]}}
    t = table2([ep], rows=("raw", "scimm")).set_index(["mode", "method"])
    assert t.loc[("Cruise", "SC-IMM"), "speed_from_raw"] == 0.25
    np.testing.assert_allclose(t.loc[("Cruise", "SC-IMM"), "lat_from_raw"], 0.2, rtol=1e-15)
    assert t.loc[("Cruise", "Original Raw Expert"), ["speed_from_raw", "lat_from_raw"]].tolist() == [0.0, 0.0]


def test_scene_adjustment_adds_a_stay_bonus_for_a_mode_its_cues_support():
    """A[i, j] = b_j + stay_gain max(b_j, 0) [i = j], b = f W_A: off the diagonal every row
    is b; on it, a supported mode gets the extra bonus, an opposed one (b_j < 0) none."""
    from scimm.modes import features
    a = synthetic_episode(30, turn=slice(5, 20))
    s = cue_vector(a)
    s[25, CUES.index("recovery")] = 1.0  # b_Avoidance < 0 there
    cfg = IMMConfig()
    b = features(s, cfg) @ cfg.W_A
    A, _ = scene_adjustment(s, cfg)
    off = ~np.eye(5, dtype=bool)
    np.testing.assert_array_equal(A[:, off], np.broadcast_to(b[:, None, :], A.shape)[:, off])
    np.testing.assert_array_equal(np.diagonal(A, axis1=1, axis2=2), b + cfg.stay_gain * np.maximum(b, 0.0))
    assert b[25, AVOID] < 0
    assert A[25, AVOID, AVOID] == b[25, AVOID]
    none, _ = scene_adjustment(s, IMMConfig(stay_gain=0.0))
    np.testing.assert_array_equal(none, np.broadcast_to(b[:, None, :], A.shape))
