"""The array toolkit: one noise estimator, one window module, one solver input contract."""
import numpy as np
import pytest

from mocapkit import windows
from mocapkit.errors import MocapValueError
from mocapkit.signal import estimate_noise
from mocapkit.solvers._linalg import prepare


# -- estimate_noise ----------------------------------------------------------------------
def test_estimate_noise_options_match_hand_computed_values():
    X = np.array([[0.0, 1.0], [1.0, 1.0], [4.0, 2.0], [9.0, 0.0], [16.0, 5.0], [25.0, 5.0]])
    D = X[2:] - 2 * X[1:-1] + X[:-2]                     # col 0: all 2; col 1: 1, -3, 7, -5
    med = np.median(D, axis=0)
    per = 1.4826 * np.median(np.abs(D - med), axis=0) / np.sqrt(6)
    np.testing.assert_allclose(estimate_noise(X), per)
    assert per[0] == 0 and per[1] > 0
    assert estimate_noise(X, pool="median") == pytest.approx(np.median(per))
    assert estimate_noise(X, pool="all") == pytest.approx(1.4826 * np.median(np.abs(D)) / np.sqrt(6))
    assert estimate_noise(X, method="diff2-rms", pool="all") == pytest.approx(np.sqrt(np.mean(D ** 2) / 6))
    np.testing.assert_allclose(estimate_noise(X, method="diff2-rms"), np.sqrt(np.mean(D ** 2, axis=0) / 6))


def test_estimate_noise_uses_only_observed_triples_and_falls_back():
    rng = np.random.default_rng(0)
    X = np.cumsum(rng.standard_normal((50, 3)), axis=0)
    M = np.ones_like(X, bool)
    M[10, 0] = False
    Xn = np.where(M, X, 1e6)                              # a wild value where unobserved
    keep = np.ones(48, bool)
    keep[8:11] = False                                    # triples touching frame 10
    D = (X[2:] - 2 * X[1:-1] + X[:-2])[keep, 0]
    expect = 1.4826 * np.median(np.abs(D - np.median(D))) / np.sqrt(6)
    assert estimate_noise(Xn, M)[0] == pytest.approx(expect)
    assert np.isnan(estimate_noise(X[:2])).all()                          # < 3 frames
    assert estimate_noise(X[:2], pool="median", fallback=0.0) == 0.0
    assert estimate_noise(X[:2], method="diff2-rms", pool="all", fallback=1.5) == 1.5
    with pytest.raises(MocapValueError, match="method"):
        estimate_noise(X, method="mad")


def test_estimate_noise_diff4_mad_hand_computed_unbiased_and_less_leaky():
    rng = np.random.default_rng(3)
    X = np.cumsum(rng.standard_normal((40, 2)), axis=0)
    M = np.ones_like(X, bool)
    M[20, 1] = False
    D = X[4:] - 4 * X[3:-1] + 6 * X[2:-2] - 4 * X[1:-3] + X[:-4]
    keep = np.ones(36, bool)
    keep[16:21] = False                                   # quintuples touching frame 20
    d1 = D[keep, 1]
    expect = 1.4826 * np.median(np.abs(d1 - np.median(d1))) / np.sqrt(70)
    assert estimate_noise(np.where(M, X, 1e6), M, method="diff4-mad")[1] == pytest.approx(expect)
    pooled = np.concatenate([D[:, 0], d1])
    assert estimate_noise(X, M, method="diff4-mad", pool="all") == pytest.approx(
        1.4826 * np.median(np.abs(pooled)) / np.sqrt(70))
    # white noise: the same sigma as diff2; a smooth motion leaks in far less
    t = np.arange(4000)[:, None] / 30.0
    motion = 20.0 * np.sin(2 * np.pi * 1.5 * t) * [1.0, 0.5, 2.0]
    noise = 0.05 * rng.standard_normal(motion.shape)
    assert estimate_noise(noise, method="diff4-mad", pool="all") == pytest.approx(0.05, rel=0.05)
    s2 = estimate_noise(motion + noise, method="diff2-mad", pool="all")
    s4 = estimate_noise(motion + noise, method="diff4-mad", pool="all")
    assert s4 < 0.5 * s2 and s4 < 0.08
    assert np.isnan(estimate_noise(X[:4], method="diff4-mad")).all()     # < 5 frames


def test_estimate_noise_diff4_rms_reads_the_second_moment_of_heavy_tailed_noise():
    """White Gaussian noise: diff4-rms and diff4-mad agree; a mixture (70 % exact
    samples, 30 % off by 2 cm) has RMS 1.1 cm, which the RMS reads and the MAD does not."""
    rng = np.random.default_rng(4)
    g = 0.5 * rng.standard_normal((6000, 3))
    assert estimate_noise(g, method="diff4-rms", pool="all") == pytest.approx(0.5, rel=0.03)
    per = estimate_noise(g, method="diff4-rms")
    D = g[4:] - 4 * g[3:-1] + 6 * g[2:-2] - 4 * g[1:-3] + g[:-4]
    assert per == pytest.approx(np.sqrt(np.mean(D ** 2, axis=0) / 70))
    mix = np.where(rng.random(g.shape) < 0.3, 2.0 * rng.standard_normal(g.shape), 0.0)
    rms = float(np.sqrt(np.mean(mix ** 2)))
    assert estimate_noise(mix, method="diff4-rms", pool="all") == pytest.approx(rms, rel=0.05)
    assert estimate_noise(mix, method="diff4-mad", pool="all") < 0.7 * rms


