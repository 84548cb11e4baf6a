"""Clip preparation for BRA / BRA-P (Li et al. 2020, seed 002, Sec. III.A.1), numpy only.

The paper's synthetic data set follows Holden et al. 2016 ([22] in the paper):

1. resample every motion to **60 fps** (:meth:`Motion.resample`, cubic splines);
2. keep **21 joints** (:data:`CMU_21`), positions in cm;
3. express the positions in a **root-local ground frame**: the origin lies on the
   ground, under the root: the root's horizontal coordinates (x, z for Y-up CMU data)
   are subtracted from every joint in every frame, heights are kept. The paper keeps the
   body's rotation about the vertical axis ("does not need to be removed", Sec.
   III.A.1), so do we: no heading normalisation. Decision: the ground is the file's own
   ground plane (height 0); CMU ASF/AMC floors lie within a few cm of 0 (checked on
   every trial in ``../shared/data``), and estimating a floor from noisy feet would
   move with the noise;
4. subtract the mean pose and divide by the standard deviation (one scalar, so the
   skeleton keeps its shape; statistics of the clean training clips, stored with the
   model: :class:`Normaliser`);
5. cut **120-frame clips overlapping by 60**; a motion shorter than 120 frames is padded
   by repeating its edge frames.

Which 21 joints
---------------
The paper shows a 21-joint CMU skeleton (Fig. 3a) and points to Holden et al. 2016 for
the preprocessing. Holden's exporter keeps the BVH joints
``0, 2-5, 7-10, 12, 13, 15, 16, 18-20, 22, 25-27, 29`` of the 31-joint CMU hierarchy
(Hips, LeftUpLeg, LeftLeg, LeftFoot, LeftToeBase, ... Spine, Spine1, Neck1, Head,
LeftArm, LeftForeArm, LeftHand, LeftHandIndex1, ...). A BVH joint sits at the *start*
of its bone, while our ASF/AMC reader names each joint by the bone whose *end* it is,
so the same 21 points are, in CMU ASF names (:data:`CMU_21`): ``root``; the hips
(``l/rhipjoint``), knees (``l/rfemur``), ankles (``l/rtibia``) and balls of the feet
(``l/rfoot``); the spine points ``lowerback``, ``upperback``, ``lowerneck``,
``upperneck`` (base of the head); the shoulders (``l/rclavicle``), elbows
(``l/rhumerus``), wrists (``l/rradius``) and hands (``l/rhand``). Dropped: ``thorax``,
``head`` (top of the head), toe tips, the short ``l/rwrist`` bones, fingers and thumbs.

Issue 20 (what the shipped networks see)
----------------------------------------
The v1 networks predicted absolute positions from zero-filled input and, undertrained on
a CPU, returned ~5 cm error whatever the input (a clean clip included). The shipped
networks are residual (:mod:`model`): the input of :func:`model_input` is
``[B, X - B, mask]`` with ``X`` the normalised root-local positions (missing values
bridged linearly in time), ``B`` = :func:`base_smooth` ``(X)`` (5-frame median +
Gaussian sigma 1 frame) and the mask of observed joints; the output is
``B + correction``. Training clips are augmented (:meth:`~mocapkit.neural.train.
SyntheticSource.augment`: rotation about the vertical, left/right mirror
(:func:`mocapkit.frames.mirror_permutation`), scale), so the normalisation's horizontal means are 0.

Joints outside the subset (output)
----------------------------------
A Denoiser returns the input's skeleton, so the dropped joints are put back by
:func:`attach_dropped`: where the input observes a dropped joint, it is the input's own
track smoothed by GCV splines; elsewhere it is carried *rigidly* by its nearest kept ancestor
``a``: its rest-pose offset from ``a`` is rotated by the minimal rotation taking the
rest direction of a kept reference segment at ``a`` (towards a kept joint below it,
else from ``a``'s kept parent) onto that segment's direction in the refined frame.
The twist about that segment is not observed (e.g. the thumb's side), which is the
documented limit of the rigid choice.

Inference on whole motions
--------------------------
:func:`split_clips` cuts any length into 120-frame windows with hop 60 (the last one
aligned to the end) and :func:`overlap_add` puts the refined windows back with
triangular weights, i.e. a linear cross-fade over each 60-frame overlap, normalised by
the weight sum (exact for an identity model). The horizontal reference of a noisy motion
is not known, so :func:`ground_reference` estimates it from the observed root track
(gaps bridged linearly, Gaussian smoothing of ``sigma`` frames); training uses the same
estimate on the noisy synthetic clips (whose clean root is at the origin), so the network
learns to undo its error (see ``docs/neural.md``).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .. import gaps
from ..errors import MocapValueError
from ..motion import Motion
from ..skeleton import Skeleton

CMU_21: tuple[str, ...] = (
    "root",
    "lhipjoint", "lfemur", "ltibia", "lfoot",
    "rhipjoint", "rfemur", "rtibia", "rfoot",
    "lowerback", "upperback", "lowerneck", "upperneck",
    "lclavicle", "lhumerus", "lradius", "lhand",
    "rclavicle", "rhumerus", "rradius", "rhand",
)
"""The 21 CMU ASF joints of the paper's data set (module docstring)."""

