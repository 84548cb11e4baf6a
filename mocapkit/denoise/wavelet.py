"""B-spline wavelet shrinkage per channel: the ``wavelet`` baseline of Xiao et al. 2015.

Xiao et al. (seed 000, Sec. 4) compare with a "Wavelet filter [5, 22]" applied to each
coordinate independently; ref. [22] is Hsieh & Kuo (2008), a B-spline wavelet
multiresolution analysis of motion data whose high-magnitude detail coefficients are
treated as noise.  We implement the standard form of that idea with PyWavelets:

1. missing samples are filled by a cubic spline per channel (ends held);
2. each channel (a column of :meth:`Motion.matrix`, cm) is decomposed with the
   biorthogonal spline wavelet ``bior3.5`` (Cohen-Daubechies-Feauveau: quadratic
   B-spline synthesis scaling function; any PyWavelets wavelet name is accepted) over
   ``level`` levels with symmetric extension at the ends;
3. the detail coefficients are soft-thresholded (Donoho & Johnstone 1994, VisuShrink)
   at the universal threshold ``t = threshold_scale * sigma * sqrt(2 ln T)``, with the
   noise level ``sigma = median(|d_1|) / 0.6745`` estimated per channel from the finest
   detail coefficients (robust to a minority of spikes;
   :func:`mocapkit.signal.estimate_noise`, ``method="wavelet-mad"``);
4. the channel is reconstructed and cut back to T frames.

Decisions (the papers give no settings): ``bior3.5``; ``level`` default
``min(5, pywt.dwt_max_level(T, wavelet))`` -- at 120 fps the coarsest kept detail band is
about 2-4 Hz, so the slow body motion stays in the untouched approximation; soft
thresholding; ``threshold_scale`` 1 (the protocol may tune it on training clips, as
Xiao et al. tuned every competitor).
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import MocapValueError
from ..motion import Motion
from ..signal import estimate_noise
from ..signal._arrays import by_channel_blocks
from .base import Denoiser, register
from .constraints import Integral, Interval, Options, Real

__all__ = ["WaveletDenoiser", "wavelet_shrink"]


def wavelet_shrink(X: np.ndarray, *, wavelet: str = "bior3.5", level: int | None = None,
                   threshold_scale: float = 1.0, mode: str = "soft") -> np.ndarray:
    """Universal-threshold wavelet shrinkage of every column of ``X`` (T, C) (see module doc).

    Returns an array like ``X``. ``X`` must be finite.
    """
    import pywt

    X = np.asarray(X, dtype=np.float64)               # read only
    if X.ndim == 1:
        return wavelet_shrink(X[:, None], wavelet=wavelet, level=level,
                              threshold_scale=threshold_scale, mode=mode)[:, 0]
    if not np.isfinite(X).all():
        raise MocapValueError("wavelet: input contains NaN/inf; fill gaps first")
    if mode not in ("soft", "hard"):
        raise MocapValueError(f"wavelet: mode must be 'soft' or 'hard', got {mode!r}")
    try:
        w = pywt.Wavelet(wavelet)
    except ValueError:
        raise MocapValueError(f"wavelet: unknown wavelet {wavelet!r}; e.g. bior3.5, bior2.2, db4, sym8") from None
    T = X.shape[0]
    max_level = pywt.dwt_max_level(T, w.dec_len)
    lev = min(5, max_level) if level is None else int(level)
    if lev < 0:
        raise MocapValueError(f"wavelet: level must be >= 0, got {level}")
    lev = min(lev, max_level)
    if lev == 0 or T < 2:
        return X.copy()
    root = math.sqrt(2.0 * math.log(T))

    def shrink(B: np.ndarray) -> np.ndarray:
        """(c, T) block of channels, time along the rows -> its shrunk series (c, T)."""
        coeffs = pywt.wavedec(B, w, mode="symmetric", level=lev, axis=-1)
        sigma = estimate_noise(B, method="wavelet-mad", wavelet=w, axis=-1)   # (c,) median|d1| / 0.6745
        thr = (float(threshold_scale) * sigma * root)[:, None]
        for d in coeffs[1:]:                         # in place: the block's own coefficients
            if mode == "soft":
                mag = np.abs(d)
                np.subtract(mag, thr, out=mag)
                np.maximum(mag, 0.0, out=mag)
                np.multiply(np.sign(d), mag, out=d)
            else:
                d[np.abs(d) <= thr] = 0.0
        return pywt.waverec(coeffs, w, mode="symmetric", axis=-1)[:, :T]

    # every channel is shrunk on its own (its own noise level and threshold), so channel
    # blocks give the same numbers while the coefficients, their thresholded copies and
    # the reconstruction exist for one block at a time, not for the whole clip (4.6x the
    # input at 100,000 frames, issue 21).  4 channels a block: their coefficients stay in
    # cache -- wavelet_shrink alone ran 263k / 248k frames/s at 10k / 100k frames with 4,
    # 267k / 146k with 16
    return by_channel_blocks(shrink, X, block=4)


@register
class WaveletDenoiser(Denoiser):
    """Per-channel B-spline wavelet shrinkage (Xiao et al. 2015 baseline after Hsieh & Kuo 2008).

    Parameters
    ----------
    wavelet : PyWavelets name, default ``'bior3.5'`` (B-spline biorthogonal).
    level : decomposition levels; default min(5, max possible).
    threshold_scale : multiplies the universal threshold sigma sqrt(2 ln T) (default 1).
    mode : ``'soft'`` (default) or ``'hard'`` thresholding.

    Missing samples are spline-filled first; the output is fully observed.
    """

    name = "wavelet"
    description = "per-channel B-spline (bior3.5) wavelet shrinkage, universal threshold (Xiao et al. baseline)"
    needs_training = False
    keeps_observed = False

    # wavelet names are checked by PyWavelets (wavelet_shrink names a few)
    _parameter_constraints = {"wavelet": [str], "level": [Interval(Integral, 0, None), None],
                              "threshold_scale": [Interval(Real, 0, None)], "mode": [Options("soft", "hard")]}

    def __init__(self, wavelet: str = "bior3.5", level: int | None = None,
                 threshold_scale: float = 1.0, mode: str = "soft"):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        from .filters import filled_matrix

        X = filled_matrix(motion, self.name, copy=False)         # read only
        Y = wavelet_shrink(X, wavelet=self.wavelet, level=self.level, threshold_scale=float(self.threshold_scale),
                           mode=self.mode)
        return motion.with_matrix(Y, handover=True)              # a new array: no second copy
