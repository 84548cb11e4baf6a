"""Example-based robust filter bases (Lou & Chai 2010, seed 001): plain array maths.

Notation (paper Sec. 3): a clip is a (T, L) array, one row per frame, L channels
(degrees of freedom). A *window* of length M starting at frame s is the vector
``z_s = Z[s:s+M].ravel()`` of length M*L.

Layout decision: windows are stacked **frame-major** (index ``m*L + l``: all channels of
the window's first frame, then its second frame, ...), which is the memory layout of a
C-ordered (T, L) array and lets every window be a zero-copy slice. The paper's eq. 2
stacks channel-major (``l*M + m``); the two differ by a fixed permutation of the basis
rows, so eigenvalues, coefficients and results are identical.

Training (Sec. 3.1, eqs. 1-5): the grand lag-covariance ``C_D = DᵀD / S_N`` of all
windows of all training clips (eq. 3; several clips: their windows are stacked), its
eigenvectors are the filter bases ``E`` (ML x K), K kept by an energy fraction (99% in
the paper) or fixed. :func:`lag_covariance` accumulates DᵀD without forming D (see its
notes); :func:`learn_bases` diagonalises it.

Denoising (Secs. 3.3-3.5, eqs. 10-16): minimise over the motion z and the coefficients
c_s

    J(z, c) = sum_{t,l} alpha_{t,l} rho(z_l(t) - y_l(t)) + lam sum_s ||z_s - E c_s||²   (11, 16)

with the Welsch function ``rho(r) = p²/2 (1 - exp(-r²/p²))`` (eq. 9) and binary weights
alpha (0 = missing, eq. 16). :func:`robust_filter` alternates (Sec. 3.4.3):

* coefficient step (eqs. 12-13): ``c_s = Eᵀ z_s`` for every window -- M matrix products
  ``Z[m:m+S] @ E_m`` (E_m = the L rows of E for window frame m), no window copies; the
  step and the overlap-add below form one fixed linear map, which
  :class:`WindowProjector` can also apply exactly as a multichannel FIR filter by FFT
  (cost independent of K; the default for long clips);
* motion step (eqs. 14-15): one IRLS step per outer iteration. Welsch is concave in r²,
  so ``rho(r) <= const + ½ w r²`` with ``w = exp(-r0²/p²) = rho'(r0)/r0`` at the current
  residual r0 (half-quadratic majoriser); minimising the majoriser plus the bases term
  (gradient ``alpha w (z - y) + 2 lam (n_t z - acc) = 0``) is, per frame and channel,
  the closed-form weighted average

      z_l(t) = (alpha w y_l(t) + 2 lam acc_l(t)) / (alpha w + 2 lam n_t)           (*)

  where ``acc(t) = sum_m E_m c_{t-m}`` sums the n_t overlapping window reconstructions
  of frame t (overlap-add, again M products). Each step cannot increase J, so the cost
  decreases monotonically.

  Note on eq. 15: printed as ``lam sum ||z - E_m c||² + sum_l w_l (z_l - y_l)²`` it drops
  the factor ½ that the IRLS majoriser of ``rho ~ r²/2`` carries, giving
  ``z = (w y + lam acc) / (w + lam n_t)``: the exact objective with lam/2. We implement
  the exact objective (11)/(16) with the paper's lam = 0.1; pass ``lam=0.05`` to
  reproduce the printed eq. 15.

Stopping: relative change of J below ``tol`` or ``max_iter`` iterations (paper: 10-20).
``p = inf`` gives rho(r) = r²/2 (plain least squares, the non-robust reference).

Missing entries (alpha = 0, eq. 16) are only moved by the averaging of window
reconstructions, a slow Jacobi-type iteration for long gaps; :func:`robust_filter`
therefore also sets them to their exact minimiser of J (conjugate gradients) before and
after the alternation (``fill_iter``; same objective, each step decreases J).
"""
from __future__ import annotations

from typing import Iterable

import numpy as np

from .. import gaps
from ..errors import MocapValueError
from ..windows import counts, lagged
from . import _linalg
from .info import SolveInfo

__all__ = ["lag_covariance", "learn_bases", "choose_k", "welsch",
           "welsch_weight", "coefficients", "overlap_add",
           "robust_filter", "objective", "dense_quadratic_reference", "WindowProjector"]


