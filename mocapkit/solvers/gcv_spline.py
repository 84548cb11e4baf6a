"""Automatic smoothing spline: penalised least squares with the smoothing chosen by
generalised cross-validation (GCV), vectorised over channels.

The biomechanics community's automatic filter is Woltring's GCVSPL (Woltring 1986, "A
Fortran package for generalized, cross-validatory spline smoothing and differentiation",
Adv. Eng. Software 8:104-113): a natural spline of order 2m-1 minimising

    sum_i w_i (y_i - f(t_i))^2 + p * integral (f^(m)(t))^2 dt                     (W1)

with p chosen by minimising the GCV score of Craven & Wahba (1979)

    GCV(p) = (1/n) ||W^1/2 (I - H_p) y||^2 / (1 - tr(H_p)/n)^2                    (W2)

For equally spaced samples (every mocap clip) we use the discrete counterpart of (W1)
(Whittaker-Henderson graduation; Garcia 2010, "Robust smoothing of gridded data in one and
higher dimensions with missing values", Comput. Stat. Data Anal. 54:1167-1178, eq. 3-7):
the m-th difference replaces the m-th derivative, and with reflective ends the hat matrix
is diagonal in the orthonormal DCT-II basis,

    H_s = C^T diag(Gamma) C,   Gamma_k = 1 / (1 + s (2 - 2 cos(pi k / n))^m)      (G7)

so one DCT per channel gives the fit, RSS (Parseval) and tr(H) = sum Gamma for *every*
candidate s at once: the GCV grid is a (grid x n) @ (n x channels) product. m = 2 is the
cubic-spline analogue (penalised acceleration), m = 3 Woltring's quintic mode.

Missing samples and outliers follow Garcia (2010, Sec. 3-4): the weighted problem is
solved by the fixed-point (EM) iteration y* = W y + (1 - W) f, f = H_s y*, started from a
linear fill; ``robust=True`` recomputes bisquare weights from studentised residuals
(``u = r / (1.4826 MAD(r) sqrt(1 - tr(H)/n))``, tuning constant 4.685) three times.

The error estimate (SURE with the GCV variance estimate sigma^2 = RSS / (n - tr H),
Wahba 1990 Sec. 4.7) simplifies to  E||f - x||^2 / n  ~=  sigma^2 tr(H) / n.

Example
-------
>>> import numpy as np
>>> from mocapkit.solvers.gcv_spline import gcv_smooth
>>> t = np.linspace(0, 2 * np.pi, 400)[:, None]
>>> truth = np.hstack([np.sin(t), np.cos(2 * t)]) * 10          # cm
>>> noisy = truth + np.random.default_rng(0).normal(0, 1.0, truth.shape)
>>> fit, info = gcv_smooth(noisy)
>>> bool(np.sqrt(np.mean((fit - truth) ** 2)) < 0.35)
True
>>> bool(0.9 < info.sigma.mean() < 1.1)          # noise level recovered (cm)
True
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.fft import dct
from scipy.linalg import solve_banded
from scipy.linalg.lapack import dpbsv
from scipy.stats import chi2

from ..errors import MocapValueError
from ..gaps import _runs
from ..signal._arrays import channel_blocks, nanmedian0
from ..windows import frame_blocks

__all__ = ["gcv_smooth", "GCVInfo", "cutoff_hz"]

_BISQUARE = 4.685
#: default floor of the robust weights' residual scale (cm): noise-free fast motion is not
#: turned into outliers (:func:`gcv_smooth`'s ``min_scale``)
ROBUST_MIN_SCALE = 1.0
_GRID = np.logspace(-4, 11, 61)           # candidate s (dimensionless); 4 per decade


@dataclass(frozen=True)
class GCVInfo:
    """What :func:`gcv_smooth` chose, per channel (C,) arrays.

    s -- smoothing parameter of (G7); trace -- tr(H_s), the effective number of
    parameters; sigma -- estimated noise std (units of the data); error -- estimated RMS
    error of the fit against the noise-free signal (units of the data); outliers --
    number of samples rejected by the robust iteration; n_iter -- robust passes run;
    rejected -- (T, C) bool, True on the observed samples the robust iteration rejected;
    smooth_error -- estimated RMS error on the samples the fit kept (SURE, see above);
    hole_error -- estimated RMS error at the filled samples (missing or rejected), by
    self-validation (see ``validate``); ``error`` then covers all samples; hole_map --
    (T, C) the same per filled sample (0 elsewhere).
    """
    s: np.ndarray
    trace: np.ndarray
    sigma: np.ndarray
    error: np.ndarray
    outliers: np.ndarray
    n_iter: int
    rejected: np.ndarray
    smooth_error: np.ndarray
    hole_error: np.ndarray | None = None
    hole_map: np.ndarray | None = None


def _eig(n: int, order: int) -> np.ndarray:
    """(n,) eigenvalues of the m-th order difference penalty in the DCT-II basis (G7)."""
    return (2.0 - 2.0 * np.cos(np.pi * np.arange(n) / n)) ** order


def cutoff_hz(s: np.ndarray | float, order: int, fps: float) -> np.ndarray:
    """Frequency (Hz) where the smoother's gain is 1/2: s (2 - 2 cos w)^m = 1."""
    c = np.clip(1.0 - 0.5 * np.asarray(s, float) ** (-1.0 / order), -1.0, 1.0)
    return np.arccos(c) / (2 * np.pi) * fps


