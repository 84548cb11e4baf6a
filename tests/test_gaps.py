"""The gap policy (mocapkit.gaps), the Denoiser guard, and fill-auto."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from mocapkit import denoise, gaps, io
from mocapkit.datasets import bundled
from mocapkit.errors import MocapValueError
from mocapkit.motion import Motion
from mocapkit.skeleton import Skeleton


def _markers(P: np.ndarray, fps: float = 100.0) -> Motion:
    J = P.shape[1]
    sk = Skeleton(tuple(f"M{j}" for j in range(J)), -np.ones(J, dtype=int), np.zeros((J, 3)))
    return Motion(P, sk, fps, source={"format": "c3d"})


def _walker(T: int = 400, J: int = 8, seed: int = 0) -> np.ndarray:
    """A rigid-ish marker cloud walking 4 m along x with some sway (cm)."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / 100.0
    base = rng.normal(0, 20, (J, 3)) + [0, 0, 100]
    sway = 5 * np.sin(2 * np.pi * 1.0 * t)[:, None, None] * rng.normal(0, 1, (1, J, 3))
    P = base[None] + sway
    P[..., 0] += 100 * t[:, None]
    return P


def test_find_gaps_kinds_and_lengths():
    obs = np.ones((10, 3), bool)
    obs[2:5, 0] = False                # interior, 3
    obs[:4, 1] = False                 # leading, 4
    obs[8:, 1] = False                 # trailing, 2
    obs[:, 2] = False                  # never
    g = gaps.find_gaps(obs)
    assert [(x.joint, x.start, x.stop, x.kind) for x in g] == [
        (0, 2, 5, "interior"), (1, 0, 4, "leading"), (1, 8, 10, "trailing"), (2, 0, 10, "never")]
    length, interior = gaps.gap_lengths(obs)
    assert length[3, 0] == 3 and length[0, 1] == 4 and length[9, 1] == 2 and length[5, 2] == 10
    assert length[0, 0] == 0
    assert interior[2:5, 0].all() and not interior[:4, 1].any() and not interior[:, 2].any()


def test_supported_interp_vs_markers_and_max_gap():
    obs = np.ones((100, 5), bool)
    obs[:30, 0] = False                # leading gap 0.3 s at 100 fps
    obs[40:60, 1] = False              # interior 0.2 s
    obs[:, 2] = False                  # never observed
    s_int = gaps.supported(obs, 100.0, "interp")
    s_mk = gaps.supported(obs, 100.0, "markers")
    assert not s_int[:30, 0].any() and s_int[40:60, 1].all()          # no extrapolation
    assert s_mk[:30, 0].all() and s_mk[40:60, 1].all()                  # other markers seen
    assert not s_int[:, 2].any() and not s_mk[:, 2].any()              # never observed: never
    with gaps.use_policy(max_gap_s=0.1):
        assert not gaps.supported(obs, 100.0, "markers")[40:60, 1].any()
    with gaps.use_policy(gaps.FILL_ALL):
        s_all = gaps.supported(obs, 100.0, "interp")
        assert s_all[:30, 0].all() and not s_all[:, 2].any()
    with pytest.raises(MocapValueError):
        gaps.GapPolicy(max_gap_s=0)


def test_fill_never_observed_rule():
    X = np.array([[np.nan, 1.0], [np.nan, np.nan], [np.nan, 3.0], [np.nan, np.nan]])
    m = np.isfinite(X)
    for kind in ("linear", "cubic"):
        Y = gaps.fill(X, m, kind=kind)
        assert np.isnan(Y[:, 0]).all()                    # never observed: stays missing
        assert np.allclose(Y[:, 1], [1, 2, 3, 3])
    assert np.allclose(gaps.fill(X, m, ends="nan")[:3, 1], [1, 2, 3])
    assert np.isnan(gaps.fill(X, m, ends="nan")[3, 1])
    assert np.isnan(gaps.fill(X, m, ends="linear")[:, 0]).all()
    # a solver's finite start asks for it explicitly
    assert (gaps.fill(X, m, never_observed=0.0)[:, 0] == 0).all()
    assert np.allclose(gaps.fill(X, m, never_observed=0.0)[:, 1], [1, 2, 3, 3])


def test_kalman_cv_does_not_extrapolate_an_edge_gap():
    """The 0.1 failure: a marker hidden for the last 2 s of a walk was extrapolated at
    constant velocity; now it is left missing and reported."""
    P = _walker()
    obs = np.ones(P.shape[:2], bool)
    obs[200:, 0] = False
    m = _markers(P).with_observed(obs)
    out = denoise.get("kalman-cv").denoise(m)
    assert not out.observed[210:, 0].any()
    rep = out.source["gap_report"]
    assert rep["left_unsupported"] >= 190 and rep["method"] == "kalman-cv"
    assert "without evidence" in gaps.summary_line(rep)