# ---------------------------------------------------------------------------------------
# training
# ---------------------------------------------------------------------------------------
def _check_clips(clips: Iterable[np.ndarray], M: int) -> tuple[list[np.ndarray], int]:
    out, L = [], None
    for X in clips:
        X = np.ascontiguousarray(X, dtype=float)
        if X.ndim != 2:
            raise MocapValueError(f"training clips must be (T, L) arrays, got shape {X.shape}")
        if L is None:
            L = X.shape[1]
        elif X.shape[1] != L:
            raise MocapValueError(f"training clips have different channel counts ({L} vs {X.shape[1]})")
        if not np.isfinite(X).all():
            raise MocapValueError("training clips must be complete (finite); fill gaps first")
        out.append(X)
    if L is None:
        raise MocapValueError("learning filter bases needs at least one training clip")
    return out, L


def lag_covariance(clips: Iterable[np.ndarray], M: int, *, method: str = "lag",
                   chunk: int = 2048) -> tuple[np.ndarray, int]:
    """Unnormalised grand lag-covariance ``G = DᵀD`` (ML x ML, frame-major) summed over
    clips, and the number of windows S (so ``C_D = G / S``, eqs. 3-5).

    Parameters
    ----------
    clips : (T_i, L) arrays (complete). Clips shorter than M contribute nothing.
    M : window length in frames.
    method : how DᵀD is accumulated (all give the same matrix up to rounding):

        * ``'lag'`` (default) -- never forms D. Block (m, m+d) of DᵀD is
          ``sum_{t=m}^{m+S-1} x_t x_{t+d}ᵀ``: block (0, d) is ``X[:S]ᵀ X[d:d+S]`` (all d
          in one product with the zero-copy window view); every other block on that
          block diagonal differs from it only by the first m terms removed and m terms
          past S added -- outer products of each clip's first and last M-1 frames,
          summed over clips and cumulated once at the end. Cost ``2 M S L²`` flops (M/2
          times less than DᵀD) and O((ML)²) memory.
        * ``'chunked'`` -- forms ``chunk`` rows of D at a time (a zero-copy view) and adds
          their Gram matrix: ``S (ML)²`` flops, O(chunk ML) extra memory.
        * ``'dense'`` -- forms D for the whole clip (reference; O(S ML) memory).

    Returns
    -------
    G : (M*L, M*L) float64, symmetric.
    S : total number of windows.
    """
    clips, L = _check_clips(clips, M)
    M = int(M)
    if M < 1:
        raise MocapValueError(f"window length M must be >= 1, got {M}")
    if method not in ("lag", "chunked", "dense"):
        raise MocapValueError(f"method must be 'lag', 'chunked' or 'dense', got {method!r}")
    n = M * L
    G = np.zeros((n, n))
    S_tot = 0
    B0_sum = np.zeros((L, n)) if method == "lag" else None   # sum over clips of X[:S]ᵀ [X[d:d+S]]_d
    heads, tails = [], []
    for X in clips:
        T = X.shape[0]
        S = T - M + 1
        if S <= 0:
            continue
        S_tot += S
        if method == "dense":
            D = lagged(X, M)
            G += D.T @ D
        elif method == "chunked":
            D = lagged(X, M, view=True)
            for a in range(0, S, chunk):
                B = np.array(D[a:a + chunk])
                G += B.T @ B
        else:
            if S * n <= 4_000_000:
                B0_sum += X[:S].T @ lagged(X, M, view=True)
            else:
                for d in range(M):
                    B0_sum[:, d * L:(d + 1) * L] += X[:S].T @ X[d:d + S]
            heads.append(X[:M - 1])                            # the corrections use only
            tails.append(X[S:])                                # the first / last M-1 frames
    if S_tot == 0:
        raise MocapValueError(f"no training clip is at least M = {M} frames long")
    if method == "lag" and M > 1:
        _lag_blocks(G, B0_sum, np.stack(heads), np.stack(tails), M, L)
    elif method == "lag":
        G += B0_sum
    return G, S_tot


