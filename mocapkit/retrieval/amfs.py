"""Adaptive multi-view feature selection (AMFS, thesis seed 003 Ch. 5, eqs. 5.1-5.24,
Algorithms 4-5) and the unsupervised feature-selection baselines of Sec. 5.3.

Layout: samples are **rows** (``F`` is (N, D), N clips, D features); the thesis stores them
as columns (``X = F^T``, D x N). A view is a block of columns of ``F``.

Local-regression Laplacian (eqs. 5.2-5.16, after Yang et al. 2012)
-------------------------------------------------------------------
For every sample i of view v, ``X_i`` (d_v x k) holds it and its k-1 nearest neighbours in
that view. Eq. 5.14::

    L_i = H - H X_i^T (X_i H X_i^T + mu I)^{-1} X_i H,     H = I_k - 1 1^T / k

a k x k matrix. With ``K_c = H X_i^T X_i H`` (the centred k x k Gram) the push-through
identity gives the same matrix from a k x k solve instead of a d_v x d_v one::

    L_i = H - K_c (K_c + mu I)^{-1} = mu (K_c + mu I)^{-1} - 1 1^T / k

which :func:`local_regression_blocks` computes for all N points at once (one batched
k x k inverse). Eq. 5.16 sums the blocks into the N x N view Laplacian
``L^(v) = sum_i S_i L_i S_i^T`` (:func:`local_regression_laplacian`, sparse).

Trace-ratio selection with view weights (eqs. 5.20-5.24)
--------------------------------------------------------
With ``W`` a 0/1 selection of d features, ``tr(W^T A W)`` is the sum of ``A``'s diagonal
over the selected features, so only ``a_j = f_j^T (sum_v alpha_v^r L^(v)) f_j`` and
``b_j = f_j^T H_N f_j`` (N times the variance of feature j) are needed: the objective
(5.22) is ``lambda = sum_S a_j / sum_S b_j``. Algorithm 4 alternates
``lambda <- ratio(S)`` and ``S <- d features by score a_j - lambda b_j``; Algorithm 5 sets
``alpha_v = f_v / sum f``, ``f_v = tr(W^T X L^(v) X^T W)^{-1/(r-1)}`` (eq. 5.24); the two
alternate until the selection and alpha stop changing.

**Misprint (``../shared/specs/METHODS.md`` Sec. 4).** Algorithm 4 step 5 says "sort in
descent order, keep the first d". For the *minimisation* (5.22) the d *smallest* scores
must be kept (then lambda decreases monotonically: the Dinkelbach / Nie et al. 2008
trace-ratio iteration); ``order='ascending'`` (default) does that, ``'descending'``
reproduces the printed step (it climbs to the largest ratio). Both are reported by the
``amfs-retrieval`` protocol.

Baselines (Sec. 5.3.1)
----------------------
* :func:`laplacian_score` -- He, Cai & Niyogi 2005 (kNN heat-kernel graph; smaller better).
* :func:`spec_score` -- Zhao & Liu 2007 SPEC, spectrum-based score phi_3 (larger better).
* :func:`udfs_score` -- Yang, Shen, Ma, Huang & Zhou 2011 UDFS: ``min tr(W^T M W) +
  gamma ||W||_{2,1}``, ``W^T W = I``, M from local discriminative scatter; iteratively
  reweighted eigenproblem; score = row norms of W (larger better).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from ..errors import MocapValueError

__all__ = ["knn_indices", "local_regression_blocks", "local_regression_laplacian",
           "feature_quadratic", "global_scatter", "trace_ratio_select", "alpha_update",
           "AMFS", "laplacian_score", "spec_score", "udfs_score", "select_top"]


def _as_rows(F) -> np.ndarray:
    F = np.asarray(F, dtype=np.float64)
    if F.ndim != 2 or F.shape[0] < 2:
        raise MocapValueError(f"features must be an (N, D) array with N >= 2, got shape {F.shape}")
    if not np.isfinite(F).all():
        raise MocapValueError("features contain NaN or infinite values")
    return F


def _sq_dists(F: np.ndarray) -> np.ndarray:
    n = (F ** 2).sum(1)
    return np.maximum(n[:, None] - 2.0 * F @ F.T + n[None, :], 0.0)


def knn_indices(F: np.ndarray, k: int) -> np.ndarray:
    """(N, k) indices of each sample and its k-1 nearest neighbours (Euclidean), self first."""
    F = _as_rows(F)
    N = F.shape[0]
    k = int(min(max(int(k), 1), N))
    D2 = _sq_dists(F)
    D2[np.arange(N), np.arange(N)] = -1.0                      # self first, always
    idx = np.argpartition(D2, k - 1, axis=1)[:, :k]
    order = np.argsort(np.take_along_axis(D2, idx, axis=1), axis=1, kind="stable")
    return np.take_along_axis(idx, order, axis=1)


def local_regression_blocks(F: np.ndarray, idx: np.ndarray, mu: float) -> np.ndarray:
    """The N local matrices L_i (eq. 5.14), (N, k, k), one batched k x k inverse.

    ``F`` (N, d) samples of one view; ``idx`` (N, k) neighbourhoods (:func:`knn_indices`);
    ``mu`` > 0 the ridge of eq. 5.5.
    """
    F = np.asarray(F, dtype=np.float64)
    idx = np.asarray(idx, dtype=np.int64)
    if mu <= 0:
        raise MocapValueError(f"mu must be > 0, got {mu}")
    N, k = idx.shape
    out = np.empty((N, k, k))
    H = np.eye(k) - 1.0 / k
    step = max(1, int(2e7 // max(k * F.shape[1], 1)))
    for s in range(0, N, step):
        Xi = F[idx[s:s + step]]                                    # (n, k, d)
        G = Xi @ np.swapaxes(Xi, 1, 2)                             # (n, k, k)
        Kc = H @ G @ H
        Kc[:, np.arange(k), np.arange(k)] += mu
        out[s:s + step] = mu * np.linalg.inv(Kc) - 1.0 / k
    return 0.5 * (out + np.swapaxes(out, 1, 2))


def _assemble(blocks: np.ndarray, idx: np.ndarray, N: int) -> sp.csr_matrix:
    """sum_i S_i B_i S_i^T (eq. 5.16) as a sparse N x N matrix."""
    n, k, _ = blocks.shape
    rows = np.broadcast_to(idx[:, :, None], (n, k, k)).ravel()
    cols = np.broadcast_to(idx[:, None, :], (n, k, k)).ravel()
    return sp.coo_matrix((blocks.ravel(), (rows, cols)), shape=(N, N)).tocsr()


def local_regression_laplacian(F, k: int = 10, mu: float = 0.1) -> sp.csr_matrix:
    """View Laplacian L^(v) (eq. 5.16), sparse (N, N), from the view's features (N, d_v)."""
    F = _as_rows(F)
    idx = knn_indices(F, k)
    return _assemble(local_regression_blocks(F, idx, mu), idx, F.shape[0])


