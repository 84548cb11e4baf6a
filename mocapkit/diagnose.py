"""What is wrong with a clip: noise level, spikes, gaps and frame rate, measured on the clip.

One robust smoothing-spline fit (:func:`mocapkit.solvers.gcv_spline.gcv_smooth`, smoothing
chosen by GCV, bisquare outlier rejection on each point's 3-D residual) gives both numbers
a cleaning tool needs first:

* **noise** -- the GCV noise estimate sigma^2 = RSS / (n - tr H) on the samples kept
  (Wahba 1990 Sec. 4.7), median over coordinates, cm. Unlike second differences it is not
  inflated by fast motion at 30 fps (the spline follows the motion).
* **spikes** -- samples off the fit by more than 4.685 x max(residual scale, 1 cm): the
  acceleration/residual test of QTM and Nexus, made robust. Rate = spikes / observed.

Gaps come from the observed mask (:func:`mocapkit.gaps.find_gaps`): count, length in
frames and seconds by bin, and how many touch the clip's ends.

>>> from mocapkit import datasets, io, corrupt
>>> clip = io.read(datasets.bundled("16_15.amc"))
>>> noisy, _ = corrupt.combine(clip, [("gaussian", {"sigma_cm": 1.0})], seed=0)
>>> d = diagnose(noisy)
>>> 0.7 < d.noise_cm < 1.3, d.spike_rate < 0.005
(True, True)
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .gaps import find_gaps
from .motion import Motion
from .solvers.gcv_spline import GCVInfo, gcv_smooth

__all__ = ["Diagnosis", "diagnose", "diagnosis_of", "robust_fit", "SPIKE_RATE"]

#: spike rate above which a clip is called spiky (and auto removes outliers). Under 1 cm
#: Gaussian noise alone the test flagged <= 0.3 % of samples on 4 CMU clips at 30/120 fps;
#: fast motion at 30 fps with 3 cm noise can pass 0.5 % (hdm05-hop in docs/results/auto.md).
SPIKE_RATE = 0.005

_BINS = ((1, 2), (3, 10), (11, 30), (31, 120), (121, None))      # gap lengths, frames


def cm_text(x: float) -> str:
    """A length in cm as the reports print it: two significant digits, never fewer than
    two decimals -- 1.30, 0.23, 0.019, 0.0056 (two fixed decimals printed a 0.0185 cm
    estimate as 0.01); under 0.0001 cm (a micrometre, far below any capture's resolution)
    ``< 0.0001`` (a noise-free clip's estimate of 4e-15 cm had printed as
    0.0000000000000037, and a 0.00015 cm noise level as 0.000).

    >>> [cm_text(v) for v in (1.3, 0.0186, 0.00015, 4e-15)]
    ['1.30', '0.019', '0.00015', '< 0.0001']
    """
    x = float(x)
    if not np.isfinite(x) or x <= 0:
        return f"{x:.2f}"
    if x < 1e-4:
        return "< 0.0001"
    return f"{x:.{max(2, 1 - int(np.floor(np.log10(x))))}f}"


def count_text(n: int, noun: str) -> str:
    """``n`` and the noun, plural but for one, as the reports print counts.

    >>> count_text(1, "gap"), count_text(12, "gap")
    ('1 gap', '12 gaps')
    """
    return f"{n} {noun}{'' if n == 1 else 's'}"


@dataclass(frozen=True)
class Diagnosis:
    """Measured properties of one clip (cm, seconds, Hz); see the module docstring."""
    fps: float
    n_frames: int
    n_points: int
    noise_cm: float
    spike_rate: float
    n_spikes: int
    missing: float                      # fraction of point samples unobserved
    n_gaps: int
    gap_bins: dict = field(default_factory=dict)      # "3-10 frames" -> count
    edge_gaps: int = 0
    longest_gap: int = 0                # frames
    never_observed: int = 0             # points

    @property
    def spiky(self) -> bool:
        return self.spike_rate > SPIKE_RATE

    def lines(self) -> list[str]:
        """Human-readable report, one fact per line."""
        dur = self.n_frames / self.fps
        out = [f"frames: {self.n_frames} at {self.fps:g} fps ({dur:.1f} s), {self.n_points} points",
               (f"noise: {cm_text(self.noise_cm)} cm RMS (GCV estimate on the samples kept)"
                if np.isfinite(self.noise_cm) else
                "noise: not measurable (too few frames or measured samples for the GCV estimate)"),
               f"spikes: {self.n_spikes} samples ({100 * self.spike_rate:.2f} % of observed)"
               + ("  -> outlier removal advised" if self.spiky else "")]
        if self.n_gaps:
            bins = ", ".join(f"{k}: {v}" for k, v in self.gap_bins.items() if v)
            out.append(f"gaps: {self.n_gaps} ({100 * self.missing:.1f} % of samples missing; {bins}); "
                       f"longest {count_text(self.longest_gap, 'frame')} ({self.longest_gap / self.fps:.2f} s); "
                       f"{self.edge_gaps} at the clip's ends")
        else:
            out.append("gaps: none")
        if self.never_observed:
            out.append(f"never observed: {self.never_observed} point(s) (left missing)")
        return out

    def as_dict(self) -> dict:
        d = dict(self.__dict__)
        d["spiky"] = self.spiky
        return d


def robust_fit(motion: Motion, validate: bool = True, plain_out: list | None = None
               ) -> tuple[np.ndarray, GCVInfo, np.ndarray]:
    """Robust GCV spline fit of the observed points. Returns (fit (T, 3J), info, usable
    (J,) bool -- points with at least one observed sample; the fit covers those only).
    ``validate``: the error at the fit's holes too (:func:`gcv_smooth`; later with
    :func:`mocapkit.solvers.gcv_spline.validated` where it is needed); ``plain_out``: gets
    the plain fit of the used columns (:func:`mocapkit.solvers.gcv_spline.plain_fit`)."""
    X, M = motion.matrix(copy=False), motion.matrix_mask()       # read only
    usable = motion.observed.any(axis=0)
    cols = np.repeat(usable, 3)
    f, info = gcv_smooth(used_columns(X, cols), used_columns(M, cols), robust=True, group=3,
                         validate=validate, plain_out=plain_out)
    if cols.all():
        return f, info, usable
    fit = np.full_like(X, np.nan)
    fit[:, cols] = f
    return fit, info, usable


def used_columns(A: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``A[:, cols]``, or A itself when every column is used (no copy of a long clip)."""
    return A if cols.all() else A[:, cols]


