"""Plain signal-processing functions on (T, C) arrays: smoothing, outlier rejection,
gap filling and Kalman/RTS smoothing.

In the style of :mod:`scipy.signal`: the data come first (positional only), options are
keyword-only, the input is never modified, and a new array is returned. Time runs along
``axis`` (default 0, one row per frame); every other axis is an independent channel
(for mocap: the (T, 3J) matrix of :meth:`mocapkit.motion.Motion.matrix`, in cm).
Functions that need complete data raise :class:`~mocapkit.errors.MocapValueError` on
non-finite input: fill gaps first with :func:`fill_gaps`.

Time is measured in frames unless a parameter says otherwise (``fs`` in Hz, ``dt`` in s).

Boundary handling (``mode='odd'`` of :func:`gaussian` and :func:`butterworth`)
--------------------------------------------------------------------------------
The signal is extended past each end by point reflection about an *estimate* of the end
value: ``x[-k] = 2 a0 - x[k]`` with ``a0`` the value at the end frame of the
least-squares line through the first ``m`` samples (and likewise at the other end). A
straight-line motion is therefore preserved exactly up to the ends (unlike even
reflection or edge repetition, which bend it), and -- unlike plain odd reflection about
the noisy end sample, which leaves the end sample unsmoothed -- the noise of the end
samples is averaged over ``m`` frames.

Kalman smoothing
----------------
:func:`rts_smoother` runs a batch of independent linear-Gaussian state-space models
(e.g. one 2-state constant-velocity filter per coordinate, all coordinates at once) with
a forward Kalman filter and a Rauch-Tung-Striebel backward pass (Rauch, Tung & Striebel
1965; Welch & Bishop 2001 for the filter). Missing observations skip the update step.
Python loops run over time only (a recursion); every step is a handful of batched
small-matrix products with precomputed model matrices. Its output is the Gaussian
posterior mean, which :func:`_dense_posterior` (tests) computes by one direct solve.
"""
from __future__ import annotations

import math
from typing import Literal, Sequence

import numpy as np

from .errors import MocapValueError

__all__ = [
    "fill_gaps", "gaussian", "butterworth", "savgol", "median", "hampel", "hampel_residuals",
    "rts_smoother", "cv_model", "random_walk_model", "estimate_noise_sigma",
    "gate_threshold", "cutoff_to_q", "select_process_noise", "steady_state_covariance",
]


# ---------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------
def _as_2d(X, axis: int) -> tuple[np.ndarray, tuple[int, ...], int]:
    """Move ``axis`` to the front and flatten the rest: (T, C) float copy + restore info."""
    A = np.asarray(X, dtype=np.float64)
    if A.ndim == 0:
        raise MocapValueError("expected an array with a time axis, got a scalar")
    axis = axis % A.ndim
    A = np.moveaxis(A, axis, 0)
    shape = A.shape
    return np.array(A.reshape(shape[0], -1), dtype=np.float64, copy=True), shape, axis


def _restore(Y: np.ndarray, shape: tuple[int, ...], axis: int) -> np.ndarray:
    return np.moveaxis(Y.reshape(shape), 0, axis)


def _require_finite(A: np.ndarray, what: str) -> None:
    if not np.isfinite(A).all():
        n = int((~np.isfinite(A)).sum())
        raise MocapValueError(
            f"{what} needs complete data but the input has {n} missing (non-finite) values; "
            f"fill the gaps first (mocapkit.signal.fill_gaps)")


def _line_end_weights(m: int) -> np.ndarray:
    """Weights w (m,) with sum(w * x[:m]) = least-squares line through x[0..m-1] at t=0."""
    if m <= 1:
        return np.ones(1)
    t = np.arange(m)
    return (2.0 * (2 * m - 1) - 6.0 * t) / (m * (m + 1))


def _pad_trend(A: np.ndarray, n: int, m: int) -> tuple[np.ndarray, int]:
    """Extend (T, C) ``A`` by ``n`` frames at both ends (capped at T-1) by point reflection
    about the end values of local least-squares lines over ``m`` samples (module doc)."""
    T = A.shape[0]
    n = int(max(0, min(n, T - 1)))
    if n == 0:
        return A, 0
    m = int(max(1, min(m, T)))
    w = _line_end_weights(m)
    a0 = w @ A[:m]
    a1 = w @ A[::-1][:m]
    left = 2.0 * a0 - A[n:0:-1]
    right = 2.0 * a1 - A[-2:-n - 2:-1]
    return np.concatenate([left, A, right], axis=0), n