def feature_quadratic(F: np.ndarray, L) -> np.ndarray:
    """``diag(X L X^T)`` = ``f_j^T L f_j`` for every feature column j: (D,)."""
    F = np.asarray(F, dtype=np.float64)
    return np.einsum("nd,nd->d", F, np.asarray(L @ F))


def global_scatter(F: np.ndarray) -> np.ndarray:
    """``diag(X H_N X^T)`` (eq. 5.21): N times each feature's variance, (D,)."""
    F = np.asarray(F, dtype=np.float64)
    C = F - F.mean(axis=0)
    return (C ** 2).sum(axis=0)


def trace_ratio_select(a: np.ndarray, b: np.ndarray, d: int, *, order: str = "ascending",
                       init: np.ndarray | None = None, max_iter: int = 100,
                       seed: int = 0) -> tuple[np.ndarray, float, int]:
    """Algorithm 4 for fixed weights: the d features of ``W`` for ``min sum_S a / sum_S b``.

    Parameters
    ----------
    a, b : (D,) diagonals of A = X L X^T and B = X H X^T (b >= 0).
    d : number of features to select.
    order : ``'ascending'`` keeps the d smallest scores ``a - lambda b`` (the misprint
        fix), ``'descending'`` the d largest (Algorithm 4 as printed).
    init : initial selection (default: d random features, as the thesis).

    Returns
    -------
    (selected indices sorted by score, final lambda, iterations).
    Features with b = 0 (constant over the samples) are never selected.
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    D = a.shape[0]
    if order not in ("ascending", "descending"):
        raise MocapValueError(f"order must be 'ascending' or 'descending', got {order!r}")
    valid = b > 1e-12 * max(float(b.max(initial=0.0)), 1e-300)
    nv = int(valid.sum())
    d = int(d)
    if not 1 <= d <= nv:
        raise MocapValueError(f"d must be between 1 and {nv} (non-constant features), got {d}")
    if init is None:
        init = np.random.default_rng(seed).choice(np.flatnonzero(valid), d, replace=False)
    sel = np.asarray(init, dtype=np.int64)
    bad = np.inf if order == "ascending" else -np.inf
    lam = float(a[sel].sum() / max(b[sel].sum(), 1e-300))
    it = 0
    for it in range(1, max_iter + 1):
        sc = np.where(valid, a - lam * b, bad)
        if order == "ascending":
            new = np.argsort(sc, kind="stable")[:d]
        else:
            new = np.argsort(-sc, kind="stable")[:d]
        lam_new = float(a[new].sum() / max(b[new].sum(), 1e-300))
        same = set(new.tolist()) == set(sel.tolist())
        sel, lam = new, lam_new
        if same:
            break
    return sel, lam, it


def alpha_update(traces: Sequence[float], r: float) -> np.ndarray:
    """Eq. 5.24 / Algorithm 5: ``alpha_v = t_v^{-1/(r-1)} / sum_u t_u^{-1/(r-1)}`` (r > 1).

    ``traces`` are ``tr(W^T X L^(v) X^T W)`` per view (>= 0); a zero trace takes all the
    weight (shared equally with other zero traces).
    """
    t = np.asarray(traces, dtype=np.float64)
    if r <= 1:
        raise MocapValueError(f"r must be > 1, got {r}")
    if (t < 0).any() and (t < -1e-9 * np.abs(t).max()).any():
        raise MocapValueError(f"view traces must be non-negative, got {t}")
    t = np.maximum(t, 0.0)
    zero = t <= 1e-300
    if zero.any():
        return zero / zero.sum()
    # work in logs: t^(-1/(r-1)) for very different traces
    lf = -np.log(t) / (r - 1.0)
    f = np.exp(lf - lf.max())
    return f / f.sum()


@dataclass
class AMFS:
    """Adaptive multi-view feature selection (module doc; eq. 5.22, Algorithms 4 + 5).

    Parameters
    ----------
    d : features to keep.
    k : neighbourhood size of the local regressions (the sample and k-1 neighbours).
    mu : ridge of the local regressions (thesis tests 0.01-0.5).
    r : view-weight exponent (> 1; thesis tests 2-16).
    order : ``'ascending'`` (misprint fixed) or ``'descending'`` (as printed).
    max_iter : outer W/alpha alternations (the thesis: converges within 20).
    seed : random initial selection.

    Fitted attributes: ``selected_`` (d,) column indices of the concatenated views,
    ``alpha_`` (M,), ``objective_`` list of lambda per outer iteration, ``n_iter_``,
    ``view_slices_`` list of (start, stop).
    """

    d: int = 100
    k: int = 10
    mu: float = 0.1
    r: float = 4.0
    order: str = "ascending"
    max_iter: int = 30
    seed: int = 0
    selected_: np.ndarray | None = field(default=None, init=False)
    alpha_: np.ndarray | None = field(default=None, init=False)
    objective_: list = field(default_factory=list, init=False)
    n_iter_: int = field(default=0, init=False)
    view_slices_: list = field(default_factory=list, init=False)

    def fit(self, views: Sequence[np.ndarray], laplacians: Sequence | None = None) -> "AMFS":
        """Fit on M views, each (N, d_v) (same N); ``laplacians`` may pass precomputed L^(v)."""
        views = [_as_rows(V) for V in views]
        if not views:
            raise MocapValueError("AMFS needs at least one view")
        N = views[0].shape[0]
        if any(V.shape[0] != N for V in views):
            raise MocapValueError(f"all views need the same samples, got {[V.shape for V in views]}")
        F = np.concatenate(views, axis=1)
        stops = np.cumsum([V.shape[1] for V in views])
        self.view_slices_ = [(int(s - V.shape[1]), int(s)) for s, V in zip(stops, views)]
        if laplacians is None:
            laplacians = [local_regression_laplacian(V, self.k, self.mu) for V in views]
        a_v = np.stack([feature_quadratic(F, L) for L in laplacians])   # (M, D)
        b = global_scatter(F)
        return self.fit_diagonals(a_v, b)

    def fit_diagonals(self, a_v: np.ndarray, b: np.ndarray) -> "AMFS":
        """Fit from the per-view diagonals ``a_v`` (M, D) and ``b`` (D,) (see module doc)."""
        M = a_v.shape[0]
        alpha = np.full(M, 1.0 / M)
        sel = None
        self.objective_ = []
        it = 0
        for it in range(1, self.max_iter + 1):
            A = (alpha ** self.r) @ a_v
            sel, lam, _ = trace_ratio_select(A, b, self.d, order=self.order, init=sel,
                                             seed=self.seed)
            new_alpha = alpha_update(a_v[:, sel].sum(axis=1), self.r)
            A = (new_alpha ** self.r) @ a_v
            self.objective_.append(float(A[sel].sum() / b[sel].sum()))
            done = np.allclose(new_alpha, alpha, atol=1e-6, rtol=0)
            alpha = new_alpha
            if done and it > 1:
                break
        self.selected_ = np.asarray(sel)
        self.alpha_ = alpha
        self.n_iter_ = it
        return self

    def transform(self, F: np.ndarray) -> np.ndarray:
        if self.selected_ is None:
            from ..errors import NotFittedError

            raise NotFittedError("AMFS is not fitted")
        return np.asarray(F)[..., self.selected_]


# --------------------------------------------------------------------------- baselines
def _heat_graph(F: np.ndarray, k: int = 5) -> sp.csr_matrix:
    """Symmetric kNN graph with heat-kernel weights exp(-|xi-xj|^2 / t), t = mean kNN d^2."""
    N = F.shape[0]
    idx = knn_indices(F, k + 1)[:, 1:]
    D2 = _sq_dists(F)
    d2 = np.take_along_axis(D2, idx, axis=1)
    t = float(d2.mean()) if d2.size and d2.mean() > 0 else 1.0
    W = sp.coo_matrix((np.exp(-d2 / t).ravel(), (np.repeat(np.arange(N), idx.shape[1]), idx.ravel())),
                      shape=(N, N)).tocsr()
    return W.maximum(W.T).tocsr()


def laplacian_score(F, k: int = 5) -> np.ndarray:
    """Laplacian score of every feature (He et al. 2005, eq. in Sec. 3); smaller = better."""
    F = _as_rows(F)
    S = _heat_graph(F, k)
    deg = np.asarray(S.sum(axis=1)).ravel()
    L = sp.diags(deg) - S
    mean = (deg @ F) / deg.sum()
    Ft = F - mean
    num = feature_quadratic(Ft, L)
    den = np.einsum("nd,n,nd->d", Ft, deg, Ft)
    return np.where(den > 1e-300, num / np.maximum(den, 1e-300), np.inf)


def spec_score(F, n_clusters: int = 10, *, k: int = 5) -> np.ndarray:
    """SPEC feature ranking phi_3 (Zhao & Liu 2007, Sec. 3.2); larger = better.

    ``phi_3(f) = sum_{j=2}^{kappa} (2 - lambda_j) (f^_T xi_j)^2`` with (lambda_j, xi_j) the
    eigenpairs of the normalised Laplacian of the kNN heat-kernel graph (ascending),
    ``f^ = D^{1/2} f / ||D^{1/2} f||`` and kappa = ``n_clusters``. (SPEC's phi_2 is
    algebraically the Laplacian score, so phi_3 is the variant that adds something.)
    """
    F = _as_rows(F)
    N = F.shape[0]
    S = _heat_graph(F, k)
    deg = np.asarray(S.sum(axis=1)).ravel()
    dh = np.sqrt(deg)
    Ln = np.eye(N) - (S.toarray() / dh[:, None]) / dh[None, :]
    lam, xi = np.linalg.eigh(0.5 * (Ln + Ln.T))
    kap = int(min(max(n_clusters, 2), N))
    Fh = dh[:, None] * F
    nrm = np.linalg.norm(Fh, axis=0)
    Fh = np.divide(Fh, nrm, out=np.zeros_like(Fh), where=nrm > 0)
    proj = xi[:, 1:kap].T @ Fh                                   # (kappa-1, D)
    return ((2.0 - lam[1:kap])[:, None] * proj ** 2).sum(axis=0)


def udfs_score(F, n_clusters: int = 10, *, k: int = 5, gamma: float = 0.01, lam: float = 1.0,
               n_iter: int = 15) -> np.ndarray:
    """UDFS (Yang et al. 2011, Algorithm 1) feature scores ||w_j||; larger = better.

    ``M = X (sum_i S_i H (X~_i^T X~_i + lam I)^{-1} H S_i^T) X^T`` with X~_i the centred
    neighbourhood (k + 1 points); then ``D = I`` and repeat: ``W`` = the c = ``n_clusters``
    eigenvectors of ``M + gamma D`` with the smallest eigenvalues, ``D_jj = 1 / (2 ||w_j||)``.
    ``gamma`` and ``lam`` are relative to the mean of diag(M) and of the local Gram
    diagonals (scale-free). M has rank <= N, so with ``M = U^T U`` (U: N x D) the
    eigenvectors come from Lanczos on ``(M + gamma D)^{-1}`` applied by the Woodbury
    identity: O(N D) per product, no D x D matrix.
    """
    from scipy.sparse.linalg import LinearOperator, eigsh

    F = _as_rows(F)
    N, D = F.shape
    c = int(min(max(n_clusters, 1), D - 1))
    idx = knn_indices(F, k + 1)
    kk = idx.shape[1]
    H = np.eye(kk) - 1.0 / kk
    Xi = F[idx]
    G = H @ (Xi @ np.swapaxes(Xi, 1, 2)) @ H
    lam_abs = lam * max(float(np.trace(G, axis1=1, axis2=2).mean() / kk), 1e-12)
    G[:, np.arange(kk), np.arange(kk)] += lam_abs
    B = H @ np.linalg.inv(G) @ H
    Lu = _assemble(0.5 * (B + np.swapaxes(B, 1, 2)), idx, N).toarray()
    ev, Q = np.linalg.eigh(0.5 * (Lu + Lu.T))
    U = np.sqrt(np.maximum(ev, 0.0))[:, None] * (Q.T @ F)          # M = U^T U
    g = gamma * max(float((U ** 2).sum() / D), 1e-12)               # gamma * mean diag(M)
    Dg = np.ones(D)
    W = None
    rng = np.random.default_rng(0)
    for _ in range(int(n_iter)):
        pinv = 1.0 / (g * Dg)
        Up = U * pinv[None, :]
        C = np.linalg.inv(np.eye(N) + Up @ U.T)

        def mv(x, pinv=pinv, Up=Up, C=C):
            x = np.asarray(x).reshape(-1)
            return pinv * x - Up.T @ (C @ (Up @ x))

        op = LinearOperator((D, D), matvec=mv, dtype=np.float64)
        v0 = W[:, 0] if W is not None else rng.standard_normal(D)
        _, W = eigsh(op, k=c, which="LA", v0=v0, tol=1e-6)
        rn = np.linalg.norm(W, axis=1)
        Dg = 1.0 / (2.0 * np.maximum(rn, 1e-8))
    return np.linalg.norm(W, axis=1)


def select_top(scores: np.ndarray, d: int, *, smallest: bool = True) -> np.ndarray:
    """Indices of the d best features by ``scores`` (non-finite scores last)."""
    s = np.asarray(scores, float)
    s = np.where(np.isfinite(s), s, np.inf if smallest else -np.inf)
    o = np.argsort(s if smallest else -s, kind="stable")
    return o[:int(d)]
