"""Shipped general models (mocapkit.shipped, issue #19 item 1).

The clips used are bundled CMU clips of subjects 16 and 09, which are held out of every
shipped model (benchmarks/train_shipped.py HELD_OUT), so the models have never seen them.
"""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from mocapkit import corrupt, io, metrics, shipped
from mocapkit.datasets import bundled
from mocapkit.denoise.bases import decimate
from mocapkit.denoise.base import Denoiser
from mocapkit.motion import Motion
from mocapkit.skeleton import Skeleton

METHODS = ("xiao-sparse", "psc", "lou-chai")


@pytest.fixture(scope="module")
def walk_full():
    return io.read(bundled("16_15.amc"))          # 471 frames at 120 fps


@pytest.fixture(scope="module")
def walk120(walk_full):
    m = walk_full
    return Motion(m.positions[:240], m.skeleton, m.fps, m.observed[:240], {})


def _quiet(model, motion):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return model.denoise(motion)


def test_available_and_index():
    assert shipped.available() == sorted(METHODS)
    idx = json.loads((shipped.MODELS_DIR / "index.json").read_text())
    total = 0
    for f, e in idx.items():
        p = shipped.MODELS_DIR / f
        assert p.is_file(), f
        total += p.stat().st_size
        assert e["bytes"] == p.stat().st_size
        assert e["method"] in METHODS and e["fps"] in (30.0, 120.0)
        # no held-out subject in the training set
        assert "16" not in e["datasets"]["cmu"] and "09" not in e["datasets"]["cmu"]
        assert "mm" not in e["datasets"]["hdm05"]
    assert total <= 15_500_000


@pytest.mark.parametrize("method", METHODS)
def test_describe_one_line(method):
    d = shipped.describe(method)
    assert "\n" not in d and d.startswith(method) and "held out" in d and "CMU" in d


def test_describe_unknown():
    with pytest.raises(Exception):
        shipped.describe("gaussian")


@pytest.mark.parametrize("fname", sorted(shipped._index()))
def test_every_file_loads_with_its_joint_set(fname, walk120):
    e = shipped._index()[fname]
    model = Denoiser.load(shipped.MODELS_DIR / fname)
    assert model.name == e["method"]
    assert list(model.joint_names_) == list(e["joint_names"]) == list(walk120.skeleton.names)
    fresh = shipped._fresh(fname)
    arrays = [v for v in fresh._fitted_attrs().values() if isinstance(v, np.ndarray) and v.dtype.kind == "f"]
    arrays += [a for v in fresh._fitted_attrs().values() if isinstance(v, list)
               for a in v if isinstance(a, np.ndarray) and a.dtype.kind == "f"]
    assert arrays and all(a.dtype == np.float64 and np.isfinite(a).all() for a in arrays)


@pytest.mark.parametrize("fps", [30, 120])
@pytest.mark.parametrize("method", METHODS)
def test_beats_noisy_input_on_held_out_clip(method, fps, walk120, walk_full):
    truth = walk120 if fps == 120 else decimate(walk_full, 4)      # 240 / 118 frames
    model = shipped.load(method, truth)
    assert model is not None and model.is_fitted()
    if method != "lou-chai":
        assert shipped.choose(method, truth)["mode"] == "native"
        assert model.shipped_model_ == f"{method}-{fps}fps.npz"
    noisy, _ = corrupt.gaussian(truth, sigma_cm=3.0, seed=1)
    if method == "psc":
        # psc keeps trusted observations and replaces only untrusted / missing ones, so it
        # leaves Gaussian noise in place (docs/results/shipped_models.md): test it on what
        # it is for, 10 % x 15 cm spikes
        noisy, _ = corrupt.outliers(truth, ratio=0.1, magnitude_cm=15.0, seed=2)
    out = _quiet(model, noisy)
    assert out.positions.shape == truth.positions.shape and np.isfinite(out.positions).all()
    e_in, e_out = metrics.rmse(truth, noisy), metrics.rmse(truth, out)
    assert e_out < 0.9 * e_in, (e_out, e_in)


