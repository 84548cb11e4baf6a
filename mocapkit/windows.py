"""Lagged windows of a time series and their overlap-add back to frames.

A clip X (T, C) -- T frames, C channels, e.g. the (T, 3J) matrix of a motion in cm -- is
cut into its S = T - M + 1 windows of M consecutive frames, stride 1; window s becomes
the row ``X[s:s+M].ravel()`` of an (S, M C) matrix, frame after frame (Xiao et al.'s
poselet groups, Sec. 3.1.3; the thesis' windows, Sec. 3.2; Lou & Chai's trajectory
matrix, eqs. 1-2, up to a column permutation; the Hankel matrix of multichannel SSA).
Going back, every frame is the sum (:func:`overlap_add`) or the mean
(:func:`overlap_mean`) of its copies in the windows that cover it; :func:`counts` says
how many do.

>>> X = np.arange(8.0).reshape(4, 2)
>>> lagged(X, 3)
array([[0., 1., 2., 3., 4., 5.],
       [2., 3., 4., 5., 6., 7.]])
>>> overlap_mean(lagged(X, 3), 4, 3)
array([[0., 1.],
       [2., 3.],
       [4., 5.],
       [6., 7.]])
"""
from __future__ import annotations

import numpy as np

from .errors import MocapValueError

__all__ = ["lagged", "counts", "window_starts", "spaced_frames", "overlap_add", "overlap_mean", "window_blocks",
           "overlap_add_into", "frame_blocks"]

#: frames per block where long-clip code passes over a (T, ...) array a piece at a time
#: (:func:`frame_blocks`): a few MB per 93-channel block, in cache, and no temporary of
#: the whole clip's size
FRAME_BLOCK = 8192

#: bytes of per-window work arrays allowed at once: windows are coded in blocks of about
#: this size (:func:`window_blocks`; issue 21: the window matrix of a whole 100k-frame clip
#: is ~20x the clip), so memory stays O(T d), not O(T M (d + K))
BLOCK_BYTES = 24 * 2 ** 20


def lagged(X, M: int, *, view: bool = False) -> np.ndarray:
    """Lagged windows (T, ...) -> (S, M * C), S = T - M + 1, C = prod(...), stride 1.

    Row s is ``[x_s, x_{s+1}, ..., x_{s+M-1}]``, each frame flattened (C-order), frame
    after frame. The dtype of X is kept (a boolean mask gives the windows' masks).
    ``view=True`` returns a read-only zero-copy strided view (M times less memory; rows
    overlap in memory), else a C-contiguous copy.

    Raises MocapValueError when T < M (no complete window).
    """
    A = np.asarray(X)
    M = int(M)
    if M < 1:
        raise MocapValueError(f"window length must be >= 1 frame, got {M}")
    T = A.shape[0]
    if T < M:
        raise MocapValueError(f"need at least {M} frames for windows of {M}, got {T}")
    A = np.ascontiguousarray(A.reshape(T, -1))
    C = A.shape[1]
    V = np.lib.stride_tricks.as_strided(A, shape=(T - M + 1, M * C),
                                        strides=(A.strides[0], A.itemsize), writeable=False)
    return V if view else V.copy()


def lagged_gram(X, M: int, side: str = "columns") -> np.ndarray:
    """The Gram matrix of ``H = lagged(X, M)`` (X (T, C) float) without forming H:
    ``H^T H`` (M C, M C) for ``side="columns"``, ``H H^T`` (S, S), S = T - M + 1, for
    ``side="rows"`` -- the smaller one is what a decomposition of H needs.

    Columns: block (i, j) (lags i, j; C x C) is ``X[i:i+S]^T X[j:j+S]``: the M blocks of
    the first block row are computed, and each next one from its upper-left neighbour by
    the window's sliding, ``G(i+1, j+1) = G(i, j) - x_i x_j^T + x_{i+S} x_{j+S}^T``: M
    products of C x S x C instead of the (M C)^2 S of ``H.T @ H`` (16 lags: 16x fewer flops).
    Rows: entry (s, u) is ``sum_l x_{s+l} . x_{u+l}``, the sum of the frame Gram matrix
    ``F = X X^T`` along its diagonals over M lags: one T x C x T product and M additions
    of S x S instead of the S^2 M C of ``H @ H.T`` (e.g. 960 frames, 93 channels, 16 lags:
    0.17 against 2.7 GFLOP).

    >>> import numpy as np
    >>> X = np.random.default_rng(0).normal(size=(50, 3))
    >>> H = lagged(X, 4)
    >>> bool(np.allclose(lagged_gram(X, 4), H.T @ H)), bool(np.allclose(lagged_gram(X, 4, "rows"), H @ H.T))
    (True, True)
    """
    X = np.asarray(X, dtype=float)
    T, C = X.shape
    M = int(M)
    S = T - M + 1
    if S < 1:
        raise MocapValueError(f"need at least {M} frames for windows of {M}, got {T}")
    if side == "rows":
        F = X @ X.T
        G = F[:S, :S].copy()
        for lag in range(1, M):                    # M lags, each an S x S addition
            G += F[lag:lag + S, lag:lag + S]
        return G
    if side != "columns":
        raise MocapValueError(f"side must be 'columns' or 'rows', got {side!r}")
    G = np.empty((M * C, M * C))
    for j in range(M):
        G[:C, j * C:(j + 1) * C] = X[:S].T @ X[j:j + S]
    for i in range(1, M):                          # along the diagonals: rank-2 updates
        for j in range(i, M):
            G[i * C:(i + 1) * C, j * C:(j + 1) * C] = (G[(i - 1) * C:i * C, (j - 1) * C:j * C]
                                                       - np.outer(X[i - 1], X[j - 1])
                                                       + np.outer(X[i - 1 + S], X[j - 1 + S]))
    for i in range(M):                             # the lower blocks: transposes
        for j in range(i + 1, M):
            G[j * C:(j + 1) * C, i * C:(i + 1) * C] = G[i * C:(i + 1) * C, j * C:(j + 1) * C].T
    return G


