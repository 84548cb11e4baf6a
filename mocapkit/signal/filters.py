"""Smoothing and outlier-rejection filters on (T, C) arrays: Gaussian, zero-phase
Butterworth, Savitzky-Golay, running median, Hampel identifier (and its residuals).

Boundary handling (``mode='odd'`` of :func:`gaussian` and :func:`butterworth`)
--------------------------------------------------------------------------------
The signal is extended past each end by point reflection about an *estimate* of the end
value: ``x[-k] = 2 a0 - x[k]`` with ``a0`` the value at the end frame of the
least-squares line through the first ``m`` samples (and likewise at the other end). A
straight-line motion is therefore preserved exactly up to the ends (unlike even
reflection or edge repetition, which bend it), and -- unlike plain odd reflection about
the noisy end sample, which leaves the end sample unsmoothed -- the noise of the end
samples is averaged over ``m`` frames.

Every filter needs complete data (raises :class:`~mocapkit.errors.MocapValueError` on
non-finite input): fill gaps first with :func:`mocapkit.gaps.fill`.
"""
from __future__ import annotations

import math
from typing import Literal

import numpy as np

from ..errors import MocapValueError
from ..windows import frame_blocks
from ._arrays import as_2d_view, by_channel_blocks, channel_blocks, require_finite, restore

__all__ = ["gaussian", "butterworth", "savgol", "median", "hampel", "hampel_residuals", "hampel_scores"]


def _line_end_weights(m: int) -> np.ndarray:
    """Weights w (m,) with sum(w * x[:m]) = least-squares line through x[0..m-1] at t=0."""
    if m <= 1:
        return np.ones(1)
    t = np.arange(m)
    return (2.0 * (2 * m - 1) - 6.0 * t) / (m * (m + 1))


def _pad_trend(B: np.ndarray, n: int, m: int) -> tuple[np.ndarray, int]:
    """Extend (c, T) ``B`` -- channels along the rows, time along the last axis, the
    layout of :func:`~mocapkit.signal._arrays.by_channel_blocks` -- by ``n`` frames at both
    ends (capped at T-1) by point reflection about the end values of local least-squares
    lines over ``m`` samples (module doc)."""
    T = B.shape[-1]
    n = int(max(0, min(n, T - 1)))
    if n == 0:
        return B, 0
    m = int(max(1, min(m, T)))
    w = _line_end_weights(m)
    # the end samples as (m, c) frames x channels, laid out as in a (T, C) array (the
    # last ones in reversed row order), so that the products sum in the same order and
    # the end values are bit-identical to those of the whole-array layout
    a0 = w @ np.ascontiguousarray(B[:, :m].T)
    a1 = w @ np.ascontiguousarray(B[:, T - m:].T)[::-1]
    left = 2.0 * a0[:, None] - B[:, n:0:-1]
    right = 2.0 * a1[:, None] - B[:, -2:-n - 2:-1]
    return np.concatenate([left, B, right], axis=1), n


# ---------------------------------------------------------------------------------------


