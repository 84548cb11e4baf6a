"""Multichannel singular spectrum denoising with optimal singular-value shrinkage, and a
Monte-Carlo SURE to judge any denoiser on the clip itself.

A smoothing spline treats every coordinate alone; the body moves as one, so the lagged
trajectory matrix of a clip (rows = windows of ``window`` frames of all channels, the
embedding of multichannel SSA, Broomhead & King 1986) is close to low rank while white
noise spreads over every singular value. Its singular values are shrunk by the
Frobenius-optimal shrinker of Gavish & Donoho (2017, "Optimal shrinkage of singular
values", IEEE Trans. Inf. Theory 63:2137, eq. 7): in units of ``sigma sqrt(n)`` (n the
larger dimension, beta = m/n <= 1)

    eta(y) = sqrt((y^2 - beta - 1)^2 - 4 beta) / y   for y > 1 + sqrt(beta), else 0  (GD7)

and the windows are averaged back to frames. The noise level ``sigma`` comes from the GCV
spline (:func:`mocapkit.solvers.gcv_spline.gcv_smooth`). Long clips are processed in
blocks of ``block`` frames with tapered overlaps (the rank of a 2,000-frame block is what
matters; cost stays linear in T).

:func:`sure` is Stein's unbiased risk estimate for any denoiser f under white Gaussian
noise of known sigma, with the divergence by one random probe (Ramani, Blu & Unser 2008,
"Monte-Carlo SURE", IEEE Trans. Image Process. 17:1540, eq. 9-10):

    MSE ~= ||y - f(y)||^2 / N - sigma^2 + 2 sigma^2 b^T (f(y + e b) - f(y)) / (e N)

:func:`sure_weights` mixes several denoisers by the convex weights of lowest SURE: the
divergence is linear in f, so SURE of a mix is a quadratic in its weights.

>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> t = np.linspace(0, 4 * np.pi, 300)[:, None]
>>> truth = np.hstack([np.sin(t + k) * (5 + k) for k in range(6)])        # cm, rank 2
>>> noisy = truth + rng.normal(0, 1.0, truth.shape)
>>> out = mssa_denoise(noisy, 1.0, window=8)
>>> bool(np.sqrt(np.mean((out - truth) ** 2)) < 0.3)        # noise: 1 cm
True
>>> est = sure(lambda Y: mssa_denoise(Y, 1.0, window=8), noisy, 1.0, rng=1)   # MSE, cm^2
>>> bool(abs(est - np.mean((out - truth) ** 2)) < 0.1)    # SURE's own spread ~ sqrt(2/N)
True
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from ..errors import MocapValueError
from ..signal.noise import _diff, _gain     # the noise estimator's differences and gain

__all__ = ["mssa_denoise", "shrink", "sure", "sure_divergence", "sure_divergence_stacked", "sure_risk",
           "sure_weights", "correlated_probe"]


def shrink(y: np.ndarray, beta: float) -> np.ndarray:
    """Frobenius-optimal shrinker (GD7); y in units of sigma sqrt(n)."""
    t = (y ** 2 - beta - 1) ** 2 - 4 * beta
    return np.where(y > 1 + np.sqrt(beta), np.sqrt(np.maximum(t, 0)) / np.maximum(y, 1e-300), 0.0)


#: first rank the subspace iteration of a block tries (doubled until the smallest value found
#: is under the noise edge)
RANK0 = 128


def _next_rank(kept: int) -> int:
    """The smallest power-of-2 multiple of :data:`RANK0` above ``kept``: where the next
    block's subspace iteration starts (:func:`_block`)."""
    k = RANK0
    while k <= kept:
        k *= 2
    return k


