"""Kalman filter + Rauch-Tung-Striebel smoother (:func:`rts_smoother`) and its three
code paths.

:func:`rts_smoother` runs a batch of independent linear-Gaussian state-space models
(e.g. one 2-state constant-velocity filter per coordinate, all coordinates at once) with
a forward Kalman filter and a Rauch-Tung-Striebel backward pass (Rauch, Tung & Striebel
1965; Welch & Bishop 2001 for the filter). Missing observations skip the update step.
Python loops run over time only (a recursion); every step is a handful of batched
small-matrix products with precomputed model matrices. Its output is the Gaussian
posterior mean, which :func:`_dense_posterior` (tests) computes by one direct solve.

Three code paths, same result (tests compare each with a dense solve):

* p = 1, n <= 2, H = first state, shared F (per-coordinate constant-velocity or
  random-walk filters): the 2 x 2 algebra written out on (B,) component arrays, RTS
  gains for all frames in one vectorised step (:func:`_rts_scalar`); with every frame
  observed and no gate, the frames after the covariances settle run as constant-gain
  filters (``lfilter``, :func:`_rts2_steady`, :func:`_rts1_steady`);
* p > n, or a single vector-observed model (B = 1) without gate (e.g. a PCA-latent
  pose model): :func:`_rts_multi` -- information or Woodbury form, Hᵀ W H
  precomputed per mask pattern, covariances reused once the Riccati recursion is
  stationary;
* otherwise the plain gain form ``K = P Hᵀ S⁻¹`` batched over B (:func:`_gain_forward`,
  :func:`_gain_backward`).

The smoothed mean needs only the filtered covariances (``G = P_f Fᵀ P_pred⁻¹``);
smoothed covariances are computed only when asked for.
"""
from __future__ import annotations

import numpy as np

from ..errors import MocapValueError
from ..windows import frame_blocks
from .statespace import gate_threshold

__all__ = ["rts_smoother"]


def _inv_small(P: np.ndarray) -> np.ndarray:
    """Inverse of a batch (..., n, n) of SPD matrices; closed form for n <= 2."""
    n = P.shape[-1]
    if n == 1:
        return 1.0 / P
    if n == 2:
        a, b, c, d = P[..., 0, 0], P[..., 0, 1], P[..., 1, 0], P[..., 1, 1]
        det = a * d - b * c
        out = np.empty_like(P)
        out[..., 0, 0] = d / det
        out[..., 0, 1] = -b / det
        out[..., 1, 0] = -c / det
        out[..., 1, 1] = a / det
        return out
    return np.linalg.inv(P)


def _is_e0(h: np.ndarray) -> bool:
    return h.shape[0] >= 1 and h[0] == 1.0 and not h[1:].any()


class _Gate:
    """Innovation gate shared by the filter loops: per group of batch members, reject
    when the summed squared Mahalanobis distance exceeds the chi-square threshold for
    the group's observed dof; a group rejected ``max_run`` frames in a row is accepted
    the next time (so the filter cannot lose a marker for good after a true sudden
    movement and then reject everything that follows)."""

    def __init__(self, n_sigmas: float, groups, B: int, p: int, max_run: int | None):
        g = np.arange(B) if groups is None else np.asarray(groups).reshape(B)
        self.ginv = np.unique(g, return_inverse=True)[1].reshape(B)
        self.n_groups = int(self.ginv.max()) + 1
        max_dof = int(np.bincount(self.ginv, minlength=self.n_groups).max()) * p
        self.thr = gate_threshold(n_sigmas, np.arange(max_dof + 1))
        self.run = np.zeros(self.n_groups, dtype=np.int64)
        self.max_run = None if max_run is None else int(max_run)

    def reject(self, d2: np.ndarray, dof: np.ndarray) -> np.ndarray:
        """d2, dof: (B,) squared distances and observed dimensions -> (B,) bool reject."""
        gd2 = np.bincount(self.ginv, weights=d2, minlength=self.n_groups)
        gdof = np.bincount(self.ginv, weights=dof, minlength=self.n_groups).astype(np.int64)
        bad = (gd2 > self.thr[gdof]) & (gdof > 0)
        if self.max_run is not None:
            bad &= self.run < self.max_run
        self.run = np.where(bad, self.run + 1, np.where(gdof > 0, 0, self.run))
        return bad[self.ginv]


