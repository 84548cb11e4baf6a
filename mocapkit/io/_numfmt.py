"""Vectorised fixed-point text for the BVH writer: ``%.9f`` with trailing zeros trimmed.

``fixed_rows(A)`` turns an (N, C) float array into the bytes of N lines of C values
separated by single spaces, each value written with at most ``decimals`` (<= 9)
decimals, trailing zeros and a bare ``.`` removed and ``-0`` written as ``0``
(``1.5``, ``-0.000000001``, ``12``). Digits come from integer arithmetic on
``rint(x * 10**decimals)``, all in numpy, in blocks of 32,768 values (several times
faster than Python's ``%`` formatting); the last digit can differ from printf's in a
near-tie (by one unit of the last place, 1e-9). Rows holding a value with
``|x| >= 9e6`` (beyond exact int64/float64 scaling) are written by ``%.9f``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["fixed_rows"]

_LIMIT = 9e6
_TOKENS = 32768                  # values per numpy block (small arrays: no page-fault storm)


def _trim(s: str) -> str:
    s = s.rstrip("0").rstrip(".") if "." in s else s
    return "0" if s in ("-0", "") else s


def _python_rows(A: np.ndarray, decimals: int) -> bytes:
    fmt = f"%.{decimals}f"
    return "".join(" ".join(_trim(fmt % v) for v in row) + "\n" for row in A.tolist()).encode()


def _block(A: np.ndarray, decimals: int) -> bytes:
    """Rows of A (all |x| < 9e6) as text: tokens laid out in 19 byte columns
    ``[-][7 integer digits][.][9 fraction digits][sep]``, then the kept bytes taken."""
    n_rows, C = A.shape
    n = A.size
    q = np.rint(A.ravel() * 10.0 ** decimals) * 10.0 ** (9 - decimals)
    neg = q < 0
    a = np.abs(q).astype(np.int64)
    ip = (a // 1000000000).astype(np.int32)
    v = (a - ip.astype(np.int64) * 1000000000).astype(np.int32)
    MT = np.empty((19, n), np.uint8)
    KT = np.empty((19, n), bool)
    zero_run = np.ones(n, bool)                       # every digit right of here is 0
    for j in range(17, 8, -1):                        # fraction digits, right to left
        q10 = v // 10
        d = v - q10 * 10
        MT[j] = d + 48
        nz = d != 0
        KT[j] = nz | ~zero_run
        zero_run &= ~nz
        v = q10
    v = ip
    for j in range(7, 0, -1):                         # integer digits, right to left
        q10 = v // 10
        MT[j] = (v - q10 * 10) + 48
        KT[j] = (v > 0) | (j == 7)
        v = q10
    MT[0], MT[8], MT[18] = 45, 46, 32
    KT[0], KT[8], KT[18] = neg, ~zero_run, True
    M = np.ascontiguousarray(MT.T)
    M.reshape(n_rows, C, 19)[:, -1, 18] = 10
    return M.ravel().take(np.flatnonzero(np.ascontiguousarray(KT.T).ravel())).tobytes()


def fixed_rows(A: np.ndarray, decimals: int = 9) -> bytes:
    """Text (bytes) of the rows of ``A`` (N, C): see the module docstring. C >= 1."""
    A = np.asarray(A, float)
    if not 0 <= decimals <= 9:
        raise ValueError("decimals must be 0 .. 9")
    parts = []
    rows = max(1, _TOKENS // max(A.shape[1], 1))
    for s in range(0, A.shape[0], rows):
        blk = A[s:s + rows]
        ok = np.abs(blk) < _LIMIT
        if ok.all():
            parts.append(_block(blk, decimals))
        else:                                             # rows with huge (or non-finite) values
            good = ok.all(axis=1)
            for a, b in _runs(good):
                parts.append(_block(blk[a:b], decimals) if good[a] else _python_rows(blk[a:b], decimals))
    return b"".join(parts)


def _runs(mask: np.ndarray):
    """(start, stop) of the runs of equal values in a 1-D bool array."""
    edges = np.flatnonzero(mask[1:] != mask[:-1]) + 1
    bounds = np.concatenate([[0], edges, [len(mask)]])
    return zip(bounds[:-1].tolist(), bounds[1:].tolist())
