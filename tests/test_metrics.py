"""mocapkit.metrics: hand-computed examples, properties and error handling."""
from __future__ import annotations

import numpy as np
import pytest

from mocapkit import Motion, Skeleton, metrics
from mocapkit.errors import MocapValueError

CHAIN = ("root", "a", "b")          # root -> a -> b
CHAIN_PARENTS = (-1, 0, 1)


def chain_motion(P, fps=10.0, names=CHAIN, parents=CHAIN_PARENTS) -> Motion:
    P = np.asarray(P, dtype=float)
    sk = Skeleton.from_positions(names, parents, np.nan_to_num(P[0]))
    return Motion(P, sk, fps)


def random_motion(T=60, J=3, seed=0, fps=30.0) -> Motion:
    rng = np.random.default_rng(seed)
    names = tuple(f"j{i}" for i in range(J))
    parents = (-1,) + tuple(range(J - 1))
    P = np.cumsum(rng.normal(size=(T, J, 3)), axis=0) + np.arange(J)[None, :, None] * 10.0
    return Motion(P, Skeleton.from_positions(names, parents, P[0]), fps)


# ---------------------------------------------------------------------------------------
# position errors
# ---------------------------------------------------------------------------------------
def two_by_two():
    truth = np.zeros((2, 2, 3))
    est = np.zeros((2, 2, 3))
    est[0, 0] = (3, 0, 0)          # joint error 3
    est[1, 0] = (0, 4, 0)          # joint error 4
    return truth, est


def test_rmse_hand_example():
    truth, est = two_by_two()
    # 12 coordinates, squared errors 9 + 16 = 25 -> sqrt(25 / 12)
    assert metrics.rmse(truth, est) == pytest.approx(np.sqrt(25 / 12))
    # joint mask: joint 0 in both frames -> 6 coordinates -> sqrt(25 / 6)
    jm = np.array([[True, False], [True, False]])
    assert metrics.rmse(truth, est, jm) == pytest.approx(np.sqrt(25 / 6))
    # coordinate mask (T, 3J): only x of joint 0 in frame 0 -> 3
    cm = np.zeros((2, 6), dtype=bool)
    cm[0, 0] = True
    assert metrics.rmse(truth, est, cm) == pytest.approx(3.0)
    # the same mask as (T, J, 3)
    assert metrics.rmse(truth, est, cm.reshape(2, 2, 3)) == pytest.approx(3.0)
    # plain (T, 3J) matrices work too
    assert metrics.rmse(truth.reshape(2, 6), est.reshape(2, 6)) == pytest.approx(np.sqrt(25 / 12))


def test_mean_joint_error_hand_example():
    truth, est = two_by_two()
    # joint errors 3, 0, 4, 0 -> 7 / 4
    assert metrics.mean_joint_error(truth, est) == pytest.approx(1.75)
    jm = np.array([[True, False], [True, False]])
    assert metrics.mean_joint_error(truth, est, jm) == pytest.approx(3.5)


def test_per_frame_rmse_hand_example():
    truth = np.zeros((3, 3, 3))
    est = np.zeros((3, 3, 3))
    est[0, 0] = (3, 0, 0)
    est[0, 1] = (0, 4, 0)
    est[1, 2] = (1, 2, 2)           # norm 3
    mask = np.array([[True, True, False], [False, False, True], [False, False, False]])
    r = metrics.per_frame_rmse(truth, est, mask)
    # frame 0: sqrt((9 + 16) / 2); frame 1: sqrt(9 / 1); frame 2: no corrupted marker
    assert r[0] == pytest.approx(np.sqrt(12.5))
    assert r[1] == pytest.approx(3.0)
    assert np.isnan(r[2])
    mean, std = metrics.per_frame_rmse_stats(truth, est, mask)
    assert mean == pytest.approx((np.sqrt(12.5) + 3) / 2)
    assert std == pytest.approx((np.sqrt(12.5) - 3) / 2)
    # no mask: every marker counts (n_e = 3)
    r = metrics.per_frame_rmse(truth, est)
    np.testing.assert_allclose(r, [np.sqrt(25 / 3), np.sqrt(3.0), 0.0])


def test_frobenius_distance_hand_example():
    X = np.array([[1.0, 2.0], [3.0, 4.0]])
    A = np.array([[1.0, 2.0], [3.0, 6.0]])
    # ||A - X||_F = 2, sqrt(m n) = 2
    assert metrics.frobenius_distance(X, A) == pytest.approx(1.0)
    m = random_motion()
    e = m.with_positions(m.positions + 0.5)
    assert metrics.frobenius_distance(m, e) == pytest.approx(0.5)
    assert metrics.frobenius_distance(m, e) == pytest.approx(metrics.rmse(m, e))