def rts_smoother(Y, mask=None, /, *, F, Q, R, H=None, b=None, x0=None, P0=None,
                 gate: float | None = None, gate_groups=None, gate_max_run: int | None = 3,
                 return_cov: bool = False):
    """Kalman filter + Rauch-Tung-Striebel smoother for a batch of B independent
    linear-Gaussian state-space models sharing their time axis:

        x[t+1] = F x[t] + b + w,   w ~ N(0, Q)          (state, n dims)
        y[t]   = H x[t] + v,       v ~ N(0, diag(R))    (observation, p dims)
        x[0]   ~ N(x0, P0)

    Observations marked missing contribute nothing (the update step is skipped for them:
    "masked observation matrix" -- row i of H is dropped where y_i is missing).

    Parameters
    ----------
    Y : (T, B, p) observations (or (T, B) when p = 1); missing values may be NaN.
    mask : bool like Y, True = observed (default: finite).
    F : (n, n) or (B, n, n) transition.   Q : (n, n) or (B, n, n) process covariance.
    R : observation noise variances: scalar, (p,), (B,) if p = 1, or (B, p).
    H : (p, n) observation matrix (default: first state component, p = 1).
    b : optional (n,) or (B, n) drift.
    x0, P0 : prior of the first state, (B, n) / (B, n, n) or (n,) / (n, n);
        default x0 = 0 and P0 = 1e8 I (effectively diffuse).
    gate : optional outlier gate in "sigmas": an observation vector whose innovation has
        a squared Mahalanobis distance above :func:`gate_threshold` (gate, dof) is
        treated as missing (forward pass decides; the backward pass uses the decision).
    gate_groups : optional int array (B,) -- batch members with the same id are gated
        together on the sum of their squared distances (e.g. the x, y, z filters of one
        marker: a 3-dof test), which catches a 3-D spike with much better power than
        three 1-dof tests.
    gate_max_run : after this many consecutive rejected frames a group's next
        observation is accepted whatever its distance (default 3; None = never), so a
        filter that fell behind a real sudden movement re-acquires the marker instead of
        rejecting it for the rest of the clip.
    return_cov : also return the smoothed covariances (T, B, n, n).

    Returns
    -------
    xs : (T, B, n) smoothed state means (the posterior means given all observations).
    used : (T, B, p) bool -- observations actually used (mask minus gated).
    Ps : (T, B, n, n), only with ``return_cov``.

    Notes
    -----
    Three code paths, same result: see the docstring of :mod:`mocapkit.signal.rts`.
    """
    Yo, Mk, F, H, Qb, Rb, bb, x, P = _check_inputs(Y, mask, F, Q, R, H, b, x0, P0)
    squeeze_p = np.ndim(Y) == 2
    T, B, p = Yo.shape
    n = F.shape[-1]
    if (p == 1 and n <= 2 and F.ndim == 2 and bb is None and _is_e0(H[0])
            and not return_cov):
        gt = None if gate is None else _Gate(gate, gate_groups, B, 1, gate_max_run)
        xs, u = _rts_scalar(Yo[:, :, 0], Mk[:, :, 0], F, Qb, Rb[:, 0], x, P, gt)
        return xs, (u if squeeze_p else u[:, :, None])
    Y0 = Yo if Mk.all() else np.where(Mk, Yo, 0.0)         # only read: no copy when complete
    used = Mk.copy()
    Fb = np.broadcast_to(F, (B, n, n))
    if gate is None and p > 1 and (p > n or B == 1):
        out = _rts_multi(Y0, used, Fb, Qb, H, Rb, bb, x, P, return_cov)
    else:
        gt = None if gate is None else _Gate(gate, gate_groups, B, p, gate_max_run)
        xf, Pf, xp, Pp = _gain_forward(Y0, used, F, Fb, Qb, H, Rb, bb, x, P, gt)
        xs, Ps = _gain_backward(xf, Pf, xp, Pp, F, Fb, return_cov)
        out = (xs, used, Ps)
    if squeeze_p:
        out = (out[0], out[1][:, :, 0]) + tuple(out[2:])
    return out if return_cov else out[:2]


def _check_inputs(Y, mask, F, Q, R, H, b, x0, P0) -> tuple:
    """Validated arrays of :func:`rts_smoother`: Y (T, B, p), mask (T, B, p), F, H (p, n),
    Q (B, n, n), R (B, p), b (B, n) or None, x0 (B, n), P0 (B, n, n) (copies)."""
    Yo = np.asarray(Y, dtype=float)
    if Yo.ndim == 2:
        Yo = Yo[:, :, None]
    if Yo.ndim != 3:
        raise MocapValueError(f"Y must have shape (T, B) or (T, B, p), got {np.shape(Y)}")
    T, B, p = Yo.shape
    if mask is None:
        Mk = np.isfinite(Yo)
    else:
        Mk = np.asarray(mask, dtype=bool).reshape(Yo.shape) & np.isfinite(Yo)
    F = np.asarray(F, dtype=float)
    n = F.shape[-1]
    H = np.eye(1, n) if H is None else np.asarray(H, dtype=float)
    if H.shape != (p, n):
        raise MocapValueError(f"H must have shape ({p}, {n}), got {H.shape}")
    Qb = np.broadcast_to(np.asarray(Q, dtype=float), (B, n, n))
    Rv = np.asarray(R, dtype=float)
    if Rv.ndim == 1 and p == 1 and Rv.shape[0] == B:
        Rv = Rv[:, None]
    Rb = np.broadcast_to(Rv, (B, p)).astype(float)
    if (Rb <= 0).any():
        raise MocapValueError("observation noise variances R must be positive")
    bb = None if b is None else np.broadcast_to(np.asarray(b, dtype=float), (B, n))
    x = np.zeros((B, n)) if x0 is None else np.broadcast_to(np.asarray(x0, float), (B, n)).copy()
    P = 1e8 * np.broadcast_to(np.eye(n), (B, n, n)).copy() if P0 is None else \
        np.broadcast_to(np.asarray(P0, float), (B, n, n)).copy()
    return Yo, Mk, F, H, Qb, Rb, bb, x, P