def test_fills_outside_the_volume_or_body_are_left_missing():
    P = _walker()
    obs = np.ones(P.shape[:2], bool)
    obs[100:300, 0] = False
    m = _markers(P).with_observed(obs)

    class Wild(denoise.base.Denoiser):
        name = "test-wild-fill"
        fill_evidence = "markers"

        def denoise(self, motion):
            Q = np.nan_to_num(np.array(motion.positions))
            Q[~motion.observed] = 1e5                   # 1 km away
            return motion.with_positions(Q)

    out = Wild().denoise(m)
    assert not out.observed[100:300, 0].any()
    assert out.source["gap_report"]["left_implausible"] == 200


def test_filled_flags_and_report():
    P = _walker()
    obs = np.ones(P.shape[:2], bool)
    obs[100:120, 3] = False
    m = _markers(P).with_observed(obs)
    out = denoise.get("linear").denoise(m)
    assert out.observed.all()
    assert np.array_equal(out.filled, ~obs)
    rep = out.source["gap_report"]
    assert rep["filled"] == 20 and rep["left_missing"] == 0
    assert rep["longest_filled_s"] == pytest.approx(0.2)
    # flags survive slicing / selection, and a second pass keeps the first one's flags
    assert out.slice(100, 110).filled[:, 3].all() and not out.slice(100, 110).filled[:, :3].any()
    again = denoise.get("gaussian").denoise(out)
    assert np.array_equal(again.filled, out.filled)


def test_guard_recentres_far_away_data_exactly():
    clip = io.read(bundled("16_15.amc")).slice(0, 120)
    far = clip.with_positions(clip.positions + 1e4)
    for name in ("gaussian", "kalman-cv"):
        a = denoise.get(name).denoise(clip).positions
        b = denoise.get(name).denoise(far).positions
        assert np.allclose(b - 1e4, a, atol=1e-6)


def test_never_observed_joint_left_missing():
    clip = io.read(bundled("16_15.amc")).slice(0, 120)
    obs = clip.observed.copy()
    obs[:, 5] = False
    out = denoise.get("spline").denoise(clip.with_observed(obs))
    assert not out.observed[:, 5].any() and np.isnan(out.positions[:, 5]).all()
    assert out.observed[:, np.arange(clip.n_joints) != 5].all()
    assert out.source["gap_report"]["never_observed"] == [clip.skeleton.names[5]]


def test_fill_auto_chooses_per_gap_and_keeps_observed():
    P = _walker(T=600, J=10)
    obs = np.ones(P.shape[:2], bool)
    obs[100:104, 2] = False            # short interior gap
    obs[300:420, 5] = False            # long interior gap
    m = _markers(P).with_observed(obs)
    out = denoise.get("fill-auto").denoise(m)
    assert np.array_equal(out.positions[obs], P[obs])        # measured samples untouched
    assert out.observed[100:104, 2].all()
    info = out.source["fill_auto"]
    assert info["gaps"] == 2 and info["estimated_rmse_cm"] is not None
    def rmse(o):
        return float(np.sqrt(np.mean((o.positions[~obs] - P[~obs]) ** 2)))

    with gaps.use_policy(validate_cm=None):                  # (the 120-frame gap validates over 5 cm)
        singles = {n: rmse(denoise.get(n).denoise(m)) for n in ("linear", "spline")}
    assert rmse(out) <= 1.05 * min(singles.values())         # per-gap choice: no worse than the best
    assert sum(out.source["gap_report"]["filled_by"].values()) == out.source["gap_report"]["filled"]


def test_fill_auto_does_not_fail_a_fill_on_a_stretch_its_evidence_misses():
    """An ankle's 60-frame gap in a CMU walk while the foot has a gap of its own just
    after it: the stretch fill-auto hides after the ankle's gap has no foot, so the
    kinematic fill cannot cover it. That round leaves it unjudged (it was failed, and a
    pattern fill 2.4 cm off took the gap); the stretch before the gap judges it."""
    from mocapkit.denoise.fill_auto import _coverage

    clip = io.read(bundled("16_15.amc")).slice(2, None)
    ankle, foot = clip.skeleton.names.index("ltibia"), clip.skeleton.names.index("lfoot")
    obs = clip.observed.copy()
    obs[300:360, ankle] = False
    obs[370:430, foot] = False
    out = denoise.get("fill-auto").denoise(clip.with_observed(obs))
    e = np.sqrt(np.mean((out.positions[300:360, ankle] - clip.positions[300:360, ankle]) ** 2))
    assert e < 1.0, e
    assert out.source["fill_auto"]["chosen"].get("fill-kinematic", 0) >= 1
    # the coverage helper against a plain per-gap count
    found = [g for g in gaps.find_gaps(obs) if g.kind != "never"]
    rng = np.random.default_rng(0)
    fills = [np.where(rng.random(clip.positions.shape[:2])[..., None] < p, np.nan, clip.positions)
             for p in (0.0, 0.45, 0.55, 1.0)]
    ref = np.array([[np.isfinite(X[g.start:g.stop, g.joint]).all(axis=1).mean() >= 0.5 for X in fills]
                    for g in found])
    assert np.array_equal(_coverage(fills, found), ref)


