"""Locality-constrained linear coding (LLC), batched, with masks (thesis Ch. 3, eqs. 3.15-3.17).

Wang, Yang, Yu, Lv, Huang & Gong (2010), "Locality-constrained linear coding for image
classification", CVPR: eq. (3) (objective), eq. (4) and its closed form (analytical
solution), Sec. 3 "approximated LLC" (k nearest atoms).  Used by the thesis' PSC recovery
(seed 003, Sec. 3.4, eqs. 3.15-3.17) with masks: distances, the data covariance and the
fit use only the *observed* entries of each sample (``Omega-bar o Y`` and
``Omega-bar o D``), and the code reconstructs the full sample, missing entries included.

Shapes: samples are rows.  ``Y`` (N, d) samples, ``D`` (K, d) atoms (the thesis and Wang
et al. store both as columns), ``mask`` (N, d) bool (True = observed), codes ``W`` (N, K).

Objective per sample y (mask m, locality adaptor g >= 0)::

    min_c  || m o (y - D^T c) ||^2 + lam * sum_k g_k c_k^2     s.t.  1^T c = 1

With ``1^T c = 1``: ``y - D^T c = (y 1^T - D^T) c``, so the fit is ``c^T Cov c`` with the
masked data covariance ``Cov = (m o (D^T - y 1^T))^T (m o (D^T - y 1^T))`` (K x K), and the
solution is the closed form of eq. 3.17 / Wang et al.::

    c~ = (Cov + lam diag(g)) \\ 1,    c = c~ / (1^T c~)

(eq. 3.17 prints ``diag(G)``; it minimises the penalty ``lam sum g_k c_k^2`` written above,
i.e. ``lam ||sqrt(g) o c||^2`` -- we state the objective that the printed closed form
solves.)  The locality adaptor is ``g = exp((dist - max dist) / sigma)`` in (0, 1]
(eq. 3.16, normalised to (0, 1] as the thesis says), dist = masked Euclidean distance from
y to each atom.  A tiny ridge ``eps * trace(Cov) I`` keeps the system regular (Wang et al.'s
code uses 1e-4).
"""
from __future__ import annotations

import numpy as np

from ..errors import MocapValueError
from . import _linalg

__all__ = ["masked_sq_distances", "locality_adaptor", "llc_code", "dense_codes", "llc_reconstruct"]