def _gain_forward(Y0, used, F, Fb, Qb, H, Rb, bb, x, P, gt) -> tuple:
    """Forward Kalman filter of the gain-form path (``K = P Hᵀ S⁻¹`` batched over B).
    Gated observations are cleared in ``used`` (T, B, p) in place. Returns the filtered
    and predicted means (T, B, n) and covariances (T, B, n, n): xf, Pf, xp, Pp."""
    T, B, p = Y0.shape
    n = F.shape[-1]
    xf = np.empty((T, B, n))
    Pf = np.empty((T, B, n, n))
    xp = np.empty((T, B, n))
    Pp = np.empty((T, B, n, n))
    FT = np.swapaxes(Fb, -1, -2)
    shared_F = F.ndim == 2
    for t in range(T):
        if t > 0:
            if shared_F:
                x = x @ F.T
                P = F @ P @ F.T + Qb
            else:
                x = np.einsum("bij,bj->bi", Fb, x)
                P = Fb @ P @ FT + Qb
            if bb is not None:
                x = x + bb
        xp[t] = x
        Pp[t] = P
        if used[t].any():
            if p == 1:
                x, P = _update_scalar(x, P, Y0[t, :, 0], used[t], H[0], Rb[:, 0], gt)
            else:
                x, P = _update_vector(x, P, Y0[t], used[t], H, Rb, gt)
            P = 0.5 * (P + np.swapaxes(P, -1, -2))
        xf[t] = x
        Pf[t] = P
    return xf, Pf, xp, Pp


def _update_scalar(x, P, y, used_t, h, r, gt) -> tuple:
    """Measurement update for scalar observations: K = P h / (h P h + r), no matrix
    inverse. ``used_t`` (B, 1) is cleared where the gate rejects."""
    HP = P[:, 0, :] if _is_e0(h) else np.einsum("n,bnk->bk", h, P)   # (B, n)
    S = (HP[:, 0] if _is_e0(h) else HP @ h) + r                       # (B,)
    nu = y - (x[:, 0] if _is_e0(h) else x @ h)
    mt = used_t[:, 0]
    if gt is not None:
        reject = gt.reject(np.where(mt, nu * nu / S, 0.0), mt) & mt
        if reject.any():
            used_t[reject, 0] = False
            mt = used_t[:, 0]
    K = np.where(mt[:, None], HP / S[:, None], 0.0)              # (B, n)
    return x + K * nu[:, None], P - K[:, :, None] * HP[:, None, :]


def _update_vector(x, P, y, used_t, H, Rb, gt) -> tuple:
    """Measurement update for vector observations (B, p) with missing rows decoupled
    and zeroed (they change nothing). ``used_t`` (B, p) is cleared where the gate rejects."""
    p = H.shape[0]
    m = used_t
    HP = np.einsum("pn,bnk->bpk", H, P)                   # (B, p, n)
    S = np.einsum("bpk,qk->bpq", HP, H)                   # (B, p, p)
    nu = y - x @ H.T                                      # (B, p)
    mm = m[:, :, None] & m[:, None, :]
    eye = np.eye(p, dtype=bool)[None]
    S = np.where(mm, S, 0.0) + np.where(eye, np.where(m[:, :, None], Rb[:, :, None], 1.0), 0.0)
    nu = np.where(m, nu, 0.0)
    Sinv = _inv_small(S)
    if gt is not None:
        reject = gt.reject(np.einsum("bp,bpq,bq->b", nu, Sinv, nu), m.sum(axis=1))
        if reject.any():
            used_t[reject] = False
            nu = np.where(m, nu, 0.0)
    HPm = np.where(m[:, :, None], HP, 0.0)
    K = np.einsum("bpn,bpq->bnq", HPm, Sinv)               # (B, n, p)
    return x + np.einsum("bnq,bq->bn", K, nu), P - K @ HPm


def _gain_backward(xf, Pf, xp, Pp, F, Fb, return_cov: bool) -> tuple:
    """RTS backward pass, ``G = P_f Fᵀ P_pred⁻¹``: smoothed means (T, B, n) and, with
    ``return_cov``, covariances (T, B, n, n) (else None)."""
    T = xf.shape[0]
    shared_F = F.ndim == 2
    FT = np.swapaxes(Fb, -1, -2)
    xs = np.empty_like(xf)
    xs[-1] = xf[-1]
    Ps = None
    if return_cov:
        Ps = np.empty_like(Pf)
        Ps[-1] = Pf[-1]
    PfFT = Pf @ F.T if shared_F else None
    for t in range(T - 2, -1, -1):
        G = (PfFT[t] if shared_F else Pf[t] @ FT) @ _inv_small(Pp[t + 1])   # (B, n, n)
        xs[t] = xf[t] + (G @ (xs[t + 1] - xp[t + 1])[:, :, None])[:, :, 0]
        if return_cov:
            Ps[t] = Pf[t] + G @ (Ps[t + 1] - Pp[t + 1]) @ np.swapaxes(G, -1, -2)
    return xs, Ps


