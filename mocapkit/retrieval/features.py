"""Motion descriptors for retrieval and recognition (thesis seed 003, Sec. 5.3.1 "Feature
Selection"): HOD and GPF bag of words, on any :class:`~mocapkit.motion.Motion`.

Pipeline (every step vectorised over frames; the only Python loops run over clips)::

    Motion --prepare()--> Prepared (T, K, 3) canonical, size-normalised keypoints
           --hod()------> HOD view       (Gowayyed et al. 2013)
           --gpf()------> GPF per frame  (T, G) (geometric pose features, Chen et al. 2011)
                          --GPFCodebook.encode()--> GPF-BoW view (k-means codebook + LLC)

**Skeleton normalisation** (:func:`prepare`) so clips of different subjects, formats and
skeletons compare:

* *Keypoints.* The 15 canonical keypoints of :data:`KEYPOINTS` (root, neck, head and
  shoulder/elbow/wrist, hip/knee/ankle per side) are found by joint *name*
  (:func:`find_keypoints`): Kinect (``ShoulderLeft``, ``ElbowLeft``, ``WristLeft`` ...), CMU
  ASF/AMC and HDM05 (joints are bone ends: ``lclavicle`` = shoulder, ``lhumerus`` = elbow,
  ``lradius``/``lwrist`` = wrist, ``lhipjoint`` = hip, ``lfemur`` = knee, ``ltibia`` =
  ankle), cgspeed BVH (``LeftArm``, ``LeftForeArm``, ``LeftHand``, ``LeftUpLeg``,
  ``LeftLeg``, ``LeftFoot``) and Daz BVH (``lShldr``, ``lForeArm``, ``lHand``, ``lThigh``,
  ``lShin``, ``lFoot``). So MSR-Action3D (20 joints), CMU/HDM05 (31) and BVH files give
  descriptors of the same length. A skeleton where some keypoint cannot be resolved falls
  back to all its joints (descriptor length then depends on J; ``Prepared.mode`` says which).
* *Frame.* Gaps are bridged linearly in time (whole missing frames of MSR files included);
  clips above ``max_fps`` (30) are resampled to it (HDM05/CMU: 120 fps). Axes: x = the
  subject's lateral direction (right hip -> left hip, averaged over the first 0.5 s),
  y = up (the axis with the largest body extent), z = x cross y; one rotation per clip,
  so turning within a clip is kept. Joints are root-relative; the root keeps its own
  trajectory relative to its first position (locomotion is a feature too).
* *Scale.* Divided by the body size ``s`` = median over frames of |head - root| plus the
  mean leg length (hip-knee + knee-ankle), about 0.9 x standing height (fallback: 0.9 x
  :meth:`Motion.height`). Descriptors are therefore unitless.

**HOD** (:func:`hod`, Gowayyed, Torki, Hussein & El-Saban 2013, "Histogram of oriented
displacements (HOD): describing trajectories of human joints for action recognition",
IJCAI): each keypoint trajectory is projected on the xy, xz and yz planes; every
displacement between consecutive frames votes into one of 8 orientation bins
(bin b covers angles [b, b+1) * 45 deg, angle = atan2 of the plane's second over first
coordinate, in [0, 360)) with its *length* as weight; a temporal pyramid (levels 1, 2, 4:
the whole clip, halves, quarters of the displacements) repeats this per segment.
Layout ``(segment, keypoint, plane, bin)`` flattened, segments ordered level by level.
``normalize='hist'`` (Gowayyed) makes each 8-bin histogram sum to 1 (an empty one stays
0); ``'none'`` keeps the lengths (body-size units).

**GPF** (:func:`gpf`, after the geometric pose descriptor of Chen, Zhuang, Nie, Yang, Wu &
Xiao 2011, the thesis' [Chen et al. 2011]): per frame, segment directions (joint-joint
orientation), joint velocities and joint heights (joint-plane distance to the horizontal
plane through the root), in body-size units. Pairwise joint distances and distances to the
body's frontal/sagittal planes were tried and dropped: on MSR-Action3D their bag of words
scored mAP 0.34 against 0.54 for this set, and added nothing to HOD (``docs/results/retrieval.md``).

**GPF-BoW** (:class:`GPFCodebook`): GPF frames are z-scored, a k-means codebook is learnt
(thesis: *kmeans*), each frame is coded with LLC (:func:`mocapkit.solvers.llc.llc_code`,
Wang et al. 2010, approximated LLC on the ``n_neighbors`` nearest words) and codes are
max-pooled over the frames of each temporal-pyramid cell (default the whole clip only,
a plain bag of words), then L2-normalised.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from .. import gaps
from .._params import store_params
from ..errors import MocapValueError
from ..frames import find_hips, up_axis_of
from ..motion import Motion
from ..skeleton import JOINT_ALIASES, Skeleton, _side, strip_side

__all__ = ["KEYPOINTS", "Prepared", "find_keypoints", "prepare", "hod", "hod_dim", "gpf", "orientation_bins",
           "GPFCodebook", "pyramid_segments", "sliding_windows"]

KEYPOINTS = ("root", "neck", "head",
             "lshoulder", "lelbow", "lwrist", "rshoulder", "relbow", "rwrist",
             "lhip", "lknee", "lankle", "rhip", "rknee", "rankle")

PLANES = ((0, 1), (0, 2), (1, 2))          # xy, xz, yz


def _sided(sk: Skeleton, patterns: Sequence[str], exclude: set[int]) -> tuple[int, int] | None:
    """Left and right joints whose side-stripped name is one of ``patterns``, tried in
    order (exact name first, then contained); the shallowest on each side wins."""
    depth = sk.depths()
    info = [(j, _side(n), strip_side(n)) for j, n in enumerate(sk.names) if j not in exclude]
    for exact in (True, False):
        for pat in patterns:
            out = []
            for side in ("left", "right"):
                c = [j for j, s, b in info if s == side and ((b == pat) if exact else (pat in b))]
                if not c:
                    break
                out.append(min(c, key=lambda j: (depth[j], j)))
            if len(out) == 2:
                return out[0], out[1]
    return None


def _ancestors(sk: Skeleton, j: int) -> list[int]:
    out = []
    while j >= 0:
        out.append(j)
        j = int(sk.parents[j])
    return out


def _next_on_chain(sk: Skeleton, j: int, reach: np.ndarray, tiny: float) -> int | None:
    """Child of ``j`` leading to its farthest descendant, skipping zero-length bones."""
    while True:
        kids = [int(c) for c in np.flatnonzero(sk.parents == j)]
        if not kids:
            return None
        c = max(kids, key=lambda c: (reach[c] + np.linalg.norm(sk.offsets[c]), -c))
        if np.linalg.norm(sk.offsets[c]) > tiny:
            return c
        j = c


def find_keypoints(skeleton: Skeleton) -> np.ndarray | None:
    """Joint index of each of the 15 :data:`KEYPOINTS`, by name and tree, or None.

    Hips: :func:`mocapkit.frames.find_hips`; shoulders by name (``arm``, ``shldr``,
    ``shoulder``, ``clavicle``; ``humerus`` when the hips came out as ``femur`` -- a BVH
    conversion of an ASF skeleton, whose joints sit at bone *starts*); elbow/knee and
    wrist/ankle are the next two joints down the limb chain (the child leading to the
    farthest descendant, zero-length bones skipped); head = a midline joint named
    ``head``; neck = the lowest common ancestor of the shoulders.
    """
    sk = skeleton
    J = sk.n_joints
    root = int(np.flatnonzero(sk.parents < 0)[0])
    hips = find_hips(sk)
    if hips is None or _side(sk.names[hips[0]]) is None or J < 15:
        return None
    rest = sk.rest_positions()
    tiny = 1e-3 * max(float(np.ptp(rest, axis=0).max()), 1e-9)
    reach = np.zeros(J)                                  # farthest descendant distance
    for j in range(J - 1, 0, -1):
        p = sk.parents[j]
        if p >= 0:
            reach[p] = max(reach[p], reach[j] + np.linalg.norm(sk.offsets[j]))
    bvh_of_asf = strip_side(sk.names[hips[0]]) == "femur"
    pats = ("humerus",) if bvh_of_asf else JOINT_ALIASES["upper_arm"]
    sh = _sided(sk, pats, {root, *hips})
    if sh is None:
        return None
    found = {"lhip": hips[0], "rhip": hips[1], "lshoulder": sh[0], "rshoulder": sh[1]}
    for side, s in (("l", 0), ("r", 1)):
        for prox, mid, dist in (("shoulder", "elbow", "wrist"), ("hip", "knee", "ankle")):
            m = _next_on_chain(sk, found[side + prox], reach, tiny)
            d = None if m is None else _next_on_chain(sk, m, reach, tiny)
            if d is None:
                return None
            found[side + mid], found[side + dist] = m, d
    heads = [j for j, n in enumerate(sk.names) if "head" in n.lower() and _side(n) is None]
    if not heads:
        return None
    depth = sk.depths()
    head = max(heads, key=lambda j: (depth[j], -j))
    a, b = _ancestors(sk, found["lshoulder"]), set(_ancestors(sk, found["rshoulder"]))
    common = [j for j in a if j in b]
    if not common:
        return None
    found.update(root=root, head=head, neck=common[0])
    idx = np.array([found[k] for k in KEYPOINTS], dtype=int)
    if len(set(idx.tolist())) != len(idx):
        return None
    return idx


@dataclass(frozen=True)
class Prepared:
    """A clip in the canonical, size-normalised frame (see module doc).

    positions : (T, K, 3) unitless (body sizes); joint 0 is the root (its own trajectory
        relative to its first position), the others root-relative.
    fps : frame rate after resampling.
    size_cm : the body size used for scaling (cm).
    mode : ``'keypoints15'`` or ``'joints<J>'`` (fallback, all joints).
    """

    positions: np.ndarray
    fps: float
    size_cm: float
    mode: str

    @property
    def n_frames(self) -> int:
        return self.positions.shape[0]

    def absolute(self) -> np.ndarray:
        """Root-relative joints put back on the root trajectory: (T, K, 3)."""
        P = self.positions.copy()
        P[:, 1:] += P[:, :1]
        return P


def _resample_linear(X: np.ndarray, fps: float, new_fps: float) -> np.ndarray:
    T = X.shape[0]
    n_new = max(1, int(np.floor((T - 1) * new_fps / fps + 1e-9)) + 1)
    t = np.arange(n_new) * (fps / new_fps)
    lo = np.clip(np.floor(t).astype(int), 0, T - 1)
    hi = np.minimum(lo + 1, T - 1)
    w = (t - lo)[:, None]
    return X[lo] * (1 - w) + X[hi] * w


def prepare(motion: Motion, *, max_fps: float = 30.0, keypoints: bool = True,
            smooth_s: float = 0.0, heading: str = "start") -> Prepared:
    """Canonical, size-normalised keypoint trajectories of ``motion`` (module doc).

    ``smooth_s``: Gaussian smoothing (sigma in seconds) after gap filling, 0 = none.
    ``heading``: lateral axis from the hips over the first 0.5 s (``'start'``), over the
    whole clip (``'mean'``), or ``'none'`` (keep the file's horizontal axes).
    Raises MocapValueError when no joint is observed in any frame (nothing to describe).
    """
    if heading not in ("start", "mean", "none"):
        raise MocapValueError(f"heading must be 'start', 'mean' or 'none', got {heading!r}")
    if not isinstance(motion, Motion):
        raise MocapValueError(f"expected a Motion, got {type(motion).__name__}")
    obs = motion.observed
    if not obs.any():
        src = motion.source.get("path", "")
        raise MocapValueError(f"{src or 'motion'}: no joint is observed in any frame; nothing to describe")
    X = gaps.fill(motion.matrix(), motion.matrix_mask(), never_observed=0.0)
    T, J = motion.n_frames, motion.n_joints
    fps = motion.fps
    if fps > max_fps * 1.01 and T > 1:
        X = _resample_linear(X, fps, max_fps)
        fps = float(max_fps)
    if smooth_s > 0 and X.shape[0] > 2:
        from .. import signal

        X = signal.gaussian(X, sigma=max(float(smooth_s) * fps, 1e-3))
    P = X.reshape(-1, J, 3)
    idx = find_keypoints(motion.skeleton) if keypoints else None
    if idx is not None:
        P = P[:, idx]
        mode = "keypoints15"
        kp = {k: i for i, k in enumerate(KEYPOINTS)}
        seg = lambda a, b: np.linalg.norm(P[:, kp[a]] - P[:, kp[b]], axis=1)  # noqa: E731
        leg = 0.5 * (seg("lhip", "lknee") + seg("lknee", "lankle")
                     + seg("rhip", "rknee") + seg("rknee", "rankle"))
        size = float(np.median(seg("head", "root") + leg))
        li, ri = kp["lhip"], kp["rhip"]
    else:
        r = int(np.flatnonzero(motion.skeleton.parents < 0)[0])
        order = [r] + [j for j in range(J) if j != r]
        P = P[:, order]
        mode = f"joints{J}"
        ext = P.max(axis=1) - P.min(axis=1)
        size = 0.9 * float(np.percentile(ext[:, up_axis_of(P)], 90))
        hips = find_hips(motion.skeleton)
        li = ri = None
        if hips is not None:
            li, ri = order.index(hips[0]), order.index(hips[1])
    if not np.isfinite(size) or size <= 1e-6:
        size = 1.0
    up = up_axis_of(P)
    e_up = np.zeros(3)
    e_up[up] = 1.0
    lat = np.zeros(3)
    if li is not None and heading != "none":
        n0 = max(1, int(round(0.5 * fps))) if heading == "start" else P.shape[0]
        lat = (P[:n0, li] - P[:n0, ri]).mean(axis=0)
    elif heading == "none":
        lat[0 if up != 0 else 1] = 1.0
    lat = lat - lat[up] * e_up
    if np.linalg.norm(lat) < 1e-9:
        lat = np.zeros(3)
        lat[(up + 1) % 3] = 1.0
    lat = lat / np.linalg.norm(lat)
    fwd = np.cross(lat, e_up)
    R = np.stack([lat, e_up, fwd])                                # rows: new axes
    root0 = P[0, 0].copy()
    Q = np.empty_like(P)
    Q[:, 0] = P[:, 0] - root0
    Q[:, 1:] = P[:, 1:] - P[:, :1]
    Q = Q @ R.T / size
    return Prepared(positions=Q, fps=fps, size_cm=size, mode=mode)


# ---------------------------------------------------------------------------------- HOD
def pyramid_segments(n: int, levels: Sequence[int] = (1, 2, 4)) -> np.ndarray:
    """Segment id (within each level) of items 0..n-1 for each level: (len(levels), n)."""
    t = np.arange(n)
    return np.stack([np.minimum((t * int(L)) // max(n, 1), int(L) - 1) for L in levels])


def orientation_bins(D: np.ndarray, bins: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Orientation bin and length of displacements ``D`` (..., 3) on the xy, xz, yz planes.

    Returns (bin, length), each (..., 3): angle = atan2(second, first coordinate of the
    plane) in [0, 2 pi); bin b covers [b, b+1) * 2 pi / bins (an angle on a boundary, up to
    1e-9 of a bin, goes to the upper bin). Lengths below 1e-9 (rounding noise of a still
    joint) count as 0, so they cannot fill a normalised histogram.
    """
    a = np.stack([D[..., i] for i, _ in PLANES], axis=-1)
    b = np.stack([D[..., j] for _, j in PLANES], axis=-1)
    ang = np.mod(np.arctan2(b, a), 2 * np.pi)
    bi = np.floor(ang * (bins / (2 * np.pi)) + 1e-9).astype(int) % bins
    w = np.hypot(a, b)
    return bi, np.where(w > 1e-9, w, 0.0)


def hod_dim(n_joints: int, levels: Sequence[int] = (1, 2, 4), bins: int = 8) -> int:
    return int(sum(levels)) * n_joints * len(PLANES) * bins


def hod(positions: np.ndarray | Prepared, *, levels: Sequence[int] = (1, 2, 4), bins: int = 8,
        normalize: str = "hist") -> np.ndarray:
    """Histogram of oriented displacements (Gowayyed et al. 2013; module doc).

    Parameters
    ----------
    positions : (T, K, 3) trajectories (or a :class:`Prepared`).
    levels : temporal pyramid (segments per level).
    bins : orientation bins over 360 degrees.
    normalize : ``'hist'`` (each histogram sums to 1) or ``'none'``.

    Returns
    -------
    (sum(levels) * K * 3 * bins,) float vector, layout (segment, joint, plane, bin).
    """
    P = positions.positions if isinstance(positions, Prepared) else np.asarray(positions, float)
    if P.ndim != 3 or P.shape[2] != 3:
        raise MocapValueError(f"positions must be (T, K, 3), got {P.shape}")
    if normalize not in ("hist", "none"):
        raise MocapValueError(f"normalize must be 'hist' or 'none', got {normalize!r}")
    T, K, _ = P.shape
    nP = len(PLANES)
    out = []
    if T < 2:
        return np.zeros(hod_dim(K, levels, bins))
    bi, w = orientation_bins(np.diff(P, axis=0), bins)           # (T-1, K, 3 planes)
    n = T - 1
    segs = pyramid_segments(n, levels)
    cell = (np.arange(K)[:, None] * nP + np.arange(nP)[None, :]) * bins   # (K, planes)
    for L, seg in zip(levels, segs):
        flat = ((seg[:, None, None] * K * nP * bins) + cell[None] + bi).ravel()
        h = np.bincount(flat, weights=w.ravel(), minlength=int(L) * K * nP * bins)
        out.append(h)
    H = np.concatenate(out)
    if normalize == "hist":
        Hh = H.reshape(-1, bins)
        s = Hh.sum(axis=1, keepdims=True)
        Hh = np.divide(Hh, s, out=np.zeros_like(Hh), where=s > 0)
        H = Hh.ravel()
    return H


# ---------------------------------------------------------------------------------- GPF
# Segments (parent keypoint, child keypoint) whose directions are GPF orientation features.
SEGMENTS = (("root", "neck"), ("neck", "head"),
            ("neck", "lshoulder"), ("lshoulder", "lelbow"), ("lelbow", "lwrist"),
            ("neck", "rshoulder"), ("rshoulder", "relbow"), ("relbow", "rwrist"),
            ("root", "lhip"), ("lhip", "lknee"), ("lknee", "lankle"),
            ("root", "rhip"), ("rhip", "rknee"), ("rknee", "rankle"))


def gpf(positions: np.ndarray | Prepared, *, fps: float | None = None,
        mode: str | None = None) -> np.ndarray:
    """Geometric pose features per frame (module doc): (T, G), vectorised over frames.

    ``positions`` as stored in :class:`Prepared` (root trajectory + root-relative joints,
    y up, body-size units). Blocks, after Chen et al. 2011's families of geometric
    relations: *joint-joint orientation* (unit direction of each of the 14
    :data:`SEGMENTS`, 42 values; in the fallback mode the direction from the root to each
    joint), *joint velocity* (central differences in body sizes per second: the root's own
    velocity and the root-relative velocity of the others, 3K values) and *joint-plane
    distance* to the horizontal plane through the root (height, K values). 15 keypoints:
    G = 42 + 45 + 15 = 102. ``fps`` defaults to the :class:`Prepared` rate (else 30).
    """
    if isinstance(positions, Prepared):
        mode = positions.mode if mode is None else mode
        fps = positions.fps if fps is None else fps
        P = positions.positions
    else:
        P = np.asarray(positions, float)
    fps = 30.0 if fps is None else float(fps)
    if P.ndim != 3 or P.shape[2] != 3:
        raise MocapValueError(f"positions must be (T, K, 3), got {P.shape}")
    T, K, _ = P.shape
    Rel = P.copy()
    Rel[:, 0] = 0.0                                               # root at the origin
    if mode == "keypoints15" or (mode is None and K == len(KEYPOINTS)):
        kp = {k: i for i, k in enumerate(KEYPOINTS)}
        a = [kp[s] for s, _ in SEGMENTS]
        b = [kp[e] for _, e in SEGMENTS]
        O = Rel[:, b] - Rel[:, a]
    else:
        O = Rel[:, 1:]
    O = O / np.maximum(np.linalg.norm(O, axis=2, keepdims=True), 1e-9)
    V = np.gradient(P, axis=0) * fps if T > 1 else np.zeros_like(P)
    height = Rel[:, :, 1]
    return np.concatenate([O.reshape(T, -1), V.reshape(T, -1), height], axis=1)


def sliding_windows(n_frames: int, window: int, stride: int) -> np.ndarray:
    """(start, stop) frame ranges of the sliding windows (thesis Fig. 6.11): (N, 2).

    ``N = floor((S - M) / stride) + 1`` windows of M frames; a clip shorter than M gives
    one window over the whole clip.
    """
    S, M, st = int(n_frames), int(window), max(1, int(stride))
    if S <= M:
        return np.array([[0, S]])
    starts = np.arange(0, S - M + 1, st)
    return np.stack([starts, starts + M], axis=1)


# ------------------------------------------------------------------------------ codebook
class GPFCodebook:
    """k-means codebook of z-scored GPF frames + LLC bag-of-words pooling (module doc).

    Parameters
    ----------
    n_words : codebook size.
    n_neighbors : LLC nearest words per frame (Wang et al.'s approximated LLC: 5).
    lam : LLC locality weight (relative: multiplied by the mean squared frame-to-word
        distance of the training frames, so it does not depend on the feature scale).
    pooling : ``'max'`` (Wang et al.) or ``'sum'`` (mean over frames).
    levels : temporal pyramid of the pooling (default (1,): one bag per clip).
    max_frames : frames sampled for k-means.
    seed : k-means seed.
    """

    def __init__(self, n_words: int = 128, *, n_neighbors: int = 5, lam: float = 1e-2,
                 pooling: str = "max", levels: Sequence[int] = (1,), max_frames: int = 20000,
                 seed: int = 0):
        store_params(self, locals(), tuples=("levels",))

    def fit(self, frames: Iterable[np.ndarray]) -> "GPFCodebook":
        from sklearn.cluster import KMeans

        F = np.concatenate([np.asarray(f, float) for f in frames], axis=0)
        if len(F) < 2:
            raise MocapValueError("the GPF codebook needs at least two frames")
        rng = np.random.default_rng(self.seed)
        if len(F) > self.max_frames:
            F = F[rng.choice(len(F), self.max_frames, replace=False)]
        self.mean_ = F.mean(axis=0)
        sd = F.std(axis=0)
        self.scale_ = np.where(sd > 1e-12, sd, 1.0)
        Z = (F - self.mean_) / self.scale_
        k = int(min(self.n_words, len(np.unique(Z, axis=0))))
        km = KMeans(n_clusters=k, n_init=1, max_iter=100, random_state=self.seed).fit(Z)
        self.centers_ = km.cluster_centers_
        d2 = ((Z[:, None, :] - self.centers_[None]) ** 2).sum(-1) if len(Z) * k < 4e6 else None
        if d2 is None:
            from ..solvers.llc import masked_sq_distances

            d2 = masked_sq_distances(Z, self.centers_)
        self.lam_abs_ = float(self.lam * max(np.mean(d2), 1e-12))
        return self

    @property
    def dim(self) -> int:
        return int(sum(self.levels)) * self.centers_.shape[0]

    def codes(self, frames: np.ndarray) -> np.ndarray:
        """Dense LLC codes (T, n_words) of GPF frames."""
        from ..solvers.llc import dense_codes, llc_code

        Z = (np.asarray(frames, float) - self.mean_) / self.scale_
        K = self.centers_.shape[0]
        c, idx = llc_code(Z, self.centers_, lam=self.lam_abs_,
                          n_neighbors=min(self.n_neighbors, K))
        return dense_codes(c, idx, K)

    def encode(self, frames: np.ndarray) -> np.ndarray:
        """Pooled, L2-normalised bag of words of one clip: (dim,)."""
        C = self.codes(frames)
        T = C.shape[0]
        out = []
        for L, seg in zip(self.levels, pyramid_segments(T, self.levels)):
            if self.pooling == "max":
                h = np.full((int(L), C.shape[1]), -np.inf)
                np.maximum.at(h, seg, C)
                h[~np.isfinite(h)] = 0.0
            else:
                h = np.zeros((int(L), C.shape[1]))
                np.add.at(h, seg, C)
                h /= np.maximum(np.bincount(seg, minlength=int(L)), 1)[:, None]
            out.append(h.ravel())
        v = np.concatenate(out)
        n = np.linalg.norm(v)
        return v / n if n > 0 else v

    def state(self) -> dict[str, np.ndarray]:
        return {"cb_mean": self.mean_, "cb_scale": self.scale_, "cb_centers": self.centers_,
                "cb_params": np.array([self.n_neighbors, self.lam_abs_, 1.0 if self.pooling == "max" else 0.0]),
                "cb_levels": np.array(self.levels)}

    @classmethod
    def from_state(cls, st: dict) -> "GPFCodebook":
        p = np.asarray(st["cb_params"], float)
        cb = cls(n_words=int(np.asarray(st["cb_centers"]).shape[0]), n_neighbors=int(p[0]),
                 pooling="max" if p[2] > 0.5 else "sum",
                 levels=tuple(int(x) for x in np.asarray(st["cb_levels"])))
        cb.mean_ = np.asarray(st["cb_mean"], float)
        cb.scale_ = np.asarray(st["cb_scale"], float)
        cb.centers_ = np.asarray(st["cb_centers"], float)
        cb.lam_abs_ = float(p[1])
        return cb
