"""Kalman / RTS smoothers (mocapkit.signal.rts_smoother, mocapkit.denoise.kalman)."""
import numpy as np
import pytest

from mocapkit import Motion, Skeleton, denoise, gaps, signal
from mocapkit.denoise.base import Denoiser
from mocapkit.errors import MocapValueError, NotFittedError
from mocapkit.signal.rts import _dense_posterior


# -- the smoother equals the dense Gaussian posterior ------------------------------------------
def _problem(rng, T, n, p, dt=1.0):
    F, Q = signal.cv_model(dt, 0.7, order=n) if n > 1 else signal.random_walk_model(0.7)
    Y = rng.normal(size=(T, p)) * 2
    M = rng.random((T, p)) > 0.35
    M[0, 0] = True
    return F, Q, Y, M


@pytest.mark.parametrize("n,p", [(1, 1), (2, 1), (3, 1), (2, 3), (3, 2)])
def test_rts_equals_dense_posterior(rng, n, p):
    T = 9
    F, Q, Y, M = _problem(rng, T, n, p)
    H = np.eye(1, n) if p == 1 else rng.normal(size=(p, n))
    R = rng.uniform(0.3, 2.0, p)
    x0 = rng.normal(size=n)
    P0 = np.diag(rng.uniform(1, 3, n))
    b = rng.normal(size=n) * 0.1 if p > 1 else None
    mu, cov = _dense_posterior(Y, M, F=F, Q=Q, R=R, H=H, x0=x0, P0=P0, b=b)
    xs, used, Ps = signal.rts_smoother(Y[:, None, :], M[:, None, :], F=F, Q=Q, R=R[None], H=H,
                                       x0=x0[None], P0=P0[None], b=b, return_cov=True)
    np.testing.assert_allclose(xs[:, 0], mu, atol=1e-8)
    blocks = np.array([cov[t * n:(t + 1) * n, t * n:(t + 1) * n] for t in range(T)])
    np.testing.assert_allclose(Ps[:, 0], blocks, atol=1e-8)
    assert (used[:, 0] == M).all()
    if p == 1 and n <= 2 and b is None:
        # the vectorised fast path (no covariances) gives the same means
        xf, _ = signal.rts_smoother(Y, M, F=F, Q=Q, R=R, x0=x0[None], P0=P0[None])
        np.testing.assert_allclose(xf[:, 0], mu, atol=1e-8)


def test_steady_state_lti_path_equals_dense_and_per_frame(rng, monkeypatch):
    """Every frame observed, no gate: after the covariances settle both RTS passes run as
    constant-gain filters (rts._rts2_steady, lfilter); the means equal the dense posterior
    and the per-frame recursion."""
    from mocapkit.signal import rts

    monkeypatch.setattr(rts, "_STEADY_MIN_FRAMES", 64)      # short, for the dense solve
    T, B = 150, 3
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    q = rng.uniform(0.01, 0.5, B)
    Q = q[:, None, None] * np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]])
    Y = np.cumsum(rng.normal(size=(T, B)), axis=0) + rng.normal(size=(T, B))
    M = np.ones((T, B), bool)
    R = rng.uniform(0.5, 2.0, B)
    x0 = np.c_[Y[0], np.zeros(B)]
    P0 = np.broadcast_to(np.diag([4.0, 1.0]), (B, 2, 2)).copy()
    assert rts._rts2_steady(Y, R, (1.0, 1.0, 0.0, 1.0) + tuple(Q[:, i, j] for i, j in ((0, 0), (0, 1), (1, 1))),
                            x0, P0) is not None                  # the path is taken
    xs, _ = signal.rts_smoother(Y, M, F=F, Q=Q, R=R, x0=x0, P0=P0)
    for b in range(B):
        mu, _ = _dense_posterior(Y[:, b:b + 1], M[:, b:b + 1], F=F, Q=Q[b], R=R[b:b + 1],
                                 H=np.eye(1, 2), x0=x0[b], P0=P0[b])
        np.testing.assert_allclose(xs[:, b], mu, atol=1e-8)
    monkeypatch.setattr(rts, "_rts2_steady", lambda *a: None)
    ref, _ = signal.rts_smoother(Y, M, F=F, Q=Q, R=R, x0=x0, P0=P0)
    np.testing.assert_allclose(xs, ref, rtol=0, atol=1e-9)