def _rts_multi(Y0, used, F, Q, H, R, b, x, P, return_cov, tol=1e-8):
    """Kalman filter + RTS smoother for vector observations with missing entries
    (W = diag(mask / R)), used when p > n or B = 1.

    Filtered covariance per frame: information form ``P⁺ = (P⁻¹ + Hᵀ W H)⁻¹`` (n x n
    inverses) when at least n channels are observed, else the Woodbury/gain form
    ``P⁺ = P - P Hₒᵀ (Hₒ P Hₒᵀ + Rₒ)⁻¹ Hₒ P`` on the p_o observed rows (p_o x p_o
    inverse; needs no inverse of P, which may be nearly singular, e.g. the lag block of
    a second-order model). Either way the mean update is ``x⁺ = x + P⁺ (Hᵀ W y - Hᵀ W H x)``
    with Hᵀ W H computed once per distinct mask pattern and Hᵀ W y for all frames in one
    product.

    Steady state: when the predicted covariance stops changing (largest entry change
    below ``tol`` x its largest entry) while the mask pattern stays the same, the
    covariances and gains of the previous frame are reused (the Riccati recursion has
    converged), so long stretches of complete frames cost a few matrix-vector products
    per frame and no inverse; the backward pass reuses its gain the same way.
    """
    T, B, p = Y0.shape
    n = F.shape[-1]
    # the distinct mask patterns from the bool mask, and H^T W y in blocks of frames: the
    # float weights W, W * Y0 and a sorted copy of W were three more arrays of Y's size
    # at once (a 100,000-frame clip: 5x its size inside the smoother)
    hy = np.empty((T, B, H.shape[1]))                               # (T, B, n)
    invR = 1.0 / R[None]
    for sl in frame_blocks(T):
        hy[sl] = np.where(used[sl], Y0[sl] * invR, 0.0) @ H
    upat, pat = np.unique(used.reshape(T, -1), axis=0, return_inverse=True)
    pat = pat.reshape(T)
    pats = np.where(upat.reshape(-1, B, p), invR, 0.0)              # (U, B, p) weights
    Jpat = np.matmul(H.T[None, None] * pats[:, :, None, :], H)      # (U, B, n, n)
    FT = np.swapaxes(F, -1, -2)
    xf = np.empty((T, B, n))
    xp = np.empty((T, B, n))
    covs_p: list[np.ndarray] = []
    covs_f: list[np.ndarray] = []
    idx_p = np.empty(T, dtype=np.int64)
    idx_f = np.empty(T, dtype=np.int64)
    steady = False
    for t in range(T):
        if t > 0:
            x = np.einsum("bij,bj->bi", F, x)
            if b is not None:
                x = x + b
        same = t > 0 and pat[t] == pat[t - 1]
        if steady and same:
            idx_p[t], idx_f[t] = idx_p[t - 1], idx_f[t - 1]
        else:
            Ppred = F @ P @ FT + Q if t > 0 else P
            if same and np.abs(Ppred - covs_p[idx_p[t - 1]]).max() <= tol * np.abs(Ppred).max():
                steady = True
                idx_p[t], idx_f[t] = idx_p[t - 1], idx_f[t - 1]
            else:
                steady = False
                Pn = _multi_filtered_cov(Ppred, pats[pat[t]], H, Jpat[pat[t]])
                covs_p.append(Ppred)
                covs_f.append(Pn)
                idx_p[t] = idx_f[t] = len(covs_f) - 1
        Pn = covs_f[idx_f[t]]
        xp[t] = x
        iv = hy[t] - np.einsum("bnk,bk->bn", Jpat[pat[t]], x)
        x = x + np.einsum("bnk,bk->bn", Pn, iv)
        P = Pn
        xf[t] = x
    xs, Ps = _multi_backward(xf, xp, F, covs_p, covs_f, idx_p, idx_f, return_cov)
    if return_cov:
        return xs, used, Ps
    return xs, used


def _multi_filtered_cov(Ppred: np.ndarray, w: np.ndarray, H: np.ndarray, J: np.ndarray) -> np.ndarray:
    """Filtered covariance (B, n, n) of :func:`_rts_multi` from the predicted one, the
    observation weights w (B, p) = mask / R and J = Hᵀ diag(w) H (B, n, n): Woodbury form
    on the observed rows when B = 1 and fewer than n are observed, else information form."""
    n = Ppred.shape[-1]
    if Ppred.shape[0] == 1 and (w[0] > 0).sum() < n:
        o = np.flatnonzero(w[0] > 0)
        Ho = H[o]
        PH = Ppred[0] @ Ho.T                            # (n, p_o)
        S = Ho @ PH + np.diag(1.0 / w[0, o])
        Pn = (Ppred[0] - PH @ np.linalg.solve(S, PH.T))[None] if o.size else Ppred.copy()
    else:
        Pn = np.linalg.inv(np.linalg.inv(Ppred) + J)
    return 0.5 * (Pn + np.swapaxes(Pn, -1, -2))


def _multi_backward(xf, xp, F, covs_p, covs_f, idx_p, idx_f, return_cov: bool) -> tuple:
    """RTS backward pass of :func:`_rts_multi` on its stored distinct covariances
    (``idx_*`` map frames to them); one gain per distinct (filtered, next predicted) pair.
    Returns the smoothed means (T, B, n; written into xf) and covariances (or None)."""
    T, B, n = xf.shape
    xs = xf                       # smoothed in place: xs[t] needs xf[t] and xs[t + 1] only
    if return_cov:
        Ps = np.empty((T, B, n, n))
        Ps[-1] = covs_f[idx_f[-1]]
    key_prev, G = None, None
    for t in range(T - 2, -1, -1):
        key = (int(idx_f[t]), int(idx_p[t + 1]))
        if key != key_prev:                                        # G = P_f Fᵀ P_pred⁻¹
            G = np.swapaxes(np.linalg.solve(covs_p[key[1]], F @ covs_f[key[0]]), -1, -2)
            key_prev = key
        xs[t] += np.einsum("bij,bj->bi", G, xs[t + 1] - xp[t + 1])
        if return_cov:
            Ps[t] = covs_f[key[0]] + G @ (Ps[t + 1] - covs_p[key[1]]) @ np.swapaxes(G, -1, -2)
    return xs, (Ps if return_cov else None)