def test_other_rates_go_through_the_adapter(walk120):
    m60 = decimate(walk120, 2)
    model = shipped.load("xiao-sparse", m60)
    assert isinstance(model, shipped.RateAdapter) and model.name == "xiao-sparse"
    c = shipped.choose("xiao-sparse", m60)
    assert c["mode"] == "phases" and c["k"] == 2 and c["model_fps"] == 30.0
    m50 = walk120.resample(50.0)
    assert shipped.choose("psc", m50) == {"file": "psc-120fps.npz", "model_fps": 120.0, "mode": "resample"}
    assert shipped.choose("psc", m60)["model_fps"] == 120.0
    assert shipped.choose("xiao-sparse", m50)["model_fps"] == 30.0
    for m in (m60, m50):
        noisy, _ = corrupt.gaussian(m, sigma_cm=3.0, seed=3)
        out = _quiet(shipped.load("xiao-sparse", m), noisy)
        assert out.n_frames == m.n_frames and out.fps == m.fps
        assert metrics.rmse(m, out) < 0.9 * metrics.rmse(m, noisy)
    # lou-chai filters multiples of 30 fps (and other rates) itself
    assert shipped.choose("lou-chai", m60)["mode"] == "native"


def test_none_for_other_joint_sets(walk120):
    # a 29-joint BVH conversion of the same trial
    bvh = io.read(bundled("16_15.bvh"))
    # a marker file (synthetic: marker names, 120 fps)
    T, J = 100, 12
    P = np.random.default_rng(0).normal(size=(T, J, 3)) * 10 + 100
    names = tuple(f"M{j:02d}" for j in range(J))
    markers = Motion(P, Skeleton(names, np.full(J, -1), np.zeros((J, 3))), 120.0, np.ones((T, J), bool), {})
    # the Acclaim skeleton minus a joint
    keep = list(range(30))
    sub = Motion(walk120.positions[:, keep], walk120.skeleton.subset(walk120.skeleton.names[:30]),
                 walk120.fps, walk120.observed[:, keep], {})
    for method in METHODS:
        for m in (bvh, markers, sub):
            assert shipped.load(method, m) is None, (method, m)
    assert shipped.load("gaussian", walk120) is None


def test_marker_files_of_the_shared_data(shared_data):
    p = shared_data / "markers" / "c3d_org" / "Eb015pr.c3d"
    if not p.is_file():
        pytest.skip("no Eb015pr.c3d")
    m = io.read(p)
    assert all(shipped.load(method, m) is None for method in METHODS)


def test_cli_uses_the_shipped_model_without_train(tmp_path, capsys):
    """`mocapkit denoise --method xiao-sparse` needs no --model on a CMU-joint clip (here
    written as TRC: names without hierarchy), and says which model it used."""
    from mocapkit import corrupt, io, metrics
    from mocapkit.cli import main
    from mocapkit.datasets import bundled

    clip = io.read(bundled("16_15.amc")).slice(2, 122)
    noisy, _ = corrupt.combine(clip, [("gaussian", {"sigma_cm": 2.0})], seed=0)
    src, out = tmp_path / "in.trc", tmp_path / "out.trc"
    io.write(noisy, src)
    assert main(["denoise", str(src), str(out), "--method", "xiao-sparse"]) == 0
    assert "shipped general xiao-sparse model" in capsys.readouterr().out
    back = io.read(out).positions
    err = float(np.sqrt(np.mean((back - clip.positions) ** 2)))
    assert err < 0.6 * metrics.rmse(clip, noisy)


def test_params_reach_the_model_inside_the_rate_adapter():
    from mocapkit import io, shipped
    from mocapkit.datasets import bundled

    clip = io.read(bundled("16_15.amc")).slice(2, 122).resample(60.0)   # no 60 fps model
    est = shipped.load("xiao-sparse", clip, n_iter=3)
    assert isinstance(est, shipped.RateAdapter) and est.model.n_iter == 3
