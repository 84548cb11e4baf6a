"""Low-rank completion of the thesis (Z. Wang 2017, seed 003, Ch. 4) and the DynaMMo baseline.

* ``tsmc`` -- bilinear low-rank + sparse error + temporal smoothness (Sec. 4.1).
* ``trnn`` -- truncated nuclear norm + sparse error + smoothness (Sec. 4.2).
* ``dynammo`` -- linear dynamical system completion by EM (Li et al. 2009), the classical
  gap filler the thesis compares with (Fig. 3.7, 4.11).

The maths lives in :mod:`mocapkit.solvers.completion`; these classes handle Motions and
masks.  Solver diagnostics (iterations, convergence) go to ``out.source["solver"]`` and to
the result's ``source["convergence"]`` summary (see :func:`mocapkit.denoise.base.report_convergence`);
a solver that stops before converging also warns once per ``denoise()`` call
(:class:`mocapkit.errors.ConvergenceWarning`).

Which entries are refilled: ``tsmc``/``trnn`` take the observed mask (optionally narrowed
by trust-data detection, ``detect=True``) and return the low-rank model everywhere
(``keep_observed=False``, the thesis' output) or only in the holes (``keep_observed=True``);
``dynammo`` keeps observed (trusted) entries and replaces only missing or untrusted ones.
"""
from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from .. import gaps
from ..io.units import CMU_CM_PER_UNIT
from ..motion import Motion
from ..errors import ConvergenceWarning
from ..solvers import completion as _cp
from ..solvers import lowrank as _lr
from ..solvers.evidence import evidence_blend
from ..solvers.info import SolveInfo
from ._refill import check_motion, known_mask, output, record, solver_info, unusable_guard
from .base import Denoiser, register
from .constraints import Integral, Interval, Options, Real

_POSITIVE = Interval(Real, 0, None, closed="neither")
_NONNEG = Interval(Real, 0, None)
_ABOVE_1 = Interval(Real, 1, None, closed="neither")      # ALM penalty growth factors

__all__ = ["TSMC", "TrNN", "DynaMMo"]


