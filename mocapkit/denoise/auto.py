"""``auto``: clean a clip without tuning, and say how well it went.

The chain, decided from the clip's own diagnosis (:mod:`mocapkit.diagnose`):

1. **Spikes** -- a robust GCV smoothing spline (bisquare on each point's 3-D residual,
   Garcia 2010) flags samples off the fit by more than 4.685 x max(scale, 1 cm). If more
   than :data:`~mocapkit.diagnose.SPIKE_RATE` of the samples are flagged the clip is
   spiky and the flagged samples are treated as missing; otherwise nothing is rejected
   (the test's false alarms on clean fast motion would cost more than they save). On a
   spiky clip without noise a second look (:func:`_second_look`) asks each joint's rigid
   partners (:func:`mocapkit.rigid.distance_consistency`): a kept sample whose distances
   to all of them are off is rejected (with exact bones -- a skeleton's joints -- also a
   one-bone joint off a partner its own bones vouch for), a rejected sample two exact
   bones vouch for is measured (or one, where the other ends in a spike: spikes@30 mean
   RMSE 0.195 -> 0.102 cm), and rejected samples are kept again when the interpolating
   spline through the kept ones -- of the position, or of the position
   relative to a trusted partner -- predicts them within 4.685 cm (on the protocol's
   spike cases RMSE e.g. run@30 1.015 -> 0.252, martial-arts@30 0.443 -> 0.232; on five
   development clips not in the protocol mean 0.247 -> 0.178 cm, none worse), and
   (``edge_test=True``, off by default) rejects spikes on the first and last frame, which
   the in-sample test cannot see -- on long clips it removed most spikes the robust fit
   kept (development clips at 30 fps: 0.259 -> 0.067, 0.183 -> 0.113 cm), but on clips
   of 20-35 frames of fast motion at 30 fps a measured end sample's extrapolation misses
   by more than the limit, and rejecting it cost up to 1.5 cm RMSE (protocol run of
   docs/results/auto.md: run@30 1.015 -> 2.542), so it is not the default. The chain
   says ``spike removal`` where samples stayed rejected, and ``spike test (no spike
   confirmed)`` where the second look kept every flagged one.
2. **Noise** -- three smoothers on the samples kept, mixed by the convex weights of lowest
   Monte-Carlo SURE (Ramani et al. 2008, :func:`mocapkit.solvers.mssa.sure_weights`; its
   probe correlated across channels as the noise is, Eldar 2009,
   :func:`mocapkit.solvers.mssa.correlated_probe`, since noise read back from a rotation
   file is shared between joints; the noise level from the kept samples' fourth differences,
   :func:`mocapkit.signal.estimate_noise`): a GCV smoothing spline
   (Woltring 1986, smoothing chosen per coordinate), multichannel SSA with optimal
   singular-value shrinkage (Gavish & Donoho 2017; it uses the body's coordination), and a
   constant-velocity Kalman/RTS smoother (Rauch, Tung & Striebel 1965; process noise by
   robust maximum likelihood, then held: :func:`_kalman_cv`). *Do no harm*: when the
   estimated noise is below ``min_noise_cm`` and there are no spikes the measured samples
   are returned as they are (at that level smoothing cannot be told from removing motion
   detail: on noise-free CMU clips the GCV spline adds 0.002-0.08 cm).
3. **Gaps** -- short holes (spikes, gaps up to ``long_gap_s``) are filled by the spline
   (on the noise-free path, per point, by the position relative to its rigid partners
   where that validates better: ``_partner_fill``; then, where that validates better
   again, refined by iterative low-rank imputation of the whole body, ``_lowrank_fill``:
   mean RMSE on 30 % random missing samples -9..-20 % on three sets of CMU clips; below
   60 fps once more with a 4-frame window, validated the same way: -1..-6 % more; and in
   ASF/AMC and BVH files, where that validates better again, moved onto the bone lengths
   the format fixes, ``_bone_fill``: -4..-10 % more);
   longer gaps by ``fill-auto`` (per-gap self-validated choice of linear / spline /
   pattern / rigid-body / PCA fill) run on the cleaned samples -- in a marker capture kept
   as measured, every gap longer than ``MARKER_SHORT_FRAMES`` (2) frames: there auto is
   the default too (since 2026-12-05; fill-auto was), and its fills of real occlusions
   are fill-auto's but for 1-2 frame gaps (docs/results/real_gaps.md). A long gap whose
   best fill validates above ``max_fill_error_cm`` (5 cm, fill-auto's own default) is left
   missing and reported, as are frames no fill has evidence for: no spline values are
   written in its place. Until 2026-12-05 every long gap was filled whatever its validated
   error (``max_fill_error_cm=None``, still available): on the protocol's ten 60-frame
   gaps of CMU clips that gave the lowest RMSE, but on real marker files it wrote fills
   the validation put far off -- kineticstoolkit's basket sprint: 27,864 samples validated
   over 5 cm and 13,965 over 20 cm (estimate 33.9 cm RMSE), ezc3d's BTS.c3d 3,594 / 2,604
   -- and the spline values it kept where fill-auto refused were charged nothing.
4. **Bones** -- after smoothing, the bones the file format fixes (ASF/AMC, BVH:
   :func:`mocapkit.rigid.fixed_bones`) get their length back (:func:`_hold_bones`); the
   estimate drops by the mean squared move. Smoothing shortens a rotating bone; the
   writers' IK would restore the length on output anyway.
5. **Rigid groups** -- after the bones, groups of at least five joints or markers that the
   input shows moving as one rigid body (:func:`mocapkit.rigid.steady_clusters`: a Daz
   skeleton's hand and chest, a marker plate) are held rigid (:func:`_hold_clusters`);
   their points' estimate drops by the mean squared move.

**Long clips** (over 1.5 x :data:`PIECE_FRAMES` = 12,288 frames) are cleaned in pieces of
~8,192 frames, each with 2 s of its neighbours' frames each side, cross-faded over the
overlaps; cuts move to where no sample is missing near them (:func:`_piece_cuts`). Peak
memory then stays that of one piece (docs/results/scaling.md: 13.6x -> 2.8x the input at
100,000 frames) and every statistic is the piece's own; on a 20,808-frame clip the result
is the whole-clip one within noise (docs/results/auto_pieces.md). The report lists the
pieces (``source['auto']['pieces']``: frames, chain, estimate) and merges them.

**Whole-body jumps** (two takes in one file, an edit point, a loop seam:
:func:`whole_body_jumps`; ``mocapkit info --diagnose`` lists them) cut the clip hard, and
each side is cleaned on its own (``source['auto']['jumps']``); smoothing, fills and the
noise estimate across a jump would mix two motions.

The error estimate (cm RMS over all coordinates, ``source['auto']['estimated_rmse_cm']``)
is the RMS over every written sample of an estimate per sample -- over what the gap
policy keeps (:meth:`Auto._after_policy`) -- by class:

* *kept and smoothed*: the variance term of the chosen smoother's risk, sigma sqrt(df / N)
  with df its SURE divergence (:func:`_smooth`);
* *kept as measured* (no smoothing): the noise, as the smallest of the per-channel GCV
  sigma, the package's robust noise level of the kept samples of the whole matrix
  (:func:`mocapkit.signal.estimate_noise`, fourth differences, pooled) and the spread of
  the distances between rigid partners (:func:`mocapkit.rigid.distance_noise`) -- upper
  bounds of white positional noise, the GCV sigma also holding the spline's misfit on fast
  channels and the fourth differences the motion at 30 fps (0.02-0.13 cm on noise-free
  clips), which the distances do not see (0 on joint data; charging the fourth
  differences instead put walk@30 / dance@30 / balance@30 spikes at 1.71 / 1.51 / 1.92 x
  their true error, with the distances 1.48 / 1.25 / 1.06 x); on a spiky clip, plus the spikes
  the robust fit kept on the end frames (:func:`_end_spikes_kept`: end samples off their
  one-sided prediction by more than the robust limit and not vouched for by their rigid
  partners' distances, charged that residual times the
  posterior that such a sample is a spike, from the clip's spike rate and how often
  measured samples one frame in fail the same test);
* *short holes* (missing or rejected samples the spline fills): local self-validation
  hole by hole (``GCVInfo.hole_map``, :func:`mocapkit.solvers.gcv_spline._with_hole_error`):
  the trusted stretch of the hole's length next to it, with a trusted frame each side,
  is hidden and predicted, and the error (less the noise variance) is shrunk towards all
  holes of that length. A hidden stretch is shaped like the real hole and sits in the same
  motion -- the shifted copy of the whole hole pattern used before made holes longer than
  the real ones on 30 % random missing samples (1.2-2.7 x too high) and missed that a
  robust fit's rejections sit where the motion is fast; a point whose holes took the
  partner-relative fill is charged that fill's own validation, and one whose holes took
  the low-rank refinement has its estimate scaled by the validated ratio of the two;
* *long gaps*: per filled frame, fill-auto's validated error of the fill that filled it
  (``source['fill_auto']['error_map']``), measured over all hidden stretches of the gap's
  own marker (not the worst round, which is right for choosing but biased up as an
  estimate); where fill-auto filled nothing the spline's own validation on the gap.

The total is then raised, where the file format fixes bone lengths, to the error the
written bones show (:func:`_bone_bound`: a bone written v cm off its length puts its two
ends at e_c + e_p >= v; a fill next to a sample kept as measured is charged v) -- a
floor that needs no assumption about the fills, for what the validations cannot see
(below).

What it cannot see: measured samples rejected in the fastest motion that no trusted
partner brings back (a whole hand over 4 frames at 120 fps, a whole leg over 12 frames
in CMU 05_05), whose fill error is the motion the spline cut: the hidden stretch next to
the hole moves slower than the hole itself. Most of the remaining spike-case misses of
docs/results/auto.md are these; the ten-gap cases miss both ways (0.3-3.6x), as ten
gaps give a heavy-tailed realised error. Measured and not kept (2026-12-04): charging a
rejected sample that two or more rigid partners vouch for (none disputes) its full
distance to the fill, as a measured motion the fill cut. On 10 CMU clips the protocol
does not use (spikes / missing30 / gaps10x60, 30 and 120 fps) it moved 4 cases into the
1.5x band and 3 out (42 -> 43 of 58); on the protocol 100 -> 99 of 115 -- at 120 fps about
one 15 cm spike per clip (~3,000 spikes) sits at a hinge (knee) and keeps both bone
lengths, is vouched for, and its 15 cm then dominates the estimate (walk@120 7.6x,
balance@120 6.5x the true error). The thumb flicks of CMU files that it was meant for
(one sample 9.3 cm off its fill held 99 % of the error of 135_09 at 120 fps) are disputed
by the hand and finger joints at those frames, so it did not see them either.

>>> from mocapkit import datasets, io, corrupt
>>> clip = io.read(datasets.bundled("16_15.amc"))
>>> noisy, _ = corrupt.combine(clip, [("gaussian", {"sigma_cm": 2.0})], seed=0)
>>> out = Auto().denoise(noisy)
>>> out.source["auto"]["chain"][0].startswith("mssa 0.")     # the SURE mix, MSSA leading
True
>>> out.source["auto"]["chain"][-1]                          # AMC: the bones keep their length
'bone lengths held'
>>> 0.2 < out.source["auto"]["estimated_rmse_cm"] < 2.0
True
"""
from __future__ import annotations

import time
import warnings
from dataclasses import replace

import numpy as np

from ..diagnose import SPIKE_RATE, cm_text, count_text, diagnose, diagnosis_of, robust_fit, used_columns
from ..gaps import gap_lengths
from ..motion import Motion
from ..signal import estimate_noise
from ..solvers import lowrank as _lr
from ..solvers.gcv_spline import (_BISQUARE, ROBUST_MIN_SCALE, cutoff_hz, gcv_smooth, plain_fit, residual_scale,
                                  validated)
from ..windows import frame_blocks
from ..solvers.mssa import (correlated_probe, mssa_denoise, sure_divergence, sure_divergence_stacked,
                            sure_weights)
from .base import Denoiser, get, register
from .fill_auto import SHORT_FRAMES
from .constraints import Integral, Interval, Real
from .fill_auto import DEFAULT_CANDIDATES

__all__ = ["Auto", "FILL_CANDIDATES", "whole_body_jumps"]

#: fills auto's fill-auto chooses from for long gaps: fill-auto's own. ``trnn`` (low-rank
#: completion) was one more until 2026-12-05: on ten 60-frame gaps of 16_15 at 120 fps it
#: gave 0.30 cm where auto without it gave 0.54, but the per-gap validation picked it where
#: it then failed -- on a real occlusion mask (real_gaps: CMU 135_04 under Eb015pr's mask) one
#: gap it took wrote 62 samples more than 20 cm off (9.3 cm RMSE where fill-auto's own
#: candidates give 0.93), and on the auto protocol balance@30 gaps10x60 0.764 against 0.390
#: cm, hdm05-kick@120 0.990 against 0.272. Without it, on the protocol and held-out clips'
#: 32 gaps10x60 cases: 24 the same, 4 better, 3 worse (at most 0.127 -> 0.157 cm), and 5
#: cases leave 33-120 more samples unfilled.
FILL_CANDIDATES = DEFAULT_CANDIDATES

#: the longest run of frames (a point's) that the rigid partners' distances may reject as
#: spikes in :func:`_second_look`; a longer disputed run is motion the partners do not share
MAX_SPIKE_RUN = 3

#: a rigid partner whose distance varies by at most this (cm; 4.685 x its robust scale) is
#: an exact bone, and its agreement is tested to this tolerance in :func:`_second_look`
EXACT_BONE_CM = 0.001

#: frames per piece of a long clip. A clip longer than 1.5 pieces is cleaned piece by
#: piece (each with :data:`PIECE_OVERLAP_S` of the neighbours' frames each side) and the
#: pieces are cross-faded: the whole-clip route holds ~18 arrays of the clip's size at
#: its peak (robust fit, its information, the smoothers and their SURE probes; 13.6x the
#: input at 100,000 frames, issue 21), pieces hold them for 8,192 frames only. Every
#: statistic auto takes (noise, spike rate, GCV strength, rigid partners) is then the
#: piece's own: 68 s at 120 fps, 4.5 min at 30 fps.
PIECE_FRAMES = 8192

