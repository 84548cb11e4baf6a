"""Batched l1-regularised coding over a fixed dictionary (Xiao et al. 2015, eqs. 3-5).

Xiao et al. reconstruct every lagged window ``z`` of a poselet from its dictionary ``D``
(n, K) by solving, for every window independently,

* eq. (4), the l2/l1 model for Gaussian noise (lasso)::

      min_theta  ||z - D theta||_2^2 + lam ||theta||_1

* eq. (5), the l1/l1 model for outliers::

      min_theta  ||z - D theta||_1 + lam ||theta||_1

* mixed noise: eq. (5) first, then eq. (4) on its reconstruction (Sec. 3.2).

The paper solves them with DALM (ref. [60]) and the alternating direction method of
Yang & Zhang (ref. [59]).  Here all windows (rows of ``Z``, shape (S, n)) are solved
*together* as one matrix problem, so every iteration is a few dense matrix products
over all windows and no Python loop runs per window:

* :func:`lasso_admm` -- ADMM on the split ``theta = w`` (Boyd et al. 2011, Sec. 6.4): the
  theta-step is the exact ridge solve ``(2 D^T D + rho I)^{-1} (2 D^T z + rho (w - u))``.
  Learned dictionaries of smooth motion windows are very ill-conditioned (eigenvalues of
  ``D^T D`` from ~0 to ~K/2), so this converges in tens of iterations where FISTA needs
  hundreds (docs/results/xiao.md); it is the denoisers' solver.
* :func:`l1l1_admm` -- ADMM on the split ``e = z - D theta``, ``w = theta`` (Yang & Zhang
  2011, "Alternating direction algorithms for l1-problems in compressive sensing"): the
  theta-step solves with ``(D^T D + I)^{-1}``, which does not depend on the penalty rho,
  so every window has its own rho, adapted by residual balancing (Boyd et al. Sec. 3.4.1).
* :func:`lasso_fista` -- FISTA (Beck & Teboulle 2009) with per-window adaptive restart
  (O'Donoghue & Candes 2015); gradient ``2 (Theta D^T D - Z D)``; a reference solver.

Both ADMM solvers work with the thin SVD ``D = P diag(s) V^T`` (:func:`dictionary_svd`,
computed once per dictionary): the K x K inverses become ``I - V diag(.) V^T``, so an
iteration costs O(S r (n + K)) with r = rank(D) instead of O(S K^2).  With
``rank_tol > 0`` singular values below ``sqrt(rank_tol) * s_max`` are dropped, i.e. the
problem is solved exactly for the truncated dictionary ``D_r = P_r diag(s_r) V_r^T``
(``||D - D_r||_2 <= sqrt(rank_tol) s_max``); motion dictionaries have fast-decaying
spectra (rank ~100 of 512 at rank_tol = 1e-6), which makes coding several times faster
without measurable loss (docs/results/xiao.md).  ``rank_tol=0`` (default of the
functions) keeps every non-zero singular value: the exact problem.

Note the paper's objectives have no 1/2 in front of the squared loss (eq. 4).  Units:
for eq. (4) ``lam`` has the units of the data (cm here: ||.||^2 is cm^2, ||theta||_1 cm);
for eq. (5) ``lam`` is dimensionless (both terms scale with the data).

Shapes: ``Z`` (S, n) windows as rows, ``D`` (n, K) atoms as columns, codes ``Theta``
(S, K) (the transpose of the paper's theta).  ``dtype=np.float32`` halves the cost of
the matrix products (used by the denoisers; the tests check float64 against reference
solvers).
"""
from __future__ import annotations

import numpy as np

from ..errors import MocapValueError
from . import _linalg
from .info import SolveInfo

__all__ = ["soft_threshold", "lasso_fista", "lasso_admm", "lasso_admm_blocks", "l1l1_admm", "dictionary_svd",
           "DictionarySVD", "lipschitz_constant", "lasso_objective", "l1l1_objective"]


def soft_threshold(X: np.ndarray, t) -> np.ndarray:
    """Elementwise ``sign(x) max(|x| - t, 0)`` (the prox of ``t ||.||_1``), computed as
    ``x - clip(x, -t, t)`` (two passes over the data instead of four)."""
    t = np.asarray(t, dtype=X.dtype)
    return X - np.clip(X, -t, t)


def lipschitz_constant(D: np.ndarray) -> float:
    """Lipschitz constant ``2 ||D||_2^2`` of the gradient of ``||z - D theta||^2``."""
    D = np.asarray(D, dtype=np.float64)
    G = D.T @ D if D.shape[1] <= D.shape[0] else D @ D.T
    return float(2.0 * _linalg.eigvalsh(G, what="sparse coding")[-1])


