"""Issue 20: the shipped BRA / BRA-P networks track their input, run without torch (ONNX),
and refuse or flag inputs outside their training range.

Uses the bundled CMU clip 16_15 (walk; subject 16 is held out of the shipped models'
training, benchmarks/train_neural.py) and the shipped ``mocapkit/neural/pretrained/*.onnx``.
Nothing here needs torch except the torch-vs-ONNX agreement test (skipped without it).
"""
from __future__ import annotations

import json
import subprocess
import sys
import warnings

import numpy as np
import pytest

from mocapkit import Motion, corrupt, denoise, io, metrics
from mocapkit.errors import MocapValueError, TrainingMismatchWarning
from mocapkit.neural import clips as C
from mocapkit.neural import pretrained_path

pytestmark = pytest.mark.skipif(not (pretrained_path("bra-p").is_file() and pretrained_path("bra").is_file()),
                                reason="no shipped ONNX models")


@pytest.fixture(scope="module")
def walk() -> Motion:
    from mocapkit.datasets import BUNDLED_DIR, bundled

    if not list(BUNDLED_DIR.rglob("16_15.amc")):
        pytest.skip("bundled clip 16_15.amc not present")
    return io.read(bundled("16_15.amc")).resample(60.0).slice(0, 480)


@pytest.fixture(scope="module", params=["bra-p", "bra"])
def net(request):
    return denoise.get(request.param)


def test_clean_clip_comes_back_within_half_a_cm(net, walk):
    """The defect of issue 20: the old checkpoints returned ~5 cm error on a clean clip."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", TrainingMismatchWarning)     # and no mismatch warning
        out = net.denoise(walk)
    assert metrics.rmse(walk, out) < 0.5
    assert not out.source["model_fit"]["mismatch"]


def test_error_grows_with_noise_and_stays_below_it(net, walk):
    errs, ins = [], []
    for s in (1.0, 3.0, 6.0):
        noisy, _ = corrupt.gaussian(walk, sigma_cm=s, seed=7)
        ins.append(metrics.rmse(walk, noisy))
        errs.append(metrics.rmse(walk, net.denoise(noisy)))
    assert errs[0] < errs[1] < errs[2], errs
    assert all(e < 0.8 * i for e, i in zip(errs, ins)), (errs, ins)


def test_offset_moves_output_by_the_same_offset(net, walk):
    noisy, _ = corrupt.gaussian(walk, sigma_cm=2.0, seed=3)
    out = net.denoise(noisy)
    off = np.array([1e4, 1e4, -1e4])
    out2 = net.denoise(noisy.with_positions(noisy.positions + off))
    np.testing.assert_allclose(out2.positions - off, out.positions, atol=1e-3)


def test_low_frame_rate_is_refused_in_one_line(walk):
    low = walk.resample(15.0)
    with pytest.raises(MocapValueError, match=r"15 fps.*trained at 60 fps.*24-1000 fps") as e:
        denoise.get("bra-p").denoise(low)
    assert "\n" not in str(e.value)


def test_other_frame_rates_are_resampled(walk):
    m120 = walk.resample(120.0).slice(0, 480)
    noisy, _ = corrupt.gaussian(m120, sigma_cm=3.0, seed=1)
    out = denoise.get("bra-p").denoise(noisy)
    assert out.fps == 120.0 and out.n_frames == m120.n_frames
    assert metrics.rmse(m120, out) < 0.8 * metrics.rmse(m120, noisy)


def test_missing_joint_is_refused(walk):
    keep = [n for n in walk.skeleton.names if n != "lfemur"]
    with pytest.raises(MocapValueError, match="lacks 1 of the 21 joints this model needs: lfemur"):
        denoise.get("bra").denoise(walk.select(keep))


def test_mismatch_warns_when_the_output_leaves_the_input():
    """check_model_fit on a network result: a result 5 cm off a clean input warns."""
    from mocapkit.denoise.base import check_model_fit

    rng = np.random.default_rng(0)
    t = np.arange(240) / 60.0
    P = np.stack([np.sin(t + k)[:, None] * np.array([10.0, 5.0, 3.0]) + 20 * k for k in range(5)], axis=1)
    from mocapkit import Skeleton

    sk = Skeleton(tuple("abcde"), [-1, 0, 1, 2, 3], np.ones((5, 3)))
    m = Motion(P, sk, 60.0)
    bad = m.with_positions(P + rng.normal(0, 5.0, P.shape))
    den = denoise.get("bra-p")
    with pytest.warns(TrainingMismatchWarning, match="training clips probably do not cover"):
        check_model_fit(den, m, bad)


def test_inference_without_torch_in_a_subprocess(tmp_path):
    """`--method bra-p` on a machine without torch: `import torch` is blocked."""
    from mocapkit.datasets import bundled

    # a finder that makes every `import torch...` fail (sys.modules['torch'] = None does the
    # same for mocapkit, but scipy's array-API helpers then trip over the None entry)
    code = f"""
