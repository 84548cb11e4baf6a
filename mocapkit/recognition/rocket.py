"""MiniRocket features + ridge classifier: the default action classifier.

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
representations, PPV only). Vectorised: one (samples x time, channels) @ (channels, 84)
product per tap and dilation -- the convolution of all 84 kernels is
``sum_t X_t @ (M o w_t)`` with ``M`` the channel-subset masks and ``w_t`` the kernels'
weights at tap ``t``.

Classifier (:class:`RocketClassifier`)
--------------------------------------
Features standardised, scikit-learn ``RidgeClassifierCV`` with ``alphas =
logspace(-3, 3, 10)`` chosen by efficient leave-one-out (the paper's classifier). The
confidence returned by ``predict`` is a softmax of the ridge scores with one temperature
fitted on the leave-one-out scores of the training set (minimum negative log-likelihood
over a grid), so it is a calibrated-ish probability, not a raw ridge score. All random
choices come from ``numpy.random.default_rng(seed)``: the same data and seed give the
same model and predictions.

A model remembers the joint names of its training skeleton; classifying a motion of
another joint set raises :class:`~mocapkit.errors.MocapValueError` naming both. Models
save to ``.npz`` (no pickle).
"""
from __future__ import annotations

import itertools
import json
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import MocapFormatError, MocapValueError, NotFittedError
from ..motion import Motion

__all__ = ["trajectories", "MiniRocket", "RocketClassifier", "fit_dilations", "golden_quantiles",
           "KERNEL_INDICES", "MODEL_FORMAT"]

KERNEL_LENGTH = 9
KERNEL_INDICES = np.array(list(itertools.combinations(range(KERNEL_LENGTH), 3)), dtype=np.int64)  # (84, 3)
N_KERNELS = len(KERNEL_INDICES)
MODEL_FORMAT = "mocapkit-minirocket"
MODEL_FORMAT_VERSION = 1
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
                 heading: str = "auto") -> np.ndarray:
    """Body-centred, size-normalised joint trajectories (3J, length) of ``motion`` (module doc).

    ``heading``: ``'start'`` / ``'mean'`` / ``'none'`` as in
    :func:`~mocapkit.retrieval.features.prepare`, or ``'auto'`` (:func:`resolve_heading`).
    Units: body sizes (about 0.9 x standing height). Raises MocapValueError for a motion
    with no observed joint.
    """
    from ..retrieval.features import prepare

    if not isinstance(motion, Motion):
        raise MocapValueError(f"expected a Motion, got {type(motion).__name__}")
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
    t = np.linspace(0.0, T - 1.0, length)
    lo = np.minimum(np.floor(t).astype(int), T - 2)
    w = (t - lo)[:, None]
    return (X[lo] * (1.0 - w) + X[lo + 1] * w).T


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
    """Zero-padded ("same") multichannel convolution of all 84 kernels: (n, L, 84)."""
    n, C, L = X.shape
    pad = (KERNEL_LENGTH - 1) * dilation // 2
    Xp = np.zeros((n, L + 2 * pad, C))
    Xp[:, pad:pad + L] = X.transpose(0, 2, 1)
    out = np.zeros((n, L, N_KERNELS))
    for t in range(KERNEL_LENGTH):
        out += Xp[:, t * dilation:t * dilation + L] @ W[t]
    return out


POOLINGS = ("ppv", "mpv", "mipv", "lspv")


