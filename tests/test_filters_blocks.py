"""Blocked / chunked filter paths (issue 21: memory at 100,000 frames) against the
whole-array computations they replace, and their memory bound."""
import tracemalloc

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d
from scipy.signal import butter, sosfiltfilt

from mocapkit import denoise, signal
from mocapkit.denoise.wavelet import wavelet_shrink
from mocapkit.signal._arrays import by_channel_blocks, channel_blocks
from mocapkit.signal.filters import hampel_scores


def _trend_pad(X, n, m):
    """Whole-array reference of the 'odd' end extension (module doc of signal.filters)."""
    w = (2.0 * (2 * m - 1) - 6.0 * np.arange(m)) / (m * (m + 1))
    a0, a1 = w @ X[:m], w @ X[::-1][:m]
    return np.concatenate([2 * a0 - X[n:0:-1], X, 2 * a1 - X[-2:-n - 2:-1]])


@pytest.fixture
def walk():
    # 37 channels: two full blocks of 16 and a short one
    return np.cumsum(np.random.default_rng(7).normal(size=(700, 37)), axis=0) * 3.0


def test_channel_blocks_cover_every_channel_once():
    sl = channel_blocks(37)
    assert [(s.start, s.stop) for s in sl] == [(0, 16), (16, 32), (32, 37)]
    assert channel_blocks(0) == []
    A = np.arange(12.0).reshape(3, 4)
    out = by_channel_blocks(lambda B: 2 * B, A)
    assert out.flags.c_contiguous and np.array_equal(out, 2 * A)
    seen = []
    out = by_channel_blocks(lambda B: seen.append(B.shape) or B[:, ::-1], A, block=3)
    assert seen == [(3, 3), (1, 3)] and np.array_equal(out, A[::-1])


def test_blocked_gaussian_and_butterworth_equal_whole_array_filters(walk):
    X = walk
    ref = gaussian_filter1d(_trend_pad(X, 5, 11), 2.0, axis=0, radius=5, mode="nearest")[5:-5]
    np.testing.assert_array_equal(signal.gaussian(X, sigma=2.0, radius=5), ref)
    # butterworth: padlen max(15, fs/cutoff = 20) frames, end lines over 10 samples
    sos = butter(4, 6.0 / 60.0, output="sos")
    ref = sosfiltfilt(sos, _trend_pad(X, 20, 10), axis=0, padtype=None)[20:-20]
    np.testing.assert_allclose(signal.butterworth(X, fs=120.0, cutoff_hz=6.0), ref, rtol=0, atol=1e-12)
    # the input is only read
    assert np.array_equal(X, walk)


def test_blocked_wavelet_equals_whole_array_shrinkage(walk):
    pywt = pytest.importorskip("pywt")
    X = walk
    w = pywt.Wavelet("bior3.5")
    for mode in ("soft", "hard"):
        coeffs = pywt.wavedec(X, w, mode="symmetric", level=5, axis=0)
        d1 = pywt.dwt(X, w, mode="symmetric", axis=0)[1]
        thr = np.median(np.abs(d1), axis=0) / 0.6745 * np.sqrt(2 * np.log(len(X)))
        out = [coeffs[0]] + [np.sign(d) * np.maximum(np.abs(d) - thr, 0) if mode == "soft"
                             else np.where(np.abs(d) > thr, d, 0.0) for d in coeffs[1:]]
        ref = pywt.waverec(out, w, mode="symmetric", axis=0)[:len(X)]
        np.testing.assert_allclose(wavelet_shrink(X, mode=mode), ref, rtol=0, atol=1e-10)


@pytest.mark.parametrize("scale", ["both", "global", "local"])
def test_hampel_scores_equal_the_residual_arrays(walk, scale):
    X = walk[:, :36].copy()
    X[100, 4] += 40.0                                     # a spike
    X[:, 9] = 5.0                                         # a flat channel: MAD 0 -> 0/0, x/0
    X[50, 9] = 6.0
    med, res, sig = signal.hampel_residuals(X, window=7, scale=scale, min_sigma=0.0,
                                            exclude_center=True)
    sigs = list(sig) if scale == "both" else [sig]
    scales = ("global", "local") if scale == "both" else (scale,)
    with np.errstate(divide="ignore", invalid="ignore"):
        got_sum = hampel_scores(X, window=7, scales=scales, exclude_center=True, group=3, chunk=61)
        got_max = hampel_scores(X, window=7, scales=scales, exclude_center=True, group=3,
                                reduce="max", chunk=61)
        for sg, gs, gm in zip(sigs, got_sum, got_max):
            z2 = ((res / sg) ** 2).reshape(len(X), 12, 3)
            np.testing.assert_array_equal(gs, z2.sum(axis=2))                    # NaN where 0/0
            np.testing.assert_array_equal(gm > 9.0, (z2 > 9.0).any(axis=2))    # any coordinate
    assert (got_sum[0][100, 1] > 100) and not np.isnan(got_max[0][50, 3])


def test_hampel_denoiser_unchanged_by_the_chunked_scores():
    """The 3-dof joint flags of the hampel method from the old whole-array formula."""
    rng = np.random.default_rng(3)
    T, J = 500, 6
    P = np.cumsum(rng.normal(size=(T, J, 3)), axis=0) + rng.normal(0, 0.5, (T, J, 3))
    P[rng.random((T, J)) < 0.03] += 20.0
    from mocapkit import Motion, Skeleton
    sk = Skeleton(tuple(f"m{j}" for j in range(J)), [-1] + [0] * (J - 1), np.zeros((J, 3)))
    mo = Motion(P, sk, 120.0)
    h = denoise.get("hampel")
    _, res, sig = signal.hampel_residuals(mo.matrix(), window=7, scale="both", min_sigma=0.5,
                                          exclude_center=True)
    ref = np.ones((T, J), bool)
    for sg, n in zip(sig, (3.0, 2.0)):
        ref &= ((res / sg).reshape(T, J, 3) ** 2).sum(axis=2) > float(signal.gate_threshold(n, 3))
    np.testing.assert_array_equal(h.flags(mo), ref)
    assert ref.sum() > 50


def _peak_over_input(fn, X):
    fn(X[:200])                                           # imports, caches
    tracemalloc.start()
    try:
        fn(X)
        return tracemalloc.get_traced_memory()[1] / X.nbytes
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize("name", ["gaussian", "butterworth", "wavelet", "hampel_scores"])
def test_blocked_filters_need_about_one_matrix_besides_the_input(name):
    # 20,000 frames x 93 channels (15 MB): a whole-array temporary would add 1x each
    X = np.cumsum(np.random.default_rng(1).normal(size=(20000, 93)), axis=0)
    fn = {"gaussian": lambda A: signal.gaussian(A, sigma=2.0, radius=5),
          "butterworth": lambda A: signal.butterworth(A, fs=120.0, cutoff_hz=6.0),
          "wavelet": wavelet_shrink,
          # chunk temporaries are fixed (chunk x C x window), not a share of T: small here
          "hampel_scores": lambda A: hampel_scores(A, group=3, exclude_center=True, chunk=512)}[name]
    bound = 2.5 if name == "hampel_scores" else 2.0       # result(s) + blocks / chunks
    assert _peak_over_input(fn, X) < bound
