"""Classical per-channel filters and gap fillers: gaussian, spline, linear, butterworth,
savgol, median, hampel, gcv-spline.

Every method here treats each coordinate (x, y, z of each joint; the columns of
:meth:`Motion.matrix`, cm) as an independent time series. Thin wrappers around the plain
array functions of :mod:`mocapkit.signal`, which hold the maths and are tested alone.

Missing data: smoothing filters first fill gaps by a cubic spline through each channel's
observed samples (:func:`mocapkit.gaps.fill`, ends held at the nearest observed
value), then filter. A joint that is never observed in the clip cannot be filled by a
per-channel method: :class:`~mocapkit.errors.MocapValueError` names it (use a data-driven
method such as ``kalman-learned`` or ``lou-chai``, or drop it with ``Motion.select``).

Window lengths are in frames (as in Lou & Chai 2010, whose data were at 30 fps), not
seconds: at 120 fps the same window smooths four times less in time. ``butterworth``
alone works in Hz and uses ``motion.fps``.
"""
from __future__ import annotations

import math

import numpy as np

from .. import gaps, signal
from ..errors import MocapValueError
from ..motion import Motion
from ..signal.filters import hampel_scores
from ..solvers.gcv_spline import cutoff_hz, gcv_smooth
from .base import Denoiser, register
from .constraints import Integral, Interval, Odd, Options, Real

__all__ = ["GaussianFilter", "SplineFill", "LinearFill", "ButterworthFilter",
           "SavgolFilter", "MedianFilter", "HampelFilter", "GCVSpline", "gcv_summary", "require_observed_joints",
           "filled_matrix"]


def require_observed_joints(motion: Motion, method: str) -> None:
    """Raise MocapValueError naming the joints that have no observed frame at all."""
    never = ~motion.observed.any(axis=0)
    if never.any():
        names = [motion.skeleton.names[j] for j in np.flatnonzero(never)]
        raise MocapValueError(
            f"{method}: joint(s) {', '.join(names)} are never observed in this clip, so a "
            f"per-channel method cannot fill them; use a data-driven method (e.g. "
            f"kalman-learned, lou-chai) or drop them with Motion.select()")


def filled_matrix(motion: Motion, method: str, kind: str = "cubic", ends: str = "nearest", *,
                  copy: bool = True, observed: np.ndarray | None = None) -> np.ndarray:
    """(T, 3J) matrix of ``motion`` with gaps filled by :func:`mocapkit.gaps.fill`.

    ``observed`` (T, J): fill where it is False instead of where ``motion`` is missing (the
    same as filling ``motion.with_observed(observed)``, without that motion's copy of
    the positions). ``copy=False``: when nothing is to be filled, the read-only view
    :meth:`Motion.matrix` ``(copy=False)`` instead of a copy -- for a filter that only
    reads it (on a long clip a copy is one more matrix in memory, issue 21)."""
    require_observed_joints(motion, method)
    obs = motion.observed if observed is None else observed
    X = motion.matrix(copy=False)
    if not copy and obs.all():
        return X
    return gaps.fill(X, np.repeat(obs, 3, axis=1), kind=kind, ends=ends)


#: end handling of :func:`mocapkit.signal.gaussian`: 'odd' or a scipy.ndimage mode
_GAUSSIAN_MODES = Options("odd", "reflect", "nearest", "mirror", "constant", "wrap",
                          "grid-mirror", "grid-constant", "grid-wrap")
_POSITIVE = Interval(Real, 0, None, closed="neither")


