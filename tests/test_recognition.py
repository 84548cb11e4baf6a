"""Recognition: graph-regularised orthogonal NMF (thesis Algorithm 6), NMC bag of words,
the skeleton classifier, and the CLI commands index/search/classify."""
from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse as sp

from conftest import kinect_skeleton
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


# ----------------------------------------------------------------- MiniRocket classifier
from mocapkit.motion import Motion  # noqa: E402
from mocapkit.recognition import rocket as rk  # noqa: E402
from mocapkit.recognition import load_model, train_classifier  # noqa: E402
from mocapkit.skeleton import Skeleton  # noqa: E402


def _reference_conv(x: np.ndarray, weights: np.ndarray, dilation: int, pad: bool) -> np.ndarray:
    """Direct (loop) dilated convolution of one channel-summed series x (C, L)."""
    C, L = x.shape
    h = 4 * dilation
    out = []
    for t in range(L):
        s = 0.0
        for k in range(9):
            i = t + (k - 4) * dilation
            if 0 <= i < L:
                s += weights[k] * x[:, i].sum()
        out.append(s)
    out = np.array(out)
    return out if pad else out[h:L - h]


def test_fit_dilations_and_quantiles_match_the_paper():
    d, nf = rk.fit_dilations(9)                       # max exponent 0: one dilation
    assert d.tolist() == [1] and nf.tolist() == [119]
    d, nf = rk.fit_dilations(64)
    assert nf.sum() == 119 and d[0] == 1 and d[-1] == 7 and np.all(np.diff(d) > 0)
    q = rk.golden_quantiles(3)
    assert np.allclose(q, [0.6180339887, 0.2360679775, 0.8541019662])
    assert rk.KERNEL_INDICES.shape == (84, 3) and len({tuple(r) for r in rk.KERNEL_INDICES}) == 84


def test_minirocket_features_equal_a_direct_convolution(rng):
    X = rng.normal(size=(3, 4, 40))
    m = rk.MiniRocket(n_features=84 * 6, seed=3).fit(X)
    F = m.transform(X)
    assert F.shape == (3, m.n_features_out) and m.n_features_out == 84 * 6
    col, b0 = 0, 0
    for di, (d, f) in enumerate(zip(m.dilations_, m.features_per_dilation_)):
        for k in (0, 1, 41, 83):
            w = -np.ones(9)
            w[rk.KERNEL_INDICES[k]] = 2.0
            ch = m.masks_[di * 84 + k] > 0
            pad = (k + di) % 2 == 0
            b = m.biases_[b0 + k * f:b0 + (k + 1) * f]
            for n in range(3):
                c = _reference_conv(X[n][ch], w, int(d), pad)
                ref = (c[:, None] > b[None, :]).mean(0)
                assert np.allclose(F[n, col + k * f:col + (k + 1) * f], ref)
        col += 84 * f
        b0 += 84 * f
    # biases are quantiles of one training example's padded output: PPV spans (0, 1)
    assert 0.2 < F.mean() < 0.8


def test_multirocket_poolings_equal_loops(rng):
    Cv = rng.normal(size=(2, 15, 3))
    b = rng.normal(scale=0.5, size=(3, 2))
    P = rk._pool(Cv, b, rk.POOLINGS)
    for n in range(2):
        for k in range(3):
            for j in range(2):
                z = Cv[n, :, k] - b[k, j]
                pos = z > 0
                run = best = 0
                for v in pos:
                    run = run + 1 if v else 0
                    best = max(best, run)
                ref = [pos.mean(), z[pos].mean() if pos.any() else 0.0,
                       np.flatnonzero(pos).mean() / 14 if pos.any() else -1.0, best / 15]
                assert np.allclose(P[n, k, j], ref)
    with pytest.raises(MocapValueError, match="unknown pooling"):
        rk._pool(Cv, b, ("max",))


def test_pyramid_poolings_are_the_halves_ppv(rng):
    Cv = rng.normal(size=(2, 15, 3))                  # odd length: halves of 7 and 8
    b = rng.normal(scale=0.5, size=(3, 2))
    P = rk._pool(Cv, b, ("ppv_h1", "ppv_h2"))
    pos = (Cv[:, :, :, None] - b[None, None]) > 0
    assert np.allclose(P[..., 0], pos[:, :7].mean(axis=1))
    assert np.allclose(P[..., 1], pos[:, 7:].mean(axis=1))
    assert "ppv_h1" not in rk.POOLINGS                # offered, not in the default


def _toy_skeleton(names=("root", "spine", "head", "hand_a", "hand_b")) -> Skeleton:
    J = len(names)
    parents = np.array([-1] + [0] * (J - 1))
    offsets = np.vstack([np.zeros(3), np.tile([0.0, 30.0, 0.0], (J - 1, 1))])
    offsets[1:, 0] = np.arange(1, J) * 5.0
    return Skeleton(names, parents, offsets)