def _lag_blocks(G: np.ndarray, B0_sum: np.ndarray, Hd: np.ndarray, Tl: np.ndarray, M: int,
                L: int) -> None:
    """Fill G (ML, ML) from the first block row ``B0_sum`` (L, ML) of DᵀD and the clips'
    first / last M-1 frames ``Hd`` / ``Tl`` (C, M-1, L) (method ``'lag'`` of
    :func:`lag_covariance`): block (m, m+d) = B0[d] - sum_{t<m} x_t x_{t+d}ᵀ +
    sum_{t<m} x_{S+t} x_{S+t+d}ᵀ, the two sums taken over all clips at once."""
    Gv = G.reshape(M, L, M, L)
    for d in range(M):
        k = M - d - 1
        blocks = np.repeat(B0_sum[:, d * L:(d + 1) * L][None], k + 1, axis=0)
        if k > 0:
            diff = (np.einsum("cti,ctj->tij", Tl[:, :k], Tl[:, d:d + k])
                    - np.einsum("cti,ctj->tij", Hd[:, :k], Hd[:, d:d + k]))
            blocks[1:] += np.cumsum(diff, axis=0)
        m = np.arange(k + 1)
        Gv[m, :, m + d, :] = blocks
        if d > 0:
            Gv[m + d, :, m, :] = blocks.transpose(0, 2, 1)


def choose_k(eigvals: np.ndarray, energy: float | None = 0.99, n_bases: int | None = None) -> int:
    """Number of bases: ``n_bases`` if given, else the smallest K whose top-K eigenvalues
    hold at least ``energy`` of the total (sum of all eigenvalues = trace of C_D)."""
    ev = np.clip(np.asarray(eigvals, dtype=float), 0, None)
    n = len(ev)
    if n_bases is not None:
        k = int(n_bases)
        if not 1 <= k <= n:
            raise MocapValueError(f"n_bases must be in 1..{n} (window x channels), got {n_bases!r}")
        return k
    e = float(energy)
    if not 0 < e <= 1:
        raise MocapValueError(f"energy must be a fraction in (0, 1], got {energy!r}")
    tot = ev.sum()
    if tot <= 0:
        return 1
    if e >= 1:
        return int(max(1, (ev > tot * 1e-12).sum()))
    return int(min(n, np.searchsorted(np.cumsum(ev) / tot, e - 1e-12) + 1))


@_linalg.one_blas_thread
def learn_bases(clips: Iterable[np.ndarray], M: int, *, energy: float | None = 0.99,
                n_bases: int | None = None, method: str = "lag") -> tuple[np.ndarray, np.ndarray, int]:
    """M-SSA filter bases (Sec. 3.1): eigenvectors of the grand lag-covariance.

    Parameters
    ----------
    clips : (T_i, L) training arrays (already centred/scaled as the caller wants).
    M : window length (frames).
    energy : keep the smallest K holding this fraction of the eigenvalue sum (paper:
        0.99); ignored when ``n_bases`` is given.
    n_bases : fixed K.
    method : accumulation of DᵀD, see :func:`lag_covariance`.

    Returns
    -------
    E : (M*L, K) orthonormal columns, frame-major rows, by decreasing eigenvalue.
    eigvals : (M*L,) all eigenvalues of C_D = DᵀD / S, decreasing (units²).
    S : number of training windows.
    """
    G, S = lag_covariance(clips, M, method=method)
    C = G / S
    w, V = _linalg.eigh(C, what="lou-chai bases")
    w, V = w[::-1], V[:, ::-1]
    k = choose_k(w, energy, n_bases)
    E = np.ascontiguousarray(V[:, :k])
    # deterministic sign: largest-magnitude entry of each basis positive
    sgn = np.sign(E[np.argmax(np.abs(E), axis=0), np.arange(k)])
    E *= np.where(sgn == 0, 1.0, sgn)
    return E, np.clip(w, 0, None), S


# ---------------------------------------------------------------------------------------
# robust estimator
# ---------------------------------------------------------------------------------------
def welsch(r: np.ndarray, p: float) -> np.ndarray:
    """Welsch function (eq. 9) ``p²/2 (1 - exp(-r²/p²))``; ``p = inf`` gives r²/2."""
    r = np.asarray(r, dtype=float)
    if np.isinf(p):
        return 0.5 * r * r
    return 0.5 * p * p * -np.expm1(-(r * r) / (p * p))


