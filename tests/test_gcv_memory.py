"""gcv_smooth's memory-saving paths (issue 21) give the numbers of the plain ones."""
import tracemalloc

import numpy as np

from mocapkit.solvers import gcv_spline as g


def _data(T=400, C=9, seed=0):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 4 * np.pi, T)[:, None]
    X = 10 * np.sin(t * rng.uniform(0.5, 2, C)) + rng.normal(0, 0.5, (T, C))
    M = rng.random((T, C)) > 0.1
    return X, M


def test_select_and_fit_in_place_and_bool_weights_match_fresh_float_ones():
    X, M = _data()
    from mocapkit.gaps import fill

    Y = fill(X, M)
    f_ref, s_ref = g._select_and_fit(Y, M.astype(float), 2, None, Y)
    f_bool, s_bool = g._select_and_fit(Y, M, 2, None, Y)
    np.testing.assert_array_equal(f_bool, f_ref)
    np.testing.assert_array_equal(s_bool, s_ref)
    prev = f_ref.copy()
    f_new, s_new = g._select_and_fit(Y, M.astype(float), 2, None, prev.copy())
    buf = prev.copy()
    f_in, s_in = g._select_and_fit(Y, M.astype(float), 2, None, buf, out=buf)
    assert f_in is buf
    np.testing.assert_array_equal(f_in, f_new)
    np.testing.assert_array_equal(s_in, s_new)


def test_blocked_trace_and_dct_match_whole_array_formulas():
    X, M = _data(C=37)
    s = np.logspace(-1, 4, 37)
    ref = (1.0 / (1.0 + g._eig(400, 2)[:, None] * s[None, :])).sum(axis=0)
    np.testing.assert_allclose(g._trace(400, s, 2), ref, rtol=1e-14)
    from scipy.fft import dct
    W = M.astype(float)
    f = np.roll(X, 3, axis=0)
    ref = dct(W * X + (1.0 - W) * f, type=2, norm="ortho", axis=0)
    np.testing.assert_allclose(g._completed_dct(X, M, f, np.empty_like(X)), ref, rtol=0, atol=1e-12)
    g._completed_dct(X, M, f, f)                          # into f itself
    np.testing.assert_allclose(f, ref, rtol=0, atol=1e-12)


def test_gcv_smooth_robust_and_complete_data_paths_run_and_keep_input():
    X, M = _data(C=6, seed=2)
    X[50, 0] += 30.0
    X0 = X.copy()
    f, info = g.gcv_smooth(X, robust=True, group=3)      # complete data: read, not copied
    assert np.array_equal(X, X0)
    assert info.rejected[50, 0] and np.isfinite(f).all()
    f2, info2 = g.gcv_smooth(X, M, group=3)             # gaps: hole validation path
    assert info2.hole_map is not None and np.isfinite(f2).all()


def test_gcv_smooth_needs_about_one_matrix_besides_the_input():
    X = np.cumsum(np.random.default_rng(1).normal(size=(20000, 93)), axis=0)
    g.gcv_smooth(X[:500], group=3)
    tracemalloc.start()
    try:
        g.gcv_smooth(X, group=3)
        peak = tracemalloc.get_traced_memory()[1] / X.nbytes
    finally:
        tracemalloc.stop()
    assert peak < 2.0, peak            # the fit + blocks (was 5x: float mask, DCT, copies)
