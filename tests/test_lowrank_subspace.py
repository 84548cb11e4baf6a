"""The spectral first phase of the IALM (issue 21, item 1): lowrank._ialm_spectral_phase.

While E = 0 the inexact ALM (Lin et al. 2010, Alg. 5) runs in D's singular basis without an
``eigh`` per iteration.  These tests compare that route with the full-eigh route (the phase
switched off), with a dense reference (numpy SVD shrinkage) and check the guards that end the
phase (threshold passed, untracked pairs, last iteration, residual near tol).
"""
from __future__ import annotations

import numpy as np
import pytest

from mocapkit.solvers import lowrank as lr


def _rel(a, b) -> float:
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300))


@pytest.fixture
def phase_log(monkeypatch):
    """Records the iterations the spectral phase did per matrix (one array per chunk)."""
    log: dict[str, list] = {"its": [], "exits": []}
    phase, exit_step = lr._ialm_spectral_phase, lr._spectral_exit_step

    def spy_phase(*a, **k):
        its, crit = phase(*a, **k)
        log["its"].append(its.copy())
        return its, crit

    def spy_exit(D, Y, E, idx, *a, **k):
        log["exits"].append(len(idx))
        return exit_step(D, Y, E, idx, *a, **k)

    monkeypatch.setattr(lr, "_ialm_spectral_phase", spy_phase)
    monkeypatch.setattr(lr, "_spectral_exit_step", spy_exit)
    return log


def _full_route(monkeypatch):
    """Switch the phase off: every iteration through the eigh of the Gram matrix."""
    def none(D, *a, **k):
        return np.zeros(len(D), dtype=int), np.full(len(D), np.inf)

    monkeypatch.setattr(lr, "_ialm_spectral_phase", none)


def _both(monkeypatch, D, lam, mask=None, tol=1e-9, max_iter=500):
    A1, E1, it1, cv1 = lr._ialm_batch(D, mask, lam, tol, max_iter, 1.5, "auto")
    with monkeypatch.context() as mp:
        _full_route(mp)
        A2, E2, it2, cv2 = lr._ialm_batch(D, mask, lam, tol, max_iter, 1.5, "auto")
    return (A1, E1, it1, cv1), (A2, E2, it2, cv2)


def _lowrank_sparse(rng, p, m, n, r, spikes=0.05, noise=0.0):
    """(p, m, n): rank-r part with a decaying spectrum + sparse spikes (+ dense noise)."""
    U = rng.standard_normal((p, m, r))
    V = rng.standard_normal((p, r, n))
    s = 10.0 ** -np.arange(r) * 50.0                   # ranks enter the shrinkage one by one
    L = (U * s) @ V
    S = np.where(rng.random((p, m, n)) < spikes, rng.normal(0, 30, (p, m, n)), 0.0)
    return L + S + noise * rng.standard_normal((p, m, n))


@pytest.mark.parametrize("shape", [(6, 120, 30), (10, 12, 40)])   # m >= n and m < n
def test_phase_equals_full_route(monkeypatch, phase_log, shape):
    rng = np.random.default_rng(1)
    p, m, n = shape
    D = _lowrank_sparse(rng, p, m, n, 4, noise=0.01)
    D[2] = 0.0                                                    # an all-zero matrix
    lam = np.full(p, 0.5)                       # E becomes non-zero after 3-6 iterations
    (A1, E1, it1, cv1), (A2, E2, it2, cv2) = _both(monkeypatch, D, lam)
    its = np.concatenate(phase_log["its"])
    assert its.max() >= 2 and its.min() >= 1                      # the phase did run ...
    assert sum(phase_log["exits"]) > 0                            # ... and ended in its exit step
    assert _rel(A1, A2) < 1e-8 and _rel(E1, E2) < 1e-8
    np.testing.assert_array_equal(it1, it2)
    np.testing.assert_array_equal(cv1, cv2)
    assert not A1[2].any() and not E1[2].any() and it1[2] == 0 and cv1[2]


