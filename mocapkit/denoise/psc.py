"""``psc`` -- poselet sparse coding (Z. Wang 2017, seed 003, Ch. 3).

Per-body-part dictionaries of M-frame windows learnt with the masked objective
(eqs. 3.7-3.12), recovery by locality-constrained linear coding (eqs. 3.15-3.17) after
trust-data detection (eq. 3.13).  Data-driven.  The maths lives in
:mod:`mocapkit.solvers.llc`; this class handles Motions, masks and body parts.  Trusted
observed entries are kept and only missing or untrusted ones replaced (METHODS.md Sec. 4
decision).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .. import gaps
from ..errors import MocapValueError
from ..frames import MARKER_ORIGIN, Frame, check_marker_origin, frame_in_place, pelvis_neck_frame
from ..motion import Motion
from ..skeleton import BODY_PARTS
from ..signal._arrays import channel_blocks
from ..solvers import llc as _llc
from ..solvers._linalg import one_blas_thread
from ..windows import lagged, overlap_add_into, window_blocks
from ._refill import check_motion, known_mask
from .base import Denoiser, check_trained_joints, register
from .constraints import Integral, Interval, Numbers, Real

_POSITIVE = Interval(Real, 0, None, closed="neither")

__all__ = ["PSC"]

#: samples per batched LLC solve inside a block (bounds the (n, k, d) atom differences)
_LLC_CHUNK = 1024


# --------------------------------------------------------------------------------------
# local frame for PSC (thesis Sec. 3.2 = Xiao et al.'s frame, mocapkit.frames)
# --------------------------------------------------------------------------------------
def _local_frame(motion: Motion, known: np.ndarray | None = None):
    """The thesis' per-pose frame (root at 0, femur/upper-neck plane parallel to XY).

    Estimated by :func:`mocapkit.frames.pelvis_neck_frame` from the trusted samples
    (robustly smoothed tracks, so outliers and gaps do not tilt it).  A skeleton without
    femurs / upper neck gets translation only (root track, gaps bridged linearly).
    """
    known = motion.observed if known is None else known
    P = np.where(known[..., None], motion.positions, np.nan)
    try:
        return pelvis_neck_frame(P, motion.skeleton, motion.fps)
    except MocapValueError:
        root = int(np.flatnonzero(motion.skeleton.parents < 0)[0])
        X = gaps.fill(P[:, root], np.repeat(known[:, root:root + 1], 3, axis=1), never_observed=0.0)
        return Frame.identity(X)


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
    (root at the origin, femur/upper-neck plane parallel to XY; :func:`mocapkit.frames.pelvis_neck_frame`,
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
    misfit_check = "learned"
    keeps_observed = True
    clean_tolerance_cm = 1.0
    _parameter_constraints = {
        "window": [Interval(Integral, 1, None)], "n_atoms": [Interval(Integral, 2, None)],
        "lam": [Interval(Real, 0, None)], "n_neighbors": [Interval(Integral, 1, None)],
        "sigma": [_POSITIVE, None], "threshold_cm": [_POSITIVE], "detect": [bool],
        "n_iter": [Interval(Integral, 0, None)], "dict_steps": [Interval(Integral, 0, None)],
        "tol": [Interval(Real, 0, None)], "train_missing": [Numbers(2)],
        "max_windows": [Interval(Integral, 1, None)], "refine": [bool], "seed": [Interval(Integral, 0, None)]}

    def __init__(self, window: int = 10, n_atoms: int = 1024, lam: float = 10.0,
                 n_neighbors: int = 5, sigma: float | None = None, threshold_cm: float = 6.0,
                 detect: bool = True, n_iter: int = 5, dict_steps: int = 3,
                 tol: float = 1e-3, train_missing: tuple[float, float] = (0.1, 0.6),
                 max_windows: int = 3000, refine: bool = True, seed: int = 0):
        self._store_params(locals())

    @classmethod
    def quick_params(cls) -> dict[str, Any]:
        return {"n_atoms": 64, "n_iter": 2, "max_windows": 600}

    # -- validation -------------------------------------------------------------------------
    def _check_combination(self) -> None:
        lo, hi = self.train_missing
        if not (0 <= lo <= hi < 1):
            raise MocapValueError(f"psc: train_missing must be (low, high) with 0 <= low <= high < 1, "
                                  f"got {self.train_missing}")

    def _parts(self, skeleton) -> list[tuple[str, np.ndarray]]:
        parts = skeleton.body_parts()
        out = [(p, np.asarray(parts[p], dtype=np.int64)) for p in BODY_PARTS if parts.get(p)]
        if not out:
            out = [("all", np.arange(skeleton.n_joints))]
        return out

    # -- training ---------------------------------------------------------------------------
    @one_blas_thread
    def fit(self, motions: Sequence[Motion]) -> "PSC":
        """Learn one dictionary per body part from clean motions (same skeleton)."""
        M, K = int(self.window), int(self.n_atoms)
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
        locs = []
        for m in motions:
            if m.n_frames < M:
                continue
            locs.append(_local_frame(m).to_local(m.positions))
        if not locs:
            raise MocapValueError(f"psc.fit(): every training motion is shorter than window={M}")
        rng = np.random.default_rng(self.seed)
        parts = self._parts(sk)
        dicts, hist = [], []
        for _, idx in parts:
            Y = np.concatenate([lagged(L[:, idx], M) for L in locs])
            if len(Y) > int(self.max_windows):
                Y = Y[rng.choice(len(Y), size=int(self.max_windows), replace=False)]
            D, h = self._train_part(Y, M, len(idx), min(K, len(Y)), rng)
            dicts.append(D)
            hist.append(h)
        self.dictionaries_ = dicts
        self.parts_ = [idx for _, idx in parts]
        self.part_names_ = [p for p, _ in parts]
        self.joint_names_ = list(sk.names)
        self.marker_origin_ = MARKER_ORIGIN
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
    @one_blas_thread
    def denoise(self, motion: Motion) -> Motion:
        """Algorithm 1 (module / class docstring).  Memory (issue 21): every window of a
        part is coded and averaged back in blocks (:func:`mocapkit.windows.window_blocks`), the
        local-frame transforms and the refinement run in place or by blocks, so the work
        arrays are a few (T, J, 3) ones -- the blocked numbers equal the whole-clip ones."""
        self._check_fitted()
        motion = check_motion(motion, self.name)
        M = int(self.window)
        check_trained_joints(self, motion)
        check_marker_origin(self, motion)
        T = motion.n_frames
        if T < M:
            raise MocapValueError(f"psc: the clip has {T} frames, fewer than the window ({M})")
        known = known_mask(motion, bool(self.detect), float(self.threshold_cm))
        frame = _local_frame(motion, known)
        # trusted samples in the local frame, 0 elsewhere (transformed in place)
        L = frame_in_place(frame, np.where(known[..., None], motion.positions, 0.0), "local")
        acc = np.zeros_like(L)
        cnt = np.zeros(L.shape[:2])
        k = int(self.n_neighbors)
        part_acc = part_cnt = None
        for idx, D in zip(self.parts_, self.dictionaries_):
            idx = np.asarray(idx, dtype=np.int64)
            nj = len(idx)
            part_acc, part_cnt = self._code_part(L[:, idx].reshape(T, -1),
                                                 np.repeat(known[:, idx], 3, axis=1), D, M, k)
            if part_acc is None:                     # no window of this part has a known sample
                continue
            acc[:, idx] += part_acc.reshape(T, nj, 3)
            cnt[:, idx] += part_cnt[:, None]
        est = acc
        est /= np.maximum(cnt, 1)[..., None]
        del part_acc, part_cnt
        none = cnt == 0
        if none.any():
            # samples no window reconstructs (joints in no part, parts missing for a whole
            # window): linear interpolation in the local frame, made for those joints only
            # (interpolation and transform are per channel / per joint)
            js = np.flatnonzero(none.any(axis=0))
            cols = (3 * js[:, None] + np.arange(3)).ravel()
            lin = gaps.fill(motion.matrix(copy=False)[:, cols], np.repeat(known[:, js], 3, axis=1),
                            never_observed=0.0).reshape(T, len(js), 3)
            sub, sel = est[:, js], none[:, js]
            sub[sel] = frame.to_local(lin)[sel]
            est[:, js] = sub
            del lin, sub
        if self.refine:
            # our extension: interpolate the coding residual of the known samples across
            # the holes, so filled samples meet the observed ones without a jump (a few
            # joints at a time: the interpolation is per channel)
            km = np.repeat(known, 3, axis=1)
            L2, E2 = L.reshape(T, -1), est.reshape(T, -1)
            for sl in channel_blocks(L2.shape[1], 24):
                res = np.where(km[:, sl], L2[:, sl] - E2[:, sl], np.nan)
                E2[:, sl] += gaps.fill(res, km[:, sl], never_observed=0.0)
        del L
        out = frame_in_place(frame, est, "world")
        np.copyto(out, motion.positions, where=known[..., None])     # trusted samples kept
        res = motion.with_positions(out, handover=True)
        return res.with_source(solver={"method": self.name, "window": M,
                                       "untrusted": int((motion.observed & ~known).sum()),
                                       "filled": int((~known).sum())})

    def _code_part(self, X: np.ndarray, known: np.ndarray, D: np.ndarray, M: int, k: int):
        """Code and reconstruct every M-frame window of one part X (T, d) with known mask
        (T, d) by LLC (eqs. 3.15-3.17) and sum the reconstructions back to frames.

        Returns (acc (T, d), cnt (T,)): sum and number of the reconstructions of coded
        windows (those with a known entry) covering each frame, or (None, None) when no
        window is coded.  The windows are zero-copy views, coded a block at a time (last
        block first, see :func:`mocapkit.windows.window_blocks`): the same numbers as coding all
        windows at once, without their (S, M d) matrices (and the (S, k, M d) atoms of the
        reconstruction) for the whole clip."""
        T = X.shape[0]
        Y = lagged(X, M, view=True)
        obs = lagged(known, M, view=True)
        d = Y.shape[1]
        kk = min(k, len(D))
        acc, cnt = np.zeros((T, X.shape[1])), np.zeros(T)
        coded = False
        # per window: its copy, mask, zeroed copy, k atoms (coding and reconstruction)
        for a, b in window_blocks(Y.shape[0], 8.0 * d * (4 + 2 * kk)):
            ob = obs[a:b]
            valid = ob.any(axis=1)
            if not valid.any():
                continue
            codes, aidx = _llc.llc_code(Y[a:b][valid], D, ob[valid], lam=float(self.lam),
                                        sigma=self.sigma, n_neighbors=kk, chunk=_LLC_CHUNK)
            R = np.zeros((b - a, d))
            R[valid] = _llc.llc_reconstruct(codes, aidx, D)
            overlap_add_into(acc, R, M, a, weights=valid, cnt=cnt)
            coded = True
        return (acc, cnt) if coded else (None, None)


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