# ---------------------------------------------------------------------------------------
# linear filters
# ---------------------------------------------------------------------------------------
def gaussian(X, /, *, sigma: float, radius: int | None = None, mode: str = "odd",
             axis: int = 0) -> np.ndarray:
    """Gaussian smoothing along time (per channel).

    Parameters
    ----------
    X : array (T, ...), complete (finite).
    sigma : standard deviation of the kernel in frames (> 0).
    radius : kernel half-width in frames (window = 2*radius+1); default ``ceil(4*sigma)``.
        The truncated kernel is renormalised to sum to 1 (as scipy does).
    mode : ``'odd'`` (default) -- trend-preserving point reflection at the ends (module
        doc); any :func:`scipy.ndimage.gaussian_filter1d` mode (``'reflect'``,
        ``'nearest'``, ``'mirror'``, ``'constant'``, ``'wrap'``) is passed through, so
        ``gaussian(X, sigma=s, radius=r, mode='reflect')`` equals
        ``gaussian_filter1d(X, s, radius=r, mode='reflect')``.

    Returns
    -------
    array like ``X`` (float64).

    Examples
    --------
    A straight line passes unchanged (the ``'odd'`` ends keep the trend); a unit impulse
    is spread over the kernel:

    >>> import numpy as np
    >>> from mocapkit import signal
    >>> line = np.arange(10.0)[:, None]
    >>> bool(np.allclose(signal.gaussian(line, sigma=2.0), line))
    True
    >>> impulse = np.zeros((9, 1)); impulse[4] = 1.0
    >>> signal.gaussian(impulse, sigma=1.0, mode="constant")[2:7, 0].round(3)
    array([0.054, 0.242, 0.399, 0.242, 0.054])
    """
    from scipy.ndimage import gaussian_filter1d

    sigma = float(sigma)
    if not np.isfinite(sigma) or sigma <= 0:
        raise MocapValueError(f"sigma must be a positive number of frames, got {sigma!r}")
    r = int(math.ceil(4.0 * sigma)) if radius is None else int(radius)
    if r < 0:
        raise MocapValueError(f"radius must be >= 0, got {radius!r}")
    A, shape, axis = as_2d_view(X, axis)          # read only: the result is a new array
    require_finite(A, "gaussian filtering")
    if r == 0:
        return restore(A.copy(), shape, axis)
    if mode == "odd":
        T = A.shape[0]

        def smooth(B):          # (c, T) block: pad it, filter it, cut the padding off
            P, n = _pad_trend(B, r, 2 * r + 1)
            return gaussian_filter1d(P, sigma, axis=-1, radius=r, mode="nearest")[:, n:n + T]

        # block by block, so that the padded copy and the filtered copy are of one block
        # (whole, they were two more matrices: 4x the input at 100,000 frames, issue 21)
        Y = by_channel_blocks(smooth, A)
    else:
        Y = gaussian_filter1d(A, sigma, axis=0, radius=r, mode=mode)
    return restore(Y, shape, axis)


def butterworth(X, /, *, fs: float, cutoff_hz: float, order: int = 4, axis: int = 0,
                padlen: int | None = None) -> np.ndarray:
    """Zero-phase Butterworth low-pass filter (forward-backward, ``scipy.signal.sosfiltfilt``).

    The forward-backward pass squares the magnitude response, so the effective filter
    has order ``2*order`` and its -3 dB point lies slightly below ``cutoff_hz`` (the
    single-pass -3 dB point is at ``cutoff_hz``; the zero-phase gain there is 0.5).

    Parameters
    ----------
    X : array (T, ...), complete (finite).
    fs : sampling rate in Hz (frames per second).
    cutoff_hz : cutoff frequency in Hz, 0 < cutoff_hz < fs/2.
    order : order of the single-pass Butterworth filter (default 4).
    padlen : frames of trend-preserving odd extension at each end (module doc) before
        filtering; default ``max(3*(2*n_sections+1), round(fs/cutoff_hz))`` (scipy's
        default or one cutoff period, whichever is longer), capped at T-1.

    Raises
    ------
    MocapValueError : bad fs/cutoff/order, or a clip shorter than scipy's default
        ``padlen + 1 = 3*(2*n_sections+1)+1`` frames (16 for order 4): too short for a
        meaningful zero-phase IIR filter (use :func:`gaussian` instead).
    """
    from scipy.signal import butter, sosfiltfilt

    fs, cutoff_hz = float(fs), float(cutoff_hz)
    if not (np.isfinite(fs) and fs > 0):
        raise MocapValueError(f"fs must be a positive frame rate in Hz, got {fs!r}")
    if not (0 < cutoff_hz < fs / 2):
        raise MocapValueError(
            f"cutoff_hz must lie strictly between 0 and the Nyquist frequency {fs / 2:g} Hz "
            f"(fps {fs:g}), got {cutoff_hz:g}")
    if int(order) != order or order < 1:
        raise MocapValueError(f"order must be a positive integer, got {order!r}")
    sos = butter(int(order), cutoff_hz / (fs / 2), btype="low", output="sos")
    A, shape, axis = as_2d_view(X, axis)          # read only: the result is a new array
    require_finite(A, "Butterworth filtering")
    T = A.shape[0]
    min_pad = 3 * (2 * len(sos) + 1)
    if T <= min_pad:
        raise MocapValueError(
            f"Butterworth filter of order {order} needs at least {min_pad + 1} frames "
            f"(zero-phase filtering pads {min_pad} frames at each end); this clip has {T}. "
            f"Use a lower order or the 'gaussian' method for such short clips")
    n = max(min_pad, int(round(fs / cutoff_hz))) if padlen is None else int(padlen)
    m = max(2, int(round(fs / cutoff_hz / 2)))

    def zero_phase(B):          # (c, T) block: pad it, filter it, cut the padding off
        P, k = _pad_trend(B, n, m)
        return sosfiltfilt(sos, P, axis=-1, padtype=None)[:, k:k + T]

    # padding inside the blocks: a padded copy of the whole clip was one more matrix
    Y = by_channel_blocks(zero_phase, A)
    return restore(Y, shape, axis)


