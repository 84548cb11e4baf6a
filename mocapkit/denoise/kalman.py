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
channels vectorised).  Every method runs with one BLAS thread: its matrices are small
(<= 3J), and on 2 busy cores OpenBLAS's spinning threads made a 1.6 s kalman-learned
solve take 55 s (measured on a 39-marker C3D).

Noise levels (documented decisions; every one is a parameter)
--------------------------------------------------------------
* measurement noise sigma (cm): by default estimated from the clip as the median over
  channels of ``1.4826 MAD(Δ²y) / √6`` (:func:`mocapkit.signal.estimate_noise`),
  floored at 0.01 cm. At 30-120 fps human motion contributes little to second
  differences, so this tracks the actual noise level (2 cm noise -> ~2 cm), and the
  MAD ignores a minority of spikes.
* process noise (kalman-cv, kalman-identity): by default chosen per channel by maximum
  (Huber-robustified) innovation likelihood over a grid of smoother bandwidths
  (:func:`mocapkit.signal.select_process_noise`; one batched forward pass over all
  channels x 10 candidate values). The process noise q and the smoother's -6 dB cutoff
  f_c are equivalent (:func:`mocapkit.signal.cutoff_to_q`: q = r dt (2 pi f_c)^(2 order)),
  so ``cutoff_hz`` can be given instead.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .. import signal
from ..errors import MocapValueError
from ..frames import MARKER_ORIGIN, Frame, check_marker_origin, heading_frame, up_axis_of
from ..motion import Motion
from ..solvers import _linalg
from ..solvers.evidence import evidence_blend
from .base import Denoiser, check_trained_joints, register, training_matrices
from .constraints import Integral, Interval, Options, Real
from .filters import require_observed_joints

__all__ = ["KalmanCV", "KalmanIdentity", "KalmanLearned"]

_POSITIVE = Interval(Real, 0, None, closed="neither")

_MIN_NOISE_CM = 0.01


def _noise_sigma(X: np.ndarray, M: np.ndarray, given) -> float:
    """Measurement sigma in cm: ``given`` (> 0, checked by the method's constraints) or the
    pooled robust estimate (module doc)."""
    if given is not None:
        return float(given)
    return max(signal.estimate_noise(X, M, pool="median", fallback=1.0), _MIN_NOISE_CM)