CLIP_FRAMES = 120
CLIP_HOP = 60
FPS = 60.0
UP_AXIS = 1          # Y up (CMU ASF/AMC, BVH)
REFERENCE_SIGMA = 4.0
"""Gaussian smoothing (frames at 60 fps) of the noisy root track used as the reference."""


# ----------------------------------------------------------------------------------------
# joints
# ----------------------------------------------------------------------------------------
def check_joints(skeleton: Skeleton, joints: Sequence[str], what: str = "motion") -> list[int]:
    """Indices of ``joints`` in ``skeleton``; MocapValueError naming the missing ones."""
    missing = [j for j in joints if j not in skeleton.names]
    if missing:
        raise MocapValueError(
            f"the {what}'s skeleton lacks {len(missing)} of the {len(joints)} joints this model "
            f"needs: {', '.join(missing)} (the BRA/BRA-P models work on the CMU ASF joint set "
            f"{', '.join(joints)}; train a model on your own skeleton with "
            f"`mocapkit train --method bra-p`)")
    return skeleton.indices(joints)


def subset_parents(skeleton: Skeleton, joints: Sequence[str]) -> np.ndarray:
    """Parent index (within ``joints``, -1 for the root) of each joint of the subset.

    Each joint is re-parented to its nearest ancestor that is in the subset
    (as :meth:`Skeleton.subset`), in the order of ``joints``.
    """
    idx = check_joints(skeleton, joints)
    pos = {j: k for k, j in enumerate(idx)}
    out = []
    for j in idx:
        p = int(skeleton.parents[j])
        while p >= 0 and p not in pos:
            p = int(skeleton.parents[p])
        out.append(pos[p] if p >= 0 else -1)
    par = np.array(out, dtype=np.int64)
    if (par < 0).sum() != 1:
        raise MocapValueError(f"the joint subset must contain exactly one root, got "
                              f"{[joints[k] for k in np.flatnonzero(par < 0)]}")
    return par


def bones_of(parents: np.ndarray) -> np.ndarray:
    """(B, 2) int array of (child, parent) pairs for a parent array."""
    parents = np.asarray(parents)
    c = np.flatnonzero(parents >= 0)
    return np.stack([c, parents[c]], axis=1).astype(np.int64)


def prepare_positions(motion: Motion, joints: Sequence[str], fps: float = FPS) -> tuple[np.ndarray, np.ndarray]:
    """Subset joints in model order and resample: positions (T', K, 3) cm (NaN = missing), observed (T', K)."""
    idx = check_joints(motion.skeleton, joints)
    m = motion.select(joints)              # skeleton order; reorder to the model's order
    order = m.skeleton.indices([motion.skeleton.names[i] for i in idx])
    chain = Skeleton(tuple(joints), np.arange(len(joints)) - 1, np.zeros((len(joints), 3)))
    m = Motion(m.positions[:, order], chain, m.fps, m.observed[:, order])
    if not np.isclose(m.fps, fps):
        m = m.resample(fps)
    return np.array(m.positions), np.array(m.observed)


