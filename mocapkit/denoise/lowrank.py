"""Low-rank family: TSVD, SVT, RPCA (inexact ALM) and SLRA (segmented RPCA, seed 004).

All four work on the frame-by-coordinate matrix ``motion.matrix()`` (T x 3J, cm; the
papers use its transpose) with the observed mask ``motion.matrix_mask()``: missing markers
are left out of the data term and filled by the low-rank model.  They are training-free
and scale-equivariant (the same result in cm or in CMU units, up to the unit).  The math
lives in :mod:`mocapkit.solvers.lowrank`; these classes only handle Motions.

Decisions (measured, see docs/results/lowrank.md):

* No centring by default for tsvd, rpca and slra (the papers' setting): subtracting
  per-column means before the low-rank step made SLRA worse on most CMU clips under the
  noise of eq. 7 (the noise has mean 1, so the mean is biased; with short segments FD
  rose from 0.04-0.14 to 0.14-0.20 CMU units); ``center`` exposes "mean"/"median".  SVT
  centres by default (its iteration converges much faster without the mean component).
* Every method has ``keep_observed`` (default False): True returns observed entries
  unchanged and only fills the missing ones (gap filling without denoising).
* Channels that are never observed in a solve window (one SLRA segment) cannot be
  recovered from the low-rank model (it returns 0 there); they take the per-channel
  linear interpolation in time (:func:`mocapkit.gaps.fill`) instead.  A
  joint never observed in the whole clip is handled by the base class (a placeholder the
  solver may use, returned missing).
* Missing entries (issue 18).  With Lin et al.'s masked constraint (``missing="free"``:
  the sparse part absorbs every unobserved entry) the nuclear norm pulls the unobserved
  entries towards the origin: on a 95 %-missing clip rpca / slra filled 90-120 cm away
  where linear interpolation was within 5-8 cm, and even at 10-30 % random missing they
  were worse than interpolation.  The default ``missing="linear"`` starts the unobserved
  entries at the per-channel linear interpolation and treats them like observed ones (same
  l1 weight): where the interpolation is wrong the error goes to the sparse part and the
  low-rank part completes; measured on 16_15 (0.5 cm noise), RMSE on the missing entries
  0.5-0.7 vs 0.9-1.3 cm (10 % missing), 0.6-1.6 vs 11-20 cm (60 %), 4.7-5.6 vs 99-122 cm
  (95 %), and within 5 % of interpolation on 20-120-frame gaps of 8 markers (where
  'free' was 0.3-6x interpolation's error); tests/test_lowrank.py checks 95 % and 30 %.
  Without missing entries the two are the same (the SLRA paper's protocol).  Then (every missing mode, and svt) frames with too few observed
  markers take the linear fill (:func:`mocapkit.solvers.evidence.evidence_blend`).
* Convergence (issue 10): svt, rpca and slra store a summary of their iterative solve in
  ``source["convergence"]`` of the result (converged, iterations, max_iter, final residual vs tol; for slra the
  worst segment and how many missed tol) and emit one
  :class:`~mocapkit.errors.ConvergenceWarning` per ``denoise()`` call that stops at
  ``max_iter`` (:func:`mocapkit.denoise.base.report_convergence`).  Measured (docs/results/reliability.md): at
  default settings rpca and slra converge on the bundled CMU clips; svt with missing
  entries does not (after 500 iterations ||P(A - X)|| is still ~1.3 eps; ~1.05-1.1 eps after
  2000), so it warns.
"""
from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from .. import gaps
from ..errors import MocapValueError, MocapWarning
from ..motion import Motion
from ..signal import estimate_noise
from ..solvers import lowrank as _lr
from ..solvers.evidence import evidence_blend, far_from_data
from .base import Denoiser, register, report_convergence
from .constraints import Integral, Interval, Options, Real

