"""Example-based robust filter bases: ``lou-chai`` (Lou & Chai 2010, seed 001).

The maths (M-SSA bases, Welsch robust objective, alternating coefficient / IRLS motion
updates, missing data) lives in :mod:`mocapkit.solvers.robust_bases`; this module turns
motions into the (T, L) arrays it works on and back.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import numpy as np

from .. import signal
from ..errors import MocapValueError
from ..frames import MARKER_ORIGIN, Frame, check_marker_origin, frame_in_place, heading_frame, mirror_local, mirror_permutation, up_axis_of
from ..motion import Motion
from ..signal._arrays import nanmedian0
from ..solvers import robust_bases as rb
from ..solvers.evidence import evidence_blend
from .base import Denoiser, check_trained_joints, register, report_convergence
from .constraints import Integral, Interval, Options, Real, center_as_string

_POSITIVE = Interval(Real, 0, None, closed="neither")

__all__ = ["LouChai", "angle_channels", "angle_fk", "decimate", "reference_as_read", "reference_frames",
           "reference_words"]

REFERENCE_HEIGHT_CM = 170.0
"""Body-frame positions are scaled to a person of this skeleton height (``normalize``)."""


# ---------------------------------------------------------------------------------------
# helpers usable by protocols
# ---------------------------------------------------------------------------------------
def decimate(motion: Motion, factor: int, phase: int = 0) -> Motion:
    """Every ``factor``-th frame starting at ``phase`` (fps / factor), keeping the
    per-frame reader data (``source['per_frame']``) aligned -- unlike
    :meth:`Motion.resample`, which drops it. 120 -> 30 fps is ``decimate(m, 4)``, the
    paper's down-sampling (Sec. 4)."""
    factor, phase = int(factor), int(phase)
    if factor < 1 or not 0 <= phase < factor:
        raise MocapValueError(f"decimate: need factor >= 1 and 0 <= phase < factor, got {factor}, {phase}")
    if factor == 1:
        return motion
    if phase >= motion.n_frames:
        raise MocapValueError(f"decimate: phase {phase} beyond a {motion.n_frames}-frame clip")
    src = dict(motion.source)
    if "per_frame" in src:
        src["per_frame"] = {k: np.asarray(v)[phase::factor] for k, v in src["per_frame"].items()}
    src["decimated_from_fps"] = motion.fps
    return Motion(motion.positions[phase::factor], motion.skeleton, motion.fps / factor,
                  motion.observed[phase::factor], src)


def angle_channels(motion: Motion) -> tuple[np.ndarray, list[str], dict[str, Any]]:
    """Joint-angle channels of a motion read from AMC or BVH.

    Returns (values (T, C) in file units -- degrees or radians, and file length units for
    root translations --, channel names, info) where info holds ``key`` (the
    ``source['per_frame']`` key: ``'dofs'`` for AMC, ``'channels'`` for BVH),
    ``rotation`` (bool (C,), rotation channels), ``period`` (360 or 2 pi) and ``root``
    (bool (C,), channels of the root node).
    """
    src = motion.source
    fmt = src.get("format")
    pf = src.get("per_frame", {})
    if fmt in ("amc", "asf") and "dofs" in pf:
        vals = np.asarray(pf["dofs"], dtype=float)
        names = [str(n) for n in src.get("dof_names", [])]
        rad = src.get("amc", {}).get("angle") == "rad"
        rot = np.array([n.split(".")[-1].upper().startswith("R") for n in names])
        root = np.array([n.split(".")[0] == "root" for n in names])
        key = "dofs"
    elif fmt == "bvh" and "channels" in pf:
        vals = np.asarray(pf["channels"], dtype=float)
        nodes = src["bvh"]["nodes"]
        names, rot, root = [], [], []
        for nd in nodes:
            for ch in nd["channels"]:
                names.append(f"{nd['name']}.{ch}")
                rot.append(ch.lower().endswith("rotation"))
                root.append(int(nd["parent"]) < 0)
        rot, root = np.array(rot, bool), np.array(root, bool)
        rad = False
        key = "channels"
    else:
        raise MocapValueError(
            "lou-chai: space='angle' needs a motion read from AMC or BVH that still carries its "
            "joint-angle channels (source['per_frame']); this one has none (resampling or "
            "selecting joints drops them) -- use space='position'")
    if vals.ndim != 2 or vals.shape[0] != motion.n_frames or len(names) != vals.shape[1]:
        raise MocapValueError("lou-chai: the motion's joint-angle channels do not match its frames")
    return vals, names, {"key": key, "rotation": rot, "root": root, "names": names,
                         "period": 2 * np.pi if rad else 360.0}