# ----------------------------------------------------------------------------------------
# ground frame
# ----------------------------------------------------------------------------------------
def ground_reference(root: np.ndarray, observed: np.ndarray | None = None, *,
                     sigma: float = REFERENCE_SIGMA, up_axis: int = UP_AXIS,
                     fallback: np.ndarray | None = None) -> np.ndarray:
    """Horizontal reference track (T, 3) of a root trajectory, its up component zero.

    Parameters
    ----------
    root : (T, 3) root positions, cm (NaN where missing).
    observed : (T,) bool, default: finite rows of ``root``.
    sigma : Gaussian smoothing in frames (0: the root itself, the paper's clean case).
    up_axis : index of the vertical axis (1 for Y-up CMU data).
    fallback : (T, 3) track used when the root is never observed (e.g. the mean of the
        observed joints); zeros if None.

    Gaps are bridged linearly (edges: nearest observed value) before smoothing
    (``scipy.ndimage.gaussian_filter1d``, ``mode='nearest'``).
    """
    R = np.asarray(root, dtype=float)
    obs = np.isfinite(R).all(axis=1) if observed is None else (np.asarray(observed, bool) & np.isfinite(R).all(axis=1))
    if not obs.any():
        if fallback is None:
            R = np.zeros_like(R)
        else:
            F = np.asarray(fallback, dtype=float)
            R = gaps.fill(F, np.isfinite(F), never_observed=0.0)
    else:
        R = gaps.fill(R, np.repeat(obs[:, None], 3, axis=1), never_observed=0.0)
    if sigma and sigma > 0 and len(R) > 1:
        from scipy.ndimage import gaussian_filter1d

        R = gaussian_filter1d(R, float(sigma), axis=0, mode="nearest")
    R = np.array(R)
    R[:, up_axis] = 0.0
    return R


def joint_mean_track(P: np.ndarray) -> np.ndarray:
    """Mean over the observed joints per frame (T, 3); NaN for frames with none."""
    with np.errstate(invalid="ignore"):
        cnt = np.isfinite(P).all(axis=2).sum(axis=1)
        s = np.nansum(P, axis=1)
        return np.where(cnt[:, None] > 0, s / np.maximum(cnt, 1)[:, None], np.nan)


# ----------------------------------------------------------------------------------------
# normalisation
# ----------------------------------------------------------------------------------------
class Normaliser:
    """Mean pose (C,) and one scalar standard deviation, cm (Sec. III.A.1).

    ``forward(X) = (X - mean) / std``; ``inverse(Z) = Z * std + mean``. Missing (NaN)
    entries become 0 after :meth:`forward_fill` (the paper sets missing joints to zero
    in the normalised data, i.e. to the mean pose).
    """

    def __init__(self, mean: np.ndarray, std: float):
        self.mean = np.asarray(mean, dtype=np.float64).reshape(-1)
        self.std = float(std)
        if not np.isfinite(self.mean).all() or not (np.isfinite(self.std) and self.std > 0):
            raise MocapValueError("normalisation statistics must be finite with std > 0")

    @classmethod
    def fit(cls, X: np.ndarray) -> "Normaliser":
        """From clean data X (..., C): per-channel mean, one std over all centred channels."""
        X = np.asarray(X, dtype=np.float64).reshape(-1, np.shape(X)[-1])
        mean = X.mean(axis=0)
        std = float(np.sqrt(np.mean((X - mean) ** 2)))
        return cls(mean, max(std, 1e-6))

    def forward(self, X: np.ndarray) -> np.ndarray:
        return (np.asarray(X, dtype=np.float64) - self.mean) / self.std

    def forward_fill(self, X: np.ndarray) -> np.ndarray:
        Z = self.forward(X)
        return np.where(np.isfinite(Z), Z, 0.0)

    def inverse(self, Z: np.ndarray) -> np.ndarray:
        return np.asarray(Z, dtype=np.float64) * self.std + self.mean


BASE_FILTERS = ("lowpass", "gcv")
"""Residual bases a network can correct (:func:`base_smooth`)."""