def test_fill_auto_leaves_gaps_it_cannot_validate_below_threshold():
    rng = np.random.default_rng(1)
    P = _walker(T=400, J=6)
    P[:, 0] += rng.normal(0, 30, (400, 3))       # a marker that jumps about: nothing predicts it
    obs = np.ones(P.shape[:2], bool)
    obs[150:190, 0] = False
    out = denoise.get("fill-auto", max_error_cm=5.0).denoise(_markers(P).with_observed(obs))
    assert not out.observed[150:190, 0].any()
    assert out.source["fill_auto"]["left_gaps"] == 1


def test_fill_auto_does_not_stretch_interpolation_scores_over_a_far_longer_gap():
    """A marker unseen for 10 s, no stretch of its own to hide and no neighbour seen
    throughout: the other markers' 20-frame gaps, which interpolation fills well, are no
    licence to interpolate it (the basket sprint's hand-held Sync marker: 14.7 s filled by
    linear interpolation on the score of gaps of at most 320 frames). It is left missing;
    the short gaps are still filled. Cross-marker fills keep the file-wide score at any
    length (their error does not grow with the gap's)."""
    from mocapkit.denoise.fill_auto import POOL_REACH_BINS, _pooled

    P = _walker(T=1200, J=8)
    obs = np.ones(P.shape[:2], bool)
    obs[100:1100, 0] = False
    for j in range(1, 8):
        obs[200 + 100 * j:220 + 100 * j, j] = False
    m = _markers(P).with_observed(obs)
    out = denoise.get("fill-auto", candidates=("linear", "spline"), max_error_cm=5.0).denoise(m)
    assert not out.observed[100:1100, 0].any() and np.isnan(out.positions[100:1100, 0]).all()
    assert out.observed[:, 1:].all()
    info = out.source["fill_auto"]
    assert info["left_gaps"] == 1 and info["unvalidated_gaps"] == 1
    # the rule itself: a gap with no score of its own, 16 and 64 frames, the pool from 16-frame gaps
    g = [gaps.Gap(0, 0 + 100 * i, 16 + 100 * i, "interior") for i in range(3)] + \
        [gaps.Gap(1, 500, 500 + 16 * 2 ** (POOL_REACH_BINS + 1), "interior")]
    err = np.array([[1.0, 1.0], [1.0, 1.0], [np.nan, np.nan], [np.nan, np.nan]])
    n = np.array([[16.0, 16.0], [16.0, 16.0], [0, 0], [0, 0]])
    got = _pooled(err, n, g, 20.0, np.array([True, False]))
    assert got[2, 0] == got[2, 1] == 1.0              # as long as the validated ones: pooled
    assert np.isnan(got[3, 0]) and got[3, 1] == 1.0   # 4x longer: interpolation unvalidated


def test_fill_auto_does_not_lend_interpolation_scores_to_a_flickering_marker(monkeypatch):
    """A marker seen one frame in eleven around its gaps: the file's other gaps, each with
    its length seen on both sides, are no licence to interpolate between its isolated
    samples (the tennis serve under the basket sprint's mask: splines through a flickering
    hand 1 m off). Its gaps are left missing; the well-seen gaps are still filled."""
    from mocapkit.denoise.fill_auto import POOL_SUPPORT, _pooled, side_support

    P = _walker(T=600, J=6)
    t = np.arange(600) / 100.0
    P[:, 0] += 40 * np.sin(2 * np.pi * 3 * t)[:, None] * [1, 0, 0]     # a fast swing
    obs = np.ones(P.shape[:2], bool)
    obs[200:300, 0] = False
    obs[200:300:11, 0] = True                       # seen one frame in eleven
    obs[205:300:11, 1:] = False                     # the others blink within its gaps: no
    for j in range(1, 6):                           # neighbour is seen throughout one
        obs[60 * j:60 * j + 3, j] = False
    m = _markers(P).with_observed(obs)
    found = [g for g in gaps.find_gaps(obs) if g.kind != "never"]
    seen = side_support(obs, found) >= POOL_SUPPORT
    assert not seen[[g.joint == 0 for g in found]].any() and seen[[g.joint > 0 for g in found]].all()
    fa = denoise.get("fill-auto", candidates=("linear", "spline"), max_error_cm=5.0)
    out = fa.denoise(m)
    inner = ~obs[212:287, 0]                         # the gaps with no stretch of their own
    assert not out.observed[212:287, 0][inner].any()
    with monkeypatch.context() as mp:                # the rule off: the pool fills them
        mp.setattr("mocapkit.denoise.fill_auto.POOL_SUPPORT", 0.0)
        assert fa.denoise(m).observed[212:287, 0][inner].all()
    assert out.observed[:, 1:].all()                 # the others' gaps: seen on both sides
    # the rule itself: an unscored gap takes the pool where its marker is seen, not elsewhere
    g = [gaps.Gap(0, 100 * i, 100 * i + 4, "interior") for i in range(3)]
    err = np.array([[1.0, 1.0], [np.nan, np.nan], [np.nan, np.nan]])
    n = np.array([[4.0, 4.0], [0, 0], [0, 0]])
    got = _pooled(err, n, g, 20.0, np.array([True, False]), np.array([True, True, False]))
    assert got[1, 0] == got[1, 1] == 1.0
    assert np.isnan(got[2, 0]) and got[2, 1] == 1.0     # bounded candidate: unvalidated


