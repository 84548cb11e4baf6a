"""Motion-matrix completion solvers of the thesis (seed 003, Ch. 4) and DynaMMo.

Plain functions on arrays.  Layout: ``X`` is the (T, C) frame-by-coordinate matrix
(T frames, C = 3J coordinates, cm in mocapkit; the thesis writes its transpose, d x n or
m x n), ``mask`` a bool array of the same shape (True = observed).  Unobserved entries
may hold anything (NaN included); they are ignored and filled by the model.  Time runs
down the rows, so the thesis' right-multiplication by the second-difference matrix O
(``Y O``, ``L R^T O``) becomes the left-multiplication ``O X`` here.

Solvers
-------
* :func:`tsmc` -- bilinear factorisation with sparse error and second-difference
  smoothness (thesis Sec. 4.1, eqs. 4.6-4.14, Algorithm 2), solved by ALM with the slack
  variable M = U V^T.  The model is the TSMC model of Feng et al. (2014b), solved with the
  thesis' bilinear factorisation (``rank`` columns) instead of Feng's partial SVD.
* :func:`trnn` -- truncated nuclear norm (sum of all but the r largest singular values)
  with sparse error and smoothness (thesis Sec. 4.2, eqs. 4.21-4.26, Algorithm 3),
  single-loop ALM whose M-step is diagonalised by the DCT-II (:func:`smooth_solve`).
* :func:`estimate_rank` -- the last-significant-jump rule (Sec. 4.1.2 / 4.2.3).
* :func:`lds_em_complete` -- DynaMMo (Li, McCann, Pollard & Faloutsos, KDD 2009): a linear
  dynamical system fitted by EM with the missing values re-estimated from the smoothed
  latent states at every iteration (the strongest classical gap-filling baseline the
  thesis compares with, Fig. 3.7 / 4.11).

Misprints of the thesis fixed here (see ../shared/specs/METHODS.md Sec. 4)
---------------------------------------------------------------------------
* eq. 4.10: ``V = Z_v^T U (I + (l1 + l2) U^T U)^-1`` -- Z_v needs a transpose;
* eq. 4.11 / 4.12: the E-step is *element-wise* soft thresholding (eq. 4.12 defines the
  singular value one);
* eq. 4.14: each multiplier goes with its own constraint: Y1 with ``M - U V^T``, Y2 with
  ``X - U V^T - E`` (the thesis swaps them);
* eq. 4.2: O is symmetric, its last row is ``[..., 1, -1]`` (as in eq. 4.22), so that
  ``O = -L`` with L the Neumann (reflecting-end) path Laplacian, whose eigenvectors are the
  DCT-II basis and eigenvalues ``-xi_i = 2 - 2 cos((i-1) pi / n)``;
* Sec. 4.2.2: ``Gamma_ii = 1 / (eta + mu xi_i^2)`` (the thesis prints ``Y_1^k`` for eta).

Speed: tsmc and trnn iterate on the transposed (C, T) matrix (C coordinates, T frames),
so that the DCT of the M-step runs along contiguous rows.  The two factor steps are taken
in Gram form (:func:`_factor_coefficients`, :func:`_apply_factors`): only the (C, C) Gram
matrix of the step's (T, C) matrix and one (C, C) x (C, T) product touch the frames, the left factor (T x k) is never
stored, and the product overwrites its input block by block.  The element-wise steps
around them are fused into two passes over blocks of channels (:func:`_step_matrix`,
:func:`_post_factor`), so that a block's arrays stay in cache.  Per trnn iteration at
10,000 frames x 93 coordinates (one core, measured 2026-12-03 at a loaded moment of this
shared machine, 44 ms in all; interleaved with the unfused loops: tsmc +16 %, trnn +-0 at
10,000 frames, both +-5 % on a 3,678-frame C3D, +9 / +16 % while another job loaded the
memory bus): the step matrix 7.9 ms, its Gram matrix 2.9, the factor
coefficients with the polar factors 5.0, the product 4.3, the fused sparse step, M-step
with its two DCTs and multiplier update 24.1 -- O(T C^2 + T C log T), linear in the
number of frames.  No step loops over frames in Python except the Kalman/RTS recursions
of DynaMMo, which are sequential by nature and handle only k x k matrices (the
data-dependent parts are batched).
"""
from __future__ import annotations

import functools
from typing import Any

import numpy as np
from scipy import fft as _fft

from .. import gaps
from ..errors import MocapValueError
from ..windows import frame_blocks
from . import _linalg
from .info import SolveInfo, warn_not_converged

__all__ = ["second_difference_matrix", "smooth_solve", "estimate_rank", "soft_threshold",
           "tsmc", "trnn", "lds_em_complete"]


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------
def second_difference_matrix(n: int) -> np.ndarray:
    """The symmetric (n, n) matrix O of thesis eqs. 4.2 / 4.22 (last row fixed to [1, -1]).

    Rows: ``[-1, 1, 0...]``, ``[.., 1, -2, 1, ..]``, ``[..., 0, 1, -1]``.  ``O x`` is the
    second difference of x with reflecting ends; O = -L with L the Neumann path Laplacian.
    For n = 1 it is [[0]].
    """
    n = int(n)
    if n < 1:
        raise MocapValueError(f"n must be >= 1, got {n}")
    O = np.zeros((n, n))
    if n == 1:
        return O
    i = np.arange(n)
    O[i, i] = -2.0
    O[i[:-1], i[:-1] + 1] = 1.0
    O[i[1:], i[1:] - 1] = 1.0
    O[0, 0] = O[-1, -1] = -1.0
    return O


def dct_eigenvalues(n: int) -> np.ndarray:
    """Eigenvalues xi_i = -2 + 2 cos((i-1) pi / n), i = 1..n, of O (DCT-II order)."""
    return -2.0 + 2.0 * np.cos(np.arange(n) * np.pi / n)


def smooth_solve(rhs: np.ndarray, eta: float, mu: float, method: str = "dct") -> np.ndarray:
    """Solve ``(eta I + mu O^T O) M = rhs`` along axis 0 (thesis eq. 4.25).

    ``method="dct"`` (the thesis): O (:func:`second_difference_matrix`) is diagonalised by
    the orthonormal DCT-II, ``O = C^T diag(xi) C``, so ``M = IDCT(Gamma DCT(rhs))`` with
    ``Gamma_ii = 1 / (eta + mu xi_i^2)``; O(T log T) per column, exact to rounding (the
    transform is orthogonal).  pocketfft is fast only for lengths whose factors are small:
    measured on 93 columns, one DCT of 8,192 or 10,000 frames takes 3.3 ms, of 8,165
    (5 x 23 x 71) 8.2 ms, of 3,678 (2 x 3 x 613) 8.7 ms.
    ``method="banded"``: the same system is pentadiagonal (``O^T O = L^2``, L the Neumann
    Laplacian) and is solved by a banded Cholesky factorisation, O(T) per column, at any
    length: 6.3 ms for the whole solve of 3,678 frames, 15.5 ms for 10,000 (the DCT route:
    22 and 7.7 ms).  It loses up to ~1e-8 relative where the system is ill-conditioned
    (condition number (eta + 16 mu) / eta, 1.6e8 at the thesis' first eta).
    ``method="auto"``: the DCT where T is a fast FFT length
    (:func:`scipy.fft.next_fast_len`), else the banded solve.

    Parameters
    ----------
    rhs : (T,) or (T, C) array; every column is solved independently.
    eta : > 0 (the ALM penalty); mu : >= 0 (smoothness weight).
    method : "dct", "banded" or "auto".
    """
    # one implementation; a copy keeps the caller's array intact
    return _smooth_solve_inplace(np.array(rhs, dtype=np.float64, copy=True), eta, mu, method)


