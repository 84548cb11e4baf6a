"""``auto``: clean a clip without tuning, and say how well it went.

The chain, decided from the clip's own diagnosis (:mod:`mocapkit.diagnose`):

1. **Spikes** -- a robust GCV smoothing spline (bisquare on each point's 3-D residual,
   Garcia 2010) flags samples off the fit by more than 4.685 x max(scale, 1 cm). If more
   than :data:`~mocapkit.diagnose.SPIKE_RATE` of the samples are flagged the clip is
   spiky and the flagged samples are treated as missing; otherwise nothing is rejected
   (the test's false alarms on clean fast motion would cost more than they save).
2. **Noise** -- three smoothers on the samples kept, and the one of lowest Monte-Carlo
   SURE (Ramani et al. 2008; the noise level from GCV) is used: a GCV smoothing spline
   (Woltring 1986, smoothing chosen per coordinate), multichannel SSA with optimal
   singular-value shrinkage (Gavish & Donoho 2017; it uses the body's coordination) and
   the mean of the two. *Do no harm*: when the
   estimated noise is below ``min_noise_cm`` and there are no spikes the measured samples
   are returned as they are (at that level smoothing cannot be told from removing motion
   detail: on noise-free CMU clips the GCV spline adds 0.002-0.08 cm).
3. **Gaps** -- short holes (spikes, gaps up to ``long_gap_s``) are filled by the spline;
   longer gaps by ``fill-auto`` (per-gap self-validated choice of linear / spline /
   pattern / rigid-body / PCA fill) run on the cleaned samples.

The error estimate (cm RMS over all coordinates, ``source['auto']['estimated_rmse_cm']``)
combines: the chosen smoother's SURE for smoothed samples, the
noise estimate itself for samples left as measured, the spline's error on the clip's own
hole pattern hidden elsewhere for short holes, and fill-auto's self-validation for long
gaps -- each weighted by its number of samples.

>>> from mocapkit import datasets, io, corrupt
>>> clip = io.read(datasets.bundled("16_15.amc"))
>>> noisy, _ = corrupt.combine(clip, [("gaussian", {"sigma_cm": 2.0})], seed=0)
>>> out = Auto().denoise(noisy)
>>> out.source["auto"]["chain"][0] in ("gcv-spline", "mssa", "gcv-spline+mssa")
True
>>> 0.2 < out.source["auto"]["estimated_rmse_cm"] < 2.0
True
"""
from __future__ import annotations

import time

import numpy as np

from ..diagnose import SPIKE_RATE, diagnose, robust_fit
from ..gaps import gap_lengths
from ..motion import Motion
from ..solvers.gcv_spline import cutoff_hz, gcv_smooth
from ..solvers.mssa import mssa_denoise, sure
from .base import Denoiser, get, register
from .constraints import Interval, Real
from .fill_auto import DEFAULT_CANDIDATES

__all__ = ["Auto", "FILL_CANDIDATES"]

#: fills auto's fill-auto chooses from for long gaps: fill-auto's own, plus trnn (low-rank
#: completion: on ten 60-frame gaps of 16_15 at 120 fps trnn alone gave 0.30 cm where auto
#: without it gave 0.54; per-gap validation does not always pick right -- see the
#: gaps10x60 rows of docs/results/auto.md, e.g. balance@30 0.76 vs fill-auto's 0.39)
FILL_CANDIDATES = DEFAULT_CANDIDATES + ("trnn",)