def lasso_objective(Z, D, Theta, lam) -> np.ndarray:
    """Per-window value of eq. (4): ``||z - D theta||^2 + lam ||theta||_1`` (S,)."""
    R = np.asarray(Z) - np.asarray(Theta) @ np.asarray(D).T
    return (R ** 2).sum(1) + np.asarray(lam) * np.abs(Theta).sum(1)


def l1l1_objective(Z, D, Theta, lam) -> np.ndarray:
    """Per-window value of eq. (5): ``||z - D theta||_1 + lam ||theta||_1`` (S,)."""
    R = np.asarray(Z) - np.asarray(Theta) @ np.asarray(D).T
    return np.abs(R).sum(1) + np.asarray(lam) * np.abs(Theta).sum(1)


def _check(Z, D, dtype):
    Z = np.asarray(Z)
    D = np.asarray(D)
    if D.ndim != 2:
        raise MocapValueError(f"dictionary must be a 2-D (n, K) array, got shape {D.shape}")
    if Z.ndim == 1:
        Z = Z[None, :]
    if Z.ndim != 2 or Z.shape[1] != D.shape[0]:
        raise MocapValueError(f"windows must be (S, {D.shape[0]}) to match the dictionary, got {Z.shape}")
    if not (np.isfinite(Z).all() and np.isfinite(D).all()):
        raise MocapValueError("sparse coding: windows or dictionary contain NaN/inf")
    dt = np.dtype(dtype)
    return Z.astype(dt, copy=False), D.astype(dt, copy=False), dt


def _lam_column(lam, S: int, dt) -> np.ndarray:
    lam = np.asarray(lam, dtype=np.float64)
    if lam.ndim == 0:
        lam = np.full(S, float(lam))
    lam = lam.reshape(-1)
    if lam.shape != (S,) or not np.all(np.isfinite(lam)) or np.any(lam < 0):
        raise MocapValueError(f"lam must be a non-negative number or one per window ({S}), got {lam!r}")
    return lam.astype(dt)[:, None]


def lasso_fista(Z, D, lam, *, n_iter: int = 200, tol: float = 1e-5, Theta0=None,
                gram: np.ndarray | None = None, lipschitz: float | None = None,
                dtype=np.float64, check_every: int = 10) -> np.ndarray:
    """Solve eq. (4) ``min ||z_s - D theta_s||^2 + lam ||theta_s||_1`` for all windows at once.

    FISTA with constant step 1/L, ``L = 2 ||D||_2^2``, and per-window adaptive restart
    (momentum reset when ``<Y - Theta_new, Theta_new - Theta> > 0``).

    Parameters
    ----------
    Z : (S, n) windows.  D : (n, K) dictionary.
    lam : >= 0, scalar or (S,) per window (data units, e.g. cm).
    n_iter : maximum iterations.  tol : stop when the largest change of any coefficient
        in an iteration is below ``tol * max(1, max |Theta|)`` (checked every
        ``check_every`` iterations).
    Theta0 : optional (S, K) warm start.
    gram, lipschitz : precomputed ``D.T @ D`` and :func:`lipschitz_constant` (reuse
        them across calls with the same dictionary).
    dtype : float64 (default) or float32.

    Returns
    -------
    Theta : (S, K) codes.
    """
    Z, D, dt = _check(Z, D, dtype)
    S, K = Z.shape[0], D.shape[1]
    lam = _lam_column(lam, S, dt)
    G = (D.T @ D if gram is None else np.asarray(gram)).astype(dt, copy=False)
    L = lipschitz_constant(D) if lipschitz is None else float(lipschitz)
    if not L > 0:
        return np.zeros((S, K), dtype=dt)
    B = Z @ D                                     # D^T z for every window (S, K)
    step = dt.type(2.0 / L)
    thr = lam / dt.type(L)
    Theta = np.zeros((S, K), dtype=dt) if Theta0 is None else np.array(Theta0, dtype=dt)
    Y = Theta.copy()
    t = np.ones((S, 1), dtype=dt)
    for it in range(int(n_iter)):
        Tn = Y - step * (Y @ G - B)
        Tn = soft_threshold(Tn, thr)
        dT = Tn - Theta
        restart = ((Y - Tn) * dT).sum(axis=1, keepdims=True) > 0
        t = np.where(restart, dt.type(1.0), t)
        tn = (1.0 + np.sqrt(1.0 + 4.0 * t * t)) / 2.0
        Y = Tn + ((t - 1.0) / tn) * dT
        Theta, t = Tn, tn.astype(dt, copy=False)
        if (it + 1) % check_every == 0:
            scale = max(1.0, float(np.abs(Theta).max(initial=0.0)))
            if float(np.abs(dT).max(initial=0.0)) <= tol * scale:
                break
    return Theta


