"""Properties every registered method must have (parametrised over denoise.available()).

Data-driven methods are trained on one bundled real clip with their ``quick_params``;
each is checked on another real clip (no shared data needed).
"""
import warnings

import numpy as np
import pytest

from mocapkit import Motion, Skeleton, corrupt, denoise, io
from mocapkit.datasets import bundled
from mocapkit.errors import MocapError

METHODS = sorted(denoise.available())


@pytest.fixture(scope="module")
def clips():
    walk = io.read(bundled("16_15.amc"))
    return walk.slice(0, 240), walk.slice(240, 471)


_fitted: dict = {}


def fitted(name, clips):
    if name not in _fitted:
        cls = denoise.available()[name]
        m = denoise.get(name, **cls.quick_params())
        if cls.needs_training:
            m.fit([clips[0]])
        _fitted[name] = m
    return _fitted[name]


@pytest.mark.parametrize("name", METHODS)
def test_fills_missing_and_keeps_shape(name, clips):
    m = fitted(name, clips)
    truth = clips[1]
    noisy, _ = corrupt.combine(truth, [("gaussian", {"sigma_cm": 1.0}), ("missing", {"ratio": 0.1})], seed=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = m.denoise(noisy)
    assert out.positions.shape == truth.positions.shape
    assert out.skeleton == truth.skeleton and out.fps == truth.fps
    assert out.observed.all() and np.isfinite(out.positions).all()
    # no input modified
    assert not noisy.observed.all()
    if type(m).keeps_observed:
        np.testing.assert_array_equal(out.positions[noisy.observed], noisy.positions[noisy.observed])
    # deterministic
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out2 = m.denoise(noisy)
    np.testing.assert_array_equal(out.positions, out2.positions)


@pytest.mark.parametrize("name", METHODS)
def test_clean_input_nearly_unchanged(name, clips):
    m = fitted(name, clips)
    truth = clips[1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = m.denoise(truth)
    err = float(np.sqrt(np.mean((out.positions - truth.positions) ** 2)))
    assert err <= type(m).clean_tolerance_cm, f"{name}: clean clip moved by {err:.3f} cm RMSE"


@pytest.mark.parametrize("name", METHODS)
def test_short_clip_works_or_fails_clearly(name, clips):
    m = fitted(name, clips)
    short = clips[1].slice(0, 4)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = m.denoise(short)
    except MocapError:
        return
    assert out.positions.shape == short.positions.shape and np.isfinite(out.positions).all()


@pytest.mark.parametrize("name", [n for n in METHODS if not denoise.available()[n].needs_training])
def test_single_joint_works_or_fails_clearly(name):
    t = np.linspace(0, 4, 240)
    P = np.stack([np.sin(t), np.cos(t), t], axis=1)[:, None, :] * 10
    mo = Motion(P, Skeleton(("m",), [-1], np.zeros((1, 3))), 60)
    try:
        out = denoise.get(name, **denoise.available()[name].quick_params()).denoise(mo)
    except MocapError:
        return
    assert out.positions.shape == P.shape and np.isfinite(out.positions).all()
