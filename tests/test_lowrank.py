"""Low-rank family: solver correctness (TSVD, SVT, RPCA-IALM, SLRA) and the Denoiser wrappers."""
import warnings

import numpy as np
import pytest

from mocapkit import Motion, Skeleton, denoise, gaps
from mocapkit.errors import MocapValueError
from mocapkit.signal import estimate_noise
from mocapkit.solvers import lowrank as lr
from mocapkit.solvers._linalg import blas_limit


# ----------------------------------------------------------------------------- helpers
def low_rank_plus_sparse(m=50, n=50, r=2, frac=0.05, seed=1):
    """Candes et al. (2011) exact-recovery regime: rank r, ``frac`` gross errors in [-10, 10]."""
    rng = np.random.default_rng(seed)
    L = rng.standard_normal((m, r)) @ rng.standard_normal((r, n))
    S = np.zeros((m, n))
    idx = rng.random((m, n)) < frac
    S[idx] = rng.uniform(-10, 10, idx.sum())
    return L, S


def reference_pcp(D, lam, tol=1e-11, max_iter=50000):
    """Plain ADMM for min ||A||_* + lam||E||_1 s.t. A + E = D with a *fixed* penalty.

    Textbook two-block ADMM (no mu growth): converges to the convex optimum; stops when
    both the primal residual and the dual change are below tol (relative).
    """
    with blas_limit():                      # small SVDs: one BLAS thread is fastest
        return _reference_pcp(D, lam, tol, max_iter)


def _reference_pcp(D, lam, tol, max_iter):
    mu = D.size / (4 * np.abs(D).sum())
    Y = np.zeros_like(D)
    E = np.zeros_like(D)
    nD = np.linalg.norm(D)
    for _ in range(max_iter):
        U, s, Vt = np.linalg.svd(D - E + Y / mu, full_matrices=False)
        A = (U * np.maximum(s - 1 / mu, 0)) @ Vt
        R = D - A + Y / mu
        E_old = E
        E = np.sign(R) * np.maximum(np.abs(R) - lam / mu, 0)
        Y = Y + mu * (D - A - E)
        if np.linalg.norm(D - A - E) < tol * nD and mu * np.linalg.norm(E - E_old) < tol * nD:
            break
    return A, E


def pcp_objective(A, D, lam):
    return np.linalg.svd(A, compute_uv=False).sum() + lam * np.abs(D - A).sum()


def chain_motion(T=240, J=31, seed=0, fps=120.0):
    """A smooth, approximately low-rank synthetic motion (cm)."""
    rng = np.random.default_rng(seed)
    sk = Skeleton(tuple(f"j{i}" for i in range(J)), np.arange(J) - 1, np.tile([0, 10.0, 0], (J, 1)))
    t = np.arange(T) / fps
    base = sk.rest_positions()[None]                                   # (1, J, 3)
    freqs = rng.uniform(0.3, 1.5, size=(3,))
    phases = rng.uniform(0, 2 * np.pi, size=(J, 3, 3))
    amps = rng.uniform(1, 5, size=(J, 3, 3))
    wave = sum(amps[None, :, :, i] * np.sin(2 * np.pi * freqs[i] * t[:, None, None] + phases[None, :, :, i])
               for i in range(3))
    return Motion(base + wave + 20.0 * t[:, None, None], sk, fps)


# ----------------------------------------------------------------------------- SVT step
def test_shrinkage_gram_equals_lapack_and_textbook():
    rng = np.random.default_rng(0)
    M = rng.standard_normal((4, 120, 30)) @ np.diag(np.linspace(0.1, 5, 30))
    tau = np.array([0.5, 3.0, 10.0, 100.0])
    Ag, rg = lr.shrink_singular_values(M, tau, "gram")
    Al, rl = lr.shrink_singular_values(M, tau, "lapack")
    np.testing.assert_allclose(Ag, Al, atol=1e-9)
    np.testing.assert_array_equal(rg, rl)
    U, s, Vt = np.linalg.svd(M[1], full_matrices=False)
    np.testing.assert_allclose(Ag[1], (U * np.maximum(s - 3.0, 0)) @ Vt, atol=1e-9)
    assert rg[3] == 0 and not Ag[3].any()
    Aw, _ = lr.shrink_singular_values(M[0].T, 0.5, "gram")          # wide: uses the other side
    np.testing.assert_allclose(Aw, Ag[0].T, atol=1e-9)


