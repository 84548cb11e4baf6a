"""Xiao et al.'s local coordinate frame per pose, and its inverse (seed 000, Sec. 3.1.1).

Xiao et al. translate each pose so that the root marker is at the origin, then rotate
it so that the plane through the left femur, right femur and upper-neck markers is
parallel to the XY plane and the ray from the midpoint of the two femurs to the upper
neck points along +Y; the transformation is recorded so that it can be undone after
denoising.  Concretely, for frame t with root r, femurs l and q, upper neck h::

    y_t = unit(h - (l + q)/2)                          (spine direction  -> +Y)
    x_t = unit((l - q) - ((l - q) . y_t) y_t)          (right-to-left    -> +X)
    z_t = x_t  x  y_t                                  (plane normal     -> +Z)
    R_t = [x_t y_t z_t]  (columns),    local = R_t^T (p - r_t),   p = R_t local + r_t

With a person facing +Z in a Y-up world (CMU), +X is the person's left, so R_t is the
identity for an upright pose facing +Z.

Decision (METHODS.md Sec. 2): the frame is estimated from a robustly smoothed copy of the
four tracks it depends on (gaps filled linearly, then a running median of
``median_s`` seconds and a Gaussian of ``sigma_s`` seconds), so outliers and noise do not
tilt or shift it; the same (smoothed) frame is used for the inverse, so the round trip
is exact whatever the smoothing.  ``smooth=False`` gives the per-pose frame of the paper.

Joint names: the four joints are found by name through a small alias table
(:data:`FRAME_JOINT_ALIASES`: CMU ASF ``lhipjoint``/``rhipjoint``/``upperneck`` -- the
hip centres, see the table's note --, cgspeed BVH ``LeftUpLeg``/``RightUpLeg``/``Neck1``
or ``Neck``, Daz ``lThigh``/``rThigh``/``neck``, Kinect ``HipLeft``/``HipRight``/
``ShoulderCenter`` ...); pass ``joints={'lfemur': ..., 'rfemur': ..., 'upperneck': ...}``
for other skeletons.  The root is the skeleton's root joint (parent -1) unless
``joints['root']`` says otherwise.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .errors import MocapValueError
from .skeleton import Skeleton

__all__ = ["FRAME_JOINT_ALIASES", "frame_joints", "LocalFrame", "estimate_frame", "to_local",
           "to_global"]

#: candidate names (case-insensitive, first usable hit wins) for the joints defining the
#: frame.  Xiao's "femur" markers are the hip joint centres (top of the femur): in our
#: ASF/AMC reader a joint sits at the *end* of its bone, so the hip centre is
#: ``lhipjoint``/``rhipjoint`` (``lfemur`` is the knee); in BVH files a joint sits at
#: the *start* of its bone, so it is ``LeftUpLeg``/``RightUpLeg`` (cgspeed's
#: ``LHipJoint`` coincides with the root there and is skipped: candidates whose rest
#: position is within 1 cm of the root's are not used).
FRAME_JOINT_ALIASES: dict[str, tuple[str, ...]] = {
    "lfemur": ("lhipjoint", "LeftUpLeg", "LeftUpperLeg", "LeftThigh", "lThigh", "LThigh",
               "HipLeft", "LeftHip", "l_hip", "LHip", "L_Hip", "lhip", "left_hip", "lfemur"),
    "rfemur": ("rhipjoint", "RightUpLeg", "RightUpperLeg", "RightThigh", "rThigh", "RThigh",
               "HipRight", "RightHip", "r_hip", "RHip", "R_Hip", "rhip", "right_hip", "rfemur"),
    "upperneck": ("upperneck", "Neck1", "Neck", "neck", "Neck2", "UpperNeck", "ShoulderCenter",
                  "SpineShoulder", "neck1", "Head", "head"),
}


def frame_joints(skeleton: Skeleton, joints: Mapping[str, str] | None = None) -> dict[str, int]:
    """Indices of ``root``, ``lfemur`` (left hip centre), ``rfemur`` (right hip centre)
    and ``upperneck`` in ``skeleton``.

    Names are looked up case-insensitively in :data:`FRAME_JOINT_ALIASES` unless given in
    ``joints``; a candidate at the root's rest position (within 1 cm) is skipped. Raises
    MocapValueError naming what it looked for.
    """
    joints = dict(joints or {})
    low = {n.lower(): i for i, n in enumerate(skeleton.names)}
    out: dict[str, int] = {}
    if "root" in joints:
        out["root"] = skeleton.index(joints["root"])
    else:
        out["root"] = int(np.flatnonzero(skeleton.parents < 0)[0])
    rest = skeleton.rest_positions()
    # the on-the-root test needs a rest pose: a marker set without hierarchy (TRC, C3D) has
    # none (every offset 0), so there the first name that matches is used
    has_rest = bool((skeleton.parents >= 0).any())
    for key, cands in FRAME_JOINT_ALIASES.items():
        if key in joints:
            out[key] = skeleton.index(joints[key])
            continue
        hit = None
        for c in cands:
            j = low.get(c.lower())
            if j is not None and j != out["root"] and (
                    not has_rest or np.linalg.norm(rest[j] - rest[out["root"]]) > 1.0):
                hit = j
                break
        if hit is None:
            raise MocapValueError(
                f"local frame: no joint for {key!r} (looked for {', '.join(cands)}); this "
                f"skeleton has: {', '.join(skeleton.names)}. Pass joints={{'{key}': NAME}}")
        out[key] = hit
    if len({out["lfemur"], out["rfemur"], out["upperneck"]}) < 3:
        raise MocapValueError(f"local frame: lfemur, rfemur and upperneck must be three different joints, got {out}")
    return out


@dataclass(frozen=True)
class LocalFrame:
    """Per-frame transform: ``global = R[t] @ local + origin[t]``.

    origin : (T, 3) cm; R : (T, 3, 3) rotation matrices (columns = local axes in world
    coordinates).
    """

    origin: np.ndarray
    R: np.ndarray


def _fill_linear(V: np.ndarray) -> np.ndarray:
    """Fill NaN rows of a (T, k) track by linear interpolation (ends held)."""
    from .gaps import fill_linear

    ok = np.isfinite(V).all(axis=1)
    if ok.all():
        return V
    if not ok.any():
        raise MocapValueError("local frame: a joint that defines the frame is never observed")
    return fill_linear(V, np.repeat(ok[:, None], V.shape[1], axis=1))


def _robust_smooth(V: np.ndarray, fps: float, median_s: float, sigma_s: float) -> np.ndarray:
    from scipy.ndimage import gaussian_filter1d, median_filter

    T = V.shape[0]
    w = int(round(median_s * fps)) | 1
    w = min(w, T if T % 2 else T - 1)
    if w >= 3:
        V = median_filter(V, size=(w, 1), mode="mirror")
    s = sigma_s * fps
    if s > 0 and T > 1:
        V = gaussian_filter1d(V, s, axis=0, mode="nearest", truncate=3.0)
    return V


def estimate_frame(positions: np.ndarray, skeleton: Skeleton, fps: float = 120.0, *,
                   smooth: bool = True, median_s: float = 0.05, sigma_s: float = 0.025,
                   joints: Mapping[str, str] | None = None) -> LocalFrame:
    """Estimate Xiao's local frame for every pose of ``positions`` (T, J, 3), cm.

    Parameters
    ----------
    positions : (T, J, 3); NaN where missing (the four tracks are gap-filled linearly).
    skeleton : gives joint names (see :func:`frame_joints`).
    fps : frame rate, for the smoothing lengths in seconds.
    smooth : estimate from robustly smoothed tracks (default, module docstring).
    median_s, sigma_s : running-median length and Gaussian sigma, seconds (defaults
        0.05 s and 0.025 s: 7 and 3 frames at 120 fps) -- short enough to follow fast
        turns, long enough to reject isolated spikes.
    """
    P = np.asarray(positions, dtype=np.float64)
    if P.ndim != 3 or P.shape[2] != 3 or P.shape[1] != skeleton.n_joints:
        raise MocapValueError(f"positions must be (T, {skeleton.n_joints}, 3), got {P.shape}")
    ix = frame_joints(skeleton, joints)
    tracks = np.concatenate([P[:, ix[k]] for k in ("root", "lfemur", "rfemur", "upperneck")], axis=1)
    tracks = _fill_linear(tracks)
    if smooth:
        tracks = _robust_smooth(tracks, float(fps), median_s, sigma_s)
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
    z = np.cross(x, y)
    R = np.stack([x, y, z], axis=2)
    return LocalFrame(origin=r, R=R)


def to_local(positions: np.ndarray, frame: LocalFrame) -> np.ndarray:
    """World positions (T, J, 3) -> local: ``R_t^T (p - origin_t)`` (NaN stays NaN)."""
    P = np.asarray(positions, dtype=np.float64)
    return np.einsum("tij,tki->tkj", frame.R, P - frame.origin[:, None, :])


def to_global(local: np.ndarray, frame: LocalFrame) -> np.ndarray:
    """Local (T, J, 3) -> world: ``R_t l + origin_t``."""
    Lc = np.asarray(local, dtype=np.float64)
    return np.einsum("tij,tkj->tki", frame.R, Lc) + frame.origin[:, None, :]