def _toy_motions(rng, n_per=8, skeleton=None):
    """Three classes of synthetic 5-joint motions: hand_a waving sideways, hand_a waving up
    and down, hand_b circling; random speed, phase, amplitude, length and noise (cm)."""
    sk = skeleton or _toy_skeleton()
    rest = sk.rest_positions()
    out, y = [], []
    for c in range(3):
        for _ in range(n_per):
            T = int(rng.integers(40, 80))
            t = np.arange(T) / 30.0
            f, ph, a = rng.uniform(0.8, 1.5), rng.uniform(0, 2 * np.pi), rng.uniform(15, 25)
            P = np.repeat(rest[None], T, axis=0) + rng.normal(0, 0.5, (T, sk.n_joints, 3))
            s = a * np.sin(2 * np.pi * f * t + ph)
            if c == 0:
                P[:, 3, 0] += s
            elif c == 1:
                P[:, 3, 1] += s
            else:
                P[:, 4, 0] += s
                P[:, 4, 2] += a * np.cos(2 * np.pi * f * t + ph)
            P += [rng.uniform(-50, 50), 0, rng.uniform(200, 300)]    # anywhere in the room
            out.append(Motion(P, sk, 30.0))
            y.append(["wave", "nod", "circle"][c])
    return out, np.array(y)


def test_rocket_separates_three_synthetic_classes_and_is_deterministic(rng):
    tr, ytr = _toy_motions(rng)
    te, yte = _toy_motions(rng, n_per=6)
    a = rk.RocketClassifier(n_features=500, seed=1).fit(tr, ytr)
    b = rk.RocketClassifier(n_features=500, seed=1).fit(tr, ytr)
    assert (a.predict_many(te) == yte).all()
    Xte = np.stack([a.series(m) for m in te])
    assert Xte.shape == (18, 15, 64)
    assert np.array_equal(a.decision_series(Xte), b.decision_series(Xte))    # same seed, same model
    c = rk.RocketClassifier(n_features=500, seed=2, augment=0).fit(tr, ytr)
    assert not np.array_equal(a.rockets_[0].biases_, c.rockets_[0].biases_)  # the seed matters
    label, conf = a.predict(te[0])
    assert label == yte[0] and 1 / 3 < conf <= 1
    P = a.predict_proba_series(Xte)
    assert np.allclose(P.sum(1), 1) and (a.classes_[P.argmax(1)] == yte).all()


def test_trajectories_are_body_centred_and_size_normalised(rng):
    ms, _ = _toy_motions(rng, n_per=1)
    m = ms[0]
    X = rk.trajectories(m, 32)
    big = Motion(m.positions * 1.7 + [100.0, 0.0, -40.0], m.skeleton, m.fps)   # bigger, elsewhere
    assert np.allclose(rk.trajectories(big, 32), X, atol=1e-9)
    assert np.allclose(X[:3, 0], 0.0)             # the root starts at the origin
    with pytest.raises(MocapValueError, match="length"):
        rk.trajectories(m, 5)


def test_rocket_save_load_round_trip_and_joint_set_error(rng, tmp_path):
    tr, ytr = _toy_motions(rng)
    te, _ = _toy_motions(rng, n_per=3)
    m = rk.RocketClassifier(n_features=300, seed=0, n_seeds=2).fit(tr, ytr)
    assert len(m.rockets_) == 4 and len(m.hydras_) == 4              # toy skeleton: joints view only
    assert m.coef_.shape[1] == 4 * m.rockets_[0].n_features_out + 4 * m.hydras_[0].n_features_out
    path = m.save(tmp_path / "r.npz")
    back = load_model(path)
    assert isinstance(back, rk.RocketClassifier) and back.params() == m.params()
    X = np.stack([m.series(x) for x in te])
    assert np.array_equal(back.decision_series(X), m.decision_series(X))
    assert [back.predict(x) for x in te] == [m.predict(x) for x in te]
    assert isinstance(SkeletonClassifier.load(path), rk.RocketClassifier)    # the CLI's loader
    other = _toy_skeleton(("root", "spine", "head", "lhand", "rhand"))
    alien = Motion(te[0].positions, other, 30.0)
    with pytest.raises(MocapValueError, match=r"trained on a 5-joint skeleton \(root, spine, head, hand_a"):
        back.predict(alien)
    six = _toy_skeleton(("root", "spine", "head", "hand_a", "hand_b", "tail"))
    with pytest.raises(MocapValueError, match="this motion has 6 joints"):
        back.predict(Motion(np.concatenate([te[0].positions, te[0].positions[:, :1]], 1), six, 30.0))
    with pytest.raises(MocapValueError, match="different joint sets"):
        rk.RocketClassifier(n_features=500).fit(tr[:3] + [alien], ["a", "b", "c", "a"])
    with pytest.raises(NotFittedError):
        rk.RocketClassifier().predict(te[0])