# ----------------------------------------------------------------------------- RPCA
@pytest.mark.parametrize("svd", ["gram", "lapack"])
def test_rpca_exact_recovery_matches_reference_solver(svd):
    L, S = low_rank_plus_sparse()
    D = L + S
    lam = 1 / np.sqrt(50)
    A, E, info = lr.rpca_ialm(D, svd=svd, return_info=True)
    assert info.converged and info.n_iter < 100
    A_ref, E_ref = reference_pcp(D, lam)
    np.testing.assert_allclose(A, A_ref, atol=1e-4)
    np.testing.assert_allclose(E, E_ref, atol=1e-4)
    # exact recovery (Candes et al. 2011, Thm 1.1)
    assert np.linalg.norm(A - L) / np.linalg.norm(L) < 1e-5
    np.testing.assert_allclose(E, S, atol=1e-4)
    assert np.linalg.matrix_rank(A, tol=1e-6) == 2


@pytest.mark.parametrize("masked", [False, True])
def test_rpca_row_blocks_equal_the_whole_matrix(monkeypatch, masked):
    """A long single matrix is solved in row blocks (three arrays of its size, not five):
    the same A, E, iterations and residual as the whole-matrix iteration (a stack of two
    copies takes that route)."""
    rng = np.random.default_rng(5)
    D = rng.standard_normal((900, 3)) @ rng.standard_normal((3, 20))
    D[rng.random(D.shape) < 0.03] += 6.0
    mask = rng.random(D.shape) > 0.1 if masked else None
    two, _, info2 = lr.rpca_ialm(np.stack([D, D]), mask=None if mask is None else np.stack([mask, mask]),
                                 return_info=True)
    monkeypatch.setattr(lr, "ROW_BLOCK", 97)
    monkeypatch.setattr(lr, "CHUNK_ELEMENTS", 1000)
    calls = []
    monkeypatch.setattr(lr, "_ialm_chunk", lambda *a, **k: calls.append(1))   # must not be used
    D.setflags(write=False)                                      # only read
    A, E, info = lr.rpca_ialm(D, mask=mask, return_info=True)
    assert not calls and info.n_iter == info2.n_iter[0] and info.converged
    np.testing.assert_allclose(A, two[0], atol=1e-8)
    np.testing.assert_allclose(info.residual, info2.residual[0], rtol=1e-4)   # ~1e-7: round-off


def test_svt_overwrite_x_and_read_only_inputs():
    rng = np.random.default_rng(6)
    X = rng.standard_normal((200, 3)) @ rng.standard_normal((3, 12)) + 0.1 * rng.standard_normal((200, 12))
    eps = 0.1 * np.sqrt(X.size)
    keep = X.copy()
    A = lr.svt(X, eps=eps)
    np.testing.assert_array_equal(X, keep)                        # default: X untouched
    B = lr.svt(X, eps=eps, overwrite_x=True)
    assert B is X
    np.testing.assert_allclose(B, A, atol=1e-10)
    assert np.linalg.norm(A - keep) == pytest.approx(eps, rel=1e-6)
    # the Gram route has the singular vectors of X: A's right vectors are X's
    _, _, Vt = np.linalg.svd(keep, full_matrices=False)
    _, sa, Vta = np.linalg.svd(A, full_matrices=False)
    r = int((sa > 1e-8 * sa[0]).sum())
    np.testing.assert_allclose(np.abs(Vta[:r] @ Vt[:r].T), np.eye(r), atol=1e-6)
    R = keep.copy()
    R.setflags(write=False)
    lr.rpca_ialm(R)                                               # read-only input is fine


def test_rpca_noisy_reaches_convex_optimum():
    L, S = low_rank_plus_sparse(seed=2)
    D = L + S + 0.1 * np.random.default_rng(3).standard_normal(L.shape)
    lam = 1 / np.sqrt(50)
    A_ref, _ = reference_pcp(D, lam, tol=1e-9)
    A, E = lr.rpca_ialm(D, rho=1.05, tol=1e-9, max_iter=2000)
    f, f_ref = pcp_objective(A, D, lam), pcp_objective(A_ref, D, lam)
    assert abs(f - f_ref) / f_ref < 1e-5
    np.testing.assert_allclose(A, A_ref, atol=2e-3)
    np.testing.assert_allclose(A + E, D, atol=1e-6)


