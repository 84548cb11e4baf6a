"""C3D marker files through ezc3d.

Reading
-------
``read(path, *, units=None, zero_missing=True)`` returns a Motion with one joint per
3D point (``POINT:LABELS``, continued by ``LABELS2`` … for files with more than 255
points), ``fps = POINT:RATE`` and positions in **cm**:

* **Units** from ``POINT:UNITS``: ``mm`` → × 0.1, ``cm`` → × 1, ``m`` → × 100 (also
  ``dm``, ``in``/``inch``, ``ft``); a file without the parameter is read as ``mm`` (the
  C3D default) and says so in ``source['units']``; ``units=`` overrides (a factor to cm or
  one of those names).
* **Occlusion**: a sample is missing (``observed`` False, position NaN) when its
  residual is negative (the C3D "invalid" flag, which ezc3d also turns into NaN), when
  the file stores NaN, or (``zero_missing=True``, default) when all three coordinates are
  exactly 0 (how several exporters write gaps).
* **Skeleton**: a marker set has no hierarchy: every joint is a root (parent -1, zero
  offset), named by its label (blank labels become ``M001`` …, repeated ones get ``_2``
  …; the original labels are kept in ``source['c3d']['labels']``).
* **Analogs** are not read into the Motion; their channel count and rate are kept in
  ``source['c3d']``.
* **Malformed files** raise :class:`~mocapkit.errors.MocapFormatError`: before ezc3d
  sees the file, the 512-byte header and the parameter-block pointer are checked
  (C3D key byte 0x50, processor type, data start) and the file size is compared with
  the size the header implies (ezc3d itself silently returns fewer frames for a truncated
  file); ezc3d exceptions are turned into MocapFormatError too. No partial Motion is
  ever returned.

Writing
-------
``write(motion, path, *, units=None)`` writes the points with ezc3d (float storage):
labels (the original ones when the joints are unchanged), rate, and units (the file's
original unit when the motion came from a C3D, else ``mm``; ``units=`` to choose);
missing samples are written as NaN with residual -1, so the occlusion mask survives a
round trip. Analog data are not written.
"""
from __future__ import annotations

import os
import struct
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import MocapFormatError, MocapValueError
from ..motion import Motion
from ..skeleton import Skeleton
from ._atomic import atomic_write_path

__all__ = ["read", "write", "UNITS"]

#: C3D ``POINT:UNITS`` value -> factor to cm
UNITS: dict[str, float] = {"mm": 0.1, "cm": 1.0, "dm": 10.0, "m": 100.0, "in": 2.54, "inch": 2.54,
                           "ft": 30.48}
_PROCESSORS = {84: "Intel", 85: "DEC", 86: "MIPS"}


