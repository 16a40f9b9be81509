"""The batched IMM (scimm.imm) against exact reductions and filterpy's IMMEstimator
(the properties listed in docs/design.md §6.2)."""
from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import IMMEstimator, KalmanFilter

from scimm.imm import imm_filter
from scimm.scene import conditioned

N, M, T = 5, 5, 60
# Tolerances against filterpy: 1e-9 on states and posteriors is the equality docs/design.md
# §11 promises (the two differ in the order of their sums: about 1e-12 measured, `bench`);
# 1e-10 on a single mode's Kalman filter, where there is no mixing; 1e-12 where both sides
# run the same arithmetic.


def random_system(rng, m=M, n=N):
    F = np.eye(n) + 0.1 * rng.normal(size=(m, n, n))
    Q = np.stack([a @ a.T + 0.05 * np.eye(n) for a in 0.3 * rng.normal(size=(m, n, n))])
    R = (lambda a: a @ a.T + 0.2 * np.eye(n))(0.3 * rng.normal(size=(n, n)))
    Pi = rng.uniform(0.05, 1.0, size=(m, m)) + 3.0 * np.eye(m)
    Pi /= Pi.sum(axis=1, keepdims=True)  # non-symmetric, rows sum to 1
    mu0 = rng.uniform(0.2, 1.0, size=m)
    mu0 /= mu0.sum()
    P0 = np.stack([np.eye(n) * rng.uniform(0.5, 2.0) for _ in range(m)])
    return F, Q, R, Pi, mu0, P0


def simulate(rng, F, Q, R, Pi, B=3, T=T):
    n = F.shape[1]
    z = np.empty((B, T, n))
    for b in range(B):
        x, mode = rng.normal(size=n), 0
        for t in range(T):
            mode = rng.choice(len(Pi), p=Pi[mode])
            x = F[mode] @ x + rng.multivariate_normal(np.zeros(n), Q[mode])
            z[b, t] = x + rng.multivariate_normal(np.zeros(n), R)
    return z


def filterpy_imm(z, F, Q, R, x0, P0, Pi, mu0):
    filters = []
    for j in range(len(F)):
        kf = KalmanFilter(dim_x=F.shape[1], dim_z=F.shape[1])
        kf.F, kf.Q, kf.R, kf.H = F[j], Q[j], R, np.eye(F.shape[1])
        kf.x, kf.P = x0[j].copy(), P0[j].copy()
        filters.append(kf)
    imm = IMMEstimator(filters, mu0.copy(), Pi)  # filterpy's code: M[i, j] = P(i -> j), as ours
    xs, mus = [], []
    for zt in z:
        imm.predict()
        imm.update(zt)
        xs.append(np.ravel(imm.x).copy())
        mus.append(np.ravel(imm.mu).copy())
    return np.array(xs), np.array(mus)


def test_posterior_equals_filterpy_on_random_5_mode_systems():
    rng = np.random.default_rng(0)
    for trial in range(3):
        F, Q, R, Pi, mu0, P0 = random_system(rng)
        z = simulate(rng, F, Q, R, Pi, B=2)
        x0 = rng.normal(size=(2, M, N))
        res = imm_filter(z, F, Q, R, x0, P0, Pi, mu0)
        for b in range(2):
            fx, fmu = filterpy_imm(z[b], F, Q, R, x0[b], P0, Pi, mu0)
            np.testing.assert_allclose(res.x[b], fx, atol=1e-9, rtol=0)
            np.testing.assert_allclose(res.mu[b], fmu, atol=1e-9, rtol=0)