def test_rpca_with_mask_completes_missing_entries():
    rng = np.random.default_rng(4)
    L, S = low_rank_plus_sparse(m=100, n=100, r=2, frac=0.05, seed=4)
    mask = rng.random(L.shape) > 0.1
    D = np.where(mask, L + S, np.nan)
    A, E = lr.rpca_ialm(D, mask=mask)
    assert np.linalg.norm(A - L) / np.linalg.norm(L) < 1e-4
    assert np.abs(A - L)[~mask].max() < 1e-3


def test_ialm_per_entry_weights():
    L, S = low_rank_plus_sparse(m=60, n=20, seed=5)
    D = np.stack([L + S, 2 * (L + S)])
    lam = 1 / np.sqrt(60)
    A1, E1, _, _ = lr._ialm_batch(D, None, np.full(2, lam), 1e-9, 500, 1.5, "auto")
    A2, E2, _, _ = lr._ialm_batch(D, None, np.full(D.shape, lam), 1e-9, 500, 1.5, "auto")
    np.testing.assert_allclose(A1, A2, atol=1e-9)
    W = np.full(D.shape, lam)
    W[:, :, 0] = 1e3                          # l1 weight so high that column 0 cannot go to E
    A3, E3, _, _ = lr._ialm_batch(D, None, W, 1e-9, 2000, 1.5, "auto")
    assert np.abs(E3[:, :, 0]).max() < 1e-6 and np.abs(E3[:, :, 1:]).max() > 1


def test_rpca_batch_equals_single_and_checks_input():
    mats = [sum(low_rank_plus_sparse(m=60, n=20, seed=s)) for s in range(3)]
    A, E = lr.rpca_ialm(np.stack(mats))
    for i, D in enumerate(mats):
        A1, _ = lr.rpca_ialm(D)
        np.testing.assert_allclose(A[i], A1, atol=1e-10)
    bad = mats[0].copy()
    bad[3, 4] = np.nan
    with pytest.raises(MocapValueError, match="non-finite"):
        lr.rpca_ialm(bad)
    with pytest.raises(MocapValueError, match="mask"):
        lr.rpca_ialm(mats[0], mask=np.ones((2, 2), bool))
    with pytest.raises(MocapValueError):
        lr.rpca_ialm(np.zeros(5))
    A0, E0 = lr.rpca_ialm(np.zeros((10, 4)))                    # all-zero input: no division by 0
    assert not A0.any() and not E0.any()


# ----------------------------------------------------------------------------- TSVD / SVT
def test_tsvd_is_eckart_young_and_imputes():
    rng = np.random.default_rng(5)
    X = rng.standard_normal((200, 20))
    U, s, Vt = np.linalg.svd(X, full_matrices=False)
    np.testing.assert_allclose(lr.tsvd(X, 4), (U[:, :4] * s[:4]) @ Vt[:4], atol=1e-9)
    np.testing.assert_allclose(lr.tsvd(X, 50), X)                  # k clipped to min(m, n)
    L = rng.standard_normal((200, 3)) @ rng.standard_normal((3, 20))
    mask = rng.random(L.shape) > 0.3
    A = lr.tsvd(np.where(mask, L, np.nan), 3, mask, max_iter=500, tol=1e-12)
    assert np.abs(A - L).max() < 1e-4
    with pytest.raises(MocapValueError):
        lr.tsvd(X, 0)


def test_svt_completes_low_rank_matrix_from_half_the_entries():
    rng = np.random.default_rng(6)
    L = rng.standard_normal((200, 3)) @ rng.standard_normal((3, 60))     # Cai et al. Sec. 5.1 setting
    mask = rng.random(L.shape) < 0.5
    A, info = lr.svt(np.where(mask, L, np.nan), mask, return_info=True)
    assert info.converged and info.extra["rank"] == 3
    assert np.linalg.norm(A - L) / np.linalg.norm(L) < 1e-3
    assert np.linalg.norm((A - L)[~mask]) / np.linalg.norm(L[~mask]) < 1e-3