import sys, json, importlib.abc
class _NoTorch(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == 'torch' or name.startswith('torch.'):
            raise ModuleNotFoundError("No module named 'torch' (blocked)")
        return None
sys.meta_path.insert(0, _NoTorch())
for k in [k for k in sys.modules if k == 'torch' or k.startswith('torch.')]:
    del sys.modules[k]
from mocapkit import io, corrupt, denoise, metrics
m = io.read({str(bundled('16_15.amc'))!r}).slice(0, 360)
noisy, _ = corrupt.gaussian(m, sigma_cm=3.0, seed=0)
out = {{}}
for name in ('bra-p', 'bra'):
    out[name] = metrics.rmse(m, denoise.get(name).denoise(noisy))
out['input'] = metrics.rmse(m, noisy)
out['torch'] = 'torch' in sys.modules
try:
    denoise.get('bra').fit([m])
    out['fit'] = 'trained'
except Exception as e:
    out['fit'] = type(e).__name__
print(json.dumps(out))
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(r.stdout.strip().splitlines()[-1])
    assert res["torch"] is False and res["fit"] == "MissingDependencyError"
    assert res["bra-p"] < 0.8 * res["input"] and res["bra"] < 0.8 * res["input"]


def test_torch_and_onnx_agree(tmp_path):
    torch = pytest.importorskip("torch")
    pytest.importorskip("onnx")
    from mocapkit.neural import train as TR
    from mocapkit.neural.bundle import Bundle, OnnxNet

    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    t = np.arange(300) / 60.0
    from mocapkit import Skeleton

    par = np.array([-1, 0, 1, 2, 3, 0, 5, 6, 7, 0, 9, 10, 11, 10, 13, 14, 15, 10, 17, 18, 19])
    off = rng.normal(0, 8, (21, 3))
    off[0] = (0, 95, 0)
    sk = Skeleton(C.CMU_21, par, off)
    P = sk.rest_positions()[None] + 4 * np.sin(2 * np.pi * t[:, None, None] + rng.uniform(0, 6, (21, 3)))
    from mocapkit.neural.bundle import make_meta
    from mocapkit.neural.model import build

    cfg = TR.TrainConfig.from_params(**dict(TR.OPERATING_POINT, hidden=16, dropout=0.0))
    src = TR.SyntheticSource([Motion(P, sk, 60.0)], augment=True, mask_input=True, base_sigma=cfg.base_sigma)
    torch.manual_seed(0)
    den = build(src.m, src.n, 16, 0.0, residual=True).eval()
    perc = build(src.n, src.n, 16, 0.0).eval()
    with torch.no_grad():                     # move the residual branch off zero
        den.dec_fc[-1].weight.normal_(0, 0.3)
    meta = make_meta("bra-p", cfg.to_json(), src.joints, src.joints, src.parents, src.offsets,
                     body_size_cm=src.body_size)
    b = Bundle(den, perc, src.norm_in, src.norm_out, meta)
    files = b.export_onnx(tmp_path / "m.onnx")
    assert len(files) == 2
    o = Bundle.load(tmp_path / "m.onnx")
    assert isinstance(o.denoise_net, OnnxNet)
    Z = rng.normal(size=(3, 130, b.denoise_net.m))
    for post in (False, True):
        np.testing.assert_allclose(o.run_windows(Z, postprocess=post), b.run_windows(Z, postprocess=post),
                                   atol=2e-4)
    np.testing.assert_allclose(o.encode_perceptual(Z[..., :63]), b.encode_perceptual(Z[..., :63]), atol=2e-4)
    noisy = corrupt.gaussian(Motion(P, sk, 60.0), sigma_cm=2.0, seed=0)[0]
    np.testing.assert_allclose(o.refine(noisy).positions, b.refine(noisy).positions, atol=1e-3)
