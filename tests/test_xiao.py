"""Xiao et al. 2015 (seed 000): K-SVD, batched lasso / l1-l1 coding, local frame, poselets,
the xiao-sparse denoisers and the wavelet baseline."""
import numpy as np
import pytest

from mocapkit import Motion, Skeleton, denoise, gaps
from mocapkit.denoise.base import Denoiser
from mocapkit.denoise.sparse import XiaoSparse, detect_noise
from mocapkit.windows import lagged, overlap_mean
from mocapkit.denoise.wavelet import wavelet_shrink
from mocapkit.errors import MocapValueError, NotFittedError
from mocapkit.frames import frame_joints, pelvis_neck_frame
from mocapkit.solvers.ksvd import batch_omp, ksvd
from mocapkit.solvers.sparse_coding import (dictionary_svd, l1l1_admm, l1l1_objective, lasso_admm,
                                            lasso_fista, lasso_objective)


# ---------------------------------------------------------------------------------------
# synthetic skeleton with CMU ASF names (joint positions at bone *ends*, like our reader)
# ---------------------------------------------------------------------------------------
NAMES = ("root", "lhipjoint", "lfemur", "ltibia", "rhipjoint", "rfemur", "rtibia",
         "lowerback", "thorax", "upperneck", "head", "lclavicle", "lhumerus", "lradius",
         "rclavicle", "rhumerus", "rradius")
PARENTS = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 9, 8, 11, 12, 8, 14, 15)
OFFSETS = np.array([[0, 0, 0], [9, -8, 0], [0, -40, 0], [0, -40, 0], [-9, -8, 0], [0, -40, 0],
                    [0, -40, 0], [0, 15, 0], [0, 25, 0], [0, 15, 0], [0, 10, 0], [6, 3, 0],
                    [14, 0, 0], [0, -28, 0], [-6, 3, 0], [-14, 0, 0], [0, -28, 0]], float)
SKEL = Skeleton(NAMES, np.array(PARENTS), OFFSETS)


def _rot_y(a):
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 0, 0] = c
    R[..., 0, 2] = s
    R[..., 1, 1] = 1
    R[..., 2, 0] = -s
    R[..., 2, 2] = c
    return R


