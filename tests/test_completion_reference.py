"""tsmc / trnn (issue 21: Gram-form factor steps on the transposed layout, in place) against
literal transcriptions of the thesis' Algorithms 2 and 3: explicit factors, the dense
second-difference matrix O of eq. 4.2 and a dense solve of the M-step, the SVD for Lemma 1.

The ALMs amplify rounding once the penalty is large: on these problems the first ~40
iterations are reproducible to 1e-13, and by iteration 50 a 1e-15 change of the input moves
the reference itself by 2e-4 to 6e-4 relative (on a real clip a converged trnn moves by
~5e-5).  So the comparison runs a fixed 1 / 15 / 40 iterations (tol = 0), where the two
must agree to rounding, and to convergence only for the iteration count, the error in the
missing entries and a loose distance.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from mocapkit.solvers import completion as cp


def _problem(T=60, C=9, seed=0, frac=0.3):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 3, T)[:, None]
    X = np.sin(t * [1.0, 2.3]) @ rng.standard_normal((2, C)) + 0.05 * rng.standard_normal((T, C))
    m = rng.random((T, C)) > frac
    return X, m


def _multipliers(D, weight):
    Y = D / max(np.linalg.svd(D, compute_uv=False)[0], np.abs(D).max() / weight)
    return Y, Y.copy()


def _m_step(rhs, eta, mu):
    """(eta I + mu O^T O)^-1 rhs with the dense O of eq. 4.2, through its numerical
    eigendecomposition (a dense solve loses ~1e-8: the system's condition number is
    (eta + 16 mu) / eta = 1.6e8 at the thesis' start eta = 1e-5, mu = 100)."""
    xi, V = np.linalg.eigh(cp.second_difference_matrix(len(rhs)))
    return V @ ((V.T @ rhs) / (eta + mu * xi ** 2)[:, None])


def ref_tsmc(X, m, k, alpha=1.0, beta=100.0, l1=1e-5, l2=1e-5, gamma=1.4, lam_max=1e10,
             tol=1e-4, max_iter=500, seed=0):
    """Algorithm 2 (eqs. 4.9-4.14, misprints fixed as in the module docstring)."""
    T, C = X.shape
    D = np.where(m, X, 0.0)
    V = np.random.default_rng(seed).random((C, k))
    V /= np.linalg.norm(V)
    Y1, Y2 = _multipliers(D, alpha)
    E, M, UV_prev = np.zeros((T, C)), np.zeros((T, C)), np.zeros((T, C))
    I = np.eye(k)
    for it in range(1, max_iter + 1):
        Z = Y1 + Y2 + l1 * M + l2 * (D - E)
        U = Z @ V @ np.linalg.inv(I + (l1 + l2) * V.T @ V)                    # 4.9
        V = Z.T @ U @ np.linalg.inv(I + (l1 + l2) * U.T @ U)                  # 4.10
        UV = U @ V.T
        Ze = D - UV + Y2 / l2
        E = np.where(m, np.sign(Ze) * np.maximum(np.abs(Ze) - alpha / l2, 0.0), Ze)   # 4.11
        M = _m_step(l1 * UV - Y1, l1, beta)                                   # 4.13
        R1, R2 = M - UV, D - UV - E
        Y1 = Y1 + l1 * R1                                                     # 4.14
        Y2 = Y2 + l2 * R2
        nx = np.linalg.norm(D)
        crit = max(np.linalg.norm(R2) / nx, np.linalg.norm(R1) / nx,
                   np.linalg.norm(UV - UV_prev) / np.linalg.norm(UV))
        UV_prev = UV
        l1, l2 = min(gamma * l1, lam_max), min(gamma * l2, lam_max)
        if crit < tol:
            break
    return UV, E, it


def ref_trnn(X, m, r=15, mu=100.0, rho=1.4, eta=1e-5, eta_max=1e6, tol=1e-4, max_iter=500,
             seed=0):
    """Algorithm 3 (eqs. 4.24-4.26), d = min(T, C), lam = 100 / sqrt(max(T, C))."""
    T, C = X.shape
    d = min(T, C)
    lam = 100.0 / np.sqrt(max(T, C))
    D = np.where(m, X, 0.0)
    B = np.random.default_rng(seed).standard_normal((C, d))
    B /= np.linalg.norm(B)
    Xlin = cp.gaps.fill(np.where(m, X, np.nan), m, never_observed=0.0)
    _, _, Vt = np.linalg.svd(Xlin, full_matrices=False)
    Q = Vt[:r]                                                                # (r, C)
    P = (Xlin @ Q.T / np.linalg.norm(Xlin @ Q.T, axis=0)).T                   # (r, T)
    Y1, Y2 = _multipliers(D, lam)
    S, M, AB_prev = np.zeros((T, C)), np.zeros((T, C)), np.zeros((T, C))
    I = np.eye(d)

    def orth_max(N):                                   # Lemma 1
        U, _, Wt = np.linalg.svd(N, full_matrices=False)
        return Wt.T @ U.T

    for it in range(1, max_iter + 1):
        T1 = P.T @ Q + Y1 + Y2 + eta * (M + D - S)
        A = T1 @ B @ np.linalg.inv(I + 2 * eta * B.T @ B)                      # 4.24
        B = T1.T @ A @ np.linalg.inv(I + 2 * eta * A.T @ A)
        AB = A @ B.T
        Ts = D - AB + Y2 / eta
        S = np.where(m, np.sign(Ts) * np.maximum(np.abs(Ts) - lam / eta, 0.0), Ts)
        M = _m_step(eta * AB - Y1, eta, mu)                                   # 4.25
        P = orth_max(A @ (Q @ B).T)                                           # 4.26
        Q = orth_max(B @ (P @ A).T)
        R1, R2 = M - AB, D - AB - S
        Y1, Y2 = Y1 + eta * R1, Y2 + eta * R2
        nd = np.linalg.norm(D)
        crit = max(np.linalg.norm(R2) / nd, np.linalg.norm(R1) / nd,
                   np.linalg.norm(AB - AB_prev) / np.linalg.norm(AB))
        AB_prev = AB
        eta = min(rho * eta, eta_max)
        if crit < tol:
            break
    return AB, S, it


def _rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


@pytest.mark.parametrize("iters", [1, 15, 40])
def test_tsmc_iterations_equal_algorithm_2(iters):
    X, m = _problem()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        Y, info = cp.tsmc(np.where(m, X, np.nan), m, tol=0.0, max_iter=iters, return_info=True)
    Yr, Er, _ = ref_tsmc(X, m, k=X.shape[1], tol=0.0, max_iter=iters)
    assert _rel(Y, Yr) < 1e-9
    assert _rel(info.extra["E"], Er) < 1e-9


@pytest.mark.parametrize("iters", [1, 15, 40])
@pytest.mark.parametrize("r", [2, 0])
def test_trnn_iterations_equal_algorithm_3(iters, r):
    X, m = _problem(seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        Y, info = cp.trnn(np.where(m, X, np.nan), m, r=r, tol=0.0, max_iter=iters,
                          return_info=True)
    Yr, Sr, _ = ref_trnn(X, m, r=r, tol=0.0, max_iter=iters)
    assert _rel(Y, Yr) < 1e-9
    assert _rel(info.extra["S"], Sr) < 1e-9


@pytest.mark.parametrize("solver", ["tsmc", "trnn"])
def test_converged_solution_equals_the_reference(solver):
    X, m = _problem(T=40, C=6, seed=2, frac=0.2)
    Xin = np.where(m, X, np.nan)
    if solver == "tsmc":
        Y, info = cp.tsmc(Xin, m, return_info=True)
        Yr, _, it = ref_tsmc(X, m, k=6)
    else:
        Y, info = cp.trnn(Xin, m, r=2, return_info=True)
        Yr, _, it = ref_trnn(X, m, r=2)
    assert info.converged and info.n_iter == it
    assert _rel(Y, Yr) < 5e-3                     # rounding, amplified (module docstring)
    err, err_ref = (np.sqrt(np.mean((A - X)[~m] ** 2)) for A in (Y, Yr))
    assert err == pytest.approx(err_ref, rel=0.01)