#: :func:`reference_frames`: a joint-angle channel is "set" where it is more than this far
#: from zero (degrees; a radian file's channels are compared in degrees too)
REFERENCE_TOL_DEG = 1e-3


def reference_frames(motion: Motion) -> int:
    """How many leading frames of ``motion`` are its file's reference pose: the T-pose
    that MotionBuilder-style and Daz BVH conversions put before the motion, and the
    converter's blend out of it (0 where the file has none; see :func:`_blend_frames`). The
    T-pose is frame 0 where either
    its non-root joint rotations are almost all exactly zero where the next frame's are
    not (cgspeed's MotionBuilder-friendly CMU 01_01: 4 of 90 rotation channels set, 70 in
    frame 1; a captured or solved frame never has its angles at exactly zero), or it is
    the skeleton's rest pose up to a rigid move, within :data:`REFERENCE_REST_CM`, and the
    next frame is over 4 times further from it (the Daz conversions: 1.6-2.3 cm, frame 1
    11-14 cm). No other shared file has one (174 AMC files, the other 6 BVH). Needs the
    reader's joint-angle channels (AMC / BVH, kept by ``slice``; dropped by
    ``resample``); 0 otherwise.

    It is no capture: every method sees the motion's first frame in its place and writes
    it back as read (the shared guard, :mod:`mocapkit.denoise.base`), and
    :func:`mocapkit.corrupt.combine` leaves it alone -- smoothed or despiked, a T-pose
    first frame had been pulled into the motion (arms 65 cm off on cgspeed's 01_01 with
    spikes) and the motion towards it.

    >>> from mocapkit import io
    >>> from mocapkit.datasets import bundled
    >>> reference_frames(io.read(bundled("16_15.amc")))     # a capture from its first frame
    0
    """
    src = motion.source
    pf = src.get("per_frame") or {}
    if motion.n_frames < 3 or not (("dofs" in pf and src.get("format") in ("amc", "asf"))
                                   or ("channels" in pf and src.get("format") == "bvh")):
        return 0
    try:
        vals, _, info = angle_channels(motion)
    except MocapValueError:
        return 0
    rot = info["rotation"] & ~info["root"]
    scale = 360.0 / info["period"]                                  # to degrees
    set0 = int((np.abs(vals[0, rot]) * scale > REFERENCE_TOL_DEG).sum())
    set1 = int((np.abs(vals[1, rot]) * scale > REFERENCE_TOL_DEG).sum())
    if set1 >= 10 and set0 <= 0.25 * set1:
        return 1 + _blend_frames(motion)
    # or the skeleton's rest pose (up to a rigid move), which the next frame leaves far
    # behind (the Daz conversions' first frame: 1.6-2.3 cm off it, frame 1 11-14 cm)
    R = motion.skeleton.rest_positions()
    r0, r1 = (_rigid_residual(motion.positions[t], R) for t in (0, 1))
    return 1 + _blend_frames(motion) if r0 < REFERENCE_REST_CM and r1 > 4.0 * r0 else 0


def reference_words(n: int) -> str:
    """The frames :func:`reference_frames` found, in words (the CLI's lines)."""
    return ("frame 0 is the file's reference pose (a T-pose)" if n == 1 else
            f"frames 0-{n - 1} are the file's reference pose (a T-pose) and the blend out of it")


#: :func:`_blend_frames`: a frame after the reference pose is the converter's blend where
#: the joints' median step out of it is over this many times the clip's median step
BLEND_RATIO = 2.0

#: :func:`_blend_frames`: the blend lasts at most this long (s)
BLEND_MAX_S = 0.1


def _blend_frames(motion: Motion) -> int:
    """How many frames after a reference pose (frame 0) are the converter's blend out of
    it into the motion: the frames 1, 2, ... whose step to the next frame -- the median
    over the joints seen in both -- is over :data:`BLEND_RATIO` times the clip's median
    step, at most :data:`BLEND_MAX_S`.

    The Daz-friendly CMU conversions ease from the T-pose into the motion over frames 1-4
    (the joint-angle channels 26 / 54 / 79 / 95 % of the way, on 60_09): the joints' median
    step is 14-22 cm per frame there, 3.7-5.8 cm out of frame 4, 0.2-0.8 out of frame 5
    (the clip's median 0.5-1.5 cm, at 120 fps). No capture moves so: cleaned as motion,
    they were taken for spikes and refilled, 8-18 cm RMS off in frames 1-3 on 60_09 with 3
    cm of noise (11 % of the squared error of the whole 2,576 frames). The median over the
    joints holds with 10 % spikes, and 3 cm of noise lifts the clip's median step to about
    7 cm: then frames 1-3 still stand out, frame 4 (5.8 cm) no longer (it is cleaned with
    the motion). cgspeed's MotionBuilder-friendly 01_01 steps 0.0 cm out of frame 1: none."""
    P, obs = motion.positions, motion.observed
    T = P.shape[0]
    cap = min(int(round(BLEND_MAX_S * motion.fps)), T - 3)
    if cap < 1:
        return 0
    both = obs[1:-1] & obs[2:]
    step = nanmedian0(np.where(both, np.linalg.norm(P[2:] - P[1:-1], axis=2), np.nan).T)
    typical = nanmedian0(step[:, None])[0]                # step[i]: frame i + 1 to i + 2
    with np.errstate(invalid="ignore"):
        big = step[:cap] > BLEND_RATIO * typical         # (NaN: no joint seen twice -> no)
    return int(cap if big.all() else np.argmin(big))


