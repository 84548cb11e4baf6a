"""xiao-sparse: convergence reports of the batched ADMM solvers, strided l1/l1 coding."""
import warnings

import numpy as np
import pytest

from mocapkit.denoise.sparse import XiaoSparse
from mocapkit.windows import lagged, overlap_mean, window_starts
from mocapkit.errors import ConvergenceWarning
from mocapkit.solvers.sparse_coding import l1l1_admm, lasso_admm

from test_xiao import synth_motion


def _problem(rng, n=12, K=20, S=6):
    D = rng.standard_normal((n, K))
    D /= np.linalg.norm(D, axis=0)
    return D, rng.standard_normal((S, n))


def test_admm_reports_non_convergence_after_one_iteration(rng):
    D, Z = _problem(rng)
    W, info = lasso_admm(Z, D, 0.5, n_iter=1, tol=1e-8, return_info=True)
    assert W.shape == (6, 20)
    assert info.n_iter == 1 and info.extra["max_iter"] == 1 and not info.converged
    assert info.extra["primal"] > 1e-8 or info.extra["dual"] > 1e-8
    assert info.residual == max(info.extra["primal"], info.extra["dual"])
    W, E, info = l1l1_admm(Z, D, 0.5, n_iter=1, tol=1e-8, return_residual=True, return_info=True)
    assert E.shape == Z.shape and info.n_iter == 1 and not info.converged
    assert info.residual == max(info.extra["primal"], info.extra["dual"]) > 1e-8


def test_admm_reports_convergence_when_residuals_are_small(rng):
    D, Z = _problem(rng)
    W, info = lasso_admm(Z, D, 0.5, n_iter=20000, tol=1e-6, return_info=True)
    assert info.converged and info.n_iter < 20000
    assert info.extra["primal"] <= 1e-6 and info.extra["dual"] <= 1e-6
    np.testing.assert_array_equal(W, lasso_admm(Z, D, 0.5, n_iter=20000, tol=1e-6))
    W, info = l1l1_admm(Z, D, 0.5, n_iter=30000, tol=1e-7, return_info=True)
    assert info.converged and info.n_iter < 30000 and info.residual <= 1e-7


@pytest.fixture(scope="module")
def model():
    train = [synth_motion(T=400, seed=s, phase=s) for s in range(3)]
    return XiaoSparse(window=7, n_atoms=96, sparsity=4, n_iter=4).fit(train)


def test_denoiser_summary_and_warning(model):
    from mocapkit import corrupt

    spiky, _ = corrupt.outliers(synth_motion(T=200, seed=7), ratio=0.1, mode="scale", factor=1.4, seed=2)
    model.set_params(noise="mixed", admm_iter=1, code_iter=1, warn_convergence=True)
    try:
        with pytest.warns(ConvergenceWarning, match=r"ADMM solves not converged after 1 iterations.*"
                                                    r"raise code_iter \(now 1\) / admm_iter"):
            out = model.denoise(spiky)
        c = out.source["convergence"]
        assert c["converged"] is False and c["n_solves"] == 2 * len(model.parts_)
        assert c["n_not_converged"] == c["n_solves"] and c["iterations"] == 1
        assert c["l1l1_iterations"] == 1 and c["lasso_iterations"] == 1
        assert c["residual"] > c["tol"] == 1e-4
        assert c["residual"] == max(c["l1l1_primal"], c["l1l1_dual"], c["lasso_primal"], c["lasso_dual"])
        model.set_params(warn_convergence=False)
        with warnings.catch_warnings():
            warnings.simplefilter("error", ConvergenceWarning)
            out = model.denoise(spiky)                # summary only, no warning
        assert out.source["convergence"]["converged"] is False and "convergence_" not in vars(model)
    finally:
        model.set_params(noise="auto", admm_iter=24, code_iter=12, warn_convergence=False)


def test_strided_windows_cover_every_frame_and_average(rng):
    T, M = 23, 5
    st = window_starts(T, M, 3)
    assert st[0] == 0 and st[-1] == T - M and np.all(np.diff(st) > 0)
    X = rng.standard_normal((T, 4))
    np.testing.assert_allclose(overlap_mean(lagged(X, M)[st], T, M, st), X)
    # frame t is the mean of its copies in the coded windows only
    R = lagged(X, M)[st] + rng.standard_normal((len(st), 4 * M))
    got = overlap_mean(R, T, M, st)
    t = 9
    copies = [R[k].reshape(M, 4)[t - s] for k, s in enumerate(st) if s <= t < s + M]
    np.testing.assert_allclose(got[t], np.mean(copies, axis=0))
    np.testing.assert_array_equal(window_starts(T, M, 1), np.arange(T - M + 1))


def test_stride_one_and_two_agree_roughly(model):
    from mocapkit import corrupt, metrics

    truth = synth_motion(T=300, seed=7, phase=0.3)
    spiky, mask = corrupt.outliers(truth, ratio=0.1, mode="scale", factor=1.4, seed=2)
    model.set_params(noise="outliers")
    try:
        errs = []
        for s in (1, 2):
            model.set_params(l1_stride=s)
            errs.append(metrics.rmse(truth, model.denoise(spiky), mask))
        assert errs[1] < 0.2 * metrics.rmse(truth, spiky, mask)
        assert abs(errs[1] - errs[0]) < 0.5 * errs[0]
    finally:
        model.set_params(noise="auto", l1_stride=2)
