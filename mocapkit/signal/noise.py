"""The package's one white-noise estimator: :func:`estimate_noise`."""
from __future__ import annotations

import math
import warnings
from typing import Literal

import numpy as np

from ..errors import MocapValueError
from ._arrays import as_2d_view
from ..windows import frame_blocks

__all__ = ["estimate_noise"]

_MAD = 1.4826          # 1 / Phi^-1(3/4): a Gaussian's sigma from its median absolute deviation
_WAVELET_MAD = 0.6745  # Phi^-1(3/4) as Donoho & Johnstone (1994) write it: sigma = median|d| / 0.6745
_BLOCK = 16            # channels per block of the per-channel estimate (memory: ~4 arrays of a block)

METHODS = ("diff2-mad", "diff2-rms", "wavelet-mad")
POOLS = (None, "median", "all")


def estimate_noise(X, mask=None, /, *, method: Literal["diff2-mad", "diff2-rms", "wavelet-mad"] = "diff2-mad",
                   pool: Literal["median", "all"] | None = None, axis: int = 0,
                   wavelet=None, fallback: float = math.nan):
    """Standard deviation of white measurement noise on smooth trajectories (units of X).

    Parameters
    ----------
    X : array (T, ...), time along ``axis``; every other axis is a channel (for mocap the
        (T, 3J) matrix of :meth:`mocapkit.motion.Motion.matrix`, cm).
    mask : optional bool like X, True = observed; non-finite entries never count.
    method : what is measured (Δ²x[t] = x[t-1] - 2 x[t] + x[t+1], over triples of
        consecutive observed samples only; Δ² of white noise of std σ has std √6 σ, while a
        smooth motion at 30-120 fps contributes little, |a| dt² -- e.g. 0.04 cm at 120 fps
        for a 500 cm/s² swing -- so these are near-unbiased for noise above that level):

        * ``"diff2-mad"`` (default) -- ``1.4826 MAD(Δ²x) / √6``, the MAD about the
          channel's median; insensitive to a minority of spikes. The choice for noisy
          captures with outliers (Kalman measurement noise, Xiao's λ, the networks' input
          level). With ``pool="all"``: ``1.4826 median|Δ²x| / √6`` over the second
          differences of all channels together (about zero, their common centre).
        * ``"diff2-rms"`` -- ``RMS(Δ²x) / √6``: efficient for pure Gaussian noise but raised
          by outliers (the noise level that sets the low-rank solvers' λ, which should
          grow with the outliers).
        * ``"wavelet-mad"`` -- ``median|d₁| / 0.6745`` with d₁ the finest-scale detail
          coefficients of the discrete wavelet transform of each channel (``wavelet``, a
          PyWavelets name or object; symmetric extension): Donoho & Johnstone's (1994)
          estimate, the one their VisuShrink threshold assumes. Needs complete data.
    pool : ``None`` -- one estimate per channel, shape ``X.shape`` without ``axis``
        (NaN where a channel has no usable difference); ``"median"`` -- the median of
        the finite per-channel estimates (a float: one noise level for a clip whose
        channels share a sensor); ``"all"`` -- one estimate from the pooled
        differences of every channel (``"diff2-*"`` only).
    fallback : returned for (or, per channel, in place of) an estimate that cannot be
        made: fewer than 3 frames, no three consecutive observed samples (default NaN).

    Relation to :mod:`mocapkit.diagnose`: its noise level is the residual variance of a
    GCV-chosen smoothing spline, RSS / (n - tr H), on the samples its spike test keeps --
    a model fit, slower, which also sees noise that is not white; the estimates here are
    local (three samples), need no fit and are what the solvers use to set thresholds.

    >>> rng = np.random.default_rng(0)
    >>> t = np.linspace(0, 1, 2000)[:, None]
    >>> x = np.sin(2 * np.pi * t) * [10.0, 20.0] + 0.5 * rng.standard_normal((2000, 2))
    >>> bool(np.allclose(estimate_noise(x), 0.5, rtol=0.1)), round(estimate_noise(x, pool="median"), 1)
    (True, 0.5)
    """
    if method not in METHODS:
        raise MocapValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if pool not in POOLS:
        raise MocapValueError(f"pool must be None, 'median' or 'all', got {pool!r}")
    A, shape, axis = as_2d_view(X, axis)          # read only: no copy of a long clip
    M = np.isfinite(A)
    if mask is not None:
        Mm = np.asarray(mask, dtype=bool)
        if Mm.shape != np.shape(X):
            raise MocapValueError(f"mask shape {Mm.shape} does not match data shape {np.shape(X)}")
        M &= np.moveaxis(Mm, axis, 0).reshape(A.shape[0], -1)
    if method == "wavelet-mad":
        if pool == "all":
            raise MocapValueError("pool='all' needs a 'diff2-*' method")
        s = _wavelet_mad(A, M, wavelet)
    elif pool == "all":
        return _pooled_diff2(A, M, method, fallback)
    else:
        s = np.concatenate([_channel_diff2(A[:, j:j + _BLOCK], M[:, j:j + _BLOCK], method)
                            for j in range(0, A.shape[1], _BLOCK)]) if A.shape[1] else np.zeros(0)
    if pool == "median":
        s = s[np.isfinite(s)]
        return float(np.median(s)) if s.size else float(fallback)
    s = np.where(np.isfinite(s), s, fallback)
    return s.reshape(shape[1:]) if len(shape) > 1 else s


