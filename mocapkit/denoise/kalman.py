"""Kalman-filter / RTS-smoother baselines: kalman-cv, kalman-identity, kalman-learned.

* ``kalman-cv`` -- constant-velocity (or constant-acceleration) model per coordinate,
  the classical marker smoother.
* ``kalman-identity`` -- Lou & Chai 2010 (seed 001, Sec. 6.2) "general Kalman filter"
  baseline: identity dynamics z(t+1) = z(t) + N(0, q), observation z + N(0, r).
* ``kalman-learned`` -- Lou & Chai's "data-driven Kalman filter": linear dynamics learned
  from training clips by least squares, in a body-centred frame and a PCA latent space.

All three run :func:`mocapkit.signal.rts_smoother` (forward Kalman filter, Rauch-Tung-
Striebel backward pass; missing observations skip the update step), whose result is
the exact Gaussian posterior mean of the model given the whole clip. The per-coordinate
filters run as one batch of 3J independent filters (one Python loop over time, all
channels vectorised).

Noise levels (documented decisions; every one is a parameter)
--------------------------------------------------------------
* measurement noise sigma (cm): by default estimated from the clip as the median over
  channels of ``1.4826 MAD(Δ²y) / √6`` (:func:`mocapkit.signal.estimate_noise_sigma`),
  floored at 0.01 cm. At 30-120 fps human motion contributes little to second
  differences, so this tracks the actual noise level (2 cm noise -> ~2 cm), and the
  MAD ignores a minority of spikes.
* process noise (kalman-cv, kalman-identity): by default chosen per channel by maximum
  (Huber-robustified) innovation likelihood over a grid of smoother bandwidths
  (:func:`mocapkit.signal.select_process_noise`; one batched forward pass over all
  channels x 13 candidate values). The process noise q and the smoother's -6 dB cutoff
  f_c are equivalent (:func:`mocapkit.signal.cutoff_to_q`: q = r dt (2 pi f_c)^(2 order)),
  so ``cutoff_hz`` can be given instead.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .. import signal
from ..errors import MocapValueError
from ..motion import Motion
from .base import Denoiser, register, training_matrices
from .filters import require_observed_joints

__all__ = ["KalmanCV", "KalmanIdentity", "KalmanLearned", "body_frame", "to_body", "from_body"]

_MIN_NOISE_CM = 0.01


def _noise_sigma(X: np.ndarray, M: np.ndarray, given) -> float:
    """Measurement sigma in cm: ``given`` or the pooled robust estimate (module doc)."""
    if given is not None:
        s = float(given)
        if not (np.isfinite(s) and s > 0):
            raise MocapValueError(f"measurement_sigma_cm must be a positive number of cm, got {given!r}")
        return s
    est = signal.estimate_noise_sigma(X, M)
    est = est[np.isfinite(est)]
    return max(float(np.median(est)) if est.size else 1.0, _MIN_NOISE_CM)


def _process_noise(method: str, X, M, dt: float, sigma: float, order: int,
                   process_noise, cutoff_hz):
    """q (scalar or per channel) from an explicit value, a cutoff, or robust ML."""
    if process_noise is not None and cutoff_hz is not None:
        raise MocapValueError(f"{method}: give process_noise or cutoff_hz, not both")
    if process_noise is not None:
        q = float(process_noise)
        if not (np.isfinite(q) and q > 0):
            raise MocapValueError(f"{method}: process_noise must be positive, got {process_noise!r}")
        return q
    if cutoff_hz is not None:
        f = float(cutoff_hz)
        if not (np.isfinite(f) and 0 < f < 0.5 / dt):
            raise MocapValueError(f"{method}: cutoff_hz must lie between 0 and half the frame rate "
                                  f"({0.5 / dt:g} Hz), got {cutoff_hz!r}")
        return float(signal.cutoff_to_q(f, r=sigma ** 2, dt=dt, order=order))
    q, _ = signal.select_process_noise(X, M, dt=dt, r=sigma ** 2, order=order)
    return q


def _first_values(X: np.ndarray, M: np.ndarray) -> np.ndarray:
    """First observed value of every channel (C,)."""
    first = np.argmax(M, axis=0)
    return X[first, np.arange(X.shape[1])]


# ---------------------------------------------------------------------------------------
@register
class KalmanCV(Denoiser):
    """Constant-velocity Kalman filter + RTS smoother per marker coordinate.

    Model per coordinate (continuous white-noise acceleration, sampled at 1/fps s;
    Bar-Shalom et al. 2001 §6.2): state (position cm, velocity cm/s),
    ``x[t+1] = F x[t] + w``, ``F = [[1, dt], [0, 1]]``,
    ``Q = q [[dt³/3, dt²/2], [dt²/2, dt]]``; observation = position + N(0, sigma²).
    ``order=3`` uses constant acceleration (white-noise jerk) instead.

    Parameters
    ----------
    order : 2 = constant velocity (default), 3 = constant acceleration.
    measurement_sigma_cm : observation noise sigma in cm; None (default) estimates it
        from the clip (module doc).
    process_noise : spectral density q of the driving white noise, in cm²/s³ (order 2)
        or cm²/s⁵ (order 3), one value for all channels.
    cutoff_hz : alternative to ``process_noise``: the steady-state smoother's -6 dB
        frequency (same for all channels). With neither given (default) q is chosen per
        channel by robust maximum likelihood (module doc).
    gate : None (default, off) or an outlier gate in sigmas: a marker whose 3-D
        innovation has a Mahalanobis distance more unlikely than a ``gate``-sigma event
        (chi-square test, 3 dof; :func:`mocapkit.signal.gate_threshold`) is treated as
        missing in that frame. Rejected joints are returned in ``source['flagged']``
        ((T, J) bool). Typical values 4-6.

    The initial state is the first observed value with zero velocity and a vague prior
    (100 cm, 1000 cm/s). Missing frames skip the update. A joint never observed raises
    MocapValueError.
    """

    name = "kalman-cv"
    description = "constant-velocity Kalman filter + RTS smoother per coordinate (noise levels estimated)"
    needs_training = False
    keeps_observed = False

    def __init__(self, order: int = 2, measurement_sigma_cm: float | None = None,
                 process_noise: float | None = None, cutoff_hz: float | None = None,
                 gate: float | None = None):
        self.order = order
        self.measurement_sigma_cm = measurement_sigma_cm
        self.process_noise = process_noise
        self.cutoff_hz = cutoff_hz
        self.gate = gate

    def denoise(self, motion: Motion) -> Motion:
        if self.order not in (2, 3):
            raise MocapValueError(f"kalman-cv: order must be 2 (constant velocity) or 3 "
                                  f"(constant acceleration), got {self.order!r}")
        require_observed_joints(motion, self.name)
        X, M = motion.matrix(), motion.matrix_mask()
        T, C = X.shape
        dt = 1.0 / motion.fps
        sigma = _noise_sigma(X, M, self.measurement_sigma_cm)
        q = _process_noise(self.name, X, M, dt, sigma, self.order, self.process_noise, self.cutoff_hz)
        F, Q = signal.cv_model(dt, q, order=self.order)
        n = self.order
        x0 = np.zeros((C, n))
        x0[:, 0] = _first_values(X, M)
        P0 = np.diag([1e4, 1e6, 1e8][:n])
        if self.gate is not None and not float(self.gate) > 0:
            raise MocapValueError(f"kalman-cv: gate must be a positive number of sigmas, got {self.gate!r}")
        xs, used = signal.rts_smoother(X, M, F=F, Q=Q, R=sigma ** 2, x0=x0, P0=P0,
                                       gate=self.gate, gate_groups=np.arange(C) // 3)
        out = motion.with_matrix(xs[:, :, 0])
        if self.gate is not None:
            flagged = (M & ~used).reshape(T, -1, 3).any(axis=2)
            out = out.with_source(flagged=flagged)
        return out


@register
class KalmanIdentity(Denoiser):
    """Lou & Chai's general Kalman filter baseline (seed 001, Sec. 6.2): per coordinate,
    identity dynamics ``z(t+1) = z(t) + N(0, q)`` and observation ``y(t) = z(t) + N(0, r)``,
    smoothed with RTS.

    Parameters
    ----------
    process_sigma_cm : sqrt(q), random-walk step per frame in cm.
    cutoff_hz : alternative: the steady-state smoother's -6 dB frequency,
        q = r (2 pi f_c dt)² per frame. With neither given (default) q is chosen per
        channel by robust maximum likelihood (module doc) -- decision: the paper does
        not give q.
    measurement_sigma_cm : sqrt(r) in cm; None (default) estimates it (module doc).
    """

    name = "kalman-identity"
    description = "Kalman + RTS with identity dynamics z(t+1)=z(t)+noise per coordinate (Lou & Chai baseline)"
    needs_training = False
    keeps_observed = False

    def __init__(self, process_sigma_cm: float | None = None, cutoff_hz: float | None = None,
                 measurement_sigma_cm: float | None = None):
        self.process_sigma_cm = process_sigma_cm
        self.cutoff_hz = cutoff_hz
        self.measurement_sigma_cm = measurement_sigma_cm

    def denoise(self, motion: Motion) -> Motion:
        require_observed_joints(motion, self.name)
        X, M = motion.matrix(), motion.matrix_mask()
        sigma = _noise_sigma(X, M, self.measurement_sigma_cm)
        dt = 1.0 / motion.fps
        if self.process_sigma_cm is not None:
            s = float(self.process_sigma_cm)
            if not (np.isfinite(s) and s > 0):
                raise MocapValueError(f"kalman-identity: process_sigma_cm must be positive, got {self.process_sigma_cm!r}")
            q = s * s
        else:   # continuous density (cm²/s) -> per-frame variance
            q = _process_noise(self.name, X, M, dt, sigma, 1, None, self.cutoff_hz) * dt
        F, Q = signal.random_walk_model(q)
        x0 = _first_values(X, M)[:, None]
        xs, _ = signal.rts_smoother(X, M, F=F, Q=Q, R=sigma ** 2, x0=x0, P0=np.array([[1e4]]))
        return motion.with_matrix(xs[:, :, 0])


# ---------------------------------------------------------------------------------------
# body-centred frame
# ---------------------------------------------------------------------------------------
def _smooth_track(V: np.ndarray, fps: float, smooth_s: float) -> np.ndarray:
    """Robustly smooth (T, k) tracks: running median (~smooth_s) then Gaussian (sigma smooth_s)."""
    T = V.shape[0]
    if T < 3 or smooth_s <= 0:
        return V
    w = max(3, int(round(smooth_s * fps)) | 1)
    w = min(w, T if T % 2 else T - 1)
    if w >= 3:
        V = signal.median(V, window=w)
    return signal.gaussian(V, sigma=max(smooth_s * fps, 0.5))


def up_axis_of(P: np.ndarray) -> int:
    """Vertical axis of positions (T, J, 3): the axis of largest median per-frame extent
    over joints (as :meth:`Motion.height`)."""
    ext = np.nanmax(P, axis=1) - np.nanmin(P, axis=1)
    ext = ext[np.isfinite(ext).all(axis=1)]
    return int(np.argmax(np.median(ext, axis=0))) if len(ext) else 1


def body_frame(motion: Motion, up_axis: int, smooth_s: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame body-centred frame estimated robustly from a (possibly noisy) motion.

    Origin: the root joint's track (joint with parent -1; the centroid of the observed
    joints if the root is never observed), gaps filled linearly, then a running median
    and a Gaussian of ``smooth_s`` seconds. Heading: rotation about ``up_axis`` aligning
    the body's lateral direction -- centroid of the left-leg joints minus centroid of the
    right-leg joints (by joint name, :meth:`Skeleton.body_parts`), projected on the
    horizontal plane -- with the first horizontal axis; the angle is unwrapped and
    smoothed the same way. Without both legs the heading is 0 (translation only).
    Smoothing the frame keeps spikes and noise out of it (METHODS.md Sec. 1).

    Returns origin (T, 3) cm and R (T, 3, 3) with ``world = R @ body + origin``.
    """
    P = np.array(motion.positions)
    obs = motion.observed
    T, J, _ = P.shape
    fps = motion.fps
    roots = np.flatnonzero(motion.skeleton.parents < 0)
    r = int(roots[0])
    if obs[:, r].any():
        O = signal.fill_gaps(P[:, r], np.repeat(obs[:, r:r + 1], 3, axis=1), kind="linear")
    else:
        w = obs[:, :, None].astype(float)
        with np.errstate(invalid="ignore", divide="ignore"):
            C = np.nansum(np.where(obs[:, :, None], P, 0.0), axis=1) / w.sum(axis=1)
        O = signal.fill_gaps(C, np.isfinite(C), kind="linear")
    O = _smooth_track(O, fps, smooth_s)
    a, b = (up_axis + 1) % 3, (up_axis + 2) % 3
    parts = motion.skeleton.body_parts()
    left = [j for j in parts.get("left_leg", []) if j not in parts.get("right_leg", [])]
    right = [j for j in parts.get("right_leg", []) if j not in parts.get("left_leg", [])]
    theta = np.zeros(T)
    if left and right:
        def centroid(js):
            w = obs[:, js].astype(float)
            s = np.where(obs[:, js, None], P[:, js], 0.0).sum(axis=1)
            n = w.sum(axis=1)[:, None]
            with np.errstate(invalid="ignore", divide="ignore"):
                return s / n
        L = centroid(left) - centroid(right)
        ok = np.isfinite(L).all(axis=1) & (np.hypot(L[:, a], L[:, b]) > 1e-6)
        if ok.any():
            th = np.full(T, np.nan)
            th[ok] = np.unwrap(np.arctan2(L[ok, b], L[ok, a]))
            th = signal.fill_gaps(th[:, None], ok[:, None], kind="linear")
            theta = _smooth_track(th, fps, smooth_s)[:, 0]
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros((T, 3, 3))
    R[:, up_axis, up_axis] = 1.0
    R[:, a, a] = c
    R[:, b, a] = s
    R[:, a, b] = -s
    R[:, b, b] = c
    return O, R