#: :func:`reference_frames`: a first frame within this of the rest pose (cm, the largest
#: joint distance after the best rigid fit) may be the file's reference pose
REFERENCE_REST_CM = 5.0


def _rigid_residual(A: np.ndarray, B: np.ndarray) -> float:
    """Largest joint distance (cm) between the points A and B (J, 3) after the best rigid
    fit of A onto B (:func:`mocapkit.rigid.kabsch`); inf where A has a missing point."""
    from ..rigid import apply_rigid, kabsch

    if not np.isfinite(A).all():
        return float("inf")
    R, t = kabsch(A, B)
    return float(np.linalg.norm(apply_rigid(R, t, A) - B, axis=1).max())


def reference_as_read(out: Motion, motion: Motion, n: int) -> Motion:
    """``out`` with its first ``n`` frames as ``motion`` has them (positions, observed,
    filled): the file's reference pose (:func:`reference_frames`), which the shared guard
    writes back after every method and :func:`mocapkit.corrupt.combine` leaves alone."""
    P, obs, filled = out.positions.copy(), out.observed.copy(), out.filled.copy()
    P[:n], obs[:n], filled[:n] = motion.positions[:n], motion.observed[:n], motion.filled[:n]
    return Motion(P, out.skeleton, out.fps, obs, out.source, filled)


def angle_fk(motion: Motion, values: np.ndarray) -> np.ndarray:
    """Joint positions (T, J, 3) cm of ``motion``'s skeleton driven by joint-angle
    channels ``values`` (T, C) (same layout as :func:`angle_channels`), through the
    reader's own forward kinematics.

    Uses the readers' FK internals (``_kinematics._Compiled`` / ``_kinematics.forward_kinematics``,
    ``bvh._meta_to_nodes`` / ``bvh.forward_kinematics``): the readers expose no public
    "FK of new channel values" function yet.
    """
    src = motion.source
    fmt = src.get("format")
    values = np.asarray(values, dtype=float)
    if fmt in ("amc", "asf"):
        from ..io import _kinematics

        comp = _kinematics._Compiled(src["asf"])
        rad = src.get("amc", {}).get("angle") == "rad"
        return _kinematics.forward_kinematics(comp, values, rad, float(src["units"]["cm_per_unit"]))
    if fmt == "bvh":
        from ..io import bvh

        nodes = bvh._meta_to_nodes(src["bvh"]["nodes"])
        X, _ = bvh.forward_kinematics(nodes, values)
        keep = list(src["bvh"]["joint_nodes"])
        return X[:, keep] * float(src["units"]["factor_to_cm"])
    raise MocapValueError(f"lou-chai: no forward kinematics for format {fmt!r}")


def _skeleton_height(motion: Motion, up: int) -> float:
    """Rest-pose extent of the skeleton along the vertical axis (cm); falls back to the
    motion's own height estimate."""
    rest = motion.skeleton.rest_positions()
    h = float(np.ptp(rest[:, up])) if motion.n_joints > 1 else 0.0
    if not (np.isfinite(h) and h > 1.0):
        h = motion.height()
    return h if (np.isfinite(h) and h > 1.0) else REFERENCE_HEIGHT_CM


def _root_euler(motion: Motion, info: dict) -> tuple[list[int], str] | None:
    """Columns of the root's three rotation channels (in the order their angles enter
    the rotation) and the scipy Euler sequence, or None if the root has no 3 rotations."""
    src = motion.source
    names = info["names"]
    if info["key"] == "dofs":                     # AMC: R = product in the ASF root 'axis' order
        axis = str(src["asf"]["root"]["axis"]).upper()
        cols = [names.index(f"root.R{c}") for c in axis if f"root.R{c}" in names]
        return (cols, axis.lower()) if len(cols) == 3 else None    # extrinsic: first axis first
    root = [i for i, (r, rt) in enumerate(zip(info["rotation"], info["root"])) if r and rt]
    if len(root) != 3:
        return None
    seq = "".join(names[i].split(".")[-1][0].upper() for i in root)  # BVH: intrinsic, listed order
    return root, seq