#: frequencies per block of :func:`_choose_s` (on a 100,000-frame clip the whole
#: (grid, n) gain matrix took 54x the time of a 10,000-frame one)
_FREQ_BLOCK = 4096


def _choose_s(Yd: np.ndarray, lam: np.ndarray, n_obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel s minimising (W2) on the grid, refined by a parabola in log s.

    Yd (n, C) DCT coefficients of the (completed) series; RSS by Parseval. Returns s (C,)
    and the minimum log GCV score (C,) (comparable between penalty orders).
    """
    n = Yd.shape[0]
    rss = np.zeros((len(_GRID), Yd.shape[1]))                    # (grid, C)
    tr = np.zeros(len(_GRID))                                    # (grid,)
    for a in range(0, n, _FREQ_BLOCK):       # blocks of frequencies: (grid, block) stays in cache
        G = 1.0 / (1.0 + _GRID[:, None] * lam[None, a:a + _FREQ_BLOCK])
        rss += ((1.0 - G) ** 2) @ (Yd[a:a + _FREQ_BLOCK] ** 2)
        tr += G.sum(axis=1)
    # Garcia (2010) eq. 9: RSS over the observed samples, tr(H)/n over all of them
    score = np.log(rss / n_obs + 1e-300) - 2 * np.log(np.maximum(1 - tr / n, 1e-12))[:, None]
    i = np.clip(np.argmin(score, axis=0), 1, len(_GRID) - 2)
    cols = np.arange(Yd.shape[1])
    a, b, c = score[i - 1, cols], score[i, cols], score[i + 1, cols]
    den = a - 2 * b + c
    step = np.where(den > 0, 0.5 * (a - c) / np.where(den > 0, den, 1), 0.0)
    step = np.clip(step, -1, 1)
    logs = np.log10(_GRID[i]) + step * (np.log10(_GRID[1]) - np.log10(_GRID[0]))
    return 10.0 ** logs, b - 0.25 * (a - c) * step


def _penalty_bands(n: int, order: int) -> np.ndarray:
    """Upper banded form (order+1, n) of D^T D, D the (n - m, n) m-th difference matrix."""
    d = np.diff(np.eye(2 * order + 1), n=order, axis=0)[0]          # binomial stencil
    P = np.zeros((order + 1, n))
    rows = np.arange(n - order)
    for k in range(order + 1):                                      # band at offset k
        acc = np.zeros(n)
        for a in range(order + 1 - k):
            np.add.at(acc, rows + a + k, d[a] * d[a + k])
        P[order - k] = acc
    return P


#: unknowns per banded solve of :func:`_solve_weighted` (columns side by side)
_SOLVE_BLOCK = 8192


def _solve_weighted(Y: np.ndarray, W: np.ndarray, s: np.ndarray, order: int,
                    out: np.ndarray | None = None) -> np.ndarray:
    """Exact minimiser of sum w (y - f)^2 + s ||D_m f||^2 per column (Whittaker 1923;
    Garcia 2010 eq. 5): a banded SPD system per column, (W + s D^T D) f = W y.

    The columns of a block of channels are solved as one block-diagonal banded system
    (their bands side by side: the penalty's band is zero across a column's start), by one
    banded Cholesky (LAPACK ``dpbsv``, O(T m^2) per column) -- the same arithmetic as a
    solve per column, without ~20 us of ``scipy.linalg.solveh_banded``'s call and checks
    per column: that was 40 % of ``auto`` on a 79-frame clip, where each solve takes ~1
    us. The DCT of (G7) is used only to choose s: at the clip's ends the two
    discretisations differ slightly, and one solver for the fit keeps it one thing.
    ``W``: float weights or a bool mask (weights 0 / 1). ``out``: (T, C) array the fit
    is written into (may hold the previous fit; ``Y`` itself is never written).
    """
    ok = (W > 0).sum(axis=0) > order
    if out is None:
        out = Y.copy()             # a column with < order + 1 weighted samples keeps Y
    else:
        out[:, ~ok] = Y[:, ~ok]
    T = Y.shape[0]
    P = _penalty_bands(T, order)
    s = np.broadcast_to(np.asarray(s, float), ok.shape)
    # columns whose triples share weights and s (a point's x, y, z: the fills' splines) are
    # solved with one factorisation and three right-hand sides (:func:`_shared_triples`)
    k = 3 if _shared_triples(W, s) else 1
    heads = np.flatnonzero(ok[0::k]) * k                            # each system's first column
    # ~8,000 unknowns a call: the per-call cost is gone by then, and a longer system leaves
    # the cache (10,000 frames took 7 % longer in blocks of 16 columns than one by one)
    for sl in channel_blocks(len(heads), max(1, _SOLVE_BLOCK // max(T, 1))):
        c0 = heads[sl]
        Wb = np.asarray(W[:, c0], float).T                          # (c, T)
        ab = s[c0][None, :, None] * P[:, None, :]                   # (m + 1, c, T)
        ab[order] += Wb
        rhs = np.stack([(Wb * Y[:, c0 + j].T).reshape(-1) for j in range(k)], axis=1)
        _, x, info = dpbsv(ab.reshape(order + 1, -1), rhs, overwrite_ab=1, overwrite_b=1)
        for j in range(k):
            if info == 0:
                out[:, c0 + j] = x[:, j].reshape(len(c0), T).T
            else:                  # a system numerically singular: each column on its own
                for c in c0 + j:
                    out[:, c] = _solve_column(Y[:, c], W[:, c], s[c], P, order)
    return out


def _shared_triples(W: np.ndarray, s: np.ndarray) -> bool:
    """Whether the columns come in triples (a point's x, y, z) with the same weights and
    the same s, so that each triple's three systems have one matrix: :func:`_solve_weighted`
    then factorises it once and solves three right-hand sides (LAPACK ``dpbsv`` with nrhs =
    3 solves each with the factor as a single solve would: the same numbers), half the time
    of three factorisations (a 62-frame, 31-point clip: 0.40 -> 0.20 ms a solve). Where it
    holds: one s for every column (the interpolating splines of ``auto``'s short-hole
    fills) or an s held per point; a GCV fit chooses s per column."""
    C = W.shape[1]
    if C % 3 or C < 3:
        return False
    return bool(np.array_equal(s[0::3], s[1::3]) and np.array_equal(s[0::3], s[2::3])
                and np.array_equal(W[:, 0::3], W[:, 1::3]) and np.array_equal(W[:, 0::3], W[:, 2::3]))


def _solve_column(y: np.ndarray, w: np.ndarray, s: float, P: np.ndarray, order: int) -> np.ndarray:
    """One column of :func:`_solve_weighted`: (w + s P) f = w y, ``P`` the penalty's upper
    bands (m + 1, T), by banded Cholesky, or by LU with pivoting where the system is
    numerically singular (huge s, few weights)."""
    ab = s * P
    ab[order] += w
    rhs = (w * y)[:, None]
    _, x, info = dpbsv(ab, rhs)
    if info == 0:
        return x[:, 0]
    full = np.vstack([ab, ab[-2::-1] * 0])
    for k in range(1, order + 1):
        full[order + k, :-k] = ab[order - k, k:]
    return solve_banded((order, order), full, rhs[:, 0], check_finite=False)


def _completed_dct(Y: np.ndarray, W: np.ndarray, f: np.ndarray, out: np.ndarray) -> np.ndarray:
    """DCT-II (orthonormal, along time) of the series completed with the current fit,
    ``W y + (1 - W) f`` (T, C), written into ``out`` (which may be ``f``: each block of
    channels is read before it is written). One block at a time, so the completed series
    and its temporaries exist for a block, not for the whole clip (issue 21)."""
    for sl in channel_blocks(Y.shape[1]):
        w = W[:, sl]
        out[:, sl] = dct(w * Y[:, sl] + (1.0 - w) * f[:, sl], type=2, norm="ortho", axis=0)
    return out


def _select_and_fit(Y: np.ndarray, W: np.ndarray, order: int, s_fixed: np.ndarray | None,
                    f: np.ndarray, passes: int = 2, out: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """s by (W2) on the series completed with the current fit, then the exact weighted fit.

    ``out``: where the fit goes (may be ``f`` itself; default a new array).  The DCT of
    the completed series is kept in that same buffer until the solve overwrites it (the
    solve reads only Y and W), so a call needs one matrix besides its inputs where it
    needed three (the DCT, the new fit and the previous one; issue 21).
    """
    if s_fixed is not None:
        return _solve_weighted(Y, W, s_fixed, order, out=out), s_fixed
    n_obs = np.maximum(W.sum(axis=0), 1.0)
    lam = _eig(Y.shape[0], order)
    if out is None:
        out = np.empty(Y.shape)
    if passes > 1 and np.isfinite(f).all() and (W.all() if W.dtype == bool else bool((W == 1.0).all())):
        # every weight 1: the completed series is Y itself whatever f is (W y + 0 f), so a
        # second pass would choose the same s and make the same fit
        passes = 1
    for _ in range(passes):
        s, _ = _choose_s(_completed_dct(Y, W, f, out), lam, n_obs)
        f = _solve_weighted(Y, W, s, order, out=out)
    return f, s


def gcv_smooth(X, mask=None, *, order: int = 2, s: float | np.ndarray | None = None,
               robust: bool = False, group: int = 1, min_scale: float = ROBUST_MIN_SCALE,
               n_robust: int = 3, validate: bool = True, plain_out: list | None = None
               ) -> tuple[np.ndarray, GCVInfo]:
    """Smooth every column of ``X`` (T, C) with its own GCV-chosen smoothing spline.

    Parameters
    ----------
    X : (T, C) array, units of the data (cm for mocap). Entries outside ``mask`` are ignored
        (may be NaN).
    mask : (T, C) bool, True where observed; None = all observed.
    order : penalty order m of (G7): 2 (cubic-spline analogue; on 4 CMU clips at 30 and
        120 fps within 3 % of order 3 under Gaussian noise, clearly better with robust
        rejection of spikes, and it adds the least to a clean clip),
        3 (quintic, Woltring's mode for derivatives) or 1 (velocity).
    s : fixed smoothing parameter (scalar or (C,)) instead of GCV.
    robust : outlier rejection. Bisquare re-weighting (Garcia 2010 Sec. 4), then a final
        fit on the samples it kept (weight 1) -- the soft weights alone were measured to
        cost 4 % on pure Gaussian noise. Rejected samples are filled by the spline.
    group : number of consecutive columns that form one point (3 for x, y, z of a joint):
        robust weights are computed from the point's residual norm and shared by its
        columns, since a corrupted marker is wrong in all its coordinates at once (a
        15 cm spike may move one axis by only a few cm).
    min_scale : floor of the residual scale in the robust weights (units of the data; 1 cm
        for mocap: a sample is rejected only if it is off by more than 4.685 x max(scale,
        min_scale)), so that noise-free fast motion is not turned into "outliers".
    n_robust : re-weighting passes of the robust iteration.
    validate : estimate the error at filled samples (missing or rejected) by hiding, next
        to every hole, a trusted stretch of the same length (two extra fits; see
        :func:`_with_hole_error`); otherwise ``info.error`` covers the smoothing of
        trusted samples only.
    plain_out : with ``robust``, a list that gets the robust iteration's first fit --
        the plain (unweighted) one -- as ``(fit, s)``, for :func:`plain_fit`.

    Returns
    -------
    fit : (T, C) smoothed, gap-free series.
    info : :class:`GCVInfo` per channel.
    """
    if order not in (1, 2, 3):
        raise MocapValueError(f"gcv spline: order must be 1, 2 or 3, got {order!r}")
    Y = np.asarray(X, dtype=float)
    if Y.ndim != 2:
        raise MocapValueError(f"gcv spline: expected a (T, C) matrix, got shape {Y.shape}")
    T, C = Y.shape
    M = np.isfinite(Y) if mask is None else (np.asarray(mask, bool) & np.isfinite(Y))
    if T < 8:
        raise MocapValueError(f"gcv spline: needs at least 8 frames, got {T}")
    if group < 1 or C % group:
        raise MocapValueError(f"gcv spline: group={group} does not divide {C} columns")
    empty = ~M.any(axis=0)
    if empty.any():
        raise MocapValueError(f"gcv spline: column(s) {np.flatnonzero(empty)[:10].tolist()} have "
                              f"no observed sample")
    s_fixed = None if s is None else np.broadcast_to(np.asarray(s, float), (C,)).copy()
    from ..gaps import fill                           # the one gap filler
    # samples outside M interpolated (a copy); complete data is only read, not copied
    Y0 = Y if M.all() else fill(Y, M)
    # weights 0 / 1 stay a bool mask (a float copy was one more matrix); the solver
    # functions take either
    W = M
    f, s_ = _select_and_fit(Y0, W, order, s_fixed, Y0)
    n_iter = 0
    if robust and plain_out is not None:
        plain_out.append((f.copy(), np.array(s_, dtype=float)))
    if robust:
        for n_iter in range(1, n_robust + 1):
            W = _bisquare(Y0, f, M, _trace(T, s_, order) / T, group, min_scale)
            f, s_ = _select_and_fit(Y0, W, order, s_fixed, f, out=f)
        W = W > 0
        f, s_ = _select_and_fit(Y0, W, order, s_fixed, f, out=f)
    info = _info(Y0, f, M, W, _trace(T, s_, order), s_, n_iter)
    if validate and (W == 0).any():
        info = _with_hole_error(info, Y0, W, s_, order, group)
    return f, info


def plain_fit(X: np.ndarray, mask: np.ndarray, first: tuple[np.ndarray, np.ndarray], *, order: int = 2,
              group: int = 1, validate: bool = True) -> tuple[np.ndarray, GCVInfo]:
    """What ``gcv_smooth(X, mask, order=order, group=group, validate=validate)`` returns,
    from the first fit of a robust :func:`gcv_smooth` of the same data (``plain_out``):
    the robust iteration starts with exactly that fit (``auto`` needs both, and a clip
    without spikes keeps the plain one)."""
    Y = np.asarray(X, dtype=float)
    M = np.asarray(mask, bool) & np.isfinite(Y)
    from ..gaps import fill                           # the one gap filler

    Y0 = Y if M.all() else fill(Y, M)
    f, s_ = first
    info = _info(Y0, f, M, M, _trace(Y.shape[0], s_, order), s_, 0)
    if validate and (~M).any():
        info = _with_hole_error(info, Y0, M, s_, order, group)
    return f, info


def validated(info: GCVInfo, X: np.ndarray, mask: np.ndarray, *, order: int = 2, group: int = 1) -> GCVInfo:
    """``info`` of a :func:`gcv_smooth` fit of ``X`` (T, C) under ``mask`` run with
    ``validate=False``, with the hole validation ``validate=True`` would have added
    (:func:`_with_hole_error`; the fit's holes: missing samples and its rejections) --
    for a caller that knows only after the fit whether it needs it (``auto``: a clip
    found without spikes keeps the plain fit, :func:`plain_fit`, and the robust fit's
    validation was two solves for nothing)."""
    Y = np.asarray(X, dtype=float)
    M = np.asarray(mask, bool) & np.isfinite(Y)
    W = M & ~info.rejected
    if not (~W).any() or info.hole_map is not None:
        return info
    from ..gaps import fill                           # the one gap filler

    return _with_hole_error(info, Y if M.all() else fill(Y, M), W, info.s, order, group)


def _trace(T: int, s: np.ndarray, order: int) -> np.ndarray:
    """tr(H_s) per channel from (G7), a block of channels at a time (the (T, C) gains of
    all channels at once were two matrices of temporaries)."""
    lam = _eig(T, order)[:, None]
    s = np.asarray(s, dtype=float)
    tr = np.empty(s.shape[0])
    for sl in channel_blocks(s.shape[0]):
        tr[sl] = (1.0 / (1.0 + lam * s[None, sl])).sum(axis=0)
    return tr


def _paint(T: int, P: int, j: np.ndarray, a: np.ndarray, b: np.ndarray, val: np.ndarray) -> np.ndarray:
    """(T, P) array holding val[k] on rows a[k]:b[k] of column j[k] (disjoint ranges), 0 elsewhere."""
    out = np.zeros((T + 1, P))
    np.add.at(out, (a, j), val)
    np.add.at(out, (b, j), -val)
    return np.cumsum(out, axis=0)[:T]


def _with_hole_error(info: GCVInfo, Y: np.ndarray, W: np.ndarray, s: np.ndarray, order: int,
                     group: int, spacing: int = 1, prior: float = 20.0) -> GCVInfo:
    """Add the error at the samples the fit had to fill (missing or rejected), by local
    self-validation, hole by hole (the scheme fill-auto uses for long gaps, here for every
    hole of the spline, vectorised over holes).

    For every hole (run of L filled frames of one point) the L trusted frames next to it
    are hidden: those ending ``spacing`` frames before it (round 1) and those starting
    ``spacing`` frames after it (round 2), each only where the hidden stretch and one
    frame beyond it are trusted, so a hidden stretch is a hole of the same length with
    trusted neighbours, as the real hole has, and never merges with another one; holes at
    the clip's ends are continued by L frames instead (an edge hole twice as deep). All
    hides of a round are hidden together (one extra fit per round, same s). A hole's error
    is its hidden stretches' prediction error minus the noise variance, shrunk towards
    the clip's pooled value for holes of its length (factor-2 bins) as
    ``(n e^2 + prior pool^2) / (n + prior)`` (n: samples validated): a 1-frame hole is
    judged mostly by all 1-frame holes, a long one mostly where it is (the holes a
    robust fit leaves are where the motion is hardest to follow). (The shifted hole pattern
    used before tested longer holes than the real ones: missing30 overestimated 1.2-2.7x.)
    Measured and not kept (2026-12-04, auto's spikes / missing30 / mixed / ten-gap cases of
    docs/results/auto.md and auto_heldout.md): shrinking towards the point's own pool of
    the length bin first (a hand is not a hip), 57 of 74 and 57 of 77 within 1.5x either
    way; subtracting no noise variance on noise-free clips, 38 of 54 and 38 of 57 either
    way. Where a point's 1-frame holes read low (walk@30 missing30, rtoes: 0.30 validated
    against 0.83 cm true) the few validated samples (10 here) miss the rare large errors of
    a heavy-tailed distribution: the estimate's spread, not a bias these would fix.

    Sets ``hole_error`` (C,) -- RMS over each column's holes -- and ``hole_map`` (T, C),
    the estimated RMS error of every filled sample (0 on trusted ones).
    """
    T, C = Y.shape
    holes = W == 0
    P = C // group
    H = holes.reshape(T, P, group).any(axis=2)                      # a point's hole
    j, a, b = _runs(H)
    keep = ~((a == 0) & (b == T))                                   # never trusted: no test
    j, a, b = j[keep], a[keep], b[keep]
    if not len(j):
        return info
    L = b - a
    ok = np.vstack([np.zeros((1, P), int), np.cumsum(~H, axis=0)])  # trusted frames before t

    def trusted(lo, hi):                         # frames lo..hi-1 all trusted (in the clip)
        lo_c, hi_c = np.clip(lo, 0, T), np.clip(hi, 0, T)
        return (lo >= 0) & (hi <= T) & (ok[hi_c, j] - ok[lo_c, j] == hi - lo)

    lead, trail = a == 0, b == T
    rounds = []
    # round 1: the stretch before an interior hole; a trailing hole's stretch continues it
    h0 = np.where(trail, a - L, a - spacing - L)
    rounds.append((h0, h0 + L, ~lead & trusted(h0 - 1, a)))
    # round 2: the stretch after an interior hole; a leading hole's stretch continues it
    h0 = np.where(lead, b, b + spacing)
    rounds.append((h0, h0 + L, ~trail & trusted(b, h0 + L + 1)))
    sig2 = (info.sigma ** 2).reshape(P, group).mean(axis=1)         # per point
    sq = np.zeros(len(j))
    n = np.zeros(len(j))
    rid = np.arange(1, len(j) + 1, dtype=float)
    for lo, hi, use in rounds:
        if not use.any():
            continue
        hide_id = _paint(T, P, j[use], lo[use], hi[use], rid[use]).round().astype(int)   # (T, P)
        hide = np.repeat(hide_id > 0, group, axis=1)
        Wh = (W & ~hide) if W.dtype == bool else np.where(hide, 0.0, W)   # 0 where hidden
        f = _solve_weighted(Y, Wh, s, order)
        del Wh
        np.subtract(f, Y, out=f)                                    # in place: f is ours
        e2 = (np.square(f, out=f)).reshape(T, P, group).mean(axis=2)   # per coordinate
        del f
        m = hide_id > 0
        sq += np.bincount(hide_id[m] - 1, weights=e2[m], minlength=len(j))
        n += np.bincount(hide_id[m] - 1, minlength=len(j))
    val = n > 0
    if not val.any():
        return info
    e2_run = np.where(val, sq / np.maximum(n, 1) - sig2[j], np.nan)
    # pooled per length bin (factor 2) and edge/interior; nearest non-empty bin where empty
    lbin = np.floor(np.log2(L)).astype(int) + 100 * (lead | trail)
    bins = np.unique(lbin[val])
    pool = {k: max(float(np.sum(sq[val & (lbin == k)]) / np.sum(n[val & (lbin == k)])
                         - np.mean(sig2[j[val & (lbin == k)]])), 0.0) for k in bins}
    near = bins[np.argmin(np.abs(bins[None, :] - lbin[:, None]), axis=1)]
    p2 = np.array([pool[k] for k in near])
    e2_run = np.where(val, (n * np.maximum(e2_run, 0.0) + prior * p2) / (n + prior), p2)
    hmap = np.sqrt(_paint(T, P, j, a, b, e2_run).clip(0))
    hmap = np.repeat(hmap, group, axis=1)
    hmap *= holes                                                   # in place: one (T, C) array
    n_fill = holes.sum(axis=0)
    e_hole = np.sqrt(np.einsum("tc,tc->c", hmap, hmap) / np.maximum(n_fill, 1))
    err = np.sqrt(((T - n_fill) * info.error ** 2 + n_fill * e_hole ** 2) / T)
    return replace(info, error=err, hole_error=e_hole, hole_map=hmap)


def residual_scale(Y: np.ndarray, f: np.ndarray, M: np.ndarray, h: np.ndarray, group: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The robust weights' residual scale per point (points,) -- the median norm of a
    point's residuals Y - f on the observed samples M over the chi median of ``group``
    dof, over sqrt(1 - mean leverage h (C,)) -- and the norms (T, points).

    The residual norms are formed a block of frames at a time (the whole-matrix residuals,
    their NaN-masked copy and squares were three more matrices of a long clip)."""
    T, C = Y.shape
    norm = np.empty((T, C // group))                                          # (T, points)
    for sl in frame_blocks(T):
        R = np.where(M[sl], Y[sl] - f[sl], np.nan).reshape(-1, C // group, group)
        norm[sl] = np.sqrt(np.sum(R ** 2, axis=2))
    # median of a chi distribution with `group` dof: the MAD constant 0.6745 for group 1
    med = float(np.sqrt(chi2.ppf(0.5, group)))
    lev = np.sqrt(np.maximum(1 - h.reshape(-1, group).mean(axis=1), 1e-6))
    return nanmedian0(norm) / med / lev, norm              # a point never observed: NaN


def _bisquare(Y: np.ndarray, f: np.ndarray, M: np.ndarray, h: np.ndarray, group: int,
              min_scale: float) -> np.ndarray:
    """Bisquare weights (T, C) from the residuals Y - f and mean leverages h (C,), per point
    (:func:`residual_scale`, floored at ``min_scale``)."""
    scale, norm = residual_scale(Y, f, M, h, group)
    u = np.nan_to_num(norm / (_BISQUARE * np.maximum(scale, min_scale)), nan=2.0)
    w = np.where(u < 1, (1 - u ** 2) ** 2, 0.0)
    W = np.repeat(w, group, axis=1)
    W *= M
    return W


def _info(Y: np.ndarray, f: np.ndarray, M: np.ndarray, W: np.ndarray, tr: np.ndarray,
          s: np.ndarray, n_iter: int) -> GCVInfo:
    T = Y.shape[0]
    use = W > 0.5
    n_use = np.maximum(use.sum(axis=0), 1)
    rss = np.empty(Y.shape[1])
    for sl in channel_blocks(Y.shape[1]):           # the squared residuals of a block at a time
        rss[sl] = np.where(use[:, sl], (Y[:, sl] - f[:, sl]) ** 2, 0.0).sum(axis=0)
    # GCV variance estimate over the trusted samples (Wahba 1990 Sec. 4.7); the fit's
    # error ~ sigma sqrt(tr H / n) (SURE at the GCV estimate, see module docstring)
    sigma = np.sqrt(rss / np.maximum(n_use * (1 - tr / T), 1e-12))
    err = sigma * np.sqrt(tr / T)
    rejected = M & (W == 0)
    return GCVInfo(s=s, trace=tr, sigma=sigma, error=err, outliers=rejected.sum(axis=0),
                   n_iter=n_iter, rejected=rejected, smooth_error=err)