def to_body(P: np.ndarray, origin: np.ndarray, R: np.ndarray) -> np.ndarray:
    """World positions (T, J, 3) -> body frame: ``Rᵀ (p - origin)`` (NaN stays NaN)."""
    return np.einsum("tji,tkj->tki", R, P - origin[:, None, :])


def from_body(Z: np.ndarray, origin: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Body frame (T, J, 3) -> world: ``R z + origin``."""
    return np.einsum("tij,tkj->tki", R, Z) + origin[:, None, :]


# ---------------------------------------------------------------------------------------
@register
class KalmanLearned(Denoiser):
    """Data-driven Kalman filter (Lou & Chai 2010, seed 001, Sec. 6.2: "learns the system
    matrices from the same set of training data"), with an RTS smoother.

    Representation (decisions): each frame's joint positions are expressed in a
    body-centred frame (:func:`body_frame`: smoothed root as origin, smoothed heading
    from the hips rotated out; ``frame='global'`` skips this) and flattened to z (3J).
    PCA on the training frames gives mean mu and an orthonormal basis U (3J x k), k
    keeping ``energy`` of the variance (default 99%; or ``n_components``), so the
    dynamics stay well-conditioned; latent s = Uᵀ (z - mu).

    Dynamics (least squares over consecutive training frames, ridge ``ridge`` relative
    to the mean Gram diagonal): order 1 (default, as the paper) ``s[t+1] = A s[t] + b + w``;
    order 2 ``s[t+1] = A1 s[t] + A2 s[t-1] + b + w`` (state [s[t], s[t-1]]). Process noise
    Q = covariance of the least-squares residuals w.

    Observation: ``z = mu + U s + e + v`` with e ~ N(0, diag(D)) the per-coordinate
    out-of-subspace residual variance measured on the training frames and v ~ N(0, r I)
    the measurement noise (r = ``measurement_sigma_cm``², estimated from the clip by
    default). Missing coordinates drop their rows of the observation matrix. After RTS
    smoothing of s, observed coordinates get the posterior mean of e added,
    ``D / (D + r) * (y - mu - U s)``, so content outside the PCA subspace is not lost
    on clean data; missing ones get ``mu + U s``. Cost per frame O(k³) (k x k inverses).

    A joint never observed in the clip is filled from the others through the learned
    latent model. The clip must have the training frame rate and skeleton.

    Fitted attributes: ``mean_`` (3J,), ``components_`` (3J, k), ``A_`` (k, order*k),
    ``b_`` (k,), ``Q_`` (k, k), ``resid_var_`` (3J,), ``state_mean_`` (k,),
    ``state_cov_`` (k, k), ``fps_``, ``up_axis_``, ``joint_names_``.
    """

    name = "kalman-learned"
    description = "Kalman + RTS with linear dynamics learned from training clips (Lou & Chai baseline; PCA latent, body frame)"
    needs_training = True
    keeps_observed = False

    def __init__(self, energy: float = 0.99, n_components: int | None = None, order: int = 1,
                 frame: str = "body", measurement_sigma_cm: float | None = None,
                 ridge: float = 1e-6, smooth_s: float = 0.1):
        self.energy = energy
        self.n_components = n_components
        self.order = order
        self.frame = frame
        self.measurement_sigma_cm = measurement_sigma_cm
        self.ridge = ridge
        self.smooth_s = smooth_s

    @classmethod
    def quick_params(cls) -> dict[str, Any]:
        return {}

    # -- coordinates ------------------------------------------------------------------
    def _frame(self, motion: Motion, up_axis: int):
        if self.frame == "global":
            T = motion.n_frames
            return np.zeros((T, 3)), np.broadcast_to(np.eye(3), (T, 3, 3))
        if self.frame != "body":
            raise MocapValueError(f"kalman-learned: frame must be 'body' or 'global', got {self.frame!r}")
        return body_frame(motion, up_axis, self.smooth_s)

    # -- training -----------------------------------------------------------------------
    def fit(self, motions: Sequence[Motion]) -> "KalmanLearned":
        motions = list(motions)
        training_matrices(motions)                      # validates: non-empty, complete
        if self.order not in (1, 2):
            raise MocapValueError(f"kalman-learned: order must be 1 or 2, got {self.order!r}")
        first = motions[0]
        for m in motions[1:]:
            if m.skeleton.names != first.skeleton.names:
                raise MocapValueError("kalman-learned: training motions must share one skeleton (joint names)")
            if not np.isclose(m.fps, first.fps):
                raise MocapValueError(
                    f"kalman-learned: training motions must share one frame rate "
                    f"({first.fps:g} vs {m.fps:g} fps); resample them first")
        up = up_axis_of(np.concatenate([m.positions for m in motions]))
        Zs = []
        for m in motions:
            O, R = self._frame(m, up)
            Zs.append(to_body(m.positions, O, R).reshape(m.n_frames, -1))
        Zall = np.concatenate(Zs)
        D = Zall.shape[1]
        mu = Zall.mean(axis=0)
        C = np.cov(Zall - mu, rowvar=False, bias=True).reshape(D, D)
        evals, evecs = np.linalg.eigh(C)
        evals, evecs = np.clip(evals[::-1], 0, None), evecs[:, ::-1]
        if self.n_components is not None:
            k = int(self.n_components)
            if not 1 <= k <= D:
                raise MocapValueError(f"kalman-learned: n_components must be in 1..{D}, got {self.n_components!r}")
        else:
            e = float(self.energy)
            if not 0 < e <= 1:
                raise MocapValueError(f"kalman-learned: energy must be in (0, 1], got {self.energy!r}")
            tot = evals.sum()
            if tot <= 0:
                k = 1
            elif e >= 1:
                k = int(max(1, (evals > tot * 1e-12).sum()))
            else:
                k = int(np.searchsorted(np.cumsum(evals) / tot, e) + 1)
            k = min(k, D)
        U = evecs[:, :k]
        order = int(self.order)
        Xin, Yout = [], []
        for Z in Zs:
            S = (Z - mu) @ U
            if len(S) <= order:
                continue
            lagged = [S[order - 1 - i:len(S) - 1 - i] for i in range(order)]   # s[t], s[t-1], ...
            Xin.append(np.hstack(lagged + [np.ones((len(S) - order, 1))]))
            Yout.append(S[order:])
        if not Xin:
            raise MocapValueError(f"kalman-learned: training clips need more than {order} frames")
        Xin, Yout = np.concatenate(Xin), np.concatenate(Yout)
        G = Xin.T @ Xin
        lam = float(self.ridge) * float(np.mean(np.diag(G)[:-1])) if k else 0.0
        reg = lam * np.eye(G.shape[0])
        reg[-1, -1] = 0.0                               # do not shrink the offset
        W = np.linalg.solve(G + reg, Xin.T @ Yout)      # (order*k + 1, k)
        A = W[:-1].T                                    # (k, order*k)
        b = W[-1]
        res = Yout - Xin @ W
        Q = res.T @ res / max(1, len(res))
        Q = 0.5 * (Q + Q.T) + 1e-9 * max(float(np.trace(Q)) / k, 1e-12) * np.eye(k)
        resid = Zall - mu - (Zall - mu) @ U @ U.T
        self.mean_ = mu
        self.components_ = U
        self.A_ = A
        self.b_ = b
        self.Q_ = Q
        self.resid_var_ = np.mean(resid ** 2, axis=0)
        S_all = (Zall - mu) @ U
        self.state_mean_ = S_all.mean(axis=0)
        self.state_cov_ = np.atleast_2d(np.cov(S_all, rowvar=False, bias=True)) + 1e-6 * np.eye(k)
        self.fps_ = float(first.fps)
        self.up_axis_ = int(up)
        self.joint_names_ = list(first.skeleton.names)
        return self

    def full_dynamics(self) -> tuple[np.ndarray, np.ndarray]:
        """Order-1 dynamics in the (body-frame or global) coordinate space:
        ``z[t+1] ≈ A z[t] + c`` with ``A = U A_ Uᵀ`` (3J x 3J) and
        ``c = mu - A mu + U b_``."""
        self._check_fitted()
        if self.A_.shape[1] != self.A_.shape[0]:
            raise MocapValueError("full_dynamics() is defined for order-1 models")
        U, mu = self.components_, self.mean_
        A = U @ self.A_ @ U.T
        return A, mu - A @ mu + U @ self.b_

    # -- denoising ------------------------------------------------------------------------
    def denoise(self, motion: Motion) -> Motion:
        self._check_fitted()
        if list(motion.skeleton.names) != list(self.joint_names_):
            raise MocapValueError(
                f"kalman-learned: the model was trained on a {len(self.joint_names_)}-joint skeleton "
                f"({', '.join(self.joint_names_[:4])}, ...); this motion has {motion.n_joints} joints "
                f"({', '.join(motion.skeleton.names[:4])}, ...)")
        if not np.isclose(motion.fps, float(self.fps_), rtol=1e-6):
            raise MocapValueError(
                f"kalman-learned: the model was trained at {float(self.fps_):g} fps but the clip is at "
                f"{motion.fps:g} fps; resample it (Motion.resample) or retrain")
        if not motion.observed.any():
            raise MocapValueError("kalman-learned: the clip has no observed joint at all")
        T, J = motion.observed.shape
        X, M = motion.matrix(), motion.matrix_mask()
        sigma = _noise_sigma(X, M, self.measurement_sigma_cm)
        O, R = self._frame(motion, int(self.up_axis_))
        Z = to_body(motion.positions, O, R).reshape(T, -1)
        mu, U = np.asarray(self.mean_), np.asarray(self.components_)
        k = U.shape[1]
        order = self.A_.shape[1] // k
        n = order * k
        F = np.zeros((n, n))
        F[:k] = self.A_
        if order > 1:
            F[k:, :-k] = np.eye(n - k)
        Qf = np.zeros((n, n))
        Qf[:k, :k] = self.Q_
        if order > 1:                                   # keep the lag block invertible
            Qf[k:, k:] = 1e-9 * max(float(np.trace(self.Q_)) / k, 1e-12) * np.eye(n - k)
        bf = np.zeros(n)
        bf[:k] = self.b_
        H = np.zeros((U.shape[0], n))
        H[:, :k] = U
        Rdiag = sigma ** 2 + np.asarray(self.resid_var_)
        x0 = np.tile(self.state_mean_, order)
        P0 = np.kron(np.eye(order), self.state_cov_)
        xs, _ = signal.rts_smoother((Z - mu)[:, None, :], M[:, None, :], F=F, Q=Qf,
                                    R=Rdiag[None, :], H=H, b=bf, x0=x0[None], P0=P0[None])
        Zhat = mu + xs[:, 0, :k] @ U.T
        gain = np.asarray(self.resid_var_) / Rdiag
        with np.errstate(invalid="ignore"):
            Zhat = np.where(M, Zhat + gain * (Z - Zhat), Zhat)
        P = from_body(Zhat.reshape(T, J, 3), O, R)
        return motion.with_positions(P)