def counts(T: int, M: int) -> np.ndarray:
    """n_t (T,) float: how many of the length-M windows (starts 0..T-M) contain frame t."""
    S = T - M + 1
    t = np.arange(T)
    return (np.minimum(t, S - 1) - np.maximum(t - M + 1, 0) + 1).astype(float)


def window_starts(T: int, M: int, stride: int) -> np.ndarray:
    """First frames of windows taken every ``stride`` frames: 0, stride, 2 stride, ... and
    always the last window T - M, so every frame is covered."""
    S = T - M + 1
    st = np.arange(0, S, max(1, int(stride)), dtype=np.int64)
    if st[-1] != S - 1:
        st = np.append(st, S - 1)
    return st


def overlap_add(R: np.ndarray, T: int, M: int, starts: np.ndarray | None = None,
                weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Sum back to frames: R (S, M C) -> acc (T, C) and the number of copies per frame (T,).

    ``starts`` (S,): first frame of every row of R (default: all windows, stride 1; see
    :func:`window_starts`; must be distinct). ``weights`` (S,): each row counts with this weight
    in both sums (e.g. a bool "this window was coded"). Loops over the M offsets, not
    over windows.
    """
    S = R.shape[0]
    R3 = R.reshape(S, M, -1)
    acc = np.zeros((T, R3.shape[2]), dtype=np.float64)
    cnt = np.zeros(T)
    st = np.arange(S) if starts is None else np.asarray(starts, dtype=np.int64)
    w = None if weights is None else np.asarray(weights)
    for m in range(M):
        if starts is None:
            acc[m:m + S] += R3[:, m] if w is None else R3[:, m] * w[:, None]
            cnt[m:m + S] += 1 if w is None else w
        else:
            acc[st + m] += R3[:, m] if w is None else R3[:, m] * w[:, None]
            cnt[st + m] += 1 if w is None else w
    return acc, cnt


def overlap_mean(R: np.ndarray, T: int, M: int, starts: np.ndarray | None = None) -> np.ndarray:
    """Inverse of :func:`lagged` by plain averaging (Xiao et al. Alg. 1 steps 5-6):
    R (S, M C) -> (T, C), each frame the mean of its copies in the windows covering it
    (``starts`` as in :func:`overlap_add`)."""
    acc, cnt = overlap_add(R, T, M, starts)
    return acc / cnt[:, None]


def window_blocks(S: int, per_window_bytes: float, budget: int | None = None,
                  align: int = 256) -> list[tuple[int, int]]:
    """Blocks ``(a, b)`` of the S windows, **last block first**, each holding about
    ``budget / per_window_bytes`` windows (a multiple of ``align``: the BLAS kernels then
    see the same row tiles as in one call, so every window gets bit-identical numbers).

    Last block first: a frame's copies are then summed by :func:`overlap_add_into` in the
    order of :func:`overlap_add` (window offset m ascending), so the
    blocked overlap-average is bit-identical to the unblocked one.
    """
    budget = BLOCK_BYTES if budget is None else budget
    n = max(align, int(budget // max(per_window_bytes, 1.0)) // align * align)
    return [(a, min(S, a + n)) for a in range(0, S, n)][::-1]


def overlap_add_into(acc: np.ndarray, R: np.ndarray, M: int, first: int,
                     starts: np.ndarray | None = None, weights: np.ndarray | None = None,
                     cnt: np.ndarray | None = None) -> None:
    """In place: add the rows of R (n, M C) -- windows starting at frames ``first`` ..
    ``first + n - 1`` (or at the frames ``starts`` (n,)) -- to ``acc`` (T, C) and, if
    given, their ``weights`` (or 1) to ``cnt`` (T,).  The same element operations as
    :func:`overlap_add` on all windows, one block at a time (called on
    the blocks of :func:`window_blocks`, last first)."""
    n = R.shape[0]
    R3 = R.reshape(n, M, -1)
    w = None if weights is None else np.asarray(weights)
    for m in range(M):
        rows = slice(first + m, first + m + n) if starts is None else starts + m
        acc[rows] += R3[:, m] if w is None else R3[:, m] * w[:, None]
        if cnt is not None:
            cnt[rows] += 1 if w is None else w


def spaced_frames(T: int, n: int) -> np.ndarray:
    """At most ``n`` evenly spaced frame indices of 0..T-1, first and last included (sorted,
    unique) -- the one way a check or a reference reads a sample of a long clip's frames.

    >>> spaced_frames(10, 4).tolist()
    [0, 3, 6, 9]
    """
    return np.unique(np.linspace(0, T - 1, max(min(T, int(n)), 1)).round().astype(int))


def frame_blocks(T: int, block: int | None = None) -> list[slice]:
    """Consecutive blocks of ``block`` frames (default :data:`FRAME_BLOCK`) covering 0..T-1
    -- the one way long-clip code walks over frames a block at a time (blocks, not frames)."""
    n = FRAME_BLOCK if block is None else int(block)
    return [slice(a, min(a + n, T)) for a in range(0, T, n)]
