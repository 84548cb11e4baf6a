"""Weighted-PCA gap fill in a body-centred frame, after Gløersen & Federolf 2016.

Gløersen Ø., Federolf P. (2016) "Predicting missing marker trajectories in human motion
data using marker intercorrelations", PLoS ONE 11(3):e0152616, building on Federolf P.
(2013) "A novel approach to solve the 'missing marker problem' in marker-based motion
analysis that exploits the segment coordination patterns in multi-limb motion data",
PLoS ONE 8(10):e78689 (eq. 1). What is kept from the paper and what is decided here:

1. **Body-centred frame.** The paper subtracts the mean trajectory of the markers without
   gaps (a translation). Here (decision, METHODS.md §6) translation *and heading* are taken
   out, robustly to which markers are visible: a template of the marker set is fitted to
   every frame by a rotation about the vertical axis plus a horizontal translation
   (:func:`body_frame`: weighted 2-D Procrustes, :func:`mocapkit.rigid.yaw_kabsch`,
   alternated with the template, markers that do not move with the body down-weighted), so
   a marker dropping out does not move the frame and a walking subject's turns do not
   leave the low-rank model. The vertical translation stays in the data (it is linear in
   the coordinates, so the PCA models it; the column means remove the standing height).
2. **Normalise and weight** (paper, Methods "Weighting"): per coordinate, subtract the mean
   and divide by the standard deviation of the training frames (floored at
   ``std_floor_cm``: a coordinate that does not move is not blown up to unit variance),
   then weight every marker by ``exp(-d^2 / (2 sigma^2))``, d its mean distance to the
   missing marker, sigma = 200 mm (the paper's default; decision: widened, up to twice,
   for a marker whose ``min_donors`` nearest markers lie beyond ``support_sigmas`` sigma,
   so that they count as close -- a skeleton's leg joints); the missing marker itself gets
   the paper's ``MMweight`` 0.02, so the components are those of its neighbours.
3. **PCA of the complete frames**, keeping the leading components whose cumulative singular
   values reach ``min_cum_sv`` = 0.99 (the paper's ``MinCumSV``).
4. **Reconstruction** (variant R2: each missing marker separately, with its own weights):
   the scores of a gap frame are fitted by least squares to the coordinates observed in
   that frame, ``s = (V_o^T V_o + s2 L^-1)^-1 V_o^T z_o`` (decision: the explicit
   least-squares form of Federolf 2013 eq. 1 -- equal to the paper's projection when the
   observed part of the components is orthonormal -- with the probabilistic-PCA prior
   ``s2 L^-1``: L the kept eigenvalues, s2 the mean discarded one; Tipping & Bishop
   1999), and the missing marker is ``V_m s`` mapped back (un-weight, un-normalise, world
   frame). Frames are batched: one ``(k, k)`` system per frame (shared by frames with the
   same mask), no Python loop over frames;
   a donor missing in some gap frames simply drops out of those frames' fits.
5. **Training frames per gap** (as the paper's R2, which drops markers whose gaps overlap
   the missing marker's): the donors are the markers seen in at least ``cover`` of the gap's
   frames, added in order of weight (times the share of the gap they are seen in) as long
   as the frames where the missing marker and all chosen donors are seen stay >=
   ``min_frames``; the frames where >= ``min_donors`` close donors (mean distance below
   ``support_sigmas`` = 2 sigma) are seen are
   filled. Frames left (other markers missing there) get a second and a third pass with
   the donors re-chosen for them (cover halved, then any share). Models are cached by
   donor set. The model's residuals at the gap's observed ends are interpolated over the
   gap and added (``end_correction``; an edge gap adds its one end's residual), so the
   fill meets the measured ends.
6. **Fallback** (decision): frames that no pass can serve (too few complete frames for any
   donor set with ``min_donors`` close donors) take an iterative low-rank completion of
   the marker's weighted neighbourhood in a window around the gap
   (:func:`lowrank_complete`: repeated PCA of the filled data, EM style), unless that
   window holds too little (the marker seen in < 30 frames, or its weighted
   neighbourhood seen in under half its entries): then the frames stay NaN. Either way a gap
   frame is filled only where at least ``min_donors`` close markers are observed;
   elsewhere it stays NaN (no evidence).
7. **Range check** (decision): a fill frame is dropped (NaN) when the filled marker's
   distance to a close marker seen in that frame leaves the range of that distance over
   the data by more than ``max(range_slack_cm, 25 % of the range)`` -- extrapolation far
   from anything seen (e.g. a body frame fitted to three forearm markers) is not kept.

Measured (docs/results/fill.md, 8 markers hidden for 0.25-2 s, interior and edge gaps,
RMSE pooled over all scenarios): tennis serve 0.56 cm, HDM05 0.71 cm (linear interpolation
16.5 / 43.5 cm); frame "translation" 0.68 / 0.69 cm, "world" 0.71 / 1.34 cm; without the
end correction 0.58 / 0.72 cm; the fallback forced everywhere 1.38 / 2.78 cm. On the real
tennis-serve gaps the fill is 0.36 cm from the vendor's own fill (linear: 4.67 cm). On
stretches hidden next to the basket sprint's real gaps: 2.23 cm RMSE, 58 % filled, 0.4 %
gross (> 20 cm); without the range check (step 7) 6.10 cm, 86 %, 7.0 %.

Units: positions in cm, (T, J, 3); masks (T, J). ``sigma_cm`` = 20 cm = the paper's 200 mm.

Example
-------
>>> import numpy as np
>>> from mocapkit.solvers.pca_fill import pca_fill
>>> rng = np.random.default_rng(0)
>>> T, J = 400, 12
>>> base = np.c_[rng.normal(size=(J, 2)) * 10, np.linspace(10, 160, J)]   # z up, cm
>>> P = np.repeat(base[None], T, 0)
>>> P[:, :, 2] += np.sin(np.arange(T) / 20)[:, None] * rng.normal(size=J) * 3   # rank-1 motion
>>> P[:, :, 0] += np.arange(T)[:, None] * 0.5                              # walking along x
>>> obs = np.ones((T, J), bool); obs[100:200, 3] = False; obs[:50, 7] = False
>>> Q, f = pca_fill(np.where(obs[..., None], P, np.nan), obs)
>>> bool(f[100:200, 3].all() and f[:50, 7].all()), bool(np.abs(Q - P).max() < 1e-6)
(True, True)
"""
from __future__ import annotations