def test_one_mode_is_a_kalman_filter():
    rng = np.random.default_rng(1)
    F, Q, R, _, _, P0 = random_system(rng, m=1)
    z = simulate(rng, F, Q, R, np.ones((1, 1)), B=1)
    x0 = rng.normal(size=(1, 1, N))
    res = imm_filter(z, F, Q, R, x0, P0, np.ones((1, 1)), np.ones(1))
    kf = KalmanFilter(dim_x=N, dim_z=N)
    kf.F, kf.Q, kf.R, kf.H, kf.x, kf.P = F[0], Q[0], R, np.eye(N), x0[0, 0].copy(), P0[0].copy()
    for t in range(T):
        kf.predict()
        kf.update(z[0, t])
        np.testing.assert_allclose(res.x[0, t], np.ravel(kf.x), atol=1e-12)
        np.testing.assert_allclose(res.P[0, t], kf.P, atol=1e-12)
        assert res.loglik[0, t] == pytest.approx(kf.log_likelihood, abs=1e-9)
    np.testing.assert_array_equal(res.mu, 1.0)


def test_identity_pi_is_a_bank_of_independent_kalman_filters():
    rng = np.random.default_rng(2)
    F, Q, R, Pi, mu0, P0 = random_system(rng, m=3)
    z = simulate(rng, F, Q, R, Pi, B=1)
    x0 = rng.normal(size=(1, 3, N))
    res = imm_filter(z, F, Q, R, x0, P0, np.eye(3), mu0)
    log_w = np.log(mu0).copy()
    for j in range(3):
        kf = KalmanFilter(dim_x=N, dim_z=N)
        kf.F, kf.Q, kf.R, kf.H, kf.x, kf.P = F[j], Q[j], R, np.eye(N), x0[0, j].copy(), P0[j].copy()
        for t in range(T):
            kf.predict()
            kf.update(z[0, t])
            np.testing.assert_allclose(res.x_modes[0, t, j], np.ravel(kf.x), atol=1e-10)
            log_w[j] += kf.log_likelihood
    # mu_T is proportional to mu0 times the product of each mode's likelihoods
    expected = np.exp(log_w - np.logaddexp.reduce(log_w))
    np.testing.assert_allclose(res.mu[0, -1], expected, atol=1e-9)


def test_identical_modes_give_mu0_times_powers_of_pi():
    rng = np.random.default_rng(3)
    F, Q, R, Pi, mu0, P0 = random_system(rng)
    F[:], Q[:], P0[:] = F[0], Q[0], P0[0]
    z = simulate(rng, F, Q, R, Pi, B=1, T=20)
    x0 = np.broadcast_to(rng.normal(size=N), (1, M, N)).copy()
    res = imm_filter(z, F, Q, R, x0, P0, Pi, mu0)
    mu = mu0.copy()
    for t in range(20):
        mu = mu @ Pi  # every frame mixes first, frame 0 included
        np.testing.assert_allclose(res.mu[0, t], mu, atol=1e-12)
        np.testing.assert_allclose(res.x_modes[0, t], np.broadcast_to(res.x[0, t], (M, N)), atol=1e-10)