def test_fill_auto_estimate_charges_pooled_fills_more(monkeypatch):
    """A fill no stretch of its own gap judged is charged the file's score for gaps like it
    times POOLED_ESTIMATE (1.5 interior, 1.8 edge: what such fills were off by against it on
    real occlusions); fills judged on their own stretches keep their own score; the choice
    and the fills themselves do not change."""
    from mocapkit.denoise.fill_auto import POOLED_ESTIMATE

    P = _walker(T=1200, J=8)
    obs = np.ones(P.shape[:2], bool)
    obs[100:1100, 0] = False                        # interior, no stretch of its own
    obs[700:990, 3] = False                         # judged on its own stretches ...
    obs[1000:, 3] = False                           # ... this edge gap is not
    for j in (1, 2, 4, 5, 6, 7):
        obs[200 + 100 * j:220 + 100 * j, j] = False
        obs[1120:1150, j] = False
    m = _markers(P).with_observed(obs)
    fa = denoise.get("fill-auto", candidates=("linear", "spline", "fill-pca"), max_error_cm=5.0)
    out = fa.denoise(m)
    with monkeypatch.context() as mp:
        mp.setattr("mocapkit.denoise.fill_auto.POOLED_ESTIMATE", (1.0, 1.0))
        plain = fa.denoise(m)
    np.testing.assert_array_equal(out.positions, plain.positions)
    rep, rep0 = out.source["fill_auto"], plain.source["fill_auto"]
    emap, emap0, pooled = rep["error_map"], rep0["error_map"], rep["pooled_map"]
    have = np.isfinite(emap)
    assert have[150:1050, 0].all() and pooled[150:1050, 0].all()
    edge = have[1000:, 3]                            # (not where the other markers blink too)
    assert edge.sum() > 100 and pooled[1000:, 3][edge].all()
    np.testing.assert_allclose(emap[150:1050, 0], POOLED_ESTIMATE[0] * emap0[150:1050, 0])
    np.testing.assert_allclose(emap[1000:, 3][edge], POOLED_ESTIMATE[1] * emap0[1000:, 3][edge])
    own = have & ~pooled
    assert own[700:990, 3].all()
    np.testing.assert_array_equal(emap[own], emap0[own])
    assert rep["estimated_rmse_cm"] > rep0["estimated_rmse_cm"]


def test_fills_off_a_rigid_partner_are_left_missing():
    """The gap policy's rigid check: a fill more than rigid_margin_cm off the distance span
    a rigid partner measured in its frame keeps is left missing (it is that far off at
    least); one within it is kept; a pair that bends in a few frames -- steady most of the
    clip, as a knee of a subject standing still -- is no rigid pair."""
    rng = np.random.default_rng(0)
    T = 300
    plate = rng.normal(0, 5, (4, 3))                          # a 4-marker plate, ~5-10 cm
    path = np.cumsum(rng.normal(0, 1, (T, 3)), axis=0) + [0, 0, 100]
    P = path[:, None, :] + plate[None]
    knee = path + [0, 0, -40.0]
    knee[140:150] += [0, 30.0, 0]                            # bends in 10 of 300 frames
    P = np.concatenate([P, knee[:, None]], axis=1)            # (T, 5, 3)
    obs = np.ones((T, 5), bool)
    obs[100:110, 0] = False                                   # plate marker 0: a gap
    obs[200:210, 4] = False                                   # the "knee": a gap
    fills = P.copy()
    fills[100:105, 0] += [15.0, 0, 0]                         # 15 cm off: broken
    fills[105:110, 0] += [0, 5.0, 0]                          # 5 cm off: within the margin
    fills[200:210, 4] += [0, 0, 25.0]                         # the knee: no rigid partner
    miss = ~obs
    flag = gaps.off_rigid_partners(P, obs, miss, 10.0, values=fills, has=np.ones((T, 5), bool))
    assert flag[100:105, 0].all() and not flag[105:110, 0].any() and not flag[200:210, 4].any()
    # through a method and the policy: the broken fill is reported, the rest kept
    m = _markers(P).with_observed(obs)
    out = gaps.apply_policy(m, Motion(fills, m.skeleton, m.fps), evidence="markers", method="test")
    assert not out.observed[100:105, 0].any() and out.observed[105:110, 0].all()
    assert out.source["gap_report"]["left_implausible"] == 5
    with gaps.use_policy(rigid_margin_cm=None):
        assert gaps.apply_policy(m, Motion(fills, m.skeleton, m.fps), evidence="markers",
                                 method="test").observed.all()


