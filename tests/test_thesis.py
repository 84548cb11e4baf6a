"""Thesis refinement (seed 003, Ch. 3-4): TDD, LLC, TSMC, TrNN, rank estimation, DynaMMo, PSC."""
import warnings

import numpy as np
import pytest

from mocapkit import Motion, Skeleton, denoise, gaps
from mocapkit.detect import detect_report, trust_data, trusted_mask
from mocapkit.errors import ConvergenceWarning, MocapValueError
from mocapkit.solvers import completion as cp
from mocapkit.solvers import llc


# ----------------------------------------------------------------------------------------
# synthetic data
# ----------------------------------------------------------------------------------------
def smooth_lowrank(T=300, C=45, r=4, seed=0):
    """A rank-(r+1) matrix whose columns are smooth trajectories (cm scale) plus offsets."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, T)[:, None]
    freqs = rng.uniform(0.5, 2.0, r)
    phases = rng.uniform(0, 2 * np.pi, r)
    basis = np.sin(2 * np.pi * freqs * t * 2 + phases) * 15.0               # (T, r)
    X = basis @ rng.standard_normal((r, C)) + rng.uniform(-80, 80, C)
    return X


def random_mask(shape, missing, seed=1):
    rng = np.random.default_rng(seed)
    m = rng.random(shape) >= missing
    m[0] = m[-1] = True                    # keep ends observed so interpolation is defined
    return m


def rmse_missing(A, X, mask):
    return float(np.sqrt(np.mean((A - X)[~mask] ** 2)))


def line_skeleton(J):
    return Skeleton(tuple(f"m{j}" for j in range(J)), np.r_[-1, np.arange(J - 1)], np.zeros((J, 3)))


# ----------------------------------------------------------------------------------------
# second-difference matrix and the DCT M-step
# ----------------------------------------------------------------------------------------
def test_second_difference_matrix_rows():
    O = cp.second_difference_matrix(6)
    np.testing.assert_array_equal(O[0, :2], [-1, 1])
    np.testing.assert_array_equal(O[2, 1:4], [1, -2, 1])
    np.testing.assert_array_equal(O[-1, -2:], [1, -1])        # the fixed last row
    np.testing.assert_array_equal(O, O.T)
    assert np.allclose(O.sum(axis=1), 0)                      # constants are in the null space


def test_dct_eigenvalues_match_dense():
    n = 9
    w = np.sort(np.linalg.eigvalsh(cp.second_difference_matrix(n)))
    np.testing.assert_allclose(np.sort(cp.dct_eigenvalues(n)), w, atol=1e-12)


@pytest.mark.parametrize("n", [2, 4, 7, 16, 17])
def test_dct_mstep_equals_dense_solve(n):
    rng = np.random.default_rng(n)
    O = cp.second_difference_matrix(n)
    eta, mu = 0.37, 12.5
    rhs = rng.standard_normal((n, 4))
    dense = np.linalg.solve(eta * np.eye(n) + mu * O.T @ O, rhs)
    np.testing.assert_allclose(cp.smooth_solve(rhs, eta, mu), dense, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(cp.smooth_solve(rhs, eta, mu, "banded"), dense, rtol=1e-10, atol=1e-12)


# ----------------------------------------------------------------------------------------
# rank estimation
# ----------------------------------------------------------------------------------------
def test_estimate_rank_planted():
    rng = np.random.default_rng(0)
    U, _ = np.linalg.qr(rng.standard_normal((200, 6)))
    V, _ = np.linalg.qr(rng.standard_normal((30, 6)))
    s = np.array([10.0, 8.0, 6.0, 4.0, 2.0, 0.5])          # normalised jumps .2,.2,.2,.2,.15
    X = (U * s) @ V.T
    assert cp.estimate_rank(X) == 5                           # last jump >= 0.1 is 4 -> 5 (0.2 -> 0.05)
    X2 = (U[:, :3] * [10.0, 7.0, 3.0]) @ V[:, :3].T + 1e-3 * rng.standard_normal((200, 30))
    assert cp.estimate_rank(X2) == 3
    assert cp.estimate_rank(X2, threshold=0.35) == 2          # only the 10 -> 7 -> 3 jump of 0.4


def test_estimate_rank_with_missing():
    X = smooth_lowrank(T=300, C=30, r=3)
    m = random_mask(X.shape, 0.3)
    full = cp.estimate_rank(X)
    assert abs(cp.estimate_rank(np.where(m, X, np.nan), m) - full) <= 1


# ----------------------------------------------------------------------------------------
# TSMC and TrNN recover a low-rank smooth matrix with 40% missing
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("solver", [cp.tsmc, cp.trnn])
def test_lowrank_smooth_recovery(solver):
    X = smooth_lowrank()
    m = random_mask(X.shape, 0.4)
    Xin = np.where(m, X, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("error")                        # must converge without warning
        A, info = solver(Xin, m, return_info=True)
    assert info.converged and info.n_iter < 200
    scale = np.sqrt(np.mean((X - X.mean(0)) ** 2))
    err = rmse_missing(A, X, m)
    assert err < 0.05 * scale, (err, scale)
    # better than filling by the column means (a trivial completion)
    mean_fill = np.where(m, X, np.nanmean(Xin, axis=0))
    assert err < 0.2 * rmse_missing(mean_fill, X, m)


def test_trnn_sparse_error_on_observed():
    """Large sparse spikes on observed entries go to S, not to the low-rank part."""
    X = smooth_lowrank(seed=3)
    rng = np.random.default_rng(4)
    m = random_mask(X.shape, 0.2)
    spikes = (rng.random(X.shape) < 0.02) & m
    D = X + spikes * 40.0
    A, info = cp.trnn(D, m, return_info=True)
    assert np.sqrt(np.mean((A - X)[spikes] ** 2)) < 0.25 * 40.0
    assert np.abs(info.extra["S"][spikes]).mean() > 20.0


def test_long_clips_solved_in_segments(recwarn):
    """tsmc / trnn with ``segment``: overlapping segments cross-faded, one summary and at
    most one convergence warning; close to the whole-clip solve on a smooth low-rank clip."""
    m = _smooth_motion(T=900, J=6)
    rng = np.random.default_rng(2)
    obs = rng.random(m.observed.shape) > 0.1
    noisy = m.with_positions(m.positions + 0.3 * rng.standard_normal(m.positions.shape), obs)
    for name in ("trnn", "tsmc"):
        whole = denoise.get(name, segment=None).denoise(noisy)
        seg = denoise.get(name, segment=256).denoise(noisy)
        assert seg.source["solver"]["segments"] == 4 and "segments" not in whole.source["solver"]
        e_whole = np.sqrt(np.mean((whole.positions - m.positions) ** 2))
        e_seg = np.sqrt(np.mean((seg.positions - m.positions) ** 2))
        assert e_seg < 1.5 * e_whole + 0.05, (name, e_seg, e_whole)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        denoise.get("trnn", segment=256, max_iter=3).denoise(noisy)
    conv = [w for w in caught if issubclass(w.category, ConvergenceWarning)]
    assert len(conv) == 1 and "of 4 segments" in str(conv[0].message)


def test_solvers_reject_bad_input():
    with pytest.raises(MocapValueError):
        cp.tsmc(np.ones((5, 3)), np.zeros((5, 3), bool))
    with pytest.raises(MocapValueError):
        cp.trnn(np.ones(5))
    with pytest.raises(MocapValueError):
        cp.trnn(np.full((4, 3), np.nan), np.ones((4, 3), bool))


def test_not_converged_warns():
    X = smooth_lowrank(T=100, C=12)
    with pytest.warns(ConvergenceWarning, match="not converged"):
        _, info = cp.trnn(X, max_iter=3, return_info=True)
    assert not info.converged and info.n_iter == 3


# ----------------------------------------------------------------------------------------
# LLC
# ----------------------------------------------------------------------------------------
def _direct_llc(y, D, m, lam, g):
    """KKT solve of min ||m o (y - D^T c)||^2 + lam sum g c^2 s.t. sum c = 1."""
    K = D.shape[0]
    Dm = D[:, m].T
    H = np.zeros((K + 1, K + 1))
    H[:K, :K] = 2 * (Dm.T @ Dm + lam * np.diag(g))
    H[:K, K] = H[K, :K] = 1.0
    sol = np.linalg.solve(H, np.r_[2 * Dm.T @ y[m], 1.0])
    return sol[:K]


def test_llc_closed_form_equals_constrained_lstsq():
    rng = np.random.default_rng(0)
    N, K, d = 6, 8, 7
    Y = rng.standard_normal((N, d))
    D = rng.standard_normal((K, d))
    mask = rng.random((N, d)) > 0.3
    mask[:, 0] = True
    codes, idx = llc.llc_code(Y, D, mask, lam=0.7, eps=0.0)
    W = llc.dense_codes(codes, idx, K)
    np.testing.assert_allclose(W.sum(axis=1), 1.0)
    for i in range(N):
        m = mask[i]
        dist = np.sqrt(((Y[i, m] - D[:, m]) ** 2).sum(1))
        g = np.exp((dist - dist.max()) / dist.mean())
        np.testing.assert_allclose(W[i], _direct_llc(Y[i], D, m, 0.7, g), atol=1e-9)


def test_llc_knn_uses_nearest_atoms_and_reconstructs():
    rng = np.random.default_rng(1)
    D = rng.standard_normal((50, 5)) * 10
    # each sample is an affine combination of 3 atoms (weights sum to 1)
    pick = np.stack([rng.choice(50, 3, replace=False) for _ in range(20)])
    w = rng.dirichlet(np.ones(3), size=20)
    Y = np.einsum("nk,nkd->nd", w, D[pick])
    codes, idx = llc.llc_code(Y, D, lam=1e-9, n_neighbors=10, eps=1e-12)
    d2 = llc.masked_sq_distances(Y, D)
    nearest = np.argsort(d2, axis=1)[:, :10]
    assert all(set(a) == set(b) for a, b in zip(idx, nearest))
    np.testing.assert_allclose(codes.sum(1), 1.0)
    # a point inside the hull of its nearest atoms is reproduced closely
    rec = llc.llc_reconstruct(codes, idx, D)
    assert np.sqrt(np.mean((rec - Y) ** 2)) < np.sqrt(np.mean((Y - Y.mean(0)) ** 2))


def test_masked_distances():
    rng = np.random.default_rng(2)
    Y, D = rng.standard_normal((4, 6)), rng.standard_normal((3, 6))
    m = rng.random((4, 6)) > 0.5
    ref = np.array([[((Y[i] - D[k]) ** 2 * m[i]).sum() for k in range(3)] for i in range(4)])
    np.testing.assert_allclose(llc.masked_sq_distances(Y, D, m), ref, atol=1e-12)


# ----------------------------------------------------------------------------------------
# trust-data detection
# ----------------------------------------------------------------------------------------
def _smooth_motion(T=600, J=8, fps=120.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None] / fps
    f = rng.uniform(0.3, 1.5, (1, J, 3))
    P = 40 * np.sin(2 * np.pi * f * t + rng.uniform(0, 6, (1, J, 3))) + rng.uniform(-50, 50, (1, J, 3))
    return Motion(P, line_skeleton(J), fps)


def test_trust_data_flags_spikes_not_clean():
    m = _smooth_motion()
    assert not trust_data(m).any()
    rng = np.random.default_rng(5)
    spikes = rng.random(m.observed.shape) < 0.05
    d = rng.standard_normal(m.positions.shape)
    d /= np.linalg.norm(d, axis=2, keepdims=True)
    noisy = m.with_positions(m.positions + 15.0 * d * spikes[..., None])
    flagged = trust_data(noisy)
    assert (flagged == spikes).all()
    # missing samples are never flagged; gaps do not create false alarms
    obs = rng.random(m.observed.shape) > 0.2
    gappy = noisy.with_observed(obs)
    f2 = trust_data(gappy)
    assert not (f2 & ~obs).any()
    assert (f2 == (spikes & obs)).all()
    np.testing.assert_array_equal(trusted_mask(gappy), obs & ~spikes)


def test_detect_report_lists_flagged_frames():
    m = _smooth_motion(T=200, J=3)
    P = m.positions.copy()
    P[50:53, 1, 0] += 20.0
    rep = detect_report(m.with_positions(P))
    assert rep["n_flagged"] == 3 and rep["frames_flagged"] == 3
    assert rep["markers"] == {"m1": {"count": 3, "frames": [50, 51, 52], "runs": [[50, 53]]}}


def test_trust_data_rejects_bad_threshold():
    with pytest.raises(MocapValueError):
        trust_data(_smooth_motion(T=20, J=2), threshold_cm=-1)


# ----------------------------------------------------------------------------------------
# DynaMMo
# ----------------------------------------------------------------------------------------
def sample_lds(T=400, k=4, C=12, seed=0):
    """Trajectory of a stable oscillating LDS observed through C channels (small noise)."""
    rng = np.random.default_rng(seed)
    blocks = []
    for w in (0.05, 0.11):
        c, s = np.cos(w), np.sin(w)
        blocks.append(0.995 * np.array([[c, -s], [s, c]]))
    A = np.zeros((k, k))
    A[:2, :2], A[2:, 2:] = blocks
    z = np.zeros((T, k))
    z[0] = rng.standard_normal(k) * 10
    for t in range(1, T):
        z[t] = A @ z[t - 1] + 0.3 * rng.standard_normal(k)
    C_ = rng.standard_normal((C, k))
    return z @ C_.T + 0.05 * rng.standard_normal((T, C))


def test_dynammo_beats_linear_interpolation_on_gap():
    X = sample_lds()
    m = np.ones(X.shape, bool)
    m[150:210, :4] = False                                    # 60-frame gap in 4 channels
    Xin = np.where(m, X, np.nan)
    A, info = cp.lds_em_complete(Xin, m, k=4, max_iter=400, return_info=True)
    assert info.converged
    lin = gaps.fill(Xin, m, never_observed=0.0)
    e_lds, e_lin = rmse_missing(A, X, m), rmse_missing(lin, X, m)
    assert e_lds < 0.5 * e_lin, (e_lds, e_lin)
    np.testing.assert_array_equal(A[m], X[m])
    assert info.n_iter >= 1


# ----------------------------------------------------------------------------------------
# Denoisers on synthetic motions
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["tsmc", "trnn", "dynammo"])
def test_training_free_denoisers_fill_and_report(name):
    J = 10
    X = smooth_lowrank(T=240, C=3 * J, r=4, seed=7)
    m = _smooth_motion(T=240, J=J).with_positions(X.reshape(240, J, 3))
    rng = np.random.default_rng(0)
    obs = rng.random((240, J)) > 0.3
    obs[[0, -1]] = True
    noisy = m.with_observed(obs)
    with gaps.use_policy(gaps.FILL_ALL):                 # the method's fill, every entry
        out = denoise.get(name).denoise(noisy)
    assert out.observed.all() and np.isfinite(out.positions).all()
    miss = ~obs
    lin = gaps.fill(noisy.matrix(), noisy.matrix_mask(), never_observed=0.0).reshape(240, J, 3)
    err = np.sqrt(np.mean((out.positions - m.positions)[miss] ** 2))
    assert err < np.sqrt(np.mean((lin - m.positions)[miss] ** 2)) + 0.5
    assert out.source["solver"]["method"] == name and out.source["solver"]["converged"]
    if name == "dynammo":
        np.testing.assert_array_equal(out.positions[obs], noisy.positions[obs])


def test_evidence_blend_weights_and_protocol_frames_untouched():
    """mocapkit.solvers.evidence: beta_t = clip((r_t - 0.15) / 0.2, 0, 1) on the fraction of
    markers observed in a frame; the thesis' 60 %-per-frame protocol (12 of 31 seen) and
    anything denser keep the model's fill, a frame with 2 of 31 takes the linear fill."""
    from mocapkit.solvers.evidence import blend_weight, evidence_blend

    obs = np.ones((5, 31), bool)
    obs[1, 12:] = False                     # 12 of 31 observed: r = 0.387
    obs[2, 2:] = False                      # 2 of 31: r = 0.065
    obs[3, 7:] = False                      # 7 of 31: r = 0.226 -> beta = 0.379
    obs[4, :] = False
    w = blend_weight(obs)
    np.testing.assert_allclose(w, [1, 1, 0, (7 / 31 - 0.15) / 0.2, 0])
    A = np.full((5, 93), 10.0)
    L = np.zeros((5, 93))
    mask = np.repeat(obs, 3, axis=1)
    B = evidence_blend(A, L, mask, obs)
    np.testing.assert_array_equal(B[mask], 10.0)                       # observed untouched
    np.testing.assert_allclose(B[3][~mask[3]], 10.0 * w[3])
    assert (B[2][~mask[2]] == 0).all() and (B[1] == 10).all()
    L[3, 40] = np.nan                                                  # no linear value: keep A
    assert evidence_blend(A, L, mask, obs)[3, 40] == 10.0