def _pool(Cv: np.ndarray, b: np.ndarray, pooling: Sequence[str]) -> np.ndarray:
    """Pooled features of ``Z = Cv - b``: Cv (n, L', K), b (K, f) -> (n, K, f, len(pooling)).

    ppv: proportion of positive values (MiniRocket); mpv: mean of the positive values (0
    when none); mipv: mean index of the positive values / (L' - 1) (-1 when none); lspv:
    longest run of consecutive positive values / L' (MultiRocket, Tan et al. 2022 Sec. 3.2;
    the index and run features are divided by the length here so they do not depend on it).
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
        elif name == "lspv":                                    # run length = t - last non-positive t
            t = np.arange(Lp)[None, :, None, None]
            last = np.maximum.accumulate(np.where(pos, -1, t), axis=1)
            out.append((t - last).max(axis=1) / Lp)
        else:
            raise MocapValueError(f"unknown pooling {name!r}; choose from {', '.join(POOLINGS)}")
    return np.stack(out, axis=-1)


class MiniRocket:
    """The MiniRocket transform of multichannel series (n, C, L) (module doc).

    Parameters
    ----------
    n_features : about this many features (multiples of 84).
    max_dilations : maximum dilations per kernel (32, paper).
    pooling : features per (kernel, bias): ``('ppv',)`` = MiniRocket; all four of
        :data:`POOLINGS` = MultiRocket.
    max_channels : largest channel subset per (dilation, kernel) (9, reference code).
    seed : random state of the channel subsets and the bias examples.
    """

    def __init__(self, *, n_features: int = 10_000, max_dilations: int = 32,
                 pooling: Sequence[str] = ("ppv",), max_channels: int = 9, seed: int = 0):
        self.n_features = n_features
        self.max_channels = max_channels
        self.max_dilations = max_dilations
        self.pooling = tuple(pooling)
        self.seed = seed

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


# -------------------------------------------------------------------------- classifier
class RocketClassifier:
    """MiniRocket (+ difference) features, standardised, RidgeClassifierCV (module doc).

    Parameters
    ----------
    length : samples per clip after resampling (64: MSR-Action3D clips have 13-100
        frames at 15 fps, median 39; HDM05 clips 0.5-3 s).
    n_features : features per representation (10,000, paper).
    diff : add the transform of the first difference (velocity).
    smooth_s : Gaussian smoothing sigma in seconds before resampling (0 = none).
    heading : heading normalisation of :func:`trajectories` (``'auto'``).
    pooling, max_channels : of :class:`MiniRocket` (PPV only and up to 9 channels per
        kernel = MiniRocket; MultiRocket's four poolings did not pay on MSR-Action3D).
    alphas : ridge penalties tried by leave-one-out.
    seed : random state of the transform.
    """

    def __init__(self, *, length: int = 64, n_features: int = 10_000, max_dilations: int = 32,
                 pooling: Sequence[str] = ("ppv",), max_channels: int = 9, diff: bool = True,
                 smooth_s: float = 0.0, heading: str = "auto",
                 alphas: Sequence[float] = tuple(np.logspace(-3, 3, 10)), seed: int = 0):
        self.length = length
        self.n_features = n_features
        self.max_dilations = max_dilations
        self.pooling = tuple(pooling)
        self.max_channels = max_channels
        self.diff = diff
        self.smooth_s = smooth_s
        self.heading = heading
        self.alphas = tuple(float(a) for a in alphas)
        self.seed = seed

    def params(self) -> dict:
        return {"length": int(self.length), "n_features": int(self.n_features),
                "max_dilations": int(self.max_dilations),
                "pooling": list(self.pooling), "max_channels": int(self.max_channels), "diff": bool(self.diff),
                "smooth_s": float(self.smooth_s), "heading": str(self.heading),
                "alphas": list(self.alphas), "seed": int(self.seed)}

    # -- input ---------------------------------------------------------------------
    def series(self, motion: Motion) -> np.ndarray:
        """(3J, length) input of one motion (:func:`trajectories` with this model's settings)."""
        return trajectories(motion, self.length, smooth_s=self.smooth_s, heading=self.heading)

    def check_joints(self, motion: Motion) -> None:
        """Raise MocapValueError when ``motion``'s joints are not the training joint set."""
        from .classifier import check_joint_set

        self._check()
        check_joint_set(self.joints_, motion)

    # -- fit -----------------------------------------------------------------------
    def fit(self, motions: Sequence[Motion], labels: Sequence) -> "RocketClassifier":
        if len(motions) != len(labels):
            raise MocapValueError(f"{len(motions)} motions but {len(labels)} labels")
        from .classifier import joint_set_of

        joints = joint_set_of(motions)
        X = np.stack([self.series(m) for m in motions])
        self.fit_series(X, labels)
        self.joints_ = np.array(joints, dtype=str)
        return self

    def fit_series(self, X: np.ndarray, labels: Sequence) -> "RocketClassifier":
        """Fit on series (n, C, length) already made by :meth:`series`."""
        from sklearn.linear_model import RidgeClassifierCV

        y = np.asarray([str(v) for v in labels])
        X = np.asarray(X, dtype=np.float64)
        if len(X) != len(y):
            raise MocapValueError(f"{len(X)} series but {len(y)} labels")
        if len(np.unique(y)) < 2:
            raise MocapValueError("a classifier needs at least two different labels")
        kw = dict(n_features=self.n_features, max_dilations=self.max_dilations, pooling=self.pooling,
                  max_channels=self.max_channels)
        self.rockets_ = [MiniRocket(seed=self.seed, **kw).fit(X)]
        if self.diff:
            self.rockets_.append(MiniRocket(seed=self.seed + 1, **kw).fit(_difference(X)))
        F = self._features(X)
        self.mean_ = F.mean(0)
        sd = F.std(0)
        self.scale_ = np.where(sd > 1e-12, sd, 1.0)
        Z = (F - self.mean_) / self.scale_
        rc = RidgeClassifierCV(alphas=np.asarray(self.alphas), store_cv_results=True).fit(Z, y)
        self.coef_ = np.atleast_2d(rc.coef_)
        self.intercept_ = np.atleast_1d(rc.intercept_)
        self.classes_ = rc.classes_.astype(str)
        self.alpha_ = float(rc.alpha_)
        # LOO scores of the chosen alpha -> softmax temperature (min NLL over a grid)
        cv = np.asarray(rc.cv_results_)
        ai = int(np.argmin(np.abs(np.asarray(self.alphas) - rc.alpha_)))
        S = cv[:, :, ai] if cv.ndim == 3 else cv[:, ai][:, None]
        S = self._two_columns(S)
        yi = np.searchsorted(self.classes_, y)
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

    def _features(self, X: np.ndarray) -> np.ndarray:
        F = [self.rockets_[0].transform(X)]
        if len(self.rockets_) > 1:
            F.append(self.rockets_[1].transform(_difference(X)))
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
        from .model_file import write_model

        self._check()
        header = {"format": MODEL_FORMAT, "version": MODEL_FORMAT_VERSION, "params": self.params(),
                  "alpha": self.alpha_, "temperature": self.temperature_}
        arrays: dict = {}
        for i, r in enumerate(self.rockets_):
            arrays.update(r.state(f"r{i}_"))
        return write_model(self, path, header, arrays, overwrite=overwrite)

    @classmethod
    def from_arrays(cls, header: dict, st: dict, path) -> "RocketClassifier":
        from .model_file import read_head

        m = read_head(cls(**header["params"]), header, st, path, MODEL_FORMAT_VERSION)
        rp = dict(n_features=m.n_features, max_dilations=m.max_dilations, pooling=m.pooling,
                  max_channels=m.max_channels)
        m.rockets_ = [MiniRocket.from_state(st, "r0_", dict(rp, seed=m.seed))]
        if m.diff:
            m.rockets_.append(MiniRocket.from_state(st, "r1_", dict(rp, seed=m.seed + 1)))
        m.alpha_ = float(header["alpha"])
        m.temperature_ = float(header["temperature"])
        return m

    @classmethod
    def load(cls, path: str | os.PathLike) -> "RocketClassifier":
        from .classifier import load_model

        m = load_model(path)
        if not isinstance(m, cls):
            raise MocapFormatError(path, f"not a MiniRocket classifier (it holds a {type(m).__name__})")
        return m