def welsch_weight(r: np.ndarray, p: float) -> np.ndarray:
    """IRLS weight ``rho'(r)/r = exp(-r²/p²)`` (Fig. 2c); 1 for ``p = inf``."""
    r = np.asarray(r, dtype=float)
    if np.isinf(p):
        return np.ones_like(r)
    return np.exp(-(r * r) / (p * p))


# ---------------------------------------------------------------------------------------
# the alternating solver
# ---------------------------------------------------------------------------------------
def _split_bases(E: np.ndarray, M: int, L: int) -> np.ndarray:
    """E (M*L, K) -> (M, L, K): E_m = rows of window frame m (the paper's E_m, eq. 14)."""
    if E.shape[0] != M * L:
        raise MocapValueError(f"bases have {E.shape[0]} rows but window {M} x {L} channels = {M * L}")
    return np.ascontiguousarray(E.reshape(M, L, -1))


def coefficients(Z: np.ndarray, Em: np.ndarray) -> np.ndarray:
    """c_s = Eᵀ z_s for every window s (eq. 13), as M products ``Z[m:m+S] @ E_m``.

    Z (T, L), Em (M, L, K) -> C (S, K)."""
    M = Em.shape[0]
    S = Z.shape[0] - M + 1
    C = Z[:S] @ Em[0]
    for m in range(1, M):
        C += Z[m:m + S] @ Em[m]
    return C


def overlap_add(C: np.ndarray, Em: np.ndarray, T: int) -> np.ndarray:
    """acc(t) = sum over windows s containing t of (E c_s) at frame t (eq. 14's sum).

    C (S, K), Em (M, L, K) -> (T, L)."""
    M, L, _ = Em.shape
    S = C.shape[0]
    acc = np.zeros((T, L))
    for m in range(M):
        acc[m:m + S] += C @ Em[m].T
    return acc


