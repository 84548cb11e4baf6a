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