# ---------------------------------------------------------------------------------------
# skeleton measures
# ---------------------------------------------------------------------------------------
def chain_pair():
    truth = np.array([[[0, 0, 0], [0, 10, 0], [0, 20, 0]]] * 2, dtype=float)
    est = truth.copy()
    est[0, 1] = (10, 0, 0)          # bone a: +y -> +x (90 deg); bone b: (0,20,0)-(10,0,0)
    est[0, 2] = (10, 10, 0)         # bone b: (0,10,0) -> 0 deg
    return chain_motion(truth), est


def test_joint_angle_error_hand_example():
    truth, est = chain_pair()
    # frame 0: 90 and 0 degrees; frame 1: 0 and 0 -> 90 / 4
    assert metrics.joint_angle_error(truth, est) == pytest.approx(22.5)
    rev = truth.positions.copy()
    rev[:, 1] = (0, -10, 0)         # bone a reversed (180), bone b (0, 30, 0) parallel (0)
    assert metrics.joint_angle_error(truth, rev) == pytest.approx(90.0)


def test_joint_angle_error_skips_zero_length_truth_bone_and_degenerate_estimate():
    names, parents = ("root", "a", "hip"), (-1, 0, 0)     # 'hip' coincides with the root
    truth = np.array([[[0, 0, 0], [0, 10, 0], [0, 0, 0]]] * 2, dtype=float)
    m = chain_motion(truth, names=names, parents=parents)
    est = truth.copy()
    est[:, 2] = (5, 5, 5)           # bone hip has no truth direction: ignored
    assert metrics.joint_angle_error(m, est) == pytest.approx(0.0)
    est[0, 1] = (0, 0, 0)           # bone a collapsed in frame 0: counts as 90
    assert metrics.joint_angle_error(m, est) == pytest.approx(45.0)


def test_bone_length_error_hand_example():
    truth = chain_motion([[[0, 0, 0], [0, 10, 0], [0, 20, 0]]] * 2)
    est = truth.positions.copy()
    est[0, 1] = (0, 12, 0)          # lengths 12, 8   -> errors 2, 2
    est[1, 2] = (0, 25, 0)          # lengths 10, 15  -> errors 0, 5
    assert metrics.bone_length_error(truth, est) == pytest.approx(9 / 4)
    np.testing.assert_allclose(metrics.bone_length_error(truth, est, per_bone=True), [1.0, 3.5])
    # BRA-P eq. (7): reference length = truth length 10 for both bones -> (2+2+0+5)/(2*2)
    assert metrics.brap_bone_error(truth, est) == pytest.approx(9 / 4)
    # explicit reference lengths 10 and 20: |12-10| + |8-20| + |10-10| + |15-20| = 19 -> 19/4
    assert metrics.brap_bone_error(truth, est, lengths=[10, 20]) == pytest.approx(19 / 4)
    assert metrics.brap_bone_error(None, truth.with_positions(est), lengths=[10, 20]) == pytest.approx(19 / 4)


def test_brap_bone_error_measures_consistency_not_difference():
    # truth bone lengths change over time; the estimate equals the truth, so the
    # frame-wise bone_length_error is 0 but B (fixed median length) is not.
    truth = chain_motion([[[0, 0, 0], [0, 10, 0], [0, 20, 0]],
                          [[0, 0, 0], [0, 10, 0], [0, 20, 0]],
                          [[0, 0, 0], [0, 13, 0], [0, 23, 0]]])
    assert metrics.bone_length_error(truth, truth) == 0.0
    # medians 10, 10; frame 2 bone a is 13 -> |3| / (3 frames * 2 bones)
    assert metrics.brap_bone_error(truth, truth) == pytest.approx(3 / 6)


# ---------------------------------------------------------------------------------------
# smoothness and acceleration
# ---------------------------------------------------------------------------------------
def quad_motion(fps=10.0):
    t = np.arange(4.0)
    P = np.zeros((4, 2, 3))
    P[:, 0, 0] = t ** 2             # second difference 2 cm/frame^2
    P[:, 1, 0] = t                  # second difference 0
    names, parents = ("root", "a"), (-1, 0)
    return Motion(P, Skeleton.from_positions(names, parents, P[0]), fps)


