"""SVD and symmetric eigendecomposition that never end in a raw ``LinAlgError``.

LAPACK's divide-and-conquer drivers (``gesdd`` behind :func:`numpy.linalg.svd`, ``syevd``
behind :func:`numpy.linalg.eigh`) occasionally fail to converge on matrices that are
valid but badly scaled or nearly degenerate (e.g. a frames x coordinates matrix with many
missing markers and repeated columns).  Every solver of :mod:`mocapkit.solvers` calls the
functions below instead, which try in turn:

1. numpy (fast path, batched over leading axes);
2. scipy with the slower but more robust driver -- ``gesvd`` (QR iteration) for the SVD,
   ``syev`` (``driver="ev"``) for ``eigh`` -- one matrix at a time;
3. the same after a tiny perturbation: a ridge ``1e-12 * trace / n`` on the diagonal of a
   symmetric matrix, or ``1e-12 * ||M||_max`` added to the diagonal of a rectangular one
   (it moves singular values by ~1e-12 relative, far below any tolerance used here).

A matrix with non-finite entries cannot be decomposed at all: that is a diverged or
corrupted computation upstream, reported as :class:`~mocapkit.errors.MocapValueError`
with the caller's name, never as a numpy traceback.
"""
from __future__ import annotations

import numpy as np

from ..errors import MocapValueError

__all__ = ["svd", "eigh", "eigvalsh"]

_JITTER = 1e-12


def _check_finite(M: np.ndarray, what: str) -> None:
    if not np.isfinite(M).all():
        raise MocapValueError(
            f"{what}: the matrix to decompose has {int((~np.isfinite(M)).sum())} non-finite "
            f"entries (the solver diverged or was given NaN/inf)")


def _per_matrix(func, M: np.ndarray):
    """Apply ``func`` to each matrix of a stack (..., m, n) and stack the outputs."""
    lead = M.shape[:-2]
    flat = M.reshape((-1,) + M.shape[-2:])
    outs = [func(A) for A in flat]
    if isinstance(outs[0], tuple):
        return tuple(np.stack([o[i] for o in outs]).reshape(lead + outs[0][i].shape)
                     for i in range(len(outs[0])))
    return np.stack(outs).reshape(lead + outs[0].shape)


def _diag_jitter(M: np.ndarray, symmetric: bool) -> np.ndarray:
    m, n = M.shape
    k = min(m, n)
    if symmetric:
        scale = float(np.abs(np.trace(M))) / max(n, 1)
    else:
        scale = float(np.abs(M).max()) if M.size else 0.0
    J = M.copy()
    J[np.arange(k), np.arange(k)] += _JITTER * (scale if scale > 0 else 1.0)
    return J


def svd(M: np.ndarray, full_matrices: bool = False, compute_uv: bool = True,
        what: str = "svd"):
    """:func:`numpy.linalg.svd` with the fallbacks of the module docstring."""
    M = np.asarray(M, dtype=np.float64)
    try:
        return np.linalg.svd(M, full_matrices=full_matrices, compute_uv=compute_uv)
    except np.linalg.LinAlgError:
        pass
    _check_finite(M, what)
    import scipy.linalg as sla

    def one(A: np.ndarray):
        for B in (A, _diag_jitter(A, False)):
            for driver in ("gesvd", "gesdd"):
                try:
                    return sla.svd(B, full_matrices=full_matrices, compute_uv=compute_uv,
                                   lapack_driver=driver, check_finite=False)
                except (np.linalg.LinAlgError, ValueError):
                    continue
        raise MocapValueError(f"{what}: the singular value decomposition did not converge "
                              f"with any LAPACK driver (matrix {A.shape})")

    if M.ndim == 2:
        return one(M)
    return _per_matrix(one, M)


def eigh(G: np.ndarray, what: str = "eigh") -> tuple[np.ndarray, np.ndarray]:
    """:func:`numpy.linalg.eigh` (ascending eigenvalues) with the module's fallbacks."""
    G = np.asarray(G, dtype=np.float64)
    try:
        return np.linalg.eigh(G)
    except np.linalg.LinAlgError:
        pass
    _check_finite(G, what)
    import scipy.linalg as sla

    def one(A: np.ndarray):
        A = 0.5 * (A + A.T)
        for B in (A, _diag_jitter(A, True)):
            for driver in ("ev", "evr"):
                try:
                    return sla.eigh(B, driver=driver, check_finite=False)
                except (np.linalg.LinAlgError, ValueError):
                    continue
        # last resort: the SVD of a symmetric matrix gives |eigenvalues| and vectors; for
        # the PSD Gram matrices the solvers decompose this is the eigendecomposition
        U, s, _ = svd(A, what=what)
        order = np.argsort(s)
        return s[order], U[:, order]

    if G.ndim == 2:
        return one(G)
    return _per_matrix(one, G)


def eigvalsh(G: np.ndarray, what: str = "eigvalsh") -> np.ndarray:
    """:func:`numpy.linalg.eigvalsh` (ascending) with the module's fallbacks."""
    G = np.asarray(G, dtype=np.float64)
    try:
        return np.linalg.eigvalsh(G)
    except np.linalg.LinAlgError:
        return eigh(G, what=what)[0]