# --------------------------------------------------------------------------------------
# low-rank completion (Ch. 4)
# --------------------------------------------------------------------------------------
class _MatrixCompletion(Denoiser):
    """Shared Motion handling of tsmc / trnn: (T, 3J) matrix + mask in, estimate out.

    The thesis' weights (beta, mu: squared second differences; alpha, lam: l1 of the
    error) are not scale-free and the thesis does not state its unit.  Decision: they are
    read in CMU ASF length units (the unit of the CMU ASF/AMC data the thesis uses;
    1 unit = 5.6444 cm): the (T, 3J) matrix is divided by ``unit_cm`` before solving and the
    result multiplied back.  Measured on CMU 05_06 and 02_01 (not protocol clips), this
    beats reading them in cm or in metres in most missing-data conditions
    (docs/results/thesis.md).  The conversion is a scale only, so it commutes with the
    base class's recentring (translation equivariance is the base class's job).

    Missing entries of frames with few observed markers move to the linear interpolation
    in time (:func:`mocapkit.solvers.evidence.evidence_blend`; issue 18: on a 95 %-missing
    clip tsmc / trnn filled 76 / 32 cm off where interpolation was 8 cm off).  Frames with
    at least 35 % of the markers observed (every frame of the thesis' protocols) are not
    affected.
    """

    keeps_observed = False
    fill_evidence = "markers"
    clean_tolerance_cm = 1.0
    #: the constraints tsmc and trnn share
    _SHARED = {"tol": [_POSITIVE], "max_iter": [Interval(Integral, 1, None)], "detect": [bool],
               "segment": [Interval(Integral, 256, None), None],
               "threshold_cm": [_POSITIVE], "keep_observed": [bool], "unit_cm": [_POSITIVE],
               "mstep": [Options("dct", "banded", "auto")], "seed": [Interval(Integral, 0, None)]}

    def _solve(self, X: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, SolveInfo]:
        raise NotImplementedError

    def _solve_segments(self, X: np.ndarray, km: np.ndarray, unit: float) -> tuple[np.ndarray, SolveInfo]:
        """The solve of the whole (T, 3J) matrix, or of overlapping time segments of
        ``segment`` frames (neighbours share at least ``segment // SEGMENT_OVERLAP_DIVISOR``
        frames, cross-faded linearly, as SLRA's overlap; the length rounded up to a fast
        FFT length for the DCT M-step) when the clip is longer; returns
        the estimate in cm and one summary of the solves."""
        starts, stops = (np.array([0]), np.array([len(X)])) if self.segment is None else \
            _lr.segment_layout(len(X), int(self.segment), int(self.segment) // SEGMENT_OVERLAP_DIVISOR,
                               fast=True)
        if len(starts) == 1:
            A, info = self._solve(X / unit, km)
            A *= unit
            return A, info
        A = np.zeros(X.shape)
        infos = []
        with warnings.catch_warnings(record=True) as caught:      # one warning, not one per segment
            warnings.simplefilter("always", ConvergenceWarning)
            for a, b, w in zip(starts, stops, _lr.blend_weights(starts, stops)):
                Ai, info = self._solve(X[a:b] / unit, km[a:b])
                Ai *= (w * unit)[:, None]
                A[a:b] += Ai
                infos.append(info)
        missed = [w for w in caught if issubclass(w.category, ConvergenceWarning)]
        for w in caught:
            if w not in missed:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        if missed:
            warnings.warn(f"{missed[0].message} ({len(missed)} of {len(starts)} segments of "
                          f"{int(self.segment)} frames)", ConvergenceWarning, stacklevel=4)
        info = SolveInfo(int(max(i.n_iter for i in infos)), bool(all(i.converged for i in infos)),
                         float(max(i.residual for i in infos)), infos[0].criterion,
                         {"rank": int(max(i.extra.get("rank", 0) for i in infos)), "segments": len(starts)})
        return A, info

    def denoise(self, motion: Motion) -> Motion:
        motion = check_motion(motion, self.name)
        known = known_mask(motion, bool(self.detect), float(self.threshold_cm))
        X = motion.matrix(copy=False)          # read only
        km = np.repeat(known, 3, axis=1)
        A, info = self._solve_segments(X, km, float(self.unit_cm))
        record(self, info)
        lin = gaps.fill(X, km, never_observed=0.0)
        if not info.converged:
            A, info = unusable_guard(self.name, A, X, km, lin, info)
        if not km.all():                 # frames with few markers: interpolation in time
            A = evidence_blend(A, lin, km, known, copy=False)   # A is ours
        return output(motion, A, known, bool(self.keep_observed), solver_info(self.name, info))


SEGMENT_OVERLAP_DIVISOR = 16
"""Neighbouring segments of tsmc / trnn share ``segment // 16`` frames (512 of 8,192)."""

SEGMENT_FRAMES = 8192
"""Default ``segment`` of tsmc / trnn: clips longer than about 1.5 x 8,192 frames (68 s at
120 fps) are solved in overlapping segments.  Why: the ALM keeps six to eight arrays of
the clip's size (U, E, M, two multipliers, scratch): a 100,000-frame clip needed 11-12x
its own size in memory and ran 25-39 % slower per frame than a 10,000-frame one; per
segment the memory is bounded and the speed per frame stays that of a 10k clip.  The
thesis' clips are far shorter, so its protocols are unchanged.  Accuracy, measured on the
8 trials of CMU subject 135 back to back (19,875 frames, 0.5 cm noise, 39 gaps of 60
frames on 6 markers; RMSE away from the trial boundaries; whole clip / 8,192 / 4,096):
trnn 0.601 / 0.586 / 0.641 cm on all samples, 2.60 / 2.52 / 3.06 cm in the gaps; tsmc
0.642 / 0.616 / 0.617 and 3.07 / 2.82 / 2.85 cm -- one low-rank model per minute of
capture fits a long take of changing motions no worse than one for all of it (at this
length the three segments cost 27-33 % more CPU time than one solve; at 100,000 frames they
are faster: docs/results/segments.md, benchmarks/long_clip_segments.py; scaling.md)."""


