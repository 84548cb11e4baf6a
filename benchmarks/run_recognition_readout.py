"""The default classifier's read-out, varied on fixed features (issue #17, inner validation).

Usage: ``python benchmarks/run_recognition_readout.py [--data DIR] [--seed 0]``.
Writes docs/results/recognition_readout.json; recognition.md (run_recognition.py) quotes it.

The default classifier's ridge picks the smallest penalty of its grid in every recorded
fit (recognition.md): with ~10^5 standardised features and ~850 training rows it is in
effect the minimum-norm interpolant. Whether another read-out of the *same* features
generalises better across subjects is asked here on the inner folds of
``run_recognition.py --select`` (training clips only: leave one training subject out, and
two half splits inside the training halves): the default is fitted once per fold, its
standardised features' Gram matrices (training x training, test x training) kept, and
read-outs that need only those are scored: the ridge at fixed penalties 1e-3..1e6
(dual form, +-1 targets, unpenalised intercept, as the default), the cosine-normalised
kernel, Gaussian kernels exp(-d^2 / (g median d^2)) at g = 0.25..4, polynomial kernels
(1 + k / median |f|^2)^p, p = 2, 3, and the nearest neighbour; and (eleventh session) the
ridge on the features centred per subject -- each training row less the mean of its
subject's rows (augmented copies included), each test clip less the mean of its own
subject's test clips -- the speaker normalisation of speech recognition, aimed at subject
2's low throws (recognition.md). It is transductive: a clip is classified with the other
clips of its performer. Thirteenth session: the ridge after nuisance attribute projection
(:func:`nap`: the leading within-class subject directions of the training rows projected
out; not transductive). One BLAS thread; ~8 min (``--cache DIR`` keeps each fold's Gram
matrices, and a rerun with it takes seconds).
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from mocapkit import bench  # noqa: E402
from mocapkit.datasets import shared_data_dir  # noqa: E402

OUT = ROOT / "docs" / "results" / "recognition_readout.json"
RIDGE_ALPHAS = (1e-3, 1e0, 1e1, 1e2, 1e3, 1e4, 3e4, 1e5, 1e6)
#: the read-out on features centred per subject (module docstring)
SUBJECT_CENTRED = "ridge, centred per subject"
#: leading within-class subject directions projected out (:func:`nap`)
NAP_K = (2, 4, 8, 16, 32, 64)


def gram(m, X: np.ndarray, a: np.ndarray, b: np.ndarray) -> dict[str, np.ndarray]:
    """The fitted default ``m``'s standardised features of its training rows (the clips of
    ``a`` and their augmented copies, rebuilt as ``fit_series`` made them) and of the test
    clips ``b``, as Gram matrices: K (train x train), Kt (test x train), nt (test norms^2)."""
    from mocapkit.recognition.rocket import augment_series

    rng = np.random.default_rng([int(m.seed), 7])
    Xa, owner = augment_series(X[a], int(m.augment), rng, time_warp=float(m.time_warp),
                               rot_deg=float(m.rot_deg), arm_deg=float(m.arm_deg), keypoints=m.keypoints_)
    F = (m._features(np.concatenate([X[a], Xa])) - m.mean_) / m.scale_
    Ft = (m._features(X[b]) - m.mean_) / m.scale_
    return {"K": F @ F.T, "Kt": Ft @ F.T, "nt": (Ft * Ft).sum(1),
            "rows": np.concatenate([np.arange(len(a)), owner])}


def centring(groups: np.ndarray) -> np.ndarray:
    """The (n, n) matrix I - S that takes from each row the mean of the rows of its group:
    features F centred per group are (I - S) F, so their Gram matrices follow from F's."""
    same = groups[:, None] == groups[None, :]
    return np.eye(len(groups)) - same / same.sum(1, keepdims=True)


def nap(K: np.ndarray, Kt: np.ndarray, ya: np.ndarray, ga: np.ndarray, k: int
        ) -> tuple[np.ndarray, np.ndarray]:
    """Gram matrices of the features with the ``k`` leading within-class subject directions
    projected out: nuisance attribute projection (Solomonoff, Campbell & Boardman 2005,
    speaker recognition), from the training rows only -- not transductive. The directions
    are the principal axes of the (subject, class) cell means less their class means (ya,
    ga: labels and subjects of the training rows), i.e. how a subject performs an action
    differently from the others; with V = F^T B their orthonormal basis (B from the
    eigenvectors of A K A^T, A the cell-less-class averaging matrix), (I - V V^T) F's Gram
    matrices are K - K B B^T K and Kt - Kt B B^T K."""
    _, cell_of = np.unique(np.stack([np.unique(ga, return_inverse=True)[1],
                                     np.unique(ya, return_inverse=True)[1]], 1), axis=0, return_inverse=True)
    cell_of = cell_of.reshape(-1)
    A = np.zeros((cell_of.max() + 1, len(ya)))
    for i in range(len(A)):
        cell = cell_of == i
        cls = ya == ya[cell][0]
        A[i, cell] += 1.0 / cell.sum()
        A[i, cls] -= 1.0 / cls.sum()
    w, E = np.linalg.eigh(A @ K @ A.T)
    top = np.argsort(w)[::-1][:k]
    top = top[w[top] > 1e-9 * w.max()]
    B = A.T @ (E[:, top] / np.sqrt(w[top]))
    KB = K @ B
    return K - KB @ KB.T, Kt - (Kt @ B) @ KB.T