# ---------------------------------------------------------------------------------------
@register
class GaussianFilter(Denoiser):
    """Per-channel Gaussian low-pass filter -- the Gaussian baseline of Lou & Chai 2010
    (seed 001, Sec. 6.2: "a standard Gaussian filter [applied] to every degree of freedom
    independently", window size 11).

    Parameters
    ----------
    window : kernel length in frames (odd). Default 11 (Lou & Chai).
    sigma_frames : kernel standard deviation in frames.
        Decision (the paper gives only the window): with ``window`` alone,
        sigma = (window-1)/5 -- MATLAB ``gausswin`` default alpha = 2.5, i.e. sigma = 2
        frames for window 11 (kernel truncated at 2.5 sigma). With ``sigma_frames``
        alone, the window is 2*ceil(4 sigma)+1 (scipy's truncation). Both may be given.
    median : 0 (off), 3 or 5 (any odd window): running-median pre-pass against spikes.
        A median(3-5)+Gaussian cascade is a strong tuned baseline under outliers
        (METHODS.md Sec. 1).
    mode : end handling, see :func:`mocapkit.signal.gaussian` (default ``'odd'``:
        trend-preserving reflection, so a marker moving at constant speed is not pulled
        back at the clip ends).

    Missing entries are filled by a cubic spline before filtering (ends held); the
    output is fully observed. Observed entries are smoothed too (keeps_observed=False).
    """

    name = "gaussian"
    description = "per-channel Gaussian smoothing (Lou & Chai baseline, window 11 frames); gaps spline-filled first"
    needs_training = False
    keeps_observed = False
    _parameter_constraints = {"window": [Odd(3), None], "sigma_frames": [_POSITIVE, None],
                              "median": [Options(0), Odd(1)], "mode": [_GAUSSIAN_MODES]}

    def __init__(self, window: int | None = None, sigma_frames: float | None = None,
                 median: int = 0, mode: str = "odd"):
        self._store_params(locals())

    def kernel(self) -> tuple[float, int]:
        """(sigma, radius) in frames implied by the parameters."""
        if self.window is None and self.sigma_frames is None:
            return 2.0, 5
        if self.sigma_frames is not None:
            s = float(self.sigma_frames)
        if self.window is None:
            return s, int(math.ceil(4 * s))
        w = int(self.window)
        return ((w - 1) / 5.0 if self.sigma_frames is None else s), (w - 1) // 2

    def denoise(self, motion: Motion) -> Motion:
        sigma, radius = self.kernel()
        X = filled_matrix(motion, self.name, copy=False)         # read only
        if self.median:
            X = signal.median(X, window=int(self.median))
        # the filter's result is new and used nowhere else: the Motion keeps it, uncopied
        return motion.with_matrix(signal.gaussian(X, sigma=sigma, radius=radius, mode=self.mode),
                                  handover=True)


@register
class SplineFill(Denoiser):
    """Cubic-spline gap filling per channel; observed entries are returned bit-identical.

    Each channel is interpolated by a not-a-knot cubic spline through its observed
    frames (:func:`mocapkit.gaps.fill`). Gaps before the first / after the last
    observed frame are filled according to ``ends``: ``'nearest'`` (default) holds the
    end value -- safe for long end gaps; ``'linear'`` continues the spline's end slope.
    No denoising: observed values, noisy or not, are kept. A joint never observed in the
    clip raises MocapValueError naming it.
    """

    name = "spline"
    description = "cubic-spline gap fill per channel; observed entries unchanged"
    needs_training = False
    keeps_observed = True
    clean_tolerance_cm = 1e-9
    _kind = "cubic"
    _parameter_constraints = {"ends": [Options("nearest", "linear")]}

    def __init__(self, ends: str = "nearest"):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        X = filled_matrix(motion, self.name, kind=self._kind, ends=self.ends)
        return motion.with_matrix(X, handover=True)          # a new array: no second copy


@register
class LinearFill(SplineFill):
    """Linear gap filling per channel (piecewise-linear in time between the observed
    frames around each gap); observed entries are returned bit-identical. ``ends`` as
    for :class:`SplineFill`."""

    name = "linear"
    description = "linear gap fill per channel; observed entries unchanged"
    _kind = "linear"


@register
class ButterworthFilter(Denoiser):
    """Zero-phase Butterworth low-pass (forward-backward ``sosfiltfilt``) per channel.

    Parameters
    ----------
    cutoff_hz : single-pass -3 dB frequency in Hz (default 6 Hz, a common choice for
        whole-body marker data); must be below half ``motion.fps``.
    order : single-pass order (default 4; the zero-phase result has order 8).

    Gaps are cubic-spline filled first. Clip ends use trend-preserving reflection
    (:func:`mocapkit.signal.butterworth`). Clips of at most 3*(2*ceil(order/2)+1) frames
    (15 for order 4) raise MocapValueError with that explanation.
    """

    name = "butterworth"
    description = "zero-phase Butterworth low-pass per channel (6 Hz, order 4); gaps spline-filled first"
    needs_training = False
    keeps_observed = False

    _parameter_constraints = {"cutoff_hz": [_POSITIVE], "order": [Interval(Integral, 1, None)]}

    def __init__(self, cutoff_hz: float = 6.0, order: int = 4):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        X = filled_matrix(motion, self.name, copy=False)         # read only
        Y = signal.butterworth(X, fs=motion.fps, cutoff_hz=self.cutoff_hz, order=self.order)
        return motion.with_matrix(Y, handover=True)              # a new array: no second copy