@register
class TSMC(_MatrixCompletion):
    """Bilinear low-rank + sparse + smooth completion (thesis Sec. 4.1, Algorithm 2).

    ``min 1/2(||U||^2 + ||V||^2) + alpha ||Omega o E||_1 + beta/2 ||O M||^2`` s.t.
    ``X = U V^T + E, M = U V^T`` on the (T, 3J) matrix (cm), by ALM with the slack variable
    M (eqs. 4.6-4.14, misprints fixed; :func:`mocapkit.solvers.completion.tsmc`).  This is
    the TSMC model of Feng et al. (2014b) solved with the thesis' bilinear factorisation;
    the rank k comes from the last-significant-jump rule (eq. 4.15).

    Parameters
    ----------
    alpha, beta, lam1, lam2, gamma, lam_max : thesis settings 1, 100, 1e-5, 1e-5, 1.4, 1e10.
    rank : factor width k; None = full width min(T, 3J) (our default), "lsj" = the thesis'
        rule (eq. 4.15) with :func:`~mocapkit.solvers.completion.estimate_rank`.
    tol, max_iter : ALM stopping.
    unit_cm : length unit the weights are read in (default: CMU ASF unit, see below).
    mstep : "dct" (thesis), "banded" (same solve, O(T), any length) or "auto" (default: the
        DCT where the length is a fast FFT length, else banded;
        :func:`~mocapkit.solvers.completion.smooth_solve`).
    detect : also treat trust-data outliers (``threshold_cm``) as missing.
    keep_observed : return observed (trusted) entries unchanged (gap filling only).
    segment : frames per solve on long clips (default :data:`SEGMENT_FRAMES` = 8,192;
        overlapping segments, cross-faded); None solves the whole clip at once.
    """

    name = "tsmc"
    misfit_check = "fitted"
    fill_drifts = True              # a temporal model (Denoiser.fill_drifts)
    description = "thesis bilinear low-rank + sparse error + 2nd-difference smoothness (TSMC model, ALM)"

    _parameter_constraints = {**_MatrixCompletion._SHARED, "alpha": [_POSITIVE], "beta": [_NONNEG],
                              "lam1": [_POSITIVE], "lam2": [_POSITIVE], "gamma": [_ABOVE_1],
                              "lam_max": [_POSITIVE], "rank": [Interval(Integral, 1, None), Options("lsj"), None]}

    def __init__(self, alpha: float = 1.0, beta: float = 100.0, lam1: float = 1e-5,
                 lam2: float = 1e-5, gamma: float = 1.4, lam_max: float = 1e10,
                 rank: int | str | None = None, tol: float = 1e-4, max_iter: int = 500,
                 detect: bool = False, threshold_cm: float = 6.0, keep_observed: bool = False,
                 unit_cm: float = CMU_CM_PER_UNIT, mstep: str = "auto", seed: int = 0,
                 segment: int | None = SEGMENT_FRAMES):
        self._store_params(locals())

    def _solve(self, X, mask):
        A, info = _cp.tsmc(X, mask, rank=self.rank, alpha=float(self.alpha), beta=float(self.beta),
                           lam1=float(self.lam1), lam2=float(self.lam2), gamma=float(self.gamma),
                           lam_max=float(self.lam_max), tol=float(self.tol),
                           max_iter=int(self.max_iter), seed=int(self.seed),
                           mstep=str(self.mstep), return_info=True)
        return A, info


