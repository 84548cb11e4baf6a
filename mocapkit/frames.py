"""Per-frame rigid coordinate frames of a body, and the joints that define them.

One frame type, :class:`Frame` (``world = rotation[t] @ local + origin[t]``, cm), built
three ways:

* :meth:`Frame.identity` -- translation only (or the world frame itself, origin 0);
* :func:`heading_frame` -- the body-centred frame of the Lou & Chai bases and the learned
  Kalman filter (smoothed root as origin, smoothed heading about the vertical rotated out);
* :func:`pelvis_neck_frame` -- Xiao et al.'s per-pose frame (seed 000, Sec. 3.1.1), used by
  the sparse-coding methods and PSC (thesis Sec. 3.2).

Why a body frame: filter bases, dictionaries and learned dynamics learned in the *global*
frame are useless on a new clip (it walks elsewhere and in another direction): measured
on CMU walks, Lou & Chai bases in the global frame give ~8 cm error, worse than the noisy
input (../shared/specs/METHODS.md Sec. 1). In a body frame the same motion looks the same
wherever and in whatever direction it happens. Each frame depends only on the input clip,
so a method may change the local positions and map them back with the same frame; the
round trip is exact up to rounding.

Joints are found by name through the one alias table :data:`mocapkit.skeleton.JOINT_ALIASES`
(:func:`find_hips`, :func:`frame_joints`, :func:`mirror_permutation`). Tracks that define a
frame are gap-bridged linearly (:func:`mocapkit.gaps.fill`, ends held) and smoothed by one
robust smoother (:func:`smooth_track`: running median against spikes, then Gaussian), so
noise and outliers do not tilt or shift the frame: what the frame does not absorb stays
in the local coordinates, where the method can remove it; noise absorbed by the frame would
pass straight through to the output.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from . import signal
from .errors import MocapValueError
from .gaps import fill, frame_centroid
from .io._rotations import axis_rotation
from .motion import Motion
from .skeleton import JOINT_ALIASES, MIDLINE_ROOTS, Skeleton, _side, bare_name, strip_side

__all__ = ["Frame", "heading_frame", "pelvis_neck_frame", "smooth_track", "up_axis_of",
           "find_hips", "frame_joints", "mirror_permutation", "mirror_local"]

#: a candidate joint this close to the root in the rest pose (cm) is not a hip or neck:
#: cgspeed BVH ``LHipJoint`` has a zero offset, i.e. coincides with the root
ON_ROOT_CM = 1.0


# ---------------------------------------------------------------------------------------
# the frame type
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Frame:
    """Per-frame rigid transform ``world = rotation[t] @ local + origin[t]``.

    Attributes
    ----------
    origin : (T, 3) cm, the local origin in world coordinates.
    rotation : (T, 3, 3) rotation matrices; columns = the local axes in world coordinates.

    Examples
    --------
    A frame at (10, 0, 0) cm turned 90 degrees about z: world x becomes local -y, and
    ``to_world`` undoes ``to_local``:

    >>> import numpy as np
    >>> from mocapkit.frames import Frame
    >>> R = np.array([[[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]])
    >>> f = Frame(origin=np.array([[10.0, 0.0, 0.0]]), rotation=R)
    >>> P = np.array([[[11.0, 0.0, 0.0]]])                # (T=1, J=1, 3) cm
    >>> f.to_local(P).round(6).tolist()
    [[[0.0, -1.0, 0.0]]]
    >>> bool(np.allclose(f.to_world(f.to_local(P)), P))
    True
    """

    origin: np.ndarray
    rotation: np.ndarray

    @classmethod
    def identity(cls, origin: np.ndarray) -> "Frame":
        """Translation-only frame: local = world - origin (origin (T, 3) cm; zeros give the
        world frame itself)."""
        origin = np.asarray(origin, dtype=float)
        T = origin.shape[0]
        return cls(origin=origin, rotation=np.broadcast_to(np.eye(3), (T, 3, 3)).copy())

    @property
    def n_frames(self) -> int:
        return self.origin.shape[0]

    def heading(self, up_axis: int) -> np.ndarray:
        """Rotation angle (T,) radians in (-pi, pi] about ``up_axis`` (counter-clockwise from
        axis ``(up_axis+1) % 3`` towards ``(up_axis+2) % 3``): exact for frames that turn
        about that axis only (:func:`heading_frame`)."""
        a, b = (up_axis + 1) % 3, (up_axis + 2) % 3
        return np.arctan2(self.rotation[:, b, a], self.rotation[:, a, a])

    def _joints(self, X: np.ndarray, what: str) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        T = self.n_frames
        ok = X.ndim == 3 and X.shape[2] == 3 or X.ndim == 2 and X.shape[1] % 3 == 0
        if X.shape[:1] != (T,) or not ok:
            raise MocapValueError(f"{what} positions must be (T={T}, J, 3) or (T={T}, 3J), got {X.shape}")
        return X.reshape(T, -1, 3)

    def to_local(self, P: np.ndarray) -> np.ndarray:
        """World positions (T, J, 3) or (T, 3J) cm -> local ``Rᵀ (p - origin)``, same shape
        (NaN stays NaN)."""
        P3 = self._joints(P, "world")
        L = np.einsum("tji,tkj->tki", self.rotation, P3 - self.origin[:, None, :])
        return L.reshape(np.shape(P))

    def to_world(self, L: np.ndarray) -> np.ndarray:
        """Local positions (T, J, 3) or (T, 3J) cm -> world ``R l + origin``, same shape."""
        L3 = self._joints(L, "local")
        P = np.einsum("tij,tkj->tki", self.rotation, L3) + self.origin[:, None, :]
        return P.reshape(np.shape(L))


# ---------------------------------------------------------------------------------------
# tracks
# ---------------------------------------------------------------------------------------
def smooth_track(V: np.ndarray, *, window: int, sigma: float, radius: int | None = None,
                 mode: str = "odd") -> np.ndarray:
    """Robust smoothing of complete (T, k) tracks along time: a running median of
    ``window`` frames (odd; shortened to the clip, skipped below 3 frames; ends mirrored,
    :func:`mocapkit.signal.median`) against spikes, then a Gaussian of ``sigma`` frames
    (skipped when ``sigma <= 0`` or T < 2; ``radius`` and ``mode`` as
    :func:`mocapkit.signal.gaussian`)."""
    T = V.shape[0]
    w = min(int(window), T if T % 2 else T - 1)
    if w >= 3:
        V = signal.median(V, window=w)
    if sigma > 0 and T > 1:
        V = signal.gaussian(V, sigma=sigma, radius=radius, mode=mode)
    return V


def up_axis_of(P: np.ndarray) -> int:
    """Vertical axis of positions (T, J, 3): the axis with the largest median per-frame
    extent over joints (Y for CMU/BVH, Z for C3D; 1 if nothing is observed)."""
    P = np.asarray(P, dtype=float)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ext = np.nanmax(P, axis=1) - np.nanmin(P, axis=1)
    ext = ext[np.isfinite(ext).all(axis=1)]
    return int(np.argmax(np.median(ext, axis=0))) if len(ext) else 1


# ---------------------------------------------------------------------------------------
# joints by name
# ---------------------------------------------------------------------------------------
def _root(skeleton: Skeleton) -> int:
    return int(np.flatnonzero(skeleton.parents < 0)[0])


def _on_root(skeleton: Skeleton, root: int) -> set[int]:
    """``root`` and the joints within :data:`ON_ROOT_CM` of it in the rest pose. A marker
    set without hierarchy (TRC, C3D: every offset 0) has no rest pose: only ``root``."""
    if skeleton.is_flat:
        return {root}
    rest = skeleton.rest_positions()
    near = np.linalg.norm(rest - rest[root], axis=1) <= ON_ROOT_CM
    return {root, *np.flatnonzero(near).tolist()}


def _sided_pair(skeleton: Skeleton, role: str, exclude: set[int]) -> tuple[int, int] | None:
    """Shallowest left and right joints whose name holds one of ``JOINT_ALIASES[role]``."""
    depth = skeleton.depths()
    words = JOINT_ALIASES[role]
    found = {}
    for side in ("left", "right"):
        cands = [j for j, n in enumerate(skeleton.names)
                 if j not in exclude and _side(n) == side and any(w in n.lower() for w in words)]
        if not cands:
            return None
        found[side] = min(cands, key=lambda j: (depth[j], j))
    return found["left"], found["right"]


def find_hips(skeleton: Skeleton, *, shoulders: bool = True) -> tuple[int, int] | None:
    """(left, right) joint indices of the hip joints, by name, or None.

    Among joints with a side named like a hip or thigh (``JOINT_ALIASES['hip']``) the one
    closest to the root in the tree is taken on each side, skipping joints within
    :data:`ON_ROOT_CM` of the root in the rest pose. So CMU ASF/AMC (joints are bone *end*
    points) gives ``lhipjoint``/``rhipjoint`` (the hip centres), cgspeed BVH gives
    ``LeftUpLeg``/``RightUpLeg`` (its ``LHipJoint`` coincides with the root), Daz BVH
    ``lThigh``/``rThigh``, Kinect ``HipLeft``/``HipRight``. Without hips, and with
    ``shoulders``, the shoulders/clavicles (``JOINT_ALIASES['shoulder']``).
    """
    skip = _on_root(skeleton, _root(skeleton))
    hips = _sided_pair(skeleton, "hip", skip)
    if hips is None and shoulders:
        return _sided_pair(skeleton, "shoulder", skip)
    return hips


def frame_joints(skeleton: Skeleton, joints: Mapping[str, str] | None = None) -> dict[str, int]:
    """Indices of ``root``, ``lfemur`` / ``rfemur`` (left / right hip centre, Xiao's femur
    markers) and ``upperneck`` in ``skeleton``, the joints of :func:`pelvis_neck_frame`.

    ``joints`` gives names for any of the four; the others come from the skeleton: the
    root joint (parent -1), :func:`find_hips` without the shoulder fallback, and the first
    name of ``JOINT_ALIASES['neck']`` present (case-insensitive), candidates on the root
    skipped as in :func:`find_hips`. Raises MocapValueError naming what it looked for.
    """
    joints = dict(joints or {})
    # a marker set (no hierarchy) has no root joint: its first marker may be anywhere (a
    # neck or hand marker); a point named like a root, else the left hip marker (below)
    markers = False
    if "root" in joints:
        root = skeleton.index(joints["root"])
    elif (mroot := _marker_root(skeleton)) is not None:
        root = mroot
    else:
        root, markers = _root(skeleton), skeleton.is_flat
    skip = set() if markers else _on_root(skeleton, root)
    out = {"root": root}
    hips = None if {"lfemur", "rfemur"} <= joints.keys() else _sided_pair(skeleton, "hip", skip)
    low: dict[str, int] = {}
    for i, n in enumerate(skeleton.names):          # 'Subject:C7' is a C7 (the first one)
        low.setdefault(bare_name(n).lower(), i)
    necks = [low[c] for c in JOINT_ALIASES["neck"] if c in low and low[c] not in skip]
    for key, auto, looked in (("lfemur", hips and hips[0], "a left joint named like a hip"),
                              ("rfemur", hips and hips[1], "a right joint named like a hip"),
                              ("upperneck", necks[0] if necks else None, "a neck")):
        if key in joints:
            out[key] = skeleton.index(joints[key])
        elif auto is None:
            words = JOINT_ALIASES["neck" if key == "upperneck" else "hip"]
            raise MocapValueError(
                f"pelvis-neck frame: no joint for {key!r} (looked for {looked}: {', '.join(words)}); "
                f"this skeleton has: {', '.join(skeleton.names)}. Pass joints={{'{key}': NAME}}")
        else:
            out[key] = auto
    if markers:
        out["root"] = out["lfemur"]
    if len({out["lfemur"], out["rfemur"], out["upperneck"]}) < 3:
        raise MocapValueError("pelvis-neck frame: lfemur, rfemur and upperneck must be three "
                              f"different joints, got {out}")
    return out


def mirror_permutation(names: Sequence[str] | Skeleton) -> np.ndarray | None:
    """Joint permutation (J,) swapping left and right joints of a skeleton (or a list of
    joint names): partners are names equal after :func:`mocapkit.skeleton.strip_side`,
    midline joints map to themselves. None when some sided joint has no partner."""
    names = names.names if isinstance(names, Skeleton) else list(names)
    perm = np.arange(len(names))
    keyed: dict[tuple[str, str], int] = {}
    for j, n in enumerate(names):
        s = _side(n)
        if s is not None:
            keyed[(s, strip_side(n))] = j
    for (s, k), j in keyed.items():
        other = keyed.get(("right" if s == "left" else "left", k))
        if other is None:
            return None
        perm[j] = other
    return perm


def mirror_local(local: np.ndarray, perm: np.ndarray, up_axis: int) -> np.ndarray:
    """Left-right mirror image of heading-frame positions (T, J, 3): the lateral axis
    (first horizontal axis after ``up_axis``, see :func:`heading_frame`) is negated and
    left/right joints are swapped (``perm`` from :func:`mirror_permutation`)."""
    out = np.array(local[:, perm], dtype=float)
    out[..., (up_axis + 1) % 3] *= -1.0
    return out


# ---------------------------------------------------------------------------------------
# the heading frame (Lou & Chai, learned Kalman)
# ---------------------------------------------------------------------------------------
def _heading_smooth(V: np.ndarray, fps: float, smooth_s: float) -> np.ndarray:
    """:func:`smooth_track` with a median of about ``smooth_s`` s (>= 3 frames) and a
    Gaussian of sigma ``smooth_s / 2`` s (>= 0.5 frame), trend-preserving ends."""
    if smooth_s <= 0 or V.shape[0] < 3:
        return V
    return smooth_track(V, window=max(3, int(round(smooth_s * fps)) | 1),
                        sigma=max(0.5 * smooth_s * fps, 0.5))


def _marker_root(skeleton: Skeleton) -> int | None:
    """A marker set's first point named like a root -- a midline name of the skeleton module
    (``root``, ``hips``, ``pelvis`` ...: joint centres exported flat keep their root's name)
    or Plug-in Gait's sacrum marker ``SACR`` -- else None; None for a skeleton with a
    hierarchy (its root is its root)."""
    if not skeleton.is_flat:
        return None
    names = MIDLINE_ROOTS | {"sacr", "sacrum"}
    return next((j for j, n in enumerate(skeleton.names) if bare_name(n).lower() in names), None)


#: how :func:`heading_frame` centres a marker set: since 2026-12-05 on a root-named marker
#: or its hip markers' midpoint (before, on its first marker, wherever that was). A model
#: fitted in that frame records this as ``marker_origin_`` (:func:`check_marker_origin`).
MARKER_ORIGIN = "root-or-hips"


def check_marker_origin(model: Any, motion: Motion) -> None:
    """Refuse a body-frame model fitted on a marker set under the older origin rule: its
    mean pose sits in a frame centred elsewhere (kineticstoolkit's tennis serve: on C7,
    median 56 cm from the ASIS midpoint; a lou-chai model fitted so moved its own training
    take's samples by a median 49 cm). Skeletons with a hierarchy are unaffected, and so is a marker
    set whose first point is named like a root (joint centres exported flat): the origin is
    that point under both rules."""
    sk = motion.skeleton
    if not sk.is_flat or getattr(model, "marker_origin_", None) == MARKER_ORIGIN or _marker_root(sk) == 0:
        return
    raise MocapValueError(
        f"{model.name}: this model was trained on a marker set before 2026-12-05, when a marker set's "
        f"body frame was centred on its first marker; retrain it (mocapkit train --method {model.name} ...)")


def _origin_track(motion: Motion) -> np.ndarray:
    """Root track (T, 3), gaps bridged linearly; the observed joints' centroid when the
    root is never observed. A marker set (no hierarchy) has no root: its first marker may
    be on a hand or a wand; the midpoint of its hip markers (:func:`find_hips`: LASI /
    RASI ...) is the origin where they are found and seen together, else the centroid."""
    P, obs, sk = np.asarray(motion.positions), motion.observed, motion.skeleton
    r = _root(sk)
    if sk.is_flat:                                   # a marker set
        r = _marker_root(sk)
        hips = find_hips(sk, shoulders=False) if r is None else None
        if hips is not None and (both := obs[:, hips[0]] & obs[:, hips[1]]).any():
            return fill(0.5 * (P[:, hips[0]] + P[:, hips[1]]), np.repeat(both[:, None], 3, axis=1))
    if r is not None and obs[:, r].any():
        return fill(P[:, r], np.repeat(obs[:, r:r + 1], 3, axis=1))
    C, n = frame_centroid(P, obs)
    return fill(C, np.repeat((n > 0)[:, None], 3, axis=1))


def _heading_angle(motion: Motion, up: int, smooth_s: float) -> np.ndarray:
    """Heading (T,) radians about ``up``: angle of the right-to-left hip vector in the
    horizontal plane (axes ``(up+1) % 3``, ``(up+2) % 3``), unwrapped, gaps bridged, smoothed;
    0 without hips or shoulders."""
    P, obs = np.asarray(motion.positions), motion.observed
    T = motion.n_frames
    a, b = (up + 1) % 3, (up + 2) % 3
    hips = find_hips(motion.skeleton)
    if hips is None:
        return np.zeros(T)
    li, ri = hips
    Lat = P[:, li] - P[:, ri]
    ok = obs[:, li] & obs[:, ri]
    ok &= np.hypot(np.where(ok, Lat[:, a], 0), np.where(ok, Lat[:, b], 0)) > 1e-9
    if not ok.any():
        return np.zeros(T)
    th = np.full(T, np.nan)
    th[ok] = np.unwrap(np.arctan2(Lat[ok, b], Lat[ok, a]))
    th = fill(th[:, None], ok[:, None])
    return _heading_smooth(th, motion.fps, smooth_s)[:, 0]


def heading_frame(motion: Motion, *, smooth_s: float = 0.5, up_axis: int | None = None) -> Frame:
    """The body-centred heading frame of ``motion`` (Lou & Chai bases, learned Kalman).

    Per frame t (``world = R_t @ local + origin_t``, cm):

    * ``origin_t`` -- the root joint's track (parent -1; the observed joints' centroid if
      the root is never observed; in a marker set the midpoint of the hip markers, see
      :func:`_origin_track`), gaps bridged linearly, then a running median of
      ``smooth_s`` s and a Gaussian of sigma ``smooth_s / 2`` s. The root's step-to-step
      sway and bounce stay in the local coordinates (the methods learn them).
    * ``R_t`` -- rotation about the vertical axis by the heading angle: the horizontal
      direction from the right hip to the left hip (:func:`find_hips`; shoulders without
      hips, angle 0 without either) is mapped to the first horizontal axis
      ``(up_axis + 1) % 3``. The angle is unwrapped and smoothed like the origin.

    Parameters
    ----------
    motion : the clip (may be noisy and have missing joints; they stay NaN in local).
    smooth_s : smoothing time scale in seconds. Default 0.5 s: flat over a gait cycle's
        step-to-step sway. 0 = no smoothing (the frame follows the raw root and hips).
    up_axis : vertical axis 0, 1 or 2; default :func:`up_axis_of`.
    """
    smooth_s = float(smooth_s)
    if not (np.isfinite(smooth_s) and smooth_s >= 0):
        raise MocapValueError(f"smooth_s must be a non-negative number of seconds, got {smooth_s!r}")
    up = up_axis_of(motion.positions) if up_axis is None else int(up_axis)
    if up not in (0, 1, 2):
        raise MocapValueError(f"up_axis must be 0, 1 or 2, got {up_axis!r}")
    if not motion.observed.any():
        raise MocapValueError("cannot estimate a body frame: no joint is observed in any frame")
    origin = _heading_smooth(_origin_track(motion), motion.fps, smooth_s)
    return Frame(origin=origin, rotation=axis_rotation(up, _heading_angle(motion, up, smooth_s)))


# ---------------------------------------------------------------------------------------
# Xiao et al.'s pelvis-neck frame (sparse coding, PSC)
# ---------------------------------------------------------------------------------------
def _frame_tracks(P: np.ndarray, ix: Mapping[str, int]) -> np.ndarray:
    """(T, 12) tracks of root, lfemur, rfemur, upperneck; frames missing any of them are
    bridged linearly from the frames that have all four (ends held)."""
    V = np.concatenate([P[:, ix[k]] for k in ("root", "lfemur", "rfemur", "upperneck")], axis=1)
    ok = np.isfinite(V).all(axis=1)
    if ok.all():
        return V
    if not ok.any():
        raise MocapValueError("pelvis-neck frame: a joint that defines the frame is never observed")
    return fill(V, np.repeat(ok[:, None], V.shape[1], axis=1))


def pelvis_neck_frame(positions: np.ndarray, skeleton: Skeleton, fps: float = 120.0, *,
                      smooth: bool = True, median_s: float = 0.05, sigma_s: float = 0.025,
                      joints: Mapping[str, str] | None = None) -> Frame:
    """Xiao et al.'s local frame for every pose of ``positions`` (T, J, 3) cm (seed 000,
    Sec. 3.1.1).

    Each pose is translated so the root is at the origin and rotated so the plane through
    the left femur l, right femur q and upper neck h (:func:`frame_joints`) is parallel to
    the XY plane, the ray from the femurs' midpoint to the neck along +Y::

        y_t = unit(h - (l + q)/2)                          (spine direction  -> +Y)
        x_t = unit((l - q) - ((l - q) . y_t) y_t)          (right-to-left    -> +X)
        z_t = x_t  x  y_t                                  (plane normal     -> +Z)
        R_t = [x_t y_t z_t] (columns),   local = R_t^T (p - r_t)

    With a person facing +Z in a Y-up world (CMU), +X is the person's left, so R_t is the
    identity for an upright pose facing +Z.

    Parameters
    ----------
    positions : (T, J, 3); NaN where missing (frames missing a defining joint are bridged
        linearly).
    skeleton : gives joint names (:func:`frame_joints`; ``joints`` overrides them).
    fps : frame rate, for the smoothing lengths in seconds.
    smooth : estimate from robustly smoothed tracks (default; METHODS.md Sec. 2: outliers
        and noise do not tilt or shift the frame); False gives the per-pose frame of the
        paper. The same frame is used for the inverse, so the round trip is exact.
    median_s, sigma_s : running-median length and Gaussian sigma, seconds (defaults
        0.05 s and 0.025 s: 7 and 3 frames at 120 fps; Gaussian truncated at 3 sigma, ends
        held) -- short enough to follow fast turns, long enough to reject isolated spikes.
    """
    P = np.asarray(positions, dtype=np.float64)
    if P.ndim != 3 or P.shape[2] != 3 or P.shape[1] != skeleton.n_joints:
        raise MocapValueError(f"positions must be (T, {skeleton.n_joints}, 3), got {P.shape}")
    tracks = _frame_tracks(P, frame_joints(skeleton, joints))
    if smooth:
        s = sigma_s * float(fps)
        tracks = smooth_track(tracks, window=int(round(median_s * float(fps))) | 1, sigma=s,
                              radius=int(3.0 * s + 0.5), mode="nearest")
    r, lf, rf, h = tracks[:, 0:3], tracks[:, 3:6], tracks[:, 6:9], tracks[:, 9:12]
    y = h - 0.5 * (lf + rf)
    y = y / np.maximum(np.linalg.norm(y, axis=1, keepdims=True), 1e-12)
    lat = lf - rf
    x = lat - (lat * y).sum(1, keepdims=True) * y
    nx = np.linalg.norm(x, axis=1, keepdims=True)
    bad = nx[:, 0] < 1e-9
    if bad.any():
        # degenerate (femurs along the spine): any unit vector orthogonal to y
        alt = np.where(np.abs(y[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 0, 1.0]]))
        alt = alt - (alt * y).sum(1, keepdims=True) * y
        x = np.where(bad[:, None], alt, x)
        nx = np.linalg.norm(x, axis=1, keepdims=True)
    x = x / nx
    return Frame(origin=r, rotation=np.stack([x, y, np.cross(x, y)], axis=2))


def frame_in_place(frame, X: np.ndarray, to: str, block: int | None = None) -> np.ndarray:
    """``frame.to_local(X)`` (``to="local"``) or ``frame.to_world(X)`` (``"world"``) of X
    (T, J, 3) written into X, ``block`` frames at a time: the per-frame products of the
    whole clip at once would take two more (T, J, 3) temporaries. Returns X."""
    from .windows import frame_blocks

    for sl in frame_blocks(X.shape[0], block):
        f = Frame(origin=frame.origin[sl], rotation=frame.rotation[sl])
        X[sl] = f.to_local(X[sl]) if to == "local" else f.to_world(X[sl])
    return X