# ---------------------------------------------------------------------------------------
# gap filling
# ---------------------------------------------------------------------------------------
def fill_gaps(X, mask=None, /, *, kind: Literal["linear", "cubic"] = "cubic",
              ends: Literal["nearest", "linear"] = "nearest", axis: int = 0) -> np.ndarray:
    """Fill unobserved samples by interpolation in time; observed samples are returned
    bit-identical.

    Parameters
    ----------
    X : array (T, ...) -- time along ``axis``; unobserved values may be NaN.
    mask : bool array like ``X``, True = observed. Default: ``np.isfinite(X)``. Entries
        that are not finite count as unobserved whatever the mask says.
    kind : ``'cubic'`` -- cubic spline through the observed samples of each channel
        (``scipy.interpolate.CubicSpline``, not-a-knot ends, so any cubic polynomial is
        reproduced exactly); channels with fewer than 4 observed samples fall back to
        linear. ``'linear'`` -- piecewise-linear interpolation.
    ends : how to fill before the first / after the last observed sample of a channel.
        ``'nearest'`` (default) holds the first/last observed value (safe: never drifts);
        ``'linear'`` continues the interpolant's end slope (one-sided derivative of the
        spline, or the last segment's slope), which follows a moving marker better over
        a few frames but diverges over long end gaps.

    Returns
    -------
    array like ``X`` (float64), fully finite.

    Raises
    ------
    MocapValueError : a channel has no observed sample at all (its indices are named).

    Notes
    -----
    Channels that share the same observed pattern (the x, y, z of a marker) are
    interpolated together in one call, so the cost is one spline per distinct mask
    column, not per channel.
    """
    if kind not in ("linear", "cubic"):
        raise MocapValueError(f"kind must be 'linear' or 'cubic', got {kind!r}")
    if ends not in ("nearest", "linear"):
        raise MocapValueError(f"ends must be 'nearest' or 'linear', got {ends!r}")
    A, shape, axis = _as_2d(X, axis)
    if mask is None:
        M = np.isfinite(A)
    else:
        Mm = np.asarray(mask, dtype=bool)
        if Mm.shape != np.shape(X):
            raise MocapValueError(f"mask shape {Mm.shape} does not match data shape {np.shape(X)}")
        M = np.moveaxis(Mm, axis, 0).reshape(A.shape[0], -1) & np.isfinite(A)
    incomplete = np.flatnonzero(~M.all(axis=0))
    if incomplete.size == 0:
        return _restore(A, shape, axis)
    empty = [int(c) for c in incomplete if not M[:, c].any()]
    if empty:
        raise MocapValueError(
            f"cannot fill channel(s) {empty[:10]}{'...' if len(empty) > 10 else ''}: "
            f"no observed sample in the whole clip")
    T = A.shape[0]
    t = np.arange(T, dtype=float)
    groups: dict[bytes, list[int]] = {}
    for c in incomplete:
        groups.setdefault(np.packbits(M[:, c]).tobytes(), []).append(int(c))
    from scipy.interpolate import CubicSpline

    for cols in groups.values():
        m = M[:, cols[0]]
        to = np.flatnonzero(m)
        tm = np.flatnonzero(~m)
        Yo = A[np.ix_(to, cols)]
        if len(to) == 1:
            A[np.ix_(tm, cols)] = Yo[0]
            continue
        inside = tm[(tm > to[0]) & (tm < to[-1])]
        before = tm[tm < to[0]]
        after = tm[tm > to[-1]]
        if kind == "cubic" and len(to) >= 4:
            cs = CubicSpline(to.astype(float), Yo, axis=0, bc_type="not-a-knot")
            if inside.size:
                A[np.ix_(inside, cols)] = cs(inside.astype(float))
            d0, d1 = cs(float(to[0]), 1), cs(float(to[-1]), 1)
        else:
            if inside.size:
                k = np.searchsorted(to, inside)            # to[k-1] < t < to[k]
                lo, hi = to[k - 1], to[k]
                w = ((inside - lo) / (hi - lo))[:, None]
                A[np.ix_(inside, cols)] = (1 - w) * A[np.ix_(lo, cols)] + w * A[np.ix_(hi, cols)]
            d0 = (Yo[1] - Yo[0]) / (to[1] - to[0])
            d1 = (Yo[-1] - Yo[-2]) / (to[-1] - to[-2])
        if ends == "nearest":
            d0 = d1 = np.zeros(len(cols))
        if before.size:
            A[np.ix_(before, cols)] = Yo[0] + (t[before] - to[0])[:, None] * d0
        if after.size:
            A[np.ix_(after, cols)] = Yo[-1] + (t[after] - to[-1])[:, None] * d1
    return _restore(A, shape, axis)


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
    """
    from scipy.ndimage import gaussian_filter1d

    sigma = float(sigma)
    if not np.isfinite(sigma) or sigma <= 0:
        raise MocapValueError(f"sigma must be a positive number of frames, got {sigma!r}")
    r = int(math.ceil(4.0 * sigma)) if radius is None else int(radius)
    if r < 0:
        raise MocapValueError(f"radius must be >= 0, got {radius!r}")
    A, shape, axis = _as_2d(X, axis)
    _require_finite(A, "gaussian filtering")
    if r == 0:
        return _restore(A, shape, axis)
    if mode == "odd":
        P, n = _pad_trend(A, r, 2 * r + 1)
        Y = gaussian_filter1d(P, sigma, axis=0, radius=r, mode="nearest")[n:n + A.shape[0]]
    else:
        Y = gaussian_filter1d(A, sigma, axis=0, radius=r, mode=mode)
    return _restore(Y, shape, axis)


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
    A, shape, axis = _as_2d(X, axis)
    _require_finite(A, "Butterworth filtering")
    T = A.shape[0]
    min_pad = 3 * (2 * len(sos) + 1)
    if T <= min_pad:
        raise MocapValueError(
            f"Butterworth filter of order {order} needs at least {min_pad + 1} frames "
            f"(zero-phase filtering pads {min_pad} frames at each end); this clip has {T}. "
            f"Use a lower order or the 'gaussian' method for such short clips")
    n = max(min_pad, int(round(fs / cutoff_hz))) if padlen is None else int(padlen)
    P, n = _pad_trend(A, n, max(2, int(round(fs / cutoff_hz / 2))))
    Y = sosfiltfilt(sos, P, axis=0, padtype=None)[n:n + T]
    return _restore(Y, shape, axis)


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
    A, shape, axis = _as_2d(X, axis)
    _require_finite(A, "Savitzky-Golay filtering")
    T = A.shape[0]
    w = min(window, T if T % 2 else T - 1)
    if w <= polyorder:
        raise MocapValueError(
            f"Savitzky-Golay of order {polyorder} needs at least {polyorder + 2} frames; this clip has {T}")
    Y = savgol_filter(A, w, polyorder, axis=0, mode="interp")
    return _restore(Y, shape, axis)


def median(X, /, *, window: int, axis: int = 0) -> np.ndarray:
    """Running median over ``window`` frames (odd); windows mirrored at the ends
    (``scipy.ndimage.median_filter``, ``mode='mirror'``: c b | a b c), so an end sample
    appears once in its window and a spike there is removed like any other (edge
    repetition would give it a majority)."""
    from scipy.ndimage import median_filter

    window = int(window)
    if window < 1 or window % 2 == 0:
        raise MocapValueError(f"median window must be a positive odd number of frames, got {window}")
    A, shape, axis = _as_2d(X, axis)
    _require_finite(A, "median filtering")
    if window == 1:
        return _restore(A, shape, axis)
    Y = median_filter(A, size=(window, 1), mode="mirror")
    return _restore(Y, shape, axis)


def _rolling_median_mad(A: np.ndarray, window: int, chunk: int = 4096,
                        exclude_center: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Rolling median and median absolute deviation (about that median) over ``window``
    frames, windows reflected at the ends ('reflect' mode); with ``exclude_center`` over
    the window minus its centre sample. Processed in time chunks so the
    (chunk, C, window) view stays small."""
    from numpy.lib.stride_tricks import sliding_window_view

    T = A.shape[0]
    h = window // 2
    if T > 1:
        idx = np.arange(-h, T + h)
        # 'reflect' (d c b a | a b c d | d c b a); for windows longer than the clip repeat it
        period = 2 * T
        idx = np.mod(idx, period)
        idx = np.where(idx >= T, period - 1 - idx, idx)
        P = A[idx]
    else:
        P = np.repeat(A, 2 * h + 1, axis=0)
    med = np.empty_like(A)
    mad = np.empty_like(A)
    for s in range(0, T, chunk):
        e = min(T, s + chunk)
        W = sliding_window_view(P[s:e + 2 * h], window, axis=0)        # (n, C, window)
        if exclude_center:
            W = np.delete(W, h, axis=-1)
        mm = np.median(W, axis=-1)
        med[s:e] = mm
        mad[s:e] = np.median(np.abs(W - mm[..., None]), axis=-1)
    return med, mad


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
    window = int(window)
    if window < 3 or window % 2 == 0:
        raise MocapValueError(f"hampel window must be an odd number of frames >= 3, got {window}")
    if scale not in ("local", "global", "both"):
        raise MocapValueError(f"scale must be 'local', 'global' or 'both', got {scale!r}")
    A, shape, axis = _as_2d(X, axis)
    _require_finite(A, "the Hampel filter")
    med, mad = _rolling_median_mad(A, window, exclude_center=exclude_center)
    res = A - med
    loc = 1.4826 * mad
    r0 = np.median(res, axis=0)
    glob = np.broadcast_to(1.4826 * np.median(np.abs(res - r0), axis=0), A.shape)
    out = []
    for sig in ((glob, loc) if scale == "both" else (glob,) if scale == "global" else (loc,)):
        out.append(_restore(np.maximum(sig, float(min_sigma)), shape, axis))
    sig = np.stack(out) if scale == "both" else out[0]
    return _restore(med, shape, axis), _restore(res, shape, axis), sig


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


