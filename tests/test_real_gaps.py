"""Real-occlusion benchmark: mask transplant, scorer, peers and the quick protocol."""
from __future__ import annotations

import numpy as np
import pytest

from mocapkit import bench
from mocapkit.bench.protocols import real_gaps as R
from mocapkit.motion import Motion
from mocapkit.gaps import find_gaps
from mocapkit.occlusion import (apply_mask, drop_duplicate_markers, fully_observed_markers,
                                resample_mask, transplant_mask)
from mocapkit.skeleton import Skeleton


def _markers(P: np.ndarray, fps: float = 100.0) -> Motion:
    J = P.shape[1]
    sk = Skeleton(tuple(f"m{j}" for j in range(J)), -np.ones(J, dtype=int), np.zeros((J, 3)))
    return Motion(P, sk, fps)


def _source_mask() -> np.ndarray:
    """(100, 4) at 100 Hz: markers 0 and 1 occluded together, marker 2 alone, 3 never."""
    obs = np.ones((100, 4), dtype=bool)
    obs[10:30, 0] = obs[10:30, 1] = False
    obs[60:70, 2] = False
    obs[:5, 0] = False            # a leading gap
    return obs


def test_resample_mask_nearest_frame():
    obs = np.array([[1], [0], [0], [1], [1], [0]], dtype=bool)
    # 100 Hz -> 50 Hz: 3 frames, source frames 0, 2, 4
    assert resample_mask(obs, 100, 50)[:, 0].tolist() == [True, False, True]
    # 50 Hz -> 100 Hz: 12 frames, source frame round(i / 2)
    up = resample_mask(obs, 50, 100)[:, 0]
    assert len(up) == 12
    assert up.tolist() == [obs[min(int(np.rint(i / 2)), 5), 0] for i in range(12)]


def test_transplant_keeps_co_missing_structure_and_is_deterministic():
    src = _source_mask()
    a = transplant_mask(src, 100.0, 40, 4, 50.0, seed=3)
    b = transplant_mask(src, 100.0, 40, 4, 50.0, seed=3)
    assert np.array_equal(a.observed, b.observed) and a.offsets == b.offsets
    assert np.array_equal(a.columns, b.columns)
    R50 = resample_mask(src, 100, 50)                      # (50, 4)
    assert not a.wrapped and len(a.offsets) == 1
    o = a.offsets[0]
    # every target marker is its source column over ONE shared window
    assert np.array_equal(a.observed, R50[o:o + 40][:, a.columns])
    assert sorted(a.columns.tolist()) == [0, 1, 2, 3]
    # the co-missing pair stays co-missing (markers on source columns 0 and 1)
    j0, j1 = int(np.flatnonzero(a.columns == 0)[0]), int(np.flatnonzero(a.columns == 1)[0])
    hid0 = ~a.observed[:, j0]
    assert np.array_equal(hid0 & ~a.observed[:, j1], hid0 & ~R50[o:o + 40, 1])
    seeds = {tuple(transplant_mask(src, 100.0, 40, 4, 50.0, seed=s).columns) for s in range(8)}
    assert len(seeds) > 1                                  # the seed matters


def test_transplant_wraps_and_reuses_columns_in_blocks():
    src = _source_mask()
    tr = transplant_mask(src, 100.0, 130, 6, 100.0, seed=1)   # longer and wider than the source
    assert tr.wrapped and len(tr.offsets) == 2
    for j in range(6):
        rows = (tr.offsets[tr.blocks[j]] + np.arange(130)) % 100
        assert np.array_equal(tr.observed[:, j], src[rows, tr.columns[j]])
    # block 0 uses every source column once, block 1 the other two target markers
    assert sorted(tr.columns[tr.blocks == 0].tolist()) == [0, 1, 2, 3]
    assert (tr.blocks == 1).sum() == 2


def test_transplant_never_invents_black_out_frames():
    src = np.zeros((50, 5), dtype=bool)
    src[:, 4] = True                    # only marker 4 is ever seen...
    src[20:30, 4] = False               # ...except a real black-out in frames 20-29
    for seed in range(6):
        tr = transplant_mask(src, 50.0, 50, 2, 50.0, seed=seed)
        blackout = ~tr.observed.any(axis=1)
        assert blackout[20:30].all()
        assert not blackout[:20].any() and not blackout[30:].any()


def test_gaps_and_apply_mask():
    assert [(g.start, g.stop) for g in find_gaps(np.array([[0], [0], [1], [1], [0], [1], [0]], dtype=bool))] \
        == [(0, 2), (4, 5), (6, 7)]
    P = np.arange(4 * 2 * 3, dtype=float).reshape(4, 2, 3)
    P[0, 1] = np.nan
    m = _markers(P)
    assert fully_observed_markers(m).skeleton.names == ("m0",)
    mask = np.ones((4, 2), dtype=bool)
    mask[2, 0] = False
    out = apply_mask(m, mask)
    assert not out.observed[2, 0] and not out.observed[0, 1] and out.observed.sum() == 6


def test_drop_duplicate_markers_keeps_the_labelled_one():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(10, 3, 3))
    P[:, 0] = P[:, 2]                                   # marker "*0" copies marker "b"
    sk = Skeleton(("*0", "a", "b"), -np.ones(3, dtype=int), np.zeros((3, 3)))
    out, dropped = drop_duplicate_markers(Motion(P, sk, 100.0))
    assert dropped == ["*0"] and out.skeleton.names == ("a", "b")
    P[3, 0] += 0.01                                     # no longer an exact copy
    out, dropped = drop_duplicate_markers(Motion(P, sk, 100.0))
    assert dropped == [] and out.n_joints == 3