def test_fills_out_of_the_markers_reach_are_left_missing():
    """The gap policy's speed check: fills cut off from the measured samples by steps the
    capture's own speed can not make (two fills taking turns) are dropped; a run joined to
    both ends with such a step left in it (a drift that arrives 60 cm off) is dropped
    whole; a fill that joins its ends smoothly is kept, however long."""
    rng = np.random.default_rng(1)
    T = 400
    P = np.cumsum(rng.normal(0, 0.5, (T, 3, 3)), axis=0) + [0, 0, 100]     # ~1 cm/frame, no rigid pairs
    obs = np.ones((T, 3), bool)
    obs[50:80, 0] = obs[150:250, 0] = obs[300:320, 0] = False
    obs[100:130, 1] = False
    fills = P.copy()                                          # the true path everywhere ...
    fills[150:250:2, 0] += [25.0, 0, 0]                       # ... but two fills taking turns 25 cm apart
    fills[300:320, 0] += np.linspace(0, 60, 20)[:, None]      # drifts, arrives 60 cm off
    v = gaps.capture_speed(P, obs)
    assert 0.5 < v < 5
    flag = gaps.unreachable_fills(P, obs, ~obs, 3.0, values=fills)
    assert not flag[50:80, 0].any() and not flag[100:130, 1].any()      # smooth: kept
    assert flag[150:249, 0].all() and flag[300:320, 0].all()           # dropped whole
    assert not flag[249, 0]                          # the last (true) one joins the data
    m = _markers(P).with_observed(obs)
    out = gaps.apply_policy(m, Motion(fills, m.skeleton, m.fps), evidence="markers", method="test")
    assert out.observed[50:80, 0].all() and not out.observed[150:249, 0].any()
    assert out.source["gap_report"]["left_implausible"] == 119
    assert out.source["gap_report"]["left_implausible_by"] == {"out of the marker's reach": 119}
    assert "119 implausible: 119 out of the marker's reach" in gaps.summary_line(out.source["gap_report"])
    with gaps.use_policy(speed_factor=None):
        assert gaps.apply_policy(m, Motion(fills, m.skeleton, m.fps), evidence="markers",
                                 method="test").observed.all()
    with pytest.raises(MocapValueError, match="speed_factor"):
        gaps.GapPolicy(speed_factor=0)


def test_measured_samples_moved_without_a_spike_are_written_as_measured():
    """A method may clean measured samples, not replace them: a stretch moved 20 cm where
    the capture is smooth is given back (with a warning and a count); a spike it removed,
    and a 1 cm smoothing, stay as the method wrote them."""
    from mocapkit.errors import MeasuredKeptWarning

    rng = np.random.default_rng(2)
    T = 300
    P = np.cumsum(rng.normal(0, 0.3, (T, 3, 3)), axis=0) + [0, 0, 100]
    noisy = P.copy()
    noisy[100, 1] += [15.0, 0, 0]                              # a spike in the input
    res = P + rng.normal(0, 0.3, P.shape)                       # the method's smoothing
    res[50:80, 0] += [0, 20.0, 0]                               # moves a smooth stretch
    obs = np.ones((T, 3), bool)
    back = gaps.moved_without_cause(noisy, obs, res, 5.0, 0.1)
    assert back[50:80, 0].all() and back.sum() == 30            # the spike's removal is not
    # samples without four measured neighbours: one between gaps thrown 30 cm away from
    # both its measured neighbours goes back; a spike on frame 0 pulled to the path stays
    obs2 = obs.copy()
    obs2[195:200, 2] = obs2[201:206, 2] = False
    res2, noisy2 = res.copy(), noisy.copy()
    res2[200, 2] += [0, 0, 30.0]
    noisy2[0, 2] += [15.0, 0, 0]                               # the method removed it (res = P)
    back2 = gaps.moved_without_cause(noisy2, obs2, res2, 5.0, 0.1)
    assert back2[200, 2] and not back2[0, 2]
    dev = gaps.neighbour_deviation(noisy, obs)
    assert dev[100, 1] > 10 and np.isnan(dev[:2]).all() and np.nanmedian(dev) < 1
    m = _markers(noisy)
    with pytest.warns(MeasuredKeptWarning, match="30 measured samples of 1 markers"):
        out = gaps.apply_policy(m, Motion(res, m.skeleton, m.fps), evidence="markers", method="test")
    assert np.array_equal(out.positions[50:80, 0], noisy[50:80, 0])
    assert np.array_equal(out.positions[100, 1], res[100, 1])
    assert out.source["gap_report"]["kept_measured"] == 30
    with gaps.use_policy(move_margin_cm=None):
        out = gaps.apply_policy(m, Motion(res, m.skeleton, m.fps), evidence="markers", method="test")
    assert np.array_equal(out.positions, res)