import warnings

import numpy as np

from ..frames import Frame, up_axis_of
from ..io._rotations import axis_rotation
from ..errors import MocapValueError
from ..gaps import fill, find_gaps
from ..rigid import distance_stats, yaw_kabsch
from . import _linalg

__all__ = ["body_frame", "pca_fill", "lowrank_complete"]


def body_frame(P: np.ndarray, observed: np.ndarray, *, up_axis: int | None = None,
               heading: bool = True, n_iter: int = 30, robust_cm: float = 5.0) -> Frame:
    """Per-frame heading and horizontal translation of a marker set, robust to which
    markers are visible (module docstring, step 1).

    Model: ``P_tj,h = Rot(theta_t) o_j,h + c_t`` in the horizontal plane, ``o`` a template
    (one point per marker), fitted by alternating (i) the template = mean of each marker's
    local positions over the frames that see it and (ii) every frame's weighted 2-D
    Procrustes fit of the template's visible markers (:func:`mocapkit.rigid.yaw_kabsch`).
    Marker weights ``1 / (rms_j^2 + robust_cm^2)``, rms_j the marker's horizontal residual,
    so a marker that does not move with the body (a sync marker, a swinging hand) counts
    little. Frames seeing fewer than 2 markers take the frame interpolated in time.

    P : (T, J, 3) cm (NaN = missing); observed : (T, J). ``heading=False`` fits the
    translation only. Returns a :class:`~mocapkit.frames.Frame` (``world =
    R_t local + origin_t``; ``origin`` has no vertical component).
    """
    P = np.asarray(P, dtype=float)
    obs = np.asarray(observed, bool) & np.isfinite(P).all(axis=-1)
    T, J, _ = P.shape
    up = up_axis_of(P) if up_axis is None else int(up_axis)
    if up not in (0, 1, 2):
        raise MocapValueError(f"up_axis must be 0, 1 or 2, got {up_axis!r}")
    h = [(up + 1) % 3, (up + 2) % 3]
    if not obs.any():
        return Frame.identity(np.zeros((T, 3)))
    Q = np.where(obs[..., None], P, 0.0)
    wo = obs.astype(float)
    n_t = wo.sum(axis=1)
    good = n_t >= 2
    # translation-only start: P ~ c_t + o_j (alternating means)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = (Q * wo[..., None]).sum(axis=1) / n_t[:, None]
        for _ in range(3):
            o = ((Q - c[:, None, :]) * wo[..., None]).sum(axis=0) / wo.sum(axis=0)[:, None]
            o = np.nan_to_num(o)
            c = ((Q - o[None]) * wo[..., None]).sum(axis=1) / n_t[:, None]
    c = np.nan_to_num(c)
    theta = np.zeros(T)
    mw = np.ones(J)
    for _ in range(int(n_iter)):
        R = axis_rotation(up, theta)
        L = np.einsum("tji,tkj->tki", R, Q - c[:, None, :])            # local
        with np.errstate(invalid="ignore", divide="ignore"):
            o = (L * wo[..., None]).sum(axis=0) / wo.sum(axis=0)[:, None]
        o = np.nan_to_num(o)
        o -= (o * mw[:, None]).sum(0) / mw.sum()                         # gauge: centred template
        res = (L - o[None])[..., h]
        with np.errstate(invalid="ignore", divide="ignore"):
            rms2 = ((res ** 2).sum(-1) * wo).sum(0) / wo.sum(0)
        mw = 1.0 / (np.nan_to_num(rms2, nan=1e6) + float(robust_cm) ** 2)
        if not heading:
            with np.errstate(invalid="ignore", divide="ignore"):
                w = wo * mw[None]
                c_new = ((Q - o[None]) * w[..., None]).sum(1) / w.sum(1)[:, None]
            c = np.nan_to_num(c_new)
            c[:, up] = 0.0
            continue
        th, c_new = yaw_kabsch(np.broadcast_to(o, (T, J, 3)), Q, wo * mw[None], up_axis=up)
        th = np.where(good, th, np.nan)
        if good.any():
            th_v = np.unwrap(th[good])
            th = np.full(T, np.nan)
            th[good] = th_v
            th = fill(th[:, None], good[:, None])[:, 0]
        else:
            th = np.zeros(T)
        done = (np.abs(th - theta).max() < 1e-12 and np.abs(c_new - c)[good].max(initial=0.0) < 1e-10)
        theta, c = th, c_new
        if done:
            break
    c[:, up] = 0.0
    if (~good).any() and good.any():
        c = fill(np.where(good[:, None], c, np.nan), np.repeat(good[:, None], 3, 1))
    R = axis_rotation(up, theta)
    return Frame(origin=c, rotation=R)