def _block(X: np.ndarray, sigma: float, window: int, k0: int = RANK0) -> tuple[np.ndarray, int, int]:
    """One block: embed, shrink, average back. X (T, C) centred. Returns the block, the
    rank its subspace iteration ended at and the number of singular values kept.

    Only the singular values above the noise edge survive (GD7), so the decomposition is
    of growing rank: it starts at ``k0`` and doubles until the smallest value it found is
    under the edge (:func:`_gram_eig`: subspace iteration, Halko, Martinsson & Tropp 2011,
    on the Gram matrix of H's smaller side, formed from X by
    :func:`mocapkit.windows.lagged_gram` without a pass over H -- ``H^T H`` on a tall block
    (more windows than columns: the blocks of long clips), ``H H^T`` on a wide one (clips
    up to ~1,500 frames at 120 fps)); where twice the rank reaches the smaller side, the
    whole Gram matrix is decomposed (``eigh``). Then only the kept directions are carried
    to H's other side, one thin product. Measured against the route before (scikit-learn's
    randomized SVD on the wide H, the exact SVD where twice the rank reached its smaller
    side), mssa_denoise of CMU 135_02 with 1 cm noise, CPU time, one thread: 8 s at 120 fps
    (one 945 x 1,488 block) 134-271 -> 78 ms and 3.9e-3 -> 3.2e-3 cm RMS from the exact
    SVD's shrinkage; 12 s at 120 fps (1,425 x 1,488) 199-219 -> 177-187 ms, 1.1e-2 ->
    8.7e-3 cm; 8 s at 30 fps (237 x 372, exact either way) 10.1 -> 4.4 ms; 10,000 frames
    (tall blocks, the route unchanged but for the thin product) 2.1-3.0 -> 2.0-2.1 s, the
    same output to 6e-15 cm.
    The Gram matrix squares the condition number, which touches only singular values under
    ~1e-8 of the largest: far under the noise edge, where GD7 returns 0 anyway.
    """
    from ..windows import lagged, lagged_gram, overlap_mean

    T, C = X.shape
    H = lagged(X, window, view=True)                                  # (m, C window), no copy
    m, n = H.shape
    right = m >= n                      # decompose H^T H (right vectors) or H H^T (left)
    G = lagged_gram(X, window, "columns" if right else "rows")
    big, beta = max(m, n), min(m, n) / max(m, n)
    unit = sigma * np.sqrt(big)
    edge = unit * (1 + np.sqrt(beta))
    k = int(k0)
    while True:
        if 2 * k >= min(m, n):                 # small matrix: the whole Gram matrix
            lam, W = np.linalg.eigh(G)
            lam, W = lam[::-1], W[:, ::-1]
            break
        lam, W = _gram_eig(G, k)
        if np.sqrt(max(lam[-1], 0.0)) <= edge:
            break
        k *= 2
    S = np.sqrt(np.maximum(lam, 0.0))
    keep = S > edge
    if not keep.any():
        return np.zeros_like(X), k, 0
    W, S = W[:, keep], S[keep]
    f = shrink(S / unit, beta) * unit / S             # eta(s) / s: H's kept part, shrunk
    if right:                                         # H V diag(f) V^T
        Hd = ((H @ W) * f) @ W.T
    else:                                             # U diag(f) U^T H
        Hd = (W * f) @ (W.T @ H)
    return overlap_mean(Hd, T, window), k, int(keep.sum())


def _gram_eig(G: np.ndarray, k: int, n_iter: int = 5, oversample: int = 10
              ) -> tuple[np.ndarray, np.ndarray]:
    """The k largest eigenpairs ``(lam (k,), W (N, k))``, descending, of a Gram matrix G
    (N, N) -- squared singular values and one side's singular vectors of the matrix it is
    the Gram matrix of: subspace iteration ``Q <- orth(G Q)`` from a seeded Gaussian
    (N, k + oversample) start (Halko, Martinsson & Tropp 2011, Alg. 4.4 on G), then
    Rayleigh-Ritz on ``Q^T G Q``. ``n_iter`` products with G span what scikit-learn's
    ``randomized_svd`` with ``n_iter - 1`` power iterations on H spans (``G^n_iter`` times
    the start), each at a fraction of the flops of a pass over H and back: on a
    2,033 x 1,488 block of a CMU clip, k = 256, n_iter = 5: 0.38 s against 0.52 s, and
    1.5e-3 cm RMS from the exact SVD's shrinkage against 1.9e-3 (n_iter = 4 would give
    3.0e-3)."""
    Q = np.random.default_rng(0).standard_normal((G.shape[0], min(k + oversample, G.shape[0])))
    for _ in range(n_iter):
        Q, _ = np.linalg.qr(G @ Q)
    lam, W = np.linalg.eigh(Q.T @ G @ Q)
    return lam[::-1][:k], Q @ W[:, ::-1][:, :k]


