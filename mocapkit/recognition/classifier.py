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
classes and parameters.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import MocapFormatError, MocapValueError, NotFittedError
from ..motion import Motion
from ..retrieval.features import Prepared, gpf, hod, prepare, pyramid_segments

__all__ = ["sequence_features", "SkeletonClassifier", "train_classifier", "classify",
           "MODEL_FORMAT_VERSION"]

MODEL_FORMAT_VERSION = 1
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
        return self.fit_features(X, labels)

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
        pr = self.predict_proba_features(sequence_features(motion))[0]
        i = int(np.argmax(pr))
        return str(self.classes_[i]), float(pr[i])

    def save(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        from ..io._atomic import atomic_write, check_output_path

        self._check()
        p = check_output_path(path, overwrite=overwrite)
        header = {"format": "mocapkit-classifier", "version": MODEL_FORMAT_VERSION,
                  "params": {"C": self.C, "max_iter": self.max_iter}, "smooth_s": SMOOTH_S}
        arrays = dict(header=np.array(json.dumps(header)), mean=self.mean_, scale=self.scale_,
                      coef=self.coef_, intercept=self.intercept_,
                      classes=np.array(self.classes_, dtype=str))
        atomic_write(p, lambda f: np.savez(f, **arrays), binary=True)
        return p

    @classmethod
    def load(cls, path: str | os.PathLike) -> "SkeletonClassifier":
        p = Path(path)
        if not p.is_file():
            raise MocapFormatError(p, "model file not found")
        try:
            with np.load(p, allow_pickle=False) as z:
                st = {k: z[k] for k in z.files}
            header = json.loads(str(st["header"]))
        except Exception as e:
            raise MocapFormatError(p, f"not a mocapkit classifier model ({type(e).__name__})") from None
        if header.get("format") != "mocapkit-classifier":
            raise MocapFormatError(p, f"not a mocapkit classifier model (it holds a {header.get('format')!r}); "
                                      "train one with 'mocapkit classify train DATA -o MODEL'")
        if header.get("version") != MODEL_FORMAT_VERSION:
            raise MocapFormatError(p, f"classifier format {header.get('format')} v{header.get('version')} "
                                      f"is not supported (expected v{MODEL_FORMAT_VERSION})")
        m = cls(**header["params"])
        m.mean_, m.scale_ = st["mean"], st["scale"]
        m.coef_, m.intercept_ = st["coef"], st["intercept"]
        m.classes_ = st["classes"].astype(str)
        return m


def train_classifier(paths_or_dir, output: str | os.PathLike, labels: Sequence[str] | None = None,
                     progress: bool = True, *, C: float = 1.0, overwrite: bool = False) -> dict:
    """Train a :class:`SkeletonClassifier` on motion files and save it (``.npz``).

    Parameters
    ----------
    paths_or_dir : folder (recursive) or list of files/folders.
    output : model file to write.
    labels : one label per file found (default: :func:`mocapkit.retrieval.index.label_of`:
        MSR-Action3D action id, HDM05 class, else the parent folder name).

    Returns ``{'output', 'n_train', 'classes', 'skipped', 'train_accuracy'}``; unreadable
    files are skipped and listed.
    """
    from ..bench.core import progress as bar
    from ..errors import MocapError
    from ..io import read
    from ..io._atomic import check_output_path
    from ..retrieval.index import find_motion_files, label_of

    check_output_path(output, overwrite=overwrite)
    files = find_motion_files(paths_or_dir)
    if labels is not None and len(labels) != len(files):
        raise MocapValueError(f"{len(labels)} labels for {len(files)} files")
    X, y, skipped = [], [], []
    for i, f in enumerate(bar(files, total=len(files), desc="features", enable=progress)):
        try:
            X.append(sequence_features(read(f)))
            y.append(str(labels[i]) if labels is not None else label_of(f))
        except MocapError as e:
            skipped.append((str(f), str(e)))
    if len(X) < 2:
        raise MocapValueError(f"fewer than two usable training files in {paths_or_dir}")
    lens = {len(x) for x in X}
    if len(lens) != 1:
        raise MocapValueError("training files give different feature layouts (mixed skeletons whose "
                              "keypoints could not all be named)")
    X = np.stack(X)
    model = SkeletonClassifier(C=C).fit_features(X, y)
    model.save(output, overwrite=overwrite)
    acc = float((model.predict_features(X) == np.asarray(y)).mean())
    return {"output": str(output), "n_train": len(y), "classes": list(model.classes_),
            "skipped": skipped, "train_accuracy": acc}


def classify(model_path: str | os.PathLike, motion_path: str | os.PathLike) -> tuple[str, float]:
    """``(label, confidence)`` of the motion file with a saved model (CLI ``mocapkit classify``)."""
    from ..io import read

    return SkeletonClassifier.load(model_path).predict(read(motion_path))