@register
class SavgolFilter(Denoiser):
    """Savitzky-Golay smoothing per channel (local least-squares polynomial of degree
    ``polyorder`` over ``window`` frames; ends from the edge windows' polynomials).

    Defaults: window 11 frames, polyorder 3. The window shrinks to the clip length for
    short clips; fewer than polyorder+2 frames raise MocapValueError. Gaps are
    cubic-spline filled first.
    """

    name = "savgol"
    description = "Savitzky-Golay smoothing per channel (window 11, cubic); gaps spline-filled first"
    needs_training = False
    keeps_observed = False

    _parameter_constraints = {"window": [Odd(1)], "polyorder": [Interval(Integral, 0, None)]}

    def __init__(self, window: int = 11, polyorder: int = 3):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        X = filled_matrix(motion, self.name, copy=False)         # read only
        return motion.with_matrix(signal.savgol(X, window=self.window, polyorder=self.polyorder),
                                  handover=True)


@register
class MedianFilter(Denoiser):
    """Running median per channel over ``window`` frames (default 5; windows mirrored at
    the clip ends). Removes isolated spikes up to (window-1)/2 frames long. Gaps are
    cubic-spline filled first."""

    name = "median"
    description = "running median per channel (5 frames) against spikes; gaps spline-filled first"
    needs_training = False
    keeps_observed = False

    _parameter_constraints = {"window": [Odd(1)]}

    def __init__(self, window: int = 5):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        X = filled_matrix(motion, self.name, copy=False)         # read only
        return motion.with_matrix(signal.median(X, window=int(self.window)), handover=True)


@register
class GCVSpline(Denoiser):
    """Automatic smoothing spline per channel, the smoothing chosen by generalised
    cross-validation (Woltring 1986 GCVSPL; discrete form and robust weights of Garcia
    2010) -- the biomechanics community's standard automatic filter. See
    :func:`mocapkit.solvers.gcv_spline.gcv_smooth` for the equations.

    Parameters
    ----------
    order : penalty order m: 2 (cubic analogue, default), 3 (quintic, Woltring's mode for
        derivatives), 1.
    robust : reject outliers (bisquare weights on each joint's 3-D residual, then a refit on
        the kept samples); rejected samples are filled by the spline.
    min_scale_cm : a sample is rejected only if it is off by more than 4.685 x max(residual
        scale, this) -- keeps fast noise-free motion from being called an outlier.

    Gaps are filled by the spline (weights 0). The result's ``source['gcv_spline']`` gives
    the median cut-off (Hz, where the gain is 1/2), the estimated noise (cm), the number
    of rejected samples and the estimated RMS error (cm) with how it was estimated.

    >>> from mocapkit import datasets, io, corrupt
    >>> clip = io.read(datasets.bundled("16_15.amc"))
    >>> noisy, _ = corrupt.combine(clip, [("gaussian", {"sigma_cm": 2.0})], seed=0)
    >>> out = GCVSpline().denoise(noisy)
    >>> 0.5 < out.source["gcv_spline"]["noise_cm"] < 3.0
    True
    """

    name = "gcv-spline"
    description = "automatic smoothing spline per channel, smoothing chosen by GCV (Woltring); robust option"
    needs_training = False
    keeps_observed = False

    _parameter_constraints = {"order": [Options(1, 2, 3)], "robust": [bool],
                              "min_scale_cm": [Interval(Real, 0, None)]}

    def __init__(self, order: int = 2, robust: bool = False, min_scale_cm: float = 1.0):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        require_observed_joints(motion, self.name)
        X, M = motion.matrix(copy=False), motion.matrix_mask()    # read only
        f, info = gcv_smooth(X, M, order=self.order, robust=bool(self.robust), group=3,
                             min_scale=float(self.min_scale_cm))
        # f is gcv_smooth's own new array: the Motion keeps it, uncopied
        return motion.with_matrix(f, handover=True).with_source(
            gcv_spline=gcv_summary(info, motion.fps, self.order))