#: the residual (noise) variance of the scores' prior is at least this share of the mean
#: eigenvalue (:func:`_residual_variance`)
S2_FLOOR = 1e-12


def _residual_variance(ev: np.ndarray, k: int) -> float:
    """The prior's noise variance for ``k`` kept components of the eigenvalues ``ev``
    (descending): the mean of the others, at least :data:`S2_FLOOR` x the mean eigenvalue.

    Why the floor: on data of exactly low rank the others are 0, so kept components with no
    variance of their own (``k`` above the rank) got no shrinkage (``s2 / lambda`` = 0) and
    their scores, free where a row's observed entries hardly see them, took up rounding
    noise that the EM fed back: on a planted rank-3 matrix with 20 % missing, a 1e-14
    change of the linear start moved :func:`lowrank_complete`'s result from 1e-9 to 13
    off after 300 iterations. With the floor such components are shrunk to nothing and
    the result is 6.5e-10 off from any start (1e-14 to 1e-6 perturbations).
    """
    rest = float(ev[k:].mean()) if len(ev) > k else 0.0
    return max(rest, S2_FLOOR * float(np.mean(ev)) if len(ev) else 0.0)


def _ncomp(S: np.ndarray, min_cum_sv: float) -> int:
    tot = S.sum()
    if tot <= 0:
        return 1
    return int(min(np.searchsorted(np.cumsum(S), min_cum_sv * tot * (1 - 1e-12)) + 1, len(S)))