@pytest.mark.parametrize("name", ["tsmc", "trnn"])
def test_thesis_95_percent_missing_not_worse_than_linear(name):
    """Issue 18: tsmc / trnn filled 76 / 32 cm off on a 95 %-missing walk (linear: 8 cm)."""
    from mocapkit import corrupt, gaps, io
    from mocapkit.datasets import bundled

    truth = io.read(bundled("16_15.amc")).slice(240, 471)
    inp, _ = corrupt.missing(truth, ratio=0.95, per_frame=False, seed=1)
    with gaps.use_policy(gaps.FILL_ALL), warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        out = denoise.get(name).denoise(inp)
        lin = denoise.get("linear").denoise(inp)
    miss = ~inp.observed
    e = np.sqrt(np.mean((out.positions - truth.positions)[miss] ** 2))
    el = np.sqrt(np.mean((lin.positions - truth.positions)[miss] ** 2))
    assert e <= 1.05 * el, (e, el)


# ----------------------------------------------------------------------------------------
# PSC on a real clip
# ----------------------------------------------------------------------------------------
def _real_clip(shared_data):
    pytest.importorskip("mocapkit.io.amc")
    from mocapkit import io
    from mocapkit.datasets import cmu_amc

    path = cmu_amc("16_15", shared_data)
    if path is None:
        pytest.skip("16_15.amc not available")
    return io.read(path)