class DictionarySVD:
    """Thin (optionally truncated) SVD ``D_r = P diag(s) V^T`` of a dictionary D (n, K).

    Attributes: ``P`` (n, r), ``s`` (r,), ``V`` (K, r) in float64, ``rank`` r, ``dropped``
    (largest dropped singular value, 0 if none).  :meth:`cast` gives the factors in
    another dtype (cached).
    """

    def __init__(self, D: np.ndarray, rank_tol: float = 0.0):
        D = np.asarray(D, dtype=np.float64)
        if D.ndim != 2:
            raise MocapValueError(f"dictionary must be a 2-D (n, K) array, got shape {D.shape}")
        P, sv, Vt = _linalg.svd(D, full_matrices=False, what="sparse coding")
        top = float(sv[0]) if sv.size else 0.0
        cut = max(float(rank_tol), 0.0) ** 0.5 * top
        keep = sv > max(cut, top * max(D.shape) * np.finfo(np.float64).eps)
        self.P, self.s, self.V = P[:, keep], sv[keep], Vt[keep].T
        self.rank = int(keep.sum())
        self.dropped = float(sv[~keep].max(initial=0.0))
        self.shape = D.shape
        self._cast: dict = {}

    def cast(self, dtype) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        dt = np.dtype(dtype)
        if dt not in self._cast:
            self._cast[dt] = (self.P.astype(dt), self.s.astype(dt), self.V.astype(dt))
        return self._cast[dt]

    def reconstruct(self, Theta: np.ndarray) -> np.ndarray:
        """``Theta D_r^T`` (S, n), computed as ((Theta V) diag(s)) P^T."""
        P, s, V = self.cast(Theta.dtype)
        return ((Theta @ V) * s) @ P.T


def dictionary_svd(D: np.ndarray, rank_tol: float = 0.0) -> DictionarySVD:
    """:class:`DictionarySVD` of D, dropping singular values below sqrt(rank_tol) s_max."""
    return DictionarySVD(D, rank_tol)


def _svd_for(D: np.ndarray, svd: DictionarySVD | None) -> DictionarySVD:
    if svd is None:
        return DictionarySVD(D)
    if svd.shape != D.shape:
        raise MocapValueError(f"svd is for a {svd.shape} dictionary, not {D.shape}")
    return svd


def lasso_admm(Z, D, lam, *, rho: float | None = None, n_iter: int = 40, tol: float = 1e-4,
               svd: DictionarySVD | None = None, dtype=np.float64,
               check_every: int = 10, relax: float = 1.0, Theta0=None, U0=None,
               return_info: bool = False):
    """Solve eq. (4) ``min ||z_s - D theta_s||^2 + lam ||theta_s||_1`` for all windows by ADMM.

    Split ``theta = w`` with scaled dual u (Boyd et al. 2011, Sec. 6.4), over-relaxed with
    parameter ``relax`` = alpha (Boyd et al. Sec. 3.4.3; alpha = 1: plain ADMM)::

        theta <- (2 D^T D + rho I)^{-1} (2 D^T z + rho (w - u))
        th^   <- alpha theta + (1 - alpha) w
        w     <- soft(th^ + u, lam / rho)
        u     <- u + th^ - w

    With ``D = P diag(s) V^T``: ``(2 D^T D + rho I)^{-1} = (I - V diag(2s^2/(2s^2+rho)) V^T)/rho``
    and ``(2 D^T D + rho I)^{-1} 2 D^T z = V diag(2s/(2s^2+rho)) P^T z``, so an iteration
    costs two (S, K) x (K, r) products.  Writing ``soft(y, t) = y - clip(y, -t, t)``, the
    new dual is ``u = clip(th^ + u, +-lam/rho)`` and ``w - u = y - 2 clip(y)`` (exact algebra),
    so an iteration is the two products and five passes over (S, K) arrays, in place.

    Parameters
    ----------
    Z : (S, n) windows.  D : (n, K) dictionary.
    lam : >= 0, scalar or (S,) per window (data units).
    rho : penalty (one for all windows); default ``0.5 * median(lam)`` (measured to
        converge fastest on motion dictionaries for lam between 0.05 and 4 cm), floored
        at 1e-6 s_max^2.
    n_iter : maximum iterations.  tol : stop when, for every window, the primal residual
        ``||theta - w||`` and the dual residual ``rho ||w - w_prev||`` are both below
        ``tol * max(1, ||w||)`` (checked every ``check_every`` iterations).
    svd : cached :func:`dictionary_svd` of D (its truncation defines the problem solved).
    dtype : float64 (default) or float32 for the iterations.
    relax : over-relaxation alpha in (0, 2) (default 1: plain ADMM; 1.5-1.8 usually
        converges faster).
    Theta0, U0 : optional (S, K) warm start of w and of the scaled dual u; default zeros.
    return_info : also return a convergence report (:func:`_admm_info`): iterations run,
        largest relative primal / dual residual at the last check, ``converged``.

    Returns
    -------
    Theta : (S, K) codes (the w variable: exactly sparse); with ``return_info``
        ``(Theta, info)``, info a :class:`~mocapkit.solvers.info.SolveInfo`.

    Examples
    --------
    With an orthonormal dictionary eq. (4) has the closed form ``theta = soft(D^T z,
    lam / 2)``; two windows, lam = 1:

    >>> import numpy as np
    >>> from mocapkit.solvers.sparse_coding import lasso_admm
    >>> D = np.linalg.qr(np.random.default_rng(0).normal(size=(4, 4)))[0]
    >>> theta = np.array([[3.0, -0.2, 1.0, 0.0], [0.0, -2.0, 0.0, 0.4]])
    >>> Theta, info = lasso_admm(theta @ D.T, D, 1.0, n_iter=200, tol=1e-10, return_info=True)
    >>> print(np.round(Theta, 4) + 0.0)
    [[ 2.5  0.   0.5  0. ]
     [ 0.  -1.5  0.   0. ]]
    >>> info.converged, info.criterion
    (True, 'relative primal/dual residual')
    """
    Z, D, dt = _check(Z, D, dtype)
    S, K = Z.shape[0], D.shape[1]
    sv = _svd_for(D, svd)
    lamc = _lam_column(lam, S, dt)
    rho = _lasso_rho(rho, lamc, sv)
    alpha = _relax_alpha(relax)
    P, V, f_b, f_q = _lasso_factors(sv, rho, alpha, dt)
    Ba = ((Z @ P) * f_b) @ V.T                     # alpha (2D^TD + rho I)^{-1} 2 D^T z
    W = np.zeros((S, K), dtype=dt) if Theta0 is None else np.array(Theta0, dtype=dt).reshape(S, K)
    C = np.zeros((S, K), dtype=dt) if U0 is None else np.array(U0, dtype=dt).reshape(S, K)   # u
    n_iter = int(n_iter)
    W, iters, rmax, smax = _lasso_iterations(Ba, V, f_q, W, C, _clipper(lamc / dt.type(rho)),
                                             rho, alpha, n_iter, tol, check_every)
    if return_info:
        return W, _admm_info(iters, n_iter, rmax, smax, tol)
    return W