def mssa_denoise(X, sigma: float, *, window: int, block: int = 2048,
                 ranks: list[int] | None = None) -> np.ndarray:
    """Denoise a complete (T, C) matrix (cm) with white noise of std ``sigma`` (cm).

    window : embedding length in frames (about 0.13 s: 4 at 30 fps, 16 at 120 fps was
        measured best on CMU clips). block : frames per block for long clips.
    ranks : where each block's subspace iteration starts (:func:`_block`). Empty (or None):
        the first block at :data:`RANK0`, each next one at the smallest power-of-2
        multiple of it above the previous block's kept count (neighbouring blocks keep
        similar ranks: a clip whose blocks keep 130-250 values paid a rank-128 try per
        block before its rank-256 one; that alone took mssa_denoise at 10,000 frames,
        120 fps, from 4.7-5.4 to 3.6-4.5 s). Given as a list, it is filled with the rank
        each block ended at; a list so filled makes a second call (SURE's probe of
        :func:`sure_divergence`) start every block where the first ended, i.e. compute the
        same map without the first call's tries.
    """
    X = np.asarray(X, dtype=float)
    if X.ndim != 2 or not np.isfinite(X).all():
        raise MocapValueError("mssa: needs a complete, finite (T, C) matrix")
    T = X.shape[0]
    window = int(window)
    if not (2 <= window <= T // 2):
        raise MocapValueError(f"mssa: window must be 2..T/2 frames, got {window} for T={T}")
    if not (sigma > 0):
        return X.copy()
    given = list(ranks) if ranks else []
    used = []
    mu = X.mean(axis=0)
    if T <= block:
        y, k, _ = _block(X - mu, float(sigma), window, given[0] if given else RANK0)
        used.append(k)
        out = y + mu
    else:
        # long clips: each block is centred on its own copy and the tapered sum is scaled
        # in place (no centred copy of the whole clip and no whole-clip temporaries; the
        # same element operations as centring first)
        ov = 4 * window                                                # overlap per side
        out = np.zeros_like(X)
        wsum = np.zeros(T)
        k0 = RANK0
        for i, a in enumerate(range(0, T, block - 2 * ov)):
            b = min(T, a + block)
            a = max(0, b - block)
            w = np.ones(b - a)
            ramp = np.linspace(0.0, 1.0, ov + 2)[1:-1]
            if a > 0:
                w[:ov] = ramp
            if b < T:
                w[-ov:] = ramp[::-1]
            y, k, kept = _block(X[a:b] - mu, float(sigma), window, given[i] if i < len(given) else k0)
            used.append(k)
            k0 = _next_rank(kept)
            y *= w[:, None]
            out[a:b] += y
            wsum[a:b] += w
            if b == T:
                break
        out /= wsum[:, None]
        out += mu
    if ranks is not None:
        ranks[:] = used
    return out


def sure(f: Callable[[np.ndarray], np.ndarray], Y: np.ndarray, sigma: float, *,
         mask: np.ndarray | None = None, eps: float | None = None, rng=0,
         fy: np.ndarray | None = None) -> float:
    """Monte-Carlo SURE (module docstring) of the denoiser ``f`` at ``Y``: an unbiased
    estimate of the mean squared error per entry against the noise-free signal, over the
    entries in ``mask`` (default all). ``fy``: f(Y) if already computed."""
    Y = np.asarray(Y, dtype=float)
    if not (sigma > 0) or (mask is not None and not np.any(mask)):
        return float("nan")
    f0 = f(Y) if fy is None else fy
    return sure_risk(Y, f0, sigma, sure_divergence(f, Y, sigma, mask=mask, eps=eps, rng=rng, fy=f0), mask=mask)


def sure_divergence(f: Callable[[np.ndarray], np.ndarray], Y: np.ndarray, sigma: float, *,
                    mask: np.ndarray | None = None, eps: float | None = None, rng=0,
                    fy: np.ndarray | None = None, probe: np.ndarray | None = None) -> float:
    """The Monte-Carlo divergence ``b^T (f(Y + e b) - f(Y)) / e`` of :func:`sure` (one
    random +-1 probe b on the entries in ``mask``, e = 0.01 sigma unless given). Linear in
    f for a fixed probe: the divergence of a mean of denoisers is the mean of theirs, so
    :func:`sure_risk` scores such a mean without running it (same ``rng``). ``probe``
    (T, C): this probe instead (e.g. :func:`correlated_probe`, for noise correlated across
    channels), zeroed outside ``mask``."""
    Y = np.asarray(Y, dtype=float)
    b, e = _probe_step(Y, sigma, mask, eps, rng, probe)
    f0 = f(Y) if fy is None else fy
    # the same arithmetic as sum(b * (f(Y + e b) - f0)), in place: at most Y, b, f0 and
    # one more array of Y's size besides what f needs (a 100,000-frame clip held 5 more)
    Yp = b * e
    Yp += Y
    fp = f(Yp)
    del Yp
    return _divergence(fp, f0, b, e)


def sure_divergence_stacked(f: Callable[[np.ndarray], np.ndarray], Y: np.ndarray, sigma: float, *,
                            mask: np.ndarray | None = None, eps: float | None = None, rng=0,
                            probe: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """(f(Y), :func:`sure_divergence`) from one call of a *channel-wise* denoiser ``f`` on
    Y and Y + e b side by side, (T, 2C) -> (T, 2C): a smoother that runs a loop over the
    frames (a Kalman filter) makes it once for both. The same numbers as ``f(Y)`` and
    ``sure_divergence(f, Y, ...)`` wherever ``f`` treats each column on its own.

    >>> import numpy as np
    >>> Y = np.random.default_rng(0).normal(size=(50, 4))
    >>> f = lambda Z: 0.5 * (Z + np.roll(Z, 1, axis=0))
    >>> fy, d = sure_divergence_stacked(f, Y, 1.0)
    >>> bool(np.array_equal(fy, f(Y))), d == sure_divergence(f, Y, 1.0)
    (True, True)
    """
    Y = np.asarray(Y, dtype=float)
    b, e = _probe_step(Y, sigma, mask, eps, rng, probe)
    Yp = b * e
    Yp += Y
    both = f(np.concatenate([Y, Yp], axis=1))
    del Yp
    C = Y.shape[1]
    f0 = np.ascontiguousarray(both[:, :C])
    return f0, _divergence(np.array(both[:, C:]), f0, b, e)


def _probe_step(Y: np.ndarray, sigma: float, mask, eps, rng, probe) -> tuple[np.ndarray, float]:
    """The probe b (T, C), zero outside ``mask``, and the step e of :func:`sure_divergence`."""
    M = np.ones(Y.shape, bool) if mask is None else np.asarray(mask, bool)
    if probe is None:
        g = np.random.default_rng(rng)
        b = np.where(g.random(Y.shape) < 0.5, -1.0, 1.0)
    else:
        b = np.array(probe, dtype=float)
    b *= M
    return b, (0.01 * sigma if eps is None else eps)


def _divergence(fp: np.ndarray, f0: np.ndarray, b: np.ndarray, e: float) -> float:
    """b^T (fp - f0) / e, in place in ``fp``."""
    fp -= f0
    fp *= b
    return float(np.sum(fp)) / e


def correlated_probe(Y: np.ndarray, mask: np.ndarray | None, sigma: float, rng=0) -> np.ndarray | None:
    """A SURE probe (T, C) whose frames are independent and whose channels are correlated
    as the noise is: Gaussian with the covariance of the clip's fourth differences (scaled
    to unit noise gain, each pair of channels over the frames where both are in ``mask``),
    shrunk towards a multiple of the identity (Ledoit & Wolf 2004), over ``sigma``^2.

    With such a probe the divergence of :func:`sure_divergence` estimates
    tr(J Sigma) / sigma^2, Sigma the noise covariance across channels within a frame, in
    place of tr(J): SURE for correlated noise (Eldar 2009). It matters where the noise is
    shared between channels -- positions read back from a rotation file (BVH, AMC), where a
    joint's error is in large part its parent's and a zero-length joint's is its parent's
    exactly: a smoother that mixes channels (MSSA) keeps noise that looks like the
    signal's correlation, and the +-1 probe, blind to it, rates it best. The shrinkage
    (intensity from the spread of the products the covariance averages, the Ledoit-Wolf
    estimate written for pairwise counts) keeps the chance structure of a short clip's
    covariance -- and the fast motion that leaks into the differences at 30 fps, which
    lies along the signal's own directions -- from being taken for shared noise (measured
    2026-12-05, eighth session, geometric mean RMSE against the +-1 probe: through BVH, 18
    held-out cases, -6.6 % without the shrinkage, -7.3 % with it; through AMC, 14 cases,
    -0.7 / -2.3 %; in memory on fast clips, 12 cases, +1.9 / +1.0 %).
    For white noise the probe is ~N(0, I) and SURE the usual one. None when a channel has
    fewer than 8 fourth differences.

    Example
    -------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> n = rng.normal(size=(2000, 1))
    >>> b = correlated_probe(np.hstack([n, n, rng.normal(size=(2000, 1))]), None, 1.0)
    >>> bool(np.corrcoef(b[:, 0], b[:, 1])[0, 1] > 0.9), b.shape
    (True, (2000, 3))
    """
    Y = np.asarray(Y, dtype=float)
    M = np.ones(Y.shape, bool) if mask is None else np.asarray(mask, bool)
    if not (sigma > 0) or Y.shape[0] < 12:
        return None
    D, Md = _diff(np.where(M, Y, 0.0), M, 4)   # fourth differences, where all five are kept
    W = Md.astype(float)
    n = W.T @ W                                 # frames behind each pair of channels
    if np.diag(n).min() < 8:
        return None
    D[~Md] = 0.0
    D /= _gain(4) * sigma                       # unit noise gain
    n = np.maximum(n, 1.0)
    S = (D.T @ D) / n
    D *= D
    spread = np.maximum((D.T @ D) / n - S * S, 0.0) / n     # variance of each entry of S
    C = S.shape[0]
    mu = float(np.trace(S)) / C
    dist = float(np.sum((S - mu * np.eye(C)) ** 2))
    a = 1.0 if dist <= 0 else min(float(spread.sum()), dist) / dist
    S = (1.0 - a) * S + a * mu * np.eye(C)
    lam, V = np.linalg.eigh(S)
    R = V * np.sqrt(np.clip(lam, 0.0, None))   # S = R R^T
    return np.random.default_rng(rng).standard_normal(Y.shape) @ R.T


def sure_risk(Y: np.ndarray, fy: np.ndarray, sigma: float, div: float, *,
              mask: np.ndarray | None = None) -> float:
    """``||Y - f(Y)||^2 / N - sigma^2 + 2 sigma^2 div / N`` over the N entries in ``mask``
    (:func:`sure` with its divergence given), summed in frame blocks (no temporaries of
    Y's size)."""
    from ..windows import frame_blocks

    Y = np.asarray(Y, dtype=float)
    M = None if mask is None else np.asarray(mask, bool)
    N = Y.size if M is None else int(M.sum())
    if N == 0 or not (sigma > 0):
        return float("nan")
    rss = 0.0
    for sl in frame_blocks(Y.shape[0]):
        r = Y[sl] - fy[sl]
        r *= r
        rss += float(r.sum()) if M is None else float(r[M[sl]].sum())
    return rss / N - sigma ** 2 + 2 * sigma ** 2 * div / N


def sure_weights(Y: np.ndarray, outs: list[np.ndarray], sigma: float, divs, *,
                 mask: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Convex weights w (w >= 0, sum 1) of the denoisers' outputs ``outs`` (each like Y)
    of lowest SURE, and that SURE (MSE per entry in ``mask``).

    The divergence of ``sum w_k f_k`` is ``sum w_k div_k`` (``divs``, from
    :func:`sure_divergence` with one probe) and its residual is ``sum w_k (Y - f_k)``, so
    SURE(w) = w^T G w / N - sigma^2 + 2 sigma^2 w . div / N, with G the Gram matrix of the
    residuals over the N entries in ``mask`` (Ramani et al. 2008's estimate, minimised over
    the simplex; the K <= 4 weights are few against the N ~ 10^4-10^6 entries SURE
    averages over). Solved exactly: the KKT system on every support, the best feasible one
    kept. A single denoiser, or a 50/50 mean, is a point of the simplex, so the mix is never
    rated worse than any of them.

    >>> rng = np.random.default_rng(0)
    >>> truth = np.cumsum(rng.normal(size=(400, 3)), axis=0)
    >>> Y = truth + rng.normal(size=truth.shape)
    >>> w, risk = sure_weights(Y, [Y, np.zeros_like(Y) + Y.mean(0)], 1.0, [Y.size, 3.0])
    >>> bool(w[0] > 0.9 and abs(w.sum() - 1) < 1e-12)          # the identity wins here
    True
    """
    from itertools import combinations

    from ..windows import frame_blocks

    Y = np.asarray(Y, dtype=float)
    M = None if mask is None else np.asarray(mask, bool)
    K = len(outs)
    N = Y.size if M is None else int(M.sum())
    d = np.asarray(divs, dtype=float)
    if K == 0 or d.shape != (K,):
        raise MocapValueError(f"sure_weights: {K} outputs but divergences of shape {d.shape}")
    if N == 0 or not (sigma > 0):
        return np.full(K, 1.0 / K), float("nan")
    G = np.zeros((K, K))
    for sl in frame_blocks(Y.shape[0]):          # no temporaries of Y's size
        R = np.stack([(Y[sl] - f[sl]) if M is None else (Y[sl] - f[sl])[M[sl]] for f in outs])
        G += R.reshape(K, -1) @ R.reshape(K, -1).T
    s2 = float(sigma) ** 2
    best_val, best_w = np.inf, np.eye(K)[0]
    for r in range(1, K + 1):
        for S in combinations(range(K), r):
            S = list(S)
            A = np.zeros((r + 1, r + 1))           # [2G 1; 1^T 0] [w; lam] = [-2 s2 d; 1]
            A[:r, :r] = 2.0 * G[np.ix_(S, S)]
            A[:r, r] = A[r, :r] = 1.0
            b = np.append(-2.0 * s2 * d[S], 1.0)
            try:
                w_s = np.linalg.solve(A, b)[:r]
            except np.linalg.LinAlgError:          # two identical outputs: a larger support
                continue                           # repeats a smaller one's optimum
            if (w_s < 0).any():
                continue
            w = np.zeros(K)
            w[S] = w_s
            val = float(w @ G @ w + 2.0 * s2 * (d @ w)) / N - s2
            if val < best_val:
                best_val, best_w = val, w
    return best_w, best_val