def test_svt_noisy_closed_form_equals_iteration():
    rng = np.random.default_rng(7)
    L = rng.standard_normal((60, 3)) @ rng.standard_normal((3, 20))
    X = L + 0.1 * rng.standard_normal(L.shape)
    eps = 0.1 * np.sqrt(X.size)
    A = lr.svt(X, eps=eps, tau=50.0)
    B = lr.svt(X, eps=eps, tau=50.0, method="iterative", tol=1e-9, max_iter=5000)
    np.testing.assert_allclose(A, B, atol=1e-5)
    assert np.linalg.norm(A - X) == pytest.approx(eps, rel=1e-6)
    assert np.linalg.norm(A - L) < np.linalg.norm(X - L)           # it denoises
    np.testing.assert_allclose(lr.svt(X), X)                       # eps = 0, all observed: X


def test_estimate_noise_rms_estimates_white_noise():
    rng = np.random.default_rng(8)
    t = np.linspace(0, 1, 2000)[:, None]
    X = np.sin(2 * np.pi * t * np.arange(1, 6)) + 0.3 * rng.standard_normal((2000, 5))
    assert estimate_noise(X, method="diff2-rms", pool="all") == pytest.approx(0.3, rel=0.05)


@pytest.mark.parametrize("method", ["diff2-rms", "diff2-mad", "diff4-mad", "diff4-rms"])
def test_pooled_noise_estimate_in_frame_blocks(monkeypatch, method):
    """The pooled estimate over blocks of frames equals the whole-matrix formula."""
    from mocapkit.signal import noise

    rng = np.random.default_rng(9)
    A = np.cumsum(rng.normal(size=(500, 5)), axis=0) * 0.01 + 0.4 * rng.normal(size=(500, 5))
    M = rng.random(A.shape) > 0.15
    k = 4 if method.startswith("diff4") else 2
    D, ok = noise._diff(np.where(M, A, 0.0), M, k)
    d2 = D[ok]
    ref = (np.sqrt(np.mean(d2 ** 2) / (6 if k == 2 else 70)) if method.endswith("rms")
           else noise._MAD * np.median(np.abs(d2)) / np.sqrt(6 if k == 2 else 70))
    from mocapkit import windows

    monkeypatch.setattr(windows, "FRAME_BLOCK", 37)
    A[~M] = np.nan
    assert estimate_noise(A, M, method=method, pool="all") == pytest.approx(ref, rel=1e-12)


# ----------------------------------------------------------------------------- SLRA
def test_segment_layout_matches_paper_and_overlaps():
    s, e = lr.segment_layout(1200, 200)
    assert list(s) == [0, 200, 400, 600, 800, 1000] and list(e - s) == [200] * 6
    s, e = lr.segment_layout(2000, n_segments=5)
    assert list(e - s) == [400] * 5
    s, e = lr.segment_layout(1005, 200)                            # near-equal parts
    assert len(s) == 5 and set(e - s) <= {200, 201} and e[-1] == 1005 and (s[1:] == e[:-1]).all()
    s, e = lr.segment_layout(1000, 100, overlap=30)
    assert s[0] == 0 and e[-1] == 1000 and len(set(e - s)) == 1
    assert ((e[:-1] - s[1:]) >= 30).all()
    s, e = lr.segment_layout(50, 200)                              # shorter than a segment
    assert list(s) == [0] and list(e) == [50]
    w = lr.blend_weights(*lr.segment_layout(1000, 100, overlap=30))
    total = np.zeros(1000)
    for (a, b), wi in zip(zip(*lr.segment_layout(1000, 100, overlap=30)), w):
        total[a:b] += wi
    np.testing.assert_allclose(total, 1.0)
    with pytest.raises(MocapValueError):
        lr.segment_layout(100, 50, overlap=50)


def test_slra_is_rpca_per_segment_and_keeps_low_rank_data():
    rng = np.random.default_rng(9)
    D = rng.standard_normal((300, 12)) @ rng.standard_normal((12, 30)) + (rng.random((300, 30)) < 0.05) * 8
    A, E, info = lr.slra(D, 100, return_info=True)
    assert list(info.extra["starts"]) == [0, 100, 200] and info.converged.all()
    for a in (0, 100, 200):
        A1, _ = lr.rpca_ialm(D[a:a + 100])
        np.testing.assert_allclose(A[a:a + 100], A1, atol=1e-8)
    np.testing.assert_allclose(A + E, D)
    # exactly low-rank data comes back unchanged with or without blended overlaps
    L = rng.standard_normal((300, 2)) @ rng.standard_normal((2, 30))
    for ov in (0, 25):
        np.testing.assert_allclose(lr.slra(L, 100, ov)[0], L, atol=1e-5)