def test_the_default_on_marker_files_is_auto_which_hands_clean_gaps_to_fill_auto():
    """auto is the default for marker files too: on a clean capture it keeps the measured
    samples and its fill of gaps of 3 frames and more is fill-auto's; a noisy one it
    cleans, where fill-auto (the marker default until 2026-12-05) left the noise."""
    from mocapkit import corrupt, metrics

    P = _walker()
    assert denoise.is_marker_capture(_markers(P))
    assert not denoise.is_marker_capture(io.read(bundled("16_15.amc")))
    obs = np.ones(P.shape[:2], bool)
    obs[100:130, 1] = False
    obs[200:202, 3] = False                                   # 2 frames: the spline chain
    m = _markers(P).with_observed(obs)
    out = denoise.default().denoise(m)
    fa = denoise.get("fill-auto").denoise(m)
    assert "fill-auto" in out.source["auto"]["chain"]
    assert np.array_equal(out.positions[obs], P[obs])
    np.testing.assert_allclose(out.positions[100:130, 1], fa.positions[100:130, 1], atol=1e-9)
    noisy, _ = corrupt.combine(_markers(P), [("gaussian", {"sigma_cm": 1.0})], seed=0)
    cleaned = denoise.default().denoise(noisy)
    assert metrics.rmse(_markers(P), cleaned) < 0.7 * metrics.rmse(_markers(P), noisy)


def _write_c3d_with_gaps(tmp_path):
    P = _walker(T=300, J=8)
    obs = np.ones(P.shape[:2], bool)
    obs[100:130, 1] = False            # interior gap
    obs[250:, 2] = False               # trailing gap
    src = tmp_path / "raw.c3d"
    io.write(_markers(P).with_observed(obs), src)
    return src, P, obs


def test_cli_default_on_a_marker_file_fills_from_evidence_and_says_so(tmp_path, capsys):
    from mocapkit.cli import main

    src, P, obs = _write_c3d_with_gaps(tmp_path)
    dst = tmp_path / "clean.c3d"
    assert main(["denoise", str(src), str(dst)]) == 0
    text = capsys.readouterr().out
    assert "fill-auto" in text and "filled" in text and "estimated error" in text
    out = io.read(dst)
    assert out.observed[100:130, 1].all()
    assert np.array_equal(out.filled, out.observed & ~obs)        # C3D residual 0 = filled
    assert np.allclose(out.positions[obs], P[obs], atol=1e-3)     # measured samples untouched
    # info --gaps on the input
    assert main(["info", str(src), "--gaps"]) == 0
    table = capsys.readouterr().out
    assert "longest(s)" in table and "M2" in table


def test_cli_max_gap_leaves_long_gaps_missing(tmp_path, capsys):
    from mocapkit.cli import main

    src, P, obs = _write_c3d_with_gaps(tmp_path)
    dst = tmp_path / "clean.c3d"
    assert main(["denoise", str(src), str(dst), "--method", "linear", "--max-gap", "0.1"]) == 0
    assert "beyond --max-gap 0.1 s" in capsys.readouterr().out
    out = io.read(dst)
    assert not out.observed[100:130, 1].any() and not out.observed[250:, 2].any()
    with pytest.raises(SystemExit) as e:                           # argparse: one line, exit 2
        main(["denoise", str(src), str(tmp_path / "x.c3d"), "--max-gap", "-1"])
    assert e.value.code == 2


@pytest.mark.parametrize("method", ["auto", "rpca", "kalman-cv", "tsmc"])
def test_real_capture_writes_no_jump_and_no_moved_arm(shared_data, method):
    """kineticstoolkit's basket sprint, frames 1800-3000 (the forearm plate hidden for
    270 frames, wheelchair markers seen for single frames): whatever the method, no written
    fill is reached by a step over the policy's allowance (auto's fill there once switched
    between candidates 200 cm apart), and the samples given back are counted and warned
    of (rpca had moved measured samples of the whole file by up to 166 cm)."""
    from mocapkit import cli
    from mocapkit.errors import MeasuredKeptWarning, ModelMisfitWarning
    from mocapkit.swaps import repair_labels

    path = shared_data / "markers" / "kineticstoolkit" / "kinematics_basket_sprint.c3d"
    if not path.exists():
        pytest.skip("basket sprint not in the data set")
    m = io.read(path).slice(1800, 3000)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = cli._method(method, {}, None, m, True).denoise(m)
    new = out.observed & ~m.observed
    assert new.any()
    assert not gaps.unreachable_fills(m.positions, m.observed, new, 3.0, values=out.positions).any()
    lo, hi = gaps.capture_volume(m.positions, m.observed)
    assert not (new & gaps.outside_volume(out.positions, lo, hi, 100.0)).any()
    rep = out.source["gap_report"]
    # (a model-based method's misfit line names the markers moved far too: one line)
    warned = [w for w in caught if issubclass(w.category, (MeasuredKeptWarning, ModelMisfitWarning))]
    assert (rep["kept_measured"] + rep["kept_measured_misfit"] > 0) == bool(warned)
    if method == "auto":
        assert rep["kept_measured"] == 0
        # measured samples written as measured -- after the label repairs every method sees
        # (ForearmL:Marker1/4 exchanged at frames 2439-2459 between shared gaps go back)
        fixed, swaps = repair_labels(m)
        assert any(r["start"] == 2439 - 1800 for r in swaps["repaired"])
        assert np.array_equal(out.positions[fixed.observed], fixed.positions[fixed.observed])
        # the estimate covers what is written: rescored over the fills the policy kept
        src = out.source["auto"]
        assert rep["left_implausible"] > 0 and "estimate_map" not in src
        assert src["estimated_rmse_cm"] != src["estimated_rmse_cm_before_policy"]
    if method == "rpca":                 # 1,747 measured samples given back (2026-12-05)
        assert rep["kept_measured"] > 1000


