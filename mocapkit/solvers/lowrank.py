"""Low-rank matrix solvers on plain arrays: TSVD, SVT, RPCA (inexact ALM) and SLRA.

All functions take a real matrix ``X`` of shape (m, n) -- for motion capture one row per
frame and one column per coordinate (m = T frames, n = 3J = 93 for the CMU skeleton; the
papers write the transpose) -- in whatever unit the caller uses (cm in mocapkit), and an
optional boolean ``mask`` of the same shape (True = observed).  Unobserved entries are
ignored (their values may be NaN) and filled by the low-rank model.  Observed entries must
be finite, otherwise :class:`~mocapkit.errors.MocapValueError` is raised.

Speed: mocap matrices are tall and thin, so every singular value shrinkage works on the
small side: the n x n Gram matrix ``M^T M`` is eigendecomposed (n = 93: ~0.8 ms) and the
shrunk matrix is ``M @ (V diag(max(1 - tau/sigma, 0)) V^T)`` -- one (m x n)(n x n) product.
The Gram route squares the condition number, which only affects singular values below
~1e-8 sigma_max; matrices that are not at least twice as long as wide use LAPACK's economy
SVD instead (``svd="auto"``).  Segments of SLRA are stacked into a (p, L, n) batch and
solved together (batched ``eigh`` / ``matmul``, no Python loop over segments).
Randomised / partial SVDs are not used (measured on a 200 x 93 CMU segment, one thread):
Gram + full ``eigh`` takes 0.60 ms, a rank-k randomised SVD with one power iteration
0.16 / 0.33 / 0.87 / 1.6 ms at k = 5 / 20 / 40 / 60, while the IALM rank climbs to 59
(tol 1e-7) or 21 (tol 1e-4) -- the saving is limited to the first ~15 iterations, and
short segments (m < 93) already work on the cheap m x m Gram matrix.  A certified
warm-started Rayleigh-Ritz step (previous iteration's Ritz vectors, up to 2 subspace
steps, a per-matrix proof that no singular value above tau is missed, exact ``eigh``
otherwise) was built and measured (issue 21, 2026-12-02): it is certifiable only in the
first ~10 of ~38 IALM iterations (once tau reaches the continuous part of the spectrum the
Ritz vectors next to tau converge 2-4x per step), skips 10-20 % of the ``eigh`` calls, and
measured within run-to-run noise (slra 5k-100k frames: +10-20 % at paper settings, -4 to
-18 % for the 24-frame overlap variant), so it was not kept.  A second build (same day:
2 block-power steps per iteration, Rayleigh-Ritz, an exact rank count by a Cholesky
Schur-complement inertia test, a Davis-Kahan bound on the shrinkage error) matched the
eigh route to ~1e-10 relative with the same iterations but certified only 16 % (paper
settings) / 22 % (24-frame overlap) of the shrinkages and measured +4-13 % frames/s at
10k frames; with ``eigh`` at 63-67 % of the time even a free ``eigh`` would leave ~20k
frames/s, so it was not kept either.  A third look (issue 21 item 1, 2026-12-03) measured why:
at the paper's tol 1e-7 the shrinkage rank of a 200 x 93 CMU segment is 1-14 in iterations
1-15 but 27-59 (median 53-59) in the 22 iterations after, where 1/mu lies inside the
continuous noise spectrum. A subspace there has to hold 60-70 of 93 directions, and its Ritz
vectors next to 1/mu must be exact to ~1e-10 relative, because a Ritz residual rho moves D_tau
by about rho / sigma however small the gap.  That is no cheaper than ``eigh``, and those 22
``eigh`` calls alone cap slra at ~13k frames/s.  For 24-frame segments the cost of the 24 x 24
``eigh`` (47-60 us, ~2.5 GFLOP/s) is LAPACK's per-call overhead, not FLOPs or Python: no
batched numpy route is faster.  What was kept is exact: :func:`_ialm_spectral_phase`.  While E
is still 0 (the first 3-12 iterations), the iterates stay in D's singular basis, and those
iterations need one ``eigh`` of D's Gram matrix and no ``eigh`` per iteration (measured: +13-17 %
frames/s at paper settings, +25-29 % for 24-frame segments with 12 frames of overlap; same
iterations; same results to round-off).  LAPACK's 93 x 93 ``eigh`` (0.6-0.9 ms) remains the floor of
the later iterations.

References
----------
* Cai, Candes & Shen (2010), "A singular value thresholding algorithm for matrix
  completion", SIAM J. Optim. 20(4): eqs. (1.3)-(1.5) (SVT iteration), (3.13) (noisy
  variant with a second-order-cone constraint), Sec. 5.1.1 (tau, delta, kicking).
* Lai, Yuen & Lee (2011), "Motion capture data completion and denoising by singular value
  thresholding", Eurographics short papers (SVT on mocap matrices).
* Lin, Chen & Ma (2010), "The augmented Lagrange multiplier method for exact recovery of
  corrupted low-rank matrices", arXiv:1009.5055, Algorithm 5 (inexact ALM for RPCA).
* Candes, Li, Ma & Wright (2011), "Robust principal component analysis?", J. ACM 58(3):
  lambda = 1/sqrt(max(m, n)).
* Peng, Liu, Cui & Zheng, "Segmented low rank approximation approach for motion capture
  data denoising" (SLRA, seed 004): eq. (2) (RPCA), eqs. (3)-(6) and Table 1 (IALM),
  Sec. 3.2 (consecutive segments, IALM per segment, concatenation).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .. import gaps
from ..errors import MocapValueError
from . import _linalg
from ..windows import frame_blocks
from .info import SolveInfo

__all__ = ["shrink_singular_values", "tsvd", "svt", "rpca_ialm", "slra", "segment_layout", "blend_weights"]


# --------------------------------------------------------------------------------------
# singular value shrinkage
# --------------------------------------------------------------------------------------
def _use_gram(m: int, n: int, svd: str) -> bool:
    if svd not in ("auto", "gram", "lapack"):
        raise MocapValueError(f"svd must be 'auto', 'gram' or 'lapack', got {svd!r}")
    if svd == "auto":
        return max(m, n) >= 2 * min(m, n)
    return svd == "gram"


def _small_eigh(M: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Eigen-decomposition of the small Gram matrix of a batch (..., m, n).

    Returns singular values (..., k) (ascending), the right (or left, when m < n) singular
    vectors (..., k, k) with k = min(m, n), and whether the vectors are right ones.
    """
    m, n = M.shape[-2:]
    Mt = np.swapaxes(M, -1, -2)
    right = m >= n
    G = Mt @ M if right else M @ Mt
    w, V = _linalg.eigh(G, what="singular value shrinkage")
    return np.sqrt(np.clip(w, 0.0, None)), V, right


