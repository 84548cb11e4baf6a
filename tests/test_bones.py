"""Bone lengths a skeleton format fixes, and auto giving them back after smoothing (#19)."""
from __future__ import annotations

import numpy as np
import pytest

from mocapkit import corrupt, io
from mocapkit.datasets import bundled
from mocapkit.denoise import get
from mocapkit.rigid import fixed_bones, hold_lengths


@pytest.fixture(scope="module")
def amc():
    return io.read(bundled("16_15.amc")).slice(2, 242)


def _lengths(P, pairs):
    return np.linalg.norm(P[:, pairs[:, 0]] - P[:, pairs[:, 1]], axis=-1)


def test_hold_lengths_gives_a_chain_its_lengths_and_moves_it_least():
    rng = np.random.default_rng(0)
    J = 6
    pairs = np.column_stack([np.arange(1, J), np.arange(J - 1)])          # a chain
    L = rng.uniform(5, 30, J - 1)
    d = rng.normal(size=(50, J - 1, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    P = np.concatenate([np.zeros((50, 1, 3)), np.cumsum(d * L[None, :, None], axis=1)], axis=1)
    noisy = P + rng.normal(0, 0.5, P.shape)
    held = hold_lengths(noisy, pairs, L, sweeps=30)
    np.testing.assert_allclose(_lengths(held, pairs), np.broadcast_to(L, (50, J - 1)), atol=1e-3)
    # a projection onto a set the truth lies on: closer to the truth than the input
    assert np.sqrt(np.mean((held - P) ** 2)) < np.sqrt(np.mean((noisy - P) ** 2))
    # a pair with a missing end is left alone, and no NaN spreads to its other end
    gap = noisy.copy()
    gap[3, 2] = np.nan
    out = hold_lengths(gap, pairs, L)
    assert np.isnan(out[3, 2]).all() and np.isfinite(np.delete(out[3], 2, axis=0)).all()
    # the input is never written, however its layout lets the joints-first copy alias it
    for T in (1, 50):
        given = noisy[:T].copy()
        held = hold_lengths(given, pairs, L, sweeps=3)
        np.testing.assert_array_equal(given, noisy[:T])
        assert held.shape == given.shape and held.flags.c_contiguous


def test_fixed_bones_per_format(amc, tmp_path):
    pairs, L = fixed_bones(amc)
    assert len(pairs) == amc.n_joints - 1
    np.testing.assert_allclose(_lengths(amc.positions, pairs), np.broadcast_to(L, (amc.n_frames, len(L))),
                               atol=1e-6)
    bvh = io.read(bundled("16_15.bvh"))
    pb, Lb = fixed_bones(bvh)
    assert len(pb) > 0
    np.testing.assert_allclose(_lengths(bvh.positions, pb), np.broadcast_to(Lb, (bvh.n_frames, len(Lb))),
                               atol=1e-4)
    # a marker format (here the same positions through TRC) fixes none
    io.write(amc, tmp_path / "m.trc")
    assert len(fixed_bones(io.read(tmp_path / "m.trc"))[0]) == 0


def test_auto_gives_noisy_skeleton_data_its_bone_lengths_back(amc):
    noisy = corrupt.combine(amc, [("gaussian", {"sigma_cm": 2.0})], seed=3)[0]
    out = get("auto").denoise(noisy)
    src = out.source["auto"]
    assert "bone lengths held" in src["chain"]
    pairs, L = fixed_bones(amc)
    assert np.max(np.abs(_lengths(out.positions, pairs) - L)) < 0.05
    err = np.sqrt(np.mean((out.positions - amc.positions) ** 2))
    free = get("auto").denoise(noisy.with_source(asf=None))          # no format: no bones
    assert "bone lengths held" not in free.source["auto"]["chain"]
    assert err < 0.93 * np.sqrt(np.mean((free.positions - amc.positions) ** 2))
    assert 0.67 < src["estimated_rmse_cm"] / err < 1.5
    # a clean clip is kept as it is: nothing smoothed, nothing moved
    assert np.array_equal(get("auto").denoise(amc).positions, amc.positions)
    # positions rescaled without their skeleton (metres): the skeleton no longer describes
    # them, so no bone is held to its (cm) length
    scaled = get("auto").denoise(noisy.with_positions(noisy.positions * 0.01))
    assert "bone lengths held" not in scaled.source["auto"]["chain"]


def test_steady_spans_finds_the_joint_that_does_not_turn_and_its_true_span():
    from mocapkit.rigid import steady_spans

    rng = np.random.default_rng(1)
    T = 400
    t = np.linspace(0, 4 * np.pi, T)
    # a chain 0-1-2-3 in a plane: joint 1 bends 0-90 degrees, joint 2 holds a 10 degree bend
    a1 = np.pi / 4 * (1 - np.cos(t))
    L = np.array([20.0, 12.0, 4.0])
    ang = np.stack([0.3 * np.sin(t / 3), 0.3 * np.sin(t / 3) + a1, 0.3 * np.sin(t / 3) + a1 + np.radians(10)], axis=1)
    steps = L[None, :, None] * np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=2)
    P = np.concatenate([np.zeros((T, 1, 3)), np.cumsum(steps, axis=1)], axis=1)
    bones = np.array([[1, 0], [2, 1], [3, 2]])
    noisy = P + rng.normal(0, 0.3, P.shape)              # a cleaned pose's leftover error,
    pairs, span = steady_spans(noisy, bones, L, np.full(4, 0.4))   # within its estimate
    assert pairs.tolist() == [[3, 1]]                    # not the bending joint's span (2, 0)
    true = np.linalg.norm(P[0, 3] - P[0, 1])
    median = np.median(np.linalg.norm(noisy[:, 3] - noisy[:, 1], axis=1))
    # the de-biased bend: closer to the true span than the noisy span's median, which
    # the leftover error shortens
    assert abs(span[0] - true) < 0.5 * abs(median - true)
    assert median < true


def test_auto_holds_the_steady_spans_of_noisy_skeleton_data(amc, monkeypatch):
    from mocapkit import rigid

    noisy = corrupt.combine(amc, [("gaussian", {"sigma_cm": 3.0})], seed=3)[0]
    err = np.sqrt(np.mean((get("auto").denoise(noisy).positions - amc.positions) ** 2))
    monkeypatch.setattr(rigid, "steady_spans", lambda *a, **k: (np.zeros((0, 2), int), np.zeros(0)))
    bones_only = np.sqrt(np.mean((get("auto").denoise(noisy).positions - amc.positions) ** 2))
    assert err < 0.99 * bones_only                     # (-1.8 % on this 120 fps walk)