def _diff2(A: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Second differences (T-2, C) and where all three samples are observed."""
    return A[2:] - 2 * A[1:-1] + A[:-2], M[2:] & M[1:-1] & M[:-2]


def _channel_diff2(A: np.ndarray, M: np.ndarray, method: str) -> np.ndarray:
    """Per-channel ``diff2-*`` estimate (C,); NaN where a channel has no usable triple."""
    if A.shape[0] < 3:
        return np.full(A.shape[1], np.nan)
    D, ok = _diff2(A, M)
    D = np.where(ok, D, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)          # all-NaN channels -> NaN
        if method == "diff2-rms":
            return np.sqrt(np.nanmean(D ** 2, axis=0) / 6.0)
        med = np.nanmedian(D, axis=0)
        return _MAD * np.nanmedian(np.abs(D - med), axis=0) / math.sqrt(6.0)


def _pooled_diff2(A: np.ndarray, M: np.ndarray, method: str, fallback: float) -> float:
    """One ``diff2-*`` estimate from the usable second differences of all channels."""
    T = A.shape[0]
    if T < 3:
        return float(fallback)
    # blocks of frames (overlapping by the 2 frames a difference spans): the usable
    # differences are gathered into one 1-D buffer (MAD) or only summed (RMS) -- the
    # whole-matrix route held the zero-filled copy, the differences and their squares
    # at once (4x the clip at 100,000 frames)
    rms = method == "diff2-rms"
    parts, ss, n = [], 0.0, 0
    for blk in frame_blocks(T - 2):                 # the differences of frames blk, +2 rows
        a, b = blk.start, blk.stop + 2
        D, ok = _diff2(np.where(M[a:b], A[a:b], 0.0), M[a:b])
        d = D[ok]
        n += d.size
        if rms:
            ss += float(np.dot(d, d))
        else:
            parts.append(np.abs(d, out=d))
    if n == 0:
        return float(fallback)
    if rms:
        return float(np.sqrt(ss / n / 6.0))
    d = np.concatenate(parts) if len(parts) > 1 else parts[0]
    del parts
    return float(_MAD * _median_inplace(d) / np.sqrt(6.0))


def _median_inplace(d: np.ndarray) -> float:
    """``np.median`` of a 1-D array that may be reordered (no copy)."""
    k = d.size // 2
    if d.size % 2:
        d.partition(k)
        return float(d[k])
    d.partition([k - 1, k])
    return 0.5 * (float(d[k - 1]) + float(d[k]))


def _wavelet_mad(A: np.ndarray, M: np.ndarray, wavelet) -> np.ndarray:
    """Per-channel ``median|d1| / 0.6745`` of the finest DWT detail coefficients (C,)."""
    import pywt

    if wavelet is None:
        raise MocapValueError("method='wavelet-mad' needs wavelet= (e.g. 'bior3.5', 'db4')")
    if not M.all():
        raise MocapValueError("method='wavelet-mad' needs complete data; fill the gaps first (mocapkit.gaps.fill)")
    d1 = pywt.dwt(A, wavelet, mode="symmetric", axis=0)[1]
    return np.median(np.abs(d1), axis=0) / _WAVELET_MAD
