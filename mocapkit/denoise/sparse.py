"""Sparse motion bases selection: ``xiao-sparse`` and ``xiao-sparse-fullpose``.

Xiao, Feng, Zhuang, Wu & Zhang (2015), "Sparse motion bases selection for human motion
denoising", Signal Processing 110 (seed 000).  Algorithm 1 of the paper:

1. **Local frame** (Sec. 3.1.1): every pose is moved to Xiao's root-centred, body-aligned
   frame (:func:`mocapkit.frames.pelvis_neck_frame`); decision: the frame is estimated from robustly
   smoothed tracks so outliers do not tilt it, and undone exactly at the end.
2. **Poselets** (Sec. 3.1.2): the pose is split into the five body parts of
   :meth:`Skeleton.body_parts` (torso, arms, legs, found by joint *name*); neighbouring
   parts share a joint (thorax for the arms, root for the legs).
3. **Poselet groups** (Sec. 3.1.3): lagged windows of ``window`` (M) frames, stride 1,
   each flattened to a vector ``g_j = [p_j; p_{j+1}; ...; p_{j+M-1}]`` of length d_i M.
4. **Dictionaries** (eqs. 1-2, training): one K-SVD dictionary per poselet with
   ``n_atoms`` (K) unit-norm atoms and target sparsity ``sparsity`` (T_s)
   (:func:`mocapkit.solvers.ksvd.ksvd`, approximate K-SVD + Batch-OMP, the paper's
   "fast K-SVD" [40]); poselets are trained in parallel processes (``n_jobs``).
5. **Coding** (eqs. 3-5): for Gaussian noise the l2/l1 model (lasso, eq. 4), for outliers
   the l1/l1 model (eq. 5), for mixed noise l1/l1 then l2/l1 on its result; solved for
   all windows of a poselet at once (:mod:`mocapkit.solvers.sparse_coding`).
6. **Reassembly** (Alg. 1 steps 5-7): every frame is the plain mean of its copies in
   the overlapping windows; joints shared by two poselets are averaged too; then the
   local frame is undone (step 8).

``xiao-sparse-fullpose`` is the same with one dictionary for the whole pose (the
"traditional pose representation" of the paper's Table 2).

Decisions where the paper is silent (each is a parameter):

* ``noise='auto'`` (default) detects outliers first: residuals from the median of the
  6 neighbouring frames (centre excluded, one robust scale sigma_c per channel, as in a
  Hampel identifier) are flagged beyond ``max(3.5 sigma_c, 1 cm)``;
  more than ``outlier_detect_ratio`` (1.5 %; real "clean" CMU clips have up to ~1 % of
  such samples: capture glitches) flagged entries -> outliers present, then
  ``'mixed'`` if the robust Gaussian noise level exceeds 0.1 cm, else ``'outliers'``;
  no outliers -> ``'gaussian'``.  ``noise='gaussian'|'outliers'|'mixed'`` forces a model.
* lambda of eq. (4): the paper's lambda=100 is in unstated units.  lambda has the units
  of the data (cm) and its best value grows with the noise: measured on validation
  clips it is close to ``0.1 sigma^2`` (cm, sigma in cm) from 40 dB to 10 dB SNR --
  the MAP rule lambda = 2 sigma^2 / b for Laplace-distributed codes of scale b ~ 20 cm,
  rather than the universal-threshold rule lambda ~ sigma.  So by default
  ``lam = lam_factor * sigma^2`` (``lam_factor`` = 0.1 per cm), sigma the clip's noise
  level estimated robustly in the local frame (second differences,
  :func:`mocapkit.signal.estimate_noise`, median over channels); a numeric ``lam``
  overrides the rule.  lambda of eq. (5) is dimensionless (``lam_l1`` = 0.1; 0.03 is a
  little better below 20 % outliers, 0.1 clearly better above).  Both defaults are the
  values with the smallest worst-case error ratio in the ``xiao-params`` sweep on
  validation folds of the training clips (docs/results/xiao.md).
* Local frame smoothing (``frame_smooth_s`` = 0.1 s Gaussian after a 0.2 s running
  median): the frame is estimated from the noisy input, and its jitter goes straight
  into the output (the dictionary smooths the local motion, the jittery inverse
  transform puts the jitter back); 0.1 s instead of 0.025 s cut the error at 10 dB by
  18 % and changed the outlier results by < 0.05 cm (dance validation).
* ``center=True``: the mean training window of each poselet is subtracted before K-SVD
  and coding and added back after (the l1 penalty then shrinks towards the mean motion
  instead of towards the origin, and the Gram matrix is much better conditioned).
* Training windows are subsampled with a stride so at most ``max_train_windows`` per
  poselet go into K-SVD (the stride is chosen per fit and recorded in ``train_stride_``).
* Window M = 21 frames (0.175 s at 120 fps; the paper's grid is 9-39 at an unstated
  rate): best of 9/15/21 on validation folds; K = 512 keeps every poselet dictionary
  overcomplete (largest d M = 8 joints x 3 x 21 = 504), as the paper requires.
* Coding uses the truncated SVD of each dictionary (``rank_tol`` = 1e-6), float32 and
  12 (l2/l1) / 24 (l1/l1) over-relaxed ADMM iterations (``relax`` alpha = 1.8, Boyd et al.
  2011 Sec. 3.4.3: same eq. (4) / (5) solutions, faster convergence), for speed (issue #5,
  one core, K = 512, CMU 05_05: Gaussian ~1300 -> ~2200 frames/s, mixed ~770 -> ~1000).
  Measured on the dance test clip (Table 1 cells) against the former plain ADMM with
  20 / 30 iterations: snr40 0.350 -> 0.358 cm, snr30 0.692 -> 0.695, snr10 3.534 -> 3.537,
  outliers15 0.700 -> 0.694, outliers25 1.202 -> 1.190, mixed 1.924 -> 1.938 (plain ADMM
  with 10 / 15 iterations: +0.13 cm at 30 dB, +0.25 at outliers15).  rank_tol = 3e-6
  would be another ~20 % faster but costs +0.035 cm at 40 dB (the truncation error shows
  at low noise), so 1e-6 is kept.  Profile (one core): the time is in the (S, K) x (K, r)
  and (S, n) x (n, r) products of the ADMM iterations (near the single-core BLAS peak), so
  iterations x rank is what costs; the solvers update preallocated (S, K) / (S, n) arrays
  in place (fresh large arrays cost page faults on this machine).  A warm start of the l2/l1
  pass of mixed noise from the l1/l1 codes was tried and not used: no better than a
  cold start at equal iterations (the l2/l1 problem has other codes).  The l1/l1 pass
  (and the l2/l1 pass of mixed noise) codes every second window only (``l1_stride``):
  twice as fast, <= 0.01 cm on the dance outlier / mixed conditions.  BLAS runs with one
  thread inside :meth:`denoise`; ``n_jobs`` codes the poselets in parallel processes.
* Missing samples are filled by a cubic spline per channel before denoising, so the
  method also fills gaps (not part of the paper).
* Clips shorter than the window are padded by repeating their end frames.

Fitted state (saved by :meth:`Denoiser.save`): ``dictionaries_`` (list of (d_i M, K)
arrays), ``means_`` (list of (d_i M,) arrays), ``parts_`` (list of joint-index arrays),
``joint_names_``, ``part_names_``, ``train_rmse_`` (final K-SVD training RMSE per
poselet, cm), ``train_stride_``, ``fps_``. A result of :meth:`denoise` carries
``source["convergence"]`` (also in ``last_report_``, never saved): a JSON summary of its
ADMM solves -- iterations, largest final relative primal / dual residuals vs tol, see
:meth:`XiaoSparse._report_convergence`.
"""
from __future__ import annotations