def synth_motion(T=300, fps=60.0, seed=0, phase=0.0):
    """A walking-like motion: limbs swing (rigid bones), root moves and turns."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / fps
    w = 2 * np.pi * (1.0 + 0.1 * rng.standard_normal())
    rest = SKEL.rest_positions()
    P = np.repeat(rest[None], T, axis=0)
    swing = {2: 0.5, 5: -0.5, 12: -0.4, 15: 0.4}                  # joint whose parent's bone swings
    for j, amp in swing.items():
        a = amp * np.sin(w * t + phase)
        p = PARENTS[j]
        sub = [k for k in range(len(NAMES)) if _descends(k, p) and k != p]
        R = np.stack([np.eye(3)] * T)
        c, s = np.cos(a), np.sin(a)
        R[:, 1, 1], R[:, 1, 2], R[:, 2, 1], R[:, 2, 2] = c, -s, s, c   # about x
        P[:, sub] = np.einsum("tij,tkj->tki", R, P[:, sub] - P[:, p:p + 1]) + P[:, p:p + 1]
    heading = 0.3 * t + 0.2 * np.sin(0.5 * w * t)
    P = np.einsum("tij,tkj->tki", _rot_y(heading), P)
    P += np.stack([30 * t, 90 + 2 * np.sin(2 * w * t), 10 * np.sin(0.3 * t)], axis=1)[:, None]
    return Motion(P, SKEL, fps)


def _descends(k, a):
    while k >= 0:
        if k == a:
            return True
        k = PARENTS[k]
    return False


# ---------------------------------------------------------------------------------------
# K-SVD and Batch-OMP
# ---------------------------------------------------------------------------------------
def test_batch_omp_matches_sklearn(rng):
    from sklearn.linear_model import orthogonal_mp_gram

    n, K, N = 30, 60, 80
    D = rng.standard_normal((n, K))
    D /= np.linalg.norm(D, axis=0)
    Y = rng.standard_normal((N, n))
    idx, coef = batch_omp(Y @ D, D.T @ D, 6)
    W = np.zeros((N, K))
    np.put_along_axis(W, idx, coef, axis=1)
    ref = orthogonal_mp_gram(D.T @ D, (Y @ D).T, n_nonzero_coefs=6).T
    np.testing.assert_allclose(W, ref, atol=1e-9)


def test_ksvd_recovers_planted_dictionary(rng):
    n, K, N, Ts = 20, 50, 1500, 3
    D0 = rng.standard_normal((n, K))
    D0 /= np.linalg.norm(D0, axis=0)
    X = np.zeros((N, K))
    for i in range(N):
        X[i, rng.choice(K, Ts, replace=False)] = rng.standard_normal(Ts)
    Y = X @ D0.T + 0.01 * rng.standard_normal((N, n))
    res = ksvd(Y, K, sparsity=Ts, n_iter=40, random_state=1, return_codes=True)
    D = res.dictionary
    np.testing.assert_allclose(np.linalg.norm(D, axis=0), 1.0, atol=1e-12)
    best = np.abs(D0.T @ D).max(axis=1)
    assert (best > 0.99).mean() >= 0.9, f"only {(best > 0.99).mean():.2f} of the atoms recovered"
    assert res.rmse[-1] < 0.3 * res.rmse[0]
    assert ((res.codes != 0).sum(axis=1) <= Ts).all()


def test_ksvd_sklearn_omp_and_exact_update_agree_on_quality(rng):
    Y = rng.standard_normal((300, 12))
    a = ksvd(Y, 24, sparsity=3, n_iter=3, random_state=0, omp="numpy")
    b = ksvd(Y, 24, sparsity=3, n_iter=3, random_state=0, omp="sklearn")
    np.testing.assert_allclose(a.dictionary, b.dictionary, atol=1e-8)
    c = ksvd(Y, 24, sparsity=3, n_iter=3, random_state=0, exact=True)
    assert c.rmse[-1] <= a.rmse[0]


def test_ksvd_rejects_bad_input():
    with pytest.raises(MocapValueError):
        ksvd(np.full((10, 3), np.nan), 4, sparsity=2)
    with pytest.raises(MocapValueError):
        ksvd(np.ones((10, 3)), 4, sparsity=5)


# ---------------------------------------------------------------------------------------
# batched coding against reference solvers
# ---------------------------------------------------------------------------------------
def _tiny(rng, n=8, K=15, S=4):
    D = rng.standard_normal((n, K))
    D /= np.linalg.norm(D, axis=0)
    return D, rng.standard_normal((S, n))


@pytest.mark.parametrize("solver", ["admm", "admm-relaxed", "fista"])
def test_lasso_matches_sklearn(rng, solver):
    from sklearn.linear_model import Lasso

    D, Z = _tiny(rng)
    n = D.shape[0]
    lam = np.array([0.7, 0.2, 1.5, 0.05])
    if solver.startswith("admm"):
        Th = lasso_admm(Z, D, lam, n_iter=20000, tol=1e-12, relax=1.8 if solver == "admm-relaxed" else 1.0)
    else:
        Th = lasso_fista(Z, D, lam, n_iter=20000, tol=1e-13)
    for s in range(len(Z)):
        # sklearn: (1/(2n)) ||y - Xw||^2 + alpha ||w||_1  ==  (eq. 4) / (2n) with alpha = lam/(2n)
        ref = Lasso(alpha=lam[s] / (2 * n), fit_intercept=False, tol=1e-14, max_iter=200000).fit(D, Z[s]).coef_
        np.testing.assert_allclose(Th[s], ref, atol=1e-6)


def _l1l1_lp(D, z, lam):
    from scipy.optimize import linprog

    n, K = D.shape
    c = np.concatenate([lam * np.ones(2 * K), np.ones(2 * n)])
    A = np.hstack([D, -D, np.eye(n), -np.eye(n)])
    r = linprog(c, A_eq=A, b_eq=z, bounds=(0, None), method="highs")
    assert r.status == 0
    return r.x[:K] - r.x[K:2 * K], r.fun


@pytest.mark.parametrize("relax", [1.0, 1.8])
@pytest.mark.parametrize("shape", [(8, 15), (12, 6)])          # overcomplete and undercomplete
def test_l1l1_admm_matches_linear_program(rng, shape, relax):
    D, Z = _tiny(rng, *shape, S=4)
    lam = 0.5
    W = l1l1_admm(Z, D, lam, n_iter=30000, tol=1e-11, relax=relax)
    for s in range(len(Z)):
        th, fun = _l1l1_lp(D, Z[s], lam)
        got = float(l1l1_objective(Z[s:s + 1], D, W[s:s + 1], lam)[0])
        assert abs(got - fun) <= 1e-4 * max(1.0, fun)
        np.testing.assert_allclose(W[s], th, atol=1e-4)


def test_l1l1_is_robust_to_sparse_outliers(rng):
    n, K, S = 40, 60, 30
    D = np.cumsum(rng.standard_normal((n, K)), axis=0)
    D /= np.linalg.norm(D, axis=0)
    X = rng.standard_normal((S, K)) * (rng.random((S, K)) < 0.05)
    clean = X @ D.T * 10
    Z = clean.copy()
    out = rng.random(Z.shape) < 0.1
    Z[out] += 30.0
    W, E = l1l1_admm(Z, D, 0.3, n_iter=1000, return_residual=True)
    Wl = lasso_admm(Z, D, 1.0, n_iter=1000)
    err_l1 = np.sqrt(np.mean((W @ D.T - clean) ** 2))
    err_l2 = np.sqrt(np.mean((Wl @ D.T - clean) ** 2))
    assert err_l1 < 0.25 * err_l2
    assert E.shape == Z.shape and np.abs(E[out]).mean() > 10 * np.abs(E[~out]).mean()


def test_truncated_svd_solves_the_truncated_problem(rng):
    n, K = 20, 30
    D = rng.standard_normal((n, 5)) @ rng.standard_normal((5, K)) + 1e-5 * rng.standard_normal((n, K))
    D /= np.linalg.norm(D, axis=0)
    Z = rng.standard_normal((3, n))
    sv = dictionary_svd(D, 1e-6)
    assert sv.rank == 5 and 0 < sv.dropped < 1e-3 * sv.s[0]
    Dr = (sv.P * sv.s) @ sv.V.T
    a = lasso_admm(Z, D, 0.3, n_iter=20000, tol=1e-12, svd=sv)
    b = lasso_fista(Z, Dr, 0.3, n_iter=50000, tol=1e-14)
    np.testing.assert_allclose(lasso_objective(Z, Dr, a, 0.3), lasso_objective(Z, Dr, b, 0.3), rtol=1e-6)
    np.testing.assert_allclose(sv.reconstruct(a), a @ Dr.T, atol=1e-10)
    assert dictionary_svd(D, 0.0).rank == n


# ---------------------------------------------------------------------------------------
# local frame, windows, poselets
# ---------------------------------------------------------------------------------------
def test_local_frame_round_trip_and_definition():
    m = synth_motion()
    for smooth in (False, True):
        f = pelvis_neck_frame(m.positions, SKEL, m.fps, smooth=smooth)
        L = f.to_local(m.positions)
        np.testing.assert_allclose(f.to_world(L), m.positions, atol=1e-10)
        R = f.rotation
        np.testing.assert_allclose(np.einsum("tji,tjk->tik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    f = pelvis_neck_frame(m.positions, SKEL, m.fps, smooth=False)
    L = f.to_local(m.positions)
    ix = frame_joints(SKEL)
    assert ix["lfemur"] == NAMES.index("lhipjoint") and ix["upperneck"] == NAMES.index("upperneck")
    np.testing.assert_allclose(L[:, ix["root"]], 0.0, atol=1e-10)                  # root at origin
    for k in ("lfemur", "rfemur", "upperneck"):
        np.testing.assert_allclose(L[:, ix[k], 2], L[:, ix["lfemur"], 2], atol=1e-10)  # plane || XY
    up = L[:, ix["upperneck"]] - 0.5 * (L[:, ix["lfemur"]] + L[:, ix["rfemur"]])
    np.testing.assert_allclose(up[:, [0, 2]], 0.0, atol=1e-10)                     # along +Y
    assert (up[:, 1] > 0).all()
    assert (L[:, ix["lfemur"], 0] > L[:, ix["rfemur"], 0]).all()                  # left is +X


def test_local_frame_aliases_and_errors():
    names = ("Hips", "LHipJoint", "LeftUpLeg", "RHipJoint", "RightUpLeg", "Spine", "Neck", "Neck1", "Head")
    parents = (-1, 0, 1, 0, 3, 0, 5, 6, 7)
    off = np.array([[0, 0, 0], [0, 0, 0], [9, -8, 0], [0, 0, 0], [-9, -8, 0], [0, 30, 0], [0, 20, 0],
                    [0, 5, 0], [0, 8, 0]], float)
    sk = Skeleton(names, np.array(parents), off)
    ix = frame_joints(sk)
    # LHipJoint sits on the root in cgspeed BVH files: skipped for LeftUpLeg
    assert (sk.names[ix["lfemur"]], sk.names[ix["rfemur"]], sk.names[ix["upperneck"]]) == ("LeftUpLeg", "RightUpLeg", "Neck1")
    with pytest.raises(MocapValueError, match="lfemur"):
        frame_joints(Skeleton(("a", "b", "c"), np.array([-1, 0, 1]), np.ones((3, 3))))
    assert sk.names[frame_joints(sk, {"upperneck": "Head"})["upperneck"]] == "Head"


def test_robust_frame_ignores_spikes():
    m = synth_motion(T=240)
    P = np.array(m.positions)
    P[100, NAMES.index("lhipjoint")] += 60.0                                       # one huge spike
    P[101, NAMES.index("upperneck")] -= 40.0
    f0 = pelvis_neck_frame(m.positions, SKEL, m.fps)
    f1 = pelvis_neck_frame(P, SKEL, m.fps)
    raw = pelvis_neck_frame(P, SKEL, m.fps, smooth=False)
    assert np.abs(raw.rotation[100] - f0.rotation[100]).max() > 0.3
    assert np.abs(f1.rotation - f0.rotation).max() < 0.01 and np.abs(f1.origin - f0.origin).max() < 0.01


def test_windows_and_overlap_mean_are_inverse(rng):
    X = rng.standard_normal((37, 6))
    Z = lagged(X, 5)
    assert Z.shape == (33, 30)
    np.testing.assert_array_equal(Z[3], X[3:8].ravel())
    np.testing.assert_allclose(overlap_mean(Z, 37, 5), X, atol=1e-12)
    with pytest.raises(MocapValueError):
        lagged(X[:3], 5)


def test_poselets_shared_joints_are_averaged(monkeypatch):
    m = synth_motion(T=120)
    model = XiaoSparse(window=5, n_atoms=16, sparsity=2, n_iter=1, noise="gaussian", lam=0.0).fit([m])
    parts = SKEL.body_parts()
    assert [model.part_names_[i] for i in range(5)] == list(parts)
    # part i returns its input + 10 (i + 1): a joint shared by several parts must come back
    # with the mean of their offsets
    monkeypatch.setattr(XiaoSparse, "_code_part", lambda self, i, X, kind, lam: X + 10.0 * (i + 1))
    with gaps.use_policy(move_margin_cm=None, misfit_factor=None):   # offsets of 10-50 cm on a smooth
        out = model.denoise(m)                                       # clip: the policy would give them back
    f = pelvis_neck_frame(m.positions, SKEL, m.fps, median_s=0.2, sigma_s=0.1)
    L = f.to_local(m.positions)
    expect = np.zeros(len(NAMES))
    for j in range(len(NAMES)):
        owners = [i for i, k in enumerate(parts) if j in parts[k]]
        expect[j] = np.mean([10.0 * (i + 1) for i in owners])
    assert expect[NAMES.index("thorax")] == 20.0 and expect[NAMES.index("root")] == 10.0 * (1 + 4 + 5) / 3
    np.testing.assert_allclose(f.to_local(out.positions), L + expect[None, :, None], atol=1e-9)


# ---------------------------------------------------------------------------------------
# the denoisers
# ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def trained():
    train = [synth_motion(T=400, seed=s, phase=s) for s in range(3)]
    return XiaoSparse(window=7, n_atoms=96, sparsity=4, n_iter=4).fit(train)


def test_denoise_removes_gaussian_noise_and_outliers(trained):
    from mocapkit import corrupt, metrics

    truth = synth_motion(T=300, seed=7, phase=0.3)
    noisy, mask = corrupt.gaussian(truth, sigma_cm=2.0, seed=1)
    out = trained.denoise(noisy)
    assert trained.last_info["type"] == "gaussian"
    assert metrics.rmse(truth, out) < 0.6 * metrics.rmse(truth, noisy)
    spiky, mask = corrupt.outliers(truth, ratio=0.1, mode="scale", factor=1.4, seed=2)
    out = trained.denoise(spiky)
    assert trained.last_info["type"] in ("outliers", "mixed")
    assert metrics.rmse(truth, out, mask) < 0.2 * metrics.rmse(truth, spiky, mask)


def test_detect_noise(rng):
    t = np.linspace(0, 6, 600)[:, None]
    X = 20 * np.sin(t * np.arange(1, 10)) + 0.3 * rng.standard_normal((600, 9))
    assert detect_noise(X)["type"] == "gaussian"
    Y = X.copy()
    sel = rng.random(Y.shape) < 0.1
    Y[sel] *= 1.4
    Y[sel] += 8.0
    info = detect_noise(Y)
    assert info["type"] == "mixed" and info["outlier_fraction"] > 0.05
    np.testing.assert_allclose(detect_noise(X)["sigma_cm"], 0.3, rtol=0.2)


def test_save_load_round_trip(trained, tmp_path):
    p = tmp_path / "xiao.npz"
    trained.save(p)
    back = Denoiser.load(p)
    assert type(back) is XiaoSparse and back.get_params() == trained.get_params()
    for a, b in zip(trained.dictionaries_, back.dictionaries_):
        np.testing.assert_array_equal(a, b)
    m = synth_motion(T=100, seed=3)
    np.testing.assert_array_equal(trained.denoise(m).positions, back.denoise(m).positions)


def test_fullpose_short_clip_missing_and_errors(trained):
    train = [synth_motion(T=300, seed=s) for s in range(2)]
    full = denoise.get("xiao-sparse-fullpose", window=5, n_atoms=64, sparsity=4, n_iter=2).fit(train)
    assert len(full.parts_) == 1 and len(full.parts_[0]) == len(NAMES)
    short = synth_motion(T=4, seed=5)
    for model in (trained, full):
        out = model.denoise(short)
        assert out.positions.shape == short.positions.shape and np.isfinite(out.positions).all()
    gappy = synth_motion(T=80, seed=6)
    obs = np.ones((80, len(NAMES)), bool)
    obs[20:30, 13] = False
    out = trained.denoise(gappy.with_observed(obs))
    assert out.observed.all() and np.abs(out.positions - gappy.positions).max() < 10
    with pytest.raises(NotFittedError):
        XiaoSparse().denoise(short)
    other = Motion(np.zeros((20, 3, 3)), Skeleton(("a", "b", "c"), np.array([-1, 0, 1]), np.ones((3, 3))), 60)
    with pytest.raises(MocapValueError, match="joints"):
        trained.denoise(other)
    with pytest.raises(MocapValueError, match="noise"):
        XiaoSparse(noise="salt").fit(train)


def test_parallel_training_gives_the_same_dictionaries():
    train = [synth_motion(T=150, seed=s) for s in range(2)]
    a = XiaoSparse(window=5, n_atoms=32, sparsity=3, n_iter=2, n_jobs=1).fit(train)
    b = XiaoSparse(window=5, n_atoms=32, sparsity=3, n_iter=2, n_jobs=2).fit(train)
    for x, y in zip(a.dictionaries_, b.dictionaries_):
        np.testing.assert_allclose(x, y, atol=1e-10)


# ---------------------------------------------------------------------------------------
# wavelet baseline
# ---------------------------------------------------------------------------------------
def test_wavelet_shrink(rng):
    t = np.linspace(0, 4, 512)
    clean = np.stack([30 * np.sin(2 * np.pi * 0.5 * t), 10 * np.cos(2 * np.pi * 0.8 * t) + 5 * t], axis=1)
    np.testing.assert_allclose(wavelet_shrink(clean, threshold_scale=0.0), clean, atol=1e-9)  # perfect reconstruction
    noisy = clean + rng.standard_normal(clean.shape)
    out = wavelet_shrink(noisy)
    assert np.sqrt(np.mean((out - clean) ** 2)) < 0.6
    assert np.sqrt(np.mean((wavelet_shrink(clean) - clean) ** 2)) < 0.05
    with pytest.raises(MocapValueError):
        wavelet_shrink(clean, wavelet="nope")


def test_wavelet_denoiser_fills_gaps():
    m = synth_motion(T=200)
    obs = np.ones((200, len(NAMES)), bool)
    obs[50:60, 3] = False
    out = denoise.get("wavelet").denoise(m.with_observed(obs))
    assert out.observed.all() and np.abs(out.positions - m.positions).max() < 2.0


# ---------------------------------------------------------------------------------------
# real data
# ---------------------------------------------------------------------------------------
def test_real_dance_clip(shared_data):
    pytest.importorskip("mocapkit.io.amc")
    from mocapkit import corrupt, io, metrics

    train = [io.read(shared_data / "cmu" / "asfamc" / "05" / f"05_0{i}.amc") for i in (2, 7)]
    truth = io.read(shared_data / "cmu" / "asfamc" / "05" / "05_03.amc").slice(20, 320)
    model = XiaoSparse(window=15, n_atoms=128, sparsity=6, n_iter=3, max_train_windows=2000).fit(train)
    gauss = denoise.get("gaussian")
    # outliers 10 % x 1.4 (the paper's "below 5 cm for outliers under 20 %")
    noisy, mask = corrupt.outliers(truth, ratio=0.1, mode="scale", factor=1.4, seed=4)
    e_x = metrics.per_frame_rmse_stats(truth, model.denoise(noisy), mask)[0]
    assert model.last_info["type"] in ("outliers", "mixed")
    assert e_x < 2.0 and e_x < 0.3 * metrics.per_frame_rmse_stats(truth, gauss.denoise(noisy), mask)[0]
    # Gaussian noise 20 dB: better than the per-channel Gaussian filter
    noisy, mask = corrupt.gaussian(truth, snr_db=20, seed=5)
    e_x = metrics.per_frame_rmse_stats(truth, model.denoise(noisy), mask)[0]
    assert model.last_info["type"] == "gaussian"
    assert e_x < metrics.per_frame_rmse_stats(truth, gauss.denoise(noisy), mask)[0] < metrics.per_frame_rmse_stats(truth, noisy, mask)[0]


def test_over_relaxation_converges_faster_and_is_validated(rng):
    """Over-relaxed lasso ADMM (alpha = 1.8) reaches a lower eq. (4) objective than plain
    ADMM after the same small number of iterations (the denoisers' fixed budget), on an
    ill-conditioned smooth dictionary like the learned ones (its exact solution is checked
    in test_lasso_matches_sklearn / test_l1l1_admm_matches_linear_program); alpha outside
    (0, 2) is an error."""
    n, K, S = 40, 60, 30
    D = np.cumsum(np.cumsum(rng.standard_normal((n, K)), axis=0), axis=0)
    D /= np.linalg.norm(D, axis=0)
    Z = (rng.standard_normal((S, K)) * (rng.random((S, K)) < 0.1)) @ D.T * 10 + 0.3 * rng.standard_normal((S, n))
    best = lasso_objective(Z, D, lasso_admm(Z, D, 0.5, n_iter=20000, tol=1e-12), 0.5).sum()
    gap = {a: lasso_objective(Z, D, lasso_admm(Z, D, 0.5, n_iter=12, tol=0.0, relax=a), 0.5).sum() - best
           for a in (1.0, 1.8)}
    assert 0 <= gap[1.8] < gap[1.0]
    for bad in (0.0, 2.0, -1.0):
        with pytest.raises(MocapValueError):
            lasso_admm(Z, D, 0.5, relax=bad)
        with pytest.raises(MocapValueError):
            l1l1_admm(Z, D, 0.5, relax=bad)
    with pytest.raises(MocapValueError, match=r"xiao-sparse: parameter l1_stride must be an integer >= 1, got 0"):
        XiaoSparse(l1_stride=0).fit([])         # parameters are checked before anything else


# ---------------------------------------------------------------------------------------
# blocked coding (issue 21: bounded memory on long clips, same numbers)
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("n_iter, stops", [(12, False), (300, True)])   # cap reached / early stop
def test_lasso_admm_blocks_equals_one_solve(rng, n_iter, stops):
    from mocapkit.solvers.sparse_coding import lasso_admm_blocks

    n, K, S, tol = 24, 40, 700, 1e-3
    D = rng.standard_normal((n, K))
    D /= np.linalg.norm(D, axis=0)
    Z = (rng.standard_normal((S, K)) * (rng.random((S, K)) < 0.1)) @ D.T + 0.05 * rng.standard_normal((S, n))
    lam = 0.2 + 0.1 * rng.random(S)                          # one lambda per window
    ref, info = lasso_admm(Z, D, lam, n_iter=n_iter, tol=tol, relax=1.8, return_info=True)
    assert info.converged == stops and (info.n_iter < n_iter) == stops
    out = np.full((S, K), np.nan)
    calls = []

    def consume(a, b, W):
        out[a:b] = W
        calls.append((a, b))

    blocks = [(512, 700), (256, 512), (0, 256)]
    got = lasso_admm_blocks(lambda a, b: Z[a:b], S, D, lam, consume, blocks=blocks,
                            restart=lambda: calls.clear(), n_iter=n_iter, tol=tol, relax=1.8)
    assert sorted(calls) == sorted(blocks)                  # the final pass covers every window once
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12)
    assert (got.n_iter, got.converged, got.residual, got.extra) == \
        (info.n_iter, info.converged, info.residual, info.extra)


@pytest.mark.parametrize("noise", ["gaussian", "mixed"])
def test_blocked_denoise_equals_one_block(monkeypatch, noise):
    """The windows of a long clip coded in many blocks (and the local frame applied by
    blocks of frames) give exactly the numbers of one block."""
    from mocapkit import windows

    train = [synth_motion(T=400, seed=s, phase=s) for s in range(2)]
    model = XiaoSparse(window=7, n_atoms=48, sparsity=3, n_iter=2, noise=noise).fit(train)
    m = synth_motion(T=1500, seed=5, phase=0.7)
    m = m.with_positions(m.positions + np.random.default_rng(1).normal(0, 1.0, m.positions.shape))
    monkeypatch.setattr(windows, "BLOCK_BYTES", 2 ** 40)
    monkeypatch.setattr(windows, "FRAME_BLOCK", 10 ** 9)
    one = model.denoise(m)
    monkeypatch.setattr(windows, "BLOCK_BYTES", 1)            # 256 windows per block
    monkeypatch.setattr(windows, "FRAME_BLOCK", 100)
    assert len(windows.window_blocks(1500, 1e3)) > 5
    many = model.denoise(m)
    np.testing.assert_allclose(many.positions, one.positions, rtol=0, atol=1e-9)   # bit-equal here; BLAS may round differently elsewhere
    assert many.source["convergence"] == one.source["convergence"]


def test_lab_marker_names_give_the_frame_joints():
    """Vicon names markers 'Subject:LASI', Qualisys 'L_IAS', Mixamo joints 'mixamorig:LeftUpLeg':
    the sides and the frame's hips and neck are found by the bare names, and a marker set's
    origin is a marker named like a root (SACR) or else its left hip marker -- not its first
    marker, which may sit on a hand."""
    from mocapkit.skeleton import _side, strip_side

    assert _side("Derrick:LASI") == "left" and _side("Derrick:RASI") == "right"
    assert _side("mixamorig:LeftUpLeg") == "left" and strip_side("Derrick:RASI") == "asi"
    assert _side("ForearmL:Marker3") is None and strip_side("ForearmL:Marker3") == "forearml:marker3"
    flat = ("Derrick:RFIN", "Derrick:C7", "Derrick:LASI", "Derrick:RASI", "Derrick:LKNE")
    sk = Skeleton(flat, -np.ones(5, int), np.zeros((5, 3)))
    assert frame_joints(sk) == {"root": 2, "lfemur": 2, "rfemur": 3, "upperneck": 1}
    sk2 = Skeleton(flat + ("Derrick:SACR",), -np.ones(6, int), np.zeros((6, 3)))
    assert frame_joints(sk2)["root"] == 5
    qtm = ("R_HM2", "CV7", "L_IAS", "R_IAS")
    assert frame_joints(Skeleton(qtm, -np.ones(4, int), np.zeros((4, 3)))) == \
        {"root": 2, "lfemur": 2, "rfemur": 3, "upperneck": 1}


def test_train_on_a_plug_in_gait_capture_and_fill_its_gaps(shared_data, tmp_path):
    """A lab's own marker set: xiao-sparse trained on kineticstoolkit's tennis serve (Vicon
    Plug-in Gait names, 'Derrick:LASI'), then run on the copy of that take with holes --
    before the bare names it refused to train ("no joint for 'lfemur'")."""
    from mocapkit import io
    from mocapkit.cli import main

    k = shared_data / "markers" / "kineticstoolkit"
    model, out = tmp_path / "pig.npz", tmp_path / "out.c3d"
    assert main(["train", "--method", "xiao-sparse", str(k / "kinematics_tennis_serve.c3d"), "-o", str(model),
                 "-q"]) == 0
    assert main(["denoise", str(k / "kinematics_tennis_serve_nan.c3d"), str(out), "--method", "xiao-sparse",
                 "--model", str(model), "-q"]) == 0
    src, got = io.read(k / "kinematics_tennis_serve_nan.c3d"), io.read(out)
    assert got.observed.all() and (~src.observed).sum() == 145