def test_steady_state_random_walk_path_equals_dense(rng, monkeypatch):
    """The one-state (random-walk) model, every frame observed: the constant-gain path
    (rts._rts1_steady) equals the dense posterior."""
    from mocapkit.signal import rts

    monkeypatch.setattr(rts, "_STEADY_MIN_FRAMES", 64)      # short, for the dense solve
    T, B = 400, 3
    F = np.array([[1.0]])
    Q = rng.uniform(0.05, 0.5, B)[:, None, None]
    Y = np.cumsum(rng.normal(size=(T, B)), axis=0) + rng.normal(size=(T, B))
    M = np.ones((T, B), bool)
    R = rng.uniform(0.5, 2.0, B)
    x0, P0 = Y[:1].T.copy(), np.full((B, 1, 1), 4.0)
    assert rts._rts1_steady(Y, R, 1.0, Q[:, 0, 0], x0[:, 0], P0[:, 0, 0]) is not None
    xs, _ = signal.rts_smoother(Y, M, F=F, Q=Q, R=R, x0=x0, P0=P0)
    for b in range(B):
        mu, _ = _dense_posterior(Y[:, b:b + 1], M[:, b:b + 1], F=F, Q=Q[b], R=R[b:b + 1],
                                 H=np.eye(1), x0=x0[b], P0=P0[b])
        np.testing.assert_allclose(xs[:, b], mu, atol=1e-8)


def test_generic_batched_vector_path_equals_dense(rng):
    """B > 1 filters with vector observations (p <= n): the generic gain-form path."""
    T, n, p = 8, 3, 2
    F, Q = signal.cv_model(1.0, 0.7, order=3)
    H = rng.normal(size=(p, n))
    Y = rng.normal(size=(T, 2, p))
    M = rng.random((T, 2, p)) > 0.3
    R = np.array([[0.5, 1.5], [1.0, 2.0]])
    xs, _ = signal.rts_smoother(Y, M, F=F, Q=Q, R=R, H=H, x0=np.zeros(n), P0=np.eye(n) * 3)
    for i in range(2):
        mu, _ = _dense_posterior(Y[:, i], M[:, i], F=F, Q=Q, R=R[i], H=H,
                                        x0=np.zeros(n), P0=np.eye(n) * 3)
        np.testing.assert_allclose(xs[:, i], mu, atol=1e-8)


def test_steady_state_covariance_and_reuse(rng):
    from scipy.linalg import solve_discrete_are

    n, p = 4, 6
    F = 0.9 * np.linalg.qr(rng.normal(size=(n, n)))[0]
    Q = np.eye(n) * 0.3
    H = rng.normal(size=(p, n))
    R = rng.uniform(0.5, 2, p)
    Pss = signal.steady_state_covariance(F, Q, H, R)
    np.testing.assert_allclose(Pss, solve_discrete_are(F.T, H.T, Q, np.diag(R)), atol=1e-10)
    # with the stationary prior, complete frames reuse one gain; the result is still
    # the exact posterior (here a long clip with one incomplete stretch)
    T = 60
    Y = rng.normal(size=(T, p))
    M = np.ones((T, p), bool)
    M[20:25, :4] = False
    x0 = rng.normal(size=n)
    mu, _ = _dense_posterior(Y, M, F=F, Q=Q, R=R, H=H, x0=x0, P0=Pss)
    xs, _ = signal.rts_smoother(Y[:, None], M[:, None], F=F, Q=Q, R=R[None], H=H, x0=x0[None], P0=Pss[None])
    np.testing.assert_allclose(xs[:, 0], mu, atol=1e-8)


