"""Trust-data detection (TDD): flag marker samples that sit far from a robust smooth fit.

The thesis (seed 003, Sec. 3.4 eq. 3.13 and Sec. 4.1.1) uses the B-spline based trust data
detection of Feng et al. (2014b) with a 6 cm threshold to decide which entries are
missing or untrustworthy before PSC / TSMC / TrNN fill them; the details are "omitted"
there, so this is our implementation of the idea:

1. every joint trajectory (x, y, z over time) is fitted by a *discrete cubic smoothing
   spline* -- the penalised spline with one knot per frame (Whittaker-Henderson; Eilers
   2003, "A perfect smoother"): ``min_z sum_t w_t |p_t - z_t|^2 + s sum_t |z_{t-1} - 2 z_t
   + z_{t+1}|^2`` -- solved as one symmetric banded system per joint (the three coordinates
   share it), missing samples with weight 0;
2. robust reweighting (Tukey's bisquare on the 3-D residual, scale ``2 * threshold_cm``)
   for the first iterations, then hard rejection (weight 0 beyond the threshold), so
   spikes do not pull the fit towards them;
3. an observed sample whose 3-D distance from the final fit exceeds ``threshold_cm`` is
   untrusted.

The smoothing weight ``s`` comes from a cut-off frequency: the smoother's transfer function
is ``1 / (1 + s (2 - 2 cos w)^2)``; ``s`` is set so it is 1/2 at ``cutoff_hz`` (default
6 Hz, above the band of human movement, so true motion passes and one-frame spikes do
not).  As the thesis warns (Sec. 3.5, "Limitations"), very fast movements (kicks) can
exceed the threshold too: raise ``threshold_cm`` or ``cutoff_hz`` for them.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from scipy.linalg import solveh_banded

from .errors import MocapValueError
from .motion import Motion
from .windows import frame_blocks

__all__ = ["trust_data", "trusted_mask", "detect_report", "smoothing_weight"]


def smoothing_weight(cutoff_hz: float, fps: float) -> float:
    """Penalty s with half gain at ``cutoff_hz`` for a second-difference smoother at ``fps``."""
    w = 2.0 * np.pi * min(float(cutoff_hz) / float(fps), 0.5)
    return 1.0 / (2.0 - 2.0 * np.cos(w)) ** 2


def _penalty_bands(T: int, s: float) -> np.ndarray:
    """Upper banded storage (3, T) of s * D2^T D2 (D2: (T-2, T) second differences)."""
    main = np.full(T, 6.0)
    main[[0, -1]] = 1.0
    if T > 2:
        main[[1, -2]] = 5.0
    off1 = np.full(T - 1, -4.0)
    off1[[0, -1]] = -2.0
    off2 = np.ones(T - 2)
    ab = np.zeros((3, T))
    ab[2] = main
    ab[1, 1:] = off1
    ab[0, 2:] = off2
    if T == 3:       # D2 is one row [1, -2, 1]
        ab[2] = [1.0, 4.0, 1.0]
        ab[1, 1:] = [-2.0, -2.0]
    return s * ab


def _fit(Pz: np.ndarray, W: np.ndarray, pen: np.ndarray) -> np.ndarray:
    """Weighted smoothing fit of every joint: Pz (T, J, 3) (missing samples 0), weights W
    (T, J) -> (T, J, 3).

    Joints whose system is singular (fewer than 2 weighted samples) come back as NaN.
    """
    T, J, _ = Pz.shape
    Z = np.full_like(Pz, np.nan)
    for j in range(J):                         # one banded solve per joint, 3 right-hand sides
        w = W[:, j]
        if (w > 0).sum() < 2:
            continue
        ab = pen.copy()
        ab[2] += w
        try:
            Z[:, j] = solveh_banded(ab, w[:, None] * Pz[:, j], check_finite=False)
        except np.linalg.LinAlgError:
            continue
    return Z


def _distance(P: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """|P - Z| per sample (T, J), in blocks of frames (no (T, J, 3) temporary)."""
    r = np.empty(P.shape[:2])
    for sl in frame_blocks(len(P)):
        r[sl] = np.linalg.norm(P[sl] - Z[sl], axis=2)
    return r


def trust_data(motion: Motion, threshold_cm: float = 6.0, *, cutoff_hz: float = 6.0,
               n_iter: int = 5, return_fit: bool = False) -> Any:
    """Untrusted (outlying) observed samples: bool (T, J).

    Parameters
    ----------
    motion : the Motion to check (positions in cm).
    threshold_cm : distance from the robust fit beyond which a sample is untrusted
        (thesis: 6 cm).
    cutoff_hz : half-gain frequency of the smoothing spline (see module docstring).
    n_iter : robust reweighting iterations (2 bisquare, then hard rejection).
    return_fit : also return the fitted trajectories (T, J, 3) (NaN for joints with fewer
        than two trusted samples).

    Returns
    -------
    untrusted : bool (T, J), True where an *observed* sample lies more than
        ``threshold_cm`` from the fit (missing samples are False: combine with
        ``~motion.observed``, or use :func:`trusted_mask`).
    """
    if not isinstance(motion, Motion):
        raise MocapValueError(f"trust_data needs a Motion, got {type(motion).__name__}")
    thr = float(threshold_cm)
    if not np.isfinite(thr) or thr <= 0:
        raise MocapValueError(f"threshold_cm must be a positive number, got {threshold_cm!r}")
    if not np.isfinite(cutoff_hz) or cutoff_hz <= 0:
        raise MocapValueError(f"cutoff_hz must be a positive number, got {cutoff_hz!r}")
    P = motion.positions
    obs = motion.observed
    T, J = obs.shape
    untrusted = np.zeros((T, J), dtype=bool)
    if T < 4:
        return (untrusted, np.where(obs[..., None], P, np.nan)) if return_fit else untrusted
    pen = _penalty_bands(T, smoothing_weight(cutoff_hz, motion.fps))
    W = obs.astype(float)
    # one zero-filled copy for every refit (none for complete data: P is only read)
    Pz = P if obs.all() and np.isfinite(P).all() else np.where(np.isfinite(P), P, 0.0)
    Z = _fit(Pz, W, pen)
    c = 2.0 * thr
    for it in range(int(n_iter)):
        r = _distance(P, Z)                                     # NaN where missing / unfit
        r = np.where(np.isfinite(r), r, 0.0)
        if it < 2:
            u = np.clip(r / c, 0.0, 1.0)
            W_new = obs * (1.0 - u ** 2) ** 2
        else:
            W_new = (obs & (r <= thr)).astype(float)
        if np.array_equal(W_new, W):
            break
        W = W_new
        del Z                                                   # not two fits at once
        Z = _fit(Pz, W, pen)
    r = _distance(P, Z)
    untrusted = obs & np.isfinite(r) & (r > thr)
    return (untrusted, Z) if return_fit else untrusted


def trusted_mask(motion: Motion, threshold_cm: float = 6.0, **options: Any) -> np.ndarray:
    """Observed and trusted samples, bool (T, J) (the complement of the thesis' Omega)."""
    return motion.observed & ~trust_data(motion, threshold_cm, **options)


def _runs(frames: np.ndarray) -> list[list[int]]:
    """Consecutive runs [start, stop) of sorted frame indices."""
    if frames.size == 0:
        return []
    cut = np.flatnonzero(np.diff(frames) > 1) + 1
    starts = np.r_[frames[0], frames[cut]]
    stops = np.r_[frames[cut - 1] + 1, frames[-1] + 1] if cut.size else np.array([frames[-1] + 1])
    return [[int(a), int(b)] for a, b in zip(starts, stops)]


def detect_report(motion: Motion, threshold_cm: float = 6.0, **options: Any) -> dict:
    """Summary of :func:`trust_data` for printing or JSON export (the ``detect`` command).

    Returns
    -------
    dict with ``threshold_cm``, ``frames`` (T), ``fps``, ``n_flagged`` (samples),
    ``fraction`` (of observed samples), ``frames_flagged`` (frames with any flag),
    ``n_missing`` (samples already missing) and ``markers``: for each joint with flags, a
    dict ``{"count", "frames" (list of frame indices), "runs" (list of [start, stop))}``.
    """
    un = trust_data(motion, threshold_cm, **options)
    markers = {}
    for j in np.flatnonzero(un.any(axis=0)):
        fr = np.flatnonzero(un[:, j])
        markers[motion.skeleton.names[j]] = {"count": int(fr.size), "frames": fr.tolist(),
                                             "runs": _runs(fr)}
    n_obs = int(motion.observed.sum())
    return {"threshold_cm": float(threshold_cm), "frames": int(motion.n_frames),
            "fps": float(motion.fps), "n_flagged": int(un.sum()),
            "fraction": float(un.sum() / n_obs) if n_obs else 0.0,
            "frames_flagged": int(un.any(axis=1).sum()),
            "n_missing": int((~motion.observed).sum()), "markers": markers}
