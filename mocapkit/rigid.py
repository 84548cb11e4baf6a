"""Least-squares rigid fits (Kabsch / SVD), batched over frames, and rigid marker clusters
found from the data.

Markers on one body segment (a head band, a pelvis, a technical cluster on a forearm or a
wheelchair frame) keep their mutual distances. That gives two tools:

* :func:`kabsch` -- the rotation ``R`` and translation ``t`` that best map a set of points
  ``A`` onto ``B`` in the weighted least-squares sense, ``min sum_i w_i |R a_i + t - b_i|^2``
  (Kabsch 1976, Acta Cryst. A32:922; the SVD form of Arun, Huang & Blostein 1987, IEEE
  TPAMI 9(5):698, with Umeyama's 1991 reflection guard, IEEE TPAMI 13(4):376 eq. 39-40:
  ``R = U diag(1, 1, d) V^T``, ``d = sign det(U V^T)``). Batched: ``A``, ``B`` of shape
  (..., N, 3), one SVD of a 3x3 matrix per batch element, no Python loop.
  :func:`yaw_kabsch` is the same fit restricted to a rotation about one axis (2-D
  Procrustes in the horizontal plane, closed form).
* :func:`find_clusters` -- groups of markers whose pairwise distances barely vary over the
  frames where both are seen (standard deviation below ``max_std_cm``, complete linkage so
  that *every* pair of a cluster passes), since C3D files carry no segment definitions.
  :func:`parse_clusters` reads an explicit list (marker names, or a JSON file with that list).
* :func:`rigid_fill` -- the rigid-body gap fill built on both (Vicon Nexus "rigid body fill",
  QTM "relational / kinematic fill", MoCap Toolbox ``mcfixrigidbody``).
* :func:`fixed_bones` / :func:`hold_lengths` -- the bones whose length a skeleton file
  format fixes (ASF/AMC, BVH: positions are forward kinematics of rotations), and the
  smallest move of the points that gives every such bone its length back.

Units: positions in cm, (T, J, 3); masks (T, J) bool.

Example
-------
>>> import numpy as np
>>> from mocapkit.rigid import kabsch, apply_rigid
>>> rng = np.random.default_rng(0)
>>> A = rng.normal(size=(5, 4, 3)) * 10                     # 5 frames, 4 points, cm
>>> q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
>>> R0 = q * np.sign(np.linalg.det(q))                      # a proper rotation
>>> B = A @ R0.T + np.array([1.0, 2.0, 3.0])
>>> R, t = kabsch(A, B)
>>> bool(np.allclose(apply_rigid(R, t, A), B))
True
"""
from __future__ import annotations

import json
import os
import warnings
from typing import Literal, Sequence

import numpy as np

from .errors import MocapFormatError, MocapValueError
from .frames import Frame
from .signal._arrays import nanmedian0
from .windows import frame_blocks, spaced_frames

__all__ = ["kabsch", "yaw_kabsch", "apply_rigid", "distance_stats", "rigid_partners", "steady_partners", "distance_noise",
           "distance_consistency", "find_clusters", "parse_clusters", "rigid_fill", "cluster_template",
           "fixed_bones", "bone_lengths", "bone_chains", "steady_spans", "steady_clusters", "hold_clusters",
           "hold_lengths", "kinematic_fill",
           "REFERENCES"]

#: reference shapes :func:`rigid_fill` knows (see its docstring)
REFERENCES = ("ends", "average")


# -- rigid fits ---------------------------------------------------------------------------
def kabsch(A: np.ndarray, B: np.ndarray, weights: np.ndarray | None = None,
           *, return_spread: bool = False):
    """Weighted least-squares rigid transform mapping ``A`` onto ``B``.

    Parameters
    ----------
    A, B : (..., N, 3) corresponding points (cm). NaN points must have weight 0.
    weights : (..., N) or (N,) non-negative weights (default 1); a point with weight 0 is
        ignored (so one call serves frames that see different subsets of the points).
    return_spread : also return the second-largest singular value of the weighted
        covariance of the centred ``A`` points divided by the weight sum (cm^2): near 0
        when the used points are (nearly) collinear, i.e. the rotation about their line is
        undetermined.

    Returns
    -------
    R : (..., 3, 3) proper rotations (det +1: the reflection guard of Umeyama 1991).
    t : (..., 3) translations, ``B ~ A @ R^T + t`` (see :func:`apply_rigid`).
    spread : (...,) only with ``return_spread``.

    Batch elements with a zero weight sum give the identity and ``t = 0`` (their
    ``spread`` is 0, so callers can reject them).
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    if A.shape != B.shape or A.ndim < 2 or A.shape[-1] != 3:
        raise MocapValueError(f"kabsch: A and B must both be (..., N, 3), got {A.shape} and {B.shape}")
    if weights is None:               # (the common case, a third faster without the weights)
        sw = np.full(A.shape[:-2], float(A.shape[-2]))
        safe = np.maximum(sw, 1.0)
        ca, cb = A.mean(axis=-2), B.mean(axis=-2)              # (..., 3)
        Ac = A - ca[..., None, :]
    else:
        w = np.broadcast_to(np.asarray(weights, dtype=float), A.shape[:-1])
        A = np.where(w[..., None] > 0, A, 0.0)
        B = np.where(w[..., None] > 0, B, 0.0)
        sw = w.sum(axis=-1)                                    # (...,)
        safe = np.where(sw > 0, sw, 1.0)
        ca = (w[..., None] * A).sum(axis=-2) / safe[..., None]
        cb = (w[..., None] * B).sum(axis=-2) / safe[..., None]
        Ac = (A - ca[..., None, :]) * w[..., None]
    Bc = B - cb[..., None, :]
    H = np.swapaxes(Ac, -1, -2) @ Bc                           # (..., 3, 3) = A_c^T W B_c
    U, S, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
    d = np.where(d == 0, 1.0, d)
    # H = U S V^T; R = V diag(1,1,d) U^T maps centred A onto centred B
    V = np.swapaxes(Vt, -1, -2).copy()
    V[..., :, 2] *= d[..., None]
    R = V @ np.swapaxes(U, -1, -2)
    t = cb - (R @ ca[..., None])[..., 0]
    zero = sw <= 0
    if zero.any():
        R[zero] = np.eye(3)
        t[zero] = 0.0
    if not return_spread:
        return R, t
    Sa = np.linalg.svd(np.swapaxes(Ac, -1, -2) @ (A - ca[..., None, :]), compute_uv=False)
    return R, t, Sa[..., 1] / safe


def yaw_kabsch(A: np.ndarray, B: np.ndarray, weights: np.ndarray | None = None,
               *, up_axis: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rotation about ``up_axis`` (and horizontal translation) mapping ``A`` onto
    ``B``, in the horizontal plane only (2-D Procrustes, closed form).

    A, B : (..., N, 3) cm; weights (..., N) or (N,). Returns the angle (...,) in radians
    (positive = counter-clockwise from the first horizontal axis ``(up+1) % 3`` towards the
    second ``(up+2) % 3``, as :func:`mocapkit.frames.heading_frame`) and the horizontal translation
    (..., 3) (its ``up_axis`` component is 0): ``B_h ~ Rot(angle) A_h + t``.
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    a, b = (up_axis + 1) % 3, (up_axis + 2) % 3
    w = np.ones(A.shape[:-1]) if weights is None else np.broadcast_to(
        np.asarray(weights, dtype=float), A.shape[:-1])
    ok = w > 0
    A2 = np.where(ok[..., None], A[..., [a, b]], 0.0)
    B2 = np.where(ok[..., None], B[..., [a, b]], 0.0)
    sw = w.sum(axis=-1)
    safe = np.where(sw > 0, sw, 1.0)
    ca = (w[..., None] * A2).sum(axis=-2) / safe[..., None]
    cb = (w[..., None] * B2).sum(axis=-2) / safe[..., None]
    Ac = A2 - ca[..., None, :]
    Bc = B2 - cb[..., None, :]
    dot = (w * (Ac * Bc).sum(axis=-1)).sum(axis=-1)
    crs = (w * (Ac[..., 0] * Bc[..., 1] - Ac[..., 1] * Bc[..., 0])).sum(axis=-1)
    th = np.arctan2(crs, dot)
    c, s = np.cos(th), np.sin(th)
    t = np.zeros(A.shape[:-2] + (3,))
    t[..., a] = cb[..., 0] - (c * ca[..., 0] - s * ca[..., 1])
    t[..., b] = cb[..., 1] - (s * ca[..., 0] + c * ca[..., 1])
    return th, t


def apply_rigid(R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``X @ R^T + t`` for points X (..., K, 3) (or (..., 3)), R (..., 3, 3), t (..., 3)."""
    X = np.asarray(X, dtype=float)
    if X.ndim == R.ndim - 1:                     # one point per batch element
        return np.einsum("...ij,...j->...i", R, X) + t
    return np.einsum("...ij,...kj->...ki", R, X) + t[..., None, :]


