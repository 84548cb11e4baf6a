"""Where a cross-marker model has no evidence: hand the fill over to interpolation in time.

A low-rank or learned pose model fills a missing marker of frame t from the markers
observed *in that frame* (and, through its temporal terms, from nearby frames).  In a
frame where only a few markers are seen, the model's per-frame coefficients are not
determined by the data and its fill drifts towards whatever its regulariser prefers --
for nuclear-norm models the origin, which is how ``rpca`` / ``slra`` / ``svt`` / ``tsmc``
reached 30-120 cm errors on a 95 %-missing clip whose linear interpolation was within
6-8 cm (issue 18).  Per-channel linear interpolation in time needs no other marker.

:func:`blend_weight` is the share of the model's fill kept in each frame, a ramp on the
fraction ``r_t`` of markers observed in the frame::

    beta_t = clip((r_t - lo) / (hi - lo), 0, 1),   lo = 0.15, hi = 0.35

and :func:`evidence_blend` returns ``beta_t A + (1 - beta_t) L`` on the missing entries
(A the model, L the linear fill), observed entries untouched.  With 35 % or more of the
markers seen in a frame the model is used unchanged, so the papers' protocols (at most
60 % of the markers of a frame removed, thesis Sec. 4.2.3; 10-30 % in the low-rank
protocols) are not affected; a frame with fewer than 15 % of its markers (fewer than
5 of 31 CMU joints) is filled by interpolation.  The thresholds are in fractions of the
markers, so they do not depend on the marker count or on any unit.
"""
from __future__ import annotations

import numpy as np

from ..windows import frame_blocks

__all__ = ["LO", "HI", "blend_weight", "evidence_blend", "UNUSABLE_RESIDUAL", "far_from_data"]

LO = 0.15
HI = 0.35


def blend_weight(observed: np.ndarray, lo: float = LO, hi: float = HI) -> np.ndarray:
    """(T,) weight of the model's fill per frame from the (T, J) observed-marker mask."""
    obs = np.asarray(observed, dtype=bool)
    if obs.ndim != 2 or obs.shape[1] == 0:
        raise ValueError(f"observed must be a (T, J) mask, got shape {obs.shape}")
    ever = obs.any(axis=0)
    n = max(int(ever.sum()), 1)
    r = obs[:, ever].sum(axis=1) / n
    if hi <= lo:
        return (r >= hi).astype(float)
    return np.clip((r - lo) / (hi - lo), 0.0, 1.0)


def evidence_blend(A: np.ndarray, L: np.ndarray, mask: np.ndarray, observed: np.ndarray,
                   lo: float = LO, hi: float = HI, *, copy: bool = True) -> np.ndarray:
    """Model fill A (T, C) moved towards the linear fill L (T, C) in frames with little
    evidence; ``mask`` (T, C) True = observed coordinate (left as in A); ``observed``
    (T, J) the per-marker mask the weight is computed from.  Entries where L is not
    finite keep A.  ``copy=False``: a float64 A the caller owns is changed in place."""
    A = np.array(A, dtype=float, copy=True if copy else None)
    m = np.asarray(mask, dtype=bool)
    beta = blend_weight(observed, lo, hi)
    if (beta >= 1).all():
        return A
    Lf = np.asarray(L, dtype=float)
    w = np.broadcast_to(beta[:, None], A.shape)
    use = ~m & (w < 1) & np.isfinite(Lf)
    wu = w[use]
    with np.errstate(invalid="ignore", over="ignore"):
        A[use] = np.where(wu > 0, wu * A[use] + (1 - wu) * Lf[use], Lf[use])
    return A


#: a stopped-early estimate farther than this (RMS, relative to the RMS spread of the
#: measured samples about their channel means) from the measured samples is not usable
UNUSABLE_RESIDUAL = 0.5


def far_from_data(A: np.ndarray, X: np.ndarray, mask: np.ndarray,
                  limit: float = UNUSABLE_RESIDUAL) -> tuple[bool, float, float]:
    """Whether an estimate A (T, C) is nowhere near the measured samples of X.

    Returns (far, resid, spread): ``resid = rms(P(A - X))``, ``spread = rms(P(X - channel
    mean))`` over the observed entries ``mask`` (same unit as X), ``far = not resid <=
    limit * spread``.  Both are translation-invariant and scale with the data.  Measured on
    a CMU walk (1 cm noise, 5 % missing): tsmc / trnn after 1-10 ALM iterations 1.4-4.2
    (every marker near the origin, 80 cm RMSE), tsmc after 20 iterations 0.75 (14 cm),
    estimates after 30+ iterations 0.07-0.2.
    """
    m = np.asarray(mask, dtype=bool)
    if not m.any():
        return False, 0.0, 0.0
    X, A = np.asarray(X, dtype=float), np.asarray(A, dtype=float)
    cnt = m.sum(axis=0)
    mean = np.sum(X, axis=0, where=m) / np.maximum(cnt, 1)
    n, ss, rr = int(cnt.sum()), 0.0, 0.0
    with np.errstate(invalid="ignore", over="ignore"):
        for sl in frame_blocks(len(X)):             # blocks of frames: no copies of the clip
            d = X[sl] - mean
            ss += float(np.sum(d * d, where=m[sl]))
            np.subtract(A[sl], X[sl], out=d)
            rr += float(np.sum(d * d, where=m[sl]))
    spread, resid = float(np.sqrt(ss / n)), float(np.sqrt(rr / n))
    return (not resid <= limit * max(spread, 1e-12)), resid, spread