def test_rank_changes_in_phase_and_untracked_pairs(monkeypatch, phase_log):
    """No sparse part and lam = 1 (max |R_ij| <= ||R||_2 <= 1/mu: E stays 0): the phase
    runs while the rank climbs 1 -> 5, until the residual nears tol; with SPECTRAL_K = 2
    it must stop before a third pair passes the threshold."""
    rng = np.random.default_rng(2)
    D = _lowrank_sparse(rng, 4, 80, 20, 5, spikes=0.0)
    lam = np.full(4, 1.0)
    (A1, E1, it1, _), (A2, E2, it2, _) = _both(monkeypatch, D, lam)
    long_run = np.concatenate(phase_log["its"])
    assert long_run.min() >= 8
    assert _rel(A1, A2) < 1e-8 and np.linalg.norm(E1 - E2) < 1e-8 * np.linalg.norm(D)
    np.testing.assert_array_equal(it1, it2)
    _, s, _ = np.linalg.svd(A1)
    assert (s > 1e-6 * s[:, :1]).sum(axis=1).min() >= 4          # the rank did change
    phase_log["its"].clear()
    monkeypatch.setattr(lr, "SPECTRAL_K", 2)
    A3, E3, it3, _ = lr._ialm_batch(D, None, lam, 1e-9, 500, 1.5, "auto")
    short_run = np.concatenate(phase_log["its"])
    assert (short_run < long_run).all() and short_run.min() >= 1
    assert _rel(A3, A2) < 1e-8
    np.testing.assert_array_equal(it3, it2)


def test_one_phase_step_against_dense_svd():
    """One step of the phase = one IALM step with numpy's SVD shrinkage (Alg. 5)."""
    rng = np.random.default_rng(3)
    for m, n in ((50, 12), (9, 25)):
        D = _lowrank_sparse(rng, 3, m, n, 3, spikes=0.0, noise=0.001)
        lam = np.full(3, 1.0 / np.sqrt(max(m, n)))
        normF, Y, mu, bar, (w, V, c0) = lr._ialm_start(D, lam, basis=True)
        Y0, mu0 = Y.copy(), mu.copy()
        E = np.zeros_like(D)
        its, crit = lr._ialm_spectral_phase(D, Y, E, w, V, c0, normF, lam, mu, bar, 1.5,
                                            1e-9, 2)               # max_iter 2: one step
        assert (its == 1).all()
        for i in range(3):
            M = D[i] + Y0[i] / mu0[i]
            U, s, Vt = np.linalg.svd(M, full_matrices=False)
            A = (U * np.clip(s - 1 / mu0[i], 0, None)) @ Vt
            R = M - A
            En = np.sign(R) * np.clip(np.abs(R) - lam[i] / mu0[i], 0, None)
            np.testing.assert_allclose(E[i], En, atol=1e-12 * np.abs(D[i]).max())
            Yr = Y0[i] + mu0[i] * (D[i] - A - En)
            assert _rel(Y[i], Yr) < 1e-10
            assert crit[i] == pytest.approx(np.linalg.norm(D[i] - A - En) / normF[i], rel=1e-8)
            assert mu[i] == pytest.approx(mu0[i] * 1.5)


def test_full_run_against_dense_reference():
    """The whole IALM with the phase against a plain numpy transcription of Alg. 5."""
    rng = np.random.default_rng(4)
    D = _lowrank_sparse(rng, 1, 60, 15, 3, noise=0.01)[0]
    lam = 1 / np.sqrt(60)
    A, E, info = lr.rpca_ialm(D, lam, tol=1e-9, return_info=True)
    # reference (Lin et al. Alg. 5 with the start of _ialm_start)
    n2 = np.linalg.norm(D, 2)
    Y = D / max(n2, np.abs(D).max() / lam)
    mu, bar = 1.25 / n2, 1.25 / n2 * 1e7
    Er = np.zeros_like(D)
    for _ in range(500):
        U, s, Vt = np.linalg.svd(D - Er + Y / mu, full_matrices=False)
        Ar = (U * np.clip(s - 1 / mu, 0, None)) @ Vt
        R = D - Ar + Y / mu
        Er = np.sign(R) * np.clip(np.abs(R) - lam / mu, 0, None)
        Z = D - Ar - Er
        Y = Y + mu * Z
        mu = min(mu * 1.5, bar)
        if np.linalg.norm(Z) / np.linalg.norm(D) < 1e-9:
            break
    assert _rel(A, Ar) < 1e-8 and _rel(E, Er) < 1e-7


