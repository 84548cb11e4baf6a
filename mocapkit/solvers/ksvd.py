"""K-SVD dictionary learning with Batch-OMP (Xiao et al. 2015, seed 000, eqs. 1-2).

Xiao et al. learn one dictionary per poselet by solving their eq. (1)/(2)::

    min_{D, W}  ||B - D W||_F^2   s.t.  ||w_j||_0 <= T_s  for every column j,

with unit-norm atoms (columns of ``D``), using "a fast variant of K-SVD" -- the
*approximate* K-SVD with Batch-OMP of Rubinstein, Zibulevsky & Elad (2008), "Efficient
implementation of the K-SVD algorithm using batch orthogonal matching pursuit",
Technion CS-2008-08 (their ref. [40]; Alg. 5 there).  This module is our own
implementation on numpy:

* **Sparse coding** (:func:`batch_omp`): Batch-OMP from the Gram matrix ``G = D^T D``
  and ``D^T y`` only (Rubinstein et al. Alg. 2), vectorised over *all* samples at once
  (every sample selects its next atom in the same step; the least-squares coefficients
  on the selected atoms are solved as one batched ``(N, s, s)`` system per step).  It
  returns the same codes as :func:`sklearn.linear_model.orthogonal_mp_gram` (the tests
  check this), about 50x faster on K=512 dictionaries, because scikit-learn loops over
  samples in Python and copies the K x K Gram matrix for each one.
  ``omp="sklearn"`` uses scikit-learn instead.
* **Dictionary update** (approximate K-SVD, Rubinstein et al. Alg. 5): atoms are
  updated one after the other (random order each sweep); for atom k with support I
  (samples that use it) and residual ``E_I`` without atom k, one power step
  ``d = E_I g / ||E_I g||``, ``g = E_I^T d`` replaces the rank-1 SVD of exact K-SVD
  (Aharon, Elad & Bruckstein 2006); ``exact=True`` uses the SVD.  The residual
  ``Y - D W`` is kept up to date, so one sweep costs O(N T_s n).
* **Dead / duplicate atoms** (as in Rubinstein's KSVD-Box): an atom used by no sample,
  or whose |cosine| with another atom exceeds ``mu_thresh`` (0.99), is replaced by the
  worst-represented training sample (largest residual), normalised.
* **Initialisation** (``init="data"``, default): ``n_atoms`` distinct random training
  samples, normalised to unit length (KSVD-Box default).  With fewer usable samples than
  atoms the rest are random Gaussian unit vectors.  ``init`` may also be an (n, K) array.

Shapes (rows are samples, as everywhere in mocapkit; the paper stores columns):
``Y`` (N, n) training samples, dictionary ``D`` (n, K) with unit-norm columns, codes
``W`` (N, K) (the transpose of the paper's W).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import MocapValueError
from . import _linalg

__all__ = ["batch_omp", "ksvd", "KSVDResult", "normalize_atoms"]


def normalize_atoms(D: np.ndarray) -> np.ndarray:
    """Columns of ``D`` scaled to unit l2 norm (zero columns left as zero)."""
    D = np.asarray(D, dtype=np.float64)
    n = np.linalg.norm(D, axis=0)
    return D / np.where(n > 0, n, 1.0)


def batch_omp(Xy: np.ndarray, G: np.ndarray, n_nonzero: int, *, chunk: int = 256,
              eps: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """Batch orthogonal matching pursuit for many samples at once.

    Solves ``min ||y - D w||_2  s.t. ||w||_0 <= n_nonzero`` greedily for every sample,
    given only ``Xy = (D^T Y^T)^T`` (N, K) -- the correlations of each sample with each
    atom -- and the Gram matrix ``G = D^T D`` (K, K) (Rubinstein et al. 2008, Alg. 2).
    Atoms should have unit norm (as OMP assumes).

    Each step picks, for every sample, the atom with the largest |correlation with the
    current residual| ``alpha = Xy - W_S G_S`` among atoms not chosen yet, then solves the
    normal equations ``G_SS w_S = Xy_S`` on the chosen set S (a batched (N, s, s) solve).
    A sample stops early (its later picks get coefficient 0) when its largest residual
    correlation squared falls below ``eps`` (same rule as scikit-learn).

    Parameters
    ----------
    Xy : (N, K) correlations ``Y @ D``.
    G : (K, K) Gram matrix ``D.T @ D``.
    n_nonzero : T_s, the number of atoms per sample (<= K).
    chunk : samples processed together (bounds the (chunk, T_s, K) temporaries).

    Returns
    -------
    idx : (N, T_s) int atom indices in selection order.
    coef : (N, T_s) coefficients (``W[i, idx[i]] = coef[i]``; 0 for unused slots).
    """
    Xy = np.asarray(Xy, dtype=np.float64)
    G = np.asarray(G, dtype=np.float64)
    N, K = Xy.shape
    if G.shape != (K, K):
        raise MocapValueError(f"batch_omp: Gram matrix must be ({K}, {K}), got {G.shape}")
    s_max = int(n_nonzero)
    if not 1 <= s_max <= K:
        raise MocapValueError(f"batch_omp: n_nonzero must be in 1..{K}, got {n_nonzero}")
    idx = np.zeros((N, s_max), dtype=np.int64)
    coef = np.zeros((N, s_max))
    for a in range(0, N, chunk):
        b = min(N, a + chunk)
        idx[a:b], coef[a:b] = _omp_chunk(Xy[a:b], G, s_max, eps)
    return idx, coef


def _omp_chunk(Xy: np.ndarray, G: np.ndarray, s_max: int, eps: float) -> tuple[np.ndarray, np.ndarray]:
    n = Xy.shape[0]
    rows = np.arange(n)
    idx = np.zeros((n, s_max), dtype=np.int64)
    coef = np.zeros((n, s_max))
    active = np.ones(n, dtype=bool)
    alpha = Xy.copy()
    for s in range(s_max):
        score = np.abs(alpha, out=alpha)
        if s:
            score[rows[:, None], idx[:, :s]] = -1.0            # never pick an atom twice
        k = np.argmax(score, axis=1)
        active &= score[rows, k] ** 2 >= eps
        idx[:, s] = k
        S = idx[:, :s + 1]                                     # (n, s+1)
        Gss = G[S[:, :, None], S[:, None, :]]                  # (n, s+1, s+1)
        rhs = np.take_along_axis(Xy, S, axis=1)                # (n, s+1)
        rhs = np.where(active[:, None], rhs, 0.0)
        # keep stopped samples' earlier coefficients: solve only for active ones
        sol = np.zeros_like(rhs)
        if active.any():
            A = Gss[active]
            A = A + 1e-12 * np.eye(s + 1)[None]
            sol[active] = np.linalg.solve(A, rhs[active][..., None])[..., 0]
        coef[active, :s + 1] = sol[active]
        if s + 1 < s_max:
            # alpha = Xy - sum_j coef_j G[S_j]   (correlation of the new residual)
            alpha = Xy - np.einsum("ns,nsk->nk", coef[:, :s + 1], G[S])
    return idx, coef


def _codes_dense(idx: np.ndarray, coef: np.ndarray, K: int) -> np.ndarray:
    W = np.zeros((idx.shape[0], K))
    np.add.at(W, (np.repeat(np.arange(idx.shape[0]), idx.shape[1]), idx.ravel()), coef.ravel())
    return W


@dataclass
class KSVDResult:
    """Output of :func:`ksvd`.

    dictionary : (n, K) unit-norm atoms (columns).
    codes : (N, K) sparse codes of the training samples for the final dictionary
        (dense array; at most T_s non-zeros per row), or None if not requested.
    rmse : training RMSE ``sqrt(mean((Y - W D^T)^2))`` after the coding step of each
        iteration (data units).
    n_replaced : atoms replaced (unused or duplicate) in each iteration.
    seconds : wall time.
    """

    dictionary: np.ndarray
    codes: np.ndarray | None
    rmse: list[float] = field(default_factory=list)
    n_replaced: list[int] = field(default_factory=list)
    seconds: float = 0.0


def _init_dictionary(Y: np.ndarray, K: int, init, rng: np.random.Generator) -> np.ndarray:
    N, n = Y.shape
    if isinstance(init, np.ndarray) or (not isinstance(init, str) and init is not None):
        D = np.array(init, dtype=np.float64)
        if D.shape != (n, K):
            raise MocapValueError(f"ksvd: initial dictionary must be ({n}, {K}), got {D.shape}")
        return normalize_atoms(D)
    if init not in ("data", "random"):
        raise MocapValueError(f"ksvd: init must be 'data', 'random' or an array, got {init!r}")
    D = rng.standard_normal((n, K))
    if init == "data":
        norms = np.linalg.norm(Y, axis=1)
        usable = np.flatnonzero(norms > 1e-12 * max(norms.max(initial=0.0), 1e-300))
        pick = rng.permutation(usable)[:K]
        D[:, :len(pick)] = Y[pick].T
    return normalize_atoms(D)


def ksvd(Y, n_atoms: int, *, sparsity: int, n_iter: int = 10, init="data",
         exact: bool = False, mu_thresh: float = 0.99, omp: str = "numpy",
         random_state=None, return_codes: bool = False, callback=None) -> KSVDResult:
    """Learn a dictionary with (approximate) K-SVD and Batch-OMP (Xiao et al. eq. 2).

    Parameters
    ----------
    Y : (N, n) training samples (rows).
    n_atoms : K, number of atoms (overcomplete when K >= n, as in the paper).
    sparsity : T_s, non-zeros per sample in the OMP coding step.
    n_iter : number of K-SVD iterations (coding + dictionary sweep). Default 10.
    init : ``'data'`` (random training samples, default), ``'random'`` (Gaussian) or an
        (n, K) array.
    exact : rank-1 SVD per atom (exact K-SVD) instead of one power step (approximate).
    mu_thresh : atoms whose |cosine| with an earlier atom exceeds this are replaced.
    omp : ``'numpy'`` (vectorised :func:`batch_omp`) or ``'sklearn'``
        (:func:`sklearn.linear_model.orthogonal_mp_gram`, slower, identical codes).
    random_state : seed / Generator for initialisation and update order.
    return_codes : also return the codes of the final dictionary (one extra OMP pass).
    callback : optional ``f(iteration, D, rmse)`` called after every iteration.

    Returns
    -------
    KSVDResult
    """
    t0 = time.perf_counter()
    Y, K, Ts = _ksvd_args(Y, n_atoms, sparsity, omp)
    rng = np.random.default_rng(random_state)
    D = _init_dictionary(Y, K, init, rng)
    res = KSVDResult(D, None)
    for it in range(int(n_iter)):
        idx, coef = _code(Y, D, Ts, omp)
        # residual R = Y - W D^T, from the sparse codes
        R = Y - np.einsum("ns,nsk->nk", coef, D.T[idx])
        res.rmse.append(float(np.sqrt(np.mean(R ** 2))))
        used_for_replacement: set[int] = set()
        err, replaced = _update_atoms(Y, D, R, idx, coef, rng, exact, used_for_replacement)
        if it < int(n_iter) - 1 and mu_thresh < 1.0:
            replaced += _replace_duplicates(Y, D, err, used_for_replacement, mu_thresh)
        D = normalize_atoms(D)
        res.n_replaced.append(replaced)
        if callback is not None:
            callback(it, D, res.rmse[-1])
    res.dictionary = D
    if return_codes:
        idx, coef = _code(Y, D, Ts, omp)
        res.codes = _codes_dense(idx, coef, K)
    res.seconds = time.perf_counter() - t0
    return res


def _ksvd_args(Y, n_atoms: int, sparsity: int, omp: str) -> tuple[np.ndarray, int, int]:
    """Checked training samples (N, n) float64, K and T_s of :func:`ksvd`."""
    Y = np.asarray(Y, dtype=np.float64)
    if Y.ndim != 2 or Y.shape[0] == 0 or Y.shape[1] == 0:
        raise MocapValueError(f"ksvd: Y must be a non-empty (N, n) array, got shape {Y.shape}")
    if not np.isfinite(Y).all():
        raise MocapValueError("ksvd: training samples contain NaN or inf")
    K = int(n_atoms)
    Ts = int(sparsity)
    if K < 1:
        raise MocapValueError(f"ksvd: n_atoms must be >= 1, got {n_atoms}")
    if not 1 <= Ts <= K:
        raise MocapValueError(f"ksvd: sparsity must be in 1..n_atoms ({K}), got {sparsity}")
    if omp not in ("numpy", "sklearn"):
        raise MocapValueError(f"ksvd: omp must be 'numpy' or 'sklearn', got {omp!r}")
    return Y, K, Ts


def _code(Y: np.ndarray, D: np.ndarray, Ts: int, omp: str) -> tuple[np.ndarray, np.ndarray]:
    """Sparse coding step of :func:`ksvd`: (idx, coef) (N, T_s) of every sample (OMP)."""
    G = D.T @ D
    Xy = Y @ D
    if omp == "numpy":
        return batch_omp(Xy, G, Ts)
    import warnings

    from sklearn.linear_model import orthogonal_mp_gram

    N, K = Y.shape[0], D.shape[1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        W = np.atleast_2d(orthogonal_mp_gram(G, Xy.T, n_nonzero_coefs=Ts)).T.reshape(N, K)
    order = np.argsort(-np.abs(W), axis=1, kind="stable")[:, :Ts]
    return order, np.take_along_axis(W, order, axis=1)


def _update_atoms(Y: np.ndarray, D: np.ndarray, R: np.ndarray, idx: np.ndarray,
                  coef: np.ndarray, rng: np.random.Generator, exact: bool,
                  used: set[int]) -> tuple[np.ndarray, int]:
    """One dictionary sweep (approximate K-SVD, Rubinstein et al. Alg. 5), in place on D,
    the residual R (N, n) and the codes: atoms in random order, each refitted to the
    residual of the samples using it (:func:`_atom_update`); an atom used by no sample is
    replaced by the worst-represented one (:func:`_worst_sample`).

    Returns the per-sample squared residual (N,) and the number of atoms replaced.
    """
    K = D.shape[1]
    Ts = idx.shape[1]
    # group (sample, slot) pairs by atom
    flat = idx.ravel()
    nz = coef.ravel() != 0.0
    order = np.argsort(np.where(nz, flat, K), kind="stable")
    counts = np.bincount(flat[nz], minlength=K)
    starts = np.concatenate([[0], np.cumsum(counts)])
    coef_flat = coef.ravel()
    err = (R ** 2).sum(axis=1)
    replaced = 0
    for k in rng.permutation(K):
        pos = order[starts[k]:starts[k + 1]]
        if pos.size == 0:
            j = _worst_sample(err, used)
            if j is not None:
                D[:, k] = Y[j] / max(np.linalg.norm(Y[j]), 1e-300)
                replaced += 1
            continue
        I = pos // Ts
        E = R[I] + np.outer(coef_flat[pos], D[:, k])          # (|I|, n) residual without atom k
        d, g = _atom_update(E, coef_flat[pos], exact)
        if d is None:
            continue
        D[:, k] = d
        coef_flat[pos] = g
        R[I] = E - np.outer(g, d)
        err[I] = (R[I] ** 2).sum(axis=1)
    return err, replaced


def _atom_update(E: np.ndarray, g: np.ndarray, exact: bool):
    """New unit atom d (n,) and coefficients g (|I|,) for the residual E (|I|, n) without the
    atom: the rank-1 SVD (exact K-SVD) or one power step ``d = E^T g / ||E^T g||``,
    ``g = E d`` (approximate); d is None when ``E^T g`` vanishes (atom left as it is)."""
    if exact:
        U, s, Vt = _linalg.svd(E, full_matrices=False, what="k-svd")
        return Vt[0], U[:, 0] * s[0]
    d = E.T @ g
    nd = np.linalg.norm(d)
    if nd <= 1e-300:
        return None, g
    d /= nd
    return d, E @ d


def _replace_duplicates(Y: np.ndarray, D: np.ndarray, err: np.ndarray, used: set[int],
                        mu_thresh: float) -> int:
    """Replace atoms whose |cosine| with an earlier atom exceeds ``mu_thresh`` by the
    worst-represented samples (KSVD-Box "cleardict"), in place; returns how many."""
    K = D.shape[1]
    replaced = 0
    Gm = np.abs(D.T @ D)
    np.fill_diagonal(Gm, 0.0)
    for k in range(K):
        if Gm[k, :k].max(initial=0.0) > mu_thresh:
            j = _worst_sample(err, used)
            if j is None:
                break
            D[:, k] = Y[j] / max(np.linalg.norm(Y[j]), 1e-300)
            Gm[k, :] = Gm[:, k] = np.abs(D.T @ D[:, k])
            Gm[k, k] = 0.0
            replaced += 1
    return replaced


def _worst_sample(err: np.ndarray, used: set[int]) -> int | None:
    """Index of the training sample with the largest residual not used yet for a replacement."""
    if len(used) >= err.size:
        return None
    e = err.copy()
    if used:
        e[list(used)] = -1.0
    j = int(np.argmax(e))
    if e[j] <= 0:
        return None
    used.add(j)
    err[j] = 0.0
    return j
