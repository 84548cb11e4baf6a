"""Small helpers shared by the text-format readers (BVH, TRC, Kinect, ...).

Every helper reports a problem as :class:`~mocapkit.errors.MocapFormatError` with the
file path, the 1-based line number and what was expected, so readers never leak a
``ValueError``/``IndexError`` from Python or numpy.

Functions
---------
read_text(path)                      whole file as str (BOM stripped, undecodable -> error)
parse_float(tok, path, line, what)   one finite float
parse_int(tok, path, line, what)     one int (optionally with a minimum)
float_rows(rows, lines, n, path, what, allow_nan=False)
                                     (N, n) float array from token rows, vectorised, with the
                                     offending line named on a wrong count / garbage / NaN / inf
"""
from __future__ import annotations

import math
import os
from typing import Sequence

import numpy as np

from ..errors import MocapFormatError

__all__ = ["read_text", "parse_float", "parse_int", "float_rows"]


def read_bytes(path: str | os.PathLike) -> bytes:
    """The file's bytes; unreadable or binary (NUL bytes) files are a MocapFormatError."""
    try:
        with open(path, "rb") as fh:
            raw = fh.read()
    except OSError as e:
        raise MocapFormatError(path, f"cannot read file ({e.strerror})") from None
    if b"\x00" in raw[:65536]:
        raise MocapFormatError(path, "binary content (NUL bytes) where a text file was expected")
    return raw


def read_text(path: str | os.PathLike) -> str:
    """Read a text file as UTF-8 (latin-1 fallback for stray accented bytes in comments).

    A file with NUL bytes is rejected as binary. A leading BOM is removed.
    """
    raw = read_bytes(path)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    return text.lstrip("\ufeff")


def parse_float(tok: str, path, line: int | None, what: str = "number") -> float:
    """Parse one finite float; NaN, inf and garbage raise MocapFormatError naming ``what``."""
    try:
        v = float(tok)
    except (TypeError, ValueError):
        raise MocapFormatError(path, f"expected {what}, found {tok!r}", line) from None
    if not math.isfinite(v):
        raise MocapFormatError(path, f"{what} is {tok!r}; only finite numbers are allowed", line)
    return v


def parse_int(tok: str, path, line: int | None, what: str = "integer", minimum: int | None = None) -> int:
    """Parse one integer (``'12'``; ``'12.0'`` is refused), optionally ``>= minimum``."""
    try:
        v = int(tok)
    except (TypeError, ValueError):
        raise MocapFormatError(path, f"expected {what} (an integer), found {tok!r}", line) from None
    if minimum is not None and v < minimum:
        raise MocapFormatError(path, f"{what} must be at least {minimum}, found {v}", line)
    return v


def float_rows(rows: Sequence[Sequence[str]], lines: Sequence[int] | np.ndarray, n: int, path,
               what: str = "values", allow_nan: bool = False) -> np.ndarray:
    """Convert token rows to an (N, n) float array in one numpy call.

    Parameters
    ----------
    rows : N sequences of string tokens (e.g. ``line.split()``).
    lines : the 1-based file line number of each row (for error messages).
    n : required number of tokens per row.
    path : file name for error messages.
    what : what a row holds, e.g. ``"channel values"``.
    allow_nan : accept ``nan``/``NaN`` tokens (returned as NaN); inf is always refused.

    Raises
    ------
    MocapFormatError naming the first bad line: wrong count ("expected n values, found m"),
    a token that is not a number, or a non-finite number.
    """
    N = len(rows)
    if N == 0:
        return np.zeros((0, n))
    counts = np.fromiter((len(r) for r in rows), dtype=np.int64, count=N)
    bad = np.flatnonzero(counts != n)
    if len(bad):
        i = int(bad[0])
        raise MocapFormatError(path, f"expected {n} {what}, found {int(counts[i])}", int(lines[i]))
    flat = [t for r in rows for t in r]
    try:
        A = np.array(flat, dtype=np.float64).reshape(N, n)
    except ValueError:
        for i, r in enumerate(rows):          # error path only: find the line
            for t in r:
                try:
                    float(t)
                except ValueError:
                    raise MocapFormatError(path, f"expected a number in {what}, found {t!r}",
                                           int(lines[i])) from None
        raise MocapFormatError(path, f"could not parse {what}", int(lines[0])) from None
    fin = np.isfinite(A)
    if not fin.all():
        bad_mask = ~fin if not allow_nan else np.isinf(A)
        if bad_mask.any():
            i, k = np.argwhere(bad_mask)[0]
            raise MocapFormatError(path, f"{what} contain {rows[i][k]!r}; only finite numbers are allowed",
                                   int(lines[i]))
    return A
