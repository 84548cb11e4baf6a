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

The module also holds the two other contracts every array solver shares: the input
checks (:func:`prepare`) and the BLAS thread limit (:func:`one_blas_thread`,
:func:`blas_limit`).
"""
from __future__ import annotations

import contextlib
import functools
from typing import Any, Callable

import numpy as np

from ..errors import MocapValueError

__all__ = ["svd", "eigh", "eigvalsh", "prepare", "one_blas_thread", "blas_limit"]

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


# --------------------------------------------------------------------------------------
# the input contract of the array solvers
# --------------------------------------------------------------------------------------
def prepare(X: Any, mask: Any = None, *, name: str = "X", batch: bool = False,
            full_mask: bool = True, copy: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """Validated float64 copy of a (frames x coordinates) matrix with its unobserved
    entries set to 0, and the observed mask.

    ``copy=False``: X itself when it is already a float64 array (then it is written
    only where the mask hides entries): for callers that hand X over or only read it.

    ``mask`` : bool like X, True = observed; None = X is complete (a NaN then raises:
    a solver never guesses which entries are missing). ``batch=True`` also accepts a
    stack (B, T, C). ``full_mask=False`` returns None instead of an all-True mask (for
    solvers with a fast path for complete data).

    Raises MocapValueError (``name`` names the argument): not 2-D (3-D with ``batch``),
    empty, non-finite entries without a mask, a mask of another shape, non-finite
    entries marked as observed, or no observed entry at all.
    """
    X = np.array(X, dtype=np.float64, copy=True if copy else None)
    if X.ndim not in ((2, 3) if batch else (2,)):
        raise MocapValueError(f"{name} must be a 2-D matrix (frames x coordinates), got shape {X.shape}")
    if X.shape[-1] == 0 or X.shape[-2] == 0:
        raise MocapValueError(f"{name} is empty (shape {X.shape})")
    if mask is None:                     # complete: nothing to zero, no (m, n) mask unless asked
        if not np.isfinite(X).all():
            raise MocapValueError(
                f"{name} has {int((~np.isfinite(X)).sum())} non-finite entries but no mask; "
                f"pass mask= (True = observed) to treat them as missing")
        return X, (np.ones(X.shape, dtype=bool) if full_mask else None)
    m = np.asarray(mask)
    if m.shape != X.shape:
        raise MocapValueError(f"mask must have the shape of {name} {X.shape}, got {m.shape}")
    m = m.astype(bool)
    bad = m & ~np.isfinite(X)
    if bad.any():
        raise MocapValueError(f"{name} has {int(bad.sum())} non-finite entries marked as observed")
    if not m.any():
        raise MocapValueError(f"{name} has no observed entries")
    if not copy and not X.flags.writeable:
        X = X.copy()                     # hidden entries must be zeroed: never in a read-only input
    X[~m] = 0.0
    return X, (None if not full_mask and m.all() else m)


# --------------------------------------------------------------------------------------
# one BLAS thread
# --------------------------------------------------------------------------------------
_CONTROLLER: Any = None


def blas_limit() -> contextlib.AbstractContextManager:
    """Context limiting BLAS/LAPACK to one thread (a no-op without threadpoolctl).

    The solvers' products and decompositions are small (<= 93 x 93, or passes over a
    T x 93 matrix): a second BLAS thread gains < 15 %, while on 2 shared cores OpenBLAS's
    spinning threads made a 1-second solve take ~50 s and a 0.2 s one 4.5 s (measured).
    Results do not depend on it (one thread computes every entry either way).
    """
    global _CONTROLLER
    try:
        if _CONTROLLER is None:
            from threadpoolctl import ThreadpoolController

            _CONTROLLER = ThreadpoolController()
        return _CONTROLLER.limit(limits=1, user_api="blas")
    except ImportError:                                # pragma: no cover
        return contextlib.nullcontext()


def one_blas_thread(func: Callable) -> Callable:
    """Decorator: run ``func`` under :func:`blas_limit`."""
    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with blas_limit():
            return func(*args, **kwargs)
    return wrapper