import math
import os
from typing import Any, Sequence

import numpy as np

from ..errors import MocapValueError
from ..frames import MARKER_ORIGIN, check_marker_origin, frame_in_place, pelvis_neck_frame
from ..motion import Motion
from ..signal import estimate_noise
from ..signal._arrays import channel_blocks
from ..windows import lagged, overlap_add_into, window_blocks, window_starts
from .base import Denoiser, check_trained_joints, register, report_convergence, training_matrices
from .constraints import Integral, Interval, Options, Real, center_as_string

__all__ = ["XiaoSparse", "XiaoSparseFullPose", "detect_noise"]

_INT1 = Interval(Integral, 1, None)
_NONNEG = Interval(Real, 0, None)

NOISE_TYPES = ("auto", "gaussian", "outliers", "mixed")

#: numerics of the coding step, fixed (constructor parameters before; measured in
#: docs/results/xiao.md): the ADMM over-relaxation alpha of both solvers (Boyd et al. 2011
#: Sec. 3.4.3; in (0, 2), 1 = plain ADMM; same fixed points, with 1.8 the 12 / 24
#: iterations give the errors plain ADMM reached with 20 / 30), the dictionary truncation
#: (singular values below sqrt(RANK_TOL) s_max are dropped for coding;
#: :mod:`mocapkit.solvers.sparse_coding`) and the working precision
RELAX = 1.8
RANK_TOL = 1e-6
CODE_DTYPE = "float32"


