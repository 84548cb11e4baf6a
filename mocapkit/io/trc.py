"""TRC (OpenSim / Motion Analysis marker trajectories) reader and writer.

Layout (tab-separated; comma-separated files such as pyomeca's are read too)::

    PathFileType  4  (X/Y/Z)  <name>
    DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame  OrigNumFrames
    100       100         652        51          mm     100           1                   652
    Frame#  Time  M1        M2 ...            (each name followed by two empty cells)
                  X1 Y1 Z1  X2 Y2 Z2 ...
    <blank line>
    1  0.00  x y z  x y z ...

* Units ``mm``/``cm``/``m`` (also spelled out) are converted to **cm**.
* A marker whose three cells are empty (or ``NaN``, as OpenSim writes) is missing in
  that frame (``observed`` False). Rows may omit trailing empty cells only in whole
  markers; a row cut inside a marker, text that is not a number, or ``inf`` is an
  error naming the line.
* ``fps`` is ``DataRate`` (else ``CameraRate``, else derived from the Time column).
* A ``NumFrames``/``NumMarkers`` header that disagrees with the data is *reported*, not
  fatal, when every data row is complete: what the data hold is read, and one
  :class:`~mocapkit.errors.HeaderMismatchWarning` per disagreeing field names both numbers
  (also kept in ``motion.source['warnings']``). Real files do this
  (``markers/pyomeca/markers.trc`` declares 652 frames and holds 93).
* Markers have no hierarchy: the skeleton is a marker set (every parent -1, offsets 0).
* ``Frame#`` and ``Time`` are kept in ``source['per_frame']`` (``frame``, ``time``), and
  the header's fields in ``source['header']``; the writer gives them back (:func:`write`).

The writer writes OpenSim's layout: tab-separated, millimetres by default
(``units='mm'|'cm'|'m'``), empty cells for missing markers, 6 decimals in the chosen
unit (1e-6 mm = 1e-7 cm), atomically.
"""
from __future__ import annotations

import os
import warnings as _warnings
from pathlib import Path

import numpy as np

from ..errors import HeaderMismatchWarning, MocapFormatError, MocapValueError
from ..motion import Motion
from ..skeleton import Skeleton
from ._atomic import atomic_write
from ._text import float_rows, read_text

__all__ = ["read", "write", "UNITS"]

#: unit spelling -> factor to cm
UNITS = {"mm": 0.1, "millimeters": 0.1, "millimetres": 0.1, "cm": 1.0, "centimeters": 1.0,
         "centimetres": 1.0, "m": 100.0, "meters": 100.0, "metres": 100.0}


def _split(line: str, sep: str) -> list[str]:
    return [c.strip() for c in line.rstrip("\r\n").split(sep)]


_READ_BLOCK = 4096
"""Data rows split and converted at a time by :func:`read` (bounds its memory)."""


def _parse_rows(rows: list[list[str]], nos: list[int], width: int, n_triples: int,
                path: Path) -> np.ndarray:
    """(len(rows), width) floats of data rows (missing cells NaN), checking each row."""
    padded = []
    for r, ln in zip(rows, nos):
        while len(r) > width and r[-1] == "":
            r = r[:-1]
        if len(r) > width:
            raise MocapFormatError(path, f"expected at most {width} cells (Frame#, Time and {n_triples} "
                                         f"X/Y/Z triples), found {len(r)}", ln)
        if len(r) < 2 or (len(r) - 2) % 3 != 0:
            raise MocapFormatError(path, f"row ends inside a marker triple ({len(r)} cells; expected "
                                         f"{width}): truncated line?", ln)
        if r[0] == "" or r[1] == "":
            raise MocapFormatError(path, "empty Frame# or Time cell", ln)
        padded.append([c if c else "nan" for c in r] + ["nan"] * (width - len(r)))
    return float_rows(padded, nos, width, path, "TRC cells (Frame#, Time, X/Y/Z values)",
                      allow_nan=True)


