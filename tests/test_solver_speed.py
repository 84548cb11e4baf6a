"""Issue 21: the chunked, in-place solvers give the results of plain per-segment references.

* batched IALM (rpca / slra) vs a per-matrix IALM written from Lin et al.'s Algorithm 5
  with a full LAPACK SVD, on random low-rank + sparse stacks with a known answer;
* slra with overlapping segments vs an explicit loop over segments + cross-fade blending;
* results independent of the chunk size (CHUNK_ELEMENTS) and of whether the RTS
  backward pass recomputes the covariances block by block;
* the in-place helpers of trnn / tsmc (DCT solve along either axis, Gram-form factor steps,
  polar factor) vs the direct formulas; svt's in-place iteration vs the textbook iteration.
"""
from __future__ import annotations

import numpy as np
import pytest

from mocapkit import signal
from mocapkit.signal import rts
from mocapkit.signal.rts import _dense_posterior
from mocapkit.solvers import completion as cp
from mocapkit.solvers import lowrank as lr


def low_rank_sparse(p=6, m=60, n=20, r=2, frac=0.05, seed=0):
    rng = np.random.default_rng(seed)
    L = rng.standard_normal((p, m, r)) @ rng.standard_normal((p, r, n))
    S = np.where(rng.random((p, m, n)) < frac, rng.uniform(-5, 5, (p, m, n)), 0.0)
    return L, S


def ref_ialm(D, lam, tol=1e-7, max_iter=500, rho=1.5):
    """Lin, Chen & Ma (2010) Alg. 5 on one matrix, full SVD each iteration."""
    norm2 = np.linalg.svd(D, compute_uv=False)[0]
    Y = D / max(norm2, np.abs(D).max() / lam)
    mu, E, nD = 1.25 / norm2, np.zeros_like(D), np.linalg.norm(D)
    bar = mu * 1e7
    for it in range(1, max_iter + 1):
        U, s, Vt = np.linalg.svd(D - E + Y / mu, full_matrices=False)
        A = (U * np.maximum(s - 1 / mu, 0)) @ Vt
        R = D - A + Y / mu
        E = np.sign(R) * np.maximum(np.abs(R) - lam / mu, 0)
        Z = D - A - E
        Y = Y + mu * Z
        mu = min(mu * rho, bar)
        if np.linalg.norm(Z) / nD < tol:
            break
    return A, E, it


@pytest.mark.parametrize("shape", [(100, 60), (16, 40)])     # tall (Gram n x n), wide (m x m)
def test_batched_ialm_equals_per_matrix_reference(shape):
    m, n = shape
    L, S = low_rank_sparse(p=3, m=m, n=n, r=2, frac=0.03, seed=1)
    L[2] *= 30.0                                   # very different scales in one batch
    S[2] *= 30.0
    D = L + S
    lam = 1 / np.sqrt(max(m, n))
    A, E, info = lr.rpca_ialm(D, lam, return_info=True)
    for i in range(len(D)):
        Ar, Er, it = ref_ialm(D[i], lam)
        assert info.n_iter[i] == it                 # each matrix stops at its own tol
        assert np.linalg.norm(A[i] - Ar) <= 1e-6 * np.linalg.norm(Ar)
        assert np.linalg.norm(E[i] - Er) <= 1e-6 * max(np.linalg.norm(Er), 1.0)
    if min(m, n) >= 60:                            # exact recovery regime: the known answer
        assert np.linalg.norm(A - L) / np.linalg.norm(L) < 1e-4


def test_chunk_size_does_not_change_results(monkeypatch):
    L, S = low_rank_sparse(p=9, m=30, n=20, seed=2)
    D = (L + S).reshape(-1, 20)
    A0, _, i0 = lr.slra(D, segment=30, return_info=True)
    monkeypatch.setattr(lr, "CHUNK_ELEMENTS", 30 * 20)          # one segment per chunk
    A1, _, i1 = lr.slra(D, segment=30, return_info=True)
    np.testing.assert_array_equal(i0.n_iter, i1.n_iter)
    np.testing.assert_allclose(A0, A1, rtol=0, atol=1e-12 * np.abs(A0).max())


def test_overlapping_slra_equals_loop_over_segments():
    rng = np.random.default_rng(3)
    T, n = 203, 12
    t = np.arange(T)[:, None] / 50.0
    X = np.sin(t * rng.uniform(0.5, 3, n) + rng.uniform(0, 6, n)) * 10
    X[rng.random(X.shape) < 0.03] += 20.0
    A, _, info = lr.slra(X, segment=24, overlap=12, tol=1e-7, return_info=True)
    starts, stops = info.extra["starts"], info.extra["stops"]
    acc, wsum = np.zeros_like(X), np.zeros(T)
    for a, b, w in zip(starts, stops, lr.blend_weights(starts, stops)):
        L = b - a
        Ai, _, _ = ref_ialm(X[a:b], 1 / np.sqrt(max(L, n)))
        acc[a:b] += w[:, None] * Ai
        wsum[a:b] += w
    ref = acc / wsum[:, None]
    assert np.linalg.norm(A - ref) <= 1e-6 * np.linalg.norm(ref)