class WindowProjector:
    """The composed linear map ``A(z) = sum_s S_sᵀ E Eᵀ S_s z`` (T, L) -> (T, L): the
    coefficient step ``c_s = Eᵀ z_s`` (eq. 13) followed by the overlap-add of the window
    reconstructions ``E c_s`` onto the frames (the sum in eq. 14).

    Exact implementations (same result up to rounding):

    * ``'direct'`` -- :func:`coefficients` then :func:`overlap_add`: 4 T M L K flops.
    * ``'fft'`` -- in the interior of the clip A is a multichannel FIR filter
      ``A(z)(t) = sum_d H_d z(t+d)``, ``H_d = sum_m E_m E_{m+d}ᵀ`` (|d| < M), whose
      frequency response is ``Ẽ(f) Ẽ(f)ᴴ`` with ``Ẽ(f) = sum_m E_m e^{-2 pi i f m / N}``.
      It is applied by overlap-save over blocks of N frames (about 8 L² real flops per
      frame, independent of K); the 2(M-1) "phantom" windows that the zero-padded
      convolution adds at each end are then subtracted exactly (their coefficients are
      computed directly). Faster than ``'direct'`` once K is more than a few tens.
    * ``'fft32'`` -- the same in single precision (relative error ~1e-6, i.e. ~1e-5 cm
      on body-frame positions), about twice as fast.
    * ``'auto'`` -- ``'fft32'`` when its estimated cost for ``n_calls`` applications
      (set-up included) is below that of ``'direct'``, else ``'direct'``.

    ``cache`` (a dict) keeps the frequency responses between projectors with the same
    bases and block length (e.g. the phases of one clip, or clips of equal length).
    """

    def __init__(self, E: np.ndarray, M: int, L: int, T: int, method: str = "auto",
                 n_calls: int = 25, cache: dict | None = None):
        import scipy.fft as sfft

        self.M, self.L, self.T = int(M), int(L), int(T)
        self.E = np.ascontiguousarray(E, dtype=float)
        self.Em = _split_bases(self.E, self.M, self.L)
        K = self.E.shape[1]
        pad = 2 * (M - 1)
        pow2 = lambda n: 1 << int(np.ceil(np.log2(max(n, 1))))   # noqa: E731
        N = min(pow2(max(8 * pad, 64)), pow2(T + pad))   # ~8x the overlap, no longer than needed
        N = max(N, pow2(pad + 1))                        # at least one new frame per block
        if method == "auto":
            F, nb = N // 2 + 1, -(-T // (N - pad))
            direct = 4.0 * T * M * L * K * n_calls
            fft = 8.0 * F * L * L * K + n_calls * (4.0 * F * L * L * nb + 5.0 * L * N * nb * np.log2(N)
                                                   + 8.0 * M * M * L * K)
            method = "fft32" if fft < direct else "direct"
        if method not in ("direct", "fft", "fft32"):
            raise MocapValueError(f"method must be 'auto', 'direct', 'fft' or 'fft32', got {method!r}")
        self.method = method
        if method != "direct":
            self.dtype = np.float32 if method == "fft32" else np.float64
            self.N, self.B = N, N - pad
            key = (method, N, M, L, K, id(E) if cache is not None else None)
            if cache is not None and key in cache and cache[key][0] is E:
                self.HfT = cache[key][1]
            else:
                Et = sfft.rfft(self.Em, n=N, axis=0)                    # (F, L, K)
                HfT = np.conj(Et) @ Et.transpose(0, 2, 1)               # (F, L, L) = Hf transposed
                self.HfT = np.ascontiguousarray(HfT, dtype=np.complex64 if method == "fft32" else np.complex128)
                if cache is not None:
                    cache[key] = (E, self.HfT)

    def __call__(self, Z: np.ndarray) -> np.ndarray:
        import scipy.fft as sfft

        if self.method == "direct":
            return overlap_add(coefficients(Z, self.Em), self.Em, self.T)
        M, L, T, N, B = self.M, self.L, self.T, self.N, self.B
        pad = M - 1
        nb = -(-T // B)
        Zp = np.zeros((nb * B + 2 * pad, L), dtype=self.dtype)
        Zp[pad:pad + T] = Z
        blocks = np.lib.stride_tricks.as_strided(            # (N, nb, L): block b = Zp[bB : bB+N]
            Zp, shape=(N, nb, L), strides=(Zp.strides[0], B * Zp.strides[0], Zp.strides[1]),
            writeable=False)
        # (the whole-clip spectra are released as soon as they are used: issue 21)
        Xf = sfft.rfft(blocks, axis=0)                                  # (F, nb, L)
        del blocks, Zp
        Yf = Xf @ self.HfT                                              # row vectors: x Hᵀ = (H x)ᵀ
        del Xf
        y = sfft.irfft(Yf, n=N, axis=0)[pad:pad + B]                    # (B, nb, L)
        del Yf
        full = np.empty((nb * B, L))                  # blocks back to frames, cast to float64
        full.reshape(nb, B, L)[...] = y.transpose(1, 0, 2)
        del y
        acc = full[:T]
        if pad:
            # subtract the phantom windows starting at -(M-1)..-1 and T-M+1..T-1: each needs
            # the 2(M-1) rows lo..lo+2(M-1) of the clip zero-padded by M-1 frames per side
            for lo, sl_buf, sl_acc in ((0, slice(pad, 2 * pad), slice(0, pad)),
                                       (T, slice(0, pad), slice(T - pad, T))):
                buf = np.zeros((2 * pad, L))
                a, b = max(lo, pad), min(lo + 2 * pad, pad + T)      # padded rows that hold Z
                if b > a:
                    buf[a - lo:b - lo] = Z[a - pad:b - pad]
                Cph = coefficients(buf, self.Em)                        # (M-1, K)
                acc[sl_acc] -= overlap_add(Cph, self.Em, 2 * pad)[sl_buf]
        return acc


def objective(Z, Y, alpha, A, n_t, lam: float, p: float) -> float:
    """J(z, c) of eq. 11/16 at the optimal coefficients ``c_s = Eᵀ z_s``, given
    ``A = WindowProjector(z)``: ``sum alpha rho(z-y) + lam (sum_t n_t ||z_t||² - sum_t z_t·A_t)``
    (E orthonormal, so ``||z_s - E c_s||² = ||z_s||² - ||c_s||²`` and
    ``sum_s ||c_s||² = sum_t z_t·A(z)_t``)."""
    data = float(np.sum(welsch(np.where(alpha, Z - Y, 0.0), p)))
    return data + lam * _prior(Z, A, n_t)


def _prior(Z, A, n_t) -> float:
    return max(float(n_t @ np.einsum("tl,tl->t", Z, Z) - np.einsum("tl,tl->", Z, A)), 0.0)


@_linalg.one_blas_thread
def robust_filter(Y: np.ndarray, E: np.ndarray, M: int, *, mask: np.ndarray | None = None,
                  lam: float = 0.1, p: float = 3.0, max_iter: int = 20, tol: float = 1e-4,
                  Z0: np.ndarray | None = None, method: str = "auto", fill_iter: int = 100,
                  cache: dict | None = None, return_info: bool = False):
    """Robust filtering with filter bases (Lou & Chai 2010, eqs. 11-16; module doc).

    Parameters
    ----------
    Y : (T, L) noisy data (same units and centring as the bases were learned in); entries
        where ``mask`` is False are ignored (may be NaN).
    E : (M*L, K) orthonormal filter bases, frame-major (:func:`learn_bases`).
    M : window length; T must be >= M.
    mask : (T, L) bool, True = observed (alpha = 1); default ``isfinite(Y)``.
    lam : weight of the filter-bases term (paper: 0.1).
    p : Welsch scale in the units of Y (paper: 3); ``np.inf`` = least squares.
    max_iter, tol : at most ``max_iter`` outer iterations; stop when the relative change
        of J is below ``tol``.
    Z0 : (T, L) initial motion; default Y linearly interpolated in time over its gaps
        (never-observed channels at 0: the training mean if Y is centred).
    method : implementation of the coefficient + overlap-add step, see
        :class:`WindowProjector` (``'auto'``, ``'direct'``, ``'fft'``, ``'fft32'``).
    cache : optional dict reused between calls with the same bases (:class:`WindowProjector`).
    fill_iter : before the first and after the last alternating iteration the missing
        entries (alpha = 0, no data term: the alternation moves them only slowly) are set
        to their exact minimiser of J, the others fixed -- ``(N - A)_mm z_m = (A z_o)_m``
        by at most ``fill_iter`` conjugate-gradient steps preconditioned by N = diag(n_t)
        (module docstring; J cannot increase). 0 = the paper's plain alternation.
    return_info : also return a :class:`~mocapkit.solvers.info.SolveInfo`: ``n_iter``
        (motion steps run), ``converged`` (the relative change of J fell to ``tol`` before
        ``max_iter`` motion steps), ``residual`` (that last relative change of J); extra
        ``cost`` (J before each motion step and at the end; non-increasing),
        ``fill_cg_iter`` and ``weights`` (alpha * w of the last step).

    Returns
    -------
    Z : (T, L) filtered motion (every entry finite), [info].

    Examples
    --------
    Bases learned from a clean 3-channel clip remove noise, an outlier and a gap:

    >>> import numpy as np
    >>> from mocapkit.solvers.robust_bases import learn_bases, robust_filter
    >>> t = np.arange(300) / 30.0
    >>> X = np.c_[np.sin(t), np.cos(2 * t), np.sin(3 * t + 1)]            # (300, 3)
    >>> E, _, _ = learn_bases([X], 10, n_bases=4)                         # (30, 4)
    >>> Y = X + 0.05 * np.random.default_rng(0).normal(size=X.shape)
    >>> Y[100, 0] += 3.0                                                  # an outlier
    >>> Y[150:160, 1] = np.nan                                            # a gap
    >>> Z, info = robust_filter(Y, E, 10, p=0.3, return_info=True)
    >>> rms = lambda A: float(np.sqrt(np.nanmean((A - X) ** 2)))
    >>> print(round(rms(Y), 2), round(rms(Z), 2), bool(abs(Z[100, 0] - X[100, 0]) < 0.01))
    0.11 0.04 True
    >>> info.converged, info.criterion
    (True, 'relative change of J')
    """
    Y, alpha, lam, p = _filter_args(Y, M, mask, lam, p)
    T, L = Y.shape
    M = int(M)
    proj = WindowProjector(E if isinstance(E, np.ndarray) and E.dtype == float else np.asarray(E, dtype=float),
                           M, L, T, method, n_calls=int(max_iter) + 2, cache=cache)
    Yf = Y if alpha.all() else np.where(alpha, Y, 0.0)        # only read (no copy if complete)
    Z = _start_motion(Y, alpha, Yf, Z0)
    n_t = counts(T, M)
    a = alpha.astype(float)
    miss = ~alpha
    fill = bool(miss.any() and fill_iter > 0)
    cg_its = 0
    if fill:
        Z, cg_its = _fill_missing(Z, miss, proj, n_t, int(fill_iter))
    Z, w, costs, it, done, rel = _alternate(Z, Yf, a, proj, n_t, lam, p, float(tol),
                                            max(1, int(max_iter)))
    if fill:
        Z, k = _fill_missing(Z, miss, proj, n_t, int(fill_iter))
        cg_its += k
        costs.append(_cost(Z, proj(Z), Yf, a, n_t, lam, p)[0])
    if return_info:
        return Z, SolveInfo(it, done, rel, "relative change of J",
                            {"cost": np.array(costs), "fill_cg_iter": cg_its, "weights": w})
    return Z


def _filter_args(Y, M: int, mask, lam: float, p: float) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Checked inputs of :func:`robust_filter`: Y (T, L) float, alpha (T, L) bool (observed
    and finite), lam, p."""
    Y = np.asarray(Y, dtype=float)
    if Y.ndim != 2:
        raise MocapValueError(f"Y must be a (T, L) array, got shape {Y.shape}")
    T, L = Y.shape
    if T < int(M):
        raise MocapValueError(f"the clip has {T} frames, fewer than the window length M = {int(M)}")
    alpha = np.isfinite(Y) if mask is None else (np.asarray(mask, dtype=bool) & np.isfinite(Y))
    if alpha.shape != (T, L):
        raise MocapValueError(f"mask must have shape {(T, L)}, got {alpha.shape}")
    lam = float(lam)
    p = float(p)
    if not lam > 0:
        raise MocapValueError(f"lam must be positive, got {lam!r}")
    if not p > 0:
        raise MocapValueError(f"Welsch p must be positive (or inf), got {p!r}")
    return Y, alpha, lam, p


def _start_motion(Y: np.ndarray, alpha: np.ndarray, Yf: np.ndarray, Z0) -> np.ndarray:
    """Initial motion of :func:`robust_filter`: ``Z0`` (checked), else Y with its missing
    entries linearly interpolated in time (never-observed channels at 0)."""
    if Z0 is None:
        return gaps.fill(Y, alpha, never_observed=0.0) if not alpha.all() else Yf.copy()
    Z = np.array(Z0, dtype=float)
    if Z.shape != Y.shape or not np.isfinite(Z).all():
        raise MocapValueError("Z0 must be a finite (T, L) array")
    return Z


def _cost(Z: np.ndarray, A: np.ndarray, Yf: np.ndarray, a: np.ndarray, n_t: np.ndarray,
          lam: float, p: float) -> tuple[float, np.ndarray]:
    """J (eq. 11/16) at motion Z with ``A = WindowProjector(Z)``, and the IRLS factors
    ``exp(-r^2/p^2)`` (rho'(r)/r, Fig. 2c; 1 for p = inf) of the residuals r = Z - Y."""
    R = Z - Yf
    if np.isinf(p):
        e = np.ones_like(R)
        data = 0.5 * float(np.sum(a * R * R))
    else:
        # e = exp(-(R R) / p^2), rho'(r)/r (Fig. 2c), computed in place in R
        e = np.multiply(R, R, out=R)
        np.negative(e, out=e)
        e /= p * p
        np.exp(e, out=e)
        t = np.subtract(1.0, e)
        t *= a
        data = 0.5 * p * p * float(np.sum(t))                  # eq. 9
        del t
    return data + lam * _prior(Z, A, n_t), e


def _alternate(Z: np.ndarray, Yf: np.ndarray, a: np.ndarray, proj, n_t: np.ndarray,
               lam: float, p: float, tol: float, n_max: int):
    """The alternation of :func:`robust_filter` (Sec. 3.4.3): coefficient step + overlap-add
    (eqs. 13-14, ``proj``), then the closed-form IRLS motion step (*) with the weights of
    eq. 15, until the relative change of J is <= ``tol`` or ``n_max`` motion steps.

    Returns (Z, last weights alpha w, J before each motion step and at the end, motion
    steps run, converged, last relative change of J).
    """
    two_lam_n = (2.0 * lam * n_t)[:, None]
    costs: list[float] = []
    w = a.copy()
    rel = float("inf")                                            # last relative change of J
    done = False
    for it in range(n_max + 1):
        A = proj(Z)                                               # eqs. 13-14
        J, e = _cost(Z, A, Yf, a, n_t, lam, p)
        if costs:
            rel = abs(costs[-1] - J) / max(abs(costs[-1]), 1e-300)
        done = bool(costs) and abs(costs[-1] - J) <= tol * max(abs(costs[-1]), 1e-300)
        costs.append(J)
        if done or it == n_max:
            break
        w = np.multiply(a, e, out=e)                              # eq. 15 (IRLS weights)
        # (*) = (w Yf + 2 lam A) / (w + 2 lam n_t), with in-place steps (fewer temporaries)
        num = np.multiply(w, Yf)
        A *= 2.0 * lam
        num += A
        del A
        num /= w + two_lam_n
        Z = num                                                   # (*)
    return Z, w, costs, it, done, rel


def _fill_missing(Z: np.ndarray, miss: np.ndarray, proj, n_t: np.ndarray, max_iter: int,
                  rtol: float = 1e-4) -> tuple[np.ndarray, int]:
    """Exact minimiser of the bases term over the missing entries, the others fixed:
    ``(N - A)_mm z_m = (A z_o)_m`` (N = diag n_t, A = window projector) by Jacobi-
    preconditioned conjugate gradients started from the current values."""
    N = np.broadcast_to(n_t[:, None], Z.shape)
    Zo = np.where(miss, 0.0, Z)
    b = proj(Zo)[miss]

    def op(v):
        full = np.zeros_like(Z)
        full[miss] = v
        return N[miss] * v - proj(full)[miss]

    x = Z[miss].copy()
    r = b - op(x)
    Minv = 1.0 / N[miss]
    zv = Minv * r
    d = zv.copy()
    rz = float(r @ zv)
    b_norm = max(float(np.linalg.norm(b)), 1e-300)
    k = 0
    while k < max_iter and np.linalg.norm(r) > rtol * b_norm:
        q = op(d)
        dq = float(d @ q)
        if dq <= 0:
            break
        step = rz / dq
        x += step * d
        r -= step * q
        zv = Minv * r
        rz_new = float(r @ zv)
        d = zv + (rz_new / rz) * d
        rz = rz_new
        k += 1
    out = Z.copy()
    out[miss] = x
    return out, k


def dense_quadratic_reference(Y: np.ndarray, E: np.ndarray, M: int, *, mask: np.ndarray | None = None,
                              lam: float = 0.1) -> np.ndarray:
    """Exact minimiser of eq. 16 with rho(r) = r²/2 (p = inf), by one dense solve.

    With c eliminated (c_s = Eᵀ z_s), J = ½ sum alpha (z-y)² + lam sum_s ||(I - EEᵀ) S_s z||²
    where S_s selects window s; the normal equations are
    ``(diag(alpha) + 2 lam sum_s S_sᵀ (I - EEᵀ) S_s) z = alpha y``. For tests on tiny
    problems only (O((TL)²) memory).
    """
    Y = np.asarray(Y, dtype=float)
    T, L = Y.shape
    alpha = np.isfinite(Y) if mask is None else (np.asarray(mask, dtype=bool) & np.isfinite(Y))
    n = M * L
    Q = np.eye(n) - E @ E.T
    H = np.zeros((T * L, T * L))
    for s in range(T - M + 1):
        sl = slice(s * L, s * L + n)
        H[sl, sl] += Q
    a = alpha.ravel().astype(float)
    A = np.diag(a) + 2.0 * lam * H
    b = a * np.where(alpha, Y, 0.0).ravel()
    return np.linalg.solve(A, b).reshape(T, L)
