"""Protocols of the thesis' retrieval and recognition chapters (seed 003, Ch. 5-6).

* ``amfs-retrieval`` -- Sec. 5.3: HDM05 (the thesis' cross-actor setting: 2 actors'
  clips are the database, the other 3 actors' clips the queries; every one of the 10
  actor pairs in the full run) and MSR-Action3D (a random half of each class is the
  database, the rest the queries; 5 seeds). Per method: mAP, P@1, P@5, P@10 (fractions,
  mean +- std over splits). Methods: ``amfs`` (ascending scores, the misprint fix),
  ``amfs-desc`` (Algorithm 4 as printed), ``hod`` and ``gpf`` (single views, all
  features), ``concat`` (both views), ``laplacian``, ``spec``, ``udfs``. Everything is
  learnt on the database only (codebook, selection); d is chosen per method and split by
  leave-one-out mAP inside the database over ``d_grid``. Euclidean ranking (as the thesis).
  The thesis gives retrieval results only as figures (no paper_value).
* ``nmc-recognition`` -- Sec. 6.3.4: MSR-Action3D, a random half of each class for
  training, the rest for testing (5 seeds); methods ``nmc`` (windows of all clips clustered
  together, thesis), ``nmc-inductive`` (clustering on training windows only) and
  ``classifier`` (the skeleton-sequence reference, :mod:`mocapkit.recognition.classifier`);
  metric ``accuracy`` (fraction), paper 0.9333 for ``nmc``. The full run writes the
  confusion matrix of ``nmc`` (summed over seeds) to ``docs/results/nmc_confusion.png``
  (``ctx.options['figures_dir']`` overrides; quick runs write none unless given).
* ``recognition-cross-subject`` -- MSR-Action3D cross-subject split (odd subjects train,
  even subjects test), the field's usual benchmark; same methods; NMC over 3 NMF seeds.

* ``recognition-msr-half``, ``recognition-msr-cross-subject``, ``recognition-hdm05-cross-actor``
  -- the default classifier (MiniRocket, :mod:`mocapkit.recognition.rocket`) against the
  skeleton classifier and NMC, on the 557 MSR-Action3D clips of the authors' list and on
  HDM05 (leave one actor out; 2 actors train / 3 test); accuracy, confusions, errors per
  subject/actor, training and inference time per clip (see the block comment below).

MSR-Action3D: 567 files, one (a13_s09_e02) has no tracked frame and is skipped (rows say
``n_clips``). Files are read and described once per process (module cache).
``ctx.quick``: one split per data set, a 64-word codebook, d-grid (400, 800), smaller NMF.
"""
from __future__ import annotations

import itertools
import re
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ...solvers._linalg import blas_limit
from ..core import Context, Row, protocol

MSR_ACTIONS = ("high arm wave", "horizontal arm wave", "hammer", "hand catch", "forward punch",
               "high throw", "draw x", "draw tick", "draw circle", "hand clap", "two hand wave",
               "side-boxing", "bend", "forward kick", "side kick", "jogging", "tennis swing",
               "tennis serve", "golf swing", "pick up & throw")
METHODS = ("amfs", "amfs-desc", "hod", "gpf", "concat", "laplacian", "spec", "udfs")
NMC_PAPER = 0.9333
_CACHE: dict[Any, Any] = {}


def _motions(ctx: Context, which: str) -> list[tuple[str, Any, Any, Any]]:
    """[(path, label, group, Motion)] of a data set (read once per process)."""
    from ... import io

    root = ctx.need_data()
    key = ("motions", str(root), which)
    if key in _CACHE:
        return _CACHE[key]
    out = []
    if which == "msr":
        for f in sorted((root / "msr_action3d" / "skeleton3d").glob("a*_s*_e*_skeleton3D.txt")):
            a, s, _ = re.findall(r"a(\d+)_s(\d+)_e(\d+)", f.name)[0]
            out.append((str(f), f"a{a}", int(s), io.read(f)))
    else:
        for f in sorted((root / "hdm05" / "asfamc").glob("*/HDM_*.amc")):
            out.append((str(f), f.parent.name, re.findall(r"HDM_([a-z]{2})_", f.name)[0], io.read(f)))
    if not out:
        from ...errors import MocapValueError

        raise MocapValueError(f"no {which} files under {root}")
    _CACHE[key] = out
    return out


