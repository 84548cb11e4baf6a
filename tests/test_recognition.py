"""Recognition: graph-regularised orthogonal NMF (thesis Algorithm 6), NMC bag of words,
the skeleton classifier, and the CLI commands index/search/classify."""
from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse as sp

from mocapkit import cli
from mocapkit.errors import MocapFormatError, MocapValueError, NotFittedError
from mocapkit.recognition.classifier import SkeletonClassifier
from mocapkit.recognition.nmc import (NMCClassifier, encode_windows, gonmf, knn_graph,
                                      nmf_objective)


def _planted(rng, k=4, d=30, per=25, noise=0.02):
    """Columns drawn around k non-negative prototypes with disjoint supports."""
    P = np.zeros((d, k))
    for j, block in enumerate(np.array_split(np.arange(d), k)):
        P[block, j] = rng.uniform(0.5, 1.5, len(block))
    truth = np.repeat(np.arange(k), per)
    X = P[:, truth] * rng.uniform(0.7, 1.3, len(truth)) + noise * rng.random((d, len(truth)))
    return X, truth, P


def test_objective_graph_term_equals_trace_with_dense_laplacian(rng):
    X, _, _ = _planted(rng)
    Z, G = rng.random((X.shape[0], 3)), rng.random((3, X.shape[1]))
    W = knn_graph(X.T, k=4)
    Wd = W.toarray()
    L = np.diag(Wd.sum(1)) - Wd
    ref = np.linalg.norm(X - Z @ G) ** 2 + 0.3 * (G ** 2).sum() + 0.7 * np.trace(G @ L @ G.T)
    assert nmf_objective(X, Z, G, W, 0.3, 0.7) == pytest.approx(ref, rel=1e-10)


def test_knn_graph_is_symmetric_non_negative_without_self_loops(rng):
    W = knn_graph(rng.random((40, 5)), k=3)
    Wd = W.toarray()
    assert np.allclose(Wd, Wd.T) and (Wd >= 0).all() and np.all(np.diag(Wd) == 0)
    assert ((Wd > 0).sum(1) >= 3).all()          # every sample keeps its k neighbours


def test_graph_nmf_lee_seung_updates_are_monotone(rng):
    # eta = 1 without the orthogonal Z step is Cai et al.'s GNMF: objective non-increasing
    X, _, _ = _planted(rng)
    W = knn_graph(X.T, k=5)
    _, _, hist = gonmf(X, 4, W=W, lam1=0.1, lam2=0.5, orthogonal=False, eta=1.0,
                       init="random", max_iter=80, tol=0, return_history=True)
    h = np.asarray(hist)
    assert len(h) == 81
    assert np.all(np.diff(h) <= 1e-9 * h[0])
    assert h[-1] < 0.2 * h[0]


def test_orthogonal_nmf_recovers_planted_clusters(rng):
    from sklearn.metrics import adjusted_rand_score

    X, truth, _ = _planted(rng)
    W = knn_graph(X.T, k=5)
    Z, G, hist = gonmf(X, 4, W=W, lam1=1e-3, lam2=1e-2, max_iter=100, return_history=True)
    assert (Z >= 0).all() and (G >= 0).all()
    assert np.allclose(np.linalg.norm(Z, axis=0), 1.0)          # Algorithm 6 step 4
    ZtZ = Z.T @ Z
    assert np.abs(ZtZ - np.diag(np.diag(ZtZ))).max() < 0.05       # near-orthogonal columns
    assert adjusted_rand_score(truth, G.argmax(0)) == pytest.approx(1.0)
    assert hist[-1] < 0.05 * hist[0]


def test_encode_windows_recovers_coefficients_for_fixed_basis(rng):
    X, truth, P = _planted(rng, noise=0.0)
    Z = P / np.linalg.norm(P, axis=0)
    G_true = np.linalg.lstsq(Z, X, rcond=None)[0]
    G = encode_windows(X, Z, n_iter=300)
    assert np.allclose(G, G_true, atol=1e-3 * G_true.max())


def test_gonmf_rejects_bad_input():
    with pytest.raises(MocapValueError, match="non-negative"):
        gonmf(-np.ones((3, 4)), 2)
    with pytest.raises(MocapValueError, match="n_components"):
        gonmf(np.ones((3, 4)), 9)


# ------------------------------------------------------------------------ real skeletons
CLASSES = ("a01", "a13", "a16")          # high arm wave, bend, jogging: clearly different


def _msr(shared_data, classes=CLASSES):
    from mocapkit import io

    root = shared_data / "msr_action3d" / "skeleton3d"
    tr, te = [], []
    for c in classes:
        for f in sorted(root.glob(f"{c}_s*_e0[12]_skeleton3D.txt")):
            if f.name == "a13_s09_e02_skeleton3D.txt":        # no tracked frame in the data
                continue
            subj = int(f.name[5:7])
            (tr if subj <= 6 else te).append((io.read(f), c, f))
    return tr, te