def base_smooth(X: np.ndarray, sigma: float, median: int = 5, *, kind: str = "lowpass",
                observed: np.ndarray | None = None) -> np.ndarray:
    """The residual base of issue 20, along time (axis -2), of a (T, C) or (B, T, C) array.

    ``kind="lowpass"``: a running median of ``median`` frames (against spikes), then a
    Gaussian of ``sigma`` frames, edges held. ``kind="gcv"``: every channel's own
    Woltring GCV smoothing spline (:func:`mocapkit.solvers.gcv_spline.gcv_smooth`,
    order 2; ``sigma`` and ``median`` unused) fitted to the samples in ``observed``
    (T, C) bool (None = all). Why GCV: on 8 held-out CMU/HDM05 clips at 60 fps it leaves
    1.08 cm of 3 cm noise where the low-pass leaves 1.46, and 0.014 cm of a clean clip
    (low-pass 0.24), so the network starts from the best automatic filter; a median
    prefilter before it measured worse (1.55 cm), since GCV then under-smooths the
    correlated residue. Clips under 8 frames fall back to the low-pass.
    """
    from scipy.ndimage import gaussian_filter1d, median_filter

    X = np.asarray(X, dtype=np.float64)
    if kind not in BASE_FILTERS:
        raise MocapValueError(f"base filter must be one of {BASE_FILTERS}, got {kind!r}")
    if kind == "gcv" and X.shape[-2] >= 8:
        from ..solvers.gcv_spline import gcv_smooth

        M = np.ones(X.shape, bool) if observed is None else np.broadcast_to(np.asarray(observed, bool), X.shape)
        if X.ndim == 3:                   # a batch: every (clip, channel) is its own column
            B, T, C = X.shape
            flat = lambda A: A.transpose(1, 0, 2).reshape(T, B * C)          # noqa: E731
            return base_smooth(flat(X), sigma, median, kind=kind,
                               observed=flat(M)).reshape(T, B, C).transpose(1, 0, 2)
        M = M | ~M.any(axis=0)            # a never-observed channel: its filled value is the data
        return gcv_smooth(X, M, validate=False)[0]
    if median and median > 1 and X.shape[-2] >= median:
        size = [1] * X.ndim
        size[-2] = int(median)
        X = median_filter(X, size=tuple(size), mode="nearest")
    if sigma and sigma > 0:
        X = gaussian_filter1d(X, float(sigma), axis=-2, mode="nearest")
    return X


def model_input(Z: np.ndarray, observed: np.ndarray, *, fill: bool = True, mask: bool = True,
                base_sigma: float = 0.0, highpass_gain: float = 1.0,
                base_filter: str = "lowpass", reference: np.ndarray | None = None) -> np.ndarray:
    """Network input (T, 3K [+ K]) from normalised positions Z (T, 3K) (NaN / anything where
    missing) and the joint observation mask ``observed`` (T, K).

    ``fill=True`` (issue 20): a missing coordinate is bridged linearly in time from its
    observed neighbours (ends held; a never-observed channel becomes 0, the mean pose), so
    a residual network only corrects the bridge. ``fill=False``: the paper's zero (mean
    pose). ``mask=True`` appends the mask itself (1 observed, 0 missing) as K channels so
    the network knows which values are bridged. ``base_sigma > 0``: the channels are
    ``[B, X - B, mask]`` with ``B = base_smooth(X, base_sigma, kind=base_filter)``, so that
    a residual network (``Y = B + net``, :mod:`model`) corrects a smoothed input and
    still sees the high-pass part, multiplied by ``highpass_gain`` (the noise is a few
    hundredths of the normalised positions' scale). Works on (B, T, C) batches too.

    ``reference`` (T, C), same units as Z (:func:`reference_channels`): the horizontal
    track that makes ``Z + reference`` the world-frame positions. The GCV base is fitted
    to those and the track taken off again, so the spline's per-channel smoothing is the
    one the standalone ``gcv-spline`` chooses (9 held-out clips at 3 cm noise: 1.01 cm on
    the 21 joints; fitted in the body frame, 1.06). The low-pass base ignores it.
    """
    Z = np.asarray(Z, dtype=np.float64)
    obs = np.asarray(observed, dtype=bool)
    oc = np.repeat(obs, 3, axis=-1) & np.isfinite(Z)
    if Z.ndim == 3:
        refs = [None] * len(Z) if reference is None else reference
        return np.stack([model_input(z, o, fill=fill, mask=mask, base_sigma=base_sigma,
                                     highpass_gain=highpass_gain, base_filter=base_filter, reference=r)
                         for z, o, r in zip(Z, obs, refs)])
    if fill and not oc.all():
        X = gaps.fill(np.where(oc, Z, 0.0), oc, never_observed=0.0)
    else:
        X = np.where(oc, Z, 0.0)
    if base_sigma and base_sigma > 0:
        R = 0.0 if reference is None or base_filter != "gcv" else np.asarray(reference, dtype=np.float64)
        B = base_smooth(X + R, base_sigma, kind=base_filter, observed=oc) - R
        X = np.concatenate([B, float(highpass_gain) * (X - B)], axis=-1)
    if mask:
        X = np.concatenate([X, obs.astype(np.float64)], axis=-1)
    return X