@register
class TrNN(_MatrixCompletion):
    """Truncated nuclear norm completion with smoothness (thesis Sec. 4.2, Algorithm 3).

    ``min ||X||_r + lam ||P_Omega(S)||_1 + mu/2 ||O M||^2`` (eqs. 4.21-4.23) on the (T, 3J)
    matrix (cm) by a single-loop ALM with a DCT-diagonalised M-step
    (:func:`mocapkit.solvers.completion.trnn`).  Settings of Sec. 4.2.3 (real data):
    lam = 100/sqrt(max(m, n)), mu = 100, rho = 1.4, eta0 = 1e-5, eps = 1e-4, r = 15;
    factor width d = min(T, 3J) by default ("lsj": the thesis' round(1.2 rank), at least
    r + 1).

    Parameters
    ----------
    r, d, lam, mu, rho, eta, eta_max, tol, max_iter : see above (None = thesis rule).
    detect, threshold_cm, keep_observed, unit_cm, mstep, segment : as :class:`TSMC`.
    """

    name = "trnn"
    misfit_check = "fitted"
    fill_drifts = True              # a temporal model (Denoiser.fill_drifts)
    description = "thesis truncated nuclear norm + sparse error + smoothness, single-loop ALM with DCT M-step"

    _parameter_constraints = {**_MatrixCompletion._SHARED, "r": [Interval(Integral, 0, None)],
                              "d": [Interval(Integral, 1, None), Options("lsj"), None],
                              "lam": [_POSITIVE, None], "mu": [_NONNEG], "rho": [_ABOVE_1],
                              "eta": [_POSITIVE], "eta_max": [_POSITIVE]}

    def __init__(self, r: int = 15, d: int | str | None = None, lam: float | None = None,
                 mu: float = 100.0, rho: float = 1.4, eta: float = 1e-5, eta_max: float = 1e6,
                 tol: float = 1e-4, max_iter: int = 500, detect: bool = False,
                 threshold_cm: float = 6.0, keep_observed: bool = False,
                 unit_cm: float = CMU_CM_PER_UNIT, mstep: str = "auto", seed: int = 0,
                 segment: int | None = SEGMENT_FRAMES):
        self._store_params(locals())

    def _solve(self, X, mask):
        A, info = _cp.trnn(X, mask, r=int(self.r), d=self.d, lam=self.lam, mu=float(self.mu),
                           rho=float(self.rho), eta=float(self.eta), eta_max=float(self.eta_max),
                           tol=float(self.tol), max_iter=int(self.max_iter), seed=int(self.seed),
                           mstep=str(self.mstep), return_info=True)
        return A, info


@register
class DynaMMo(Denoiser):
    """DynaMMo gap filling: a linear dynamical system fitted by EM with missing values.

    Li, McCann, Pollard & Faloutsos (2009), KDD (the LDS baseline of thesis Fig. 3.7/4.11);
    :func:`mocapkit.solvers.completion.lds_em_complete` on the (T, 3J) matrix (cm).
    Observed entries are kept; missing (and, with ``detect``, untrusted) ones are filled
    with the smoothed LDS prediction.

    Parameters
    ----------
    k : latent dimension (default 48, capped at 3J: measured on CMU 05_06 with 20 % random
        missing markers, k = 16 / 32 / 48 / 64 gives 2.0 / 0.51 / 0.32 / 0.32 cm -- missing
        entries are predicted as C E[z], so k must be large enough for C z to reproduce a
        frame).  max_iter, tol : EM stopping.
    estep : "fill" (DynaMMo: smooth the filled data, fast) or "observed" (condition on the
        observed entries only, exact but ~10x slower); see
        :func:`~mocapkit.solvers.completion.lds_em_complete`.
    detect, threshold_cm : treat trust-data outliers as missing.
    """

    name = "dynammo"
    misfit_check = "fitted"
    fill_drifts = True              # a temporal model (Denoiser.fill_drifts)
    fill_evidence = "markers"
    description = "DynaMMo: linear dynamical system with missing values fitted by EM (Kalman/RTS E-step)"
    keeps_observed = True
    clean_tolerance_cm = 1.0

    _parameter_constraints = {"k": [Interval(Integral, 1, None)], "max_iter": [Interval(Integral, 1, None)],
                              "tol": [_POSITIVE], "estep": [Options("fill", "observed")], "detect": [bool],
                              "threshold_cm": [_POSITIVE]}

    def __init__(self, k: int = 48, max_iter: int = 100, tol: float = 1e-4, estep: str = "fill",
                 detect: bool = False, threshold_cm: float = 6.0):
        self._store_params(locals())

    @classmethod
    def quick_params(cls) -> dict[str, Any]:
        return {"max_iter": 20}

    def denoise(self, motion: Motion) -> Motion:
        motion = check_motion(motion, self.name)
        known = known_mask(motion, bool(self.detect), float(self.threshold_cm))
        km = np.repeat(known, 3, axis=1)
        X = motion.matrix(copy=False)          # read only (the solver copies)
        A, info = _cp.lds_em_complete(X, km, k=int(self.k), max_iter=int(self.max_iter),
                                      tol=float(self.tol), estep=str(self.estep),
                                      return_info=True)
        record(self, info)
        return output(motion, A, known, True, solver_info(self.name, info))