def _process_noise(method: str, X, M, dt: float, sigma: float, order: int,
                   process_noise, cutoff_hz):
    """q (scalar or per channel) from an explicit value (> 0, and not with ``cutoff_hz``:
    the method's constraints), a cutoff, or robust ML."""
    if process_noise is not None:
        return float(process_noise)
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
    gate_max_run : a marker rejected this many frames in a row is accepted on the next
        frame (default 3), so the filter re-acquires a marker after a real sudden
        movement instead of losing it for the rest of the clip.

    The initial state is the first observed value with zero velocity and a vague prior
    (100 cm, 1000 cm/s). Missing frames skip the update. A joint never observed raises
    MocapValueError.
    """

    name = "kalman-cv"
    description = "constant-velocity Kalman filter + RTS smoother per coordinate (noise levels estimated)"
    needs_training = False
    keeps_observed = False

    # order 2: constant velocity, 3: constant acceleration
    _parameter_constraints = {"order": [Options(2, 3)], "measurement_sigma_cm": [_POSITIVE, None],
                              "process_noise": [_POSITIVE, None], "cutoff_hz": [_POSITIVE, None],
                              "gate": [_POSITIVE, None], "gate_max_run": [Interval(Integral, 0, None)]}

    def _check_combination(self) -> None:
        if self.process_noise is not None and self.cutoff_hz is not None:
            raise MocapValueError(f"{self.name}: give process_noise or cutoff_hz, not both")

    def __init__(self, order: int = 2, measurement_sigma_cm: float | None = None,
                 process_noise: float | None = None, cutoff_hz: float | None = None,
                 gate: float | None = None, gate_max_run: int = 3):
        self._store_params(locals())

    @_linalg.one_blas_thread
    def denoise(self, motion: Motion) -> Motion:
        require_observed_joints(motion, self.name)
        X, M = motion.matrix(copy=False), motion.matrix_mask()      # read only: no copy
        T, C = X.shape
        dt = 1.0 / motion.fps
        sigma = _noise_sigma(X, M, self.measurement_sigma_cm)
        q = _process_noise(self.name, X, M, dt, sigma, self.order, self.process_noise, self.cutoff_hz)
        F, Q = signal.cv_model(dt, q, order=self.order)
        n = self.order
        x0 = np.zeros((C, n))
        x0[:, 0] = _first_values(X, M)
        P0 = np.diag([1e4, 1e6, 1e8][:n])
        xs, used = signal.rts_smoother(X, M, F=F, Q=Q, R=sigma ** 2, x0=x0, P0=P0,
                                       gate=self.gate, gate_groups=np.arange(C) // 3,
                                       gate_max_run=self.gate_max_run)
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

    _parameter_constraints = {"process_sigma_cm": [_POSITIVE, None], "cutoff_hz": [_POSITIVE, None],
                              "measurement_sigma_cm": [_POSITIVE, None]}

    def __init__(self, process_sigma_cm: float | None = None, cutoff_hz: float | None = None,
                 measurement_sigma_cm: float | None = None):
        self._store_params(locals())

    @_linalg.one_blas_thread
    def denoise(self, motion: Motion) -> Motion:
        require_observed_joints(motion, self.name)
        X, M = motion.matrix(copy=False), motion.matrix_mask()      # read only: no copy
        sigma = _noise_sigma(X, M, self.measurement_sigma_cm)
        dt = 1.0 / motion.fps
        if self.process_sigma_cm is not None:
            s = float(self.process_sigma_cm)
            q = s * s
        else:   # continuous density (cm²/s) -> per-frame variance
            q = _process_noise(self.name, X, M, dt, sigma, 1, None, self.cutoff_hz) * dt
        F, Q = signal.random_walk_model(q)
        x0 = _first_values(X, M)[:, None]
        xs, _ = signal.rts_smoother(X, M, F=F, Q=Q, R=sigma ** 2, x0=x0, P0=np.array([[1e4]]))
        return motion.with_matrix(xs[:, :, 0])


# ---------------------------------------------------------------------------------------
@register
class KalmanLearned(Denoiser):
    """Data-driven Kalman filter (Lou & Chai 2010, seed 001, Sec. 6.2: a Kalman filter
    "which learns the system matrices from the same set of training data"), with an RTS
    smoother.

    Representation (decisions): each frame's joint positions are expressed in the
    body-centred frame of :func:`mocapkit.frames.heading_frame` (smoothed root as origin, smoothed
    heading rotated out, time scale ``smooth_s``; ``frame='global'`` keeps world
    coordinates) and flattened to z (3J). PCA on the training frames gives the mean mu
    and an orthonormal basis U (3J x k); latent s = Uᵀ (z - mu). ``energy`` (default 1.0)
    keeps the k leading components holding that fraction of the variance; 1.0 keeps the
    numerical rank (drops only directions with no training variance, e.g. CMU joints
    that coincide), ``n_components`` sets k directly. Decision: default 1.0, not 0.99 --
    a basis learned on other clips misses part of a new clip's poses, and what it
    misses is lost (measured on 07_05 and 135_04, 2 cm noise, order 1: 0.999 energy
    (k = 34) 0.98 / 0.74 cm RMSE at 30 / 120 fps, full rank (k = 87) 0.93 / 0.59 cm);
    the ridge below keeps the full-rank fit well-conditioned.

    Dynamics, fitted by ridge least squares over consecutive training frames:
    order 1 (default, as the paper) ``s[t+1] = A s[t] + b + w``; order 2
    ``s[t+1] = A1 s[t] + A2 s[t-1] + b + w`` (state [s[t], s[t-1]]). Decision: the ridge
    (strength ``ridge`` x the mean diagonal of the Gram matrix) shrinks the dynamics
    towards the kinematic prior -- identity (order 1) or constant velocity
    A1 = 2I, A2 = -I (order 2) -- not towards zero: the regression is done on the
    differences s[t+1] - s[t] (resp. s[t+1] - 2 s[t] + s[t-1]). At 30-120 fps A is close
    to that prior and an unregularised fit on a few clips generalises worse than the
    prior itself (measured on CMU walks: the one-step prediction error of the order-1
    least-squares A on a held-out walk was 18 x the plain frame-to-frame change).
    Process noise Q = ``q_scale`` x the covariance of the training residuals w
    (``q_scale`` > 1 allows for new clips being less predictable than training ones;
    default 3, chosen on two CMU clips, 07_05 and 135_04, that are in neither the
    benchmark's test nor training set: RMSE at 2 cm noise, order 1, 120 fps 0.71 -> 0.59
    cm, 30 fps 0.96 -> 0.93 cm against q_scale = 1).

    Observation: ``z = mu + U s + e + v`` with e ~ N(0, diag(D)) the per-coordinate
    out-of-subspace variance of the training frames and v ~ N(0, r I) the measurement
    noise (r = ``measurement_sigma_cm``², estimated from the clip by default). Missing
    coordinates drop their rows of the observation matrix. After RTS smoothing of s,
    observed coordinates get the posterior mean of e added,
    ``D / (D + r) * (y - mu - U s)``; missing ones get ``mu + U s``.
    The prior of the first state is the first frame's projection with the steady-state
    prediction covariance (Riccati equation), so on complete frames one set of gains
    serves every frame (cost O(n²) per frame); frames whose missing pattern changes cost
    O(n³) (n x n inverses), n = order x k.

    A joint never observed in the clip is filled from the others through the learned
    latent model (the base class then returns it missing).  In frames with few observed
    markers the fill moves to the linear interpolation in time
    (:func:`mocapkit.solvers.evidence.evidence_blend`; on a 95 %-missing clip the body
    frame is a guess and the fill was 16 cm off where interpolation was 8 cm off). The clip must have the training frame rate and skeleton.

    Fitted attributes: ``mean_`` (3J,), ``components_`` (3J, k), ``A_`` (k, order*k),
    ``b_`` (k,), ``Q_`` (k, k), ``resid_var_`` (3J,), ``state_mean_`` (k,),
    ``state_cov_`` (k, k), ``fps_``, ``up_axis_``, ``joint_names_``.
    """

    name = "kalman-learned"
    fill_evidence = "markers"
    description = "Kalman + RTS with linear dynamics learned from training clips (Lou & Chai baseline; body frame, PCA latent)"
    needs_training = True
    misfit_check = "learned"
    keeps_observed = False

    _parameter_constraints = {"order": [Options(1, 2)], "energy": [Interval(Real, 0, 1, closed="right")],
                              "n_components": [Interval(Integral, 1, None), None],   # <= 3J: in fit
                              "ridge": [Interval(Real, 0, None)], "q_scale": [_POSITIVE],
                              "frame": [Options("body", "global")], "smooth_s": [Interval(Real, 0, None)],
                              "measurement_sigma_cm": [_POSITIVE, None]}

    def __init__(self, order: int = 1, energy: float = 1.0, n_components: int | None = None,
                 ridge: float = 1.0, q_scale: float = 3.0, frame: str = "body",
                 smooth_s: float = 0.5, measurement_sigma_cm: float | None = None):
        self._store_params(locals())

    @classmethod
    def quick_params(cls) -> dict[str, Any]:
        return {}

    # -- coordinates ------------------------------------------------------------------
    def _transform(self, motion: Motion, up_axis: int | None):
        if self.frame == "global":
            return Frame.identity(np.zeros((motion.n_frames, 3)))
        return heading_frame(motion, smooth_s=self.smooth_s, up_axis=up_axis)

    # -- training -----------------------------------------------------------------------
    @_linalg.one_blas_thread
    def fit(self, motions: Sequence[Motion]) -> "KalmanLearned":
        motions = list(motions)
        training_matrices(motions)                      # validates: non-empty, complete
        first = motions[0]
        for m in motions[1:]:
            if m.skeleton.names != first.skeleton.names:
                raise MocapValueError("kalman-learned: training motions must share one skeleton (joint names)")
            if not np.isclose(m.fps, first.fps):
                raise MocapValueError(
                    f"kalman-learned: training motions must share one frame rate "
                    f"({first.fps:g} vs {m.fps:g} fps); resample them first")
        up = up_axis_of(np.concatenate([m.positions for m in motions]))
        Zs = [self._transform(m, up).to_local(m.positions).reshape(m.n_frames, -1) for m in motions]
        Zall = np.concatenate(Zs)
        D = Zall.shape[1]
        mu = Zall.mean(axis=0)
        C = np.atleast_2d(np.cov(Zall - mu, rowvar=False, bias=True))
        evals, evecs = _linalg.eigh(C, what="kalman-learned PCA")
        evals, evecs = np.clip(evals[::-1], 0, None), evecs[:, ::-1]
        tot = float(evals.sum())
        if self.n_components is not None:
            k = int(self.n_components)
            if not 1 <= k <= D:
                raise MocapValueError(f"kalman-learned: n_components must be in 1..{D}, got {self.n_components!r}")
        else:
            e = float(self.energy)
            rank = int(max(1, (evals > max(tot, 1e-300) * 1e-10).sum()))
            k = rank if (e >= 1 or tot <= 0) else min(rank, int(np.searchsorted(np.cumsum(evals) / tot, e) + 1))
        U = np.ascontiguousarray(evecs[:, :k])       # contiguous: same BLAS path after load()
        order = int(self.order)
        prior = np.zeros((k, order * k))                # kinematic prior the ridge shrinks to
        if order == 1:
            prior[:, :k] = np.eye(k)
        else:
            prior[:, :k] = 2 * np.eye(k)
            prior[:, k:] = -np.eye(k)
        Xin, Yout = [], []
        for Z in Zs:
            S = (Z - mu) @ U
            if len(S) <= order:
                continue
            lagged = np.hstack([S[order - 1 - i:len(S) - 1 - i] for i in range(order)])   # s[t], s[t-1]
            Xin.append(np.hstack([lagged, np.ones((len(S) - order, 1))]))
            Yout.append(S[order:] - lagged @ prior.T)
        if not Xin:
            raise MocapValueError(f"kalman-learned: training clips need more than {order} frames")
        Xin, Yout = np.concatenate(Xin), np.concatenate(Yout)
        G = Xin.T @ Xin
        lam = float(self.ridge) * float(np.mean(np.diag(G)[:-1]))
        reg = lam * np.eye(G.shape[0])
        reg[-1, -1] = 0.0                               # do not shrink the offset
        W = np.linalg.lstsq(G + reg, Xin.T @ Yout, rcond=None)[0]      # (order*k + 1, k)
        res = Yout - Xin @ W
        Q = res.T @ res / max(1, len(res))
        Q = 0.5 * (Q + Q.T) + 1e-9 * max(float(np.trace(Q)) / k, 1e-12) * np.eye(k)
        resid = (Zall - mu) - (Zall - mu) @ U @ U.T
        S_all = (Zall - mu) @ U
        self.mean_ = mu
        self.components_ = U
        self.A_ = np.ascontiguousarray(prior + W[:-1].T)     # (k, order*k)
        self.b_ = np.ascontiguousarray(W[-1])
        self.Q_ = Q
        self.resid_var_ = np.mean(resid ** 2, axis=0)
        self.state_mean_ = S_all.mean(axis=0)
        self.state_cov_ = np.atleast_2d(np.cov(S_all, rowvar=False, bias=True)) + 1e-6 * np.eye(k)
        self.fps_ = float(first.fps)
        self.up_axis_ = int(up)
        self.joint_names_ = list(first.skeleton.names)
        self.marker_origin_ = MARKER_ORIGIN
        return self

    def _initial_state(self, y0, F, Qf, H, Rdiag, order):
        """Prior of the first state: mean = the first frame projected on the basis
        (``y0``: the first frame minus the training mean, 0 on missing coordinates, i.e.
        missing coordinates at the training mean; zero velocity for order 2);
        covariance = the steady-state prediction covariance of the filter (discrete
        algebraic Riccati equation), so on complete frames the covariance recursion is
        stationary from the start and :func:`mocapkit.signal.rts_smoother` reuses one
        set of gains for every frame (:func:`mocapkit.signal.steady_state_covariance`).
        Falls back to the training state covariance if the doubling iteration does not
        converge."""
        U = np.asarray(self.components_)
        s0 = U.T @ y0
        x0 = np.tile(s0, order)
        try:
            with np.errstate(all="ignore"):
                P0 = signal.steady_state_covariance(F, Qf, H, Rdiag)
            if not (np.isfinite(P0).all() and _linalg.eigvalsh(P0).min() > 0):
                raise np.linalg.LinAlgError("not positive definite")
        except (np.linalg.LinAlgError, ValueError):
            P0 = np.kron(np.eye(order), self.state_cov_)
        return x0, P0

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
    @_linalg.one_blas_thread
    def denoise(self, motion: Motion) -> Motion:
        self._check_fitted()
        check_trained_joints(self, motion)
        if self.frame == "body":
            check_marker_origin(self, motion)
        if not np.isclose(motion.fps, float(self.fps_), rtol=1e-6):
            raise MocapValueError(
                f"kalman-learned: the model was trained at {float(self.fps_):g} fps but the clip is at "
                f"{motion.fps:g} fps; resample it (Motion.resample) or retrain")
        if not motion.observed.any():
            raise MocapValueError("kalman-learned: the clip has no observed joint at all")
        T, J = motion.observed.shape
        X, M = motion.matrix(copy=False), motion.matrix_mask()      # read only: no copy
        sigma = _noise_sigma(X, M, self.measurement_sigma_cm)
        tr = self._transform(motion, int(self.up_axis_))
        mu, U = np.asarray(self.mean_), np.asarray(self.components_)
        # the smoother's observations y - mu (0 where missing), made in place in the new
        # local-coordinate array: the local positions themselves are not kept (one matrix
        # less; below, y - mu - U s stands for y - (mu + U s))
        Yc = tr.to_local(motion.positions).reshape(T, -1)
        Yc -= mu
        Yc[~M] = 0.0
        k = U.shape[1]
        order = self.A_.shape[1] // k
        n = order * k
        F = np.zeros((n, n))
        F[:k] = self.A_
        if order > 1:
            F[k:, :-k] = np.eye(n - k)
        qs = float(self.q_scale)
        Qf = np.zeros((n, n))
        Qf[:k, :k] = qs * np.asarray(self.Q_)
        if order > 1:                                   # keep the lag block invertible
            Qf[k:, k:] = 1e-9 * max(float(np.trace(Qf[:k, :k])) / k, 1e-12) * np.eye(n - k)
        bf = np.zeros(n)
        bf[:k] = self.b_
        H = np.zeros((U.shape[0], n))
        H[:, :k] = U
        Dres = np.asarray(self.resid_var_, dtype=float)
        Rdiag = sigma ** 2 + Dres
        x0, P0 = self._initial_state(Yc[0], F, Qf, H, Rdiag, order)
        xs, _ = signal.rts_smoother(Yc[:, None, :], M[:, None, :], F=F, Q=Qf,
                                    R=Rdiag[None, :], H=H, b=bf, x0=x0[None], P0=P0[None])
        Zhat = xs[:, 0, :k] @ U.T                                   # U s
        del xs
        # observed coordinates get the posterior mean of e, D / (D + r) (y - mu - U s);
        # missing ones mu + U s -- in place, in the two matrices already there
        Yc -= Zhat
        Yc *= Dres / Rdiag
        Yc[~M] = 0.0
        Zhat += mu
        Zhat += Yc
        del Yc
        # to_world's result is new: the Motion keeps it, uncopied
        out = motion.with_positions(tr.to_world(Zhat.reshape(T, J, 3)), handover=True)
        del Zhat
        if not M.all():          # frames with few observed markers: interpolation in time
            from .. import gaps

            out = out.with_matrix(evidence_blend(out.matrix(copy=False), gaps.fill(X, M, never_observed=0.0),
                                                 M, motion.observed), handover=True)
        return out