def diagnose(motion: Motion, fit: tuple | None = None) -> Diagnosis:
    """Diagnose ``motion``; ``fit`` reuses a :func:`robust_fit` result."""
    if not isinstance(motion, Motion):
        from .errors import MocapValueError
        raise MocapValueError(f"diagnose: expected a Motion, got {type(motion).__name__}")
    if motion.n_frames >= 8 and motion.observed.any():
        _, info, _ = fit if fit is not None else robust_fit(motion)
        noise = float(np.median(info.sigma))
        n_spk = int(info.rejected[:, ::3].sum())
    else:
        noise, n_spk = float("nan"), 0
    return diagnosis_of(motion, noise, n_spk)


def diagnosis_of(motion: Motion, noise_cm: float, n_spikes: int) -> Diagnosis:
    """The :class:`Diagnosis` of ``motion`` given its noise level (cm) and spike count
    (points' samples); the gap statistics are measured here."""
    T, J = motion.observed.shape
    obs = motion.observed
    usable = obs.any(axis=0)
    noise, n_spk = float(noise_cm), int(n_spikes)
    gaps = [g for g in find_gaps(obs) if g.kind != "never"]
    lengths = np.array([g.length for g in gaps], dtype=int)
    bins = {}
    for lo, hi in _BINS:
        sel = (lengths >= lo) & ((lengths <= hi) if hi else True)
        bins[f"{lo}-{hi} frames" if hi else f">{lo - 1} frames"] = int(sel.sum())
    return Diagnosis(
        fps=float(motion.fps), n_frames=T, n_points=J, noise_cm=noise,
        spike_rate=n_spk / max(int(obs.sum()), 1), n_spikes=n_spk,
        missing=float(1 - obs[:, usable].mean()) if usable.any() else 1.0,
        n_gaps=len(gaps), gap_bins=bins,
        edge_gaps=sum(g.kind in ("leading", "trailing") for g in gaps),
        longest_gap=int(lengths.max()) if len(lengths) else 0,
        never_observed=int((~usable).sum()))
