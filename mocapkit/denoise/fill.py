"""Practitioners' gap fills (../shared/specs/METHODS.md §6): rigid-body, pattern and
body-frame weighted-PCA fills, each a registered method usable alone.

All three only fill gaps: observed samples are returned unchanged (``keeps_observed``),
and they use the evidence of other markers seen in the same frames (``fill_evidence =
"markers"``, :mod:`mocapkit.gaps`). Each leaves missing what it has no support for (a
marker outside every rigid cluster, a gap with no donor seen, a frame without close
markers); the gap policy of the base class then reports it.

* ``fill-rigid`` -- :func:`mocapkit.rigid.rigid_fill`: Vicon Nexus "rigid body fill", QTM
  "relational / kinematic fill", MoCap Toolbox ``mcfixrigidbody``.
* ``fill-pattern`` -- :func:`pattern_fill`: Vicon Nexus "pattern fill".
* ``fill-pca`` -- :func:`mocapkit.solvers.pca_fill.pca_fill`: Gløersen & Federolf 2016
  (PLoS ONE 11(3):e0152616) weighted PCA, variant R2, in a body-centred frame.

The plain array functions (``rigid_fill``, ``pattern_fill``, ``pca_fill``: (T, J, 3) cm
positions + (T, J) masks in, ``(P_filled, filled_mask)`` out, NaN where they cannot fill)
are what ``fill-auto`` combines per gap.

Example (from the repository root, with ../shared/data)::

    from mocapkit import io, denoise
    from mocapkit.gaps import summary_line
    m = io.read("../shared/data/markers/kineticstoolkit/kinematics_basket_sprint.c3d")
    for name in ("fill-rigid", "fill-pattern", "fill-pca"):
        out = denoise.get(name).denoise(m)
        print(name, summary_line(out.source["gap_report"]))
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ..gaps import find_gaps
from ..motion import Motion
from ..rigid import REFERENCES, find_clusters, parse_clusters, rigid_fill
from ..solvers.pca_fill import pca_fill
from .base import Denoiser, register
from .constraints import Integral, Interval, Options, Real

__all__ = ["FillRigid", "FillPattern", "FillPCA", "pattern_fill", "rigid_fill", "pca_fill",
           "discover_clusters"]


def _result(motion: Motion, X: np.ndarray, filled: np.ndarray, counts: dict[str, int] | None = None) -> Motion:
    """The method's raw output; ``counts`` (samples per sub-fill, before the gap policy) go
    to ``source['fill_detail']`` when more than one sub-fill was used (the gap report
    counts what the policy kept, under the method's name)."""
    obs = motion.observed | filled
    src = dict(motion.source)
    counts = {k: int(v) for k, v in (counts or {}).items() if v}
    if len(counts) > 1:
        src["fill_detail"] = counts
    return Motion(X, motion.skeleton, motion.fps, obs, src, motion.filled)


# -- pattern fill --------------------------------------------------------------------------
def pattern_fill(P: np.ndarray, observed: np.ndarray, *, window: int = 120,
                 min_common: int = 3, max_edge: int | None = None,
                 max_drift_cm: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pattern fill (Vicon Nexus): a gap takes the shape of a donor marker's trajectory.

    For every gap ``[s, e)`` of marker m, the candidate donors are the markers observed
    over the whole gap and at its ends (frames ``s-1`` and ``e`` where they exist). The
    donor is the candidate whose position relative to m varies least around the gap: the
    summed per-coordinate variance of ``P_d - P_m`` over the frames within ``window``
    frames before and after the gap where both are seen (at least ``min_common`` of them).
    The fill is ``P_d(t) + offset(t)``, the offset interpolated linearly in time between
    ``P_m - P_d`` at ``s-1`` and at ``e``; an edge gap holds the offset of its one end. The
    fill therefore meets both ends of the gap exactly.

    Limits (both None: every gap with a donor is filled): ``max_edge`` frames -- an edge
    gap is filled only that far from its observed end, the rest left missing (nothing
    checks a held offset from the other side); ``max_drift_cm`` -- an interior gap is left
    missing when the offset changes between its two ends by more than this (3-D, cm), or
    for a gap longer than ``window``, by more than this per ``window`` frames of gap: the
    donor did not move with the marker across it, and the straight-line blend of the two
    offsets is then a guess, where a slow drift over a long gap is what the blend follows.
    Measured on real occlusions (real_gaps' 40 cases, fill-pattern
    under the gap policy, 2026-12-06): fills off by more than 20 cm were 14.6 % of the edge
    fills of gaps over 120 frames and 1.1 % of the interior fills of gaps up to 30 frames;
    interior gaps whose ends' offsets differ by 10-20 cm were 24 % gross before the
    policy, over 20 cm 62 %, under 2 cm none.

    P : (T, J, 3) cm; observed : (T, J). Returns (P_filled (T, J, 3), filled (T, J));
    observed samples unchanged, NaN where no donor is seen or a limit leaves it.

    >>> import numpy as np
    >>> t = np.linspace(0, 1, 50)[:, None]
    >>> P = np.stack([np.hstack([np.sin(6 * t), t, 0 * t]), np.hstack([np.sin(6 * t) + 5, t, 0 * t + 1])], 1)
    >>> obs = np.ones((50, 2), bool); obs[10:30, 1] = False
    >>> Q, f = pattern_fill(np.where(obs[..., None], P, np.nan), obs)
    >>> bool(np.allclose(Q, P)), int(f.sum())
    (True, 20)
    """
    P = np.asarray(P, dtype=float)
    obs = np.asarray(observed, bool) & np.isfinite(P).all(axis=-1)
    T, J, _ = P.shape
    out = np.where(obs[..., None], P, np.nan)
    filled = np.zeros((T, J), bool)
    W = max(int(window), 1)
    for g in find_gaps(obs):                                      # loop over gaps
        if g.kind == "never":
            continue
        m, s, e = g.joint, g.start, g.stop
        lo, hi = max(s - 1, 0), min(e + 1, T)                      # gap and its end frames
        cand = obs[lo:hi].all(axis=0)
        cand[m] = False
        if not cand.any():
            continue
        win = np.r_[np.arange(max(s - W, 0), s), np.arange(e, min(e + W, T))]
        both = obs[win][:, cand] & obs[win, m][:, None]             # (W, nc)
        rel = P[win][:, cand] - P[win, m][:, None, :]               # (W, nc, 3)
        n = both.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            mu = np.where(both[..., None], rel, 0.0).sum(0) / n[:, None]
            var = (np.where(both[..., None], rel - mu[None], 0.0) ** 2).sum((0, 2)) / n
        var = np.where(n >= int(min_common), var, np.inf)
        if not np.isfinite(var).any():
            continue
        d = int(np.flatnonzero(cand)[int(np.argmin(var))])
        fr = np.arange(s, e)
        o0 = P[s - 1, m] - P[s - 1, d] if s > 0 else None
        o1 = P[e, m] - P[e, d] if e < T else None
        if o0 is not None and o1 is not None:
            a = ((fr - (s - 1)) / float(e - s + 1))[:, None]
            off = (1 - a) * o0 + a * o1
            if max_drift_cm is not None and np.linalg.norm(o1 - o0) > max_drift_cm * max(1.0, len(fr) / W):
                continue
        else:
            off = np.broadcast_to(o0 if o0 is not None else o1, (len(fr), 3))
            if max_edge is not None and len(fr) > max_edge:
                keep = slice(len(fr) - max_edge, None) if o0 is None else slice(0, max_edge)
                fr, off = fr[keep], off[keep]
        out[fr, m] = P[fr, d] + off
        filled[fr, m] = True
    return out, filled


# -- cluster discovery shared by fill-rigid ---------------------------------------------------
def discover_clusters(motion: Motion, clusters: Any = None, *, max_std_cm: float = 1.0,
                      min_common_s: float = 0.5) -> list[list[int]]:
    """Rigid clusters of ``motion`` as marker-index lists: ``clusters`` (names, or a JSON
    file of name lists; :func:`mocapkit.rigid.parse_clusters`) when given, otherwise found
    from the data (:func:`mocapkit.rigid.find_clusters`; pairs must share
    ``min_common_s`` seconds of frames, at least 20 frames)."""
    if clusters is not None:
        return parse_clusters(clusters, list(motion.skeleton.names))
    min_common = max(20, int(round(float(min_common_s) * motion.fps)))
    return find_clusters(motion.positions, motion.observed, max_std_cm=float(max_std_cm),
                         min_common=min(min_common, motion.n_frames))


@register
class FillRigid(Denoiser):
    """Rigid-body gap fill: a marker's gap rebuilt from >= 3 markers of its rigid cluster by a
    least-squares rigid fit (Kabsch 1976 / Umeyama 1991 with reflection guard), batched over
    the frames of the gap. Vicon Nexus "rigid body fill", QTM "relational fill", MoCap
    Toolbox ``mcfixrigidbody``; :func:`mocapkit.rigid.rigid_fill`.

    Parameters
    ----------
    clusters : None (default: found from the data -- markers whose pairwise distances have
        a standard deviation below ``max_std_cm`` over >= ``min_common_s`` s of common
        frames, complete linkage), or a list of lists of marker names, or a path to a
        JSON file holding that list; overrides the discovery.
    max_std_cm : rigidity threshold of the discovery (cm).
    min_common_s : common observed time a pair needs to be judged (s).
    reference : ``"ends"`` (default, Vicon style: fits from the nearest frames before and
        after the gap where the marker and >= 3 donors are seen, blended over the gap) or
        ``"average"`` (robust average cluster shape over all frames). Measured
        (docs/results/fill.md): tennis serve 0.71 vs 0.86 cm, HDM05 0.47 vs 0.44 cm.
    min_donors : donors of the cluster that must be seen in a frame (>= 3).

    Units cm; shapes as :class:`~mocapkit.motion.Motion`. Markers in no usable cluster and
    frames with fewer than ``min_donors`` donors are left missing.

    Example (with ../shared/data; ``clusters`` may also name the markers explicitly)::

        from mocapkit import io, denoise
        m = io.read("../shared/data/markers/kineticstoolkit/kinematics_basket_sprint.c3d")
        fr = denoise.get("fill-rigid")
        out = fr.denoise(m)
        print(out.source["clusters"])            # the clusters found, as marker names
        print(out.source["gap_report"]["filled"], out.source["gap_report"]["left_missing"])
        head = denoise.get("fill-rigid", clusters=[["ArmL:Marker1", "ArmL:Marker2",
                                                     "ArmL:Marker3", "ArmL:Marker4"]])
    """

    name = "fill-rigid"
    description = ("rigid-body gap fill from >= 3 markers of the same rigid cluster (found from "
                   "the data); observed samples unchanged")
    needs_training = False
    keeps_observed = True
    fill_evidence = "markers"
    clean_tolerance_cm = 1e-9

    _parameter_constraints = {"clusters": [object], "max_std_cm": [Interval(Real, 0, None, closed="neither")],
                              "min_common_s": [Interval(Real, 0, None)], "reference": [Options(*REFERENCES)],
                              "min_donors": [Interval(Integral, 3, None)]}   # a rigid fit needs 3 points

    def __init__(self, clusters: Any = None, max_std_cm: float = 1.0, min_common_s: float = 0.5,
                 reference: str = "ends", min_donors: int = 3):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        if motion.observed.all():
            return motion
        cl = discover_clusters(motion, self.clusters, max_std_cm=self.max_std_cm,
                               min_common_s=self.min_common_s)
        # a diagnostic of this run (the result's source["clusters"]), not fitted state
        self.report(clusters=[[motion.skeleton.names[i] for i in c] for c in cl])
        X, f = rigid_fill(motion.positions, motion.observed, cl, reference=self.reference,
                          min_donors=int(self.min_donors))
        return _result(motion, X, f)


@register
class FillPattern(Denoiser):
    """Pattern fill (Vicon Nexus): each gap takes the trajectory shape of the donor marker
    that is observed over the gap and whose position relative to the missing marker
    varies least around it, offset so the fill meets the gap's ends (an edge gap holds its
    one end's offset). :func:`pattern_fill`.

    Parameters
    ----------
    window_s : seconds before and after the gap over which donors are compared.
    max_edge_s : an edge gap (at the take's start or end) is filled at most this far (s)
        from its observed end; the rest is left missing. None: all of it.
    max_drift_cm : an interior gap is left missing when the donor's offset to the marker
        differs by more than this (cm) between the gap's two ends -- for a gap longer than
        ``window_s``, by more than this per ``window_s`` of gap. None: no limit.

    Units cm. Gaps with no donor observed throughout are left missing.

    Why the limits (measured on real_gaps: 40 real occlusion masks laid over gap-free real
    captures, 2026-12-06; the same run without the limits in brackets): fill RMSE 2.54
    (6.16) cm, fills more than 20 cm off 0.88 (4.31) % of those written, 16,578 (19,577)
    hidden samples filled. A held offset grows off the path with every frame away from
    the gap's end (edge gaps over 120 frames: 14.6 % of fills gross without the limit),
    and a donor whose offset changes fast across the gap does not move with the marker
    (interior gaps up to 30 frames: 0.63 (3.02) cm). The drift limit flat, not per
    window: 2.49 cm, 0.89 %, but the tennis serve's 2 s gaps that it fills 1.8 cm off left
    missing (``tests/test_fill.py``). With the gap policy's rule for the edge gaps of a
    drifting fill (``fill_drifts``: left missing where no stretch of their own judged
    them, :func:`~mocapkit.denoise.fill_auto.unvalidated_fills`) on top: 1.48 cm, 0.008 %
    gross, 13,212 samples filled. fill-auto runs it without them: it
    validates each fill on the clip and chooses per gap (:mod:`mocapkit.denoise.fill_auto`).

    >>> import numpy as np
    >>> from mocapkit import denoise
    >>> from mocapkit.motion import Motion
    >>> from mocapkit.skeleton import Skeleton
    >>> t = np.linspace(0, 2, 100)[:, None]
    >>> a = np.hstack([np.sin(3 * t), t, 0 * t]) * 10                       # cm
    >>> P = np.stack([a, a + [0, 0, 10], a + [0, 30, 0], 0 * a + [50, 0, 0]], 1)
    >>> P[40:60, 1] = np.nan                                                 # a 20-frame gap
    >>> m = Motion(P, Skeleton(("a", "b", "c", "d"), [-1] * 4, np.zeros((4, 3))), 50.0)
    >>> out = denoise.get("fill-pattern").denoise(m)
    >>> bool(np.allclose(out.positions[40:60, 1], a[40:60] + [0, 0, 10])), int(out.filled.sum())
    (True, 20)
    """

    name = "fill-pattern"
    description = ("pattern fill: a gap copies the trajectory shape of the best donor marker, "
                   "offset to meet the gap's ends; observed samples unchanged")
    needs_training = False
    keeps_observed = True
    fill_evidence = "markers"
    #: the donor's shape drifts from the gap's own path the longer the gap (at an edge gap,
    #: from its one end): fill-auto judges it by gaps at least half as long
    fill_drifts = True
    clean_tolerance_cm = 1e-9

    _parameter_constraints = {"window_s": [Interval(Real, 0, None, closed="neither")],
                              "max_edge_s": [Interval(Real, 0, None), None],
                              "max_drift_cm": [Interval(Real, 0, None), None]}

    def __init__(self, window_s: float = 1.0, max_edge_s: float | None = 1.0,
                 max_drift_cm: float | None = 10.0):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        if motion.observed.all():
            return motion
        X, f = pattern_fill(motion.positions, motion.observed,
                            window=max(3, int(round(float(self.window_s) * motion.fps))),
                            max_edge=None if self.max_edge_s is None else int(round(float(self.max_edge_s) * motion.fps)),
                            max_drift_cm=self.max_drift_cm)
        return _result(motion, X, f)


@register
class FillPCA(Denoiser):
    """Weighted-PCA gap fill in a body-centred frame after Gløersen & Federolf 2016 (PLoS ONE
    11(3):e0152616; Federolf 2013 PLoS ONE 8(10):e78689 eq. 1), variant R2 (each missing
    marker reconstructed separately). :func:`mocapkit.solvers.pca_fill.pca_fill`.

    Translation and heading are taken out by a visibility-robust template fit, coordinates
    are normalised, markers weighted by ``exp(-d^2 / 2 sigma^2)`` (distance to the missing
    marker, sigma 20 cm = the paper's 200 mm, widened up to 40 cm for a marker whose 3
    nearest markers lie farther than 2 sigma), the PCA of the weighted complete frames keeps
    99 % of the cumulative singular values, and each gap frame's scores are fitted by least
    squares to the coordinates observed there. The fill meant for long and edge gaps of a
    moving subject. **Fallback:** frames of a gap for which no donor set of >= ``min_donors``
    close markers has ``min_frames`` complete frames take an iterative low-rank completion
    of the marker's weighted neighbourhood (repeated PCA of the filled body-frame matrix,
    EM style) instead; the gap report's ``filled_by`` then counts ``fill-pca`` and
    ``fill-pca:iterative`` separately. Frames with fewer than ``min_donors`` markers within
    2 sigma seen are left missing.

    Measured (docs/results/fill.md; 8 markers hidden for 0.25-2 s, interior and edge gaps,
    RMSE pooled): tennis serve 0.56 cm (linear interpolation 16.5 cm), HDM05 0.71 cm (99 %
    filled; linear 43.5 cm); translation-only frame 0.68 / 0.69 cm, no frame 0.71 / 1.34
    cm; the fallback forced everywhere 1.38 / 2.78 cm (it is a last resort; on the
    basket-sprint capture it is not needed). Fills whose distance to a close observed
    marker leaves the range seen in the data are dropped (``range_slack_cm`` of
    :func:`~mocapkit.solvers.pca_fill.pca_fill`).

    Parameters
    ----------
    sigma_cm : Gaussian weight scale (cm).
    min_cum_sv : cumulative singular-value share kept (paper: 0.99).
    mm_weight : weight of the missing marker in the PCA (paper: 0.02).
    frame : ``"heading"`` (default), ``"translation"`` (the paper's mean-trajectory
        removal) or ``"world"``.
    min_frames : fewest complete training frames for the R2 model.
    min_donors : close markers that must be seen.
    end_correction : add the model's residuals at the gap's observed ends, interpolated
        over the gap, so the fill meets the ends (measured better on the real captures).

    Units cm; shapes as :class:`~mocapkit.motion.Motion`.

    Example (with ../shared/data)::

        from mocapkit import io, denoise
        m = io.read("../shared/data/markers/kineticstoolkit/kinematics_basket_sprint.c3d")
        out = denoise.get("fill-pca").denoise(m)
        print(out.source["gap_report"]["filled_by"], out.source["gap_report"]["left_missing"])
    """

    name = "fill-pca"
    description = ("weighted-PCA gap fill in a body-centred frame (Gloersen & Federolf 2016, R2); "
                   "for long and edge gaps; observed samples unchanged")
    needs_training = False
    keeps_observed = True
    fill_evidence = "markers"
    clean_tolerance_cm = 1e-9

    _parameter_constraints = {"sigma_cm": [Interval(Real, 0, None, closed="neither")],
                              "min_cum_sv": [Interval(Real, 0, 1, closed="right")],
                              "mm_weight": [Interval(Real, 0, None)],
                              "frame": [Options("heading", "translation", "world")],
                              "min_frames": [Interval(Integral, 1, None)], "min_donors": [Interval(Integral, 1, None)],
                              "end_correction": [bool]}

    def __init__(self, sigma_cm: float = 20.0, min_cum_sv: float = 0.99, mm_weight: float = 0.02,
                 frame: str = "heading", min_frames: int = 30, min_donors: int = 3,
                 end_correction: bool = True):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        if motion.observed.all():
            return motion
        X, f, info = pca_fill(motion.positions, motion.observed, sigma_cm=float(self.sigma_cm),
                              min_cum_sv=float(self.min_cum_sv), mm_weight=float(self.mm_weight),
                              frame=self.frame, min_frames=int(self.min_frames),
                              min_donors=int(self.min_donors),
                              end_correction=bool(self.end_correction), return_info=True)
        return _result(motion, X, f, {self.name: info["pca"],
                                      f"{self.name}:iterative": info["pca-iterative"]})


@register
class FillKinematic(Denoiser):
    """Kinematic gap fill of a skeleton's joints on the bone lengths the file format fixes
    (ASF/AMC, BVH, or a C3D mocapkit wrote from them: :func:`mocapkit.rigid.fixed_bones`):
    a joint whose parent and a child are seen is put on the circle of its two bone
    lengths, at the swivel angle about the parent -> child axis interpolated over the gap
    (:func:`mocapkit.rigid.kinematic_fill`). QTM's "kinematic gap fill" and MotionBuilder's
    reach-based fills work the same way with a solved skeleton.

    No parameters. Marker files (no fixed bones), joints without a seen parent and child,
    and gaps at the clip's ends are left missing. A candidate of ``fill-auto``
    (:data:`mocapkit.denoise.fill_auto.DEFAULT_CANDIDATES`), which picks it per gap where
    it validates best: knees, elbows and ankles rather than trunk joints.

    >>> from mocapkit import corrupt, datasets, denoise, io
    >>> clean = io.read(datasets.bundled("16_15.amc")).slice(0, 240)
    >>> noisy, _ = corrupt.combine(clean, [("block_gaps", {"n_markers": 3, "length": 60})], seed=2)
    >>> out = denoise.get("fill-kinematic").denoise(noisy)
    >>> int((~noisy.observed).sum()) > int((~out.observed).sum())      # some gaps filled
    True
    """

    name = "fill-kinematic"
    description = ("kinematic gap fill of a skeleton's joints on their fixed bone lengths (swivel angle "
                   "interpolated); observed samples unchanged")
    needs_training = False
    keeps_observed = True
    fill_evidence = "markers"
    clean_tolerance_cm = 1e-9

    _parameter_constraints: dict = {}

    def __init__(self):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        from ..rigid import fixed_bones, kinematic_fill

        if motion.observed.all():
            return motion
        bones, lengths = fixed_bones(motion, motion.positions)
        X, f = kinematic_fill(motion.positions, motion.observed, motion.skeleton.parents, bones, lengths,
                              measured=motion.observed & ~motion.filled)
        return _result(motion, X, f)