def _header(path: Path) -> dict[str, Any]:
    """Sanity-check the C3D header; return what it implies about the file."""
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            head = fh.read(512)
            if len(head) < 512:
                raise MocapFormatError(path, f"file too short for a C3D header ({size} bytes, need 512)")
            pblock = head[0]
            if head[1] != 0x50:
                raise MocapFormatError(path, f"not a C3D file (byte 2 is 0x{head[1]:02x}, expected 0x50)")
            if pblock < 2:
                raise MocapFormatError(path, f"bad C3D header: parameter section pointer {pblock} (must be >= 2)")
            pstart = (pblock - 1) * 512
            if pstart + 4 > size:
                raise MocapFormatError(path, f"truncated C3D file: parameter section at byte {pstart} is past "
                                       f"the end ({size} bytes)")
            fh.seek(pstart)
            phead = fh.read(4)
    except OSError as e:
        raise MocapFormatError(path, f"cannot read file ({e.strerror})") from None
    nblocks, proc = phead[2], phead[3]
    if proc not in _PROCESSORS:
        raise MocapFormatError(path, f"bad C3D parameter section: processor type {proc} "
                               f"(expected 84 Intel, 85 DEC or 86 MIPS)")
    if pstart + 512 * max(nblocks, 1) > size:
        raise MocapFormatError(path, f"truncated C3D file: the parameter section needs "
                               f"{pstart + 512 * max(nblocks, 1)} bytes, the file has {size}")
    le = "<" if proc in (84, 85) else ">"
    npts, nanalog, first, last = struct.unpack(le + "4H", head[2:10])
    if proc == 85:      # DEC float: swap 16-bit words; only the sign/magnitude order matters here
        scale = struct.unpack("<f", head[14:16] + head[12:14])[0] / 4.0
    else:
        scale = struct.unpack(le + "f", head[12:16])[0]
    dstart = struct.unpack(le + "H", head[16:18])[0]
    info = {"size": size, "points": npts, "analog_per_frame": nanalog, "first": first, "last": last,
            "scale": scale, "data_start": dstart, "processor": _PROCESSORS[proc]}
    if dstart < 2 or (dstart - 1) * 512 > size:
        raise MocapFormatError(path, f"bad or truncated C3D file: data section starts at block {dstart}, "
                               f"the file has {size} bytes")
    if dstart <= pblock:
        raise MocapFormatError(path, f"bad C3D header: data section (block {dstart}) does not come after "
                               f"the parameter section (block {pblock})")
    try:
        with open(path, "rb") as fh:
            fh.seek(pstart)
            params = fh.read(512 * max(nblocks, 1))
    except OSError as e:
        raise MocapFormatError(path, f"cannot read file ({e.strerror})") from None
    _check_parameters(path, params, le)
    if last >= first:
        frames = last - first + 1
        bps = 4 if scale < 0 else 2
        need = (dstart - 1) * 512 + frames * (npts * 4 * bps + nanalog * bps)
        info["frames"] = frames
        if size < need:
            raise MocapFormatError(path, f"truncated C3D file: the header announces {frames} frames of "
                                   f"{npts} points ({need} bytes), the file has {size} bytes")
    return info


def _check_parameters(path: Path, sec: bytes, le: str) -> None:
    """Walk the parameter records and check that each one fits (ezc3d can crash or hang
    on a corrupted parameter section, so it only sees files whose structure is sound)."""
    end = len(sec)
    i = 4
    n = 0
    while i < end:
        if i + 2 > end:
            break
        nlen = struct.unpack("b", sec[i:i + 1])[0]
        gid = struct.unpack("b", sec[i + 1:i + 2])[0]
        if nlen == 0:
            break
        j = i + 2 + abs(nlen)
        where = f"parameter record {n + 1} (byte {i} of the parameter section)"
        if j + 2 > end:
            raise MocapFormatError(path, f"corrupted C3D parameters: {where} runs past the section")
        name = sec[i + 2:j]
        if gid == 0 or not all(32 < ch < 127 for ch in name):
            raise MocapFormatError(path, f"corrupted C3D parameters: {where} has a bad name/group id")
        off = struct.unpack(le + "h", sec[j:j + 2])[0]
        nxt = j + off
        if off < 0 or (off and nxt > end):
            raise MocapFormatError(path, f"corrupted C3D parameters: {where} points outside the section")
        k = j + 2
        if gid > 0:                                  # parameter: type, dims, data
            if k + 2 > end:
                raise MocapFormatError(path, f"corrupted C3D parameters: {where} is truncated")
            typ = struct.unpack("b", sec[k:k + 1])[0]
            ndim = sec[k + 1]
            if typ not in (-1, 1, 2, 4) or ndim > 7:
                raise MocapFormatError(path, f"corrupted C3D parameters: {where} has data type {typ} "
                                       f"and {ndim} dimensions")
            if typ == -1 and ndim == 0:              # ezc3d segfaults on a scalar character parameter
                raise MocapFormatError(path, f"corrupted C3D parameters: {where} is character data "
                                       f"without dimensions")
            dims = sec[k + 2:k + 2 + ndim]
            if len(dims) != ndim:
                raise MocapFormatError(path, f"corrupted C3D parameters: {where} is truncated")
            count = int(np.prod([d for d in dims])) if ndim else 1
            k = k + 2 + ndim + abs(typ) * count
        if k + 1 > end or k + 1 + sec[k] > end:
            raise MocapFormatError(path, f"corrupted C3D parameters: {where} (data/description) runs past "
                                   f"the section")
        k = k + 1 + sec[k]
        if off and k > nxt:
            raise MocapFormatError(path, f"corrupted C3D parameters: {where} overlaps the next record")
        n += 1
        if off == 0:
            break
        i = nxt