def savgol(X, /, *, window: int, polyorder: int = 3, axis: int = 0) -> np.ndarray:
    """Savitzky-Golay smoothing (``scipy.signal.savgol_filter``, ``mode='interp'``: the
    end frames take the value of the polynomial fitted to the first/last window).

    ``window`` (odd, frames) is reduced to the largest odd length <= T for short clips;
    a clip with fewer than ``polyorder + 2`` frames raises MocapValueError.
    """
    from scipy.signal import savgol_filter

    window, polyorder = int(window), int(polyorder)
    if polyorder < 0:
        raise MocapValueError(f"polyorder must be >= 0, got {polyorder}")
    if window < 1 or window % 2 == 0 or window <= polyorder:
        raise MocapValueError(f"window must be an odd number of frames > polyorder ({polyorder}), got {window}")
    A, shape, axis = as_2d_view(X, axis)          # read only: the result is a new array
    require_finite(A, "Savitzky-Golay filtering")
    T = A.shape[0]
    w = min(window, T if T % 2 else T - 1)
    if w <= polyorder:
        raise MocapValueError(
            f"Savitzky-Golay of order {polyorder} needs at least {polyorder + 2} frames; this clip has {T}")
    Y = savgol_filter(A, w, polyorder, axis=0, mode="interp")
    return restore(Y, shape, axis)


def median(X, /, *, window: int, axis: int = 0) -> np.ndarray:
    """Running median over ``window`` frames (odd); windows mirrored at the ends
    (``scipy.ndimage.median_filter``, ``mode='mirror'``: c b | a b c), so an end sample
    appears once in its window and a spike there is removed like any other (edge
    repetition would give it a majority)."""
    from scipy.ndimage import median_filter

    window = int(window)
    if window < 1 or window % 2 == 0:
        raise MocapValueError(f"median window must be a positive odd number of frames, got {window}")
    A, shape, axis = as_2d_view(X, axis)          # read only: the result is a new array
    require_finite(A, "median filtering")
    if window == 1:
        return restore(A.copy(), shape, axis)
    Y = median_filter(A, size=(window, 1), mode="mirror")
    return restore(Y, shape, axis)


def _reflect_index(T: int, h: int) -> np.ndarray:
    """Frames -h .. T+h-1 of the 'reflect' extension (d c b a | a b c d | d c b a) as
    indices into 0..T-1; for windows longer than the clip the reflection repeats."""
    if T <= 1:
        return np.zeros(T + 2 * h, dtype=np.intp)
    idx = np.mod(np.arange(-h, T + h), 2 * T)
    return np.where(idx >= T, 2 * T - 1 - idx, idx)


def _rolling_chunks(A: np.ndarray, window: int, chunk: int, exclude_center: bool):
    """Yield ``(start, stop, med, mad)`` for time chunks of the (T, C) array ``A``: the
    rolling median of ``window`` frames (windows reflected at the ends; with
    ``exclude_center`` the window minus its centre sample) and the median absolute
    deviation about it, (stop - start, C) each.  Each chunk pads only its own frames, so
    the (chunk, C, window) window view and the padding stay small whatever T is."""
    from numpy.lib.stride_tricks import sliding_window_view

    T = A.shape[0]
    h = window // 2
    idx = _reflect_index(T, h)
    for s in range(0, T, chunk):
        e = min(T, s + chunk)
        W = sliding_window_view(A[idx[s:e + 2 * h]], window, axis=0)   # (n, C, window)
        if exclude_center:
            # np.delete copies: the median may reorder that copy's windows in place (no
            # second copy) -- the deviations below do not depend on the order in a window
            W = np.delete(W, h, axis=-1)
            mm = np.median(W, axis=-1, overwrite_input=True)
        else:
            mm = np.median(W, axis=-1)
        D = np.subtract(W, mm[..., None])
        yield s, e, mm, np.median(np.abs(D, out=D), axis=-1, overwrite_input=True)


