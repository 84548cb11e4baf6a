import numpy as np
import pytest

from mocapkit import Motion, Skeleton
from mocapkit.errors import MocapValueError


def chain(J=4):
    return Skeleton(tuple(f"j{i}" for i in range(J)), np.arange(J) - 1, np.tile([0, 10.0, 0], (J, 1)))


def test_skeleton_basics():
    sk = chain()
    assert sk.bones() == [(1, 0), (2, 1), (3, 2)]
    np.testing.assert_allclose(sk.rest_positions()[:, 1], [10, 20, 30, 40])
    sub = sk.subset(["j0", "j2"])
    assert sub.names == ("j0", "j2") and list(sub.parents) == [-1, 0]
    np.testing.assert_allclose(sub.offsets[1], [0, 20, 0])
    with pytest.raises(MocapValueError, match="unknown joint"):
        sk.index("nope")
    with pytest.raises(MocapValueError, match="duplicate"):
        Skeleton(("a", "a"), [-1, 0], np.zeros((2, 3)))


def test_body_parts_by_name():
    names = ["root", "lhipjoint", "lfemur", "rhipjoint", "rfemur", "lowerback", "thorax",
             "lclavicle", "lhumerus", "rclavicle", "rhumerus", "head"]
    parents = [-1, 0, 1, 0, 3, 0, 5, 6, 7, 6, 9, 6]
    sk = Skeleton(tuple(names), parents, np.ones((12, 3)))
    parts = {k: [names[i] for i in v] for k, v in sk.body_parts().items()}
    assert parts["left_leg"] == ["root", "lhipjoint", "lfemur"]
    assert parts["right_arm"] == ["thorax", "rclavicle", "rhumerus"]
    assert set(parts["torso"]) == {"root", "lowerback", "thorax", "head"}
    bvh = ["Hips", "LeftUpLeg", "LeftLeg", "RightUpLeg", "Spine", "LeftShoulder", "LeftArm", "Head"]
    sk2 = Skeleton(tuple(bvh), [-1, 0, 1, 0, 0, 4, 5, 4], np.ones((8, 3)))
    p2 = {k: [bvh[i] for i in v] for k, v in sk2.body_parts().items()}
    assert p2["left_leg"] == ["Hips", "LeftUpLeg", "LeftLeg"]
    assert p2["left_arm"] == ["Spine", "LeftShoulder", "LeftArm"]
    assert p2["torso"] == ["Hips", "Spine", "Head"]


def test_motion_masks_and_immutability():
    sk = chain()
    P = np.random.default_rng(0).normal(size=(10, 4, 3))
    P[3, 1] = np.nan
    m = Motion(P, sk, 30)
    assert not m.observed[3, 1] and m.observed.sum() == 39
    with pytest.raises(ValueError):
        m.positions[0, 0, 0] = 1.0
    m2 = m.with_observed(np.ones((10, 4), bool) & (np.arange(10)[:, None] != 5))
    assert np.isnan(m2.positions[5]).all() and np.isnan(m2.positions[3, 1]).all()
    assert m.slice(2, 6).n_frames == 4
    assert m.matrix().shape == (10, 12)
    with pytest.raises(MocapValueError):
        m.slice(20, 30)
    with pytest.raises(MocapValueError):
        Motion(P[:, :3], sk, 30)


def test_handover_shares_the_array_and_freezes_it():
    """``handover=True`` makes the caller's array the motion's storage (no copy of a long
    clip) and read-only; without it, or for a partial view, the motion copies."""
    m = Motion(np.random.default_rng(1).normal(size=(10, 4, 3)), chain(), 30)
    A = m.matrix() + 1.0
    out = m.with_matrix(A, handover=True)
    assert np.shares_memory(out.positions, A) and not A.flags.writeable
    with pytest.raises(ValueError):
        A[0, 0] = 5.0
    B = m.matrix() + 1.0
    assert not np.shares_memory(m.with_matrix(B).positions, B) and B.flags.writeable
    C = np.zeros((20, 4, 3))
    part = m.with_positions(C[:10], handover=True)               # a view of part of C: copied
    assert not np.shares_memory(part.positions, C) and C.flags.writeable
    np.testing.assert_array_equal(out.positions, m.positions + 1.0)


def test_resample_keeps_values_and_masks():
    sk = chain(2)
    t = np.arange(121) / 120
    P = np.zeros((121, 2, 3))
    P[:, 0, 0] = np.sin(2 * np.pi * t)
    P[:, 1, 1] = t
    m = Motion(P, sk, 120).resample(30)
    assert m.n_frames == 31 and m.fps == 30
    np.testing.assert_allclose(m.positions[:, 0, 0], np.sin(2 * np.pi * np.arange(31) / 30), atol=1e-6)
    P[50:60, 1] = np.nan
    m2 = Motion(P, sk, 120).resample(30)
    assert not m2.observed[13, 1] and m2.observed[13, 0] and m2.observed[16, 1]
