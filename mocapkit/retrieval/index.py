"""A searchable index of a motion library (thesis Fig. 5.1: learn a compact feature
space on the database, map every query into it, rank by Euclidean distance).

Pieces
------
:func:`describe`        Motion -> :class:`Descriptor` (HOD vector + GPF frames).
:class:`RetrievalModel` learns the GPF codebook, the feature selection (AMFS or a
                        baseline) and the embedding on the database descriptors;
                        ``embed`` maps descriptors into the search space.
:class:`MotionIndex`    the database embeddings + file paths + the model; ``search``;
                        ``save``/``load`` to one ``.idx`` file (npz format).
:func:`build_index`     files or a folder -> ``.idx`` file (CLI ``mocapkit index build``).
:func:`search`          ``.idx`` + query file -> ``[(path, distance), ...]`` (CLI
                        ``mocapkit search``).

Embedding (decision, documented in ``docs/results/retrieval.md``)
----------------------------------------------------------------
Views: HOD (length-weighted, ``normalize='none'``, pyramid 1/2/4, L2-normalised per clip)
and the GPF bag of words (L2-normalised). Selection scores are computed on the
concatenated views z-scored over the database (so the trace ratio does not just pick the
highest-variance columns), the view Laplacians on the views themselves. The search space
is the selected columns of the (un-z-scored) views, each view's selected block
L2-normalised and multiplied by sqrt(w_v): w = the AMFS view weights alpha (equal weights
for the baselines). ``d`` is an int, a fraction of D (default 0.3), or ``'auto'``: chosen
from ``d_grid`` by leave-one-out mAP inside the database (needs labels).

File format (``.idx``, an npz archive, ``allow_pickle=False``): ``header`` (JSON: format
version, parameters, feature mode), ``paths``, ``labels``, ``emb`` (float32 (N, d')),
``selected``, ``weights``, ``view_sizes`` and the codebook arrays ``cb_*``.
"""
from __future__ import annotations

import json
import os
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from .._params import store_params
from ..errors import MocapError, MocapFormatError, MocapValueError, NotFittedError
from ..motion import Motion
from . import amfs as A
from .evaluate import retrieval_scores
from .features import GPFCodebook, gpf, hod, prepare

__all__ = ["Descriptor", "describe", "RetrievalModel", "MotionIndex", "build_index", "search",
           "label_of", "find_motion_files", "METHODS", "INDEX_FORMAT_VERSION"]

INDEX_FORMAT_VERSION = 1
METHODS = ("amfs", "amfs-desc", "hod", "gpf", "concat", "laplacian", "spec", "udfs")


@dataclass(frozen=True)
class Descriptor:
    """Raw per-clip descriptors: ``hod`` (D_hod,), ``gpf`` (T, G) frames, feature ``mode``."""

    hod: np.ndarray
    gpf: np.ndarray
    mode: str


def describe(motion: Motion, *, max_fps: float = 30.0, levels: Sequence[int] = (1, 2, 4),
             smooth_s: float = 0.0) -> Descriptor:
    """HOD (``normalize='none'``) and GPF frames of one motion (see :mod:`.features`)."""
    p = prepare(motion, max_fps=max_fps, smooth_s=smooth_s)
    return Descriptor(hod=hod(p, levels=levels, normalize="none"), gpf=gpf(p), mode=p.mode)


