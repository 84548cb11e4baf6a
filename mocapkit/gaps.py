"""Gaps: finding them, the one gap filler (:func:`fill`), the one policy on which of them
may be filled, and the report.

Real captures have many short gaps, some very long ones, and gaps that touch the start
or end of the trial. Extrapolating a trajectory into such a gap is how a marker ends up
metres away, so every method runs under one policy (applied by
:class:`mocapkit.denoise.base.Denoiser` around each method's ``denoise``):

* A missing sample is filled only from **evidence**. A method declares the evidence it
  uses (``Denoiser.fill_evidence``):

  - ``"interp"`` (per-channel filters, splines, the constant-velocity Kalman smoother):
    the observed ends of the gap. Only interior gaps (observed on both sides) are
    supported, plus an edge gap no longer than ``edge_horizon_s``.
  - ``"markers"`` (low-rank, PCA, rigid-body, dictionaries, networks): other markers
    observed in the same frame. Supported where at least ``min_markers`` other markers
    are observed, or the gap is interior.

* No gap longer than ``max_gap_s`` is filled (Vicon Nexus / QTM "maximum gap"; ``None``:
  no limit), and a channel that is never observed is never filled (the one
  never-observed rule of the package: it stays missing).
* A fill more than ``volume_margin_cm`` outside the capture volume (the axis-aligned box
  of the observed samples) is not trusted: it is left missing and counted. So is a fill
  that leaves the body: farther from the centroid of the markers observed in its frame
  than that marker ever was when observed (x 1.25, + ``envelope_margin_cm``) — a
  straight line across a 10 s gap of a sprinting subject stays inside the capture
  volume but metres away from the runner. And a fill that breaks its rigid partners'
  distances (a marker of the same plate, a bone's other end, measured in that frame) by
  more than ``rigid_margin_cm``: it is at least that far off. And a fill the marker
  reaches or leaves only by a step faster than ``speed_factor`` times the capture's own
  speed (:func:`unreachable_fills`): a jump of metres between two frames, or between two
  fills that take turns.
* A fill of a gap longer than 2 frames that the method itself cannot reproduce on the
  file is not trusted either: observed stretches of the marker next to each gap, shaped
  like it (with the markers missing alongside it), are hidden and filled by the same
  method (two more runs), and a gap whose fills miss there by more than ``validate_cm``
  RMSE is left missing, as is a gap longer than 1 s that nothing on the file judged
  (:func:`mocapkit.denoise.fill_auto.unvalidated_fills`; ``auto`` and ``fill-auto`` choose
  and validate their fills themselves). Without it the methods that do not validate
  wrote a quarter of their real-occlusion fills more than 20 cm off; with it at most
  4.3 % (docs/results/real_gaps.md).
* Measured samples are a method's to clean, not to replace: where it moved a stretch of
  a marker by more than ``move_margin_cm`` (and ten times the noise) that its neighbours
  show no spike in, the measured samples are kept (:func:`moved_without_cause`) and
  counted in the report. A model -- learned from other clips (xiao-sparse, psc, lou-chai,
  kalman-learned, the networks) or fitted to the clip (the low-rank methods, dynammo) --
  that moved a marker's measured samples by more than ``misfit_factor`` times the input's
  noise, where the input shows no spike, gets them back too (:func:`model_misfit`): its
  result there is further from the truth than the measurement.
* What is filled is flagged (``Motion.filled``); what is left is reported in
  ``motion.source["gap_report"]`` (see :func:`summary_line`).

``use_policy(FILL_ALL)`` switches the restrictions off: the papers' synthetic protocols
measure every entry, as the papers do.

Example
-------
>>> import numpy as np
>>> from mocapkit.gaps import find_gaps
>>> obs = np.array([[1, 0], [0, 0], [1, 1], [1, 0]], bool)
>>> [(int(g.joint), int(g.start), int(g.stop), g.kind) for g in find_gaps(obs)]
[(0, 1, 2, 'interior'), (1, 0, 2, 'leading'), (1, 3, 4, 'trailing')]
"""
from __future__ import annotations

import contextlib
import contextvars
import warnings
from dataclasses import dataclass, replace
from typing import Iterator, NamedTuple

import numpy as np

from .errors import MeasuredKeptWarning, MocapValueError
from .windows import frame_blocks

__all__ = ["Gap", "GapPolicy", "DEFAULT_POLICY", "FILL_ALL", "find_gaps", "gap_lengths",
           "gap_table", "supported", "capture_volume", "outside_volume", "outside_envelope", "off_rigid_partners",
           "capture_speed", "unreachable_fills", "neighbour_deviation", "moved_without_cause", "model_misfit",
           "misfit_warning",
           "fill", "frame_centroid",
           "use_policy", "current_policy", "apply_policy", "summary_line"]


class Gap(NamedTuple):
    """One run of missing frames of one joint: frames ``start:stop`` (stop exclusive)."""

    joint: int
    start: int
    stop: int
    kind: str          # "interior", "leading", "trailing" or "never" (never observed)

    @property
    def length(self) -> int:
        return self.stop - self.start


@dataclass(frozen=True)
class GapPolicy:
    """Which missing samples a method may fill (see the module docstring).

    Parameters
    ----------
    max_gap_s : longest gap (seconds) that is filled; None = no limit.
    edge_horizon_s : longest leading/trailing gap an ``"interp"`` method may fill (s).
    min_markers : other markers that must be observed in a frame for ``"markers"``
        evidence to support a sample of that frame.
    volume_margin_cm : fills farther than this outside the observed capture volume are
        left missing; None = no check.
    envelope_margin_cm : margin of the body-envelope check (module docstring); None = no
        check.
    rigid_margin_cm : fills off the distance to their rigid partners measured in the same
        frame by more than this (:func:`off_rigid_partners`) are left missing; None = no
        check.
    speed_factor : a gap's fill with a step faster than this many times the capture's
        99.9th-percentile speed (:func:`unreachable_fills`) is left missing; None = no
        check.
    move_margin_cm : measured samples a method moved by more than this (and ten times the
        noise) where their neighbours show no spike are given back as measured
        (:func:`moved_without_cause`); None = no check.
    misfit_factor : a model-based method's measured samples of a marker it moved by more than
        this many times the input's noise (RMS, where the input shows no spike) are given
        back as measured (:func:`model_misfit`); None = no check.
    validate_cm : a fill of a gap longer than 2 frames that the method's own
        self-validation on the file puts over this RMSE (cm) is left missing
        (:func:`mocapkit.denoise.fill_auto.unvalidated_fills`: the method runs twice more);
        None = no check. Methods that validate their own fills (``auto``, ``fill-auto``:
        their ``max_fill_error_cm`` / ``max_error_cm``) are not run again.
    swaps : on a marker capture, label swaps (two markers that traded labels for a stretch,
        :mod:`mocapkit.swaps`) are put back before the method runs; False = as read.
    restrict : False fills everything (the papers' synthetic protocols), and puts no swap
        back.
    """

    max_gap_s: float | None = None
    edge_horizon_s: float = 0.05
    min_markers: int = 3
    volume_margin_cm: float | None = 100.0
    envelope_margin_cm: float | None = 30.0
    rigid_margin_cm: float | None = 10.0
    speed_factor: float | None = 3.0
    move_margin_cm: float | None = 5.0
    misfit_factor: float | None = 2.0
    validate_cm: float | None = 5.0
    swaps: bool = True
    restrict: bool = True

    def __post_init__(self) -> None:
        if self.move_margin_cm is not None and not (self.move_margin_cm > 0):
            raise MocapValueError(f"move_margin_cm must be a positive number of cm, got {self.move_margin_cm!r}")
        if self.misfit_factor is not None and not (self.misfit_factor > 0):
            raise MocapValueError(f"misfit_factor must be a positive number, got {self.misfit_factor!r}")
        if self.validate_cm is not None and not (self.validate_cm > 0):
            raise MocapValueError(f"validate_cm must be a positive number of cm, got {self.validate_cm!r}")
        if self.speed_factor is not None and not (self.speed_factor > 0):
            raise MocapValueError(f"speed_factor must be a positive number, got {self.speed_factor!r}")
        if self.max_gap_s is not None and not (self.max_gap_s > 0):
            raise MocapValueError(f"max_gap_s must be a positive number of seconds, got {self.max_gap_s!r}")
        if not self.edge_horizon_s >= 0:
            raise MocapValueError(f"edge_horizon_s must be >= 0, got {self.edge_horizon_s!r}")


