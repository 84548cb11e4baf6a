"""Thesis refinement methods (Z. Wang 2017, seed 003, Ch. 3-4) and the DynaMMo baseline.

* ``psc``  -- poselet sparse coding (Ch. 3): per-body-part dictionaries of M-frame windows
  learnt with the masked objective (eqs. 3.7-3.12), recovery by locality-constrained
  linear coding (eqs. 3.15-3.17) after trust-data detection (eq. 3.13).  Data-driven.
* ``tsmc`` -- bilinear low-rank + sparse error + temporal smoothness (Sec. 4.1).
* ``trnn`` -- truncated nuclear norm + sparse error + smoothness (Sec. 4.2).
* ``dynammo`` -- linear dynamical system completion by EM (Li et al. 2009), the classical
  gap filler the thesis compares with (Fig. 3.7, 4.11).

The maths lives in :mod:`mocapkit.solvers.completion` and :mod:`mocapkit.solvers.llc`;
these classes handle Motions, masks and body parts.  Solver diagnostics (iterations,
convergence) go to ``out.source["solver"]`` and, for tsmc / trnn / dynammo, to the
method's ``convergence_`` summary (see :func:`mocapkit.denoise.base.report_convergence`);
a solver that stops before converging also warns once per ``denoise()`` call
(:class:`mocapkit.errors.ConvergenceWarning`, which is here also a RuntimeWarning).

Which entries are refilled: ``tsmc``/``trnn`` take the observed mask (optionally narrowed
by trust-data detection, ``detect=True``) and return the low-rank model everywhere
(``keep_observed=False``, the thesis' output) or only in the holes (``keep_observed=True``);
``psc`` and ``dynammo`` keep observed (trusted) entries and replace only missing or
untrusted ones (METHODS.md Sec. 4 decision).
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..detect import trust_data
from ..errors import MocapValueError
from ..motion import Motion, fill_gaps_linear
from ..skeleton import BODY_PARTS
from ..solvers import completion as _cp
from ..solvers import llc as _llc
from ..solvers.completion import _one_blas_thread
from ..solvers.evidence import evidence_blend, far_from_data
from .base import Denoiser, register, report_convergence

__all__ = ["PSC", "TSMC", "TrNN", "DynaMMo"]


# --------------------------------------------------------------------------------------
# shared helpers
# --------------------------------------------------------------------------------------
def _check_motion(motion: Any, method: str) -> Motion:
    if not isinstance(motion, Motion):
        raise MocapValueError(f"{method}: expected a Motion, got {type(motion).__name__}")
    if not motion.observed.any():
        raise MocapValueError(f"{method}: the motion has no observed entries")
    return motion


def _known_mask(motion: Motion, detect: bool, threshold_cm: float) -> np.ndarray:
    """(T, J) samples the method may trust: observed, minus TDD outliers when ``detect``."""
    known = motion.observed.copy()
    if detect:
        known &= ~trust_data(motion, threshold_cm)
        if not known.any():
            known = motion.observed.copy()
    return known


def _never_observed(known: np.ndarray, motion: Motion, method: str) -> None:
    """A joint never observed in the clip: nothing to do here any more.  The base class
    (:func:`mocapkit.denoise.base._prepare`) gives it a placeholder before the method runs
    and the gap policy returns it missing (issue 18: it used to be filled with (0, 0, 0)
    under a RuntimeWarning)."""


def _output(motion: Motion, A: np.ndarray, known: np.ndarray, keep: bool,
            solver: dict[str, Any]) -> Motion:
    """Motion from a (T, 3J) estimate; ``keep``: trusted observed entries unchanged."""
    X = motion.matrix()
    km = np.repeat(known, 3, axis=1)
    if not np.isfinite(A).all():                    # defensive: never return NaN
        lin = fill_gaps_linear(X, km)
        bad = ~np.isfinite(A)
        A[bad] = lin[bad]
    if keep:
        A[km] = X[km]
    out = motion.with_matrix(A)
    return out.with_source(solver=solver)


def _unusable_guard(method: str, A: np.ndarray, X: np.ndarray, km: np.ndarray,
                    lin: np.ndarray, info: dict[str, Any]) -> tuple[np.ndarray, dict[str, Any]]:
    """Replace a stopped-early ALM iterate that is nowhere near the data.

    The thesis' ALM starts with a tiny penalty (eta0 = 1e-5) and its iterates only approach
    the data as the penalty grows: after 1-10 iterations A B^T is ~0, every marker near
    the origin (80 cm RMSE on a CMU walk), which the gap policy cannot catch on measured
    samples.  When the solver did not converge and the estimate is far from the measured
    samples (:func:`mocapkit.solvers.evidence.far_from_data`), the measured samples are
    kept and the gaps linearly interpolated, with a :class:`~mocapkit.errors.MocapWarning`.
    """
    far, resid, spread = far_from_data(A, X, km)
    if far:
        _warn_unusable(method, info["iterations"], resid, spread)
        A = np.where(km, X, lin)
        info = {**info, "fallback": "linear"}
    return A, info


def _warn_unusable(method: str, iterations: int, resid: float, spread: float) -> None:
    import warnings

    from ..errors import MocapWarning

    warnings.warn(f"{method}: stopped after {iterations} iterations far from the data (RMS "
                  f"{resid:.3g} cm from the measured samples, whose spread is {spread:.3g} cm): "
                  f"measured samples kept, gaps interpolated linearly; raise max_iter",
                  MocapWarning, stacklevel=5)


def _record(den: Denoiser, info: dict[str, Any], key: str) -> None:
    """``den.convergence_`` from a solver's info dict (the solver itself already warned)."""
    report_convergence(den, iterations=info["iterations"], converged=info["converged"],
                       residual=info[key], tol=float(den.tol), max_iter=int(den.max_iter),
                       criterion="max relative residual / change" if key == "criterion"
                       else "relative change of the filled values", warn=False)


