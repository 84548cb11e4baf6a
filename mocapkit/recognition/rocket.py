"""MultiRocket-style features + augmented ridge classifier: the default action classifier.

Paper: A. Dempster, D. F. Schmidt, G. I. Webb, "MiniRocket: A Very Fast (Almost)
Deterministic Transform for Time Series Classification", KDD 2021 (multivariate variant
as in the authors' ``minirocket_multivariate`` reference code); the two-representation
idea (the series and its first difference) is from MultiRocket (Tan, Dempster, Bergmeir
& Webb 2022, Data Min. Knowl. Disc.). Written here in plain numpy: the maintained
library implementation (``aeon`` 1.5/1.6) needs ``numba < 0.64``, which needs
``numpy < 2.4`` and would downgrade the numpy/scikit-learn this project pins.

Input (:func:`trajectories`, vectorised over frames)
----------------------------------------------------
Every joint of the skeleton (no keypoint selection: the Kinect hands and feet matter for
the drawing actions), gaps bridged linearly, in the canonical frame of
:func:`mocapkit.retrieval.features.prepare` (``keypoints=False``): up axis found, one
heading rotation per clip from the hips over the first 0.5 s, joints relative to the root
(hip centre), the root relative to its first position. Decision (``heading='auto'``):
depth-sensor files (Kinect format) keep the camera's horizontal axes -- the subject faces
the sensor, and a heading from the Kinect hip joints (its noisiest) cost 1-2 points on
MSR-Action3D, while on HDM05 (actors facing any way) dropping the heading step cost 7
points in the 2-actor cross-actor split. Then divided by the body size (median
|head - root| + mean leg length, from the named keypoints when the skeleton has them,
else prepare's extent-based size), optionally Gaussian-smoothed (``smooth_s`` seconds),
then linearly resampled to ``length`` samples over the clip's duration. Channels are the
joint coordinates, ``3 J`` of them, joint-major (x, y, z of the root first).

Views (``views``): ``'joints'`` = these series; ``'arms'`` = :func:`arm_view` of them, 18
channels (per side elbow - shoulder, wrist - shoulder, wrist - head, divided by that arm's
length: the hand path about the shoulder, which is what tells the one-arm drawing actions
apart), for skeletons whose keypoints :func:`series_keypoints` finds (Kinect 20 joints, CMU,
HDM05; left out otherwise). Each view gets its own transforms; features are concatenated.
Offered, not in the default (inner validation did not pay, ``docs/results/recognition.md``):
``'bones'`` = :func:`bone_view`, the unit directions of the 14 keypoint bones (42 channels),
``'reach'`` = :func:`reach_view`, head, elbows and wrists about the hip centre (15),
``'dist'`` = :func:`dist_view`, distances of 16 key joint pairs, ``'angles'`` =
:func:`angles_view`, 11 joint angles, and ``'height'`` = :func:`height_view`, hand and
elbow heights and horizontal reach per arm length (10).

Transform (:class:`MiniRocket`)
-------------------------------
84 fixed kernels of length 9: weights -1 everywhere except 2 at three of the nine
positions (all C(9, 3) choices; the weights sum to 0). Dilations
``floor(2^linspace(0, log2((L - 1) / 8), 32))`` (unique values; features per dilation
proportional to the repeats, Sec. 3.2). Each (dilation, kernel) pair is applied to a
random subset of 1-9 channels (``2^U(0, log2(min(C, 9) + 1))`` of them), the per-channel
convolutions summed. Output with zero padding ("same" length) for every other
(dilation, kernel) pair, the valid part only for the others (Sec. 3.4). Biases: quantiles
``frac(i * golden ratio)`` of the convolution output of one random training example per
pair (Sec. 3.3). Feature = PPV, the proportion of positive values of ``C - b``. With
``diff=True`` a second, independent transform is applied to the first difference of the
series (the velocity) and the features are concatenated (MultiRocket's two
representations). Poolings (``pooling``): PPV only = MiniRocket; PPV, mean of positive
values, mean index of positive values and longest run of positive values = MultiRocket
(Tan et al. 2022 Sec. 3.2; :func:`_pool`). Vectorised: one (samples x time, channels) @ (channels, 84)
product per tap and dilation -- the convolution of all 84 kernels is
``sum_t X_t @ (M o w_t)`` with ``M`` the channel-subset masks and ``w_t`` the kernels'
weights at tap ``t``.

Classifier (:class:`RocketClassifier`)
--------------------------------------
Defaults (chosen by inner validation on training clips only, see
``benchmarks/run_recognition.py --select``, ``benchmarks/run_recognition_explore.py`` and
``docs/results/recognition.md``): the joints and arms views, MultiRocket poolings, 5,000
(kernel, bias) pairs per representation (series and first difference) and view (~80,000
features), plus :class:`Hydra` counts of every view and its difference (``hydra=True``;
HYDRA + MultiRocket as in Dempster et al. 2023; ~25,000 features), and ``augment = 2``
perturbed copies of every training clip
(:func:`augment_series`: time crop/extension up to +-10 % at each end, a smooth speed
warp, and a turn about the vertical axis of up to +-15 deg). The transform's biases are
taken from the original clips; the copies only add training rows. Features standardised,
then a ridge read-out on +-1 one-hot targets (:func:`ridge_group_loo`, replacing
scikit-learn's ``RidgeClassifierCV``: its efficient leave-one-out would let the copies of
a clip validate each other) with ``alphas = logspace(-3, 5, 17)`` chosen by exact
leave-one-**clip**-out (a clip and its copies form one group). ``n_seeds > 1``
concatenates the features of several transform seeds. The confidence returned by
``predict`` is a softmax of the ridge scores with one temperature fitted on the
held-out scores of the original training clips (minimum negative log-likelihood over a
grid), so it is a calibrated-ish probability, not a raw ridge score. All random choices
come from ``numpy.random.default_rng``: the same data and seed give the same model and
predictions.

Model files: format ``mocapkit-minirocket`` version 3 (parameters, transforms ``r{i}_`` /
``h{i}_``, the ``keypoints`` of :func:`series_keypoints` -- the 7 arm keypoints in files
written before the bone view existed, which is all the arm view reads --, linear read-out;
a file with a view an older reader lacks fails there with a shape error). Version-2 files (joints view only) and
version-1 files (MiniRocket PPV, no augmentation) still load and predict as before; other
versions are refused with :class:`~mocapkit.errors.MocapFormatError`.

A model remembers the joint names of its training skeleton; classifying a motion of
another joint set raises :class:`~mocapkit.errors.MocapValueError` naming both. Models
save to ``.npz`` (no pickle).
"""
from __future__ import annotations

import itertools
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from .._params import store_params
from ..errors import MocapFormatError, MocapValueError, NotFittedError
from ..motion import Motion
from .model_file import (check_joint_set, joint_set_of, load_model, read_head, register_format,
                         write_model)

__all__ = ["trajectories", "MiniRocket", "Hydra", "arm_view", "bone_view", "reach_view", "dist_view",
           "angles_view", "height_view", "series_keypoints", "RocketClassifier", "fit_dilations", "golden_quantiles",
           "augment_series", "ridge_group_loo", "KERNEL_INDICES", "MODEL_FORMAT"]

KERNEL_LENGTH = 9
KERNEL_INDICES = np.array(list(itertools.combinations(range(KERNEL_LENGTH), 3)), dtype=np.int64)  # (84, 3)
N_KERNELS = len(KERNEL_INDICES)
MODEL_FORMAT = "mocapkit-minirocket"
MODEL_FORMAT_VERSION = 3
# settings of version-1 model files (MiniRocket PPV, one transform, no augmentation), which
# stored no ``augment`` / ``n_seeds``: they still load and predict as before
V1_PARAMS = {"pooling": ["ppv"], "n_features": 10_000, "augment": 0, "n_seeds": 1}
# settings of version-1/2 files, which stored no ``views`` / ``hydra``: the joints view, no HYDRA
V2_PARAMS = {"views": ["joints"], "hydra": False}
_CHUNK = 64                           # samples per block in the transform (bounds memory)


