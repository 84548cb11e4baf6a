"""Array plumbing shared by the :mod:`mocapkit.signal` modules: time axis to the front,
channels flattened, and the complete-data check."""
from __future__ import annotations

import warnings

import numpy as np

from ..errors import MocapValueError


def as_2d(X, axis: int) -> tuple[np.ndarray, tuple[int, ...], int]:
    """Move ``axis`` to the front and flatten the rest: (T, C) float copy + restore info."""
    A, shape, axis = as_2d_view(X, axis)
    return np.array(A, dtype=np.float64, copy=True), shape, axis


def as_2d_view(X, axis: int) -> tuple[np.ndarray, tuple[int, ...], int]:
    """:func:`as_2d` without the copy: a (T, C) float64 *view* of ``X`` where its layout
    allows (a (T, 3J) motion matrix always does), for code that only reads it -- on a long
    clip the copy is one more matrix in memory (issue 21)."""
    A = np.asarray(X, dtype=np.float64)
    if A.ndim == 0:
        raise MocapValueError("expected an array with a time axis, got a scalar")
    axis = axis % A.ndim
    A = np.moveaxis(A, axis, 0)
    shape = A.shape
    return A.reshape(shape[0], -1), shape, axis


#: channels per call of :func:`by_channel_blocks`
CHANNEL_BLOCK = 16


def channel_blocks(n_channels: int, block: int = CHANNEL_BLOCK) -> list[slice]:
    """Slices of consecutive channels, ``block`` at a time (the last one shorter): the
    blocks of :func:`by_channel_blocks`, for per-channel code whose results are not one
    (T, C) array (per-channel statistics, in-place updates)."""
    return [slice(c, min(c + block, n_channels)) for c in range(0, n_channels, block)]


def by_channel_blocks(func, A: np.ndarray, out: np.ndarray | None = None,
                      block: int = CHANNEL_BLOCK) -> np.ndarray:
    """``func`` (a filter along the last axis of a (c, T) array, returning (c, T)) applied
    to the (T, C) array ``A`` channel block by channel block, on the transposed layout;
    returns (T, C) C-contiguous (``out`` when given, which may be ``A`` itself: each block
    is read before it is written).

    Why: scipy's recursive filters on one long (T, C) array slow down far more than the
    data grows once it leaves the cache -- ``sosfiltfilt`` on 100,000 x 93 frames took 37x
    the time of 10,000 frames; blocks of 16 time-contiguous channels took 0.29 s against
    0.85-1.04 s for the whole array, the same numbers.  Memory: only one block is
    transposed at a time and the results go straight into the output, so the call needs
    ``A``, the output and a few blocks (a whole transposed copy and its filtered copy were
    two more matrices at 100,000 frames).  ``block``: channels per block (a filter whose
    per-channel work makes several arrays of the series' length may want fewer)."""
    T, C = A.shape
    if out is None:
        out = np.empty((T, C), dtype=A.dtype)
    for sl in channel_blocks(C, block):                              # blocks of channels, not frames
        out[:, sl] = func(np.ascontiguousarray(A[:, sl].T)).T
    return out


def restore(Y: np.ndarray, shape: tuple[int, ...], axis: int) -> np.ndarray:
    return np.moveaxis(Y.reshape(shape), 0, axis)



def require_finite(A: np.ndarray, what: str) -> None:
    if not np.isfinite(A).all():
        n = int((~np.isfinite(A)).sum())
        raise MocapValueError(
            f"{what} needs complete data but the input has {n} missing (non-finite) values; "
            f"fill the gaps first (mocapkit.gaps.fill)")


#: columns longer than this go to numpy's own ``nanmedian`` in :func:`nanmedian0`
NANMEDIAN_SORT_MAX = 2048


def nanmedian0(A: np.ndarray) -> np.ndarray:
    """``np.nanmedian(A, axis=0)`` (NaN where a column has no finite value, no warning),
    the same numbers, by one sort for columns of up to :data:`NANMEDIAN_SORT_MAX` values:
    NaN sort last, so the median of the n finite values of a column sits at rows
    (n - 1) // 2 and n // 2. numpy's own took 3x longer on the (960, 31, 31) pairwise
    distances of :func:`mocapkit.rigid.rigid_partners` (72 vs 21 ms), and under 600
    values a column it goes through masked arrays (``auto`` on a 240-frame clip: ~2 ms
    in 4 calls); on long columns its partition wins (10,000 x 93 with NaN: 47 vs 124 ms)
    and is used.

    >>> A = np.array([[1.0, np.nan], [3.0, 2.0], [2.0, np.nan], [np.nan, np.nan]])
    >>> nanmedian0(A)
    array([2., 2.])
    """
    A = np.asarray(A, dtype=np.float64)
    if A.shape[0] == 0:
        return np.full(A.shape[1:], np.nan)
    if A.shape[0] > NANMEDIAN_SORT_MAX:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)           # all-NaN columns -> NaN
            return np.nanmedian(A, axis=0)
    S = np.sort(A, axis=0)
    n = np.isfinite(A).sum(axis=0)
    lo = np.take_along_axis(S, np.maximum((n - 1) // 2, 0)[None], axis=0)[0]
    hi = np.take_along_axis(S, np.maximum(n // 2, 0)[None], axis=0)[0]
    with np.errstate(invalid="ignore"):
        return np.where(n > 0, 0.5 * (lo + hi), np.nan)