def test_smoothness_hand_example():
    m = quad_motion()
    # second differences: joint 0: 2, 2; joint 1: 0, 0 -> mean 1
    assert metrics.smoothness(m) == pytest.approx(1.0)
    # a missing sample removes the second differences that use it
    obs = np.ones((4, 2), dtype=bool)
    obs[3, 1] = False               # joint 1, frame 3: drops joint 1's 2nd diff at t=2
    assert metrics.smoothness(m.with_observed(obs)) == pytest.approx(4 / 3)


def test_acceleration_error_hand_example():
    m = quad_motion(fps=10.0)
    truth = m.positions.copy()
    truth[:, 0, 0] = np.arange(4.0)  # linear: zero acceleration
    # joint 0: |2 cm/frame^2| * fps^2 = 200 cm/s^2 at t=1,2; joint 1: 0 -> mean 100
    assert metrics.acceleration_error(m.with_positions(truth), m) == pytest.approx(100.0)
    assert metrics.acceleration_error(truth, m.positions, fps=10.0) == pytest.approx(100.0)
    with pytest.raises(MocapValueError, match="frame rate"):
        metrics.acceleration_error(truth, m.positions)


# ---------------------------------------------------------------------------------------
# BRA-P R and S
# ---------------------------------------------------------------------------------------
def test_brap_reproduction_error_hand_example():
    truth = np.zeros((2, 1, 3))
    est = np.array([[[1, -2, 0]], [[0, 0, 3]]], dtype=float)
    # (1/(f d)) sum |Y - X| = (1 + 2 + 3) / (2 * 3)
    assert metrics.brap_reproduction_error(truth, est) == pytest.approx(1.0)


def test_brap_smoothness_error_hand_example():
    P = np.zeros((3, 1, 3))
    P[:, 0, 0] = (0, 1, 4)
    # X' = [0, 0, 1, 4, 4]; O X' = [0, 1, 2, -3, 0] -> 6 / ((3 + 2) * 3 channels)
    assert metrics.brap_smoothness_error(P) == pytest.approx(6 / 15)


def test_brap_smoothness_error_matches_explicit_eq5_matrix():
    m = random_motion(T=12, J=2, seed=3)
    X = m.matrix()
    f, d = X.shape
    Xp = np.vstack([X[:1], X, X[-1:]])
    O = np.zeros((f + 2, f + 2))            # eq. (5)
    O[0, :2] = (-1, 1)
    O[-1, -2:] = (1, -1)
    for i in range(1, f + 1):
        O[i, i - 1:i + 2] = (1, -2, 1)
    assert np.allclose(O, O.T)
    expected = np.abs(O @ Xp).sum() / ((f + 2) * d)
    assert metrics.brap_smoothness_error(m) == pytest.approx(expected)


# ---------------------------------------------------------------------------------------
# properties
# ---------------------------------------------------------------------------------------
def test_zero_on_identical_input():
    m = random_motion()
    for f in (metrics.rmse, metrics.mean_joint_error, metrics.frobenius_distance,
              metrics.joint_angle_error, metrics.bone_length_error, metrics.acceleration_error,
              metrics.brap_reproduction_error):
        assert f(m, m) == pytest.approx(0.0, abs=1e-9), f.__name__
    assert np.allclose(metrics.per_frame_rmse(m, m), 0.0)
    # B compares with one fixed length per bone: zero for a rigid skeleton moving in space
    t = np.arange(30.0)[:, None, None]
    rigid = chain_motion(np.array([[0, 0, 0], [0, 10, 0], [0, 20, 0]])[None] + t * [1.0, 0.5, 0.0])
    assert metrics.brap_bone_error(rigid, rigid) == pytest.approx(0.0, abs=1e-9)
    # smoothness of uniform straight-line motion is zero
    assert metrics.smoothness(rigid) == pytest.approx(0.0, abs=1e-9)
    assert metrics.brap_smoothness_error(np.zeros((5, 2, 3))) == 0.0


def test_scaling_properties():
    m = random_motion(seed=1)
    rng = np.random.default_rng(2)
    e = m.positions + rng.normal(size=m.positions.shape)
    c = 2.5
    mc = m.with_positions(m.positions * c)
    for f in (metrics.rmse, metrics.mean_joint_error, metrics.frobenius_distance,
              metrics.bone_length_error, metrics.brap_reproduction_error, metrics.brap_bone_error,
              metrics.acceleration_error):
        assert f(mc, e * c) == pytest.approx(c * f(m, e)), f.__name__
    assert metrics.smoothness(e * c) == pytest.approx(c * metrics.smoothness(e))
    assert metrics.brap_smoothness_error(e * c) == pytest.approx(c * metrics.brap_smoothness_error(e))
    # angles are scale and translation invariant
    ang = metrics.joint_angle_error(m, e)
    assert 0 < ang < 180
    assert metrics.joint_angle_error(m, e * c) == pytest.approx(ang)
    assert metrics.joint_angle_error(m, e + 7.0) == pytest.approx(ang)
    # rmse is the root mean squared joint error divided by 3 (per coordinate)
    d2 = np.sum((e - m.positions) ** 2, axis=2)
    assert metrics.rmse(m, e) == pytest.approx(np.sqrt(d2.mean() / 3))
    # FD and rmse agree on complete data
    assert metrics.frobenius_distance(m, e) == pytest.approx(metrics.rmse(m, e))