# ------------------------------------------------------------------------------- input
def _body_size(P: np.ndarray, skeleton) -> float | None:
    """Median |head - root| + mean leg length of prepared positions (T, J, 3), root-first
    order of :func:`prepare` (``keypoints=False``); None when the keypoints are unknown."""
    from ..retrieval.features import KEYPOINTS, find_keypoints

    idx = find_keypoints(skeleton)
    if idx is None:
        return None
    J = skeleton.n_joints
    r = int(np.flatnonzero(skeleton.parents < 0)[0])
    order = [r] + [j for j in range(J) if j != r]
    pos = {j: i for i, j in enumerate(order)}
    kp = {k: pos[int(j)] for k, j in zip(KEYPOINTS, idx)}
    A = P.copy()
    A[:, 1:] += A[:, :1]                                   # back to absolute (root trajectory)
    seg = lambda a, b: np.linalg.norm(A[:, kp[a]] - A[:, kp[b]], axis=1)  # noqa: E731
    leg = 0.5 * (seg("lhip", "lknee") + seg("lknee", "lankle") + seg("rhip", "rknee") + seg("rknee", "rankle"))
    s = float(np.median(seg("head", "root") + leg))
    return s if np.isfinite(s) and s > 1e-9 else None


def resolve_heading(motion: Motion, heading: str = "auto") -> str:
    """``'auto'`` -> ``'none'`` for depth-sensor files (Kinect format: already in the
    camera frame the subject faces), ``'start'`` otherwise (module doc)."""
    if heading != "auto":
        return heading
    return "none" if str(motion.source.get("format", "")) == "kinect" else "start"


def trajectories(motion: Motion, length: int = 64, *, smooth_s: float = 0.0,
                 heading: str = "auto", trim: float = 0.0, motion_time: float = 0.0) -> np.ndarray:
    """Body-centred, size-normalised joint trajectories (3J, length) of ``motion`` (module doc).

    ``heading``: ``'start'`` / ``'mean'`` / ``'none'`` as in
    :func:`~mocapkit.retrieval.features.prepare`, or ``'auto'`` (:func:`resolve_heading`).
    ``trim`` (0 <= trim < 0.5): the fraction of the clip's motion (the summed joint speeds,
    body sizes per frame) cut off at each end before resampling -- idle frames before and
    after the action, which the subjects hold for different times. ``motion_time`` (0-1):
    the resampling clock, 0 = time, 1 = the motion's progress (the cumulative summed joint
    speed), between = their mix: pauses shrink and fast strokes get more samples.
    Units: body sizes (about 0.9 x standing height). A file's reference pose (a BVH's
    T-pose first frame, :func:`mocapkit.denoise.bases.reference_frames`) is left out.
    Raises MocapValueError for a motion with no observed joint.

    >>> from mocapkit import datasets, io
    >>> m = io.read(datasets.bundled("16_15.amc")).slice(0, 60)
    >>> trajectories(m, 32).shape, trajectories(m, 32, trim=0.05, motion_time=0.5).shape
    ((93, 32), (93, 32))
    """
    from ..denoise.bases import reference_frames
    from ..retrieval.features import prepare

    if not isinstance(motion, Motion):
        raise MocapValueError(f"expected a Motion, got {type(motion).__name__}")
    ref = reference_frames(motion)
    if ref:                        # a BVH's T-pose first frame is no part of the action
        motion = motion.slice(ref, None)
    length = int(length)
    if length < KERNEL_LENGTH:
        raise MocapValueError(f"length must be at least {KERNEL_LENGTH} samples, got {length}")
    p = prepare(motion, keypoints=False, smooth_s=smooth_s, heading=resolve_heading(motion, heading))
    P = p.positions                                        # (T, J, 3), / prepare's size
    s = _body_size(P, motion.skeleton)
    if s is not None:
        P = P / s
    T = P.shape[0]
    X = P.reshape(T, -1)
    if T == 1:
        return np.repeat(X.T, length, axis=1)
    t = _sample_times(P, length, float(trim), float(motion_time))
    lo = np.minimum(np.floor(t).astype(int), T - 2)
    w = (t - lo)[:, None]
    return (X[lo] * (1.0 - w) + X[lo + 1] * w).T


def _sample_times(P: np.ndarray, length: int, trim: float, motion_time: float) -> np.ndarray:
    """Fractional frame indices (length,) at which :func:`trajectories` samples positions
    P (T, J, 3): evenly in time over the whole clip by default; with ``trim`` the span
    between the frames where the cumulative motion passes ``trim`` and ``1 - trim`` of its
    total; with ``motion_time`` evenly in the mixed clock (1 - m) t / (T - 1) + m c(t), c the
    cumulative motion over its total."""
    T = P.shape[0]
    if not (0.0 <= trim < 0.5 and 0.0 <= motion_time <= 1.0):
        raise MocapValueError(f"trim must be in [0, 0.5) and motion_time in [0, 1], got {trim}, {motion_time}")
    frames = np.arange(T, dtype=float)
    if trim == 0.0 and motion_time == 0.0:
        return np.linspace(0.0, T - 1.0, length)
    speed = np.linalg.norm(np.diff(P, axis=0), axis=2).sum(axis=1)
    cum = np.concatenate([[0.0], np.cumsum(np.nan_to_num(speed))])
    if not cum[-1] > 1e-12:                               # no motion at all: the time clock
        return np.linspace(0.0, T - 1.0, length)
    # strictly increasing (np.interp needs it): a tiny share of time breaks the ties of
    # frames without motion
    c = (cum / cum[-1]) * (1.0 - 1e-9) + 1e-9 * frames / (T - 1)
    a, b = np.interp([trim, 1.0 - trim], c, frames)
    u = (1.0 - motion_time) * frames / (T - 1) + motion_time * c   # the resampling clock
    ua, ub = np.interp([a, b], frames, u)
    return np.interp(np.linspace(ua, ub, length), u, frames)