# ---------------------------------------------------------------------------------------
# noise detection
# ---------------------------------------------------------------------------------------
def detect_noise(X: np.ndarray, *, outlier_detect_ratio: float = 0.015, n_sigmas: float = 3.5,
                 floor_cm: float = 1.0, mixed_sigma_cm: float = 0.1) -> dict[str, Any]:
    """Classify the noise of a (T, C) local-frame matrix (cm): gaussian / outliers / mixed.

    Robust residual test: residual of every sample from the median of its 6 neighbours
    (running window of 7, centre excluded, :func:`scipy.ndimage.rank_filter`), per-channel
    robust scale sigma_c (1.4826 MAD of the residuals); a sample is an outlier candidate when
    ``|r| > max(n_sigmas sigma_c, floor_cm)``.  Outliers are declared when the flagged
    fraction exceeds ``outlier_detect_ratio``.  The Gaussian noise level ``sigma`` is the
    median over channels of the second-difference estimate
    (:func:`mocapkit.signal.estimate_noise` with ``pool="median"``; 0 when it cannot be made).

    Returns dict(type=..., outlier_fraction=..., sigma_cm=...).
    """
    from scipy.ndimage import rank_filter

    X = np.asarray(X, dtype=np.float64)
    T = X.shape[0]
    if T >= 7:
        # running median of the 6 neighbours (centre excluded) = mean of their 3rd and 4th
        # order statistics (unbiased for a marker moving at constant speed), mirrored ends
        # every step is per channel: done 24 channels at a time (a few (T, 24) temporaries
        # instead of (T, C) ones; the flag count, hence the fraction, is exact either way)
        foot = np.array([1, 1, 1, 0, 1, 1, 1], dtype=bool)[:, None]
        n_flags = 0
        for sl in channel_blocks(X.shape[1], 24):
            Xc = X[:, sl]
            med = 0.5 * (rank_filter(Xc, 2, footprint=foot, mode="mirror")
                         + rank_filter(Xc, 3, footprint=foot, mode="mirror"))
            res = Xc - med
            dev = np.abs(res - np.median(res, axis=0))
            sig = 1.4826 * np.median(dev, axis=0)
            n_flags += int(np.count_nonzero(np.abs(res) > np.maximum(n_sigmas * sig, floor_cm)))
        frac = n_flags / X.size
    else:
        frac = 0.0
    sigma = estimate_noise(X, pool="median", fallback=0.0)
    if frac > outlier_detect_ratio:
        kind = "mixed" if sigma > mixed_sigma_cm else "outliers"
    else:
        kind = "gaussian"
    return {"type": kind, "outlier_fraction": frac, "sigma_cm": sigma}


# ---------------------------------------------------------------------------------------
# training worker (module level so process pools can pickle it)
# ---------------------------------------------------------------------------------------
def _train_part(Y: np.ndarray, n_atoms: int, sparsity: int, n_iter: int, center: bool,
                seed: int) -> tuple[np.ndarray, np.ndarray, float]:
    from ..solvers._linalg import blas_limit

    from ..solvers.ksvd import ksvd

    with blas_limit():
        mu = Y.mean(axis=0) if center else np.zeros(Y.shape[1])
        Yc = Y - mu
        sp = min(int(sparsity), int(n_atoms))
        res = ksvd(Yc, int(n_atoms), sparsity=sp, n_iter=int(n_iter), random_state=seed)
        rmse = res.rmse[-1] if res.rmse else float("nan")
    return res.dictionary, mu, float(rmse)