def test_slra_with_mask_and_centre():
    rng = np.random.default_rng(10)
    L = rng.standard_normal((240, 2)) @ rng.standard_normal((2, 93)) + 50.0
    mask = rng.random(L.shape) > 0.05
    for center in ("none", "mean", "median"):
        A, E = lr.slra(np.where(mask, L, np.nan), 80, 20, mask=mask, center=center)
        assert np.isfinite(A).all() and not E[~mask].any()
        assert np.abs(A - L).max() < 1e-3
    with pytest.raises(MocapValueError, match="center"):
        lr.slra(L, center="mode")


# ----------------------------------------------------------------------------- Denoisers
@pytest.mark.parametrize("name", ["tsvd", "svt", "rpca", "slra"])
def test_denoisers_fill_missing_and_keep_shape(name):
    truth = chain_motion()
    rng = np.random.default_rng(11)
    P = truth.positions + rng.normal(0, 0.5, truth.positions.shape)
    obs = rng.random(truth.observed.shape) > 0.1
    noisy = Motion(P, truth.skeleton, truth.fps, obs)
    m = denoise.get(name, **denoise.available()[name].quick_params())
    out = m.denoise(noisy)
    assert out.positions.shape == truth.positions.shape and out.observed.all()
    assert np.isfinite(out.positions).all() and out.skeleton == truth.skeleton
    err = np.sqrt(np.mean((out.positions - truth.positions) ** 2, axis=2))
    assert err[~obs].mean() < 2.0                                  # missing joints recovered
    # the values behind the mask are never used
    P2 = P.copy()
    P2[~obs] = 1e6
    out2 = m.denoise(Motion(P2, truth.skeleton, truth.fps, obs))
    np.testing.assert_allclose(out2.positions, out.positions)


@pytest.mark.parametrize("name", ["tsvd", "svt", "rpca", "slra"])
def test_keep_observed_only_fills_gaps(name):
    truth = chain_motion(T=200)
    obs = np.random.default_rng(12).random(truth.observed.shape) > 0.2
    P = truth.positions + np.random.default_rng(13).normal(0, 0.3, truth.positions.shape)
    noisy = Motion(P, truth.skeleton, truth.fps, obs)
    out = denoise.get(name, keep_observed=True).denoise(noisy)
    np.testing.assert_array_equal(out.positions[obs], noisy.positions[obs])
    assert np.isfinite(out.positions).all()


def test_denoisers_edge_cases():
    truth = chain_motion(T=300)
    obs = np.ones(truth.observed.shape, bool)
    obs[:, 2] = False                                              # a joint never observed
    obs[100:290, 3] = False                                        # a gap longer than a segment
    m = Motion(np.where(obs[..., None], truth.positions, np.nan), truth.skeleton, truth.fps, obs)
    for name in ("tsvd", "svt", "rpca", "slra"):
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)         # issue 18: no raw warning
            out = denoise.get(name).denoise(m)
        # the never-observed joint comes back missing (never (0, 0, 0)); the rest is filled
        assert not out.observed[:, 2].any() and np.isnan(out.positions[:, 2]).all()
        keep = np.arange(31) != 2
        rep = out.source["gap_report"]
        assert np.isfinite(out.positions[:, keep][out.observed[:, keep]]).all()
        if name == "svt":
            # its fill of the 190-frame gap steps 9 cm into it and 27 cm out of it (9-27 cm
            # off the truth): the policy's speed check leaves it missing and says so
            assert not out.observed[100:290, 3].any() and rep["left_implausible"] == 190
        else:   # the 190-frame gap: kept where the method's own validation on the clip passes it
            assert out.observed[:, keep].all() or rep["left_implausible_by"].get("not validated under 5 cm")
        assert rep["never_observed"] == [truth.skeleton.names[2]]
    with gaps.use_policy(validate_cm=None):        # the segments' mechanics, every fill kept
        out = denoise.get("slra", segment=60, overlap=20).denoise(
            m.with_observed(np.ones_like(obs) & (np.arange(31) != 2)))
    assert np.isfinite(out.positions[:, np.arange(31) != 2]).all()
    short = truth.slice(0, 8)                                      # fewer frames than coordinates
    for name in ("tsvd", "svt", "rpca", "slra"):
        out = denoise.get(name).denoise(short)
        assert out.positions.shape == short.positions.shape and np.isfinite(out.positions).all()
        assert np.sqrt(np.mean((out.positions - short.positions) ** 2)) < 3.0
    for name in ("tsvd", "svt"):                                   # fine on 2 frames
        assert np.isfinite(denoise.get(name).denoise(truth.slice(0, 2)).positions).all()
    for name, params in (("rpca", {}), ("slra", {}), ("slra", {"segment": 4})):
        with pytest.raises(MocapValueError, match="at least 6"):
            denoise.get(name, **params).denoise(truth.slice(0, 5) if not params else truth)
    empty = truth.with_observed(np.zeros_like(obs))
    with pytest.raises(MocapValueError, match="no observed"):
        denoise.get("slra").denoise(empty)
    with pytest.raises(MocapValueError):
        denoise.get("slra", overlap=300).denoise(truth)