def _info(name: str, info: dict[str, Any]) -> dict[str, Any]:
    return {"method": name, **{k: (v.item() if isinstance(v, np.generic) else v)
                               for k, v in info.items() if np.isscalar(v)}}


# --------------------------------------------------------------------------------------
# local frame for PSC (thesis Sec. 3.2 = Xiao et al.'s frame, mocapkit.localframe)
# --------------------------------------------------------------------------------------
def _local_frame(motion: Motion, known: np.ndarray | None = None):
    """The thesis' per-pose frame (root at 0, femur/upper-neck plane parallel to XY).

    Estimated by :func:`mocapkit.localframe.estimate_frame` from the trusted samples
    (robustly smoothed tracks, so outliers and gaps do not tilt it).  A skeleton without
    femurs / upper neck gets translation only (root track, gaps bridged linearly).
    """
    from .. import localframe as lf

    known = motion.observed if known is None else known
    P = np.where(known[..., None], motion.positions, np.nan)
    try:
        return lf.estimate_frame(P, motion.skeleton, motion.fps)
    except MocapValueError:
        root = int(np.flatnonzero(motion.skeleton.parents < 0)[0])
        X = fill_gaps_linear(P[:, root], np.repeat(known[:, root:root + 1], 3, axis=1))
        return lf.LocalFrame(origin=X, R=np.broadcast_to(np.eye(3), (motion.n_frames, 3, 3)).copy())


def _windows(A: np.ndarray, M: int) -> np.ndarray:
    """(T, ...) -> (T - M + 1, M * prod(...)) lagged windows, stride 1 (thesis Sec. 3.2)."""
    W = np.lib.stride_tricks.sliding_window_view(A, M, axis=0)      # (N, ..., M)
    W = np.moveaxis(W, -1, 1)                                        # (N, M, ...)
    return W.reshape(W.shape[0], -1)


def _kmeans(Y: np.ndarray, K: int, rng: np.random.Generator, n_iter: int = 5) -> np.ndarray:
    """Plain Lloyd k-means (k-means++-lite seeding: random distinct samples)."""
    N = len(Y)
    D = Y[rng.choice(N, size=K, replace=False)].copy()
    for _ in range(n_iter):
        lab = np.argmin(_llc.masked_sq_distances(Y, D), axis=1)
        cnt = np.bincount(lab, minlength=K)
        S = np.zeros_like(D)
        np.add.at(S, lab, Y)
        ok = cnt > 0
        D[ok] = S[ok] / cnt[ok, None]
        if (~ok).any():                              # re-seed empty clusters
            D[~ok] = Y[rng.choice(N, size=int((~ok).sum()), replace=False)]
    return D