def _smooth_root(motion: Motion, V: np.ndarray, info: dict, median: int = 5, sigma: float = 1.0) -> np.ndarray:
    """Robustly smoothed root channels (decision, angle space): the root's translation
    and orientation are global, so the filter bases do not model them; instead they get
    a running median (``median`` frames) then a Gaussian (``sigma`` frames) -- the
    orientation as sign-continuous unit quaternions (renormalised), converted back to
    the file's Euler channels nearest the input values."""
    from scipy.spatial.transform import Rotation

    T = V.shape[0]
    out = V.copy()
    root, rot = info["root"], info["rotation"]
    med = min(median, T if T % 2 else T - 1)

    def smooth(A):
        if med >= 3:
            A = signal.median(A, window=med)
        return signal.gaussian(A, sigma=sigma) if T >= 2 else A

    tr = root & ~rot
    if tr.any():
        out[:, tr] = smooth(V[:, tr])
    eul = _root_euler(motion, info)
    if eul is not None:
        cols, seq = eul
        deg = info["period"] == 360.0
        q = Rotation.from_euler(seq, V[:, cols], degrees=deg).as_quat()
        flip = np.concatenate([[1.0], np.sign(np.einsum("ti,ti->t", q[1:], q[:-1]))])
        q *= np.cumprod(np.where(flip == 0, 1.0, flip))[:, None]
        q = smooth(q)
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        ang = Rotation.from_quat(q).as_euler(seq, degrees=deg)
        per = info["period"]
        ang = ang + per * np.round((V[:, cols] - ang) / per)       # nearest turn to the input
        out[:, cols] = ang
    return out


