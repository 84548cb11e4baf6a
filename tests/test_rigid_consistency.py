"""Rigid partners and the distance-consistency test of mocapkit.rigid (used by auto's spike
test)."""
from __future__ import annotations

import numpy as np

from mocapkit import corrupt, io
from mocapkit.datasets import bundled
from mocapkit.rigid import distance_consistency, rigid_partners


def _clip():
    return io.read(bundled("16_15.amc")).slice(2, None)


def test_partners_are_the_bones_of_a_cmu_skeleton():
    m = _clip()
    part, real, med, scale = rigid_partners(m.positions, m.observed)
    names = list(m.skeleton.names)
    j = names.index("lfemur")                        # the knee: hip joint and ankle first
    assert {names[k] for k in part[j, :2]} == {"lhipjoint", "ltibia"}
    assert real[j, :2].all() and np.all(scale[j, :2] < 1e-3)
    B = np.linalg.norm(m.positions[:, j] - m.positions[:, part[j, 0]], axis=-1)
    assert abs(med[j, 0] - np.median(B)) < 1e-6


def test_spikes_disagree_measured_samples_agree():
    m = _clip()
    noisy = corrupt.combine(m, [("outliers", {"ratio": 0.1, "magnitude_cm": 15.0})], seed=3)[0]
    spike = np.linalg.norm(noisy.positions - m.positions, axis=-1) > 1e-9
    agree, disagree, pinned = distance_consistency(noisy.positions, noisy.observed)
    # a 15 cm spike in a random direction breaks at least one bone length ...
    assert (disagree[spike] >= 1).mean() > 0.99
    # ... and a measured sample breaks none unless a partner is itself a spike there, or a
    # "rigid" pair is not quite rigid: finger and thumb keep their distance in most frames
    # (MAD 0) but not all (here 6 of 8,831 samples)
    part, real, _, _ = rigid_partners(noisy.positions, noisy.observed)
    partner_spiked = (spike[:, part] & real).any(axis=2)
    clean = ~spike & ~partner_spiked
    assert (disagree[clean] > 0).mean() < 1e-3
    assert (agree[clean] >= 1).all()
    assert not (pinned & spike & (disagree == 0)).any()


def test_unobserved_samples_count_nothing():
    m = _clip()
    obs = m.observed.copy()
    obs[10:20, 5] = False
    P = np.array(m.positions)
    P[10:20, 5] = np.nan
    agree, disagree, _ = distance_consistency(P, obs)
    assert (agree[10:20, 5] == 0).all() and (disagree[10:20, 5] == 0).all()


def test_distance_noise_reads_zero_on_joint_data_and_the_noise_on_noisy_data():
    from mocapkit.rigid import distance_noise
    m = _clip()
    assert distance_noise(m.positions, m.observed) < 1e-6      # FK positions: rigid bones
    for sigma in (0.1, 0.5):
        noisy = corrupt.combine(m, [("gaussian", {"sigma_cm": sigma})], seed=1)[0]
        est = distance_noise(noisy.positions, noisy.observed)
        assert 0.95 * sigma < est < 1.05 * sigma                 # cross-fitted: no low bias
    # spikes on 10 % of the samples (19 % of the pairs) raise the robust scale by ~20 %;
    # masked out (as auto passes only the samples it kept) they are gone
    noisy = corrupt.combine(m, [("gaussian", {"sigma_cm": 0.2})], seed=2)[0]
    spiky = corrupt.combine(noisy, [("outliers", {"ratio": 0.1, "magnitude_cm": 15.0})], seed=2)[0]
    spike = np.linalg.norm(spiky.positions - noisy.positions, axis=-1) > 1e-9
    assert 0.2 < distance_noise(spiky.positions, spiky.observed) < 0.26
    assert 0.17 < distance_noise(spiky.positions, spiky.observed & ~spike) < 0.205


def test_distance_noise_needs_partners():
    from mocapkit.rigid import distance_noise
    rng = np.random.default_rng(0)
    P = np.cumsum(5.0 * rng.normal(size=(200, 4, 3)), axis=0)   # 4 independent random walks
    assert np.isnan(distance_noise(P, np.ones((200, 4), bool)))
    # a pair that is not quite rigid counts as noise: an upper bound, never a false zero
    P[:, 1] = P[:, 0] + [10.0, 0.0, 0.0] + np.cumsum(0.05 * rng.normal(size=(200, 3)), axis=0)
    P[:, 3] = P[:, 2] + [10.0, 0.0, 0.0] + np.cumsum(0.05 * rng.normal(size=(200, 3)), axis=0)
    assert distance_noise(P, np.ones((200, 4), bool)) > 0.05


def test_steady_clusters_find_a_noisy_rigid_body_and_not_a_swinging_limb():
    """Under 2 cm of noise a rigid body of five points turning is found; a limb swinging
    about a point near the body keeps its distances to the body's points within a
    fraction of a centimetre while it leaves any rigid fit of them -- the fit's residual
    leaves it out; hold_clusters then cuts the body's error."""
    from mocapkit.rigid import hold_clusters, steady_clusters

    rng = np.random.default_rng(3)
    T = 600
    t = np.arange(T) / 120.0
    body = np.array([[0, 0, 0], [12, 0, 0], [0, 10, 0], [6, 5, 0.5], [-6, 4, 0.2]])   # nearly flat
    c, s = np.cos(0.6 * t), np.sin(0.6 * t)
    R = np.stack([np.stack([c, -s, 0 * t], 1), np.stack([s, c, 0 * t], 1), np.tile([0.0, 0, 1], (T, 1))], 1)
    truth_body = np.einsum("tij,kj->tki", R, body)
    # a limb 40 cm long swinging out of the body's plane about its first point
    a = 0.8 * np.sin(2 * np.pi * 0.7 * t)
    limb = np.stack([np.full(T, 2.0), 1.0 + 40 * np.sin(a), -40 * np.cos(a)], 1)
    truth = np.concatenate([truth_body, np.einsum("tij,tj->ti", R, limb)[:, None]], axis=1)
    noisy = truth + rng.normal(0, 2.0, truth.shape)
    groups = steady_clusters(noisy, np.ones((T, 6), bool), 120.0, 0.3)
    assert groups == [[0, 1, 2, 3, 4]]
    held = hold_clusters(noisy, groups)
    err = lambda P: float(np.sqrt(np.mean((P[:, :5] - truth[:, :5]) ** 2)))
    assert err(held) < 0.8 * err(noisy)
    assert np.array_equal(held[:, 5], noisy[:, 5])