def _sample_masks(N: int, M: int, nj: int, ratio: tuple[float, float],
                  rng: np.random.Generator) -> np.ndarray:
    """Training masks (N, M * nj * 3), True = observed: half random cells, half whole joints."""
    lo, hi = ratio
    r = rng.uniform(lo, hi, size=(N, 1, 1))
    cells = rng.random((N, M, nj)) >= r
    joint = rng.random((N, 1, nj)) >= r
    use_joint = rng.random((N, 1, 1)) < 0.5
    obs = np.where(use_joint, np.broadcast_to(joint, (N, M, nj)), cells)
    none = ~obs.reshape(N, -1).any(axis=1)           # keep at least one observed cell
    if none.any():
        obs[none, 0, 0] = True
    return np.repeat(obs[..., None], 3, axis=3).reshape(N, -1)


# --------------------------------------------------------------------------------------
# PSC (Ch. 3)
# --------------------------------------------------------------------------------------
@register
class PSC(Denoiser):
    """Poselet sparse coding with LLC recovery (thesis Ch. 3; Wang et al. 2016/2017).

    Training (Sec. 3.2-3.3): every clean training motion goes to the thesis' local frame
    (root at the origin, femur/upper-neck plane parallel to XY; :mod:`mocapkit.localframe`,
    estimated from robustly smoothed tracks), is split into the five body parts of
    :meth:`Skeleton.body_parts` (torso, arms, legs; shared joints in several parts) and cut
    into overlapping M-frame windows (stride 1), one vector of ``3 * joints * M`` per
    window.  One dictionary per part is learnt with the masked objective of eqs. 3.7-3.10:
    missing masks are sampled for every window (augmentation: random joint-frame cells or
    whole joints, ratio drawn from ``train_missing``), codes are computed from the observed
    entries only, and the dictionary is updated to predict the *missing* entries
    (projected gradient on eq. 3.10, a few steps per outer iteration); the outer loop stops
    on the relative changes of eq. 3.12 (``tol``) or after ``n_iter`` iterations.

    Recovery (Sec. 3.4, Algorithm 1): trust-data detection (6 cm, :mod:`mocapkit.detect`)
    marks untrusted samples, which join the missing ones; each window is coded by LLC on
    its observed entries (eqs. 3.15-3.17: closed form on the ``n_neighbors`` nearest atoms,
    Wang et al.'s approximated LLC) and reconstructed in full; overlapping windows are
    averaged, shared joints averaged over parts, and the result is put back in the global
    frame.  Observed trusted entries are returned unchanged.

    Decisions (the thesis is silent or its choice does not fit LLC):

    * training codes use the same LLC coder as recovery instead of the l1 (lasso) coder of
      eq. 3.11, so the dictionary is trained for the coder that uses it;
    * atoms are not normalised to unit length: LLC codes sum to one (affine combinations
      of atoms), so atoms live in data space (cm); they start from k-means of the training
      windows (as LLC codebooks do);
    * the thesis' K = 1024 (``n_atoms``) is the default; it is capped at the number of
      training windows (``max_windows`` windows per part are sampled, default 3000) and
      ``n_iter`` = 5 outer iterations (the thesis: about 30, Sec. 3.3), so training takes
      seconds to a minute on one CPU core -- the CPU-friendly defaults; the missing-entry
      training error barely moves after the k-means start in our runs;
    * frames whose every window has a part fully missing fall back to linear interpolation
      in the local frame.

    Parameters
    ----------
    window : M, frames per window (thesis: 10).
    n_atoms : K atoms per part (thesis: 1024).
    lam : LLC locality weight lambda (thesis: 10).
    n_neighbors : atoms per LLC code (Wang et al.: 5).
    sigma : locality-adaptor scale (None = per-window mean distance).
    threshold_cm : TDD threshold (thesis: 6 cm); ``detect=False`` skips detection.
    n_iter, dict_steps, tol : outer training iterations, gradient steps per iteration,
        eq.-3.12 tolerance.
    train_missing : (low, high) missing ratio of the sampled training masks.
    max_windows : training windows per part (random subset); seed : randomness.
    refine : our extension (default on; False = the thesis): the coding residual of the
        known samples is linearly interpolated across each hole and added to the
        reconstruction, so filled samples join the observed ones continuously and keep the
        local offset the dictionary cannot represent (measured in docs/results/thesis.md).
    """

    name = "psc"
    fill_evidence = "markers"
    description = "thesis PSC: per-body-part window dictionaries trained to predict missing markers, LLC recovery"
    needs_training = True
    keeps_observed = True
    clean_tolerance_cm = 1.0

    def __init__(self, window: int = 10, n_atoms: int = 1024, lam: float = 10.0,
                 n_neighbors: int = 5, sigma: float | None = None, threshold_cm: float = 6.0,
                 detect: bool = True, n_iter: int = 5, dict_steps: int = 3,
                 tol: float = 1e-3, train_missing: tuple[float, float] = (0.1, 0.6),
                 max_windows: int = 3000, refine: bool = True, seed: int = 0):
        self.refine = refine
        self.window = window
        self.n_atoms = n_atoms
        self.lam = lam
        self.n_neighbors = n_neighbors
        self.sigma = sigma
        self.threshold_cm = threshold_cm
        self.detect = detect
        self.n_iter = n_iter
        self.dict_steps = dict_steps
        self.tol = tol
        self.train_missing = train_missing
        self.max_windows = max_windows
        self.seed = seed

    @classmethod
    def quick_params(cls) -> dict[str, Any]:
        return {"n_atoms": 64, "n_iter": 2, "max_windows": 600}

    # -- validation -------------------------------------------------------------------------
    def _check_params(self) -> tuple[int, int]:
        M, K = int(self.window), int(self.n_atoms)
        if M < 1 or K < 2:
            raise MocapValueError(f"psc needs window >= 1 and n_atoms >= 2, got {M}, {K}")
        lo, hi = self.train_missing
        if not (0 <= lo <= hi < 1):
            raise MocapValueError(f"train_missing must be 0 <= low <= high < 1, got {self.train_missing}")
        return M, K

    def _parts(self, skeleton) -> list[tuple[str, np.ndarray]]:
        parts = skeleton.body_parts()
        out = [(p, np.asarray(parts[p], dtype=np.int64)) for p in BODY_PARTS if parts.get(p)]
        if not out:
            out = [("all", np.arange(skeleton.n_joints))]
        return out

    # -- training ---------------------------------------------------------------------------
    @_one_blas_thread
    def fit(self, motions: Sequence[Motion]) -> "PSC":
        """Learn one dictionary per body part from clean motions (same skeleton)."""
        M, K = self._check_params()
        motions = list(motions)
        if not motions:
            raise MocapValueError("psc.fit() needs at least one training motion")
        sk = motions[0].skeleton
        for m in motions:
            if not isinstance(m, Motion):
                raise MocapValueError(f"psc.fit() expects Motions, got {type(m).__name__}")
            if m.skeleton.names != sk.names:
                raise MocapValueError("psc.fit(): all training motions need the same joints")
            if not m.observed.all():
                raise MocapValueError(f"training motion {m!r} has missing entries; fill them first")
        from .. import localframe as lf

        locs = []
        for m in motions:
            if m.n_frames < M:
                continue
            locs.append(lf.to_local(m.positions, _local_frame(m)))
        if not locs:
            raise MocapValueError(f"psc.fit(): every training motion is shorter than window={M}")
        rng = np.random.default_rng(self.seed)
        parts = self._parts(sk)
        dicts, hist = [], []
        for _, idx in parts:
            Y = np.concatenate([_windows(L[:, idx], M) for L in locs])
            if len(Y) > int(self.max_windows):
                Y = Y[rng.choice(len(Y), size=int(self.max_windows), replace=False)]
            D, h = self._train_part(Y, M, len(idx), min(K, len(Y)), rng)
            dicts.append(D)
            hist.append(h)
        self.dictionaries_ = dicts
        self.parts_ = [idx for _, idx in parts]
        self.part_names_ = [p for p, _ in parts]
        self.joint_names_ = list(sk.names)
        self.train_iterations_ = [int(len(h)) for h in hist]
        self.train_error_ = [float(h[-1]) if len(h) else float("nan") for h in hist]
        return self

    def _train_part(self, Y: np.ndarray, M: int, nj: int, K: int, rng: np.random.Generator
                    ) -> tuple[np.ndarray, list[float]]:
        """Masked dictionary learning for one part (eqs. 3.9-3.12); returns D (K, d)."""
        D = _kmeans(Y, K, rng)
        lo, hi = self.train_missing
        k = int(min(self.n_neighbors, K))
        hist: list[float] = []
        prev_pred = None
        best, best_err = D.copy(), np.inf
        for it in range(int(self.n_iter)):
            obs = _sample_masks(len(Y), M, nj, (lo, hi), rng)
            codes, idx = _llc.llc_code(Y, D, obs, lam=float(self.lam), sigma=self.sigma,
                                       n_neighbors=k)
            miss = ~obs
            # sparse code matrix W (N, K) for the dictionary gradient
            from scipy import sparse

            N = len(Y)
            W = sparse.csr_matrix((codes.ravel(), idx.ravel(), np.arange(0, N * k + 1, k)),
                                  shape=(N, K))
            Lw = _sparse_norm2(W) ** 2
            pred = np.asarray(W @ D)
            err = np.linalg.norm((Y - pred)[miss]) / max(np.linalg.norm(Y[miss]), 1e-300)
            if err < best_err:
                best, best_err = D.copy(), err
            change = (np.linalg.norm((pred - prev_pred)[miss]) / max(np.linalg.norm(pred[miss]), 1e-300)
                      if prev_pred is not None else np.inf)
            hist.append(float(err))
            if err <= self.tol or change <= self.tol:
                break
            for _ in range(int(self.dict_steps)):          # eq. 3.10: predict missing entries
                R = np.where(miss, Y - np.asarray(W @ D), 0.0)
                D = D + (W.T @ R) / max(Lw, 1e-12)
            prev_pred = np.asarray(W @ D)
        # final check of the last update against a fresh mask
        obs = _sample_masks(len(Y), M, nj, (lo, hi), rng)
        codes, idx = _llc.llc_code(Y, D, obs, lam=float(self.lam), sigma=self.sigma, n_neighbors=k)
        pred = _llc.llc_reconstruct(codes, idx, D)
        err = np.linalg.norm((Y - pred)[~obs]) / max(np.linalg.norm(Y[~obs]), 1e-300)
        hist.append(float(err))
        if err < best_err:
            best = D
        return best, hist

    # -- recovery ---------------------------------------------------------------------------
    @_one_blas_thread
    def denoise(self, motion: Motion) -> Motion:
        self._check_fitted()
        motion = _check_motion(motion, self.name)
        M, _ = self._check_params()
        if list(motion.skeleton.names) != list(self.joint_names_):
            raise MocapValueError(
                f"psc: the model was trained on joints {', '.join(self.joint_names_[:5])}...; "
                f"this motion has {', '.join(motion.skeleton.names[:5])}... (train on this skeleton)")
        T = motion.n_frames
        if T < M:
            raise MocapValueError(f"psc: the clip has {T} frames, fewer than the window ({M})")
        known = _known_mask(motion, bool(self.detect), float(self.threshold_cm))
        _never_observed(known, motion, self.name)
        from .. import localframe as lf

        frame = _local_frame(motion, known)
        P = np.where(known[..., None], motion.positions, 0.0)
        L = lf.to_local(P, frame)
        L_lin = lf.to_local(fill_gaps_linear(motion.matrix(), np.repeat(known, 3, axis=1)
                                             ).reshape(P.shape), frame)
        acc = np.zeros_like(L)
        cnt = np.zeros(L.shape[:2])
        k = int(self.n_neighbors)
        for idx, D in zip(self.parts_, self.dictionaries_):
            idx = np.asarray(idx, dtype=np.int64)
            nj = len(idx)
            Y = _windows(L[:, idx], M)
            obs = _windows(np.repeat(known[:, idx, None], 3, axis=2), M)
            valid = obs.any(axis=1)
            if not valid.any():
                continue
            codes, aidx = _llc.llc_code(Y[valid], D, obs[valid], lam=float(self.lam),
                                        sigma=self.sigma, n_neighbors=min(k, len(D)))
            R = np.zeros_like(Y)
            R[valid] = _llc.llc_reconstruct(codes, aidx, D)
            R = R.reshape(len(Y), M, nj, 3)
            N = len(Y)
            part_acc = np.zeros((T, nj, 3))
            part_cnt = np.zeros(T)
            for f in range(M):                             # loop over window offsets, not frames
                part_acc[f:f + N] += R[:, f] * valid[:, None, None]
                part_cnt[f:f + N] += valid
            acc[:, idx] += part_acc
            cnt[:, idx] += part_cnt[:, None]
        est = np.where(cnt[..., None] > 0, acc / np.maximum(cnt, 1)[..., None], L_lin)
        if self.refine:
            # our extension: interpolate the coding residual of the known samples across
            # the holes, so filled samples meet the observed ones without a jump
            km = np.repeat(known, 3, axis=1)
            res = np.where(km, (L - est).reshape(T, -1), np.nan)
            est = est + fill_gaps_linear(res, km).reshape(est.shape)
        G = lf.to_global(est, frame)
        out = np.where(known[..., None], motion.positions, G)
        res = motion.with_positions(out)
        return res.with_source(solver={"method": self.name, "window": M,
                                       "untrusted": int((motion.observed & ~known).sum()),
                                       "filled": int((~known).sum())})