@register
class Auto(Denoiser):
    """Diagnose, then remove spikes, smooth (GCV spline) and fill gaps; see the module
    docstring for the chain and the error estimate.

    Parameters
    ----------
    min_noise_cm : below this estimated noise (and without spikes) measured samples are
        kept as they are. Default 0.25 cm.
    spike_rate : fraction of flagged samples above which spikes are removed.
    long_gap_s : gaps longer than this (seconds) are filled by ``fill-auto``; shorter
        holes by the spline. Default 0.1 s.
    """

    name = "auto"
    description = ("diagnose the clip, remove spikes, smooth (best of GCV spline / MSSA by SURE), "
                   "fill long gaps by fill-auto; prints what it chose and an error estimate (cm)")
    needs_training = False
    keeps_observed = False
    fill_evidence = "markers"

    _parameter_constraints = {"min_noise_cm": [Interval(Real, 0, None)], "spike_rate": [Interval(Real, 0, 1)],
                              "long_gap_s": [Interval(Real, 0, None)]}

    def __init__(self, min_noise_cm: float = 0.25, spike_rate: float = SPIKE_RATE,
                 long_gap_s: float = 0.1):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        from ..solvers._linalg import blas_limit

        with blas_limit():          # many small solves: one BLAS thread is fastest
            return self._denoise(motion)

    def _denoise(self, motion: Motion) -> Motion:
        t0 = time.perf_counter()
        X, M = motion.matrix(), motion.matrix_mask()
        if motion.n_frames < 8:                     # too short to fit a smoothing spline
            return get("linear").denoise(motion).with_source(auto={
                "chain": ["linear fill (clip under 8 frames)"], "estimated_rmse_cm": None})
        robust = robust_fit(motion)
        fit, info, usable = robust
        diag = diagnose(motion, robust)
        cols = np.repeat(usable, 3)
        spiky = diag.spike_rate > float(self.spike_rate)
        if not spiky:                                    # nothing rejected: plain GCV fit
            f, info = gcv_smooth(X[:, cols], M[:, cols], group=3)
            fit[:, cols] = f
        holes = ~M
        holes[:, cols] |= info.rejected
        smooth = not (diag.noise_cm < float(self.min_noise_cm))
        out = np.where(holes, fit, X)
        est = self._per_channel_errors(info, cols, smooth)
        chain = ["spike removal"] if spiky else []
        if smooth:
            out[:, cols], picked, est["kept"][cols] = _smooth(
                out[:, cols], ~holes[:, cols], fit[:, cols], diag.noise_cm, motion.fps)
            chain.append(picked)
        long = self._long_gaps(motion)
        if (holes & ~long).any() and not smooth:
            chain.append("spline fill")
        e_long = None
        if long.any():
            out, e_long = self._fill_long(motion, out, long)
            chain.append("fill-auto")
        estimate = _combine(est, holes, long, e_long, usable)
        src = {
            "chain": chain, "diagnosis": diag.as_dict(),
            "gcv_cutoff_hz": float(np.median(cutoff_hz(info.s, 2, motion.fps))),
            "rejected": int(info.rejected[:, ::3].sum()) if spiky else 0,
            "estimated_rmse_cm": estimate, "seconds": time.perf_counter() - t0,
            "how": _how(smooth, bool(holes.any()), e_long is not None),
        }
        return motion.with_matrix(out).with_source(auto=src)

    def _long_gaps(self, motion: Motion) -> np.ndarray:
        """(T, 3J) True on samples of gaps longer than ``long_gap_s``."""
        length, _ = gap_lengths(motion.observed)
        never = ~motion.observed.any(axis=0)
        long = (length > float(self.long_gap_s) * motion.fps) & ~never[None, :]
        return np.repeat(long, 3, axis=1)

    @staticmethod
    def _per_channel_errors(info, cols: np.ndarray, smooth: bool) -> dict:
        """Estimated RMS error (C,) per sample class, NaN outside the fitted columns."""
        C = cols.size
        kept = np.full(C, np.nan)
        hole = np.full(C, np.nan)
        kept[cols] = info.smooth_error if smooth else info.sigma
        hole[cols] = info.hole_error if info.hole_error is not None else info.smooth_error
        return {"kept": kept, "hole": hole}

    def _fill_long(self, motion: Motion, out: np.ndarray, long: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Long gaps by fill-auto; returns the new matrix and the per-sample error estimate
        (T, 3J): fill-auto's own where it filled, and its validation bound (5 cm) where it
        found no fill validated under it -- those samples keep the spline's values, which
        nothing supports better, and the estimate says so instead of hiding them."""
        filler = get("fill-auto", candidates=FILL_CANDIDATES)
        work = motion.with_matrix(np.where(long, np.nan, out), observed=~long[:, ::3])
        filled = filler.denoise(work)
        Y = filled.matrix()
        take = long & np.isfinite(Y)
        out = out.copy()
        out[take] = Y[take]
        e_fill = filled.source.get("fill_auto", {}).get("estimated_rmse_cm")
        bound = float(filler.max_error_cm or 5.0)
        e = np.where(take, np.nan if e_fill is None else e_fill, bound)
        return out, np.where(long, e, np.nan)


def _smooth(Y: np.ndarray, kept: np.ndarray, fit: np.ndarray, sigma: float,
            fps: float) -> tuple[np.ndarray, str, float]:
    """Best of GCV spline, MSSA and their mean on the complete matrix Y (holes filled),
    judged by Monte-Carlo SURE on the kept samples. Returns (out, name, estimated RMSE).

    Measured on 5 CMU clips x 30/120 fps x Gaussian 1/3 cm (before the bench, see
    docs/results/auto.md for the full run): the mean of the two was best or tied in 18 of
    20 cases (0.60-0.80 x the oracle-tuned classical filter; GCV alone 0.67-0.92, MSSA
    alone 0.65-0.87), and the SURE pick was within 3 % of the best candidate.
    ``kalman-cv`` as a fourth candidate was tried: SURE picked it in 4 of 36 fast-motion
    cases and it was worse each time (its outlier gate makes it far from linear, and the
    one-probe divergence then misjudges it), so it is not a candidate.
    """
    window = max(2, min(int(round(0.13 * fps)), Y.shape[0] // 4))

    def f_gcv(Z):
        return gcv_smooth(Z, kept, group=3)[0]

    def f_mssa(Z):
        return mssa_denoise(Z, sigma, window=window)

    if Y.shape[0] < 4 * window:
        return fit, "gcv-spline", float(sigma)
    outs = {"gcv-spline": fit, "mssa": f_mssa(Y)}
    outs["gcv-spline+mssa"] = 0.5 * (outs["gcv-spline"] + outs["mssa"])
    funcs = {"gcv-spline": f_gcv, "mssa": f_mssa,
             "gcv-spline+mssa": lambda Z: 0.5 * (f_gcv(Z) + f_mssa(Z))}
    risk = {k: sure(funcs[k], Y, sigma, mask=kept, fy=outs[k], rng=0) for k in outs}
    best = min(risk, key=risk.get)
    return outs[best], best, float(np.sqrt(max(risk[best], 0.0)))


def _how(smooth: bool, holes: bool, long: bool) -> str:
    parts = ["Monte-Carlo SURE of the smoother" if smooth else "noise estimate (samples kept as measured)"]
    if holes:
        parts.append("spline on the clip's own holes hidden elsewhere")
    if long:
        parts.append("fill-auto self-validation")
    return ", ".join(parts)


def _combine(est: dict, holes: np.ndarray, long: np.ndarray, e_long: np.ndarray | None,
             usable: np.ndarray) -> float | None:
    """Sample-weighted RMS of the per-class estimates over the fitted points (cm)."""
    cols = np.repeat(usable, 3)
    short = holes & ~long
    kept = ~holes
    e_l = e_long if e_long is not None else np.full(holes.shape, np.nan)
    sq = np.where(kept, est["kept"] ** 2, np.where(short, est["hole"] ** 2, e_l ** 2))[:, cols]
    if not sq.size or not np.isfinite(sq).any():
        return None
    return float(np.sqrt(np.nanmean(sq)))