def test_psc_fit_denoise_save_load(shared_data, tmp_path):
    clip = _real_clip(shared_data)
    train, test = clip.slice(0, 300), clip.slice(300, 420)
    model = denoise.get("psc", n_atoms=48, n_iter=2, max_windows=500).fit([train])
    assert len(model.dictionaries_) == 5
    rng = np.random.default_rng(0)
    obs = rng.random(test.observed.shape) > 0.3
    noisy = test.with_observed(obs)
    out = model.denoise(noisy)
    assert out.observed.all() and np.isfinite(out.positions).all()
    np.testing.assert_array_equal(out.positions[obs], test.positions[obs])      # kept
    miss = ~obs
    err = np.sqrt(np.mean((out.positions - test.positions)[miss] ** 2))
    assert err < 5.0, err                                    # cm, a walk with 30% markers missing
    path = tmp_path / "psc.npz"
    model.save(path)
    loaded = denoise.Denoiser.load(path)
    np.testing.assert_array_equal(loaded.denoise(noisy).positions, out.positions)
    with pytest.raises(MocapValueError):
        model.denoise(test.slice(0, 5))                      # shorter than the window


@pytest.mark.parametrize("masked", [False, True])
def test_kalman_rts_equals_dense_posterior(masked):
    """The smoother's means, summed covariances and lag-one cross covariances are the
    Gaussian posterior of the LDS, computed here by one dense solve."""
    rng = np.random.default_rng(0)
    T, k, C = (40 if masked else 150), 3, 5          # 150: steady-state shortcuts are used
    A = np.array([[0.9, 0.1, 0], [-0.1, 0.9, 0], [0, 0, 0.8]])
    Cm = rng.standard_normal((C, k))
    Q = np.eye(k) * 0.1 + 0.02
    Rd = rng.uniform(0.1, 0.5, C)
    u0, V0 = rng.standard_normal(k), np.eye(k)
    X = rng.standard_normal((T, C))
    obs = rng.random((T, C)) > 0.3 if masked else np.ones((T, C), bool)
    if masked:
        out = cp._kalman_rts_masked(X, obs / Rd, A, Cm, Q, u0, V0)
    else:
        out = cp._kalman_rts(X, A, Cm, Q, Rd, u0, V0)
    n = T * k
    H, h = np.zeros((n, n)), np.zeros(n)
    iQ = np.linalg.inv(Q)

    def b(i):
        return slice(i * k, (i + 1) * k)
    H[b(0), b(0)] += np.linalg.inv(V0)
    h[b(0)] += np.linalg.inv(V0) @ u0
    for t in range(1, T):
        H[b(t), b(t)] += iQ
        H[b(t - 1), b(t - 1)] += A.T @ iQ @ A
        H[b(t), b(t - 1)] -= iQ @ A
        H[b(t - 1), b(t)] -= A.T @ iQ
    for t in range(T):
        w = obs[t] / Rd
        H[b(t), b(t)] += Cm.T @ (w[:, None] * Cm)
        h[b(t)] += Cm.T @ (w * X[t])
    S = np.linalg.inv(H)
    mean = (S @ h).reshape(T, k)
    Vsum = sum(S[b(t), b(t)] for t in range(T))
    cross = sum(S[b(t), b(t - 1)] for t in range(1, T))
    ms, vs, vs_prev, vs_next, cr, v1 = out
    np.testing.assert_allclose(ms, mean, atol=1e-8)
    np.testing.assert_allclose(vs, Vsum, atol=1e-8)
    np.testing.assert_allclose(vs_prev, Vsum - S[b(T - 1), b(T - 1)], atol=1e-8)
    np.testing.assert_allclose(vs_next, Vsum - S[b(0), b(0)], atol=1e-8)
    np.testing.assert_allclose(cr, cross, atol=1e-8)
    np.testing.assert_allclose(v1, S[b(0), b(0)], atol=1e-8)