@functools.lru_cache(maxsize=4)
def _dct_gain(n: int, eta: float, mu: float) -> np.ndarray:
    """``Gamma_ii = 1 / (eta + mu xi_i^2)`` of the DCT M-step (read-only, cached: the loops
    solve one block of channels at a time with the same eta)."""
    g = 1.0 / (eta + mu * dct_eigenvalues(n) ** 2)
    g.setflags(write=False)
    return g


def soft_threshold(A: np.ndarray, tau: float) -> np.ndarray:
    """Element-wise soft thresholding sign(a) max(|a| - tau, 0) (the prox of tau ||.||_1)."""
    return A - np.clip(A, -tau, tau)


def _shrink_observed(Z: np.ndarray, tau: float, miss: np.ndarray) -> np.ndarray:
    """Soft thresholding on observed entries, identity on missing ones (eqs. 4.11, 4.24)."""
    out = soft_threshold(Z, tau)
    np.copyto(out, Z, where=miss)
    return out


def _singular_values(X: np.ndarray) -> np.ndarray:
    """Singular values (descending) of a (T, C) matrix via its small Gram matrix."""
    T, C = X.shape
    G = X.T @ X if T >= C else X @ X.T
    w = _linalg.eigvalsh(G, what="singular values")[::-1]
    return np.sqrt(np.clip(w, 0.0, None))


def estimate_rank(X: Any, mask: Any = None, threshold: float = 0.1) -> int:
    """Rank by the last significant jump of the normalised singular values.

    Thesis Sec. 4.1.2 / 4.2.3 (Wang & Yin 2010): missing entries are first filled by linear
    interpolation in time; with ``s_i = sigma_i / sigma_1`` (normalised to [0, 1],
    descending) the rank is the largest i (1-based) with ``s_i - s_{i+1} >= threshold``
    (0.1 in the thesis); at least 1.

    Parameters
    ----------
    X : (T, C) matrix; mask : optional bool (T, C), True = observed.
    threshold : jump threshold on the normalised singular values.
    """
    X, m = _linalg.prepare(X, mask)
    if not m.all():
        X = gaps.fill(np.where(m, X, np.nan), m, never_observed=0.0)
    s = _singular_values(X)
    if s[0] <= 0:
        return 1
    s = s / s[0]
    jumps = s[:-1] - s[1:]
    big = np.flatnonzero(jumps >= threshold)
    return int(big[-1] + 1) if big.size else 1


def _rel(a: float, b: float) -> float:
    return a / b if b > 0 else a


ALM_CRITERION = "max relative residual / change"
"""What the ALM solvers' ``residual`` is (:func:`tsmc`, :func:`trnn`, stopping rule of
Sec. 4.2.3): the largest of the two relative constraint residuals and the relative change
of the low-rank product."""
EM_CRITERION = "relative change of the filled values"
"""What :func:`lds_em_complete`'s ``residual`` is: ``||new - old|| / ||old||`` over the
missing entries (centred)."""


# --------------------------------------------------------------------------------------
# bilinear factorisation + sparse error + smoothness (thesis Sec. 4.1)
# --------------------------------------------------------------------------------------
@_linalg.one_blas_thread
def tsmc(X: Any, mask: Any = None, *, rank: int | str | None = None, alpha: float = 1.0,
         beta: float = 100.0, lam1: float = 1e-5, lam2: float = 1e-5, gamma: float = 1.4,
         lam_max: float = 1e10, tol: float = 1e-4, max_iter: int = 500,
         rank_threshold: float = 0.1, seed: int = 0, mstep: str = "auto",
         return_info: bool = False):
    """Low-rank + sparse + smooth completion by bilinear factorisation (thesis Sec. 4.1).

    Solves (thesis eq. 4.7, our (T, C) layout)::

        min_{U,V,E,M}  1/2 (||U||_F^2 + ||V||_F^2) + alpha ||Omega o E||_1 + beta/2 ||O M||_F^2
        s.t.  X = U V^T + E,   M = U V^T

    with U (T, k), V (C, k), by ALM (eqs. 4.8-4.14, Algorithm 2; misprints fixed as in the
    module docstring)::

        Z   = Y1 + Y2 + l1 M + l2 (X - E)
        U   = Z V (I + (l1 + l2) V^T V)^-1                          (4.9)
        V   = Z^T U (I + (l1 + l2) U^T U)^-1                        (4.10)
        E   = Omega o S_{alpha/l2}(Ze) + (1 - Omega) o Ze,  Ze = X - U V^T + Y2 / l2   (4.11)
        M   = (l1 I + beta O^T O)^-1 (l1 U V^T - Y1)    [DCT, eq. 4.25]  (4.13)
        Y1 += l1 (M - U V^T);  Y2 += l2 (X - U V^T - E)              (4.14)
        l1, l2 <- min(gamma l, lam_max)

    ``1/2 (||U||^2 + ||V||^2)`` equals the nuclear norm of U V^T at the optimum (eq. 4.4).
    Stopping (the thesis' criterion of Sec. 4.2.3): ``max(||X - UV^T - E|| / ||X||,
    ||M - UV^T|| / ||X||, ||UV^T - previous|| / ||UV^T||) < tol`` (Frobenius norms,
    observed part of X).

    Parameters
    ----------
    X : (T, C) data (cm); mask : bool (T, C), True = observed (None: X complete).
    rank : k, columns of U and V.  ``"lsj"``: the thesis' ``min(ceil(1.1 r), C, T)`` with
        r from :func:`estimate_rank` (eq. 4.15).  None (default): ``min(C, T)``, the full
        width -- our decision: on raw (uncentred) mocap matrices the last-jump rank is 2-3
        (the mean pose dominates sigma_1), and a rank-3 factorisation misses the motion by
        15+ cm, while the full width lets the nuclear norm choose the rank; measured on CMU
        05_06 / 02_01 (docs/results/thesis.md).
    alpha, beta, lam1, lam2, gamma, lam_max : thesis settings (Sec. 4.1.3): 1, 100, 1e-5,
        1e-5, 1.4, 1e10.  beta multiplies a squared second difference, so it depends on the
        unit (cm here, as the thesis' RMSE).
    tol, max_iter : stopping tolerance and iteration cap.
    seed : for the random initial V (Algorithm 2, step 1).
    mstep : "dct" (thesis eq. 4.25), "banded" or "auto" (the faster of the two for the
        clip's length) for the M-update (:func:`smooth_solve`).
    The multipliers start at ``X / max(||X||_2, ||X||_inf / alpha)`` (Lin et al. 2010's
    J(X); Algorithm 2 prints a squared Frobenius norm there).

    Returns
    -------
    Y : (T, C) low-rank estimate U V^T (the thesis' output); with ``return_info`` also a
    :class:`~mocapkit.solvers.info.SolveInfo` (residual: the stopping criterion above,
    :data:`ALM_CRITERION`; extra ``rank`` k and ``E`` (T, C) sparse error).  Stopping at
    ``max_iter`` above ``tol`` warns (:func:`~mocapkit.solvers.info.warn_not_converged`).
    """
    X, m = _linalg.prepare(X, mask)
    T, C = X.shape
    k = _tsmc_rank(X, m, rank, rank_threshold)
    if alpha < 0 or beta < 0:
        raise MocapValueError(f"alpha and beta must be >= 0, got {alpha}, {beta}")
    if lam1 <= 0 or lam2 <= 0 or gamma < 1:
        raise MocapValueError("lam1, lam2 must be > 0 and gamma >= 1")
    rng = np.random.default_rng(seed)
    V = rng.random((C, k))
    V /= np.linalg.norm(V)
    nx = np.linalg.norm(X)
    if nx == 0:
        Y = np.zeros((T, C))
        info = SolveInfo(0, True, 0.0, ALM_CRITERION, {"rank": k, "E": np.zeros((T, C))})
        return (Y, info) if return_info else Y
    Xt, obs = _transposed(X, m)
    del X
    UVt, V, Et, it, converged, crit = _tsmc_loop(
        Xt, obs, V, _alm_multipliers(Xt, alpha), (float(alpha), float(beta)),
        (float(lam1), float(lam2), float(gamma), float(lam_max)), float(tol), int(max_iter), mstep)
    del Xt
    info = SolveInfo(it, converged, float(crit), ALM_CRITERION, {"rank": k, "E": Et.T})
    if not converged:
        warn_not_converged("tsmc", info, tol, max_iter, stacklevel=2)
    Y = np.ascontiguousarray(UVt.T)
    return (Y, info) if return_info else Y