#: per-column centring before the solve (``center``; "none" is the papers')
_CENTERS = ("none", "mean", "median")
_INT1 = Interval(Integral, 1, None)
_POSITIVE = Interval(Real, 0, None, closed="neither")
#: the constraints the four methods share
_COMMON = {"center": [Options(*_CENTERS)], "keep_observed": [bool], "max_iter": [_INT1]}
_ROBUST = {**_COMMON, "tol": [_POSITIVE], "lam": [_POSITIVE, None], "rho": [Interval(Real, 1, None, closed="neither")],
           "missing": [Options("linear", "free")]}

MIN_FRAMES = 6
"""Fewest frames RPCA/SLRA accept per solve window.  On clean CMU data (131_02) RPCA of
windows of 2 / 4 / 6 / 8 frames moves the data by 16 / 1.8 / 0.45 / 0.48 cm RMSE (mean
over windows): with lam = 1/sqrt(93) a window of a few frames has no low-rank structure
to exploit and whole rows go to E.  Shorter clips or segments raise MocapValueError."""


def _check_frames(n: int, method: str, what: str) -> None:
    if n < MIN_FRAMES:
        raise MocapValueError(
            f"{method}: {what} has {n} frame(s); robust PCA needs at least {MIN_FRAMES} "
            f"(use a longer clip/segment, or a filter such as 'median' for very short clips)")