def read(path: str | os.PathLike, *, units: str | None = None) -> Motion:
    """Read a TRC file (positions in cm; see the module docstring).

    ``units`` overrides the file's Units field (e.g. for a file that lacks it).
    """
    path = Path(path)
    lines = read_text(path).splitlines()
    sep, keys, vals, header = _header(path, lines)
    names, order = _marker_names(path, lines[3], sep)
    n_triples = max(order) + 1
    unit_txt = (units if units is not None else header.get("units", "")).strip().lower()
    if unit_txt not in UNITS:
        if units is not None:
            raise MocapValueError(f"unknown TRC unit {units!r}; use one of mm, cm, m")
        raise MocapFormatError(path, f"Units {header.get('units', '')!r} not understood; expected mm, cm "
                                     f"or m (or pass units=)", 3)
    factor = UNITS[unit_txt]
    A, line_nos = _data(path, lines, sep, n_triples)
    del lines
    T, M = A.shape[0], len(names)
    frame_no, times, data = A[:, 0], A[:, 1], A[:, 2:]
    if not (np.isfinite(frame_no).all() and np.isfinite(times).all()):
        i = int(np.flatnonzero(~(np.isfinite(frame_no) & np.isfinite(times)))[0])
        raise MocapFormatError(path, "Frame# and Time must be numbers", line_nos[i])
    P = data.reshape(T, n_triples, 3)[:, order] * factor
    observed = np.isfinite(P).all(axis=2)
    warnings: list[str] = []
    mismatches = [m for m in (
        _count_check(header, "numframes", "NumFrames", T, warnings,
                     f"the file holds {T} complete data rows; all {T} rows were read"),
        _count_check(header, "nummarkers", "NumMarkers", M, warnings,
                     f"line 4 names {M} markers (and the data rows hold them); all {M} were read")) if m]
    fps = _frame_rate(path, header, times, warnings)
    skeleton = Skeleton(tuple(names), -np.ones(M, dtype=int), np.zeros((M, 3)))
    source = {"path": str(path), "format": "trc",
              "units": {"name": unit_txt, "factor_to_cm": factor, "chosen_by": "file header" if units is None else "user (units=)"},
              "header": {k: v for k, v in zip(keys, vals) if k},
              "per_frame": {"frame": frame_no, "time": times}}
    if warnings:
        source["warnings"] = warnings
    for w in mismatches:
        _warnings.warn(f"{path}: {w}", HeaderMismatchWarning, stacklevel=2)
    return Motion(P, skeleton, fps, observed, source)


def _header(path: Path, lines: list[str]):
    """(cell separator, header keys, header values, {lower-case key: value}) of lines 1-3."""
    if not lines or not lines[0].strip():
        raise MocapFormatError(path, "empty file; expected a TRC header starting with 'PathFileType'", 1)
    if not lines[0].lstrip().lower().startswith("pathfiletype"):
        raise MocapFormatError(path, f"expected 'PathFileType' on the first line of a TRC file, found "
                                     f"{lines[0][:40]!r}", 1)
    sep = "\t" if "\t" in lines[0] else ","
    if len(lines) < 5:
        raise MocapFormatError(path, "truncated TRC header (expected 5 header lines: PathFileType, "
                                     "keys, values, marker names, X1/Y1/Z1)", len(lines))
    keys = [k for k in _split(lines[1], sep)]
    vals = _split(lines[2], sep)
    header = {k.lower(): v for k, v in zip(keys, vals) if k}
    if "nummarkers" not in header and "datarate" not in header:
        raise MocapFormatError(path, f"line 2 should hold the header keys (DataRate ... NumMarkers ... "
                                     f"Units), found {lines[1][:60]!r}", 2)
    return sep, keys, vals, header