def gcv_summary(info, fps: float, order: int) -> dict:
    """JSON-able summary of a :class:`~mocapkit.solvers.gcv_spline.GCVInfo` (cm, Hz)."""
    return {
        "cutoff_hz": float(np.median(cutoff_hz(info.s, order, fps))),
        "noise_cm": float(np.median(info.sigma)),
        "rejected": int(info.outliers.sum() // 3),
        "estimated_rmse_cm": float(np.sqrt(np.mean(info.error ** 2))),
        "how": "SURE at the GCV noise estimate on kept samples; filled samples by hiding the "
               "clip's own hole pattern elsewhere",
    }


@register
class HampelFilter(Denoiser):
    """Hampel-type outlier rejection + cubic-spline refill.

    Residuals r = x - (running median of the ``window - 1`` neighbours of each frame; the
    frame itself left out, which calibrates the MAD-based sigma) are computed per
    coordinate (:func:`mocapkit.signal.hampel_residuals`) and scaled by robust sigmas:
    *global* -- 1.4826 x MAD of the coordinate's residuals over the whole clip -- and
    *local* -- 1.4826 x MAD of the window's neighbours; both floored at ``min_sigma_cm``.
    A joint is flagged in a frame when its three scaled residuals together are too
    large, ``Σ_xyz (r/sigma)² > chi2_3(n)``, the chi-square threshold exceeded with the
    probability of a two-sided n-sigma Gaussian event
    (:func:`mocapkit.signal.gate_threshold`; n = 3 -> 14.2): a marker spike moves the
    whole marker, and this 3-dof test detects a 3-D spike whatever its direction.

    ``scale='both'`` (default) requires the global test at ``n_sigmas`` *and* the local
    test at ``n_sigmas - 1``: the global scale alone flags fast movements of a noiseless
    clip (its residual tails are long), the local scale alone misses spikes next to
    fast movements. Measured on CMU clips (135_02, 09_06, 16_15; 10 % 15 cm spikes,
    3 sigmas): spikes only -- global: recall 100 %, false alarms 3-19 % of clean joints;
    both: recall 82-99 %, false alarms 0.0-5 %; spikes over 2 cm noise -- global: recall
    74-99 %, both: 64-98 %, false alarms <= 5 % either way (lower recall at 30 fps and on
    the running clip). ``scale='global'`` or ``'local'`` use one test at ``n_sigmas``;
    ``scale='local', joint_test=False`` is close to the classic per-coordinate Hampel
    identifier (a joint is then flagged when any coordinate is).

    Flagged joints are treated as missing and every gap (flagged or originally missing)
    is filled by a cubic spline through the remaining observed frames. Unflagged
    observed entries are returned unchanged (their noise is not smoothed: use
    ``gaussian`` with ``median`` for a smoothing cascade).

    Output: the returned motion's ``source['flagged']`` is a (T, J) bool array, True
    where an observed joint was rejected as an outlier (it is not a ``per_frame`` entry,
    so ``Motion.slice`` does not carry it along).

    Parameters
    ----------
    window : odd number of frames of the running median (default 7).
    n_sigmas : threshold (default 3).
    scale : ``'both'`` (default), ``'global'`` or ``'local'`` (see above).
    joint_test : True (default) for the 3-dof joint test, False for per-coordinate tests.
    min_sigma_cm : floor of the robust sigmas in cm (default 0.5: a joint closer than
        sqrt(14.2) x 0.5 = 1.9 cm to its neighbours' median is never flagged at 3
        sigmas). Without noise the residual MAD of real motion is ~0.05 cm.
    """

    name = "hampel"
    description = "Hampel outlier rejection (running median, robust sigmas, 3-D test per joint) then cubic-spline refill"
    needs_training = False
    keeps_observed = False

    _parameter_constraints = {"window": [Odd(3)], "n_sigmas": [_POSITIVE],
                              "scale": [Options("both", "global", "local")], "joint_test": [bool],
                              "min_sigma_cm": [Interval(Real, 0, None)]}

    def __init__(self, window: int = 7, n_sigmas: float = 3.0, scale: str = "both",
                 joint_test: bool = True, min_sigma_cm: float = 0.5):
        self._store_params(locals())

    def flags(self, motion: Motion) -> np.ndarray:
        """(T, J) bool: observed joints the test rejects."""
        X = filled_matrix(motion, self.name, copy=False)         # read only
        T, J = motion.observed.shape
        if T < 3:
            return np.zeros((T, J), dtype=bool)
        ns = float(self.n_sigmas)
        scales = ("global", "local") if self.scale == "both" else (self.scale,)
        levels = [ns, max(ns - 1.0, 0.5)] if self.scale == "both" else [ns]
        # per joint: sum over x, y, z of (r / sigma)² (3-dof test), or the largest one
        # (any coordinate over n sigmas); computed in time chunks (hampel_scores), not
        # from whole residual / sigma / square arrays
        scores = hampel_scores(X, window=int(self.window), scales=scales,
                               min_sigma=self.min_sigma_cm, exclude_center=True, group=3,
                               reduce="sum" if self.joint_test else "max")
        flagged = np.ones((T, J), dtype=bool)
        for z2, n in zip(scores, levels):
            flagged &= z2 > (float(signal.gate_threshold(n, 3)) if self.joint_test else n * n)
        return flagged & motion.observed

    def denoise(self, motion: Motion) -> Motion:
        flagged = self.flags(motion)
        keep = motion.observed & ~flagged
        lost = ~keep.any(axis=0) & motion.observed.any(axis=0)
        keep[:, lost] = motion.observed[:, lost]        # never reject every frame of a joint
        flagged &= ~keep
        Y = filled_matrix(motion, self.name, observed=keep)      # a new array
        return motion.with_matrix(Y, handover=True).with_source(flagged=flagged)
