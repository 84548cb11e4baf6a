"""mocapkit.corrupt: seeded determinism, masks, ratios, SNR, Xiao's rule, SLRA eq. (7)."""
from __future__ import annotations

import numpy as np
import pytest

from mocapkit import Motion, Skeleton, corrupt
from mocapkit.errors import MocapValueError

NAMES = ("root", "spine", "head", "lhumerus", "lhand", "rhumerus", "rhand",
         "lfemur", "lfoot", "rfemur", "rfoot")
PARENTS = (-1, 0, 1, 1, 3, 1, 5, 0, 7, 0, 9)
REST = np.array([[0, 90, 0], [0, 130, 0], [0, 165, 0], [-18, 140, 0], [-20, 90, 0],
                 [18, 140, 0], [20, 90, 0], [-10, 85, 0], [-10, 5, 0], [10, 85, 0], [10, 5, 0]],
                dtype=float)


def walker(T: int = 400, fps: float = 120.0, seed: int = 0) -> Motion:
    """A synthetic walker: root moves forward, limbs swing (cm)."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / fps
    P = np.repeat(REST[None], T, axis=0)
    phase = 2 * np.pi * 1.0 * t
    swing = np.array([0, 0, 0, 0, 25, 0, -25, 0, -30, 0, 30])[None, :] * np.sin(phase)[:, None]
    P[:, :, 2] += swing
    P[:, :, 1] += 2 * np.abs(np.sin(phase))[:, None]
    P[:, :, 0] += 100 * t[:, None]                          # walk along x
    P += rng.normal(scale=0.1, size=P.shape)
    return Motion(P, Skeleton.from_positions(NAMES, PARENTS, REST), fps)


@pytest.fixture(scope="module")
def clip():
    return walker()


ALL = [
    ("gaussian", {"sigma_cm": 2.0}),
    ("gaussian", {"snr_db": 20.0}),
    ("outliers", {"ratio": 0.1}),
    ("outliers", {"ratio": 0.1, "mode": "scale"}),
    ("outliers", {"ratio": 0.1, "mode": "scale", "entries": "coordinate"}),
    ("missing", {"ratio": 0.3}),
    ("missing", {"ratio": 0.3, "per_frame": False}),
    ("block_gaps", {"n_markers": 3, "length": 40, "n_blocks": 2}),
    ("slra_noise", {"n_frames": 100}),
]


def changed(a: Motion, b: Motion) -> np.ndarray:
    """(T, J) entries that differ (value changed or observed state changed)."""
    both = a.observed & b.observed
    diff = np.zeros(a.observed.shape, dtype=bool)
    diff[both] = np.any(a.positions[both] != b.positions[both], axis=1)
    return diff | (a.observed != b.observed)


@pytest.mark.parametrize("name,kw", ALL)
def test_seeded_deterministic_mask_exact_input_untouched(clip, name, kw):
    P0, O0 = clip.positions.copy(), clip.observed.copy()
    f = corrupt.STEPS[name]
    out, mask = f(clip, seed=7, **kw)
    out2, mask2 = f(clip, seed=np.random.default_rng(7), **kw)
    out3, _ = f(clip, seed=8, **kw)
    np.testing.assert_array_equal(out.positions, out2.positions)      # int seed == Generator(seed)
    np.testing.assert_array_equal(mask, mask2)
    assert not np.array_equal(out.positions, out3.positions, equal_nan=True)
    # mask: bool (T, J), exactly the entries that changed
    assert mask.dtype == bool and mask.shape == clip.observed.shape
    np.testing.assert_array_equal(mask, changed(clip, out))
    # the input is untouched, the output keeps skeleton / fps, records the step
    np.testing.assert_array_equal(clip.positions, P0)
    np.testing.assert_array_equal(clip.observed, O0)
    assert out.skeleton == clip.skeleton and out.fps == clip.fps
    assert out.source["corruption"][-1]["step"] == name
    assert "corruption" not in clip.source


def test_gaussian_sigma_and_restrictions(clip):
    out, mask = corrupt.gaussian(clip, sigma_cm=2.0, seed=0)
    assert mask.all()
    noise = out.positions - clip.positions
    assert noise.std() == pytest.approx(2.0, rel=0.03)
    assert abs(noise.mean()) < 0.05
    out, mask = corrupt.gaussian(clip, sigma_cm=2.0, seed=0, frames=slice(10, 20), joints=["lhand", 0])
    expect = np.zeros(mask.shape, dtype=bool)
    expect[10:20, [0, 4]] = True
    np.testing.assert_array_equal(mask, expect)
    np.testing.assert_array_equal(changed(clip, out), expect)
    # existing gaps are not marked and stay missing
    obs = clip.observed.copy()
    obs[:, 2] = False
    gappy = clip.with_observed(obs)
    out, mask = corrupt.gaussian(gappy, sigma_cm=1.0, seed=0)
    assert not mask[:, 2].any() and mask[:, [0, 1, 3]].all()
    assert np.isnan(out.positions[:, 2]).all()


@pytest.mark.parametrize("snr", [10.0, 20.0, 40.0])
def test_snr_achieved_on_long_clip(snr):
    m = walker(T=4000, seed=1)
    out, mask = corrupt.gaussian(m, snr_db=snr, seed=3)
    # the documented definition: root-relative signal power of the non-root joints
    rel = m.positions - m.positions[:, :1]
    p_signal = np.mean(rel[:, 1:] ** 2)
    assert corrupt.signal_power(m) == pytest.approx(p_signal)
    noise = out.positions - m.positions
    measured = 10 * np.log10(p_signal / np.mean(noise ** 2))
    assert measured == pytest.approx(snr, abs=0.2)
    assert out.source["corruption"][-1]["sigma_cm"] == pytest.approx(np.sqrt(p_signal / 10 ** (snr / 10)))


def test_outlier_ratio_and_spike_magnitude(clip):
    T, J = clip.observed.shape
    for ratio in (0.0, 0.05, 0.1, 0.25, 1.0):
        out, mask = corrupt.outliers(clip, ratio=ratio, mode="spike", magnitude_cm=12.0, seed=1)
        assert abs(int(mask.sum()) - ratio * T * J) <= 1
        d = np.linalg.norm(out.positions - clip.positions, axis=2)
        np.testing.assert_allclose(d[mask], 12.0, rtol=1e-9)
        assert np.all(d[~mask] == 0)
    # coordinate entries: exactly one coordinate per selected (t, j, axis), by ±magnitude
    out, mask = corrupt.outliers(clip, ratio=0.1, mode="spike", magnitude_cm=5.0, seed=2,
                                 entries="coordinate")
    d = out.positions - clip.positions
    n_changed = np.count_nonzero(d)
    assert abs(n_changed - 0.1 * T * J * 3) <= 1
    np.testing.assert_allclose(np.abs(d[d != 0]), 5.0, rtol=1e-9)


def test_xiao_scale_rule_exact(clip):
    T, J = clip.observed.shape
    out, mask = corrupt.outliers(clip, ratio=0.2, mode="scale", seed=4)
    assert not mask[:, 0].any()                                        # the root is never scaled
    assert abs(int(mask.sum()) - 0.2 * T * (J - 1)) <= 1               # eligible: non-root joints
    P, Q = clip.positions, out.positions
    root = P[:, :1]
    expect = np.where(mask[..., None], root + 1.4 * (P - root), P)
    np.testing.assert_allclose(Q, expect, rtol=0, atol=1e-12)
    # distance to the root grows by exactly 1.4 on the selected entries
    r0 = np.linalg.norm(P - root, axis=2)
    r1 = np.linalg.norm(Q - Q[:, :1], axis=2)
    np.testing.assert_allclose(r1[mask], 1.4 * r0[mask], rtol=1e-12)
    # coordinate entries: a selected root-relative coordinate times 1.4, others unchanged
    out, mask = corrupt.outliers(clip, ratio=0.1, mode="scale", factor=2.0, seed=5, entries="coordinate")
    relp, relq = P - root, out.positions - out.positions[:, :1]
    sel = relp != relq
    assert abs(int(sel.sum()) - 0.1 * T * (J - 1) * 3) <= 1
    np.testing.assert_allclose(relq[sel], 2.0 * relp[sel], rtol=1e-12)
    np.testing.assert_array_equal(mask, sel.any(axis=2))


def test_missing_per_frame_and_overall(clip):
    T, J = clip.observed.shape
    out, mask = corrupt.missing(clip, ratio=0.3, seed=0)
    k = round(0.3 * J)
    assert (mask.sum(axis=1) == k).all()
    assert (out.observed.sum(axis=1) == J - k).all()
    assert np.isnan(out.positions[mask]).all() and np.isfinite(out.positions[~mask]).all()
    out, mask = corrupt.missing(clip, ratio=0.3, per_frame=False, seed=0)
    assert abs(int(mask.sum()) - 0.3 * T * J) <= 1
    assert mask.sum(axis=1).std() > 0                                  # not the same count per frame
    # already-missing markers are not removed again: the count is taken from observed ones
    second, mask2 = corrupt.missing(out, ratio=0.3, seed=1)
    assert not (mask2 & mask).any()
    assert (mask2.sum(axis=1) == np.minimum(k, out.observed.sum(axis=1))).all()


def test_block_gaps_rectangles_and_whole_joints(clip):
    T, J = clip.observed.shape
    out, mask = corrupt.block_gaps(clip, n_markers=4, length=30, seed=0)
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    assert len(cols) == 4 and len(rows) == 30 and np.all(np.diff(rows) == 1)
    assert mask.sum() == 4 * 30 and mask[np.ix_(rows, cols)].all()
    # several blocks: at most n_blocks * n * L entries
    _, mask = corrupt.block_gaps(clip, n_markers=3, length=20, n_blocks=5, seed=1)
    assert 20 * 3 <= mask.sum() <= 5 * 20 * 3
    # Lou & Chai: both arms missing for the whole clip
    arms = ["lhumerus", "lhand", "rhumerus", "rhand"]
    out, mask = corrupt.block_gaps(clip, joints=arms, length=None, seed=0)
    idx = clip.skeleton.indices(arms)
    assert mask[:, idx].all() and mask.sum() == T * len(idx)
    assert not out.observed[:, idx].any() and out.observed.sum() == T * (J - len(idx))
    with pytest.raises(MocapValueError, match="gap length"):
        corrupt.block_gaps(clip, n_markers=2, length=T + 1, seed=0)
    with pytest.raises(MocapValueError, match="unknown joint"):
        corrupt.block_gaps(clip, joints=["nose"], length=5, seed=0)


def test_slra_noise_eq7(clip):
    T, J = clip.observed.shape
    out, mask = corrupt.slra_noise(clip, n_frames=150, seed=0)
    d = out.matrix() - clip.matrix()
    noisy_frames = np.flatnonzero((d != 0).any(axis=1))
    assert len(noisy_frames) == 150                                     # exactly p frames
    np.testing.assert_array_equal(np.flatnonzero(mask.any(axis=1)), noisy_frames)
    hit = d[noisy_frames] != 0
    n = hit.size
    # each coordinate of a noisy frame with probability 1/2 (eq. 7): binomial, 4 sigma
    assert abs(hit.sum() - n / 2) < 4 * np.sqrt(n / 4)
    vals = d[noisy_frames][hit]
    assert vals.mean() == pytest.approx(1.0, abs=0.05)                 # mean eps = 1
    assert vals.std() == pytest.approx(1.2, rel=0.04)                  # std sigma = 1.2
    # units: scale multiplies the noise; eps is an alias of mean
    out2, mask2 = corrupt.slra_noise(clip, n_frames=150, seed=0, scale=5.6444)
    np.testing.assert_allclose(out2.matrix() - clip.matrix(), 5.6444 * d, rtol=1e-9, atol=1e-9)
    out3, _ = corrupt.slra_noise(clip, n_frames=150, seed=0, eps=1.0)
    np.testing.assert_array_equal(out3.positions, out.positions)
    with pytest.raises(MocapValueError, match="n_frames"):
        corrupt.slra_noise(clip, n_frames=T + 1, seed=0)


def test_combine_union_and_derived_seeds(clip):
    steps = [("gaussian", {"sigma_cm": 1.0, "frames": slice(0, 50)}),
             ("outliers", {"ratio": 0.05}), ("missing", {"ratio": 0.2})]
    out, mask = corrupt.combine(clip, steps, seed=11)
    out2, mask2 = corrupt.combine(clip, steps, seed=11)
    np.testing.assert_array_equal(out.positions, out2.positions)
    # the same as applying the steps with the children of SeedSequence(seed)
    kids = np.random.SeedSequence(11).spawn(3)
    m, masks = clip, []
    for (name, kw), ss in zip(steps, kids):
        m, mk = corrupt.STEPS[name](m, seed=np.random.default_rng(ss), **kw)
        masks.append(mk)
    np.testing.assert_array_equal(m.positions, out.positions)
    np.testing.assert_array_equal(mask, masks[0] | masks[1] | masks[2])
    assert mask[:50].all()
    assert [s["step"] for s in out.source["corruption"]] == ["gaussian", "outliers", "missing"]
    # a spec string works the same way
    out3, mask3 = corrupt.combine(clip, "gaussian:sigma_cm=2,outliers:ratio=0.05,missing:ratio=0.1", seed=0)
    out4, _ = corrupt.combine(clip, [("gaussian", {"sigma_cm": 2}), ("outliers", {"ratio": 0.05}),
                                     ("missing", {"ratio": 0.1})], seed=0)
    np.testing.assert_array_equal(out3.positions, out4.positions)
    with pytest.raises(MocapValueError, match="unknown corruption"):
        corrupt.combine(clip, [("blur", {})], seed=0)
    with pytest.raises(MocapValueError, match="no parameter"):
        corrupt.combine(clip, [("gaussian", {"sigma": 1})], seed=0)
    with pytest.raises(MocapValueError, match="seed"):
        corrupt.combine(clip, [("gaussian", {"sigma_cm": 1, "seed": 3})], seed=0)


def test_parse_spec():
    assert corrupt.parse_spec("gaussian:sigma_cm=2,outliers:ratio=0.05,missing:ratio=0.1") == [
        ("gaussian", {"sigma_cm": 2}), ("outliers", {"ratio": 0.05}), ("missing", {"ratio": 0.1})]
    assert corrupt.parse_spec("outliers:ratio=0.1,mode=scale,factor=1.4; gaps:n_markers=10,length=60") == [
        ("outliers", {"ratio": 0.1, "mode": "scale", "factor": 1.4}),
        ("block_gaps", {"n_markers": 10, "length": 60})]
    assert corrupt.parse_spec("block_gaps:joints=lhumerus/rhumerus,length=none,missing:ratio=0.2,per_frame=false") == [
        ("block_gaps", {"joints": ["lhumerus", "rhumerus"], "length": None}),
        ("missing", {"ratio": 0.2, "per_frame": False})]
    for bad, msg in (("", "empty"), ("ratio=0.1", "before any step"), ("blur:x=1", "unknown corruption"),
                     ("gaussian:sigma=1", "no parameter"), ("gaussian:sigma_cm", "key=value")):
        with pytest.raises(MocapValueError, match=msg):
            corrupt.parse_spec(bad)


def test_bad_arguments(clip):
    with pytest.raises(MocapValueError, match="exactly one"):
        corrupt.gaussian(clip, sigma_cm=1, snr_db=20, seed=0)
    with pytest.raises(MocapValueError, match="exactly one"):
        corrupt.gaussian(clip, seed=0)
    with pytest.raises(MocapValueError, match="between 0 and 1"):
        corrupt.outliers(clip, ratio=1.5, seed=0)
    with pytest.raises(MocapValueError, match="mode"):
        corrupt.outliers(clip, ratio=0.1, mode="pulse", seed=0)
    with pytest.raises(MocapValueError, match="seed"):
        corrupt.missing(clip, ratio=0.1, seed="x")
    with pytest.raises(MocapValueError, match="seed"):
        corrupt.missing(clip, ratio=0.1, seed=-1)
    with pytest.raises(MocapValueError, match="Motion"):
        corrupt.missing(clip.positions, ratio=0.1, seed=0)
    with pytest.raises(TypeError):
        corrupt.missing(clip, ratio=0.1)                                # the seed is required


def test_real_cmu_clip(shared_data):
    pytest.importorskip("mocapkit.io.amc")
    from mocapkit import io
    from mocapkit.datasets import cmu_amc

    path = cmu_amc("16_15", shared_data)
    if path is None:
        pytest.skip("CMU 16_15 not in the shared data")
    m = io.read(path).slice(0, 480)
    # a walk's root-relative signal is tens of cm: 20 dB is a few cm of noise
    sigma = corrupt.snr_to_sigma(m, 20.0)
    assert 1.0 < sigma < 10.0
    out, mask = corrupt.gaussian(m, snr_db=20.0, seed=0)
    noise = out.positions - m.positions
    assert 10 * np.log10(corrupt.signal_power(m) / np.mean(noise ** 2)) == pytest.approx(20.0, abs=0.2)
    out, mask = corrupt.outliers(m, ratio=0.1, mode="scale", seed=0)
    r = m.skeleton.index(m.skeleton.names[int(np.flatnonzero(m.skeleton.parents < 0)[0])])
    root = m.positions[:, r:r + 1]
    np.testing.assert_allclose(out.positions[mask], (root + 1.4 * (m.positions - root))[mask], atol=1e-9)
