"""The parameter contract of every Denoiser (issue 16): declared constraints checked once by
the base class, one spelling for shared options, run diagnostics off the saved state, a
model loader per file format."""
from __future__ import annotations

import numpy as np
import pytest

from mocapkit import denoise
from mocapkit.denoise import constraints as C
from mocapkit.denoise.base import model_suffixes, params_from_text
from mocapkit.errors import MocapValueError


def _clip():
    from mocapkit import datasets, io

    return io.read(datasets.bundled("16_15.amc")).slice(0, 60)


@pytest.mark.parametrize("name", sorted(denoise.available()))
def test_every_parameter_is_declared_and_defaults_satisfy_it(name):
    cls = denoise.available()[name]
    assert set(cls._parameter_constraints) == set(cls._param_names()), name
    cls()._validate_params("test")
    cls(**cls.quick_params())._validate_params("test")


def test_one_error_names_method_parameter_value_and_what_is_allowed():
    with pytest.raises(MocapValueError, match=r"^gaussian: parameter sigma_frames must be a number > 0 "
                                              r"or None, got -1\.0 \(checked in get\(\)\)$"):
        denoise.get("gaussian", sigma_frames=-1.0)
    d = denoise.get("median")
    with pytest.raises(MocapValueError, match=r"median: parameter window must be an odd integer >= 1 "
                                              r"\(frames\), got 4 \(checked in set_params\(\)\)"):
        d.set_params(window=4)
    assert d.window == 5                                   # a refused value is not set
    from mocapkit.denoise.filters import HampelFilter

    with pytest.raises(MocapValueError, match=r"hampel: parameter scale must be one of 'both', 'global', "
                                              r"'local', got 'mad' \(checked in denoise\(\)\)"):
        HampelFilter(scale="mad").denoise(_clip())
    from mocapkit.denoise.kalman import KalmanLearned

    with pytest.raises(MocapValueError, match=r"kalman-learned: parameter frame .* \(checked in fit\(\)\)"):
        KalmanLearned(frame="local").fit([_clip()])
    with pytest.raises(MocapValueError, match="true or false"):
        denoise.get("gcv-spline", robust=1)                # a number is not a bool
    with pytest.raises(MocapValueError, match="psc: train_missing must be"):   # a rule between values
        denoise.get("psc", train_missing=(0.5, 0.2))


def test_vocabulary():
    assert C.Interval(C.Integral, 1, None).accepts(3.0) and not C.Interval(C.Integral, 1, None).accepts(2.5)
    assert not C.Interval(C.Real, 0, None).accepts(True) and not C.Interval(C.Real, 0, None).accepts(np.nan)
    assert C.Interval(C.Real, 0, 1, closed="right").accepts(1) and not C.Interval(C.Real, 0, 1, closed="right").accepts(0)
    assert str(C.Interval(C.Real, 0, 2, closed="neither")) == "a number in (0, 2)"
    assert C.Options(1, 2).accepts(2.0) and not C.Options("a").accepts(1)
    assert C.Numbers(2).accepts((0.1, 0.6)) and not C.Numbers(2).accepts((0.1,))


def test_cli_conversion_uses_the_same_constraints():
    assert params_from_text("median", {"window": 3.0}) == {"window": 3}
    out = params_from_text("gaussian", {"sigma_frames": 2})
    assert out == {"sigma_frames": 2.0} and isinstance(out["sigma_frames"], float)
    assert params_from_text("psc", {"train_missing": [0.1, 0.5]}) == {"train_missing": (0.1, 0.5)}
    assert params_from_text("median", {"window": "abc"}) == {"window": "abc"}     # get() reports it
    with pytest.raises(MocapValueError, match="min_noise_cm must be a number >= 0, got 'abc'"):
        denoise.get("auto", **params_from_text("auto", {"min_noise_cm": "abc"}))


def test_one_spelling_for_center_and_seed():
    for name in ("tsvd", "svt", "rpca", "slra", "lou-chai", "xiao-sparse"):
        assert isinstance(denoise.get(name).center, str), name
    for name in ("xiao-sparse", "psc", "trnn", "tsmc", "bra"):
        assert "seed" in denoise.available()[name]._param_names() and \
            "random_state" not in denoise.available()[name]._param_names()
    cls = denoise.available()["xiao-sparse"]
    old = {"center": True, "random_state": 3, "relax": 1.8, "rank_tol": 1e-6, "dtype": "float32"}
    assert cls._upgrade_params(old) == {"center": "mean", "seed": 3}
    with pytest.raises(MocapValueError, match="relax"):
        cls._upgrade_params({"relax": 1.0})


def test_diagnostics_are_on_the_result_and_never_saved(tmp_path):
    d = denoise.get("rpca", max_iter=3)
    with pytest.warns(Warning):
        out = d.denoise(_clip())
    assert out.source["convergence"]["iterations"] == 3
    assert d.last_report_["convergence"] == out.source["convergence"]
    d.save(tmp_path / "m.npz")
    back = denoise.Denoiser.load(tmp_path / "m.npz")
    assert "last_report_" not in vars(back) and "convergence_" not in vars(back)
    assert "last_report_" not in d._fitted_attrs()


def test_model_formats_and_training_come_from_the_registry():
    assert {".onnx", ".pt"} <= set(model_suffixes())       # registered by the neural family
    assert denoise.available()["bra"].training_side_files == (".ckpt",)
    assert denoise.available()["kalman-learned"].train_files(["x"], "m.npz", params={}, resume=False,
                                                             progress=False, exclude=()) is False


def test_cli_trains_a_neural_method_through_its_registry_hook(tmp_path, capsys):
    pytest.importorskip("torch")
    from mocapkit import datasets
    from mocapkit.cli import main

    clip, out = str(datasets.bundled("16_15.amc")), tmp_path / "m.pt"
    assert main(["train", "--method", "bra", clip, "-o", str(out), "--param", "dropout=x", "-q"]) == 2
    assert "bra: parameter dropout must be a number in [0, 1), got 'x'" in capsys.readouterr().err
    assert main(["train", "--method", "bra", clip, "-o", str(out), "-q", "--param", "hidden=8",
                 "--param", "steps_perceptual=0", "--param", "steps_denoise=1", "--param", "threads=1"]) == 0
    # training flushes denormals to zero for speed; the process-wide CPU mode must be back
    assert np.float64(np.finfo(float).tiny) / 2.0 > 0.0, "training left flush-to-zero on"
    back = denoise.Denoiser.load(out)                       # the loader registered for .pt
    assert back.name == "bra" and back.hidden == 8 and back.train_options["residual"] is True