def _cached(ctx: Context, which: str, kind: str):
    """Per-clip objects computed once: 'desc' (retrieval descriptors) or 'prep' (recognition)."""
    from ...errors import MocapError
    from ...recognition.classifier import SMOOTH_S, sequence_features
    from ...retrieval.features import prepare
    from ...retrieval.index import describe

    key = (kind, str(ctx.data_dir), which)
    if key not in _CACHE:
        items, labels, groups, skipped = [], [], [], []
        for path, lab, grp, m in _motions(ctx, which):
            try:
                if kind == "desc":
                    items.append(describe(m))
                else:
                    p = prepare(m, smooth_s=SMOOTH_S)
                    items.append((p, sequence_features(p)))
            except MocapError:
                skipped.append(path)
                continue
            labels.append(lab)
            groups.append(grp)
        _CACHE[key] = (items, np.array(labels), np.array(groups), skipped)
    return _CACHE[key]


def _class_halves(labels: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    first = np.zeros(len(labels), bool)
    for c in np.unique(labels):
        i = np.flatnonzero(labels == c)
        rng.shuffle(i)
        first[i[:len(i) // 2]] = True
    return np.flatnonzero(first), np.flatnonzero(~first)


def _rows(name: str, clip: str, condition: str, method: str, vals: dict[str, list[float]],
          secs: list[float], extra: dict, paper: dict | None = None) -> Iterator[Row]:
    for metric, v in vals.items():
        v = np.asarray(v, float)
        yield Row(name, clip, condition, method, metric, "fraction", float(v.mean()),
                  paper_value=(paper or {}).get(metric), seconds=float(np.mean(secs)),
                  std=float(v.std()) if len(v) > 1 else None, n=len(v), extra=dict(extra))


# ------------------------------------------------------------------------- retrieval
@protocol("amfs-retrieval", "Thesis Ch. 5: AMFS vs single views and feature-selection baselines, "
          "HDM05 (2 actors db / 3 query) and MSR-Action3D (half per class), mAP and P@k")
def amfs_retrieval(ctx: Context) -> Iterator[Row]:
    from ...retrieval.evaluate import pairwise_distances, retrieval_scores
    from ...retrieval.features import GPFCodebook
    from ...retrieval.index import RetrievalModel

    quick = ctx.quick
    methods = tuple(ctx.options.get("methods", METHODS))
    d_grid = tuple(ctx.options.get("d_grid", (400, 800) if quick else (200, 400, 800, 1200, 1600)))
    n_words = int(ctx.options.get("n_words", 64 if quick else 128))
    for ds in ("hdm05", "msr-action3d"):
        which = "hdm" if ds == "hdm05" else "msr"
        descs, labels, groups, skipped = _cached(ctx, which, "desc")
        if which == "hdm":
            actors = sorted(set(groups.tolist()))
            pairs = list(itertools.combinations(actors, 2))
            pairs = pairs[:1] if quick else pairs
            splits = [(np.flatnonzero(np.isin(groups, p)), np.flatnonzero(~np.isin(groups, p)), "+".join(p))
                      for p in pairs]
            cond = f"db = 2 actors, queries = other 3 ({len(splits)} actor pair{'s' if len(splits) > 1 else ''})"
        else:
            seeds = range(ctx.seed, ctx.seed + (1 if quick else int(ctx.options.get("seeds", 5))))
            splits = [(*_class_halves(labels, s), f"seed {s}") for s in seeds]
            cond = f"db = random half of each class ({len(splits)} seed{'s' if len(splits) > 1 else ''})"
        res: dict[str, dict[str, list]] = {m: {"mAP": [], "P@1": [], "P@5": [], "P@10": []} for m in methods}
        secs: dict[str, list] = {m: [] for m in methods}
        info: dict[str, list] = {m: [] for m in methods}
        for db, q, tag in splits:
            with blas_limit():
                cb = GPFCodebook(n_words, seed=ctx.seed).fit([descs[i].gpf for i in db])
                for m in methods:
                    t0 = time.perf_counter()
                    d = 0.3 if m in ("hod", "gpf", "concat") else "auto"
                    model = RetrievalModel(m, d=d, d_grid=d_grid, seed=ctx.seed).fit(
                        [descs[i] for i in db], labels[db], codebook=cb)
                    E = model.embed(descs)
                    sc = retrieval_scores(pairwise_distances(E[q], E[db]), labels[q], labels[db])
                    secs[m].append(time.perf_counter() - t0)
                    for k in res[m]:
                        res[m][k].append(sc[k])
                    amfs = getattr(model, "amfs_", None)
                    info[m].append({"split": tag, "d": int(model.d_),
                                    "alpha": None if amfs is None else [round(float(a), 4) for a in amfs.alpha_],
                                    "iterations": None if amfs is None else int(amfs.n_iter_)})
        for m in methods:
            extra = {"n_db": int(len(splits[0][0])), "n_queries": int(len(splits[0][1])),
                     "n_clips": int(len(descs)), "skipped": skipped, "splits": info[m]}
            yield from _rows("amfs-retrieval", ds, cond, m, res[m], secs[m], extra)


# ----------------------------------------------------------------------- recognition
def _recognition(ctx: Context, name: str, splits: list[tuple[np.ndarray, np.ndarray, int]],
                 cond: str, confusion_png: str | None) -> Iterator[Row]:
    from ...recognition.classifier import SkeletonClassifier
    from ...recognition.nmc import NMCClassifier

    items, labels, _, skipped = _cached(ctx, "msr", "prep")
    P = [it[0] for it in items]
    Xc = np.stack([it[1] for it in items])
    quick = ctx.quick
    nmc_kw = dict(n_clusters=64, max_iter=60) if quick else {}
    nmc_kw.update(ctx.options.get("nmc", {}))
    acc: dict[str, list] = {"nmc": [], "nmc-inductive": [], "classifier": []}
    secs: dict[str, list] = {k: [] for k in acc}
    classes = np.unique(labels)
    conf = np.zeros((len(classes), len(classes)), int)
    for tr, te, seed in splits:
        ptr, pte = [P[i] for i in tr], [P[i] for i in te]
        with blas_limit():
            t0 = time.perf_counter()
            m = NMCClassifier(seed=seed, **nmc_kw).fit(ptr, labels[tr], test_seqs=pte)
            pred = m.predict()
            secs["nmc"].append(time.perf_counter() - t0)
            acc["nmc"].append(float((pred == labels[te]).mean()))
            ci = np.searchsorted(classes, labels[te])
            np.add.at(conf, (ci, np.searchsorted(classes, pred)), 1)
            t0 = time.perf_counter()
            m2 = NMCClassifier(seed=seed, transductive=False, **nmc_kw).fit(ptr, labels[tr])
            acc["nmc-inductive"].append(float((m2.predict(pte) == labels[te]).mean()))
            secs["nmc-inductive"].append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            c = SkeletonClassifier().fit_features(Xc[tr], labels[tr])
            acc["classifier"].append(float((c.predict_features(Xc[te]) == labels[te]).mean()))
            secs["classifier"].append(time.perf_counter() - t0)
    extra = {"n_train": int(len(splits[0][0])), "n_test": int(len(splits[0][1])),
             "n_clips": len(P), "skipped": skipped}
    for meth, v in acc.items():
        e = dict(extra, per_split=[round(x, 4) for x in v])
        if meth == "nmc":
            e["confusion"] = conf.tolist()
            e["classes"] = classes.tolist()
        yield from _rows(name, "msr-action3d", cond, meth, {"accuracy": v}, secs[meth], e,
                         {"accuracy": NMC_PAPER} if meth == "nmc" and name == "nmc-recognition" else None)
    if confusion_png:
        _plot_confusion(conf, classes, confusion_png, f"NMC on MSR-Action3D ({cond})")


def _plot_confusion(conf: np.ndarray, classes: np.ndarray, path: str, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [MSR_ACTIONS[int(c[1:]) - 1] if re.fullmatch(r"a\d\d", str(c)) else str(c) for c in classes]
    R = conf / np.maximum(conf.sum(axis=1, keepdims=True), 1)
    fig, ax = plt.subplots(figsize=(9, 8))
    ax.imshow(R, cmap="Blues", vmin=0, vmax=1)
    ax.set_xticks(range(len(names)), names, rotation=90, fontsize=7)
    ax.set_yticks(range(len(names)), names, fontsize=7)
    for i, j in zip(*np.nonzero(R >= 0.005)):
        ax.text(j, i, f"{R[i, j]:.2f}", ha="center", va="center", fontsize=5,
                color="white" if R[i, j] > 0.6 else "black")
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _figures_dir(ctx: Context) -> Path | None:
    if "figures_dir" in ctx.options:
        return Path(ctx.options["figures_dir"])
    if ctx.quick:
        return None
    return Path(__file__).resolve().parents[3] / "docs" / "results"


@protocol("nmc-recognition", "Thesis Sec. 6.3: NMF-based motion clustering + bag of words on "
          "MSR-Action3D, random half of each class for training; accuracy (paper 0.9333)")
def nmc_recognition(ctx: Context) -> Iterator[Row]:
    _, labels, _, _ = _cached(ctx, "msr", "prep")
    seeds = range(ctx.seed, ctx.seed + (1 if ctx.quick else int(ctx.options.get("seeds", 5))))
    splits = [(*_class_halves(labels, s), s) for s in seeds]
    fd = _figures_dir(ctx)
    yield from _recognition(ctx, "nmc-recognition", splits,
                            f"random half of each class ({len(splits)} seed{'s' if len(splits) > 1 else ''})",
                            None if fd is None else str(fd / "nmc_confusion.png"))


@protocol("recognition-cross-subject", "MSR-Action3D cross-subject split (odd subjects train, "
          "even test): NMC and the skeleton classifier, accuracy")
def recognition_cross_subject(ctx: Context) -> Iterator[Row]:
    _, labels, groups, _ = _cached(ctx, "msr", "prep")
    tr, te = np.flatnonzero(groups % 2 == 1), np.flatnonzero(groups % 2 == 0)
    seeds = range(ctx.seed, ctx.seed + (1 if ctx.quick else int(ctx.options.get("seeds", 3))))
    fd = _figures_dir(ctx)
    yield from _recognition(ctx, "recognition-cross-subject", [(tr, te, s) for s in seeds],
                            f"subjects 1,3,5,7,9 train / 2,4,6,8,10 test ({len(seeds)} NMF seed"
                            f"{'s' if len(seeds) > 1 else ''})",
                            None if fd is None else str(fd / "nmc_confusion_cross_subject.png"))


# ------------------------------------------------------- recognition: MiniRocket and co.
# Protocols ``recognition-msr-half``, ``recognition-msr-cross-subject`` and
# ``recognition-hdm05-cross-actor`` (benchmarks/run_recognition.py -> docs/results/recognition.md):
# MSR-Action3D restricted to the 557 sequences of ``files_used_in_cvpr12_paper.txt`` (the
# list the data set's authors used), HDM05 all 141 clips. Methods: ``minirocket`` (the
# default classifier, :class:`mocapkit.recognition.rocket.RocketClassifier`),
# (HDM05: the 140 cut clips of the 6 class folders; ``takes/`` holds one uncut take, no class),
# ``minirocket-heading-start`` (MSR only: heading normalised from the hips, the setting
# 'auto' replaces for Kinect files), ``classifier`` (HOD + pose statistics + logistic
# regression), ``nmc`` (thesis NMC, transductive, our defaults) and on the half split
# ``nmc-thesis-window`` (the thesis' stated windows: M = 60 frames, stride M/2 = 30).
# Rows: accuracy (fraction, mean +- std over splits / seeds) with the confusion matrix,
# the most frequent confusions and errors per test subject/actor in ``extra``; training
# seconds per training clip and inference milliseconds per test clip (features included,
# file reading excluded) as their own rows.
RECOG_PNG = {"recognition-msr-half": "recognition_confusion_msr_half.png",
             "recognition-msr-cross-subject": "recognition_confusion_msr_cross_subject.png",
             "recognition-hdm05-cross-actor": "recognition_confusion_hdm05.png"}


def _recog_data(ctx: Context, which: str) -> dict:
    """Clips, labels, groups and per-clip inputs of every recognition method (cached)."""
    from ...errors import MocapError
    from ...recognition.classifier import SMOOTH_S, sequence_features
    from ...recognition.rocket import series_keypoints, trajectories
    from ...retrieval.features import prepare

    key = ("recog", str(ctx.data_dir), which)
    if key in _CACHE:
        return _CACHE[key]
    root = ctx.need_data()
    keep = None
    if which == "msr":
        lst = root / "msr_action3d" / "files_used_in_cvpr12_paper.txt"
        keep = set(lst.read_text().split()) if lst.is_file() else None
    d: dict[str, list] = {k: [] for k in ("path", "label", "group", "series", "series_start", "prep", "feat")}
    t_series = t_feat = 0.0
    skipped = []
    for path, lab, grp, m in _motions(ctx, which):
        if keep is not None and Path(path).name[:11] not in keep:
            continue
        if which == "hdm" and Path(path).parent.name == "takes":     # an uncut take, not a class
            continue
        try:
            t0 = time.perf_counter()
            s = trajectories(m, 64)
            t_series += time.perf_counter() - t0
            ss = trajectories(m, 64, heading="start") if which == "msr" else None
            t0 = time.perf_counter()
            p = prepare(m, smooth_s=SMOOTH_S)
            f = sequence_features(p)
            t_feat += time.perf_counter() - t0
        except MocapError:
            skipped.append(path)
            continue
        for k, v in (("path", path), ("label", lab), ("group", grp), ("series", s), ("series_start", ss),
                     ("prep", p), ("feat", f)):
            d[k].append(v)
    n = len(d["path"])
    out = {"paths": d["path"], "labels": np.array(d["label"]), "groups": np.array(d["group"]),
           "X": np.stack(d["series"]), "X_start": None if which != "msr" else np.stack(d["series_start"]),
           "prep": d["prep"], "feat": np.stack(d["feat"]), "skipped": skipped,
           "s_series": t_series / n, "s_feat": t_feat / n, "list": None if keep is None else len(keep),
           "keypoints": series_keypoints(_motions(ctx, which)[0][3].skeleton)}
    _CACHE[key] = out
    return out


def _gkey(g: str):
    return (0, int(g), "") if str(g).isdigit() else (1, 0, str(g))


def _top_confusions(conf: np.ndarray, classes: np.ndarray, k: int = 8) -> list:
    C = conf.copy()
    np.fill_diagonal(C, 0)
    idx = np.dstack(np.unravel_index(np.argsort(-C, axis=None), C.shape))[0]
    return [[str(classes[i]), str(classes[j]), int(C[i, j])] for i, j in idx[:k] if C[i, j] > 0]


def _recognise(ctx: Context, name: str, which: str, splits: list, cond: str, methods: dict,
               paper: dict | None = None, figure: bool = True) -> Iterator[Row]:
    """Run ``methods`` ({name: (kind, params, seeds)}) over ``splits`` [(train, test, tag)];
    the confusion matrix of ``minirocket`` goes to ``RECOG_PNG[name]`` when ``figure``."""
    from ...recognition.classifier import SkeletonClassifier
    from ...recognition.nmc import NMCClassifier
    from ...recognition.rocket import RocketClassifier

    D = _recog_data(ctx, which)
    y, groups = D["labels"], D["groups"]
    classes = np.unique(y)
    for meth, (kind, params, seeds) in methods.items():
        acc, fit_s, tr_clip, inf_clip, tags = [], [], [], [], []
        conf = np.zeros((len(classes), len(classes)), int)
        err_by_group: dict[str, int] = {}
        for tr, te, tag in splits:
            for seed in seeds:
                with blas_limit():
                    t0 = time.perf_counter()
                    if kind == "rocket":
                        X = D["X_start"] if params.get("heading") == "start" else D["X"]
                        kw = {k: v for k, v in params.items() if k != "heading"}
                        m = RocketClassifier(seed=seed, **kw).fit_series(X[tr], y[tr], keypoints=D["keypoints"])
                        t_fit = time.perf_counter() - t0
                        t0 = time.perf_counter()
                        pred = m.predict_series(X[te])
                        t_inf = time.perf_counter() - t0
                        per_tr, per_te = D["s_series"], D["s_series"]
                    elif kind == "classifier":
                        m = SkeletonClassifier().fit_features(D["feat"][tr], y[tr])
                        t_fit = time.perf_counter() - t0
                        t0 = time.perf_counter()
                        pred = m.predict_features(D["feat"][te])
                        t_inf = time.perf_counter() - t0
                        per_tr, per_te = D["s_feat"], D["s_feat"]
                    else:                                  # nmc, transductive (thesis)
                        P = D["prep"]
                        m = NMCClassifier(seed=seed, **params).fit([P[i] for i in tr], y[tr],
                                                                   test_seqs=[P[i] for i in te])
                        pred = m.predict()
                        t_fit, t_inf = time.perf_counter() - t0, 0.0
                        per_tr, per_te = D["s_feat"], D["s_feat"]
                acc.append(float((pred == y[te]).mean()))
                fit_s.append(t_fit)
                tr_clip.append(t_fit / len(tr) + per_tr)
                inf_clip.append(1000.0 * (t_inf / len(te) + per_te))
                tags.append(f"{tag}, seed {seed}" if len(seeds) > 1 else str(tag))
                np.add.at(conf, (np.searchsorted(classes, y[te]), np.searchsorted(classes, pred)), 1)
                for g in groups[te][pred != y[te]]:
                    err_by_group[str(g)] = err_by_group.get(str(g), 0) + 1
        n_by_group: dict[str, int] = {}
        for tr, te, _ in splits:
            for g in groups[te]:
                n_by_group[str(g)] = n_by_group.get(str(g), 0) + len(seeds)
        extra = {"n_train": int(len(splits[0][0])), "n_test": int(len(splits[0][1])), "n_clips": int(len(y)),
                 "clip_list": D["list"], "skipped": D["skipped"], "params": dict(params),
                 "per_split": [round(a, 4) for a in acc], "splits": tags, "confusion": conf.tolist(),
                 "classes": classes.tolist(), "top_confusions": _top_confusions(conf, classes),
                 "errors_by_group": dict(sorted(err_by_group.items(), key=lambda kv: _gkey(kv[0]))),
                 "tested_by_group": dict(sorted(n_by_group.items(), key=lambda kv: _gkey(kv[0]))),
                 "nmc_inference": "transductive: test clips join the clustering" if kind == "nmc" else None}
        yield from _rows(name, which if which != "msr" else "msr-action3d", cond, meth, {"accuracy": acc},
                         fit_s, extra, (paper or {}).get(meth))
        for metric, unit, v in (("train_s_per_clip", "s", tr_clip), ("inference_ms_per_clip", "ms", inf_clip)):
            v = np.asarray(v)
            yield Row(name, which if which != "msr" else "msr-action3d", cond, meth, metric, unit, float(v.mean()),
                      std=float(v.std()) if len(v) > 1 else None, n=len(v))
        fd = _figures_dir(ctx)
        if meth == "minirocket" and fd is not None and figure:
            _plot_confusion(conf, classes, str(fd / RECOG_PNG[name]),
                            f"MiniRocket, {which if which != 'msr' else 'MSR-Action3D'} ({cond})")


def _recog_methods(ctx: Context, which: str, extra: dict | None = None, rocket_seeds=(0,),
                   nmc_seeds=(0,)) -> dict:
    quick = ctx.quick
    rk = {"n_features": 2000} if quick else {}
    nmc = dict(n_clusters=64, max_iter=60) if quick else {}
    out = {"minirocket": ("rocket", dict(rk), tuple(rocket_seeds))}
    if which == "msr" and not quick:
        out["minirocket-heading-start"] = ("rocket", dict(rk, heading="start"), tuple(rocket_seeds))
    out["classifier"] = ("classifier", {}, (0,))
    out["nmc"] = ("nmc", nmc, tuple(nmc_seeds))
    out.update(extra or {})
    only = ctx.options.get("methods")
    return {k: v for k, v in out.items() if not only or k in only}


@protocol("recognition-msr-half", "MSR-Action3D (557 clips of the authors' list), random half of each "
          "class for training (thesis protocol, 5 seeds): MiniRocket (default), skeleton classifier, NMC")
def recognition_msr_half(ctx: Context) -> Iterator[Row]:
    D = _recog_data(ctx, "msr")
    seeds = range(ctx.seed, ctx.seed + (1 if ctx.quick else int(ctx.options.get("seeds", 5))))
    splits = [(*_class_halves(D["labels"], s), f"split {s}") for s in seeds]
    extra = {} if ctx.quick else {"nmc-thesis-window": ("nmc", dict(window=60, stride=30), (0,))}
    yield from _recognise(ctx, "recognition-msr-half", "msr", splits,
                          f"random half of each class ({len(splits)} split{'s' if len(splits) > 1 else ''})",
                          _recog_methods(ctx, "msr", extra), {"nmc": {"accuracy": NMC_PAPER},
                                                              "nmc-thesis-window": {"accuracy": NMC_PAPER}})


@protocol("recognition-msr-cross-subject", "MSR-Action3D (557 clips) cross-subject: subjects 1,3,5,7,9 "
          "train, 2,4,6,8,10 test; MiniRocket over 3 transform seeds, skeleton classifier, NMC")
def recognition_msr_cross_subject(ctx: Context) -> Iterator[Row]:
    D = _recog_data(ctx, "msr")
    g = D["groups"]
    splits = [(np.flatnonzero(g % 2 == 1), np.flatnonzero(g % 2 == 0), "odd/even subjects")]
    n = 1 if ctx.quick else int(ctx.options.get("seeds", 3))
    seeds = tuple(range(ctx.seed, ctx.seed + n))
    yield from _recognise(ctx, "recognition-msr-cross-subject", "msr", splits,
                          f"subjects 1,3,5,7,9 train / 2,4,6,8,10 test ({n} seed{'s' if n > 1 else ''})",
                          _recog_methods(ctx, "msr", rocket_seeds=seeds, nmc_seeds=seeds))


@protocol("recognition-hdm05-cross-actor", "HDM05 (140 cut clips, 6 classes, 5 actors) cross-actor: "
          "leave one actor out (5 folds) and 2 actors train / 3 test (10 pairs)")
def recognition_hdm05_cross_actor(ctx: Context) -> Iterator[Row]:
    D = _recog_data(ctx, "hdm")
    g = D["groups"]
    actors = sorted(set(g.tolist()))
    loao = [(np.flatnonzero(g != a), np.flatnonzero(g == a), f"test {a}") for a in actors]
    pairs = [(np.flatnonzero(np.isin(g, p)), np.flatnonzero(~np.isin(g, p)), "train " + "+".join(p))
             for p in itertools.combinations(actors, 2)]
    if ctx.quick:
        loao, pairs = loao[:1], pairs[:1]
    meths = _recog_methods(ctx, "hdm")
    yield from _recognise(ctx, "recognition-hdm05-cross-actor", "hdm", loao,
                          f"leave one actor out ({len(loao)} folds)", meths)
    yield from _recognise(ctx, "recognition-hdm05-cross-actor", "hdm", pairs,
                          f"2 actors train / 3 test ({len(pairs)} pair{'s' if len(pairs) > 1 else ''})", meths,
                          figure=False)