def _marker_names(path: Path, line: str, sep: str) -> tuple[list[str], list[int]]:
    """Marker names of line 4 (every non-empty cell after Frame#, Time) and the X/Y/Z
    triple index of each."""
    names_row = _split(line, sep)
    if len(names_row) < 2 or names_row[0].lower() not in ("frame#", "frame"):
        raise MocapFormatError(path, f"line 4 should start with 'Frame#' and 'Time', found "
                                     f"{line[:40]!r}", 4)
    names, cols = [], []
    for i, c in enumerate(names_row[2:]):
        if c:
            names.append(c)
            cols.append(i)
    if not names:
        raise MocapFormatError(path, "no marker names on line 4", 4)
    bad = [n for n, c in zip(names, cols) if c % 3 != 0]
    if bad:
        raise MocapFormatError(path, f"marker name {bad[0]!r} is not aligned on an X/Y/Z triple "
                                     f"(each name must be followed by two empty cells)", 4)
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise MocapFormatError(path, f"duplicate marker names: {', '.join(dup)}", 4)
    return names, [c // 3 for c in cols]


def _data(path: Path, lines: list[str], sep: str, n_triples: int) -> tuple[np.ndarray, list[int]]:
    """(T, 2 + 3 n_triples) floats of the data rows (missing cells NaN) and their line numbers.

    The X1/Y1/Z1 line and blank lines are skipped. Parsed in blocks of _READ_BLOCK rows so
    only one block of split cells (Python strings, ~60 bytes each) is alive at a time:
    100,000 frames x 31 markers peaked at 14x the positions array when all rows were split
    first (docs/results/reliability.md).
    """
    width = 2 + 3 * n_triples
    line_nos = [k + 1 for k in range(5, len(lines))
                if lines[k].strip() and lines[k].replace(sep, "").strip()]
    if not line_nos:
        raise MocapFormatError(path, "no data rows after the header (empty motion)", len(lines))
    A = np.concatenate([
        _parse_rows([_split(lines[n - 1], sep) for n in line_nos[a:a + _READ_BLOCK]],
                    line_nos[a:a + _READ_BLOCK], width, n_triples, path)
        for a in range(0, len(line_nos), _READ_BLOCK)])
    return A, line_nos


def _count_check(header: dict, key: str, label: str, n: int, warnings: list[str], held: str) -> str | None:
    """Compare a header count with what the data hold: the mismatch text (also appended to
    ``warnings``; reported, not fatal), or None when they agree or the field is absent."""
    try:
        v = int(float(header.get(key, n)))
    except (ValueError, OverflowError):                  # 'abc', 'nan', 'inf'
        warnings.append(f"header {label} {header.get(key)!r} is not a number")
        return None
    if v == n:
        return None
    warnings.append(f"header {label}={v} but {held}")
    return warnings[-1]


def _frame_rate(path: Path, header: dict, times: np.ndarray, warnings: list[str]) -> float:
    """``DataRate``, else ``CameraRate``, else 1 / the median step of the Time column."""
    for key in ("datarate", "camerarate"):
        try:
            v = float(header.get(key, "nan"))
        except ValueError:
            v = float("nan")
        if np.isfinite(v) and v > 0:
            return v
    dt = np.diff(times)
    if len(dt) and np.all(dt > 0):
        warnings.append("no valid DataRate/CameraRate: fps derived from the Time column")
        return 1.0 / float(np.median(dt))
    raise MocapFormatError(path, "no valid DataRate or CameraRate in the header and no usable "
                                 "Time column to derive the frame rate", 3)


_WRITE_BLOCK = 2048
"""Frames formatted at a time by :func:`write` (bounds its memory)."""


def write(motion: Motion, path: str | os.PathLike, *, units: str = "mm") -> None:
    """Write ``motion`` as a tab-separated TRC file (default millimetres, like OpenSim).

    Missing entries become empty cells. Joint names are used as marker names. A motion
    read from a TRC file at its own rate keeps the file's ``Frame#`` numbers and its
    ``CameraRate`` / ``OrigDataRate`` / ``OrigDataStartFrame`` / ``OrigNumFrames`` (a
    cleaned file lines up with the video and the software that exported it); otherwise
    frames are numbered from 1 and the original fields describe this motion.
    """
    u = str(units).strip().lower()
    if u not in UNITS:
        raise MocapValueError(f"unknown TRC unit {units!r}; use mm, cm or m")
    factor = UNITS[u]
    label = {0.1: "mm", 1.0: "cm", 100.0: "m"}[factor]
    bad = [n for n in motion.skeleton.names if any(ch in n for ch in "\t\r\n")]
    if bad:
        raise MocapValueError(f"marker names cannot contain tabs or newlines: {bad[:3]}")
    T, J = motion.n_frames, motion.n_joints
    X = motion.positions / factor
    pf = motion.source.get("per_frame", {})
    times = np.asarray(pf.get("time")) if np.shape(pf.get("time", ())) == (T,) else np.arange(T) / motion.fps
    frames = np.arange(1, T + 1)
    orig = [f"{motion.fps:g}", f"{motion.fps:g}", "1", f"{T}"]   # CameraRate, OrigDataRate, -StartFrame, -NumFrames
    hdr = motion.source.get("header", {}) if motion.source.get("format") == "trc" else {}
    try:
        same_rate = bool(hdr) and np.isclose(float(hdr.get("DataRate", "nan")), motion.fps)
    except ValueError:
        same_rate = False
    if same_rate:
        kept = [str(hdr.get(k, "")).strip() for k in ("CameraRate", "OrigDataRate", "OrigDataStartFrame",
                                                        "OrigNumFrames")]
        orig = [k if k and not any(ch in k for ch in "\t\r\n") else o for k, o in zip(kept, orig)]
        fr = np.asarray(pf.get("frame", ()), dtype=float)
        if fr.shape == (T,) and np.isfinite(fr).all():
            frames = fr
    p = Path(path)

    def body(f):
        f.write(f"PathFileType\t4\t(X/Y/Z)\t{p.name}\n")
        f.write("DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\t"
                "OrigNumFrames\n")
        f.write(f"{motion.fps:g}\t{orig[0]}\t{T}\t{J}\t{label}\t{orig[1]}\t{orig[2]}\t{orig[3]}\n")
        f.write("Frame#\tTime\t" + "\t".join(f"{n}\t\t" for n in motion.skeleton.names).rstrip("\t") + "\n")
        f.write("\t\t" + "\t".join(f"X{j + 1}\tY{j + 1}\tZ{j + 1}" for j in range(J)) + "\n\n")
        # blocks of frames, each formatted by one C-level % operation ("%.6f", as
        # np.char.mod did; missing cells are NaN -> "nan" -> ""): O(block) memory instead
        # of a (T, 3J) string array (100,000 frames x 31 markers: 23x the positions -> ~2x)
        V = np.where(np.repeat(motion.observed, 3, axis=1), X.reshape(T, 3 * J), np.nan)
        row = "%d\t%.6f\t" + "\t".join(["%.6f"] * (3 * J)) + "\n"
        for a in range(0, T, _WRITE_BLOCK):
            b = min(a + _WRITE_BLOCK, T)
            block = np.empty((b - a, 2 + 3 * J))
            block[:, 0] = frames[a:b]
            block[:, 1] = times[a:b]
            block[:, 2:] = V[a:b]
            f.write(((row * (b - a)) % tuple(block.ravel().tolist())).replace("nan", ""))

    atomic_write(path, body)