def _transposed(X: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(X^T, mask^T), C-contiguous: the (C, T) layout the tsmc / trnn loops work in, so
    that the DCT of their M-step runs along contiguous rows (:func:`_smooth_solve_inplace`)."""
    return np.ascontiguousarray(X.T), np.ascontiguousarray(m.T)


def _alm_multipliers(D: np.ndarray, weight: float) -> tuple[np.ndarray, np.ndarray]:
    """Start of both ALM multipliers of :func:`tsmc` / :func:`trnn`: Lin et al. (2010)'s
    ``J(D) = D / max(||D||_2, ||D||_inf / weight)`` (weight: the l1 weight)."""
    spec = _singular_values(D)[0]
    Y1 = D / max(spec, np.abs(D).max() / max(weight, 1e-12))
    return Y1, Y1.copy()


def _tsmc_rank(X: np.ndarray, m: np.ndarray, rank, rank_threshold: float) -> int:
    """Factor width k of :func:`tsmc` from its ``rank`` argument."""
    T, C = X.shape
    if isinstance(rank, str):
        if rank != "lsj":
            raise MocapValueError(f"rank must be an int, None or 'lsj', got {rank!r}")
        r = estimate_rank(X, m, rank_threshold)
        return int(min(np.ceil(1.1 * r), C, T))
    if rank is None:
        return min(C, T)
    k = int(rank)
    if k < 1:
        raise MocapValueError(f"rank must be >= 1, got {rank}")
    return min(k, C, T)


def _tsmc_loop(Xt: np.ndarray, obs: np.ndarray, V: np.ndarray, mults: tuple, weights: tuple,
               lams: tuple, tol: float, max_iter: int, mstep: str):
    """Algorithm 2 iterations of :func:`tsmc`, in place, on the transposed (C, T) layout.

    Xt (the data), E, M, Y1, Y2 and two work arrays: W (Z, then U V^T in place,
    :func:`_factor_coefficients`, :func:`_apply_factors`) and Wp (the previous U V^T, then
    scratch); U is never formed.
    ``Y2 += l2 (X - UV - E)`` is folded into the E-step (``Y2_new = l2 clip(Ze,
    +-alpha/l2)`` on Omega, 0 off it; :func:`_sparse_step`).  Returns (U V^T)^T (C, T), V,
    E (C, T) and the iteration count, convergence flag and last criterion.
    """
    Y1, Y2 = mults
    alpha, beta = weights
    l1, l2, gamma, lam_max = lams
    nx = float(np.linalg.norm(Xt))
    E, M, W, Wp = np.zeros(Xt.shape), np.zeros(Xt.shape), np.empty(Xt.shape), np.zeros(Xt.shape)
    crit, it, converged = np.inf, 0, False
    for it in range(1, max_iter + 1):
        # Z = Y1 + Y2 + l1 M + l2 (X - E), one pass
        _step_matrix(W, Xt, E, M, Y1, Y2, l2, l1)
        F, V, _, _ = _factor_coefficients(W @ W.T, W, V, l1 + l2)                    # eqs. 4.9, 4.10
        _apply_factors(F, V, W)                            # W = (U V^T)^T
        # E-step (4.11), M-step (4.13), Y1 (4.14), in place, one pass
        duv, nuv, nr2, nr1 = _post_factor(W, Wp, Xt, E, M, Y1, Y2, obs, (l2, l1), alpha / l2, beta, mstep)
        W, Wp = Wp, W                                      # Wp = this U V^T
        crit = max(_rel(nr2, nx), _rel(nr1, nx), _rel(duv, nuv))
        l1 = min(gamma * l1, lam_max)
        l2 = min(gamma * l2, lam_max)
        if crit < tol:
            converged = True
            break
    return Wp, V, E, it, converged, crit


# --------------------------------------------------------------------------------------
# truncated nuclear norm (thesis Sec. 4.2)
# --------------------------------------------------------------------------------------
def _sparse_step(D: np.ndarray, W: np.ndarray, Y: np.ndarray, M: np.ndarray, S: np.ndarray,
                 pen: float, thr: float, obs: np.ndarray) -> float:
    """The sparse-error step shared by the tsmc (eq. 4.11, 4.14) and trnn (4.24) ALMs, in
    place: S = Z - shrink_Omega(Z, thr) with Z = D - W + Y / pen (soft threshold on the
    observed entries, identity on missing ones), then Y <- pen (D - W - S) and
    ``||D - W - S||_F^2`` is returned. M is scratch of D's shape; on return M = D - W - S.
    (Y is used as scratch for the clipped Z, and Y_old + pen R equals pen clip(Z).)
    ``obs`` is the bool observed mask; multiplying by it is 3x faster than a masked copy."""
    np.multiply(Y, 1.0 / pen, out=M)                   # M = Y / pen
    np.subtract(D, W, out=S)
    S += M                                             # S = Z
    np.clip(S, -thr, thr, out=Y)
    np.multiply(Y, obs, out=Y)                         # 0 off Omega (the clip is finite)
    S -= Y                                             # soft threshold on Omega
    np.subtract(Y, M, out=M)                           # R = D - W - S
    nr2 = _sq(M)
    Y *= pen                                           # = Y_old + pen R, since Y holds the clip
    return nr2


def _smooth_solve_inplace(rhs: np.ndarray, eta: float, mu: float, method: str,
                          axis: int = 0) -> np.ndarray:
    """:func:`smooth_solve` along ``axis`` (0 or -1 of a 2-d ``rhs``) that may overwrite
    ``rhs`` (no extra array of its size kept).  The solvers call it with axis=-1 on their
    (C, T) arrays: a DCT along contiguous rows is faster than down the columns, and
    pocketfft must be called along that axis itself -- on the transposed view it runs 2x
    slower (measured, 93 x 10,000: 6.3 vs 13.6 ms at a loaded moment)."""
    ax = axis % rhs.ndim
    if ax not in (0, rhs.ndim - 1):
        raise MocapValueError(f"axis must be the first or the last, got {axis}")
    n = rhs.shape[ax]
    if method == "auto":
        method = "dct" if _fft.next_fast_len(n, real=True) == n else "banded"
    if method == "banded" and n > 3:
        from scipy.linalg import solveh_banded

        d0 = np.full(n, 6.0)
        d0[[0, -1]] = 2.0
        d1 = np.full(n - 1, -4.0)
        d1[[0, -1]] = -3.0
        ab = np.zeros((3, n))
        ab[2] = eta + mu * d0
        ab[1, 1:] = mu * d1
        ab[0, 2:] = mu
        if ax != 0:                                      # LAPACK solves down the columns
            return solveh_banded(ab, rhs.T, overwrite_b=True, check_finite=False).T
        return solveh_banded(ab, rhs, overwrite_b=True, check_finite=False)
    if method not in ("dct", "banded"):
        raise MocapValueError(f"method must be 'dct', 'banded' or 'auto', got {method!r}")
    gamma = _dct_gain(n, float(eta), float(mu))
    y = _fft.dct(rhs, type=2, axis=ax, norm="ortho", overwrite_x=True)
    y *= gamma if ax == rhs.ndim - 1 else gamma.reshape((n,) + (1,) * (rhs.ndim - 1))
    return _fft.idct(y, type=2, axis=ax, norm="ortho", overwrite_x=True)


#: frames per block of the in-place product of the factor steps (:func:`_apply_factors`;
#: a 93 x 2,048 block is 1.5 MB: in cache)
PRODUCT_BLOCK = 2048

#: elements per block of channels (rows of the (C, T) arrays) of the fused element-wise
#: passes of the tsmc / trnn loops (:func:`_step_matrix`, :func:`_post_factor`): rows
#: are contiguous (a block of frames, i.e. columns, is strided, and numpy's element-wise
#: loops run 4x slower on it, measured), and a block of 2^16 elements (0.5 MB an
#: array) keeps the ~9 arrays of one pass in cache instead of streaming each (C, T)
#: array from memory once per operation (trnn at 10,000 x 93, ms per iteration: 2^13
#: 52.5, 2^15 44.6, 2^16 41.0, 2^17 44.6, unblocked 47.9; measured interleaved)
FUSE_BLOCK = 1 << 16

#: matrices up to this many elements (4 MB an array) are one block: their arrays fit in
#: the last-level cache together, and blocks would only add calls (the 3,678 x 78 C3D
#: of docs/results/scaling.md ran 5 % slower in 5 blocks)
FUSE_WHOLE = 1 << 19


def _channel_blocks(C: int, T: int) -> list[slice]:
    """Blocks of whole rows of a (C, T) array, :data:`FUSE_BLOCK` elements or one row
    (one block up to :data:`FUSE_WHOLE` elements)."""
    if C * T <= FUSE_WHOLE:
        return [slice(0, C)]
    return frame_blocks(C, max(1, FUSE_BLOCK // max(T, 1)))


def _factor_coefficients(G: np.ndarray, W: np.ndarray, B: np.ndarray, c: float,
                         P: np.ndarray | None = None, Q: np.ndarray | None = None):
    """The small matrices of the two factor steps of the tsmc / trnn ALMs in Gram form.

    With Z = W^T the (T, C) matrix of the step (tsmc's Z, eqs. 4.9-4.10; trnn's T1, eq.
    4.24), G = Z^T Z = W W^T its (C, C) Gram matrix and the current right factor B (C, d)::

        A = Z B (I + c B^T B)^-1 = Z F,     B_new = Z^T A (I + c A^T A)^-1

    Only G touches the T frames: A^T A = F^T G F, B_new = G F (I + c A^T A)^-1, and the new
    product is (A B_new^T)^T = B_new F^T W (:func:`_apply_factors`).  The products are those
    of the explicit steps (same values to rounding; tests/test_completion_reference.py),
    for 1.5 instead of 4 (T x C x C) products per iteration at the full width d = C, and A
    (T, d) is never stored.  With P (r, T), Q (r, C) (trnn, eq. 4.26; r > 0) they are
    updated from A and B_new too: ``P = argmax tr(P A B^T Q^T)``, then
    ``Q = argmax tr(Q B A^T P^T)`` (thesis Appendix Lemma 1; :func:`_polar`).

    Returns (F, B_new, P, Q).
    """
    d = B.shape[1]
    Id = np.eye(d)
    F = B @ np.linalg.inv(Id + c * (B.T @ B))
    GF = G @ F
    Bn = GF @ np.linalg.inv(Id + c * (F.T @ GF))
    if P is not None and P.shape[0] > 0:
        P = _polar((Q @ Bn) @ F.T @ W)                     # N^T = Q B_new A^T, (r, T)
        Q = _polar(((P @ W.T) @ F) @ Bn.T)                 # N^T = P A B_new^T, (r, C)
    return F, Bn, P, Q


def _apply_factors(F: np.ndarray, Bn: np.ndarray, W: np.ndarray) -> None:
    """``W <- B_new F^T W`` in place, block of frames by block (:data:`PRODUCT_BLOCK`; no
    (C, T) copy): the new product (A B_new^T)^T of :func:`_factor_coefficients`.  The thin
    order, (d, n) first, where 2 d < C takes fewer flops."""
    thin = 2 * Bn.shape[1] < Bn.shape[0]
    Z = None if thin else Bn @ F.T
    for s in frame_blocks(W.shape[1], PRODUCT_BLOCK):
        W[:, s] = Bn @ (F.T @ W[:, s]) if thin else Z @ W[:, s]


def _sq(a: np.ndarray) -> float:
    """Squared Frobenius norm of a C-contiguous array (BLAS dot on its flat view)."""
    v = a.reshape(-1)
    return float(v @ v)


def _step_matrix(W: np.ndarray, D: np.ndarray, S: np.ndarray, M: np.ndarray, Y1: np.ndarray,
                 Y2: np.ndarray, a: float, b: float, PQ: tuple | None = None) -> None:
    """The factor steps' matrix ``W = a (D - S) + b M + Y1 + Y2 [+ Q^T P]`` (tsmc's Z: a =
    l2, b = l1; trnn's T1: a = b = eta, PQ = (Q^T, P)) written into W in one pass, block of
    channels by block (:func:`_channel_blocks`).  M may be scaled in place where a != b
    (it is scratch until the M-step)."""
    for s in _channel_blocks(*W.shape):
        w = W[s]
        if a == b:
            np.add(M[s], D[s], out=w)
            w -= S[s]
            w *= a
        else:
            np.subtract(D[s], S[s], out=w)
            w *= a
            m = M[s]
            m *= b
            w += m
        w += Y1[s]
        w += Y2[s]
        if PQ is not None:
            _add_product(w, PQ[0][s], PQ[1])               # (P^T Q)^T = Q^T P, rows s


def _post_factor(W: np.ndarray, Wp: np.ndarray, D: np.ndarray, S: np.ndarray, M: np.ndarray,
                 Y1: np.ndarray, Y2: np.ndarray, obs: np.ndarray, pens: tuple, thr: float,
                 mu: float, mstep: str) -> tuple[float, float, float, float]:
    """Everything of one tsmc / trnn iteration after the new product W, in place, in one
    pass over blocks of channels (:func:`_channel_blocks`; the M-step's DCT runs along
    them): the change of W from the previous product Wp, the sparse step
    (:func:`_sparse_step`, penalty ``pens[0]``, threshold ``thr``), the M-step
    ``M = solve(pens[1] W - Y1)`` (:func:`_smooth_solve_inplace`), ``R1 = M - W`` into Wp
    and ``Y1 += pens[1] R1``.  Returns the Frobenius norms (||W - Wp||, ||W||,
    ||D - W - S||, ||R1||), summed over the blocks as squares; Wp is scratch afterwards
    (it holds pens[1] R1)."""
    pen2, pen1 = pens
    dab = nab = nr2 = nr1 = 0.0
    for s in _channel_blocks(*W.shape):
        w, p, m, y1 = W[s], Wp[s], M[s], Y1[s]
        nab += _sq(w)
        np.subtract(w, p, out=p)
        dab += _sq(p)                                      # p = scratch from here
        nr2 += _sparse_step(D[s], w, Y2[s], p, S[s], pen2, thr, obs[s])
        np.multiply(w, pen1, out=m)
        m -= y1
        m = M[s] = _smooth_solve_inplace(m, pen1, mu, mstep, axis=-1)
        np.subtract(m, w, out=p)                           # R1 = M - W
        nr1 += _sq(p)
        p *= pen1
        y1 += p
    return tuple(float(np.sqrt(v)) for v in (dab, nab, nr2, nr1))


def _trnn_loop(Dt: np.ndarray, obs: np.ndarray, factors: tuple, mults: tuple, lam: float,
               mu: float, eta_s: tuple, tol: float, max_iter: int, mstep: str):
    """Algorithm 3 iterations of :func:`trnn`, in place, on the transposed (C, T) layout.

    Dt (P_Omega(X)^T), S, M, Y1, Y2 and two work arrays: W (T1, then (A B^T)^T in place,
    :func:`_factor_coefficients`, :func:`_apply_factors`) and Wp (the previous product, then
    scratch); A is never formed.  ``Y2 += eta (D - AB - S)`` is folded into the S-step (``Y2_new = eta
    clip(Ts, +-lam/eta)`` on Omega, 0 off it; :func:`_sparse_step`).  Returns (A B^T)^T
    (C, T), S (C, T) and the iteration count, convergence flag and last criterion.
    """
    B, P, Q = factors
    Y1, Y2 = mults
    eta, rho, eta_max = eta_s
    nd = float(np.linalg.norm(Dt))
    S, M, W, Wp = np.zeros(Dt.shape), np.zeros(Dt.shape), np.empty(Dt.shape), np.zeros(Dt.shape)
    crit, it, converged = np.inf, 0, False
    for it in range(1, max_iter + 1):
        # T1 = P^T Q + Y1 + Y2 + eta (M + D - S), one pass
        _step_matrix(W, Dt, S, M, Y1, Y2, eta, eta, (Q.T, P) if P.shape[0] > 0 else None)
        F, B, P, Q = _factor_coefficients(W @ W.T, W, B, 2.0 * eta, P, Q)           # (4.24), (4.26)
        _apply_factors(F, B, W)                            # W = (A B^T)^T
        # S-step (soft threshold on Omega), M-step (4.25), Y1, in place, one pass
        dab, nab, nr2, nr1 = _post_factor(W, Wp, Dt, S, M, Y1, Y2, obs, (eta, eta), lam / eta, mu, mstep)
        W, Wp = Wp, W                                      # Wp = this (AB)^T
        crit = max(_rel(nr2, nd), _rel(nr1, nd), _rel(dab, nab))
        eta = min(rho * eta, eta_max)
        if crit < tol:
            converged = True
            break
    return Wp, S, it, converged, crit


def _add_product(W: np.ndarray, L: np.ndarray, R: np.ndarray) -> None:
    """W += L @ R in place by BLAS dgemm (beta = 1), no temporary of W's size.

    W is a C-contiguous (m, n) array, i.e. the Fortran-ordered (n, m) W^T, so the call
    computes W^T <- R^T L^T + W^T."""
    from scipy.linalg import blas

    out = blas.dgemm(1.0, R.T, L.T, beta=1.0, c=W.T, overwrite_c=True)
    if not np.shares_memory(out, W):                     # a copy was made: write it back
        W[...] = out.T


def _trnn_settings(Xlin: np.ndarray, r: int, d, lam: float | None,
                   rank_threshold: float) -> tuple[int, int, float]:
    """Truncation r, factor width d (:func:`_trnn_width`, r <= d) and sparse weight lam
    (default ``100 / sqrt(max(T, C))``, Sec. 4.2.3) of :func:`trnn`."""
    T, C = Xlin.shape
    r = int(min(max(int(r), 0), T, C))
    d = _trnn_width(Xlin, d, r, rank_threshold)
    return min(r, d), d, 100.0 / np.sqrt(max(T, C)) if lam is None else lam


def _trnn_width(Xlin: np.ndarray, d, r: int, rank_threshold: float) -> int:
    """Factor width d of :func:`trnn` from its ``d`` argument (Sec. 4.2.3)."""
    T, C = Xlin.shape
    n_small = min(T, C)
    if isinstance(d, str):
        if d != "lsj":
            raise MocapValueError(f"d must be an int, None or 'lsj', got {d!r}")
        rk = estimate_rank(Xlin, None, rank_threshold)
        d = max(int(min(round(1.2 * rk), C, T)), min(r + 1, n_small))
    elif d is None:
        d = n_small
    return int(min(max(int(d), 1), n_small))


def _trnn_pq(Xlin: np.ndarray, r: int) -> tuple[np.ndarray, np.ndarray]:
    """P (r, T), Q (r, C) of :func:`trnn`: top-r singular vectors of the interpolated data."""
    T, C = Xlin.shape
    if r == 0:
        return np.zeros((0, T)), np.zeros((0, C))
    _, Vg = _linalg.eigh(Xlin.T @ Xlin, what="trnn")
    Vr = Vg[:, ::-1][:, :r]                               # (C, r)
    Ur = Xlin @ Vr
    Ur /= np.maximum(np.linalg.norm(Ur, axis=0, keepdims=True), 1e-300)
    return Ur.T, Vr.T


#: smallest eigenvalue / largest of N N^T for which :func:`_polar` uses the Gram route
#: (its error is about eps / this ratio = 1e-8 relative); below it, the SVD
POLAR_GRAM_RATIO = 1e-8


def _polar(N: np.ndarray) -> np.ndarray:
    """The orthogonal polar factor U V^T of a wide (r, n) matrix N = U S V^T, r <= n: the
    argmax of tr(W N^T) over W W^T = I (thesis Appendix Lemma 1, written for N^T).

    From the (r, r) Gram matrix, ``U S^-1 U^T N`` with ``N N^T = U S^2 U^T`` (5x faster
    than the SVD of a 15 x 10,000 N: 0.6 vs 3.4 ms, measured), when N is well conditioned
    (:data:`POLAR_GRAM_RATIO`); else by the SVD."""
    w, U = _linalg.eigh(N @ N.T, what="trnn")
    if w[0] > POLAR_GRAM_RATIO * w[-1]:
        return (U / np.sqrt(w)) @ (U.T @ N)
    U, _, Vt = _linalg.svd(N, full_matrices=False, what="trnn")
    return U @ Vt


@_linalg.one_blas_thread
def trnn(X: Any, mask: Any = None, *, r: int = 15, d: int | str | None = None, lam: float | None = None,
         mu: float = 100.0, rho: float = 1.4, eta: float = 1e-5, eta_max: float = 1e6,
         tol: float = 1e-4, max_iter: int = 500, rank_threshold: float = 0.1, seed: int = 0,
         mstep: str = "auto", return_info: bool = False):
    """Truncated-nuclear-norm completion with sparse error and smoothness (thesis Sec. 4.2).

    Solves (thesis eq. 4.23, our (T, C) layout: A = R, B = L of the thesis)::

        min  1/2 (||A||^2 + ||B||^2) - tr(P A B^T Q^T) + lam ||P_Omega(S)||_1 + mu/2 ||O M||^2
        s.t. M + S = P_Omega(X),  M = A B^T,  P P^T = I_r,  Q Q^T = I_r

    A (T, d), B (C, d), P (r, T), Q (r, C).  The first two terms equal the truncated nuclear
    norm ``sum_{i > r} sigma_i(A B^T)`` at the optimum (eq. 4.20).  Single-loop ALM
    (Algorithm 3) with closed-form steps::

        T1 = P^T Q + Y1 + Y2 + eta (M + P_Omega(X) - S)
        A  = T1 B (I + 2 eta B^T B)^-1;   B = T1^T A (I + 2 eta A^T A)^-1          (4.24)
        S  = P_Omega^c(Ts) + P_Omega(soft(Ts, lam/eta)),  Ts = P_Omega(X) - A B^T + Y2/eta
        M  = IDCT(Gamma DCT(eta A B^T - Y1)),  Gamma_ii = 1/(eta + mu xi_i^2)     (4.25)
        P  = argmax tr(P A B^T Q^T);  Q = argmax tr(Q B A^T P^T)   (Lemma 1)     (4.26)
        Y1 += eta (M - A B^T);  Y2 += eta (P_Omega(X) - A B^T - S);  eta <- min(rho eta, eta_max)

    Stopping (Sec. 4.2.3): ``max(||P_Omega(X) - AB^T - S|| / ||P_Omega(X)||,
    ||M - AB^T|| / ||P_Omega(X)||, ||AB^T - previous|| / ||AB^T||) < tol``.

    Parameters
    ----------
    X : (T, C) data (cm); mask : bool (T, C), True = observed.
    r : truncation (singular values left unpenalised); thesis: 15.
    d : factor width.  ``"lsj"``: the thesis' ``min(round(1.2 rank), C, T)`` (Sec. 4.2.3)
        with the rank of :func:`estimate_rank`, raised to at least ``r + 1`` (the model needs
        r <= rank <= d).  None (default): ``min(C, T)`` -- our decision, as for
        :func:`tsmc`: the last-jump rank of raw mocap matrices is 2-3, far below r = 15.
    lam : sparse weight, default ``100 / sqrt(max(T, C))`` (Sec. 4.2.3, real data).
    mu, rho, eta, eta_max, tol : thesis settings 100, 1.4, 1e-5, 1e6, 1e-4.
    mstep : "dct" (thesis eq. 4.25), "banded" or "auto" (the faster of the two for the
        clip's length) for the M-update (:func:`smooth_solve`).
    P and Q start from the top-r singular vectors of the linearly interpolated data (the
    thesis does not say; Algorithm 3 only initialises R at random, as we do with ``seed``).

    Returns
    -------
    Xhat : (T, C) = A B^T; with ``return_info`` also a
    :class:`~mocapkit.solvers.info.SolveInfo` (residual: the stopping criterion above,
    :data:`ALM_CRITERION`; extra ``r``, ``d`` and ``S`` (T, C) sparse error).  Stopping at
    ``max_iter`` above ``tol`` warns (:func:`~mocapkit.solvers.info.warn_not_converged`).

    Examples
    --------
    >>> import numpy as np
    >>> from mocapkit.solvers.completion import trnn
    >>> rng = np.random.default_rng(0)
    >>> X = np.sin(np.linspace(0, 2 * np.pi, 120)[:, None] * [1, 2]) @ rng.normal(size=(2, 9))
    >>> M = rng.random(X.shape) > 0.3                             # 30 % missing
    >>> Xhat, info = trnn(np.where(M, X, np.nan), M, r=2, return_info=True)
    >>> print(round(float(np.sqrt(np.mean((Xhat - X)[~M] ** 2))), 2), info.converged)
    0.01 True
    """
    X, m = _linalg.prepare(X, mask)
    T, C = X.shape
    Xlin = X if m.all() else gaps.fill(np.where(m, X, np.nan), m, never_observed=0.0)
    r, d, lam = _trnn_settings(Xlin, r, d, lam, rank_threshold)
    if lam < 0 or mu < 0 or eta <= 0 or rho < 1:
        raise MocapValueError("trnn needs lam >= 0, mu >= 0, eta > 0 and rho >= 1")
    if np.linalg.norm(X) == 0:                           # X = P_Omega(X): zeros off Omega
        info = SolveInfo(0, True, 0.0, ALM_CRITERION, {"r": r, "d": d, "S": np.zeros((T, C))})
        return (np.zeros((T, C)), info) if return_info else np.zeros((T, C))
    B = np.random.default_rng(seed).standard_normal((C, d))
    B /= np.linalg.norm(B)
    P, Q = _trnn_pq(Xlin, r)
    del Xlin
    Dt, obs = _transposed(X, m)
    del X
    ABt, St, it, converged, crit = _trnn_loop(
        Dt, obs, (B, P, Q), _alm_multipliers(Dt, lam), float(lam), float(mu),
        (float(eta), float(rho), float(eta_max)), float(tol), int(max_iter), mstep)
    del Dt
    info = SolveInfo(it, converged, float(crit), ALM_CRITERION, {"r": r, "d": d, "S": St.T})
    if not converged:
        warn_not_converged("trnn", info, tol, max_iter, stacklevel=2)
    Xhat = np.ascontiguousarray(ABt.T)
    return (Xhat, info) if return_info else Xhat


# --------------------------------------------------------------------------------------
# DynaMMo: linear dynamical system with missing values, fitted by EM
# --------------------------------------------------------------------------------------
def _psd_floor(S: np.ndarray, floor: float) -> np.ndarray:
    """Symmetrise and lift the eigenvalues of a covariance to at least ``floor``."""
    S = 0.5 * (S + S.T)
    w, V = _linalg.eigh(S, what="dynammo")
    return (V * np.maximum(w, floor)) @ V.T


def _kalman_rts(Xc: np.ndarray, A: np.ndarray, Cm: np.ndarray, Q: np.ndarray, Rd: np.ndarray,
                u0: np.ndarray, V0: np.ndarray):
    """Kalman filter + RTS smoother for fully filled data (DynaMMo's E-step).

    Observation noise is diagonal (``Rd`` (C,)), so the update works in information form
    on k x k matrices.  With every frame (filled) observed, the covariances do not depend
    on the data: the forward ones are iterated until they reach their steady state (after
    ``ns`` frames) and reused; the backward (smoothed) ones reach a fixed point in the
    steady middle of the sequence, which is then counted instead of iterated.  Only the
    k-vector mean recursions visit every frame.  Memory is O(ns k^2 + T k).

    Returns smoothed means (T, k), the sum of smoothed covariances over all frames, over
    frames 1..T-1 and 2..T, the sum of lag-one cross covariances
    ``sum_t Cov(z_t, z_{t-1})``, and the first frame's smoothed covariance.
    """
    T, k = Xc.shape[0], A.shape[0]
    CtRinv = Cm.T / Rd                                   # (k, C)
    info = CtRinv @ Cm                                    # C^T R^-1 C (k, k)
    Pp_l, Pf_l = [], []
    for t in range(T):                                    # forward covariances to steady state
        Pp = V0 if t == 0 else A @ Pf_l[-1] @ A.T + Q
        Pf = np.linalg.inv(np.linalg.inv(Pp) + info)
        Pf = 0.5 * (Pf + Pf.T)
        steady = (t > 2 and np.abs(Pf - Pf_l[-1]).max() <= 1e-10 * max(np.abs(Pf).max(), 1e-300))
        Pp_l.append(Pp)
        Pf_l.append(Pf)
        if steady:
            break
    ns = len(Pf_l)                                        # t >= ns - 1 uses the last entry
    Pp_u, Pf_u = np.array(Pp_l), np.array(Pf_l)
    Ppinv_u = np.linalg.inv(Pp_u)
    GA_u = Pf_u @ Ppinv_u @ A                             # (I - K_t C) A
    nxt = np.minimum(np.arange(ns) + 1, ns - 1)
    J_u = Pf_u @ A.T @ Ppinv_u[nxt]                       # J_t = Pf_t A^T Pp_{t+1}^-1
    # filter means: mu_t = (I - K_t C) A mu_{t-1} + K_t x_t, K_t x_t = Pf_t C^T R^-1 x_t
    # b_t = K_t x_t in blocks of frames (no (T, k) array of C^T R^-1 x_t besides b)
    b = np.empty((T, k))
    m0 = min(ns, T)
    b[:m0] = np.einsum("tij,tj->ti", Pf_u[:m0], Xc[:m0] @ CtRinv.T)
    KPf = CtRinv.T @ Pf_u[-1].T                           # (C, k): x_t -> Pf C^T R^-1 x_t
    for sl in frame_blocks(T - ns):
        sl = slice(sl.start + ns, sl.stop + ns)
        b[sl] = Xc[sl] @ KPf
    mu = np.empty((T, k))
    mu[0] = Pf_u[0] @ Ppinv_u[0] @ u0 + b[0]
    last = ns - 1
    for t in range(1, T):
        mu[t] = GA_u[t if t < last else last] @ mu[t - 1] + b[t]
    # backward covariances with fixed-point skipping
    Vs_last = Pf_u[min(T - 1, last)]
    Vsum = Vs_last.copy()
    cross = np.zeros((k, k))
    Vn = Vs_last
    t = T - 2
    while t >= 0:
        i, i1 = min(t, last), min(t + 1, last)
        Jt = J_u[i]
        Vt = Pf_u[i] + Jt @ (Vn - Pp_u[i1]) @ Jt.T
        Vsum += Vt
        cross += Vn @ Jt.T
        if (t > ns and t < T - 3 and np.abs(Vt - Vn).max() <= 1e-10 * max(np.abs(Vt).max(), 1e-300)):
            c = t - ns                                    # frames ns .. t-1 share Vt
            Vsum += c * Vt
            cross += c * (Vt @ Jt.T)
            Vn = Vt
            t = ns - 1
            continue
        Vn = Vt
        t -= 1
    V1 = Vn if T > 1 else Vs_last
    # smoothed means, written over the filtered ones (mu_t is last needed at step t)
    Amu = mu @ A.T
    ms = mu
    D = ms[-1]
    for t in range(T - 2, -1, -1):
        D = mu[t] + J_u[t if t < last else last] @ (D - Amu[t])
        ms[t] = D
    return ms, Vsum, Vsum - Vs_last, Vsum - V1, cross, V1


def _kalman_rts_masked(Xc: np.ndarray, W: np.ndarray, A: np.ndarray, Cm: np.ndarray,
                       Q: np.ndarray, u0: np.ndarray, V0: np.ndarray):
    """Kalman filter + RTS smoother that conditions on the observed entries only.

    ``W`` (T, C) holds ``mask / R`` (0 on missing entries), so frame t contributes the
    information ``C^T diag(W_t) C`` and ``C^T diag(W_t) x_t`` (information-form update;
    Shumway & Stoffer 1982 for LDS with missing observations).  Covariances now depend
    on the mask, so they are computed for every frame (memory O(T k^2)).  Same returns as
    :func:`_kalman_rts`.
    """
    T, k = Xc.shape[0], A.shape[0]
    Ckl = (Cm[:, :, None] * Cm[:, None, :]).reshape(Cm.shape[0], k * k)
    info = (W @ Ckl).reshape(T, k, k)                     # C^T diag(w_t) C per frame
    bx = (W * Xc) @ Cm                                    # C^T diag(w_t) x_t
    Pp = np.empty((T, k, k))
    Pf = np.empty((T, k, k))
    Ppinv = np.empty((T, k, k))
    mu = np.empty((T, k))
    for t in range(T):
        Pp[t] = V0 if t == 0 else A @ Pf[t - 1] @ A.T + Q
        Ppinv[t] = np.linalg.inv(Pp[t])
        P = np.linalg.inv(Ppinv[t] + info[t])
        Pf[t] = 0.5 * (P + P.T)
        mp = u0 if t == 0 else A @ mu[t - 1]
        mu[t] = Pf[t] @ (Ppinv[t] @ mp + bx[t])
    J = Pf[:-1] @ A.T @ Ppinv[1:]                         # (T-1, k, k)
    Vn = Pf[-1]
    Vsum = Vn.copy()
    cross = np.zeros((k, k))
    for t in range(T - 2, -1, -1):
        Vt = Pf[t] + J[t] @ (Vn - Pp[t + 1]) @ J[t].T
        Vsum += Vt
        cross += Vn @ J[t].T
        Vn = Vt
    ms = np.empty((T, k))
    ms[-1] = mu[-1]
    Amu = mu @ A.T
    D = ms[-1]
    for t in range(T - 2, -1, -1):
        D = mu[t] + J[t] @ (D - Amu[t])
        ms[t] = D
    return ms, Vsum, Vsum - Pf[-1], Vsum - Vn, cross, Vn


@_linalg.one_blas_thread
def lds_em_complete(X: Any, mask: Any = None, *, k: int | None = None, max_iter: int = 100,
                    tol: float = 1e-4, min_var: float = 1e-6, estep: str = "fill",
                    return_info: bool = False):
    """Fill missing entries with a linear dynamical system learnt by EM (DynaMMo).

    Li, McCann, Pollard & Faloutsos (2009), "DynaMMo: mining and summarization of
    coevolving sequences with missing values", KDD, Sec. 3 (model eq. 1, Algorithm 1):

        z_1 ~ N(u0, V0),   z_{t+1} = A z_t + w_t, w ~ N(0, Q),   x_t = C z_t + v_t, v ~ N(0, R)

    with latent z_t in R^k and x_t the (centred) frame.  Every EM iteration runs the Kalman
    filter and the Rauch-Tung-Striebel smoother (E-step), re-estimates the missing entries
    as ``C E[z_t]`` (DynaMMo's step 4) and updates (u0, V0, A, Q, C, R) in closed form
    (M-step; Ghahramani & Hinton 1996) with the missing entries at their expected values.

    E-step (``estep``): ``"fill"`` (default, DynaMMo's algorithm) runs the smoother on the
    current filled data -- every frame is then fully "observed", the covariances do not
    depend on the data and reach a steady state, so an iteration costs O(T k^2);
    ``"observed"`` conditions on the observed entries only (per-frame information update,
    Shumway & Stoffer 1982), which is the exact posterior but costs two k x k inversions per
    frame.  Measured on CMU 135_09 (600 frames, k = 48): 60 % random missing markers
    0.16 cm ("fill") vs 0.14 cm ("observed"); 10 markers x 60 frames 9.5 vs 9.3 cm, at
    about 10x the run time for "observed".

    Decisions: R is diagonal (one variance per
    coordinate) estimated on observed entries and floored at ``min_var`` times the data
    variance; the parameters start from PCA of the linearly interpolated data (C = top-k
    principal directions, A by least squares on the latent sequence) rather than at random,
    which needs far fewer EM iterations; observed entries are returned unchanged.

    Parameters
    ----------
    X : (T, C) data (cm); mask : bool (T, C), True = observed.
    k : latent dimension (default ``min(48, C)``; see :class:`mocapkit.denoise.completion.DynaMMo`).
    max_iter, tol : EM iterations; stop when the filled values change by less than ``tol``
        relative to their norm (centred).

    Returns
    -------
    Xhat : (T, C) completed matrix (X itself, after 0 iterations, when nothing is
    missing: observed entries are kept as they are); with ``return_info`` also a
    :class:`~mocapkit.solvers.info.SolveInfo` (residual: the last relative change of the
    filled values, :data:`EM_CRITERION`; extra ``k``).  Stopping at ``max_iter`` above
    ``tol`` warns (:func:`~mocapkit.solvers.info.warn_not_converged`).
    """
    X, m = _linalg.prepare(X, mask)
    T, Cn = X.shape
    k = int(min(48, Cn) if k is None else k)
    if k < 1:
        raise MocapValueError(f"k must be >= 1, got {k}")
    k = min(k, Cn, max(T - 1, 1))
    if T < 3 or m.all():                 # nothing to fill (observed entries are kept as they are)
        Xf = X if m.all() else gaps.fill(np.where(m, X, np.nan), m, never_observed=0.0)
        info = SolveInfo(0, True, 0.0, EM_CRITERION, {"k": k})
        return (Xf, info) if return_info else Xf
    Xc = gaps.fill(np.where(m, X, np.nan), m, never_observed=0.0)    # ours: centred in place
    mean = Xc.mean(axis=0)
    Xc -= mean
    scale = max(float(Xc.var()), 1e-12)
    floor = min_var * scale
    params = _lds_init(Xc, k, floor)
    if estep not in ("fill", "observed"):
        raise MocapValueError(f"estep must be 'fill' or 'observed', got {estep!r}")
    it, converged, change = _lds_em(Xc, m, params, estep, floor, int(max_iter), tol)
    info = SolveInfo(it, converged, change, EM_CRITERION, {"k": k})
    if not converged:
        warn_not_converged("dynammo", info, tol, max_iter, stacklevel=2)
    out = Xc
    out += mean
    np.copyto(out, X, where=m)
    return (out, info) if return_info else out


def _lds_init(Xc: np.ndarray, k: int, floor: float) -> tuple[np.ndarray, ...]:
    """DynaMMo's starting parameters (A, C, Q, R, u0, V0) from PCA of the centred, linearly
    filled data Xc (T, C): C = the top-k principal directions, A by least squares on the
    latent sequence, Q / V0 the (floored) residual / latent covariances, R (diagonal, (C,))
    the per-coordinate reconstruction error."""
    _, Vg = _linalg.eigh(Xc.T @ Xc, what="dynammo")
    Cm = Vg[:, ::-1][:, :k].copy()                        # (C, k)
    Zs = Xc @ Cm
    A = np.linalg.lstsq(Zs[:-1], Zs[1:], rcond=None)[0].T
    Q = _psd_floor(np.cov((Zs[1:] - Zs[:-1] @ A.T).T).reshape(k, k), floor)
    Rd = np.maximum(((Xc - Zs @ Cm.T) ** 2).mean(axis=0), floor)
    u0, V0 = Zs[0].copy(), _psd_floor(np.cov(Zs.T).reshape(k, k), floor)
    return A, Cm, Q, Rd, u0, V0


def _lds_em(Xc: np.ndarray, m: np.ndarray, params: tuple, estep: str, floor: float,
            max_iter: int, tol: float) -> tuple[int, bool, float]:
    """EM iterations of :func:`lds_em_complete` on the centred data Xc (T, C), whose missing
    entries (``~m``) are overwritten in place with C E[z_t] (DynaMMo's step 4).

    Returns (iterations, converged, last relative change of the filled values; inf when
    nothing is missing: one iteration, converged by definition).
    """
    miss = ~m
    n_obs = np.maximum(m.sum(axis=0), 1)
    change = np.inf
    converged = not miss.any()
    it = 0
    for it in range(1, max_iter + 1):
        stats, change = _lds_estep(Xc, m, params, estep, change)
        params = _lds_mstep(Xc, m, stats, n_obs, floor)
        if not miss.any():
            break
        if change < tol:
            converged = True
            break
    return it, converged, change


def _lds_estep(Xc: np.ndarray, m: np.ndarray, params: tuple, estep: str,
               change: float) -> tuple[tuple, float]:
    """Kalman/RTS smoothing (E-step) and the re-estimate ``Xc[~m] = C E[z]`` (in place).

    Returns the smoother's statistics (:func:`_kalman_rts`) and the relative change of the
    filled values (``change`` unchanged when nothing is missing)."""
    A, Cm, Q, Rd, u0, V0 = params
    miss = ~m
    if miss.any() and estep == "observed":
        stats = _kalman_rts_masked(Xc, m / Rd, A, Cm, Q, u0, V0)
    else:
        stats = _kalman_rts(Xc, A, Cm, Q, Rd, u0, V0)
    if miss.any():
        new = (stats[0] @ Cm.T)[miss]
        change = float(np.linalg.norm(new - Xc[miss]) / max(np.linalg.norm(Xc[miss]), 1e-300))
        Xc[miss] = new                                    # E[x_missing] = C E[z]
    return stats, change


def _lds_mstep(Xc: np.ndarray, m: np.ndarray, stats: tuple, n_obs: np.ndarray,
               floor: float) -> tuple[np.ndarray, ...]:
    """Closed-form M-step (Ghahramani & Hinton 1996) with the missing entries at their
    expected values; R from the observed entries only plus the state uncertainty."""
    ms, Vsum, Vsum_prev, Vsum_next, cross, V1 = stats
    T = Xc.shape[0]
    # sufficient statistics
    S11 = Vsum + ms.T @ ms                            # sum_t E[z_t z_t^T]
    Sprev = Vsum_prev + ms[:-1].T @ ms[:-1]           # t = 1..T-1
    Snext = Vsum_next + ms[1:].T @ ms[1:]             # t = 2..T
    S10 = cross + ms[1:].T @ ms[:-1]                  # sum E[z_t z_{t-1}^T]
    A = np.linalg.solve(Sprev.T, S10.T).T
    Q = _psd_floor((Snext - A @ S10.T) / (T - 1), floor)
    XZ = Xc.T @ ms                                    # (C, k), missing entries filled
    Cm = np.linalg.solve(S11.T, XZ.T).T
    # R from the observed entries only (plus the state uncertainty, averaged over frames)
    resid = np.where(m, Xc - ms @ Cm.T, 0.0)
    Rd = np.maximum((resid ** 2).sum(axis=0) / n_obs
                    + np.einsum("ck,kl,cl->c", Cm, Vsum / T, Cm), floor)
    return A, Cm, Q, Rd, ms[0].copy(), _psd_floor(V1, floor)