def _inputs(motion: Motion, method: str, lin: bool = True) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(T, 3J) data with missing entries as NaN, its mask (None when complete), linear fill
    (``lin=False``: None, for a caller that makes it after its solve, when the solver's
    arrays are gone -- :func:`_linear_fill`)."""
    X = motion.matrix(copy=False)          # read only (the solvers copy what they change)
    mask = motion.matrix_mask()
    if not mask.any():
        raise MocapValueError(f"{method}: the motion has no observed entries")
    if mask.all():                         # complete: the linear fill is the data itself
        return X, None, X
    return X, mask, (_linear_fill(X, mask) if lin else None)


def _linear_fill(X: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """Per-channel linear interpolation in time of the unobserved entries (X if complete)."""
    return X if mask is None else gaps.fill(X, mask, never_observed=0.0)


def _centre(X: np.ndarray, mask: np.ndarray | None, how: str) -> np.ndarray:
    """Per-column centre (1, C) of observed entries ("none" -> zeros)."""
    if how == "none":
        return np.zeros((1, X.shape[1]))
    if how == "mean":                                   # no NaN-aware copy of the clip
        if mask is None:
            return X.mean(axis=0, keepdims=True)
        n = mask.sum(axis=0)
        s = np.sum(X, axis=0, where=mask)
        return np.where(n > 0, s / np.maximum(n, 1), 0.0)[None]
    Z = X if mask is None else np.where(mask, X, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        c = (np.nanmean if how == "mean" else np.nanmedian)(Z, axis=0, keepdims=True)
    return np.nan_to_num(c, nan=0.0)


def _finish(motion: Motion, A: np.ndarray, lin: np.ndarray, mask: np.ndarray | None,
            keep_observed: bool, windows: tuple[np.ndarray, np.ndarray] | None = None,
            den: Denoiser | None = None) -> Motion:
    """Put unrecoverable channels back to the linear fill and build the output Motion.

    Frames with too few observed markers move to the linear fill
    (:func:`~mocapkit.solvers.evidence.evidence_blend`).  A solve that stopped at
    ``max_iter`` far from the measured samples (``den.last_report_["convergence"]``;
    :func:`~mocapkit.solvers.evidence.far_from_data`: svt / rpca after 1 iteration are
    14-16 cm off on a CMU walk) is replaced by the measured samples and the linear fill,
    with a MocapWarning.  ``keep_observed``: observed entries are returned unchanged.
    """
    conv = getattr(den, "last_report_", {}).get("convergence") if den is not None else None
    if conv is not None and not conv.get("converged", True):
        X = motion.matrix(copy=False)                       # read only
        m = np.isfinite(X) if mask is None else mask
        far, resid, spread = far_from_data(A, X, m)
        if far:
            warnings.warn(f"{den.name}: stopped after {conv['iterations']} iterations far from the "
                          f"data (RMS {resid:.3g} cm from the measured samples, whose spread is "
                          f"{spread:.3g} cm): measured samples kept, gaps interpolated linearly; "
                          f"raise max_iter", MocapWarning, stacklevel=4)
            A = lin.copy()
    if mask is not None:
        A = evidence_blend(A, lin, mask, motion.observed, copy=False)   # A is ours
        starts, stops = windows if windows is not None else (np.array([0]), np.array([len(A)]))
        for a, b in zip(starts, stops):                     # a handful of segments, not frames
            dead = ~mask[a:b].any(axis=0)
            if dead.any():
                A[a:b, dead] = lin[a:b, dead]
    if not np.isfinite(A).all():                           # defensive: never return NaN
        bad = ~np.isfinite(A)
        A[bad] = lin[bad]
    if keep_observed:
        obs = np.ones(A.shape, bool) if mask is None else mask
        A[obs] = lin[obs]                                   # lin == data on observed entries
    return motion.with_matrix(A, handover=True)             # A is ours: no copy of the clip


@register
class TSVD(Denoiser):
    """Truncated SVD: the best rank-k approximation of the T x 3J matrix (Eckart-Young).

    The TSVD baseline of SLRA (seed 004, Sec. 4.3: "取前10个较大的本征值", k = 10) and of
    Lai et al. (2011).  Missing entries: iterative hard imputation
    (:func:`mocapkit.solvers.lowrank.tsvd`).

    Parameters
    ----------
    k : singular values kept (default 10, as seed 004).
    center : "none" (paper), "mean" or "median" -- subtract per-column centres first.
    max_iter : imputation iterations when entries are missing.
    keep_observed : return observed entries unchanged (gap filling only).
    """

    name = "tsvd"
    misfit_check = "fitted"
    fill_evidence = "markers"
    description = "truncated SVD, keep k singular values of the frames x coordinates matrix (SLRA baseline)"
    clean_tolerance_cm = 2.0

    _parameter_constraints = {"k": [_INT1], **_COMMON}

    def __init__(self, k: int = 10, center: str = "none", max_iter: int = 100,
                 keep_observed: bool = False):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        X, mask, lin = _inputs(motion, self.name)
        c = _centre(X, mask, self.center)
        A = _lr.tsvd(X - c, int(self.k), mask, max_iter=int(self.max_iter)) + c
        return _finish(motion, A, lin, mask, bool(self.keep_observed))


@register
class SVT(Denoiser):
    """Singular value thresholding (Cai, Candes & Shen 2010; Lai et al. 2011 for mocap).

    ``min tau ||A||_* + 1/2 ||A||_F^2  s.t.  ||P_Omega(A - X)||_F <= eps`` on the T x 3J
    matrix (Cai et al. eqs. 1.3 / 3.12-3.13), Omega = observed entries.  ``eps`` is the
    expected noise norm: ``noise_cm * sqrt(|Omega|)``; by default ``noise_cm`` is estimated
    from the data (:func:`mocapkit.signal.estimate_noise`, ``method="diff2-rms"``: RMS
    second difference / sqrt 6).  Fully observed input is solved in closed form; with missing entries the SVT
    iteration runs (``max_iter``, ``tol``).

    Parameters
    ----------
    tau, delta : SVT threshold and step (default Cai et al.'s, made scale-free).
    noise_cm : per-entry noise level in cm (None = estimate; 0 = exact interpolation).
    center : "mean" (default: subtracting column means of the observed entries removes the
        dominant mean component; with missing entries the SVT iteration then converges in
        far fewer iterations -- 1.2 vs 1.9 cm RMSE after 500 iterations on 16_15 with 1 cm
        noise + 10 % missing), "none" or "median".
    tol, max_iter : SVT iteration (used only with missing entries).
    keep_observed : return observed entries unchanged (gap filling only).
    """

    name = "svt"
    misfit_check = "fitted"
    fill_evidence = "markers"
    description = "singular value thresholding (Cai-Candes-Shen), noise-bounded, completes missing markers"
    clean_tolerance_cm = 1.0

    @classmethod
    def quick_params(cls) -> dict[str, Any]:
        return {"max_iter": 150}

    _parameter_constraints = {"tau": [_POSITIVE, None], "delta": [_POSITIVE, None],
                              "noise_cm": [Interval(Real, 0, None), None], "tol": [_POSITIVE], **_COMMON}

    def __init__(self, tau: float | None = None, delta: float | None = None,
                 noise_cm: float | None = None, center: str = "mean", tol: float = 1e-4,
                 max_iter: int = 500, keep_observed: bool = False):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        X, mask, _ = _inputs(motion, self.name, lin=False)    # the fill after the solve
        c = _centre(X, mask, self.center)
        noise = (estimate_noise(X, mask, method="diff2-rms", pool="all", fallback=0.0)
                 if self.noise_cm is None else float(self.noise_cm))
        n_obs = X.size if mask is None else int(mask.sum())
        A, info = _lr.svt(X - c, mask, self.tau, self.delta, eps=noise * np.sqrt(n_obs),
                          tol=float(self.tol), max_iter=int(self.max_iter), return_info=True,
                          overwrite_x=True)                 # X - c is ours: the result goes in it
        A += c
        lin = _linear_fill(X, mask)
        fit = float(info.extra.get("fit_ratio", 0.0))
        report_convergence(self, info, tol=float(self.tol), max_iter=int(self.max_iter),
                           extra={"fit_ratio": fit},
                           detail=(f"; data fit ||P(A - X)|| / eps = {fit:.3f}, needs <= 1.001"
                                   if fit > 1.001 else ""))
        return _finish(motion, A, lin, mask, bool(self.keep_observed), den=self)


@register
class RPCA(Denoiser):
    """Robust PCA of the whole clip: ``min ||A||_* + lam ||E||_1 s.t. A + E = D``.

    Principal component pursuit (Candes, Li, Ma & Wright 2011) by inexact ALM (Lin, Chen
    & Ma 2010, Alg. 5; SLRA eqs. 3-6 and Table 1) on the T x 3J matrix, lam =
    1/sqrt(max(T, 3J)); missing entries are excluded from the constraint and completed.
    The global-RPCA baseline of SLRA (seed 004, Table 2).

    Parameters
    ----------
    lam : sparsity weight (None = 1/sqrt(max(m, n))).
    center : "none" (default), "mean" or "median".
    Clips under MIN_FRAMES = 6 frames raise MocapValueError.
    tol, max_iter, rho : IALM stopping tolerance (Lin et al. 1e-7), cap, mu growth.
    missing : "linear" (default: unobserved entries start at the linear interpolation and
        count as data, module docstring) or "free" (Lin et al.'s masked constraint).
    keep_observed : return observed entries unchanged (gap filling only).
    """

    name = "rpca"
    misfit_check = "fitted"
    fill_evidence = "markers"
    description = "robust PCA (low rank + sparse) of the whole clip by inexact ALM (Lin-Chen-Ma)"
    clean_tolerance_cm = 2.0

    _parameter_constraints = _ROBUST

    def __init__(self, lam: float | None = None, center: str = "none", tol: float = 1e-7,
                 max_iter: int = 500, rho: float = 1.5, missing: str = "linear",
                 keep_observed: bool = False):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        _check_frames(motion.n_frames, self.name, "the clip")
        mode = self.missing
        X, mask, lin = _inputs(motion, self.name)
        D, Dmask = (lin, None) if mode == "linear" else (X, mask)
        c = _centre(D, Dmask, self.center)
        A, _, info = _lr.rpca_ialm(D - c if c.any() else D, self.lam, Dmask, float(self.tol),
                                   int(self.max_iter), rho=float(self.rho), return_info=True,
                                   want_E=False)
        report_convergence(self, info, tol=float(self.tol), max_iter=int(self.max_iter))
        A += c
        return _finish(motion, A, lin, mask, bool(self.keep_observed), den=self)


@register
class SLRA(Denoiser):
    """Segmented low-rank approximation (Peng, Liu, Cui & Zheng; seed 004).

    Split the T frames into consecutive segments, run RPCA by inexact ALM on each segment's
    (m_i x 3J) matrix with lam = 1/sqrt(max(m_i, 3J)) (eqs. 2-6, Table 1), concatenate the
    low-rank parts in time order (Sec. 3.2).  Missing entries are completed per segment.

    Parameters
    ----------
    segment : segment length in frames (default 200, the paper's best in Table 3).  A clip
        shorter than one segment is processed as a single segment (= ``rpca``); clips or
        segments under MIN_FRAMES = 6 frames raise MocapValueError.
    overlap : frames shared by neighbouring segments, blended by linear cross-fade (our
        extension; 0 = the paper).  Measured on CMU clips under eq.-7 noise: overlap of a
        quarter to half a segment lowers FD by 5-30 %, most for short segments.
    n_segments : fixed number of segments (the paper's tables give counts); overrides
        ``segment``.
    lam : fixed sparsity weight (None = per segment, as the paper).
    center : "none" (paper, default), "mean", "median" per segment.
    tol, max_iter, rho : IALM settings (Lin et al.: 1e-7, rho 1.5).  A looser ``tol``
        (1e-4..1e-5) changes FD by < 0.1 % and needs ~40 % fewer iterations.
    missing : "linear" (default) or "free", as :class:`RPCA`.
    keep_observed : return observed entries unchanged (gap filling only).

    Short segments work much better than the paper's 200 frames on 120 fps CMU data
    (e.g. ``segment=24, overlap=12``: FD about 1/3 of the paper setting, see
    docs/results/lowrank.md); the default stays the paper's.
    """

    name = "slra"
    misfit_check = "fitted"
    fill_evidence = "markers"
    description = "segmented RPCA (SLRA, seed 004): IALM per consecutive segment, optional blended overlap"
    clean_tolerance_cm = 2.0

    # overlap < segment depends on both: checked by the solver's segment layout
    _parameter_constraints = {"segment": [_INT1], "overlap": [Interval(Integral, 0, None)],
                              "n_segments": [_INT1, None], **_ROBUST}

    def __init__(self, segment: int = 200, overlap: int = 0, n_segments: int | None = None,
                 lam: float | None = None, center: str = "none", tol: float = 1e-7,
                 max_iter: int = 500, rho: float = 1.5, missing: str = "linear",
                 keep_observed: bool = False):
        self._store_params(locals())

    @classmethod
    def quick_params(cls) -> dict[str, Any]:
        return {"segment": 24, "overlap": 12, "tol": 1e-5}

    def denoise(self, motion: Motion) -> Motion:
        starts, stops = _lr.segment_layout(motion.n_frames, int(self.segment), int(self.overlap),
                                           self.n_segments)
        _check_frames(int((stops - starts).min()), self.name,
                      "the clip" if len(starts) == 1 else "a segment")
        mode = self.missing
        X, mask, lin = _inputs(motion, self.name)
        A, _, info = _lr.slra(lin if mode == "linear" else X, int(self.segment), int(self.overlap),
                              n_segments=self.n_segments, mask=None if mode == "linear" else mask,
                              lam=self.lam,
                              center=self.center, tol=float(self.tol),
                              max_iter=int(self.max_iter), rho=float(self.rho),
                              return_info=True)
        report_convergence(self, info, tol=float(self.tol), max_iter=int(self.max_iter))
        return _finish(motion, A, lin, mask, bool(self.keep_observed),
                       (info.extra["starts"], info.extra["stops"]),
                       den=self)