_RTS_STORE_BYTES = 64 << 20
"""Up to this size (48 bytes per frame and channel) :func:`_rts_scalar` keeps the filtered and
predicted covariances of every frame; above it (e.g. 100,000 frames x 93 channels: 446 MB)
they are recomputed block by block in the backward pass (~20 % more time, same numbers)."""

_RTS_BLOCK = 1024
"""Frames per block of the vectorised RTS gain computation in :func:`_rts_scalar` (the
block's covariances are recomputed from a checkpoint, :func:`_rts2_backward`)."""


def _rts_scalar(Y, M, F, Q, R, x0, P0, gt):
    """Fast path of :func:`rts_smoother` for n <= 2 states, one scalar observation of the
    first state and a transition shared by the batch: the 2 x 2 algebra is written out on
    (B,) component arrays (about 40 vector operations per frame for both passes)."""
    T, B = Y.shape
    n = F.shape[0]
    used = M.copy()
    if n == 1:
        f = float(F[0, 0])
        q = np.ascontiguousarray(Q[:, 0, 0])
        if gt is None and used.all():
            xs = _rts1_steady(Y, R, f, q, x0[:, 0], P0[:, 0, 0])
            if xs is not None:
                return xs[:, :, None], used
        x = x0[:, 0].copy()
        P = P0[:, 0, 0].copy()
        xf = np.empty((T, B)); Pf = np.empty((T, B)); Pp = np.empty((T, B))
        for t in range(T):
            if t > 0:
                x = f * x
                P = f * f * P + q
            Pp[t] = P
            m = used[t]
            S = P + R
            nu = np.where(m, Y[t], 0.0) - x
            if gt is not None:
                m = m & ~gt.reject(np.where(m, nu * nu / S, 0.0), m)
                used[t] = m
            k = np.where(m, P / S, 0.0)
            x = x + k * nu
            P = P - k * P
            xf[t] = x; Pf[t] = P
        xs = np.empty_like(xf)
        xs[-1] = xf[-1]
        G = Pf[:-1] * f / Pp[1:]
        for t in range(T - 2, -1, -1):
            xs[t] = xf[t] + G[t] * (xs[t + 1] - f * xf[t])
        return xs[:, :, None], used
    f00, f01, f10, f11 = (float(v) for v in F.ravel())
    fq = (f00, f01, f10, f11) + tuple(np.ascontiguousarray(Q[:, i, j]) for i, j in ((0, 0), (0, 1), (1, 1)))
    if gt is None and used.all():
        xs = _rts2_steady(Y, R, fq, x0, P0)
        if xs is not None:
            return xs, used
    x0_, x1_ = x0[:, 0].copy(), x0[:, 1].copy()
    pc = (P0[:, 0, 0].copy(), P0[:, 0, 1].copy(), P0[:, 1, 1].copy())
    XF = np.empty((T, 2, B))
    marks = {}                                   # predicted covariance at every block start
    store = 48 * T * B <= _RTS_STORE_BYTES       # short clips: keep covariances, no recompute
    PF, PN = (np.empty((T, 3, B)), np.empty((T, 3, B))) if store else (None, None)
    for t in range(T):
        if t > 0:
            x0_, x1_ = f00 * x0_ + f01 * x1_, f10 * x0_ + f11 * x1_
            pc = _cv2_predict(pc, fq)
            if store:
                PN[t - 1] = pc
        if t % _RTS_BLOCK == 0:
            marks[t] = pc
        m = used[t]
        S = pc[0] + R
        nu = np.where(m, Y[t], 0.0) - x0_
        if gt is not None:
            m = m & ~gt.reject(np.where(m, nu * nu / S, 0.0), m)
            used[t] = m
        inv_s = np.where(m, 1.0 / S, 0.0)
        x0_ = x0_ + pc[0] * inv_s * nu
        x1_ = x1_ + pc[1] * inv_s * nu
        pc = _cv2_update(pc, inv_s)
        XF[t, 0] = x0_; XF[t, 1] = x1_
        if store:
            PF[t] = pc
    _rts2_backward(XF, used, R, fq, marks, None if PF is None else (PF, PN))
    return np.moveaxis(XF, 1, 2), used


_STEADY_MIN_FRAMES = 1024
"""Shortest clip given to :func:`_rts2_steady` / :func:`_rts1_steady`. On CMU clips the
covariances settled after 30-250 frames (kalman-cv, 0.5-3 cm noise, 30 and 120 fps), but a
clip of a few hundred frames often does not settle within its first half, and then the
covariance steps tried are done again by the per-frame path; short clips take that path
directly (they are fast either way)."""