def masked_sq_distances(Y: np.ndarray, D: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Squared Euclidean distances over observed entries: (N, K).

    ``out[i, k] = sum_j mask[i, j] (Y[i, j] - D[k, j])^2``; three matrix products, no
    (N, K, d) temporary.
    """
    Y = np.asarray(Y, dtype=np.float64)
    D = np.asarray(D, dtype=np.float64)
    if mask is None:
        d2 = (Y ** 2).sum(1)[:, None] - 2.0 * Y @ D.T + (D ** 2).sum(1)[None, :]
    else:
        mk = np.asarray(mask, dtype=np.float64)
        Ym = np.where(mask, Y, 0.0)
        d2 = (Ym ** 2).sum(1)[:, None] - 2.0 * Ym @ D.T + mk @ (D ** 2).T
    return np.maximum(d2, 0.0)


def locality_adaptor(dist: np.ndarray, sigma: float | np.ndarray | None = None) -> np.ndarray:
    """g = exp((dist - max dist) / sigma) per row, in (0, 1] (thesis eq. 3.16).

    ``dist`` (N, K) Euclidean distances; ``sigma`` scalar, per-row (N,) or None (= the mean
    distance of each row, our default: the thesis and Wang et al. leave sigma open).
    """
    dist = np.asarray(dist, dtype=np.float64)
    if sigma is None:
        sigma = dist.mean(axis=1)
    sigma = np.asarray(sigma, dtype=np.float64)
    if sigma.ndim == 0:
        sigma = np.full(dist.shape[0], float(sigma))
    sigma = np.where(sigma > 0, sigma, 1.0)[:, None]
    return np.exp((dist - dist.max(axis=1, keepdims=True)) / sigma)


@_linalg.one_blas_thread
def llc_code(Y: np.ndarray, D: np.ndarray, mask: np.ndarray | None = None, *, lam: float = 10.0,
             sigma: float | None = None, n_neighbors: int | None = None, eps: float = 1e-4,
             chunk: int = 4096) -> tuple[np.ndarray, np.ndarray]:
    """LLC codes of every sample (closed form, optionally on the k nearest atoms).

    Parameters
    ----------
    Y : (N, d) samples; D : (K, d) atoms; mask : optional (N, d) bool, True = observed.
    lam : locality weight (thesis: 10).
    sigma : locality-adaptor scale (None = per-sample mean distance).
    n_neighbors : None = all K atoms (exact closed form, O(K^3) per sample); k = solve on
        the k nearest atoms only (Wang et al.'s approximated LLC; the other codes are 0).
    eps : ridge ``eps * trace(Cov)`` added to the diagonal.
    chunk : samples per batched solve (bounds memory: chunk * k * (k + d) floats).

    Returns
    -------
    codes : (N, k) coefficients of the atoms used, each row sums to 1;
    idx : (N, k) indices of those atoms (``dense_codes`` makes the (N, K) matrix).
    """
    Y = np.asarray(Y, dtype=np.float64)
    D = np.asarray(D, dtype=np.float64)
    if Y.ndim != 2 or D.ndim != 2 or Y.shape[1] != D.shape[1]:
        raise MocapValueError(f"Y (N, d) and D (K, d) must share d; got {Y.shape} and {D.shape}")
    N, d = Y.shape
    K = D.shape[0]
    if K < 1:
        raise MocapValueError("the dictionary has no atoms")
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != Y.shape:
            raise MocapValueError(f"mask must have shape {Y.shape}, got {mask.shape}")
    Yz = Y if mask is None else np.where(mask, Y, 0.0)
    if not np.isfinite(Yz).all():
        raise MocapValueError("Y has non-finite observed entries")
    k = K if n_neighbors is None else int(min(max(int(n_neighbors), 1), K))
    codes = np.empty((N, k))
    idx_all = np.empty((N, k), dtype=np.int64)
    for s in range(0, N, int(chunk)):
        e = min(N, s + int(chunk))
        y = Yz[s:e]
        mk = None if mask is None else mask[s:e]
        d2 = masked_sq_distances(y, D, mk)
        if k < K:
            idx = np.argpartition(d2, k - 1, axis=1)[:, :k]
        else:
            idx = np.broadcast_to(np.arange(K), (e - s, K))
        dist = np.sqrt(np.take_along_axis(d2, idx, axis=1))
        g = locality_adaptor(dist, sigma)
        Z = D[idx] - y[:, None, :]                                  # (n, k, d)
        if mk is not None:
            Z = Z * mk[:, None, :]
        Cov = Z @ np.swapaxes(Z, 1, 2)                               # (n, k, k)
        tr = np.trace(Cov, axis1=1, axis2=2)
        ridge = eps * np.where(tr > 0, tr, 1.0)
        diag = lam * g + ridge[:, None]
        Cov[:, np.arange(k), np.arange(k)] += diag
        c = np.linalg.solve(Cov, np.ones((e - s, k, 1)))[..., 0]
        ssum = c.sum(axis=1, keepdims=True)
        bad = ~np.isfinite(ssum[:, 0]) | (np.abs(ssum[:, 0]) < 1e-300)
        if bad.any():                                               # degenerate: nearest atom
            c[bad] = 0.0
            c[bad, np.argmin(dist[bad], axis=1)] = 1.0
            ssum[bad] = 1.0
        c = c / ssum
        codes[s:e] = c
        idx_all[s:e] = idx
    return codes, idx_all


def dense_codes(codes: np.ndarray, idx: np.ndarray, K: int) -> np.ndarray:
    """(N, K) code matrix from the compact (codes, idx) form of :func:`llc_code`."""
    W = np.zeros((codes.shape[0], int(K)))
    np.put_along_axis(W, idx, codes, axis=1)
    return W


def llc_reconstruct(codes: np.ndarray, idx: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Reconstructed samples ``sum_j codes[:, j] D[idx[:, j]]`` (N, d)."""
    return np.einsum("nk,nkd->nd", codes, np.asarray(D)[idx])