# ---------------------------------------------------------------------------------------
@register
class XiaoSparse(Denoiser):
    """Xiao et al. 2015 poselet sparse motion bases (K-SVD dictionaries + l1 coding).

    Parameters
    ----------
    window : M, frames per poselet group (paper grid 9-39; default 21 = 0.175 s at 120 fps,
        chosen on validation folds, docs/results/xiao.md; the arms then have d M = 504 <= K).
    n_atoms : K, atoms per dictionary (paper grid 500-1000; default 512).
    sparsity : T_s, K-SVD target sparsity (default 8).
    n_iter : K-SVD iterations (default 10).
    noise : ``'auto'`` (detect, default), ``'gaussian'`` (l2/l1), ``'outliers'`` (l1/l1),
        ``'mixed'`` (l1/l1 then l2/l1).
    lam : lambda of eq. (4) in cm; None (default) = ``lam_factor * sigma_hat**2``.
    lam_factor : per cm; multiplies the squared estimated noise sigma (default 0.1).
    lam_l1 : lambda of eq. (5), dimensionless (default 0.1).
    center : ``'mean'`` (default) subtracts the mean training window per poselet, ``'none'``
        does not (the low-rank family's spelling; model files storing True / False load).
    max_train_windows : K-SVD training windows per poselet (default 8000, strided).
    n_jobs : parallel worker processes over poselets, for K-SVD training and for denoising
        (default 1; the paper's parallel mode, Sec. 3.3 / Table 2; needs ``fork``, i.e.
        POSIX -- elsewhere denoising runs serially).
    code_iter : ADMM iterations for eq. (4) (default 12).
    admm_iter : ADMM iterations for eq. (5) (default 24).
    (The ADMM over-relaxation, the dictionary truncation and the float32 coding precision
    are fixed: :data:`RELAX`, :data:`RANK_TOL`, :data:`CODE_DTYPE`.)
    smooth_frame : estimate the local frame from smoothed tracks (default True).
    frame_smooth_s : Gaussian sigma (s) of that smoothing, after a running median of
        twice that length (default 0.1 s).
    l1_stride : the l1/l1 model (eq. 5) -- and, for mixed noise, the l2/l1 pass after it --
        codes every ``l1_stride``-th window only (plus the last one); frames are still the
        mean of their copies in the coded windows (default 2: each frame in ~11 windows
        instead of 21; halves the cost of the outlier / mixed paths, measured change of the
        dance outlier / mixed errors <= 0.01 cm; 1 = every window).
    warn_convergence : emit a :class:`~mocapkit.errors.ConvergenceWarning` when an ADMM
        solve stops at its iteration cap above tol (default False: the fixed, small
        iteration budgets are a deliberate speed/accuracy trade-off, so they practically
        never reach tol = 1e-4); the summary is always in the result's
        ``source["convergence"]``.
    seed : seed of the K-SVD initialisation (poselet i uses seed + i).
    """

    name = "xiao-sparse"
    fill_evidence = "markers"
    description = "Xiao et al. 2015: poselet K-SVD dictionaries, l2/l1 (Gaussian) or l1/l1 ADMM (outliers) coding"
    needs_training = True
    misfit_check = "learned"
    keeps_observed = False
    clean_tolerance_cm = 1.0
    _fullpose = False
    _parameter_constraints = {
        "window": [_INT1], "n_atoms": [_INT1], "sparsity": [_INT1], "n_iter": [Interval(Integral, 0, None)],
        "noise": [Options(*NOISE_TYPES)], "lam": [_NONNEG, None], "lam_factor": [_NONNEG],
        "lam_l1": [_NONNEG], "center": [Options("mean", "none")], "max_train_windows": [_INT1],
        "n_jobs": [_INT1], "code_iter": [_INT1], "admm_iter": [_INT1], "smooth_frame": [bool],
        "frame_smooth_s": [_NONNEG], "l1_stride": [_INT1], "warn_convergence": [bool],
        "seed": [Interval(Integral, 0, None)]}

    @classmethod
    def _upgrade_params(cls, params: dict[str, Any]) -> dict[str, Any]:
        """Model files written before ``random_state`` was spelled ``seed``, ``center`` was a
        string and the coding numerics were fixed (they store the fixed values)."""
        p = center_as_string(dict(params))
        if "random_state" in p:
            p["seed"] = p.pop("random_state")
        for k, fixed in (("relax", RELAX), ("rank_tol", RANK_TOL), ("dtype", CODE_DTYPE)):
            if k in p and p.pop(k) != fixed:
                raise MocapValueError(f"{cls.name}: this model file sets {k}={params[k]!r}; "
                                      f"this version codes with {k}={fixed!r} only")
        return p

    def __init__(self, window: int = 21, n_atoms: int = 512, sparsity: int = 8, n_iter: int = 10,
                 noise: str = "auto", lam: float | None = None, lam_factor: float = 0.1,
                 lam_l1: float = 0.1, center: str = "mean", max_train_windows: int = 8000,
                 n_jobs: int = 1, code_iter: int = 12, admm_iter: int = 24, smooth_frame: bool = True,
                 frame_smooth_s: float = 0.1, l1_stride: int = 2, warn_convergence: bool = False,
                 seed: int = 0):
        self._store_params(locals())

    @classmethod
    def quick_params(cls) -> dict[str, Any]:
        return {"window": 5, "n_atoms": 128, "sparsity": 4, "n_iter": 3,
                "max_train_windows": 2000, "n_jobs": 1}

    # -- helpers -------------------------------------------------------------------------
    def _part_lists(self, motion: Motion) -> tuple[list[str], list[list[int]]]:
        if self._fullpose:
            return ["pose"], [list(range(motion.n_joints))]
        parts = motion.skeleton.body_parts()
        names = [k for k, v in parts.items() if v]
        return names, [sorted(parts[k]) for k in names]

    def _local(self, P: np.ndarray, motion: Motion, in_place: bool = False):
        """Local frame of positions P (T, J, 3) in ``motion``'s joint order, and P in it
        (``in_place``: written into P, a block of frames at a time)."""
        s = float(self.frame_smooth_s)
        frame = pelvis_neck_frame(P, motion.skeleton, motion.fps, smooth=bool(self.smooth_frame),
                                  median_s=2.0 * s, sigma_s=s)
        return frame, (frame_in_place(frame, P, "local") if in_place else frame.to_local(P))

    # -- training ------------------------------------------------------------------------
    def fit(self, motions: Sequence[Motion]) -> "XiaoSparse":
        """Learn one K-SVD dictionary per poselet from clean training motions (eqs. 1-2)."""
        motions = list(motions)
        training_matrices(motions)                       # checks: non-empty, fully observed
        M = int(self.window)
        ref = motions[0]
        names = list(ref.skeleton.names)
        part_names, parts = self._part_lists(ref)
        locals_ = []
        for m in motions:
            if set(m.skeleton.names) != set(names):
                raise MocapValueError(f"{self.name}: all training motions need the same joints; "
                                      f"{m!r} differs from the first one")
            P = np.asarray(m.positions)
            if P.shape[0] < M:
                P = np.concatenate([P, np.repeat(P[-1:], M - P.shape[0], axis=0)])
            _, L = self._local(P, m)
            locals_.append(L[:, m.skeleton.indices(names)])      # joints in training order
        n_total = sum(L.shape[0] - M + 1 for L in locals_)
        stride = max(1, math.ceil(n_total / int(self.max_train_windows)))
        jobs = []
        for i, joints in enumerate(parts):
            Y = np.concatenate([lagged(L[:, joints].reshape(L.shape[0], -1), M) for L in locals_])
            Y = Y[::stride]
            jobs.append((Y, int(self.n_atoms), int(self.sparsity), int(self.n_iter), self.center == "mean",
                         int(self.seed) + i))
        n_jobs = min(int(self.n_jobs), len(jobs), os.cpu_count() or 1)
        if n_jobs > 1:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            # 'fork' (POSIX): children inherit the arrays and need no re-import of the
            # caller's __main__ (a script without a main guard would break 'spawn')
            ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
            with ProcessPoolExecutor(max_workers=n_jobs, mp_context=ctx) as ex:
                results = list(ex.map(_train_part, *zip(*jobs)))
        else:
            results = [_train_part(*j) for j in jobs]
        self.dictionaries_ = [r[0] for r in results]
        self.means_ = [r[1] for r in results]
        self.train_rmse_ = np.array([r[2] for r in results])
        self.parts_ = [np.asarray(p, dtype=np.int64) for p in parts]
        self.part_names_ = list(part_names)
        self.joint_names_ = names
        self.marker_origin_ = MARKER_ORIGIN
        self.train_stride_ = int(stride)
        self.fps_ = float(ref.fps)
        self._cache = None
        return self

    # -- denoising -----------------------------------------------------------------------
    def _solvers(self) -> list:
        """Truncated SVD of every dictionary (:func:`mocapkit.solvers.sparse_coding.dictionary_svd`
        with :data:`RANK_TOL`), cached in memory (not saved)."""
        key = (RANK_TOL, len(self.dictionaries_))
        if getattr(self, "_cache", None) is None or self._cache[0] != key:
            from ..solvers.sparse_coding import dictionary_svd

            self._cache = (key, [dictionary_svd(D, RANK_TOL) for D in self.dictionaries_])
        return self._cache[1]

    def _code_part(self, i: int, X: np.ndarray, kind: str, lam2: float) -> np.ndarray:
        """Denoise one poselet matrix X (T, d) in the local frame; returns (T, d).

        The lagged windows are zero-copy views of X; they are centred, coded, reconstructed
        and averaged back to frames a block at a time (:func:`window_blocks`,
        :func:`overlap_add_into`, :func:`~mocapkit.solvers.sparse_coding.lasso_admm_blocks`):
        the same numbers as coding all windows at once, without the (S, M d) window
        matrices and (S, K) codes of the whole clip (issue 21).  The l1/l1 solve (eq. 5)
        is the exception: its residual balancing adapts one penalty from the residuals
        of all its windows, so they are solved together (only their matrix is built by
        blocks)."""
        from ..solvers.sparse_coding import l1l1_admm, lasso_admm_blocks

        M = int(self.window)
        T, d = X.shape
        n = M * d
        sv = self._solvers()[i]
        D = self.dictionaries_[i]
        K = D.shape[1]
        mu = np.asarray(self.means_[i], dtype=np.float64)
        dt = np.dtype(CODE_DTYPE)
        conv = self.__dict__.setdefault("_conv_log", [])
        # bytes per window of a block: centred copy (float64 + float32), the ADMM arrays
        # (8 of K float32), the reconstruction (rank, then n float32 and float64)
        per_window = 28.0 * n + 32.0 * K + 8.0 * sv.rank
        starts = None
        if kind in ("outliers", "mixed"):
            st = int(self.l1_stride)
            starts = window_starts(T, M, st) if st > 1 else None
        H = lagged(X, M, view=True)
        S = H.shape[0] if starts is None else len(starts)

        def windows(a: int, b: int) -> np.ndarray:            # centred windows a..b-1 (float64)
            return (H[a:b] if starts is None else H[starts[a:b]]) - mu

        acc, cnt = np.zeros((T, d)), np.zeros(T)

        def consume(a: int, b: int, codes: np.ndarray) -> None:   # reconstruct, add to frames
            overlap_add_into(acc, sv.reconstruct(codes) + mu, M, a,
                             None if starts is None else starts[a:b], cnt=cnt)

        def restart() -> None:
            acc[:] = 0.0
            cnt[:] = 0.0

        if kind in ("outliers", "mixed"):
            Zs = np.empty((S, n), dtype=dt)
            for a, b in window_blocks(S, per_window):
                Zs[a:b] = windows(a, b)
            W, info = l1l1_admm(Zs, D, float(self.lam_l1), n_iter=int(self.admm_iter), tol=1e-4,
                                svd=sv, dtype=dt, balance_every=5, relax=RELAX,
                                return_info=True)
            del Zs
            conv.append(("l1l1", i, info))
            for a, b in window_blocks(S, per_window):
                consume(a, b, W[a:b])
            del W
            acc /= cnt[:, None]
            if kind == "outliers":
                return acc
            H = lagged(acc, M, view=True)                     # l2/l1 pass on its result
            acc, cnt = np.zeros((T, d)), np.zeros(T)
        info = lasso_admm_blocks(windows, S, D, lam2, consume, blocks=window_blocks(S, per_window),
                                 restart=restart, n_iter=int(self.code_iter), tol=1e-4, svd=sv,
                                 dtype=dt, relax=RELAX)
        conv.append(("lasso", i, info))
        acc /= cnt[:, None]
        return acc

    def denoise(self, motion: Motion) -> Motion:
        """Denoise (and gap-fill) ``motion`` with the learned dictionaries (Alg. 1)."""
        import time

        t_start = time.perf_counter()
        self._check_fitted()
        from .filters import filled_matrix

        names = list(self.joint_names_)
        if set(motion.skeleton.names) != set(names):   # (another order is the model's own business)
            check_trained_joints(self, motion)
        check_marker_origin(self, motion)
        M = int(self.window)
        T0 = motion.n_frames
        P = filled_matrix(motion, self.name).reshape(T0, motion.n_joints, 3)
        if T0 < M:
            P = np.concatenate([P, np.repeat(P[-1:], M - T0, axis=0)])
        perm = np.asarray(motion.skeleton.indices(names), dtype=np.int64)   # training -> motion index
        frame, L = self._local(P, motion, in_place=True)          # P is ours: transformed in place
        del P
        T, J = L.shape[0], L.shape[1]
        Lm = L.reshape(T, 3 * J)
        if self.noise == "auto":
            info = detect_noise(Lm)
        else:
            info = {"type": self.noise, "sigma_cm": estimate_noise(Lm, pool="median", fallback=0.0)}
        del Lm
        kind = info["type"]
        lam2 = float(self.lam) if self.lam is not None else float(self.lam_factor) * info["sigma_cm"] ** 2
        acc = np.zeros((T, J, 3))
        cnt = np.zeros(J)
        parts = [perm[np.asarray(j, dtype=np.int64)] for j in self.parts_]
        for joints in parts:
            cnt[joints] += 1
        if np.any(cnt == 0):
            raise MocapValueError(f"{self.name}: some joints are in no poselet")
        self._solvers()                                  # build the cache before any thread
        self._conv_log = []
        n_workers = min(int(self.n_jobs), len(parts))
        from ..solvers._linalg import blas_limit

        # One BLAS thread: the products are (S x K) x (K x r) with r ~ 100, where BLAS
        # threading gains little and, on a busy machine, oversubscription cost us 10x.
        # Parallelism comes from n_jobs: poselets coded in forked worker processes (the
        # paper's parallel mode; threads do not help: this OpenBLAS serialises calls made
        # from several threads when it is limited to one thread).
        with blas_limit():
            part_s = []
            if n_workers > 1 and _can_fork():
                jobs = [(i, L[:, joints].reshape(T, -1)) for i, joints in enumerate(parts)]
                coded, logs = _code_parallel(self, jobs, kind, lam2, n_workers)
                del jobs
                self._conv_log = [e for lg in logs for e in lg]
                for joints, Yi in zip(parts, coded):
                    acc[:, joints] += Yi.reshape(T, len(joints), 3)
                del coded
            else:
                # one poselet at a time, added to the frames as soon as it is coded
                for i, joints in enumerate(parts):
                    t0 = time.perf_counter()
                    Yi = self._code_part(i, _part_matrix(L, joints), kind, lam2)
                    part_s.append(time.perf_counter() - t0)
                    _part_add(acc, joints, Yi.reshape(T, len(joints), 3))
                    del Yi
        del L
        acc /= cnt[None, :, None]
        out = frame_in_place(frame, acc, "world")[:T0]
        self._last_info = {**info, "lam": lam2, "lam_l1": float(self.lam_l1),
                           "seconds": time.perf_counter() - t_start, "part_seconds": part_s}
        self._report_convergence()
        return motion.with_positions(out, handover=True)

    def _report_convergence(self) -> None:
        """Summarise the ADMM solves of the last :meth:`denoise` in the result's
        ``source["convergence"]``
        (:func:`~mocapkit.denoise.base.report_convergence`; a solve's residual is the larger
        of its final relative primal / dual residuals) and, with ``warn_convergence=True``,
        warn once when any stopped at its iteration cap above tol.  Per model (``l1l1`` /
        ``lasso``) also ``<model>_converged`` / ``_iterations`` / ``_primal`` / ``_dual``.
        """
        log = list(getattr(self, "_conv_log", []))
        extra: dict[str, Any] = {}
        for model in ("l1l1", "lasso"):
            sel = [e[2] for e in log if e[0] == model]
            if sel:
                extra[f"{model}_converged"] = all(x.converged for x in sel)
                extra[f"{model}_iterations"] = max(x.n_iter for x in sel)
                extra[f"{model}_primal"] = max(x.extra["primal"] for x in sel)
                extra[f"{model}_dual"] = max(x.extra["dual"] for x in sel)
        info = [e[2] for e in log]
        report_convergence(
            self, info, tol=max((x.extra["tol"] for x in info), default=0.0),
            max_iter=max((x.extra["max_iter"] for x in info), default=0), unit="ADMM solve",
            warn=bool(self.warn_convergence), stacklevel=4, extra=extra,
            param=f"raise code_iter (now {self.code_iter}) / admm_iter (now {self.admm_iter}) "
                  f"for a more exact solution")

    @property
    def last_info(self) -> dict[str, Any]:
        """What the last :meth:`denoise` call detected and used: noise ``type``,
        ``outlier_fraction``, ``sigma_cm``, ``lam``, ``lam_l1``, wall ``seconds`` and, when
        the poselets were coded serially, ``part_seconds`` (coding time per poselet)."""
        return dict(getattr(self, "_last_info", {}))