def test_svt_iteration_equals_textbook_loop():
    rng = np.random.default_rng(4)
    X = rng.standard_normal((80, 3)) @ rng.standard_normal((3, 15))
    mask = rng.random(X.shape) > 0.3
    tau, delta, eps, iters = 30.0, 1.2 / 0.7, 0.5, 40
    A, info = lr.svt(X, mask, tau, delta, eps=eps, tol=0.0, max_iter=iters, return_info=True)
    P = lambda Z: np.where(mask, Z, 0.0)                             # noqa: E731
    spec = np.linalg.norm(P(X), 2)
    Y = np.ceil(tau / (delta * spec)) * delta * P(X)
    s = np.linalg.norm(Y)
    for _ in range(iters):
        U, sv, Vt = np.linalg.svd(Y, full_matrices=False)
        Ar = (U * np.maximum(sv - tau, 0)) @ Vt
        y, s = Y + delta * P(X - Ar), s - delta * eps
        ny = np.linalg.norm(y)
        if ny > s:
            c = 0.0 if ny <= -s else (ny + s) / (2 * ny)
            y, s = c * y, c * ny
        Y = P(y)
    assert info.n_iter == iters
    assert np.linalg.norm(A - Ar) <= 1e-8 * np.linalg.norm(Ar)


@pytest.mark.parametrize("method", ["dct", "banded"])
def test_inplace_smooth_solve(method):
    rng = np.random.default_rng(5)
    R = rng.standard_normal((50, 4))
    ref = cp.smooth_solve(R, 0.3, 7.0, method)
    np.testing.assert_allclose(cp._smooth_solve_inplace(R.copy(), 0.3, 7.0, method), ref,
                               rtol=1e-12, atol=1e-12)
    # the (C, T) layout of the tsmc / trnn loops: along the last axis
    np.testing.assert_allclose(cp._smooth_solve_inplace(np.ascontiguousarray(R.T), 0.3, 7.0, method,
                                                        axis=-1), ref.T, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("d", [8, 3])                    # full width (C x C product), thin
def test_factor_steps_equal_the_explicit_steps(monkeypatch, d):
    """Gram-form factor steps (A never formed, W overwritten block by block) = the thesis'
    explicit steps A = Z B (I + c B^T B)^-1, B = Z^T A (I + c A^T A)^-1 (eqs. 4.9-4.10 /
    4.24), and P, Q = the SVD polar factors of eq. 4.26."""
    monkeypatch.setattr(cp, "PRODUCT_BLOCK", 7)             # several blocks and a short last one
    rng = np.random.default_rng(11)
    T, C, r, c = 50, 8, 2, 0.7
    Z, B = rng.standard_normal((T, C)), rng.standard_normal((C, d))
    P = np.linalg.qr(rng.standard_normal((T, r)))[0].T
    Q = np.linalg.qr(rng.standard_normal((C, r)))[0].T
    A = Z @ B @ np.linalg.inv(np.eye(d) + c * B.T @ B)
    Bn = Z.T @ A @ np.linalg.inv(np.eye(d) + c * A.T @ A)

    def orth_max(N):                                        # Lemma 1: argmax tr(W N), W W^T = I
        U, _, Vt = np.linalg.svd(N, full_matrices=False)
        return Vt.T @ U.T

    Pn = orth_max(A @ (Q @ Bn).T)
    Qn = orth_max(Bn @ (Pn @ A).T)
    W = np.ascontiguousarray(Z.T)
    _, B1, P1, Q1 = cp._factor_coefficients(W @ W.T, W, B, c, P, Q)
    cp._apply_factors(cp._factor_coefficients(W @ W.T, W, B, c)[0], B1, W)
    np.testing.assert_allclose(B1, Bn, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(W, (A @ Bn.T).T, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(P1, Pn, atol=1e-10)
    np.testing.assert_allclose(Q1, Qn, atol=1e-10)


@pytest.mark.parametrize("solver", ["trnn", "tsmc"])
@pytest.mark.parametrize("mstep", ["dct", "banded"])
def test_fused_passes_in_blocks_of_channels_equal_one_block(monkeypatch, solver, mstep):
    """The fused element-wise passes (_step_matrix, _post_factor) in blocks of a few
    channels -- the route of clips over FUSE_WHOLE elements -- give the one-block result
    (same iterations; values to rounding), with a short last block."""
    rng = np.random.default_rng(13)
    t = np.linspace(0, 6, 256)[:, None]
    X = np.hstack([np.sin(t * (1 + 0.2 * k) + k) * (3 + k) for k in range(11)]) + rng.normal(0, 0.1, (256, 11))
    M = rng.random(X.shape) > 0.2
    f = getattr(cp, solver)
    one, i1 = f(np.where(M, X, np.nan), M, mstep=mstep, return_info=True)
    monkeypatch.setattr(cp, "FUSE_WHOLE", 0)
    monkeypatch.setattr(cp, "FUSE_BLOCK", 3 * 256)                 # 3 channels a block: 3, 3, 3, 2
    assert [s.stop - s.start for s in cp._channel_blocks(11, 256)] == [3, 3, 3, 2]
    many, i2 = f(np.where(M, X, np.nan), M, mstep=mstep, return_info=True)
    assert i1.n_iter == i2.n_iter
    np.testing.assert_allclose(many, one, rtol=1e-9, atol=1e-9 * np.abs(one).max())


def test_polar_gram_route_and_svd_fallback():
    rng = np.random.default_rng(12)
    for N in (rng.standard_normal((4, 60)),                 # well conditioned: Gram route
              np.outer([1.0, 1e-9, 0.5, 0.0], rng.standard_normal(60))):   # rank 1: SVD route
        U, s, Vt = np.linalg.svd(N, full_matrices=False)
        W = cp._polar(N)
        np.testing.assert_allclose(W @ W.T, np.eye(4), atol=1e-10)
        # the maximiser of tr(W N^T): its value is the nuclear norm
        assert np.trace(W @ N.T) == pytest.approx(s.sum(), rel=1e-10)
        if s[-1] > 1e-6 * s[0]:
            np.testing.assert_allclose(W, U @ Vt, atol=1e-10)


@pytest.mark.parametrize("gate", [None, 3.0])
def test_rts_recomputed_covariances_do_not_change_results(monkeypatch, gate):
    rng = np.random.default_rng(6)
    T, B = 257, 6
    Y = np.cumsum(rng.standard_normal((T, B)), axis=0) + 0.3 * rng.standard_normal((T, B))
    Y[rng.random((T, B)) < 0.1] = np.nan
    Y[100:104, 2] += 25.0
    F, Q = signal.cv_model(0.01, 50.0)
    kw = dict(F=F, Q=Q, R=0.09, gate=gate, gate_groups=np.arange(B) // 3)
    x0, u0 = signal.rts_smoother(Y, **kw)
    monkeypatch.setattr(rts, "_RTS_BLOCK", 10)          # recompute covariances per block
    monkeypatch.setattr(rts, "_RTS_STORE_BYTES", 0)
    x1, u1 = signal.rts_smoother(Y, **kw)
    np.testing.assert_array_equal(u0, u1)
    np.testing.assert_array_equal(x0, x1)
    if gate is None:                                # the smoother = the dense posterior mean
        y = np.nan_to_num(Y[:60, :1])
        dense = _dense_posterior(y, np.isfinite(Y[:60, :1]), F=F, Q=Q, R=0.09,
                                        H=np.eye(1, 2), x0=np.zeros(2), P0=1e8 * np.eye(2))
        xs = signal.rts_smoother(Y[:60, :1], F=F, Q=Q, R=0.09)[0]
        np.testing.assert_allclose(xs[:, 0, :], dense[0], rtol=1e-6, atol=1e-6)


def test_fast_segment_layout_and_auto_mstep():
    """tsmc / trnn segments get a fast FFT length (still covering the clip, neighbours
    sharing at least the overlap), and mstep="auto" solves the same system as the DCT at
    a fast length and at an awkward one (where it takes the banded route)."""
    from scipy.fft import next_fast_len

    for T in (20000, 100000, 54321):
        s, e = lr.segment_layout(T, 8192, 512, fast=True)
        L = e - s
        assert s[0] == 0 and e[-1] == T and (L == L[0]).all()
        assert next_fast_len(int(L[0]), real=True) == L[0]
        assert (e[:-1] - s[1:] >= 512).all()
    rng = np.random.default_rng(13)
    for n in (64, 613):                                     # fast; prime
        R = rng.standard_normal((n, 3))
        np.testing.assert_allclose(cp.smooth_solve(R, 0.05, 100.0, "auto"),
                                   cp.smooth_solve(R, 0.05, 100.0, "dct"), rtol=1e-7, atol=1e-9)