def test_fill_auto_estimate_is_rescored_over_what_is_written():
    """fill-auto's estimate is the RMS of the validated error of each written fill: fills
    the gap policy then drops are no longer charged."""
    from mocapkit.denoise.fill_auto import rescored

    emap = np.full((10, 2), np.nan)
    emap[2:6, 0] = 1.0
    emap[6:8, 1] = 4.0                         # a worse fill the policy drops
    rep = {"estimated_rmse_cm": float(np.sqrt(np.mean(emap[np.isfinite(emap)] ** 2))),
           "error_map": emap}
    written = np.ones((10, 2), bool)
    assert rescored(rep, written) is rep                     # nothing dropped: unchanged
    written[6:8, 1] = False
    got = rescored(rep, written)
    assert got["estimated_rmse_cm"] == pytest.approx(1.0) and got["estimated_rmse_cm_before_policy"] == rep["estimated_rmse_cm"]


def test_a_plate_seen_for_one_frame_keeps_its_shape():
    """A marker measured alone between long gaps that a method moves towards its next
    measurement (no neighbour in time can judge it) is given back when it kept the
    distance to a rigid partner measured in that frame and the method's value breaks it."""
    T = 300
    path = np.arange(T)[:, None] * np.array([1.0, 0, 0]) + [0, 0, 100]        # 1 cm / frame
    P = path[:, None, :] + np.array([[0, 0, 0], [8.0, 0, 0], [0, 6.0, 0]])   # a plate
    obs = np.ones((T, 3), bool)
    obs[100:150, 0] = obs[151:200, 0] = False                 # marker 0 seen once, frame 150
    res = P.copy()
    res[150, 0] += [24.0, 0, 0]            # half way to its next measurement, off its plate
    assert gaps.moved_without_cause(P, obs, res, 5.0)[150, 0]
    ok = P.copy()
    ok[150, 0] += [0, 0, 15.0]                                 # the input itself off its plate
    assert not gaps.moved_without_cause(ok, obs, P, 5.0)[150, 0]


def test_a_limb_thrown_with_its_partner_is_not_given_back():
    """A tracker glitch that throws two rigid partners 30 cm together for two frames
    (MSR-Action3D's Kinect wrist and hand): the method's partial correction leaves both
    input and result rough there, and the partners' kept distance is no evidence that the
    measurement is right -- it is not given back."""
    T = 300
    path = np.arange(T)[:, None] * np.array([1.0, 0, 0]) + [0, 0, 100]
    P = path[:, None, :] + np.array([[0, 0, 0], [8.0, 0, 0], [0, 6.0, 0]])
    noisy = P.copy()
    noisy[100:102, :2] += [0, 30.0, 0]                       # marker 0 and 1 thrown together
    res = P.copy()
    res[100:102, 0] += [0, 15.0, 0]                          # marker 0 half put back
    back = gaps.moved_without_cause(noisy, np.ones((T, 3), bool), res, 5.0)
    assert not back[100:102, 0].any()


def _circling(T: int = 600, J: int = 6, fps: float = 100.0) -> np.ndarray:
    """Markers circling 40 cm about the z axis, one turn per second (cm)."""
    t = np.arange(T) / fps
    ph = np.linspace(0, 2 * np.pi, J, endpoint=False)
    P = np.zeros((T, J, 3))
    P[..., 0] = 40 * np.cos(2 * np.pi * t[:, None] + ph)
    P[..., 1] = 40 * np.sin(2 * np.pi * t[:, None] + ph)
    P[..., 2] = 100 + 10 * ph
    return P


