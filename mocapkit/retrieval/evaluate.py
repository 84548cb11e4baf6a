"""Retrieval measures: average precision, mAP and precision@k from a distance matrix.

A query's relevant items are the database items with the query's label. Rankings sort
distances ascending with a stable sort (ties keep database order).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import MocapValueError

__all__ = ["pairwise_distances", "ranking", "average_precision", "retrieval_scores"]


def pairwise_distances(Q: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Euclidean distances (nq, n) between rows of Q and rows of X (vectorised)."""
    Q = np.asarray(Q, float)
    X = np.asarray(X, float)
    d2 = (Q ** 2).sum(1)[:, None] - 2.0 * Q @ X.T + (X ** 2).sum(1)[None, :]
    return np.sqrt(np.maximum(d2, 0.0))


def ranking(dist: np.ndarray) -> np.ndarray:
    """Database indices per query, nearest first: (nq, n)."""
    return np.argsort(np.asarray(dist, float), axis=1, kind="stable")


def average_precision(relevant: np.ndarray) -> np.ndarray:
    """AP of ranked relevance rows (nq, n) bool: mean of precision@rank over relevant ranks.

    A query with no relevant item gets NaN.
    """
    R = np.asarray(relevant, dtype=bool)
    if R.ndim == 1:
        R = R[None]
    hits = np.cumsum(R, axis=1)
    prec = hits / np.arange(1, R.shape[1] + 1)[None, :]
    n_rel = R.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n_rel > 0, (prec * R).sum(axis=1) / n_rel, np.nan)


def retrieval_scores(dist: np.ndarray, query_labels: Sequence, db_labels: Sequence,
                     ks: Sequence[int] = (1, 5, 10)) -> dict[str, float]:
    """``{'mAP': ..., 'P@1': ..., 'P@5': ..., 'P@10': ...}`` as fractions.

    ``dist`` (nq, n) query-to-database distances. Queries without any relevant database
    item are left out of the means (their count is ``'n_queries'``).
    """
    dist = np.asarray(dist, float)
    ql = np.asarray(query_labels)
    dl = np.asarray(db_labels)
    if dist.shape != (len(ql), len(dl)):
        raise MocapValueError(f"dist must be ({len(ql)}, {len(dl)}), got {dist.shape}")
    order = ranking(dist)
    R = dl[order] == ql[:, None]
    ap = average_precision(R)
    ok = np.isfinite(ap)
    out = {"mAP": float(np.mean(ap[ok])) if ok.any() else float("nan")}
    for k in ks:
        kk = min(int(k), R.shape[1])
        out[f"P@{k}"] = float(R[ok, :kk].mean()) if ok.any() else float("nan")
    out["n_queries"] = int(ok.sum())
    return out
