"""Array plumbing shared by the :mod:`mocapkit.signal` modules: time axis to the front,
channels flattened, and the complete-data check."""
from __future__ import annotations

import numpy as np

from ..errors import MocapValueError


def as_2d(X, axis: int) -> tuple[np.ndarray, tuple[int, ...], int]:
    """Move ``axis`` to the front and flatten the rest: (T, C) float copy + restore info."""
    A = np.asarray(X, dtype=np.float64)
    if A.ndim == 0:
        raise MocapValueError("expected an array with a time axis, got a scalar")
    axis = axis % A.ndim
    A = np.moveaxis(A, axis, 0)
    shape = A.shape
    return np.array(A.reshape(shape[0], -1), dtype=np.float64, copy=True), shape, axis




def restore(Y: np.ndarray, shape: tuple[int, ...], axis: int) -> np.ndarray:
    return np.moveaxis(Y.reshape(shape), 0, axis)



def require_finite(A: np.ndarray, what: str) -> None:
    if not np.isfinite(A).all():
        n = int((~np.isfinite(A)).sum())
        raise MocapValueError(
            f"{what} needs complete data but the input has {n} missing (non-finite) values; "
            f"fill the gaps first (mocapkit.gaps.fill)")