def test_slra_reduces_eq7_noise_on_real_clip(shared_data):
    pytest.importorskip("mocapkit.io.amc")
    corrupt = pytest.importorskip("mocapkit.corrupt")
    metrics = pytest.importorskip("mocapkit.metrics")
    from mocapkit import io
    from mocapkit.datasets import cmu_amc

    clean = io.read(cmu_amc("131_02", shared_data)).slice(0, 600)
    asf = clean.with_positions(clean.positions / 5.6444)           # CMU units, as the paper
    noisy, _ = corrupt.slra_noise(asf, n_frames=200, seed=0)
    fd_in = metrics.frobenius_distance(asf, noisy)
    for params in ({"segment": 200}, {"segment": 24, "overlap": 12, "tol": 1e-5}):
        est = denoise.get("slra", **params).denoise(noisy)
        fd = metrics.frobenius_distance(asf, est)
        assert fd < 0.6 * fd_in, (params, fd, fd_in)


# ----------------------------------------------------------------------------- issue 18
def _walk_95():
    from mocapkit import corrupt, io
    from mocapkit.datasets import bundled

    truth = io.read(bundled("16_15.amc")).slice(240, 471)
    inp, _ = corrupt.missing(truth, ratio=0.95, per_frame=False, seed=1)
    return truth, inp


def test_svt_heavy_missing_does_not_overflow():
    """Issue 18: at 95 % missing Cai et al.'s step 1.2 mn/|Omega| = 24 made the iterates
    overflow (a leaked RuntimeWarning, a NaN 'relative change').  The step is halved when
    the residual blows up; the result is finite and the criterion a number."""
    truth, inp = _walk_95()
    X, M = inp.matrix(), inp.matrix_mask()
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        A, info = lr.svt(X, M, eps=0.5 * np.sqrt(M.sum()), max_iter=200, return_info=True)
    assert np.isfinite(A).all() and np.isfinite(info.residual)
    assert info.extra["restarts"] >= 1 and info.extra["delta"] < 1.2 * M.size / M.sum()
    # a well-posed case is untouched: no restart, the paper's step
    _, info2 = lr.svt(truth.matrix(), np.random.default_rng(0).random(M.shape) > 0.2,
                      eps=1.0, max_iter=20, return_info=True)
    assert info2.extra["restarts"] == 0


@pytest.mark.parametrize("name", ["svt", "rpca", "slra", "tsvd"])
def test_lowrank_95_missing_close_to_linear(name):
    """Issue 18: rpca / slra reached 69-120 cm at 95 % missing (linear fill 6-8 cm)."""
    from mocapkit import gaps

    truth, inp = _walk_95()
    params = denoise.available()[name].quick_params()
    with gaps.use_policy(gaps.FILL_ALL), warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        warnings.filterwarnings("ignore", category=UserWarning)
        out = denoise.get(name, **params).denoise(inp)
        lin = denoise.get("linear").denoise(inp)
    miss = ~inp.observed

    def err(o):
        return float(np.sqrt(np.mean((o.positions - truth.positions)[miss] ** 2)))

    assert err(out) <= 1.05 * err(lin), (err(out), err(lin))


