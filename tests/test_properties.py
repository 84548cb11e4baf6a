"""Properties every registered method must have (parametrised over denoise.available()).

Data-driven methods are trained on one bundled real clip with their ``quick_params``;
each is checked on another real clip (no shared data needed).
"""
import warnings

import numpy as np
import pytest

from mocapkit import Motion, Skeleton, corrupt, denoise, gaps, io
from mocapkit.datasets import bundled
from mocapkit.errors import MocapError, MocapWarning

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
    # the gap policy may leave a gap missing (issue 15): measured samples stay, what is
    # returned is finite, what is left is NaN and counted in the report
    _sane(out, noisy)
    rep = out.source["gap_report"]
    assert rep["left_missing"] == int((~out.observed).sum())
    assert rep["filled"] == int((out.observed & ~noisy.observed).sum())
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
    """A clean clip comes back within the class's ``clean_tolerance_cm``; a model-based
    method (learned or fitted) within 0.25 cm: the default policy gives back, as measured,
    every marker it moved beyond twice the clip's noise (measured: at most 0.10 cm, tsmc;
    without the check lou-chai 0.80, xiao-sparse-fullpose 0.52, rpca 0.39 cm)."""
    m = fitted(name, clips)
    truth = clips[1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = m.denoise(truth)
    err = float(np.sqrt(np.mean((out.positions - truth.positions) ** 2)))
    tol = min(type(m).clean_tolerance_cm, 0.25) if type(m).misfit_check else type(m).clean_tolerance_cm
    assert err <= tol, f"{name}: clean clip moved by {err:.3f} cm RMSE"


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


# -- issue 18: numerics every method must get right ------------------------------------------
def _no_numpy_warnings():
    """Warnings context: RuntimeWarning (numpy's overflow / invalid / empty-slice ...) is an
    error; mocapkit's own warnings (convergence, training mismatch) are allowed."""
    ctx = warnings.catch_warnings()
    ctx.__enter__()
    warnings.simplefilter("error", RuntimeWarning)
    warnings.filterwarnings("ignore", category=MocapWarning)      # checked first
    return ctx


def _run(m, motion):
    ctx = _no_numpy_warnings()
    try:
        return m.denoise(motion)
    finally:
        ctx.__exit__(None, None, None)


@pytest.fixture(scope="module")
def noisy_short(clips):
    """120 frames of the test walk, 0.5 cm noise, 5 % of the joint entries missing."""
    m, _ = corrupt.combine(clips[1].slice(0, 120), [("gaussian", {"sigma_cm": 0.5}),
                                                    ("missing", {"ratio": 0.05, "per_frame": False})],
                           seed=5)
    return m


_base: dict = {}


def base_result(name, clips, noisy_short):
    """The method's result on ``noisy_short`` (computed once per method)."""
    if name not in _base:
        _base[name] = _run(fitted(name, clips), noisy_short)
    return _base[name]


def _sane(out, inp):
    """The output contract on observed output samples: finite, never (0, 0, 0), measured
    samples kept, missing ones NaN."""
    P, ob = out.positions, out.observed
    assert ob[inp.observed].all()
    assert np.isfinite(P[ob]).all()
    assert not (np.abs(P[ob]).sum(axis=-1) == 0).any()
    assert np.isnan(P[~ob]).all()


@pytest.mark.parametrize("name", METHODS)
def test_translation_equivariance(name, clips, noisy_short):
    """A clip 100 m (1e4 cm) or 10 km away gives the same result shifted (issue 18: trnn /
    tsmc lost 51-61 cm and bra / bra-p dropped a +1e6 cm offset)."""
    m = fitted(name, clips)
    base = base_result(name, clips, noisy_short)
    _sane(base, noisy_short)
    mag = float(np.abs(base.positions[base.observed]).max())
    off = np.array([1e4, 1e6, -1e4])                 # 100 m, 10 km, -100 m
    out = _run(m, noisy_short.with_positions(noisy_short.positions + off))
    np.testing.assert_array_equal(out.observed, base.observed)
    d = np.abs(out.positions[out.observed] - off - base.positions[base.observed]).max()
    assert d <= 1e-3 * mag, f"{name}: offset {off} changed the result by {d:.3g} cm"
    cls = denoise.available()[name]
    if cls.needs_training:                  # fit() is not recentred: train far away too
        far = denoise.get(name, **cls.quick_params())
        far.fit([clips[0].with_positions(clips[0].positions + off)])
        out = _run(far, noisy_short.with_positions(noisy_short.positions + off))
        np.testing.assert_array_equal(out.observed, base.observed)
        d = np.abs(out.positions[out.observed] - off - base.positions[base.observed]).max()
        assert d <= 1e-3 * mag, f"{name}: trained and used at {off}: changed by {d:.3g} cm"


@pytest.mark.parametrize("name", METHODS)
def test_scale_sanity(name, clips, noisy_short):
    """The same clip in metres or millimetres (x 0.01, x 10): a clear MocapError, or a
    result about as good as in cm (RMSE on the observed output <= max(3 x, + 2 cm) of the
    cm result, in cm after undoing the scale).  Sanity, not equivariance: a method with an
    absolute threshold (psc's 6 cm trust test) may lose a little; bra / bra-p were 30 cm
    off before they refused such input."""
    cls = denoise.available()[name]
    truth = clips[1].slice(0, 120)
    base = base_result(name, clips, noisy_short)
    e1 = float(np.sqrt(np.mean((base.positions - truth.positions)[base.observed] ** 2)))
    for s in (0.01, 10.0):
        m = denoise.get(name, **cls.quick_params())
        try:
            if cls.needs_training:
                m.fit([clips[0].with_positions(clips[0].positions * s)])
            out = _run(m, noisy_short.with_positions(noisy_short.positions * s))
        except MocapError:
            continue
        _sane(out, noisy_short)
        e = float(np.sqrt(np.mean((out.positions / s - truth.positions)[out.observed] ** 2)))
        assert e <= max(3 * e1, e1 + 2.0), f"{name} at scale {s}: {e:.3f} cm vs {e1:.3f} cm"


@pytest.mark.parametrize("name", METHODS)
def test_never_observed_joint_comes_back_missing(name, clips, noisy_short):
    """Issue 18: a joint missing in every frame was filled with (0, 0, 0) (65 cm off) by
    dynammo, rpca, slra, svt, trnn, tsmc and tsvd, with a raw RuntimeWarning."""
    m = fitted(name, clips)
    j = 10
    obs = noisy_short.observed.copy()
    obs[:, j] = False
    inp = noisy_short.with_observed(obs)
    try:
        out = _run(m, inp)
    except MocapError as e:                 # a clear refusal is allowed, never a traceback
        assert noisy_short.skeleton.names[j] in str(e) or "observed" in str(e)
        return
    assert not out.observed[:, j].any() and np.isnan(out.positions[:, j]).all()
    _sane(out, inp)
    assert out.source["gap_report"]["never_observed"] == [noisy_short.skeleton.names[j]]


@pytest.mark.parametrize("name", METHODS)
def test_95_percent_missing_no_worse_than_linear(name, clips):
    """Issue 18: rpca / slra reached 69 cm at 95 % missing where linear fill gets 6.6.
    Every entry is filled (FILL_ALL, as the papers' protocols); on the samples both fill the
    method's RMSE is at most the linear fill's plus max(10 %, the method's clean-clip
    tolerance) -- a method that moves a clean clip by up to that much cannot do better."""
    cls = denoise.available()[name]
    m = fitted(name, clips)
    truth = clips[1]
    inp, _ = corrupt.missing(truth, ratio=0.95, per_frame=False, seed=1)
    with gaps.use_policy(gaps.FILL_ALL):
        try:
            out = _run(m, inp)
        except MocapError:
            return
        lin = denoise.get("linear").denoise(inp)
    _sane(out, inp)
    both = out.observed & lin.observed & ~inp.observed     # a fill may decline samples
    if not both.any():
        return

    def err(o):
        return float(np.sqrt(np.mean((o.positions - truth.positions)[both] ** 2)))

    e, el = err(out), err(lin)
    assert e <= el + max(0.1 * el, cls.clean_tolerance_cm), f"{name}: {e:.2f} cm vs linear {el:.2f} cm"