def _lasso_factors(sv: DictionarySVD, rho: float, alpha: float, dt):
    """(P, V, f_b, f_q) of :func:`lasso_admm`: the SVD factors in ``dt`` and the diagonal
    factors of alpha (2 D^T D + rho I)^{-1} 2 D^T and of alpha V diag(f) V^T."""
    P, _, V = sv.cast(dt)
    s64 = sv.s
    f_b = (2.0 * alpha * s64 / (2.0 * s64 ** 2 + rho)).astype(dt)
    f_q = (2.0 * alpha * s64 ** 2 / (2.0 * s64 ** 2 + rho)).astype(dt)
    return P, V, f_b, f_q


def lasso_admm_blocks(windows, S: int, D, lam, consume, *, blocks, restart=None,
                      rho: float | None = None, n_iter: int = 40, tol: float = 1e-4,
                      svd: DictionarySVD | None = None, dtype=np.float64,
                      check_every: int = 10, relax: float = 1.0) -> SolveInfo:
    """:func:`lasso_admm` of S windows given block by block, for long clips: the (S, n)
    windows and the (S, K) iterates of all windows are never held at once.

    ``windows(a, b)`` returns the rows a..b-1 of Z; ``blocks`` is a list of ``(a, b)``
    ranges covering 0..S-1 once (any order); ``consume(a, b, Theta)`` receives the codes
    of each block.  Returns the convergence report of the whole solve.

    Same result as ``lasso_admm`` on all of Z: the windows only interact through rho
    (from ``lam`` of all windows, as there) and the stopping test (every window's
    residuals below tol), so each block runs all ``n_iter`` iterations and records its
    largest residuals at every check; if all windows were below tol at an earlier check,
    the unblocked solve would have stopped there, and the blocks are solved again with
    that many iterations (``restart()`` is called first, so the caller can clear what
    ``consume`` accumulated).  Every block is then iterated exactly as the rows of the
    single solve (the iterations are row-wise; see :func:`mocapkit.windows.window_blocks`
    for blocks that also give bit-identical matrix products).
    """
    _, D, dt = _check(np.zeros((0, np.shape(D)[0])), D, dtype)     # D as lasso_admm casts it
    sv = _svd_for(D, svd)
    lamc = _lam_column(lam, int(S), dt)
    rho = _lasso_rho(rho, lamc, sv)
    alpha = _relax_alpha(relax)
    P, V, f_b, f_q = _lasso_factors(sv, rho, alpha, dt)

    def solve_all(n: int) -> dict[int, tuple[float, float]]:
        worst: dict[int, tuple[float, float]] = {}       # check iteration -> max residuals
        for a, b in blocks:
            Z, _, _ = _check(windows(a, b), D, dt)
            Ba = ((Z @ P) * f_b) @ V.T
            del Z
            W, C = np.zeros((b - a, D.shape[1]), dtype=dt), np.zeros((b - a, D.shape[1]), dtype=dt)
            hist: list = []
            W, _, _, _ = _lasso_iterations(Ba, V, f_q, W, C, _clipper(lamc[a:b] / dt.type(rho)),
                                           rho, alpha, n, tol, check_every, history=hist)
            del Ba, C
            for it, r, sd in hist:
                r0, s0 = worst.get(it, (0.0, 0.0))
                worst[it] = (max(r0, r), max(s0, sd))
            consume(a, b, W)
        return worst

    n_iter = int(n_iter)
    worst = solve_all(n_iter)
    stop = next((it for it in sorted(worst) if worst[it][0] <= tol and worst[it][1] <= tol), None)
    if stop is not None and stop + 1 < n_iter:           # the single solve stops earlier
        if restart is not None:
            restart()
        solve_all(stop + 1)
        last = stop
    else:
        last = n_iter - 1
    rmax, smax = worst.get(last, (float("inf"), float("inf")))
    return _admm_info(last + 1 if n_iter > 0 else 0, n_iter, rmax, smax, tol)


