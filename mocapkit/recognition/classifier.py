"""Skeleton-sequence action classifier: the modern reference next to NMC.

The thesis' CNNs (gait silhouettes, NTU energy images) need image input we do not have
(``../shared/specs/METHODS.md`` Sec. 4); this is the skeleton-sequence classifier that
takes their place.

Features (:func:`sequence_features`, vectorised over frames), on the canonical,
size-normalised keypoints of :func:`mocapkit.retrieval.features.prepare` (Gaussian
smoothing sigma 0.15 s: Kinect joints jitter; measured +2 points on MSR-Action3D):

* HOD, length-weighted, pyramid 1/2/4, L2-normalised (Gowayyed et al. 2013);
* GPF frames (segment directions, joint velocities, heights) summarised per temporal
  pyramid cell (levels 1/2/4) by mean, std, min and max;
* the root-relative keypoint positions summarised the same way.

Model (decision): standardisation + multinomial **logistic regression** (scikit-learn,
L2, C = 1). On ~300 training clips with ~5,000 features it beat an RBF SVM, a ridge
classifier and PCA + LR on MSR-Action3D (``docs/results/retrieval.md``), and it gives
calibrated-ish probabilities: ``predict`` returns the most probable label and its
probability as the confidence. A model saves to ``.npz`` (no pickle): scaler, weights,
classes, parameters and (from this version on) the joint names of the training skeleton.

Model files and the CLI (:func:`train_classifier`, :func:`~mocapkit.recognition.model_file.load_model`,
:func:`classify`):
``mocapkit classify train`` trains the **MiniRocket/MultiRocket** classifier by default
(:class:`mocapkit.recognition.rocket.RocketClassifier`: MultiRocket poolings on the joint
and arm views, augmented training set, leave-one-clip-out ridge; ``method='skeleton'`` this
classifier, ``method='nmc'`` the thesis' NMC, :class:`mocapkit.recognition.nmc.NMCClassifier`,
inductive). :func:`~mocapkit.recognition.model_file.load_model` (the CLI's loader; it
dispatches on the header format each classifier module registers, and
:meth:`SkeletonClassifier.load` calls it) returns whichever model a file holds. Every model remembers the joint
names of its training skeleton and refuses a motion of another joint set with a
:class:`~mocapkit.errors.MocapValueError` naming both.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import MocapValueError, NotFittedError
from ..motion import Motion
from ..retrieval.features import Prepared, gpf, hod, prepare, pyramid_segments
from .model_file import (check_joint_set, joint_set_of, load_model, read_head, register_format,
                         write_model)

__all__ = ["sequence_features", "SkeletonClassifier", "train_classifier", "classify",
           "METHODS", "DEFAULT_METHOD", "MODEL_FORMAT_VERSION", "MODEL_FORMAT"]

METHODS = ("minirocket", "skeleton", "nmc")
DEFAULT_METHOD = "minirocket"

MODEL_FORMAT_VERSION = 1
MODEL_FORMAT = "mocapkit-classifier"
SMOOTH_S = 0.15


def _pyramid_stats(G: np.ndarray, levels: Sequence[int] = (1, 2, 4)) -> np.ndarray:
    """mean, std, min, max of the rows of G per temporal-pyramid cell (no frame loop)."""
    T, C = G.shape
    out = []
    for L, seg in zip(levels, pyramid_segments(T, levels)):
        L = int(L)
        cnt = np.bincount(seg, minlength=L).astype(float)
        s1 = np.zeros((L, C))
        s2 = np.zeros((L, C))
        np.add.at(s1, seg, G)
        np.add.at(s2, seg, G * G)
        mx = np.full((L, C), -np.inf)
        mn = np.full((L, C), np.inf)
        np.maximum.at(mx, seg, G)
        np.minimum.at(mn, seg, G)
        empty = cnt == 0                                  # clips shorter than L frames
        if empty.any():
            s1[empty], s2[empty] = G.sum(0), (G * G).sum(0)
            cnt[empty] = T
            mx[empty], mn[empty] = G.max(0), G.min(0)
        mean = s1 / cnt[:, None]
        std = np.sqrt(np.maximum(s2 / cnt[:, None] - mean ** 2, 0.0))
        out.append(np.stack([mean, std, mn, mx], axis=1).ravel())
    return np.concatenate(out)


def sequence_features(seq: Motion | Prepared) -> np.ndarray:
    """Fixed-length descriptor of one sequence (module doc)."""
    p = seq if isinstance(seq, Prepared) else prepare(seq, smooth_s=SMOOTH_S)
    h = hod(p, normalize="none")
    h = h / max(np.linalg.norm(h), 1e-12)
    Q = p.positions.copy()
    Q[:, 0] = 0.0
    return np.concatenate([h, _pyramid_stats(gpf(p)), _pyramid_stats(Q.reshape(p.n_frames, -1))])


class SkeletonClassifier:
    """HOD + pose statistics + logistic regression (module doc).

    Parameters
    ----------
    C : inverse L2 regularisation of the logistic regression.
    max_iter : solver iterations.
    """

    def __init__(self, *, C: float = 1.0, max_iter: int = 3000):
        self.C = C
        self.max_iter = max_iter

    def fit(self, seqs: Sequence[Motion | Prepared], labels: Sequence) -> "SkeletonClassifier":
        labels = np.asarray([str(x) for x in labels])
        if len(seqs) != len(labels):
            raise MocapValueError(f"{len(seqs)} sequences but {len(labels)} labels")
        if len(np.unique(labels)) < 2:
            raise MocapValueError("a classifier needs at least two different labels")
        X = np.stack([sequence_features(s) for s in seqs])
        self.fit_features(X, labels)
        if all(isinstance(s, Motion) for s in seqs):
            self.joints_ = np.array(joint_set_of(seqs), dtype=str)
        return self

    def fit_features(self, X: np.ndarray, labels: Sequence) -> "SkeletonClassifier":
        from sklearn.linear_model import LogisticRegression

        X = np.asarray(X, float)
        labels = np.asarray([str(x) for x in labels])
        self.mean_ = X.mean(0)
        sd = X.std(0)
        self.scale_ = np.where(sd > 1e-12, sd, 1.0)
        lr = LogisticRegression(C=self.C, max_iter=self.max_iter)
        lr.fit((X - self.mean_) / self.scale_, labels)
        self.coef_ = lr.coef_
        self.intercept_ = lr.intercept_
        self.classes_ = lr.classes_.astype(str)
        self.joints_ = np.array([], dtype=str)
        return self

    def _check(self) -> None:
        if not hasattr(self, "coef_"):
            raise NotFittedError("the classifier is not fitted (train it or load a model)")

    def predict_proba_features(self, X: np.ndarray) -> np.ndarray:
        self._check()
        X = np.atleast_2d(np.asarray(X, float))
        if X.shape[1] != self.mean_.shape[0]:
            raise MocapValueError(
                f"features have {X.shape[1]} values, the model expects {self.mean_.shape[0]} "
                "(a skeleton whose keypoints could not be named gives another layout)")
        S = ((X - self.mean_) / self.scale_) @ self.coef_.T + self.intercept_
        if S.shape[1] == 1:                                  # binary: sklearn's one column
            S = np.hstack([-S, S])
        S -= S.max(axis=1, keepdims=True)
        E = np.exp(S)
        return E / E.sum(axis=1, keepdims=True)

    def predict_features(self, X: np.ndarray) -> np.ndarray:
        self._check()
        return self.classes_[np.argmax(self.predict_proba_features(X), axis=1)]

    def predict(self, motion: Motion | Prepared) -> tuple[str, float]:
        """``(label, confidence)`` of one motion; confidence = the label's probability."""
        if isinstance(motion, Motion):
            check_joint_set(getattr(self, "joints_", ()), motion)
        pr = self.predict_proba_features(sequence_features(motion))[0]
        i = int(np.argmax(pr))
        return str(self.classes_[i]), float(pr[i])

    def save(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        self._check()
        header = {"format": MODEL_FORMAT, "version": MODEL_FORMAT_VERSION,
                  "params": {"C": self.C, "max_iter": self.max_iter}, "smooth_s": SMOOTH_S}
        return write_model(self, path, header, overwrite=overwrite)

    @classmethod
    def load(cls, path: str | os.PathLike):
        """Load a classifier model file. Generic: returns the model the file holds
        (:func:`~mocapkit.recognition.model_file.load_model`) -- this class, a MiniRocket or an NMC model."""
        return load_model(path)

    @classmethod
    def from_arrays(cls, header: dict, st: dict, path) -> "SkeletonClassifier":
        return read_head(cls(**header["params"]), header, st, path, MODEL_FORMAT_VERSION)


def train_classifier(paths_or_dir, output: str | os.PathLike, labels: Sequence[str] | None = None,
                     progress: bool = True, *, C: float = 1.0, overwrite: bool = False,
                     method: str = DEFAULT_METHOD, seed: int = 0, **params) -> dict:
    """Train a classifier on motion files and save it (``.npz``).

    Parameters
    ----------
    paths_or_dir : folder (recursive) or list of files/folders.
    output : model file to write.
    labels : one label per file found (default: :func:`mocapkit.retrieval.index.label_of`:
        MSR-Action3D action id, HDM05 class, else the parent folder name).
    method : ``'minirocket'`` (default, :class:`~mocapkit.recognition.rocket.RocketClassifier`),
        ``'skeleton'`` (:class:`SkeletonClassifier`) or ``'nmc'`` (the thesis' NMC,
        :class:`~mocapkit.recognition.nmc.NMCClassifier`, inductive).
    C : inverse regularisation of the logistic regression of ``'skeleton'`` and ``'nmc'``
        (MiniRocket chooses its ridge penalty itself by leave-one-out; C is not used).
    seed : random state (MiniRocket transform, NMC clustering).
    params : further constructor parameters of the chosen classifier.

    Returns ``{'output', 'method', 'n_train', 'classes', 'skipped', 'train_accuracy'}``;
    unreadable files (and clips with no observed joint) are skipped and listed. Training
    files of different joint sets raise MocapValueError.
    """
    from ..bench.core import progress as bar
    from ..errors import MocapError
    from ..io import read
    from ..io._atomic import check_output_path
    from ..retrieval.index import find_motion_files, label_of

    if method not in METHODS:
        raise MocapValueError(f"unknown classifier {method!r}; choose from {', '.join(METHODS)}")
    check_output_path(output, overwrite=overwrite)
    files = find_motion_files(paths_or_dir)
    if labels is not None and len(labels) != len(files):
        raise MocapValueError(f"{len(labels)} labels for {len(files)} files")
    if method == "minirocket":
        from .rocket import RocketClassifier

        model = RocketClassifier(seed=seed, **params)
        describe = model.series
    elif method == "nmc":
        from .nmc import NMCClassifier

        model = NMCClassifier(C=C, seed=seed, transductive=False, **params)
        describe = prepare
    else:
        model = SkeletonClassifier(C=C, **params)

        def describe(m):
            return sequence_features(prepare(m, smooth_s=SMOOTH_S))
    X, y, skipped, motions = [], [], [], []
    for i, f in enumerate(bar(files, total=len(files), desc="features", enable=progress)):
        try:
            m = read(f)
            X.append(describe(m))
            motions.append(m)
            y.append(str(labels[i]) if labels is not None else label_of(f))
        except MocapError as e:
            skipped.append((str(f), str(e)))
    if len(X) < 2:
        raise MocapValueError(f"fewer than two usable training files in {paths_or_dir}")
    joints = joint_set_of(motions)
    del motions
    if method == "minirocket":
        model.fit_series(np.stack(X), y)
        pred = model.predict_series(np.stack(X))
    elif method == "nmc":
        model.fit(X, y)
        pred = model.predict(X)
    else:
        X = np.stack(X)
        model.fit_features(X, y)
        pred = model.predict_features(X)
    model.joints_ = np.array(joints, dtype=str)
    model.save(output, overwrite=overwrite)
    acc = float((np.asarray(pred) == np.asarray(y)).mean())
    return {"output": str(output), "method": method, "n_train": len(y), "classes": [str(c) for c in model.classes_],
            "skipped": skipped, "train_accuracy": acc}


def classify(model_path: str | os.PathLike, motion_path: str | os.PathLike) -> tuple[str, float]:
    """``(label, confidence)`` of the motion file with a saved model (CLI ``mocapkit classify``)."""
    from ..io import read

    return load_model(model_path).predict(read(motion_path))


register_format(MODEL_FORMAT, SkeletonClassifier)