# --------------------------------------------------------------------------- transform
def fit_dilations(length: int, n_features: int = 10_000, max_dilations: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """Dilations and features per dilation of MiniRocket (paper Sec. 3.2 / reference code)."""
    per_kernel = max(1, n_features // N_KERNELS)
    true_max = min(per_kernel, max_dilations)
    mult = per_kernel / true_max
    max_exp = np.log2((length - 1) / (KERNEL_LENGTH - 1))
    dil, counts = np.unique(np.logspace(0, max_exp, true_max, base=2).astype(np.int64), return_counts=True)
    nf = (counts * mult).astype(np.int64)
    rem = per_kernel - int(nf.sum())
    i = 0
    while rem > 0:
        nf[i] += 1
        rem -= 1
        i = (i + 1) % len(nf)
    return dil, nf


def golden_quantiles(n: int) -> np.ndarray:
    """``frac(i * (1 + sqrt 5) / 2)``, i = 1..n: the low-discrepancy bias quantiles."""
    return (np.arange(1, n + 1) * ((np.sqrt(5.0) + 1.0) / 2.0)) % 1.0


def _tap_weights(masks: np.ndarray) -> np.ndarray:
    """(9, C, 84) matrices ``M o w_t``: channel mask times each kernel's weight at tap t."""
    w = -np.ones((KERNEL_LENGTH, N_KERNELS))
    w[KERNEL_INDICES.T, np.arange(N_KERNELS)[None, :]] = 2.0
    return masks.T[None, :, :] * w[:, None, :]


def _convolve(X: np.ndarray, dilation: int, W: np.ndarray) -> np.ndarray:
    """Zero-padded ("same") multichannel convolution of the kernels W (9, C, K): (n, L, K)."""
    n, C, L = X.shape
    pad = (KERNEL_LENGTH - 1) * dilation // 2
    Xp = np.zeros((n, L + 2 * pad, C))
    Xp[:, pad:pad + L] = X.transpose(0, 2, 1)
    out = np.zeros((n, L, W.shape[2]))
    for t in range(KERNEL_LENGTH):
        out += Xp[:, t * dilation:t * dilation + L] @ W[t]
    return out


POOLINGS = ("ppv", "mpv", "mipv", "lspv")          # MultiRocket's four: the default
PYRAMID_POOLINGS = ("ppv_h1", "ppv_h2")           # offered, not in the default


def _pool(Cv: np.ndarray, b: np.ndarray, pooling: Sequence[str]) -> np.ndarray:
    """Pooled features of ``Z = Cv - b``: Cv (n, L', K), b (K, f) -> (n, K, f, len(pooling)).

    ppv: proportion of positive values (MiniRocket); mpv: mean of the positive values (0
    when none); mipv: mean index of the positive values / (L' - 1) (-1 when none); lspv:
    longest run of consecutive positive values / L' (MultiRocket, Tan et al. 2022 Sec. 3.2;
    the index and run features are divided by the length here so they do not depend on it);
    ppv_h1 / ppv_h2: the PPV of the first / second half of the output (a two-level temporal
    pyramid: *when* in the action a pattern occurs, which the whole-series poolings only
    summarise through mipv).
    """
    Lp = Cv.shape[1]
    Z = Cv[:, :, :, None] - b[None, None, :, :]                 # (n, L', K, f)
    pos = Z > 0
    cnt = pos.sum(axis=1)
    out = []
    for name in pooling:
        if name == "ppv":
            out.append(cnt / Lp)
        elif name == "mpv":
            out.append(np.where(cnt > 0, (Z * pos).sum(axis=1) / np.maximum(cnt, 1), 0.0))
        elif name == "mipv":
            t = np.arange(Lp, dtype=np.float64)[None, :, None, None]
            mi = (t * pos).sum(axis=1) / np.maximum(cnt, 1) / max(Lp - 1, 1)
            out.append(np.where(cnt > 0, mi, -1.0))
        elif name in ("ppv_h1", "ppv_h2"):
            h = Lp // 2
            part = pos[:, :h] if name == "ppv_h1" else pos[:, h:]
            out.append(part.sum(axis=1) / max(part.shape[1], 1))
        elif name == "lspv":                                    # run length = t - last non-positive t
            t = np.arange(Lp)[None, :, None, None]
            last = np.maximum.accumulate(np.where(pos, -1, t), axis=1)
            out.append((t - last).max(axis=1) / Lp)
        else:
            raise MocapValueError(f"unknown pooling {name!r}; choose from {', '.join(POOLINGS + PYRAMID_POOLINGS)}")
    return np.stack(out, axis=-1)


class MiniRocket:
    """The MiniRocket transform of multichannel series (n, C, L) (module doc).

    Parameters
    ----------
    n_features : about this many features (multiples of 84).
    max_dilations : maximum dilations per kernel (32, paper).
    pooling : features per (kernel, bias): ``('ppv',)`` = MiniRocket; all four of
        :data:`POOLINGS` = MultiRocket; :data:`PYRAMID_POOLINGS` (the PPV of each half)
        may be added (inner validation did not pay, docs/results/recognition.md).
    max_channels : largest channel subset per (dilation, kernel) (9, reference code).
    seed : random state of the channel subsets and the bias examples.
    """

    def __init__(self, *, n_features: int = 10_000, max_dilations: int = 32,
                 pooling: Sequence[str] = ("ppv",), max_channels: int = 9, seed: int = 0):
        store_params(self, locals(), tuples=("pooling",))

    def fit(self, X: np.ndarray) -> "MiniRocket":
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 3 or X.shape[2] < KERNEL_LENGTH or len(X) < 1:
            raise MocapValueError(f"MiniRocket needs series (n, channels, length >= 9), got shape {X.shape}")
        if not np.isfinite(X).all():
            raise MocapValueError("MiniRocket needs finite series")
        n, C, L = X.shape
        rng = np.random.default_rng(self.seed)
        dil, nf = fit_dilations(L, self.n_features, self.max_dilations)
        n_comb = len(dil) * N_KERNELS
        max_exp = np.log2(min(C, int(self.max_channels)) + 1)
        n_ch = (2.0 ** rng.uniform(0, max_exp, n_comb)).astype(np.int64)
        masks = np.zeros((n_comb, C))
        for i, k in enumerate(n_ch):                       # one draw per (dilation, kernel)
            masks[i, rng.choice(C, int(k), replace=False)] = 1.0
        examples = rng.integers(0, n, n_comb)
        q = golden_quantiles(int((nf * N_KERNELS).sum()))
        biases, start = [], 0
        for di, (d, f) in enumerate(zip(dil, nf)):
            sl = slice(di * N_KERNELS, (di + 1) * N_KERNELS)
            ex = examples[sl]
            u, inv = np.unique(ex, return_inverse=True)
            Cfull = _convolve(X[u], int(d), _tap_weights(masks[sl]))          # (u, L, 84)
            rows = np.sort(Cfull[inv, :, np.arange(N_KERNELS)], axis=1)       # (84, L)
            qq = q[start:start + f * N_KERNELS].reshape(N_KERNELS, f)        # kernel-major
            start += f * N_KERNELS
            pos = qq * (L - 1)                                                # np.quantile 'linear'
            lo = np.floor(pos).astype(np.int64)
            hi = np.minimum(lo + 1, L - 1)
            g = pos - lo
            r = np.arange(N_KERNELS)[:, None]
            biases.append(rows[r, lo] * (1 - g) + rows[r, hi] * g)            # (84, f)
        self.length_ = int(L)
        self.n_channels_ = int(C)
        self.dilations_ = dil
        self.features_per_dilation_ = nf
        self.masks_ = masks
        self.biases_ = np.concatenate([b.ravel() for b in biases])
        return self

    @property
    def n_features_out(self) -> int:
        return int((self.features_per_dilation_ * N_KERNELS).sum()) * len(self.pooling)

    def transform(self, X: np.ndarray) -> np.ndarray:
        """Pooled features (n, F), F = 84 * sum(features per dilation) * len(pooling),
        dilation-major, then kernel, bias, pooling."""
        if not hasattr(self, "biases_"):
            raise NotFittedError("MiniRocket is not fitted")
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 3 or X.shape[1:] != (self.n_channels_, self.length_):
            raise MocapValueError(f"series must have shape (n, {self.n_channels_}, {self.length_}), got {X.shape}")
        L = self.length_
        out = np.empty((len(X), self.n_features_out))
        for a in range(0, len(X), _CHUNK):
            Xc = X[a:a + _CHUNK]
            col, bstart = 0, 0
            for di, (d, f) in enumerate(zip(self.dilations_, self.features_per_dilation_)):
                d, f = int(d), int(f)
                sl = slice(di * N_KERNELS, (di + 1) * N_KERNELS)
                Cv = _convolve(Xc, d, _tap_weights(self.masks_[sl]))
                b = self.biases_[bstart:bstart + f * N_KERNELS].reshape(N_KERNELS, f)
                bstart += f * N_KERNELS
                npool = len(self.pooling)
                F = np.empty((len(Xc), N_KERNELS, f, npool))
                pad = (KERNEL_LENGTH - 1) * d // 2
                padded = (np.arange(N_KERNELS) + di) % 2 == 0       # alternate padding (Sec. 3.4)
                F[:, padded] = _pool(Cv[:, :, padded], b[padded], self.pooling)
                valid = Cv[:, pad:L - pad] if L - 2 * pad > 0 else Cv  # dilations keep L - 8d >= 1
                F[:, ~padded] = _pool(valid[:, :, ~padded], b[~padded], self.pooling)
                out[a:a + _CHUNK, col:col + N_KERNELS * f * npool] = F.reshape(len(Xc), -1)
                col += N_KERNELS * f * npool
        return out

    def state(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}dilations": self.dilations_, f"{prefix}nfeat": self.features_per_dilation_,
                f"{prefix}masks": self.masks_.astype(np.uint8), f"{prefix}biases": self.biases_,
                f"{prefix}shape": np.array([self.n_channels_, self.length_])}

    @classmethod
    def from_state(cls, st: dict, prefix: str, params: dict) -> "MiniRocket":
        m = cls(**params)
        m.dilations_ = st[f"{prefix}dilations"].astype(np.int64)
        m.features_per_dilation_ = st[f"{prefix}nfeat"].astype(np.int64)
        m.masks_ = st[f"{prefix}masks"].astype(np.float64)
        m.biases_ = st[f"{prefix}biases"].astype(np.float64)
        m.n_channels_, m.length_ = (int(v) for v in st[f"{prefix}shape"])
        return m


def _difference(X: np.ndarray) -> np.ndarray:
    """First difference along time, same length (the first sample repeated): (n, C, L)."""
    D = np.diff(X, axis=2)
    return np.concatenate([D[:, :, :1], D], axis=2)


# ------------------------------------------------------------------------------ HYDRA
class Hydra:
    """HYDRA dictionary-convolution counts of multichannel series (n, C, L).

    Paper: A. Dempster, D. F. Schmidt, G. I. Webb, "HYDRA: Competing convolutional kernels
    for fast and accurate time series classification", Data Min. Knowl. Disc. 2023
    (Sec. 3; multivariate variant of the authors' ``hydra_multivariate`` code): ``g`` groups
    of ``k`` random kernels of length 9 (weights N(0, 1), mean removed, divided by their
    absolute sum), dilations ``2^0 .. 2^floor(log2((L - 1) / 8))``, zero ("same") padding;
    each group reads a random subset of ``max_channels`` channels (the per-channel
    convolutions summed). At every time step the kernels of a group compete: the
    arg-max kernel adds its response to its count ("soft max count"), the arg-min kernel
    adds 1 ("hard min count"). Features ``sqrt(max(count, 0))`` (the paper's sparse
    scaling, before the classifier's standardisation): ``2 g k`` per dilation.
    """

    def __init__(self, *, k: int = 8, g: int = 64, max_channels: int = 3, seed: int = 0):
        self.k, self.g, self.max_channels, self.seed = int(k), int(g), int(max_channels), seed

    def fit(self, X: np.ndarray) -> "Hydra":
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 3 or X.shape[2] < KERNEL_LENGTH:
            raise MocapValueError(f"HYDRA needs series (n, channels, length >= 9), got shape {X.shape}")
        _, C, L = X.shape
        rng = np.random.default_rng(self.seed)
        self.dilations_ = 2 ** np.arange(int(np.log2((L - 1) / (KERNEL_LENGTH - 1))) + 1)
        W = rng.standard_normal((len(self.dilations_), KERNEL_LENGTH, C, self.g * self.k))
        W -= W.mean(1, keepdims=True)
        W /= np.abs(W).sum(1, keepdims=True)
        mask = np.zeros((len(self.dilations_), C, self.g))
        for di in range(len(self.dilations_)):
            for gi in range(self.g):
                mask[di, rng.choice(C, min(C, self.max_channels), replace=False), gi] = 1.0
        self.weights_ = W * np.repeat(mask, self.k, axis=2)[:, None]
        self.n_channels_, self.length_ = int(C), int(L)
        return self

    @property
    def n_features_out(self) -> int:
        return 2 * len(self.dilations_) * self.g * self.k

    def transform(self, X: np.ndarray) -> np.ndarray:
        """Features (n, 2 g k per dilation), dilation-major, then (max, min) counts, group, kernel."""
        if not hasattr(self, "weights_"):
            raise NotFittedError("HYDRA is not fitted")
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 3 or X.shape[1:] != (self.n_channels_, self.length_):
            raise MocapValueError(f"series must have shape (n, {self.n_channels_}, {self.length_}), got {X.shape}")
        n, L = len(X), self.length_
        out = np.empty((n, self.n_features_out))
        oh = np.arange(self.k)
        for a in range(0, n, _CHUNK):
            Xc = X[a:a + _CHUNK]
            m, col = len(Xc), 0
            for d, W in zip(self.dilations_, self.weights_):
                Z = _convolve(Xc, int(d), W).reshape(m, L, self.g, self.k)
                top = Z.argmax(3)[..., None] == oh                           # (m, L, g, k)
                cmax = (top * Z.max(3)[..., None]).sum(1)
                cmin = (Z.argmin(3)[..., None] == oh).sum(1)
                out[a:a + m, col:col + 2 * self.g * self.k] = np.concatenate(
                    [cmax.reshape(m, -1), cmin.reshape(m, -1)], axis=1)
                col += 2 * self.g * self.k
        return np.sqrt(np.maximum(out, 0.0))

    def state(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}dilations": self.dilations_, f"{prefix}weights": self.weights_,
                f"{prefix}shape": np.array([self.n_channels_, self.length_, self.k, self.g])}

    @classmethod
    def from_state(cls, st: dict, prefix: str, seed: int = 0) -> "Hydra":
        C, L, k, g = (int(v) for v in st[f"{prefix}shape"])
        h = cls(k=k, g=g, seed=seed)
        h.dilations_ = st[f"{prefix}dilations"].astype(np.int64)
        h.weights_ = st[f"{prefix}weights"].astype(np.float64)
        h.n_channels_, h.length_ = C, L
        return h