def test_fills_the_method_cannot_validate_on_the_file_are_left_missing():
    """Linear interpolation across half a turn cuts the circle (up to 40 cm off): the
    self-validation on the file (stretches of the marker next to the gap, hidden and
    filled by the method) finds that and the fill is left missing and counted; a 2-frame
    hole is not judged; the same fill on a straight walk validates and is written."""
    P = _circling()
    obs = np.ones(P.shape[:2], bool)
    obs[200:250, 1] = False                  # half a turn
    obs[400:402, 2] = False                  # a 2-frame hole
    m = _markers(np.where(obs[..., None], P, np.nan)).with_observed(obs)
    out = denoise.get("linear").denoise(m)
    rep = out.source["gap_report"]
    assert not out.observed[200:250, 1].any() and out.observed[400:402, 2].all()
    assert rep["left_implausible_by"] == {"not validated under 5 cm": 50}
    with gaps.use_policy(validate_cm=None):                # the switch (CLI --keep-unvalidated)
        off = denoise.get("linear").denoise(m).source["gap_report"]["left_implausible_by"]
    assert "not validated under 5 cm" not in off     # (the rigid check still drops part of it)
    W = _walker(T=600, J=6)
    w = _markers(W).with_observed(obs)
    out = denoise.get("linear").denoise(w)
    assert out.observed[200:250, 1].all()
    assert np.sqrt(np.mean((out.positions[200:250, 1] - W[200:250, 1]) ** 2)) < 5.0


def test_methods_that_validate_their_own_fills_are_not_run_again(monkeypatch):
    from mocapkit.denoise import fill_auto

    calls = []
    real = fill_auto.unvalidated_fills
    monkeypatch.setattr(fill_auto, "unvalidated_fills", lambda *a: calls.append(a[0].name) or real(*a))
    P = _circling()
    obs = np.ones(P.shape[:2], bool)
    obs[200:250, 1] = False
    m = _markers(np.where(obs[..., None], P, np.nan)).with_observed(obs)
    for name in ("fill-auto", "auto", "spline"):
        denoise.get(name).denoise(m)
    assert calls == ["spline"]


def test_cli_keep_unvalidated(tmp_path, capsys):
    from mocapkit.cli import main

    P = _circling()
    obs = np.ones(P.shape[:2], bool)
    obs[200:250, 1] = False
    src = io.write(_markers(np.where(obs[..., None], P, np.nan)).with_observed(obs), tmp_path / "c.c3d")
    assert main(["denoise", str(src), str(tmp_path / "a.c3d"), "--method", "linear"]) == 0
    assert "50 not validated under 5 cm" in capsys.readouterr().out
    assert main(["denoise", str(src), str(tmp_path / "b.c3d"), "--method", "linear", "--keep-unvalidated"]) == 0
    assert "not validated" not in capsys.readouterr().out


def test_moved_without_cause_clip_edges_are_not_samples_alone():
    """A pair of rigid partners thrown together on the first two frames (a joint-angle
    spike of a skeleton file moves the limb below it as a whole): in a skeleton a method
    that puts one back is not given back for breaking the pair there, as the take's edge
    is no gap; in a marker set it is, and so is the same stretch seen alone before a gap
    (the Kinect / trnn case)."""
    T = 60
    t = np.arange(T)[:, None] / 30.0
    A = np.hstack([50 * np.sin(t), 100 + 0 * t, 20 * np.cos(t)])
    P = np.stack([A, A + [10.0, 0, 0], A + [0, 40.0, 0]], axis=1)     # A, its partner B, C
    Q = P.copy()
    P[:2, :2] += [15.0, 0, 0]                   # A and B thrown together on frames 0-1
    Q[:2, 1] += [15.0, 0, 0]                    # the method put A back, not B: pair broken
    obs = np.ones((T, 3), bool)
    assert not gaps.moved_without_cause(P, obs, Q, 5.0, edges_alone=False).any()     # a skeleton
    assert gaps.moved_without_cause(P, obs, Q, 5.0)[:2, 0].all()        # a marker set: judged
    obs[2:4, 0] = False                         # frames 0-1 of A now seen alone before a gap
    back = gaps.moved_without_cause(P, obs, Q, 5.0, edges_alone=False)
    assert back[:2, 0].all() and back.sum() == 2


def test_pooled_share_counts_the_written_fills_judged_by_other_gaps_only():
    from mocapkit.denoise.fill_auto import pooled_share, rescored

    emap = np.full((4, 2), np.nan)
    emap[:, 0] = 1.0                                    # four fills of marker 0
    pooled = np.zeros((4, 2), bool)
    pooled[:3, 0] = True                                # three of them judged by the pool
    assert pooled_share(emap, pooled) == 0.75
    written = np.ones((4, 2), bool)
    written[0, 0] = False                               # the policy left one of those out
    assert pooled_share(emap, pooled, written) == pytest.approx(2 / 3)
    rep = rescored({"error_map": emap, "estimated_rmse_cm": 1.0, "pooled_map": pooled,
                    "pooled_share": 0.75}, written)
    assert rep["pooled_share"] == pytest.approx(2 / 3)
    assert pooled_share(np.full((2, 1), np.nan), np.zeros((2, 1), bool)) is None
