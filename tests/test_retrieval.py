"""Retrieval: HOD / GPF features, LLC bag of words, AMFS (thesis Ch. 5), baselines, index."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from conftest import kinect_skeleton
from mocapkit.errors import MocapFormatError, MocapValueError
from mocapkit.motion import Motion
from mocapkit.retrieval import amfs as A
from mocapkit.retrieval.evaluate import average_precision, retrieval_scores
from mocapkit.retrieval.features import (KEYPOINTS, GPFCodebook, find_keypoints, gpf, hod,
                                         prepare, sliding_windows)
from mocapkit.retrieval.index import MotionIndex, RetrievalModel, build_index, label_of, search


# ------------------------------------------------------------------------------ HOD
def test_hod_hand_computed_histograms():
    # one joint; displacements (1,0,0), (0,2,0), (0,0,3), (-1,0,0)
    P = np.array([[0, 0, 0], [1, 0, 0], [1, 2, 0], [1, 2, 3], [0, 2, 3]], float)[:, None, :]
    H = hod(P, levels=(1, 2), normalize="none").reshape(3, 1, 3, 8)   # (segment, joint, plane, bin)
    exp = np.zeros((3, 1, 3, 8))
    # whole clip.  xy: 0 deg len 1, 90 deg len 2, 180 deg len 1
    exp[0, 0, 0, [0, 2, 4]] = [1, 2, 1]
    exp[0, 0, 1, [0, 2, 4]] = [1, 3, 1]          # xz: (1,0), (0,3), (-1,0)
    exp[0, 0, 2, [0, 2]] = [2, 3]                # yz: (2,0), (0,3)
    # first half = displacements 0, 1; second half = 2, 3
    exp[1, 0, 0, [0, 2]] = [1, 2]
    exp[1, 0, 1, 0] = 1
    exp[1, 0, 2, 0] = 2
    exp[2, 0, 0, 4] = 1
    exp[2, 0, 1, [2, 4]] = [3, 1]
    exp[2, 0, 2, 2] = 3
    np.testing.assert_allclose(H, exp)
    Hn = hod(P, levels=(1, 2), normalize="hist").reshape(-1, 8)
    s = exp.reshape(-1, 8).sum(1, keepdims=True)
    np.testing.assert_allclose(Hn, np.divide(exp.reshape(-1, 8), s, out=np.zeros((9, 8)), where=s > 0))


def test_hod_bins_mid_angles_and_layout():
    # 8 displacements at 22.5 + 45 b degrees in the xy plane -> one vote per bin, in order
    th = np.deg2rad(22.5 + 45 * np.arange(8))
    steps = np.stack([np.cos(th), np.sin(th), np.zeros(8)], 1) * np.arange(1, 9)[:, None]
    P = np.vstack([np.zeros(3), np.cumsum(steps, 0)])[:, None, :]
    P = np.concatenate([P, np.zeros_like(P)], axis=1)                    # a second, still joint
    H = hod(P, levels=(1,), normalize="none").reshape(2, 3, 8)
    np.testing.assert_allclose(H[0, 0], np.arange(1, 9))
    np.testing.assert_allclose(H[1], 0.0)
    assert hod(P).shape == (7 * 2 * 3 * 8,)


# ------------------------------------------------------------------ skeleton handling
def _toy_motion(T=40, missing_frames=()):
    sk = kinect_skeleton()
    rest = sk.rest_positions()
    t = np.arange(T)[:, None]
    P = np.repeat(rest[None], T, 0)
    P[:, 10] += np.c_[10 * np.sin(t / 5), 20 * np.cos(t / 5), 0 * t]   # waving right wrist
    P[:, :, 0] += 0.5 * t                                               # walking sideways
    obs = np.ones((T, 20), bool)
    obs[list(missing_frames)] = False
    return Motion(P, sk, 15.0, obs)


def test_keypoints_and_prepare_normalise():
    m = _toy_motion(missing_frames=(3, 4, 5))
    idx = find_keypoints(m.skeleton)
    names = [m.skeleton.names[i] for i in idx]
    assert names[:4] == ["HipCenter", "ShoulderCenter", "Head", "ShoulderLeft"]
    assert names[KEYPOINTS.index("rwrist")] == "WristRight"
    assert names[KEYPOINTS.index("lankle")] == "AnkleLeft"
    p = prepare(m)
    assert p.mode == "keypoints15" and np.isfinite(p.positions).all()
    # body size: |head - root| + leg (hip-knee + knee-ankle) = 65 + 43 + 42 = 150 cm
    assert p.size_cm == pytest.approx(150.0, rel=1e-6)
    # x = lateral (right hip -> left hip), y = up: the left hip sits at +x, head at +y
    kp = {k: i for i, k in enumerate(KEYPOINTS)}
    assert p.positions[0, kp["lhip"], 0] > 0 and p.positions[0, kp["head"], 1] > 0
    # root trajectory relative to its start: moves 0.5 cm/frame along the file's x = -lateral
    np.testing.assert_allclose(p.positions[:, 0, 0], -0.5 * np.arange(40) / 150.0, atol=1e-12)
    # scale invariance: a 1.2x bigger subject gives the same descriptors
    big = m.with_positions(m.positions * 1.2, m.observed)
    np.testing.assert_allclose(hod(prepare(big)), hod(p), atol=1e-9)
    G = gpf(p)
    assert G.shape == (40, 42 + 45 + 15)
    np.testing.assert_allclose(gpf(prepare(big)), G, atol=1e-9)


def test_prepare_rejects_fully_missing_motion():
    m = _toy_motion(T=6, missing_frames=range(6))
    with pytest.raises(MocapValueError, match="no joint is observed"):
        prepare(m)


def test_sliding_windows():
    np.testing.assert_array_equal(sliding_windows(20, 10, 5), [[0, 10], [5, 15], [10, 20]])
    np.testing.assert_array_equal(sliding_windows(7, 10, 5), [[0, 7]])


# ---------------------------------------------------------------------- bag of words
def test_llc_bag_of_words_shapes_and_normalisation(rng):
    frames = [rng.standard_normal((int(n), 6)) for n in rng.integers(5, 30, 12)]
    cb = GPFCodebook(8, n_neighbors=3, seed=0).fit(frames)
    assert cb.centers_.shape == (8, 6) and cb.dim == 8
    C = cb.codes(frames[0])
    assert C.shape == (len(frames[0]), 8)
    np.testing.assert_allclose(C.sum(1), 1.0, atol=1e-9)          # LLC: codes sum to one
    assert ((C != 0).sum(1) <= 3).all()                             # 3 nearest words only
    v = cb.encode(frames[1])
    assert v.shape == (8,) and np.linalg.norm(v) == pytest.approx(1.0)
    C1 = cb.codes(frames[1])
    np.testing.assert_allclose(v, C1.max(0) / np.linalg.norm(C1.max(0)))   # max pooling
    cb2 = GPFCodebook(8, pooling="sum", levels=(1, 2), seed=0).fit(frames)
    v2 = cb2.encode(frames[1])
    assert v2.shape == (24,) and np.linalg.norm(v2) == pytest.approx(1.0)
    st = GPFCodebook.from_state(cb.state())
    np.testing.assert_allclose(st.encode(frames[2]), cb.encode(frames[2]))


# ---------------------------------------------------------------------------- AMFS
def test_local_regression_block_equals_direct_formula(rng):
    for d in (3, 9):                                  # d < k and d > k
        F = rng.standard_normal((12, d))
        k, mu = 5, 0.3
        idx = A.knn_indices(F, k)
        assert (idx[:, 0] == np.arange(12)).all()
        B = A.local_regression_blocks(F, idx, mu)
        H = np.eye(k) - np.ones((k, k)) / k
        for i in (0, 7):
            Xi = F[idx[i]].T                               # d x k, the thesis' X_i
            Li = H - H @ Xi.T @ np.linalg.inv(Xi @ H @ Xi.T + mu * np.eye(d)) @ Xi @ H
            np.testing.assert_allclose(B[i], Li, atol=1e-10)
        L = A.local_regression_laplacian(F, k, mu).toarray()
        Ld = np.zeros((12, 12))
        for i in range(12):
            S = np.zeros((12, k))
            S[idx[i], np.arange(k)] = 1.0
            Ld += S @ B[i] @ S.T                           # eq. 5.16
        np.testing.assert_allclose(L, Ld, atol=1e-10)
        np.testing.assert_allclose(L @ np.ones(12), 0.0, atol=1e-10)
        assert np.linalg.eigvalsh(L).min() > -1e-10     # PSD


def test_alpha_update_eq_5_24():
    np.testing.assert_allclose(A.alpha_update([2.0, 8.0], r=3), [2 / 3, 1 / 3])
    t, r = np.array([0.5, 1.5, 4.0]), 2.5
    f = t ** (-1 / (r - 1))
    np.testing.assert_allclose(A.alpha_update(t, r), f / f.sum())
    np.testing.assert_allclose(A.alpha_update([0.0, 3.0], r=2), [1.0, 0.0])
    with pytest.raises(MocapValueError):
        A.alpha_update([1.0, 2.0], r=1.0)


def test_trace_ratio_is_global_optimum_of_subset_ratio(rng):
    a, b = rng.random(9), rng.random(9) + 0.1
    ratios = {s: a[list(s)].sum() / b[list(s)].sum() for s in itertools.combinations(range(9), 3)}
    sel, lam, _ = A.trace_ratio_select(a, b, 3, order="ascending", seed=1)
    assert lam == pytest.approx(min(ratios.values()))
    assert set(sel.tolist()) == set(min(ratios, key=ratios.get))
    # the printed (descending) step climbs to the largest ratio instead
    _, lam_d, _ = A.trace_ratio_select(a, b, 3, order="descending", seed=1)
    assert lam_d == pytest.approx(max(ratios.values()))


def _planted(rng, n_per=30):
    y = np.repeat(np.arange(3), n_per)
    means = rng.standard_normal((3, 8)) * 3
    V1 = np.c_[means[y, :5] + 0.3 * rng.standard_normal((len(y), 5)), rng.standard_normal((len(y), 20))]
    V2 = np.c_[means[y, 5:] + 0.3 * rng.standard_normal((len(y), 3)), rng.standard_normal((len(y), 15))]
    return V1, V2, y


def test_amfs_selects_planted_informative_features(rng):
    V1, V2, y = _planted(rng)
    informative = set(range(5)) | {25, 26, 27}
    m = A.AMFS(d=8, k=6, mu=0.1, r=2).fit([V1, V2])
    assert set(m.selected_.tolist()) == informative
    assert m.alpha_.shape == (2,) and m.alpha_.sum() == pytest.approx(1.0)
    assert m.objective_[-1] <= m.objective_[0] + 1e-12
    desc = A.AMFS(d=8, k=6, mu=0.1, r=2, order="descending").fit([V1, V2])
    assert len(set(desc.selected_.tolist()) & informative) <= 2      # as printed: the wrong end
    F = np.c_[V1, V2]
    for scores, small in ((A.laplacian_score(F), True), (A.spec_score(F, 3), False),
                          (A.udfs_score(F, 3), False)):
        top = set(A.select_top(scores, 8, smallest=small).tolist())
        assert len(top & informative) >= 6


def test_laplacian_score_matches_definition(rng):
    F = rng.random((15, 4))
    sc = A.laplacian_score(F, k=3)
    S = A._heat_graph(F, 3).toarray()
    Dg = np.diag(S.sum(1))
    L = Dg - S
    one = np.ones(15)
    for j in range(4):
        f = F[:, j]
        ft = f - (f @ Dg @ one) / (one @ Dg @ one) * one
        assert sc[j] == pytest.approx((ft @ L @ ft) / (ft @ Dg @ ft))


def test_udfs_woodbury_matches_dense_eigensolver(rng):
    from scipy.linalg import eigh

    F = rng.random((60, 12))
    got = A.udfs_score(F, 3, k=4, gamma=0.1, lam=1e-3, n_iter=4)
    N, D = F.shape
    idx = A.knn_indices(F, 5)
    H = np.eye(5) - 1 / 5
    grams = [H @ F[idx[i]] @ F[idx[i]].T @ H for i in range(N)]
    lam = 1e-3 * np.mean([np.trace(G) / 5 for G in grams])
    Lu = np.zeros((N, N))
    for i in range(N):
        Lu[np.ix_(idx[i], idx[i])] += H @ np.linalg.inv(grams[i] + lam * np.eye(5)) @ H
    M = F.T @ Lu @ F
    g = 0.1 * np.mean(np.diag(M))
    Dg = np.ones(D)
    for _ in range(4):
        _, W = eigh(M + g * np.diag(Dg), subset_by_index=(0, 2))
        Dg = 1 / (2 * np.maximum(np.linalg.norm(W, axis=1), 1e-8))
    np.testing.assert_allclose(got, np.linalg.norm(W, axis=1), atol=1e-6)


# -------------------------------------------------------------------------- metrics
def test_average_precision_and_precision_at_k():
    np.testing.assert_allclose(average_precision(np.array([[1, 0, 1, 0]], bool)), [(1 + 2 / 3) / 2])
    dist = np.array([[0.1, 0.2, 0.3, 0.4], [0.4, 0.3, 0.2, 0.1]])
    s = retrieval_scores(dist, ["a", "b"], ["a", "b", "a", "b"], ks=(1, 2))
    # query a: ranking a b a b -> AP (1 + 2/3)/2; query b: ranking b a b a -> same
    assert s["mAP"] == pytest.approx((1 + 2 / 3) / 2)
    assert s["P@1"] == 1.0 and s["P@2"] == 0.5


# ---------------------------------------------------------------------------- index
def test_index_search_matches_brute_force_at_scale(rng, tmp_path):
    emb = rng.standard_normal((10000, 64)).astype(np.float32)
    model = RetrievalModel("hod")
    idx = MotionIndex(model, emb, [f"clip{i}" for i in range(10000)])
    q = emb[[17, 4242]] + 1e-3
    got_i, got_d = idx.search_embedding(q, k=5)
    d = np.linalg.norm(emb[None].astype(float) - q[:, None].astype(float), axis=2)
    np.testing.assert_array_equal(got_i, np.argsort(d, axis=1)[:, :5])
    np.testing.assert_allclose(got_d, np.sort(d, axis=1)[:, :5], rtol=1e-4, atol=1e-4)
    assert got_i[0, 0] == 17 and got_i[1, 0] == 4242


def test_label_of():
    assert label_of("x/a07_s03_e02_skeleton3D.txt") == "a07"
    assert label_of("hdm/kickLFront1Reps/HDM_bd_kickLFront1Reps_001_120.amc") == "kickLFront1Reps"
    assert label_of("lib/walk/clip.bvh") == "walk"


@pytest.mark.shared_data
def test_index_build_search_round_trip(shared_data, tmp_path):
    root = shared_data / "hdm05" / "asfamc"
    files = []
    for cls in ("hopBothLegs1hops", "rotateArmsBothBackward1Reps", "kickLFront1Reps"):
        files += sorted((root / cls).glob("HDM_*.amc"))[:4]
    out = tmp_path / "lib.idx"
    info = build_index(files, out, progress=False, d=0.5, n_words=16)
    assert info["n_indexed"] == 12 and not info["skipped"] and info["mode"] == "keypoints15"
    with pytest.raises(MocapValueError, match="exists"):
        build_index(files, out, progress=False)
    hits = search(out, files[5], k=4)
    assert len(hits) == 4
    assert hits[0][0] == str(files[5]) and hits[0][1] == pytest.approx(0.0, abs=1e-3)
    assert [h[1] for h in hits] == sorted(h[1] for h in hits)
    # a clip of the same class comes next
    assert sum("rotateArms" in h[0] for h in hits[1:]) >= 2
    idx = MotionIndex.load(out)
    assert len(idx) == 12 and idx.labels[0] == "hopBothLegs1hops"
    bad = tmp_path / "bad.idx"
    bad.write_bytes(b"not an index")
    with pytest.raises(MocapFormatError):
        MotionIndex.load(bad)


@pytest.mark.shared_data
def test_keypoints_on_every_shared_skeleton_kind(shared_data):
    from mocapkit import io

    files = [next((shared_data / "msr_action3d" / "skeleton3d").glob("a01_*.txt")),
             next((shared_data / "hdm05" / "asfamc").rglob("*.amc")),
             shared_data / "cmu" / "bvh" / "motionbuilder75" / "16_15.bvh",
             next((shared_data / "cmu" / "bvh" / "daz_friendly").glob("*.bvh"))]
    for f in files:
        m = io.read(f)
        idx = find_keypoints(m.skeleton)
        assert idx is not None and len(set(idx.tolist())) == 15, f
        p = prepare(m.slice(0, 60))
        # upper arm and shin are anatomical (15-60 cm) for every naming convention
        P = p.absolute() * p.size_cm
        kp = {k: i for i, k in enumerate(KEYPOINTS)}
        for a, b in (("lshoulder", "lelbow"), ("rknee", "rankle")):
            seg = np.median(np.linalg.norm(P[:, kp[a]] - P[:, kp[b]], axis=1))
            assert 15 < seg < 60, (f, a, b, seg)