# ------------------------------------------------------------------------------ views
ARM_KEYPOINTS = ("head", "lshoulder", "lelbow", "lwrist", "rshoulder", "relbow", "rwrist")
# the order of :func:`series_keypoints`: the arm keypoints first (all that version-3 files
# stored, and all :func:`arm_view` reads), then the rest of the body for :func:`bone_view`
SERIES_KEYPOINTS = ARM_KEYPOINTS + ("root", "neck", "lhip", "lknee", "lankle", "rhip", "rknee", "rankle")
# bones of :func:`bone_view` as (parent, child) names of SERIES_KEYPOINTS
BONES = (("root", "neck"), ("neck", "head"),
         ("neck", "lshoulder"), ("lshoulder", "lelbow"), ("lelbow", "lwrist"),
         ("neck", "rshoulder"), ("rshoulder", "relbow"), ("relbow", "rwrist"),
         ("root", "lhip"), ("lhip", "lknee"), ("lknee", "lankle"),
         ("root", "rhip"), ("rhip", "rknee"), ("rknee", "rankle"))
VIEWS = ("joints", "arms", "bones", "reach", "dist", "angles", "height")
# keypoints a view needs (it is left out when the model has fewer)
VIEW_KEYPOINTS = {"joints": 0, "arms": len(ARM_KEYPOINTS), "bones": len(SERIES_KEYPOINTS),
                  "reach": len(ARM_KEYPOINTS), "dist": len(SERIES_KEYPOINTS),
                  "angles": len(SERIES_KEYPOINTS), "height": len(SERIES_KEYPOINTS)}
REACH_KEYPOINTS = ("head", "lelbow", "lwrist", "relbow", "rwrist")
# joint pairs of :func:`dist_view` ("ankles" = their midpoint): the hands' distances to each
# other, the head, the hip centre, the feet and the other shoulder (arm height and reach,
# hand catch / side-boxing / throws), the elbows' to the head, and the feet's to each other
# and the hips (kicks, jogging, bend: the head comes down towards the feet)
DIST_PAIRS = (("lwrist", "rwrist"), ("lwrist", "head"), ("rwrist", "head"),
              ("lwrist", "root"), ("rwrist", "root"), ("lwrist", "lankle"), ("rwrist", "rankle"),
              ("lwrist", "rshoulder"), ("rwrist", "lshoulder"), ("lelbow", "head"), ("relbow", "head"),
              ("lelbow", "relbow"), ("head", "ankles"), ("lankle", "rankle"), ("lankle", "root"),
              ("rankle", "root"))


def series_keypoints(skeleton) -> np.ndarray | None:
    """Channel-joint indices (in :func:`trajectories`' root-first joint order) of
    :data:`SERIES_KEYPOINTS` (the 7 :data:`ARM_KEYPOINTS` first), or None when the
    skeleton's keypoints are not found."""
    from ..retrieval.features import KEYPOINTS, find_keypoints

    idx = find_keypoints(skeleton)
    if idx is None:
        return None
    r = int(np.flatnonzero(skeleton.parents < 0)[0])
    order = [r] + [j for j in range(skeleton.n_joints) if j != r]
    pos = {j: i for i, j in enumerate(order)}
    kp = dict(zip(KEYPOINTS, (pos[int(j)] for j in idx)))
    return np.array([kp[k] for k in SERIES_KEYPOINTS], dtype=np.int64)