def _consecutive(joints: np.ndarray) -> slice | None:
    """``joints`` as a slice when they are consecutive and ascending (e.g. the full pose)."""
    j = np.asarray(joints)
    if j.size and np.array_equal(j, np.arange(j[0], j[0] + j.size)):
        return slice(int(j[0]), int(j[0]) + j.size)
    return None


def _part_matrix(L: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """(T, 3 len(joints)) matrix of the poselet ``joints`` of L (T, J, 3): a view when the
    joints are consecutive, else a copy."""
    sl = _consecutive(joints)
    return (L[:, sl] if sl is not None else L[:, joints]).reshape(L.shape[0], -1)


def _part_add(acc: np.ndarray, joints: np.ndarray, Y: np.ndarray) -> None:
    """``acc[:, joints] += Y`` -- in place through a view when the joints are consecutive
    (no (T, J, 3) temporary for the full pose)."""
    sl = _consecutive(joints)
    if sl is not None:
        acc[:, sl] += Y
    else:
        acc[:, joints] += Y


_WORKER_MODEL: list = []


def _can_fork() -> bool:
    import multiprocessing as mp

    return "fork" in mp.get_all_start_methods()


def _code_worker(i: int, X: np.ndarray, kind: str, lam2: float) -> tuple[np.ndarray, list]:
    from ..solvers._linalg import blas_limit

    model = _WORKER_MODEL[0]
    model._conv_log = []
    with blas_limit():
        return model._code_part(i, X, kind, lam2), model._conv_log


def _code_parallel(model: "XiaoSparse", jobs: list, kind: str, lam2: float, n_workers: int) -> list:
    """Code the poselets in ``n_workers`` forked processes (the model is inherited by
    fork, only the poselet matrices travel); largest poselets are submitted first."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    _WORKER_MODEL[:] = [model]
    try:
        order = sorted(range(len(jobs)), key=lambda k: -jobs[k][1].size)
        with ProcessPoolExecutor(max_workers=n_workers, mp_context=mp.get_context("fork")) as ex:
            futs = {k: ex.submit(_code_worker, jobs[k][0], jobs[k][1], kind, lam2) for k in order}
            res = [futs[k].result() for k in range(len(jobs))]
            return [r[0] for r in res], [r[1] for r in res]
    finally:
        _WORKER_MODEL.clear()


@register
class XiaoSparseFullPose(XiaoSparse):
    """Xiao et al. 2015 with one dictionary for the whole pose (their Table 2 baseline).

    Same parameters as :class:`XiaoSparse`; the windows hold all joints (d = 3J).
    """

    name = "xiao-sparse-fullpose"
    description = "Xiao et al. 2015 with one K-SVD dictionary for the whole pose (Table 2 comparison)"
    _fullpose = True
