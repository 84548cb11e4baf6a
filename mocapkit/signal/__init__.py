"""Plain signal-processing functions on (T, C) arrays: smoothing and outlier rejection
(:mod:`.filters`), the noise estimator (:mod:`.noise`), state-space models
(:mod:`.statespace`) and the Kalman/RTS smoother (:mod:`.rts`).

In the style of :mod:`scipy.signal`: the data come first (positional only), options are
keyword-only, the input is never modified, and a new array is returned. Time runs along
``axis`` (default 0, one row per frame); every other axis is an independent channel
(for mocap: the (T, 3J) matrix of :meth:`mocapkit.motion.Motion.matrix`, in cm).
Functions that need complete data raise :class:`~mocapkit.errors.MocapValueError` on
non-finite input: fill gaps first with :func:`mocapkit.gaps.fill`.

Time is measured in frames unless a parameter says otherwise (``fs`` in Hz, ``dt`` in s).
"""
from .filters import butterworth, gaussian, hampel, hampel_residuals, median, savgol
from .noise import estimate_noise
from .rts import rts_smoother
from .statespace import (cutoff_to_q, cv_model, gate_threshold, random_walk_model,
                         select_process_noise, steady_state_covariance)

__all__ = [
    "gaussian", "butterworth", "savgol", "median", "hampel", "hampel_residuals",
    "estimate_noise", "rts_smoother", "cv_model", "random_walk_model",
    "gate_threshold", "cutoff_to_q", "select_process_noise", "steady_state_covariance",
]