#: seconds of overlap between neighbouring pieces (each side of a cut), at least 32 frames:
#: far beyond the reach of the smoothers (the GCV spline's kernel and MSSA's windows span
#: ~0.1-0.2 s), so a piece's own edge effects fall in the part the cross-fade gives away
PIECE_OVERLAP_S = 2.0


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
    edge_test : reject spikes on the end frames on a spiky noise-free clip (second look;
        off by default, see the module docstring).
    max_fill_error_cm : cm; a long gap whose best fill validates above it (fill-auto's
        ``max_error_cm``), or a short hole whose spline / partner fill does, is left
        missing (None: fill every gap with its best-validated fill, however far off).
    readmit : passes of the second look's re-admission of rejected samples (0: none).
    """

    name = "auto"
    description = ("diagnose the clip, remove spikes, smooth (GCV spline / MSSA / Kalman mixed by SURE weights), "
                   "fill long gaps by fill-auto; prints what it chose and an error estimate (cm)")
    needs_training = False
    keeps_observed = False
    fill_evidence = "markers"
    validates_fills = True           # (max_fill_error_cm / max_error_cm: the policy does not re-run it)

    _parameter_constraints = {"min_noise_cm": [Interval(Real, 0, None)], "spike_rate": [Interval(Real, 0, 1)],
                              "long_gap_s": [Interval(Real, 0, None)], "edge_test": [bool],
                              "max_fill_error_cm": [Interval(Real, 0, None, closed="neither"), None],
                              "readmit": [Interval(Integral, 0, None)]}

    def __init__(self, min_noise_cm: float = 0.25, spike_rate: float = SPIKE_RATE,
                 long_gap_s: float = 0.1, edge_test: bool = False,
                 max_fill_error_cm: float | None = 5.0, readmit: int = 3):
        self._store_params(locals())

    def denoise(self, motion: Motion) -> Motion:
        from ..solvers._linalg import blas_limit

        from ._refill import check_motion

        check_motion(motion, self.name)      # (a Kinect file of zeros: MSR-Action3D a13_s09_e02)
        with blas_limit():          # many small solves: one BLAS thread is fastest
            # (a file's reference pose -- a BVH's T-pose first frame -- is the shared
            # guard's: auto sees the motion's first frame in its place)
            jumps = whole_body_jumps(motion)
            if jumps or motion.n_frames > 1.5 * PIECE_FRAMES:
                return self._denoise_pieces(motion, jumps)
            out, src, _ = self._denoise(motion)
            codes = src.pop("fill_codes", None)
            res = motion.with_matrix(out, handover=True).with_source(auto=src)
            return res if codes is None else res.with_source(fill_codes=codes)

    def _after_policy(self, out: Motion) -> Motion:
        """The estimate over what is written: the gap policy may leave fills missing (off a
        rigid partner, out of the marker's reach) that the estimate charged. Scaled by the
        RMS of the per-sample estimates (``estimate_map``) over the written samples against
        all of them (:func:`~mocapkit.denoise.fill_auto.over_written`), so the estimate's
        own corrections (bones held, the bones' floor) keep their share. Found on the basket
        sprint (2026-12-05): the policy left 6,522 of auto's fills missing as implausible
        (5,508 of them out of the marker's reach), and the estimate still counted them."""
        from .fill_auto import over_written, rescored

        src = dict(out.source.get("auto") or {})
        emap = src.pop("estimate_map", None)
        if src.get("fill_auto") is not None:
            src["fill_auto"] = rescored(src["fill_auto"], out.observed)
        rep = out.source.get("gap_report") or {}
        est = src.get("estimated_rmse_cm")
        if emap is not None and est is not None and rep.get("left_implausible"):
            new = over_written(est, emap, out.observed)
            if new is not None:
                src["estimated_rmse_cm_before_policy"] = est
                src["estimated_rmse_cm"] = new
        return out.with_source(auto=src)

    def _denoise_pieces(self, motion: Motion, jumps: list[int] = ()) -> Motion:
        """Piece by piece: cut hard at the whole-body ``jumps`` (:func:`whole_body_jumps`), and a
        stretch longer than 1.5 x :data:`PIECE_FRAMES` into pieces of ~that many frames,
        cross-faded over the overlaps; the report merges the pieces' (``pieces``: each
        one's frames, chain and estimate; ``jumps``)."""
        t0 = time.perf_counter()
        T = motion.n_frames
        ov = min(max(32, int(round(PIECE_OVERLAP_S * motion.fps))), PIECE_FRAMES // 8)
        cuts, hard = [], []
        edges = [0, *jumps, T]
        for a, b in zip(edges[:-1], edges[1:]):
            if a > 0:
                cuts.append(a)
                hard.append(True)
            if b - a > 1.5 * PIECE_FRAMES:
                sub = _piece_cuts(motion.observed[a:b], PIECE_FRAMES, ov)
                cuts += [a + c for c in sub]
                hard += [False] * len(sub)
        bounds = list(zip([0] + cuts, cuts + [T]))
        n = len(bounds)
        starts = np.array([max(0, lo - (0 if i == 0 or hard[i - 1] else ov)) for i, (lo, _) in enumerate(bounds)])
        stops = np.array([min(T, hi + (0 if i == n - 1 or hard[i] else ov)) for i, (_, hi) in enumerate(bounds)])
        out = np.zeros((T, 3 * motion.n_joints))
        rejected = 0
        pieces, sq, chain, how, noise, hz = [], 0.0, [], [], [], []
        unestimated = 0                                          # frames of pieces without one
        emap = np.full((T, motion.n_joints), np.nan, np.float32)     # each piece's own frames
        # linear ramps over each cut's 2 ov shared frames, as tsmc / trnn / slra segments
        for (lo, hi), a, b, w in zip(bounds, starts, stops, _lr.blend_weights(starts, stops)):
            Y, src, rej = self._denoise(motion.slice(a, b))
            Y *= w[:, None]
            out[a:b] += Y
            rejected += int(rej[lo - a:hi - a].sum())             # the frames this piece owns
            est = src["estimated_rmse_cm"]
            if src.get("estimate_map") is not None:
                emap[lo:hi] = src["estimate_map"][lo - a:hi - a]
            pieces.append({"frames": [lo, hi], "chain": src["chain"], "estimated_rmse_cm": est})
            if est is None:
                unestimated += hi - lo
            else:
                sq += est ** 2 * (hi - lo)
            if hi - lo < 8 and est is None:        # the linear route of a piece too short
                span = f"frame {lo}" if hi - lo == 1 else f"frames {lo}-{hi - 1}"
                done = "linear fill of" if not motion.observed[lo:hi].all() else "as read:"
                src["chain"] = [f"{done} {span} (under 8 frames)"]
            chain += [c for c in src["chain"] if c not in chain]
            how += [h for h in src["how"].split(", ") if h and h not in how]
            noise.append(src["diagnosis"]["noise_cm"])
            hz.append(src["gcv_cutoff_hz"])
        diag = diagnosis_of(motion, float(np.nanmedian(noise)) if np.isfinite(noise).any() else float("nan"),
                            rejected)
        # the RMS over the frames of the pieces that have an estimate (a piece under 8
        # frames after a jump has none: it is said in `how`, and the rest stands)
        estimate = float(np.sqrt(sq / (T - unestimated))) if T > unestimated else None
        if unestimated and estimate is not None:
            how.append(f"{unestimated} frame(s) in pieces under 8 frames (kept as read) not estimated")
        hz_all = float(np.nanmedian(hz)) if np.isfinite(hz).any() else float("nan")
        src = {"chain": chain, "diagnosis": diag.as_dict(), "gcv_cutoff_hz": hz_all,
               "rejected": rejected, "estimated_rmse_cm": estimate, "seconds": time.perf_counter() - t0,
               "how": ", ".join(how) + (f"; {n - len(edges) + 2} pieces of ~{PIECE_FRAMES} frames, cross-faded "
                                        f"over {2 * ov} frames" if n > len(edges) - 1 else "")
                      + (f"; cut at {len(jumps)} whole-body jump(s) (frames "
                         f"{', '.join(map(str, jumps[:5]))}{', ...' if len(jumps) > 5 else ''}), each side "
                         f"cleaned on its own" if len(jumps) else ""),
               "pieces": pieces, "jumps": list(jumps),
               "left_missing": _left_missing(out, motion.observed.any(axis=0)),
               "max_fill_error_cm": self.max_fill_error_cm, "estimate_map": emap}
        return motion.with_matrix(out, handover=True).with_source(auto=src)

    def _denoise(self, motion: Motion) -> tuple[np.ndarray, dict, np.ndarray]:
        """The whole-clip route. Returns the cleaned (T, 3J) matrix (the caller's to keep),
        the report and the number of samples rejected as spikes per frame (T,)."""
        t0 = time.perf_counter()
        X, M = motion.matrix(copy=False), motion.matrix_mask()      # read only
        if motion.n_frames < 8:                     # too short to fit a smoothing spline
            # (a whole clip, or a piece between whole-body jumps: the report has every key
            # a piece's has)
            return (get("linear").denoise(motion).matrix(),
                    {"chain": ["linear fill (clip under 8 frames)"], "estimated_rmse_cm": None,
                     "how": "",
                     "diagnosis": diagnosis_of(motion, float("nan"), 0).as_dict(),
                     "gcv_cutoff_hz": float("nan"), "estimate_map": None},
                    np.zeros(motion.n_frames, int))
        # the robust fit's hole validation only where its fit is the one kept (below): a
        # clip without spikes keeps the robust iteration's first, plain pass instead, and a
        # spiky one may be fitted again (_refit_floor, _second_look)
        first: list = []                     # that first pass
        robust = robust_fit(motion, validate=False, plain_out=first)
        fit, info, usable = robust
        diag = diagnose(motion, robust)
        cols = np.repeat(usable, 3)
        spiky = diag.spike_rate > float(self.spike_rate)
        flagged = info.rejected                          # the robust fit's, spiky or not
        if not spiky:                                    # nothing rejected: plain GCV fit
            f, info = plain_fit(used_columns(X, cols), used_columns(M, cols), first[0], group=3)
            fit[:, cols] = f
        del first
        smooth = not (diag.noise_cm < float(self.min_noise_cm))
        unseen = None                  # what the estimate of the kept samples cannot see
        if spiky and smooth:
            # a noisy clip: the robust fit's residual-scale floor (1 cm, there so that the
            # fast motion of a noise-free clip is not called outliers) can drop to the
            # noise level auto smooths at. What it changes: corruption that is a mixture --
            # many samples exact, the others off by 0.3-5 cm -- keeps a small residual
            # scale, which the 1 cm floor hid (_refit_floor)
            fit, info = _refit_floor(X, M, cols, fit, info, float(self.min_noise_cm))
        confirmed = None
        if spiky and not smooth:                          # spikes on noise-free samples
            fit, info, confirmed = _second_look(X, M, cols, fit, info, self.edge_test, self.readmit)
        holes = ~M
        holes[:, cols] |= info.rejected
        out = np.where(holes, fit, X)
        info = validated(info, used_columns(X, cols), used_columns(M, cols), group=3)
        est = self._per_channel_errors(info, cols, smooth)
        if not smooth:
            # samples kept as measured: their error is the noise. The per-channel GCV
            # sigma also holds the spline's misfit on fast channels (0.04-0.1 cm RMS on
            # noise-free CMU clips at 120 fps); the package's robust estimate from the
            # whole matrix's fourth differences is another upper bound, the tighter one
            # where the noise is small against the motion (its docstring) -- the smaller
            # of the two is charged; where rigid partners exist, the spread of their
            # distances is a third, which no motion leaks into (rigid.distance_noise:
            # 0 on noise-free joint data where diff4-mad reads up to 0.09 cm at 30 fps)
            from ..rigid import distance_noise
            kept_m = used_columns(M, cols) & ~holes[:, cols]       # not the rejected spikes
            d4 = estimate_noise(used_columns(X, cols), kept_m, method="diff4-mad", pool="all", fallback=0.0)
            T = X.shape[0]
            sig_r = distance_noise(X.reshape(T, -1, 3)[:, usable], kept_m.reshape(T, -1, 3).all(axis=2))
            est["kept"] = np.fmin(est["kept"], np.fmin(d4, sig_r))
            if sig_r < FIXED_BONES_CM and d4 > sig_r:
                # every rigid distance is fixed to 10 micrometres: a skeleton's forward
                # kinematics (a Kinect SDK skeleton, a solver's AMC / BVH), where jitter of
                # the joint angles keeps the distances, so their zero spread is no evidence
                # of zero noise -- said, as no measurement on the clip tells the two apart
                # (MSR-Action3D at 15 fps: 16 of 23 clips kept as measured, the diagnosis
                # reading 0.04-0.23 cm of noise, most estimates ~0.00003 cm)
                unseen = (f"joint-angle jitter not measured as the bones keep fixed lengths "
                          f"(up to {cm_text(d4)} cm by time differences)")
            if spiky:
                # the prior that a kept end sample is a spike: the rate of the samples that
                # stayed rejected after the second look, not the robust test's -- a clip
                # whose flagged samples were all vouched for or readmitted holds no spike
                # evidence (found on a 30-frame clean CMU clip read back from C3D: nothing
                # rejected, the output the input, and an estimated 0.48 cm from its ends)
                kept_rate = (float(info.rejected[:, ::3].sum())
                             / max(int(used_columns(M, cols)[:, ::3].sum()), 1))
                est["kept_extra"] = np.zeros(X.shape)
                est["kept_extra"][:, cols] = _end_spikes_kept(X, M, cols, fit, info, kept_rate, confirmed)
        # what the user is told it did: a spiky clip whose flagged samples all stayed (the
        # second look's partners vouched for them) had no spike removed
        chain = (["spike removal"] if spiky and info.rejected.any()
                 else ["spike test (no spike confirmed)"] if spiky else [])
        if smooth:
            out[:, cols], picked, est["kept"][cols], sigma_s = _smooth(
                out[:, cols], ~holes[:, cols], fit[:, cols], diag.noise_cm, motion.fps,
                s=None if spiky else info.s, flagged=flagged)
            chain.append(picked)
        long = self._long_gaps(motion, smooth)
        if (holes & ~long).any() and not smooth:
            chain.append("spline fill")
            short = holes[:, cols] & ~long[:, cols]
            Xc, kept_c = used_columns(X, cols), used_columns(M, cols) & ~holes[:, cols]
            vals, err, val, match = _partner_fill(Xc, kept_c, fit[:, cols], info.s, short,
                                                  tie_cm=float(np.fmin(d4, sig_r)))
            if err is not None:
                oc = used_columns(out, cols)             # a view when every column is used
                oc[short] = vals[short]
                if not cols.all():
                    out[:, cols] = oc
                h = est["hole"][..., cols]
                est["hole"][..., cols] = np.where(np.isfinite(err), err, h)
                chain.append("partner-relative fill")
            if val is not None:
                def refined(vals, scale, label):
                    """Take a validated refinement of the short holes; its per-point
                    ratio scales their estimate."""
                    if scale is None:
                        return
                    oc = used_columns(out, cols)
                    oc[short] = vals[short]
                    if not cols.all():
                        out[:, cols] = oc
                    h = np.broadcast_to(est["hole"], out.shape).copy()
                    h[:, cols] *= np.repeat(scale, 3)[None, :]
                    est["hole"] = h
                    chain.append(label)

                sigma = 0.5 * (_combine(est, holes, long, None, usable, out) or 0.0)
                if match is not None:     # for the final estimate only (hole lengths matched)
                    m3 = np.ones(out.shape[1])
                    m3[cols] = np.repeat(match, 3)
                    est["match"] = m3
                vals, scale, val = _lowrank_fill(Xc, kept_c, used_columns(out, cols), val, sigma)
                refined(vals, scale, "low-rank fill")
                if motion.fps < LOW_FPS:
                    vals, scale, val = _lowrank_fill(Xc, kept_c, used_columns(out, cols), val, sigma,
                                                     window=LOWRANK_WINDOW_LOW_FPS)
                    refined(vals, scale, f"low-rank fill ({LOWRANK_WINDOW_LOW_FPS}-frame window)")
                h = np.broadcast_to(est["hole"], out.shape)[:, cols]
                refined(*_bone_fill(motion, usable, Xc, kept_c, used_columns(out, cols), short, val, h),
                        "bone lengths held")
        # (missing samples only: a rejected spike is a measured sample, and no method may
        # drop one -- its fill stays, charged its validated error)
        short_missing = ~M & ~long
        if self.max_fill_error_cm is not None and short_missing.any():
            out = _leave_unvalidated(out, short_missing, est["hole"], float(self.max_fill_error_cm))
        e_long, fa = None, None
        if long.any():
            out, e_long, fa = self._fill_long(motion, out, long, holes)
            chain.append("fill-auto")
        moved2 = None
        if smooth:
            kept_e = np.broadcast_to(np.asarray(est["kept"], float), (out.shape[1],))
            out, moved2, bones = _hold_bones(motion, out, usable,
                                             err=np.sqrt(np.mean(kept_e.reshape(-1, 3) ** 2, axis=1)))
            if moved2 is not None:
                chain.append("bone lengths held")
                moved2 *= _off_skeleton_share(X, ~holes, *bones, sigma_s)
            out, held = _hold_clusters(X, ~holes, out, usable, est, motion.fps)
            if held:
                chain.append(held)
        estimate, emap = _combine(est, holes, long, e_long, usable, out, per_point=True)
        if estimate is not None and moved2 is not None:
            # the move is (nearly) orthogonal to the error left: the smoothed pose lies off
            # the skeleton's pose set, the truth on it, so |e_before|^2 ~ |e_after|^2 +
            # |move|^2 (Pythagoras; measured on the protocol's 60 Gaussian / mixed cases:
            # estimate / true RMSE 0.83-1.18 after the subtraction, 1.05-1.38 without it) --
            # for the share of the noise that was off the skeleton's poses
            estimate = float(np.sqrt(max(estimate ** 2 - moved2, 0.25 * estimate ** 2)))
        # (where the bones were just held -- the smoothing path -- they show nothing)
        bound, bones_off = (_bone_bound(motion, out, usable, holes[:, ::3])
                            if estimate is not None and moved2 is None else (None, None))
        if bound is not None and bound > estimate:
            estimate = bound
        src = {
            "chain": chain, "diagnosis": diag.as_dict(),
            "gcv_cutoff_hz": float(np.median(cutoff_hz(info.s, 2, motion.fps))),
            "rejected": int(info.rejected[:, ::3].sum()) if spiky else 0,
            "estimated_rmse_cm": estimate, "seconds": time.perf_counter() - t0,
            "how": _how(smooth, bool(holes.any()), e_long is not None, unseen)
            + ("; raised to the error the written bones' lengths show"
               if bound is not None and bound >= estimate else ""),
            "bone_bound_cm": bound, "bones_off": bones_off,
            "left_missing": _left_missing(out, usable),
            "max_fill_error_cm": self.max_fill_error_cm,
            "fill_codes": _fill_codes(~M & ~long, fa, out),
            "estimate_map": emap,
        }
        if fa is not None:
            src["fill_auto"] = {k: v for k, v in fa.items() if k != "codes"}
        rej = info.rejected[:, ::3].sum(axis=1) if spiky else np.zeros(motion.n_frames, int)
        return out, src, rej

    def _long_gaps(self, motion: Motion, smooth: bool) -> np.ndarray:
        """(T, 3J) True on samples of gaps longer than ``long_gap_s`` -- or, in a marker
        capture whose samples are kept as measured, longer than ``MARKER_SHORT_FRAMES``."""
        from . import is_marker_capture

        length, _ = gap_lengths(motion.observed)
        never = ~motion.observed.any(axis=0)
        limit = float(self.long_gap_s) * motion.fps
        if not smooth and is_marker_capture(motion):
            limit = min(limit, MARKER_SHORT_FRAMES)
        long = (length > limit) & ~never[None, :]
        return np.repeat(long, 3, axis=1)

    @staticmethod
    def _per_channel_errors(info, cols: np.ndarray, smooth: bool) -> dict:
        """Estimated RMS error (C,) per sample class, NaN outside the fitted columns."""
        C = cols.size
        kept = np.full(C, np.nan)
        hole = np.full(C, np.nan)
        kept[cols] = info.smooth_error if smooth else info.sigma
        hole[cols] = info.hole_error if info.hole_error is not None else info.smooth_error
        if info.hole_map is not None:                   # per filled sample (T, C)
            hole = np.broadcast_to(hole, (info.hole_map.shape[0], C)).copy()
            hole[:, cols] = np.where(info.hole_map > 0, info.hole_map, hole[:, cols])
        return {"kept": kept, "hole": hole}

    def _fill_long(self, motion: Motion, out: np.ndarray, long: np.ndarray, holes: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, dict]:
        """Long gaps by fill-auto; returns the new matrix, the per-sample error estimate
        (T, 3J): for every frame fill-auto filled, the validated error of the candidate that
        filled it (``error_map``); NaN where it filled nothing (those samples are left
        missing: NaN in the matrix too) -- and fill-auto's report (its ``source['fill_auto']``
        without the error map, and ``source['fill_codes']`` as ``codes``). ``holes`` (T, 3J):
        the samples auto filled or replaced itself (short holes, rejected spikes), flagged as
        filled for fill-auto's candidates (:data:`mocapkit.rigid.KINEMATIC_MAX_GAIN`)."""
        filler = get("fill-auto", candidates=FILL_CANDIDATES, max_error_cm=self.max_fill_error_cm)
        work = motion.with_matrix(np.where(long, np.nan, out), observed=~long[:, ::3])
        # the spline's values are no measurement: a fill resting on them must know it
        short = (holes & ~long).reshape(len(holes), -1, 3).any(axis=2)
        work = work.with_filled(work.filled | short)
        filled = filler.denoise(work)
        Y = filled.matrix()
        take = long & np.isfinite(Y)
        out = out.copy()
        out[take] = Y[take]
        # what fill-auto did not fill (validated above max_fill_error_cm, or no evidence)
        # stays missing: the spline's values there are the kind of fill it refused
        out[long & ~take] = np.nan
        rep = dict(filled.source.get("fill_auto", {}))
        emap = rep.get("error_map")           # kept: the estimate is rescored after the policy
        e = np.full(long.shape, np.nan) if emap is None else np.repeat(emap, 3, axis=1)
        rep["codes"] = filled.source.get("fill_codes")
        return out, np.where(take, e, np.nan), rep


def _second_look(X: np.ndarray, M: np.ndarray, cols: np.ndarray, fit: np.ndarray, info,
                 edge: bool = True, readmit: int = 3):
    """A second look at the robust fit's rejections, for spikes on noise-free samples.

    *End frames* (``edge``): a natural spline bends to pass through an end sample
    (one-sided support), so its in-sample residual stays small -- on the development
    clips most spikes the robust fit kept sat on the clip's first or last frame. Each
    point's end samples are hidden (one extra fit, same s) and predicted from the rest; a
    kept end sample whose prediction residual (3-D) exceeds the robust test's limit,
    4.685 x max(scale, 1 cm) with the scale from all end residuals (chi-3 median), is
    rejected too.

    *Rigid partners* first (:func:`mocapkit.rigid.distance_consistency`): a kept sample
    whose distance to two or more partners is off and to none is right is a spike (on the
    development clips: most of the spikes the robust fit kept sat next to another spike of
    the same joint, or on an end frame); a rejected one that agrees with partners in three
    independent directions is measured.

    *Exact bones* (partners whose distance varies by at most :data:`EXACT_BONE_CM`: a
    skeleton's joints in any file format) are tested to that tolerance. A rejected sample
    is measured where two of them agree (whatever else disagrees: since 2026-12-05,
    eleventh session, martial-arts@120 spikes 0.096 -> 0.063 cm, @30 0.167 -> 0.163, the
    other 38 spikes cases of both clip sets identical; new seeds below: measured samples
    replaced at 30 fps 11 -> 9, no spike let back), or one agrees and every one that does not ends
    in a sample off all its own exact bones (two or more: a spike) -- at a hinge two
    distances do not pin a sample, and the apex of a kick at 30 fps, rejected by the
    spline's test with the spiked joints next to it, was filled 30 cm off. A kept sample
    none of them vouches for is a spike where a partner it is off from is vouched for by
    another exact bone of its own (a toe's or a finger's single bone). One bone alone
    never vouches (a spike keeps one length by chance, below), nor does anything a rigid
    partner that is not itself a spike still disputes. Measured (2026-12-05, tenth
    session) on the auto protocol's spikes cases, both clip sets: mean RMSE at 30 fps
    0.195 -> 0.102 cm (protocol) and 0.103 -> 0.049 (held-out), at 120 fps 0.027 -> 0.024
    and unchanged; 10 of the 40 cases better (kick@30 0.326 -> 0.080, hdm05-hop@30 0.444
    -> 0.074, 135_04@30 0.368 -> 0.098), none worse. Estimates within 1.5x: 7 and 8 of 10
    -> 7 and 7 at 30 fps (hdm05-hop@30: the holes' validated estimate, 0.45 cm, had
    matched the false rejections' error and now reads 6x the 0.074 left). Without the
    rigid partners' dispute: protocol 0.095 (kick@30 0.035), but on the test clip tiled
    three times a wrist spike was let back (below). What the exact bones vouch for is also
    ``confirmed`` (returned: :func:`_end_spikes_kept` does not charge it): estimates within
    1.5x on the spikes cases at 30 fps 7 -> 8 of 10 held-out (05_03@30 1.91 -> 0.92: a
    measured hand on the last frame had been charged 6.9 cm), hdm05-hop@30 6.16 -> 1.90;
    the charge also sets the low-rank step's noise level, so two outputs moved (05_03@30
    0.050 -> 0.056 cm, hdm05-hop@30 0.074 -> 0.072). On 40 new cases (four held-out clips
    at 30 and 120 fps, 10 % spikes of 15 cm, seeds 100-104;
    docs/results/auto_spike_seeds.md): spikes left in the output 15 -> 1 of 43,270,
    measured samples replaced 41 -> 19, mean RMSE 0.090 -> 0.047 cm (one case worse,
    0.044 -> 0.045).

    *Re-admission* (``readmit`` passes): where the motion is fast the spline, with one s
    per channel, cuts corners by more than the limit and rejects measured samples (and
    then their neighbours: runs of 3-8 rejected frames at 30 fps, most of a spiky clip's
    error). Without noise the right local model is interpolation: the rejected samples
    are predicted by the interpolating spline (s -> 0) through the kept ones -- both the
    position and, for each partner kept at that frame, the position relative to it, which
    moves far less in a kick -- and those within 4.685 cm (the limit's 1 cm floor) of
    either are measured samples and kept; a run shrinks pass by pass, and along a limb
    from the joint next to a trusted one.

    The fit is then redone on what is kept (same s). Returns (fit, info, confirmed): the
    last (T, J) True on the measured samples that two or more partners vouch for and none
    disputes (:func:`_end_spikes_kept` does not charge them).
    """
    from scipy.stats import chi2

    from ..rigid import distance_consistency, rigid_partners
    from ..solvers.gcv_spline import _solve_weighted

    Xc, Mc = used_columns(X, cols), used_columns(M, cols)
    T = Xc.shape[0]
    Y0 = np.where(Mc, Xc, fit[:, cols])
    rej = info.rejected.copy()
    P0, obs = Xc.reshape(T, -1, 3), Mc[:, ::3]
    # distances to the point's rigid partners first: they hold however fast the motion
    partners = rigid_partners(P0, obs)
    agree, disagree, pinned, slot = distance_consistency(P0, obs, partners=partners, per_partner=True)
    # at least two partners and none against: what the estimate takes as measured; to be
    # re-admitted the partners must also pin the sample (three independent directions)
    confirmed = obs & (agree >= 2) & (disagree == 0)
    back = rej[:, ::3] & confirmed & pinned
    # Exact bones (a skeleton's joints, in whatever file format): two partners whose
    # distance never varies beyond EXACT_BONE_CM vouch for a sample at a hinge too, where
    # two distances do not pin it (a knee between hip and ankle), while the apex of a kick
    # at 30 fps -- which the spline's test rejects with its neighbours -- keeps them exactly
    part, real, mref, scale = partners
    exact = real & (_BISQUARE * np.nan_to_num(scale, nan=np.inf) <= EXACT_BONE_CM)
    spike_x = np.zeros_like(obs)
    if exact.any():
        ag_x, dis_x, _, slot_x = distance_consistency(P0, obs, partners=(part, exact, mref, scale),
                                                      floor_cm=EXACT_BONE_CM, per_partner=True)
        # Two agreeing bones vouch whatever else disagrees: a spike keeps two lengths within
        # 0.001 cm in ~1e-9 of tries, so a partner off them is the one that moved (a thumb
        # flicking about the wrist, its distances to the hand and fingers broken: on
        # martial-arts@120 three finger samples next to it had been filled 10-12 cm off).
        # One agreeing bone vouches too where every partner that disagrees -- exact, or
        # rigid to the usual limit -- is off all its own exact bones (two or more: a
        # spike), and it counts as the second. One bone never vouches alone: a 15 cm spike
        # keeps a length within 0.001 cm in ~1 of 10^4 tries, and a clip at 120 fps has
        # ~3,000 (a head spike was let back on duck@120); nor where a rigid partner still
        # disputes it (a wrist spike kept its 21 cm bone to 0.0004 cm, next to a spiked
        # hand, and was let back 15 cm off while the thumb and hand disputed it)
        definite = obs & (ag_x == 0) & (dis_x >= 2)
        explained = ((slot_x < 0) & definite[:, part]).sum(axis=2)
        disputed = ((slot < 0) & ~definite[:, part]).any(axis=2)
        vouched_x = obs & ((ag_x >= 2) | ((ag_x >= 1) & (ag_x + explained >= 2)
                                           & (dis_x == explained) & ~disputed))
        back |= rej[:, ::3] & vouched_x
        confirmed |= vouched_x          # nor is it charged as a spike kept on an end frame
        # ... and a kept sample that no exact bone vouches for, while one it is off from is
        # vouched for by another of its own, is a spike: a toe or a finger tip has a single
        # bone, so the two disputing partners below never exist for it (hdm05-kick@30, 10 %
        # spikes: two 15 cm toe spikes kept, one on the first frame)
        vouched = ag_x[:, part] >= 1                                # (T, J, K): the partner
        spike_x = obs & ~rej[:, ::3] & (ag_x == 0) & ((slot_x < 0) & vouched).any(axis=2)
    # Measured and not kept (2026-12-05): also rejecting where the disputing partners
    # outnumber agreeing ones that do not pin the sample (a 15 cm spike kept two of four
    # skin-marker distances by chance): tennis serve 2 players + 2 % spikes 0.123 -> 0.114
    # cm, but protocol spikes jump@120 0.031 -> 0.060, martial-arts@30 0.199 -> 0.242,
    # duck@30 0.091 -> 0.113 (kick@30 0.380 -> 0.296; held-out 2 better, none worse)
    out = (~rej[:, ::3] & obs & (disagree >= 2) & (agree == 0)) | spike_x
    # A spike is a glitch of a frame or a few; partners disputing a longer run of frames is
    # the motion of a point they are not rigid with -- skin markers across a shoulder or a
    # wrist: in a 50 fps tennis serve (kineticstoolkit, 2 % spikes added) 27 and 23 frames
    # of a clean upper-arm marker were rejected here and then filled up to 43 cm off
    # (the run of these samples alone: next to the robust fit's own rejections, which run
    # 3-8 frames in fast motion at 30 fps, real spikes would be let through -- run@30 spikes
    # 0.21 -> 0.62 cm when the two were counted as one run)
    run, _ = gap_lengths(~out)
    out &= run <= MAX_SPIKE_RUN
    changed = bool(back.any() or out.any())
    rej &= ~np.repeat(back, 3, axis=1)
    rej |= np.repeat(out, 3, axis=1)
    # the position relative to a rigid partner moves far slower than the position itself
    # in a strike or a kick: interpolated, it tells a measured sample from a spike. Any of
    # the partners trusted at that frame will do, so a run of rejected samples along a limb
    # (hip -> knee -> ankle -> toes) comes back a joint per pass
    n_pts = P0.shape[1]
    xyz = np.tile(np.arange(3), n_pts)
    slots = [(np.repeat(np.where(real[:, q], part[:, q], np.arange(n_pts)) * 3, 3) + xyz,
              np.repeat(real[:, q], 3)) for q in range(part.shape[1])]
    s0 = np.full(Xc.shape[1], 1e-6)
    for _ in range(int(readmit)):
        if not rej.any():
            break
        kept = Mc & ~rej
        pred = _solve_weighted(Y0, kept.astype(float), s0, 2)
        d = np.sqrt((((pred - Y0) ** 2).reshape(T, -1, 3)).sum(axis=2))
        back = rej[:, ::3] & (d < _BISQUARE)             # the spike limit's 1 cm floor
        for pc, has in slots:
            trusted = kept[:, pc] & has                     # partner measured and kept there
            if not (rej & trusted).any():
                continue
            Rel = Y0 - Y0[:, pc]
            pred = _solve_weighted(Rel, (kept & trusted).astype(float), s0, 2)
            d = np.sqrt((((pred - Rel) ** 2).reshape(T, -1, 3)).sum(axis=2))
            back |= rej[:, ::3] & trusted[:, ::3] & (d < 4.685)
        if not back.any():
            break
        rej &= ~np.repeat(back, 3, axis=1)
        changed = True
    if edge:
        W = (Mc & ~rej).astype(float)
        ends = [0, T - 1]
        W2 = W.copy()
        W2[ends] = 0.0
        pred = _solve_weighted(Y0, W2, info.s, 2)
        d = np.sqrt(((pred - Y0)[ends].reshape(2, -1, 3) ** 2).sum(axis=2))          # (2, points)
        kept = W[ends, ::3] > 0
        if kept.any():
            scale = float(np.median(d[kept])) / float(np.sqrt(chi2.ppf(0.5, 3)))
            flag = kept & (d > 4.685 * max(scale, 1.0))
            if flag.any():
                rej[ends] |= np.repeat(flag, 3, axis=1)
                changed = True
    if not changed:
        return fit, info, confirmed
    f, info2 = gcv_smooth(Xc, Mc & ~rej, s=info.s, group=3)
    fit = fit.copy()
    fit[:, cols] = f
    return fit, replace(info2, rejected=rej, outliers=rej.sum(axis=0)), confirmed


def _judged(ref: np.ndarray, hide: np.ndarray, a: np.ndarray, b: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two fills judged on hidden samples: their squared 3-D distances (T, J) to ``ref``
    (T, C), and the hidden points that count for choosing between them (T, J).

    A hidden sample neither fill predicts within the spike limit (4.685 cm, the limit's
    1 cm floor) is most likely a spike the tests kept: it says nothing about which fill is
    better and would swamp both sums (measured: one kept spike made a point's
    relative-fill estimate 29 cm), so it does not count."""
    T, C = ref.shape
    da = ((a - ref) ** 2).reshape(T, C // 3, 3).sum(axis=2)
    db = ((b - ref) ** 2).reshape(T, C // 3, 3).sum(axis=2)
    return da, db, hide[:, ::3] & (np.minimum(da, db) <= _BISQUARE ** 2)


#: frames (evenly spaced) on which :func:`_partner_fill` picks each point's rigid partners:
#: 512 as :func:`mocapkit.rigid.distance_noise` (1,024 before 2026-12-05: on the two clip
#: sets' missing30 / spikes cases 10 of 80 outputs moved, by 0.974-1.001x, and the 120 fps
#: cases ran 6 % faster)
PARTNER_REF_FRAMES = 512
#: :func:`_partner_fill`: a point takes the relative fill (or its mean with the spline) only
#: where its hidden samples' RMS error is lower than the spline's by more than this times
#: the capture's noise (``tie_cm``)
PARTNER_TIE = 1.0


def _length_weights(kept: np.ndarray, W: np.ndarray, fill: np.ndarray, hp: np.ndarray) -> np.ndarray:
    """(T, J) weights of the hidden points ``hp`` that give the lengths (1, 2, 3+ frames) of
    the holes they sit in -- in the validation's pattern ``W`` (kept and not hidden) -- the
    distribution of the real holes' (``fill``, in the pattern ``kept``), pooled over the
    points: a post-stratification of the validation to the clip's own holes.

    >>> kept = np.ones((10, 1), bool); kept[[2, 6]] = False          # real holes: 1 frame
    >>> hp = np.zeros((10, 1), bool); hp[[3, 8]] = True               # hidden: 2 and 1 frames
    >>> _length_weights(kept, kept & ~hp, ~kept, hp)[[3, 8], 0].tolist()
    [0.0, 2.0]
    """
    Lr, _ = gap_lengths(kept)
    Lv, _ = gap_lengths(W)
    cr = np.minimum(Lr, 3)[fill]
    cv = np.minimum(Lv, 3)
    w = np.zeros(hp.shape)
    for c in (1, 2, 3):
        pr = float(np.mean(cr == c)) if cr.size else 0.0
        sel = hp & (cv == c)
        pv = float(sel.sum()) / max(int(hp.sum()), 1)
        if pv > 0:
            w[sel] = pr / pv
    return w


def _partner_fill(X: np.ndarray, kept: np.ndarray, fit: np.ndarray, s: np.ndarray,
                  fill: np.ndarray, frac: float = 0.1, seed: int = 0, tie_cm: float = 0.0
                  ) -> tuple[np.ndarray, np.ndarray | None]:
    """Short holes of noise-free samples filled through each point's rigid partners, for
    the points where that validates better than the spline.

    The spline fills a hole from the point's own trajectory; in fast motion the position
    relative to a rigid partner (:func:`mocapkit.rigid.rigid_partners`: a bone's other end,
    a marker of the same cluster) moves far less -- only the segment's rotation, not the
    body's travel -- so ``p_k(t) + interp(p_j - p_k)(t)``, averaged over the partners k
    kept at t, can be the better fill. Which one is better depends on the point (a hand
    at 30 fps: the relative fill; a point whose partners are poor: the spline), so it is
    validated per point: ``frac`` of the kept samples (seeded) are hidden and predicted
    both ways (the spline with the clip's GCV strength ``s``, the relative trajectories
    by an interpolating spline), and a point takes the relative fill, or the mean of the two
    fills, where its hidden samples' squared error is lower than the spline's (the two
    fills' errors are far from fully correlated, so their mean often beats both: with the
    mean as a third choice, mean RMSE on the protocol's spikes / missing30 cases @30
    0.206 / 0.245 -> 0.204 / 0.238 cm, @120 0.030 / 0.043 -> 0.030 / 0.041; on 10 CMU
    clips the protocol does not use 0.126 / 0.209 -> 0.124 / 0.176 and 0.023 / 0.042 ->
    0.022 / 0.041, per case 0.40-1.09 x; estimates within 1.5x 33 -> 31 of 40 on the
    protocol and 29 -> 32 on those clips). Measured on the auto protocol against the spline fill
    alone (docs/results/auto.json): 30 % random missing, RMSE lower in 18 of 20 cases,
    higher in 2 (at most +3 %); 10 % spikes, lower in 17 of 20, higher in 3 (at most
    +0.4 %). Hidden samples neither fill predicts within 4.685 cm are left out of the
    choice (kept spikes: without that, run@30 spikes went 0.252 -> 0.346 cm; now 0.236).
    A point whose fills' validated RMS errors differ by less than the capture's noise
    (``tie_cm``: the smaller of the diff4-MAD and rigid-distance estimates) keeps the
    spline, as a tie in fill-auto goes to interpolation. Measured (2026-12-06, twentieth
    session): the auto protocol's 114 corrupted cases unchanged (noise-free clips); on
    real_gaps, the tennis serve under the Optotrak mask's single-frame dropouts 0.0248 ->
    0.0224 cm (the cubic 0.0198). Measured and not kept: a paired t test (the taken fill's
    squared errors lower than the spline's by 2 standard errors) -- the tennis serves 0.0224
    / 0.0424 cm, but on noise-free clips the glitches' heavy tails hid real gains: protocol
    missing30@120 worst auto / oracle 0.93 -> 1.06, estimates within 1.5x 88 -> 84 %.

    X (T, C) cm, kept (T, C) the measured samples trusted, fit (T, C) the spline, s (C,),
    fill (T, C) the samples to fill. Returns (values (T, C) -- the relative fill where a
    point took it (or its mean with ``fit``), ``fit`` elsewhere; err (C,) cm -- the RMS per
    coordinate of the taken fill's hidden-sample errors where a point took it, NaN elsewhere, for the error
    estimate), or (fit, None) when no point takes it; and the validation, (hide (T, C) the
    kept samples hidden, pred (T, C) what the fill each point took predicts there), for
    :func:`_lowrank_fill` (None when nothing could be hidden); and ``match`` (J,), the
    factor that turns a point's estimate into that of holes as long as the real ones
    (:func:`_length_weights`; None when no point takes the fill), applied to the final
    estimate only (the 5 cm rule, the low-rank noise level and the bone guard read the
    plain one: outputs unchanged). Measured (2026-12-05, missing30 / spikes cases, same
    seeds): estimates within 1.5x of the true error 56 -> 59 of 80 on the protocol and
    held-out clips (49_19@120 1.51 / 1.50 -> 1.40 / 1.39; out: duck@30 spikes 0.72 ->
    0.59), 24 -> 23 of 40 on the ten clips of docs/results/auto_lowrank.md (131_09@30
    missing30 1.67 -> 1.30 in; 05_01@30 missing30 0.74 -> 0.66 and 135_03@120 spikes 0.75
    -> 0.66 out): the estimates move down, which helps where they read high and costs
    where glitches make them read low.
    """
    from ..rigid import rigid_partners
    from ..solvers.gcv_spline import _solve_weighted

    T, C = X.shape
    J = C // 3
    Y0 = np.where(kept, X, fit)
    hide = np.repeat(np.random.default_rng(seed).random((T, J)) < frac, 3, axis=1) & kept
    if not hide.any():
        return fit, None, None, None
    W = kept & ~hide
    pa = _solve_weighted(Y0, W.astype(float), np.asarray(s, float), 2)
    part, real, _, _ = rigid_partners(np.where(kept, X, np.nan).reshape(T, J, 3), kept[:, ::3],
                                    n_ref=PARTNER_REF_FRAMES)
    if not real.any():
        return fit, None, (hide, pa), None
    xyz = np.tile(np.arange(3), J)
    s0 = np.full(C, 1e-6)                             # interpolating: noise-free samples

    def relative(W: np.ndarray, base: np.ndarray) -> np.ndarray:
        acc, n = np.zeros((T, C)), np.zeros((T, C))
        for q in range(part.shape[1]):
            pc = np.repeat(np.where(real[:, q], part[:, q], np.arange(J)) * 3, 3) + xyz
            trusted = W[:, pc] & np.repeat(real[:, q], 3)
            pred = _solve_weighted(Y0 - Y0[:, pc], (W & trusted).astype(float), s0, 2)
            pred += Y0[:, pc]
            acc += np.where(trusted, pred, 0.0)
            n += trusted
        return np.where(n > 0, acc / np.maximum(n, 1.0), base)

    pr = relative(W, pa)
    da, dr, hj = _judged(Y0, hide, pa, pr)
    # the estimate below keeps the samples the choice leaves out (at 30 fps a fast hand's
    # fill can miss by more than the spike limit: leaving them out there made estimates
    # too low)
    hp = hide[:, ::3]                                              # (T, J) hidden points
    ea = (da * hj).sum(axis=0)
    er = (dr * hj).sum(axis=0)
    dm = ((0.5 * (pa + pr) - Y0) ** 2).reshape(T, J, 3).sum(axis=2)  # the mean of the two
    em = (dm * hj).sum(axis=0)
    # the relative fill or the mean, where it beats the spline by more than the capture's
    # noise (RMS per coordinate over the judged points): below the noise no score is
    # evidence, and a tie goes to the spline (fill-auto's rule; :data:`PARTNER_TIE`)
    nh = np.maximum(3 * hj.sum(axis=0), 1)
    use = np.sqrt(np.minimum(er, em) / nh) < np.sqrt(ea / nh) - PARTNER_TIE * tie_cm
    half = use & (em < er)                         # the mean
    if not use.any():
        return fit, None, (hide, pa), None
    # The error estimate of a relative fill is its own validation: the RMS per coordinate
    # of its hidden-sample errors. Scaling the spline's hole-by-hole estimate by the
    # validated ratio instead was measured worse (spikes + missing30, 40 cases: within
    # a factor 1.5 of the truth 68 % against 75 %). So was charging the points that keep
    # the spline this same random-hide validation of the spline (2026-12-04: there the
    # hole-by-hole estimate reads 1.7-6x low on the misses, e.g. walk@30 missing30 0.17
    # against 0.37 cm), as the estimate or as a floor under it: 33 of 40 cases within
    # 1.5x -> 29 / 30 of 40 -- at 30 fps a hidden sample next to a real hole makes a longer
    # hole (estimates up to 1.8x high), and one kept spike among the hidden samples
    # swamped run@30 spikes (12x).
    # Measured and not kept (2026-12-06, twenty-second session; the 80 missing30 / spikes
    # cases of both clip sets, estimate only, outputs unchanged): the chosen fill's error
    # measured on a second random set of hidden samples (seed + 1), not the set that chose
    # it -- choosing on a point's 6-30 hidden samples biases their score low. missing30
    # cases within 1.5x 31 -> 35 (duck@120, hdm05-hop@120, 07_03@30, 135_09@120, 131_12@120
    # in; kick@30 out), spikes 27 -> 23 (run@30 0.75 -> 2.97x: the second set alone read
    # 4x the first); the mean of the two sets' squared errors 31 -> 34 and 27 -> 25; either
    # with the spike-limit filter on the second set 34 / 23. A point's few hidden samples
    # are too noisy a judge for either set alone.
    er_all = np.where(half, (dm * hp).sum(axis=0), (dr * hp).sum(axis=0))
    err = np.repeat(np.where(use, np.sqrt(er_all / np.maximum(3 * hp.sum(axis=0), 1)), np.nan), 3)
    # the holes the validation makes are longer than the real ones (a hidden sample next
    # to a real hole): its errors re-weighted to the real holes' lengths give the estimate
    # (not the fill's noise level for the low-rank step, measured on the plain ones)
    wv = _length_weights(kept[:, ::3], W[:, ::3], fill[:, ::3], hp)
    nw = (hp * wv).sum(axis=0)
    ew = np.where(half, (dm * hp * wv).sum(axis=0), (dr * hp * wv).sum(axis=0)) / np.maximum(nw, 1e-12)
    ep = er_all / np.maximum(hp.sum(axis=0), 1)
    match = np.where(use & (ep > 0) & (nw > 0), np.sqrt(ew / np.maximum(ep, 1e-300)), 1.0)
    rel = relative(kept, fit)
    rel = np.where(np.repeat(half, 3)[None, :], 0.5 * (rel + fit), rel)
    vals = np.where(np.repeat(use, 3)[None, :] & fill, rel, fit)
    pick = np.where(np.repeat(half, 3)[None, :], 0.5 * (pa + pr), pr)
    return vals, err, (hide, np.where(np.repeat(use, 3)[None, :], pick, pa)), match


#: in a marker capture (:func:`mocapkit.denoise.is_marker_capture`) kept as measured, gaps
#: longer than this (frames) go to fill-auto: real occlusions of skin markers are filled best
#: per gap, by the rigid cluster, pattern or body-frame PCA fill its validation picks
#: (docs/results/real_gaps.md); a gap of 1-2 frames by the spline chain, which is as good
#: there and avoids fill-auto's per-gap cost on thousands of them. The gap policy's
#: self-validation of other methods' fills leaves the same gaps out (one number)
MARKER_SHORT_FRAMES = SHORT_FRAMES

#: :func:`_impute`: embedding window (frames), passes of the validation run and of the
#: final run (which starts from the validation run's result) and over-relaxation factor.
#: Measured on the auto protocol's and held-out missing30 / spikes cases (2026-12-05):
#: 10 + 5 passes at 1.7 keep the mean RMSE of 20 + 20 plain passes within 2.2 % with 15
#: passes instead of 40 (auto / gcv-spline on missing30 @120 12.3x with 20 + 20, 9.4x
#: with these); on the holes at 120 fps (20 plain passes) a window of 4 frames gained 3
#: points at 5.7x the imputation's time, 8 frames none at 24x; 4 frames at 30
#: fps only (the same cost per second as 2 at 120) in place of 2: protocol missing30 @30
#: worst auto / oracle 0.84 -> 0.74, held-out 0.86 -> 0.83, mean RMSE -3 / -1 %, but
#: estimates within 1.5x 3 fewer of 80 missing30 / spikes cases -- not kept; as a second
#: validated step after the 2-frame one it is (:data:`LOWRANK_WINDOW_LOW_FPS`)
LOWRANK_WINDOW = 2
#: below :data:`LOW_FPS` the 2-frame refinement is followed by one with this window,
#: validated per point the same way (a point takes it where its hidden samples come out
#: better than after the 2-frame step). At 30 fps two frames span 67 ms, too short for the
#: body's coordination over a fast movement. Measured (2026-12-05, same seeds, mean RMSE
#: cm, missing30@30): protocol 0.209 -> 0.202 (worst auto / oracle 0.83 -> 0.72: the 0.8
#: target is met), held-out 0.125 -> 0.120 (0.77 -> 0.71), the ten clips of
#: docs/results/auto_lowrank.md 0.175 -> 0.165 (0.81 -> 0.67); spikes@30 -0.1 / -2 / -1 %;
#: per case 0.80-1.07x but for one 1.29x (held-out 135_09: a knee's 6-frame gap, which
#: fill-auto fills from its neighbours, went to another candidate and 8 cm off); estimates
#: within 1.5x 49 -> 48 of 60 (the three sets' missing30 / spikes @30)
LOWRANK_WINDOW_LOW_FPS = 4
LOW_FPS = 60.0
LOWRANK_PASSES = 10
LOWRANK_FINAL_PASSES = 5
LOWRANK_RELAX = 1.7


def _impute(Z: np.ndarray, fixed: np.ndarray, X: np.ndarray, sigma: float,
            passes: int | None = None, window: int = LOWRANK_WINDOW) -> np.ndarray:
    """Iterative low-rank imputation of the (T, C) matrix ``Z`` (cm): ``passes`` passes of
    MSSA (``LOWRANK_PASSES`` when None) with optimal shrinkage at noise level ``sigma``
    (:func:`mocapkit.solvers.mssa.mssa_denoise`, ``window`` frames), each
    over-relaxed by ``LOWRANK_RELAX`` (Z + w (S(Z) - Z)), with the ``fixed`` samples reset
    to ``X`` after each pass -- the iterative SSA gap filling of Kondrashov & Ghil 2006
    (Nonlin. Processes Geophys. 13:151, Sec. 2), with the Gavish-Donoho shrinkage in place
    of a number of components chosen by cross-validation.

    >>> import numpy as np
    >>> t = np.linspace(0, 6, 200)[:, None]
    >>> X = np.hstack([np.sin(t + k) for k in range(6)])        # rank 2: shifted sines
    >>> fixed = np.random.default_rng(0).random(X.shape) > 0.3
    >>> Z = np.where(fixed, X, 0.5 * (np.roll(X, 1, 0) + np.roll(X, -1, 0)))   # a rough fill
    >>> bool(np.abs(_impute(Z, fixed, X, 0.01) - X)[~fixed].mean() < np.abs(Z - X)[~fixed].mean())
    True
    """
    Z = np.where(fixed, X, Z)
    for _ in range(LOWRANK_PASSES if passes is None else int(passes)):
        S = mssa_denoise(Z, sigma, window=window)
        Z += LOWRANK_RELAX * (S - Z)
        np.copyto(Z, X, where=fixed)
    return Z


def _validated_choice(dc: np.ndarray, dr: np.ndarray, hj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A refinement of the short-hole fills, judged per point on hidden samples (squared
    errors dc of the current fill, dr of the refined one, (T, J); hj the samples that count,
    :func:`_judged`). Returns (use (J,): where the refined fill's sum is lower; scale (J,):
    the factor on a point's hole estimate, 1 where it keeps its fill).

    The scale is cross-fitted: the rule is decided on the hidden samples of even frames and
    scored on those of odd frames, and the other way round, so that it measures the
    choice, not the luck of the samples that made it. The ratio on the samples that chose
    (sqrt(er / ec) where er < ec) is biased low -- a point takes the refinement exactly
    where its hidden samples happened to favour it -- and compounded over the low-rank and
    bone steps it read the error of 30 % missing samples at half the truth (walk@30:
    holes' true RMSE 0.236 -> 0.197 cm over the two steps, the estimate 0.066 -> 0.047).
    """
    ec, er = (dc * hj).sum(axis=0), (dr * hj).sum(axis=0)
    use = er < ec
    odd = (np.arange(dc.shape[0]) % 2 == 1)[:, None]
    a_c, a_r = (dc * (hj & ~odd)).sum(axis=0), (dr * (hj & ~odd)).sum(axis=0)
    b_c, b_r = ec - a_c, er - a_r
    got = np.where(a_r < a_c, b_r, b_c) + np.where(b_r < b_c, a_r, a_c)
    return use, np.where(use, np.sqrt(got / np.maximum(ec, 1e-300)), 1.0)


def _lowrank_fill(X: np.ndarray, kept: np.ndarray, out: np.ndarray, val, sigma: float,
                  window: int = LOWRANK_WINDOW) -> tuple[np.ndarray, np.ndarray | None]:
    """Short holes of noise-free samples refined by iterative low-rank imputation
    (:func:`_impute`), for the points where that validates better than their fill.

    The spline and partner fills use one point's own path and its rigid partners; the
    whole body's coordination -- every point's path at once, the model of ``auto``'s MSSA
    smoother -- says more. The imputation starts from those fills (``out``, every hole
    filled) and keeps the measured samples; ``sigma`` (cm, the shrinkage's noise level) is
    half the estimated RMS error of the completed matrix (the fill error, spread over all
    samples). Validation as in :func:`_partner_fill` (``val``: its hidden kept samples and
    what each point's fill predicts there): the imputation runs first with those hidden
    too, and a point takes the refined fill where its hidden samples' squared error is
    lower (samples neither predicts within the spike limit left out); its hole estimate is
    scaled by the validated ratio of the two. The final run starts from the validation
    run's result with the hidden samples back.

    Measured (2026-12-05, same seeds as docs/results/auto.md; mean RMSE, cm): protocol
    missing30 @30 0.238 -> 0.217, @120 0.041 -> 0.036, spikes 0.204 -> 0.199 and 0.029 ->
    0.027; held-out clips missing30 0.164 -> 0.139 and 0.038 -> 0.031, spikes 0.120 ->
    0.112 and 0.025 -> 0.022; ten CMU clips in neither set, used for no choice (05_01,
    05_05, 07_05, 131_01/04/09/14, 135_03/06/11; docs/results/auto_lowrank.md) missing30
    0.220 -> 0.187 and 0.050 -> 0.042, spikes 0.222 -> 0.214 and 0.070 -> 0.068. Per case
    at most 1.015x (run@30 spikes; 1.014x on the third set). Estimates within 1.5x of the
    truth, all conditions: protocol 98 -> 99 of 114, held-out 100 -> 97 of 117; the third
    set's missing30 + spikes 27 -> 24 of 40 -- where a few thumb steps or fast rejected
    samples rule the error, the validated ratio (on
    ordinary samples) lowers the estimate more than the error falls, and where the gain is
    large it reads it low (the validation hides 10 % more samples than the clip lacks).
    The real marker files of docs/results/auto_markers.md (spiky rows: the noise-free
    path) moved by at most 0.0007 cm. sigma as 0.25 / 0.5 / 1 / 2 times the estimate: the
    holes' RMSE 0.84 / 0.83 / 0.90 / 1.12 of before (mean over the two sets' missing30
    cases, 20 plain passes, windows of 4-16 frames; 2x made 120 fps fills worse, up to
    1.5x). Cost: docs/results/auto_lowrank.md (``benchmarks/auto_lowrank.py``); auto /
    gcv-spline on missing30 @120 7.3 -> 9.4x.

    X, kept, out (T, C) cm (X NaN where missing). Returns (values (T, C), scale (J,) or
    None when no point takes it -- 1 where a point keeps its fill).
    """
    hide, pred = val
    if not sigma > 0 or X.shape[0] < 2 * window + 2:
        return out, None, val
    Rv = _impute(np.where(hide, pred, out), kept & ~hide, X, sigma, window=window)
    use, scale = _validated_choice(*_judged(np.where(kept, X, out), hide, pred, Rv))
    if not use.any():
        return out, None, val
    R = _impute(Rv, kept, X, sigma, passes=LOWRANK_FINAL_PASSES, window=window)    # the hidden samples back
    u3 = np.repeat(use, 3)[None, :]
    vals = np.where(u3, R, out)
    return vals, scale, (hide, np.where(u3, Rv, pred))


#: a bone is left alone where its length is off by more than this many times the moving
#: end's estimated 3-D fill error (a kept spike, a step, a fill the validation missed)
BONE_FILL_GUARD = 5.0
#: Gauss-Seidel sweeps of :func:`_bone_fill`'s projection (the bones are in parent-first order, so a
#: moving child is final after one; 3 against 10: the same mean RMSE to 0.001 cm on the
#: two clip sets' missing30 / spikes cases, at a fifth of the time, 9 against 51 ms on 469
#: frames)
BONE_FILL_SWEEPS = 3


def _bone_fill(motion: Motion, usable: np.ndarray, X: np.ndarray, kept: np.ndarray, out: np.ndarray,
               fill: np.ndarray, val, hole: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Short-hole fills of a noise-free clip moved onto the bone lengths the file format
    fixes (:func:`mocapkit.rigid.hold_lengths` with only the fills movable; ASF/AMC and BVH,
    :func:`mocapkit.rigid.fixed_bones`), for
    the points where that validates better.

    A fill from one point's path, its partners or the body's low-rank model does not know
    the bone: at 30 fps a chord fill of a swinging forearm shortens it. Of a bone's two
    ends only a fill moves (a measured sample is exact), the child where both are fills (a
    bad distal fill cannot drag a good proximal one), and a bone is left alone where its
    length is off by more than ``BONE_FILL_GUARD`` (5) times the moving end's estimated
    3-D error (a kept spike, a step inside the hole). Validation as in
    :func:`_lowrank_fill` (``val``: the kept samples hidden and what the fills so far
    predict there): the hidden samples are held with the holes, and a point takes the held
    fills where its hidden samples' squared error is lower; its hole estimate is scaled by
    the validated ratio. (An earlier version without the validation, in the
    :func:`_hold_bones` docstring, cut the error as much but left no honest estimate.)

    Measured (2026-12-05, same seeds as docs/results/auto.md; mean RMSE in cm, before ->
    after): protocol missing30 @30 0.217 -> 0.209, @120 0.0359 -> 0.0341, spikes 0.199 ->
    0.195 and 0.0272 -> 0.0269; held-out clips missing30 0.139 -> 0.124 and 0.0305 ->
    0.0282, spikes 0.112 -> 0.106 and 0.0220 -> 0.0208; the ten CMU clips of
    docs/results/auto_lowrank.md, used for no choice, missing30 0.187 -> 0.174 and 0.0425
    -> 0.0394, spikes 0.214 -> 0.209 and 0.0675 -> 0.0670. Per case at most 1.114x
    (hdm05-hop@30 spikes, a 20-frame clip: the last frame's rejected shank sample is
    filled 12 cm off and its foot, a spike filled 4 cm off, is pulled to 10 cm), then
    1.075x (jump@120 spikes); held-out at most 1.010x, third set 1.043x. Worst missing30
    auto / oracle: held-out @30 0.86 -> 0.77 (the 0.8 target met there), protocol @30
    0.84 -> 0.83, @120 0.92 -> 0.93 / 0.94 -> 0.90. Estimates within 1.5x: protocol 99 ->
    96 of 115 (three missing30 / spikes cases whose error thumb steps rule: the
    validated ratio, on ordinary samples, lowers the estimate more than the error falls),
    held-out 97 -> 97 of 117, third set 24 -> 24 of 40. Cost: 9 ms on 469 frames
    (``BONE_FILL_SWEEPS``); auto / gcv-spline on missing30@120 9.4x (protocol), 9.5x
    (held-out) after it. Measured and not kept: also leaving a bone alone where the fixed
    end is a fill with a larger estimate than the moving one (mean RMSE the same to 0.001
    cm, 4 of 80 missing30 / spikes cases worse by over 1 %, and hdm05-hop@30 spikes, the
    case it aimed at, unchanged). Nor (2026-12-05, tenth session) a hole between a kept
    parent and child put on their circle at the azimuth interpolated (cubic, over the
    joint's measured frames) about the parent-child axis from the grandparent's direction:
    on the missing30@30 cases of both clip sets, over those holes, root-sum-square error
    85.5 cm against the fills' 34.8 (the reference direction swings with the grandparent,
    and near a straight limb the azimuth is ill-defined).

    X, kept, out, fill, hole (T, C) over the used columns (``usable`` (J,) points); hole
    the per-sample estimate (cm per coordinate). Returns (values (T, C), scale (J_used,)
    or None when nothing takes it).
    """
    from ..rigid import fixed_bones, hold_lengths

    T, C = out.shape
    J = motion.n_joints
    full = np.full((T, J, 3), np.nan)
    full[:, usable] = out.reshape(T, -1, 3)
    bones, lengths = fixed_bones(motion, full)
    if not len(bones) or val is None:
        return out, None
    hide, pred = val
    tol = np.full((T, J), np.inf)
    tol[:, usable] = np.sqrt(3.0) * np.nan_to_num(hole[:, ::3], nan=np.inf)

    # the validation (hidden samples movable too) and the real fill in one call: frames
    # stacked, each half held on its own
    V = np.where(hide, pred, out)
    P = np.concatenate([full, full])
    P[:, usable] = np.concatenate([V, out]).reshape(2 * T, -1, 3)
    mov = np.zeros((2 * T, J), bool)
    mov[:, usable] = np.concatenate([fill | hide, fill])[:, ::3]
    H2 = hold_lengths(P, bones, lengths, sweeps=BONE_FILL_SWEEPS, movable=mov,
                      max_off=BONE_FILL_GUARD * np.concatenate([tol, tol]))[:, usable].reshape(2 * T, C)
    Hv, H = H2[:T], H2[T:]
    use, scale = _validated_choice(*_judged(np.where(kept, X, out), hide, V, Hv))
    if not use.any():
        return out, None
    return np.where(np.repeat(use, 3)[None, :], H, out), scale


def _end_spikes_kept(X: np.ndarray, M: np.ndarray, cols: np.ndarray, fit: np.ndarray, info,
                     rate: float, confirmed: np.ndarray | None = None) -> np.ndarray:
    """(T, C) squared error to charge kept samples for the spikes the robust fit kept on
    the first and last frame (a natural spline bends through an end sample, so the
    in-sample test cannot see them; the end test that would reject them is off, see
    ``edge_test``). Estimate only: the output keeps them as measured.

    The kept end samples are hidden (one extra fit, same s) and predicted from the rest;
    one off by more than the robust limit (4.685 x max(scale, 1 cm), scale from all end
    residuals) is *flagged*, and charged p d^2 / 3 per coordinate (d: its 3-D prediction
    residual, what it is off by if it is a spike), p the posterior that a flagged sample
    is a spike, ``rate / (rate + f (1 - rate))``: the prior is the clip's spike rate, and f
    the rate at which measured samples are flagged by the same one-sided prediction, as
    measured one frame in (frames 1 and T-2, predicted with the two end frames hidden).
    """
    from scipy.stats import chi2

    from ..solvers.gcv_spline import _solve_weighted

    Xc, Mc = used_columns(X, cols), used_columns(M, cols)
    T, C = Xc.shape
    extra = np.zeros((T, C))
    if T < 8 or not rate > 0:
        return extra
    W = (Mc & ~info.rejected).astype(float)
    Y0 = np.where(Mc, Xc, fit[:, cols])
    med = float(np.sqrt(chi2.ppf(0.5, 3)))

    def flags(hidden, test):
        W2 = W.copy()
        W2[hidden] = 0.0
        pred = _solve_weighted(Y0, W2, info.s, 2)
        d = np.sqrt(((pred - Y0)[test].reshape(2, -1, 3) ** 2).sum(axis=2))          # (2, points)
        kept = W[test, ::3] > 0
        if not kept.any():
            return d, kept, kept
        scale = float(np.median(d[kept])) / med
        return d, kept, kept & (d > 4.685 * max(scale, 1.0))

    d, kept, flag = flags([0, T - 1], [0, T - 1])
    if confirmed is not None:                    # partners' distances vouch for the sample
        flag &= ~confirmed[[0, T - 1]]
    if not flag.any():
        return extra
    _, kept_in, flag_in = flags([0, 1, T - 2, T - 1], [1, T - 2])
    f = float(flag_in.sum()) / max(int(kept_in.sum()), 1)
    p = rate / (rate + f * (1.0 - rate))
    extra[[0, T - 1]] = np.repeat(np.where(flag, p * d ** 2 / 3.0, 0.0), 3, axis=1)
    return extra


def _smooth(Y: np.ndarray, kept: np.ndarray, fit: np.ndarray, sigma: float,
            fps: float, s: np.ndarray | None = None, flagged: np.ndarray | None = None
            ) -> tuple[np.ndarray, str, float, float]:
    """GCV spline, MSSA and a constant-velocity Kalman/RTS smoother on the complete matrix Y
    (holes filled), mixed by the convex weights of lowest Monte-Carlo SURE on the kept
    samples (:func:`mocapkit.solvers.mssa.sure_weights`). Returns (out, what was used,
    estimated RMSE, the noise level used). ``sigma`` (the GCV noise level) is used only where the fourth
    differences cannot be formed; ``flagged`` (T, C): samples the noise level leaves out. ``s`` (per column): ``fit`` is the plain GCV fit of the
    kept samples with this smoothing (the path without spikes) and is used as it is; None:
    the spline is fitted here. Either way its probe run holds that smoothing (a fixed
    linear map, as the other two hold their ranks and process noise).

    The noise level was the GCV sigma before 2026-12-05; the fourth differences' (measured
    that day, same seeds, against it): mean RMSE gauss1 / mixed @30 -3.4 / -3.3 % on the
    protocol's clips (run@30 gauss1 0.664 -> 0.595, hdm05-hop@30 0.712 -> 0.630) and -0.5 /
    -2.8 % on the held-out clips; gauss3@30 and every 120 fps condition within +-0.3 %;
    worst case +1.3 %.

    The weights replaced (2026-12-05) the pick of lowest SURE among the three and two fixed
    50/50 means (gcv+mssa, mssa+kalman), and the spline is refitted on the kept samples
    (its robust fit as the probe's reference had made SURE pick the spline alone on spiky
    clips). Protocol (docs/results/auto.md, same seeds) mean RMSE gauss1 / gauss3 / mixed
    @30 0.497 / 1.196 / 1.067 -> 0.494 / 1.184 / 1.007 cm, @120 0.291 / 0.686 / 0.538 ->
    0.290 / 0.681 / 0.525; held-out clips mixed @30 / @120 0.918 / 0.500 -> 0.877 / 0.491.
    Typical weights: MSSA 0.5-0.8, the Kalman smoother 0.2-0.4, the spline 0-0.2 (more
    on slow clips).

    Measured and not kept on Gaussian noise written to AMC (2026-12-05, sixth session;
    held-out clips, gauss3@30 unless said; auto / oracle median / worst 0.817 / 0.878):
    the three smoothers on bone vectors (child minus parent, summed back from the root),
    since an AMC read-back's noise is per bone: 1.24 / 1.29 (the smoothing errors add up
    along each chain); on channels whitened by the noise covariance of the fourth
    differences (eigenvalues floored at 1 / 10 / 30 % of their mean): 0.89-0.95; SURE for
    noise correlated across channels (the probe drawn from that covariance, so that the
    divergence is tr(J Sigma) / sigma^2): weights move from MSSA to the spline, mean RMSE
    +1.1 % (a plain covariance; with shrinkage it was kept in the eighth session, below);
    truth-optimal convex weights of the three (least squares on the truth, before
    the bone hold) gain 3-8 % on the SURE mix, so the weights are not where the AMC route
    loses. MSSA's window doubled: AMC gauss3 / mixed mean RMSE -2 % (worst, in memory
    after the AMC read: 0.88 / 0.87 -> 0.87 / 0.85 at 30 fps, 0.87 / 0.84 -> 0.83 / 0.80
    at 120), gauss1 -0.4 / -0.3 %; but positions in memory +0.9 / +0.3 / +0.7 % at 120 fps
    (held-out, gauss1 / gauss3 / mixed), +0.6 / +0.3 / +0.6 % at 30 fps (protocol clips),
    -0.3..+0.4 % at 30 fps (held-out) -- the AMC worst case still misses 0.8, not kept; window
    x3 / x4 no better on AMC gauss3@30, x0.5 +5 %. MSSA's noise level x1.3 (fewer
    components kept): AMC gauss3@30 -1.9 % (worst 0.878 -> 0.862), its estimate within
    1.5x 10 -> 7 of 10; x0.8 +9 %.

    Where the AMC route loses against memory (2026-12-05, seventh session; per joint,
    held-out 131_08@30 gauss3: 1.352 cm through AMC, 1.194 in memory): in the short distal
    bones -- fingers 2.1-2.3 against 1.3-1.5 cm, hands 1.3-1.5 against 1.1, thumbs, the
    head. A 3 cm bone under 3 cm noise gets an almost random direction from the writer's
    IK, so the read-back child no longer carries the information a noisy position does.
    Tried: such a child rebuilt as its parent's result plus its length along the
    GCV-smoothed noisy parent-to-child vector (in world axes), for bones shorter than k x
    the diagnosis noise level. Held-out gauss3@30 auto / oracle median / worst 0.817 /
    0.878 -> 0.803 / 0.875 (k = 1.45), 0.792 / 0.860 (every bone under 3.2 cm: fingers,
    a few hands and thumbs), none worse; but on the protocol's clips through AMC 0.836 /
    0.895 -> 0.829 / 0.895 (k = 1.45), 0.814 / 0.897 (1.75), 0.810 / 0.916 (2.1), one or
    two of ten worse (a fast hand turns the vector faster than the smoothing allows); in
    memory (held-out, bones under 3.2 cm), where the child's noise is plain positional,
    6 of 10 clips worse, by up to 4.4 % (49_19). Not kept; a smoother in the parent's own
    frame (its rotation taken out) is what this points to.

    Measured and not kept (2026-12-05, ninth session; the held-out clips through AMC at
    gauss3@30, positions as read back and cleaned, auto / oracle worst 0.87 on 131_08 and
    131_12): smoothing in each parent's frame, i.e. the file's own local rotations (GCV on
    the nine entries of each bone's rotation matrix, projected back onto rotations, then
    forward kinematics): 8.2 cm against auto's 1.34 on 131_08 (a small error at the root or
    the spine turns everything below it: femur ends 3.5 cm off, hands 8-16 cm); the Euler
    angles GCV-smoothed after unwrapping, 7.7 cm (noisy IK flips between the two Euler
    branches of one rotation). Where the error sits: with fingers and thumbs as good as
    their hands, 131_08 would still be at 0.81 x the oracle. The shipped general
    ``xiao-sparse`` model as a fourth smoother: alone 0.78-1.12 x the oracle, a 50/50 mean
    with auto worst 0.87 (49_19: 0.81 -> 0.87), the truth-optimal weight per clip (0.11-0.72)
    worst 0.80 (05_03, 49_19, 131_12) -- and 07_03, 131_08 and 131_12 are of subjects the
    shipped models were trained on, so their gains are not the general model's. Neither
    reaches 0.8 in every clip.

    SURE's probe is correlated across channels as the noise is (since 2026-12-05, eighth
    session; :func:`mocapkit.solvers.mssa.correlated_probe`: the covariance of the fourth
    differences, shrunk towards the identity). Read back from a rotation file the noise is
    shared between joints -- through BVH a zero-length ``_base`` joint carries its
    parent's exactly and each joint's error is in large part its parent's -- and the +-1
    probe, blind to that, rated MSSA, which keeps noise that looks like the signal's
    correlation, best: MSSA alone in 11 of 12 BVH cases looked at (held-out 01_01@120
    gauss1, positions as read back and cleaned, before the write: 0.499 cm, MSSA alone
    0.507, the GCV spline alone 0.400; 0.383 with the correlated probe). Measured against
    the +-1 probe, same seeds: through BVH (docs/results/auto_files.md, 10 held-out clips)
    worst auto / oracle gauss1 / gauss3 / mixed / spikes @30 0.96 / 0.85 / 0.79 / 0.65 ->
    0.79 / 0.79 / 0.76 / 0.65, @120 1.05 / 0.81 / 0.69 / 0.46 -> 0.72 / 0.63 / 0.62 / 0.45
    (mean RMSE gauss1@120 0.434 -> 0.315 cm), estimates within 1.5x 48 -> 70 of 80;
    through AMC worst gauss3@30 0.88 -> 0.87, gauss3@120 0.85 -> 0.80, mixed@120 0.82 ->
    0.78, mixed@30 0.87 -> 0.85, per case 0.92-1.03x; in memory (white noise: the probe
    ~N(0, I)) mean RMSE per condition +0.0 to +0.6 % on the protocol's clips (per case
    0.99-1.03x, hdm05-hop@30 gauss1 +3.0 %, fast motion at 30 fps leaking into the
    differences) and -0.3 to +0.4 % on the held-out ones (0.99-1.02x); no in-memory target
    moved, estimates within 1.5x 99 of 114 and 99 of 117 as before. The shrinkage: see
    :func:`~mocapkit.solvers.mssa.correlated_probe`.

    Measured on 5 CMU clips x 30/120 fps x Gaussian 1/3 cm (before the bench, see
    docs/results/auto.md for the full run): the mean of GCV and MSSA was best or tied in
    18 of 20 cases (0.60-0.80 x the oracle-tuned classical filter; GCV alone 0.67-0.92,
    MSSA alone 0.65-0.87), and the SURE pick was within 3 % of the best candidate.

    The Kalman candidate (:func:`_kalman_cv`): the ``kalman-cv`` model with the noise at
    auto's sigma, the process noise per channel by robust maximum likelihood on Y *once*,
    then held, and the rejected / missing samples as missing -- a fixed linear smoother,
    so the one-probe SURE judges it exactly (the gated ``kalman-cv``, far from linear, was
    tried before and misjudged: SURE picked it in 4 of 36 fast-motion cases and it was
    worse each time). It adds what a second-difference prior lacks in fast motion at low
    frame rates; mostly its mean with MSSA wins. On the protocol's 60 Gaussian / mixed
    cases (docs/results/auto.md, same seeds), against the three candidates before: mean
    RMSE gauss1 / gauss3 / mixed @30 0.523 / 1.216 / 1.109 -> 0.514 / 1.199 / 1.103 cm,
    @120 0.293 / 0.695 / 0.542 -> 0.291 / 0.686 / 0.538; per case 0.94-1.03 x (worst
    kick@30 mixed +2.7 %; hdm05-hop@30 gauss3 -5 %). On 10 CMU clips the protocol does not
    use (same conditions, 60 cases): mean -0.05..-1.3 % per condition, per case 0.92-1.02 x.
    """
    window = max(2, min(int(round(0.13 * fps)), Y.shape[0] // 4))
    # the smoothers' noise level: the package's estimator on the kept samples' fourth
    # differences, not the GCV spline's sigma, which the spline's misfit of fast motion at
    # low frame rates pulls low (run@30 and hdm05-hop@30 with 1 cm noise: GCV 0.69, diff4
    # 0.99 / 0.985), and a low sigma makes MSSA keep and the Kalman filter follow noise.
    # Their RMS, not their MAD (since 2026-12-05): a linear smoother's risk and SURE hold
    # the noise's second moment whatever its distribution, and the MAD reads only the core
    # of a heavy-tailed one -- in an AMC file the writer's IK spreads a spike over the
    # frame, and the samples kept after the spikes are rejected are half exact, half off
    # by 0.3-3 cm (held-out 01_01@120: MAD 0.21, RMS of the kept error 0.77 cm). Through
    # AMC files (docs/results/auto_files.md) RMSE spikes@120 0.247 -> 0.195, gauss3@120
    # 0.822 -> 0.770 on 01_01; in memory, Gaussian noise, every protocol / held-out case
    # within 0.97-1.008x of the MAD's. The RMS leaves out the samples the robust fit
    # flagged (``flagged``, (T, C)) even where the clip was not called spiky: a few jumps it
    # keeps would rule it -- 10,000 frames of a clip tiled 9 times with 1 cm noise read
    # 3.2 cm from its seams, 1.0 without them.
    sig4 = float(estimate_noise(Y, kept if flagged is None else kept & ~flagged, method="diff4-rms",
                                pool="all"))
    sigma = sig4 if np.isfinite(sig4) and sig4 > 0 else float(sigma)

    held = [] if s is None else [s]          # the smoothing, chosen on Y, then held

    def f_gcv(Z):
        if held:
            return gcv_smooth(Z, kept, s=held[0], group=3, validate=False)[0]
        f, inf = gcv_smooth(Z, kept, group=3, validate=False)
        held.append(inf.s)
        return f

    ranks: list[int] = []                  # filled by the first run: the probe's run then
                                           # takes the same ranks, i.e. the same map

    def f_mssa(Z):
        return mssa_denoise(Z, sigma, window=window, ranks=ranks)

    if Y.shape[0] < 4 * window:
        return fit, "gcv-spline", float(sigma), float(sigma)
    f_kal = _kalman_cv(Y, kept, sigma, fps)
    # the spline refitted on the kept samples, not the robust fit passed in: the probe's run
    # is this refit, and a reference other than f(Y) puts (f(Y) - fit) / e, e = 0.01 sigma,
    # into the divergence (on spiky clips it made SURE pick the spline alone: run@30 mixed
    # 1.68 cm where the mix below gives 1.30)
    fns = {"gcv-spline": f_gcv, "mssa": f_mssa}
    outs = {k: (fit if k == "gcv-spline" and s is not None else f(Y)) for k, f in fns.items()}
    # one probe for all: the divergence is linear in f, so a mix's is the mix of theirs
    # the probe correlated across channels as the noise is (None, too few differences: +-1)
    probe = correlated_probe(Y, kept, sigma, rng=0)
    div = {k: sure_divergence(f, Y, sigma, mask=kept, fy=outs[k], rng=0, probe=probe) for k, f in fns.items()}
    # the Kalman smoother's run and its probe's in one call, side by side: its loop over the
    # frames is paid once for both; the same numbers as two runs (the 62-frame HDM05 jog at
    # 30 fps, best of 30 runs' CPU time: 4.7 ms side by side, 11.2 ms as the clip's run and
    # sure_divergence's, one run alone 3.5 ms -- a short clip's time is per-frame overhead)
    outs["kalman-cv"], div["kalman-cv"] = sure_divergence_stacked(f_kal, Y, sigma, mask=kept, rng=0,
                                                                  probe=probe)
    names = list(outs)
    w, _ = sure_weights(Y, [outs[k] for k in names], sigma, [div[k] for k in names], mask=kept)
    out = outs[names[0]] * w[0]
    for k, wk in zip(names[1:], w[1:]):
        if wk > 0:
            out += wk * outs[k]
    order = np.argsort(-w)
    picked = " + ".join(f"{names[i]} {w[i]:.2f}" for i in order if w[i] >= 0.005)
    if w.max() > 0.995:
        picked = names[int(order[0])]
    # the estimate: the variance term sigma^2 df / N of the risk, df = the divergence (as
    # the spline's own sigma sqrt(tr H / n)), not the SURE value: SURE's -sigma^2 cancels
    # this clip's realised noise energy in the residual only as well as sigma matches it,
    # and 1 % off in sigma at 3 cm moves the risk by 0.18 cm^2 (49_19@30: SURE 0.39
    # against 0.63 true). On the kept samples of the 120 Gaussian / mixed cases of
    # the protocol and held-out clips: within 1.5x of the true RMSE 119 of 120, SURE 113
    N = max(int(np.count_nonzero(kept)), 1)
    df = float(np.dot(w, [div[k] for k in names]))
    return out, picked, float(sigma * np.sqrt(max(df, 0.0) / N)), sigma


def _kalman_cv(Y: np.ndarray, kept: np.ndarray, sigma: float, fps: float):
    """A fixed linear smoother for :func:`_smooth`: constant-velocity Kalman filter + RTS
    (:class:`mocapkit.denoise.kalman.KalmanCV`'s model, no gate) with measurement noise
    ``sigma`` and the process noise chosen per channel on Y (robust ML,
    :func:`mocapkit.signal.select_process_noise`) and then held, the samples not ``kept``
    missing. Returns ``f(Z) -> (T, C)``."""
    from .. import signal

    dt = 1.0 / float(fps)
    q, _ = signal.select_process_noise(Y, kept, dt=dt, r=sigma ** 2, order=2)
    C = Y.shape[1]
    first = np.argmax(kept, axis=0)
    P0 = np.diag([1e4, 1e6])                 # vague prior, as kalman-cv: 100 cm, 1000 cm/s

    def f(Z: np.ndarray) -> np.ndarray:
        # Z may hold k copies of the channels side by side (k C columns; the SURE probe's
        # run with Y's, :func:`mocapkit.solvers.mssa.sure_divergence_stacked`): one loop
        # over the frames for all, each column's numbers as alone
        k = Z.shape[1] // C
        F, Q = signal.cv_model(dt, np.tile(q, k), order=2)
        x0 = np.zeros((k * C, 2))
        x0[:, 0] = Z[np.tile(first, k), np.arange(k * C)]
        xs, _ = signal.rts_smoother(Z, np.tile(kept, (1, k)), F=F, Q=Q, R=sigma ** 2, x0=x0, P0=P0)
        return xs[:, :, 0]

    return f


def _refit_floor(X: np.ndarray, M: np.ndarray, cols: np.ndarray, fit: np.ndarray, info, floor: float):
    """The robust spline fit of a noisy spiky clip again, with the bisquare's residual-scale
    floor at ``floor`` cm (auto's ``min_noise_cm``) instead of the diagnosis' 1 cm.
    ``info``: the diagnosis fit's GCVInfo. Returns (fit (T, 3J), its GCVInfo) -- the ones
    given where no point's residual scale is under the 1 cm floor.

    The 1 cm floor keeps a noise-free clip's fast motion from being called outliers; on
    the smoothing path the clip has noise of at least ``floor``, and the floor then only
    hides a residual scale smaller than the noise estimate -- the case of a corruption that
    is a mixture. Written to AMC by ``mocapkit corrupt`` (the writer's IK fits each
    spiked frame), 10 % spiked samples leave ~30 % of the samples exact and spread the rest
    over 0.3-5 cm; with a 1 cm floor only the samples off by more than 4.7 cm were rejected
    and the rest smoothed as noise. Held-out clips through AMC (docs/results/auto_files.md),
    auto / oracle-tuned classical, median / worst of 10 clips, with the RMS noise level of
    :func:`_smooth`: spikes@120 1.01 / 1.67 -> 0.47 / 0.52, spikes@30 0.76 / 1.18 -> 0.58 /
    0.79; mixed and Gaussian cases -- in memory and through AMC -- came out the same to the
    4th digit: their residual scale is above 1 cm anyway
    (points' scales 1.3-2.2 cm with 2 cm noise, 0.35-0.9 cm on the spread spikes). So the
    refit runs only where some point's scale is under half the 1 cm floor: run on every
    spiky noisy clip it had doubled auto's time on the protocol's mixed@30 (7.8 -> 13.8 x
    the method it picks, against the 10x target), and with 1 cm noise half the points read
    a scale just under 1 cm (10,000 frames with 1 cm noise and a few jumps: 2,150 -> 1,750
    frames/s for nothing).
    """
    Xc, Mc = used_columns(X, cols), used_columns(M, cols)
    scale, _ = residual_scale(Xc, used_columns(fit, cols), Mc, info.trace / X.shape[0], 3)
    if not (scale < 0.5 * ROBUST_MIN_SCALE).any():
        return fit, info
    f, info = gcv_smooth(Xc, Mc, robust=True, group=3, min_scale=floor)
    fit = fit.copy()
    fit[:, cols] = f
    return fit, info


def _off_skeleton_share(X: np.ndarray, kept: np.ndarray, bones: np.ndarray, lengths: np.ndarray,
                        sigma: float) -> float:
    """Share (0-1) of the kept samples' noise that lies off the skeleton's poses: the noise
    the bones' lengths read squared over ``sigma`` squared. The bones (B, 2) (child,
    parent) the format fixes, ``lengths`` (B,) cm (:func:`mocapkit.rigid.fixed_bones`):
    white noise of std s per coordinate on both ends moves a bone's length by s sqrt(2)
    (for bones over 3 cm), read from its fourth differences over the kept frames (no
    motion leaks in: the length is fixed); the median over the bones. 0 where the input's
    bones hold their length, e.g. positions read from an AMC / BVH file: there noise is in
    the joint angles, and holding the bones after smoothing only undoes the smoother's
    shortening of them, not noise (held-out 01_01@120 through AMC, Gaussian 3 cm: true
    RMSE 0.714 -> 0.712 by the hold while the full Pythagoras subtraction took the estimate
    0.53 -> 0.27). 1 where no bone says anything.

    (Until 2026-12-06 the noise was :func:`mocapkit.rigid.distance_noise`'s, from each
    point's most rigid partner: 2.8 ms of a 240-frame clip's 80, where this one costs a
    tenth. Measured on 20 of the protocol's cases with white 1 / 3 cm noise the share reads
    0.73-0.99 (the partner search's 0.55-1.00), and 0 on six AMC / BVH read-backs, as
    before.)"""
    from ..signal import estimate_noise

    T = X.shape[0]
    K = kept.reshape(T, -1, 3).all(axis=2)
    use = np.asarray(lengths, float) >= 3.0
    c, p = bones[use, 0], bones[use, 1]
    if not (sigma > 0) or not len(c):
        return 1.0
    P = X.reshape(T, -1, 3)
    d = np.linalg.norm(P[:, c] - P[:, p], axis=2)
    ok = K[:, c] & K[:, p] & np.isfinite(d)
    n = np.asarray(estimate_noise(np.where(ok, d, 0.0), ok, method="diff4-rms"), float)
    n = n[np.isfinite(n)]
    if not n.size:
        return 1.0
    return float(min(np.median(n) ** 2 / 2.0 / sigma ** 2, 1.0))


#: a point joins a rigid group held by :func:`_hold_clusters` where the slow part of its
#: distances and of its rigid-fit residual varies by at most this times the smoothing's
#: estimated error (std, cm): a group that bends by less is held -- the bend becomes
#: error, a third of what the hold removes. Measured 2026-12-06 on the 19 vendor BVH files
#: (in memory, Gaussian 1 / 3 cm and mixed; a first version, groups from four points): at
#: an absolute 0.3 cm, groups bending by up to 0.23 cm were held on the cgspeed skeletons
#: and gauss1 got worse (131_03 +8 %); at 0.3 x the estimate none of the cgspeed files
#: changed by over 1 % and every Daz file gained 2-8 %
CLUSTER_TOL = 0.3

#: the window (s) of the slow part :func:`_hold_clusters` tests
CLUSTER_WINDOW_S = 0.25

#: :func:`_hold_clusters` holds groups of at least this many points (at distinct places).
#: Four-point groups (a CMU hand: wrist, hand, fingers, thumb) gained 1 % on the protocol's
#: clips at 30 fps and cost a tenth of auto's time there; the Daz hands (12) and chests (7)
#: are what the hold is for
CLUSTER_MIN_POINTS = 5


def _hold_clusters(X: np.ndarray, kept: np.ndarray, out: np.ndarray, usable: np.ndarray,
                   est: dict, fps: float) -> tuple[np.ndarray, str]:
    """The smoothed (T, 3J) ``out`` with the groups of joints or markers that move as one
    rigid body held rigid (:func:`mocapkit.rigid.steady_clusters` on the input ``X``'s
    ``kept`` samples, :func:`mocapkit.rigid.hold_clusters` on ``out``), and the chain's
    words for it ('' where no group is found). The smoothing's estimate of the held points
    (``est['kept']``, updated in place) loses the mean squared move: the truth is rigid,
    the noise is not, so the move is (nearly) orthogonal to the error left (as for the
    bones, :func:`_hold_bones`), floored at half the estimate.

    Why: a rigid body's points carry independent noise, and a smoother works on each
    point's path alone; the rigid fit keeps the 6 coordinates a body's motion has out of
    its points' 3K. Vendor BVH conversions carry such bodies: in the Daz-friendly CMU
    files each hand (forearm, wrist, ten finger joints) and the chest (abdomen, chest,
    neck, collars, shoulders) are rigid to 0.3 cm, and the writer's IK turns their 1-3 cm
    finger bones almost at random under noise. So do marker plates, head bands and the
    pelvis of a marker set. Measured (2026-12-06, twenty-fourth session, same seeds): the 19
    vendor BVH files through the CLI (docs/results/auto_vendor_bvh.md, with the Daz blend
    written back as read, :func:`mocapkit.denoise.bases.reference_frames`): worst auto /
    oracle gauss3 / mixed 0.83 / 0.83 -> 0.74 / 0.77; the held-out CMU clips through BVH
    (auto_files.md) gauss3@30 0.813 -> 0.78; in memory (auto.md, auto_heldout.md: some CMU
    forearm-and-hand and spine groups at 30 fps) mean RMSE gauss1 / gauss3 @30 -0.7..-1.5 %,
    no case worse by over 0.6 %, 120 fps within 0.2 %."""
    from ..rigid import hold_clusters, steady_clusters

    T = X.shape[0]
    e = float(np.sqrt(np.mean(np.asarray(est["kept"], float) ** 2)))
    if not (e > 0):
        return out, ""
    idx = np.flatnonzero(usable)
    Pin = X.reshape(T, -1, 3)[:, idx]
    ok = kept.reshape(T, -1, 3).all(axis=2)[:, idx]
    P = out.reshape(T, -1, 3)
    # the groups' shapes from the smoothed positions: the input's 1-3 cm finger bones under
    # 3 cm of noise read short (the mean of noisy directions lies inside the sphere; a Daz
    # hand's template from the input was up to 1.2 cm off its true shape)
    groups, shapes = steady_clusters(Pin, ok, fps, CLUSTER_TOL * e, window_s=CLUSTER_WINDOW_S,
                                     min_size=CLUSTER_MIN_POINTS, shape_from=P[:, idx], return_shapes=True)
    if not groups:
        return out, ""
    held = hold_clusters(P[:, idx], groups, shapes)
    moved = np.nanmean((held - P[:, idx]) ** 2, axis=(0, 2))            # cm^2 per coordinate
    P = P.copy()
    P[:, idx] = held
    ek = np.broadcast_to(np.asarray(est["kept"], float), (out.shape[1],)).copy().reshape(-1, 3)
    pts = np.unique(np.concatenate(groups))                             # positions in idx
    e2 = ek[idx[pts]] ** 2
    ek[idx[pts]] = np.sqrt(np.maximum(e2 - np.nan_to_num(moved[pts])[:, None], 0.25 * e2))
    est["kept"] = ek.reshape(-1)
    n = sum(len(g) for g in groups)
    return P.reshape(T, -1), f"{count_text(len(groups), 'rigid group')} held ({n} points)"


def _hold_bones(motion: Motion, out: np.ndarray, usable: np.ndarray,
                err: np.ndarray) -> tuple[np.ndarray, float | None, tuple[np.ndarray, np.ndarray]]:
    """The smoothed (T, 3J) ``out`` with the bones the file format fixes given their length
    back (:func:`mocapkit.rigid.fixed_bones`, :func:`mocapkit.rigid.hold_lengths`); the
    mean squared move per written coordinate (cm^2), None when the format fixes no bone;
    and those bones (B, 2) with their lengths (B,) (bones between usable joints).
    The two-bone spans that stay steady in ``out`` against ``err`` (J,) (the smoothing's
    estimated error per coordinate, cm) are held too (:func:`mocapkit.rigid.steady_spans`).

    Smoothing channel by channel shortens a rotating bone and leaves the noise along it;
    ASF/AMC and BVH fix every bone's length (their writers' IK gives it back on output
    anyway, so the positions auto returns and its estimate now describe what is written).
    Measured on the ``auto`` protocol (CMU / HDM05 AMC, 2026-12-05, same seeds): RMSE
    -9..-24 % per Gaussian / mixed case (60 cases); the AMC writer's full IK (Levenberg-Marquardt on
    every dof, hinge knees and elbows included) gains a few points more but costs 0.5-1 ms
    per frame, about as much as the rest of auto. Only on the smoothing path: measured
    samples of a noise-free clip are exact already.

    Measured and not kept (2026-12-05, same seeds): on the noise-free path, after the
    long-gap fill, moving only the fills (the measured samples held fixed, PBD's zero
    inverse mass). With equal weights 9 of 111 noise-free cases got worse, up to 1.28x: a
    chord fill of a CMU thumb that steps 5 cm inside its hole, pushed onto the bone's
    sphere, lands farther from the step's end, and a poor fill drags a good one (a wrist
    0.01 -> 1.16 cm; a rejected shank filled 34 cm off pulled a good foot fill 8 -> 31 cm
    in 135_04@30 spikes). Second version (the projection :func:`_bone_fill` makes,
    unvalidated): of two fills only the child moves, and a bone is left alone where its length is off by more than 5 x the fills'
    estimated 3-D error (a kept spike, a step, a fill the validation did not see; the
    gain by that ratio, summed over the 112 cases, turned negative above ~10). Mean RMSE
    protocol / held-out, cm: missing30@30 0.238 -> 0.186 / 0.164 -> 0.141, @120 0.041 ->
    0.038 / 0.038 -> 0.035; gaps10x60@30 0.268 -> 0.176 / 0.416 -> 0.362, @120 0.201 ->
    0.186 / 0.144 -> 0.103; spikes@30 0.204 -> 0.197 / 0.120 -> 0.110; 6 of 112 cases
    worse by over 1 %, at most 1.10x (run@120 gaps10x60: an ankle filled 15 cm off,
    projected between the knee's and the foot's spheres); worst missing30 auto / oracle
    0.89 -> 0.85 and 0.94 -> 0.93 (protocol @30 / @120), 0.88 -> 0.82 and 0.98 -> 0.96
    (held-out): the 0.8 target stays out of reach. (For the short holes it is now in the
    code with a per-point validation on hidden samples: :func:`_bone_fill`.) It was not
    kept for the estimate:
    within 1.5x of the true error in 78 of these 112 cases before, 69 with each moved
    fill's estimate scaled by sqrt(1 - k/3) (k bones moved it: one direction of three
    removed per bone), 63 unscaled, 63-64 with the move subtracted sample by sample, 66-68
    with it subtracted class by class (floor 0.25-0.5 of the estimate); on long gaps alone
    (movable = long-gap fills) 15 of 32 against 17. The fills the projection moves most
    are the ones whose validated estimate is small (the validation does not know which
    fill is bad): on dance@30 gaps10x60 the long-gap samples' true MSE fell 1.77 -> 0.76
    cm^2 with a mean squared move of 0.89 against an estimate of 1.84 -- right in sum,
    but subtracted sample by sample (clipped at 0) it removed 4 %. Nor did putting the
    projection inside fill-auto's self-validation (every candidate's fills held, on the
    hidden stretches too, bones more than 50 % off their length left alone), so that the
    estimate measures what is written: on the 31 ten-gap cases mean RMSE 0.228 -> 0.171
    (protocol) and 0.256 -> 0.229 (held-out), but 135_09@120 0.118 -> 0.481 cm, and the
    estimate spread more (RMS log of estimate / true 0.64 -> 0.86; within 1.5x 17 -> 15).
    Bone-holding only matters for AMC/BVH, whose real files have no gaps: their holes are
    rejected spikes.

    The steady two-bone spans (2026-12-05, ninth session; :func:`mocapkit.rigid.steady_spans`,
    held with the bones, then the bones alone). First measured with the span's median in the
    cleaned output as its length, on top of auto's held output (held-out clips through AMC,
    30 fps, geometric mean of RMSE after / before over the ten): chosen where the span's std
    is under k x sqrt(2) x auto's estimate, k = 0.75 / 1 / 1.25: gauss3 -2.4 / -3.3 / -2.5 %,
    gauss1 -2.2 / -1.6 / -0.4 %; in memory (white 3 cm noise) -1.5 %, 2 of 10 clips worse.
    The bound: every span held at its true path -18 %; only the truly steady ones (true std
    < 0.5 cm) at their true length -11 %, at the cleaned median -3.4 % (the median is 0.1-2
    cm short at fingers and thumbs). The noisy spans GCV-smoothed as the target +6.5 %;
    their squares less the noise's 3 sigma^2 +21 %. Kept: the length from the de-biased
    bend (k = 1, the smoothing's own estimate per joint), held in one projection with the
    bones: numbers in docs/results/auto_files.md and the CHANGELOG.
    """
    from ..rigid import fixed_bones, hold_lengths, steady_spans

    T = out.shape[0]
    P = out.reshape(T, -1, 3)
    # with the zero-length bones: a BVH joint at OFFSET 0 0 0 (CMU's LHipJoint, lowerback,
    # LeftCollar ...; the writer's ``<child>_base``) is its parent's point in the file, and
    # left out of the sweeps its own child's bone pulled it off (CMU 49_19 through BVH at
    # 120 fps, 3 cm noise: the lower neck's base 2.6 cm off the thorax). Held to length 0
    # (both ends meet), measured against leaving them out (2026-12-05, twelfth session;
    # held-out 01_01 / 131_08 / 05_07 through BVH files at 30 and 120 fps, sum of six
    # cases' RMSE as written): gauss3 5.39 -> 4.97 cm, spikes 3.30 -> 3.64 (spikes spread
    # by the writer's IK over a frame: 6-16 % worse per case). Also measured and not kept:
    # the bones below such a joint hung from its parent (the spans run through it): gauss3
    # 5.20, spikes 3.83; with it a last parent-first pass putting each joint at its exact
    # length from where its parent was put (the output exactly what the file holds): gauss3
    # 5.20 -> 4.95 without that pass -- it crumples the chain as the writer's closed-form
    # IK did
    bones, lengths = fixed_bones(motion, P, zero_length=True)
    if not len(bones):
        return out, None, (bones, lengths)
    spans, span_len = steady_spans(P, bones, lengths, err)   # (one with a missing sample is not)
    if len(spans):
        # the spans with the bones, then the bones alone: the format fixes those exactly,
        # and the sweeps over both leave a bone up to ~0.2 cm off (six more over the bones:
        # 0.09 cm on CMU 131_08 at 30 fps with 3 cm noise through AMC; the AMC and BVH
        # writers give the exact lengths back)
        P = hold_lengths(P, np.concatenate([bones, spans]), np.concatenate([lengths, span_len]),
                         sweeps=SPAN_SWEEPS)
    held = hold_lengths(P, bones, lengths, sweeps=6 if len(spans) else 10).reshape(T, -1)
    cols = np.repeat(usable, 3)
    d = (held - out)[:, cols]
    fin = np.isfinite(d)
    both = usable[bones[:, 0]] & usable[bones[:, 1]]
    return held, (float(np.mean(d[fin] ** 2)) if fin.any() else None), (bones[both], lengths[both])


#: sweeps of :func:`_hold_bones`' projection onto the bones and the steady spans together
#: (before six over the bones alone): 5 against 10 on the held-out clips at 30 fps, AMC
#: gauss3 / in-memory gauss1 RMSE +0.3 / -0.04 % (each clip within 0.99-1.01x), and the
#: spans' cost on a 240-frame clip ~10 -> ~3 % of auto's time (2026-12-05, ninth session)
SPAN_SWEEPS = 5

#: a written bone further than this (cm) off its fixed length is reported
#: (``source['auto']['bones_off']``, one CLI line): a fill no validation saw go wrong
BONE_OFF_CM = 5.0


def _bone_bound(motion: Motion, out: np.ndarray, usable: np.ndarray,
                filled: np.ndarray) -> tuple[float | None, dict | None]:
    """A floor (cm RMS per coordinate over the written samples) under the error of the
    (T, 3J) ``out``, from the bones the file format fixes (:func:`mocapkit.rigid.fixed_bones`),
    and the bones written more than :data:`BONE_OFF_CM` off their length (frames, the
    worst: cm, frame, joint); (None, None) where the format fixes no bone. ``filled``
    (T, J): the samples auto wrote in place of a missing or rejected one (the rest are kept
    as measured).

    The truth holds every such bone at its length L, so a written bone of length d puts
    its two ends' errors at e_c + e_p >= |d - L| = v. Per frame the larger of two floors
    on the squared error is counted:

    * each filled sample, the largest v of its bones whose other end is kept as measured
      (that end taken as exact: this path runs on noise-free samples, the smoothing path
      gives every bone its length back, v ~ 0), or, between a kept parent and a kept
      child, its distance to the circle where the two bones' spheres meet (at least
      either v) -- distinct samples, so they add up;
    * the frame's worst bone, v^2 / 2 (e_c^2 + e_p^2 >= v^2 / 2, whatever the ends).

    No assumption about the fills: fills the validation vouched for but that put the
    ankle-to-foot bone 26 cm too long (135_04@30 with 10 % spikes: a kick's apex rejected
    and filled from the frames around it, the ankle 33 cm off, the validated estimate
    0.05 cm) raise the estimate to
    what the output itself shows. Measured on the auto protocol / held-out clips
    (2026-12-05): estimates within 1.5x of the true error 95 -> 99 of 114 and 98 -> 99 of
    117 (the circle: one of them); the 11 estimates it moves all move towards their true
    error, none past it.
    """
    from ..rigid import bone_chains, bone_lengths, fixed_bones, sphere_circle

    T = out.shape[0]
    P = out.reshape(T, -1, 3)
    bones, lengths = fixed_bones(motion, P)
    n = int(np.count_nonzero(np.isfinite(out[:, np.repeat(usable, 3)])))
    if not len(bones) or n == 0:
        return None, None
    c, p = bones[:, 0], bones[:, 1]
    v = np.abs(bone_lengths(P, bones) - lengths)                        # (T, B)
    v = np.where(np.isfinite(v), v, 0.0)
    t, b = np.unravel_index(int(np.argmax(v)), v.shape)
    off = None
    if v[t, b] > BONE_OFF_CM:
        off = {"frames": int(np.count_nonzero((v > BONE_OFF_CM).any(axis=1))), "worst_cm": float(v[t, b]),
               "frame": int(t), "joint": motion.skeleton.names[int(c[b])]}
    worst = v.max(axis=1) ** 2 / 2.0
    # per filled joint: the largest v of a bone whose other end is kept (T, J)
    lb = np.zeros(P.shape[:2])
    np.maximum.at(lb.T, c, np.where(filled[:, c] & ~filled[:, p], v, 0.0).T)
    np.maximum.at(lb.T, p, np.where(filled[:, p] & ~filled[:, c], v, 0.0).T)
    # a fill between a kept parent and a kept child: the truth is on the circle where the
    # two bones' spheres meet, and the distance to that circle is at least either v
    # (pa -> j -> ch: triples of two fixed bones, all frames at once)
    k1, k2 = bone_chains(bones)
    if len(k2):
        pa, j, ch = p[k1], p[k2], c[k2]
        rows = filled[:, j] & ~filled[:, pa] & ~filled[:, ch]          # (T, K)
        if rows.any():
            f, k = np.nonzero(rows)                                      # frame, triple
            u, a0, R, ok = sphere_circle(P[f, pa[k]], P[f, ch[k]], lengths[k1][k], lengths[k2][k])
            x = P[f, j[k]] - P[f, pa[k]]
            a = np.einsum("ij,ij->i", x, u)
            r = np.linalg.norm(x - a[:, None] * u, axis=1)
            dist = np.nan_to_num(np.where(ok, np.hypot(a - a0, r - R), 0.0))
            np.maximum.at(lb, (f, j[k]), dist)
    return float(np.sqrt(np.maximum((lb ** 2).sum(axis=1), worst).sum() / n)), off


#: the gap report's name for auto's own fills of short gaps (spline, partner-relative,
#: low-rank and bone steps)
SHORT_FILL = "auto short-gap fill"


def _fill_codes(short: np.ndarray, fa: dict | None, out: np.ndarray) -> dict | None:
    """``source['fill_codes']`` (which fill wrote each missing sample, for the gap report,
    :func:`mocapkit.gaps.apply_policy`): fill-auto's candidates on the long gaps it filled,
    :data:`SHORT_FILL` on the short gaps; None when nothing was missing. ``short`` (T, 3J)."""
    T = out.shape[0]
    wrote = np.isfinite(out).reshape(T, -1, 3).all(axis=2)
    sh = short[:, ::3] & wrote
    fac = None if fa is None else fa.get("codes")
    if not sh.any() and fac is None:
        return None
    names = list(fac["names"]) if fac is not None else []
    codes = np.array(fac["codes"], dtype=np.int8) if fac is not None else np.full(sh.shape, -1, np.int8)
    codes[sh] = len(names)
    return {"names": names + [SHORT_FILL], "codes": codes}


def _how(smooth: bool, holes: bool, long: bool, unseen: str | None = None) -> str:
    """How the estimate was made, part by part (``unseen``: what it cannot see)."""
    parts = ["noise x sqrt(the smoother's degrees of freedom per sample, by Monte-Carlo SURE)" if smooth
             else "noise estimate (samples kept as measured)"]
    if holes:
        parts.append("spline on trusted stretches hidden next to each hole")
    if long:
        parts.append("fill-auto self-validation of the fill behind each frame")
    if unseen:
        parts.append(unseen)
    return ", ".join(parts)


#: rigid distances whose spread (:func:`mocapkit.rigid.distance_noise`, cm) is under this
#: are a skeleton's fixed bones: the report says that the kept samples' joint-angle
#: jitter is not measured (:meth:`Auto._denoise`)
FIXED_BONES_CM = 1e-3


#: :func:`whole_body_jumps`: a frame-to-frame step of the whole body (the 20th percentile
#: over the points seen in both frames) larger than this many times the steps before it and
#: the steps after it, and than
#: :data:`JUMP_MIN_CM`, is a discontinuity -- an edit point, two takes in one file, a loop
#: seam -- not motion: a spike moves one point, and the step of even a sprint at 30 fps
#: (about 27 cm) is matched by the steps beside it
JUMP_RATIO = 8.0
JUMP_MIN_CM = 5.0


def whole_body_jumps(motion: Motion) -> list[int]:
    """Frames where the whole body jumps (the first frame after each jump; see
    :data:`JUMP_RATIO`). auto cleans each side on its own: smoothing, fills and the noise
    estimate across such a jump mix two motions -- a CMU walk tiled 4 times with 1 cm of
    noise came back 5.6 cm off (0.22 cm for the clip alone), its estimate 0.65 cm."""
    P, obs = motion.positions, motion.observed
    T, J = obs.shape
    if T < 6 or J < 3:
        return []
    step = _body_step(P, obs, np.arange(T - 1), np.arange(1, T))
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)          # frames with no point seen twice
        # against both sides: the larger of the two steps' mean before and after (a jump
        # stands out from both; a landing at 30 fps -- 6.7 cm a frame, then 0.4 -- does not
        # stand out from the steps before it)
        pad = np.concatenate([[np.nan] * 2, step, [np.nan] * 2])
        before = np.nanmean(np.stack([pad[:-4], pad[1:-3]]), axis=0)
        after = np.nanmean(np.stack([pad[3:-1], pad[4:]]), axis=0)
        around = np.fmax(before, after)
        jump = (step > JUMP_MIN_CM) & (step > JUMP_RATIO * around)
        cand = np.flatnonzero(jump)
        if len(cand):
            # a jump stays: the body does not come back within a frame or two, as it does
            # after a whole-body spike -- in a rotation file a spike on the root moves every
            # joint, and the writer's IK pulls some back, so the step into the spike can read
            # small and the step out alone stands out (CMU 131_01 in cgspeed's BVH with 10 %
            # spikes: two false jumps, one four frames from the end)
            jump[cand[_comes_back(P, obs, cand, step[cand])]] = False
    return [int(t) + 1 for t in np.flatnonzero(jump)]


def _body_step(P: np.ndarray, obs: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n,) how far the whole body is between frames ``a`` and ``b`` (n,): the 20th
    percentile of the distances of the points seen in both (cm); NaN where fewer than
    max(3, J / 2) are. A low quantile over the points, not their median: every point moves
    in a jump, while spikes (10 % of the samples: 16 of 31 points were off in one step of
    CMU 131_01 at 120 fps) or holes can take half of a step's points. (The k-th smallest
    of each row, NaN sorted last: np.nanpercentile took 0.3 s on 10,000 frames, a tenth
    of auto's time.)"""
    J = obs.shape[1]
    both = obs[a] & obs[b]                                                  # (n, J)
    with np.errstate(invalid="ignore"):
        srt = np.sort(np.where(both, np.linalg.norm(P[b] - P[a], axis=2), np.nan), axis=1)
    n_ok = both.sum(axis=1)
    q = np.take_along_axis(srt, np.maximum((0.2 * (n_ok - 1)).astype(int), 0)[:, None], axis=1)[:, 0]
    return np.where(n_ok >= max(3, J // 2), q, np.nan)


def _comes_back(P: np.ndarray, obs: np.ndarray, steps: np.ndarray, size: np.ndarray) -> np.ndarray:
    """(len(steps),) True where the body, across the step from frame t to t + 1 (``steps``:
    t), is back within half the step's ``size`` (cm) two or three frames apart -- frames
    (t - 1, t + 1), (t, t + 2), (t - 2, t + 1), (t - 1, t + 2), (t, t + 3): an excursion of
    one or two frames, not a jump. A jump that :func:`whole_body_jumps` flags stands out 8 times
    from the steps beside it, so three frames of motion take at most 3/8 of it back."""
    T = obs.shape[0]
    back = np.zeros(len(steps), bool)
    for da, db in ((-1, 1), (0, 2), (-2, 1), (-1, 2), (0, 3)):
        a, b = steps + da, steps + db
        ok = (a >= 0) & (b < T)
        with np.errstate(invalid="ignore"):                 # NaN: too few points seen in both
            back |= ok & (_body_step(P, obs, np.clip(a, 0, T - 1), np.clip(b, 0, T - 1)) < 0.5 * size)
    return back


def _piece_cuts(observed: np.ndarray, piece: int, ov: int) -> list[int]:
    """Frames where a long clip is cut into pieces of about ``piece`` frames: each cut is
    moved (by up to an eighth of a piece, so pieces stay over ``2 ov`` frames) to where
    the fewest samples are missing within ``ov`` frames of it, the nearest such frame
    first, so that a gap seldom spans an overlap (a piece would see it as a gap at its
    end, which its fills extrapolate or leave to the spline)."""
    T = observed.shape[0]
    n = max(1, int(round(T / piece)))
    miss = np.concatenate([[0], np.cumsum((~observed).sum(axis=1))])
    cuts = []
    for k in range(1, n):
        c0 = round(k * T / n)
        c = np.arange(max(ov + 1, c0 - piece // 8), min(T - ov - 1, c0 + piece // 8) + 1)
        cost = miss[c + ov] - miss[c - ov]
        cuts.append(int(c[np.argmin(np.abs(c - c0) + cost.astype(float) * T)]))   # fewest missing, then nearest
    return cuts


def _leave_unvalidated(out: np.ndarray, short: np.ndarray, hole, limit: float) -> np.ndarray:
    """``out`` with the short holes whose hole-by-hole validated error (``hole``: (C,) or
    (T, C), cm per coordinate) exceeds ``limit`` set to NaN, the whole point at once -- the
    same rule as fill-auto's for long gaps, so that no fill auto writes was validated worse
    than that. On the auto protocol, the held-out clips and real_gaps (2026-12-05) no short
    hole validated above 5 cm, so nothing there changed; the gross fills of real_gaps'
    CMU 135_04 / Eb015pr case came from a long gap (see :data:`FILL_CANDIDATES`)."""
    T, C = out.shape
    for sl in frame_blocks(T):
        bad = short[sl] & (np.broadcast_to(_rows(hole, sl), short[sl].shape) > limit)
        if bad.any():
            bad = np.repeat(bad.reshape(bad.shape[0], -1, 3).any(axis=2), 3, axis=1)
            out[sl][bad] = np.nan
    return out


def _combine(est: dict, holes: np.ndarray, long: np.ndarray, e_long: np.ndarray | None,
             usable: np.ndarray, out: np.ndarray, per_point: bool = False):
    """Sample-weighted RMS of the per-class estimates over the samples written (cm): what
    is left missing (NaN in ``out``: long gaps fill-auto left, holes no fill validated) is
    not counted. ``per_point``: also the (T, J) map of each point sample's squared estimate
    (cm^2, the mean of its coordinates'; NaN where nothing is charged), for
    :meth:`Auto._after_policy`."""
    cols = np.repeat(usable, 3)
    T = holes.shape[0]
    total, count = 0.0, 0
    pmap = np.full((T, len(usable)), np.nan, np.float32) if per_point else None
    for sl in frame_blocks(T):                     # blocks of frames: no (T, 3J) temporaries
        h, lg = holes[sl], long[sl]
        e_l = e_long[sl] if e_long is not None else np.full(h.shape, np.nan)
        hole2 = np.broadcast_to(_rows(est["hole"], sl) ** 2 * est.get("match", 1.0) ** 2, h.shape)
        e_l2 = np.where(np.isfinite(e_l), e_l ** 2, np.nan)
        kept2 = _rows(est["kept"], sl) ** 2 + _rows(est.get("kept_extra", 0.0), sl)
        sq = np.where(~h, kept2, np.where(h & ~lg, hole2, e_l2))
        sq = np.where(np.isnan(out[sl]), np.nan, sq)            # left missing: not charged
        if per_point:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)      # all-NaN points
                pmap[sl][:, usable] = np.nanmean(sq.reshape(len(sq), -1, 3), axis=2)[:, usable]
        sq = sq[:, cols]
        fin = np.isfinite(sq)
        total += float(sq[fin].sum())
        count += int(fin.sum())
    value = float(np.sqrt(total / count)) if count else None
    return (value, pmap) if per_point else value


def _left_missing(out: np.ndarray, usable: np.ndarray) -> int:
    """Point samples (frames x points) of the points that have data, left missing (NaN) in
    the (T, 3J) result: gaps and holes no fill validated under ``max_fill_error_cm``."""
    return int(np.count_nonzero(np.isnan(out[:, ::3][:, usable])))


def _rows(v, sl: slice):
    """Rows ``sl`` of a per-sample (T, C) estimate; a per-channel (C,) one or a scalar as is."""
    return v[sl] if np.ndim(v) == 2 else v