def test_batched_channels_are_independent(rng):
    """A batch of C filters equals C separate runs (different q, r and masks)."""
    T, C = 30, 5
    q = rng.uniform(0.1, 5, C)
    F, Q = signal.cv_model(0.5, q)
    Y = rng.normal(size=(T, C))
    M = rng.random((T, C)) > 0.3
    R = rng.uniform(0.5, 2, C)
    xs, _ = signal.rts_smoother(Y, M, F=F, Q=Q, R=R, P0=np.eye(2) * 10)
    for c in range(C):
        mu, _ = _dense_posterior(Y[:, c:c + 1], M[:, c:c + 1], F=F, Q=Q[c], R=R[c:c + 1],
                                        H=np.eye(1, 2), x0=np.zeros(2), P0=np.eye(2) * 10)
        np.testing.assert_allclose(xs[:, c], mu, atol=1e-8)


# -- noise estimates -----------------------------------------------------------------------------
def test_noise_sigma_and_ml_process_noise(rng):
    t = np.arange(2000) / 120
    smooth = np.stack([30 * np.sin(2 * np.pi * 0.8 * t), 10 * np.cos(2 * np.pi * 1.3 * t)], axis=1)
    noisy = smooth + rng.normal(0, 1.5, smooth.shape)
    noisy[::50] += 20                                           # spikes do not bias the MAD
    np.testing.assert_allclose(signal.estimate_noise(noisy), 1.5, rtol=0.08)
    # q of a simulated white-noise-acceleration model is recovered by the likelihood grid
    dt, qtrue = 1 / 120, np.array([100.0, 3000.0, 50000.0])
    F, Q = signal.cv_model(dt, qtrue)
    L = np.linalg.cholesky(Q)
    x = np.zeros((3, 2))
    Y = np.empty((3000, 3))
    for k in range(3000):
        x = x @ F.T + np.einsum("bij,bj->bi", L, rng.normal(size=(3, 2)))
        Y[k] = x[:, 0] + rng.normal(0, 1.0, 3)
    q, fc = signal.select_process_noise(Y, dt=dt, r=1.0)
    assert np.all(np.abs(np.log(q / qtrue)) < np.log(2.0)), q / qtrue
    np.testing.assert_allclose(signal.cutoff_to_q(fc, r=1.0, dt=dt), q)