def test_scorer_hand_example():
    T, J = 4, 2
    truth = np.zeros((T, J, 3))
    hidden = np.zeros((T, J), dtype=bool)
    hidden[1, 0] = hidden[2, 0] = hidden[3, 1] = True
    est = np.zeros((T, J, 3))
    est[1, 0] = [3.0, 4.0, 0.0]          # 5 cm off
    est[2, 0] = [0.0, 0.0, 30.0]         # 30 cm off: gross
    est_obs = np.ones((T, J), dtype=bool)
    est_obs[3, 1] = False                # left missing: not filled
    box = (np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0]))
    f = R.score_fill(truth, hidden, est, est_obs, box)
    s = f.summary()
    # what an estimate is scored against: the fills, or every sample written (the measured
    # ones 0 cm off here, 5 of them written)
    assert f.true_error("fills") == pytest.approx(s["rmse"])
    assert f.true_error("written") == pytest.approx(np.sqrt((25 + 900) / (3 * 7)))
    assert s["n_hidden"] == 3 and s["n_filled"] == 2
    assert s["coverage"] == pytest.approx(200 / 3)
    assert s["rmse"] == pytest.approx(np.sqrt((25 + 900) / 6))
    assert s["gross_pct"] == pytest.approx(50.0)
    assert s["max_err"] == pytest.approx(30.0)
    assert s["outside_1m"] == 0 and s["zero_fills"] == 0
    est[2, 0] = [0.0, 0.0, 150.0]        # 149 cm above the box: outside
    est[1, 0] = 0.0                      # an exact (0, 0, 0) fill
    s = R.score_fill(truth, hidden, est, est_obs, box).summary()
    assert s["outside_1m"] == 1 and s["zero_fills"] == 1


def test_peers_linear_holds_edges_and_cubic_is_exact_on_a_cubic():
    t = np.arange(20, dtype=float)
    P = np.stack([np.stack([t, 2 * t, 0.01 * t ** 3], axis=1)] * 2, axis=1)     # (20, 2, 3)
    P[:3, 0] = np.nan
    P[8:12, 0] = np.nan
    P[:, 1] = 5.0                        # marker 1: observed once only below
    P[1:, 1] = np.nan
    m = _markers(P)
    L, lo = R.fill_linear(m)
    assert lo[:, 0].all() and not lo[1:, 1].any()          # < 2 observed frames: left missing
    assert np.allclose(L[:3, 0], P[3, 0])                  # leading gap held at the first value
    assert np.allclose(L[8:12, 0, 0], t[8:12])             # linear channel exact
    C, co = R.fill_cubic(m)
    assert np.allclose(C[8:12, 0], np.stack([t, 2 * t, 0.01 * t ** 3], axis=1)[8:12], atol=1e-9)
    assert np.allclose(C[:3, 0], P[3, 0])


def test_find_sources_on_shared_data(shared_data):
    sources, notes = R.find_sources(shared_data)
    keys = [k for k, _ in sources]
    assert "kineticstoolkit/kinematics_basket_sprint.c3d" in keys
    assert "pyomeca/markers_analogs.c3d" in keys and "ezc3d/Vicon.c3d" not in keys
    assert any("Vicon.c3d" in n and "byte-identical" in n for n in notes)
    assert all(m.n_frames > 2 and not m.observed.all() for _, m in sources)


def test_quick_protocol_on_shared_data(shared_data, monkeypatch):
    def boom(motion):
        raise RuntimeError("peer exploded")

    monkeypatch.setitem(R.PEER_FUNCS, "cubic", boom)
    ctx = bench.Context(shared_data, quick=True, progress=False,
                        options={"methods": ["linear", "cubic", "kalman-cv", "default"],
                                 "max_frames": 160})
    rows = bench.run("real-gaps", ctx)
    by = {(r.clip, r.condition, r.method, r.metric): r for r in rows}
    cases = {(r.clip, r.condition) for r in rows if r.method == "mask" and r.clip != "tennis_serve_vendor"}
    assert len(cases) == 4
    for clip, cond in cases:
        assert by[(clip, cond, "cubic", "failed")].extra["error"].startswith("RuntimeError")
        lin = by[(clip, cond, "linear", "rmse")]
        assert 0 < by[(clip, cond, "linear", "coverage")].value <= 100
        assert np.isfinite(lin.value) and lin.value > 0
        # linear is a peer: the best peer on its own samples is never worse than itself
        assert by[(clip, cond, "linear", "ratio_best_peer")].value <= 1 + 1e-9
        assert (clip, cond, "default", "rmse") in by or (clip, cond, "default", "failed") in by
    crashes = by[("targets", "cases <= 60% missing", "cubic", "crashes")]
    assert crashes.value == 4
    assert ("targets", "cases <= 60% missing", "default", "gross_pct") in by
    # the default (auto) says what error it expects: scored against the truth, per case
    est = [r for r in rows if r.metric == "estimate_ratio"]
    assert est and {r.method for r in est} == {"default"}
    for r in est:
        assert r.extra["over"] == "written" and r.extra["true_cm"] > 0
        assert r.value == pytest.approx(r.extra["estimate_cm"] / r.extra["true_cm"])
    within = by[("targets", "cases <= 60% missing", "default", "estimate_within_1.5x")]
    assert within.n == len([r for r in est if r.clip != "tennis_serve_vendor"])
    assert any(r.metric == "rms_to_vendor_fill" and r.method == "linear" for r in rows)