def test_exit_step_keeps_a_converging_matrix():
    """_spectral_exit_step leaves a matrix untouched when its residual would meet tol
    (the full route then redoes that step and stops)."""
    rng = np.random.default_rng(5)
    D = _lowrank_sparse(rng, 2, 40, 10, 2, spikes=0.1)
    lam = np.full(2, 1 / np.sqrt(40))
    normF, Y, mu, bar, (w, V, c0) = lr._ialm_start(D, lam, basis=True)
    E, its, crit = np.zeros_like(D), np.zeros(2, dtype=int), np.full(2, np.inf)
    Y0, mu0 = Y.copy(), mu.copy()
    R = D + Y / mu[:, None, None]
    thr = (lam / mu)[:, None, None]
    args = (R, thr, np.zeros((2, 10)), np.zeros((2, 40, 10)), np.zeros((2, 10, 10)),
            c0.copy(), np.zeros((2, 10)), mu, bar, 1.5, normF)
    lr._spectral_exit_step(D, Y, E, np.arange(2), *args[:10], normF, np.inf, its, crit)
    assert (its == 0).all() and not E.any() and np.array_equal(Y, Y0) and np.array_equal(mu, mu0)
    lr._spectral_exit_step(D, Y, E, np.arange(2), *args[:10], normF, 0.0, its, crit)
    assert (its == 1).all() and E.any() and (mu == np.minimum(mu0 * 1.5, bar)).all()


def test_mask_and_lapack_route_skip_the_phase(monkeypatch, phase_log):
    rng = np.random.default_rng(6)
    D = _lowrank_sparse(rng, 3, 60, 20, 3, noise=0.01)
    mask = rng.random(D.shape) > 0.2
    Dm = np.where(mask, D, 0.0)
    lam = np.full(3, 1 / np.sqrt(60))
    (A1, E1, it1, _), (A2, E2, it2, _) = _both(monkeypatch, Dm, lam, mask=mask)
    assert phase_log["its"] == []                                 # masked: full route only
    np.testing.assert_array_equal(A1, A2)
    np.testing.assert_array_equal(it1, it2)
    lr._ialm_batch(D[:, :30], None, lam, 1e-9, 500, 1.5, "auto")  # 30 x 20: LAPACK SVD route
    assert phase_log["its"] == []


def test_per_entry_weights_and_short_runs(monkeypatch, phase_log):
    rng = np.random.default_rng(7)
    D = _lowrank_sparse(rng, 3, 70, 20, 3, noise=0.01)
    W = np.full(D.shape, 0.4)
    W[:, :10] *= 3.0
    (A1, E1, it1, _), (A2, E2, it2, _) = _both(monkeypatch, D, W)
    assert np.concatenate(phase_log["its"]).min() >= 1
    assert _rel(A1, A2) < 1e-8 and _rel(E1, E2) < 1e-8
    np.testing.assert_array_equal(it1, it2)
    for k in (1, 2, 3, 5):                                        # max_iter caps: same result
        phase_log["its"].clear()
        (A1, E1, it1, cv1), (A2, E2, it2, cv2) = _both(monkeypatch, D, W[:, 0, 0], max_iter=k)
        assert (it1 == k).all() and (it2 == k).all() and not cv1.any()
        assert all((i < k).all() for i in phase_log["its"])      # the last step: full route
        assert _rel(A1, A2) < 1e-10 and _rel(E1, E2) < 1e-8


def test_slra_on_mocap_equals_full_route(monkeypatch, phase_log):
    from mocapkit import io
    from mocapkit.datasets import bundled

    X = io.read(bundled("16_15.amc")).matrix()[:480]
    X = X + np.random.default_rng(8).normal(0, 0.5, X.shape)
    for seg, ov, tol in ((200, 0, 1e-7), (24, 12, 1e-5)):
        phase_log["its"].clear()
        A1, E1, i1 = lr.slra(X, seg, ov, tol=tol, return_info=True)
        with monkeypatch.context() as mp:
            _full_route(mp)
            A2, E2, i2 = lr.slra(X, seg, ov, tol=tol, return_info=True)
        assert np.concatenate(phase_log["its"]).mean() >= 3
        assert _rel(A1, A2) < 1e-9
        assert np.linalg.norm(E1 - E2) < 1e-9 * np.linalg.norm(X)
        np.testing.assert_array_equal(i1.n_iter, i2.n_iter)