@pytest.mark.shared_data
def test_nmc_and_classifier_recognise_distinct_actions_of_unseen_subjects(shared_data):
    tr, te = _msr(shared_data)
    assert len(tr) >= 24 and len(te) >= 12
    ytr = np.array([c for _, c, _ in tr])
    yte = np.array([c for _, c, _ in te])
    nmc = NMCClassifier(n_clusters=24, max_iter=40).fit([m for m, _, _ in tr], ytr,
                                                        test_seqs=[m for m, _, _ in te])
    assert (nmc.predict() == yte).mean() >= 0.8
    ind = NMCClassifier(n_clusters=24, max_iter=40, transductive=False).fit([m for m, _, _ in tr], ytr)
    assert (ind.predict([m for m, _, _ in te]) == yte).mean() >= 0.8
    clf = SkeletonClassifier().fit([m for m, _, _ in tr], ytr)
    pred = [clf.predict(m) for m, _, _ in te]
    assert np.mean([p == c for (p, _), c in zip(pred, yte)]) >= 0.8
    assert all(1 / 3 <= conf <= 1 for _, conf in pred)


def test_classifier_save_load_round_trip_and_errors(rng, tmp_path):
    X = np.vstack([rng.normal(0, 1, (20, 6)), rng.normal(2, 1, (20, 6)), rng.normal(-2, 1, (20, 6))])
    y = np.repeat(["walk", "run", "jump"], 20)
    with pytest.raises(NotFittedError):
        SkeletonClassifier().predict_features(X)
    clf = SkeletonClassifier(C=0.5).fit_features(X, y)
    P = clf.predict_proba_features(X)
    assert np.allclose(P.sum(1), 1) and (clf.predict_features(X) == y).mean() > 0.9
    # our softmax equals scikit-learn's probabilities
    from sklearn.linear_model import LogisticRegression

    lr = LogisticRegression(C=0.5, max_iter=3000).fit((X - X.mean(0)) / X.std(0), y)
    ref = lr.predict_proba((X - X.mean(0)) / X.std(0))
    assert np.allclose(P, ref[:, np.searchsorted(lr.classes_, clf.classes_)], atol=1e-6)
    path = clf.save(tmp_path / "m.npz")
    with pytest.raises(MocapValueError, match="exists"):
        clf.save(path)
    back = SkeletonClassifier.load(path)
    assert back.C == 0.5 and np.allclose(back.predict_proba_features(X), P)
    with pytest.raises(MocapValueError, match="model expects 6"):
        back.predict_features(X[:, :4])
    bad = tmp_path / "bad.npz"
    bad.write_text("no")
    with pytest.raises(MocapFormatError, match="bad.npz"):
        SkeletonClassifier.load(bad)
    other = tmp_path / "other.npz"
    np.savez(other, header=np.array(json.dumps({"format": "something", "version": 1})))
    with pytest.raises(MocapFormatError, match="not a mocapkit classifier"):
        SkeletonClassifier.load(other)


# ------------------------------------------------------------------------------- CLI
@pytest.mark.shared_data
def test_cli_index_search_classify(shared_data, tmp_path, capsys):
    root = shared_data / "msr_action3d" / "skeleton3d"
    lib = tmp_path / "lib"
    lib.mkdir()
    for c in CLASSES:
        for f in sorted(root.glob(f"{c}_s0[1-4]_e01_skeleton3D.txt")):
            (lib / f.name).symlink_to(f)
    query = next(root.glob("a16_s08_e01_skeleton3D.txt"))
    idx = tmp_path / "lib.idx"
    assert cli.main(["index", "build", str(lib), "-o", str(idx), "--words", "16", "-q"]) == 0
    n = len(list(lib.iterdir()))
    assert n >= 10 and f"{n} clips" in capsys.readouterr().out
    assert cli.main(["search", str(idx), str(query), "-k", "3", "-q"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split()[:3] == ["rank", "distance", "label"] and len(out) == 4
    assert cli.main(["search", str(idx), str(query), "-k", str(n), "--json", "-q"]) == 0
    hits = json.loads(capsys.readouterr().out)
    assert [h["rank"] for h in hits] == list(range(1, n + 1))
    assert sorted(h["distance"] for h in hits) == [h["distance"] for h in hits]
    assert sum("a16_" in h["path"] for h in hits[:4]) >= 3        # jogging finds jogging

    model = tmp_path / "m.npz"
    assert cli.main(["classify", "train", str(lib), "-o", str(model), "-q"]) == 0
    assert "3 classes" in capsys.readouterr().out
    assert cli.main(["classify", str(model), str(query), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["label"] == "a16" and 0 < res["confidence"] <= 1

    # errors: one line, exit 2, nothing written
    assert cli.main(["index", "build", str(lib), "-o", str(idx), "-q"]) == 2
    assert "exists" in capsys.readouterr().err
    assert cli.main(["search", str(model), str(query)]) == 2
    err = capsys.readouterr().err
    assert "not a mocapkit index" in err and len(err.strip().splitlines()) == 1
    assert cli.main(["classify", str(idx), str(query)]) == 2
    assert "classifier" in capsys.readouterr().err
    assert cli.main(["classify", "train", str(lib)]) == 2
    assert "-o" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli.main(["index", "build", str(empty), "-o", str(tmp_path / "e.idx"), "-q"]) == 2
    assert "no motion files" in capsys.readouterr().err
    assert not (tmp_path / "e.idx").exists()
