"""NMF-based motion clustering (NMC, thesis seed 003 Sec. 6.3, eqs. 6.1-6.15, Algorithm 6)
and the bag-of-words action classifier built on it.

Pipeline (thesis Sec. 6.3.4, Fig. 6.11)
---------------------------------------
1. Every sequence is cut into overlapping windows of M frames with stride M/2
   (:func:`mocapkit.retrieval.features.sliding_windows`).
2. Each window becomes a non-negative vector (:func:`window_features`): its HOD
   (length-weighted orientation histograms of the 15 keypoints on 3 planes) and its mean
   pose split into positive and negative parts (``[max(p, 0), max(-p, 0)]``, the usual
   way to feed signed data to NMF), each block L2-normalised and weighted.
3. All windows are clustered with graph-regularised orthogonal NMF (:func:`gonmf`):
   ``min ||X - Z G||_F^2 + lam1 ||G||_F^2 + lam2 tr(G L G^T)``, Z >= 0, G >= 0, Z^T Z = I
   (eq. 6.3) with a kNN heat-kernel graph L = D - W on the windows.
4. A sequence's bag of words is the mean of its windows' normalised memberships
   (columns of G scaled to sum 1), over a temporal pyramid (levels ``bow_levels``).
5. Classifier (decision): an L2-regularised **logistic regression** (scikit-learn,
   multinomial, C = ``C``) on the square-rooted bag of words (Hellinger map), standardised.

Updates (Algorithm 6), samples are columns of X (d x n) as in the thesis:

* Z (eq. 6.9, Ding et al. 2006 orthogonal NMF): ``Z <- Z o [(X G^T) / (Z Z^T X G^T)]^(1/2)``,
  then the columns of Z are scaled to unit norm (Algorithm 6 step 4) and the rows of G
  by the inverse factors, so Z G -- the fit -- is unchanged by the normalisation
  (decision: the thesis only says "normalize Z").
* G (eq. 6.15 with two fixes): the printed gradient (6.12) has ``X - 2G`` and uses L in
  the denominator, which can be negative. With the non-negative split L = D - W of the
  Laplacian (Cai et al. 2011 GNMF) and the gradient of (6.10) without the gamma term::

      G <- G o [ (Z^T X + lam2 G W) / (Z^T Z G + lam1 G + lam2 G D) ]^eta

  ``eta = 1/2`` (the thesis' square root, default) or 1 (Lee-Seung/Cai). The objective
  (6.3) is non-increasing under the G step for fixed Z (auxiliary-function argument of
  Cai et al.); the orthogonal Z step decreases the Lagrangian, not (6.3) itself, so
  :func:`gonmf` records the objective per iteration (``history``) and the tests check
  it on the settings we use.

Model files: a fitted NMC saves to ``.npz`` (:meth:`NMCClassifier.save`: the basis Z, the
scaler and the logistic-regression weights, the parameters and the joint names of the
training skeleton) and is used for new clips inductively; ``mocapkit classify train
--method nmc`` (library: ``train_classifier(method='nmc')``) trains one.

Out-of-sample windows (``transductive=False``): G for new windows by the G step with Z
fixed and no graph term (lam2 = 0), from a uniform start. ``transductive=True`` clusters
the training and test windows together (labels are never used by the clustering), as the
thesis does ("a clustering is taken ... for all the clips").
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import scipy.sparse as sp

from .._params import store_params
from ..errors import MocapValueError, NotFittedError
from ..motion import Motion
from ..retrieval.features import PLANES, Prepared, orientation_bins, prepare, sliding_windows
from .model_file import check_joint_set, load_model, read_head, register_format, write_model

__all__ = ["knn_graph", "nmf_objective", "gonmf", "encode_windows", "window_features",
           "NMCClassifier", "MODEL_FORMAT"]

MODEL_FORMAT = "mocapkit-nmc"
MODEL_FORMAT_VERSION = 1


def knn_graph(F: np.ndarray, k: int = 5) -> sp.csr_matrix:
    """Symmetric kNN heat-kernel affinity W (n, n) of the rows of F (t = mean kNN d^2)."""
    from sklearn.neighbors import NearestNeighbors

    F = np.asarray(F, float)
    n = F.shape[0]
    k = int(min(max(k, 1), n - 1))
    nn = NearestNeighbors(n_neighbors=k + 1).fit(F)
    dist, idx = nn.kneighbors(F)
    d2 = dist[:, 1:] ** 2
    t = float(d2.mean()) if d2.size and d2.mean() > 0 else 1.0
    W = sp.coo_matrix((np.exp(-d2 / t).ravel(), (np.repeat(np.arange(n), k), idx[:, 1:].ravel())),
                      shape=(n, n)).tocsr()
    return W.maximum(W.T).tocsr()


def nmf_objective(X, Z, G, W=None, lam1: float = 0.0, lam2: float = 0.0) -> float:
    """Eq. 6.3: ``||X - Z G||_F^2 + lam1 ||G||_F^2 + lam2 tr(G L G^T)``, L = D - W."""
    X = np.asarray(X, float)
    R = X - Z @ G
    val = float((R * R).sum()) + lam1 * float((G * G).sum())
    if W is not None and lam2:
        deg = np.asarray(W.sum(axis=1)).ravel()
        val += lam2 * float((G * G * deg[None, :]).sum() - (G * (W @ G.T).T).sum())
    return val


def _kmeans_init(X: np.ndarray, k: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    from sklearn.cluster import KMeans

    km = KMeans(n_clusters=k, n_init=1, max_iter=50, random_state=seed).fit(X.T)
    Z = np.maximum(km.cluster_centers_.T, 0.0) + 1e-3 * X.mean()
    G = np.full((k, X.shape[1]), 0.2)
    G[km.labels_, np.arange(X.shape[1])] += 1.0
    return Z, G


def gonmf(X, n_components: int, *, W=None, lam1: float = 0.0, lam2: float = 0.0,
          orthogonal: bool = True, eta: float = 0.5, max_iter: int = 200, tol: float = 1e-5,
          init: str | tuple = "kmeans", seed: int = 0, return_history: bool = False):
    """Graph-regularised orthogonal NMF (module doc; thesis Algorithm 6).

    Parameters
    ----------
    X : (d, n) non-negative data, samples as columns.
    n_components : k clusters.
    W : (n, n) sparse/dense non-negative affinity (L = D - W); None = no graph term.
    lam1, lam2 : weights of ||G||_F^2 and tr(G L G^T) (absolute).
    orthogonal : Ding's orthogonal Z step + column normalisation (thesis) or the plain
        Lee-Seung step ``Z <- Z o (X G^T) / (Z G G^T)``.
    eta : exponent of the G step (1/2 thesis, 1 Lee-Seung).
    init : ``'kmeans'`` (thesis), ``'random'`` or a (Z, G) pair.

    Returns
    -------
    Z (d, k), G (k, n)[, history list of objective values, the first one at the start].
    """
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2 or (X < 0).any() or not np.isfinite(X).all():
        raise MocapValueError("NMF needs a finite, non-negative 2-D matrix")
    d, n = X.shape
    k = int(n_components)
    if not 1 <= k <= n:
        raise MocapValueError(f"n_components must be between 1 and {n}, got {k}")
    eps = 1e-12
    if isinstance(init, tuple):
        Z, G = (np.array(a, dtype=np.float64) for a in init)
    elif init == "kmeans":
        Z, G = _kmeans_init(X, k, seed)
    elif init == "random":
        rng = np.random.default_rng(seed)
        Z, G = rng.random((d, k)) + 0.1, rng.random((k, n)) + 0.1
    else:
        raise MocapValueError(f"init must be 'kmeans', 'random' or (Z, G), got {init!r}")
    if W is not None:
        W = sp.csr_matrix(W)
        deg = np.asarray(W.sum(axis=1)).ravel()
    if orthogonal:                                           # start from normalised Z
        s = np.maximum(np.linalg.norm(Z, axis=0), eps)
        Z, G = Z / s, G * s[:, None]
    hist = [nmf_objective(X, Z, G, W, lam1, lam2)]
    for _ in range(int(max_iter)):
        XGt = X @ G.T
        if orthogonal:
            Z *= np.sqrt(XGt / np.maximum(Z @ (Z.T @ XGt), eps))
            s = np.maximum(np.linalg.norm(Z, axis=0), eps)
            Z, G = Z / s, G * s[:, None]
        else:
            Z *= XGt / np.maximum(Z @ (G @ G.T), eps)
        num = Z.T @ X
        den = (Z.T @ Z) @ G + lam1 * G
        if W is not None and lam2:
            num = num + lam2 * (W @ G.T).T
            den = den + lam2 * G * deg[None, :]
        ratio = num / np.maximum(den, eps)
        G *= ratio if eta == 1 else ratio ** eta
        hist.append(nmf_objective(X, Z, G, W, lam1, lam2))
        if abs(hist[-2] - hist[-1]) <= tol * max(abs(hist[0]), eps):
            break
    return (Z, G, hist) if return_history else (Z, G)


def encode_windows(X, Z, *, lam1: float = 0.0, eta: float = 0.5, n_iter: int = 100) -> np.ndarray:
    """G (k, n) of new columns X (d, n) for a fixed Z: the G step without the graph term."""
    X = np.asarray(X, np.float64)
    eps = 1e-12
    ZtZ = Z.T @ Z
    num = Z.T @ X
    G = np.full((Z.shape[1], X.shape[1]), 1.0 / Z.shape[1])
    for _ in range(int(n_iter)):
        ratio = num / np.maximum(ZtZ @ G + lam1 * G, eps)
        G *= ratio if eta == 1 else ratio ** eta
    return G


# ---------------------------------------------------------------------------- windows
def _split(V: np.ndarray) -> np.ndarray:
    return np.concatenate([np.maximum(V, 0.0), np.maximum(-V, 0.0)], axis=-1)


def _l2(V: np.ndarray) -> np.ndarray:
    return V / np.maximum(np.linalg.norm(V, axis=-1, keepdims=True), 1e-12)


def window_features(p: Prepared, window: int, stride: int, *, bins: int = 8,
                    weights: Sequence[float] = (1.0, 1.0)) -> np.ndarray:
    """Non-negative window vectors (N_w, K*3*bins + 2*3K) of one prepared clip (module doc).

    Vectorised with cumulative sums over the frames (no loop over windows): HOD of each
    window from the displacements inside it, mean root-relative pose (root: trajectory
    mean minus the window's first root position is dropped; the root's slot holds the
    window's root displacement) split into positive/negative parts.
    """
    P = p.positions
    T, K, _ = P.shape
    win = sliding_windows(T, window, stride)                     # (N, 2)
    nP = len(PLANES)
    # HOD contributions per displacement: (T-1, K*nP*bins)
    if T > 1:
        bi, w = orientation_bins(np.diff(P, axis=0), bins)
        C = np.zeros((T - 1, K, nP, bins))
        np.put_along_axis(C, bi[..., None], w[..., None], axis=3)
        C = C.reshape(T - 1, -1)
        cs = np.vstack([np.zeros((1, C.shape[1])), np.cumsum(C, axis=0)])
        s, e = win[:, 0], np.maximum(win[:, 1] - 1, win[:, 0])
        Hw = cs[e] - cs[s]                                       # displacements s..e-1
    else:
        Hw = np.zeros((len(win), K * nP * bins))
    Q = P.copy()
    Q[:, 0] = 0.0
    cq = np.vstack([np.zeros((1, K * 3)), np.cumsum(Q.reshape(T, -1), axis=0)])
    n = (win[:, 1] - win[:, 0])[:, None]
    pose = (cq[win[:, 1]] - cq[win[:, 0]]) / n
    root_disp = P[win[:, 1] - 1, 0] - P[win[:, 0], 0]
    pose[:, :3] = root_disp
    blocks = [_l2(Hw), _l2(_split(pose))]
    if len(weights) > 2:
        from ..retrieval.features import gpf

        Gf = gpf(p)
        cg = np.vstack([np.zeros((1, Gf.shape[1])), np.cumsum(Gf, axis=0)])
        blocks.append(_l2(_split((cg[win[:, 1]] - cg[win[:, 0]]) / n)))
    return np.concatenate([w * b for w, b in zip(weights, blocks)], axis=1)


def _bow(G: np.ndarray, owner: np.ndarray, pos: np.ndarray, n_seq: int,
         levels: Sequence[int]) -> np.ndarray:
    """Mean normalised membership per sequence and pyramid cell: (n_seq, sum(levels) * k)."""
    Gn = G / np.maximum(G.sum(axis=0, keepdims=True), 1e-12)
    k = G.shape[0]
    out = []
    for L in levels:
        cell = np.minimum((pos * L).astype(int), L - 1)
        key = owner * L + cell
        H = np.zeros((n_seq * L, k))
        np.add.at(H, key, Gn.T)
        cnt = np.bincount(key, minlength=n_seq * L)
        H /= np.maximum(cnt, 1)[:, None]
        out.append(H.reshape(n_seq, L * k))
    return np.concatenate(out, axis=1)


class NMCClassifier:
    """NMC bag of words + logistic regression (module doc).

    Parameters
    ----------
    window, stride : window length and step in frames *at 15 fps* (scaled with the clip's
        frame rate after :func:`~mocapkit.retrieval.features.prepare`). The thesis uses a
        stride of M/2 = 30 frames; MSR-Action3D clips have 13-100 frames at 15 fps (median
        39), so M = 60 would leave one window per clip -- decision: M = 10, stride 5.
    n_clusters : k of the NMF (words).
    lam1, lam2 : NMF weights, relative to ``||X||_F^2 / n`` (lam2 per unit graph degree).
    n_neighbors : kNN graph size.
    transductive : cluster train and test windows together (thesis) when ``predict`` gets
        several sequences; else encode test windows with the learnt Z.
    bow_levels : temporal pyramid of the bag of words.
    C : inverse regularisation of the logistic regression.
    """

    def __init__(self, *, window: int = 10, stride: int = 5, n_clusters: int = 128,
                 lam1: float = 1e-3, lam2: float = 1e-2, n_neighbors: int = 5,
                 max_iter: int = 150, eta: float = 0.5, transductive: bool = True,
                 bow_levels: Sequence[int] = (1, 2), C: float = 10.0,
                 block_weights: Sequence[float] = (1.0, 1.0), seed: int = 0):
        store_params(self, locals(), tuples=("bow_levels", "block_weights"))

    def _windows(self, seqs: Sequence) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        feats, owner, pos = [], [], []
        for i, s in enumerate(seqs):
            p = s if isinstance(s, Prepared) else prepare(s)
            f = p.fps / 15.0
            M = max(2, int(round(self.window * f)))
            st = max(1, int(round(self.stride * f)))
            Fw = window_features(p, M, st, weights=self.block_weights)
            w = sliding_windows(p.n_frames, M, st)
            feats.append(Fw)
            owner.append(np.full(len(Fw), i))
            pos.append(((w[:, 0] + w[:, 1]) / 2.0) / max(p.n_frames, 1))
        return np.concatenate(feats), np.concatenate(owner), np.concatenate(pos)

    def _cluster(self, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        X = F.T
        scale = float((X ** 2).sum() / X.shape[1])
        W = knn_graph(F, self.n_neighbors) if self.lam2 > 0 else None
        k = int(min(self.n_clusters, X.shape[1]))
        Z, G = gonmf(X, k, W=W, lam1=self.lam1 * scale, lam2=self.lam2 * scale,
                     eta=self.eta, max_iter=self.max_iter, seed=self.seed)
        return Z, G

    def _classifier(self):
        from sklearn.linear_model import LogisticRegression
        from sklearn.pipeline import make_pipeline
        from sklearn.preprocessing import StandardScaler

        return make_pipeline(StandardScaler(), LogisticRegression(C=self.C, max_iter=2000))

    def fit(self, seqs: Sequence, labels: Sequence, test_seqs: Sequence | None = None) -> "NMCClassifier":
        """Fit on training sequences (Motion or Prepared); ``test_seqs`` (optional, unlabelled)
        join the clustering when ``transductive`` -- their bags are kept for :meth:`predict`
        with ``test_seqs=None``."""
        labels = np.asarray(labels)
        if len(seqs) != len(labels) or len(seqs) < 2:
            raise MocapValueError("NMC needs at least two labelled sequences")
        Ftr, otr, ptr = self._windows(seqs)
        n_tr = len(seqs)
        if self.transductive and test_seqs is not None:
            Fte, ote, pte = self._windows(test_seqs)
            F = np.vstack([Ftr, Fte])
            Z, G = self._cluster(F)
            self.test_bow_ = np.sqrt(_bow(G[:, len(Ftr):], ote, pte, len(test_seqs), self.bow_levels))
            G = G[:, :len(Ftr)]
        else:
            Z, G = self._cluster(Ftr)
            self.test_bow_ = None
        self.Z_ = Z
        scale = float((Ftr ** 2).sum() / len(Ftr))
        self.lam1_abs_ = self.lam1 * scale
        if self.test_bow_ is None:     # inductive: train bags coded exactly like test bags
            G = encode_windows(Ftr.T, Z, lam1=self.lam1_abs_, eta=self.eta)
        Btr = np.sqrt(_bow(G, otr, ptr, n_tr, self.bow_levels))
        clf = self._classifier().fit(Btr, labels)
        sc, lr = clf[0], clf[-1]
        self.bow_mean_, self.bow_scale_ = sc.mean_, sc.scale_
        self.coef_, self.intercept_ = np.atleast_2d(lr.coef_), np.atleast_1d(lr.intercept_)
        self.classes_ = lr.classes_
        motions = all(isinstance(s, Motion) for s in seqs)
        if motions and len({s.skeleton.names for s in seqs}) == 1:
            self.joints_ = np.array(seqs[0].skeleton.names, dtype=str)
        else:                  # Prepared clips (or mixed kinds): no joint-set check
            self.joints_ = np.array([], dtype=str)
        return self

    def _proba(self, B: np.ndarray) -> np.ndarray:
        """Logistic-regression probabilities of bags B (n, d) (scikit-learn's, from the arrays)."""
        S = ((B - self.bow_mean_) / self.bow_scale_) @ self.coef_.T + self.intercept_
        if S.shape[1] == 1:                                   # binary: sigmoid = softmax([0, s])
            S = np.hstack([np.zeros_like(S), S])
        S = S - S.max(axis=1, keepdims=True)
        E = np.exp(S)
        return E / E.sum(axis=1, keepdims=True)

    def _labels(self, B: np.ndarray) -> np.ndarray:
        return np.asarray(self.classes_)[np.argmax(self._proba(B), axis=1)]

    def bags(self, seqs: Sequence) -> np.ndarray:
        """Bags of words (Hellinger-mapped) of new sequences with the learnt Z."""
        if not hasattr(self, "Z_"):
            raise NotFittedError("NMC is not fitted")
        F, o, p = self._windows(seqs)
        G = encode_windows(F.T, self.Z_, lam1=self.lam1_abs_, eta=self.eta)
        return np.sqrt(_bow(G, o, p, len(seqs), self.bow_levels))

    def predict(self, seqs: Sequence | Motion | None = None):
        """Labels of ``seqs`` (inductive) or, with None, of the transductive test set.

        Given one :class:`~mocapkit.motion.Motion` (not a list) it returns ``(label,
        confidence)`` like the other classifiers (the CLI's interface), after checking the
        motion's joint set against the training skeleton's."""
        if isinstance(seqs, Motion):
            check_joint_set(getattr(self, "joints_", ()), seqs)
            pr = self._proba(self.bags([seqs]))[0]
            i = int(np.argmax(pr))
            return str(self.classes_[i]), float(pr[i])
        if seqs is None:
            if getattr(self, "test_bow_", None) is None:
                raise MocapValueError("no transductive test set: pass sequences to predict")
            return self._labels(self.test_bow_)
        return self._labels(self.bags(seqs))

    # -- save / load ---------------------------------------------------------------
    def params(self) -> dict:
        return {"window": int(self.window), "stride": int(self.stride), "n_clusters": int(self.n_clusters),
                "lam1": float(self.lam1), "lam2": float(self.lam2), "n_neighbors": int(self.n_neighbors),
                "max_iter": int(self.max_iter), "eta": float(self.eta), "transductive": bool(self.transductive),
                "bow_levels": [int(v) for v in self.bow_levels], "C": float(self.C),
                "block_weights": [float(v) for v in self.block_weights], "seed": int(self.seed)}

    def save(self, path, *, overwrite: bool = False):
        """Write the fitted model (inductive use) to ``.npz`` (no pickle)."""
        if not hasattr(self, "Z_"):
            raise NotFittedError("NMC is not fitted")
        header = {"format": MODEL_FORMAT, "version": MODEL_FORMAT_VERSION, "params": self.params(),
                  "lam1_abs": float(self.lam1_abs_)}
        self.mean_, self.scale_ = self.bow_mean_, self.bow_scale_      # the shared read-out names
        return write_model(self, path, header, {"Z": self.Z_}, overwrite=overwrite)

    @classmethod
    def from_arrays(cls, header: dict, st: dict, path) -> "NMCClassifier":
        if "bow_mean" in st:                    # files written before the shared layout
            st = {**st, "mean": st["bow_mean"], "scale": st["bow_scale"]}
        m = read_head(cls(**header["params"]), header, st, path, MODEL_FORMAT_VERSION)
        m.Z_ = st["Z"]
        m.lam1_abs_ = float(header["lam1_abs"])
        m.bow_mean_, m.bow_scale_ = m.mean_, m.scale_
        m.test_bow_ = None
        return m

    @classmethod
    def load(cls, path) -> "NMCClassifier":
        from ..errors import MocapFormatError

        m = load_model(path)
        if not isinstance(m, cls):
            raise MocapFormatError(path, f"not an NMC model (it holds a {type(m).__name__})")
        return m


register_format(MODEL_FORMAT, NMCClassifier)