def _unit_factor(units, path) -> tuple[str, float]:
    if isinstance(units, str):
        u = units.strip().lower()
        if u not in UNITS:
            raise MocapValueError(f"units must be a factor to cm or one of {', '.join(UNITS)}, got {units!r}")
        return u, UNITS[u]
    f = float(units)
    if not np.isfinite(f) or f <= 0:
        raise MocapValueError(f"units must be a positive factor to cm, got {units!r}")
    return f"x{f:g} cm", f


def _labels(params: dict, n: int) -> list[str]:
    point = params.get("POINT", {})
    labels: list[str] = []
    for key in ["LABELS"] + [f"LABELS{i}" for i in range(2, 100)]:
        if key not in point:
            if key != "LABELS":
                break
            continue
        labels += [str(x) for x in point[key]["value"]]
    return labels[:n]


def _unique_names(labels: list[str], n: int) -> list[str]:
    names, seen = [], {}
    for i in range(n):
        lab = labels[i].strip() if i < len(labels) else ""
        base = lab or f"M{i + 1:03d}"
        name = base
        k = seen.get(base, 0)
        while name in seen or name in names:
            k += 1
            name = f"{base}_{k + 1}"
        seen[base] = k
        names.append(name)
    return names


def read(path: str | os.PathLike, *, units: str | float | None = None, zero_missing: bool = True) -> Motion:
    """Read the 3D points of a C3D file (positions in cm, occlusions as ``observed``).

    Raises MocapFormatError for malformed, truncated or empty files.
    """
    import ezc3d

    path = Path(path)
    info = _header(path)
    try:
        c = ezc3d.c3d(str(path), extract_forceplat_data=False)
    except (RuntimeError, OSError, ValueError, IndexError, MemoryError) as e:
        raise MocapFormatError(path, f"ezc3d cannot read this C3D file: {str(e).splitlines()[0][:200]}") from None
    params = c["parameters"]
    pts = np.asarray(c["data"]["points"], dtype=float)                # (4, N, T)
    if pts.ndim != 3 or pts.shape[1] == 0:
        raise MocapFormatError(path, "no 3D points in this C3D file (analog-only files are not supported)")
    N, T = pts.shape[1], pts.shape[2]
    if T == 0:
        raise MocapFormatError(path, "no frames (empty motion)")
    if "frames" in info and T < info["frames"]:
        raise MocapFormatError(path, f"truncated C3D file: {T} of {info['frames']} frames readable")
    res = np.asarray(c["data"]["meta_points"]["residuals"], dtype=float).reshape(N, T)
    try:
        rate = float(params["POINT"]["RATE"]["value"][0])
    except (KeyError, IndexError, TypeError):
        rate = float(c["header"]["points"]["frame_rate"])
    if not np.isfinite(rate) or rate <= 0:
        raise MocapFormatError(path, f"bad POINT:RATE {rate!r} (frames per second must be positive)")
    file_units = None
    try:
        file_units = str(params["POINT"]["UNITS"]["value"][0]).strip()
    except (KeyError, IndexError, TypeError):
        pass
    if units is not None:
        ulabel, factor = _unit_factor(units, path)
        how = "override (units=)"
    elif file_units:
        if file_units.lower() not in UNITS:
            raise MocapFormatError(path, f"unknown POINT:UNITS {file_units!r} (expected one of "
                                   f"{', '.join(UNITS)}); pass units= to read it anyway")
        ulabel, factor, how = file_units.lower(), UNITS[file_units.lower()], "POINT:UNITS"
    else:
        ulabel, factor, how = "mm", UNITS["mm"], "no POINT:UNITS in the file; C3D default mm assumed"
    xyz = np.transpose(pts[:3], (2, 1, 0))                            # (T, N, 3)
    obs = np.isfinite(xyz).all(axis=2) & (res.T >= 0)
    if zero_missing:
        obs &= ~(xyz == 0).all(axis=2)
    labels = _labels(params, N)
    names = _unique_names(labels, N)
    sk = Skeleton(tuple(names), -np.ones(N, dtype=int), np.zeros((N, 3)))
    try:
        n_analog = int(np.asarray(c["data"]["analogs"]).shape[1])
    except (KeyError, IndexError):
        n_analog = 0
    analog_rate = float(c["header"]["analogs"].get("frame_rate", 0.0)) if "analogs" in c["header"] else 0.0
    meta = {"labels": labels + [""] * (N - len(labels)), "rate": rate,
            "first_frame": int(c["header"]["points"]["first_frame"]),
            "analog_channels": n_analog, "analog_rate": analog_rate, "processor": info["processor"]}
    src = {"path": str(path), "format": "c3d",
           "units": {"file": ulabel, "cm_per_unit": factor, "how": how}, "c3d": meta,
           "per_frame": {"residuals": np.where(obs, res.T, -1.0)}}
    return Motion(xyz * factor, sk, rate, obs, src)