def reference_channels(ref: np.ndarray, n_joints: int, norm: "Normaliser") -> np.ndarray:
    """A horizontal track (T, 3) cm as (T, 3 n_joints) channels in ``norm``'s units (its
    scale only: the mean pose is not part of a track), for :func:`model_input`."""
    return np.tile(np.asarray(ref, dtype=np.float64), (1, int(n_joints))) / norm.std


def body_size(P: np.ndarray, observed: np.ndarray | None = None) -> float:
    """Median over frames (with >= 3 observed joints) of the RMS distance of the joints
    from their centroid, cm; P (T, K, 3). NaN when no frame qualifies."""
    P = np.asarray(P, dtype=np.float64)
    W = np.isfinite(P).all(axis=2) if observed is None else np.asarray(observed, bool) & np.isfinite(P).all(axis=2)
    ok = W.sum(axis=1) >= 3
    if not ok.any():
        return float("nan")
    L, W = np.nan_to_num(P[ok]), W[ok][..., None]
    n = W.sum(axis=1)
    c = np.where(W, L, 0.0).sum(axis=1) / n
    d2 = np.where(W[..., 0], ((L - c[:, None]) ** 2).sum(axis=2), 0.0)
    return float(np.median(np.sqrt(d2.sum(axis=1) / n[:, 0])))


def turn(P: np.ndarray, angle, up: int = UP_AXIS) -> np.ndarray:
    """Points P (..., 3) turned about axis ``up`` by ``angle`` radians (a scalar, or an
    array broadcasting against P's leading axes, e.g. (B, 1, 1) for a batch of clips):
    ``h0' = cos a h0 + sin a h1``, ``h1' = -sin a h0 + cos a h1`` on the two horizontal
    axes. Returns a new array."""
    h0, h1 = [a for a in range(3) if a != up]
    out = np.array(P, dtype=np.float64, copy=True)
    c, s = np.cos(angle), np.sin(angle)
    a, b = out[..., h0].copy(), out[..., h1].copy()
    out[..., h0] = c * a + s * b
    out[..., h1] = -s * a + c * b
    return out