# -- clusters -----------------------------------------------------------------------------
def distance_stats(P: np.ndarray, observed: np.ndarray, *, chunk: int = 2048,
                   return_range: bool = False):
    """Mean and standard deviation of every pairwise marker distance over the frames where
    both markers are observed, and the number of those frames.

    P : (T, J, 3) cm; observed : (T, J). Returns (mean (J, J) cm, std (J, J) cm, n (J, J)
    int) and, with ``return_range``, (min (J, J), max (J, J)) cm; NaN where a pair is never
    seen together. Accumulated over chunks of frames, so memory stays O(chunk * J^2).
    """
    P = np.asarray(P, dtype=float)
    obs = np.asarray(observed, dtype=bool) & np.isfinite(P).all(axis=-1)
    T, J, _ = P.shape
    s1 = np.zeros((J, J))
    s2 = np.zeros((J, J))
    n = np.zeros((J, J))
    lo = np.full((J, J), np.inf)
    hi = np.full((J, J), -np.inf)
    ref = None
    for a in range(0, T, chunk):                  # chunks of frames (memory), not frames
        Q = np.where(obs[a:a + chunk, :, None], P[a:a + chunk], 0.0)
        o = obs[a:a + chunk].astype(float)
        D = np.linalg.norm(Q[:, :, None, :] - Q[:, None, :, :], axis=-1)
        both = o[:, :, None] * o[:, None, :]
        if ref is None:                           # shift for a numerically stable variance
            with np.errstate(invalid="ignore", divide="ignore"):
                ref = np.nan_to_num((D * both).sum(0) / both.sum(0))
        if return_range and len(D):
            lo = np.minimum(lo, np.where(both > 0, D, np.inf).min(axis=0))
            hi = np.maximum(hi, np.where(both > 0, D, -np.inf).max(axis=0))
        Dc = (D - ref) * both
        s1 += Dc.sum(axis=0)
        s2 += (Dc * Dc).sum(axis=0)
        n += both.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s1 / n
        var = np.maximum(s2 / n - mean ** 2, 0.0)
    mean = np.where(n > 0, mean + ref, np.nan)
    std = np.where(n > 0, np.sqrt(var), np.nan)
    if return_range:
        return mean, std, n.astype(np.int64), np.where(n > 0, lo, np.nan), np.where(n > 0, hi, np.nan)
    return mean, std, n.astype(np.int64)