def arm_view(X: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """Hand-relative arm trajectories (n, 18, L) of joint series X (n, 3J, L).

    Per side: elbow - shoulder, wrist - shoulder and wrist - head, divided by that arm's
    length in the clip (median over time of |shoulder - elbow| + |elbow - wrist|): the
    path of the hand about the shoulder, independent of body position and arm length
    (the one-arm drawing actions differ in that path only). ``keypoints``: the indices of
    :data:`ARM_KEYPOINTS` (:func:`series_keypoints`). The joints other than the root are
    root-relative in X, so their differences are the differences of positions.
    """
    J = lambda j: X[:, 3 * int(j):3 * int(j) + 3]          # noqa: E731
    head = J(keypoints[0])
    parts = []
    for sh, el, wr in (keypoints[1:4], keypoints[4:7]):
        S, E, W = J(sh), J(el), J(wr)
        arm = np.median(np.linalg.norm(E - S, axis=1) + np.linalg.norm(W - E, axis=1), axis=1)
        arm = np.maximum(arm, 1e-6)[:, None, None]
        parts += [(E - S) / arm, (W - S) / arm, (W - head) / arm]
    return np.concatenate(parts, axis=1)


def reach_view(X: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """Head, elbow and wrist trajectories (n, 15, L) of joint series X (n, 3J, L):
    :data:`REACH_KEYPOINTS` relative to the hip centre, in body sizes -- channels of the
    joints view given transforms of their own, so that every kernel reads the arm height
    and reach rather than a random mix of all 3J channels. ``keypoints``: the
    :data:`ARM_KEYPOINTS` indices first (:func:`series_keypoints`)."""
    kp = dict(zip(ARM_KEYPOINTS, (int(k) for k in keypoints)))
    return np.concatenate([X[:, 3 * kp[k]:3 * kp[k] + 3] for k in REACH_KEYPOINTS], axis=1)


def bone_view(X: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """Bone directions (n, 42, L) of joint series X (n, 3J, L): the unit vector of each of
    the 14 :data:`BONES` (spine, neck, per side clavicle, upper arm, forearm, hip, thigh,
    shank), frame by frame.

    The bone stream of two-stream skeleton networks (Shi et al., "Two-Stream Adaptive Graph
    Convolutional Networks for Skeleton-Based Action Recognition", CVPR 2019, Sec. 3.4:
    bone = child - parent joint), here divided by its length in every frame, so that only
    the directions -- the joint angles, e.g. how high the upper arm is raised -- remain,
    independent of body size and proportions. ``keypoints``: the 15 indices of
    :data:`SERIES_KEYPOINTS` (:func:`series_keypoints`). The root is the origin of the
    other joints in X (its own channels hold its path), so a bone from the root is the
    child's series itself.
    """
    kp = dict(zip(SERIES_KEYPOINTS, (int(k) for k in keypoints)))
    root = kp["root"]
    zero = np.zeros((len(X), 3, X.shape[2]))
    J = lambda k: zero if kp[k] == root else X[:, 3 * kp[k]:3 * kp[k] + 3]   # noqa: E731
    parts = []
    for a, b in BONES:
        B = J(b) - J(a)
        parts.append(B / np.maximum(np.linalg.norm(B, axis=1, keepdims=True), 1e-6))
    return np.concatenate(parts, axis=1)


def _named_joints(X: np.ndarray, keypoints: np.ndarray):
    """``J(name)`` -> (n, 3, L) position of a :data:`SERIES_KEYPOINTS` joint in X (n, 3J, L),
    the root as the origin (its own channels hold its path, the others are root-relative);
    ``'ankles'`` = the midpoint of the ankles."""
    kp = dict(zip(SERIES_KEYPOINTS, (int(k) for k in keypoints)))
    zero = np.zeros((len(X), 3, X.shape[2]))

    def J(k: str) -> np.ndarray:
        if k == "ankles":
            return 0.5 * (J("lankle") + J("rankle"))
        return zero if kp[k] == kp["root"] else X[:, 3 * kp[k]:3 * kp[k] + 3]
    return J


def dist_view(X: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """Distances (n, 16, L) between the key joint pairs of :data:`DIST_PAIRS`, frame by frame,
    of joint series X (n, 3J, L) (in body sizes: :func:`trajectories` already divided the
    positions by the clip's body size).

    Distances do not change under any rotation of the body (so neither under the heading
    left by the sensor nor under the augmentation's turn) nor its position, and, relative
    to the body size, little between subjects: the classic pairwise-joint-distance feature
    of skeleton action recognition (e.g. Wang, Liu, Wu & Yuan, "Mining actionlet ensemble
    for action recognition with depth cameras", CVPR 2012, Sec. 3.1), here on 16 pairs that
    tell hand height and reach apart (wrist - head, wrist - hip centre, wrist - foot),
    which the error list of ``docs/results/recognition.md`` points at. ``keypoints``: the
    15 indices of :data:`SERIES_KEYPOINTS` (:func:`series_keypoints`).
    """
    J = _named_joints(X, keypoints)
    return np.stack([np.linalg.norm(J(a) - J(b), axis=1) for a, b in DIST_PAIRS], axis=1)


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle in radians (n, L) between vector series a, b (n, 3, L); arctan2 of |a x b| and
    a . b, which is accurate at 0 and pi where arccos of the cosine is not."""
    return np.arctan2(np.linalg.norm(np.cross(a, b, axis=1), axis=1), np.einsum("nkl,nkl->nl", a, b))


def angles_view(X: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """Joint angles (n, 11, L) in radians of joint series X (n, 3J, L): per side (left,
    right) elbow flexion (upper arm to forearm, 0 = straight), shoulder elevation (upper
    arm to the torso's up direction, hip centre -> neck: 0 = arm straight up, pi = hanging),
    whole-arm elevation (shoulder -> wrist to the torso's up direction), hip flexion (thigh
    to the torso's down direction) and knee flexion (thigh to shank), then the trunk bend
    (hip centre -> neck to the vertical +y of :func:`trajectories`).

    Angles are free of the body's position, heading and size, and of the subject's limb
    lengths: they say how high an arm is raised relative to the trunk (high vs horizontal
    arm wave, hand catch vs high throw) and how far the trunk bends (bend vs pick up &
    throw) whatever the subject's build. ``keypoints``: the 15 indices of
    :data:`SERIES_KEYPOINTS` (:func:`series_keypoints`).
    """
    J = _named_joints(X, keypoints)
    up = J("neck") - J("root")
    out = []
    for s in "lr":
        S, E, W = J(s + "shoulder"), J(s + "elbow"), J(s + "wrist")
        H, K, A = J(s + "hip"), J(s + "knee"), J(s + "ankle")
        out += [_angle(E - S, W - E), _angle(E - S, up), _angle(W - S, up),
                _angle(K - H, -up), _angle(K - H, A - K)]
    vertical = np.zeros_like(up)
    vertical[:, 1] = 1.0
    out.append(_angle(up, vertical))
    return np.stack(out, axis=1)


def height_view(X: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """Arm height and horizontal reach (n, 10, L) of joint series X (n, 3J, L), per side
    (left, right): the vertical (y) offsets wrist - head, wrist - shoulder and elbow -
    shoulder, and the horizontal (x, z) distances wrist - shoulder and wrist - hip centre,
    all divided by that arm's length in the clip (as :func:`arm_view`).

    The height of the hand relative to the head and the shoulder is what separates the
    remaining confusions (high vs horizontal arm wave, hand catch vs side-boxing / high
    throw, pick up & throw vs bend); here it is given kernels of its own instead of being
    one of the 18 mixed arm-view channels, and the horizontal reach is taken as a distance,
    which does not change under a turn about the vertical. ``keypoints``: the 15 indices of
    :data:`SERIES_KEYPOINTS` (:func:`series_keypoints`).
    """
    J = _named_joints(X, keypoints)
    head, root = J("head"), J("root")
    out = []
    for s in "lr":
        S, E, W = J(s + "shoulder"), J(s + "elbow"), J(s + "wrist")
        arm = np.median(np.linalg.norm(E - S, axis=1) + np.linalg.norm(W - E, axis=1), axis=1)
        arm = np.maximum(arm, 1e-6)[:, None]
        horiz = lambda v: np.hypot(v[:, 0], v[:, 2])                     # noqa: E731
        out += [(W - head)[:, 1] / arm, (W - S)[:, 1] / arm, (E - S)[:, 1] / arm,
                horiz(W - S) / arm, horiz(W - root) / arm]
    return np.stack(out, axis=1)


# ------------------------------------------------------------------------ augmentation
def _raise_arms(Xa: np.ndarray, keypoints: np.ndarray, deg: float, rng: np.random.Generator) -> np.ndarray:
    """Joint series Xa (m, 3J, L) (:func:`trajectories` layout, y up) with each arm turned
    about its shoulder by an angle uniform in +-``deg`` degrees per series and side, in the
    vertical plane of the shoulder -> wrist vector (positive = raised): the elbow, the wrist
    and the joints beyond the wrist (hand / fingers: other joints whose median distance to
    the wrist is under half the forearm) move rigidly, the rest of the body stays. The angle
    is scaled frame by frame by the sine of the arm's angle to the vertical, so that an arm
    pointing straight up or down (where the plane is not defined) is left as it is.
    ``keypoints``: the :data:`ARM_KEYPOINTS` indices first (:func:`series_keypoints`)."""
    m, C, L = Xa.shape
    J3 = Xa.reshape(m, C // 3, 3, L).copy()
    kp = np.asarray(keypoints, np.int64)
    others = np.setdiff1d(np.arange(1, C // 3), kp)              # joint 0 holds the root's path
    theta = np.deg2rad(rng.uniform(-deg, deg, (m, 2)))
    up = np.array([0.0, 1.0, 0.0])[None, :, None]
    for side, (s, e, w) in enumerate((kp[1:4], kp[4:7])):
        S, E, W = J3[:, s], J3[:, e], J3[:, w]                    # (m, 3, L)
        v = W - S
        c = np.cross(v, up, axis=1)
        nc = np.linalg.norm(c, axis=1, keepdims=True)             # |v| sin(angle to vertical)
        axis = c / np.maximum(nc, 1e-9)
        ang = theta[:, side, None, None] * nc / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
        cos, sin = np.cos(ang), np.sin(ang)

        def turn(P: np.ndarray) -> np.ndarray:                   # Rodrigues about S; P (m, k, 3, L)
            a, cs, sn = axis[:, None], cos[:, None], sin[:, None]
            r = P - S[:, None]
            return S[:, None] + r * cs + np.cross(a, r, axis=2) * sn + a * (a * r).sum(2, keepdims=True) * (1 - cs)
        if len(others):
            O = J3[:, others]                                     # (m, k, 3, L)
            forearm = np.median(np.linalg.norm(W - E, axis=1), axis=1)
            hand = np.median(np.linalg.norm(O - W[:, None], axis=2), axis=2) < 0.5 * forearm[:, None]
            J3[:, others] = np.where(hand[:, :, None, None], turn(O), O)
        J3[:, [e, w]] = turn(J3[:, [e, w]])
    return J3.reshape(m, C, L)


def augment_series(X: np.ndarray, copies: int, rng: np.random.Generator, *, time_warp: float = 0.1,
                   rot_deg: float = 15.0, arm_deg: float = 0.0,
                   keypoints: np.ndarray | None = None, mix: float = 0.0,
                   labels: np.ndarray | None = None,
                   mix_rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``copies`` randomly perturbed versions of each series of X (n, C, L): ``(Xa, owner)``
    with Xa (n * copies, C, L) and owner (n * copies,) the index of the source series.

    * time: the clip's start and end are moved by up to ``time_warp`` of its duration each
      (inwards = cropping, outwards = holding the first / last sample: temporal scaling of
      up to +-20 %) and the time axis is bent by ``t + u sin(pi t)``, ``|u| <= time_warp``
      (speed jitter), linear interpolation;
    * rotation: when C = 3 J (joint-major x, y, z with y up, as :func:`trajectories`
      gives), all joints and the root path are turned about the vertical axis by an angle
      uniform in +-``rot_deg`` degrees (left out for other channel layouts, or rot_deg = 0);
    * arm height (``arm_deg > 0`` and the :data:`ARM_KEYPOINTS` given as ``keypoints``):
      each arm raised or lowered about its shoulder by up to +-``arm_deg`` degrees
      (:func:`_raise_arms`): subjects reach to different heights in the same action (in
      MSR-Action3D test subject 2's throwing hand stays below the head), which the turn
      about the vertical does not vary. Its random draws come after the others', so
      ``arm_deg = 0`` gives the copies of the models trained without it.
    * style mix (``mix > 0`` and ``labels`` given): each copy's series i moved by
      lam (X_j - X_i) towards (lam > 0) or away from (lam < 0) another series j of its class,
      lam uniform in +-``mix`` (:func:`_style_mix`; draws from ``mix_rng``, so ``mix = 0``
      gives the copies of the models trained without it). Meant to widen the training
      subjects' styles; inner validation (2026-12-06) 0.3 / 0.6: -1.1 / -1.8 points
      cross-subject, +0.7 / +0.7 on the half splits -- not in the default.

    Left/right mirroring was measured and is not offered: the MSR-Action3D actions are
    one-handed and their side is part of the class (inner validation -4 points).
    """
    X = np.asarray(X, dtype=np.float64)
    n, C, L = X.shape
    copies = int(copies)
    if copies <= 0:
        return X[:0], np.zeros(0, dtype=np.int64)
    owner = np.repeat(np.arange(n), copies)
    m = len(owner)
    t = np.linspace(0.0, 1.0, L)[None, :]
    a0 = rng.uniform(-time_warp, time_warp, (m, 1))
    a1 = rng.uniform(-time_warp, time_warp, (m, 1))
    u = rng.uniform(-time_warp, time_warp, (m, 1))
    tt = np.clip(a0 + (t + u * np.sin(np.pi * t)) * (1.0 - a0 - a1), 0.0, 1.0) * (L - 1)   # (m, L)
    lo = np.minimum(np.floor(tt).astype(np.int64), L - 2)
    w = (tt - lo)[:, None, :]
    src = X[owner]                                                       # (m, C, L)
    if mix > 0 and labels is not None:
        src = src + _style_mix(X, owner, np.asarray(labels), float(mix),
                               mix_rng if mix_rng is not None else rng)
    Xa = (np.take_along_axis(src, np.broadcast_to(lo[:, None, :], src.shape), 2) * (1.0 - w)
          + np.take_along_axis(src, np.broadcast_to(lo[:, None, :] + 1, src.shape), 2) * w)
    if rot_deg > 0 and C % 3 == 0:
        ang = np.deg2rad(rng.uniform(-rot_deg, rot_deg, m))[:, None, None]
        J3 = Xa.reshape(m, C // 3, 3, L)
        x, z = J3[:, :, 0].copy(), J3[:, :, 2].copy()
        J3[:, :, 0] = np.cos(ang) * x + np.sin(ang) * z
        J3[:, :, 2] = -np.sin(ang) * x + np.cos(ang) * z
        Xa = J3.reshape(m, C, L)
    if arm_deg > 0 and C % 3 == 0 and keypoints is not None and len(keypoints) >= len(ARM_KEYPOINTS):
        Xa = _raise_arms(Xa, keypoints, float(arm_deg), rng)
    return Xa, owner


def _style_mix(X: np.ndarray, owner: np.ndarray, labels: np.ndarray, mix: float,
               rng: np.random.Generator) -> np.ndarray:
    """(m, C, L) moves lam (X[j] - X[i]) of each copy's series i towards (lam > 0) or
    away from (lam < 0) another series j of the same class, lam uniform in +-``mix``."""
    _, cls = np.unique(labels, return_inverse=True)
    m = len(owner)
    partner = owner.copy()
    draw = rng.random(m)
    for c in np.unique(cls[owner]):
        members = np.flatnonzero(cls == c)
        if len(members) < 2:
            continue
        sel = np.flatnonzero(cls[owner] == c)
        k = np.minimum((draw[sel] * (len(members) - 1)).astype(np.int64), len(members) - 2)
        pos = np.searchsorted(members, owner[sel])
        partner[sel] = members[k + (k >= pos)]                    # any member but the owner
    lam = rng.uniform(-mix, mix, (m, 1, 1))
    return lam * (X[partner] - X[owner])


# ---------------------------------------------------------------------------- ridge
def ridge_group_loo(Z: np.ndarray, Y: np.ndarray, groups: np.ndarray, alphas: Sequence[float]):
    """Ridge regression of targets Y (n, k) on centred features Z (n, p) with an
    unpenalised intercept, the penalty chosen by exact **leave-one-group-out** squared error.

    Dual form: with the Gram matrix ``K = Z Z^T = V diag(w) V^T`` and ``q = a / (w + a)``
    (q = 0 on the centring direction, w = 0: the intercept), the residuals of the fit are
    ``r = V diag(q) V^T Y`` and ``I - H = V diag(q) V^T``; leaving group g out gives the
    residuals ``e_g = [(I - H)_gg]^-1 r_g`` exactly (the block form of the usual
    leave-one-out identity; a group = a training clip and its augmented copies, so that
    the copies of a clip never validate each other). Returns ``(alpha, A, S_loo)``: the
    chosen penalty, dual coefficients A (n, k) -- weights ``Z^T A`` -- and the held-out
    scores ``S_loo = Y - E`` (n, k) at that penalty.
    """
    Z = np.asarray(Z, dtype=np.float64)
    K = Z @ Z.T
    w, V = np.linalg.eigh(K)
    w = np.maximum(w, 0.0)
    null = w < 1e-9 * max(float(w.max()), 1e-300)
    ym = Y.mean(0)
    VtY = V.T @ (Y - ym)
    _, inv_g = np.unique(groups, return_inverse=True)
    order = np.argsort(inv_g, kind="stable")
    sizes = np.bincount(inv_g)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    stacks = []                                            # row indices, one array per group size
    for b in np.unique(sizes):
        sel = starts[sizes == b]
        stacks.append(order[sel[:, None] + np.arange(b)[None, :]])
    best = None
    for a in alphas:
        q = a / (w + a)
        q[null] = 0.0
        R = V @ (q[:, None] * VtY)
        E = np.empty_like(R)
        for ix in stacks:                                   # (groups, size) blocks of one size
            Vg = V[ix]                                      # (G, b, n)
            M = np.einsum("gin,gjn->gij", Vg * q, Vg)
            E[ix] = np.linalg.solve(M, R[ix])
        err = float(np.mean(E ** 2))
        if best is None or err < best[0] - 1e-12:
            best = (err, float(a), E)
    _, a, E = best
    inv = 1.0 / (w + a)
    inv[null] = 0.0
    A = V @ (inv[:, None] * VtY)
    return a, A, Y - E


# -------------------------------------------------------------------------- classifier
class RocketClassifier:
    """MultiRocket-style features of the series and its first difference, standardised,
    ridge read-out with the penalty chosen by leave-one-clip-out on an augmented training
    set (module doc).

    Parameters
    ----------
    length : samples per clip after resampling (64: MSR-Action3D clips have 13-100
        frames at 15 fps, median 39; HDM05 clips 0.5-3 s).
    n_features : (kernel, bias) pairs per representation (5,000); each gives
        ``len(pooling)`` features.
    diff : differences transformed besides the series: 1 (default) the first difference
        (velocity, MultiRocket's second representation), 2 also the second (acceleration),
        0 none (``True`` / ``False`` of older model files read as 1 / 0).
    smooth_s : Gaussian smoothing sigma in seconds before resampling (0 = none).
    heading : heading normalisation of :func:`trajectories` (``'auto'``).
    pooling : MultiRocket's four poolings (default) or ``('ppv',)`` (MiniRocket).
    max_channels : largest channel subset per (dilation, kernel) (9, reference code).
    augment : randomly perturbed copies of every training clip (:func:`augment_series`;
        0 = none); ``time_warp`` and ``rot_deg`` their time-warp and rotation ranges,
        ``arm_deg`` the range of the arms' raising about the shoulders (0 = none; needs the
        keypoints), ``mix`` the range of the style mix (0 = none; :func:`augment_series`).
    n_seeds : transforms with seeds ``seed, seed + 2, ...`` whose features are concatenated
        (1 = one transform per representation).
    views : inputs, each with its own transforms, features concatenated: ``'joints'`` (the
        3J joint trajectories of :func:`trajectories`), ``'arms'`` (:func:`arm_view`:
        hand paths about the shoulders and the head, per arm length), ``'bones'``
        (:func:`bone_view`: unit directions of the 14 keypoint bones) and ``'reach'``
        (:func:`reach_view`: head, elbows and wrists about the hip centre), ``'dist'``
        (:func:`dist_view`: distances of 16 key joint pairs), ``'angles'``
        (:func:`angles_view`: elbow, shoulder, arm, hip and knee angles and the trunk bend)
        and ``'height'`` (:func:`height_view`: hand and elbow height, horizontal reach, per
        arm length); all but ``'joints'`` need the skeleton's keypoints (:func:`series_keypoints`) and are left
        out without them.
    hydra : add :class:`Hydra` counts of every view and its first difference (HYDRA +
        MultiRocket, Dempster et al. 2023 Sec. 5).
    alphas : ridge penalties tried by leave-one-clip-out (:func:`ridge_group_loo`).
    seed : random state of the transform and the augmentation.
    """

    def __init__(self, *, length: int = 64, n_features: int = 5_000, max_dilations: int = 32,
                 pooling: Sequence[str] = POOLINGS, max_channels: int = 9, diff: int = 1,
                 smooth_s: float = 0.0, heading: str = "auto", augment: int = 2,
                 time_warp: float = 0.1, rot_deg: float = 15.0, arm_deg: float = 0.0, n_seeds: int = 1,
                 views: Sequence[str] = ("joints", "arms"), hydra: bool = True,
                 alphas: Sequence[float] = tuple(np.logspace(-3, 5, 17)), seed: int = 0,
                 trim: float = 0.0, motion_time: float = 0.0, view_weights: Sequence[float] = (),
                 mix: float = 0.0):
        store_params(self, locals(), tuples=("pooling", "views", "view_weights"))
        self.alphas = tuple(float(a) for a in alphas)

    def params(self) -> dict:
        return {"length": int(self.length), "n_features": int(self.n_features),
                "max_dilations": int(self.max_dilations),
                "pooling": list(self.pooling), "max_channels": int(self.max_channels), "diff": int(self.diff),
                "smooth_s": float(self.smooth_s), "heading": str(self.heading),
                "augment": int(self.augment), "time_warp": float(self.time_warp), "rot_deg": float(self.rot_deg),
                "arm_deg": float(self.arm_deg),
                "n_seeds": int(self.n_seeds), "views": list(self.views), "hydra": bool(self.hydra),
                "alphas": list(self.alphas), "seed": int(self.seed),
                "trim": float(self.trim), "motion_time": float(self.motion_time),
                "view_weights": [float(w) for w in self.view_weights], "mix": float(self.mix)}

    # -- input ---------------------------------------------------------------------
    def series(self, motion: Motion) -> np.ndarray:
        """(3J, length) input of one motion (:func:`trajectories` with this model's settings)."""
        return trajectories(motion, self.length, smooth_s=self.smooth_s, heading=self.heading,
                            trim=self.trim, motion_time=self.motion_time)

    def check_joints(self, motion: Motion) -> None:
        """Raise MocapValueError when ``motion``'s joints are not the training joint set."""
        self._check()
        check_joint_set(self.joints_, motion)

    # -- fit -----------------------------------------------------------------------
    def fit(self, motions: Sequence[Motion], labels: Sequence) -> "RocketClassifier":
        if len(motions) != len(labels):
            raise MocapValueError(f"{len(motions)} motions but {len(labels)} labels")
        joints = joint_set_of(motions)
        X = np.stack([self.series(m) for m in motions])
        self.fit_series(X, labels, keypoints=series_keypoints(motions[0].skeleton) if len(motions) else None)
        self.joints_ = np.array(joints, dtype=str)
        return self

    def fit_series(self, X: np.ndarray, labels: Sequence, keypoints=None) -> "RocketClassifier":
        """Fit on series (n, C, length) already made by :meth:`series`; ``keypoints``
        (:func:`series_keypoints`) enable the ``'arms'`` view, which is left out without them."""
        y = np.asarray([str(v) for v in labels])
        X = np.asarray(X, dtype=np.float64)
        if len(X) != len(y):
            raise MocapValueError(f"{len(X)} series but {len(y)} labels")
        if len(np.unique(y)) < 2:
            raise MocapValueError("a classifier needs at least two different labels")
        if int(self.n_seeds) < 1 or int(self.augment) < 0:
            raise MocapValueError(f"n_seeds must be >= 1 and augment >= 0, got {self.n_seeds}, {self.augment}")
        bad = [v for v in self.views if v not in VIEWS]
        if bad or not self.views:
            raise MocapValueError(f"unknown views {bad or '(none)'}; choose from {', '.join(VIEWS)}")
        self.keypoints_ = np.zeros(0, np.int64) if keypoints is None else np.asarray(keypoints, np.int64)
        self.views_ = self._usable_views()
        self._fit_transforms(X)                          # biases from the original clips only
        rng = np.random.default_rng([int(self.seed), 7])
        Xa, owner = augment_series(X, int(self.augment), rng, time_warp=float(self.time_warp),
                                   rot_deg=float(self.rot_deg), arm_deg=float(self.arm_deg),
                                   keypoints=self.keypoints_, mix=float(self.mix), labels=y,
                                   mix_rng=np.random.default_rng([int(self.seed), 11]))
        F = self._features(np.concatenate([X, Xa]) if len(Xa) else X)
        groups = np.concatenate([np.arange(len(X)), owner])
        ya = y[groups]
        self.mean_ = F.mean(0)
        sd = F.std(0)
        self.scale_ = np.where(sd > 1e-12, sd, 1.0)
        if len(self.view_weights):
            # a view's standardised features times w: in the (near) minimum-norm ridge
            # read-out, its coefficients cost 1 / w^2 as much
            if len(self.view_weights) != len(self.views):
                raise MocapValueError(f"view_weights needs one weight per view ({len(self.views)}), "
                                      f"got {len(self.view_weights)}")
            w = dict(zip(self.views, (float(v) for v in self.view_weights)))
            self.scale_ /= np.concatenate([np.full(t.n_features_out, w[self.views_[vi]])
                                           for (vi, *_), t in zip(self._plan(), self._transforms())])
        F -= self.mean_
        F /= self.scale_
        self.classes_ = np.unique(y)
        Y = np.where(ya[:, None] == self.classes_[None, :], 1.0, -1.0)
        self.alpha_, A, S = ridge_group_loo(F, Y, groups, self.alphas)
        self.coef_ = (F.T @ A).T
        self.intercept_ = Y.mean(0)
        # held-out (leave-one-clip-out) scores of the original clips -> softmax temperature
        S, yi = S[:len(X)], np.searchsorted(self.classes_, y)
        best = (np.inf, 1.0)
        for tau in np.logspace(-1, 2.5, 36):
            Q = tau * S
            Q = Q - Q.max(1, keepdims=True)
            nll = float(np.mean(np.log(np.exp(Q).sum(1)) - Q[np.arange(len(y)), yi]))
            if nll < best[0]:
                best = (nll, float(tau))
        self.temperature_ = best[1]
        self.joints_ = np.array([], dtype=str)
        return self

    def _usable_views(self) -> list[str]:
        """The requested views this model's keypoints allow (the others are left out)."""
        return [v for v in self.views if len(self.keypoints_) >= VIEW_KEYPOINTS[v]]

    def _view(self, X: np.ndarray, view: str) -> np.ndarray:
        fn = {"joints": lambda X, _: X, "arms": arm_view, "bones": bone_view, "reach": reach_view,
              "dist": dist_view, "angles": angles_view, "height": height_view}[view]
        return fn(X, self.keypoints_)

    def _plan(self) -> list[tuple[int, int, bool, str, int]]:
        """(view index, seed index, on the difference, 'r' / 'h', seed) of every transform,
        in feature order; view 0 keeps the seeds of version-2 files."""
        out = []
        for vi in range(len(self.views_)):
            for k in range(int(self.n_seeds)):
                for d in range(int(self.diff) + 1):
                    # seeds of the series and first difference as in files written before
                    # the second difference existed; the second's offset keeps clear of them
                    sd = self.seed + 100 * vi + 2 * k + (d if d < 2 else 30)
                    out.append((vi, k, d, "r", sd))
                    if self.hydra:
                        out.append((vi, k, d, "h", sd + 50))
        return out

    def _fit_transforms(self, X: np.ndarray) -> None:
        kw = dict(n_features=self.n_features, max_dilations=self.max_dilations, pooling=self.pooling,
                  max_channels=self.max_channels)
        self.rockets_, self.hydras_ = [], []
        for vi, _, d, kind, seed in self._plan():
            V = self._view(X, self.views_[vi])
            for _ in range(d):
                V = _difference(V)
            if kind == "r":
                self.rockets_.append(MiniRocket(seed=seed, **kw).fit(V))
            else:
                self.hydras_.append(Hydra(seed=seed).fit(V))

    def _transforms(self) -> list:
        """The fitted transforms in feature order (:meth:`_plan`)."""
        it = {"r": iter(self.rockets_), "h": iter(self.hydras_)}
        return [next(it[kind]) for *_, kind, _ in self._plan()]

    def _features(self, X: np.ndarray) -> np.ndarray:
        views = [self._view(X, v) for v in self.views_]
        reps = [[V] for V in views]                       # per view: series, 1st, 2nd difference
        for r in reps:
            for _ in range(int(self.diff)):
                r.append(_difference(r[-1]))
        F, ir, ih = [], 0, 0
        for vi, _, d, kind, _ in self._plan():
            V = reps[vi][d]
            if kind == "r":
                F.append(self.rockets_[ir].transform(V))
                ir += 1
            else:
                F.append(self.hydras_[ih].transform(V))
                ih += 1
        return np.concatenate(F, axis=1)

    def _check(self) -> None:
        if not hasattr(self, "coef_"):
            raise NotFittedError("the classifier is not fitted (train it or load a model)")

    @staticmethod
    def _two_columns(S: np.ndarray) -> np.ndarray:
        return np.hstack([-S, S]) if S.shape[1] == 1 else S

    # -- predict -------------------------------------------------------------------
    def decision_series(self, X: np.ndarray) -> np.ndarray:
        """Ridge scores (n, n_classes) of series (n, C, length)."""
        self._check()
        X = np.asarray(X, dtype=np.float64)
        if X.ndim == 2:
            X = X[None]
        S = ((self._features(X) - self.mean_) / self.scale_) @ self.coef_.T + self.intercept_
        return self._two_columns(S)

    def predict_proba_series(self, X: np.ndarray) -> np.ndarray:
        Q = self.temperature_ * self.decision_series(X)
        Q = Q - Q.max(1, keepdims=True)
        E = np.exp(Q)
        return E / E.sum(1, keepdims=True)

    def predict_series(self, X: np.ndarray) -> np.ndarray:
        return self.classes_[np.argmax(self.decision_series(X), axis=1)]

    def predict(self, motion: Motion) -> tuple[str, float]:
        """``(label, confidence)`` of one motion of the training joint set."""
        self.check_joints(motion)
        pr = self.predict_proba_series(self.series(motion)[None])[0]
        i = int(np.argmax(pr))
        return str(self.classes_[i]), float(pr[i])

    def predict_many(self, motions: Sequence[Motion]) -> np.ndarray:
        for m in motions:
            self.check_joints(m)
        return self.predict_series(np.stack([self.series(m) for m in motions]))

    # -- save / load ---------------------------------------------------------------
    def save(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        self._check()
        header = {"format": MODEL_FORMAT, "version": MODEL_FORMAT_VERSION, "params": self.params(),
                  "alpha": self.alpha_, "temperature": self.temperature_}
        arrays: dict = {"keypoints": self.keypoints_}
        for i, r in enumerate(self.rockets_):
            arrays.update(r.state(f"r{i}_"))
        for i, h in enumerate(self.hydras_):
            arrays.update(h.state(f"h{i}_"))
        return write_model(self, path, header, arrays, overwrite=overwrite)

    @classmethod
    def from_arrays(cls, header: dict, st: dict, path) -> "RocketClassifier":
        version = header.get("version")
        params = dict(header.get("params", {}))
        if version in (1, 2):            # v1: MiniRocket PPV, no augmentation; v1-2: joints view only
            params = {**(V1_PARAMS if version == 1 else {}), **V2_PARAMS, **params}
        m = read_head(cls(**params), header, st, path, version if version in (1, 2, MODEL_FORMAT_VERSION)
                      else MODEL_FORMAT_VERSION)
        rp = dict(n_features=m.n_features, max_dilations=m.max_dilations, pooling=m.pooling,
                  max_channels=m.max_channels)
        m.keypoints_ = st["keypoints"].astype(np.int64) if "keypoints" in st else np.zeros(0, np.int64)
        bad = [v for v in m.views if v not in VIEWS]
        if bad:
            raise MocapFormatError(path, f"unknown views {bad} in the model file")
        m.views_ = m._usable_views()
        m.rockets_, m.hydras_ = [], []
        for _, _, _, kind, seed in m._plan():
            if kind == "r":
                m.rockets_.append(MiniRocket.from_state(st, f"r{len(m.rockets_)}_", dict(rp, seed=seed)))
            else:
                m.hydras_.append(Hydra.from_state(st, f"h{len(m.hydras_)}_", seed))
        m.alpha_ = float(header["alpha"])
        m.temperature_ = float(header["temperature"])
        return m

    @classmethod
    def load(cls, path: str | os.PathLike) -> "RocketClassifier":
        m = load_model(path)
        if not isinstance(m, cls):
            raise MocapFormatError(path, f"not a MiniRocket classifier (it holds a {type(m).__name__})")
        return m


register_format(MODEL_FORMAT, RocketClassifier)