def _lasso_rho(rho: float | None, lamc: np.ndarray, sv: DictionarySVD) -> float:
    """The ADMM penalty of :func:`lasso_admm`: ``rho`` or ``0.5 median(lam)``, floored at
    1e-6 s_max^2 (s_max the largest singular value of the dictionary)."""
    top = float(sv.s.max(initial=0.0)) ** 2
    if rho is None:
        rho = 0.5 * float(np.median(lamc))
    rho = max(float(rho), 1e-6 * max(top, 1e-300))
    if not np.isfinite(rho):
        raise MocapValueError(f"rho must be a positive number, got {rho!r}")
    return rho


def _relax_alpha(relax) -> float:
    """The over-relaxation parameter alpha of the ADMM solvers, checked to lie in (0, 2)."""
    alpha = float(relax)
    if not (0.0 < alpha < 2.0):
        raise MocapValueError(f"relax must be in (0, 2), got {relax!r}")
    return alpha


def _lasso_iterations(Ba: np.ndarray, V: np.ndarray, f_q: np.ndarray, W: np.ndarray,
                      C: np.ndarray, clip, rho: float, alpha: float, n_iter: int, tol: float,
                      check_every: int, history: list | None = None
                      ) -> tuple[np.ndarray, int, float, float]:
    """The ADMM iterations of :func:`lasso_admm`, in place on w (``W``) and u (``C``).

    ``Ba`` = alpha (2 D^T D + rho I)^{-1} 2 D^T z, ``f_q`` the factors of alpha V diag(f)
    V^T, ``clip`` the clip to +-lam/rho (:func:`_clipper`).  Returns (w, iterations run,
    largest relative primal and dual residual at the last check).  With a ``history``
    list, all ``n_iter`` iterations run (no early stop) and every check appends
    ``(iteration index, primal, dual)`` (:func:`lasso_admm_blocks`).
    """
    dt = W.dtype
    S, K = W.shape
    X = W - C                                      # w - u
    Y = np.empty((S, K), dtype=dt)
    XV = np.empty((S, V.shape[1]), dtype=dt)
    tmp = np.empty((S, K), dtype=dt) if alpha != 1.0 else None
    Th, W_prev = np.empty((S, K), dtype=dt), np.empty((S, K), dtype=dt)     # check buffers
    rmax = smax = float("inf")
    it = -1
    for it in range(n_iter):
        check = (it + 1) % check_every == 0 or it == n_iter - 1
        np.matmul(X, V, out=XV)
        XV *= f_q
        np.matmul(XV, V.T, out=Y)                  # alpha V diag(f) V^T (w - u)
        np.subtract(Ba, Y, out=Y)
        if check:
            # unrelaxed theta = (Ba - q) / alpha + (w - u), for the primal residual
            np.multiply(Y, dt.type(1.0 / alpha), out=Th)
            Th += X
            np.copyto(W_prev, W)
        # th^ + u = alpha theta + (1 - alpha) w + u = Ba - q + w + (1 - alpha) u  (w - u = X)
        Y += W
        if tmp is not None:
            np.multiply(C, dt.type(1.0 - alpha), out=tmp)
            Y += tmp
        clip(Y, out=C)                             # new u
        np.subtract(Y, C, out=W)                   # new w = soft(th^ + u)
        np.subtract(W, C, out=X)
        if check:
            scale = np.maximum(1.0, _row_norms(W))
            Th -= W
            W_prev -= W
            rmax = float((_row_norms(Th) / scale).max(initial=0.0))
            smax = float((rho * _row_norms(W_prev) / scale).max(initial=0.0))
            if history is not None:
                history.append((it, rmax, smax))
            elif rmax <= tol and smax <= tol:
                break
    return W, it + 1, rmax, smax


