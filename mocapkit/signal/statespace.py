"""Linear-Gaussian state-space models for mocap trajectories: kinematic (constant
velocity / acceleration) and random-walk models, the innovation gate threshold, the
cutoff <-> process-noise relation, maximum-likelihood process noise, and the
steady-state Riccati covariance. The smoother that runs them is :mod:`.rts`."""
from __future__ import annotations

import numpy as np

from ..errors import MocapValueError
from ._arrays import as_2d

__all__ = ["cv_model", "random_walk_model", "gate_threshold", "cutoff_to_q",
           "select_process_noise", "steady_state_covariance"]


def cv_model(dt: float, q, *, order: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Transition F (n, n) and process covariance Q (..., n, n) of a continuous
    white-noise-driven kinematic model sampled every ``dt`` seconds (Bar-Shalom, Li &
    Kirubarajan 2001, §6.2-6.3).

    order 2 -- constant velocity, state (position, velocity), q = acceleration spectral
    density: Q = q [[dt³/3, dt²/2], [dt²/2, dt]].
    order 3 -- constant acceleration, state (position, velocity, acceleration), q = jerk
    spectral density: Q = q [[dt⁵/20, dt⁴/8, dt³/6], [dt⁴/8, dt³/3, dt²/2], [dt³/6, dt²/2, dt]].
    order 1 -- random walk, F = [[1]], Q = q dt.
    ``q`` may be an array (C,): Q then has shape (C, n, n).
    """
    d = float(dt)
    if order == 1:
        F = np.eye(1)
        Q0 = np.array([[d]])
    elif order == 2:
        F = np.array([[1.0, d], [0.0, 1.0]])
        Q0 = np.array([[d ** 3 / 3, d ** 2 / 2], [d ** 2 / 2, d]])
    elif order == 3:
        F = np.array([[1.0, d, d * d / 2], [0.0, 1.0, d], [0.0, 0.0, 1.0]])
        Q0 = np.array([[d ** 5 / 20, d ** 4 / 8, d ** 3 / 6],
                       [d ** 4 / 8, d ** 3 / 3, d ** 2 / 2],
                       [d ** 3 / 6, d ** 2 / 2, d]])
    else:
        raise MocapValueError(f"order must be 1, 2 or 3, got {order!r}")
    q = np.asarray(q, dtype=float)
    return F, q[..., None, None] * Q0


def random_walk_model(q) -> tuple[np.ndarray, np.ndarray]:
    """Lou & Chai's identity dynamics z(t+1) = z(t) + N(0, q): F = [[1]], Q = [[q]]
    (q: per-frame variance, scalar or (C,))."""
    q = np.asarray(q, dtype=float)
    return np.eye(1), q[..., None, None] * np.ones((1, 1))


def gate_threshold(n_sigmas: float, dof) -> np.ndarray:
    """Chi-square threshold on a squared Mahalanobis distance with ``dof`` degrees of
    freedom that is exceeded with the same probability as a two-sided ``n_sigmas``
    deviation of one Gaussian variable (e.g. 5 -> p = 5.7e-7)."""
    from scipy.special import chdtri, ndtr

    p = 2.0 * ndtr(-float(n_sigmas))
    dof = np.maximum(np.asarray(dof, dtype=float), 1.0)
    return chdtri(dof, p)


def cutoff_to_q(cutoff_hz, *, r, dt: float, order: int = 2):
    """Process-noise spectral density q giving a steady-state smoother with -6 dB point
    ``cutoff_hz``: for an ``order``-times integrated white noise of density q observed in
    white noise of variance r every dt seconds (noise density r dt), the Wiener smoother
    is H(w) = 1 / (1 + r dt w^(2 order) / q), so q = r dt (2 pi f_c)^(2 order)
    (cm²/s³ for order 2; cm²/s for order 1 -- multiply by dt for a per-frame variance)."""
    w = 2.0 * np.pi * np.asarray(cutoff_hz, dtype=float)
    return np.asarray(r, dtype=float) * dt * w ** (2 * order)


def select_process_noise(Y, mask=None, /, *, dt: float, r, order: int = 2,
                         grid_hz=None, huber: float = 3.0, max_frames: int = 1200,
                         x0=None) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel process noise q of a kinematic model (:func:`cv_model`) by maximising
    a robustified innovation log-likelihood over a grid of smoother cutoffs.

    For each candidate cutoff f (``grid_hz``; default 10 values from 0.25 Hz to 16 Hz by
    factors of 2^(2/3), those below fps/2.5) the q of :func:`cutoff_to_q` is tried on every channel
    at once (one batched forward Kalman pass over C x len(grid) filters) and scored by
    the prediction-error decomposition  -1/2 Σ_t [log S_t + ρ(ν_t² / S_t)], with ρ the
    Huber function at ``huber`` sigmas (so a minority of spikes does not drive the
    choice). The best grid point is refined by a parabola through its neighbours (in
    log f). Only the first ``max_frames`` frames are used.

    Returns q (C,) and the chosen cutoffs in Hz (C,).
    """
    A, shape, axis = as_2d(Y, 0)
    A = A[:max_frames]
    T, C = A.shape
    M = np.isfinite(A) if mask is None else (np.asarray(mask, bool).reshape(shape[0], -1)[:max_frames] & np.isfinite(A))
    g = _cutoff_grid(grid_hz, 1.0 / dt)
    G = g.size
    rr = np.broadcast_to(np.asarray(r, float), (C,))
    q = cutoff_to_q(g[:, None], r=rr[None, :], dt=dt, order=order)        # (G, C)
    F, Qm = cv_model(dt, q.reshape(-1), order=order)                      # (G*C, n, n)
    Yb = np.tile(np.where(M, A, 0.0), (1, G))                             # (T, G*C)
    Mb = np.tile(M, (1, G))
    Rb = np.tile(rr, G)
    first = np.tile(A[np.argmax(M, axis=0), np.arange(C)] if x0 is None
                    else np.asarray(x0, float).reshape(C), G)
    if F.shape[0] == 2 and M.all() and np.all(rr == rr[0]):
        # every frame observed and one noise level: the covariances depend on the grid
        # point only (the same numbers for its C channels), so they are run on G filters
        NU, SS = _innovations_shared(Yb, float(F[0, 1]), Qm, Rb, first, C)
    elif F.shape[0] <= 2:
        NU, SS = _innovations_2(Yb, Mb, F, Qm, Rb, first)
    else:
        NU, SS = _innovations_n(Yb, Mb, F, Qm, Rb, first)
    c2 = float(huber) ** 2
    u = NU[2:] ** 2 / SS[2:]                   # frames 0, 1 only set the state up
    rho = np.where(u <= c2, u, 2.0 * np.sqrt(c2 * u) - c2)
    ll = -np.where(Mb[2:], 0.5 * (np.log(SS[2:]) + rho), 0.0).sum(axis=0)
    fc = np.exp(_parabola_peak(ll.reshape(G, C), np.log(g)))
    return cutoff_to_q(fc, r=rr, dt=dt, order=order), fc


def _cutoff_grid(grid_hz, fs: float) -> np.ndarray:
    """The candidate cutoffs (Hz) of :func:`select_process_noise`."""
    if grid_hz is None:
        grid_hz = 0.25 * 2.0 ** (np.arange(10) * 2 / 3)
        grid_hz = grid_hz[grid_hz < fs / 2.5]
        if grid_hz.size < 3:
            grid_hz = np.geomspace(0.05 * fs, 0.4 * fs, 5)
    return np.asarray(grid_hz, dtype=float)


def _innovations_2(Yb, Mb, F, Qm, Rb, first) -> tuple[np.ndarray, np.ndarray]:
    """Forward Kalman pass for n <= 2 states with the 2x2 algebra on (B,) component
    arrays (as :func:`mocapkit.signal.rts._rts_scalar`): innovations and their variances
    (T, B); prior x = (first, 0), P = diag(1e4, 1e6)."""
    T, B = Yb.shape
    n = F.shape[0]
    NU = np.empty((T, B))
    SS = np.empty((T, B))
    d = float(F[0, 1]) if n == 2 else 0.0
    f00 = float(F[0, 0])
    q00 = np.ascontiguousarray(Qm[:, 0, 0])
    if n == 2:
        q01, q11 = np.ascontiguousarray(Qm[:, 0, 1]), np.ascontiguousarray(Qm[:, 1, 1])
        x1 = np.zeros(B)
        p01 = np.zeros(B)
        p11 = np.full(B, 1e6)
    x0_ = first.copy()
    p00 = np.full(B, 1e4)
    for t in range(T):
        if t > 0:
            if n == 2:      # F = [[1, d], [0, 1]]
                x0_ = x0_ + d * x1
                p00 = p00 + 2 * d * p01 + d * d * p11 + q00
                p01 = p01 + d * p11 + q01
                p11 = p11 + q11
            else:
                x0_ = f00 * x0_
                p00 = f00 * f00 * p00 + q00
        S = p00 + Rb
        nu = Yb[t] - x0_
        NU[t] = nu
        SS[t] = S
        inv_s = np.where(Mb[t], 1.0 / S, 0.0)
        k0 = p00 * inv_s
        x0_ = x0_ + k0 * nu
        if n == 2:
            k1 = p01 * inv_s
            x1 = x1 + k1 * nu
            p11 = p11 - k1 * p01
            p01 = p01 - k0 * p01
        p00 = p00 - k0 * p00
    return NU, SS


def _innovations_shared(Yb: np.ndarray, d: float, Qm: np.ndarray, Rb: np.ndarray, first: np.ndarray,
                        k: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_innovations_2` for two states (F = [[1, d], [0, 1]]) with every sample
    observed and the filters in runs of k sharing one model (Qm, Rb): the covariances and
    gains are run once per run (:func:`_gains_2`) and the frame loop updates the means only
    -- the same numbers, a third of the operations a frame."""
    S, K0, K1 = (np.repeat(a, k, axis=1) for a in _gains_2(Yb.shape[0], d, Qm[::k], Rb[::k]))
    NU = np.empty(Yb.shape)
    x0, x1 = first.copy(), np.zeros(Yb.shape[1])
    for t in range(Yb.shape[0]):            # the recursion of the means: frame by frame
        if t > 0:
            x0 = x0 + d * x1
        nu = Yb[t] - x0
        NU[t] = nu
        x0 = x0 + K0[t] * nu
        x1 = x1 + K1[t] * nu
    return NU, S


def _gains_2(T: int, d: float, Qm: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The covariance recursion of :func:`_innovations_2` (F = [[1, d], [0, 1]], every
    frame observed) for filters with process covariances Qm (B, 2, 2) and noise R (B,):
    innovation variances and the two gains, each (T, B)."""
    q00, q01, q11 = (np.ascontiguousarray(Qm[:, i, j]) for i, j in ((0, 0), (0, 1), (1, 1)))
    B = len(R)
    S, K0, K1 = np.empty((T, B)), np.empty((T, B)), np.empty((T, B))
    p00, p01, p11 = np.full(B, 1e4), np.zeros(B), np.full(B, 1e6)
    for t in range(T):
        if t > 0:           # the operations of _innovations_2, in its order
            p00 = p00 + 2 * d * p01 + d * d * p11 + q00
            p01 = p01 + d * p11 + q01
            p11 = p11 + q11
        S[t] = s = p00 + R
        inv_s = 1.0 / s
        K0[t] = k0 = p00 * inv_s
        K1[t] = k1 = p01 * inv_s
        p11 = p11 - k1 * p01
        p01 = p01 - k0 * p01
        p00 = p00 - k0 * p00
    return S, K0, K1


def _innovations_n(Yb, Mb, F, Qm, Rb, first) -> tuple[np.ndarray, np.ndarray]:
    """Forward Kalman pass for n = 3 states (batched matrices): innovations and their
    variances (T, B); prior x = (first, 0, 0), P = diag(1e4, 1e6, 1e8)."""
    T, B = Yb.shape
    n = F.shape[0]
    NU = np.empty((T, B))
    SS = np.empty((T, B))
    x = np.zeros((B, n))
    x[:, 0] = first
    P = np.broadcast_to(np.diag([1e4, 1e6, 1e8][:n]), (B, n, n)).copy()
    FT = F.T
    for t in range(T):
        if t > 0:
            x = x @ FT
            P = F @ P @ FT + Qm
        HP = P[:, 0, :]
        S = HP[:, 0] + Rb
        nu = Yb[t] - x[:, 0]
        NU[t] = nu
        SS[t] = S
        K = np.where(Mb[t], 1.0 / S, 0.0)[:, None] * HP
        x = x + K * nu[:, None]
        P = P - K[:, :, None] * HP[:, None, :]
    return NU, SS


def _parabola_peak(L: np.ndarray, logf: np.ndarray) -> np.ndarray:
    """Per column of the scores L (G, C) on the equally spaced grid ``logf`` (G,): the
    argmax, refined by the vertex of the parabola through it and its neighbours (moved
    at most half a grid step). Returns (C,) log-frequencies."""
    G = L.shape[0]
    best = np.argmax(L, axis=0)
    out = logf[best].copy()
    inner = (best > 0) & (best < G - 1)
    if inner.any():
        i = best[inner]
        cols = np.flatnonzero(inner)
        y0, y1, y2 = L[i - 1, cols], L[i, cols], L[i + 1, cols]
        den = y0 - 2 * y1 + y2
        h = logf[1] - logf[0]
        with np.errstate(invalid="ignore", divide="ignore"):
            off = np.where(den < 0, 0.5 * (y0 - y2) / den, 0.0)
        out[cols] = logf[i] + np.clip(off, -0.5, 0.5) * h
    return out


def steady_state_covariance(F, Q, H, R, *, tol: float = 1e-12, max_iter: int = 100) -> np.ndarray:
    """Steady-state *predicted* covariance P of the Kalman filter for
    ``x' = F x + w`` (w ~ N(0, Q)), ``y = H x + v`` (v ~ N(0, R)): the stabilising
    solution of the filter Riccati equation

        P = F P Fᵀ - F P Hᵀ (H P Hᵀ + R)⁻¹ H P Fᵀ + Q,

    by the structure-preserving doubling algorithm (Chu, Fan, Lin & Wang 2004): with
    A0 = Fᵀ, G0 = Hᵀ R⁻¹ H, H0 = Q, iterate  W = I + G H,
    A ← A W⁻¹ A,  G ← G + A W⁻¹ G Aᵀ,  H ← H + Aᵀ H W⁻¹ A  (old A on the right-hand
    sides); H converges quadratically to P (stops at relative change ``tol``, or when
    rounding stalls it below 1e-8). Unlike scipy's QZ-based ``solve_discrete_are`` it
    copes with a nearly singular Q (e.g. the deterministic lag block of a second-order
    model, where QZ reordering fails).
    ``R``: (p,) variances or (p, p). Raises ``np.linalg.LinAlgError`` without convergence.
    """
    F = np.asarray(F, dtype=float)
    H = np.asarray(H, dtype=float)
    R = np.asarray(R, dtype=float)
    Ri = np.diag(1.0 / R) if R.ndim == 1 else np.linalg.inv(R)
    A = F.T.copy()
    G = H.T @ Ri @ H
    X = np.array(Q, dtype=float, copy=True)
    n = A.shape[0]
    I = np.eye(n)
    prev = np.inf
    for it in range(max_iter):
        W = I + G @ X
        WiA = np.linalg.solve(W, A)                      # W⁻¹ A
        WiG = np.linalg.solve(W, G)                      # W⁻¹ G
        A_new = A @ WiA
        G_new = G + A @ WiG @ A.T
        X_new = X + A.T @ X @ WiA
        X_new = 0.5 * (X_new + X_new.T)
        G_new = 0.5 * (G_new + G_new.T)
        scale = max(np.abs(X_new).max(), 1e-300)
        diff = np.abs(X_new - X).max() / scale
        A, G, X = A_new, G_new, X_new
        if not np.isfinite(X).all():
            break
        # converged, or stalled at the rounding floor (quadratic convergence stops)
        if diff <= tol or (it > 3 and diff >= prev and diff <= 1e-8):
            return X
        prev = diff
    raise np.linalg.LinAlgError("steady-state Riccati iteration did not converge")