def test_rmse_leaves_out_truth_gaps_and_accepts_partial_estimate_on_mask():
    m = random_motion(seed=4)
    obs = np.ones(m.observed.shape, dtype=bool)
    obs[5, 1] = False
    noisy = m.with_positions(m.positions + 1.0, obs)          # a gap in the "estimate"
    # scoring only observed entries works; every error is 1 per coordinate
    assert metrics.rmse(m, noisy, noisy.observed) == pytest.approx(1.0)
    with pytest.raises(MocapValueError, match=r"frame 5, joint 'j1'"):
        metrics.rmse(m, noisy)
    # gaps in the truth are simply not scored
    assert metrics.rmse(noisy, m) == pytest.approx(1.0)


def test_all_metrics_keys_units_and_values():
    m = random_motion(seed=5)
    rng = np.random.default_rng(6)
    e = m.with_positions(m.positions + rng.normal(size=m.positions.shape))
    mask = np.zeros(m.observed.shape, dtype=bool)
    mask[::3, 1] = True
    res = metrics.all_metrics(m, e, mask)
    expected_units = {"rmse": "cm", "mean_joint_error": "cm", "rmse_corrupted": "cm",
                      "mean_joint_error_corrupted": "cm", "per_frame_rmse": "cm",
                      "per_frame_rmse_std": "cm", "frobenius_distance": "cm",
                      "joint_angle_error": "deg", "bone_length_error": "cm/bone",
                      "brap_B": "cm/bone", "brap_R": "cm/channel", "brap_S": "cm/frame^2",
                      "smoothness": "cm/frame^2", "smoothness_truth": "cm/frame^2",
                      "acceleration_error": "cm/s^2"}
    assert {k: u for k, (_, u) in res.items()} == expected_units
    assert res["rmse"][0] == pytest.approx(metrics.rmse(m, e))
    assert res["rmse_corrupted"][0] == pytest.approx(metrics.rmse(m, e, mask))
    assert res["per_frame_rmse"][0] == pytest.approx(metrics.per_frame_rmse_stats(m, e, mask)[0])
    assert all(isinstance(v, float) and np.isfinite(v) for v, _ in res.values())
    # without a mask: no *_corrupted keys, per-frame over all markers
    res = metrics.all_metrics(m, e)
    assert "rmse_corrupted" not in res and "per_frame_rmse" in res


def test_errors_are_clear():
    m = random_motion(T=20, J=3)
    with pytest.raises(MocapValueError, match="differ in shape"):
        metrics.rmse(m, m.slice(0, 10))
    other = Motion(m.positions, Skeleton.from_positions(("x", "y", "z"), (-1, 0, 1), m.positions[0]), m.fps)
    with pytest.raises(MocapValueError, match="different skeletons"):
        metrics.rmse(m, other)
    with pytest.raises(MocapValueError, match="frame rate"):
        metrics.rmse(m, Motion(m.positions, m.skeleton, 60.0))
    with pytest.raises(MocapValueError, match="mask must have shape"):
        metrics.rmse(m, m, np.ones((20, 4), dtype=bool))
    with pytest.raises(MocapValueError, match="no entries"):
        metrics.rmse(m, m, np.zeros((20, 3), dtype=bool))
    gap = m.with_observed(np.pad(np.ones((19, 3), bool), ((1, 0), (0, 0))))
    with pytest.raises(MocapValueError, match="frobenius_distance: the estimate"):
        metrics.frobenius_distance(m, gap)
    with pytest.raises(MocapValueError, match="fill the gaps"):
        metrics.all_metrics(m, gap)
    with pytest.raises(MocapValueError, match="skeleton"):
        metrics.joint_angle_error(m.positions, m.positions)
    with pytest.raises(MocapValueError, match="shape"):
        metrics.rmse(np.zeros((4, 5)), np.zeros((4, 5)))