def _sparse_norm2(W) -> float:
    """Largest singular value of a sparse matrix (a few power iterations, upper-biased)."""
    rng = np.random.default_rng(0)
    v = rng.standard_normal(W.shape[1])
    v /= np.linalg.norm(v)
    s = 0.0
    for _ in range(30):
        u = W @ v
        v = W.T @ u
        s_new = np.linalg.norm(v)
        if s_new == 0:
            return 0.0
        v /= s_new
        if abs(s_new - s) <= 1e-6 * s_new:
            s = s_new
            break
        s = s_new
    return float(np.sqrt(s) * 1.01)


# --------------------------------------------------------------------------------------
# low-rank completion (Ch. 4)
# --------------------------------------------------------------------------------------
CMU_UNIT_CM = 5.6444
"""1 CMU ASF length unit in cm ((1/0.45) inch)."""


class _MatrixCompletion(Denoiser):
    """Shared Motion handling of tsmc / trnn: (T, 3J) matrix + mask in, estimate out.

    The thesis' weights (beta, mu: squared second differences; alpha, lam: l1 of the
    error) are not scale-free and the thesis does not state its unit.  Decision: they are
    read in CMU ASF length units (the unit of the CMU ASF/AMC data the thesis uses;
    1 unit = 5.6444 cm): the (T, 3J) matrix is divided by ``unit_cm`` before solving and the
    result multiplied back.  Measured on CMU 05_06 and 02_01 (not protocol clips), this
    beats reading them in cm or in metres in most missing-data conditions
    (docs/results/thesis.md).  The conversion is a scale only, so it commutes with the
    base class's recentring (translation equivariance is the base class's job).

    Missing entries of frames with few observed markers move to the linear interpolation
    in time (:func:`mocapkit.solvers.evidence.evidence_blend`; issue 18: on a 95 %-missing
    clip tsmc / trnn filled 76 / 32 cm off where interpolation was 8 cm off).  Frames with
    at least 35 % of the markers observed (every frame of the thesis' protocols) are not
    affected.
    """

    keeps_observed = False
    fill_evidence = "markers"
    clean_tolerance_cm = 1.0

    def _solve(self, X: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
        raise NotImplementedError

    def denoise(self, motion: Motion) -> Motion:
        motion = _check_motion(motion, self.name)
        known = _known_mask(motion, bool(self.detect), float(self.threshold_cm))
        _never_observed(known, motion, self.name)
        X = motion.matrix()
        km = np.repeat(known, 3, axis=1)
        unit = float(self.unit_cm)
        if not np.isfinite(unit) or unit <= 0:
            raise MocapValueError(f"{self.name}: unit_cm must be a positive number, got {self.unit_cm!r}")
        A, info = self._solve(X / unit, km)
        _record(self, info, "criterion")
        A *= unit
        lin = fill_gaps_linear(X, km)
        if not info["converged"]:
            A, info = _unusable_guard(self.name, A, X, km, lin, info)
        if not km.all():                 # frames with few markers: interpolation in time
            A = evidence_blend(A, lin, km, known)
        return _output(motion, A, known, bool(self.keep_observed), _info(self.name, info))


@register
class TSMC(_MatrixCompletion):
    """Bilinear low-rank + sparse + smooth completion (thesis Sec. 4.1, Algorithm 2).

    ``min 1/2(||U||^2 + ||V||^2) + alpha ||Omega o E||_1 + beta/2 ||O M||^2`` s.t.
    ``X = U V^T + E, M = U V^T`` on the (T, 3J) matrix (cm), by ALM with the slack variable
    M (eqs. 4.6-4.14, misprints fixed; :func:`mocapkit.solvers.completion.tsmc`).  This is
    the TSMC model of Feng et al. (2014b) solved with the thesis' bilinear factorisation;
    the rank k comes from the last-significant-jump rule (eq. 4.15).

    Parameters
    ----------
    alpha, beta, lam1, lam2, gamma, lam_max : thesis settings 1, 100, 1e-5, 1e-5, 1.4, 1e10.
    rank : factor width k; None = full width min(T, 3J) (our default), "lsj" = the thesis'
        rule (eq. 4.15) with :func:`~mocapkit.solvers.completion.estimate_rank`.
    tol, max_iter : ALM stopping.
    unit_cm : length unit the weights are read in (default: CMU ASF unit, see below).
    mstep : "dct" (thesis) or "banded" (same solve, O(T); faster on long clips).
    detect : also treat trust-data outliers (``threshold_cm``) as missing.
    keep_observed : return observed (trusted) entries unchanged (gap filling only).
    """

    name = "tsmc"
    description = "thesis bilinear low-rank + sparse error + 2nd-difference smoothness (TSMC model, ALM)"

    def __init__(self, alpha: float = 1.0, beta: float = 100.0, lam1: float = 1e-5,
                 lam2: float = 1e-5, gamma: float = 1.4, lam_max: float = 1e10,
                 rank: int | str | None = None, tol: float = 1e-4, max_iter: int = 500,
                 detect: bool = False, threshold_cm: float = 6.0, keep_observed: bool = False,
                 unit_cm: float = CMU_UNIT_CM, mstep: str = "dct", seed: int = 0):
        self.unit_cm = unit_cm
        self.mstep = mstep
        self.alpha = alpha
        self.beta = beta
        self.lam1 = lam1
        self.lam2 = lam2
        self.gamma = gamma
        self.lam_max = lam_max
        self.rank = rank
        self.tol = tol
        self.max_iter = max_iter
        self.detect = detect
        self.threshold_cm = threshold_cm
        self.keep_observed = keep_observed
        self.seed = seed

    def _solve(self, X, mask):
        A, info = _cp.tsmc(X, mask, rank=self.rank, alpha=float(self.alpha), beta=float(self.beta),
                           lam1=float(self.lam1), lam2=float(self.lam2), gamma=float(self.gamma),
                           lam_max=float(self.lam_max), tol=float(self.tol),
                           max_iter=int(self.max_iter), seed=int(self.seed),
                           mstep=str(self.mstep), return_info=True)
        return A, info


@register
class TrNN(_MatrixCompletion):
    """Truncated nuclear norm completion with smoothness (thesis Sec. 4.2, Algorithm 3).

    ``min ||X||_r + lam ||P_Omega(S)||_1 + mu/2 ||O M||^2`` (eqs. 4.21-4.23) on the (T, 3J)
    matrix (cm) by a single-loop ALM with a DCT-diagonalised M-step
    (:func:`mocapkit.solvers.completion.trnn`).  Settings of Sec. 4.2.3 (real data):
    lam = 100/sqrt(max(m, n)), mu = 100, rho = 1.4, eta0 = 1e-5, eps = 1e-4, r = 15;
    factor width d = min(T, 3J) by default ("lsj": the thesis' round(1.2 rank), at least
    r + 1).

    Parameters
    ----------
    r, d, lam, mu, rho, eta, eta_max, tol, max_iter : see above (None = thesis rule).
    detect, threshold_cm, keep_observed, unit_cm, mstep : as :class:`TSMC`.
    """

    name = "trnn"
    description = "thesis truncated nuclear norm + sparse error + smoothness, single-loop ALM with DCT M-step"

    def __init__(self, r: int = 15, d: int | str | None = None, lam: float | None = None,
                 mu: float = 100.0, rho: float = 1.4, eta: float = 1e-5, eta_max: float = 1e6,
                 tol: float = 1e-4, max_iter: int = 500, detect: bool = False,
                 threshold_cm: float = 6.0, keep_observed: bool = False,
                 unit_cm: float = CMU_UNIT_CM, mstep: str = "dct", seed: int = 0):
        self.unit_cm = unit_cm
        self.mstep = mstep
        self.r = r
        self.d = d
        self.lam = lam
        self.mu = mu
        self.rho = rho
        self.eta = eta
        self.eta_max = eta_max
        self.tol = tol
        self.max_iter = max_iter
        self.detect = detect
        self.threshold_cm = threshold_cm
        self.keep_observed = keep_observed
        self.seed = seed

    def _solve(self, X, mask):
        A, info = _cp.trnn(X, mask, r=int(self.r), d=self.d, lam=self.lam, mu=float(self.mu),
                           rho=float(self.rho), eta=float(self.eta), eta_max=float(self.eta_max),
                           tol=float(self.tol), max_iter=int(self.max_iter), seed=int(self.seed),
                           mstep=str(self.mstep), return_info=True)
        return A, info


@register
class DynaMMo(Denoiser):
    """DynaMMo gap filling: a linear dynamical system fitted by EM with missing values.

    Li, McCann, Pollard & Faloutsos (2009), KDD (the LDS baseline of thesis Fig. 3.7/4.11);
    :func:`mocapkit.solvers.completion.lds_em_complete` on the (T, 3J) matrix (cm).
    Observed entries are kept; missing (and, with ``detect``, untrusted) ones are filled
    with the smoothed LDS prediction.

    Parameters
    ----------
    k : latent dimension (default 48, capped at 3J: measured on CMU 05_06 with 20 % random
        missing markers, k = 16 / 32 / 48 / 64 gives 2.0 / 0.51 / 0.32 / 0.32 cm -- missing
        entries are predicted as C E[z], so k must be large enough for C z to reproduce a
        frame).  max_iter, tol : EM stopping.
    estep : "fill" (DynaMMo: smooth the filled data, fast) or "observed" (condition on the
        observed entries only, exact but ~10x slower); see
        :func:`~mocapkit.solvers.completion.lds_em_complete`.
    detect, threshold_cm : treat trust-data outliers as missing.
    """

    name = "dynammo"
    fill_evidence = "markers"
    description = "DynaMMo: linear dynamical system with missing values fitted by EM (Kalman/RTS E-step)"
    keeps_observed = True
    clean_tolerance_cm = 1.0

    def __init__(self, k: int = 48, max_iter: int = 100, tol: float = 1e-4, estep: str = "fill",
                 detect: bool = False, threshold_cm: float = 6.0):
        self.estep = estep
        self.k = k
        self.max_iter = max_iter
        self.tol = tol
        self.detect = detect
        self.threshold_cm = threshold_cm

    @classmethod
    def quick_params(cls) -> dict[str, Any]:
        return {"max_iter": 20}

    def denoise(self, motion: Motion) -> Motion:
        motion = _check_motion(motion, self.name)
        known = _known_mask(motion, bool(self.detect), float(self.threshold_cm))
        _never_observed(known, motion, self.name)
        km = np.repeat(known, 3, axis=1)
        X = motion.matrix()
        A, info = _cp.lds_em_complete(X, km, k=int(self.k), max_iter=int(self.max_iter),
                                      tol=float(self.tol), estep=str(self.estep),
                                      return_info=True)
        _record(self, info, "change")
        return _output(motion, A, known, True, _info(self.name, info))
