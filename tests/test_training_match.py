"""Training-mismatch check of data-driven methods (mocapkit.denoise.base.check_training_match)."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from mocapkit import cli, corrupt, datasets, denoise
from mocapkit import io as mio
from mocapkit.denoise.base import check_training_match
from mocapkit.errors import MocapWarning, TrainingMismatchWarning


def _noisy(m, sigma, seed=0):
    return corrupt.gaussian(m, sigma_cm=sigma, seed=seed)[0]


class _Stub:
    name = "stub"


@pytest.fixture(scope="module")
def clip():
    return mio.read(datasets.bundled("09_06.amc"))


def _caught(fn):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        out = fn()
    return out, [x for x in w if issubclass(x.category, TrainingMismatchWarning)]


def test_threshold_on_known_changes(clip):
    inp = _noisy(clip, 1.0)
    d = _Stub()
    info, w = _caught(lambda: check_training_match(d, inp, clip))     # perfect denoiser
    assert w == [] and info["mismatch"] is False and d.last_report_["training_match"] is info
    assert 0.8 < info["noise_cm"] < 1.2                   # robust estimate of the 1 cm noise
    assert 0.55 < info["median_change_cm"] < 0.8          # median |N(0, 1)| = 0.674
    moved = clip.with_positions(clip.positions + np.array([3.0, -3.0, 3.0]))
    info, w = _caught(lambda: check_training_match(d, inp, moved))     # every coordinate 3 cm off
    assert info["mismatch"] is True and len(w) == 1 and issubclass(w[0].category, MocapWarning)
    assert "stub:" in str(w[0].message) and "train on clean clips" in str(w[0].message)
    info, w = _caught(lambda: check_training_match(d, clip, clip.with_positions(clip.positions + 0.9)))
    assert info["threshold_cm"] == 1.0 and info["mismatch"] is False and w == []  # 1 cm floor


def test_lou_chai_self_vs_other_behaviour(clip):
    inp = _noisy(clip, 0.1)
    own = denoise.get("lou-chai").fit([clip])
    out, w = _caught(lambda: own.denoise(inp))
    assert w == [] and out.source["training_match"]["mismatch"] is False
    other = denoise.get("lou-chai").fit([mio.read(datasets.bundled(c + ".amc")) for c in ("16_15", "07_05")])
    out, w = _caught(lambda: other.denoise(inp))
    assert len(w) == 1 and out.source["training_match"]["median_change_cm"] > 2.0


def test_cli_prints_one_line(tmp_path, capsys, clip):
    model = tmp_path / "walk.npz"
    denoise.get("lou-chai").fit([mio.read(datasets.bundled("16_15.amc"))]).save(model)
    src = tmp_path / "in.trc"
    mio.write(_noisy(clip, 0.1), src)
    with warnings.catch_warnings():
        warnings.simplefilter("default")            # independent of pytest's -W options
        rc = cli.main(["denoise", str(src), str(tmp_path / "out.trc"), "--method", "lou-chai",
                       "--model", str(model), "-q"])
    err = capsys.readouterr().err
    assert rc == 0 and (tmp_path / "out.trc").exists()
    lines = [ln for ln in err.splitlines() if "training clips probably do not cover" in ln]
    assert len(lines) == 1 and lines[0].startswith("mocapkit denoise: warning: lou-chai:")