def shrink_singular_values(M: np.ndarray, tau: float | np.ndarray, svd: str = "auto"
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Singular value soft thresholding D_tau(M) = U max(Sigma - tau, 0) V^T.

    The proximal operator of tau ||.||_* (Cai et al. 2010, eq. 2.2; SLRA eq. 4).

    Parameters
    ----------
    M : (..., m, n) matrix or stack of matrices.
    tau : threshold >= 0, scalar or one per matrix (shape ``M.shape[:-2]``).
    svd : "gram" (eigh of the small Gram matrix), "lapack" (economy SVD) or "auto"
        (gram when the matrix is at least twice as long as wide).

    Returns
    -------
    A : (..., m, n) shrunk matrix; rank : (...) number of singular values above tau.
    """
    M = np.asarray(M, dtype=np.float64)
    m, n = M.shape[-2:]
    tau = np.asarray(tau, dtype=np.float64)
    if _use_gram(m, n, svd):
        s, V, right = _small_eigh(M)
        t = tau[..., None]
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(s > t, 1.0 - t / np.where(s > 0, s, 1.0), 0.0)
        K = (V * f[..., None, :]) @ np.swapaxes(V, -1, -2)
        A = M @ K if right else K @ M
        return A, (f > 0).sum(axis=-1)
    U, s, Vt = _linalg.svd(M, full_matrices=False, what="singular value shrinkage")
    s2 = np.clip(s - tau[..., None], 0.0, None)
    return (U * s2[..., None, :]) @ Vt, (s2 > 0).sum(axis=-1)


def _spectral_norm(M: np.ndarray) -> np.ndarray:
    """Largest singular value of each matrix in a stack (..., m, n)."""
    m, n = M.shape[-2:]
    Mt = np.swapaxes(M, -1, -2)
    G = Mt @ M if m >= n else M @ Mt
    return np.sqrt(np.clip(_linalg.eigvalsh(G, what="spectral norm")[..., -1], 0.0, None))


# --------------------------------------------------------------------------------------
# truncated SVD
# --------------------------------------------------------------------------------------
@_linalg.one_blas_thread
def tsvd(X: Any, k: int = 10, mask: Any = None, *, max_iter: int = 100, tol: float = 1e-6
         ) -> np.ndarray:
    """Best rank-k approximation (Eckart-Young), with iterative imputation of missing entries.

    Without a mask: ``X V_k V_k^T`` with V_k the top-k right singular vectors (from the
    n x n Gram matrix).  Seed 004 keeps k = 10 for its TSVD baseline.  With a mask ("hard
    impute"): missing entries start at the per-column linear interpolation in time and are
    replaced by the rank-k reconstruction until they change by less than ``tol`` (relative)
    or ``max_iter`` iterations.

    Parameters
    ----------
    X : (m, n) matrix; mask : optional (m, n) bool, True = observed.
    k : number of singular values kept (clipped to min(m, n)).

    Returns
    -------
    (m, n) rank-<=k matrix (observed entries are *not* forced back).
    """
    X, mask = _linalg.prepare(X, mask, full_mask=False)
    k = int(k)
    if k < 1:
        raise MocapValueError(f"k must be >= 1, got {k}")
    m, n = X.shape
    k = min(k, m, n)

    def project(Z: np.ndarray) -> np.ndarray:
        if k == min(m, n):
            return Z.copy()
        _, V, right = _small_eigh(Z)
        Vk = V[:, -k:]
        return Z @ Vk @ Vk.T if right else Vk @ (Vk.T @ Z)

    if mask is None:
        return project(X)
    Z = gaps.fill(X, mask, never_observed=0.0)
    miss = ~mask
    A = project(Z)
    for _ in range(max_iter):
        new = A[miss]
        change = np.linalg.norm(new - Z[miss]) / max(np.linalg.norm(Z), 1e-300)
        Z[miss] = new
        A = project(Z)
        if change < tol:
            break
    return A


# --------------------------------------------------------------------------------------
# singular value thresholding (Cai, Candes & Shen 2010)
# --------------------------------------------------------------------------------------
def _proj_soc(y: np.ndarray, s: float) -> tuple[np.ndarray, float]:
    """Projection of (y, s) on the cone {(y, s): ||y||_F <= s} (Cai et al. 2010, Sec. 3.3)."""
    ny = float(np.linalg.norm(y))
    if ny <= s:
        return y, s
    if ny <= -s:
        return np.zeros_like(y), 0.0
    c = (ny + s) / (2 * ny)
    return c * y, c * ny


@_linalg.one_blas_thread
def svt(X: Any, mask: Any = None, tau: float | None = None, delta: float | None = None, *,
        eps: float = 0.0, tol: float = 1e-4, max_iter: int = 500, svd: str = "auto",
        method: str = "auto", return_info: bool = False, overwrite_x: bool = False):
    """Singular value thresholding (Cai, Candes & Shen 2010) for matrix completion / denoising.

    Solves ``min tau ||A||_* + 1/2 ||A||_F^2`` subject to ``P_Omega(A) = P_Omega(X)``
    (eq. 1.3; iteration 1.5: ``A_k = D_tau(Y_{k-1})``, ``Y_k = Y_{k-1} + delta P_Omega(X -
    A_k)``) or, when ``eps > 0``, subject to ``||P_Omega(A - X)||_F <= eps`` (the noisy
    variant, eq. 3.13, a projection on a second-order cone).  Lai et al. (2011) apply it to
    mocap matrices (frames x coordinates) for completion and denoising.

    Parameters
    ----------
    X : (m, n) data; mask : (m, n) bool, True = observed (default: all observed).
    tau : threshold; default ``sqrt(m n) * rms(P_Omega X)`` (about ||X||_F).  Cai et al.
        use 5n for their unit-scale n x n test matrices; 5x our default needed > 2000
        iterations on mocap matrices (whose singular values decay fast) where 1x needs a
        few hundred, and exact completion is as accurate (measured, see tests).
    delta : step; default Cai et al.'s ``1.2 m n / |Omega|``.
    eps : noise bound on the observed entries (same unit as X, Frobenius norm over Omega);
        0 = exact constraint.  With every entry observed and eps = 0 the solution is X.
    tol : stop when ``||P_Omega(A - X)||_F / ||P_Omega X||_F < tol`` (eps = 0) or when the
        relative change of A is below tol (eps > 0).
    max_iter : iteration cap (Cai et al.: 500).
    method : "auto" solves the fully observed case in closed form (below), "iterative"
        always runs the SVT iteration.
    overwrite_x : X (a float64 array) may be used as the result's storage (as scipy's
        ``overwrite_a``): one (m, n) array less for a caller that no longer needs it.

    With every entry observed the program has a closed form (KKT of eq. 3.12): A has the
    singular vectors of X and singular values ``max(s sigma_i - (1 - s) tau, 0)`` with
    ``s = nu / (1 + nu)`` in [0, 1] set by bisection so that ``||A - X||_F = eps`` (A = X
    when eps = 0).  The iteration converges to the same point, only slowly.

    Returns
    -------
    A : (m, n) estimate; with ``return_info`` also a :class:`~mocapkit.solvers.info.SolveInfo`
    (residual = the final value of the stopping criterion compared with ``tol``, criterion =
    its name; extra ``rank``, ``fit_ratio`` = ``||P_Omega(A - X)||_F / eps`` for eps > 0
    (must end <= 1.001), else 0, ``restarts``, ``delta``).
    Initial "kicking" ``Y_0 = k_0 delta P_Omega(X)`` with ``k_0 = ceil(tau / (delta
    ||P_Omega X||_2))`` (Sec. 5.1.1) skips the first iterations that return 0.
    Divergence guard (ours): when ``||P_Omega(X - A)||`` leaves ``(2 + 2 delta) ||P_Omega
    X||`` the step is halved and the iteration restarts (``restarts``, final ``delta`` in
    the info's extra).  Cost with missing entries: max_iter iterations of :func:`_svt_loop`.
    """
    X, mask = _linalg.prepare(X, mask, full_mask=False, copy=not overwrite_x)
    m, n = X.shape
    n_obs = m * n if mask is None else int(mask.sum())
    if n_obs == 0:
        raise MocapValueError("svt needs at least one observed entry")
    normX = float(np.linalg.norm(X))
    if normX == 0.0:
        A = np.zeros_like(X)
        return (A, SolveInfo(0, True, 0.0, "exact", {"rank": 0, "fit_ratio": 0.0})
                ) if return_info else A
    if tau is None:
        tau = np.sqrt(m * n) * normX / np.sqrt(n_obs)
    if delta is None:
        delta = 1.2 * m * n / n_obs
    tau, delta, eps = float(tau), float(delta), float(eps)
    if tau < 0 or delta <= 0 or eps < 0:
        raise MocapValueError(f"need tau >= 0, delta > 0, eps >= 0; got {tau}, {delta}, {eps}")

    if mask is None and method == "auto":
        A, rank = _svt_full(X, tau, eps, overwrite=True)    # X is prepare's copy or the caller's
        return (A, SolveInfo(0, True, 0.0, "closed form", {"rank": rank, "fit_ratio": 0.0,
                                                           "restarts": 0, "delta": delta})
                ) if return_info else A
    if method not in ("auto", "iterative"):
        raise MocapValueError(f"method must be 'auto' or 'iterative', got {method!r}")

    A, it, converged, rank, crit, fit, restarts, delta = _svt_loop(
        X, None if mask is None else ~mask, tau, delta, eps, tol, max_iter, _use_gram(m, n, svd),
        normX)
    if return_info:
        return A, SolveInfo(it, converged, float(crit),
                            ("relative residual ||P(X - A)|| / ||P X||" if eps == 0.0
                             else "relative change of A"),
                            {"rank": int(rank), "fit_ratio": float(fit), "restarts": restarts,
                             "delta": float(delta)})
    return A


def _svt_loop(X: np.ndarray, miss: np.ndarray | None, tau: float, delta: float, eps: float,
              tol: float, max_iter: int, gram: bool, normX: float) -> tuple:
    """The SVT iteration of :func:`svt` (Cai et al. 2010, eqs. 1.5 / 3.13), in place.

    Two (m, n) arrays besides X (Y and A): each iteration takes the shrinkage
    ``D_tau(Y) = Y (V f V^T)`` from Y's right singular vectors (eigh of the small Gram
    matrix, or the SVD for a matrix less than twice as long as wide) and then passes over
    the rows in blocks (:data:`ROW_BLOCK`): new A, residual ``R = P(X - A)``, its norms
    and ``Y += delta R`` -- the whole-matrix route kept A_new and R as two more arrays.
    Y stays zero off Omega by construction (Y_0 = k_0 delta P(X), and every update adds
    P(.) or scales), so the projection P(Y) of eq. 3.13 is not applied again.  Returns
    (A, iterations, converged, rank, criterion, fit ratio, restarts, final delta).
    """
    spec = float(_spectral_norm(X))
    m, n = X.shape
    Y, A = np.empty_like(X), np.zeros_like(X)
    rows = frame_blocks(m, ROW_BLOCK)

    def start(step: float) -> float:
        k0 = int(np.ceil(tau / (step * spec))) if tau > 0 and spec > 0 else 1
        np.multiply(X, k0 * step, out=Y)
        return float(np.linalg.norm(Y)) if eps > 0 else 0.0

    s = start(delta)
    converged, it, rank, crit, fit, restarts = False, 0, 0, float("inf"), 0.0, 0
    for it in range(1, max_iter + 1):
        Vk, fk = _shrink_operator(Y, tau, gram)
        rank = len(fk)
        # the cheaper product, as _shrink_into: (Y V_k f) V_k^T for a small rank, else Y K
        K = None if 2 * rank < n else (Vk * fk) @ Vk.T
        res2 = nA2 = chg2 = ny2 = 0.0
        for r in rows:                                     # blocks of rows, not frames
            An = (np.zeros_like(Y[r]) if rank == 0 else
                  (Y[r] @ Vk * fk) @ Vk.T if K is None else Y[r] @ K)
            R = X[r] - An
            if miss is not None:
                np.copyto(R, 0.0, where=miss[r])
            res2 += float(np.vdot(R, R))
            if eps > 0:
                nA2 += float(np.vdot(An, An))
                D = A[r] - An
                chg2 += float(np.vdot(D, D))
            A[r] = An
            R *= delta
            Y[r] += R                                      # Y + delta P(X - A)
            if eps > 0:
                ny2 += float(np.vdot(Y[r], Y[r]))
        res = float(np.sqrt(res2))
        if not (np.isfinite(res) and res <= (2.0 + 2.0 * delta) * normX):
            # diverging: Cai et al. prove convergence for 0 < delta < 2 only, and their
            # 1.2 m n / |Omega| exceeds that once 40 % of the entries are missing (24 at
            # 95 %: the iterates overflowed).  Halve the step and start again.
            if restarts >= 40:
                raise MocapValueError(f"svt diverged (step delta reduced to {delta:.3g})")
            restarts += 1
            delta *= 0.5
            s = start(delta)
            A[...] = 0.0
            crit = float("inf")
            continue
        if eps == 0.0:
            crit = res / normX
            if crit < tol:
                converged = True
                break
            continue
        change = float(np.sqrt(chg2)) / max(float(np.sqrt(nA2)), 1e-300)
        crit = change if it > 1 else float("inf")
        fit = res / eps
        if it > 1 and change < tol and res <= eps * (1 + 1e-3):
            converged = True
            break
        s -= delta * eps
        ny = float(np.sqrt(ny2))                           # projection on the cone (Sec. 3.3)
        if ny > s:
            c = 0.0 if ny <= -s else (ny + s) / (2 * ny)
            Y *= c
            s = c * ny
    return A, it, converged, rank, crit, fit, restarts, delta


def _shrink_operator(Y: np.ndarray, tau: float, gram: bool) -> tuple[np.ndarray, np.ndarray]:
    """``(V_k, f)`` with ``D_tau(Y) = Y V_k diag(f) V_k^T`` (Cai et al. eq. 2.2 through Y's
    right singular vectors): the k right vectors whose singular value exceeds tau (n, k)
    and ``f = 1 - tau / sigma`` (k,).  Gram route: eigh of ``Y^T Y``; otherwise the
    economy SVD of Y."""
    if gram and Y.shape[0] >= Y.shape[1]:
        w, V = _linalg.eigh(Y.T @ Y, what="singular value shrinkage")
        sv = np.sqrt(np.clip(w, 0.0, None))
    else:
        _, sv, Vt = _linalg.svd(Y, full_matrices=False, what="singular value shrinkage")
        V = Vt.T
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(sv > tau, 1.0 - tau / np.where(sv > 0, sv, 1.0), 0.0)
    keep = f > 0
    return V[:, keep], f[keep]


def _rank(A: np.ndarray) -> int:
    """Numerical rank (as :func:`numpy.linalg.matrix_rank`, through the robust SVD)."""
    if not A.any():
        return 0
    sv = _linalg.svd(A, compute_uv=False, what="svt")
    return int((sv > sv[0] * max(A.shape) * np.finfo(float).eps).sum())


def _svt_full(X: np.ndarray, tau: float, eps: float, overwrite: bool = False) -> tuple[np.ndarray, int]:
    """Closed-form solution of ``min tau||A||_* + 1/2||A||_F^2 s.t. ||A - X||_F <= eps``
    and its rank (the singular values it keeps: no SVD of the result).

    A tall X (T frames x 3J coordinates) goes through its small Gram matrix: singular
    values and right vectors from ``eigh(X^T X)``, then ``A = X (V diag(v / sigma) V^T)``
    row block by row block -- no (T, 3J) array besides the result (written into X with
    ``overwrite``), where the economy SVD held U, U * v and its workspace."""
    m, n = X.shape
    out = X if overwrite else None
    if eps <= 0:
        return (X if overwrite else X.copy()), _rank(X)
    if m < n:                                # wide: the economy SVD is the small side
        U, sig, Vt = _linalg.svd(X, full_matrices=False, what="svt")
    else:
        w, V = _linalg.eigh(X.T @ X, what="svt")
        sig = np.sqrt(np.clip(w, 0.0, None))
    if float(np.linalg.norm(sig)) <= eps:
        return (np.zeros_like(X) if out is None else _fill_zero(out)), 0

    def vals(s: float) -> np.ndarray:
        return np.maximum(s * sig - (1 - s) * tau, 0.0)

    lo, hi = 0.0, 1.0                        # distance decreases in s: ||X|| at 0, 0 at 1
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if np.linalg.norm(sig - vals(mid)) > eps:
            lo = mid
        else:
            hi = mid
    v = vals(hi)
    rank = int((v > 0).sum())
    if m < n:
        return (U * v) @ Vt, rank
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(sig > 0, v / np.where(sig > 0, sig, 1.0), 0.0)
    K = (V * f) @ V.T
    out = np.empty_like(X) if out is None else out
    for rows in frame_blocks(m, ROW_BLOCK):
        out[rows] = X[rows] @ K
    return out, rank


def _fill_zero(A: np.ndarray) -> np.ndarray:
    A[...] = 0.0
    return A


ROW_BLOCK = 4096
"""Rows per block where a whole-clip solver passes over a tall (T, 3J) matrix (svt's closed
form, whole-clip rpca): ~3 MB per 93-column block, in cache, and no temporary of the
whole matrix's size."""


# --------------------------------------------------------------------------------------
# robust PCA by inexact ALM (Lin, Chen & Ma 2010)
# --------------------------------------------------------------------------------------
CHUNK_ELEMENTS = 1 << 17
"""Matrices of a stack solved together per IALM chunk: as many as fit in ~131k entries
(1 MB per working array, so the five arrays of a chunk stay in the L2/L3 cache; a stack of
500 segments at once ran 1.8x slower per frame and needed 20x the input in memory)."""


IALM_CRITERION = "relative residual ||D-A-E||/||D||"
"""What the IALM solvers' ``residual`` is (:func:`rpca_ialm`, :func:`slra`): the final
``||D - A - E||_F / ||D||_F`` (observed entries), compared with ``tol``."""


def _shrink_into(M: np.ndarray, tau: np.ndarray, out: np.ndarray, gram: bool) -> np.ndarray:
    """``out = D_tau(M)`` for a stack (c, m, n), writing into ``out`` (no other big array).

    Returns the rank (number of singular values above tau) per matrix.
    Gram route: eigh of the small Gram matrix, then the cheaper of ``M (V_k f V_k^T)`` and
    ``(M V_k) (f V_k^T)`` with only the k columns whose singular value exceeds tau (k =
    the largest rank in the chunk) -- the same product as :func:`shrink_singular_values`.
    """
    if not gram:
        out[...], rank = shrink_singular_values(M, tau, "lapack")
        return rank
    c, m, n = M.shape
    right = m >= n
    Mt = np.swapaxes(M, -1, -2)
    if c == 1:                                          # 2-D product: numpy uses syrk
        G = (Mt[0] @ M[0] if right else M[0] @ Mt[0])[None]
    else:
        G = Mt @ M if right else M @ Mt
    w, V = _linalg.eigh(G, what="singular value shrinkage")
    s = np.sqrt(np.clip(w, 0.0, None))
    t = tau[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(s > t, 1.0 - t / np.where(s > 0, s, 1.0), 0.0)
    rank = (f > 0).sum(axis=-1)
    k = int(rank.max())
    if k == 0:
        out[...] = 0.0
        return rank
    Vk, fk = V[..., -k:], f[:, None, -k:]
    Vkt = np.swapaxes(Vk, -1, -2)
    q, r = (n, m) if right else (m, n)                 # q = side of V, r = the other side
    if 4 * r * q * k < 2 * r * q * q + 2 * q * q * k:   # low-rank product is cheaper
        if right:
            np.matmul(M @ Vk * fk, Vkt, out=out)
        else:
            np.matmul(Vk * fk, Vkt @ M, out=out)
    else:
        K = (Vk * fk) @ Vkt
        np.matmul(M, K, out=out) if right else np.matmul(K, M, out=out)
    return rank


def _ialm_start(D: np.ndarray, lam: np.ndarray, basis: bool = False) -> tuple[np.ndarray, ...]:
    """Lin et al.'s start per matrix: ||D||_F, Y_0, mu_0, mu_bar (Alg. 5, step 1).

    ``basis=True`` also returns the eigen-decomposition ``(w, V)`` of each matrix's small
    Gram matrix (ascending, as :func:`_small_eigh`), from which ||D||_2 is then taken,
    for :func:`_ialm_spectral_phase`."""
    normF = np.sqrt(np.einsum("ijk,ijk->i", D, D))
    if basis:
        m, n = D.shape[-2:]
        Dt = np.swapaxes(D, -1, -2)
        w, V = _linalg.eigh(Dt @ D if m >= n else D @ Dt, what="singular value shrinkage")
        norm2 = np.sqrt(np.clip(w[:, -1], 0.0, None))
    else:
        norm2 = _spectral_norm(D)
    safe2 = np.where(norm2 > 0, norm2, 1.0)
    lam_s = lam if lam.ndim == 1 else lam.min(axis=(1, 2))      # per-entry weights allowed
    norm_inf = np.maximum(D.max(axis=(1, 2)), -D.min(axis=(1, 2))) / lam_s   # no |D| copy
    Y = D / np.maximum(safe2, norm_inf)[:, None, None]
    mu = 1.25 / safe2
    if basis:
        return normF, Y, mu, mu * 1e7, (w, V, 1.0 / np.maximum(safe2, norm_inf))
    return normF, Y, mu, mu * 1e7


SPECTRAL_K = 32
"""Leading singular pairs of D tracked by :func:`_ialm_spectral_phase` (the phase ends
for a matrix before one beyond them could pass the threshold)."""


def _spectral_exit_step(D, Y, E, idx, R, thr, a, Lk, Rt, cc, z, mu, bar, rho, normF, tol,
                        its, crit) -> None:
    """The iteration in which E first becomes non-zero, for the matrices ``idx`` of
    :func:`_ialm_spectral_phase` (R = M - A already formed there): the full route's
    steps from the same M and A -- A = U diag(a) V^T made explicit, E = soft(R) (eqs.
    5-6), Z = D - A - E, ``Y_{k+1} = Y_k + mu Z`` -- written into Y and E; the matrices
    then continue in :func:`_ialm_chunk`.  A matrix whose residual ``||Z|| / ||D||``
    would already be below ``tol`` is left as it was (the full route redoes the step and
    stops there)."""
    kk = int(np.flatnonzero((a != 0.0).any(axis=0))[-1]) + 1 if a.any() else 0
    A = (Lk[idx, :, :kk] * a[:, None, :kk]) @ Rt[idx, :kk] if kk else np.zeros_like(R)
    En = np.clip(R, -thr, thr)                                # soft threshold of R
    np.subtract(R, En, out=En)
    Z = D[idx] - A
    Z -= En
    cr = np.sqrt(np.einsum("ijk,ijk->i", Z, Z)) / normF[idx]
    go = cr >= tol
    if not go.any():
        return
    g_idx, mus = idx[go], mu[idx[go]]
    Y[g_idx] = (D[g_idx] * cc[g_idx, None, None] + (Lk[g_idx] * z[g_idx, None, :]) @ Rt[g_idx]
                + Z[go] * mus[:, None, None])
    E[g_idx] = En[go]
    mu[g_idx] = np.minimum(mus * rho, bar[g_idx])
    its[g_idx] += 1
    crit[g_idx] = cr[go]
    cc[g_idx] = np.nan                                        # Y is final: not rebuilt


def _ialm_spectral_phase(D: np.ndarray, Y: np.ndarray, E: np.ndarray, w: np.ndarray,
                         V: np.ndarray, c0: np.ndarray, normF: np.ndarray, lam: np.ndarray,
                         mu: np.ndarray, bar: np.ndarray, rho: float, tol: float,
                         max_iter: int) -> tuple[np.ndarray, np.ndarray]:
    """The first IALM iterations (Lin et al. 2010, Alg. 5) in D's singular basis, while E = 0.

    Complete data only (no mask).  While E stays exactly 0, every iterate shares D's
    singular vectors: with D = sum_l s_l u_l v_l^T and Y = c D + sum_l z_l u_l v_l^T
    (Y_0 = D / max(||D||_2, ||D||_inf / lam): c = that scale's inverse, z = 0),
    ``M = D + Y / mu`` has singular values ``m_l = (1 + c / mu) s_l + z_l / mu``, so
    ``A = D_{1/mu}(M) = sum_l (m_l - 1/mu)_+ u_l v_l^T`` (eq. 4) and, with E = 0,
    ``Y += mu (D - A)`` is ``c += mu, z_l -= mu a_l``: the step is a recurrence on the
    scalars (c, z) -- no ``eigh`` of M.  Only the K = :data:`SPECTRAL_K` leading pairs
    carry z (the others stay inside the ``c D`` term, so their vectors are never formed).

    Why it is exact: the iteration is advanced for a matrix only when it can be checked
    that E stays 0 in it, i.e. that the soft threshold (eqs. 5-6) of ``R = M - A`` is 0:
    R is formed explicitly (``(1 + c/mu) D + U_K diag(z/mu - a) V_K^T``, one product of
    rank <= K) and every ``|R_ij| <= lam / mu`` is tested -- the same test the full route
    applies entry by entry.  A matrix leaves the phase (and continues in
    :func:`_ialm_chunk` from the same state, with the same mu) before the first iteration
    where any entry passes the threshold (that iteration itself is still done from the
    explicit R, see :func:`_spectral_exit_step`), where a pair beyond the K tracked ones could
    exceed 1/mu, where some ``m_l < 0``, where ``1/mu < 1e-7 ||D||_2`` (the Gram route's
    small singular vectors are then not accurate enough), where the residual
    ``||D - A||_F / ||D||_F`` (from the singular values) falls below ``10 tol + 1e-6``
    (so the convergence test is always made on explicit matrices), and before the last
    iteration (max_iter).  The iterates are therefore the full route's, up to round-off
    (the singular vectors come from one ``eigh`` of D's Gram matrix, as the full route's
    come from one per iteration).  The phase ends on real mocap segments after 3-12
    iterations (tau still above the noise floor, E not yet active).

    D, Y, E : (c, m, n) (Y and E, zeros on entry, are overwritten with the state the phase
    ends in); ``w, V`` the
    ascending eigen-decomposition of the small Gram matrix of each D; ``c0`` (c,) the
    scale of Y_0; ``mu`` (c,) is updated in place.  Returns the iterations done (c,) and
    the last residual of each matrix (inf when none was done).
    """
    c, m, n = D.shape
    q = min(m, n)
    K = min(q, SPECTRAL_K)
    lam2 = np.clip(w[:, ::-1], 0.0, None)                  # descending eigenvalues
    s = np.sqrt(lam2[:, :K])
    tail = np.sqrt(lam2[:, K]) if K < q else np.zeros(c)   # largest untracked value
    tail2 = lam2[:, K:].sum(axis=1)                          # ||D||_F^2 of the untracked pairs
    smax = np.sqrt(lam2[:, 0])
    Vk = V[..., ::-1][..., :K]
    inv_s = np.where(s > 0, 1.0 / np.where(s > 0, s, 1.0), 0.0)
    if m >= n:                                                # V: right singular vectors
        Rt = np.swapaxes(Vk, -1, -2)                          # (c, K, n)
        Lk = (D @ Vk) * inv_s[:, None, :]                     # (c, m, K)
    else:                                                     # V: left singular vectors
        Lk = Vk
        Rt = (np.swapaxes(Vk, -1, -2) @ D) * inv_s[:, :, None]
    cc, z = c0.copy(), np.zeros((c, K))
    its, crit = np.zeros(c, dtype=int), np.full(c, np.inf)
    act = np.arange(c)
    for _ in range(1, max_iter):                              # the last one: full route
        if act.size == 0:
            break
        tau = 1.0 / mu[act]
        g = 1.0 + cc[act] * tau
        sa = s[act]
        mval = g[:, None] * sa + z[act] * tau[:, None]       # singular values of M
        a = np.clip(mval - tau[:, None], 0.0, None)          # of A (eq. 4)
        cr = np.sqrt(np.einsum("ij,ij->i", sa - a, sa - a) + tail2[act]) / normF[act]
        ok = ((g * tail[act] <= tau) & (mval.min(axis=1) >= 0.0) & (tau > 1e-7 * smax[act])
              & (cr > 10.0 * tol + 1e-6))
        idx = act[ok]
        if idx.size == 0:
            break
        tau, g, a, cr = tau[ok], g[ok], a[ok], cr[ok]
        wv = z[idx] * tau[:, None] - a                        # R = g D + U diag(wv) V^T
        nz = np.flatnonzero((wv != 0.0).any(axis=0))
        R = D[idx] * g[:, None, None]
        if nz.size:
            kk = int(nz[-1]) + 1
            R += (Lk[idx, :, :kk] * wv[:, None, :kk]) @ Rt[idx, :kk]
        lt = lam[idx]
        thr = (lt[:, None, None] if lt.ndim == 1 else lt) * tau[:, None, None]
        if lt.ndim == 1:
            fits = (R.max(axis=(1, 2)) <= thr[:, 0, 0]) & (-R.min(axis=(1, 2)) <= thr[:, 0, 0])
        else:
            fits = (np.abs(R) <= thr).all(axis=(1, 2))
        if not fits.all():                  # the phase's last step: E becomes non-zero
            out = ~fits
            _spectral_exit_step(D, Y, E, idx[out], R[out], thr[out], a[out], Lk, Rt, cc, z,
                                mu, bar, rho, normF, tol, its, crit)
        step = idx[fits]
        mus = mu[step]
        cc[step] += mus
        z[step] -= mus[:, None] * a[fits]
        its[step] += 1
        crit[step] = cr[fits]
        mu[step] = np.minimum(mus * rho, bar[step])
        act = step
    done = np.flatnonzero((its > 0) & ~np.isnan(cc))
    if done.size:
        Y[done] = D[done] * cc[done, None, None] + (Lk[done] * z[done, None, :]) @ Rt[done]
    return its, crit


def _ialm_chunk(D: np.ndarray, mask: np.ndarray | None, lam: np.ndarray, tol: float,
                max_iter: int, rho: float, gram: bool, A_out: np.ndarray,
                E_out: np.ndarray | None, iters: np.ndarray, conv: np.ndarray,
                crit: np.ndarray) -> None:
    """IALM on one chunk (c, m, n); results into A_out / E_out / iters / conv / crit (c,).

    Five working arrays of the chunk's size (D, E, Y, M, A_new), all updated in place; a
    matrix leaves the working set (and is written out) in the iteration where it meets
    ``tol`` -- each matrix stops at its own tolerance, exactly as if solved alone.
    Complete data (no mask) on the Gram route starts with :func:`_ialm_spectral_phase`
    (the iterations while E = 0, without an ``eigh`` per iteration); each matrix then
    continues here from its own iteration count.
    """
    spectral = mask is None and gram and max_iter > 1
    start = _ialm_start(D, lam, basis=spectral)
    normF, Y, mu, bar = start[:4]
    run = np.flatnonzero(normF > 0)
    A_out[normF == 0] = 0.0
    if E_out is not None:
        E_out[normF == 0] = 0.0
    conv[:] = normF == 0
    crit[:] = np.where(conv, 0.0, np.inf)
    iters[:] = 0
    if run.size == D.shape[0]:                             # no copies of D and Y
        Dw, Yw, Mw = D, Y, None if mask is None else ~mask
    else:
        Dw, Yw, Mw = D[run], Y[run], None if mask is None else ~mask[run]
    mu, bar, nF, lam_w = mu[run], bar[run], normF[run], lam[run]
    one = D.shape[0] == 1 == run.size and A_out.flags.c_contiguous   # whole-clip rpca:
    Abuf = A_out if one else np.empty_like(Dw)                       # work in the outputs
    if one and E_out is not None and E_out.flags.c_contiguous:
        E = E_out
        E[...] = 0.0
    else:
        E = np.zeros_like(Dw)
    Mbuf = np.empty_like(Dw)
    if spectral and run.size:                              # first iterations, E = 0
        w, V, c0 = start[4]
        its, crs = _ialm_spectral_phase(Dw, Yw, E, w[run], V[run], c0[run], nF, lam_w, mu,
                                        bar, rho, tol, max_iter)
        iters[run], crit[run] = its, crs
    while run.size and max_iter >= 1:
        c = run.size
        M, An = Mbuf[:c], Abuf[:c]
        inv_mu = 1.0 / mu
        np.multiply(Yw, inv_mu[:, None, None], out=M)      # M = D - E + Y / mu
        M += Dw
        M -= E
        _shrink_into(M, inv_mu, An, gram)                  # eq. 4
        M += E                                             # R = D - A + Y / mu
        M -= An
        thr = (lam_w[:, None, None] if lam_w.ndim == 1 else lam_w) * inv_mu[:, None, None]
        np.clip(M, -thr, thr, out=E)                       # soft threshold, eqs. 5-6
        np.subtract(M, E, out=E)
        if Mw is not None:
            np.copyto(E, M, where=Mw)                      # unobserved: E absorbs all
        np.subtract(Dw, An, out=M)                         # Z = D - A - E
        M -= E
        cr = np.sqrt(np.einsum("ijk,ijk->i", M, M)) / nF
        M *= mu[:, None, None]
        Yw += M
        mu = np.minimum(mu * rho, bar)
        iters[run] += 1
        crit[run] = cr
        done = cr < tol
        conv[run[done]] = True
        done |= iters[run] >= max_iter
        if done.any():
            if not one:                                    # else An already is A_out
                A_out[run[done]] = An[done]
            if E_out is not None and E is not E_out:
                E_out[run[done]] = E[done]
            keep = ~done
            run, Dw, Yw, E, mu, bar, nF, lam_w = (run[keep], Dw[keep], Yw[keep], E[keep],
                                                   mu[keep], bar[keep], nF[keep], lam_w[keep])
            Mw = None if Mw is None else Mw[keep]
    if max_iter < 1:
        A_out[run] = 0.0
        if E_out is not None:
            E_out[run] = 0.0


def _ialm_rows(D: np.ndarray, miss: np.ndarray | None, lam: float, tol: float, max_iter: int,
               rho: float, A: np.ndarray, E: np.ndarray | None) -> tuple[int, bool, float]:
    """IALM (the iteration of :func:`_ialm_chunk`) on one tall matrix D (m, n), m >= n,
    passing over it in row blocks (:data:`ROW_BLOCK`): per iteration one pass accumulates
    the Gram matrix of ``M = D - E + Y / mu``, one more recomputes each block of M and
    applies the shrinkage ``A = M V f V^T``, the soft threshold and the multiplier step.

    D is only read (it may be a read-only view of the caller's data); the state is Y, E
    and A (written into ``A``, and into ``E`` when given) -- three arrays of D's size
    where the whole-matrix route needs five, and every pass stays in cache (the whole-clip
    rpca ran 35 % slower per frame at 100k than at 10k frames). Returns (iterations,
    converged, final ``||D - A - E|| / ||D||``).
    """
    m, n = D.shape
    normF, Y, mu, bar = (v[0] for v in _ialm_start(D[None], np.array([lam])))
    E = np.zeros_like(D) if E is None else _fill_zero(E)
    if normF == 0 or max_iter < 1:
        A[...] = 0.0
        return 0, normF == 0, 0.0 if normF == 0 else float("inf")
    rows = frame_blocks(m, ROW_BLOCK)

    def block_m(r: slice, inv_mu: float) -> np.ndarray:   # M = D - E + Y / mu, one block
        Mb = Y[r] * inv_mu
        Mb += D[r]
        Mb -= E[r]
        return Mb

    it, crit = 0, float("inf")
    for it in range(1, max_iter + 1):
        inv_mu = 1.0 / mu
        G = np.zeros((n, n))
        for r in rows:
            Mb = block_m(r, inv_mu)
            G += Mb.T @ Mb
        w, V = _linalg.eigh(G, what="singular value shrinkage")
        sv = np.sqrt(np.clip(w, 0.0, None))
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(sv > inv_mu, 1.0 - inv_mu / np.where(sv > 0, sv, 1.0), 0.0)
        k = int((f > 0).sum())
        Vk, fk = V[:, n - k:], f[n - k:]
        low = 4 * m * n * k < 2 * m * n * n + 2 * n * n * k   # the cheaper product, as _shrink_into
        K = None if low else (Vk * fk) @ Vk.T
        thr, zz = lam * inv_mu, 0.0
        for r in rows:
            Mb = block_m(r, inv_mu)
            Ab = A[r]
            if k == 0:
                Ab[...] = 0.0
            elif low:
                np.matmul(Mb @ Vk * fk, Vk.T, out=Ab)
            else:
                np.matmul(Mb, K, out=Ab)
            Mb += E[r]                                     # R = D - A + Y / mu
            Mb -= Ab
            Eb = E[r]
            np.clip(Mb, -thr, thr, out=Eb)                 # soft threshold, eqs. 5-6
            np.subtract(Mb, Eb, out=Eb)
            if miss is not None:
                np.copyto(Eb, Mb, where=miss[r])           # unobserved: E absorbs all
            np.subtract(D[r], Ab, out=Mb)                  # Z = D - A - E
            Mb -= Eb
            zz += float(np.vdot(Mb, Mb))
            Mb *= mu
            Y[r] += Mb
        crit = float(np.sqrt(zz)) / normF
        mu = min(mu * rho, bar)
        if crit < tol:
            return it, True, crit
    return it, False, crit


def _chunk_size(m: int, n: int) -> int:
    return max(1, CHUNK_ELEMENTS // max(m * n, 1))


def _ialm_batch(D: np.ndarray, mask: np.ndarray | None, lam: np.ndarray, tol: float,
                max_iter: int, rho: float, svd: str, crit_out: np.ndarray | None = None,
                want_E: bool = True) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
    """Inexact ALM (Lin et al. 2010, Alg. 5) on a stack D (p, m, n); unobserved D entries are 0.

    ``lam`` is one weight per matrix (p,) or one per entry (p, m, n) (weighted l1 norm).

    Per matrix: Y_0 = D / max(||D||_2, ||D||_inf / lambda), mu_0 = 1.25 / ||D||_2,
    mu_bar = 1e7 mu_0, mu_{k+1} = min(rho mu_k, mu_bar).  With a mask, E is unconstrained
    (not penalised) on unobserved entries, i.e. the constraint is P_Omega(A + E) = P_Omega(D)
    and Y stays 0 there.  A matrix stops updating once ``||D - A - E||_F / ||D||_F < tol``.
    The stack is solved in chunks of :data:`CHUNK_ELEMENTS` entries (:func:`_ialm_chunk`),
    so the working memory is five chunk-sized arrays whatever p is.
    ``crit_out`` (optional, shape (p,)) receives each matrix's last relative residual
    ``||D - A - E||_F / ||D||_F`` (0 for an all-zero matrix, inf if never iterated).
    ``want_E=False`` returns None for E (saves one array of D's size).
    """
    p, m, n = D.shape
    gram = _use_gram(m, n, svd)
    A = np.empty_like(D)
    E = np.empty_like(D) if want_E else None
    iters = np.zeros(p, dtype=int)
    conv = np.zeros(p, dtype=bool)
    crit = np.empty(p) if crit_out is None else crit_out
    if p == 1 and gram and m >= n and m * n > CHUNK_ELEMENTS and lam.ndim == 1:   # one long clip
        iters[0], conv[0], crit[0] = _ialm_rows(D[0], None if mask is None else ~mask[0], float(lam[0]),
                                                tol, max_iter, rho, A[0], None if E is None else E[0])
        return A, E, iters, conv
    cs = _chunk_size(m, n)
    for a in range(0, p, cs):
        sl = slice(a, min(a + cs, p))
        _ialm_chunk(D[sl], None if mask is None else mask[sl], lam[sl], tol, max_iter, rho,
                    gram, A[sl], None if E is None else E[sl], iters[sl], conv[sl], crit[sl])
    return A, E, iters, conv


@_linalg.one_blas_thread
def rpca_ialm(D: Any, lam: float | None = None, mask: Any = None, tol: float = 1e-7,
              max_iter: int = 500, *, rho: float = 1.5, svd: str = "auto",
              return_info: bool = False, want_E: bool = True):
    """Robust PCA ``min ||A||_* + lam ||E||_1  s.t.  A + E = D`` by inexact ALM.

    Candes et al. (2011) principal component pursuit, solved with Lin, Chen & Ma (2010)
    Algorithm 5 (= SLRA Table 1, eqs. 4-6).  With ``mask`` the constraint only holds on
    observed entries (``P_Omega(A + E) = P_Omega(D)``), so A also completes missing data.

    Parameters
    ----------
    D : (m, n) matrix, or a stack (p, m, n) of matrices solved independently in one batch.
    lam : sparsity weight; default 1/sqrt(max(m, n)) (Candes et al. 2011, Thm 1.1).
    mask : optional bool like D, True = observed.
    tol : stop when ``||D - A - E||_F / ||D||_F < tol`` (Lin et al.: 1e-7).
    max_iter : iteration cap; rho : growth factor of the penalty mu (Lin et al.'s code: 1.5).
    svd : singular value route, see :func:`shrink_singular_values`.

    Returns
    -------
    A, E : low-rank and sparse parts (same shape as D; on unobserved entries E = -A is
    meaningless and A is the completion).  With ``return_info`` also a
    :class:`~mocapkit.solvers.info.SolveInfo` (``n_iter``, ``converged`` and ``residual``,
    the final ``||D - A - E||_F / ||D||_F`` compared with ``tol`` (:data:`IALM_CRITERION`);
    arrays of length p for a stack, else scalars).  ``want_E=False`` returns None for E
    (one array of D's size less).

    Examples
    --------
    A rank-1 matrix with two gross errors is split into its low-rank and sparse parts:

    >>> import numpy as np
    >>> from mocapkit.solvers.lowrank import rpca_ialm
    >>> rng = np.random.default_rng(0)
    >>> L = np.outer(rng.normal(size=60), rng.normal(size=20))     # rank 1, (60, 20)
    >>> D = L.copy()
    >>> D[3, 2] += 10.0
    >>> D[17, 5] -= 8.0
    >>> A, E, info = rpca_ialm(D, return_info=True)
    >>> info.converged, info.residual < 1e-7
    (True, True)
    >>> print(np.round([E[3, 2], E[17, 5]], 3), bool(np.abs(A - L).max() < 1e-4))
    [10. -8.] True
    """
    # D is only read: without a mask (nothing to zero) the caller's array is used as is
    D, mask = _linalg.prepare(D, mask, name="D", batch=True, full_mask=False, copy=mask is not None)
    single = D.ndim == 2
    if single:
        D = D[None]
        mask = None if mask is None else mask[None]
    m, n = D.shape[-2:]
    if lam is None:
        lam = 1.0 / np.sqrt(max(m, n))
    lam = float(lam)
    if not lam > 0:
        raise MocapValueError(f"lam must be > 0, got {lam}")
    if not (rho > 1):
        raise MocapValueError(f"rho must be > 1, got {rho}")
    crit = np.empty(D.shape[0])
    A, E, iters, conv = _ialm_batch(D, mask, np.full(D.shape[0], lam), float(tol), int(max_iter),
                                    float(rho), svd, crit_out=crit, want_E=bool(want_E))
    if single:
        A, iters, conv, crit = A[0], int(iters[0]), bool(conv[0]), float(crit[0])
        E = None if E is None else E[0]
    if return_info:
        return A, E, SolveInfo(iters, conv, crit, IALM_CRITERION)
    return A, E


# --------------------------------------------------------------------------------------
# segmented low-rank approximation (SLRA, seed 004)
# --------------------------------------------------------------------------------------
def segment_layout(T: int, segment: int = 200, overlap: int = 0,
                   n_segments: int | None = None, fast: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Start and stop frames of the SLRA segments.

    Without overlap the T frames are split into ``p = max(1, round(T / segment))``
    consecutive near-equal parts (SLRA's "平均划分", equal division: 1200 frames / 200 ->
    6 x 200); lengths differ by at most one frame.  With ``overlap = o > 0``, ``p =
    max(1, round((T - o) / (segment - o)))`` segments of equal length
    ``L = ceil((T + (p - 1) o) / p)`` start at evenly spaced frames, so neighbours share
    at least o frames.  ``n_segments`` fixes p instead.  A clip shorter than one segment
    is a single segment (plain RPCA).  ``fast=True`` (with overlap) lengthens L to the next
    fast FFT length (:func:`scipy.fft.next_fast_len`; the neighbours then share a few more
    frames): for the DCT M-step of tsmc / trnn, whose cost at an awkward length is 2.5x
    (8,165 frames: 8.2 ms a DCT, 8,192: 3.3 ms).
    """
    T, overlap = int(T), int(overlap)
    if T < 1:
        raise MocapValueError("need at least one frame")
    if n_segments is not None:
        p = int(n_segments)
        if p < 1:
            raise MocapValueError(f"n_segments must be >= 1, got {n_segments}")
    else:
        segment = int(segment)
        if segment < 1:
            raise MocapValueError(f"segment must be >= 1 frame, got {segment}")
        if not 0 <= overlap < segment:
            raise MocapValueError(f"overlap must be in [0, segment) = [0, {segment}), got {overlap}")
        p = max(1, int(round((T - overlap) / (segment - overlap))))
    if overlap < 0:
        raise MocapValueError(f"overlap must be >= 0, got {overlap}")
    p = min(p, T)
    if overlap == 0 or p == 1:
        b = np.round(np.linspace(0, T, p + 1)).astype(int)
        return b[:-1], b[1:]
    L = min(T, int(np.ceil((T + (p - 1) * overlap) / p)))
    if fast:
        from scipy.fft import next_fast_len

        L = min(T, next_fast_len(L, real=True))
    starts = np.round(np.linspace(0, T - L, p)).astype(int)
    return starts, starts + L


def blend_weights(starts: np.ndarray, stops: np.ndarray) -> list[np.ndarray]:
    """Per-segment weights: linear ramps over the frames shared with each neighbour
    (they sum to 1 on every frame of a :func:`segment_layout`)."""
    ws = []
    p = len(starts)
    for i in range(p):
        L = stops[i] - starts[i]
        t = np.arange(L) + 0.5
        w = np.ones(L)
        if i > 0 and stops[i - 1] > starts[i]:
            o = stops[i - 1] - starts[i]
            w = np.minimum(w, t / o)
        if i < p - 1 and stops[i] > starts[i + 1]:
            o = stops[i] - starts[i + 1]
            w = np.minimum(w, (L - t) / o)
        ws.append(w)
    return ws


@_linalg.one_blas_thread
def slra(D: Any, segment: int = 200, overlap: int = 0, *, n_segments: int | None = None,
         mask: Any = None, lam: float | None = None, center: str = "none", tol: float = 1e-7,
         max_iter: int = 500, rho: float = 1.5, svd: str = "auto", return_info: bool = False):
    """Segmented low-rank approximation (SLRA, seed 004 Sec. 3.2).

    1. split the m frames into p consecutive segments (:func:`segment_layout`);
    2. per segment solve RPCA ``min ||A_i||_* + lam ||E_i||_1 s.t. A_i + E_i = D_i`` by inexact
       ALM with ``lam = 1/sqrt(max(m_i, n))`` (eqs. 2-6, Table 1) -- all segments of one
       length are solved together as a batch;
    3. concatenate the A_i in time order.  With ``overlap > 0`` (our extension) the frames
       shared by two segments are blended with linear cross-fade weights, so the result does
       not jump at segment borders.

    Parameters
    ----------
    D : (m, n) noisy matrix (frames x coordinates); mask : optional bool, True = observed.
    segment : target segment length in frames (default 200, the paper's best, Table 3).
    overlap : frames shared by neighbouring segments (0 = the paper's method).
    n_segments : fixed segment count (the paper's Tables 2-3 give counts), overrides segment.
    lam : fixed sparsity weight for every segment (default per segment, see above).
    center : "none" (paper), "mean" or "median": subtract each segment's per-column
        mean/median of observed entries before RPCA and add it back to A.
    tol, max_iter, rho, svd : IALM settings, see :func:`rpca_ialm`.

    Returns
    -------
    A, E : (m, n) low-rank estimate and sparse part (E = D - A on observed entries).
    With ``return_info`` also a :class:`~mocapkit.solvers.info.SolveInfo` with one
    ``n_iter`` / ``converged`` / ``residual`` per segment (the final relative IALM residual,
    see :func:`rpca_ialm`) and extra ``starts``, ``stops`` (the segments' frames).
    """
    D, mask = _linalg.prepare(D, mask, name="D", full_mask=False)
    m, n = D.shape
    if center not in ("none", "mean", "median"):
        raise MocapValueError(f"center must be 'none', 'mean' or 'median', got {center!r}")
    if not (rho > 1):
        raise MocapValueError(f"rho must be > 1, got {rho}")
    starts, stops = segment_layout(m, segment, overlap, n_segments)
    p = len(starts)
    weights = blend_weights(starts, stops)
    A = np.zeros_like(D)
    iters, conv, resid = np.zeros(p, dtype=int), np.zeros(p, dtype=bool), np.zeros(p)
    for seg in _segment_chunks(starts, stops, D.shape[1]):
        _slra_chunk(D, mask, seg, starts, stops, weights, A, lam, center,
                    (float(tol), int(max_iter), float(rho), svd), (iters, conv, resid))
    lengths = stops - starts
    all_rows = np.repeat(starts - np.cumsum(lengths) + lengths, lengths) + np.arange(lengths.sum())
    wsum = np.bincount(all_rows, weights=np.concatenate(weights), minlength=m)
    A /= wsum[:, None]
    E = D                                                 # D is our copy: E = D - A in place
    E -= A
    if mask is not None:
        E[~mask] = 0.0
    if return_info:
        return A, E, SolveInfo(iters, conv, resid, IALM_CRITERION,
                               {"starts": starts, "stops": stops})
    return A, E


def _segment_chunks(starts: np.ndarray, stops: np.ndarray, n: int) -> list[np.ndarray]:
    """Segment indices grouped by length, then cut into IALM chunks (:func:`_chunk_size`).

    Within a chunk no two segments share a frame (with overlap a chunk takes every q-th
    segment), so the blended results can be added with one fancy-indexed ``+=``.
    """
    lengths = stops - starts
    out = []
    for L in np.unique(lengths):
        seg = np.flatnonzero(lengths == L)
        cs = _chunk_size(int(L), n)
        q = 1                                 # classes i mod q share no frame
        while q < len(seg) and bool((stops[seg[:-q]] > starts[seg[q:]]).any()):
            q += 1
        for r in range(q):
            g = seg[r::q]
            out.extend(g[i:i + cs] for i in range(0, len(g), cs))
    return out


def _slra_chunk(D: np.ndarray, mask: np.ndarray | None, seg: np.ndarray, starts: np.ndarray,
                stops: np.ndarray, weights: list[np.ndarray], A: np.ndarray, lam: float | None,
                center: str, settings: tuple, info: tuple) -> None:
    """IALM of the segments ``seg`` (equal length, no shared frame); A[rows] += w A_i."""
    L, n = int(stops[seg[0]] - starts[seg[0]]), D.shape[1]
    rows = (starts[seg][:, None] + np.arange(L)).ravel()
    Db = D[rows].reshape(len(seg), L, n)                   # gathered copy (chunk only)
    Mb = None if mask is None else mask[rows].reshape(len(seg), L, n)
    if center != "none":
        c = _segment_centre(Db, Mb, center)                # (g, 1, n)
        Db -= c
        if Mb is not None:
            Db[~Mb] = 0.0
    seg_lam = np.full(len(seg), 1.0 / np.sqrt(max(L, n)) if lam is None else float(lam))
    crit = np.empty(len(seg))
    tol, max_iter, rho, svd = settings
    Ab, _, it, cv = _ialm_batch(Db, Mb, seg_lam, tol, max_iter, rho, svd, crit_out=crit,
                                want_E=False)
    if center != "none":
        Ab += c
    Ab *= np.stack([weights[i] for i in seg])[..., None]
    A[rows] += Ab.reshape(-1, n)
    iters, conv, resid = info
    iters[seg], conv[seg], resid[seg] = it, cv, crit


def _segment_centre(Db: np.ndarray, Mb: np.ndarray | None, how: str) -> np.ndarray:
    """Per-segment, per-column mean/median of observed entries (g, 1, n); 0 where none."""
    if Mb is None:
        f = np.mean if how == "mean" else np.median
        return f(Db, axis=1, keepdims=True)
    X = np.where(Mb, Db, np.nan)
    f = np.nanmean if how == "mean" else np.nanmedian
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        c = f(X, axis=1, keepdims=True)
    return np.nan_to_num(c, nan=0.0)