# ---------------------------------------------------------------------------------------
# noise estimates
# ---------------------------------------------------------------------------------------
def _robust_var_of_diff(A: np.ndarray, M: np.ndarray | None, coeffs: Sequence[float], lag: int) -> np.ndarray:
    """Per-channel robust variance (1.4826 MAD)^2 of sum_i coeffs[i] * x[t + i*lag], using
    only terms whose samples are all observed. NaN for channels with no usable term."""
    k = len(coeffs)
    T = A.shape[0]
    span = (k - 1) * lag
    if T <= span:
        return np.full(A.shape[1], np.nan)
    D = sum(c * A[i * lag:T - span + i * lag] for i, c in enumerate(coeffs))
    if M is not None:
        ok = np.logical_and.reduce([M[i * lag:T - span + i * lag] for i in range(k)])
        D = np.where(ok, D, np.nan)
    with np.errstate(invalid="ignore"):
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(D, axis=0)
            mad = np.nanmedian(np.abs(D - med), axis=0)
    return (1.4826 * mad) ** 2


_DIFF = {1: (1.0, -1.0), 2: (1.0, -2.0, 1.0), 3: (-1.0, 3.0, -3.0, 1.0)}


def estimate_noise_sigma(X, mask=None, /, *, axis: int = 0) -> np.ndarray:
    """Per-channel white-noise sigma from second differences: ``1.4826 MAD(Δ²x) / √6``.

    Δ² of white noise of std σ has std √6 σ, while a smooth motion sampled at 30-120 fps
    contributes little to Δ² (|a| dt², e.g. 0.04 cm at 120 fps for a 500 cm/s² swing), so
    this is a near-unbiased estimate for noise well above that level; the MAD makes it
    insensitive to a minority of spikes. Only second differences of three observed
    samples are used. Returns (C,) -- NaN for a channel with no three consecutive
    observed samples. Units as the data.
    """
    A, shape, axis = _as_2d(X, axis)
    M = None if mask is None else np.moveaxis(np.asarray(mask, bool), axis, 0).reshape(A.shape[0], -1) & np.isfinite(A)
    v = _robust_var_of_diff(A, M, _DIFF[2], 1)
    out = np.sqrt(v / 6.0)
    return out.reshape(shape[1:]) if len(shape) > 1 else out