def project_bones(P: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """Positions (T, K, 3) with every bone set to its median length over the clip.

    From the root outward, each child is moved along the direction from its parent's new
    position to its own old one, to the bone's median length in ``P``: the bones of a
    skeleton are rigid, and a denoiser's residual error stretches them frame by frame.
    Measured with the shipped bra-p on 5 CMU clips of *training* subjects (05_05, 07_03,
    131_08, 135_05, 01_01; 60 fps; Table 1's conditions, 21 joints): bone error B 2.12 ->
    0.86 (1 dB), 0.70 -> 0.24 (20 dB), 1.48 -> 0.45 cm (40 % missing + 15 dB), R 3.04 ->
    3.01, 0.69 -> 0.68, 1.78 -> 1.68 cm, and 0.88 -> 0.87 cm RMSE at 3 cm noise.
    ``parents`` (K,): parent index per joint, -1 for a root, every parent before its
    children (the :class:`~mocapkit.skeleton.Skeleton` order), so one pass in joint order
    visits parents first. P must be complete (a network's output).
    """
    P = np.asarray(P, dtype=np.float64)
    parents = np.asarray(parents, dtype=np.int64)
    if np.any(parents >= np.arange(len(parents))):
        raise MocapValueError("project_bones: every parent must come before its children")
    b = bones_of(parents)                                   # (child, parent)
    L = np.median(np.linalg.norm(P[:, b[:, 0]] - P[:, b[:, 1]], axis=2), axis=0)
    Q = P.copy()
    for (j, q), length in zip(b, L):                        # one (T, 3) update per bone
        d = P[:, j] - Q[:, q]
        n = np.linalg.norm(d, axis=1, keepdims=True)
        Q[:, j] = np.where(n > 1e-9, Q[:, q] + d * (length / np.maximum(n, 1e-9)), P[:, j])
    return Q


MIRROR_AXIS = 0
"""Horizontal axis negated by the left/right mirror augmentation (x of Y-up CMU data)."""


# ----------------------------------------------------------------------------------------
# clips
# ----------------------------------------------------------------------------------------
def clip_starts(T: int, f: int = CLIP_FRAMES, hop: int = CLIP_HOP) -> np.ndarray:
    """Start frames of the windows covering T frames: 0, hop, 2 hop, ... and T - f last.

    For T <= f a single window at 0 (the motion is padded, :func:`pad_edges`).
    """
    if T <= f:
        return np.zeros(1, dtype=np.int64)
    s = np.arange(0, T - f + 1, hop, dtype=np.int64)
    if s[-1] + f < T:
        s = np.append(s, T - f)
    return s


def pad_edges(X: np.ndarray, f: int = CLIP_FRAMES) -> tuple[np.ndarray, int]:
    """Pad a (T, ...) array shorter than f by repeating its first/last frame.

    Returns (padded (f, ...), left) where ``left`` is the number of frames added before
    (the original occupies ``left:left + T``). Arrays of length >= f come back unchanged.
    """
    T = len(X)
    if T >= f:
        return X, 0
    left = (f - T) // 2
    right = f - T - left
    return np.concatenate([np.repeat(X[:1], left, axis=0), X, np.repeat(X[-1:], right, axis=0)]), left


def triangular_window(f: int = CLIP_FRAMES) -> np.ndarray:
    """Weights w[t] = min(t + 1, f - t): overlapping halves cross-fade linearly."""
    t = np.arange(f)
    return np.minimum(t + 1, f - t).astype(np.float64)


def split_clips(X: np.ndarray, f: int = CLIP_FRAMES, hop: int = CLIP_HOP) -> tuple[np.ndarray, np.ndarray, int]:
    """Cut (T, C) into windows (K, f, C); returns (windows, starts, left padding)."""
    X = np.asarray(X)
    Xp, left = pad_edges(X, f)
    starts = clip_starts(len(Xp), f, hop)
    idx = starts[:, None] + np.arange(f)[None, :]
    return Xp[idx], starts, left


def overlap_add(Y: np.ndarray, starts: np.ndarray, T: int, left: int = 0,
                window: np.ndarray | None = None) -> np.ndarray:
    """Reassemble windows (K, f, C) into (T, C) with a linear cross-fade.

    Frame t is the weighted mean of the windows covering it (weights
    :func:`triangular_window`), so an identity model gives the input back exactly.
    ``left`` is the padding returned by :func:`split_clips` (removed here).
    """
    Y = np.asarray(Y, dtype=np.float64)
    K, f, C = Y.shape
    w = triangular_window(f) if window is None else np.asarray(window, dtype=np.float64)
    Tp = int(starts[-1]) + f
    idx = (starts[:, None] + np.arange(f)[None, :]).reshape(-1)
    acc = np.zeros((Tp, C))
    wsum = np.bincount(idx, weights=np.tile(w, K), minlength=Tp)
    np.add.at(acc, idx, (Y * w[None, :, None]).reshape(-1, C))
    out = acc / wsum[:, None]
    return out[left:left + T]


def training_windows(T: int, f: int = CLIP_FRAMES, hop: int = CLIP_HOP) -> np.ndarray:
    """Starts of the paper's training clips of a T-frame motion (same as :func:`clip_starts`)."""
    return clip_starts(T, f, hop)


# ----------------------------------------------------------------------------------------
# dropped joints
# ----------------------------------------------------------------------------------------
def _min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation matrices (T, 3, 3) taking unit vector a (3,) onto unit vectors b (T, 3)."""
    a = a / max(np.linalg.norm(a), 1e-12)
    nb = np.linalg.norm(b, axis=1, keepdims=True)
    b = np.where(nb > 1e-9, b / np.maximum(nb, 1e-12), a[None, :])
    v = np.cross(np.broadcast_to(a, b.shape), b)
    c = b @ a
    T = len(b)
    K = np.zeros((T, 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    R = np.eye(3)[None] + K + (K @ K) / (1.0 + c)[:, None, None]
    # opposite vectors (c ~ -1): rotate by pi about any axis orthogonal to a
    opp = c < -1 + 1e-9
    if opp.any():
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        R[opp] = 2 * np.outer(axis, axis) - np.eye(3)
    return R


def attach_dropped(kept: np.ndarray, skeleton: Skeleton, joints: Sequence[str], *,
                   source: np.ndarray | None = None, source_observed: np.ndarray | None = None) -> np.ndarray:
    """Full-skeleton positions (T, J, 3) from refined positions of the kept joints.

    Parameters
    ----------
    kept : (T, K, 3) cm, positions of ``joints`` (model order).
    skeleton : the motion's full skeleton (J joints, rest offsets in cm).
    joints : names of the kept joints.
    source, source_observed : optional input positions (T, J, 3) and mask (T, J). Then a
        dropped joint is the input's own track smoothed by each coordinate's GCV spline
        (:func:`mocapkit.solvers.gcv_spline.gcv_smooth`, the network's base filter) where
        the input observes it. Elsewhere, and without ``source``, it follows its nearest
        kept ancestor rigidly (module docstring).

    Why not the rigid attachment everywhere: it is 0.9-1.0 cm off on clean CMU clips (the
    hands and toes move about their ancestors). Measured with the shipped bra-p on 5 CMU
    clips of *training* subjects (05_05, 07_03, 131_08, 135_05, 01_01; 60 fps, whole
    skeleton): rigid 0.029 / 0.78 / 1.17 cm (clean / 1 cm / 3 cm noise), the refined
    ancestor plus the input's GCV-smoothed offset 0.004 / 0.44 / 1.00, the joint's own
    GCV-smoothed track 0.004 / 0.43 / 0.95 (this rule).
    """
    rigid = _attach_rigid(kept, skeleton, joints)
    if source is None:
        return rigid
    from ..solvers.gcv_spline import gcv_smooth

    src = np.asarray(source, dtype=np.float64)
    obs = np.isfinite(src).all(axis=2) if source_observed is None else np.asarray(source_observed, bool)
    kset = set(skeleton.indices(joints))
    drop = [j for j in range(skeleton.n_joints) if j not in kset and obs[:, j].any()]
    if not drop or len(src) < 8:                # the spline needs 8 frames
        return rigid
    M = np.repeat(obs[:, drop], 3, axis=1)
    fit, _ = gcv_smooth(src[:, drop].reshape(len(src), -1), M, validate=False)   # M: what it may use
    out = rigid.copy()
    ok = obs[:, drop]
    sub = out[:, drop]
    sub[ok] = fit.reshape(len(src), -1, 3)[ok]
    out[:, drop] = sub
    return out


def _attach_rigid(kept: np.ndarray, skeleton: Skeleton, joints: Sequence[str]) -> np.ndarray:
    """:func:`attach_dropped` without an input: the rigid attachment alone."""
    kept = np.asarray(kept, dtype=np.float64)
    T = kept.shape[0]
    J = skeleton.n_joints
    kidx = skeleton.indices(joints)
    out = np.full((T, J, 3), np.nan)
    out[:, kidx] = kept
    if len(kidx) == J:
        return out
    kset = {j: k for k, j in enumerate(kidx)}
    rest = skeleton.rest_positions()
    par = skeleton.parents

    def kept_ancestor(j: int) -> int:
        p = int(par[j])
        while p >= 0 and p not in kset:
            p = int(par[p])
        return p

    def subtree(j: int) -> list[int]:
        out_, stack = [], [j]
        while stack:
            u = stack.pop()
            out_.append(u)
            stack.extend(skeleton.children(u))
        return sorted(out_)

    for j in range(J):
        if j in kset:
            continue
        a = kept_ancestor(j)
        if a < 0:                       # above every kept joint: follow the first kept joint
            a = kidx[0]
            out[:, j] = out[:, a] + (rest[j] - rest[a])
            continue
        below = [u for u in subtree(j) if u in kset] or [u for u in subtree(a) if u in kset and u != a]
        if below:
            c = below[0]
            rest_dir, cur_dir = rest[c] - rest[a], out[:, c] - out[:, a]
        else:
            b = kept_ancestor(a)
            if b < 0:
                out[:, j] = out[:, a] + (rest[j] - rest[a])
                continue
            rest_dir, cur_dir = rest[a] - rest[b], out[:, a] - out[:, b]
        if np.linalg.norm(rest_dir) < 1e-9:
            out[:, j] = out[:, a] + (rest[j] - rest[a])
            continue
        R = _min_rotation(rest_dir, cur_dir)
        out[:, j] = out[:, a] + R @ (rest[j] - rest[a])
    return out