# -- kalman-cv -------------------------------------------------------------------------------------
def _line_motion(T=600, J=5, fps=120.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(T) / fps
    P = rng.uniform(-50, 50, (J, 3))[None] + t[:, None, None] * rng.uniform(-100, 100, (J, 3))[None]
    sk = Skeleton(tuple(f"m{j}" for j in range(J)), [-1] + [0] * (J - 1), np.zeros((J, 3)))
    return Motion(P, sk, fps)


def test_kalman_cv_on_constant_velocity_beats_noise():
    clean = _line_motion()
    rng = np.random.default_rng(1)
    noisy = clean.with_positions(clean.positions + rng.normal(0, 2.0, clean.positions.shape))
    out = denoise.get("kalman-cv").denoise(noisy)
    err = np.sqrt(np.mean((out.positions - clean.positions) ** 2))
    # measured: factor 11-14 over seeds (2 cm -> 0.14-0.18 cm); require 6
    assert 2.0 / err > 6.0, err
    # with 30 % missing markers it still fills and smooths (every entry scored: FILL_ALL)
    obs = rng.random(clean.observed.shape) > 0.3
    obs[0] = True
    with gaps.use_policy(gaps.FILL_ALL):
        out2 = denoise.get("kalman-cv").denoise(noisy.with_observed(obs))
    assert out2.observed.all() and np.isfinite(out2.positions).all()
    assert np.sqrt(np.mean((out2.positions - clean.positions) ** 2)) < 0.5
    # default policy: a subset of the same fills (the rest left missing, NaN, reported)
    out3 = denoise.get("kalman-cv").denoise(noisy.with_observed(obs))
    assert out3.observed[obs].all() and np.isnan(out3.positions[~out3.observed]).all()
    assert out3.source["gap_report"]["left_missing"] == int((~out3.observed).sum())
    np.testing.assert_allclose(out3.positions[out3.observed], out2.positions[out3.observed])


def test_kalman_cv_constant_acceleration_and_fixed_params():
    clean = _line_motion(T=300)
    P = clean.positions + 0.5 * 200.0 * (np.arange(300) / 120.0)[:, None, None] ** 2   # accelerating
    clean = clean.with_positions(P)
    noisy = clean.with_positions(P + np.random.default_rng(2).normal(0, 1.0, P.shape))
    for params in ({"order": 3}, {"cutoff_hz": 3.0}, {"process_noise": 1e3, "measurement_sigma_cm": 1.0}):
        out = denoise.get("kalman-cv", **params).denoise(noisy)
        assert np.sqrt(np.mean((out.positions - P) ** 2)) < 0.6, params
    with pytest.raises(MocapValueError):
        denoise.get("kalman-cv", order=5).denoise(noisy)
    with pytest.raises(MocapValueError):
        denoise.get("kalman-cv", cutoff_hz=100.0).denoise(noisy)


def test_kalman_cv_gate_rejects_spikes():
    clean = _walker(T=600, fps=120.0, seed=3)
    rng = np.random.default_rng(4)
    P = clean.positions + rng.normal(0, 1.0, clean.positions.shape)
    spikes = rng.random(clean.observed.shape) < 0.05
    spikes[:5] = False
    d = rng.normal(size=P.shape)
    d /= np.linalg.norm(d, axis=2, keepdims=True)
    P[spikes] += 15 * d[spikes]
    noisy = clean.with_positions(P)
    plain = denoise.get("kalman-cv").denoise(noisy)
    gated = denoise.get("kalman-cv", gate=4.0).denoise(noisy)
    e = lambda m: np.sqrt(np.mean((m.positions - clean.positions) ** 2))
    assert e(gated) < 0.6 * e(plain)                            # measured ~0.21 vs ~0.43 cm
    f = gated.source["flagged"]
    assert (f & spikes).sum() >= 0.95 * spikes.sum()
    assert (f & ~spikes).sum() <= 0.01 * (~spikes).sum()


def test_kalman_identity_smooths():
    clean = _line_motion(T=400, seed=5)
    noisy = clean.with_positions(clean.positions + np.random.default_rng(6).normal(0, 2.0, clean.positions.shape))
    out = denoise.get("kalman-identity").denoise(noisy)
    assert np.sqrt(np.mean((out.positions - clean.positions) ** 2)) < 1.0
    out = denoise.get("kalman-identity", process_sigma_cm=0.5, measurement_sigma_cm=2.0).denoise(noisy)
    assert np.isfinite(out.positions).all()


# -- kalman-learned ---------------------------------------------------------------------------------
def _linear_system_motions(A, c, n_clips=6, T=40, seed=0):
    rng = np.random.default_rng(seed)
    D = A.shape[0]
    sk = Skeleton(("a", "b"), [-1, 0], np.zeros((2, 3)))
    out = []
    for _ in range(n_clips):
        z = rng.normal(size=D) * 20
        Z = np.empty((T, D))
        for t in range(T):
            Z[t] = z
            z = A @ z + c
        out.append(Motion(Z.reshape(T, 2, 3), sk, 30.0))
    return out


def _stable_A(rng, D=6):
    Qm, _ = np.linalg.qr(rng.normal(size=(D, D)))
    return 0.97 * Qm @ np.diag(rng.uniform(0.6, 1.0, D)) @ Qm.T + 0.05 * rng.normal(size=(D, D))


def test_kalman_learned_recovers_known_linear_system(rng):
    A = _stable_A(rng)
    c = rng.normal(size=6)
    clips = _linear_system_motions(A, c)
    m = denoise.get("kalman-learned", frame="global", energy=1.0, ridge=0.0, q_scale=1.0).fit(clips)
    assert m.components_.shape == (6, 6)
    A_hat, c_hat = m.full_dynamics()
    np.testing.assert_allclose(A_hat, A, atol=1e-8)
    np.testing.assert_allclose(c_hat, c, atol=1e-7)
    assert np.abs(m.Q_).max() < 1e-6                        # noise-free: residuals vanish


def test_kalman_learned_save_load_roundtrip(tmp_path, rng):
    A = _stable_A(rng)
    clips = _linear_system_motions(A, np.zeros(6), T=60)
    m = denoise.get("kalman-learned", frame="global", energy=0.999, order=2).fit(clips[:-1])
    test = clips[-1]
    noisy = test.with_positions(test.positions + rng.normal(0, 1.0, test.positions.shape))
    out = m.denoise(noisy)
    path = tmp_path / "kl.npz"
    m.save(path)
    m2 = Denoiser.load(path)
    assert type(m2) is type(m) and m2.get_params() == m.get_params()
    np.testing.assert_array_equal(m2.denoise(noisy).positions, out.positions)
    for k, v in m._fitted_attrs().items():
        np.testing.assert_array_equal(np.asarray(getattr(m2, k)), np.asarray(v))
    with pytest.raises(NotFittedError):
        denoise.get("kalman-learned").denoise(noisy)


def _walker(T=360, fps=60.0, heading=0.0, speed=80.0, seed=0):
    """A crude walking figure with CMU-style joint names (Y up)."""
    rng = np.random.default_rng(seed)
    names = ("root", "lhipjoint", "lfemur", "ltibia", "lfoot", "rhipjoint", "rfemur", "rtibia",
             "rfoot", "lowerback", "thorax", "head", "lhumerus", "lwrist", "rhumerus", "rwrist")
    parents = [-1, 0, 1, 2, 3, 0, 5, 6, 7, 0, 9, 10, 10, 12, 10, 14]
    base = np.array([[0, 95, 0], [9, 95, 0], [9, 92, 0], [9, 50, 0], [9, 8, 0], [-9, 95, 0],
                     [-9, 92, 0], [-9, 50, 0], [-9, 8, 0], [0, 110, 0], [0, 140, 0], [0, 165, 0],
                     [18, 140, 0], [20, 95, 0], [-18, 140, 0], [-20, 95, 0]], float)
    t = np.arange(T) / fps
    f = 0.9 + 0.1 * rng.random()
    ph = 2 * np.pi * f * t
    P = np.repeat(base[None], T, 0)
    swing = np.sin(ph)[:, None]
    P[:, [3, 4], 2] += 25 * swing * np.array([0.5, 1.0])
    P[:, [7, 8], 2] -= 25 * swing * np.array([0.5, 1.0])
    P[:, 13, 2] -= 20 * np.sin(ph)
    P[:, 15, 2] += 20 * np.sin(ph)
    P[:, :, 1] += 2 * np.cos(2 * ph)[:, None]
    th = heading + 0.2 * np.sin(0.3 * t)
    c, s = np.cos(th)[:, None], np.sin(th)[:, None]
    x, z = P[:, :, 0].copy(), P[:, :, 2].copy()
    P[:, :, 0] = c * x + s * z
    P[:, :, 2] = -s * x + c * z
    fwd = np.cumsum(speed / fps * np.stack([np.sin(th), np.cos(th)], 1), axis=0)
    P[:, :, 0] += fwd[:, 0:1]
    P[:, :, 2] += fwd[:, 1:2]
    sk = Skeleton(names, parents, np.zeros((len(names), 3)))
    return Motion(P, sk, fps)


def test_kalman_learned_denoises_and_fills_unobserved_joint():
    train = [_walker(heading=h, seed=i) for i, h in enumerate((0.0, 2.0, -1.0, 3.0))]
    test = _walker(heading=0.7, seed=9)
    m = denoise.get("kalman-learned").fit(train)
    rng = np.random.default_rng(0)
    noisy = test.with_positions(test.positions + rng.normal(0, 2.0, test.positions.shape))
    out = m.denoise(noisy)
    err = np.sqrt(np.mean((out.positions - test.positions) ** 2))
    assert err < 1.2, err
    # a wrist seen in the first frame only: recovered from the other joints through the
    # learned model (a trailing gap with marker evidence, filled under the default policy)
    obs = noisy.observed.copy()
    j = test.skeleton.index("lwrist")
    obs[1:, j] = False
    with gaps.use_policy(validate_cm=None):    # a 6 s edge gap nothing on the clip can judge:
        out2 = m.denoise(noisy.with_observed(obs))          # the default policy leaves it missing
    assert not m.denoise(noisy.with_observed(obs)).observed[1:, j].any()
    assert out2.observed.all() and np.isfinite(out2.positions).all()
    err_j = np.sqrt(np.mean((out2.positions[:, j] - test.positions[:, j]) ** 2))
    assert err_j < 5.0, err_j
    # never observed at all: returned missing (issue 18), the other joints unchanged
    obs[0, j] = False
    out_n = m.denoise(noisy.with_observed(obs))
    assert not out_n.observed[:, j].any() and np.isnan(out_n.positions[:, j]).all()
    assert out_n.observed[:, np.arange(test.n_joints) != j].all()
    # 30 % missing markers
    obs = rng.random(obs.shape) > 0.3
    with gaps.use_policy(gaps.FILL_ALL):
        out3 = m.denoise(noisy.with_observed(obs))
    assert out3.observed.all() and np.sqrt(np.mean((out3.positions - test.positions) ** 2)) < 2.0
    with pytest.raises(MocapValueError, match="fps"):
        m.denoise(test.resample(30.0))
    with pytest.raises(MocapValueError, match="joints"):
        m.denoise(test.select(["root", "lfemur", "rfemur"]))


@pytest.mark.parametrize("name", ["kalman-cv", "kalman-identity"])
def test_kalman_complete_output_with_30pct_missing(name):
    clean = _walker(T=240)
    rng = np.random.default_rng(7)
    obs = rng.random(clean.observed.shape) > 0.3
    obs[0] = True
    noisy = clean.with_positions(clean.positions + rng.normal(0, 1.0, clean.positions.shape)).with_observed(obs)
    out = denoise.get(name).denoise(noisy)
    assert out.positions.shape == clean.positions.shape
    assert out.observed.all() and np.isfinite(out.positions).all()
    assert np.sqrt(np.mean((out.positions - clean.positions) ** 2)) < 1.5


def test_kalman_on_real_clip(shared_data):
    pytest.importorskip("mocapkit.io.amc")
    from mocapkit import io
    from mocapkit.datasets import cmu_amc

    paths = [cmu_amc(t, shared_data) for t in ("07_03", "07_05", "16_15")]
    if any(p is None for p in paths):
        pytest.skip("CMU walks 07_03/07_05/16_15 not in the data set")
    clips = [io.read(p).resample(30.0) for p in paths]
    test = clips[2]
    rng = np.random.default_rng(0)
    noisy = test.with_positions(test.positions + rng.normal(0, 2.0, test.positions.shape))
    obs = rng.random(test.observed.shape) > 0.3
    obs[0] = True
    noisy_m = noisy.with_observed(obs)
    learned = denoise.get("kalman-learned").fit(clips[:2])
    for m in (denoise.get("kalman-cv"), denoise.get("kalman-identity"), learned):
        for inp in (noisy, noisy_m):
            with gaps.use_policy(gaps.FILL_ALL):             # every entry scored
                out = m.denoise(inp)
            assert out.observed.all() and np.isfinite(out.positions).all()
        err = np.sqrt(np.mean((m.denoise(noisy).positions - test.positions) ** 2))
        assert err < 2.0, (m.name, err)


def test_process_noise_selection_runs_shared_covariances_with_the_same_numbers():
    """Every frame observed and one noise level: the innovations' covariances are run once
    per grid point, not once per channel -- the same innovations and variances."""
    from mocapkit.signal import statespace as ss

    rng = np.random.default_rng(3)
    Y = rng.normal(size=(70, 6)).cumsum(axis=0)
    q = ss.cutoff_to_q(np.repeat([0.5, 2.0, 6.0], 6), r=0.25, dt=1 / 30)
    F, Qm = ss.cv_model(1 / 30, q, order=2)
    Yb, Mb = np.tile(Y, (1, 3)), np.ones((70, 18), bool)
    first, Rb = np.tile(Y[0], 3), np.full(18, 0.25)
    plain = ss._innovations_2(Yb, Mb, F, Qm, Rb, first)
    shared = ss._innovations_shared(Yb, float(F[0, 1]), Qm, Rb, first, 6)
    for a, b in zip(plain, shared):
        np.testing.assert_array_equal(a, b)
