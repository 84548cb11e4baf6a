"""The Whittaker solve behind the GCV spline: columns solved side by side in one banded
system (``_solve_weighted``) solve each column's normal equations to round-off."""
import numpy as np
import pytest

from mocapkit.solvers import gcv_spline as g


def _backward_error(f, y, w, s, order):
    """Relative residual of (diag(w) + s D^T D) f = w y, the minimiser's normal equations
    (a backward error: with s up to 1e4 the system's condition number reaches ~1e12, so two
    correct solvers' f may differ in the 5th digit while both residuals sit at round-off)."""
    D = np.diff(np.eye(len(y)), n=order, axis=0)
    A = np.diag(w) + s * D.T @ D
    return np.abs(A @ f - w * y).max() / (np.abs(A) @ np.abs(f) + np.abs(w * y)).max()


@pytest.mark.parametrize("T, C, order", [(5, 7, 2), (79, 37, 2), (79, 37, 3), (1000, 10, 2)])
def test_columns_side_by_side_solve_each_columns_normal_equations(T, C, order):
    rng = np.random.default_rng(T + C + order)
    Y = rng.normal(size=(T, C)).cumsum(axis=0)
    W = (rng.random((T, C)) > 0.3) * rng.uniform(0.2, 1.0, (T, C))    # float weights with holes
    W[:, 1] = 1.0
    W[:, 2] = 0.0
    W[: order + 1, 2] = 1.0 if T > order + 1 else 0.0                 # exactly order + 1 weights
    W[1:, 3] = 0.0                                                    # too few: the column keeps Y
    s = 10.0 ** rng.uniform(-1, 4, C)
    s[5:7] = s[4]                                                     # equal neighbours
    out = g._solve_weighted(Y, W, s, order)
    for c in range(C):
        if (W[:, c] > 0).sum() > order:
            assert _backward_error(out[:, c], Y[:, c], W[:, c], s[c], order) < 1e-13
        else:
            np.testing.assert_array_equal(out[:, c], Y[:, c])
    prev = rng.normal(size=(T, C))                                    # into a buffer holding an old fit
    np.testing.assert_array_equal(g._solve_weighted(Y, W, s, order, out=prev), out)
    np.testing.assert_array_equal(g._solve_weighted(Y, W > 0, s, order),
                                  g._solve_weighted(Y, (W > 0).astype(float), s, order))


def test_a_numerically_singular_column_falls_back_and_the_others_are_untouched():
    rng = np.random.default_rng(1)
    Y = rng.normal(size=(50, 4))
    W = np.ones((50, 4))
    W[:, 0] = 0.0
    W[[0, 25, 49], 0] = 1.0
    s = np.array([1e300, 1.0, 10.0, 100.0])          # huge s, three weights: Cholesky fails
    out = g._solve_weighted(Y, W, s, 2)
    assert np.isfinite(out).all()
    for c in (1, 2, 3):
        assert _backward_error(out[:, c], Y[:, c], W[:, c], s[c], 2) < 1e-13
    assert g._solve_weighted(np.zeros((0, 3)), np.zeros((0, 3)), np.ones(3), 2).shape == (0, 3)


def test_the_plain_fit_and_the_validation_afterwards_are_the_ones_gcv_smooth_gives():
    """auto fits robustly first and keeps the plain fit on a clip without spikes: the
    robust iteration's first fit (``plain_out``) with :func:`plain_fit` is exactly
    ``gcv_smooth`` without the robust weights, and a robust fit run without validation,
    :func:`validated` afterwards, exactly the validated one."""
    rng = np.random.default_rng(5)
    T, C = 300, 6
    t = np.linspace(0, 4 * np.pi, T)[:, None]
    X = np.sin(t * np.arange(1, C + 1)) * 10 + rng.normal(0, 0.3, (T, C))
    X[rng.random((T, C)) < 0.02] += 15.0                      # spikes the robust fit rejects
    M = rng.random((T, C)) > 0.1
    M[:, 3:] = M[:, :3]                                       # points of 3 coordinates
    first = []
    f_r, i_r = g.gcv_smooth(X, M, robust=True, group=3, validate=False, plain_out=first)
    f_p, i_p = g.gcv_smooth(X, M, group=3)
    f_q, i_q = g.plain_fit(X, M, first[0], group=3)
    np.testing.assert_array_equal(f_p, f_q)
    for k in ("s", "sigma", "error", "hole_error", "hole_map", "rejected"):
        np.testing.assert_array_equal(getattr(i_p, k), getattr(i_q, k), err_msg=k)
    _, i_v = g.gcv_smooth(X, M, robust=True, group=3)
    i_l = g.validated(i_r, X, M, group=3)
    assert i_r.hole_map is None and i_l.hole_map is not None and i_r.rejected.any()
    for k in ("hole_error", "hole_map", "error"):
        np.testing.assert_array_equal(getattr(i_v, k), getattr(i_l, k), err_msg=k)


@pytest.mark.parametrize("T, J, order", [(62, 31, 2), (9, 4, 3)])
def test_a_points_three_columns_share_one_factorisation_with_the_same_numbers(T, J, order):
    """Columns in triples with one point's weights and s (group=3 fits, point masks) are
    solved with one factor and three right-hand sides: bit for bit the per-column solve."""
    rng = np.random.default_rng(T + J)
    Y = rng.normal(size=(T, 3 * J)).cumsum(axis=0)
    Wp = (rng.random((T, J)) > 0.3) * rng.uniform(0.2, 1.0, (T, J))
    Wp[1:, 1] = 0.0                                                   # too few: the point keeps Y
    W = np.repeat(Wp, 3, axis=1)
    s = np.repeat(10.0 ** rng.uniform(-1, 4, J), 3)
    assert g._shared_triples(W, s)
    out = g._solve_weighted(Y, W, s, order)
    W2 = W.copy()
    W2[:, 2] *= 0.5                                                   # one column apart: no triples
    assert not g._shared_triples(W2, s)
    per_column = np.column_stack([g._solve_weighted(Y[:, [c]], W[:, [c]], s[[c]], order)[:, 0]
                                  for c in range(3 * J)])
    np.testing.assert_array_equal(out, per_column)
    np.testing.assert_array_equal(out[:, 3:6], Y[:, 3:6])