def _rolling_median_mad(A: np.ndarray, window: int, chunk: int = 4096,
                        exclude_center: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Rolling median and median absolute deviation (about that median) over ``window``
    frames, windows reflected at the ends ('reflect' mode); with ``exclude_center`` over
    the window minus its centre sample (:func:`_rolling_chunks`)."""
    med = np.empty_like(A)
    mad = np.empty_like(A)
    for s, e, mm, dev in _rolling_chunks(A, window, chunk, exclude_center):
        med[s:e] = mm
        mad[s:e] = dev
    return med, mad


def _hampel_window(window) -> int:
    """The Hampel window as an int, checked: an odd number of frames >= 3."""
    window = int(window)
    if window < 3 or window % 2 == 0:
        raise MocapValueError(f"hampel window must be an odd number of frames >= 3, got {window}")
    return window


def _global_scale(res: np.ndarray) -> np.ndarray:
    """(C,) 1.4826 x the MAD of each column of ``res`` (T, C) about its median, a block
    of columns at a time (np.median copies its input: a block, not the whole matrix)."""
    out = np.empty(res.shape[1])
    for sl in channel_blocks(res.shape[1]):
        r = res[:, sl]
        out[sl] = 1.4826 * np.median(np.abs(r - np.median(r, axis=0)), axis=0)
    return out


def hampel_residuals(X, /, *, window: int = 7, scale: Literal["local", "global", "both"] = "local",
                     min_sigma: float = 0.0, exclude_center: bool = False, axis: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals from the running median and their robust scale (see :func:`hampel`).

    Returns ``med`` (running median), ``res = X - med`` and ``sigma`` (all like X):
    ``scale='local'`` -- classic Hampel, 1.4826 x the MAD of the ``window`` samples about
    their median; ``scale='global'`` -- one value per channel, 1.4826 x the MAD of that
    channel's residuals over the whole clip (stable, and not inflated by fast motion,
    which moves the window's samples but not their residuals); ``scale='both'`` returns
    both as ``sigma`` of shape (2, *X.shape): [global, local]. Floored at ``min_sigma``.

    ``exclude_center=True`` takes the median (and MAD) of the ``window - 1`` neighbours
    of each sample, leaving the sample itself out. The residual is then independent of
    the neighbours' statistics, so for Gaussian noise it is Gaussian and the MAD-based
    sigma is calibrated; with the centre included the residual is exactly 0 whenever
    the sample is the window's median (1/window of the time), which shrinks the MAD by
    ~15 % (window 7) and inflates false alarms about tenfold at 3 sigmas.
    """
    window = _hampel_window(window)
    if scale not in ("local", "global", "both"):
        raise MocapValueError(f"scale must be 'local', 'global' or 'both', got {scale!r}")
    A, shape, axis = as_2d_view(X, axis)          # read only
    require_finite(A, "the Hampel filter")
    med, mad = _rolling_median_mad(A, window, exclude_center=exclude_center)
    res = A - med
    loc = np.multiply(mad, 1.4826, out=mad)
    glob = np.broadcast_to(_global_scale(res), A.shape)
    sigs = (glob, loc) if scale == "both" else (glob,) if scale == "global" else (loc,)
    S = np.empty((len(sigs),) + A.shape)              # written in place: no stacked copy
    for o, sg in zip(S, sigs):
        np.maximum(sg, float(min_sigma), out=o)
    S = np.moveaxis(S.reshape((len(sigs),) + shape), 1, axis + 1)
    return restore(med, shape, axis), restore(res, shape, axis), (S if scale == "both" else S[0])


def hampel_scores(X, /, *, window: int = 7, scales: tuple[str, ...] = ("global", "local"),
                  min_sigma: float = 0.0, exclude_center: bool = False, group: int = 1,
                  reduce: Literal["sum", "max"] = "sum", chunk: int = 1024) -> list[np.ndarray]:
    """Squared scaled residuals ``(res / sigma)²`` of :func:`hampel_residuals`, reduced
    over each group of ``group`` consecutive channels (``"sum"``: the 3-dof statistic of a
    marker's x, y, z; ``"max"``: the largest of them, NaN ignored): one (T, C // group)
    array per entry of ``scales`` (``"global"``, ``"local"``).

    The same numbers as from the arrays of :func:`hampel_residuals` (same operations, in
    time chunks), without holding them: only the residuals are kept whole (the global
    scale needs all of them), so the call needs about 1.7 matrices besides ``X`` where
    ``hampel_residuals`` and the scaled squares made from its output needed about eight
    (issue 21: 10x the input at 100,000 frames for the ``hampel`` method).

    ``X`` : (T, C) complete (finite); ``window``, ``min_sigma``, ``exclude_center`` as
    :func:`hampel_residuals`.  ``chunk``: frames per chunk (its window temporaries are
    ~2 x chunk x C x window values: 1,024 frames ran as fast as 4,096 at 100,000 frames,
    2.5 s, and need a quarter of the memory).
    """
    window = _hampel_window(window)
    if not scales or any(sc not in ("global", "local") for sc in scales):
        raise MocapValueError(f"scales must be 'global' and/or 'local', got {scales!r}")
    if reduce not in ("sum", "max"):
        raise MocapValueError(f"reduce must be 'sum' or 'max', got {reduce!r}")
    A = np.asarray(X, dtype=np.float64)                  # read only
    if A.ndim != 2 or A.shape[1] % int(group):
        raise MocapValueError(f"expected a (T, C) array with C a multiple of group={group}, got {A.shape}")
    require_finite(A, "the Hampel filter")
    T, C = A.shape
    G = C // int(group)
    floor = float(min_sigma)

    def score(r: np.ndarray, sig: np.ndarray) -> np.ndarray:        # (n, C) -> (n, G)
        z2 = (r / sig).reshape(len(r), G, int(group)) ** 2
        return z2.sum(axis=2) if reduce == "sum" else np.fmax.reduce(z2, axis=2)

    out = {sc: np.empty((T, G)) for sc in scales}
    res = np.empty((T, C)) if "global" in scales else None
    for s, e, mm, mad in _rolling_chunks(A, window, chunk, exclude_center):
        r = A[s:e] - mm
        if res is not None:
            res[s:e] = r
        if "local" in out:
            out["local"][s:e] = score(r, np.maximum(1.4826 * mad, floor))
    if res is not None:
        glob = np.maximum(_global_scale(res), floor)
        for sl in frame_blocks(T, chunk):
            out["global"][sl] = score(res[sl], glob)
    return [out[sc] for sc in scales]


def hampel(X, /, *, window: int = 7, n_sigmas: float = 3.0, scale: Literal["local", "global"] = "local",
           min_sigma: float = 0.0, exclude_center: bool = False,
           axis: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Hampel identifier: flag samples far from the running median and replace them by it.

    A sample x_t is flagged when ``|x_t - med_t| > n_sigmas * sigma_t``, med_t the median
    of the ``window`` samples centred on t (windows reflected at the clip ends) and
    sigma_t a robust scale: ``scale='local'`` (default, the classic Hampel filter)
    1.4826 x the median absolute deviation of those samples about med_t (1.4826 makes
    the MAD a consistent Gaussian sigma); ``scale='global'`` one robust scale per channel
    from all its residuals (:func:`hampel_residuals`). ``sigma`` is floored at
    ``min_sigma`` (data units), so flat stretches with MAD = 0 do not flag every tiny
    deviation (default 0: classic behaviour). ``exclude_center`` leaves each sample out
    of its own window statistics (:func:`hampel_residuals`; default False: classic).

    Parameters
    ----------
    X : array (T, ...), complete (finite).
    window : odd number of frames (default 7).
    n_sigmas : threshold in robust standard deviations (default 3).

    Returns
    -------
    Y : array like X -- flagged samples replaced by the running median.
    flagged : bool array like X.
    """
    n_sigmas = float(n_sigmas)
    if not n_sigmas > 0:
        raise MocapValueError(f"n_sigmas must be positive, got {n_sigmas}")
    if scale not in ("local", "global"):
        raise MocapValueError(f"scale must be 'local' or 'global', got {scale!r}")
    med, res, sig = hampel_residuals(X, window=window, scale=scale, min_sigma=min_sigma,
                                     exclude_center=exclude_center, axis=axis)
    flagged = np.abs(res) > n_sigmas * sig
    return np.where(flagged, med, np.asarray(X, dtype=float)), flagged