def _patterns(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct rows of a bool matrix (p, C) and each row's index into them (n,)."""
    packed = np.ascontiguousarray(np.packbits(M, axis=1))
    key = packed.view(np.dtype((np.void, packed.shape[1]))).ravel()
    _, first, inv = np.unique(key, return_index=True, return_inverse=True)
    return M[first], np.asarray(inv).reshape(-1)


def _scores(V: np.ndarray, lam: np.ndarray, s2: float, Z: np.ndarray, M: np.ndarray,
            patterns: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Per-row least-squares scores on the observed entries with the probabilistic-PCA prior:
    ``s_t = (V_o^T V_o + s2 L^-1)^-1 V_o^T z_o`` (module docstring step 4). Rows sharing a
    mask pattern share the (k, k) matrix (one inverse per pattern, no loop over rows).
    Z (n, C) with anything at unobserved entries, M (n, C) bool; V (C, k); returns (n, k)."""
    pat, inv = _patterns(M) if patterns is None else patterns
    PV = pat[:, :, None] * V[None]                                  # (p, C, k)
    A = np.matmul(PV.transpose(0, 2, 1), V)                          # (p, k, k), BLAS
    A += np.diag(s2 / np.maximum(lam, 1e-300) + 1e-12)[None]
    b = np.where(M, Z, 0.0) @ V                                      # (n, k)
    if len(pat) > 64 or len(pat) * 8 > len(M):                       # many patterns: per row
        return np.linalg.solve(A[inv], b[:, :, None])[:, :, 0]
    out = np.empty_like(b)
    order = np.argsort(inv, kind="stable")
    bounds = np.searchsorted(inv[order], np.arange(len(pat) + 1))
    Ainv = np.linalg.inv(A)
    for p in range(len(pat)):                          # loop over (at most 64) mask patterns
        r = order[bounds[p]:bounds[p + 1]]
        out[r] = b[r] @ Ainv[p].T
    return out


def lowrank_complete(X: np.ndarray, mask: np.ndarray, *, min_cum_sv: float = 0.99,
                     std_floor: float = 0.1, n_iter: int = 30, tol: float = 1e-2,
                     weights: np.ndarray | None = None) -> np.ndarray:
    """Iterative low-rank completion of a (T, C) matrix (EM for PCA with missing data,
    Roweis 1998): start from the linear fill in time (ends held), normalise the columns
    (mean and std of the observed entries, std floored at ``std_floor``, then multiplied
    by ``weights`` (C,) if given), then repeat: PCA of the filled matrix (leading
    components reaching ``min_cum_sv`` of the cumulative singular values), each row's
    scores fitted to its observed entries (:func:`_scores`), missing entries replaced by
    the reconstruction -- until the largest change of a missing entry is below ``tol`` (units
    of X) or ``n_iter``. Observed entries are returned unchanged; never-observed columns
    stay NaN.

    The prior's noise variance has a floor (:func:`_residual_variance`): without it the EM
    path was not robust to its start on data of exactly low rank (a 1e-14 change of the
    start: 1e-9 -> 13 off)."""
    X = np.asarray(X, dtype=float)
    M = np.asarray(mask, bool) & np.isfinite(X)
    ever = M.any(axis=0)
    Y = fill(X, M, never_observed=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mu = np.nan_to_num(np.nanmean(np.where(M, X, np.nan), axis=0))
        sd = np.nan_to_num(np.nanstd(np.where(M, X, np.nan), axis=0))
    sd = np.maximum(sd, std_floor)
    if weights is not None:
        sd = sd / np.maximum(np.asarray(weights, dtype=float), 1e-12)
    Z = (Y - mu) / sd
    rows = np.flatnonzero((~M).any(axis=1))
    Mr = M[rows]
    pats = _patterns(Mr)
    # rank from the pairwise-complete covariance of the observed entries: the linear start
    # must not add components of its own
    Mf = M.astype(float)
    Zo = np.where(M, Z, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        n_ij = Mf.T @ Mf
        m_i = (Zo.T @ Mf) / n_ij                                  # mean of col i where j seen
        C = (Zo.T @ Zo) / n_ij - m_i * m_i.T
    C = np.nan_to_num(0.5 * (C + C.T))
    k = _ncomp(np.sqrt(np.maximum(_linalg.eigvalsh(C, 'pca_fill covariance')[::-1], 0.0)), min_cum_sv)
    for _ in range(int(n_iter)):
        if not len(rows):
            break
        # right singular vectors from the (C, C) covariance: cheap for T >> C
        ev, V = _linalg.eigh(Z.T @ Z / max(len(Z) - 1, 1), 'pca_fill completion')
        ev, V = np.maximum(ev[::-1], 0.0), V[:, ::-1]
        s2 = _residual_variance(ev, k)
        Zr = Z[rows]
        A = _scores(V[:, :k], ev[:k], s2, Zr, Mr, pats) @ V[:, :k].T
        d = np.abs(np.where(Mr, 0.0, A - Zr)) * sd
        Z[rows] = np.where(Mr, Zr, A)
        if d.max() < tol:
            break
    out = Z * sd + mu
    out[M] = X[M]
    out[:, ~ever] = np.nan
    return out


def _model(Xl: np.ndarray, train: np.ndarray, cols: np.ndarray, wcol: np.ndarray,
           min_cum_sv: float, std_floor: float):
    """PCA of the weighted, normalised training frames (module docstring steps 2-3)."""
    Y = Xl[np.ix_(train, cols)]
    mu = Y.mean(axis=0)
    sd = np.maximum(Y.std(axis=0), std_floor)
    Z = (Y - mu) / sd * wcol
    # right singular vectors from the (C, C) Gram matrix: the same subspace as the SVD of Z,
    # ~10x cheaper for T >> C (measured 36 -> 3 ms per model on the sprint capture)
    ev, V = _linalg.eigh(Z.T @ Z, 'pca_fill model')
    ev, V = np.maximum(ev[::-1], 0.0), V[:, ::-1]
    S = np.sqrt(ev[:min(Z.shape)])
    k = _ncomp(S, min_cum_sv)
    lam = S ** 2 / max(len(Y) - 1, 1)
    s2 = _residual_variance(lam, k)
    return mu, sd, V[:, :k], lam[:k], s2


def _r2_predict(Xl, m, fr, ends, cd, mu, sd, V, lam, s2, wcol):
    """Local coordinates (len(fr), 3) of marker m at frames fr from one R2 model (module
    docstring step 4); the residuals at the gap's observed ``ends`` are interpolated over
    the frames and added, so the fill meets the observed ends."""
    frx = np.r_[fr, ends].astype(int)
    Zo = (Xl[np.ix_(frx, cd)] - mu[3:]) / sd[3:] * wcol[3:]
    o = np.isfinite(Zo)
    s = _scores(V[3:], lam, s2, Zo, o)
    xm = (s @ V[:3].T) / wcol[:3] * sd[:3] + mu[:3]
    n = len(fr)
    if ends:
        res = Xl[ends][:, 3 * m:3 * m + 3] - xm[n:]
        if len(ends) == 2:
            a = ((fr - ends[0]) / float(ends[1] - ends[0]))[:, None]
            return xm[:n] + (1 - a) * res[0] + a * res[1]
        return xm[:n] + res[0]
    return xm


def _weighted_complete(Xl, m, w, mm_weight, min_cum_sv, std_floor, n_iter, min_frames):
    """Fallback for marker m: iterative low-rank completion (:func:`lowrank_complete`) of its
    weighted neighbourhood (the markers with weight > 0.01, weighted as in R2). (T, 3), or
    None when the window holds too little to learn from: m seen in fewer than
    ``min_frames`` (30) frames, or the neighbourhood (weighted) seen in under half its entries
    (measured: at 95 % random missing the completion is worse than linear interpolation)."""
    js = [m] + [j for j in np.argsort(-w) if j != m and w[j] > 1e-2]
    cols = (3 * np.asarray(js)[:, None] + np.arange(3)).ravel()
    wcol = np.repeat(np.r_[mm_weight, w[js[1:]]], 3)
    X = Xl[:, cols]
    seen = np.isfinite(X[:, ::3])                                     # (T, markers)
    share = float((seen[:, 1:].mean(axis=0) * w[js[1:]]).sum() / max(w[js[1:]].sum(), 1e-12))
    if seen[:, 0].sum() < min_frames or len(js) < 2 or share < 0.5:
        return None
    Y = lowrank_complete(X, np.isfinite(X), min_cum_sv=min_cum_sv, std_floor=std_floor,
                         n_iter=n_iter, weights=wcol)
    return Y[:, :3]


def pca_fill(P: np.ndarray, observed: np.ndarray, *, sigma_cm: float = 20.0,
             mm_weight: float = 0.02, min_cum_sv: float = 0.99, frame: str = "heading",
             up_axis: int | None = None, min_frames: int = 30, min_donors: int = 3,
             cover: float = 0.9, std_floor_cm: float = 0.1, n_iter: int = 30,
             end_correction: bool = True, support_sigmas: float = 2.0,
             range_slack_cm: float = 5.0, return_info: bool = False):
    """Weighted-PCA (R2) fill of every gap, in a body-centred frame (module docstring).

    Parameters
    ----------
    P : (T, J, 3) positions, cm (NaN where missing).
    observed : (T, J) bool.
    sigma_cm : Gaussian weight scale (cm); the paper's 200 mm.
    mm_weight : weight of the missing marker in the PCA (paper: 0.02).
    min_cum_sv : cumulative singular-value share of the kept components (paper: 0.99).
    frame : ``"heading"`` (translation and heading removed, default), ``"translation"``
        (translation only, as the paper) or ``"world"`` (none).
    up_axis : vertical axis (default :func:`mocapkit.frames.up_axis_of`).
    min_frames : fewest training frames of a model; fewer -> iterative fallback.
    min_donors : markers within 2 sigma of the missing one that must be seen in a frame
        for it to be filled (and for a gap to use the R2 model).
    cover : in the first pass, a donor must be seen in this share of the gap's frames.
    std_floor_cm : floor of the per-coordinate standard deviation used to normalise.
    n_iter : iterations of the fallback completion.
    end_correction : add the model's residuals at the gap's observed ends (step 5).
    support_sigmas : a marker closer than this many ``sigma_cm`` (mean distance) to the
        missing one is "close": it counts as support and as a near donor.
    range_slack_cm : a fill frame is dropped (left NaN) when its distance to a close
        marker seen there leaves the range of that distance over the data by more than
        ``max(range_slack_cm, 25 % of the range)``.
    return_info : also return ``{"pca": n, "pca-iterative": n}`` (samples filled by each).

    Returns
    -------
    (P_filled (T, J, 3), filled (T, J) bool[, info]): observed samples unchanged, fills
    where supported, NaN elsewhere.
    """
    P, obs = _pca_fill_args(P, observed, frame, sigma_cm, min_cum_sv, mm_weight)
    T, J, _ = P.shape
    out = np.where(obs[..., None], P, np.nan)
    filled = np.zeros((T, J), bool)
    info = {"pca": 0, "pca-iterative": 0}
    todo = [g for g in find_gaps(obs) if g.kind != "never"]
    if not todo or J < 2:
        return (out, filled, info) if return_info else (out, filled)
    up = up_axis_of(P) if up_axis is None else int(up_axis)
    tr = (Frame.identity(np.zeros((T, 3))) if frame == "world"
          else body_frame(P, obs, up_axis=up, heading=(frame == "heading")))
    gf = _GapFiller(P, obs, tr.to_local(np.where(obs[..., None], P, 0.0)), sigma_cm=sigma_cm,
                    mm_weight=mm_weight, min_cum_sv=min_cum_sv, min_frames=min_frames,
                    min_donors=min_donors, cover=cover, std_floor_cm=std_floor_cm, n_iter=n_iter,
                    end_correction=end_correction, support_sigmas=support_sigmas,
                    range_slack_cm=range_slack_cm)
    for g in todo:                                               # loop over gaps
        left = gf.r2(g, info)
        if len(left):                                            # too few complete frames
            gf.fallback(g, left, info)
    new = np.isfinite(gf.local_fill).all(axis=-1) & ~obs
    if new.any():
        world = tr.to_world(np.nan_to_num(gf.local_fill))
        out[new] = world[new]
        filled = new
    return (out, filled, info) if return_info else (out, filled)


def _pca_fill_args(P, observed, frame: str, sigma_cm: float, min_cum_sv: float,
                   mm_weight: float) -> tuple[np.ndarray, np.ndarray]:
    """Checked positions (T, J, 3) float and observed mask (T, J) (finite samples only) of
    :func:`pca_fill`."""
    P = np.asarray(P, dtype=float)
    if P.ndim != 3 or P.shape[2] != 3:
        raise MocapValueError(f"positions must be (T, J, 3), got {P.shape}")
    obs = np.asarray(observed, bool) & np.isfinite(P).all(axis=-1)
    if frame not in ("heading", "translation", "world"):
        raise MocapValueError(f"frame must be 'heading', 'translation' or 'world', got {frame!r}")
    if not (float(sigma_cm) > 0 and 0 < float(min_cum_sv) <= 1 and float(mm_weight) > 0):
        raise MocapValueError("sigma_cm and mm_weight must be > 0 and min_cum_sv in (0, 1]")
    return P, obs


def _cols(js) -> np.ndarray:
    """Columns (3 per marker) of markers ``js`` in a (T, 3J) matrix."""
    return (3 * np.asarray(js)[:, None] + np.arange(3)).ravel()


class _GapFiller:
    """The per-gap steps of :func:`pca_fill` (module docstring steps 4-7) on the local-frame
    positions ``Ll`` (T, J, 3): marker weights and support from the mean pair distances,
    R2 models cached by donor set, the fills collected in ``local_fill`` (T, J, 3; NaN
    where not filled).  Settings as :func:`pca_fill`."""

    def __init__(self, P: np.ndarray, obs: np.ndarray, Ll: np.ndarray, *, sigma_cm, mm_weight,
                 min_cum_sv, min_frames, min_donors, cover, std_floor_cm, n_iter,
                 end_correction, support_sigmas, range_slack_cm):
        T, J, _ = P.shape
        self.obs, self.T = obs, T
        self.Xl = np.where(np.repeat(obs, 3, axis=1), Ll.reshape(T, 3 * J), np.nan)
        self.L3 = self.Xl.reshape(T, J, 3)
        dmean, _, _, dlo, dhi = distance_stats(P, obs, return_range=True)
        slack = np.maximum(float(range_slack_cm), 0.25 * (dhi - dlo))
        self.dlo, self.dhi = dlo - slack, dhi + slack     # plausible distance range of each pair
        d = np.nan_to_num(dmean, nan=np.inf)
        # per missing marker, sigma widened (up to twice sigma_cm) until its min_donors
        # nearest markers count as close (decision): a sparse set -- a skeleton's shin has
        # two joints within 40 cm -- otherwise has no support, and its gaps were left to
        # interpolation or low-rank fills that missed by 6-27 cm on 60-frame leg gaps
        # (development clips 05_05, 135_05, 49_19); dense marker sets keep the paper's 20 cm,
        # and a marker far from all others still has no support
        dk = np.sort(np.where(np.eye(J, dtype=bool), np.inf, d), axis=1)[:, min(int(min_donors), J - 1) - 1]
        sig = np.clip(np.where(np.isfinite(dk), dk * 1.0001 / float(support_sigmas), 0.0),
                      float(sigma_cm), 2.0 * float(sigma_cm))
        self.W = np.exp(-d ** 2 / (2.0 * sig[:, None] ** 2))
        self.close = self.W >= np.exp(-0.5 * float(support_sigmas) ** 2)   # counts as support
        np.fill_diagonal(self.close, False)
        self.mm_weight, self.min_cum_sv = float(mm_weight), float(min_cum_sv)
        self.std_floor, self.n_iter, self.cover = float(std_floor_cm), int(n_iter), float(cover)
        self.min_frames, self.k_min, self.end_correction = min_frames, int(min_donors), end_correction
        self.cache: dict = {}
        self.local_fill = np.full((T, J, 3), np.nan)

    def plausible(self, m: int, fr: np.ndarray, xm: np.ndarray) -> np.ndarray:
        """Frames whose fill keeps every close marker seen there at a distance inside the
        range seen in the data (widened by the slack): no extrapolated garbage."""
        cj = np.flatnonzero(self.close[m])
        d = np.linalg.norm(self.L3[fr][:, cj] - xm[:, None, :], axis=-1)     # NaN where unseen
        with np.errstate(invalid="ignore"):
            bad = (d < self.dlo[m, cj]) | (d > self.dhi[m, cj])
        return ~bad.any(axis=1)

    def r2(self, g, info: dict) -> np.ndarray:
        """R2 fill of gap ``g`` (steps 4-5, 7): up to three passes, the donors re-chosen for
        the frames left (cover, half of it, any share); returns the gap frames with evidence
        that no pass could fill."""
        obs, m, k_min = self.obs, g.joint, self.k_min
        gap = np.arange(g.start, g.stop)
        left = gap[obs[gap][:, self.close[m]].sum(axis=1) >= k_min]    # frames with evidence
        ends = ([f for f in (g.start - 1, g.stop) if 0 <= f < self.T and obs[f, m]]
                if self.end_correction else [])
        for cov in (self.cover, 0.5 * self.cover, 0.0):
            if not len(left):
                break
            donors, train = self._donors(m, left, cov)
            near = [j for j in donors if self.close[m, j]]
            ok = obs[left][:, near].sum(axis=1) >= k_min if len(near) >= k_min else np.zeros(len(left), bool)
            if not ok.any():
                continue
            fr = left[ok]
            e_ok = [f for f in ends if obs[f, near].sum() >= k_min]
            xm = _r2_predict(self.Xl, m, fr, e_ok, _cols(donors), *self._model(m, donors, train))
            keep = self.plausible(m, fr, xm)
            self.local_fill[fr[keep], m] = xm[keep]
            info["pca"] += int(keep.sum())
            left = left[~ok]
        return left

    def _donors(self, m: int, left: np.ndarray, cov: float) -> tuple[list[int], np.ndarray]:
        """Donors of marker m for the frames ``left``: markers seen in at least ``cov`` of
        them, added greedily by weight x share seen while the frames where m and every
        chosen donor are seen stay >= ``min_frames``; returns them and those frames (T,)."""
        obs, W = self.obs, self.W
        seen = obs[left].mean(axis=0)
        cand = [j for j in np.argsort(-W[m] * seen) if j != m and W[m, j] > 1e-4
                and seen[j] >= cov and seen[j] > 0]
        train = obs[:, m].copy()
        donors = []
        for j in cand:                                       # greedy, by weight
            t2 = train & obs[:, j]
            if t2.sum() >= self.min_frames:
                donors.append(int(j))
                train = t2
        return donors, train

    def _model(self, m: int, donors: list[int], train: np.ndarray) -> tuple:
        """The R2 model of marker m from ``donors`` (:func:`_model`, cached) and its weights."""
        key = (m, tuple(donors))
        if key not in self.cache:
            wcol = np.repeat(np.r_[self.mm_weight, self.W[m, donors]], 3)
            self.cache[key] = _model(self.Xl, np.flatnonzero(train), _cols([m] + donors), wcol,
                                     self.min_cum_sv, self.std_floor) + (wcol,)
        return self.cache[key]

    def fallback(self, g, left: np.ndarray, info: dict) -> None:
        """Step 6: the frames ``left`` of gap ``g`` from the iterative low-rank completion
        of a window around the gap (:func:`_weighted_complete`), where plausible."""
        m = g.joint
        pad = max(g.length, int(self.min_frames), 2 * len(left))
        a, b = max(g.start - pad, 0), min(g.stop + pad, self.T)     # a window around the gap
        Y = _weighted_complete(self.Xl[a:b], m, self.W[m], self.mm_weight, self.min_cum_sv,
                               self.std_floor, self.n_iter, min(30, b - a))
        if Y is None:
            return
        keep = self.plausible(m, left, Y[left - a])
        self.local_fill[left[keep], m] = Y[left - a][keep]
        info["pca-iterative"] += int(keep.sum())