def ridge_predict(K: np.ndarray, Kt: np.ndarray, ya: np.ndarray, alpha: float) -> np.ndarray:
    """Kernel ridge on +-1 one-hot targets with an unpenalised intercept (the default's read-out)."""
    cls = np.unique(ya)
    Y = np.where(ya[:, None] == cls[None, :], 1.0, -1.0)
    ym = Y.mean(0)
    w, V = np.linalg.eigh(K)
    A = V @ ((1.0 / (np.maximum(w, 0.0) + alpha))[:, None] * (V.T @ (Y - ym)))
    return cls[np.argmax(Kt @ A + ym, axis=1)]


def readouts(G: dict, ya: np.ndarray, ga: np.ndarray, gt: np.ndarray) -> dict[str, np.ndarray]:
    """Predictions of every read-out from one fold's Gram matrices (labels ya and subjects
    ga of the training rows, subjects gt of the test clips)."""
    K, Kt, nt = G["K"], G["Kt"], G["nt"]
    n = np.diag(K)
    out = {f"ridge alpha {a:g}": ridge_predict(K, Kt, ya, a) for a in RIDGE_ALPHAS}
    A, At = centring(ga), centring(gt)
    out[SUBJECT_CENTRED] = ridge_predict(A @ K @ A, At @ Kt @ A, ya, 1e-3)
    for k in NAP_K:
        out[f"ridge after NAP k={k}"] = ridge_predict(*nap(K, Kt, ya, ga, k), ya, 1e-3)
    out["cosine kernel"] = ridge_predict(K / np.sqrt(np.outer(n, n)), Kt / np.sqrt(np.outer(nt, n)), ya, 1e-3)
    D2, Dt2 = n[:, None] + n[None, :] - 2 * K, nt[:, None] + n[None, :] - 2 * Kt
    med = float(np.median(D2[D2 > 0]))
    for g in (0.25, 0.5, 1.0, 2.0, 4.0):
        out[f"gaussian kernel g={g:g}"] = ridge_predict(np.exp(-D2 / (g * med)), np.exp(-Dt2 / (g * med)), ya, 1e-3)
    s = float(np.median(n))
    for p in (2, 3):
        out[f"polynomial kernel p={p}"] = ridge_predict((1 + K / s) ** p, (1 + Kt / s) ** p, ya, 1e-3)
    out["nearest neighbour"] = ya[np.argmin(Dt2, axis=1)]
    out.update(margin_readouts(K, Kt, ya))
    return out


#: inverse penalties C of the margin read-outs (:func:`margin_readouts`)
MARGIN_C = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1.0, 1e2)


def margin_readouts(K: np.ndarray, Kt: np.ndarray, ya: np.ndarray) -> dict[str, np.ndarray]:
    """Linear classifiers of the same features with other losses than the ridge's squared
    one (sixteenth round): the max-margin SVM (hinge loss; scikit-learn's ``SVC`` on the
    precomputed Gram matrix, one-vs-one) and multinomial logistic regression. The logistic
    model is fitted on the training rows' coordinates in the span of their features, Z = V
    sqrt(w) from K = V w V^T (test rows Kt V / sqrt(w)): a linear model's L2-penalised fit
    lies in that span (representer theorem), so this is the logistic regression of the
    ~10^5 features themselves at the cost of an n x n problem."""
    from sklearn.linear_model import LogisticRegression
    from sklearn.svm import SVC

    out = {}
    for C in MARGIN_C:
        out[f"linear SVM C={C:g}"] = SVC(kernel="precomputed", C=C).fit(K, ya).predict(Kt)
    w, V = np.linalg.eigh(K)
    keep = w > 1e-9 * w.max()
    Z, Zt = V[:, keep] * np.sqrt(w[keep]), Kt @ V[:, keep] / np.sqrt(w[keep])
    for C in MARGIN_C:
        lr = LogisticRegression(C=C, max_iter=2000)
        out[f"logistic C={C:g}"] = lr.fit(Z, ya).predict(Zt)
    return out


def main() -> int:
    from threadpoolctl import threadpool_limits

    import run_recognition as RR
    from mocapkit.bench.protocols import retrieval as R
    from mocapkit.recognition.rocket import RocketClassifier

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cache", type=Path, help="keep / reuse each fold's Gram matrices here (npz)")
    a = ap.parse_args()
    t0 = time.time()
    ctx = bench.Context(data_dir=shared_data_dir(a.data), progress=False)
    D = R._recog_data(ctx, "msr")
    X, y, g = D["X"], D["labels"], D["groups"]
    right: dict[str, dict[str, int]] = {}
    n = {"cross-subject": 0, "half": 0}
    with threadpool_limits(1):
        for kind, name, tr, te in RR.inner_folds(y, g):
            cache = None if a.cache is None else a.cache / f"gram_seed{a.seed}_{name}.npz"
            if cache is not None and cache.is_file():
                G = dict(np.load(cache))
            else:
                m = RocketClassifier(seed=a.seed).fit_series(X[tr], y[tr], keypoints=D["keypoints"])
                G = gram(m, X, tr, te)
                if cache is not None:
                    cache.parent.mkdir(parents=True, exist_ok=True)
                    np.savez(cache, **G)
            for ro, pred in readouts(G, y[tr][G["rows"]], g[tr][G["rows"]], g[te]).items():
                right.setdefault(ro, {"cross-subject": 0, "half": 0})[kind] += int((pred == y[te]).sum())
            n[kind] += len(te)
            print(kind, name, f"{time.time() - t0:.0f} s", flush=True)
    rows = [{"readout": ro, "seed": a.seed, **{k: v / n[k] for k, v in r.items()}} for ro, r in right.items()]
    OUT.write_text(json.dumps({"n": n, "seconds": time.time() - t0, "rows": rows}, indent=1))
    for r in rows:
        print(f"{r['readout']:28s} cs {100 * r['cross-subject']:.1f}  half {100 * r['half']:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
