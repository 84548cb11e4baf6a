"""``mssa``: multichannel singular spectrum denoising with optimal singular-value shrinkage
(Gavish & Donoho 2017), the noise level estimated by a GCV spline. The maths is in
:mod:`mocapkit.solvers.mssa`; ``auto`` uses it as one of its smoothers.

>>> from mocapkit import datasets, io, corrupt, metrics
>>> clip = io.read(datasets.bundled("16_15.amc"))
>>> noisy, _ = corrupt.combine(clip, [("gaussian", {"sigma_cm": 2.0})], seed=0)
>>> out = MSSA().denoise(noisy)
>>> metrics.rmse(clip, out) < 0.5 * metrics.rmse(clip, noisy)
True
"""
from __future__ import annotations

import numpy as np

from ..motion import Motion
from ..solvers.gcv_spline import gcv_smooth
from ..solvers.mssa import mssa_denoise
from .base import Denoiser, register
from .constraints import Interval, Real
from .filters import require_observed_joints

__all__ = ["MSSA"]


@register
class MSSA(Denoiser):
    """Lagged-window (multichannel SSA) low-rank denoising of the whole body.

    Parameters
    ----------
    window_s : embedding window in seconds (default 0.13 s: 4 frames at 30 fps, 16 at
        120 fps, measured best of 0.07 / 0.13 / 0.27 s on CMU clips).
    sigma_cm : noise level; default None = the GCV spline's estimate (median over
        coordinates).

    Gaps are filled by the GCV spline first (weights 0 there), then the completed clip is
    denoised; white Gaussian noise is assumed (remove spikes first, e.g. with ``auto``).
    """

    name = "mssa"
    description = "multichannel SSA with optimal singular-value shrinkage (Gavish-Donoho); noise level by GCV"
    needs_training = False
    keeps_observed = False

    _parameter_constraints = {"window_s": [Interval(Real, 0, None, closed="neither")],
                              "sigma_cm": [Interval(Real, 0, None), None]}

    def __init__(self, window_s: float = 0.13, sigma_cm: float | None = None):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        require_observed_joints(motion, self.name)
        X, M = motion.matrix(copy=False), motion.matrix_mask()      # read-only view
        fit, info = gcv_smooth(X, M, group=3)
        sigma = float(np.median(info.sigma)) if self.sigma_cm is None else float(self.sigma_cm)
        L = max(2, min(int(round(float(self.window_s) * motion.fps)), motion.n_frames // 4))
        if motion.n_frames < 8:
            return motion.with_matrix(fit, handover=True)
        Y = fit                                       # the spline where missing, else the data
        np.copyto(Y, X, where=M)
        del fit, M
        return motion.with_matrix(mssa_denoise(Y, sigma, window=L), handover=True).with_source(
            mssa={"sigma_cm": sigma, "window_frames": L})