def rigid_partners(P: np.ndarray, observed: np.ndarray, *, n_partners: int = 4,
                   max_scale_cm: float = 1.0, n_ref: int = 1024
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each point's most rigid partners: the points whose distance to it varies least.

    The robust scale of the distance |p_j - p_k| is 1.4826 MAD over up to ``n_ref`` evenly
    spaced frames where both are observed (spikes in 10 % of the samples leave median and
    MAD in place); a partner needs a scale <= ``max_scale_cm`` and 3 such frames.

    P : (T, J, 3) cm; observed : (T, J) bool. Returns (part (J, K) int, most rigid first;
    real (J, K) bool, False on a slot with no partner; median distance (J, K) cm; scale
    (J, K) cm), K = min(n_partners, J - 1). Memory O(n_ref J^2).
    """
    P = np.asarray(P, dtype=float)
    obs = np.asarray(observed, dtype=bool) & np.isfinite(P).all(axis=-1)
    T, J, _ = P.shape
    K = int(max(min(n_partners, J - 1), 0))
    ref = spaced_frames(T, n_ref)
    Q = np.where(obs[ref, :, None], P[ref], np.nan)
    D = np.linalg.norm(Q[:, :, None, :] - Q[:, None, :, :], axis=-1)     # (R, J, J), NaN unseen
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)                  # all-NaN pairs
        med = nanmedian0(D)
        scale = 1.4826 * nanmedian0(np.abs(D - med))
    seen = (np.isfinite(D).sum(axis=0) >= 3) & ~np.eye(J, dtype=bool)
    scale = np.where(seen & (scale <= float(max_scale_cm)), scale, np.inf)
    part = np.argsort(scale, axis=1, kind="stable")[:, :K]
    sc = np.take_along_axis(scale, part, axis=1)
    real = np.isfinite(sc)
    return part, real, np.take_along_axis(med, part, axis=1), np.where(real, sc, np.nan)


def steady_partners(P: np.ndarray, observed: np.ndarray, *, n_partners: int = 4,
                    max_span_cm: float = 2.0, min_frames: int = 20
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each point's rigid partners by the *whole* span of their distance: the points whose
    distance to it, over every frame where both are observed (at least ``min_frames``),
    stays within ``max_span_cm`` -- the steadiest ``n_partners`` first.

    Unlike :func:`rigid_partners` (a robust scale, which spikes leave in place) the span
    takes every frame: a subject who stands still most of a clip keeps a knee-to-foot
    distance steady in most frames (CMU balance: a robust scale of 0.085 cm on a distance
    that bends from 57 to 50 cm), and spikes only widen a span, i.e. drop a pair. For a
    test that must never flag a correct sample (:func:`mocapkit.gaps.off_rigid_partners`).
    Candidate pairs come from 1,024 spaced frames (a span there is a lower bound of the
    whole one; pairs seen together there fewer than 3 times stay candidates) and only they
    are spanned over every frame: O(T x pairs), not the O(T J^2) of all pairs (17 s on
    100,000 frames of 50 markers that all move as one body, on the loaded 2-core machine).

    P : (T, J, 3) cm; observed : (T, J) bool. Returns (part (J, K) int, steadiest first;
    real (J, K) bool, False on a slot with no partner; lo, hi (J, K) cm, the distance's
    range, NaN where not real), K = min(n_partners, J - 1).

    >>> import numpy as np
    >>> t = np.linspace(0, 1, 50)[:, None]
    >>> P = np.stack([np.hstack([t * 100, t * 0, t * 0]) + [0, 10 * i, 0] for i in range(3)], 1)
    >>> P[:10, 2, 2] += 15.0                    # point 2 moves off the others in 10 frames
    >>> part, real, lo, hi = steady_partners(P, np.ones((50, 3), bool), n_partners=2)
    >>> part[0][real[0]].tolist(), real[2].tolist()     # 0 and 1 rigid, 2 with neither
    ([1], [False, False])
    """
    P = np.asarray(P, dtype=float)
    obs = np.asarray(observed, dtype=bool) & np.isfinite(P).all(axis=-1)
    T, J = obs.shape
    K = int(max(min(n_partners, J - 1), 0))
    ref = spaced_frames(T, 1024)
    _, _, n_s, lo_s, hi_s = distance_stats(P[ref], obs[ref], return_range=True,
                                           chunk=max(16, int(2e6 // max(J * J, 1))))
    ia, ib = np.nonzero(np.triu((n_s < 3) | (hi_s - lo_s <= max_span_cm), 1))
    n = np.zeros(len(ia), np.int64)
    lo_p = np.full(len(ia), np.inf)
    hi_p = np.full(len(ia), -np.inf)
    for sl in frame_blocks(T, max(16, int(4e6 // max(len(ia), 1)))):     # blocks of frames
        v = P[sl][:, ia] - P[sl][:, ib]
        d2 = np.einsum("bpi,bpi->bp", v, v)                             # squared: same order
        both = obs[sl][:, ia] & obs[sl][:, ib]
        n += both.sum(axis=0)
        lo_p = np.minimum(lo_p, np.where(both, d2, np.inf).min(axis=0, initial=np.inf))
        hi_p = np.maximum(hi_p, np.where(both, d2, -np.inf).max(axis=0, initial=-np.inf))
    lo_p, hi_p = np.sqrt(lo_p), np.sqrt(np.maximum(hi_p, 0.0))       # pairs never seen: inf, 0
    ok = (n >= min_frames) & (hi_p - lo_p <= max_span_cm)
    span = np.full((J, J), np.inf)
    lo = np.full((J, J), np.nan)
    hi = np.full((J, J), np.nan)
    for x, y in ((ia, ib), (ib, ia)):
        span[x[ok], y[ok]] = (hi_p - lo_p)[ok]
        lo[x, y], hi[x, y] = lo_p, hi_p
    part = np.argsort(span, axis=1, kind="stable")[:, :K]
    real = np.isfinite(np.take_along_axis(span, part, axis=1))
    return (part, real, np.where(real, np.take_along_axis(lo, part, axis=1), np.nan),
            np.where(real, np.take_along_axis(hi, part, axis=1), np.nan))


#: frames :func:`fixed_bones` reads to check that positions are on the skeleton's scale
SCALE_CHECK_FRAMES = 512


def bone_lengths(P: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """(T, B) length (cm) of each bone (child, parent) of ``bones`` (B, 2) in every frame of
    P (T, J, 3); NaN where an end is missing.

    >>> bone_lengths(np.array([[[0.0, 0, 0], [3, 4, 0]]]), np.array([[1, 0]])).tolist()
    [[5.0]]
    """
    bones = np.asarray(bones).reshape(-1, 2)
    return np.linalg.norm(P[:, bones[:, 0]] - P[:, bones[:, 1]], axis=-1)


def fixed_bones(motion, positions: np.ndarray | None = None, *, zero_length: bool = False
                ) -> tuple[np.ndarray, np.ndarray]:
    """The bones whose length the motion's file format fixes.

    In ASF/AMC and BVH the positions are forward kinematics of rotations, so a bone keeps
    its skeleton length in every frame (and a cleaned motion written back to those
    formats gets it back through the writer's IK whatever the positions say). ASF/AMC
    (``source['asf']``): every bone (the reader refuses a length dof). BVH
    (``source['bvh']``): every joint whose node has no position channel. A C3D that
    mocapkit wrote from such a motion (``source['c3d']['fixed_bones']``, the flags of its
    ``MOCAPKIT`` group, :mod:`mocapkit.io.c3d`): the bones flagged there. Any other source
    (other C3D, TRC, Kinect -- whose skeleton is the median of the data --, a Motion built in
    code): none.

    ``positions`` (T, J, 3) cm (e.g. the motion's own): none either when they are not on
    the skeleton's scale -- the median bone's measured length off its declared one by more
    than 0.8-1.25x, as when positions were rescaled (metres, millimetres) without the
    skeleton: the declared lengths then describe other positions.

    ``zero_length``: also the bones of length 0 -- a joint the format puts exactly at its
    parent (a BVH joint with OFFSET 0 0 0: ten in every CMU BVH conversion, LHipJoint,
    lowerback, LeftCollar, lhand, LThumb ...; the ``<child>_base`` joints mocapkit's BVH
    writer adds). Off by default: a zero length gives no direction (a kinematic fill, a
    bone chain, a scale check cannot use it); holding positions to the format's lengths
    wants them (:func:`hold_lengths` puts the two ends together).

    Returns (pairs (B, 2) int -- child joint, parent joint; lengths (B,) cm), B = 0 when
    none.

    >>> import numpy as np
    >>> from mocapkit.motion import Motion
    >>> from mocapkit.skeleton import Skeleton
    >>> sk = Skeleton(("root", "knee"), np.array([-1, 0]), np.array([[0.0, 0, 0], [0, -40, 0]]))
    >>> fixed_bones(Motion(np.zeros((5, 2, 3)), sk, 30.0))[0].shape     # built in code: none
    (0, 2)
    """
    src = motion.source
    sk = motion.skeleton
    bones = np.array(sk.bones(), dtype=np.int64).reshape(-1, 2)
    lengths = np.linalg.norm(sk.offsets[bones[:, 0]], axis=1) if len(bones) else np.zeros(0)
    if isinstance(src.get("asf"), dict):
        keep = np.ones(len(bones), bool)
    elif isinstance(src.get("bvh"), dict):
        meta = src["bvh"]
        nodes, joint_nodes = meta.get("nodes", ()), tuple(meta.get("joint_nodes", ()))
        if len(joint_nodes) != sk.n_joints:
            keep = np.zeros(len(bones), bool)
        else:
            keep = np.array([not any("position" in c.lower() for c in (nodes[joint_nodes[c]].get("channels") or ()))
                             for c in bones[:, 0]], bool)
    elif isinstance(src.get("c3d"), dict) and src["c3d"].get("fixed_bones") is not None:
        flags = np.asarray(src["c3d"]["fixed_bones"], bool)
        keep = flags[bones[:, 0]] if len(flags) == sk.n_joints else np.zeros(len(bones), bool)
    else:
        keep = np.zeros(len(bones), bool)
    keep &= lengths >= 0 if zero_length else lengths > 0
    bones, lengths = bones[keep], lengths[keep]
    if positions is not None and (lengths > 0).any():
        P = np.asarray(positions, float)
        # a scale check: the median over at most SCALE_CHECK_FRAMES evenly spaced frames
        # (all 10,000 of a long clip cost 24 ms a call, and auto calls it up to three times)
        P = P[spaced_frames(len(P), SCALE_CHECK_FRAMES)]
        pos = lengths > 0
        ratio = nanmedian0(bone_lengths(P, bones[pos])) / lengths[pos]     # a bone never seen: NaN
        if not np.isfinite(ratio).any() or not 0.8 <= float(np.nanmedian(ratio)) <= 1.25:
            return bones[:0], lengths[:0]
    return bones, lengths


def _transport(a: np.ndarray, b: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v (n, 3) turned by the minimal rotation that takes unit vectors a to b (n, 3)
    (Rodrigues; the identity where a = b, v reflected through the plane normal to a where
    a = -b)."""
    k = np.cross(a, b)
    c = np.sum(a * b, axis=1)[:, None]
    # R v = v c + (k x v) + k (k . v) / (1 + c)
    return v * c + np.cross(k, v) + k * (np.sum(k * v, axis=1)[:, None] / np.maximum(1.0 + c, 1e-12))


def sphere_circle(A: np.ndarray, C: np.ndarray, l1: float | np.ndarray, l2: float | np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where a joint between a parent at A and a child at C (each (N, 3) cm) can be with
    bones of lengths l1 (to A) and l2 (to C; cm, scalars or (N,)): the circle where the two
    spheres meet. Returns
    (u (N, 3) the unit axis A -> C, d (N,) the circle's centre along it from A, r (N,) its
    radius, ok (N,) True where the spheres meet; elsewhere r is clamped at 0).

    >>> u, d, r, ok = sphere_circle(np.zeros((1, 3)), np.array([[0.0, 0, 8]]), 5.0, 5.0)
    >>> d.round(6).tolist(), r.round(6).tolist(), ok.tolist()
    ([4.0], [3.0], [True])
    """
    D = C - A
    n = np.linalg.norm(D, axis=1)
    dn = np.maximum(n, 1e-9)
    u = D / dn[:, None]
    d = (l1 ** 2 - l2 ** 2 + dn ** 2) / (2.0 * dn)
    r2 = l1 ** 2 - d ** 2
    ok = (n > 1e-9) & (r2 >= 0)
    return u, d, np.sqrt(np.maximum(r2, 0.0)), ok


#: the largest gain from an error in the parent-child distance to the filled joint's
#: position at which :func:`kinematic_fill` fills a frame from a parent or child that was
#: itself filled, not measured. Near full extension (a straight knee or elbow) the circle's
#: radius r is small and moves by d / r times the change of its centre d: found on CMU 07_03
#: at 30 fps with 30 % of the samples missing (the auto protocol's held-out clips), a knee's
#: 4-frame gap of a straight leg (hip-ankle 80.3 of 80.6 cm) filled from a hip the spline
#: had filled was 2.39 cm off, where a line through the knee's own path was 0.36 cm off, and
#: its stretches next to the gap (hip measured) had read 0.33 cm. Measured on the 40
#: missing30 cases of both clip sets (auto): gain 2 / 3 / 5, summed RMSE 3.838 -> 3.816 /
#: 3.820 / 3.820 cm (07_03@30 0.139 -> 0.125, balance@30 0.024 -> 0.021, the rest within
#: 1 %); leaving every frame with a filled partner unfilled instead: 07_03@30 0.104 but CMU
#: 135_09@30 0.089 -> 0.126 (a bent knee's fill from a filled hip was the best fill there)
KINEMATIC_MAX_GAIN = 2.0


def kinematic_fill(P: np.ndarray, observed: np.ndarray, parents, bones: np.ndarray, lengths: np.ndarray,
                   measured: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Gaps of a skeleton's joints filled on their fixed bone lengths: a joint j whose
    parent p and a child c are seen lies on the circle where the spheres of its two bone
    lengths about them meet; where on it -- the swivel angle about the axis p -> c (a
    knee's or an elbow's, measured from a world axis carried along by the axis' minimal
    rotations) -- is interpolated over the gap by the package's cubic gap fill of the angle
    (:func:`mocapkit.gaps.fill`). The swivel moves slowly where the
    joint's path does not: a knee's 60-frame gap at 120 fps, 3.8 cm off with fill-auto's
    rigid / PCA candidates, 1.3 cm with a cubic through the position, is 0.48 cm this way
    (CMU 05_03, docs/results/auto_heldout.md); a trunk joint with several children is
    better filled by the others, so it is a candidate of ``fill-auto``'s per-gap choice.

    P (T, J, 3) cm, observed (T, J); parents (J,); bones (B, 2) child, parent and lengths
    (B,) cm of the fixed bones (:func:`fixed_bones`); ``measured`` (T, J), optional: the
    observed samples that were measured, not filled. Returns (P with the filled samples,
    filled (T, J)); filled only inside a gap of the angle (seen on both sides, and p and c
    seen from one side to the other: no extrapolation). Of several children the one seen
    most. ``(P, zeros)`` when no bone is fixed. A frame whose p or c was filled is filled
    only where the joint moves by at most :data:`KINEMATIC_MAX_GAIN` times a change of the
    p-c distance: near full extension a filled partner's error is amplified.

    >>> import numpy as np
    >>> t = np.linspace(0, 1, 50)
    >>> hip = np.zeros((50, 3)); ankle = np.stack([np.zeros(50), -70 + 10 * t, np.zeros(50)], 1)
    >>> root = np.tile([10.0, 0, 0], (50, 1))
    >>> a = np.arccos((70 - 10 * t) / 80)                  # knee bent in the x-y plane ...
    >>> knee = np.stack([40 * np.sin(a) * 0, -40 * np.cos(a), 40 * np.sin(a)], 1)  # ... turned to z
    >>> P = np.stack([root, hip, knee, ankle], 1); obs = np.ones((50, 4), bool); obs[20:30, 2] = False
    >>> Q, f = kinematic_fill(P, obs, [-1, 0, 1, 2], np.array([[1, 0], [2, 1], [3, 2]]),
    ...                       np.array([10.0, 40.0, 40.0]))
    >>> bool(f[20:30, 2].all()) and bool(np.abs(Q[20:30, 2] - knee[20:30]).max() < 1e-6)
    True
    """
    from .gaps import fill

    P = np.asarray(P, float)
    obs = np.asarray(observed, bool)
    T, J = obs.shape
    out, filled = P.copy(), np.zeros((T, J), bool)
    par = np.asarray(parents)
    L = {int(c): float(x) for (c, _), x in zip(np.asarray(bones).reshape(-1, 2), lengths) if x > 0}
    for j in range(J):
        p = int(par[j])
        if p < 0 or j not in L or obs[:, j].all():
            continue
        kids = [int(c) for c in np.flatnonzero(par == j) if int(c) in L]
        if not kids:
            continue
        c = max(kids, key=lambda k: int(obs[:, k].sum()))
        seen = obs[:, p] & obs[:, c]
        A, C = np.where(seen[:, None], P[:, p], 0.0), np.where(seen[:, None], P[:, c], 0.0)
        u, d, r, _ = sphere_circle(A, C, L[j], L[c])
        # reference: the world axis least along the axis on average (carried along below)
        ref = np.eye(3)[int(np.argmin(np.abs(u[seen]).mean(axis=0)))] if seen.any() else np.eye(3)[0]
        v = ref[None, :] - (u @ ref)[:, None] * u
        vn = np.linalg.norm(v, axis=1)
        seen &= vn > 1e-6
        v /= np.maximum(vn, 1e-300)[:, None]
        w = np.cross(u, v)
        o = A + d[:, None] * u
        q = np.where(obs[:, j, None], P[:, j], 0.0) - o
        known = seen & obs[:, j]
        if known.sum() < 4:
            continue
        # the reference turns about the axis as the axis moves -- fast where the axis nears
        # it; the angle is measured against the reference carried along by the axis' own
        # minimal rotations (parallel transport) instead: gamma, the reference's turn
        # beyond that, summed frame by frame, is known inside a gap too (p and c are seen),
        # so the angle to interpolate is th - gamma and the fill th = interpolated + gamma.
        # (The parent's parent as the reference, without the transport, put a raised arm's
        # elbow 9.1 cm off over a 60-frame gap of CMU 135_02, the protocol's martial-arts
        # clip, at 120 fps.)
        # Measured and not kept (2026-12-06, twenty-second session; auto on the 40 missing30
        # and 32 gaps10x60 cases of both clip sets): a straight knee's angle is undefined
        # (CMU 07_03 at 30 fps: 0.000 cm off the axis at three seen frames, its angle
        # flipping by pi, and a cubic through it 2.15 cm off over a 4-frame gap next to
        # them). Leaving frames under 0.1 / 1 cm off the axis out of the angle's known
        # frames: missing30 summed RMSE -0.4 / -0.8 % (07_03@30 0.125 -> 0.111 / 0.098),
        # gaps10x60 +2.2 / +2.7 % (run@120 0.77 -> 0.91 / 0.92: a knee's 60-frame gap next
        # to a straight frame, left to other fills before, was then filled 4.2 cm off);
        # interpolating the 2-D offset from the axis instead of the angle: missing30 -0.6 %,
        # gaps10x60 +52 % (run@120 3.4 cm: a cubic through the offset cuts a wide swivel)
        gam = np.zeros(T)
        pair = seen[1:] & seen[:-1]
        vt = _transport(u[:-1], u[1:], v[:-1])
        dg = np.arctan2(np.sum(np.cross(vt, v[1:]) * u[1:], axis=1), np.sum(vt * v[1:], axis=1))
        gam[1:] = np.cumsum(np.where(pair, dg, 0.0))
        th = np.full(T, np.nan)
        idx = np.flatnonzero(known)
        th[idx] = np.unwrap(np.arctan2(np.sum(q * w, axis=1), np.sum(q * v, axis=1))[idx] - gam[idx])
        thf = fill(th[:, None], known[:, None], kind="cubic")[:, 0] + gam
        # inside a gap of the angle, and no unseen frame between the gap and its ends
        # (gamma's sum would skip the axis' turn over it)
        run = np.cumsum(~seen)
        prev = np.maximum.accumulate(np.where(known, np.arange(T), -1))
        nxt = np.minimum.accumulate(np.where(known, np.arange(T), T)[::-1])[::-1]
        ok_run = (prev >= 0) & (nxt < T)
        ok_run &= run[np.clip(nxt, 0, T - 1)] == run[np.clip(prev, 0, T - 1)]
        can = ~obs[:, j] & seen & ok_run & np.isfinite(thf)
        if measured is not None:
            # d(d)/dD = (1 - (l1^2 - l2^2) / D^2) / 2 moves the circle's centre along the
            # axis and its radius by -(d / r) times that (r^2 = l1^2 - d^2)
            with np.errstate(divide="ignore", invalid="ignore"):
                dn = np.maximum(np.linalg.norm(C - A, axis=1), 1e-9)
                gain = np.abs(0.5 * (1.0 - (L[j] ** 2 - L[c] ** 2) / dn ** 2)) * np.sqrt(1.0 + (d / r) ** 2)
            can &= (measured[:, p] & measured[:, c]) | (gain <= KINEMATIC_MAX_GAIN)
        out[can, j] = (o + r[:, None] * (np.cos(thf)[:, None] * v + np.sin(thf)[:, None] * w))[can]
        filled[can, j] = True
    return out, filled


def hold_lengths(P: np.ndarray, pairs: np.ndarray, lengths: np.ndarray, *, sweeps: int = 10,
                 movable: np.ndarray | None = None, max_off: np.ndarray | None = None) -> np.ndarray:
    """Points moved so that each pair is ``lengths`` apart, both ends by the same amount
    along the pair's line (the distance-constraint projection of position-based dynamics,
    Müller, Heidelberger, Hennix & Ratcliff 2007, J. Vis. Commun. Image R. 18(2):109, with
    equal weights), in ``sweeps`` Gauss-Seidel passes over the pairs, vectorised over
    frames.

    Why: smoothing a bone's two ends channel by channel shortens a rotating bone (the
    chord of its arc) and leaves the noise along it; a skeleton format fixes the length.
    Measured on six of the ``auto`` protocol's cases (walk, jump, HDM05 kick at 30 and 120
    fps, 3 cm noise, after auto's smoothing): RMSE -11.5..-16 % at 0.02-0.09 ms per frame,
    against -14..-19 % for the full least-squares IK of the AMC writer at 0.5-1.0 ms per
    frame (11-25 times the cost).

    ``movable`` (T, J) bool: only these samples move (PBD with inverse mass 0 for the
    others), the whole length error onto the one end that moves -- the first of the pair
    (a skeleton's child) where both may; ``max_off`` (T, J) cm: a pair is left alone where
    its length is off by more than the moving end's value (a fill the length would pull
    far). Without ``movable`` every point may move and both ends share the move.

    P : (T, J, 3) cm, NaN where missing (a pair with a missing end is left as it is);
    pairs (B, 2) int; lengths (B,) cm. Returns a new (T, J, 3) array.

    >>> import numpy as np
    >>> P = np.array([[[0.0, 0, 0], [3.0, 0, 0]]])
    >>> hold_lengths(P, np.array([[1, 0]]), np.array([2.0]))[0].tolist()
    [[0.5, 0.0, 0.0], [2.5, 0.0, 0.0]]
    >>> hold_lengths(P, np.array([[1, 0]]), np.array([2.0]), movable=np.array([[False, True]]))[0].tolist()
    [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    L = np.asarray(lengths, dtype=float).reshape(-1)
    # joints first, (J, T, 3): a group's ends are then gathered as whole (T, 3) blocks, and
    # the weights and indices are made once, not every sweep (the same arithmetic as frames
    # first: 10,000 frames 125 -> 60 ms, 79 frames 3.0 -> 2.1 ms, six sweeps of CMU's bones, one thread)
    Q = np.array(np.asarray(P, dtype=float).transpose(1, 0, 2), order="C", copy=True)   # never P itself
    mv = None if movable is None else np.asarray(movable, bool).T                  # (J, T)
    mo = None if max_off is None else np.asarray(max_off, float).T
    steps = []
    for g in _disjoint_groups(pairs):
        # pairs that share no point: moved at once, as one after the other would move them
        a, b = pairs[g, 0], pairs[g, 1]
        if mv is None:
            wa = wb = np.full((len(g), 1, 1), 0.5)
        else:
            ma = mv[a]
            wa, wb = ma.astype(float)[..., None], (mv[b] & ~ma).astype(float)[..., None]
            if not (wa.any() or wb.any()):
                continue
        steps.append((a, b, L[g][:, None], wa, wb))
    # (a group's ends are distinct points, so each end is gathered once a step and written
    # back once; with every point finite -- a smoothed clip -- no NaN needs masking. The
    # same numbers; six sweeps of a CMU skeleton's bones 2.07 -> 1.49 ms on 62 frames, 3.31
    # -> 2.34 on 240: a short clip's time is the per-operation cost)
    complete = bool(np.isfinite(Q).all())
    with np.errstate(invalid="ignore"):
        for _ in range(int(sweeps)):
            for a, b, l, wa, wb in steps:
                Qa, Qb = Q[a], Q[b]
                d = Qa - Qb                                                   # (G, T, 3)
                n = np.sqrt(np.einsum("gti,gti->gt", d, d))                   # NaN with a missing end
                k = np.where(n > 1e-9, (n - l) / np.maximum(n, 1e-9), 0.0)
                if mo is not None:
                    lim = np.where(np.broadcast_to(wa[..., 0], k.shape) > 0, mo[a], mo[b])
                    k = np.where(np.abs(n - l) <= lim, k, 0.0)
                c = k[..., None] * d
                if not complete:
                    c = np.where((k != 0.0)[..., None], c, 0.0)               # 0 with a missing end
                Qa -= wa * c
                Qb += wb * c
                Q[a] = Qa
                Q[b] = Qb
    return Q.transpose(1, 0, 2).copy()


def bone_chains(bones: np.ndarray, lengths: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The pairs of consecutive bones, grandparent -> parent -> child: (upper, lower), each
    (S,) indices into ``bones`` (B, 2) (child, parent), where bone ``lower`` hangs from the
    joint bone ``upper`` ends at. With ``lengths`` (B,) cm, bones of zero length (a BVH
    ``_base`` joint's) take no part.

    >>> bone_chains(np.array([[1, 0], [2, 1], [3, 2], [4, 0]]))
    (array([0, 1]), array([1, 2]))
    """
    bones = np.asarray(bones, dtype=np.int64).reshape(-1, 2)
    ok = np.ones(len(bones), bool) if lengths is None else np.asarray(lengths, float).reshape(-1) > 1e-6
    up = {int(c): b for b, c in enumerate(bones[:, 0]) if ok[b]}     # a joint's bone to its parent
    lower = np.array([b for b, p in enumerate(bones[:, 1].tolist()) if ok[b] and p in up], np.int64)
    return np.array([up[int(bones[b, 1])] for b in lower], np.int64), lower


def _disjoint_groups(pairs: np.ndarray) -> list[np.ndarray]:
    """The pairs (B, 2) split into groups in which no point appears twice, each pair in a
    later group than every earlier pair it shares a point with: :func:`hold_lengths` moves
    each group in one array operation, and the result is that of taking the pairs one
    after the other in their order (pairs with no point in common commute) -- so a
    skeleton's bones in parent-first order still leave a moving child final after one
    sweep. The 30 bones of a CMU skeleton take 13 groups instead of 30 steps per sweep."""
    colour = np.zeros(len(pairs), np.int64)
    last: dict[int, int] = {}
    for i, (a, b) in enumerate(pairs.tolist()):
        colour[i] = c = max(last.get(a, -1), last.get(b, -1)) + 1
        last[a] = last[b] = c
    return [np.flatnonzero(colour == c) for c in range(int(colour.max()) + 1)] if len(pairs) else []


def steady_spans(P: np.ndarray, bones: np.ndarray, lengths: np.ndarray, err: np.ndarray,
                 k: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Two-bone spans (a joint to its grandparent, through its parent) that stay steady in
    the cleaned positions P, and their length: pairs to hold with :func:`hold_lengths`
    besides the bones.

    Why: a skeleton file lets a joint turn, but many barely do (in CMU captures the
    clavicles, the spine's links, the wrists, fingers and thumbs stay within a few degrees
    of their parent's direction), and there the span through the joint is nearly fixed
    while a cleaned pose still bends it by its leftover error. A span counts as steady
    where its std over the clip is under ``k`` x the spread its two ends' errors alone
    would give it (sqrt(err_c^2 + err_g^2), cm). Its length is not the median of the
    cleaned span: leftover error only ever bends a nearly straight joint, which shortens
    the span (CMU 01_01 at 30 fps, 3 cm of noise through AMC: a fingers-to-wrist span of
    7.28 cm read 5.71 as the cleaned median). The bend angle theta between the two bones is
    taken as sqrt(max(mean(theta^2) - 2 var(theta), 0)) -- for a steady joint theta is
    |theta_0 + n|, n the error's 2-D bend, so mean(theta^2) = theta_0^2 + 2 s^2 and
    var(theta) ~ s^2 -- and the span is the law of cosines of the two bones' lengths and
    that angle.

    Measured (2026-12-05, ninth session; the held-out clips of the ``auto`` protocol at 30
    fps, geometric mean RMSE after / before over ten clips), the spans projected after
    auto's output had its bones held: read back from AMC, gauss3 -4.7 % (each clip
    0.94-0.96), gauss1 -1.7 % (0.95-1.003); positions with white 3 cm noise in memory -2.4 %
    (0.96-0.99); the cleaned median as the length: -3.3 / -1.6 % through AMC. As auto uses
    them (one projection with the bones, before those are held alone), end to end through
    AMC files: see ``auto._hold_bones`` and docs/results/auto_files.md.

    P (T, J, 3) cm, complete; bones (B, 2) (child, parent) and lengths (B,) cm, the bones
    the format fixes (:func:`fixed_bones`); err (J,) the cleaned positions' error per
    coordinate (cm). Returns (pairs (S, 2) int -- joint, grandparent; lengths (S,) cm);
    S = 0 where none is steady. Spans through a zero-length bone (a BVH ``_base`` joint)
    are left out: the span is then the other bone.

    >>> import numpy as np
    >>> t = np.linspace(0, 1, 50)[:, None]
    >>> arm = np.stack([np.zeros((50, 3)), np.hstack([10 * np.cos(t), 10 * np.sin(t), 0 * t]),
    ...                 np.hstack([20 * np.cos(t), 20 * np.sin(t), 0 * t])], axis=1)
    >>> pairs, span = steady_spans(arm, np.array([[1, 0], [2, 1]]), np.array([10.0, 10.0]),
    ...                            np.full(3, 0.1))
    >>> pairs.tolist(), np.round(span, 3).tolist()
    ([[2, 0]], [20.0])
    """
    bones = np.asarray(bones, dtype=np.int64).reshape(-1, 2)
    lengths = np.asarray(lengths, dtype=float).reshape(-1)
    b1, b2 = bone_chains(bones, lengths)
    if not len(b2):
        return np.zeros((0, 2), np.int64), np.zeros(0)
    c, p, g = bones[b2, 0], bones[b2, 1], bones[b1, 1]
    pairs = np.stack([c, g], axis=1)
    err = np.asarray(err, dtype=float)
    steady = np.std(bone_lengths(P, pairs), axis=0) < k * np.sqrt(err[c] ** 2 + err[g] ** 2)
    if not steady.any():
        return np.zeros((0, 2), np.int64), np.zeros(0)
    c, p, g, b1, b2, pairs = c[steady], p[steady], g[steady], b1[steady], b2[steady], pairs[steady]
    u, v = P[:, p] - P[:, g], P[:, c] - P[:, p]                               # (T, S, 3)
    cos = np.einsum("tsi,tsi->ts", u, v) / np.maximum(np.linalg.norm(u, axis=2) * np.linalg.norm(v, axis=2), 1e-12)
    th = np.arccos(np.clip(cos, -1.0, 1.0))
    th0 = np.sqrt(np.maximum(np.mean(th ** 2, axis=0) - 2.0 * np.var(th, axis=0), 0.0))
    l1, l2 = lengths[b1], lengths[b2]
    return pairs, np.sqrt(l1 ** 2 + l2 ** 2 + 2.0 * l1 * l2 * np.cos(th0))


def steady_clusters(P: np.ndarray, observed: np.ndarray, fps: float, tol_cm: float, *,
                    window_s: float = 0.25, min_size: int = 4, apart_cm: float = 1.0,
                    shape_from: np.ndarray | None = None, return_shapes: bool = False):
    """Groups of points that move as one rigid body, found from *noisy* positions: what
    :func:`hold_clusters` may hold.

    :func:`find_clusters` asks for distances whose spread is under a fixed level, which
    noise of a few centimetres hides. Here a pair is steady where the slow part of its
    distance -- its moving average over ``window_s`` -- varies by at most ``tol_cm`` (std)
    beyond what the pair's own white noise leaves in that average (the noise from the
    distance's fourth differences, :func:`mocapkit.signal.estimate_noise`, divided by the
    window's length); steady pairs are grouped by complete linkage, as in
    :func:`find_clusters`. Distances alone do not make a body rigid: a knee swinging about
    a hip keeps its distances to the pelvis points within 0.6 cm while it moves 2.5 cm off
    any rigid fit of them (a nearly flat group bends out of its plane at second order
    only). So each group is confirmed on its rigid fit: every point's residual from the
    group's template, moved by :func:`kabsch` onto each frame (taken in the group's own
    frame, where an error of the template is a constant), must have a slow part within
    ``tol_cm`` too; the point whose residual is furthest off, and any over twice the limit,
    are dropped until all are within it.
    A group needs ``min_size`` points at least ``apart_cm`` apart (joints at one place, a
    BVH ``_base`` joint and its parent, count once).

    P (T, J, 3) cm; observed (T, J); fps the frame rate. Returns lists of point indices,
    largest first; [] where the clip is shorter than four windows. ``shape_from`` (T, J, 3),
    complete: the positions each group's shape (its template) is taken from, e.g. the
    cleaned ones (default P); with ``return_shapes`` also those shapes ((K, 3) each), for
    :func:`hold_clusters`.

    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> t = np.linspace(0, 4, 480)
    >>> body = np.array([[0, 0, 0], [10, 0, 0], [0, 8, 0], [0, 0, 6.0]])
    >>> c, s = np.cos(t), np.sin(t)
    >>> R = np.stack([np.stack([c, -s, 0 * t], 1), np.stack([s, c, 0 * t], 1),
    ...               np.tile([0.0, 0, 1], (480, 1))], 1)               # turning about z
    >>> P = np.einsum("tij,kj->tki", R, body) + rng.normal(0, 1.0, (480, 4, 3))
    >>> free = np.stack([20 * np.sin(2 * t), 5 * t, 0 * t], 1)[:, None] + rng.normal(0, 1.0, (480, 1, 3))
    >>> steady_clusters(np.concatenate([P, free], axis=1), np.ones((480, 5), bool), 120.0, 0.3)
    [[0, 1, 2, 3]]
    """
    from scipy.cluster.hierarchy import fcluster, linkage
    from scipy.ndimage import uniform_filter1d
    from scipy.spatial.distance import squareform

    from .signal import estimate_noise

    P = np.asarray(P, dtype=float)
    obs = np.asarray(observed, bool) & np.isfinite(P).all(axis=-1)
    T, J, _ = P.shape
    w = max(3, int(round(float(window_s) * float(fps))))
    S = P if shape_from is None else np.asarray(shape_from, dtype=float)
    if J < min_size or T < 4 * w:
        return ([], []) if return_shapes else []

    def slow_var(X: np.ndarray, ok: np.ndarray, w: int = w) -> np.ndarray:
        """Per column of X (T, K): the variance of its w-frame moving average less the
        share its white noise puts there."""
        if ok.all():                              # (the common case, twice as fast)
            N = np.asarray(estimate_noise(X, method="diff4-rms"), float)
            V = uniform_filter1d(X, w, axis=0, mode="nearest").var(axis=0)
            return np.where(np.isfinite(V) & np.isfinite(N), V - np.nan_to_num(N) ** 2 / w, np.inf)
        Z = np.where(ok, X, 0.0)
        N = np.asarray(estimate_noise(Z, ok, method="diff4-rms"), float)
        c = uniform_filter1d(ok.astype(float), w, axis=0, mode="nearest")
        A = uniform_filter1d(Z, w, axis=0, mode="nearest") / np.maximum(c, 1e-12)
        A[c < 0.5] = np.nan                       # windows mostly missing say nothing
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            V = np.nanvar(A, axis=0)
        return np.where(np.isfinite(V) & np.isfinite(N), V - np.nan_to_num(N) ** 2 / w, np.inf)

    # every pair's distance, in chunks of pairs (memory O(T x chunk)), at about 30 frames
    # a second: the proposal needs no more (the slow part is a quarter of a second or
    # longer, and white noise kept every k-th frame is white), and at 120 fps all frames
    # made this a fifth of auto's time
    k = max(1, int(round(fps / 30.0)))
    Pd, od = P[::k], obs[::k]
    wd = max(3, int(round(float(window_s) * float(fps) / k)))
    Pd = np.where(od[..., None], Pd, 0.0)
    Pd = Pd - Pd.sum(axis=1, keepdims=True) / np.maximum(od.sum(axis=1), 1)[:, None, None]
    i, j = np.triu_indices(J, 1)
    E = np.zeros((J, J))
    step = max(16, 2_000_000 // len(Pd))
    for a in range(0, len(i), step):
        ii, jj = i[a:a + step], j[a:a + step]
        ok = od[:, ii] & od[:, jj]
        # |p_i - p_j|^2 from the frame's Gram matrix (points centred on the frame's mean:
        # no cancellation worth the name), one batched product instead of a pair gather
        lo, hi = int(ii.min()), int(max(ii.max(), jj.max())) + 1
        Gm = Pd[:, lo:hi] @ Pd[:, lo:hi].transpose(0, 2, 1)              # (T, n, n)
        n2 = np.einsum("tii->ti", Gm)
        D = np.sqrt(np.maximum(n2[:, ii - lo] + n2[:, jj - lo] - 2.0 * Gm[:, ii - lo, jj - lo], 0.0))
        ex = np.sqrt(np.maximum(slow_var(D, ok, wd), 0.0))
        E[ii, jj] = E[jj, ii] = np.where(ok.sum(axis=0) >= 4 * wd, ex, np.inf)
    E = np.minimum(E, 1e6)
    # the distances only propose groups: a pair's distance reads its two points' noise
    # along one direction, the rigid fit's residual (below) three coordinates of each point,
    # so its slow part is the sharper test -- on a body of five points under 2 cm of noise
    # over 600 frames, pure chance lifts a pair's distance term to 0.6 cm and a residual's
    # to 0.2
    lab = fcluster(linkage(squareform(E, checks=False), method="complete"), t=PROPOSE * float(tol_cm),
                   criterion="distance")
    out = []
    for label in np.unique(lab):
        g = np.flatnonzero(lab == label)
        if len(g) < min_size:
            continue
        full = obs[:, g].all(axis=1) & np.isfinite(S[:, g]).all(axis=(1, 2))      # (S: the shapes)
        if full.sum() < 4 * w:
            continue
        Q = P[full][:, g]
        # the test's shape once, from the tested positions themselves (a dropped point
        # leaves the others' as it is)
        tm = cluster_template(Q, np.ones(Q.shape[:2], bool), n_iter=1, max_frames=TEMPLATE_FRAMES,
                              start="middle")
        keep = np.arange(len(g))
        while len(keep) >= min_size:
            B = np.broadcast_to(tm[keep], (len(Q), len(keep), 3))
            R, t = kabsch(B, Q[:, keep])
            # the residual in the group's own frame: there an error of the shape is a
            # constant, which the variance takes out (in the world's axes it turns with
            # the body and reads as a slow bend: 0.3 cm on a shape from 128 frames with 3 cm
            # of noise, and no group was confirmed)
            r = (Frame(origin=t, rotation=R).to_local(Q[:, keep]) - tm[keep]).reshape(len(Q), -1)
            ex = np.sqrt(np.maximum(slow_var(r, np.ones(r.shape, bool)).reshape(len(keep), 3).sum(axis=1) / 3, 0.0))
            if ex.max() <= tol_cm:
                if _apart(tm[keep], apart_cm) >= min_size:
                    out.append((g[keep].tolist(), full))
                break
            # the worst point goes, and with it every point off by over twice the limit
            # (one fit less per such point; the rest are judged again without them)
            drop = (ex > 2.0 * tol_cm) | (np.arange(len(keep)) == int(np.argmax(ex)))
            keep = keep[~drop]
    out.sort(key=lambda gs: (-len(gs[0]), gs[0][0]))
    groups = [g for g, _ in out]
    if not return_shapes:
        return groups
    return groups, [cluster_template(S[full][:, g], np.ones((int(full.sum()), len(g)), bool), n_iter=2,
                                     max_frames=TEMPLATE_FRAMES, start="middle") for g, full in out]


#: frames (evenly spread) :func:`steady_clusters` and :func:`hold_clusters` take a group's
#: shape from (:func:`cluster_template`'s ``max_frames``): a median shape needs no more, and
#: all frames of a long clip made :func:`steady_clusters` a third of auto's time
TEMPLATE_FRAMES = 128


#: :func:`steady_clusters`: pairs whose distance's slow part varies by up to this times
#: the tolerance are grouped, for the rigid fit's residual to confirm
PROPOSE = 3.0


def _apart(X: np.ndarray, min_cm: float) -> int:
    """How many of the points X (K, 3) lie at distinct places (greedily, more than
    ``min_cm`` from every one counted before)."""
    kept: list[np.ndarray] = []
    for x in X:
        if all(np.linalg.norm(x - y) > min_cm for y in kept):
            kept.append(x)
    return len(kept)


def hold_clusters(P: np.ndarray, clusters: Sequence[Sequence[int]],
                  shapes: Sequence[np.ndarray] | None = None) -> np.ndarray:
    """P (T, J, 3) cm with every cluster (lists of point indices, e.g. from
    :func:`steady_clusters`) made rigid: its shape -- ``shapes`` ((K, 3) each, e.g. from
    :func:`steady_clusters`), or the aligned median of its frames -- moved onto each
    frame's points by :func:`kabsch` (all clusters in one batch), in their place.
    Non-finite points stay as they are (and do not weigh in the fit); a frame with fewer
    than three finite points of a cluster is left alone. Returns a new array.

    Why: noise moves a rigid body's points independently, and a rigid fit of K points
    keeps only the 6 of their 3K coordinates the body's motion has -- for K = 12 finger
    and hand joints 6 of 36: about 40 % of their noise (RMS) is left.

    >>> import numpy as np
    >>> rng = np.random.default_rng(1)
    >>> body = rng.normal(0, 10, (6, 3))
    >>> P = body + rng.normal(0, 1.0, (200, 6, 3))
    >>> err = lambda Q: float(np.sqrt(np.mean((Q - body) ** 2)))
    >>> bool(err(hold_clusters(P, [list(range(6))])) < 0.8 * err(P))
    True
    """
    P = np.array(P, dtype=float)
    clusters = [list(g) for g in clusters]
    if not clusters:
        return P
    T, G, K = P.shape[0], len(clusters), max(len(g) for g in clusters)
    idx = np.zeros((G, K), np.int64)
    inn = np.zeros((G, K), bool)                   # padded: the clusters side by side
    tm = np.zeros((G, K, 3))
    for c, g in enumerate(clusters):
        idx[c, :len(g)], inn[c, :len(g)] = g, True
        if shapes is not None:
            tm[c, :len(g)] = shapes[c]
            continue
        Q = P[:, g]
        ok = np.isfinite(Q).all(axis=2)
        tm[c, :len(g)] = cluster_template(Q, ok, n_iter=2, max_frames=TEMPLATE_FRAMES)
    inn &= np.isfinite(tm).all(axis=2)
    tm = np.where(inn[..., None], tm, 0.0)
    Q = P[:, idx]                                                       # (T, G, K, 3)
    w = np.isfinite(Q).all(axis=3) & inn                                # (T, G, K)
    use = w.sum(axis=2) >= 3                                            # (T, G)
    B = np.broadcast_to(tm, Q.shape)
    R, t = kabsch(B, np.where(w[..., None], Q, 0.0), w.astype(float))
    fitted = apply_rigid(R, t, B)
    put = w & use[..., None]
    for c, g in enumerate(clusters):
        k = len(g)
        P[:, g] = np.where(put[:, c, :k, None], fitted[:, c, :k], P[:, g])
    return P


def distance_noise(P: np.ndarray, observed: np.ndarray, *, min_distance_cm: float = 3.0,
                   max_scale_cm: float = 5.0, min_points: float = 0.5, n_ref: int = 512) -> float:
    """Positional noise (cm, per coordinate) from how much rigid distances vary.

    Two points of one rigid segment keep their distance d; white noise of std sigma per
    coordinate on both moves d by the noise along the segment, std ``sqrt(2) sigma``
    (for d >> sigma), whatever the motion. So each point's most rigid partner
    (:func:`rigid_partners`: the smallest 1.4826 MAD of the distance; partners closer than
    ``min_distance_cm`` are left out, as the distance of near-coincident points is not
    Gaussian) gives ``scale / sqrt(2)``, and the median over the points is returned. The
    partner is chosen on the even frames and its scale read on the odd ones, and the other
    way round (the two averaged): the smallest of noisy scales read on the frames that chose
    it is biased low (measured 2-12 % at 120 fps, up to 30 % on 240 frames at 30 fps).
    Unlike the time differences of :func:`mocapkit.signal.estimate_noise`, no motion leaks
    in. On the ``auto`` protocol's clips (CMU / HDM05 joint positions, 8 s; samples of 15 cm
    spikes on 10 % masked out as auto does) it reads 0 with no noise, where ``diff4-mad``
    reads 0.019-0.134 cm at 30 fps and 0.0006-0.025 at 120; with white noise of 0.1 / 0.2 /
    0.5 cm it reads 0.087-0.103 / 0.184-0.206 / 0.458-0.518 cm at 30 fps and 0.095-0.103 /
    0.192-0.206 / 0.480-0.514 at 120.

    What it cannot see: noise that keeps the distances (a joint-angle jitter of a skeleton
    solver moves a bone's end across, not along, the bone), and on markers it also holds
    the skin's motion against the bone (an upper bound of the noise there).

    ``n_ref`` evenly spaced frames are used, half per half (:func:`rigid_partners`; 512: 22 ms
    on 960 frames of CMU 135_02, where 0.1 / 0.5 cm noise reads 0.097-0.100 / 0.492-0.498).

    P : (T, J, 3) cm; observed : (T, J) bool. Returns NaN when fewer than ``min_points`` x J
    points have a partner (scale <= ``max_scale_cm``, median distance >= ``min_distance_cm``).

    >>> rng = np.random.default_rng(0)
    >>> T = 400
    >>> a = np.cumsum(rng.normal(size=(T, 1, 3)), axis=0)          # a wandering segment
    >>> P = np.concatenate([a, a + [10.0, 0, 0], a + [0, 20.0, 0]], axis=1)
    >>> round(distance_noise(P, np.ones((T, 3), bool)), 3)
    0.0
    >>> 0.15 < distance_noise(P + 0.2 * rng.normal(size=P.shape), np.ones((T, 3), bool)) < 0.22
    True
    """
    P = np.asarray(P, dtype=float)
    obs = np.asarray(observed, dtype=bool)
    J = P.shape[1]
    if J < 2 or P.shape[0] < 2:
        return float("nan")

    def scales(sl):             # (J, J) robust scale of every pair, inf where unusable
        part, real, med, sc = rigid_partners(P[sl], obs[sl], n_partners=J - 1,
                                             max_scale_cm=max_scale_cm, n_ref=n_ref // 2)
        out = np.full((J, J), np.inf)
        ok = real & (med >= float(min_distance_cm))
        np.put_along_axis(out, part, np.where(ok, sc, np.inf), axis=1)
        return out

    # cross-fitted: the partner is chosen on one half of the frames and its scale read on
    # the other (the minimum of noisy scales read on the same frames is biased low: 2-12 %
    # at 120 fps, up to 30 % on 240 frames at 30 fps)
    halves = [scales(slice(0, None, 2)), scales(slice(1, None, 2))]
    s = []
    for a, b in ((0, 1), (1, 0)):
        best = np.argmin(halves[a], axis=1)
        chosen = np.isfinite(halves[a][np.arange(J), best])
        s.append(np.where(chosen, halves[b][np.arange(J), best], np.inf))
    s = 0.5 * (s[0] + s[1])
    s = s[np.isfinite(s)]
    if s.size < max(float(min_points) * J, 1):
        return float("nan")
    return float(np.median(s) / np.sqrt(2.0))


def distance_consistency(P: np.ndarray, observed: np.ndarray, *, n_partners: int = 4,
                         max_scale_cm: float = 1.0, floor_cm: float = 1.0,
                         n_ref: int = 1024, min_spread: float = 0.1,
                         partners: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
                         per_partner: bool = False, pinning: bool = True) -> tuple[np.ndarray, ...]:
    """Per sample, how many of its point's rigid partners keep their usual distance to it.

    A measured sample keeps its distance to every point of its own body segment (a bone's
    other end, a marker of the same cluster); a spike -- a sample moved by 15 cm in a random
    direction -- changes most of them by centimetres, however fast the true motion is. This
    is the test a robust smoothing spline cannot make in fast motion, where it cuts corners
    by more than any spike limit (on CMU clips at 120 fps: runs of 3-4 rejected hand samples
    10-12 cm off their fill).

    Partners: :func:`rigid_partners`. A partner *agrees* at frame t when the distance there
    is within ``max(floor_cm, 4.685 scale)`` of its median (the bisquare limit of
    :func:`mocapkit.solvers.gcv_spline.gcv_smooth`'s robust test).

    Distances that agree *pin* the sample only when the partners lie in three independent
    directions from it: at a hinge (a knee between hip and ankle, an elbow between shoulder
    and a collinear forearm) a displacement normal to the limb's plane leaves both bone
    lengths unchanged to first order, and on CMU clips 1 of ~3,000 random 15 cm spikes kept
    them within 0.5 cm. ``pinned`` is True where the unit directions u_k to the agreeing
    partners have ``lambda_min(sum_k u_k u_k^T) >= min_spread``.

    ``partners``: the result of :func:`rigid_partners` on the same P and observed, for a
    caller that needs it too (computed here when None; ``n_partners``, ``max_scale_cm`` and
    ``n_ref`` are then unused), or any (part, real, median, scale) of that form.
    ``pinning=False``: ``pinned`` is not computed (all False; a 3 x 3 eigenproblem per sample).

    P : (T, J, 3) cm; observed : (T, J) bool. Returns (agree, disagree, pinned), (T, J):
    the number (int8) of observed partners at frame t that agree / disagree (0 and 0 at an
    unobserved sample or a point without partners), and whether the agreeing ones pin it;
    with ``per_partner`` a fourth, (T, J, K) int8: +1 where partner slot k agrees, -1
    where it disagrees, 0 where it is not observed or not real (the slots of ``partners``).
    Memory O(T J n_partners + n_ref J^2).

    >>> import numpy as np
    >>> t = np.linspace(0, 1, 50)[:, None]
    >>> P = np.stack([np.hstack([t * 100, t * 0, t * 0]) + [0, 10 * i, 0] for i in range(4)], 1)
    >>> P[20, 1] += [0, 0, 15.0]                 # a spike on point 1
    >>> agree, disagree, pinned = distance_consistency(P, np.ones((50, 4), bool), n_partners=3)
    >>> int(disagree[20, 1]), int(agree[20, 1]), int(agree[21, 1])
    (3, 0, 3)
    >>> bool(pinned[21, 1])                     # all four points on one line: nothing pins it
    False
    """
    P = np.asarray(P, dtype=float)
    obs = np.asarray(observed, dtype=bool) & np.isfinite(P).all(axis=-1)
    T, J, _ = P.shape
    agree = np.zeros((T, J), np.int8)
    disagree = np.zeros((T, J), np.int8)
    pinned = np.zeros((T, J), bool)
    if J < 2 or (partners is None and T < 3):           # given partners: any frame count
        K0 = 0 if partners is None else partners[0].shape[1]
        return (agree, disagree, pinned) + ((np.zeros((T, J, K0), np.int8),) if per_partner else ())
    if partners is None:
        partners = rigid_partners(P, obs, n_partners=n_partners, max_scale_cm=max_scale_cm, n_ref=n_ref)
    part, real, mref, scale = partners
    slots = np.zeros((T,) + part.shape, np.int8) if per_partner else None
    lim = np.maximum(float(floor_cm), 4.685 * np.nan_to_num(scale))
    jj = np.arange(J)
    for sl in frame_blocks(T):                     # blocks of frames: (block, J, K) arrays
        v = P[sl][:, jj[:, None]] - P[sl][:, part]                          # (b, J, K, 3)
        d = np.linalg.norm(v, axis=-1)                                      # (b, J, K)
        both = obs[sl][:, :, None] & obs[sl][:, part] & real
        off = np.abs(d - mref) > lim
        good = both & ~off
        agree[sl] = good.sum(axis=2)
        disagree[sl] = (both & off).sum(axis=2)
        if slots is not None:
            slots[sl] = good.astype(np.int8) - (both & off)
        if pinning:
            u = np.where(good[..., None], v / np.maximum(d, 1e-9)[..., None], 0.0)
            spread = np.linalg.eigvalsh(np.einsum("tjki,tjkl->tjil", u, u))[..., 0]
            pinned[sl] = spread >= float(min_spread)
    return (agree, disagree, pinned) + ((slots,) if per_partner else ())


def find_clusters(P: np.ndarray, observed: np.ndarray, *, max_std_cm: float = 1.0,
                  min_common: int = 20, min_size: int = 4) -> list[list[int]]:
    """Rigid clusters found from the data: groups of markers whose pairwise distances vary
    by less than ``max_std_cm`` (standard deviation over the frames where both are seen).

    Complete-linkage agglomerative clustering (scipy) on the (J, J) matrix of distance
    standard deviations, cut at ``max_std_cm``: every pair inside a cluster is rigid to
    that level (a chain A~B~C with A and C not rigid is not merged). Pairs seen together in
    fewer than ``min_common`` frames cannot be in one cluster. Only clusters of at least
    ``min_size`` markers are returned (a marker's gap needs 3 donors of its cluster), as
    lists of marker indices, largest first.

    Measured on the shared captures (docs/results/fill.md, section 4): head bands and
    technical clusters (marker plates, a wheelchair, a box) keep their distances to a std
    of 0.04-0.5 cm; pelvis and trunk skin markers 0.5-1 cm; markers across a joint more.
    The 1 cm default finds the head, pelvis, trunk and technical clusters.
    """
    from scipy.cluster.hierarchy import fcluster, linkage
    from scipy.spatial.distance import squareform

    P = np.asarray(P, dtype=float)
    J = P.shape[1]
    if J < 2:
        return []
    _, std, n = distance_stats(P, observed)
    big = 1e6
    D = np.where((n >= max(int(min_common), 2)) & np.isfinite(std), std, big)
    D = np.minimum(D, D.T)
    np.fill_diagonal(D, 0.0)
    Z = linkage(squareform(D, checks=False), method="complete")
    lab = fcluster(Z, t=float(max_std_cm), criterion="distance")
    groups = [np.flatnonzero(lab == k).tolist() for k in np.unique(lab)]
    groups = [g for g in groups if len(g) >= int(min_size)]
    return sorted(groups, key=lambda g: (-len(g), g[0]))


def parse_clusters(spec, names: Sequence[str]) -> list[list[int]]:
    """Explicit clusters: a list of lists of marker names (or indices), or a path to a JSON
    file holding that list. Returns lists of marker indices; unknown names raise
    :class:`~mocapkit.errors.MocapValueError`; a marker in two clusters too."""
    path = None
    if isinstance(spec, (str, os.PathLike)):
        path = os.fspath(spec)
        try:
            with open(path, encoding="utf-8") as f:
                spec = json.load(f)
        except OSError as e:
            raise MocapValueError(f"cannot read the cluster file {path!r}: {e.strerror or e}") from None
        except json.JSONDecodeError as e:
            raise MocapFormatError(path, f"not a JSON list of marker-name lists ({e})") from None
    if not isinstance(spec, (list, tuple)) or not all(isinstance(g, (list, tuple)) for g in spec):
        what = f"the cluster file {path!r}" if path else "clusters"
        raise MocapValueError(f"{what} must be a list of lists of marker names, "
                              f'e.g. [["LFHD", "RFHD", "LBHD", "RBHD"]]')
    index = {n: i for i, n in enumerate(names)}
    short = {}
    for i, n in enumerate(names):                  # "Subject:LFHD" also answers to "LFHD"
        short.setdefault(str(n).split(":")[-1], []).append(i)
    out, seen = [], set()
    for g in spec:
        idx = []
        for m in g:
            if isinstance(m, (int, np.integer)) and not isinstance(m, bool):
                if not 0 <= int(m) < len(names):
                    raise MocapValueError(f"cluster marker index {m} out of range (0..{len(names) - 1})")
                i = int(m)
            elif str(m) in index:
                i = index[str(m)]
            elif len(short.get(str(m), [])) == 1:
                i = short[str(m)][0]
            else:
                more = " ..." if len(names) > 8 else ""
                raise MocapValueError(f"cluster marker {m!r} is not a marker of this motion "
                                      f"(markers: {', '.join(map(str, names[:8]))}{more})")
            if i in seen:
                raise MocapValueError(f"marker {names[i]!r} is in more than one cluster")
            seen.add(i)
            idx.append(i)
        if idx:
            out.append(idx)
    return out


# -- the fill -----------------------------------------------------------------------------
def cluster_template(P: np.ndarray, observed: np.ndarray, *, n_iter: int = 5,
                     min_points: int = 3, max_frames: int | None = None,
                     start: Literal["most", "middle"] = "most") -> np.ndarray:
    """Robust average shape of a rigid cluster: generalised Procrustes with missing markers.

    P : (T, K, 3) the cluster's markers (cm), observed (T, K). Every frame that sees at
    least ``min_points`` markers is rigidly aligned (:func:`kabsch`) onto the current
    template and the template is the per-marker median of the aligned positions;
    ``n_iter`` rounds, vectorised over frames. Returns (K, 3) cm (NaN for a marker never
    seen in an aligned frame), in the frame of the frame it starts from: the one that sees
    most markers (``start="most"``), or the middle one (``"middle"``: complete frames of a
    group whose first frames may be unlike the rest). ``max_frames``: at most that many
    frames, evenly spread, are used (a median shape needs no more).
    """
    P = np.asarray(P, dtype=float)
    obs = np.asarray(observed, bool) & np.isfinite(P).all(axis=-1)
    use = obs.sum(axis=1) >= min_points
    if not use.any():
        return np.full(P.shape[1:], np.nan)
    Q, o = P[use], obs[use]
    if max_frames is not None and len(Q) > max_frames:
        sub = spaced_frames(len(Q), max_frames)
        Q, o = Q[sub], o[sub]
    best = int(np.argmax(o.sum(axis=1))) if start == "most" else len(Q) // 2
    tmpl = np.where(o[best][:, None], Q[best], np.nan)
    complete = bool(o.all())      # (the frames used see at least min_points markers)
    for _ in range(int(n_iter)):
        if complete:                # (no missing-point bookkeeping: three times faster)
            R, t = kabsch(np.broadcast_to(tmpl, Q.shape), Q)
            tmpl = np.median(Frame(origin=t, rotation=R).to_local(Q), axis=0)
            continue
        have = np.isfinite(tmpl).all(axis=1)
        w = (o & have[None, :]).astype(float)
        R, t = kabsch(np.where(have[:, None], tmpl, 0.0)[None].repeat(len(Q), 0), Q, w)
        # frame -> template: R^T (q - t)
        aligned = Frame(origin=t, rotation=R).to_local(np.where(o[..., None], Q, 0.0))
        ok = o & (w.sum(axis=1) >= min_points)[:, None]
        aligned[~ok] = np.nan
        new = nanmedian0(aligned)
        tmpl = np.where(np.isfinite(new), new, tmpl)
    return tmpl


def _nearest_ref(ok: np.ndarray, s: int, e: int) -> tuple[int | None, int | None]:
    """Last frame < s and first frame >= e where ``ok`` (T,) holds."""
    before = np.flatnonzero(ok[:s])
    after = np.flatnonzero(ok[e:])
    return (int(before[-1]) if len(before) else None, int(after[0]) + e if len(after) else None)


def rigid_fill(P: np.ndarray, observed: np.ndarray, clusters: Sequence[Sequence[int]], *,
               reference: str = "ends", min_donors: int = 3, min_spread_cm: float = 0.5
               ) -> tuple[np.ndarray, np.ndarray]:
    """Rigid-body gap fill: a marker's missing frames rebuilt from >= ``min_donors`` markers
    of its rigid cluster by a least-squares rigid fit (:func:`kabsch`).

    Parameters
    ----------
    P : (T, J, 3) positions, cm (NaN where missing).
    observed : (T, J) bool.
    clusters : lists of marker indices (:func:`find_clusters` or :func:`parse_clusters`).
    reference : the reference shape the donors are fitted from

        * ``"ends"`` (Vicon Nexus style): the frames nearest to the gap where the missing
          marker and >= ``min_donors`` donors are observed, one before and one after; each
          gives a prediction ``R_t p_ref + t_t`` (fit of the donors from the reference frame
          to frame t, the donors seen in both), and the two are blended linearly over the
          gap (an edge gap uses its one side). The fill meets both ends of the gap.
        * ``"average"``: a robust average shape of the cluster over all frames
          (:func:`cluster_template`) fitted to the donors seen in each frame.

    min_donors : fewest donors seen in a frame (and in the reference frame) for a fit.
    min_spread_cm : donors (nearly) collinear -- second singular value of their spread
        below ``min_spread_cm^2`` per unit weight -- give no fit (the rotation about their
        line is undetermined).

    Returns
    -------
    (P_filled (T, J, 3), filled (T, J) bool): observed samples unchanged, filled samples
    set, everything else NaN (markers outside every cluster, frames with too few donors).

    Measured (docs/results/fill.md, hidden blocks of 0.25-2 s on real captures, RMSE
    pooled): tennis serve ``"ends"`` 0.71 cm vs ``"average"`` 0.86 cm, HDM05 0.47 vs 0.44
    cm (its markers are model-based, nearly exactly rigid); ``"ends"`` is the default: the
    reference frames carry the current skin/cluster deformation and the fill meets both
    ends of the gap.
    """
    P = np.asarray(P, dtype=float)
    obs = np.asarray(observed, dtype=bool) & np.isfinite(P).all(axis=-1)
    if reference not in REFERENCES:
        raise MocapValueError(f"reference must be one of {REFERENCES}, got {reference!r}")
    T, J, _ = P.shape
    out = np.where(obs[..., None], P, np.nan)
    filled = np.zeros((T, J), dtype=bool)
    k_min = max(int(min_donors), 3)
    spread_min = float(min_spread_cm) ** 2
    from .gaps import find_gaps

    for cl in clusters:                                       # loop over clusters / markers / gaps
        cl = [int(c) for c in cl]
        if len(cl) < k_min + 1:
            continue
        Pc, oc = P[:, cl], obs[:, cl]
        Qc = np.where(oc[..., None], Pc, 0.0)
        tmpl = cluster_template(Pc, oc) if reference == "average" else None
        for g in find_gaps(oc):
            if g.kind == "never":
                continue
            if reference == "average":
                got = _template_prediction(tmpl, Qc, oc, g.joint, g.start, g.stop, k_min, spread_min)
            else:
                got = _ends_prediction(Pc, Qc, oc, g.joint, g.start, g.stop, k_min, spread_min)
            if got is None:
                continue
            pred, good = got
            good &= np.isfinite(pred).all(axis=1)
            if good.any():
                fr = np.arange(g.start, g.stop)
                j = cl[g.joint]
                out[fr[good], j] = pred[good]
                filled[fr[good], j] = True
    return out, filled


def _template_prediction(tmpl: np.ndarray, Qc: np.ndarray, oc: np.ndarray, m: int, s: int,
                         e: int, k_min: int, spread_min: float):
    """``reference="average"`` of :func:`rigid_fill`: marker m of the cluster at frames
    s..e-1 from the template ``tmpl`` (K, 3) fitted to the donors seen in each frame.

    Qc (T, K, 3) the cluster's positions (0 where unseen), oc (T, K) seen.  Returns the
    prediction (e - s, 3) and the frames with a usable fit (>= ``k_min`` donors, spread >=
    ``spread_min``), or None when the template lacks marker m."""
    have = np.isfinite(tmpl).all(axis=1)
    if not have[m]:
        return None
    don = np.array([i for i in range(oc.shape[1]) if i != m])
    w = oc[s:e][:, don] & have[don][None, :]
    R, t, spr = kabsch(np.where(have[don][:, None], tmpl[don], 0.0)[None].repeat(e - s, 0),
                       Qc[s:e][:, don], w.astype(float), return_spread=True)
    pred = apply_rigid(R, t, np.broadcast_to(tmpl[m], (e - s, 3)))
    return pred, (w.sum(axis=1) >= k_min) & (spr >= spread_min)


def _ends_prediction(Pc: np.ndarray, Qc: np.ndarray, oc: np.ndarray, m: int, s: int, e: int,
                     k_min: int, spread_min: float) -> tuple[np.ndarray, np.ndarray]:
    """``reference="ends"`` of :func:`rigid_fill`: marker m at frames s..e-1 predicted from
    the nearest frames before and after the gap that see it and >= ``k_min`` donors (a
    rigid fit of the donors seen in both), blended linearly over the gap (one side only
    where the other has no usable fit).  Pc (T, K, 3) the cluster, Qc the same with 0 where
    unseen, oc (T, K) seen.  Returns the prediction (e - s, 3) and the frames with a fit."""
    don = np.array([i for i in range(oc.shape[1]) if i != m])
    fr = np.arange(s, e)
    od = oc[s:e][:, don]                              # donors seen in the gap frames
    ok_ref = oc[:, m] & (oc[:, don].sum(axis=1) >= k_min)
    r0, r1 = _nearest_ref(ok_ref, s, e)
    preds, goods = [], []
    for r in (r0, r1):
        if r is None:
            preds.append(None)
            goods.append(np.zeros(len(fr), bool))
            continue
        w = od & oc[r, don][None, :]
        R, t, spr = kabsch(np.broadcast_to(Qc[r, don], (len(fr), len(don), 3)),
                           Qc[s:e][:, don], w.astype(float), return_spread=True)
        preds.append(apply_rigid(R, t, np.broadcast_to(Pc[r, m], (len(fr), 3))))
        goods.append((w.sum(axis=1) >= k_min) & (spr >= spread_min))
    if r0 is not None and r1 is not None:
        a = ((fr - r0) / float(r1 - r0))[:, None]
    else:
        a = np.full((len(fr), 1), 0.0 if r0 is not None else 1.0)
    a = np.where(~goods[1][:, None], 0.0, np.where(~goods[0][:, None], 1.0, a))
    p0 = np.where(goods[0][:, None], preds[0] if preds[0] is not None else 0.0, 0.0)
    p1 = np.where(goods[1][:, None], preds[1] if preds[1] is not None else 0.0, 0.0)
    return (1.0 - a) * p0 + a * p1, goods[0] | goods[1]         # blend of the two predictions