DEFAULT_POLICY = GapPolicy()
FILL_ALL = GapPolicy(restrict=False, volume_margin_cm=None, envelope_margin_cm=None, rigid_margin_cm=None,
                     speed_factor=None, move_margin_cm=None, misfit_factor=None, validate_cm=None)

_POLICY: contextvars.ContextVar[GapPolicy] = contextvars.ContextVar("mocapkit_gap_policy",
                                                                    default=DEFAULT_POLICY)


def current_policy() -> GapPolicy:
    """The policy in force (:data:`DEFAULT_POLICY` unless :func:`use_policy` is active)."""
    return _POLICY.get()


@contextlib.contextmanager
def use_policy(policy: GapPolicy | None = None, **changes) -> Iterator[GapPolicy]:
    """Run a block under ``policy`` (or the current one with ``changes``)::

        with use_policy(max_gap_s=0.5):
            out = method.denoise(motion)
    """
    pol = replace(policy or current_policy(), **changes)
    token = _POLICY.set(pol)
    try:
        yield pol
    finally:
        _POLICY.reset(token)


# -- finding gaps ------------------------------------------------------------------------------
def _runs(missing: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(joint, start, stop) of every run of True in the columns of ``missing`` (T, J)."""
    T, J = missing.shape
    pad = np.zeros((1, J), dtype=bool)
    d = np.diff(np.vstack([pad, missing, pad]).astype(np.int8), axis=0).T   # (J, T+1)
    st_j, st_t = np.nonzero(d == 1)          # row-major: ordered by joint, then time
    en_t = np.nonzero(d == -1)[1]            # starts and ends alternate within a joint
    return st_j, st_t, en_t


def find_gaps(observed: np.ndarray) -> list[Gap]:
    """Every gap of an observed mask (T, J), ordered by joint then time."""
    obs = np.asarray(observed, dtype=bool)
    T = obs.shape[0]
    j, s, e = _runs(~obs)
    out = []
    for jj, ss, ee in zip(j.tolist(), s.tolist(), e.tolist()):
        kind = ("never" if ss == 0 and ee == T else "leading" if ss == 0
                else "trailing" if ee == T else "interior")
        out.append(Gap(jj, ss, ee, kind))
    return out


def gap_lengths(observed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per missing sample: the length (frames) of its gap and whether the gap is interior.

    Returns (length (T, J) int, 0 where observed; interior (T, J) bool).
    """
    obs = np.asarray(observed, dtype=bool)
    T, J = obs.shape
    # int32 (a clip has < 2**31 frames): these (T, J) arrays are a third of the clip's
    # (T, 3J) float matrix each in int64
    length = np.zeros((T, J), dtype=np.int32)
    interior = np.zeros((T, J), dtype=bool)
    j, s, e = _runs(~obs)
    if len(j):
        n = (e - s).astype(np.int32)
        # paint each run with its length via a cumulative-sum trick on the (T+1, J) grid
        paint = np.zeros((T + 1, J), dtype=np.int32)
        np.add.at(paint, (s, j), n)
        np.add.at(paint, (e, j), -n)
        length = np.cumsum(paint, axis=0, dtype=np.int32)[:T]
        paint[...] = 0
        inner = ((s > 0) & (e < T)).astype(np.int32)
        np.add.at(paint, (s, j), inner)
        np.add.at(paint, (e, j), -inner)
        interior = np.cumsum(paint, axis=0, dtype=np.int32)[:T] > 0
        del paint
    return length, interior & ~obs


def gap_table(motion) -> list[dict]:
    """Per marker: missing %, number of gaps, longest gap (frames and s), edge gaps.

    The rows ``mocapkit info FILE --gaps`` prints.
    """
    obs = motion.observed
    T = motion.n_frames
    gaps = find_gaps(obs)
    rows = []
    for j, name in enumerate(motion.skeleton.names):
        g = [x for x in gaps if x.joint == j]
        longest = max((x.length for x in g), default=0)
        rows.append({"marker": name, "missing_percent": round(100 * (1 - obs[:, j].mean()), 2),
                     "gaps": len(g), "longest_gap_frames": int(longest),
                     "longest_gap_s": round(longest / motion.fps, 3),
                     "leading_frames": int(next((x.length for x in g if x.kind in ("leading", "never")), 0)),
                     "trailing_frames": int(next((x.length for x in g if x.kind == "trailing"), 0)),
                     "filled_frames": int(motion.filled[:, j].sum()),
                     "never_observed": bool(not obs[:, j].any()) and T > 0})
    return rows


# -- the policy ------------------------------------------------------------------------------
def supported(observed: np.ndarray, fps: float, evidence: str,
              policy: GapPolicy | None = None) -> np.ndarray:
    """(T, J) bool: the missing samples a method with ``evidence`` may fill under ``policy``.

    ``evidence`` is ``"interp"`` or ``"markers"`` (module docstring). Observed samples are
    False. Under a non-restricting policy every missing sample of a channel observed at
    least once is supported; a never-observed channel never is.
    """
    pol = policy or current_policy()
    obs = np.asarray(observed, dtype=bool)
    if not pol.restrict:
        return ~obs & obs.any(axis=0)[None, :]
    if evidence not in ("interp", "markers"):
        raise MocapValueError(f"fill evidence must be 'interp' or 'markers', got {evidence!r}")
    length, interior = gap_lengths(obs)
    miss = ~obs
    ever = obs.any(axis=0)[None, :]
    horizon = int(np.floor(pol.edge_horizon_s * fps + 1e-9))
    ok = miss & ever & (interior | (length <= horizon))
    if evidence == "markers":
        n_obs = obs.sum(axis=1, keepdims=True)                      # markers seen per frame
        ok |= miss & ever & (n_obs >= pol.min_markers)
    if pol.max_gap_s is not None:
        ok &= length <= pol.max_gap_s * fps + 1e-9
    return ok


def capture_volume(positions: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box (lo (3,), hi (3,)) of the observed samples, cm."""
    P, obs = np.asarray(positions), np.asarray(observed, bool)
    if not obs.any():
        return np.full(3, -np.inf), np.full(3, np.inf)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for sl in frame_blocks(len(P)):                      # blocks of frames: no gathered copy
        Q = P[sl][obs[sl]]
        if len(Q):
            lo, hi = np.minimum(lo, Q.min(axis=0)), np.maximum(hi, Q.max(axis=0))
    return lo, hi


def outside_volume(positions: np.ndarray, lo: np.ndarray, hi: np.ndarray, margin_cm: float) -> np.ndarray:
    """(T, J) bool: samples farther than ``margin_cm`` (Euclidean distance to the box) outside
    the box, or not finite."""
    P = np.asarray(positions)
    out = np.empty(P.shape[:-1], bool)
    for sl in frame_blocks(len(P)):                      # blocks of frames: small temporaries
        Pb = P[sl]
        with np.errstate(invalid="ignore"):
            d = np.linalg.norm(np.maximum(np.maximum(lo - Pb, Pb - hi), 0.0), axis=-1)
        out[sl] = (d > margin_cm) | ~np.isfinite(Pb).all(axis=-1)
    return out


def outside_envelope(positions: np.ndarray, observed: np.ndarray, candidate: np.ndarray,
                     margin_cm: float, min_markers: int = 3, *, fills: np.ndarray | None = None) -> np.ndarray:
    """(T, J) bool: samples of ``positions`` marked in ``candidate`` that lie farther from the
    centroid of the markers observed in their frame than ``1.25 * r_j + margin_cm``, where
    ``r_j`` is the largest such distance of marker j over the frames it is observed (the
    largest over all markers for a marker observed in fewer than 10 frames). Frames with
    fewer than ``min_markers`` observed markers are not checked (no reference).
    ``fills`` (T, J, 3): the values of the unobserved samples (``positions`` then only
    gives the observed ones), merged block by block instead of in one more (T, J, 3) copy.
    """
    P = np.asarray(positions, dtype=float)
    obs = np.asarray(observed, dtype=bool)
    cand = np.asarray(candidate, dtype=bool)
    n = obs.sum(axis=1)
    frames = (n >= min_markers)[:, None]                                              # has a reference
    if not (cand & frames).any():
        return np.zeros_like(cand)
    d = np.empty(obs.shape)                                                            # (T, J)
    for sl in frame_blocks(len(P)):                                                 # blocks of frames
        Pb = P[sl] if fills is None else np.where(obs[sl, :, None], P[sl], fills[sl])
        c, _ = frame_centroid(Pb, obs[sl])
        with np.errstate(invalid="ignore"):
            d[sl] = np.linalg.norm(np.nan_to_num(Pb) - c[:, None, :], axis=2)
    ref = obs & frames
    r = np.where(ref, d, -np.inf).max(axis=0)
    enough = ref.sum(axis=0) >= 10
    r_all = r[enough].max() if enough.any() else (r.max() if np.isfinite(r.max()) else np.inf)
    r = np.where(enough, r, r_all)
    return cand & frames & (d > 1.25 * r[None, :] + margin_cm)


def off_rigid_partners(positions: np.ndarray, observed: np.ndarray, candidate: np.ndarray,
                       margin_cm: float, *, values: np.ndarray, has: np.ndarray,
                       n_partners: int = 4) -> np.ndarray:
    """(T, J) bool: fills marked in ``candidate`` that break the distance to a rigid partner
    by more than ``margin_cm``: off a partner *measured* in that frame (the fill is then at
    least ``margin_cm`` off, by the triangle inequality), or off more of the partners
    *filled* in that frame than on them (of two fills that disagree at least one is off;
    the one off most of its partners goes, on a tie both go).

    Rigid partners: :func:`mocapkit.rigid.steady_partners` of the input's measured samples
    (``positions``, ``observed``; up to ``n_partners`` per point whose distance spans at
    most 2 cm over every frame both are measured -- a marker of the same plate or cluster,
    a bone's other end); "off" is outside that span by more than ``margin_cm``, tested by
    :func:`mocapkit.rigid.distance_consistency` on ``values`` (T, J, 3) where ``has``
    (T, J): the method's result (cleaned measured samples and fills). A fill within
    ``margin_cm`` of its true place is never flagged by a measured partner. Found on
    kineticstoolkit's basket sprint (2026-12-05): markers of the wheelchair, arm and
    forearm plates (spans of 0.2-2 cm), each filled on its own while the whole plate was
    hidden, 20-270 cm off their plate's shape, inside the capture volume and the body's
    envelope. On the real-occlusion benchmark (docs/results/real_gaps.md, 40 cases) auto's
    gross fills (> 20 cm) went 3.27 -> 2.05 % at coverage 37.1 -> 36.1 %. Measured and not
    kept (same benchmark): every rigid partner (up to 16) with fills that contradict each
    other dropped greedily until none do -- coverage 35.4 %, gross 2.07 %; a robust scale
    (MAD, :func:`mocapkit.rigid.rigid_partners`) for rigidity, which dropped exact fills
    of CMU balance clips.
    """
    from .rigid import distance_consistency, steady_partners

    P = np.asarray(positions, dtype=float)
    obs = np.asarray(observed, dtype=bool) & np.isfinite(P).all(axis=-1)
    cand = np.asarray(candidate, dtype=bool)
    out = np.zeros_like(cand)
    if not cand.any() or P.shape[1] < 2:
        return out
    part, real, lo, hi = steady_partners(P, obs, n_partners=n_partners)
    if not real.any():
        return out
    # off the span by more than the margin: |d - mid| > margin + half span, i.e. the
    # consistency test's bisquare limit 4.685 scale with scale = (margin + half) / 4.685
    mid, half = (hi + lo) / 2, (hi - lo) / 2
    rows = np.flatnonzero(cand.any(axis=1))               # only the frames with a candidate
    slots = distance_consistency(np.asarray(values, dtype=float)[rows], np.asarray(has, bool)[rows],
                                 partners=(part, real, mid, (float(margin_cm) + half) / 4.685),
                                 floor_cm=0.0, per_partner=True, pinning=False)[3]   # (rows, J, K)
    meas = obs[rows][:, part]                                                 # partner measured
    off = slots < 0
    good = (slots > 0).sum(axis=2)
    out[rows] = cand[rows] & ((off & meas).any(axis=2) | ((off & ~meas).sum(axis=2) > good))
    return out


#: slack (cm) of :func:`unreachable_fills` on top of the speed allowance: a step this small
#: is never judged (noise, a fill's offset at its anchor)
SPEED_SLACK_CM = 2.0


def capture_speed(positions: np.ndarray, observed: np.ndarray, q: float = 99.9) -> float:
    """The ``q``-th percentile (cm per frame) of the displacement of the measured samples
    between consecutive frames, pooled over markers; NaN with fewer than 20 such steps."""
    P = np.asarray(positions, dtype=float)
    obs = np.asarray(observed, dtype=bool)
    steps = [np.linalg.norm(np.diff(P[:, j], axis=0), axis=1)[obs[1:, j] & obs[:-1, j]]
             for j in range(P.shape[1])]                    # per marker: (T, 3) temporaries only
    s = np.concatenate(steps) if steps else np.zeros(0)
    s = s[np.isfinite(s)]
    return float(np.percentile(s, q)) if s.size >= 20 else float("nan")


def unreachable_fills(positions: np.ndarray, observed: np.ndarray, candidate: np.ndarray,
                      factor: float, *, values: np.ndarray, slack_cm: float = SPEED_SLACK_CM) -> np.ndarray:
    """(T, J) bool: fills marked in ``candidate`` on a path the marker could not have taken
    at ``factor`` times the capture's speed ``v`` (:func:`capture_speed` of the measured
    samples, cm per frame).

    Per marker, the samples that are measured or in ``candidate`` are taken in time order
    (``values`` (T, J, 3): measured samples as the method returned them, the fills); a
    *run* is a stretch of consecutive fills, with the measured sample before and after it.
    A step between consecutive samples ``dt`` frames apart that is longer than
    ``factor v dt + slack_cm`` can not be motion; a run with such a step anywhere -- into
    it, inside it, out of it -- is dropped whole: of the two samples beside the step at
    least one is off by about half of it, and which one no test without the truth can
    say. So a fill that leaves its anchor with an offset, one that arrives 50 cm from
    where the marker reappears, and two fills that take turns frame by frame two metres
    apart all go; a fill that joins its ends at a plausible speed stays.

    Found on kineticstoolkit's basket sprint (2026-12-05, 120 fps, ``v`` = 4.2 cm): auto's
    fill of a forearm marker over a 270-frame gap switched between two candidates 200 cm
    apart (steps of 210-264 cm between frames), and a wheelchair marker's fill stepped
    99 cm -- inside the capture volume, the body's envelope and, the whole plate hidden,
    its rigid partners' majority. On CMU clips the truth's largest step is at most 2.5 x
    its 99.9th percentile (a thumb that steps in one frame), under the factor 3.
    """
    P = np.asarray(values, dtype=float)
    obs = np.asarray(observed, dtype=bool)
    cand = np.asarray(candidate, dtype=bool) & ~obs
    out = np.zeros_like(cand)
    if not cand.any():
        return out
    v = capture_speed(positions, obs)
    if not np.isfinite(v):
        return out                                   # too little measured motion to judge
    for j in np.flatnonzero(cand.any(axis=0)):
        c = cand[:, j].copy()
        while True:
            idx = np.flatnonzero(obs[:, j] | c)
            fill_ = ~obs[idx, j]
            step = np.linalg.norm(np.diff(P[idx, j], axis=0), axis=1)
            broken = ~(step <= factor * v * np.diff(idx) + slack_cm) & (fill_[1:] | fill_[:-1])
            if not broken.any():
                break
            # pieces between the breaks that hold no measured sample go first (a fill's
            # one-frame jump, a stretch from another candidate); then a break that is left
            # lies between pieces joined to measured samples: their whole run goes
            piece = np.r_[0, np.cumsum(broken)]
            loose = fill_ & ~(np.bincount(piece, weights=~fill_)[piece] > 0)
            if loose.any():
                c[idx[loose]] = False
                continue
            run = np.cumsum(fill_ & ~np.r_[False, fill_[:-1]])          # run number of each fill
            bad_runs = np.zeros(run[-1] + 1, bool)
            i = np.flatnonzero(broken)                                   # step i: entries i, i+1
            for e in (i, i + 1):
                bad_runs[run[e[fill_[e]]]] = True
            c[idx[fill_ & bad_runs[run]]] = False
            break
        out[:, j] = cand[:, j] & ~c
    return out


def sample_distance(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(T, J) 3-D distance between two (T, J, 3) position arrays, sample by sample --
    ``np.linalg.norm(A - B, axis=2)`` to the last bit, with one (T, J, 3) temporary
    instead of two (the gap policy's checks run on whole takes)."""
    D = np.subtract(A, B)
    np.multiply(D, D, out=D)
    return np.sqrt(D.sum(axis=2))


def neighbour_deviation(positions: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """(T, J) distance (cm) of each sample from the cubic through its two neighbours on
    each side, ``(-p[t-2] + 4 p[t-1] + 4 p[t+1] - p[t+2]) / 6`` -- large on a spike or a
    step, small on motion however fast; NaN where the sample or a neighbour is missing
    and on the first and last two frames."""
    P = np.asarray(positions, dtype=float)
    obs = np.asarray(observed, dtype=bool)
    T = P.shape[0]
    d = np.full(obs.shape, np.nan)
    if T >= 5:
        with np.errstate(invalid="ignore"):
            # (-p[t-2] + 4 p[t-1] + 4 p[t+1] - p[t+2]) / 6, in place (the same operations in
            # the same order as the expression, so the same bits)
            acc, tmp = np.negative(P[:-4]), np.multiply(P[1:-3], 4.0)
            acc += tmp
            np.multiply(P[3:-1], 4.0, out=tmp)
            acc += tmp
            del tmp
            acc -= P[4:]
            acc /= 6.0
            acc -= P[2:-2]
            np.multiply(acc, acc, out=acc)
            d[2:-2] = np.sqrt(acc.sum(axis=2))
        d[2:-2][~(obs[:-4] & obs[1:-3] & obs[2:-2] & obs[3:-1] & obs[4:])] = np.nan
    return d


#: a stretch a method moved is explained by a spike or a step of the input when the input
#: lies at least this share of the largest move off the cubic through its neighbours
#: somewhere in the stretch or within 2 frames of it, and twice as far as the method's
#: result does (:func:`moved_without_cause`)
SPIKE_SHARE = 1.0 / 5.0


def _window_max(A: np.ndarray, k: int = 2) -> np.ndarray:
    """(T, ...) the largest value of ``A`` within ``k`` frames of each frame (NaN wins)."""
    W = A.copy()
    for i in range(1, k + 1):
        W[i:] = np.maximum(W[i:], A[:-i])
        W[:-i] = np.maximum(W[:-i], A[i:])
    return W


def moved_without_cause(positions: np.ndarray, observed: np.ndarray, result: np.ndarray,
                        margin_cm: float, noise_cm: float = 0.0, *, edges_alone: bool = True) -> np.ndarray:
    """(T, J) bool: measured samples a method should have left where they were measured.

    ``positions`` (T, J, 3) the input, ``result`` the method's values. A sample is *moved*
    when ``|result - input|`` exceeds ``max(margin_cm, 10 noise_cm)``. Per marker, a
    stretch of consecutive moved samples is moved *with cause* when somewhere in it, or
    within 2 frames of it, the input lies at least :data:`SPIKE_SHARE` of the stretch's
    largest move off the cubic through its neighbours (:func:`neighbour_deviation`), and
    more than twice as far as the method's result does in that frame: the method smoothed
    away a spike, a bump of a few frames, the edge of a stretch of wrong samples (a
    swapped label: a step in and a step out), a sharp turn. A stretch moved where the
    input is as smooth as the result -- its neighbours agree with every measurement, or
    the method put a bump of its own there -- is returned whole, so that giving it back
    leaves no step larger than the margin at its ends.

    A stretch with no sample of its own that has four measured neighbours -- or where
    input and result are both rough: a whole-body jump between two takes, kept in both,
    whose sides' cubic is no reference -- (samples between gaps, the first frame, the last
    frame of a take) is moved without cause when the method took its ends farther, by
    more than the threshold, from the marker's measured samples before and after it than
    the measurements were: a spike's removal brings a sample towards its neighbours; or,
    for samples without four measured neighbours only, when in a frame of it the
    measurement keeps its distance to a rigid partner measured there and the result
    breaks it (:func:`_breaks_partners`; on the take's first and last two frames only
    with ``edges_alone``, which apply_policy sets unless the positions are forward
    kinematics of a skeleton's angles, :func:`mocapkit.rigid.fixed_bones`) -- not
    where input and result are both rough:
    a tracker that throws a limb throws its partners with it (MSR-Action3D's Kinect: a
    wrist and hand 30 cm off together, which auto had put back, were given back).

    Found on the shared marker files (2026-12-05; stretches given back, by ``mocapkit
    denoise`` with the method named): ``rpca`` had moved the serving arm of
    kineticstoolkit's tennis serve by up to 85 cm (1,320 samples of 23 markers; the
    input's noise 0.03 cm), ``svt`` (not converged) 6,976 samples of ezc3d's BTS by up to
    210 cm, ``kalman-cv`` (its defaults) held a forearm marker of the basket sprint 20-28
    cm behind its measurements for 20 frames after a long gap (818 samples of 3 markers,
    up to 110 cm). auto, mssa and wavelet move no sample of those files by more than
    5 cm. Measured and not kept: each sample judged on its own deviation (a two-frame
    glitch of a CMU foot, each sample a third of the step off its neighbours' cubic,
    that slra removed was given back); a third of the move and no comparison with the
    result (3-frame bumps that a spike in a BVH joint angle leaves on the joints below
    it, 12.7 cm high with the input 4.1 cm off its neighbours' cubic, that auto removed
    were given back: auto_files 6 of 237 cases moved, 4 of them worse by 2-5 %). Left: a
    sample measured alone between long gaps, with no rigid partner measured beside it,
    that a method moves towards one neighbour and away from the other is not judged.
    """
    P = np.asarray(positions, dtype=float)
    obs = np.asarray(observed, dtype=bool)
    Q = np.asarray(result, dtype=float)
    thr = max(float(margin_cm), 10.0 * float(noise_cm))
    with np.errstate(invalid="ignore"):
        d = sample_distance(Q, P)
    moved = obs & (d > thr)
    if not moved.any():
        return np.zeros_like(moved)
    g = neighbour_deviation(P, obs)
    gq = neighbour_deviation(Q, obs)
    # a moved sample says something when the cubic test works on the input, unless
    # input and result are both rough there (a whole-body jump between two takes, kept
    # in both: a sample's neighbours straddle it and their cubic is no reference)
    has_g = np.isfinite(g)
    with np.errstate(invalid="ignore"):
        judged = has_g & ~((g >= SPIKE_SHARE * d) & ~(gq < SPIKE_SHARE * d))
    g, gq = np.nan_to_num(g, nan=0.0), np.nan_to_num(gq, nan=0.0)
    T = len(g)
    # the input's deviation where it is more than twice the result's, frame by frame
    # (a whole-body jump kept in both is no cause), the largest within 2 frames
    gw = _window_max(np.where(g > 2.0 * gq, g, 0.0))
    # stretches of moved samples (marker, first frame, stop); per-stretch maxima over the
    # (J, T + 1) layout, a column's stretches never reaching into the next one
    js, t0, stop = _runs(moved)
    first = js * (T + 1) + t0
    lay = lambda A: np.vstack([A, np.zeros((1, A.shape[1]), A.dtype)]).T.ravel()   # noqa: E731
    gmax = np.maximum.reduceat(lay(np.where(moved, gw, 0.0)), first)
    dmax = np.maximum.reduceat(lay(np.where(moved, d, 0.0)), first)
    seen = np.maximum.reduceat(lay(moved & judged), first)
    bad = seen & (gmax < SPIKE_SHARE * dmax)
    if not seen.all():
        # a stretch without four measured neighbours anywhere (samples between gaps, the
        # first frame): moved without cause when the method took it farther from the
        # marker's measured samples before and after it than the measurement was -- a
        # spike's removal brings a sample towards its neighbours' path, never away
        t1 = stop - 1
        tt = np.arange(T)[:, None]
        last = np.maximum.accumulate(np.where(obs, tt, -1), axis=0)
        nxt = np.minimum.accumulate(np.where(obs, tt, T)[::-1], axis=0)[::-1]
        p = np.where(t0 > 0, last[np.maximum(t0 - 1, 0), js], -1)
        n = np.where(t1 < T - 1, nxt[np.minimum(t1 + 1, T - 1), js], T)

        def away(a, b):                                   # Q[a] farther than P[a] from P[b]
            bb = np.clip(b, 0, T - 1)
            grow = np.linalg.norm(Q[a, js] - P[bb, js], axis=1) - np.linalg.norm(P[a, js] - P[bb, js], axis=1)
            return (b < 0) | (b >= T) | (grow > thr)

        bad |= ~seen & ((p >= 0) | (n < T)) & away(t0, p) & away(t1, n)
        # only samples without four measured neighbours: where input and result are both
        # rough, a limb the tracker threw as a whole keeps its partners' distances (MSR
        # Kinect: a wrist and hand 30 cm off together, which auto had put back)
        alone = ~np.maximum.reduceat(lay(moved & has_g), first)
        # ... and, unless ``edges_alone``, next to a gap: in a BVH / AMC file a spike in a
        # joint angle throws the limb below it as a whole, and auto's removal of such
        # spikes on the take's first and last two frames was given back (auto_files, BVH
        # spikes: 07_03@120 0.30 -> 0.52 cm RMSE, worst auto / oracle 0.46 -> 0.80); on
        # a marker set or a Kinect take the edges stay judged so (real_gaps: without,
        # tsmc's worst fill 49 -> 70 cm, trnn's and tsmc's gross fills 1.27 / 1.00 -> 1.29
        # / 1.02 %)
        by_gap = np.ones(len(js), bool)
        if not edges_alone:
            cs = np.vstack([np.zeros((1, obs.shape[1]), int), np.cumsum(~obs, axis=0)])
            lo, hi = np.maximum(t0 - 2, 0), np.minimum(stop + 2, T)
            by_gap = (cs[hi, js] - cs[lo, js]) > 0
        rest = np.flatnonzero(~seen & ~bad & alone & by_gap)
        if len(rest):
            bad[rest] = _breaks_partners(P, obs, Q, js[rest], t0[rest], stop[rest], thr)
    # the bad stretches back to samples: +1 at a start, -1 at a stop, summed along time
    mark = np.zeros((T + 1, moved.shape[1]), np.int8)
    np.add.at(mark, (t0[bad], js[bad]), 1)
    np.add.at(mark, (stop[bad], js[bad]), -1)
    return np.cumsum(mark, axis=0)[:T] > 0


def _breaks_partners(P: np.ndarray, obs: np.ndarray, Q: np.ndarray, joints: np.ndarray,
                     t0: np.ndarray, stop: np.ndarray, margin_cm: float) -> np.ndarray:
    """(n,) bool, per stretch (marker ``joints[i]``, frames ``t0[i]:stop[i]``): somewhere in
    it the measurement keeps the distance to a rigid partner measured in that frame
    (:func:`mocapkit.rigid.steady_partners`, within ``margin_cm`` of its span) and the
    result ``Q`` breaks it by more than ``margin_cm`` -- a coherent glimpse of a plate
    that the method moved off its own partners. For :func:`moved_without_cause`: samples
    measured alone between long gaps (kineticstoolkit's basket sprint: a wheelchair plate
    seen for one frame, moved 2 m by trnn), which no neighbour in time can judge."""
    from .rigid import steady_partners

    part, real, lo, hi = steady_partners(P, obs)
    # every (stretch, frame) at once: the stretch of each, its marker and frame
    sid = np.repeat(np.arange(len(joints)), stop - t0)
    fr = t0[sid] + np.arange(len(sid)) - np.repeat(np.cumsum(stop - t0) - (stop - t0), stop - t0)
    j = joints[sid]
    ks = part[j]                                                    # (N, K)
    seen = real[j] & obs[fr[:, None], ks]
    d_in = np.linalg.norm(P[fr, j][:, None] - P[fr[:, None], ks], axis=2)
    d_out = np.linalg.norm(Q[fr, j][:, None] - P[fr[:, None], ks], axis=2)
    with np.errstate(invalid="ignore"):                             # NaN bounds: no partner
        keeps = (d_in >= lo[j] - margin_cm) & (d_in <= hi[j] + margin_cm)
        breaks = (d_out < lo[j] - margin_cm) | (d_out > hi[j] + margin_cm)
    hit = (seen & keeps & breaks).any(axis=1)
    return np.bincount(sid, weights=hit, minlength=len(joints)) > 0

#: :func:`model_misfit`: the input has a spike (or a step) at a sample when it lies more
#: than this many times the noise, and at least :data:`MISFIT_SPIKE_FLOOR_CM`, off the
#: cubic through its neighbours, and farther than the result does
MISFIT_SPIKE_FACTOR = 6.0
MISFIT_SPIKE_FLOOR_CM = 1.0
#: fewer samples without a spike than this: the marker is not judged
MISFIT_MIN_SAMPLES = 10
#: moves below this RMS (cm) are never a misfit: a noise-free input (noise estimate 0)
#: must not flag a method's rounding
MISFIT_FLOOR_CM = 1e-3
#: :func:`model_misfit`: a sample the model moved more than this many times the noise
#: (3-D move against the per-coordinate noise; Gaussian noise alone reaches 4 sqrt(3) with
#: probability 2e-10, the chi-square(3) tail at 48), where the input is smooth
#: (:data:`MISFIT_LOCAL_CAUSE`), is given back on its own (a *local* misfit)
MISFIT_LOCAL_FACTOR = 4.0 * np.sqrt(3.0)
#: ... where the input lies off its neighbours' cubic by less than 1 / this of the move
#: everywhere within 2 frames (2 let through a pair of spikes a frame apart on 2 cm noise)
MISFIT_LOCAL_CAUSE = 3.0
#: local misfits on more than this share of a marker's judged samples: the model does not
#: fit the marker, which is judged on all of them
MISFIT_LOCAL_SHARE = 0.005
#: a marker with local misfits is judged without them only where its other samples moved
#: at most this many times the noise (RMS): up to sqrt(2) the model may still be nearer
#: the truth than the measurement (:func:`model_misfit`)
MISFIT_LOCAL_REST = float(np.sqrt(2.0))
#: local misfits all smaller than this (cm) are given back and counted in the report
#: (``source["model_fit"]``) but not warned of: on a file measured to 30 um (ezc3d's
#: Vicon.c3d) trnn moved 2 samples by 0.2 mm, no line a user needs
MISFIT_LOCAL_WARN_CM = 0.1


def local_threshold(noise_cm: float) -> float:
    """The 3-D move (cm) beyond which a measured sample is a local misfit
    (:data:`MISFIT_LOCAL_FACTOR` x noise, the noise at least :data:`MISFIT_FLOOR_CM`)."""
    return float(MISFIT_LOCAL_FACTOR * max(float(noise_cm), MISFIT_FLOOR_CM))


def model_misfit(positions: np.ndarray, observed: np.ndarray, result: np.ndarray, noise_cm: float,
                 factor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Measured samples a model moved beyond the noise: ((T, J) bool, (J,) RMS cm, (T, J) bool local).

    ``positions`` (T, J, 3) the input, ``result`` the model's values, ``noise_cm`` the
    input's noise (per coordinate, e.g. :func:`mocapkit.signal.estimate_noise`). Per
    marker, the RMS move per coordinate is taken over its measured samples where the
    input shows no spike -- a spike being a sample more than :data:`MISFIT_SPIKE_FACTOR`
    x noise (and :data:`MISFIT_SPIKE_FLOOR_CM`) off the cubic through its neighbours
    (:func:`neighbour_deviation`) that the result brought closer; on the first and last
    two frames and beside a gap, where that test cannot run, a move more than 4 sqrt(3)
    times the marker's RMS move stands for one. A marker whose RMS move exceeds
    ``factor`` x noise (and :data:`MISFIT_FLOOR_CM`) is returned (all its measured samples
    but the spikes), as is its RMS move (NaN where fewer than :data:`MISFIT_MIN_SAMPLES`
    samples were judged).

    **Local misfits** (the third array, also in the first): a judged sample the model moved
    more than :data:`MISFIT_LOCAL_FACTOR` x noise (4 sqrt(3), and 4 sqrt(3) x
    :data:`MISFIT_FLOOR_CM`) and more than :data:`MISFIT_LOCAL_CAUSE` (3) times as far as
    the input lies off its neighbours' cubic anywhere within 2 frames -- the input is
    smooth there and the model went elsewhere -- is given back on its own. A
    marker with local misfits has its RMS taken without them and without the samples
    within 2 frames of a spike that it moved as far (beside a jump the model smoothed
    across, it moved those far too), if they are at most :data:`MISFIT_LOCAL_SHARE` of its
    judged samples and its other samples moved at most :data:`MISFIT_LOCAL_REST` x noise
    RMS; otherwise the model does not fit the marker at all, and it is judged on all of
    them like every other marker. A spike the model removed is not one: the input lies
    off its neighbours by about the move, and a spike throws its neighbours' cubic off too.
    Measured (2026-12-06, nineteenth session; ``benchmarks/model_misfit.py``, 1,875 runs):
    over the 1,812 runs whose model values had not changed since the last run, mean RMSE
    1.144 -> 1.140 cm, 223 runs better and 4 worse by more than 0.1 % (at most 2.1 %: tsmc
    on spikes, 0.094 -> 0.096 cm), none worse than the model's own values; the CMU 135
    trials joined back to back (``benchmarks/long_clip_segments.py``): trnn 1,656 samples
    given back instead of all 600,736 measured ones, 0.455 cm on the measured samples (the
    input's 0.865, the model's own 0.456). Measured and not kept: twice the input's
    deviation instead of 3 (a pair of spikes a frame apart on 2 cm noise left one near
    its neighbours' cubic and was given back: 21 runs worse than the model's values, by
    up to 2.2 %); 10 % for the share (on clips with spikes and no Gaussian noise, where the
    estimated noise exceeds the true one, markers a model had moved everywhere were no
    longer given back: trnn on a 30 fps martial-arts clip 1.143 -> 1.185 cm; 44 runs with
    spikes worse); the near-spike samples all left out of the RMS (not only those moved
    as far: clean clips 70 runs worse).

    Why ``factor`` x noise: with ``result = truth + e`` and ``input = truth + n``, the move
    is ``e - n`` and ``|e|^2 = |move|^2 - |n|^2 + 2 e.n``; a smoother leaves ``e`` and ``n``
    positively correlated, so a move of RMS ``f`` x noise means an error of at least
    ``sqrt(f^2 - 1)`` x noise -- beyond 1.41 x noise the measurement is the better of the
    two. 2 leaves room for the noise estimate's own error.

    Measured (2026-12-06, ``benchmarks/model_misfit.py``, docs/results/model_misfit.md;
    1,875 runs: the shipped and same-behaviour xiao-sparse, psc and lou-chai models and
    rpca, slra, tsvd, svt, trnn, tsmc, dynammo on the 14 held-out clips of
    ``benchmarks/shipped_models.py`` at 30 and 120 fps, and four models trained on one
    subject's tennis serve with the same seven run on another's; no noise / Gaussian 1
    and 3 cm / 10 % x 15 cm spikes / both; RMSE cm against the clean clip): 452 results
    were worse than their input; with the samples returned given back the mean RMSE falls
    from 1.27 to 1.12 cm and no result gets worse by more than 0.1 %, e.g. lou-chai
    trained on other subjects' clips of the behaviour on 1 cm noise 1.72 -> 1.00 cm, on
    clean clips 1.00 -> 0.16 cm; rpca on 1 cm noise 1.14 -> 0.98, tsmc 1.19 -> 0.82; tsvd
    on a clean tennis serve 1.46 -> 0.20 cm. Measured and not kept (on the first 860
    runs): the whole marker given back (spikes restored: xiao-sparse on spikes 0.44 ->
    2.74 cm); the spikes taken as every sample within 2 frames of a deviation (clean clips
    kept the model's values on fast motion: 0.52 -> 0.28 instead of 0.16); the median
    move instead of the RMS (per marker, over the old test's 2 x noise and 1 cm: lou-chai's
    same-behaviour results on 1 cm noise stayed worse than their input in 23 of 28 runs,
    17 with the RMS); 1 s windows of a marker judged too (on top of the whole take): 0.948 ->
    0.941 cm, for steps at the windows' edges (on a 51 s take of five CMU 131 trials,
    walks / jumps / a duck, with lou-chai trained on four other walks: 1.37 -> 1.32 cm); a
    spike required to stand out 3 or 5 times from the marker's running median deviation
    (15-31 frames), so that fast motion at 30 fps is not taken for one: 0.95 -> 1.03-1.14
    cm (10 % of spikes raise the median: spikes kept); or a move 2-3 times the median
    move of the 5 frames about it: 0.98-0.99 cm (clean clips 0.11 -> 0.07, spikes 0.60
    -> 0.81-0.85).
    Why the local misfits (found 2026-12-06, eighteenth session): with one RMS per marker
    over the whole take, a take whose input jumps -- the CMU 135 trials joined back to
    back in ``benchmarks/long_clip_segments.py``, steps of up to 2 m that no model follows
    -- had every marker judged a misfit and all of trnn's / tsmc's denoising given back
    (97 % of the squared move in 1 % of the samples, at the joins; 0.46 cm RMS move
    elsewhere against a 1.0 cm threshold): the measured samples came back about as
    measured (0.874 cm RMSE against the input's 0.865, away from the joins). Now the
    samples beside the joins go back one by one and the rest is judged without them.
    """
    P = np.asarray(positions, dtype=float)
    obs = np.asarray(observed, dtype=bool)
    Q = np.asarray(result, dtype=float)
    sigma = max(float(noise_cm), 0.0)
    with np.errstate(invalid="ignore"):
        mv = sample_distance(Q, P)
    ok = obs & np.isfinite(mv)
    g, gq = neighbour_deviation(P, obs), neighbour_deviation(Q, obs)
    has_g = np.isfinite(g)
    with np.errstate(invalid="ignore"):
        spike = has_g & (g > max(MISFIT_SPIKE_FACTOR * sigma, MISFIT_SPIKE_FLOOR_CM)) & ~(gq >= g)
    judged = ok & has_g & ~spike
    with np.errstate(invalid="ignore"):
        # the input smooth within 2 frames: a spike (or a pair of them) throws the cubic of
        # its neighbours off too
        far = mv > local_threshold(sigma)
        local = judged & far & (mv > MISFIT_LOCAL_CAUSE * _window_max(g))
    sq = np.square(np.where(judged, mv, 0.0))
    n, n_loc = judged.sum(axis=0), local.sum(axis=0)
    rms = np.sqrt(sq.sum(axis=0) / np.maximum(3 * n, 1))
    # a marker with local misfits is judged without them and without the samples within 2
    # frames of a spike that it moved as far (beside a jump the model smoothed across),
    # unless they are too many to be local or the rest moved more than a denoiser's moves:
    # then on all, as every other marker
    rest = judged & ~local & ~(far & _window_max(spike))
    n_rest = rest.sum(axis=0)
    rms_rest = np.sqrt(np.where(rest, sq, 0.0).sum(axis=0) / np.maximum(3 * n_rest, 1))
    with np.errstate(invalid="ignore"):
        own = ((n_loc > 0) & (n_loc <= MISFIT_LOCAL_SHARE * n)
               & (rms_rest <= MISFIT_LOCAL_REST * max(sigma, MISFIT_FLOOR_CM)))
    rms = np.where(own, rms_rest, rms)
    rms = np.where(np.where(own, n_rest, n) >= MISFIT_MIN_SAMPLES, rms, np.nan)
    with np.errstate(invalid="ignore"):
        spike |= ok & ~has_g & (mv > MISFIT_LOCAL_FACTOR * np.fmax(rms, sigma)[None, :])
        bad = rms > max(float(factor) * sigma, MISFIT_FLOOR_CM)
    return (ok & bad[None, :] & ~spike) | local, rms, local


def local_said(info: dict | None) -> bool:
    """Whether the misfit report ``info`` has local misfits worth a warning line
    (:data:`MISFIT_LOCAL_WARN_CM`)."""
    return bool(info and info.get("local_samples") and info.get("local_max_cm", 0.0) >= MISFIT_LOCAL_WARN_CM)


def misfit_warning(method: str, info: dict, given: int, *, stacklevel: int = 3) -> None:
    """The one warning line of a model's misfit (:func:`mocapkit.denoise.base.check_model_fit`'s
    ``info``): the markers, how far, why, and ``given`` -- the measured samples of those
    markers written as measured (0 when the policy gives nothing back)."""
    from .errors import ModelMisfitWarning, TrainingMismatchWarning

    names = info["markers"]
    k, nk = (info.get("local_samples", 0), info.get("local_markers", 0)) if local_said(info) else (0, 0)
    some = (f"{k} measured samples of {nk} {'other ' if names else ''}markers by "
            f"{info['local_threshold_cm']:.2g}-{info['local_max_cm']:.2g} cm where the input is smooth "
            f"(over {MISFIT_LOCAL_FACTOR:.1f} times its noise of about {info['noise_cm']:.2g} cm)") if k else ""
    if names:
        what = (f"{len(names)} of {info['n_markers']} markers ({', '.join(names[:4])}{' ...' if len(names) > 4 else ''}) "
                f"by up to {info['moved_rms_cm']:.2g} cm RMS ({info['worst_marker']}) where the input's noise is "
                f"about {info['noise_cm']:.2g} cm" + (f", and {some}" if k else ""))
    else:
        what = some
    tail = (f"{given} measured samples are written as measured (its values kept only where the input has "
            f"a spike)" if info["given_back"] else "they are written as the model put them")
    if info["kind"] == "fitted":
        why, advice, cat = (f"its model does not fit {'these markers' if names else 'the capture there'}",
                            "Use --method auto", ModelMisfitWarning)
    else:
        why, advice, cat = ("its training clips probably do not cover this motion",
                            "Train on clean clips like this one, or use --method auto", TrainingMismatchWarning)
    warnings.warn(f"{method}: the model moved {what}: {why}; {tail}. {advice}", cat, stacklevel=stacklevel)


def fill(X, mask=None, /, *, kind: str = "linear", ends: str = "nearest",
         never_observed: float = np.nan) -> np.ndarray:
    """Fill the unobserved samples of a (T, ...) array by interpolation in time (axis 0,
    every other axis a channel); observed samples are returned bit-identical. The one gap
    filler of the package (the gap *policy* -- which fills a method may return -- is
    :func:`apply_policy`).

    Parameters
    ----------
    X : array (T, ...); unobserved values may be NaN.
    mask : bool like X, True = observed (default ``np.isfinite(X)``); non-finite entries
        count as unobserved whatever the mask says.
    kind : ``"linear"`` (default) -- piecewise-linear, one ``np.interp`` per incomplete
        channel. ``"cubic"`` -- cubic spline through each channel's observed samples
        (``scipy.interpolate.CubicSpline``, not-a-knot ends, so a cubic polynomial is
        reproduced exactly), one spline per distinct mask column (the x, y, z of a marker
        together); channels with fewer than 4 observed samples fall back to linear.
    ends : before the first / after the last observed sample of a channel:
        ``"nearest"`` (default) holds the first/last observed value (never drifts);
        ``"linear"`` continues the interpolant's end slope (the spline's one-sided
        derivative, or the last segment's slope): follows a moving marker over a few
        frames but diverges over long end gaps; ``"nan"`` leaves them missing.
    never_observed : value of a channel with no observed sample. The never-observed rule
        of the package: nothing supports a value there, so by default it stays NaN (and
        the gap policy leaves it missing). A solver that needs a finite starting matrix
        asks for one explicitly with ``never_observed=0.0``; that value is never returned
        to the user.

    Returns
    -------
    float64 array like X.

    >>> fill(np.array([[0.], [np.nan], [2.], [np.nan]])).ravel()
    array([0., 1., 2., 2.])
    >>> fill(np.array([[0., np.nan], [np.nan, np.nan], [2., np.nan]]), ends="nan", never_observed=0.0)
    array([[0., 0.],
           [1., 0.],
           [2., 0.]])
    """
    if kind not in ("linear", "cubic"):
        raise MocapValueError(f"kind must be 'linear' or 'cubic', got {kind!r}")
    if ends not in ("nearest", "linear", "nan"):
        raise MocapValueError(f"ends must be 'nearest', 'linear' or 'nan', got {ends!r}")
    X = np.array(X, dtype=float, copy=True)
    if X.ndim == 0:
        raise MocapValueError("expected an array with a time axis, got a scalar")
    A = X.reshape(X.shape[0], -1)                       # a view: filled in place
    M = np.isfinite(A)
    if mask is not None:
        Mm = np.asarray(mask, dtype=bool)
        if Mm.shape != X.shape:
            raise MocapValueError(f"mask shape {Mm.shape} does not match data shape {X.shape}")
        M &= Mm.reshape(A.shape)
    if M.all():
        return X
    cols = np.flatnonzero(~M.all(axis=0))
    never = cols[~M[:, cols].any(axis=0)]
    A[:, never] = never_observed
    cols = cols[M[:, cols].any(axis=0)]
    t = np.arange(A.shape[0])
    cubic = cols[M[:, cols].sum(axis=0) >= 4] if kind == "cubic" else cols[:0]
    # one np.interp per incomplete channel (C small, T large). Not the grouped formula
    # (1 - w) a + w b: it gives the same values to 1e-14, but solvers started from it
    # (pca_fill.lowrank_complete) were measured to land elsewhere -- see the note there
    for c in np.setdiff1d(cols, cubic):
        m = M[:, c]
        A[:, c] = np.interp(t, t[m], A[m, c])
    slopes = _fill_cubic(A, M, cubic) if cubic.size else {}
    if ends != "nearest":
        _fill_ends(A, M, cols, ends, slopes)
    return X


def _fill_cubic(A: np.ndarray, M: np.ndarray, cols: np.ndarray) -> dict[int, tuple]:
    """Cubic-spline fill (in place) of channels ``cols`` of A (T, C), one spline per
    distinct mask column; ends held. Returns the end slopes {channel: (d0, d1)}."""
    from scipy.interpolate import CubicSpline

    T = A.shape[0]
    groups: dict[bytes, list[int]] = {}
    for c in cols:
        groups.setdefault(np.packbits(M[:, c]).tobytes(), []).append(int(c))
    slopes = {}
    for cs_cols in groups.values():
        m = M[:, cs_cols[0]]
        to = np.flatnonzero(m)
        tm = np.flatnonzero(~m)
        Yo = A[np.ix_(to, cs_cols)]
        cs = CubicSpline(to.astype(float), Yo, axis=0, bc_type="not-a-knot")
        inside = tm[(tm > to[0]) & (tm < to[-1])]
        if inside.size:
            A[np.ix_(inside, cs_cols)] = cs(inside.astype(float))
        A[np.ix_(np.arange(to[0]), cs_cols)] = Yo[0]
        A[np.ix_(np.arange(to[-1] + 1, T), cs_cols)] = Yo[-1]
        d0, d1 = cs(float(to[0]), 1), cs(float(to[-1]), 1)
        slopes.update({c: (d0[i], d1[i]) for i, c in enumerate(cs_cols)})
    return slopes


def _fill_ends(A: np.ndarray, M: np.ndarray, cols: np.ndarray, ends: str, slopes: dict) -> None:
    """Overwrite (in place) the leading / trailing gaps of channels ``cols`` (each observed
    at least once, ends currently held): NaN, or continued with the end slope (``slopes``
    for spline channels, else the first / last segment's; 0 for one observed sample)."""
    t = np.arange(A.shape[0], dtype=float)
    for c in cols:
        to = np.flatnonzero(M[:, c])
        lo, hi = to[0], to[-1]
        if ends == "nan":
            A[:lo, c] = np.nan
            A[hi + 1:, c] = np.nan
            continue
        if len(to) == 1:
            continue
        y = A[to, c]
        d0, d1 = slopes.get(int(c), ((y[1] - y[0]) / (to[1] - to[0]), (y[-1] - y[-2]) / (to[-1] - to[-2])))
        A[:lo, c] = y[0] + (t[:lo] - lo) * d0
        A[hi + 1:, c] = y[-1] + (t[hi + 1:] - hi) * d1


def frame_centroid(positions: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, the centroid (T, 3) of the observed markers (NaN where none is) and how
    many markers it averages (T,)."""
    obs = np.asarray(observed, dtype=bool)
    n = obs.sum(axis=1)
    s = np.where(obs[..., None], np.nan_to_num(np.asarray(positions, dtype=float)), 0.0).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return s / n[:, None], n


def apply_policy(inp, out, *, evidence: str, method: str, policy: GapPolicy | None = None,
                 unvalidated: np.ndarray | None = None, misfit: np.ndarray | None = None,
                 fit: dict | None = None):
    # ``out.source['fill_codes']`` = {"names": [...], "codes": (T, J) int, -1 = none} lets a
    # method that combines fills (fill-auto) report which one produced each kept sample.
    """The motion a method may return for ``inp``: unsupported or implausible fills of ``out``
    left missing, fills flagged, a ``gap_report`` in its source.

    ``out`` is the method's raw result (same T and J). Samples observed in ``inp`` are
    taken from ``out`` as they are (denoised); samples missing in ``inp`` are kept only
    where :func:`supported` allows, they are finite and (policy permitting) inside the
    capture volume. Where ``out`` itself left a sample missing it stays missing.
    ``unvalidated`` (T, J): fills the method's self-validation put over
    ``policy.validate_cm`` (computed by the caller, which can run the method again).
    ``misfit`` (T, J): measured samples a model-based method moved beyond the noise
    (:func:`model_misfit`, computed by the caller, which knows the method is one); they
    are written as measured and counted in ``kept_measured_misfit``. ``fit``: the misfit
    report of :func:`mocapkit.denoise.base.check_model_fit`, warned of here in one line
    (:func:`misfit_warning`) with the samples of its markers given back -- the moves over
    ``move_margin_cm`` among them, whose own warning it then replaces; None: no warning.
    """
    pol = policy or current_policy()
    obs_in = inp.observed
    P = out.positions                       # read-only; copied below only if samples change
    has = out.observed.copy()
    # first the measured samples: the fills are judged against what will be written
    back = np.zeros_like(obs_in)
    if pol.move_margin_cm is not None and obs_in.any():
        with np.errstate(invalid="ignore"):       # cheap first: is anything moved that far?
            far = obs_in & (sample_distance(P, inp.positions) > pol.move_margin_cm)
        if far.any():
            from .signal import estimate_noise

            sigma = estimate_noise(inp.matrix(copy=False), inp.matrix_mask(), pool="all", fallback=0.0)
            from .rigid import fixed_bones

            # positions that are forward kinematics of angles (BVH, ASF/AMC): the take's
            # edges are no samples alone (moved_without_cause)
            back = moved_without_cause(inp.positions, obs_in, P, pol.move_margin_cm, sigma,
                                       edges_alone=not len(fixed_bones(inp)[0]))
    moved = np.linalg.norm(P[back] - inp.positions[back], axis=1) if back.any() else None
    misfit = (obs_in & misfit) if misfit is not None else np.zeros_like(obs_in)
    named = misfit.any(axis=0)              # the markers the misfit warning names and counts
    warned = bool(fit and (fit["mismatch"] or local_said(fit)))
    said = warned and not (back.any(axis=0) & ~named).any()
    misfit &= ~back
    given = back | misfit
    if given.any():
        P = P.copy()
        P[given] = inp.positions[given]
    miss = ~obs_in
    want = miss & has
    # gap lengths are (T, J) int arrays: only built when something is missing
    ok = supported(obs_in, inp.fps, evidence, pol) if miss.any() else np.ones_like(miss)
    unsupported = want & ~ok
    implausible = np.zeros_like(want)
    why: dict[str, int] = {}                # fills dropped, by the check that dropped them

    def reject(reason: str, flags: np.ndarray) -> None:
        nonlocal implausible
        why[reason] = int((flags & ~implausible).sum())
        implausible = implausible | flags

    if unvalidated is not None and pol.validate_cm is not None and want.any():
        reject(f"not validated under {pol.validate_cm:g} cm", want & ok & unvalidated)
    if pol.volume_margin_cm is not None and want.any():
        lo, hi = capture_volume(inp.positions, obs_in)
        reject("outside the capture volume", want & ok & outside_volume(P, lo, hi, pol.volume_margin_cm))
    if pol.envelope_margin_cm is not None and want.any():
        reject("away from the body", outside_envelope(inp.positions, obs_in, want & ok & ~implausible,
                                                      pol.envelope_margin_cm, pol.min_markers, fills=P))
    if pol.rigid_margin_cm is not None and want.any():
        reject("off a rigid partner's distance",
             off_rigid_partners(inp.positions, obs_in, want & ok & ~implausible, pol.rigid_margin_cm,
                                values=P, has=has))
    if pol.speed_factor is not None and want.any():
        # last: the chain is judged on the fills the other checks kept
        reject("out of the marker's reach", unreachable_fills(inp.positions, obs_in, want & ok & ~implausible,
                                                              pol.speed_factor, values=P))
    keep = has & ~(unsupported | implausible)
    filled_now = keep & miss
    filled = (inp.filled & obs_in & keep) | filled_now
    if not out.observed[obs_in].all():      # a method must never drop a measured sample
        raise RuntimeError(f"{method}: returned missing values for observed samples")
    prev = inp.source.get("gap_report") or {}
    by = dict(prev.get("filled_by", {}))
    codes = out.source.get("fill_codes")
    if codes is not None:       # which sub-fill produced each sample (fill-auto): count what was kept
        c = np.asarray(codes["codes"])
        for k, name in enumerate(codes["names"]):
            by[name] = by.get(name, 0) + int((filled_now & (c == k)).sum())
    else:
        by[method] = by.get(method, 0) + int(filled_now.sum())
    by = {k: v for k, v in by.items() if v}
    left = miss & ~keep
    length = gap_lengths(obs_in)[0] if (filled_now.any() or left.any()) else None
    report = {
        "method": method,
        "filled": int(filled_now.sum()) + int(prev.get("filled", 0)),
        "filled_by": by,
        "left_missing": int(left.sum()),
        "left_unsupported": int((unsupported | (miss & ~has & ~ok)).sum()),
        "left_implausible": int(implausible.sum()),
        "left_implausible_by": {k: v for k, v in why.items() if v},
        "left_by_method": int((miss & ~has & ok).sum()),
        "longest_filled_s": float(length[filled_now].max() / inp.fps) if filled_now.any() else 0.0,
        "longest_left_s": float(length[left].max() / inp.fps) if left.any() else 0.0,
        "never_observed": [inp.skeleton.names[j] for j in np.flatnonzero(~obs_in.any(axis=0))],
        "max_gap_s": pol.max_gap_s,
        "restricted": pol.restrict,
        "kept_measured": int(back.sum()),
        "kept_measured_misfit": int(misfit.sum()),
    }
    if moved is not None:                   # (report first; the warning unless the misfit's said it)
        t, j = np.argwhere(back)[int(moved.argmax())]
        report["kept_measured_max_cm"] = float(moved.max())
        report["kept_measured_worst"] = f"{inp.skeleton.names[j]} frame {t}"
    if warned:
        misfit_warning(method, fit, int(given[:, named].sum()), stacklevel=4)
    if moved is not None and not said:
        warnings.warn(f"{method} moved {int(back.sum())} measured samples of "
                      f"{int(back.any(axis=0).sum())} markers by more than {pol.move_margin_cm:g} cm where the "
                      f"capture shows no spike (up to {moved.max():.0f} cm, {report['kept_measured_worst']}): "
                      f"they are written as measured (the method does not fit this capture there)",
                      MeasuredKeptWarning, stacklevel=3)
    src = dict(out.source)
    src.pop("fill_codes", None)
    src["gap_report"] = report
    drop = ~keep & has
    if drop.any() or given.any():
        P = P.copy() if not given.any() else P      # (already a copy when samples came back)
        P[drop] = np.nan
        P.setflags(write=False)             # handed over: the Motion shares it
    return type(out)(P, out.skeleton, out.fps, keep, src, filled)     # a Motion (no import: motion uses fill)


def summary_line(report: dict | None) -> str:
    """One line for the CLI: what was filled, by which fill, what was left and why."""
    if not report:
        return "no gaps"
    by = ", ".join(f"{k} {v}" for k, v in sorted(report.get("filled_by", {}).items(), key=lambda kv: -kv[1]))
    s = f"filled {report['filled']} missing samples"
    if by and (len(report.get("filled_by", {})) > 1 or next(iter(report["filled_by"])) != report["method"]):
        s += f" ({by})"
    if report["filled"]:
        s += f", longest gap filled {report['longest_filled_s']:.2f} s"
    if report["left_missing"]:
        why = []
        if report["left_unsupported"]:
            why.append(f"{report['left_unsupported']} without evidence"
                       + (f" or beyond --max-gap {report['max_gap_s']:g} s" if report.get("max_gap_s") else ""))
        if report["left_implausible"]:
            by = report.get("left_implausible_by") or {}
            why.append(f"{report['left_implausible']} implausible: "
                       + (", ".join(f"{v} {k}" for k, v in sorted(by.items(), key=lambda kv: -kv[1])) if by else
                          "outside the capture volume, away from the body, off a rigid partner's distance "
                          "or out of the marker's reach"))
        if report["left_by_method"]:
            why.append(f"{report['left_by_method']} the fill could not support")
        s += (f"; left {report['left_missing']} missing ({'; '.join(why)}), "
              f"longest {report['longest_left_s']:.2f} s")
        if report.get("never_observed"):
            nv = report["never_observed"]
            s += f"; never observed: {', '.join(nv[:5])}{' ...' if len(nv) > 5 else ''}"
    return s