# ---------------------------------------------------------------------------------------
# state-space models
# ---------------------------------------------------------------------------------------
def cv_model(dt: float, q, *, order: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Transition F (n, n) and process covariance Q (..., n, n) of a continuous
    white-noise-driven kinematic model sampled every ``dt`` seconds (Bar-Shalom, Li &
    Kirubarajan 2001, §6.2-6.3).

    order 2 -- constant velocity, state (position, velocity), q = acceleration spectral
    density: Q = q [[dt³/3, dt²/2], [dt²/2, dt]].
    order 3 -- constant acceleration, state (position, velocity, acceleration), q = jerk
    spectral density: Q = q [[dt⁵/20, dt⁴/8, dt³/6], [dt⁴/8, dt³/3, dt²/2], [dt³/6, dt²/2, dt]].
    order 1 -- random walk, F = [[1]], Q = q dt.
    ``q`` may be an array (C,): Q then has shape (C, n, n).
    """
    d = float(dt)
    if order == 1:
        F = np.eye(1)
        Q0 = np.array([[d]])
    elif order == 2:
        F = np.array([[1.0, d], [0.0, 1.0]])
        Q0 = np.array([[d ** 3 / 3, d ** 2 / 2], [d ** 2 / 2, d]])
    elif order == 3:
        F = np.array([[1.0, d, d * d / 2], [0.0, 1.0, d], [0.0, 0.0, 1.0]])
        Q0 = np.array([[d ** 5 / 20, d ** 4 / 8, d ** 3 / 6],
                       [d ** 4 / 8, d ** 3 / 3, d ** 2 / 2],
                       [d ** 3 / 6, d ** 2 / 2, d]])
    else:
        raise MocapValueError(f"order must be 1, 2 or 3, got {order!r}")
    q = np.asarray(q, dtype=float)
    return F, q[..., None, None] * Q0


def random_walk_model(q) -> tuple[np.ndarray, np.ndarray]:
    """Lou & Chai's identity dynamics z(t+1) = z(t) + N(0, q): F = [[1]], Q = [[q]]
    (q: per-frame variance, scalar or (C,))."""
    q = np.asarray(q, dtype=float)
    return np.eye(1), q[..., None, None] * np.ones((1, 1))


def gate_threshold(n_sigmas: float, dof) -> np.ndarray:
    """Chi-square threshold on a squared Mahalanobis distance with ``dof`` degrees of
    freedom that is exceeded with the same probability as a two-sided ``n_sigmas``
    deviation of one Gaussian variable (e.g. 5 -> p = 5.7e-7)."""
    from scipy.special import chdtri, ndtr

    p = 2.0 * ndtr(-float(n_sigmas))
    dof = np.maximum(np.asarray(dof, dtype=float), 1.0)
    return chdtri(dof, p)


def cutoff_to_q(cutoff_hz, *, r, dt: float, order: int = 2):
    """Process-noise spectral density q giving a steady-state smoother with -6 dB point
    ``cutoff_hz``: for an ``order``-times integrated white noise of density q observed in
    white noise of variance r every dt seconds (noise density r dt), the Wiener smoother
    is H(w) = 1 / (1 + r dt w^(2 order) / q), so q = r dt (2 pi f_c)^(2 order)
    (cm²/s³ for order 2; cm²/s for order 1 -- multiply by dt for a per-frame variance)."""
    w = 2.0 * np.pi * np.asarray(cutoff_hz, dtype=float)
    return np.asarray(r, dtype=float) * dt * w ** (2 * order)


def select_process_noise(Y, mask=None, /, *, dt: float, r, order: int = 2,
                         grid_hz=None, huber: float = 3.0, max_frames: int = 1200,
                         x0=None) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel process noise q of a kinematic model (:func:`cv_model`) by maximising
    a robustified innovation log-likelihood over a grid of smoother cutoffs.

    For each candidate cutoff f (``grid_hz``; default 10 values from 0.25 Hz to 16 Hz by
    factors of 2^(2/3), those below fps/2.5) the q of :func:`cutoff_to_q` is tried on every channel
    at once (one batched forward Kalman pass over C x len(grid) filters) and scored by
    the prediction-error decomposition  -1/2 Σ_t [log S_t + ρ(ν_t² / S_t)], with ρ the
    Huber function at ``huber`` sigmas (so a minority of spikes does not drive the
    choice). The best grid point is refined by a parabola through its neighbours (in
    log f). Only the first ``max_frames`` frames are used.

    Returns q (C,) and the chosen cutoffs in Hz (C,).
    """
    A, shape, axis = _as_2d(Y, 0)
    A = A[:max_frames]
    T, C = A.shape
    M = np.isfinite(A) if mask is None else (np.asarray(mask, bool).reshape(shape[0], -1)[:max_frames] & np.isfinite(A))
    fs = 1.0 / dt
    if grid_hz is None:
        grid_hz = 0.25 * 2.0 ** (np.arange(10) * 2 / 3)
        grid_hz = grid_hz[grid_hz < fs / 2.5]
        if grid_hz.size < 3:
            grid_hz = np.geomspace(0.05 * fs, 0.4 * fs, 5)
    g = np.asarray(grid_hz, dtype=float)
    G = g.size
    rr = np.broadcast_to(np.asarray(r, float), (C,))
    q = cutoff_to_q(g[:, None], r=rr[None, :], dt=dt, order=order)        # (G, C)
    F, Qm = cv_model(dt, q.reshape(-1), order=order)                      # (G*C, n, n)
    n = F.shape[0]
    Yb = np.tile(np.where(M, A, 0.0), (1, G))                             # (T, G*C)
    Mb = np.tile(M, (1, G))
    Rb = np.tile(rr, G)
    x = np.zeros((G * C, n))
    if x0 is None:
        first = np.argmax(M, axis=0)
        x[:, 0] = np.tile(A[first, np.arange(C)], G)
    else:
        x[:, 0] = np.tile(np.asarray(x0, float).reshape(C), G)
    c2 = float(huber) ** 2
    NU = np.empty((T, G * C))           # innovations and their variances, scored after the loop
    SS = np.empty((T, G * C))
    if n <= 2:      # 2x2 algebra on component arrays (as _rts_scalar)
        d = float(F[0, 1]) if n == 2 else 0.0
        f00 = float(F[0, 0])
        q00 = np.ascontiguousarray(Qm[:, 0, 0])
        if n == 2:
            q01, q11 = np.ascontiguousarray(Qm[:, 0, 1]), np.ascontiguousarray(Qm[:, 1, 1])
            x1 = np.zeros(G * C)
            p01 = np.zeros(G * C)
            p11 = np.full(G * C, 1e6)
        x0_ = x[:, 0].copy()
        p00 = np.full(G * C, 1e4)
        for t in range(T):
            if t > 0:
                if n == 2:      # F = [[1, d], [0, 1]]
                    x0_ = x0_ + d * x1
                    p00 = p00 + 2 * d * p01 + d * d * p11 + q00
                    p01 = p01 + d * p11 + q01
                    p11 = p11 + q11
                else:
                    x0_ = f00 * x0_
                    p00 = f00 * f00 * p00 + q00
            S = p00 + Rb
            nu = Yb[t] - x0_
            m = Mb[t]
            NU[t] = nu
            SS[t] = S
            inv_s = np.where(m, 1.0 / S, 0.0)
            k0 = p00 * inv_s
            x0_ = x0_ + k0 * nu
            if n == 2:
                k1 = p01 * inv_s
                x1 = x1 + k1 * nu
                p11 = p11 - k1 * p01
                p01 = p01 - k0 * p01
            p00 = p00 - k0 * p00
    else:
        P = np.broadcast_to(np.diag([1e4, 1e6, 1e8][:n]), (G * C, n, n)).copy()
        FT = F.T
        for t in range(T):
            if t > 0:
                x = x @ FT
                P = F @ P @ FT + Qm
            HP = P[:, 0, :]
            S = HP[:, 0] + Rb
            nu = Yb[t] - x[:, 0]
            m = Mb[t]
            NU[t] = nu
            SS[t] = S
            K = np.where(m, 1.0 / S, 0.0)[:, None] * HP
            x = x + K * nu[:, None]
            P = P - K[:, :, None] * HP[:, None, :]
    u = NU[2:] ** 2 / SS[2:]                   # frames 0, 1 only set the state up
    rho = np.where(u <= c2, u, 2.0 * np.sqrt(c2 * u) - c2)
    ll = -np.where(Mb[2:], 0.5 * (np.log(SS[2:]) + rho), 0.0).sum(axis=0)
    L = ll.reshape(G, C)
    best = np.argmax(L, axis=0)
    logf = np.log(g)
    out = logf[best].copy()
    inner = (best > 0) & (best < G - 1)
    if inner.any():
        i = best[inner]
        cols = np.flatnonzero(inner)
        y0, y1, y2 = L[i - 1, cols], L[i, cols], L[i + 1, cols]
        den = y0 - 2 * y1 + y2
        h = logf[1] - logf[0]
        with np.errstate(invalid="ignore", divide="ignore"):
            off = np.where(den < 0, 0.5 * (y0 - y2) / den, 0.0)
        out[cols] = logf[i] + np.clip(off, -0.5, 0.5) * h
    fc = np.exp(out)
    return cutoff_to_q(fc, r=rr, dt=dt, order=order), fc


# ---------------------------------------------------------------------------------------
# Kalman filter + RTS smoother
# ---------------------------------------------------------------------------------------
def _inv_small(P: np.ndarray) -> np.ndarray:
    """Inverse of a batch (..., n, n) of SPD matrices; closed form for n <= 2."""
    n = P.shape[-1]
    if n == 1:
        return 1.0 / P
    if n == 2:
        a, b, c, d = P[..., 0, 0], P[..., 0, 1], P[..., 1, 0], P[..., 1, 1]
        det = a * d - b * c
        out = np.empty_like(P)
        out[..., 0, 0] = d / det
        out[..., 0, 1] = -b / det
        out[..., 1, 0] = -c / det
        out[..., 1, 1] = a / det
        return out
    return np.linalg.inv(P)


def steady_state_covariance(F, Q, H, R, *, tol: float = 1e-12, max_iter: int = 100) -> np.ndarray:
    """Steady-state *predicted* covariance P of the Kalman filter for
    ``x' = F x + w`` (w ~ N(0, Q)), ``y = H x + v`` (v ~ N(0, R)): the stabilising
    solution of the filter Riccati equation

        P = F P Fᵀ - F P Hᵀ (H P Hᵀ + R)⁻¹ H P Fᵀ + Q,

    by the structure-preserving doubling algorithm (Chu, Fan, Lin & Wang 2004): with
    A0 = Fᵀ, G0 = Hᵀ R⁻¹ H, H0 = Q, iterate  W = I + G H,
    A ← A W⁻¹ A,  G ← G + A W⁻¹ G Aᵀ,  H ← H + Aᵀ H W⁻¹ A  (old A on the right-hand
    sides); H converges quadratically to P (stops at relative change ``tol``, or when
    rounding stalls it below 1e-8). Unlike scipy's QZ-based ``solve_discrete_are`` it
    copes with a nearly singular Q (e.g. the deterministic lag block of a second-order
    model, where QZ reordering fails).
    ``R``: (p,) variances or (p, p). Raises ``np.linalg.LinAlgError`` without convergence.
    """
    F = np.asarray(F, dtype=float)
    H = np.asarray(H, dtype=float)
    R = np.asarray(R, dtype=float)
    Ri = np.diag(1.0 / R) if R.ndim == 1 else np.linalg.inv(R)
    A = F.T.copy()
    G = H.T @ Ri @ H
    X = np.array(Q, dtype=float, copy=True)
    n = A.shape[0]
    I = np.eye(n)
    prev = np.inf
    for it in range(max_iter):
        W = I + G @ X
        WiA = np.linalg.solve(W, A)                      # W⁻¹ A
        WiG = np.linalg.solve(W, G)                      # W⁻¹ G
        A_new = A @ WiA
        G_new = G + A @ WiG @ A.T
        X_new = X + A.T @ X @ WiA
        X_new = 0.5 * (X_new + X_new.T)
        G_new = 0.5 * (G_new + G_new.T)
        scale = max(np.abs(X_new).max(), 1e-300)
        diff = np.abs(X_new - X).max() / scale
        A, G, X = A_new, G_new, X_new
        if not np.isfinite(X).all():
            break
        # converged, or stalled at the rounding floor (quadratic convergence stops)
        if diff <= tol or (it > 3 and diff >= prev and diff <= 1e-8):
            return X
        prev = diff
    raise np.linalg.LinAlgError("steady-state Riccati iteration did not converge")


def _is_e0(h: np.ndarray) -> bool:
    return h.shape[0] >= 1 and h[0] == 1.0 and not h[1:].any()


class _Gate:
    """Innovation gate shared by the filter loops: per group of batch members, reject
    when the summed squared Mahalanobis distance exceeds the chi-square threshold for
    the group's observed dof; a group rejected ``max_run`` frames in a row is accepted
    the next time (so the filter cannot lose a marker for good after a true sudden
    movement and then reject everything that follows)."""

    def __init__(self, n_sigmas: float, groups, B: int, p: int, max_run: int | None):
        g = np.arange(B) if groups is None else np.asarray(groups).reshape(B)
        self.ginv = np.unique(g, return_inverse=True)[1].reshape(B)
        self.n_groups = int(self.ginv.max()) + 1
        max_dof = int(np.bincount(self.ginv, minlength=self.n_groups).max()) * p
        self.thr = gate_threshold(n_sigmas, np.arange(max_dof + 1))
        self.run = np.zeros(self.n_groups, dtype=np.int64)
        self.max_run = None if max_run is None else int(max_run)

    def reject(self, d2: np.ndarray, dof: np.ndarray) -> np.ndarray:
        """d2, dof: (B,) squared distances and observed dimensions -> (B,) bool reject."""
        gd2 = np.bincount(self.ginv, weights=d2, minlength=self.n_groups)
        gdof = np.bincount(self.ginv, weights=dof, minlength=self.n_groups).astype(np.int64)
        bad = (gd2 > self.thr[gdof]) & (gdof > 0)
        if self.max_run is not None:
            bad &= self.run < self.max_run
        self.run = np.where(bad, self.run + 1, np.where(gdof > 0, 0, self.run))
        return bad[self.ginv]


def rts_smoother(Y, mask=None, /, *, F, Q, R, H=None, b=None, x0=None, P0=None,
                 gate: float | None = None, gate_groups=None, gate_max_run: int | None = 3,
                 return_cov: bool = False):
    """Kalman filter + Rauch-Tung-Striebel smoother for a batch of B independent
    linear-Gaussian state-space models sharing their time axis:

        x[t+1] = F x[t] + b + w,   w ~ N(0, Q)          (state, n dims)
        y[t]   = H x[t] + v,       v ~ N(0, diag(R))    (observation, p dims)
        x[0]   ~ N(x0, P0)

    Observations marked missing contribute nothing (the update step is skipped for them:
    "masked observation matrix" -- row i of H is dropped where y_i is missing).

    Parameters
    ----------
    Y : (T, B, p) observations (or (T, B) when p = 1); missing values may be NaN.
    mask : bool like Y, True = observed (default: finite).
    F : (n, n) or (B, n, n) transition.   Q : (n, n) or (B, n, n) process covariance.
    R : observation noise variances: scalar, (p,), (B,) if p = 1, or (B, p).
    H : (p, n) observation matrix (default: first state component, p = 1).
    b : optional (n,) or (B, n) drift.
    x0, P0 : prior of the first state, (B, n) / (B, n, n) or (n,) / (n, n);
        default x0 = 0 and P0 = 1e8 I (effectively diffuse).
    gate : optional outlier gate in "sigmas": an observation vector whose innovation has
        a squared Mahalanobis distance above :func:`gate_threshold` (gate, dof) is
        treated as missing (forward pass decides; the backward pass uses the decision).
    gate_groups : optional int array (B,) -- batch members with the same id are gated
        together on the sum of their squared distances (e.g. the x, y, z filters of one
        marker: a 3-dof test), which catches a 3-D spike with much better power than
        three 1-dof tests.
    gate_max_run : after this many consecutive rejected frames a group's next
        observation is accepted whatever its distance (default 3; None = never), so a
        filter that fell behind a real sudden movement re-acquires the marker instead of
        rejecting it for the rest of the clip.
    return_cov : also return the smoothed covariances (T, B, n, n).

    Returns
    -------
    xs : (T, B, n) smoothed state means (the posterior means given all observations).
    used : (T, B, p) bool -- observations actually used (mask minus gated).
    Ps : (T, B, n, n), only with ``return_cov``.

    Notes
    -----
    Three code paths, same result (tests compare each with a dense solve):

    * p = 1, n <= 2, H = first state, shared F (per-coordinate constant-velocity or
      random-walk filters): the 2 x 2 algebra written out on (B,) component arrays, RTS
      gains for all frames in one vectorised step (:func:`_rts_scalar`);
    * p > n, or a single vector-observed model (B = 1) without gate (e.g. a PCA-latent
      pose model): :func:`_rts_multi` -- information or Woodbury form, Hᵀ W H
      precomputed per mask pattern, covariances reused once the Riccati recursion is
      stationary;
    * otherwise the plain gain form ``K = P Hᵀ S⁻¹`` batched over B.

    The smoothed mean needs only the filtered covariances (``G = P_f Fᵀ P_pred⁻¹``);
    smoothed covariances are computed only when asked for.
    """
    Yo = np.asarray(Y, dtype=float)
    squeeze_p = Yo.ndim == 2
    if squeeze_p:
        Yo = Yo[:, :, None]
    if Yo.ndim != 3:
        raise MocapValueError(f"Y must have shape (T, B) or (T, B, p), got {np.shape(Y)}")
    T, B, p = Yo.shape
    if mask is None:
        Mk = np.isfinite(Yo)
    else:
        Mk = np.asarray(mask, dtype=bool).reshape(Yo.shape) & np.isfinite(Yo)
    F = np.asarray(F, dtype=float)
    n = F.shape[-1]
    H = np.eye(1, n) if H is None else np.asarray(H, dtype=float)
    if H.shape != (p, n):
        raise MocapValueError(f"H must have shape ({p}, {n}), got {H.shape}")
    Fb = np.broadcast_to(F, (B, n, n))
    Qb = np.broadcast_to(np.asarray(Q, dtype=float), (B, n, n))
    Rv = np.asarray(R, dtype=float)
    if Rv.ndim == 1 and p == 1 and Rv.shape[0] == B:
        Rv = Rv[:, None]
    Rb = np.broadcast_to(Rv, (B, p)).astype(float)
    if (Rb <= 0).any():
        raise MocapValueError("observation noise variances R must be positive")
    bb = None if b is None else np.broadcast_to(np.asarray(b, dtype=float), (B, n))
    x = np.zeros((B, n)) if x0 is None else np.broadcast_to(np.asarray(x0, float), (B, n)).copy()
    P = 1e8 * np.broadcast_to(np.eye(n), (B, n, n)).copy() if P0 is None else \
        np.broadcast_to(np.asarray(P0, float), (B, n, n)).copy()
    if (p == 1 and n <= 2 and F.ndim == 2 and bb is None and _is_e0(H[0])
            and not return_cov):
        gt = None if gate is None else _Gate(gate, gate_groups, B, 1, gate_max_run)
        xs, u = _rts_scalar(Yo[:, :, 0], Mk[:, :, 0], F, Qb, Rb[:, 0], x, P, gt)
        return xs, (u if squeeze_p else u[:, :, None])
    Y0 = np.where(Mk, Yo, 0.0)
    used = Mk.copy()

    gt = None if gate is None else _Gate(gate, gate_groups, B, p, gate_max_run)

    xf = np.empty((T, B, n))
    Pf = np.empty((T, B, n, n))
    xp = np.empty((T, B, n))
    Pp = np.empty((T, B, n, n))
    FT = np.swapaxes(Fb, -1, -2)
    info_form = p > n
    if gate is None and p > 1 and (info_form or B == 1):
        out = _rts_multi(Y0, used, Fb, Qb, H, Rb, bb, x, P, return_cov)
        if squeeze_p:
            out = (out[0], used[:, :, 0]) + tuple(out[2:])
        else:
            out = (out[0], used) + tuple(out[2:])
        return out if return_cov else out[:2]
    shared_F = F.ndim == 2
    h = H[0]
    Rb1 = Rb[:, 0]

    for t in range(T):
        if t > 0:
            if shared_F:
                x = x @ F.T
                P = F @ P @ F.T + Qb
            else:
                x = np.einsum("bij,bj->bi", Fb, x)
                P = Fb @ P @ FT + Qb
            if bb is not None:
                x = x + bb
        xp[t] = x
        Pp[t] = P
        m = used[t]                                                  # (B, p)
        if m.any():
            if p == 1:
                # scalar observations: K = P h / (h P h + r), no matrix inverse
                HP = P[:, 0, :] if _is_e0(h) else np.einsum("n,bnk->bk", h, P)   # (B, n)
                S = (HP[:, 0] if _is_e0(h) else HP @ h) + Rb1                       # (B,)
                nu = Y0[t, :, 0] - (x[:, 0] if _is_e0(h) else x @ h)
                mt = m[:, 0]
                if gt is not None:
                    reject = gt.reject(np.where(mt, nu * nu / S, 0.0), mt) & mt
                    if reject.any():
                        used[t, reject, 0] = False
                        mt = used[t, :, 0]
                K = np.where(mt[:, None], HP / S[:, None], 0.0)              # (B, n)
                x = x + K * nu[:, None]
                P = P - K[:, :, None] * HP[:, None, :]
            else:
                HP = np.einsum("pn,bnk->bpk", H, P)                   # (B, p, n)
                S = np.einsum("bpk,qk->bpq", HP, H)                   # (B, p, p)
                nu = Y0[t] - x @ H.T                                  # (B, p)
                # missing rows: decouple and zero so they change nothing
                mm = m[:, :, None] & m[:, None, :]
                eye = np.eye(p, dtype=bool)[None]
                S = np.where(mm, S, 0.0) + np.where(eye, np.where(m[:, :, None], Rb[:, :, None], 1.0), 0.0)
                nu = np.where(m, nu, 0.0)
                Sinv = _inv_small(S)
                if gt is not None:
                    reject = gt.reject(np.einsum("bp,bpq,bq->b", nu, Sinv, nu), m.sum(axis=1))
                    if reject.any():
                        used[t, reject] = False
                        m = used[t]
                        nu = np.where(m, nu, 0.0)
                HPm = np.where(m[:, :, None], HP, 0.0)
                K = np.einsum("bpn,bpq->bnq", HPm, Sinv)               # (B, n, p)
                x = x + np.einsum("bnq,bq->bn", K, nu)
                P = P - K @ HPm
            P = 0.5 * (P + np.swapaxes(P, -1, -2))
        xf[t] = x
        Pf[t] = P

    xs = np.empty_like(xf)
    xs[-1] = xf[-1]
    if return_cov:
        Ps = np.empty_like(Pf)
        Ps[-1] = Pf[-1]
    PfFT = Pf @ F.T if shared_F else None
    for t in range(T - 2, -1, -1):
        G = (PfFT[t] if shared_F else Pf[t] @ FT) @ _inv_small(Pp[t + 1])   # (B, n, n)
        xs[t] = xf[t] + (G @ (xs[t + 1] - xp[t + 1])[:, :, None])[:, :, 0]
        if return_cov:
            Ps[t] = Pf[t] + G @ (Ps[t + 1] - Pp[t + 1]) @ np.swapaxes(G, -1, -2)
    if squeeze_p:
        used = used[:, :, 0]
    if return_cov:
        return xs, used, Ps
    return xs, used


def _rts_multi(Y0, used, F, Q, H, R, b, x, P, return_cov, tol=1e-8):
    """Kalman filter + RTS smoother for vector observations with missing entries
    (W = diag(mask / R)), used when p > n or B = 1.

    Filtered covariance per frame: information form ``P⁺ = (P⁻¹ + Hᵀ W H)⁻¹`` (n x n
    inverses) when at least n channels are observed, else the Woodbury/gain form
    ``P⁺ = P - P Hₒᵀ (Hₒ P Hₒᵀ + Rₒ)⁻¹ Hₒ P`` on the p_o observed rows (p_o x p_o
    inverse; needs no inverse of P, which may be nearly singular, e.g. the lag block of
    a second-order model). Either way the mean update is ``x⁺ = x + P⁺ (Hᵀ W y - Hᵀ W H x)``
    with Hᵀ W H computed once per distinct mask pattern and Hᵀ W y for all frames in one
    product.

    Steady state: when the predicted covariance stops changing (largest entry change
    below ``tol`` x its largest entry) while the mask pattern stays the same, the
    covariances and gains of the previous frame are reused (the Riccati recursion has
    converged), so long stretches of complete frames cost a few matrix-vector products
    per frame and no inverse; the backward pass reuses its gain the same way.
    """
    T, B, p = Y0.shape
    n = F.shape[-1]
    W = np.where(used, 1.0 / R[None], 0.0)                          # (T, B, p)
    hy = (W * Y0) @ H                                               # (T, B, n)
    pats, pat = np.unique(W.reshape(T, -1), axis=0, return_inverse=True)
    pat = pat.reshape(T)
    pats = pats.reshape(-1, B, p)
    Jpat = np.matmul(H.T[None, None] * pats[:, :, None, :], H)      # (U, B, n, n)
    FT = np.swapaxes(F, -1, -2)
    xf = np.empty((T, B, n))
    xp = np.empty((T, B, n))
    covs_p: list[np.ndarray] = []
    covs_f: list[np.ndarray] = []
    idx_p = np.empty(T, dtype=np.int64)
    idx_f = np.empty(T, dtype=np.int64)
    steady = False
    for t in range(T):
        if t > 0:
            x = np.einsum("bij,bj->bi", F, x)
            if b is not None:
                x = x + b
        same = t > 0 and pat[t] == pat[t - 1]
        if steady and same:
            idx_p[t], idx_f[t] = idx_p[t - 1], idx_f[t - 1]
        else:
            Ppred = F @ P @ FT + Q if t > 0 else P
            if same and np.abs(Ppred - covs_p[idx_p[t - 1]]).max() <= tol * np.abs(Ppred).max():
                steady = True
                idx_p[t], idx_f[t] = idx_p[t - 1], idx_f[t - 1]
            else:
                steady = False
                w = pats[pat[t]]                                    # (B, p)
                if B == 1 and (w[0] > 0).sum() < n:
                    o = np.flatnonzero(w[0] > 0)
                    Ho = H[o]
                    PH = Ppred[0] @ Ho.T                            # (n, p_o)
                    S = Ho @ PH + np.diag(1.0 / w[0, o])
                    Pn = (Ppred[0] - PH @ np.linalg.solve(S, PH.T))[None] if o.size else Ppred.copy()
                else:
                    Pn = np.linalg.inv(np.linalg.inv(Ppred) + Jpat[pat[t]])
                Pn = 0.5 * (Pn + np.swapaxes(Pn, -1, -2))
                covs_p.append(Ppred)
                covs_f.append(Pn)
                idx_p[t] = idx_f[t] = len(covs_f) - 1
        Pn = covs_f[idx_f[t]]
        xp[t] = x
        iv = hy[t] - np.einsum("bnk,bk->bn", Jpat[pat[t]], x)
        x = x + np.einsum("bnk,bk->bn", Pn, iv)
        P = Pn
        xf[t] = x
    xs = np.empty_like(xf)
    xs[-1] = xf[-1]
    if return_cov:
        Ps = np.empty((T, B, n, n))
        Ps[-1] = covs_f[idx_f[-1]]
    key_prev, G = None, None
    for t in range(T - 2, -1, -1):
        key = (int(idx_f[t]), int(idx_p[t + 1]))
        if key != key_prev:                                        # G = P_f Fᵀ P_pred⁻¹
            G = np.swapaxes(np.linalg.solve(covs_p[key[1]], F @ covs_f[key[0]]), -1, -2)
            key_prev = key
        xs[t] = xf[t] + np.einsum("bij,bj->bi", G, xs[t + 1] - xp[t + 1])
        if return_cov:
            Ps[t] = covs_f[key[0]] + G @ (Ps[t + 1] - covs_p[key[1]]) @ np.swapaxes(G, -1, -2)
    if return_cov:
        return xs, used, Ps
    return xs, used


_RTS_STORE_BYTES = 64 << 20
"""Up to this size (48 bytes per frame and channel) :func:`_rts_scalar` keeps the filtered and
predicted covariances of every frame; above it (e.g. 100,000 frames x 93 channels: 446 MB)
they are recomputed block by block in the backward pass (~20 % more time, same numbers)."""

_RTS_BLOCK = 1024
"""Frames per block of the vectorised RTS gain computation in :func:`_rts_scalar` (the
block's covariances are recomputed from a checkpoint, :func:`_rts2_backward`)."""


def _rts_scalar(Y, M, F, Q, R, x0, P0, gt):
    """Fast path of :func:`rts_smoother` for n <= 2 states, one scalar observation of the
    first state and a transition shared by the batch: the 2 x 2 algebra is written out on
    (B,) component arrays (about 40 vector operations per frame for both passes)."""
    T, B = Y.shape
    n = F.shape[0]
    used = M.copy()
    if n == 1:
        f = float(F[0, 0])
        q = np.ascontiguousarray(Q[:, 0, 0])
        x = x0[:, 0].copy()
        P = P0[:, 0, 0].copy()
        xf = np.empty((T, B)); Pf = np.empty((T, B)); Pp = np.empty((T, B))
        for t in range(T):
            if t > 0:
                x = f * x
                P = f * f * P + q
            Pp[t] = P
            m = used[t]
            S = P + R
            nu = np.where(m, Y[t], 0.0) - x
            if gt is not None:
                m = m & ~gt.reject(np.where(m, nu * nu / S, 0.0), m)
                used[t] = m
            k = np.where(m, P / S, 0.0)
            x = x + k * nu
            P = P - k * P
            xf[t] = x; Pf[t] = P
        xs = np.empty_like(xf)
        xs[-1] = xf[-1]
        G = Pf[:-1] * f / Pp[1:]
        for t in range(T - 2, -1, -1):
            xs[t] = xf[t] + G[t] * (xs[t + 1] - f * xf[t])
        return xs[:, :, None], used
    f00, f01, f10, f11 = (float(v) for v in F.ravel())
    fq = (f00, f01, f10, f11) + tuple(np.ascontiguousarray(Q[:, i, j]) for i, j in ((0, 0), (0, 1), (1, 1)))
    x0_, x1_ = x0[:, 0].copy(), x0[:, 1].copy()
    pc = (P0[:, 0, 0].copy(), P0[:, 0, 1].copy(), P0[:, 1, 1].copy())
    XF = np.empty((T, 2, B))
    marks = {}                                   # predicted covariance at every block start
    store = 48 * T * B <= _RTS_STORE_BYTES       # short clips: keep covariances, no recompute
    PF, PN = (np.empty((T, 3, B)), np.empty((T, 3, B))) if store else (None, None)
    for t in range(T):
        if t > 0:
            x0_, x1_ = f00 * x0_ + f01 * x1_, f10 * x0_ + f11 * x1_
            pc = _cv2_predict(pc, fq)
            if store:
                PN[t - 1] = pc
        if t % _RTS_BLOCK == 0:
            marks[t] = pc
        m = used[t]
        S = pc[0] + R
        nu = np.where(m, Y[t], 0.0) - x0_
        if gt is not None:
            m = m & ~gt.reject(np.where(m, nu * nu / S, 0.0), m)
            used[t] = m
        inv_s = np.where(m, 1.0 / S, 0.0)
        x0_ = x0_ + pc[0] * inv_s * nu
        x1_ = x1_ + pc[1] * inv_s * nu
        pc = _cv2_update(pc, inv_s)
        XF[t, 0] = x0_; XF[t, 1] = x1_
        if store:
            PF[t] = pc
    _rts2_backward(XF, used, R, fq, marks, None if PF is None else (PF, PN))
    return np.moveaxis(XF, 1, 2), used


def _cv2_predict(pc: tuple, fq: tuple) -> tuple:
    """Predicted 2 x 2 covariance F P F^T + Q on (B,) components (p00, p01, p11)."""
    p00, p01, p11 = pc
    f00, f01, f10, f11, q00, q01, q11 = fq
    a = f00 * p00 + f01 * p01
    b = f00 * p01 + f01 * p11
    c = f10 * p00 + f11 * p01
    e = f10 * p01 + f11 * p11
    return a * f00 + b * f01 + q00, a * f10 + b * f11 + q01, c * f10 + e * f11 + q11


def _cv2_update(pc: tuple, inv_s: np.ndarray) -> tuple:
    """Filtered covariance after observing the first state (gain k = P e0 / S)."""
    p00, p01, p11 = pc
    k0 = p00 * inv_s
    k1 = p01 * inv_s
    return p00 - k0 * p00, p01 - k0 * p01, p11 - k1 * p01


def _rts2_backward(XF: np.ndarray, used: np.ndarray, R: np.ndarray, fq: tuple,
                   marks: dict, stored: tuple | None = None) -> None:
    """RTS backward pass of :func:`_rts_scalar`, overwriting the filtered means XF (T, 2, B)
    with the smoothed ones.

    Covariances are not stored for all frames: each block of _RTS_BLOCK frames recomputes
    its filtered / predicted covariances from the predicted covariance saved at its start
    (``marks``) with the same operations as the forward pass (:func:`_cv2_predict`,
    :func:`_cv2_update`; bit-identical), then the gains G = Pf Fᵀ Pp[t+1]⁻¹ of the block
    are formed in one vectorised step.  Memory: O(block x B) besides XF.  ``stored``
    (PF, PN) (T, 3, B): the forward pass kept them (short clips), nothing is recomputed.
    """
    T, _, B = XF.shape
    f00, f01, f10, f11 = fq[:4]
    s0, s1 = XF[-1, 0].copy(), XF[-1, 1].copy()
    for lo in range(((T - 2) // _RTS_BLOCK) * _RTS_BLOCK, -1, -_RTS_BLOCK):
        hi = min(lo + _RTS_BLOCK, T - 1)                 # gains for t in [lo, hi)
        if stored is not None:
            PF, PN = stored[0][lo:hi], stored[1][lo:hi]
        else:
            PF, PN = np.empty((hi - lo, 3, B)), np.empty((hi - lo, 3, B))
            pc = marks[lo]
            for t in range(lo, hi):
                S = pc[0] + R
                pc = _cv2_update(pc, np.where(used[t], 1.0 / S, 0.0))
                PF[t - lo] = pc
                pc = _cv2_predict(pc, fq)
                PN[t - lo] = pc
        a00, a01, a11 = PF[:, 0], PF[:, 1], PF[:, 2]
        c00 = a00 * f00 + a01 * f01; c01 = a00 * f10 + a01 * f11      # Pf Fᵀ (2x2, not symmetric)
        c10 = a01 * f00 + a11 * f01; c11 = a01 * f10 + a11 * f11
        b00, b01, b11 = PN[:, 0], PN[:, 1], PN[:, 2]
        det = b00 * b11 - b01 * b01
        i00, i01, i11 = b11 / det, -b01 / det, b00 / det
        g00 = c00 * i00 + c01 * i01; g01 = c00 * i01 + c01 * i11
        g10 = c10 * i00 + c11 * i01; g11 = c10 * i01 + c11 * i11
        # predicted means x_pred[t+1] = F x_f[t]
        xp0 = f00 * XF[lo:hi, 0] + f01 * XF[lo:hi, 1]
        xp1 = f10 * XF[lo:hi, 0] + f11 * XF[lo:hi, 1]
        for t in range(hi - 1, lo - 1, -1):
            k = t - lo
            d0 = s0 - xp0[k]
            d1 = s1 - xp1[k]
            s0 = XF[t, 0] + g00[k] * d0 + g01[k] * d1
            s1 = XF[t, 1] + g10[k] * d0 + g11[k] * d1
            XF[t, 0] = s0; XF[t, 1] = s1


def _dense_posterior(Y, mask, *, F, Q, R, H, x0, P0, b=None):
    """Reference for tests: posterior mean and covariance of one small state-space model
    by one dense solve of the normal equations (information matrix of the joint
    Gaussian over all T*n states). Y (T, p), mask (T, p). Returns (T, n), (T*n, T*n)."""
    Y = np.asarray(Y, float)
    T, p = Y.shape
    n = F.shape[0]
    N = T * n
    Lam = np.zeros((N, N))
    eta = np.zeros(N)
    P0i = np.linalg.inv(P0)
    Lam[:n, :n] += P0i
    eta[:n] += P0i @ x0
    Qi = np.linalg.inv(Q)
    bb = np.zeros(n) if b is None else np.asarray(b, float)
    for t in range(T - 1):
        i, j = slice(t * n, (t + 1) * n), slice((t + 1) * n, (t + 2) * n)
        # (x_{t+1} - F x_t - b)ᵀ Q⁻¹ (x_{t+1} - F x_t - b)
        Lam[j, j] += Qi
        Lam[i, i] += F.T @ Qi @ F
        Lam[i, j] -= F.T @ Qi
        Lam[j, i] -= Qi @ F
        eta[j] += Qi @ bb
        eta[i] -= F.T @ Qi @ bb
    Rv = np.broadcast_to(np.asarray(R, float), (p,))
    for t in range(T):
        m = np.asarray(mask[t], bool) & np.isfinite(Y[t])
        W = np.diag(np.where(m, 1.0 / Rv, 0.0))
        i = slice(t * n, (t + 1) * n)
        Lam[i, i] += H.T @ W @ H
        eta[i] += H.T @ W @ np.where(m, Y[t], 0.0)
    cov = np.linalg.inv(Lam)
    return np.linalg.solve(Lam, eta).reshape(T, n), cov