def write(motion: Motion, path: str | os.PathLike, *, units: str | float | None = None) -> Path:
    """Write the motion's joints as C3D points (ezc3d, float storage), atomically.

    Labels: the original C3D labels when the motion came from a C3D with the same joints,
    else the joint names. Units: ``units=`` if given, else the source file's unit (C3D
    input), else ``mm``. Missing samples: NaN coordinates with residual -1.
    """
    import ezc3d

    p = Path(path)
    src = motion.source
    meta = src.get("c3d") if src.get("format") == "c3d" else None
    if units is not None:
        ulabel, factor = _unit_factor(units, p)
        if ulabel not in UNITS:
            raise MocapValueError("C3D output units must be a unit name (mm, cm, m, …), not a factor")
    elif meta is not None and str(src.get("units", {}).get("file", "")) in UNITS:
        ulabel = src["units"]["file"]
        factor = UNITS[ulabel]
    else:
        ulabel, factor = "mm", UNITS["mm"]
    names = list(motion.skeleton.names)
    labels = names
    if meta is not None and len(meta.get("labels", [])) == len(names):
        orig = [str(x) for x in meta["labels"]]
        if _unique_names(orig, len(orig)) == names:
            labels = orig
    T, J = motion.n_frames, motion.n_joints
    obs = motion.observed
    xyz = np.where(obs[..., None], motion.positions / factor, np.nan)
    pts = np.ones((4, J, T))
    pts[:3] = np.transpose(xyz, (2, 1, 0))
    res = np.where(obs, 0.0, -1.0)
    stored = src.get("per_frame", {}).get("residuals")
    if stored is not None and np.shape(stored) == (T, J):
        res = np.where(obs, np.maximum(np.asarray(stored, float), 0.0), -1.0)
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [float(motion.fps)]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    c["parameters"]["POINT"]["UNITS"]["value"] = [ulabel]
    c["data"]["points"] = pts
    c["data"]["meta_points"]["residuals"] = res.T[None, :, :]
    c["data"]["meta_points"]["camera_masks"] = np.zeros((7, J, T), dtype=bool)

    def _write(tmp: str) -> None:
        try:
            c.write(tmp)
        except (RuntimeError, OSError, ValueError) as e:
            raise MocapFormatError(p, f"ezc3d could not write the file: {e}") from None

    atomic_write_path(p, _write, suffix=".c3d")
    return p