def test_nmc_model_save_load_round_trip(rng, tmp_path):
    tr, ytr = _toy_motions(rng, n_per=6)
    te, _ = _toy_motions(rng, n_per=2)
    m = NMCClassifier(n_clusters=12, max_iter=30, transductive=False).fit(tr, ytr)
    back = load_model(m.save(tmp_path / "n.npz"))
    assert isinstance(back, NMCClassifier)
    assert np.array_equal(back.predict(te), m.predict(te))
    lab, conf = back.predict(te[0])
    assert lab == m.predict([te[0]])[0] and 0 < conf <= 1
    # the stored arrays reproduce scikit-learn's pipeline
    ref = m._classifier().fit(m.bags(tr), ytr)
    assert np.allclose(m._proba(m.bags(te)), ref.predict_proba(m.bags(te)), atol=1e-8)
    with pytest.raises(MocapValueError, match="joint"):
        back.predict(Motion(te[0].positions, _toy_skeleton(("a", "b", "c", "d", "e")), 30.0))


@pytest.mark.shared_data
def test_train_classifier_on_hdm05_and_mismatch_with_kinect_model(shared_data, tmp_path, capsys):
    """MiniRocket (the default) on HDM05 ASF/AMC; a Kinect-trained model refuses an AMC clip."""
    root = shared_data / "hdm05" / "asfamc"
    lib = tmp_path / "hdm"
    for cls in ("hopBothLegs1hops", "rotateArmsBothBackward1Reps", "kickLFront1Reps"):
        (lib / cls).mkdir(parents=True)
        for f in sorted((root / cls).glob("HDM_bd_*.amc"))[:3] + sorted((root / cls).glob("HDM_mm_*.amc"))[:2]:
            (lib / cls / f.name).symlink_to(f)
    for asf in root.glob("*.asf"):
        for cls in lib.iterdir():
            (cls / asf.name).symlink_to(asf)
    res = train_classifier(lib, tmp_path / "h.npz", progress=False, n_features=500)   # default method, smaller
    assert res["method"] == "minirocket" and res["n_train"] == 15 and res["train_accuracy"] == 1.0
    test = sorted((root / "kickLFront1Reps").glob("HDM_dg_*.amc"))[0]
    assert cli.main(["classify", str(tmp_path / "h.npz"), str(test), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["label"] == "kickLFront1Reps"
    msr = shared_data / "msr_action3d" / "skeleton3d"
    kin = tmp_path / "kin"
    kin.mkdir()
    for f in sorted(msr.glob("a0[12]_s0[12]_e01_skeleton3D.txt")):
        (kin / f.name).symlink_to(f)
    train_classifier(kin, tmp_path / "k.npz", progress=False, n_features=300, augment=0)
    assert cli.main(["classify", str(tmp_path / "k.npz"), str(test)]) == 2
    err = capsys.readouterr().err
    assert "20-joint skeleton" in err and "31 joints" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("method", ["skeleton", "nmc"])
def test_cli_classify_train_each_method(method, shared_data, tmp_path, capsys):
    """Every classifier the CLI offers trains and predicts end to end (the skeleton path
    once failed with a NameError)."""
    from mocapkit.cli import main

    root = shared_data / "hdm05" / "asfamc"
    picked = tmp_path / "train"
    for cls in ("hopBothLegs1hops", "kickLFront1Reps"):
        (picked / cls).mkdir(parents=True)
        for f in sorted((root / cls).glob("*.amc"))[:4]:
            (picked / cls / f.name).symlink_to(f)
        for a in sorted(root.glob("*.asf")):
            if not (picked / cls / a.name).exists():
                (picked / cls / a.name).symlink_to(a)
    model = tmp_path / "m.npz"
    assert main(["classify", "train", str(picked), "-o", str(model), "--method", method, "-q"]) == 0
    capsys.readouterr()
    probe = sorted((root / "kickLFront1Reps").glob("*.amc"))[-1]
    assert main(["classify", str(model), str(probe)]) == 0
    from mocapkit.retrieval.index import label_of

    assert capsys.readouterr().out.strip().split("\t")[0] == label_of(probe)


def test_ridge_group_loo_equals_refitting_without_each_group(rng):
    """The closed-form leave-one-group-out scores equal explicit refits (with intercept)."""
    n, p = 41, 120
    Z = rng.normal(size=(n, p))
    Z -= Z.mean(0)
    Y = np.where(rng.integers(0, 3, n)[:, None] == np.arange(3)[None], 1.0, -1.0)
    groups = rng.integers(0, 15, n)                 # groups of unequal sizes
    alphas = [0.5, 20.0, 1e4]
    a, A, S = rk.ridge_group_loo(Z, Y, groups, alphas)
    errs = {}
    for al in alphas:
        Sb = np.empty_like(Y)
        for g in np.unique(groups):
            m = groups != g
            mu, ym = Z[m].mean(0), Y[m].mean(0)
            W = np.linalg.solve((Z[m] - mu).T @ (Z[m] - mu) + al * np.eye(p), (Z[m] - mu).T @ (Y[m] - ym))
            Sb[~m] = (Z[~m] - mu) @ W + ym
        errs[al] = ((Y - Sb) ** 2).mean()
        if al == a:
            assert np.allclose(S, Sb, atol=1e-9)
    assert a == min(errs, key=errs.get)
    Wfull = np.linalg.solve(Z.T @ Z + a * np.eye(p), Z.T @ (Y - Y.mean(0)))
    assert np.allclose(Z.T @ A, Wfull, atol=1e-9)


def test_augment_series_rotates_about_the_vertical_and_warps_time(rng):
    X = rng.normal(size=(3, 6, 20))                 # 2 joints x (x, y, z)
    Xa, owner = rk.augment_series(X, 4, rng, time_warp=0.0, rot_deg=30.0)
    assert Xa.shape == (12, 6, 20) and owner.tolist() == [0] * 4 + [1] * 4 + [2] * 4
    J, Ja = X.reshape(3, 2, 3, 20)[owner], Xa.reshape(12, 2, 3, 20)
    assert np.allclose(Ja[:, :, 1], J[:, :, 1])      # heights unchanged
    assert np.allclose(np.hypot(Ja[:, :, 0], Ja[:, :, 2]), np.hypot(J[:, :, 0], J[:, :, 2]))
    ang = np.arctan2(Ja[:, :, 2], Ja[:, :, 0]) - np.arctan2(J[:, :, 2], J[:, :, 0])
    ang = (ang + np.pi) % (2 * np.pi) - np.pi
    assert np.allclose(ang, ang[:, :1, :1], atol=1e-9) and np.abs(ang).max() <= np.deg2rad(30) + 1e-9
    same, _ = rk.augment_series(X, 2, rng, time_warp=0.0, rot_deg=0.0)
    assert np.allclose(same, X[[0, 0, 1, 1, 2, 2]])  # no warp, no turn: copies
    ramp = np.tile(np.linspace(0.0, 1.0, 20), (1, 5, 1))   # 5 channels: no rotation layout
    W, _ = rk.augment_series(ramp, 50, rng, time_warp=0.1, rot_deg=30.0)
    assert np.all(np.diff(W, axis=2) >= -1e-12)      # a time warp keeps a ramp monotone
    assert np.allclose(W, W[:, :1])                  # the same warp on every channel
    assert 0.0 <= W[:, 0, 0].min() and W[:, 0, 0].max() <= 0.1 + 1e-12
    assert 0.9 - 1e-12 <= W[:, 0, -1].min() and W[:, 0, -1].max() <= 1.0
    assert np.abs(W - ramp).max() > 0.05             # ... and it does warp
    assert rk.augment_series(X, 0, rng)[0].shape == (0, 6, 20)


def test_version_1_rocket_model_files_still_load(rng, tmp_path):
    """A v1 file (MiniRocket PPV, no augmentation, no n_seeds in its parameters) keeps
    predicting; an unknown version is refused with a clear error."""
    tr, ytr = _toy_motions(rng, n_per=5)
    te, _ = _toy_motions(rng, n_per=2)
    m = rk.RocketClassifier(n_features=300, pooling=("ppv",), augment=0, seed=0).fit(tr, ytr)
    path = m.save(tmp_path / "v2.npz")
    with np.load(path) as z:
        st = {k: z[k] for k in z.files}
    head = json.loads(str(st["header"]))
    for k in ("augment", "time_warp", "rot_deg", "n_seeds"):
        del head["params"][k]
    X = np.stack([m.series(x) for x in te])
    for version, ok in ((1, True), (7, False)):
        head["version"] = version
        st["header"] = np.array(json.dumps(head))
        p = tmp_path / f"v{version}.npz"
        np.savez(p, **st)
        if ok:
            back = load_model(p)
            assert back.n_seeds == 1 and back.augment == 0
            assert np.array_equal(back.decision_series(X), m.decision_series(X))
        else:
            with pytest.raises(MocapFormatError, match="v7 is not supported"):
                load_model(p)


def test_hydra_counts_equal_loops(rng):
    """HYDRA's soft max / hard min counts equal explicit loops over time, group and kernel."""
    X = rng.normal(size=(3, 4, 20))
    h = rk.Hydra(k=3, g=2, max_channels=2, seed=5).fit(X)
    assert h.dilations_.tolist() == [1, 2]          # floor(log2(19 / 8)) = 1
    F = h.transform(X)
    assert F.shape == (3, h.n_features_out) == (3, 2 * 2 * 2 * 3)
    ref = []
    for x in X:
        row = []
        for d, W in zip(h.dilations_, h.weights_):  # W (9, C, g k)
            pad = 4 * d
            xp = np.pad(x, ((0, 0), (pad, pad)))
            Z = np.array([[sum(W[t, c, j] * xp[c, i + t * d] for t in range(9) for c in range(4))
                           for j in range(6)] for i in range(20)])          # (L, g k)
            cmax, cmin = np.zeros(6), np.zeros(6)
            for i in range(20):
                for gi in range(2):
                    z = Z[i, 3 * gi:3 * gi + 3]
                    cmax[3 * gi + np.argmax(z)] += z.max()
                    cmin[3 * gi + np.argmin(z)] += 1
            row += [*cmax, *cmin]
        ref.append(row)
    assert np.allclose(F, np.sqrt(np.maximum(np.array(ref), 0)), atol=1e-10)
    assert ((np.abs(h.weights_).sum(1) > 0).sum(1) == 2).all()    # each group reads 2 channels
    assert np.allclose(np.abs(h.weights_).sum(1)[h.weights_.any(1)], 1.0)   # |w| sums to 1 per channel
    with pytest.raises(MocapValueError, match="shape"):
        h.transform(X[:, :3])


def test_arm_view_is_shoulder_relative_and_arm_length_normalised(rng):
    X = rng.normal(size=(2, 24, 16))                # 8 joints, joint-major x, y, z
    kp = np.array([1, 2, 3, 4, 5, 6, 7])            # head, l shoulder/elbow/wrist, r shoulder/elbow/wrist
    V = rk.arm_view(X, kp)
    assert V.shape == (2, 18, 16)
    J = X.reshape(2, 8, 3, 16)
    arm = np.median(np.linalg.norm(J[:, 3] - J[:, 2], axis=1) + np.linalg.norm(J[:, 4] - J[:, 3], axis=1), axis=1)
    assert np.allclose(V[:, 3:6], (J[:, 4] - J[:, 2]) / arm[:, None, None])     # left wrist - shoulder
    assert np.allclose(V[:, 15:18], (J[:, 7] - J[:, 1]) / np.median(
        np.linalg.norm(J[:, 6] - J[:, 5], axis=1) + np.linalg.norm(J[:, 7] - J[:, 6], axis=1), axis=1)[:, None, None])
    moved = (J * 2.5 + rng.normal(size=(1, 1, 3, 1))).reshape(2, 24, 16)  # bigger body elsewhere
    assert np.allclose(rk.arm_view(moved, kp), V)


def test_rocket_views_and_hydra_save_load_round_trip(rng, tmp_path):
    X = rng.normal(size=(24, 24, 32)).cumsum(2) * 0.1
    y = np.repeat(["a", "b", "c"], 8)
    X[y == "b", 12:15] += np.sin(np.linspace(0, 6, 32))       # the left wrist draws
    kp = np.array([1, 2, 3, 4, 5, 6, 7])
    m = rk.RocketClassifier(n_features=168, views=("joints", "arms"), hydra=True, augment=1).fit_series(
        X, y, keypoints=kp)
    assert m.views_ == ["joints", "arms"] and len(m.rockets_) == 4 and len(m.hydras_) == 4
    assert m.coef_.shape[1] == sum(r.n_features_out for r in m.rockets_ + m.hydras_)
    back = load_model(m.save(tmp_path / "v.npz"))
    assert back.params() == m.params() and back.views_ == m.views_
    assert np.array_equal(back.decision_series(X), m.decision_series(X))
    plain = rk.RocketClassifier(n_features=168, views=("joints", "arms"), hydra=False, augment=0).fit_series(X, y)
    assert plain.views_ == ["joints"] and not plain.hydras_    # no keypoints: the arm view is left out
    with pytest.raises(MocapValueError, match="unknown views"):
        rk.RocketClassifier(views=("legs",)).fit_series(X, y)


def test_version_2_rocket_model_files_load_with_the_joints_view_only(rng, tmp_path):
    """A v2 file (no views / hydra / keypoints stored) predicts as the joints-view model it was."""
    tr, ytr = _toy_motions(rng, n_per=4)
    m = rk.RocketClassifier(n_features=200, views=("joints",), hydra=False, augment=0, seed=0).fit(tr, ytr)
    with np.load(m.save(tmp_path / "v3.npz")) as z:
        st = {k: z[k] for k in z.files if k != "keypoints"}
    head = json.loads(str(st["header"]))
    del head["params"]["views"], head["params"]["hydra"]
    head["version"] = 2
    st["header"] = np.array(json.dumps(head))
    np.savez(tmp_path / "v2.npz", **st)
    back = load_model(tmp_path / "v2.npz")
    assert back.views == ("joints",) and back.views_ == ["joints"] and not back.hydra
    X = np.stack([m.series(x) for x in tr])
    assert np.array_equal(back.decision_series(X), m.decision_series(X))


def test_series_keypoints_put_the_arm_keypoints_first_then_the_body():
    sk = kinect_skeleton()
    kp = rk.series_keypoints(sk)
    names = ["HipCenter"] + [n for n in sk.names if n != "HipCenter"]    # trajectories' root-first order
    assert [names[i] for i in kp] == ["Head", "ShoulderLeft", "ElbowLeft", "WristLeft", "ShoulderRight",
                                      "ElbowRight", "WristRight", "HipCenter", "ShoulderCenter", "HipLeft",
                                      "KneeLeft", "AnkleLeft", "HipRight", "KneeRight", "AnkleRight"]


def test_bone_and_reach_views_hand_computed(rng):
    X = rng.normal(size=(2, 45, 12))                # 15 joints, joint-major x, y, z; joint 0 = root
    kp = np.array([3, 4, 5, 6, 8, 9, 10, 0, 2, 12, 13, 14, 11, 7, 1])   # rk.SERIES_KEYPOINTS order
    J = X.reshape(2, 15, 3, 12)
    B = rk.bone_view(X, kp)
    assert B.shape == (2, 42, 12)
    unit = lambda v: v / np.linalg.norm(v, axis=1, keepdims=True)  # noqa: E731
    assert np.allclose(B[:, 0:3], unit(J[:, 2]))                    # spine: neck - root (root = origin)
    assert np.allclose(B[:, 9:12], unit(J[:, 5] - J[:, 4]))         # left upper arm: elbow - shoulder
    assert np.allclose(B[:, 21:24], unit(J[:, 10] - J[:, 9]))       # right forearm: wrist - elbow
    assert np.allclose(B[:, 39:42], unit(J[:, 1] - J[:, 7]))        # right shank: ankle - knee
    assert np.allclose(np.linalg.norm(B.reshape(2, 14, 3, 12), axis=2), 1.0)
    moved = J.copy()
    moved[:, 1:] *= 1.8                             # a bigger body: same directions
    assert np.allclose(rk.bone_view(moved.reshape(2, 45, 12), kp), B)
    Rv = rk.reach_view(X, kp)
    assert Rv.shape == (2, 15, 12)
    assert np.allclose(Rv[:, 0:3], J[:, 3]) and np.allclose(Rv[:, 9:12], J[:, 9])  # head, right elbow
    assert np.allclose(Rv[:, 6:9], J[:, 6]) and np.allclose(Rv[:, 12:15], J[:, 10])  # the wrists


def test_rocket_bone_and_reach_views_fit_save_load_and_need_the_keypoints(rng, tmp_path):
    sk = kinect_skeleton()
    rest = sk.rest_positions()
    ms, y = [], []
    for c in range(2):                              # right hand raised above the head or kept low
        for _ in range(6):
            T = int(rng.integers(30, 50))
            P = np.repeat(rest[None], T, 0) + rng.normal(0, 0.5, (T, 20, 3))
            up = np.sin(np.linspace(0, np.pi, T)) * (70 if c == 0 else 25) * rng.uniform(0.8, 1.2)
            P[:, 9:12, 1] += up[:, None] * np.array([0.5, 1.0, 1.0])
            ms.append(Motion(P, sk, 15.0))
            y.append(["high", "low"][c])
    m = rk.RocketClassifier(n_features=168, length=32, views=("joints", "bones", "reach"), hydra=False,
                            augment=1, seed=3).fit(ms, y)
    assert m.views_ == ["joints", "bones", "reach"] and len(m.keypoints_) == 15
    assert [r.n_channels_ for r in m.rockets_] == [60, 60, 42, 42, 15, 15]
    assert m.coef_.shape[1] == sum(r.n_features_out for r in m.rockets_)
    assert (m.predict_many(ms) == np.array(y)).all()
    back = load_model(m.save(tmp_path / "b.npz"))
    X = np.stack([m.series(x) for x in ms])
    assert back.views_ == m.views_ and np.array_equal(back.decision_series(X), m.decision_series(X))
    # the bone view needs all 15 keypoints: with the 7 arm keypoints of a version-3 file it is left out
    few = rk.RocketClassifier(n_features=168, length=32, views=("joints", "arms", "bones", "reach"),
                              hydra=False, augment=0).fit_series(X, y, keypoints=m.keypoints_[:7])
    assert few.views_ == ["joints", "arms", "reach"]
    # the default views (joints, arms) give the same model with 15 keypoints as with the 7 arm ones
    a = rk.RocketClassifier(n_features=168, length=32, augment=1).fit_series(X, y, keypoints=m.keypoints_)
    b = rk.RocketClassifier(n_features=168, length=32, augment=1).fit_series(X, y, keypoints=m.keypoints_[:7])
    assert np.array_equal(a.decision_series(X), b.decision_series(X))


def test_rocket_second_difference_keeps_the_first_seeds_and_round_trips(rng, tmp_path):
    """diff=2 adds transforms of the second difference; the series' and first difference's
    transforms keep the seeds (hence the features) of diff=1, and the model round-trips."""
    X = rng.normal(size=(18, 6, 32)).cumsum(2) * 0.1
    y = np.repeat(["a", "b", "c"], 6)
    one = rk.RocketClassifier(n_features=168, views=("joints",), hydra=True, augment=0).fit_series(X, y)
    two = rk.RocketClassifier(n_features=168, views=("joints",), hydra=True, augment=0, diff=2).fit_series(X, y)
    assert len(two.rockets_) == 3 and len(two.hydras_) == 3
    F1, F2 = one._features(X), two._features(X)
    n1 = one.rockets_[0].n_features_out
    np.testing.assert_array_equal(F1[:, :n1], F2[:, :n1])                # the series' transform
    acc = rk._difference(rk._difference(X))
    np.testing.assert_allclose(acc[:, :, 3:], np.diff(X, 2, axis=2)[:, :, 1:])   # second difference
    back = load_model(two.save(tmp_path / "d2.npz"))
    assert back.params()["diff"] == 2
    assert np.array_equal(back.decision_series(X), two.decision_series(X))


def _turn_about_vertical(X: np.ndarray, deg: float) -> np.ndarray:
    """X (n, 3J, L) joint-major x, y, z with every joint turned about the y axis."""
    a = np.deg2rad(deg)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    n, C, L = X.shape
    return np.einsum("ij,njl->nil", R, X.reshape(n, C // 3, 3, L).transpose(0, 2, 1, 3).reshape(n, 3, -1)
                     ).reshape(n, 3, C // 3, L).transpose(0, 2, 1, 3).reshape(n, C, L)


def test_dist_angles_height_views_hand_computed_and_invariant(rng):
    """The distance, angle and height views: shapes, one channel each by hand, and no change
    under a turn about the vertical (all three) or a bigger body (the angles)."""
    X = rng.normal(size=(2, 45, 12))                # 15 joints, joint-major x, y, z; joint 0 = root
    kp = np.array([3, 4, 5, 6, 8, 9, 10, 0, 2, 12, 13, 14, 11, 7, 1])   # rk.SERIES_KEYPOINTS order
    J = X.reshape(2, 15, 3, 12)
    D, A, H = rk.dist_view(X, kp), rk.angles_view(X, kp), rk.height_view(X, kp)
    assert D.shape == (2, 16, 12) and A.shape == (2, 11, 12) and H.shape == (2, 10, 12)
    assert np.allclose(D[:, 0], np.linalg.norm(J[:, 6] - J[:, 10], axis=1))          # wrist - wrist
    assert np.allclose(D[:, 4], np.linalg.norm(J[:, 10], axis=1))                     # r wrist - hip centre (origin)
    u, f = J[:, 5] - J[:, 4], J[:, 6] - J[:, 5]                                       # left upper arm, forearm
    cos = (u * f).sum(1) / np.linalg.norm(u, axis=1) / np.linalg.norm(f, axis=1)
    assert np.allclose(A[:, 0], np.arccos(cos))                                       # left elbow flexion
    assert np.allclose(A[:, 10], np.arccos(J[:, 2, 1] / np.linalg.norm(J[:, 2], axis=1)))  # trunk bend
    assert (A >= 0).all() and (A <= np.pi + 1e-12).all()
    arm = np.median(np.linalg.norm(u, axis=1) + np.linalg.norm(f, axis=1), axis=1)[:, None]
    assert np.allclose(H[:, 0], (J[:, 6, 1] - J[:, 3, 1]) / arm)                     # left hand above the head
    turned = _turn_about_vertical(X, 37.0)
    assert not np.allclose(turned, X)
    for view in (rk.dist_view, rk.angles_view, rk.height_view):
        assert np.allclose(view(turned, kp), view(X, kp))
    moved = J.copy()
    moved[:, 1:] *= 1.8                             # a bigger body: same angles, distances x 1.8
    assert np.allclose(rk.angles_view(moved.reshape(2, 45, 12), kp), A)
    assert np.allclose(rk.dist_view(moved.reshape(2, 45, 12), kp), 1.8 * D)


def test_rocket_dist_view_fits_and_round_trips(rng, tmp_path):
    X = rng.normal(size=(12, 45, 32)).cumsum(2) * 0.1
    y = np.repeat(["a", "b"], 6)
    kp = np.array([3, 4, 5, 6, 8, 9, 10, 0, 2, 12, 13, 14, 11, 7, 1])
    m = rk.RocketClassifier(n_features=168, views=("joints", "dist", "angles", "height"), hydra=True,
                            augment=1).fit_series(X, y, keypoints=kp)
    assert m.views_ == ["joints", "dist", "angles", "height"]
    assert [r.n_channels_ for r in m.rockets_] == [45, 45, 16, 16, 11, 11, 10, 10]
    back = load_model(m.save(tmp_path / "v.npz"))
    assert back.views_ == m.views_ and np.array_equal(back.decision_series(X), m.decision_series(X))
    few = rk.RocketClassifier(n_features=168, views=("joints", "dist"), hydra=False,
                              augment=0).fit_series(X, y, keypoints=kp[:7])
    assert few.views_ == ["joints"]                 # the distance view needs all 15 keypoints


def test_augment_series_raises_the_arms_rigidly_about_the_shoulders(rng):
    """arm_deg turns elbow, wrist and hand about the shoulder (lengths kept, the rest of the
    body unmoved); arm_deg = 0 gives the copies of the augmentation without it."""
    sk = kinect_skeleton()
    rest = sk.rest_positions()
    P = np.repeat(rest[None], 20, 0) + rng.normal(0, 0.5, (20, 20, 3))
    X = rk.trajectories(Motion(P, sk, 15.0), 32)[None].repeat(3, 0)
    kp = rk.series_keypoints(sk)
    Xa, _ = rk.augment_series(X, 2, np.random.default_rng(1), rot_deg=0.0, time_warp=0.0, arm_deg=20.0,
                              keypoints=kp)
    J, K = X[:1].reshape(1, 20, 3, 32), Xa.reshape(6, 20, 3, 32)
    moved = np.flatnonzero(np.abs(K - J).max(axis=(0, 2, 3)) > 1e-9)
    names = ["HipCenter"] + [n for n in sk.names if n != "HipCenter"]
    assert sorted(names[j] for j in moved) == sorted(["ElbowLeft", "WristLeft", "HandLeft", "ElbowRight",
                                                      "WristRight", "HandRight"])
    for s, e, w in (kp[1:4], kp[4:7]):
        for a, b in ((s, e), (e, w)):
            np.testing.assert_allclose(np.linalg.norm(K[:, b] - K[:, a], axis=1),
                                       np.linalg.norm(J[:, b] - J[:, a], axis=1).repeat(6, 0), atol=1e-12)
    plain, _ = rk.augment_series(X, 2, np.random.default_rng(1))
    same, _ = rk.augment_series(X, 2, np.random.default_rng(1), arm_deg=0.0, keypoints=kp)
    assert np.array_equal(plain, same)


def test_augment_series_style_mix_moves_along_same_class_differences():
    """mix moves each copy by lam (X_j - X_i) with j another series of its own class and
    |lam| <= mix; mix = 0 (or no labels) gives the copies of the augmentation without it."""
    rng = np.random.default_rng(3)
    X = rng.normal(0, 1, (6, 3, 16))
    labels = np.array(["a", "a", "a", "b", "b", "c"])           # "c" has no partner
    Xa, owner = rk.augment_series(X, 4, np.random.default_rng(1), rot_deg=0.0, time_warp=0.0, mix=0.5,
                                  labels=labels, mix_rng=np.random.default_rng(2))
    for k, i in enumerate(owner):
        d = Xa[k] - X[i]
        if labels[i] == "c":
            assert np.abs(d).max() == 0                          # nothing to mix with
            continue
        fits = []
        for j in np.flatnonzero(labels == labels[i]):
            if j == i:
                continue
            D = X[j] - X[i]
            lam = float(np.sum(d * D) / np.sum(D * D))
            fits.append((np.abs(d - lam * D).max(), lam))
        err, lam = min(fits)
        assert err < 1e-12 and abs(lam) <= 0.5
    plain, _ = rk.augment_series(X, 4, np.random.default_rng(1))
    same, _ = rk.augment_series(X, 4, np.random.default_rng(1), mix=0.0, labels=labels)
    assert np.array_equal(plain, same)


def test_sample_times_trim_idle_ends_and_follow_the_motion_clock():
    """``trim`` cuts the still frames at both ends by the cumulative motion; the motion
    clock puts the samples where the motion is; the defaults are the time clock."""
    T = 20
    P = np.zeros((T, 2, 3))
    P[5:15, 0, 0] = np.arange(1, 11)              # still, moving 1 per frame, then still
    P[15:, 0, 0] = 10.0
    np.testing.assert_allclose(rk._sample_times(P, 8, 0.0, 0.0), np.linspace(0, T - 1, 8))
    t = rk._sample_times(P, 6, 0.1, 0.0)          # 10 % of the motion cut at each end
    np.testing.assert_allclose(t[[0, -1]], [5.0, 13.0], atol=1e-6)
    np.testing.assert_allclose(np.diff(t), 1.6, atol=1e-6)
    t = rk._sample_times(P, 11, 0.0, 1.0)         # progress clock: one sample per unit
    np.testing.assert_allclose(t[1:-1], np.arange(5, 14), atol=1e-6)
    assert np.all(np.diff(rk._sample_times(P, 16, 0.05, 0.5)) > 0)
    still = np.zeros((T, 2, 3))                    # no motion: the time clock
    np.testing.assert_allclose(rk._sample_times(still, 5, 0.1, 1.0), np.linspace(0, T - 1, 5))
    with pytest.raises(MocapValueError, match="trim"):
        rk._sample_times(P, 8, 0.5, 0.0)


def test_rocket_trim_and_motion_clock_round_trip(rng, tmp_path):
    ms, labels = _toy_motions(rng, n_per=3)
    m = rk.RocketClassifier(length=16, n_features=336, augment=0, trim=0.05, motion_time=0.5,
                            views=["joints"]).fit(ms, labels)
    assert m.series(ms[0]).shape == rk.trajectories(ms[0], 16).shape
    assert not np.allclose(m.series(ms[0]), rk.trajectories(ms[0], 16))
    back = rk.RocketClassifier.load(m.save(tmp_path / "m.npz"))
    assert (back.trim, back.motion_time) == (0.05, 0.5)
    np.testing.assert_allclose(back.predict_proba_series(np.stack([m.series(x) for x in ms])),
                               m.predict_proba_series(np.stack([m.series(x) for x in ms])))


def test_rocket_view_weights_scale_a_views_features_and_round_trip(rng, tmp_path):
    """``view_weights``: a view's standardised features times its weight (the scale of
    its columns divided by it), kept in the file; one weight per view or a clear error."""
    ms, labels = _toy_motions(rng, n_per=3)
    kw = dict(length=16, n_features=336, augment=0, views=["joints"])
    m0 = rk.RocketClassifier(**kw).fit(ms, labels)
    m = rk.RocketClassifier(view_weights=[2.0], **kw).fit(ms, labels)
    np.testing.assert_allclose(m.scale_ * 2.0, m0.scale_)
    X = np.stack([m.series(x) for x in ms])
    back = rk.RocketClassifier.load(m.save(tmp_path / "w.npz"))
    assert back.view_weights == (2.0,)
    np.testing.assert_allclose(back.decision_series(X), m.decision_series(X))
    with pytest.raises(MocapValueError, match="one weight per view"):
        rk.RocketClassifier(view_weights=[1.0, 2.0], **kw).fit(ms, labels)