def _row_norms(A: np.ndarray) -> np.ndarray:
    """Euclidean norm of every row of A, float64 (S,) (einsum: no squared copy of A)."""
    return np.sqrt(np.einsum("ij,ij->i", A, A, dtype=np.float64))


def _clipper(t):
    """``f(Y, out)`` = clip(Y, -t, t) into ``out``; scalar bounds when all of t (S, 1) are
    equal (numpy's clip is ~7x faster with scalar bounds)."""
    t = np.asarray(t)
    if t.size == 1 or np.all(t == t.flat[0]):
        tt = t.dtype.type(t.flat[0])
        return lambda Y, out: np.clip(Y, -tt, tt, out=out)

    def f(Y, out):
        np.minimum(Y, t, out=out)
        np.maximum(out, -t, out=out)
        return out
    return f


ADMM_CRITERION = "relative primal/dual residual"
"""What the ADMM solvers' ``residual`` is: the larger of the largest relative primal and
dual residuals over the windows at the last check (both are compared with ``tol``)."""


def _admm_info(iters: int, n_iter: int, rmax: float, smax: float, tol: float) -> SolveInfo:
    """Convergence report of a batched ADMM run: ``n_iter`` iterations run, ``converged``
    (both residuals <= ``tol``), ``residual`` = max(primal, dual) (:data:`ADMM_CRITERION`);
    extra ``max_iter`` (the cap), ``primal`` / ``dual`` (largest relative residual over the
    windows at the last check) and ``tol``."""
    return SolveInfo(n_iter=int(iters), converged=bool(rmax <= tol and smax <= tol),
                     residual=max(float(rmax), float(smax)), criterion=ADMM_CRITERION,
                     extra={"max_iter": int(n_iter), "primal": float(rmax), "dual": float(smax),
                            "tol": float(tol)})


def l1l1_admm(Z, D, lam, *, n_iter: int = 300, tol: float = 1e-5, rho: float | None = None,
              svd: DictionarySVD | None = None, dtype=np.float64, balance_every: int = 10,
              balance_until: int = 200, relax: float = 1.0,
              return_residual: bool = False, return_info: bool = False):
    """Solve eq. (5) ``min ||z_s - D theta_s||_1 + lam ||theta_s||_1`` for all windows at once.

    ADMM on ``min ||e||_1 + lam ||w||_1  s.t.  D theta + e = z,  theta = w`` (scaled
    duals u, v; Yang & Zhang 2011)::

        theta <- (D^T D + I)^{-1} [D^T (z - e - u) + (w - v)]
        e     <- soft(z - D theta - u, 1/rho)
        w     <- soft(theta + v, lam/rho)
        u     <- u + D theta + e - z;     v <- v + theta - w

    With ``D = P diag(s) V^T``: ``a = (z - e - u) P``, ``b = (w - v) V``,
    ``c = a s/(1+s^2) - b s^2/(1+s^2)``, ``theta = (w - v) + c V^T`` and
    ``D theta = (b + c) s P^T`` -- four (S, .) x (., r) products per iteration.

    Eq. (5) is positively homogeneous (z -> c z gives theta -> c theta), so every window
    is divided by its mean absolute value first and the solution scaled back: the
    problem is unchanged, and one penalty rho (default 1) then suits all windows, so the
    soft thresholds have scalar thresholds (much faster).  rho is doubled or halved every
    ``balance_every`` iterations when the total primal and dual residuals differ by
    more than 10x (duals rescaled accordingly; Boyd et al. 2011 Sec. 3.4.1), during the
    first ``balance_until`` iterations only (a penalty that keeps changing can break
    convergence).

    Parameters
    ----------
    Z : (S, n) windows.  D : (n, K) dictionary.  lam : >= 0 (dimensionless), scalar or (S,).
    n_iter : maximum iterations.  tol : stop when every window's primal and dual
        residual norms (of the normalised problem) are below ``tol * max(1, ||z_s||)``.
    rho : initial penalty of the normalised problem (default 1).
    relax : over-relaxation alpha in (0, 2) (Boyd et al. 2011 Sec. 3.4.3): the e- and
        w-steps and the dual updates use ``alpha D theta + (1 - alpha)(z - e_prev)`` and
        ``alpha theta + (1 - alpha) w_prev`` (default 1: plain ADMM; same solutions,
        1.5-1.8 usually converges faster).  The primal residual checked is that of the
        relaxed iterates (the dual updates ``u' - u``, ``v' - v``).
    svd : cached :func:`dictionary_svd` of D.
    return_residual : also return the sparse residual ``e`` (S, n) -- the outliers found.
    return_info : also return a convergence report (iterations run, largest relative
        primal / dual residual at the last check -- always made at the last iteration --,
        ``converged``), appended last to the returned tuple.

    Returns
    -------
    Theta : (S, K) codes (the w variable, exactly sparse); with ``return_residual``
        ``(Theta, E)``; with ``return_info`` ``(..., info)``, info a
        :class:`~mocapkit.solvers.info.SolveInfo` (:func:`_admm_info`).
    """
    Z, D, dt = _check(Z, D, dtype)
    sv = _svd_for(D, svd)
    lam = _lam_column(lam, Z.shape[0], dt)
    alpha = _relax_alpha(relax)
    Z, zscale = _normalise_rows(Z, dt)
    rho = 1.0 if rho is None else float(rho)
    if not (np.isfinite(rho) and rho > 0):
        raise MocapValueError(f"rho must be a positive number, got {rho!r}")
    st = _L1L1State(Z, lam, sv, alpha, rho)
    check, it, n_iter = True, -1, int(n_iter)
    rmax = smax = float("inf")
    for it in range(n_iter):
        check = (it + 1) % balance_every == 0 or it == n_iter - 1
        st.step(check)
        if check:
            r, sdual = st.residuals()
            rmax = float((r / st.znorm).max(initial=0.0))
            smax = float((sdual / st.znorm).max(initial=0.0))
            if rmax <= tol and smax <= tol:
                break
            if it < balance_until:
                st.balance(r, sdual)
    W, E = st.result(check)
    out = (W * zscale.astype(dt),)
    if return_residual:
        out += (E * zscale.astype(dt),)
    if return_info:
        out += (_admm_info(it + 1, n_iter, rmax, smax, tol),)
    return out if len(out) > 1 else out[0]


