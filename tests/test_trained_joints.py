"""A lab's own model on its other captures: one check of a trained model's joints
(:func:`mocapkit.denoise.base.trained_joint_map` / ``check_trained_joints``), Vicon's
``Subject:`` prefixes, marker order, and models fitted under the older marker-set origin."""
from __future__ import annotations

import numpy as np
import pytest

from mocapkit import Motion, Skeleton, gaps
from mocapkit.denoise import get
from mocapkit.denoise.base import Denoiser, trained_joint_map
from mocapkit.errors import MocapValueError

PIG = ("C7", "CLAV", "LASI", "RASI", "LKNE", "RKNE", "LANK", "RANK", "LWRA", "RWRA")


def _markers(prefix: str, seed: int, T: int = 240, order=None) -> Motion:
    """A flat Plug-in-Gait-named marker set walking in place: the same body for every
    prefix, a different phase per seed."""
    rng = np.random.default_rng(seed)
    base = np.array([[0, 0, 150], [0, 8, 140], [-12, 6, 100], [12, 6, 100], [-10, 4, 50], [10, 4, 50],
                     [-10, 0, 8], [10, 0, 8], [-30, 0, 90], [30, 0, 90]], float)
    t = np.arange(T)[:, None] / 60.0 + rng.uniform(0, 1)
    P = np.repeat(base[None], T, axis=0)
    P[:, 4:8, 1] += 12 * np.sin(2 * np.pi * t + np.array([0, np.pi, 0, np.pi]))   # legs swing
    P[:, 8:10, 1] += 15 * np.sin(2 * np.pi * t + np.array([np.pi, 0]))              # arms swing
    P += rng.normal(0, 0.2, P.shape)
    names = [f"{prefix}{n}" for n in PIG]
    order = list(range(len(PIG))) if order is None else list(order)
    sk = Skeleton(tuple(names[i] for i in order), -np.ones(len(PIG), int), np.zeros((len(PIG), 3)))
    return Motion(P[:, order], sk, 60.0)


def test_joint_map_by_bare_name_and_marker_order():
    model = [f"Derrick:{n}" for n in PIG]
    np.testing.assert_array_equal(trained_joint_map(model, _markers("Viktor:", 0)), np.arange(10))
    shuffled = _markers("Viktor:", 0, order=[3, 1, 0, 2, 4, 5, 6, 7, 9, 8])
    idx = trained_joint_map(model, shuffled)
    assert [shuffled.skeleton.names[i].split(":")[1] for i in idx] == list(PIG)
    assert trained_joint_map(model, _markers("Viktor:", 0).select(list(f"Viktor:{n}" for n in PIG[:9]))) is None
    # a skeleton with a hierarchy keeps its order (parents come first)
    sk = Skeleton(("a:root", "a:spine"), np.array([-1, 0]), np.zeros((2, 3)))
    m = Motion(np.zeros((3, 2, 3)), sk, 30.0)
    assert trained_joint_map(["b:root", "b:spine"], m) is not None
    assert trained_joint_map(["b:spine", "b:root"], m) is None


@pytest.mark.parametrize("method", ["xiao-sparse", "psc", "lou-chai", "kalman-learned"])
def test_a_model_of_one_subject_cleans_another_subjects_take(method):
    """Trained on 'Derrick:' takes, run on a 'Viktor:' take with its markers in another
    order: the output carries Viktor's names and order, and equals the run on the same take
    renamed to Derrick's by hand. Another marker set gets the one message."""
    quick = {"xiao-sparse": {"n_atoms": 32, "n_iter": 2}, "psc": {}, "lou-chai": {}, "kalman-learned": {}}[method]
    den = get(method, **quick).fit([_markers("Derrick:", s) for s in (1, 2)])
    order = [3, 1, 0, 2, 4, 5, 6, 7, 9, 8]
    take = _markers("Viktor:", 5, order=order)
    take = take.with_positions(take.positions + np.random.default_rng(9).normal(0, 1.0, take.positions.shape))
    by_hand = Motion(take.positions[:, np.argsort(order)], Skeleton(tuple(f"Derrick:{n}" for n in PIG),
                     -np.ones(10, int), np.zeros((10, 3))), 60.0)
    with gaps.use_policy(gaps.FILL_ALL):
        out, ref = den.denoise(take), den.denoise(by_hand)
    assert out.skeleton.names == take.skeleton.names
    np.testing.assert_allclose(out.positions, ref.positions[:, order], atol=1e-9)
    other = _markers("Viktor:", 5).select([f"Viktor:{n}" for n in PIG[:9]])
    with pytest.raises(MocapValueError, match=rf"{method}: the model was trained on 10 joints, this motion "
                                              r"has 9 \(missing RWRA\); train a model"):
        den.denoise(other)


@pytest.mark.parametrize("method", ["xiao-sparse", "psc", "lou-chai", "kalman-learned"])
def test_a_marker_set_model_from_the_older_origin_rule_is_refused(method, tmp_path):
    """Before 2026-12-05 a marker set's body frame was centred on its first marker (here
    C7); a model saved then has no ``marker_origin_`` and would put its outputs tens of cm off:
    it is refused with a one-line reason. A skeleton model (a hierarchy) is unaffected."""
    quick = {"xiao-sparse": {"n_atoms": 32, "n_iter": 2}}.get(method, {})
    den = get(method, **quick).fit([_markers("S:", s) for s in (1, 2)])
    del den.marker_origin_
    den.save(tmp_path / "old.npz")
    old = Denoiser.load(tmp_path / "old.npz")
    with pytest.raises(MocapValueError, match="trained on a marker set before 2026-12-05.*retrain"):
        old.denoise(_markers("S:", 3))
