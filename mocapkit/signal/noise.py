"""The package's one white-noise estimator: :func:`estimate_noise`."""
from __future__ import annotations

import math
from typing import Literal

import numpy as np

from ..errors import MocapValueError
from ._arrays import as_2d_view, nanmedian0
from ..windows import frame_blocks

__all__ = ["estimate_noise"]

_MAD = 1.4826          # 1 / Phi^-1(3/4): a Gaussian's sigma from its median absolute deviation
_WAVELET_MAD = 0.6745  # Phi^-1(3/4) as Donoho & Johnstone (1994) write it: sigma = median|d| / 0.6745
_BLOCK = 16            # channels per block of the per-channel estimate (memory: ~4 arrays of a block)
_BLOCK_SAMPLES = 1 << 18  # ... or as many as make this many samples

METHODS = ("diff2-mad", "diff2-rms", "diff4-mad", "diff4-rms", "wavelet-mad")
#: difference order of each ``diff*`` method
_ORDER = {"diff2-mad": 2, "diff2-rms": 2, "diff4-mad": 4, "diff4-rms": 4}
POOLS = (None, "median", "all")


def estimate_noise(X, mask=None, /, *,
                   method: Literal["diff2-mad", "diff2-rms", "diff4-mad", "diff4-rms", "wavelet-mad"] = "diff2-mad",
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
        * ``"diff4-mad"`` -- ``1.4826 MAD(Δ⁴x) / √70`` with Δ⁴x[t] = x[t-2] - 4 x[t-1] +
          6 x[t] - 4 x[t+1] + x[t+2] over five consecutive observed samples (√70: the
          std of Δ⁴ of unit white noise). A motion component of frequency f leaks in as
          (2 sin(π f / fps))^k for order k, so the fourth difference sees far less of the
          motion where the noise is small against it. Measured on the ten clips of the
          ``auto`` protocol (noise-free CMU / HDM05, 8 s, pooled): diff2-mad reads
          0.03-0.38 cm at 30 fps and 0.007-0.046 cm at 120 fps with no noise at all,
          diff4-mad 0.02-0.13 and 0.0006-0.025 cm; with 0.05 cm white noise at 120 fps
          0.053-0.077 against 0.050-0.064 cm. Noisier (fewer samples' worth) on pure noise
          and it needs five consecutive samples: the estimate of how much a *noise-free
          or nearly noise-free* clip's kept samples are off (:mod:`mocapkit.denoise.auto`).
        * ``"diff4-rms"`` -- ``RMS(Δ⁴x) / √70``: the second moment of the noise whatever
          its distribution -- what a linear smoother's risk holds. The noise level of
          auto's smoothers (:func:`mocapkit.denoise.auto._smooth`), where the samples kept
          after the spikes are rejected can be a mixture: positions read back from an AMC
          file that ``mocapkit corrupt`` spiked are half exact and half off by 0.3-3 cm
          (diff4-mad 0.21, true RMS 0.77 cm); on Gaussian noise it matches diff4-mad.
        * ``"wavelet-mad"`` -- ``median|d₁| / 0.6745`` with d₁ the finest-scale detail
          coefficients of the discrete wavelet transform of each channel (``wavelet``, a
          PyWavelets name or object; symmetric extension): Donoho & Johnstone's (1994)
          estimate, the one their VisuShrink threshold assumes. Needs complete data.
    pool : ``None`` -- one estimate per channel, shape ``X.shape`` without ``axis``
        (NaN where a channel has no usable difference); ``"median"`` -- the median of
        the finite per-channel estimates (a float: one noise level for a clip whose
        channels share a sensor); ``"all"`` -- one estimate from the pooled
        differences of every channel (``"diff*"`` methods only).
    fallback : returned for (or, per channel, in place of) an estimate that cannot be
        made: fewer than 3 frames, no three consecutive observed samples (default NaN).

    Relation to :mod:`mocapkit.diagnose`: its noise level is the residual variance of a
    GCV-chosen smoothing spline, RSS / (n - tr H), on the samples its spike test keeps --
    a model fit, slower, which also sees noise that is not white; the estimates here are
    local (three samples), need no fit and are what the solvers use to set thresholds.
    For points of rigid segments (joints of a skeleton, markers of a cluster)
    :func:`mocapkit.rigid.distance_noise` reads the noise from the spread of their
    distances instead, which no motion enters (``auto`` charges the smallest of them).

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
            raise MocapValueError("pool='all' needs a 'diff*' method")
        s = _wavelet_mad(A, M, wavelet)
    elif pool == "all":
        return _pooled_diff(A, M, method, fallback)
    else:
        # blocks of channels, at least _BLOCK and about _BLOCK_SAMPLES samples (a short
        # clip's thousands of channels -- every pair distance of a marker set -- in a few)
        b = max(_BLOCK, _BLOCK_SAMPLES // max(A.shape[0], 1))
        s = np.concatenate([_channel_diff(A[:, j:j + b], M[:, j:j + b], method)
                            for j in range(0, A.shape[1], b)]) if A.shape[1] else np.zeros(0)
    if pool == "median":
        s = s[np.isfinite(s)]
        return float(np.median(s)) if s.size else float(fallback)
    s = np.where(np.isfinite(s), s, fallback)
    return s.reshape(shape[1:]) if len(shape) > 1 else s


def _diff(A: np.ndarray, M: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Differences of ``order`` 2 or 4 (T - order, C) and where all their samples are
    observed."""
    if order == 2:
        D = A[2:] - 2 * A[1:-1] + A[:-2]
    else:
        D = A[4:] - 4 * A[3:-1] + 6 * A[2:-2] - 4 * A[1:-3] + A[:-4]
    ok = M[order:].copy()
    for i in range(order):
        ok &= M[i:len(M) - order + i]
    return D, ok


def _gain(order: int) -> float:
    """Std of the order-k difference of unit white noise: sqrt(C(2k, k)) (√6, √70)."""
    return math.sqrt(math.comb(2 * order, order))


def _channel_diff(A: np.ndarray, M: np.ndarray, method: str) -> np.ndarray:
    """Per-channel ``diff*`` estimate (C,); NaN where a channel has no usable run of
    samples."""
    k = _ORDER[method]
    if A.shape[0] < k + 1:
        return np.full(A.shape[1], np.nan)
    D, ok = _diff(A, M, k)
    if method.endswith("-rms"):                 # (no NaN copy: nanmean was most of its time)
        D = np.where(ok, D, 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):     # channels with none -> NaN
            return np.sqrt(np.einsum("tc,tc->c", D, D) / ok.sum(axis=0)) / _gain(k)
    D = np.where(ok, D, np.nan)
    med = nanmedian0(D)                                          # all-NaN channels -> NaN
    return _MAD * nanmedian0(np.abs(D - med)) / _gain(k)


def _pooled_diff(A: np.ndarray, M: np.ndarray, method: str, fallback: float) -> float:
    """One ``diff*`` estimate from the usable differences of all channels."""
    T = A.shape[0]
    k = _ORDER[method]
    if T < k + 1:
        return float(fallback)
    # blocks of frames (overlapping by the k frames a difference spans): the usable
    # differences are gathered into one 1-D buffer (MAD) or only summed (RMS) -- the
    # whole-matrix route held the zero-filled copy, the differences and their squares
    # at once (4x the clip at 100,000 frames)
    rms = method.endswith("-rms")
    parts, ss, n = [], 0.0, 0
    for blk in frame_blocks(T - k):                 # the differences of frames blk, +k rows
        a, b = blk.start, blk.stop + k
        D, ok = _diff(np.where(M[a:b], A[a:b], 0.0), M[a:b], k)
        d = D[ok]
        n += d.size
        if rms:
            ss += float(np.dot(d, d))
        else:
            parts.append(np.abs(d, out=d))
    if n == 0:
        return float(fallback)
    if rms:
        return float(np.sqrt(ss / n) / _gain(k))
    d = np.concatenate(parts) if len(parts) > 1 else parts[0]
    del parts
    return float(_MAD * _median_inplace(d) / _gain(k))


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
