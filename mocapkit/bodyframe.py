"""Body-centred coordinate frame: joint positions relative to a smoothed root, with a
smoothed heading rotated out.

Why: filter bases, dictionaries and learned dynamics learned in the *global* frame are
useless on a new clip (it walks elsewhere and in another direction): measured on CMU
walks, Lou & Chai bases in the global frame give ~8 cm error, worse than the noisy input
(../shared/specs/METHODS.md Sec. 1). In the body frame the same motion looks the same
wherever and in whatever direction it happens.

The frame, per frame t (``world = R_t @ local + origin_t``, cm):

* ``origin_t`` -- the root joint's track (the joint whose parent is -1), gaps bridged
  linearly, then a running median (``smooth_s`` seconds) and a Gaussian (sigma
  ``smooth_s / 2`` s). Smoothing keeps noise and spikes out of the frame: what the frame
  does not absorb stays in the local coordinates, where the method can remove it; noise
  absorbed by the frame would pass straight through to the output. The root's
  step-to-step sway and bounce stay in the local coordinates (the methods learn them).
* ``R_t`` -- rotation about the vertical axis by the heading angle: the horizontal
  direction from the right hip to the left hip (the *lateral* axis) is mapped to the
  first horizontal axis. Hip joints are found by **name** (:func:`find_hips`): thigh
  joints (``lfemur``/``rfemur`` in CMU ASF, ``LeftUpLeg``/``RightUpLeg`` in cgspeed BVH,
  ``lThigh``/``rThigh`` in Daz BVH, ``HipLeft``/``HipRight`` on Kinect); a candidate that
  sits on the root in the rest pose (CMU ``LHipJoint``/``RHipJoint``) is skipped. Without
  hips the shoulders are used, without either the heading is 0 (translation only). The
  angle is unwrapped and smoothed like the origin.
* the vertical axis is the one with the largest median per-frame extent over joints
  (Y for CMU/BVH, Z for C3D), as :meth:`Motion.height`, unless given.

:func:`to_body_frame` returns the local positions and a :class:`BodyTransform`;
:func:`from_body_frame` inverts it exactly (up to rounding). The transform depends only
on the input clip, so a method may change the local positions and map them back with
the same transform. Missing joints stay NaN in the local positions.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import signal
from .errors import MocapValueError
from .io._rotations import axis_rotation
from .motion import Motion
from .skeleton import Skeleton, _side

__all__ = ["BodyTransform", "to_body_frame", "from_body_frame", "body_transform",
           "find_hips", "up_axis_of"]

_HIP_WORDS = ("hipjoint", "upleg", "femur", "thigh", "hip")
_SHOULDER_WORDS = ("clavicle", "collar", "shoulder", "shldr", "humerus", "upperarm", "arm")


@dataclass(frozen=True)
class BodyTransform:
    """Per-frame rigid transform ``world = rotation[t] @ local + origin[t]``.

    Attributes
    ----------
    origin : (T, 3) cm.
    rotation : (T, 3, 3), rotations about ``up_axis``.
    up_axis : 0, 1 or 2.
    heading : (T,) heading angle in radians (rotation about ``up_axis``).
    """

    origin: np.ndarray
    rotation: np.ndarray
    up_axis: int
    heading: np.ndarray

    @classmethod
    def identity(cls, n_frames: int, up_axis: int = 2) -> "BodyTransform":
        """The world frame itself (no translation, no rotation) for ``n_frames`` frames."""
        return cls(origin=np.zeros((n_frames, 3)), rotation=np.broadcast_to(np.eye(3), (n_frames, 3, 3)).copy(),
                   up_axis=int(up_axis), heading=np.zeros(n_frames))

    @property
    def n_frames(self) -> int:
        return self.origin.shape[0]

    def to_local(self, P: np.ndarray) -> np.ndarray:
        """World (T, J, 3) -> local ``Rᵀ (p - origin)`` (NaN stays NaN)."""
        P = np.asarray(P, dtype=float)
        return np.einsum("tji,tkj->tki", self.rotation, P - self.origin[:, None, :])

    def to_world(self, Z: np.ndarray) -> np.ndarray:
        """Local (T, J, 3) -> world ``R z + origin``."""
        Z = np.asarray(Z, dtype=float)
        return np.einsum("tij,tkj->tki", self.rotation, Z) + self.origin[:, None, :]


def up_axis_of(P: np.ndarray) -> int:
    """Vertical axis of positions (T, J, 3): the axis with the largest median per-frame
    extent over joints (1 if nothing is observed)."""
    import warnings

    P = np.asarray(P, dtype=float)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ext = np.nanmax(P, axis=1) - np.nanmin(P, axis=1)
    ext = ext[np.isfinite(ext).all(axis=1)]
    return int(np.argmax(np.median(ext, axis=0))) if len(ext) else 1


def _depths(skeleton: Skeleton) -> np.ndarray:
    d = np.zeros(skeleton.n_joints, dtype=int)
    for j, p in enumerate(skeleton.parents):
        d[j] = d[p] + 1 if p >= 0 else 0
    return d


def _pair(skeleton: Skeleton, words: tuple[str, ...], exclude: set[int]) -> tuple[int, int] | None:
    """Shallowest left and right joints whose name holds one of ``words``."""
    depth = _depths(skeleton)
    found = {}
    for side in ("left", "right"):
        cands = [j for j, n in enumerate(skeleton.names)
                 if j not in exclude and _side(n) == side and any(w in n.lower() for w in words)]
        if not cands:
            return None
        found[side] = min(cands, key=lambda j: (depth[j], j))
    return found["left"], found["right"]


def find_hips(skeleton: Skeleton) -> tuple[int, int] | None:
    """(left, right) joint indices marking the hip joints, by name, or None.

    Among joints named like a hip or thigh (``hipjoint``, ``upleg``, ``femur``,
    ``thigh``, ``hip``) with a side, the one closest to the root in the tree is taken on
    each side, skipping joints that sit on the root in the rest pose. So CMU ASF/AMC
    (joints are bone *end* points) gives ``lhipjoint``/``rhipjoint`` (the hip centres),
    cgspeed BVH gives ``LeftUpLeg``/``RightUpLeg`` (its ``LHipJoint`` has a zero offset,
    i.e. coincides with the root), Daz BVH ``lThigh``/``rThigh``, Kinect
    ``HipLeft``/``HipRight``. Without hips the shoulders/clavicles are used.
    """
    rest = skeleton.rest_positions()
    root = int(np.flatnonzero(skeleton.parents < 0)[0])
    size = float(np.ptp(rest, axis=0).max()) if skeleton.n_joints > 1 else 0.0
    on_root = {j for j in range(skeleton.n_joints)
               if np.linalg.norm(rest[j] - rest[root]) <= 1e-6 * max(size, 1e-9)}
    on_root.add(root)
    return _pair(skeleton, _HIP_WORDS, on_root) or _pair(skeleton, _SHOULDER_WORDS, on_root)


def _smooth(V: np.ndarray, fps: float, smooth_s: float) -> np.ndarray:
    """Running median (about smooth_s) then Gaussian (sigma smooth_s / 2) along time."""
    T = V.shape[0]
    if smooth_s <= 0 or T < 3:
        return V
    w = max(3, int(round(smooth_s * fps)) | 1)
    w = min(w, T if T % 2 else T - 1)
    if w >= 3:
        V = signal.median(V, window=w)
    return signal.gaussian(V, sigma=max(0.5 * smooth_s * fps, 0.5))


def body_transform(motion: Motion, *, smooth_s: float = 0.5, up_axis: int | None = None) -> BodyTransform:
    """Estimate the body frame of ``motion`` (module doc).

    Parameters
    ----------
    motion : the clip (may be noisy and have missing joints).
    smooth_s : smoothing time scale in seconds (median window; Gaussian sigma is half of
        it). Default 0.5 s: flat over a gait cycle's step-to-step sway. 0 = no smoothing
        (the frame follows the raw root and hips).
    up_axis : vertical axis; default estimated (:func:`up_axis_of`).
    """
    smooth_s = float(smooth_s)
    if not (np.isfinite(smooth_s) and smooth_s >= 0):
        raise MocapValueError(f"smooth_s must be a non-negative number of seconds, got {smooth_s!r}")
    P = np.asarray(motion.positions)
    obs = motion.observed
    T = motion.n_frames
    up = up_axis_of(P) if up_axis is None else int(up_axis)
    if up not in (0, 1, 2):
        raise MocapValueError(f"up_axis must be 0, 1 or 2, got {up_axis!r}")
    if not obs.any():
        raise MocapValueError("cannot estimate a body frame: no joint is observed in any frame")
    r = int(np.flatnonzero(motion.skeleton.parents < 0)[0])
    if obs[:, r].any():
        O = signal.fill_gaps(P[:, r], np.repeat(obs[:, r:r + 1], 3, axis=1), kind="linear")
    else:   # root never observed: centroid of the observed joints
        n = obs.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            Cc = np.where(obs[:, :, None], P, 0.0).sum(axis=1) / n[:, None]
        O = signal.fill_gaps(Cc, np.repeat((n > 0)[:, None], 3, axis=1), kind="linear")
    O = _smooth(O, motion.fps, smooth_s)
    a, b = (up + 1) % 3, (up + 2) % 3
    theta = np.zeros(T)
    hips = find_hips(motion.skeleton)
    if hips is not None:
        li, ri = hips
        Lat = P[:, li] - P[:, ri]
        ok = obs[:, li] & obs[:, ri]
        ok &= np.hypot(np.where(ok, Lat[:, a], 0), np.where(ok, Lat[:, b], 0)) > 1e-9
        if ok.any():
            th = np.full(T, np.nan)
            th[ok] = np.unwrap(np.arctan2(Lat[ok, b], Lat[ok, a]))
            th = signal.fill_gaps(th[:, None], ok[:, None], kind="linear")
            theta = _smooth(th, motion.fps, smooth_s)[:, 0]
    return BodyTransform(origin=O, rotation=axis_rotation(up, theta), up_axis=up, heading=theta)


def to_body_frame(motion: Motion, *, smooth_s: float = 0.5, up_axis: int | None = None,
                  transform: BodyTransform | None = None) -> tuple[np.ndarray, BodyTransform]:
    """Local (body-frame) positions (T, J, 3) cm and the transform (module doc).

    ``transform`` reuses a transform instead of estimating one (it must have T frames).
    Missing joints are NaN in the result.
    """
    tr = transform if transform is not None else body_transform(motion, smooth_s=smooth_s, up_axis=up_axis)
    if tr.n_frames != motion.n_frames:
        raise MocapValueError(f"transform has {tr.n_frames} frames, the motion {motion.n_frames}")
    return tr.to_local(motion.positions), tr


def from_body_frame(local: np.ndarray, transform: BodyTransform) -> np.ndarray:
    """World positions (T, J, 3) cm from local ones: the inverse of :func:`to_body_frame`."""
    local = np.asarray(local, dtype=float)
    if local.ndim != 3 or local.shape[2] != 3 or local.shape[0] != transform.n_frames:
        raise MocapValueError(f"local positions must be (T={transform.n_frames}, J, 3), got {local.shape}")
    return transform.to_world(local)


def _strip_side(name: str) -> str:
    """Joint name without its left/right marker (lowercase): 'lfemur' -> 'femur',
    'LeftUpLeg' -> 'upleg', 'HipLeft' -> 'hip', 'l_knee' -> 'knee'."""
    import re

    low = name.strip().lower()
    for pre in ("left", "right"):
        if low.startswith(pre):
            return low[len(pre):].lstrip("_. ")
        if low.endswith(pre):
            return low[:-len(pre)].rstrip("_. ")
    m = re.match(r"^[lr][_\.\s](.+)$", low) or re.match(r"^(.+)[_\.\s][lr]$", low)
    if m:
        return m.group(1)
    return low[1:] if low[:1] in ("l", "r") else low


def mirror_permutation(skeleton: Skeleton) -> np.ndarray | None:
    """Joint permutation (J,) swapping left and right joints by name (midline joints map
    to themselves), or None when some sided joint has no partner."""
    J = skeleton.n_joints
    perm = np.arange(J)
    keyed: dict[tuple[str, str], int] = {}
    for j, n in enumerate(skeleton.names):
        s = _side(n)
        if s is not None:
            keyed[(s, _strip_side(n))] = j
    for (s, k), j in keyed.items():
        other = keyed.get(("right" if s == "left" else "left", k))
        if other is None:
            return None
        perm[j] = other
    return perm


def mirror_local(local: np.ndarray, perm: np.ndarray, up_axis: int) -> np.ndarray:
    """Left-right mirror image of body-frame positions (T, J, 3): the lateral axis
    (first horizontal axis after ``up_axis``, see :func:`body_transform`) is negated and
    left/right joints are swapped (``perm`` from :func:`mirror_permutation`)."""
    out = np.array(local[:, perm], dtype=float)
    out[..., (up_axis + 1) % 3] *= -1.0
    return out
