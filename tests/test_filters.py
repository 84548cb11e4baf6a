"""Classical filters (mocapkit.signal + mocapkit.denoise.filters) against scipy and known answers."""
import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d, median_filter
from scipy.signal import butter, savgol_filter, sosfreqz

from mocapkit import Motion, Skeleton, denoise, gaps, signal
from mocapkit.errors import MocapError, MocapValueError

FILTERS = ("gaussian", "spline", "linear", "butterworth", "savgol", "median", "hampel")


def smooth_motion(T=600, J=8, fps=120.0, seed=0):
    """Sums of slow sinusoids (0.3-1.5 Hz, 3-12 cm): marker-like smooth tracks, cm."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / fps
    f = rng.uniform(0.3, 1.5, (J, 3, 3))
    a = rng.uniform(3, 12, (J, 3, 3))
    ph = rng.uniform(0, 2 * np.pi, (J, 3, 3))
    P = (a[None] * np.sin(2 * np.pi * f[None] * t[:, None, None, None] + ph[None])).sum(-1)
    P += rng.uniform(-50, 50, (J, 3))
    sk = Skeleton(tuple(f"m{j}" for j in range(J)), [-1] + [0] * (J - 1), np.zeros((J, 3)))
    return Motion(P, sk, fps)


# -- gaps.fill / spline / linear -------------------------------------------------------------
def test_spline_exact_on_cubic_and_keeps_observed_bitwise():
    T = 80
    t = np.arange(T, dtype=float)
    cubic = np.stack([0.001 * t ** 3 - 0.1 * t ** 2 + 2 * t + 5,
                      -0.0005 * t ** 3 + 0.02 * t ** 2 - t,
                      0.3 * t + 1.0], axis=1)
    P = np.stack([cubic, 2 * cubic + 1], axis=1)                 # (T, 2, 3)
    obs = np.ones((T, 2), bool)
    obs[10:25, 0] = False                                         # interior gaps only
    obs[40:43, 0] = False
    obs[5:60:3, 1] = False
    mo = Motion(P, Skeleton(("a", "b"), [-1, 0], np.zeros((2, 3))), 30.0, obs)
    out = denoise.get("spline").denoise(mo)
    np.testing.assert_allclose(out.positions, P, atol=1e-9, rtol=0)
    np.testing.assert_array_equal(out.positions[obs], mo.positions[obs])   # bit-identical
    assert out.observed.all()


def test_fill_gaps_ends_and_linear():
    t = np.arange(20, dtype=float)
    x = np.stack([3 * t - 7, -t + 2], axis=1)
    m = np.ones_like(x, bool)
    m[:4] = False
    m[15:] = False
    m[8:11, 0] = False
    near = gaps.fill(np.where(m, x, np.nan), m, kind="cubic")
    np.testing.assert_allclose(near[:4], np.repeat(x[4:5], 4, axis=0))          # held
    np.testing.assert_allclose(near[15:], np.repeat(x[14:15], 5, axis=0))
    for kind in ("cubic", "linear"):
        lin = gaps.fill(np.where(m, x, np.nan), m, kind=kind, ends="linear")
        np.testing.assert_allclose(lin, x, atol=1e-9)                          # a line is kept
    # linear fill between two points is the chord
    y = np.array([0.0, np.nan, np.nan, 3.0])
    np.testing.assert_allclose(gaps.fill(y, kind="linear"), [0, 1, 2, 3])
    assert np.isnan(gaps.fill(np.full((5, 2), np.nan), kind="cubic")).all()   # never observed: stays NaN
    with pytest.raises(MocapValueError, match="mask shape"):
        gaps.fill(y, np.ones(3, bool))


def test_never_observed_joint_is_named():
    """Issue 18: a never-observed joint is returned missing and named in the gap report
    (it used to raise here and be filled with (0, 0, 0) by the low-rank methods)."""
    mo = smooth_motion(T=50, J=3)
    obs = mo.observed.copy()
    obs[:, 2] = False
    for name in ("spline", "gaussian", "kalman-cv"):
        out = denoise.get(name).denoise(mo.with_observed(obs))
        assert not out.observed[:, 2].any() and np.isnan(out.positions[:, 2]).all()
        assert out.observed[:, :2].all() and np.isfinite(out.positions[:, :2]).all()
        assert out.source["gap_report"]["never_observed"] == ["m2"]


def test_linear_fill_keeps_observed_and_interpolates():
    mo = smooth_motion(T=100, J=2)
    obs = mo.observed.copy()
    obs[30:40, 1] = False
    out = denoise.get("linear").denoise(mo.with_observed(obs))
    P = mo.positions
    w = (np.arange(30, 40) - 29) / 11.0
    expect = (1 - w)[:, None] * P[29, 1] + w[:, None] * P[40, 1]
    np.testing.assert_allclose(out.positions[30:40, 1], expect, atol=1e-12)
    np.testing.assert_array_equal(out.positions[obs], mo.positions[obs])


# -- gaussian ------------------------------------------------------------------------------
def test_gaussian_matches_scipy(rng):
    X = np.cumsum(rng.normal(size=(200, 6)), axis=0)
    np.testing.assert_allclose(signal.gaussian(X, sigma=2.0, radius=5, mode="reflect"),
                               gaussian_filter1d(X, 2.0, axis=0, radius=5, mode="reflect"), atol=1e-12)
    # default trend-preserving ends: identical in the interior; at the ends it equals
    # scipy on the explicitly extended signal (reflection about the local-line end value)
    Y = signal.gaussian(X, sigma=2.0, radius=5)
    ref = gaussian_filter1d(X, 2.0, axis=0, radius=5)
    np.testing.assert_allclose(Y[5:-5], ref[5:-5], atol=1e-12)
    m = 11
    w = (2.0 * (2 * m - 1) - 6.0 * np.arange(m)) / (m * (m + 1))
    a0, a1 = w @ X[:m], w @ X[::-1][:m]
    ext = np.concatenate([2 * a0 - X[5:0:-1], X, 2 * a1 - X[-2:-7:-1]])
    np.testing.assert_allclose(Y, gaussian_filter1d(ext, 2.0, axis=0, radius=5, mode="nearest")[5:-5], atol=1e-12)
    # a straight line (constant-speed marker) passes unchanged, ends included
    line = np.outer(np.arange(50.0), [1.0, -2.0]) + 3
    np.testing.assert_allclose(signal.gaussian(line, sigma=3.0), line, atol=1e-9)


def test_gaussian_denoiser_defaults_are_lou_chai_window_11():
    mo = smooth_motion(T=300, J=3)
    noisy = mo.with_positions(mo.positions + np.random.default_rng(1).normal(0, 2, mo.positions.shape))
    out = denoise.get("gaussian").denoise(noisy)
    X = noisy.matrix()
    ref = gaussian_filter1d(X, 2.0, axis=0, radius=5)          # window 11, sigma (11-1)/5
    np.testing.assert_allclose(out.matrix()[5:-5], ref[5:-5], atol=1e-12)
    assert denoise.get("gaussian", sigma_frames=3).kernel() == (3.0, 12)
    assert denoise.get("gaussian", window=21).kernel() == (4.0, 10)
    err_in = np.sqrt(np.mean((noisy.positions - mo.positions) ** 2))
    err_out = np.sqrt(np.mean((out.positions - mo.positions) ** 2))
    assert err_out < 0.5 * err_in
    with pytest.raises(MocapValueError):
        denoise.get("gaussian", window=4).denoise(mo)


def test_median_prepass_removes_spikes():
    mo = smooth_motion(T=400, J=4)
    P = np.array(mo.positions)
    P[::37, :, 1] += 20.0                                       # isolated 20 cm spikes
    noisy = mo.with_positions(P)
    plain = denoise.get("gaussian").denoise(noisy)
    robust = denoise.get("gaussian", median=5).denoise(noisy)
    e = lambda m: np.sqrt(np.mean((m.positions - mo.positions) ** 2))
    assert e(robust) < 0.3 * e(plain)


# -- butterworth / savgol / median -------------------------------------------------------------
def test_butterworth_attenuation_matches_design():
    fs, fc = 120.0, 6.0
    t = np.arange(1200) / fs
    X = np.stack([np.sin(2 * np.pi * 1.0 * t), np.sin(2 * np.pi * 20.0 * t)], axis=1)
    Y = signal.butterworth(X, fs=fs, cutoff_hz=fc, order=4)
    sos = butter(4, fc / (fs / 2), output="sos")
    _, h = sosfreqz(sos, worN=[1.0, 20.0], fs=fs)
    gain = np.abs(h) ** 2                                        # forward-backward squares |H|
    mid = slice(240, 960)                                        # whole periods of 1, 6, 20 Hz
    amp = np.sqrt(2 * np.mean(Y[mid] ** 2, axis=0))
    np.testing.assert_allclose(amp, gain, rtol=2e-3, atol=1e-5)
    assert amp[1] < 1e-3 and amp[0] > 0.99                      # 20 Hz gone, 1 Hz kept
    # at the cutoff the zero-phase gain is exactly |H|^2 = 1/2
    Yc = signal.butterworth(np.sin(2 * np.pi * fc * t), fs=fs, cutoff_hz=fc)
    assert abs(np.sqrt(2 * np.mean(Yc[mid] ** 2)) - 0.5) < 5e-3


def test_butterworth_errors_are_clear():
    with pytest.raises(MocapValueError, match="at least 16 frames"):
        signal.butterworth(np.zeros((10, 2)), fs=120, cutoff_hz=6)
    with pytest.raises(MocapValueError, match="Nyquist"):
        signal.butterworth(np.zeros((100, 2)), fs=30, cutoff_hz=20)
    mo = smooth_motion(T=8, J=2)
    with pytest.raises(MocapError):
        denoise.get("butterworth").denoise(mo)


def test_savgol_and_median_match_scipy(rng):
    X = np.cumsum(rng.normal(size=(150, 4)), axis=0)
    np.testing.assert_allclose(signal.savgol(X, window=11, polyorder=3),
                               savgol_filter(X, 11, 3, axis=0, mode="interp"), atol=1e-12)
    np.testing.assert_allclose(signal.median(X, window=5),
                               median_filter(X, size=(5, 1), mode="mirror"), atol=0)
    t = np.arange(60.0)
    cubic = (0.01 * t ** 3 - t ** 2 + 4)[:, None]
    np.testing.assert_allclose(signal.savgol(cubic, window=11, polyorder=3), cubic, atol=1e-7)


# -- hampel --------------------------------------------------------------------------------
def test_hampel_function_matches_bruteforce(rng):
    X = rng.normal(size=(40, 3))
    X[7, 1] += 10
    Y, flags = signal.hampel(X, window=5, n_sigmas=3.0)
    idx = np.arange(-2, 42)
    idx = np.where(idx < 0, -idx - 1, np.where(idx >= 40, 79 - idx, idx))   # 'reflect'
    Pd = X[idx]
    for t in range(40):
        for c in range(3):
            w = Pd[t:t + 5, c]
            med = np.median(w)
            sig = 1.4826 * np.median(np.abs(w - med))
            f = abs(X[t, c] - med) > 3 * sig
            assert flags[t, c] == f
            assert Y[t, c] == (med if f else X[t, c])
    assert flags[7, 1]


def test_hampel_flags_spikes_recall_and_false_alarms():
    recalls, fps_ = [], []
    for seed in range(2):
        rng = np.random.default_rng(10 + seed)
        clean = smooth_motion(T=1000, J=10, seed=seed)
        T, J = clean.observed.shape
        P = clean.positions + rng.normal(0, 2.0, (T, J, 3))
        spikes = rng.random((T, J)) < 0.05
        d = rng.normal(size=(T, J, 3))
        d /= np.linalg.norm(d, axis=2, keepdims=True)
        P[spikes] += 15.0 * d[spikes]                           # 15 cm in a random direction
        out = denoise.get("hampel").denoise(clean.with_positions(P))
        f = out.source["flagged"]
        assert f.shape == (T, J) and f.dtype == bool
        recalls.append((f & spikes).sum() / spikes.sum())
        fps_.append((f & ~spikes).sum() / (~spikes).sum())
        # flagged joints are refilled: the spikes are gone from the output
        err_spk = np.sqrt(np.mean((out.positions[spikes] - clean.positions[spikes]) ** 2))
        assert err_spk < 4.0
    assert min(recalls) >= 0.95, recalls
    assert max(fps_) <= 0.01, fps_


# -- every filter: shapes, completeness, missing markers ---------------------------------------
@pytest.mark.parametrize("name", FILTERS)
def test_filters_complete_output_with_30pct_missing(name):
    mo = smooth_motion(T=300, J=6, seed=3)
    rng = np.random.default_rng(4)
    obs = rng.random(mo.observed.shape) > 0.3
    obs[0] = True                                               # keep every joint seen at least once
    noisy = mo.with_positions(mo.positions + rng.normal(0, 1.0, mo.positions.shape)).with_observed(obs)
    out = denoise.get(name).denoise(noisy)
    assert out.positions.shape == mo.positions.shape
    assert out.observed.all() and np.isfinite(out.positions).all()
    assert out.skeleton == mo.skeleton and out.fps == mo.fps
    err = np.sqrt(np.mean((out.positions - mo.positions) ** 2))
    assert err < 2.0, f"{name}: {err:.2f} cm"
    assert not noisy.observed.all()                             # input untouched


def test_registry_metadata():
    av = denoise.available()
    for name in FILTERS:
        cls = av[name]
        assert cls.description and not cls.needs_training
    assert av["spline"].keeps_observed and av["linear"].keeps_observed
    assert denoise.DEFAULT_METHOD in denoise.available()


# -- one real clip -------------------------------------------------------------------------------
def test_filters_on_real_clip(shared_data):
    pytest.importorskip("mocapkit.io.amc")
    from mocapkit import io
    from mocapkit.datasets import cmu_amc

    path = cmu_amc("16_15", shared_data)
    if path is None:
        pytest.skip("CMU 16_15 not in the data set")
    clean = io.read(path).slice(0, 300)
    rng = np.random.default_rng(0)
    noise = rng.normal(0, 2.0, clean.positions.shape)
    obs = rng.random(clean.observed.shape) > 0.3
    obs[0] = True
    noisy = clean.with_positions(clean.positions + noise).with_observed(obs)
    for name in FILTERS:
        out = denoise.get(name).denoise(noisy)
        # everything filled but what the policy's speed check drops: the truth's left arm
        # jumps 85 cm between frames 1 and 2 (an artefact of the AMC), and a fill of frame
        # 1 between them is at least 40 cm off (gaps.unreachable_fills); hampel moves a
        # measured sample next to it, given back, and the fills beside that one go too
        # as above, and (since the policy's self-validation,
        # 2026-12-05) the fills the method's own validation on the clip puts over 5 cm RMSE:
        # the interpolating spline and the median through 2 cm noise, 13 and 7 samples
        left = ~out.observed
        rep = out.source["gap_report"]
        assert left.sum() == rep["left_implausible"] <= 20
        assert set(rep["left_implausible_by"]) <= {"out of the marker's reach", "not validated under 5 cm"}
        assert left[10:].sum() <= rep["left_implausible_by"].get("not validated under 5 cm", 0)
        assert np.isfinite(out.positions[out.observed]).all()
        err = float(np.sqrt(np.mean((out.positions - clean.positions)[out.observed] ** 2)))
        if name in ("gaussian", "butterworth", "savgol"):
            assert err < 1.6, f"{name}: {err:.2f} cm"        # smoothing beats the 2 cm noise