def test_rpca_missing_modes():
    """missing='linear' (default) vs Lin et al.'s masked constraint ('free'): the same
    without missing entries; with 30 % missing the prefill is the better completion
    (measured 2.1 vs 3.2 cm here), and 'free' is the solver with a mask."""
    from mocapkit import corrupt, io
    from mocapkit.datasets import bundled

    truth = io.read(bundled("16_15.amc")).slice(0, 200)
    a = denoise.get("rpca", tol=1e-5).denoise(truth)
    b = denoise.get("rpca", tol=1e-5, missing="free").denoise(truth)
    np.testing.assert_allclose(a.positions, b.positions)
    noisy, _ = corrupt.combine(truth, [("gaussian", {"sigma_cm": 0.5}),
                                       ("missing", {"ratio": 0.3, "per_frame": False})], seed=2)
    X, M = noisy.matrix(), noisy.matrix_mask()
    A, _ = lr.rpca_ialm(X, mask=M, tol=1e-5)
    free = denoise.get("rpca", tol=1e-5, missing="free", keep_observed=False)
    from mocapkit import gaps

    with gaps.use_policy(gaps.FILL_ALL):
        fo = free.denoise(noisy)
        lo = denoise.get("rpca", tol=1e-5).denoise(noisy)
    np.testing.assert_allclose(fo.matrix(), A, atol=1e-9)
    miss = ~M
    e_free = np.sqrt(np.mean((fo.matrix() - truth.matrix())[miss] ** 2))
    e_lin = np.sqrt(np.mean((lo.matrix() - truth.matrix())[miss] ** 2))
    assert e_lin < 0.8 * e_free, (e_lin, e_free)
    with pytest.raises(MocapValueError, match="missing"):
        denoise.get("slra", missing="zero").denoise(noisy)


def _flaky(real, fail_times):
    """A numpy.linalg routine that raises LinAlgError the first ``fail_times`` calls."""
    calls = {"n": 0}

    def f(*a, **k):
        calls["n"] += 1
        if calls["n"] <= fail_times:
            raise np.linalg.LinAlgError("SVD did not converge")
        return real(*a, **k)
    return f, calls


@pytest.mark.parametrize("routine", ["svd", "eigh", "eigvalsh"])
def test_decompositions_survive_lapack_failure(monkeypatch, routine):
    """Issue 18: `--method svt` on a 44-marker C3D stopped with a raw
    ``numpy.linalg.LinAlgError: SVD did not converge``.  Every SVD / eigh of the solvers
    goes through mocapkit.solvers._linalg, which retries with scipy's gesvd / syev and a
    tiny ridge; here numpy's routine fails every time."""
    from mocapkit.solvers import _linalg

    rng = np.random.default_rng(0)
    M = rng.standard_normal((40, 12)) @ rng.standard_normal((12, 30))
    ref = {"svd": lambda: np.linalg.svd(M, full_matrices=False)[1],
           "eigh": lambda: np.linalg.eigh(M.T @ M)[0],
           "eigvalsh": lambda: np.linalg.eigvalsh(M.T @ M)}[routine]()
    fake, calls = _flaky(getattr(np.linalg, routine), 10 ** 9)
    monkeypatch.setattr(np.linalg, routine, fake)
    got = {"svd": lambda: _linalg.svd(M)[1], "eigh": lambda: _linalg.eigh(M.T @ M)[0],
           "eigvalsh": lambda: _linalg.eigvalsh(M.T @ M)}[routine]()
    np.testing.assert_allclose(got, ref, rtol=1e-8, atol=1e-8 * ref.max())
    assert calls["n"] >= 1
    # the solvers themselves, end to end, on a stack too
    Xs = np.stack([M, 2 * M])
    A, rank = lr.shrink_singular_values(Xs, 1.0, svd="lapack" if routine == "svd" else "gram")
    assert np.isfinite(A).all() and rank.shape == (2,)
    with pytest.raises(MocapValueError, match="non-finite"):
        _linalg.svd(np.full((3, 3), np.nan)) if routine == "svd" else _linalg.eigh(np.full((3, 3), np.nan))


def test_svt_denoiser_survives_lapack_failure(monkeypatch):
    """The svt method on a masked 44-marker-like matrix with numpy's SVD failing now and then."""
    from mocapkit import corrupt, io
    from mocapkit.datasets import bundled

    truth = io.read(bundled("16_15.amc")).slice(0, 60)      # T = 60 < 2 x 93: LAPACK route
    noisy, _ = corrupt.missing(truth, ratio=0.3, per_frame=False, seed=4)
    fake, calls = _flaky(np.linalg.svd, 3)
    monkeypatch.setattr(np.linalg, "svd", fake)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        out = denoise.get("svt", max_iter=20).denoise(noisy)
    assert calls["n"] > 3 and np.isfinite(out.positions[out.observed]).all()
