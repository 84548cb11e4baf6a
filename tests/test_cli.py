"""End-to-end CLI tests on the bundled real clip (no shared data needed)."""
import json

import numpy as np
import pytest

from mocapkit import io
from mocapkit.cli import main
from mocapkit.datasets import bundled


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    return bundled("16_15.amc")


def test_info_and_methods(clip, capsys):
    assert main(["info", str(clip), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames"] == 471 and info["joints"] == 31
    assert 150 < info["height_cm"] < 200
    assert main(["methods"]) == 0
    out = capsys.readouterr().out
    assert "gaussian" in out and "spline" in out


def test_corrupt_denoise_eval_roundtrip(clip, tmp_path, capsys):
    noisy, est, mask = tmp_path / "noisy.amc", tmp_path / "est.amc", tmp_path / "mask.npy"
    assert main(["corrupt", str(clip), str(noisy), "--gaussian-cm", "2", "--seed", "1",
                 "--mask", str(mask)]) == 0
    assert np.load(mask).shape == (471, 31)
    assert main(["denoise", str(noisy), str(est), "-q"]) == 0
    capsys.readouterr()
    assert main(["eval", str(clip), str(est), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["rmse"]["unit"] == "cm"
    truth, n = io.read(clip), io.read(noisy)
    from mocapkit import metrics
    assert res["rmse"]["value"] < metrics.rmse(truth, n)   # the cleaned file is closer than the noisy one


def test_bad_input_is_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0\n")
    assert main(["info", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "bad.bvh" in err
    assert main(["info", str(tmp_path / "nope.bvh")]) == 2
    assert main(["denoise", str(bad), str(tmp_path / "o.bvh"), "--method", "no-such-method"]) == 2


def test_refuses_to_overwrite_input(clip, tmp_path, capsys):
    src = tmp_path / "in.amc"
    src.write_bytes(clip.read_bytes())
    (tmp_path / "16.asf").write_bytes((clip.parent / "16.asf").read_bytes())
    before = src.read_bytes()
    assert main(["denoise", str(src), str(src), "--force"]) == 2
    assert src.read_bytes() == before
    assert "input" in capsys.readouterr().err


def test_bench_smoke_quick(tmp_path, capsys):
    out = tmp_path / "smoke.json"
    assert main(["bench", "smoke", "--quick", "--out", str(out), "-q"]) == 0
    rows = json.loads(out.read_text())
    keys = {"protocol", "clip", "condition", "method", "metric", "unit", "value", "paper_value", "seconds"}
    assert rows and all(keys <= set(r) for r in rows)
    assert {r["method"] for r in rows} >= {"gaussian", "spline"}
    for r in rows:
        assert np.isfinite(r["value"]) and r["unit"] == "cm"


def test_train_then_denoise_with_model(clip, tmp_path, capsys):
    model = tmp_path / "walk.npz"
    assert main(["train", "--method", "kalman-learned", str(clip), "-o", str(model), "-q"]) == 0
    noisy = tmp_path / "noisy.amc"
    assert main(["corrupt", str(clip), str(noisy), "--gaussian-cm", "1", "-q"]) == 0
    out = tmp_path / "out.amc"
    assert main(["denoise", str(noisy), str(out), "--method", "kalman-learned", "--model", str(model), "-q"]) == 0
    assert io.read(out).n_frames == 471
    # a data-driven method without a model is refused with advice
    assert main(["denoise", str(noisy), str(tmp_path / "x.amc"), "--method", "kalman-learned"]) == 2
    assert "mocapkit train" in capsys.readouterr().err


def test_denoise_says_when_the_fill_estimate_rests_on_the_files_other_gaps(shared_data, tmp_path, capsys):
    """The basket sprint's real gaps: most of auto's long fills have no observed stretch of
    their own gap to be judged on, so the fill-auto line says the estimate may run low
    (on real occlusions, scaled for such fills, a median three quarters of the true error);
    Eb015pr's few gaps are judged on their own stretches, and the line says nothing of it."""
    lines = {}
    for name in ("kineticstoolkit/kinematics_basket_sprint.c3d", "c3d_org/Eb015pr.c3d"):
        assert main(["denoise", str(shared_data / "markers" / name), str(tmp_path / "o.c3d"), "--force"]) == 0
        out = capsys.readouterr().out
        lines[name] = next(x for x in out.splitlines() if x.startswith("fill-auto:"))
    assert "the estimate may run low" in lines["kineticstoolkit/kinematics_basket_sprint.c3d"]
    assert "may run low" not in lines["c3d_org/Eb015pr.c3d"]