def _l2(V: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(V, axis=-1, keepdims=True)
    return V / np.maximum(n, 1e-12)


class RetrievalModel:
    """Feature learning for retrieval on a database (module doc).

    Parameters
    ----------
    method : one of :data:`METHODS`: ``'amfs'`` (ascending scores, the misprint fix),
        ``'amfs-desc'`` (Algorithm 4 as printed), ``'hod'`` / ``'gpf'`` (one view, all
        features), ``'concat'`` (both views, all features), ``'laplacian'``, ``'spec'``,
        ``'udfs'`` (feature-selection baselines on the concatenated views).
    d : selected features: int, fraction of D (float < 1), or ``'auto'`` (LOO mAP on the
        database over ``d_grid``; needs labels).
    n_words : GPF codebook size. k, mu, r : AMFS parameters (:class:`~.amfs.AMFS`).
    n_clusters : c of UDFS / kappa of SPEC (default: number of database labels, else 10).
    max_fit : at most this many database clips are used to learn the selection.
    """

    def __init__(self, method: str = "amfs", *, d: int | float | str = 0.3, n_words: int = 128,
                 k: int = 5, mu: float = 0.1, r: float = 2.0, n_clusters: int | None = None,
                 d_grid: Sequence[int] = (200, 400, 800, 1200, 1600), max_fit: int = 3000,
                 seed: int = 0):
        if method not in METHODS:
            raise MocapValueError(f"unknown retrieval method {method!r}; choose from {', '.join(METHODS)}")
        store_params(self, locals(), tuples=("d_grid",))

    # -- views ---------------------------------------------------------------------------
    def _views(self, descs: Sequence[Descriptor]) -> list[np.ndarray]:
        H = _l2(np.stack([np.asarray(x.hod, float) for x in descs]))
        B = np.stack([self.codebook_.encode(x.gpf) for x in descs])
        return [H, B]

    def fit(self, descs: Sequence[Descriptor], labels: Sequence | None = None, *,
            codebook: GPFCodebook | None = None) -> "RetrievalModel":
        """Learn codebook (unless a fitted ``codebook`` is given), selection and weights."""
        descs = list(descs)
        if len(descs) < 2:
            raise MocapValueError("an index needs at least two clips")
        modes = {x.mode for x in descs}
        if len(modes) != 1:
            raise MocapValueError(f"clips with different feature layouts cannot share an index: {sorted(modes)}")
        self.mode_ = modes.pop()
        rng = np.random.default_rng(self.seed)
        fit_idx = np.arange(len(descs))
        if len(descs) > self.max_fit:
            fit_idx = np.sort(rng.choice(len(descs), self.max_fit, replace=False))
        fd = [descs[i] for i in fit_idx]
        self.codebook_ = codebook if codebook is not None else GPFCodebook(
            min(self.n_words, max(2, sum(len(x.gpf) for x in fd) // 4)),
            seed=self.seed).fit([x.gpf for x in fd])
        views = self._views(fd)
        self.view_sizes_ = np.array([V.shape[1] for V in views])
        D = int(self.view_sizes_.sum())
        lab = None if labels is None else np.asarray(labels)[fit_idx]
        nc = self.n_clusters or (len(np.unique(lab)) if lab is not None else 10)
        if self.method in ("hod", "gpf", "concat"):
            self.selected_ = {"hod": np.arange(self.view_sizes_[0]),
                              "gpf": np.arange(self.view_sizes_[0], D),
                              "concat": np.arange(D)}[self.method]
            self.weights_ = np.full(2, 0.5)
            self.d_ = len(self.selected_)
            return self
        X = np.concatenate(views, axis=1)
        mu, sd = X.mean(0), X.std(0)
        Z = (X - mu) / np.where(sd > 1e-12, sd, 1.0)
        if self.method.startswith("amfs"):
            Ls = [A.local_regression_laplacian(V, self.k, self.mu) for V in views]
            a_v = np.stack([A.feature_quadratic(Z, L) for L in Ls])
            b = A.global_scatter(Z)
            order = "descending" if self.method == "amfs-desc" else "ascending"

            def select(d):
                m = A.AMFS(d=d, k=self.k, mu=self.mu, r=self.r, order=order,
                           seed=self.seed).fit_diagonals(a_v, b)
                return m.selected_, m.alpha_, m
        else:
            if self.method == "laplacian":
                sc, small = A.laplacian_score(Z, k=self.k), True
            elif self.method == "spec":
                sc, small = A.spec_score(Z, nc, k=self.k), False
            else:
                sc, small = A.udfs_score(Z, nc, k=self.k), False

            def select(d):
                return A.select_top(sc, d, smallest=small), np.full(2, 0.5), None
        n_valid = int((sd > 1e-12).sum())
        if self.d == "auto":
            if lab is None:
                raise MocapValueError("d='auto' needs database labels")
            best = None
            self.d_scores_ = {}
            for d in [g for g in self.d_grid if g <= n_valid] or [n_valid]:
                sel, w, _ = select(d)
                E = self._embed_views(views, sel, w)
                s = _loo_map(E, lab)
                self.d_scores_[int(d)] = s
                if best is None or s > best[0] + 1e-12:
                    best = (s, d)
            d = best[1]
        elif isinstance(self.d, float) and 0 < self.d < 1:
            d = int(round(self.d * D))
        else:
            d = int(self.d)
        d = int(min(max(d, 1), n_valid))
        sel, w, m = select(d)
        self.selected_, self.weights_, self.d_ = np.asarray(sel), np.asarray(w, float), d
        if m is not None:
            self.amfs_ = m
        return self

    def _embed_views(self, views: list[np.ndarray], sel: np.ndarray, w: np.ndarray) -> np.ndarray:
        X = np.concatenate(views, axis=1)
        edges = np.cumsum(np.r_[0, [V.shape[1] for V in views]])
        blocks = []
        for v in range(len(views)):
            s = sel[(sel >= edges[v]) & (sel < edges[v + 1])]
            if len(s):
                blocks.append(np.sqrt(w[v]) * _l2(X[:, s]))
        return np.concatenate(blocks, axis=1)

    def embed(self, descs: Sequence[Descriptor]) -> np.ndarray:
        """Search-space coordinates (n, d') of descriptors (float64)."""
        if not hasattr(self, "selected_"):
            raise NotFittedError("the retrieval model is not fitted")
        descs = list(descs)
        bad = [x.mode for x in descs if x.mode != self.mode_]
        if bad:
            raise MocapValueError(
                f"query features have layout {bad[0]!r}, the index was built on {self.mode_!r} "
                "(the skeleton's shoulders/elbows/wrists/hips/knees/ankles/head could not be named)")
        return self._embed_views(self._views(descs), self.selected_, self.weights_)

    # -- persistence -------------------------------------------------------------------
    def state(self) -> dict[str, np.ndarray]:
        st = self.codebook_.state()
        st.update(selected=np.asarray(self.selected_), weights=np.asarray(self.weights_),
                  view_sizes=np.asarray(self.view_sizes_))
        return st

    def params(self) -> dict:
        return {"method": self.method, "d": self.d, "n_words": self.n_words, "k": self.k,
                "mu": self.mu, "r": self.r, "seed": self.seed, "mode": self.mode_,
                "d_selected": int(self.d_)}

    @classmethod
    def from_state(cls, params: dict, st: dict) -> "RetrievalModel":
        m = cls(params["method"], d=params["d"], n_words=params["n_words"], k=params["k"],
                mu=params["mu"], r=params["r"], seed=params["seed"])
        m.codebook_ = GPFCodebook.from_state(st)
        m.selected_ = np.asarray(st["selected"], dtype=np.int64)
        m.weights_ = np.asarray(st["weights"], float)
        m.view_sizes_ = np.asarray(st["view_sizes"], dtype=np.int64)
        m.mode_ = params["mode"]
        m.d_ = int(params["d_selected"])
        return m


def _loo_map(E: np.ndarray, labels: np.ndarray) -> float:
    """Leave-one-out mAP of a database against itself (self excluded)."""
    from .evaluate import pairwise_distances

    Dm = pairwise_distances(E, E)
    np.fill_diagonal(Dm, np.inf)
    order = np.argsort(Dm, axis=1, kind="stable")[:, :-1]
    R = labels[order] == labels[:, None]
    from .evaluate import average_precision

    ap = average_precision(R)
    return float(np.nanmean(ap))


# ---------------------------------------------------------------------------- the index
def label_of(path: str | os.PathLike) -> str:
    """Action label guessed from a file name: MSR-Action3D ``aAA_sSS_eEE`` -> ``'aAA'``;
    HDM05 ``HDM_xx_<class>_...`` -> the class; otherwise the parent folder's name."""
    p = Path(path)
    m = re.match(r"^(a\d\d)_s\d\d_e\d\d", p.name)
    if m:
        return m.group(1)
    m = re.match(r"^HDM_[a-z]{2}_([A-Za-z0-9]+?)_\d+", p.name)
    if m:
        return m.group(1)
    return p.parent.name


def find_motion_files(paths_or_dir) -> list[Path]:
    """Motion files under a folder (recursively) or from a list of paths/folders.

    Supported extensions of :mod:`mocapkit.io` except ``.asf`` (skeleton files);
    ``.txt`` files are kept only when named like MSR-Action3D skeletons
    (``*_skeleton*.txt``) or given explicitly.
    """
    from ..io import SUPPORTED_EXTENSIONS

    items = [paths_or_dir] if isinstance(paths_or_dir, (str, os.PathLike)) else list(paths_or_dir)
    out: list[Path] = []
    for it in items:
        p = Path(it)
        if p.is_dir():
            for f in sorted(p.rglob("*")):
                ext = f.suffix.lower()
                if not f.is_file() or ext not in SUPPORTED_EXTENSIONS or ext == ".asf":
                    continue
                if ext == ".txt" and "skeleton" not in f.name.lower():
                    continue
                out.append(f)
        elif p.is_file():
            out.append(p)
        else:
            raise MocapValueError(f"{p}: no such file or folder")
    return out


class MotionIndex:
    """Database embeddings + paths + model; vectorised Euclidean search (module doc)."""

    def __init__(self, model: RetrievalModel, emb: np.ndarray, paths: Sequence[str],
                 labels: Sequence[str] | None = None):
        self.model = model
        self.emb = np.ascontiguousarray(emb, dtype=np.float32)
        self.paths = [str(p) for p in paths]
        self.labels = [str(x) for x in labels] if labels is not None else [""] * len(self.paths)
        self._sq = (self.emb.astype(np.float64) ** 2).sum(1)

    def __len__(self) -> int:
        return len(self.paths)

    def search_embedding(self, q: np.ndarray, k: int = 10) -> tuple[np.ndarray, np.ndarray]:
        """(indices, distances) of the k nearest clips to embedded queries ``q`` (n, d') or
        (d',): one matrix product and an argpartition, no per-clip loop."""
        q = np.asarray(q, dtype=np.float32)
        single = q.ndim == 1
        q = np.atleast_2d(q)
        k = int(min(max(int(k), 1), len(self)))
        d2 = self._sq[None, :] - 2.0 * (q @ self.emb.T).astype(np.float64) + (q.astype(np.float64) ** 2).sum(1)[:, None]
        d2 = np.maximum(d2, 0.0)
        kk = int(min(len(self), k + 8))                         # a few spare candidates
        part = np.argpartition(d2, kk - 1, axis=1)[:, :kk]
        # exact distances of the candidates (the expansion above cancels badly near 0)
        diff = self.emb[part].astype(np.float64) - q.astype(np.float64)[:, None, :]
        pd = np.sqrt((diff ** 2).sum(axis=2))
        o = np.lexsort((part, pd), axis=1)[:, :k]
        idx = np.take_along_axis(part, o, axis=1)
        dist = np.take_along_axis(pd, o, axis=1)
        return (idx[0], dist[0]) if single else (idx, dist)

    def search(self, query: Motion | Descriptor, k: int = 10) -> list[tuple[str, float]]:
        """Ranked ``[(path, distance), ...]`` of the k clips nearest to ``query``."""
        desc = query if isinstance(query, Descriptor) else describe(query)
        idx, dist = self.search_embedding(self.model.embed([desc])[0], k)
        return [(self.paths[i], float(d)) for i, d in zip(idx, dist)]

    def save(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        from ..io._atomic import atomic_write, check_output_path

        p = check_output_path(path, overwrite=overwrite)
        header = {"format": "mocapkit-index", "version": INDEX_FORMAT_VERSION,
                  "params": self.model.params(), "n": len(self)}
        arrays = dict(self.model.state())
        arrays.update(header=np.array(json.dumps(header)), emb=self.emb,
                      paths=np.array(self.paths, dtype=str), labels=np.array(self.labels, dtype=str))
        atomic_write(p, lambda f: np.savez(f, **arrays), binary=True)
        return p

    @classmethod
    def load(cls, path: str | os.PathLike) -> "MotionIndex":
        from ..io._npz import read_npz

        p = Path(path)
        header, st = read_npz(p, "index file")
        if header.get("format") != "mocapkit-index":
            raise MocapFormatError(p, f"not a mocapkit index file (it holds a {header.get('format')!r}); "
                                      "build one with 'mocapkit index build'")
        if header.get("version") != INDEX_FORMAT_VERSION:
            raise MocapFormatError(p, f"index format {header.get('format')} v{header.get('version')} "
                                      f"is not supported (expected v{INDEX_FORMAT_VERSION}); rebuild it")
        model = RetrievalModel.from_state(header["params"], st)
        return cls(model, st["emb"], list(st["paths"]), list(st["labels"]))


def _describe_files(files: Sequence[Path], progress: bool, desc: str = "features"):
    from ..bench.core import progress as bar
    from ..io import read

    descs, ok, skipped = [], [], []
    for f in bar(files, total=len(files), desc=desc, enable=progress):
        try:
            descs.append(describe(read(f)))
            ok.append(f)
        except MocapError as e:
            skipped.append((str(f), str(e)))
    return descs, ok, skipped


def build_index(paths_or_dir, output: str | os.PathLike, progress: bool = True, *,
                method: str = "amfs", d: int | float | str = 0.3, n_words: int = 128,
                labels: Sequence[str] | None = None, overwrite: bool = False,
                seed: int = 0) -> dict:
    """Build a ``.idx`` index of motion files (CLI ``mocapkit index build DIR -o lib.idx``).

    Parameters
    ----------
    paths_or_dir : a folder (searched recursively) or a list of files/folders.
    output : the ``.idx`` file to write (atomically; refuses to overwrite unless asked).
    progress : tqdm bar on stderr.
    method, d, n_words, seed : see :class:`RetrievalModel`.
    labels : optional labels per file (default: :func:`label_of`, stored for display).

    Returns
    -------
    ``{'output', 'n_indexed', 'skipped': [(path, reason)], 'seconds', 'd', 'mode'}``.
    Files that cannot be read or described are skipped and listed (the rest go on);
    files whose skeleton gives another feature layout than the majority are skipped too.
    """
    from ..io._atomic import check_output_path

    check_output_path(output, overwrite=overwrite)
    files = find_motion_files(paths_or_dir)
    if not files:
        raise MocapValueError(f"no motion files found in {paths_or_dir}")
    t0 = time.perf_counter()
    descs, ok, skipped = _describe_files(files, progress)
    lab_map = None
    if labels is not None:
        if len(labels) != len(files):
            raise MocapValueError(f"{len(labels)} labels for {len(files)} files")
        lab_map = {str(f): str(l) for f, l in zip(files, labels)}
    if descs:
        modes, counts = np.unique([x.mode for x in descs], return_counts=True)
        major = modes[np.argmax(counts)]
        keep = [i for i, x in enumerate(descs) if x.mode == major]
        for i, x in enumerate(descs):
            if x.mode != major:
                skipped.append((str(ok[i]), f"feature layout {x.mode} differs from the index's {major}"))
        descs = [descs[i] for i in keep]
        ok = [ok[i] for i in keep]
    if len(descs) < 2:
        raise MocapValueError(f"fewer than two usable motion files ({len(skipped)} skipped: "
                              + "; ".join(f"{p}: {r}" for p, r in skipped[:3]) + ")")
    labs = [lab_map[str(f)] if lab_map else label_of(f) for f in ok]
    model = RetrievalModel(method, d=d, n_words=n_words, seed=seed).fit(
        descs, labs if d == "auto" else None)
    index = MotionIndex(model, model.embed(descs), [str(f) for f in ok], labs)
    index.save(output, overwrite=overwrite)
    if progress and skipped:
        for p, r in skipped:
            print(f"skipped {p}: {r}", file=sys.stderr)
    return {"output": str(output), "n_indexed": len(ok), "skipped": skipped,
            "seconds": time.perf_counter() - t0, "d": int(model.d_), "mode": model.mode_}


def search(index_path: str | os.PathLike, query_path: str | os.PathLike, k: int = 10) -> list[tuple[str, float]]:
    """The k indexed files nearest to the motion in ``query_path``: ``[(path, distance)]``
    nearest first (CLI ``mocapkit search lib.idx QUERY -k 10``). Distances are Euclidean in
    the index's embedding (unitless)."""
    from ..io import read

    if int(k) < 1:
        raise MocapValueError(f"k must be at least 1, got {k}")
    index = MotionIndex.load(index_path)
    return index.search(read(query_path), k=int(k))