def test_simplex_psd_and_extreme_innovations_stay_finite():
    rng = np.random.default_rng(4)
    F, Q, R, Pi, mu0, P0 = random_system(rng)
    z = simulate(rng, F, Q, R, Pi, B=2, T=200)
    z[1, 100] = 1e8  # an absurd measurement: likelihoods about -1e16 in log space
    res = imm_filter(z, F, Q, R, rng.normal(size=(2, M, N)), P0, Pi, mu0)
    assert np.isfinite(res.x).all()
    assert np.isfinite(res.mu).all()
    assert np.isfinite(res.loglik).all()
    assert (res.mu >= 0).all()
    np.testing.assert_allclose(res.mu.sum(axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(res.P, np.swapaxes(res.P, -1, -2), atol=0)
    eig = np.linalg.eigvalsh(res.P)
    assert (eig > -1e-10 * np.trace(res.P, axis1=-2, axis2=-1)[..., None]).all()
    assert np.isclose(res.mu[1, 100].max(), 1.0)  # one mode takes it all


def test_missing_measurement_predicts_only():
    rng = np.random.default_rng(5)
    F, Q, R, Pi, mu0, P0 = random_system(rng)
    z = simulate(rng, F, Q, R, Pi, B=1, T=5)
    z[0, 3] = np.nan
    x0 = rng.normal(size=(1, M, N))
    full = imm_filter(z[:, :3], F, Q, R, x0, P0, Pi, mu0)
    res = imm_filter(z, F, Q, R, x0, P0, Pi, mu0)
    np.testing.assert_allclose(res.mu[0, 3], full.mu[0, 2] @ Pi, atol=1e-12)  # mu = cbar
    assert res.loglik[0, 3] == 0.0
    # P^j = Pbar^j on that frame; the fused P stays exactly symmetric even if Q is not quite
    skew = 1e-12 * rng.normal(size=Q.shape)
    lopsided = imm_filter(z, F, Q + skew - np.swapaxes(skew, -1, -2), R, x0, P0, Pi, mu0)
    np.testing.assert_array_equal(lopsided.P, np.swapaxes(lopsided.P, -1, -2))


def test_a_missing_frame_carries_x_p_and_mu_as_filterpy_predicts():
    """Oracle: filterpy's IMMEstimator with predict() only at the missing frame, and then its
    mode probabilities set to cbar (mixing and fused estimate recomputed from them). x, P
    and mu must agree at and after the NaN frame (frames 4-7 read the carried mu). Measured
    1.8e-15; 1e-9 is the file's filterpy tolerance (order of sums). Sequence 1 has no gap:
    a batch mixing seen and missing rows."""
    rng = np.random.default_rng(5)
    F, Q, R, Pi, mu0, P0 = random_system(rng)
    z = simulate(rng, F, Q, R, Pi, B=2, T=8)
    z[0, 3] = np.nan
    x0 = rng.normal(size=(2, M, N))
    res = imm_filter(z, F, Q, R, x0, P0, Pi, mu0)
    for b in range(2):
        filters = []
        for j in range(M):
            kf = KalmanFilter(dim_x=N, dim_z=N)
            kf.F, kf.Q, kf.R, kf.H = F[j], Q[j], R, np.eye(N)
            kf.x, kf.P = x0[b, j].copy(), P0[j].copy()
            filters.append(kf)
        imm = IMMEstimator(filters, mu0.copy(), Pi)
        for t in range(8):
            imm.predict()
            if np.isnan(z[b, t]).any():
                imm.mu = imm.cbar.copy()
                imm._compute_mixing_probabilities()
                imm._compute_state_estimate()
            else:
                imm.update(z[b, t])
            np.testing.assert_allclose(res.x[b, t], np.ravel(imm.x), atol=1e-9, rtol=0, err_msg=f"x {b} {t}")
            np.testing.assert_allclose(res.P[b, t], imm.P, atol=1e-9, rtol=0, err_msg=f"P {b} {t}")
            np.testing.assert_allclose(res.mu[b, t], imm.mu, atol=1e-9, rtol=0, err_msg=f"mu {b} {t}")


def test_an_unreachable_mode_changes_nothing():
    # mode 4 has mu0 = 0 and no transition into it, so cbar_4 = 0 (log -inf) every frame: it
    # must stay at mu = 0 without NaN and leave the other four modes as an IMM without it
    rng = np.random.default_rng(11)
    F, Q, R, Pi, mu0, P0 = random_system(rng)
    Pi[:, 4] = 0.0
    Pi /= Pi.sum(axis=1, keepdims=True)
    mu0[4] = 0.0
    mu0 /= mu0.sum()
    z = simulate(rng, F[:4], Q[:4], R, Pi[:4, :4], B=2, T=40)
    x0 = rng.normal(size=(2, M, N))
    five = imm_filter(z, F, Q, R, x0, P0, Pi, mu0)
    four = imm_filter(z, F[:4], Q[:4], R, x0[:, :4], P0[:4], Pi[:4, :4], mu0[:4])
    assert np.isfinite(five.x_modes).all()
    assert (five.mu[..., 4] == 0.0).all()
    # the same sums with exact zero terms added, possibly in another order: 1e-12
    np.testing.assert_allclose(five.x, four.x, atol=1e-12)
    np.testing.assert_allclose(five.P, four.P, atol=1e-12)
    np.testing.assert_allclose(five.mu[..., :4], four.mu, atol=1e-12)
    np.testing.assert_allclose(five.loglik, four.loglik, atol=1e-12)


def test_batched_equals_one_sequence_at_a_time():
    rng = np.random.default_rng(6)
    F, Q, R, Pi, mu0, P0 = random_system(rng)
    z = simulate(rng, F, Q, R, Pi, B=4, T=30)
    x0 = rng.normal(size=(4, M, N))
    res = imm_filter(z, F, Q, R, x0, P0, Pi, mu0)
    for b in range(4):
        one = imm_filter(z[b:b + 1], F, Q, R, x0[b:b + 1], P0, Pi, mu0)
        np.testing.assert_allclose(one.x[0], res.x[b], atol=1e-12)
        np.testing.assert_allclose(one.mu[0], res.mu[b], atol=1e-12)


def test_scene_conditioning_reductions():
    rng = np.random.default_rng(7)
    F, Q, R, Pi, mu0, P0 = random_system(rng)
    B, Tn = 2, 25
    z = simulate(rng, F, Q, R, Pi, B=B, T=Tn)
    x0 = rng.normal(size=(B, M, N))
    base = imm_filter(z, F, Q, R, x0, P0, Pi, mu0)
    Pi_t, Q_t = conditioned(Pi, Q, np.zeros((B, Tn, M, M)), np.ones((B, Tn, M)))  # A = 0, gamma = 1
    same = imm_filter(z, F, Q_t, R, x0, P0, Pi_t, mu0)
    np.testing.assert_allclose(same.x, base.x, atol=1e-12)
    np.testing.assert_allclose(same.mu, base.mu, atol=1e-12)
    A = rng.normal(size=(B, Tn, M, M))
    shifted = A + rng.normal(size=(B, Tn, M, 1))  # a row-constant offset changes nothing
    Pa, _ = conditioned(Pi, Q, A, np.ones((B, Tn, M)))
    Pb, _ = conditioned(Pi, Q, shifted, np.ones((B, Tn, M)))
    np.testing.assert_allclose(Pa, Pb, atol=1e-12)
    np.testing.assert_allclose(Pa.sum(axis=-1), 1.0, atol=1e-12)
    Pz = Pi.copy()
    Pz[0, 1] = 0.0
    Pz[0] /= Pz[0].sum()
    Pc, _ = conditioned(Pz, Q, A, np.ones((B, Tn, M)))
    assert (Pc[..., 0, 1] == 0.0).all()  # structural zeros stay zero


def test_scene_conditioning_by_hand():
    """Paper eq. 8-9 on two modes: Pi_ij proportional to Pi0_ij exp(A_ij) along each row, and
    Q_j = gamma_j Q0_j. With A_01 = ln 2, row 0 becomes (0.9, 0.1 x 2) / 1.1; row 1 is
    untouched; gamma (1, 3) triples mode 1's Q."""
    Pi0 = np.array([[0.9, 0.1], [0.2, 0.8]])
    Q0 = np.array([np.eye(2), 2 * np.eye(2)])
    A = np.array([[0.0, np.log(2.0)], [0.0, 0.0]])[None, None]
    Pi, Q = conditioned(Pi0, Q0, A, np.array([1.0, 3.0])[None, None])
    # to a few units in the last place: a log, an exp and a division per entry
    np.testing.assert_allclose(Pi[0, 0], [[0.9 / 1.1, 0.2 / 1.1], [0.2, 0.8]], rtol=1e-14, atol=0)
    np.testing.assert_array_equal(Q[0, 0], [np.eye(2), 6 * np.eye(2)])


def test_bad_shapes_and_pi_orientation_are_refused():
    rng = np.random.default_rng(8)
    F, Q, R, Pi, mu0, P0 = random_system(rng)
    z = np.zeros((1, 3, N))
    x0 = np.zeros((1, M, N))
    with pytest.raises(ValueError, match="rows must be probabilities"):
        imm_filter(z, F, Q, R, x0, P0, Pi.T, mu0)  # columns of a non-symmetric Pi do not sum to 1
    with pytest.raises(ValueError, match="F must be"):
        imm_filter(z, F[:, :4], Q, R, x0, P0, Pi, mu0)


def filterpy_imm_per_frame(z, F, Q, R, x0, P0, Pi, mu0):
    """filterpy with Pi (T,M,M) and Q (T,M,n,n) changing every frame. filterpy mixes with the
    matrix it held at the previous update, so Pi_t is set and its mixing probabilities are
    recomputed (a private method) before each predict."""
    n = F.shape[1]
    filters = []
    for j in range(len(F)):
        kf = KalmanFilter(dim_x=n, dim_z=n)
        kf.F, kf.R, kf.H, kf.x, kf.P = F[j], R, np.eye(n), x0[j].copy(), P0[j].copy()
        filters.append(kf)
    imm = IMMEstimator(filters, mu0.copy(), Pi[0])
    xs, mus = [], []
    for t, zt in enumerate(z):
        imm.M = Pi[t]
        imm._compute_mixing_probabilities()
        for j, kf in enumerate(filters):
            kf.Q = Q[t, j]
        imm.predict()
        imm.update(zt)
        xs.append(np.ravel(imm.x).copy())
        mus.append(np.ravel(imm.mu).copy())
    return np.array(xs), np.array(mus)


def test_per_frame_pi_and_q_equal_filterpy():
    # T = 75 frames spans three of the blocks in which imm_filter re-lays per-frame inputs
    rng = np.random.default_rng(9)
    F, Q, R, Pi, mu0, P0 = random_system(rng)
    B, Tn = 2, 75
    z = simulate(rng, F, Q, R, Pi, B=B, T=Tn)
    A = rng.normal(size=(B, Tn, M, M))
    Pi_t, Q_t = conditioned(Pi, Q, A, np.exp(rng.normal(scale=0.5, size=(B, Tn, M))))
    assert not np.allclose(Pi_t[:, 1:], Pi_t[:, :-1])  # really changes every frame
    x0 = rng.normal(size=(B, M, N))
    res = imm_filter(z, F, Q_t, R, x0, P0, Pi_t, mu0)
    for b in range(B):
        fx, fmu = filterpy_imm_per_frame(z[b], F, Q_t[b], R, x0[b], P0, Pi_t[b], mu0)
        np.testing.assert_allclose(res.x[b], fx, atol=1e-9, rtol=0)
        np.testing.assert_allclose(res.mu[b], fmu, atol=1e-9, rtol=0)


def test_shared_and_per_frame_inputs_give_identical_results():
    # the shared (M,M) / (M,n,n) inputs and the same values repeated per frame run the same
    # arithmetic in a different layout, so the outputs are bitwise equal, NaN frames included
    rng = np.random.default_rng(10)
    F, Q, R, Pi, mu0, P0 = random_system(rng)
    B, Tn = 3, 40
    z = simulate(rng, F, Q, R, Pi, B=B, T=Tn)
    z[1, 5:9] = np.nan
    z[2, 33, 0] = np.nan
    x0 = rng.normal(size=(B, M, N))
    Pi_t = np.broadcast_to(Pi, (B, Tn, M, M))
    Q_t = np.broadcast_to(Q, (B, Tn, M, N, N))
    shared = imm_filter(z, F, Q, R, x0, P0, Pi, mu0)
    for q, p in ((Q_t, Pi), (Q, Pi_t), (Q_t, Pi_t)):
        res = imm_filter(z, F, q, R, x0, P0, p, mu0)
        for field in ("x", "P", "mu", "x_modes", "loglik"):
            np.testing.assert_array_equal(getattr(res, field), getattr(shared, field))


def test_bench_reports_its_figures_from_a_fresh_process():
    # not a timing test: the figures exist and the IMM agrees with filterpy on the bench system
    from sumo_scimm.bench.imm import run_imm_bench
    r = run_imm_bench(batch=3, frames=12, filterpy_sequences=2)
    assert (r["imm_batch"], r["imm_frames"]) == (3, 12)
    assert r["imm_frames_per_s"] > 0
    assert r["imm_frames_per_s_wall"] > 0
    assert r["filterpy_frames_per_s"] > 0
    assert r["max_abs_diff_x"] < 1e-9
    assert r["max_abs_diff_mu"] < 1e-9


def test_known_input_equals_filterpy_with_per_frame_transition_and_control():
    """Step 3b (the ego-motion carry): x_t = F_j (C_t x_t-1 + u_t) + w is filterpy's
    KalmanFilter with F = F_j C_t, B = F_j and control u_t, mixed by its IMMEstimator.
    Measurements simulated from that model, so innovations stay moderate (filterpy replaces
    an underflowing likelihood by the smallest float, which a wild system would trigger)."""
    rng = np.random.default_rng(12)
    F, Q, R, Pi, mu0, P0 = random_system(rng)
    B, Tn = 2, 40
    C = np.eye(N) + 0.1 * rng.normal(size=(B, Tn, N, N))
    u = 0.3 * rng.normal(size=(B, Tn, N))
    z = np.empty((B, Tn, N))
    for b in range(B):
        x, mode = rng.normal(size=N), 0
        for t in range(Tn):
            mode = rng.choice(M, p=Pi[mode])
            x = F[mode] @ (C[b, t] @ x + u[b, t]) + rng.multivariate_normal(np.zeros(N), Q[mode])
            z[b, t] = x + rng.multivariate_normal(np.zeros(N), R)
    x0 = rng.normal(size=(B, M, N))
    res = imm_filter(z, F, Q, R, x0, P0, Pi, mu0, carry=C, shift=u, keep_P_modes=True)
    for b in range(B):
        filters = []
        for j in range(M):
            kf = KalmanFilter(dim_x=N, dim_z=N, dim_u=N)
            kf.Q, kf.R, kf.H, kf.x, kf.P = Q[j], R, np.eye(N), x0[b, j].copy(), P0[j].copy()
            filters.append(kf)
        imm = IMMEstimator(filters, mu0.copy(), Pi)
        for t in range(Tn):
            for j, kf in enumerate(filters):
                kf.F, kf.B = F[j] @ C[b, t], F[j]
            imm.predict(u[b, t])
            imm.update(z[b, t])
            np.testing.assert_allclose(res.x[b, t], np.ravel(imm.x), atol=1e-9, rtol=0)
            np.testing.assert_allclose(res.mu[b, t], np.ravel(imm.mu), atol=1e-9, rtol=0)
            for j, kf in enumerate(filters):
                np.testing.assert_allclose(res.P_modes[b, t, j], kf.P, atol=1e-9, rtol=0)


def test_a_zero_pose_change_is_the_uncompensated_filter_bit_for_bit():
    # C = I, u = 0: every product is by 1 or 0 and every sum adds exact zeros
    rng = np.random.default_rng(13)
    F, Q, R, Pi, mu0, P0 = random_system(rng)
    B, Tn = 2, 30
    z = simulate(rng, F, Q, R, Pi, B=B, T=Tn)
    x0 = rng.normal(size=(B, M, N))
    plain = imm_filter(z, F, Q, R, x0, P0, Pi, mu0)
    still = imm_filter(z, F, Q, R, x0, P0, Pi, mu0, carry=np.broadcast_to(np.eye(N), (B, Tn, N, N)),
                       shift=np.zeros((B, Tn, N)))
    for field in ("x", "P", "mu", "x_modes", "loglik"):
        np.testing.assert_array_equal(getattr(still, field), getattr(plain, field))
    with pytest.raises(ValueError, match="give both or neither"):
        imm_filter(z, F, Q, R, x0, P0, Pi, mu0, carry=np.broadcast_to(np.eye(N), (B, Tn, N, N)))
    with pytest.raises(ValueError, match="carry must be"):
        imm_filter(z, F, Q, R, x0, P0, Pi, mu0, carry=np.eye(N), shift=np.zeros(N))