# ---------------------------------------------------------------------------------------
@register
class LouChai(Denoiser):
    """Example-based robust filter bases (Lou & Chai 2010, IEEE TVCG 16(5), seed 001).

    Training (Sec. 3.1, eqs. 1-7): per channel lagged windows of M frames, grand
    lag-covariance of all channels over all training clips (eqs. 3-5, accumulated without
    forming the trajectory matrices, :func:`mocapkit.solvers.robust_bases.lag_covariance`),
    eigenvectors = filter bases E; K kept for ``energy`` of the eigenvalue sum (99%) or
    ``n_bases``.

    Denoising (Secs. 3.3-3.5): minimise ``sum alpha rho(z - y) + lam sum_s ||z_s - E c_s||²``
    (eqs. 11/16) with the Welsch rho (eq. 9), alternating c_s = Eᵀ z_s (eq. 13) and a
    per-frame closed-form IRLS weighted average (eqs. 14-15) until the relative cost
    change is below ``tol`` (paper: 10-20 iterations). Missing entries get alpha = 0
    (eq. 16), start from linear interpolation in time (a joint never observed starts at
    the training mean) and are set to their exact minimiser of the cost (conjugate
    gradients) before and after the alternation (``fill_iter``; the plain alternation
    moves long gaps very slowly).  In frames with few observed markers the fill then moves
    to the linear interpolation (:func:`mocapkit.solvers.evidence.evidence_blend`; on a
    95 %-missing clip the body frame itself is a guess and the fill was 18 cm off where
    interpolation was 8 cm off). See :mod:`mocapkit.solvers.robust_bases` (which also
    explains the factor ½ of eq. 15).

    Representation (decisions; METHODS.md Sec. 1):

    * ``space='position'`` (default): joint positions in the body-centred frame
      (:func:`mocapkit.frames.heading_frame`: smoothed root subtracted, smoothed heading from the
      hips rotated out; ``frame='global'`` skips it -- measured useless), scaled to a
      170 cm skeleton (``normalize``), so that the clips of different subjects share one
      model (the paper's "large walking database" setting; one model per skeleton would
      leave too little data), and centred by the training mean (``center``; otherwise
      the mean pose dominates the energy and 99% keeps almost nothing of the motion).
      The transform is estimated from the noisy input itself and inverted exactly, so
      the output keeps the input's path and heading. ``mirror=True`` also trains on the
      left/right mirror image of every clip (joints paired by name; not in the paper).
    * ``space='angle'``: the joint-angle channels of AMC (``source['per_frame']['dofs']``)
      or BVH (``['channels']``) input, in the file's unit (degrees), unwrapped. The bases
      model the non-root rotation channels (local, so independent of where the body is
      and where it faces). The root's translation and orientation are global and not
      modelled: they get a robust smoother (running median of 5 frames then Gaussian of
      sigma 1 frame; orientation as unit quaternions, so Euler flips do not matter).
      Positions then come from the reader's forward kinematics, and the output carries
      the denoised channels in ``source['per_frame']`` (same turn as the input values),
      so writing it back keeps them. Needs a complete motion.

    Units of ``p``: the paper sets p = 3 for joint angles in degrees and leaves position
    units unstated. Decision: ``p`` is in degrees in angle space and in cm in position
    space (cm of the 170 cm reference body: it scales with the skeleton like the data).
    3 cm is about 1.5-3x typical marker noise (1-2 cm): noise keeps weights near 1, a
    15 cm spike gets weight exp(-25) ~ 0. ``lam`` has no unit (near 0 the data term is
    r²/2 in the same unit as the bases term).

    Data rate (decision): the bases are learned at ``fps`` (default 30, the paper's
    rate: Sec. 4 down-samples 120 -> 30 fps; M = 20 frames = 0.67 s). A clip whose
    rate is an integer multiple r of ``fps`` (120 = 4 x 30) is split into its r
    interleaved phases (frames t, t+r, t+2r, ...), each a genuine ``fps`` clip, which are
    filtered separately and interleaved again -- no interpolation, every input sample is
    used, and training clips contribute all r phases. Other rates are resampled to
    ``fps`` (cubic spline) and the result is interpolated back (position space only).
    ``fps=None`` uses the training clips' own rate as is (M then counts those frames).
    A clip shorter than M frames is padded with missing frames.

    Parameters
    ----------
    window : M, frames at ``fps`` (paper: 20).
    energy : eigenvalue fraction kept (paper: 0.99).
    n_bases : fixed K instead of ``energy``.
    lam : weight of the bases term (paper: 0.1; exact objective, see above).
    p : Welsch scale (paper: 3), cm or degrees (above); ``float('inf')`` = least squares.
    max_iter, tol : outer iterations (paper: 10-20) and relative cost change to stop.
        ``denoise`` records ``source["convergence"]`` on its result. The paper runs a fixed 10-20 iterations and
        that early stop is part of the method: on the bundled CMU clips (1 cm noise, 5 %
        missing) the defaults stop at a relative change of J of 3e-3..1e-2, tol 1e-4 is
        reached only after ~210-330 iterations (docs/results/reliability.md), and running
        that far *raises* the error (16_15 trained on three other clips: 3.57 cm at 20
        iterations, 3.96 at 50, 4.92 at 400; 07_05 trained on its first half: 3.20 / 3.60
        / 5.05 cm). Hence no warning by default.
    warn_convergence : emit a ConvergenceWarning when an outer loop hits ``max_iter``
        before ``tol`` (off by default, see above).
    space : ``'position'`` or ``'angle'``.
    fps : working frame rate of the bases (above).
    frame : ``'body'`` or ``'global'`` (position space).
    smooth_s : time scale (s) of the body-frame smoothing (0.5).
    normalize : scale body-frame positions by 170 cm / skeleton height.
    center : ``'mean'`` (default) subtracts the training mean of each channel, ``'none'``
        does not (the spelling of the low-rank family's ``center``; model files that
        stored ``True`` / ``False`` load as ``'mean'`` / ``'none'``).
    mirror : also train on mirrored clips (position space).
    method : ``'auto'`` | ``'direct'`` | ``'fft'`` | ``'fft32'`` implementation of the
        coefficient and overlap-add step (the same map;
        :class:`~mocapkit.solvers.robust_bases.WindowProjector`).

    Measured (docs/results/lou_chai.md): with these paper settings the bases keep ~66
    components for walking and filter worse than a tuned Kalman filter on unseen
    subjects; ``energy=0.999, mirror=True, lam=0.2`` is our better setting for noise and
    outliers, while the paper's 99% fills whole missing limbs better.

    Fitted attributes: ``bases_`` (M*L, K), ``eigvals_`` (M*L,), ``mean_`` (L,),
    ``window_``, ``fps_`` (0 = input rate), ``space_``, ``up_axis_``, ``joint_names_``,
    ``channel_names_`` (angle space), ``n_windows_``, ``n_frames_``.
    """

    name = "lou-chai"
    fill_evidence = "markers"
    description = ("Lou & Chai 2010 example-based robust filter bases (M-SSA bases learned from clean "
                   "clips + Welsch IRLS; fills gaps)")
    needs_training = True
    misfit_check = "learned"
    keeps_observed = False
    #: trained on 2 s of one walk (quick_params), a clean continuation of it comes back
    #: within 0.8 cm RMSE (CMU 16_15): the bases term projects out what the few training
    #: windows did not contain
    clean_tolerance_cm = 1.5
    _parameter_constraints = {
        "window": [Interval(Integral, 1, None)], "energy": [Interval(Real, 0, 1, closed="right")],
        "n_bases": [Interval(Integral, 1, None), None], "lam": [_POSITIVE], "p": [_POSITIVE],
        "max_iter": [Interval(Integral, 1, None)], "tol": [Interval(Real, 0, None)],
        "space": [Options("position", "angle")], "fps": [_POSITIVE, None],
        "frame": [Options("body", "global")], "smooth_s": [Interval(Real, 0, None)],
        "normalize": [bool], "center": [Options("mean", "none")], "mirror": [bool],
        "method": [Options("auto", "direct", "fft", "fft32")], "warn_convergence": [bool]}

    @classmethod
    def _upgrade_params(cls, params: dict[str, Any]) -> dict[str, Any]:
        """``center`` was a bool before it took the low-rank family's spelling."""
        return center_as_string(params)

    def __init__(self, window: int = 20, energy: float = 0.99, n_bases: int | None = None,
                 lam: float = 0.1, p: float = 3.0, max_iter: int = 20, tol: float = 1e-4,
                 space: str = "position", fps: float | None = 30.0, frame: str = "body",
                 smooth_s: float = 0.5, normalize: bool = True, center: str = "mean",
                 mirror: bool = False, method: str = "auto", warn_convergence: bool = False):
        self._store_params(locals())

    @classmethod
    def quick_params(cls) -> dict[str, Any]:
        return {"window": 10, "max_iter": 10}

    # -- rate handling -------------------------------------------------------------------
    @staticmethod
    def _ratio(fps_in: float, fps_model: float) -> int | None:
        """Integer r with fps_in = r * fps_model, else None."""
        r = fps_in / fps_model
        ri = int(round(r))
        return ri if ri >= 1 and abs(r - ri) <= 1e-3 * max(r, 1.0) else None

    def _phases(self, motion: Motion, model_fps: float) -> list[Motion] | None:
        n = self._n_phases(motion, model_fps)
        return None if n is None else [decimate(motion, n, k) for k in range(n)]

    def _n_phases(self, motion: Motion, model_fps: float) -> int | None:
        """Number of interleaved phases of ``motion`` at the model rate (None: not a multiple)."""
        r = self._ratio(motion.fps, model_fps)
        return None if r is None else min(r, motion.n_frames)

    # -- representation ------------------------------------------------------------------------
    def _to_array(self, motion: Motion, up: int):
        """(Y (T, L) uncentred, mask (T, L), context for :meth:`_from_array`)."""
        if self.space == "position":
            if self.frame == "body":
                tr = heading_frame(motion, smooth_s=float(self.smooth_s), up_axis=up)
            else:
                tr = Frame.identity(np.zeros((motion.n_frames, 3)))
            s = REFERENCE_HEIGHT_CM / _skeleton_height(motion, up) if self.normalize else 1.0
            # a copy of the positions transformed and scaled in place (issue 21: no
            # whole-clip temporaries; the same element operations)
            local = frame_in_place(tr, np.array(motion.positions, dtype=float), "local")
            local *= s
            return (local.reshape(motion.n_frames, -1), motion.matrix_mask(), (tr, s))
        vals, names, info = angle_channels(motion)
        if not motion.observed.all():
            raise MocapValueError("lou-chai: space='angle' needs a complete motion (joint angles "
                                  "have no missing-data mask); use space='position' for gaps")
        V = vals.copy()
        rot = info["rotation"]
        V[:, rot] = np.unwrap(V[:, rot], axis=0, period=info["period"])
        joint = rot & ~info["root"]
        return V[:, joint], np.ones((len(V), int(joint.sum())), dtype=bool), (vals, V, names, info, joint)

    def _from_array(self, motion: Motion, Z: np.ndarray, ctx) -> Motion:
        if self.space == "position":
            tr, s = ctx                              # Z is ours (_solve): changed in place
            P = Z.reshape(motion.n_frames, -1, 3)
            P /= s
            return motion.with_positions(frame_in_place(tr, P, "world"), handover=True)
        raw, V, names, info, joint = ctx
        out_v = V.copy()
        out_v[:, joint] = Z
        root = info["root"]
        if root.any():
            out_v[:, root] = _smooth_root(motion, V, info)[:, root]
        # rotations back to the turn of the input values (file range; FK is unchanged)
        rot, per = info["rotation"], info["period"]
        d = out_v[:, rot] - raw[:, rot]
        out_v[:, rot] = raw[:, rot] + (d - per * np.round(d / per))
        P = angle_fk(motion, out_v)
        out = motion.with_positions(P)
        pf = dict(out.source.get("per_frame", {}))
        pf[info["key"]] = out_v
        return out.with_source(per_frame=pf)

    # -- training ----------------------------------------------------------------------------
    def fit(self, motions: Sequence[Motion]) -> "LouChai":
        motions = list(motions)
        if not motions:
            raise MocapValueError("lou-chai: fit() needs at least one clean training motion")
        first = motions[0]
        for m in motions:
            if not isinstance(m, Motion):
                raise MocapValueError(f"lou-chai: fit() takes Motion objects, got {type(m).__name__}")
            if m.skeleton.names != first.skeleton.names:
                raise MocapValueError(
                    "lou-chai: training motions must share the joint names "
                    f"({first.n_joints} joints {', '.join(first.skeleton.names[:3])}, ... vs "
                    f"{m.n_joints} joints {', '.join(m.skeleton.names[:3])}, ...)")
            if not m.observed.all():
                raise MocapValueError(f"lou-chai: training motion {m!r} has missing entries; fill them first")
        model_fps = float(self.fps) if self.fps is not None else float(first.fps)
        if self.fps is None and any(not np.isclose(m.fps, first.fps) for m in motions):
            raise MocapValueError("lou-chai: with fps=None all training motions need one frame rate")
        up = up_axis_of(np.concatenate([m.positions[:: max(1, m.n_frames // 200)] for m in motions]))
        arrays, channel_names = [], None
        for m in motions:
            parts = self._phases(m, model_fps)
            if parts is None:
                if self.space == "angle":
                    raise MocapValueError(
                        f"lou-chai: space='angle' needs training clips at a multiple of {model_fps:g} fps "
                        f"(got {m.fps:g})")
                parts = [m.resample(model_fps)]
            for part in parts:
                Y, _, ctx = self._to_array(part, up)
                if self.space == "angle":
                    names = ctx[2]
                    if channel_names is None:
                        channel_names = names
                    elif names != channel_names:
                        raise MocapValueError("lou-chai: training motions have different joint-angle channels")
                arrays.append(Y)
                if self.mirror and self.space == "position":
                    perm = mirror_permutation(part.skeleton)
                    if perm is None:
                        raise MocapValueError("lou-chai: mirror=True needs every left joint to have a "
                                              "right partner (by name)")
                    T = Y.shape[0]
                    arrays.append(mirror_local(Y.reshape(T, -1, 3), perm, up).reshape(T, -1))
        L = arrays[0].shape[1]
        M = int(self.window)
        if max(len(a) for a in arrays) < M:
            raise MocapValueError(
                f"lou-chai: training clips are shorter than the window (M = {M} frames at "
                f"{model_fps:g} fps); give longer clips or a smaller window")
        mean = np.concatenate(arrays).mean(axis=0) if self.center == "mean" else np.zeros(L)
        E, ev, S = rb.learn_bases([a - mean for a in arrays], M, energy=self.energy, n_bases=self.n_bases)
        self.bases_ = E
        self.eigvals_ = ev
        self.mean_ = mean
        self.window_ = M
        self.fps_ = model_fps if self.fps is not None else 0.0
        self.space_ = self.space
        self.up_axis_ = int(up)
        self.joint_names_ = list(first.skeleton.names)
        self.marker_origin_ = MARKER_ORIGIN
        self.channel_names_ = list(channel_names) if channel_names else []
        self.n_windows_ = int(S)
        self.n_frames_ = int(sum(len(a) for a in arrays))
        return self

    @property
    def n_bases_(self) -> int:
        return int(np.asarray(self.bases_).shape[1])

    # -- denoising -----------------------------------------------------------------------------
    def _solve(self, Y: np.ndarray, mask: np.ndarray, return_info: bool = False,
               own: bool = False):
        """Robust filter of centred (T, L) data; pads clips shorter than M with missing frames.
        ``own``: Y is a scratch array of the caller, centred in place (one copy less)."""
        M = int(self.window_)
        T = Y.shape[0]
        if own:
            Yc = Y
            Yc -= np.asarray(self.mean_)
        else:
            Yc = Y - np.asarray(self.mean_)
        if T < M:
            Yc = np.concatenate([Yc, np.full((M - T, Yc.shape[1]), np.nan)])
            mask = np.concatenate([mask, np.zeros((M - T, mask.shape[1]), bool)])
        E = self.bases_
        if not (isinstance(E, np.ndarray) and E.dtype == float and E.flags.c_contiguous):
            E = self.bases_ = np.ascontiguousarray(E, dtype=float)
        if getattr(self, "_cache_owner", None) is not E:
            self._cache, self._cache_owner = {}, E
        out = rb.robust_filter(Yc, E, M, mask=mask, lam=float(self.lam),
                               p=float(self.p), max_iter=int(self.max_iter), tol=float(self.tol),
                               method=self.method, cache=self._cache, return_info=True)
        Z, info = out
        del Y, Yc, mask
        log = getattr(self, "_conv_log", None)
        if log is not None:                     # collected by denoise() (source['convergence'])
            # without the (T, L) weights: the summary does not use them (issue 21: one
            # matrix less held per phase until the end of denoise())
            log.append(dataclasses.replace(info, extra={k: v for k, v in info.extra.items()
                                                        if k != "weights"}))
        Z = Z[:T]
        Z += np.asarray(self.mean_)
        return (Z, info) if return_info else Z

    def _denoise_at_rate(self, motion: Motion) -> Motion:
        Y, mask, ctx = self._to_array(motion, int(self.up_axis_))
        if not mask.any():
            raise MocapValueError("lou-chai: the clip has no observed entry at all")
        Z = self._solve(Y, mask, own=True)        # Y: _to_array's own copy
        del Y, mask
        return self._from_array(motion, Z, ctx)

    def denoise(self, motion: Motion) -> Motion:
        """Robust filtering of ``motion``; records ``source["convergence"]`` on the result and, with
        ``warn_convergence``, warns (ConvergenceWarning) once if an outer iteration hit
        ``max_iter`` before the relative change of J fell to ``tol``. The guard gives back the
        markers the model moved beyond their noise (:func:`~mocapkit.denoise.base.check_model_fit`)."""
        self._conv_log = []
        try:
            out = self._denoise_all(motion)
            log = self._conv_log
        finally:
            self._conv_log = None
        if not motion.observed.all():    # frames with few observed markers: interpolation in time
            from .. import gaps

            X, M = motion.matrix(copy=False), motion.matrix_mask()
            out = out.with_matrix(evidence_blend(out.matrix(), gaps.fill(X, M, never_observed=0.0), M,
                                                 motion.observed), handover=True)
            del X, M
        if log:
            report_convergence(self, log, tol=float(self.tol), max_iter=int(self.max_iter),
                               unit="phase", warn=bool(self.warn_convergence))
        return out

    def _denoise_all(self, motion: Motion) -> Motion:
        self._check_fitted()
        if self.space != self.space_:
            raise MocapValueError(f"lou-chai: the model was trained in space={self.space_!r}, "
                                  f"not {self.space!r}")
        check_trained_joints(self, motion)
        if self.space_ == "position" and self.frame == "body":
            check_marker_origin(self, motion)
        if not motion.observed.any():
            raise MocapValueError("lou-chai: the clip has no observed joint at all")
        if self.space_ == "angle":
            _, names, _ = angle_channels(motion)
            if names != list(self.channel_names_):
                raise MocapValueError("lou-chai: the clip's joint-angle channels differ from the model's")
        model_fps = float(self.fps_) if float(self.fps_) > 0 else motion.fps
        n_phases = self._n_phases(motion, model_fps)
        if n_phases == 1:
            return self._denoise_at_rate(motion)
        if n_phases is not None:
            ratio, r = self._ratio(motion.fps, model_fps), n_phases
            P = np.empty(motion.positions.shape)
            outs = []                                # kept in angle space only (their channels)
            for k in range(n_phases):                # one phase (a copy) at a time
                o = self._denoise_at_rate(decimate(motion, ratio, k))
                P[k::r] = o.positions
                if self.space_ == "angle":
                    outs.append(o)
                del o
            out = motion.with_positions(P, handover=True)
            if self.space_ == "angle":
                key = outs[0].source["per_frame"]
                pf = dict(motion.source.get("per_frame", {}))
                for name in key:
                    V = np.empty((motion.n_frames,) + np.shape(key[name])[1:])
                    for k, o in enumerate(outs):
                        V[k::r] = o.source["per_frame"][name]
                    pf[name] = V
                out = out.with_source(per_frame=pf)
            return out
        if self.space_ == "angle":
            raise MocapValueError(
                f"lou-chai: space='angle' needs a clip at a multiple of the model's {model_fps:g} fps "
                f"(got {motion.fps:g})")
        # other rates: resample to the model rate, filter, interpolate back
        from scipy.interpolate import CubicSpline

        low = motion.resample(model_fps)
        if low.n_frames < 2:
            return self._denoise_at_rate(motion.with_source())
        den = self._denoise_at_rate(low)
        t_low = np.arange(low.n_frames) / model_fps
        t = np.clip(np.arange(motion.n_frames) / motion.fps, 0, t_low[-1])
        Pl = den.positions.reshape(low.n_frames, -1)
        P = CubicSpline(t_low, Pl, axis=0)(t) if low.n_frames >= 4 else \
            np.stack([np.interp(t, t_low, Pl[:, c]) for c in range(Pl.shape[1])], axis=1)
        return motion.with_positions(P.reshape(motion.positions.shape))