def test_estimate_noise_wavelet_mad_is_donoho_johnstone():
    pywt = pytest.importorskip("pywt")
    rng = np.random.default_rng(1)
    X = np.sin(np.linspace(0, 6, 512))[:, None] * [5.0, 1.0] + 0.3 * rng.standard_normal((512, 2))
    d1 = pywt.dwt(X, "db4", mode="symmetric", axis=0)[1]
    np.testing.assert_array_equal(estimate_noise(X, method="wavelet-mad", wavelet="db4"),
                                  np.median(np.abs(d1), axis=0) / 0.6745)
    np.testing.assert_allclose(estimate_noise(X, method="wavelet-mad", wavelet="db4"), 0.3, rtol=0.15)
    with pytest.raises(MocapValueError):
        estimate_noise(np.where(X > 4, np.nan, X), method="wavelet-mad", wavelet="db4")


# -- windows -----------------------------------------------------------------------------
def test_lagged_windows_and_overlap_add_with_weights():
    rng = np.random.default_rng(2)
    X = rng.standard_normal((9, 2, 3))                   # (T, J, 3): channels flattened
    W = windows.lagged(X, 4)
    assert W.shape == (6, 24)
    np.testing.assert_array_equal(W[2], X[2:6].ravel())
    V = windows.lagged(X, 4, view=True)
    np.testing.assert_array_equal(V, W)
    assert not V.flags.writeable
    assert windows.lagged(X > 0, 4).dtype == bool
    acc, cnt = windows.overlap_add(W, 9, 4)
    np.testing.assert_array_equal(cnt, windows.counts(9, 4))
    np.testing.assert_allclose(acc / cnt[:, None], X.reshape(9, -1))
    w = np.array([1, 0, 1, 1, 0, 1], bool)               # windows 1 and 4 not coded
    acc, cnt = windows.overlap_add(W, 9, 4, weights=w)
    np.testing.assert_array_equal(cnt, [1, 1, 2, 3, 2, 3, 2, 1, 1])
    np.testing.assert_allclose(acc / cnt[:, None], X.reshape(9, -1))
    st = windows.window_starts(9, 4, 4)
    np.testing.assert_array_equal(st, [0, 4, 5])
    np.testing.assert_allclose(windows.overlap_mean(W[st], 9, 4, st), X.reshape(9, -1))
    with pytest.raises(MocapValueError, match="at least 4 frames"):
        windows.lagged(X[:3], 4)


# -- prepare -----------------------------------------------------------------------------
def test_prepare_contract():
    X = np.arange(12.0).reshape(4, 3)
    Z, m = prepare(X)
    assert m.all() and prepare(X, full_mask=False)[1] is None
    mask = np.ones((4, 3), bool)
    mask[1, 2] = False
    Xn = np.where(mask, X, np.nan)
    Z, m = prepare(Xn, mask)
    assert Z[1, 2] == 0.0 and not m[1, 2] and np.isnan(Xn[1, 2])     # input untouched
    with pytest.raises(MocapValueError, match="no mask"):
        prepare(Xn)
    with pytest.raises(MocapValueError, match="marked as observed"):
        prepare(Xn, np.ones((4, 3), bool))
    with pytest.raises(MocapValueError, match="no observed entries"):
        prepare(X, np.zeros((4, 3), bool))
    with pytest.raises(MocapValueError, match="D must be a 2-D"):
        prepare(np.ones(3), name="D")
    assert prepare(np.ones((2, 4, 3)), batch=True)[0].shape == (2, 4, 3)


@pytest.mark.parametrize("shape", [(1, 4), (7, 5), (62, 31), (128, 6, 3), (2049, 3)])
def test_nanmedian0_is_numpys_nanmedian_bit_for_bit(shape):
    """The one column-median helper: by a sort on short columns, numpy's own beyond
    NANMEDIAN_SORT_MAX -- the same numbers either way, NaN (no warning) where a column
    holds none."""
    import warnings

    from mocapkit.signal._arrays import nanmedian0

    rng = np.random.default_rng(sum(shape))
    A = rng.normal(size=shape)
    A[rng.random(shape) < 0.3] = np.nan
    A[:, 0] = np.nan                                       # a column with no value
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        want = np.nanmedian(A, axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = nanmedian0(A)
    np.testing.assert_array_equal(got, want)