def _normalise_rows(Z: np.ndarray, dt) -> tuple[np.ndarray, np.ndarray]:
    """Z (S, n) divided by each row's mean absolute value (eq. 5 is positively homogeneous),
    in ``dt``, and that scale (S, 1) in float64 (1 for an all-zero row)."""
    zscale = np.abs(Z.astype(np.float64)).mean(axis=1, keepdims=True)
    zscale = np.where(zscale > 0, zscale, 1.0)
    return (Z / zscale).astype(dt), zscale


class _L1L1State:
    """The iterates of :func:`l1l1_admm` on the row-normalised problem, updated in place.

    Scaled duals kept as N = -u and C = v; with the soft threshold written as
    soft(y, t) = y - clip(y, -t, t) the updates collapse to (exact algebra):

    * e-step:  Ye = z - (D theta)^ + N;  N' = clip(Ye, +-1/rho);  e = Ye - N'
    * w-step:  Y = theta^ + C;           C' = clip(Y, +-lam/rho); w = Y - C'

    and the next theta-step needs only  z - e - u = (D theta)^ - N + 2 N'  and
    w - v = Y - 2 C'.  Over-relaxation (alpha): (D theta)^ = alpha D theta +
    (1 - alpha)(z - e), theta^ = alpha theta + (1 - alpha) w, with z - e = Ain - N and
    w = X + C; alpha is folded into the factors f_a, f_b and the P^T product.
    All (S, n) / (S, K) arrays are preallocated here (no fresh large array per iteration).
    """

    def __init__(self, Z: np.ndarray, lam: np.ndarray, sv: DictionarySVD, alpha: float,
                 rho: float):
        dt = Z.dtype
        S, n = Z.shape
        self.P, self.s, self.V = sv.cast(dt)
        K, r_ = self.V.shape
        s64 = sv.s
        self.f_a = (alpha * s64 / (1.0 + s64 ** 2)).astype(dt)
        self.f_b = (alpha * s64 ** 2 / (1.0 + s64 ** 2)).astype(dt)
        self.Z, self.lam, self.alpha, self.dt = Z, lam, alpha, dt
        self.W = np.zeros((S, K), dtype=dt)
        self.E = Z.copy()
        self.N = np.zeros((S, n), dtype=dt)           # -u
        self.C = np.zeros((S, K), dtype=dt)           # v
        self.Ain = Z - self.E + self.N                # z - e - u
        self.X = self.W - self.C                      # w - v
        self.a, self.b, self.c = (np.empty((S, r_), dtype=dt) for _ in range(3))
        self.Y = np.empty((S, K), dtype=dt)
        self.DT = np.empty((S, n), dtype=dt)
        self.Ye = np.empty((S, n), dtype=dt)
        # buffers of the residual checks
        self.N_old, self.Ain_old = np.empty((S, n), dtype=dt), np.empty((S, n), dtype=dt)
        self.C_old, self.X_old, self.DtdE = (np.empty((S, K), dtype=dt) for _ in range(3))
        self.znorm = np.maximum(_row_norms(Z), 1.0)
        self._set_rho(rho)

    def _set_rho(self, rho: float) -> None:
        self.rho = rho
        self.clip_e = _clipper(np.asarray(1.0 / rho, dtype=self.dt))
        self.clip_w = _clipper(self.lam / self.dt.type(rho))

    def step(self, check: bool) -> None:
        """One iteration: theta-step, e- and w-steps with their dual updates; with ``check``
        the previous duals and iterates are kept for :meth:`residuals`."""
        P, s, V, dt, alpha = self.P, self.s, self.V, self.dt, self.alpha
        a, b, c, Y, DT, Ye = self.a, self.b, self.c, self.Y, self.DT, self.Ye
        N, C, Ain, X = self.N, self.C, self.Ain, self.X
        np.matmul(Ain, P, out=a)
        np.matmul(X, V, out=b)
        a *= self.f_a
        np.multiply(b, self.f_b, out=c)
        np.subtract(a, c, out=c)                 # alpha c
        np.matmul(c, V.T, out=Y)                 # alpha (theta - (w - v))
        b *= dt.type(alpha)
        b += c
        b *= s                                   # alpha s (V^T theta)
        np.matmul(b, P.T, out=DT)                # alpha D theta
        if check:
            np.copyto(self.N_old, N)
            np.copyto(self.C_old, C)
            np.copyto(self.Ain_old, Ain)
            np.copyto(self.X_old, X)
        if alpha != 1.0:
            np.subtract(Ain, N, out=Ye)          # z - e
            Ye *= dt.type(1.0 - alpha)
            DT += Ye                             # (D theta)^
        np.subtract(self.Z, DT, out=Ye)
        Ye += N
        np.subtract(DT, N, out=Ain)
        self.clip_e(Ye, out=N)                   # N'
        Ain += N
        Ain += N                                 # z - e' - u' = (D theta)^ - N + 2 N'
        Y += X
        Y += C
        if alpha != 1.0:
            Y += dt.type(1.0 - alpha) * C        # theta^ + C
        self.clip_w(Y, out=C)                    # C'
        np.subtract(Y, C, out=X)
        X -= C                                   # w - v = Y - 2 C'

    def residuals(self) -> tuple[np.ndarray, np.ndarray]:
        """After a checked :meth:`step`: set e', w' and return every window's primal and
        dual residual norms (S,) (primal: of the relaxed iterate, the dual updates
        ``u' - u``, ``v' - v``)."""
        np.subtract(self.Ye, self.N, out=self.E)     # e'
        np.subtract(self.Y, self.C, out=self.W)      # w'
        # previous iterate: w = (w - v) + v,  e = z - (z - e - u) - u
        dE = self.Ain_old
        dE -= self.Z
        dE += self.E
        dE -= self.N_old                             # e' - e
        dW = self.X_old
        dW += self.C_old
        np.subtract(self.W, dW, out=dW)              # w' - w
        # primal residuals (of the relaxed iterate): u' - u = N - N';  C' - C
        self.N_old -= self.N
        self.C_old -= self.C
        r = np.sqrt(_row_norms(self.N_old) ** 2 + _row_norms(self.C_old) ** 2)
        np.matmul((dE @ self.P) * self.s, self.V.T, out=self.DtdE)
        self.DtdE -= dW
        return r, self.rho * _row_norms(self.DtdE)

    def balance(self, r: np.ndarray, sdual: np.ndarray) -> None:
        """Residual balancing (Boyd et al. 2011 Sec. 3.4.1): rho doubled / halved when the
        total primal and dual residuals differ by more than 10x, duals rescaled."""
        rt, st = float(np.sqrt((r ** 2).sum())), float(np.sqrt((sdual ** 2).sum()))
        f = 2.0 if rt > 10.0 * st else (0.5 if st > 10.0 * rt else 1.0)
        if f != 1.0:
            self.N /= self.dt.type(f)
            self.C /= self.dt.type(f)
            self._set_rho(self.rho * f)
            np.subtract(self.Z, self.E, out=self.Ain)
            self.Ain += self.N
            np.subtract(self.W, self.C, out=self.X)

    def result(self, checked: bool) -> tuple[np.ndarray, np.ndarray]:
        """(w, e) of the normalised problem after the last step."""
        if not checked:
            return self.Y - self.C, self.Ye - self.N
        return self.W, self.E