_STEADY_TOL = 1e-13
"""Relative change of every covariance component below which :func:`_rts2_steady` and
:func:`_rts1_steady` take the gains as constant."""


def _rts2_steady(Y: np.ndarray, R: np.ndarray, fq: tuple, x0: np.ndarray,
                 P0: np.ndarray) -> np.ndarray | None:
    """:func:`_rts_scalar` (n = 2) for a batch observed in every frame, without a gate:
    (T, B, 2) smoothed means, or None when the covariances do not settle within the
    first half of the clip.

    Why: the covariance recursion does not depend on the data, and with every frame
    observed it converges geometrically to its steady state (the Riccati fixed point):
    30-250 frames on CMU clips (:data:`_STEADY_MIN_FRAMES`). From the frame ``tc`` where every component has
    settled (relative change < :data:`_STEADY_TOL`, plus two frames) the Kalman gain K and
    the smoother gain G are constant, so both passes are linear time-invariant
    recursions, run by ``scipy.signal.lfilter`` (C) per channel instead of a Python loop
    over frames (kalman-cv on 200,000 frames x 87 channels, the whole ``denoise``:
    16.2 s -> 6.1 s):

    * forward, ``x_t = A x_{t-1} + K y_t`` with ``A = (I - K e0^T) F``: each state is a
      second-order filter of y, ``(adj(I - A z^-1) K) / det(I - A z^-1)``, started from
      the exact states of frames tc-1, tc-2 (``lfiltic``);
    * backward, ``s_t = G s_{t+1} + (I - G F) x_t`` (``s_{T-1} = x_{T-1}``): two inputs,
      two outputs, run on the reversed frames from zero.

    Frames before tc go through the exact per-frame recursions. Agrees with the per-frame
    path to ~1e-12 relative (tests/test_kalman.py)."""
    from scipy.signal import lfilter, lfiltic

    T, B = Y.shape
    f00, f01, f10, f11 = fq[:4]
    if T < _STEADY_MIN_FRAMES:
        return None
    PP = [(P0[:, 0, 0].copy(), P0[:, 0, 1].copy(), P0[:, 1, 1].copy())]   # predicted, frames 0..tc
    PF = [_cv2_update(PP[0], 1.0 / (PP[0][0] + R))]                         # filtered
    tc = None
    for t in range(1, T // 2 + 3):                   # the covariances only: (B,) vectors
        PP.append(_cv2_predict(PF[-1], fq))
        PF.append(_cv2_update(PP[-1], 1.0 / (PP[-1][0] + R)))
        if tc is None and all(np.all(np.abs(a - b) <= _STEADY_TOL * np.abs(b)) for a, b in zip(PF[-1], PF[-2])):
            tc = t + 2                               # settled at t; two more frames to be sure
        if t == tc:
            break
    if tc is None or tc >= T - 2 or len(PF) < tc + 1:
        return None
    # channel-major (B, 2, T): each channel's filters write contiguous rows (the input
    # columns are read strided: a transposed copy would cost the input's size again)
    XF = np.empty((B, 2, T))
    a0, a1 = x0[:, 0].copy(), x0[:, 1].copy()
    for t in range(tc):                              # exact forward frames
        if t > 0:
            a0, a1 = f00 * a0 + f01 * a1, f10 * a0 + f11 * a1
        p00, p01 = PP[t][0], PP[t][1]
        inv_s = 1.0 / (p00 + R)
        nu = Y[t] - a0
        a0, a1 = a0 + p00 * inv_s * nu, a1 + p01 * inv_s * nu
        XF[:, 0, t] = a0; XF[:, 1, t] = a1
    # steady gains (B,): K from the settled predicted covariance, G from filtered / predicted
    p00, p01, p11 = PP[tc]
    k0, k1 = p00 / (p00 + R), p01 / (p00 + R)
    A00, A01 = (1 - k0) * f00, (1 - k0) * f01                  # (I - K e0^T) F
    A10, A11 = f10 - k1 * f00, f11 - k1 * f01
    g00, g01, g10, g11 = _gain2(PF[tc], PP[tc], fq[:4])       # steady: Pp[tc+1] = Pp[tc]
    # u = (I - G F) x
    h00 = 1 - (g00 * f00 + g01 * f10); h01 = -(g00 * f01 + g01 * f11)
    h10 = -(g10 * f00 + g11 * f10); h11 = 1 - (g10 * f01 + g11 * f11)
    for b in range(B):           # a loop over channels, not frames; smoothed means overwrite XF
        den = np.array([1.0, -(A00[b] + A11[b]), A00[b] * A11[b] - A01[b] * A10[b]])
        y = Y[tc:, b]
        for i, num in enumerate(([k0[b], A01[b] * k1[b] - A11[b] * k0[b]],
                                 [k1[b], A10[b] * k0[b] - A00[b] * k1[b]])):
            zi = lfiltic(num, den, XF[b, i, [tc - 1, tc - 2]], Y[[tc - 1, tc - 2], b])
            XF[b, i, tc:] = lfilter(num, den, y, zi=zi)[0]
        x0r, x1r = XF[b, 0, tc:][::-1].copy(), XF[b, 1, tc:][::-1].copy()   # reversed, T-1 .. tc
        u0 = h00[b] * x0r + h01[b] * x1r
        u1 = h10[b] * x0r + h11[b] * x1r
        u0[0], u1[0] = x0r[0], x1r[0]                 # s_{T-1} = x_{T-1}
        gd = np.array([1.0, -(g00[b] + g11[b]), g00[b] * g11[b] - g01[b] * g10[b]])
        XF[b, 0, tc:] = (lfilter([1.0, -g11[b]], gd, u0) + lfilter([0.0, g01[b]], gd, u1))[::-1]
        XF[b, 1, tc:] = (lfilter([0.0, g10[b]], gd, u0) + lfilter([1.0, -g00[b]], gd, u1))[::-1]
    s0, s1 = XF[:, 0, tc].copy(), XF[:, 1, tc].copy()
    for t in range(tc - 1, -1, -1):                  # exact backward frames
        G00, G01, G10, G11 = _gain2(PF[t], PP[t + 1], fq[:4])
        d0 = s0 - (f00 * XF[:, 0, t] + f01 * XF[:, 1, t])
        d1 = s1 - (f10 * XF[:, 0, t] + f11 * XF[:, 1, t])
        s0, s1 = XF[:, 0, t] + G00 * d0 + G01 * d1, XF[:, 1, t] + G10 * d0 + G11 * d1
        XF[:, 0, t] = s0; XF[:, 1, t] = s1
    return np.transpose(XF, (2, 0, 1))               # (T, B, 2), a view


def _rts1_steady(Y: np.ndarray, R: np.ndarray, f: float, q: np.ndarray, x0: np.ndarray,
                 P0: np.ndarray) -> np.ndarray | None:
    """:func:`_rts_scalar` for one state (n = 1) observed in every frame, without a gate:
    (T, B) smoothed means, or None when the variance does not settle within the first half
    of the clip. As :func:`_rts2_steady`: exact recursions up to the frame ``tc`` where
    the variances have settled, then the constant-gain forward filter
    ``x_t = (1 - k) f x_{t-1} + k y_t`` and backward smoother
    ``s_t = G s_{t+1} + (1 - G f) x_t`` by ``lfilter`` per channel."""
    from scipy.signal import lfilter, lfiltic

    T, B = Y.shape
    if T < _STEADY_MIN_FRAMES:
        return None
    PP = [P0.copy()]                                 # predicted / filtered variances, frames 0..tc
    PF = [PP[0] - PP[0] ** 2 / (PP[0] + R)]
    tc = None
    for t in range(1, T // 2 + 3):
        PP.append(f * f * PF[-1] + q)
        PF.append(PP[-1] - PP[-1] ** 2 / (PP[-1] + R))
        if tc is None and np.all(np.abs(PF[-1] - PF[-2]) <= _STEADY_TOL * np.abs(PF[-2])):
            tc = t + 2                               # settled at t; two more frames to be sure
        if t == tc:
            break
    if tc is None or tc >= T - 2 or len(PF) < tc + 1:
        return None
    XF = np.empty((B, T))                            # channel-major, as _rts2_steady
    x = x0.copy()
    for t in range(tc):                              # exact forward frames
        if t > 0:
            x = f * x
        x = x + PP[t] / (PP[t] + R) * (Y[t] - x)
        XF[:, t] = x
    k = PP[tc] / (PP[tc] + R)
    G = PF[tc] * f / PP[tc]
    for b in range(B):                               # a loop over channels, not frames
        num, den = [k[b]], [1.0, -(1.0 - k[b]) * f]
        zi = lfiltic(num, den, XF[b, [tc - 1]], Y[[tc - 1], b])
        XF[b, tc:] = lfilter(num, den, Y[tc:, b], zi=zi)[0]
        u = (1.0 - G[b] * f) * XF[b, tc:][::-1]
        u[0] = XF[b, -1]                              # s_{T-1} = x_{T-1}
        XF[b, tc:] = lfilter([1.0], [1.0, -G[b]], u)[::-1]
    s = XF[:, tc].copy()
    for t in range(tc - 1, -1, -1):                  # exact backward frames
        g = PF[t] * f / PP[t + 1]
        s = XF[:, t] + g * (s - f * XF[:, t])
        XF[:, t] = s
    return XF.T                                      # (T, B), a view


def _cv2_predict(pc: tuple, fq: tuple) -> tuple:
    """Predicted 2 x 2 covariance F P F^T + Q on (B,) components (p00, p01, p11)."""
    p00, p01, p11 = pc
    f00, f01, f10, f11, q00, q01, q11 = fq
    a = f00 * p00 + f01 * p01
    b = f00 * p01 + f01 * p11
    c = f10 * p00 + f11 * p01
    e = f10 * p01 + f11 * p11
    return a * f00 + b * f01 + q00, a * f10 + b * f11 + q01, c * f10 + e * f11 + q11


def _cv2_update(pc: tuple, inv_s: np.ndarray) -> tuple:
    """Filtered covariance after observing the first state (gain k = P e0 / S)."""
    p00, p01, p11 = pc
    k0 = p00 * inv_s
    k1 = p01 * inv_s
    return p00 - k0 * p00, p01 - k0 * p01, p11 - k1 * p01


def _gain2(pf: tuple, pp: tuple, f: tuple) -> tuple:
    """RTS gain ``G = Pf F^T Pp^-1`` of the 2 x 2 model from the components (p00, p01,
    p11) of the filtered and next predicted covariances (arrays of any shape) and F's
    (f00, f01, f10, f11); returns (g00, g01, g10, g11)."""
    f00, f01, f10, f11 = f
    a00, a01, a11 = pf
    c00 = a00 * f00 + a01 * f01; c01 = a00 * f10 + a01 * f11      # Pf Fᵀ (2x2, not symmetric)
    c10 = a01 * f00 + a11 * f01; c11 = a01 * f10 + a11 * f11
    b00, b01, b11 = pp
    det = b00 * b11 - b01 * b01
    i00, i01, i11 = b11 / det, -b01 / det, b00 / det
    return (c00 * i00 + c01 * i01, c00 * i01 + c01 * i11,
            c10 * i00 + c11 * i01, c10 * i01 + c11 * i11)


def _rts2_backward(XF: np.ndarray, used: np.ndarray, R: np.ndarray, fq: tuple,
                   marks: dict, stored: tuple | None = None) -> None:
    """RTS backward pass of :func:`_rts_scalar`, overwriting the filtered means XF (T, 2, B)
    with the smoothed ones.

    Covariances are not stored for all frames: each block of _RTS_BLOCK frames recomputes
    its filtered / predicted covariances from the predicted covariance saved at its start
    (``marks``) with the same operations as the forward pass (:func:`_cv2_predict`,
    :func:`_cv2_update`; bit-identical), then the gains G = Pf Fᵀ Pp[t+1]⁻¹ of the block
    are formed in one vectorised step.  Memory: O(block x B) besides XF.  ``stored``
    (PF, PN) (T, 3, B): the forward pass kept them (short clips), nothing is recomputed.
    """
    T, _, B = XF.shape
    f00, f01, f10, f11 = fq[:4]
    s0, s1 = XF[-1, 0].copy(), XF[-1, 1].copy()
    for lo in range(((T - 2) // _RTS_BLOCK) * _RTS_BLOCK, -1, -_RTS_BLOCK):
        hi = min(lo + _RTS_BLOCK, T - 1)                 # gains for t in [lo, hi)
        if stored is not None:
            PF, PN = stored[0][lo:hi], stored[1][lo:hi]
        else:
            PF, PN = np.empty((hi - lo, 3, B)), np.empty((hi - lo, 3, B))
            pc = marks[lo]
            for t in range(lo, hi):
                S = pc[0] + R
                pc = _cv2_update(pc, np.where(used[t], 1.0 / S, 0.0))
                PF[t - lo] = pc
                pc = _cv2_predict(pc, fq)
                PN[t - lo] = pc
        g00, g01, g10, g11 = _gain2((PF[:, 0], PF[:, 1], PF[:, 2]), (PN[:, 0], PN[:, 1], PN[:, 2]),
                                    (f00, f01, f10, f11))
        # predicted means x_pred[t+1] = F x_f[t]
        xp0 = f00 * XF[lo:hi, 0] + f01 * XF[lo:hi, 1]
        xp1 = f10 * XF[lo:hi, 0] + f11 * XF[lo:hi, 1]
        for t in range(hi - 1, lo - 1, -1):
            k = t - lo
            d0 = s0 - xp0[k]
            d1 = s1 - xp1[k]
            s0 = XF[t, 0] + g00[k] * d0 + g01[k] * d1
            s1 = XF[t, 1] + g10[k] * d0 + g11[k] * d1
            XF[t, 0] = s0; XF[t, 1] = s1


def _dense_posterior(Y, mask, *, F, Q, R, H, x0, P0, b=None):
    """Reference for tests: posterior mean and covariance of one small state-space model
    by one dense solve of the normal equations (information matrix of the joint
    Gaussian over all T*n states). Y (T, p), mask (T, p). Returns (T, n), (T*n, T*n)."""
    Y = np.asarray(Y, float)
    T, p = Y.shape
    n = F.shape[0]
    N = T * n
    Lam = np.zeros((N, N))
    eta = np.zeros(N)
    P0i = np.linalg.inv(P0)
    Lam[:n, :n] += P0i
    eta[:n] += P0i @ x0
    Qi = np.linalg.inv(Q)
    bb = np.zeros(n) if b is None else np.asarray(b, float)
    for t in range(T - 1):
        i, j = slice(t * n, (t + 1) * n), slice((t + 1) * n, (t + 2) * n)
        # (x_{t+1} - F x_t - b)ᵀ Q⁻¹ (x_{t+1} - F x_t - b)
        Lam[j, j] += Qi
        Lam[i, i] += F.T @ Qi @ F
        Lam[i, j] -= F.T @ Qi
        Lam[j, i] -= Qi @ F
        eta[j] += Qi @ bb
        eta[i] -= F.T @ Qi @ bb
    Rv = np.broadcast_to(np.asarray(R, float), (p,))
    for t in range(T):
        m = np.asarray(mask[t], bool) & np.isfinite(Y[t])
        W = np.diag(np.where(m, 1.0 / Rv, 0.0))
        i = slice(t * n, (t + 1) * n)
        Lam[i, i] += H.T @ W @ H
        eta[i] += H.T @ W @ np.where(m, Y[t], 0.0)
    cov = np.linalg.inv(Lam)
    return np.linalg.solve(Lam, eta).reshape(T, n), cov
