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
  …; the original labels are kept in ``source['c3d']['labels']``) -- unless the file
  carries the joint hierarchy mocapkit writes (group ``MOCAPKIT``: ``PARENTS``,
  ``OFFSETS`` in point units, ``FIXED_BONES``, see Writing), which is read back: the
  points are then joint centres of that skeleton, and the bones whose length the motion's
  first format fixed (ASF/AMC, BVH) stay fixed (:func:`mocapkit.rigid.fixed_bones`). A
  group that does not fit the points is ignored with a warning naming the parameter.
* **Residuals and filled samples** (the convention of Vicon Nexus / QTM): residual < 0
  missing, 0 computed (filled / interpolated), > 0 measured. The residuals (file units,
  -1 where missing) are kept in ``source['per_frame']['residuals']``. ``Motion.filled`` is
  set where a valid sample has residual exactly 0, but **only when the file carries real
  residuals** (some valid sample has a residual > 0): files that write 0 for every valid
  sample (mocapkit 0.1, several exporters) are read with ``filled`` all False;
  ``source['c3d']['residuals']`` says which case it was.
* **Analogs** are not read into the Motion; their channel count and rate are kept in
  ``source['c3d']`` (and the writer copies them back, see Writing). An analog-only file
  (no 3D points) is refused with a clear error.
* **Frame numbers**: ``source['per_frame']['frame']`` holds the file's own frame number of
  each frame (the header's first frame, 0-based as ezc3d counts, onwards); it follows
  :meth:`~mocapkit.motion.Motion.slice`.
* **Header vs data**: the frames the data hold are read (ezc3d stops at the last complete
  frame). A header frame count that disagrees (a truncated file, or vendors such as
  Optotrak whose header announces 1149 frames for 29) gives one
  :class:`~mocapkit.errors.HeaderMismatchWarning` naming both numbers (also in
  ``source['warnings']``).
* **Malformed files** raise :class:`~mocapkit.errors.MocapFormatError`. ezc3d can crash
  or hang on a corrupted *structure* (see ``tests/fuzz_regressions/c3d``), so before it
  sees the file the 512-byte header, the parameter-block pointer (C3D key byte 0x50,
  processor type, data start) and every parameter record (name, group id, offsets, data
  type, dimensions) are checked; that guard refuses only what ezc3d cannot read safely,
  never a file ezc3d handles (names with spaces, as Qualisys writes, are fine). After
  ezc3d: no 3D points, no frames, a bad ``POINT:RATE``, a ``POINT:SCALE`` that is NaN,
  infinite or 0 (the storage format and the coordinates' scale are then unknown), or an
  unknown ``POINT:UNITS``. ezc3d exceptions are turned into MocapFormatError too. No
  numpy warning escapes the reader.

Writing
-------
``write(motion, path, *, units=None)`` writes the points with ezc3d (float storage):
labels (the original ones when the joints are unchanged), rate, and units (the file's
original unit when the motion came from a C3D, else ``mm``; ``units=`` to choose).
Residuals: -1 (and NaN coordinates) for missing samples, **0 for filled samples**
(``motion.filled``), the **measured residual** kept from a C3D input for the others,
converted to the output unit. A motion with a joint hierarchy (read from ASF/AMC, BVH,
Kinect, or built with one) also gets it written, as group ``MOCAPKIT`` (at most 255
joints): ``PARENTS`` (parent index per point, -1 for a root), ``OFFSETS`` (3 x points,
rest offsets in the point unit) and ``FIXED_BONES`` (1 where the bone to the point's
parent has a length the source format fixed) -- so AMC -> C3D -> back loses no
hierarchy, and a cleaner knows the bone lengths of joint-centre data. Other readers skip
the unknown group. The residual field is one byte times ``|POINT:SCALE|``:
the writer sets ``POINT:SCALE = -step`` (the C3D input's own step when its residuals fit,
else 0.01 mm, coarser only when the kept residuals exceed 255 steps), rounds residuals to it, and writes a measured sample without
a known positive residual (e.g. from a TRC input) as **one step** (0.01 mm), never 0,
since 0 means "computed". So the occlusion mask and the filled flags survive a round
trip.

**Nothing else of the source is lost.** A motion read from a C3D file, with the file's
points in its order and at its rate (cleaned, filled, or a slice of it), is written into a
copy of that file (:func:`_source_copy`): its analog channels (force plates, EMG), events,
subject, force-plate and every other parameter group, and its first frame, are kept; only
the points, their residuals, ``POINT:UNITS`` / ``SCALE`` and the labels' lists (cut to one
entry per point or channel, as ezc3d requires) change. A slice keeps the analog samples
of its frames and moves the header's first frame (and ``TRIAL:ACTUAL_START_FIELD`` /
``END_FIELD``) with it, so events still fall on their frames. Until 2026-12-05 the writer
started from an empty file: a lab's force plates and events were gone from every cleaned
file (38 analog channels of pyomeca's Vicon export, 69 of the Qualisys file, and the
first frames 704, 1165, 2924 of three shared files). A motion whose frames or joints are
no longer the source's (resampled, joints selected) is written with its points only and
one :class:`~mocapkit.errors.MocapWarning` says what was left out and why.
"""
from __future__ import annotations

import os
import struct
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import HeaderMismatchWarning, MocapFormatError, MocapValueError, MocapWarning
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
        # what the header announces; the data may hold fewer (truncated file, or a vendor
        # that writes another count: Optotrak.c3d announces 1149 frames and holds 29) or more:
        # ezc3d reads the frames the data hold and read() warns about the difference
        info["frames"] = last - first + 1
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
        # printable ASCII, spaces included (Qualisys writes 'Uncropped Measurement Length'):
        # control bytes or NUL in a name mean the walk is off the records
        if gid == 0 or not all(32 <= ch < 127 for ch in name):
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


#: POINT parameters listing the labels of points that are not marker trajectories (C3D
#: specification: "3D trajectories that match strings in POINT:ANGLES should be treated as
#: three-dimensional angles", and so on; OpenSim's C3D reader leaves them out too)
MODEL_OUTPUTS = ("ANGLES", "FORCES", "MOMENTS", "POWERS", "SCALARS", "REACTIONS")


def _model_outputs(params: dict, labels: list[str]) -> dict[str, list[int]]:
    """Point indices whose label a ``POINT:ANGLES`` / ``FORCES`` / ... list names, per list."""
    point = params.get("POINT", {})
    out: dict[str, list[int]] = {}
    for kind in MODEL_OUTPUTS:
        names: set[str] = set()
        for key in [kind] + [f"{kind}{i}" for i in range(2, 100)]:
            if key not in point:
                break
            names |= {str(x).strip() for x in np.atleast_1d(point[key].get("value", []))}
        found = [i for i, lab in enumerate(labels) if lab.strip() and lab.strip() in names]
        if found:
            out[kind] = found
    return out


def outputs_text(outputs: dict[str, Any]) -> str:
    """'12 angles, 6 forces' from {kind: indices or count}."""
    return ", ".join(f"{v if isinstance(v, int) else len(v)} {k.lower()}" for k, v in outputs.items())


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
    _check_scale(path, params)
    warn: list[str] = []
    announced = info.get("frames")
    if announced is not None and announced != T and not (T > 65535 and announced < T):
        # (a clip longer than the 16-bit header field can hold is the documented exception)
        warn.append(f"the C3D header announces {announced} frames (frames {info['first']}..{info['last']}) "
                    f"but the data hold {T}; read the {T} frames the data hold")
    res = np.asarray(c["data"]["meta_points"]["residuals"], dtype=float).reshape(N, T)
    # model outputs (angles, forces, ... that Vicon Nexus and others store as points) are
    # not markers: they stay in the file for the writer, out of the Motion
    all_labels = _labels(params, N)
    outputs = _model_outputs(params, all_labels)
    is_output = np.isin(np.arange(N), sorted(i for ix in outputs.values() for i in ix))
    if is_output.all():
        raise MocapFormatError(path, f"no marker trajectories in this C3D file: its {N} points are all model "
                               f"outputs ({outputs_text(outputs)})")
    markers = np.flatnonzero(~is_output)
    pts, res = pts[:, markers], res[markers]
    N_file, N = N, len(markers)
    rate = _frame_rate(path, c)
    ulabel, factor, how = _point_units(path, params, units)
    xyz = np.transpose(pts[:3], (2, 1, 0))                            # (T, N, 3)
    with np.errstate(invalid="ignore"):
        obs = np.isfinite(xyz).all(axis=2) & (res.T >= 0)
    if zero_missing:
        obs &= ~(xyz == 0).all(axis=2)
    # residual convention: > 0 measured, 0 computed (filled / interpolated), < 0 missing;
    # only a file that carries real residuals says anything with a 0 (mocapkit 0.1 and many
    # exporters write 0 for every valid sample)
    res_t = np.where(obs, res.T, -1.0)
    has_residuals = bool((res_t > 0).any())
    filled = obs & (res_t == 0) if has_residuals else np.zeros_like(obs)
    labels = [all_labels[i] if i < len(all_labels) else "" for i in markers]
    names = _unique_names(labels, N)
    sk_warn: list[str] = []
    sk, fixed = _stored_skeleton(params, names, factor, sk_warn)
    meta = {"labels": labels + [""] * (N - len(labels)), "rate": rate,
            "first_frame": int(c["header"]["points"]["first_frame"]), **_analogs(c),
            "processor": info["processor"], "header_frames": announced,
            "residual_step": _residual_step(params),
            "residuals": "measured (0 = filled)" if has_residuals else
                         "none (every valid sample has residual 0: nothing read as filled)"}
    if fixed is not None:
        meta["fixed_bones"] = fixed
    if N < N_file:
        meta["points_in_file"] = N_file
        meta["marker_points"] = markers.tolist()          # the file's point index of each joint
        meta["model_outputs"] = {k: len(v) for k, v in outputs.items() if v}
    # the file's frame numbers (0-based, as ezc3d counts): they follow Motion.slice, so the
    # writer knows which analog samples, events and first frame belong to what it writes
    first = meta["first_frame"]
    src = {"path": str(path), "format": "c3d",
           "units": {"file": ulabel, "cm_per_unit": factor, "how": how}, "c3d": meta,
           "per_frame": {"residuals": res_t, "frame": np.arange(first, first + T)}}
    if warn or sk_warn:
        src["warnings"] = warn + sk_warn
    for w in warn:
        warnings.warn(f"{path}: {w}", HeaderMismatchWarning, stacklevel=2)
    for w in sk_warn:
        warnings.warn(f"{path}: {w}", MocapWarning, stacklevel=2)
    with np.errstate(over="ignore", invalid="ignore"):
        P = xyz * factor
    return Motion(P, sk, rate, obs, src, filled)


#: the parameter group of the joint hierarchy mocapkit writes (module docstring)
SKELETON_GROUP = "MOCAPKIT"


def _stored_skeleton(params: dict, names: list[str], factor: float, warn: list[str]
                     ) -> tuple[Skeleton, list[bool] | None]:
    """The skeleton of a file's points: the hierarchy of group ``MOCAPKIT`` when the file
    has one that fits, else a marker set (every point a root). Returns it and the
    per-point fixed-bone flags (None for a marker set). A group that does not fit adds a
    line to ``warn``."""
    N = len(names)
    marker_set = Skeleton(tuple(names), -np.ones(N, dtype=int), np.zeros((N, 3)))
    grp = params.get(SKELETON_GROUP)
    if not isinstance(grp, dict):
        return marker_set, None

    def value(key):
        v = grp.get(key)
        return None if not isinstance(v, dict) else np.asarray(v.get("value"), dtype=float)

    par, off, fix = value("PARENTS"), value("OFFSETS"), value("FIXED_BONES")
    bad = ("PARENTS" if par is None or par.shape != (N,) or not np.all(np.isin(par, np.arange(-1, N)))
           else "OFFSETS" if off is None or off.shape != (3, N) or not np.isfinite(off).all()
           else "FIXED_BONES" if fix is None or fix.shape != (N,) else None)
    if bad is None:
        try:
            sk = Skeleton(tuple(names), par.astype(int), off.T * factor)
        except MocapValueError:
            bad = "PARENTS"
    if bad is not None:
        warn.append(f"parameter {SKELETON_GROUP}:{bad} does not fit the {N} points: the joint hierarchy "
                    f"is ignored (read as a marker set)")
        return marker_set, None
    return sk, [bool(x) for x in (fix > 0) & (par >= 0)]


def _frame_rate(path: Path, c) -> float:
    """Frames per second: ``POINT:RATE``, else the header's rate; must be positive."""
    try:
        rate = float(c["parameters"]["POINT"]["RATE"]["value"][0])
    except (KeyError, IndexError, TypeError):
        rate = float(c["header"]["points"]["frame_rate"])
    if not np.isfinite(rate) or rate <= 0:
        raise MocapFormatError(path, f"bad POINT:RATE {rate!r} (frames per second must be positive)")
    return rate


def _point_units(path: Path, params: dict, units) -> tuple[str, float, str]:
    """(unit label, cm per file unit, how it was chosen): ``units=``, else ``POINT:UNITS``,
    else the C3D default mm."""
    file_units = None
    try:
        file_units = str(params["POINT"]["UNITS"]["value"][0]).strip()
    except (KeyError, IndexError, TypeError):
        pass
    if units is not None:
        return (*_unit_factor(units, path), "override (units=)")
    if file_units:
        if file_units.lower() not in UNITS:
            raise MocapFormatError(path, f"unknown POINT:UNITS {file_units!r} (expected one of "
                                   f"{', '.join(UNITS)}); pass units= to read it anyway")
        return file_units.lower(), UNITS[file_units.lower()], "POINT:UNITS"
    return "mm", UNITS["mm"], "no POINT:UNITS in the file; C3D default mm assumed"


def _analogs(c) -> dict[str, Any]:
    """Analog channel count and rate (the analog data themselves are not read)."""
    try:
        n_analog = int(np.asarray(c["data"]["analogs"]).shape[1])
    except (KeyError, IndexError):
        n_analog = 0
    analog_rate = float(c["header"]["analogs"].get("frame_rate", 0.0)) if "analogs" in c["header"] else 0.0
    return {"analog_channels": n_analog, "analog_rate": analog_rate}


def _residual_step(params: dict) -> float | None:
    """|POINT:SCALE|: one step of the residual byte, in file units (None if absent)."""
    try:
        v = abs(float(np.asarray(params["POINT"]["SCALE"]["value"], dtype=float).ravel()[0]))
    except (KeyError, TypeError, ValueError, IndexError):
        return None
    return v if np.isfinite(v) and v > 0 else None


def _check_scale(path: Path, params: dict) -> None:
    """POINT:SCALE must be a finite non-zero number: its sign is the storage format (negative:
    float) and, for integer storage, it multiplies every coordinate; NaN or 0 would read as
    every sample missing (or every coordinate 0)."""
    try:
        vals = np.asarray(params["POINT"]["SCALE"]["value"], dtype=float).ravel()
    except (KeyError, TypeError, ValueError):
        return                                     # ezc3d read it with its default
    bad = vals[~np.isfinite(vals) | (vals == 0)]
    if len(bad):
        raise MocapFormatError(path, f"bad POINT:SCALE {float(bad[0])!r}: it must be a finite non-zero "
                               f"number (negative: float storage; positive: the integer coordinates' "
                               f"scale), so the coordinates cannot be read")


#: residual quantum of a written file when the kept residuals allow it: 0.01 mm (in cm)
RESIDUAL_STEP_CM = 1e-3
_RES_MAX_STEPS = 255        # the residual is one byte of the 4th point word (C3D spec, ezc3d)


def _residuals_out(motion: Motion, factor: float) -> tuple[np.ndarray, float]:
    """(T, J) residuals to write (file units) and the residual step (``|POINT:SCALE|``).

    -1 missing, 0 filled (``motion.filled``), else the measured residual kept from a C3D
    input (``source['per_frame']['residuals']``, converted to the output unit), rounded to
    the step and at least one step (0 would mean "computed"); a measured sample without a
    known positive residual gets one step. The step is the input file's own
    ``|POINT:SCALE|`` when the kept residuals fit its 255 steps (so residuals round-trip
    exactly), else 0.01 mm, or ``max residual / 255`` when the residuals are larger than
    255 steps (the residual field is one byte).
    """
    T, J = motion.n_frames, motion.n_joints
    obs, filled = motion.observed, motion.filled & motion.observed
    src = motion.source
    known = np.zeros((T, J))
    to_out = 1.0
    stored = src.get("per_frame", {}).get("residuals")
    if src.get("format") == "c3d" and stored is not None and np.shape(stored) == (T, J):
        to_out = float(src.get("units", {}).get("cm_per_unit", 1.0)) / factor
        with np.errstate(all="ignore"):
            known = np.asarray(stored, float) * to_out
        known = np.where(np.isfinite(known) & (known > 0), known, 0.0)
    measured = obs & ~filled
    rmax = float(known[measured].max()) if measured.any() else 0.0
    step = float(np.float32(max(RESIDUAL_STEP_CM / factor, rmax / _RES_MAX_STEPS)))
    src_step = float(src.get("c3d", {}).get("residual_step") or 0.0) * to_out if known.any() else 0.0
    if np.isfinite(src_step) and src_step > 0 and rmax <= _RES_MAX_STEPS * src_step * (1 + 1e-6):
        step = float(np.float32(src_step))          # the input's own step: residuals kept exactly
    k = np.clip(np.rint(known / step), 1, _RES_MAX_STEPS)
    # (k + 0.5) steps: ezc3d stores int(residual / |scale|) (truncation), so this reads back as k steps
    res = np.where(measured, (k + 0.5) * step, np.where(filled, 0.0, -1.0))
    return res, step


def write(motion: Motion, path: str | os.PathLike, *, units: str | float | None = None) -> Path:
    """Write the motion's joints as C3D points (ezc3d, float storage), atomically.

    Labels: the original C3D labels when the motion came from a C3D with the same joints,
    else the joint names. Units: ``units=`` if given, else the source file's unit (C3D
    input), else ``mm``. Residuals: -1 missing (NaN coordinates), 0 filled
    (``motion.filled``), the measured residual otherwise (see :func:`_residuals_out`).
    Everything else of a source C3D file (analog channels, events, parameters, first
    frame) is kept when the motion still has its points and frames (:func:`_source_copy`);
    otherwise a :class:`~mocapkit.errors.MocapWarning` says it was left out.

    >>> import tempfile, warnings
    >>> from mocapkit import io
    >>> m = io.read("../shared/data/markers/pyomeca/markers_analogs.c3d")  # doctest: +SKIP
    >>> out = io.write(m, tempfile.mkdtemp() + "/clean.c3d")              # doctest: +SKIP
    >>> io.read(out).source["c3d"]["analog_channels"]                     # doctest: +SKIP
    38
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
    res, step = _residuals_out(motion, factor)
    parents = np.asarray(motion.skeleton.parents, dtype=int)

    def with_points(c):
        """``c`` with this motion's points, residuals, rate, unit and hierarchy."""
        c["parameters"]["POINT"]["RATE"]["value"] = [float(motion.fps)]
        c["parameters"]["POINT"]["UNITS"]["value"] = [ulabel]
        c["parameters"]["POINT"]["SCALE"]["value"] = [-step]          # negative: float storage
        if idx is None:
            c["data"]["points"] = pts
            c["data"]["meta_points"]["residuals"] = res.T[None, :, :]
        else:                              # the source's model outputs stay as they are
            P, R = np.array(c["data"]["points"], dtype=float), np.array(c["data"]["meta_points"]["residuals"])
            P[:, idx], R[0, idx] = pts, res.T
            c["data"]["points"], c["data"]["meta_points"]["residuals"] = P, R
        if (parents >= 0).any() and J <= 255:         # a C3D parameter dimension is one byte
            from ..rigid import fixed_bones

            fixed = np.zeros(J, int)
            fixed[fixed_bones(motion)[0][:, 0]] = 1
            # (add_parameter replaces a copied source's own values)
            c.add_parameter(SKELETON_GROUP, "PARENTS", parents.tolist())
            c.add_parameter(SKELETON_GROUP, "OFFSETS", np.asarray(motion.skeleton.offsets, float).T / factor)
            c.add_parameter(SKELETON_GROUP, "FIXED_BONES", fixed.tolist())
        return c

    copy, idx, why_not = _source_copy(motion, labels, T)

    def _write(tmp: str) -> None:
        nonlocal why_not, idx
        if copy is not None:
            try:
                with_points(copy).write(tmp)
                return
            except (RuntimeError, ValueError) as e:   # ezc3d's checks of the copied parameters
                why_not = (f"written without the source file's data other than the points: ezc3d "
                           f"could not write them back ({str(e).splitlines()[0][:160]})")
        c, idx = ezc3d.c3d(), None
        c["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
        c["data"]["meta_points"]["camera_masks"] = np.zeros((7, J, T), dtype=bool)
        try:
            with_points(c).write(tmp)
        except (RuntimeError, OSError, ValueError) as e:
            raise MocapFormatError(p, f"ezc3d could not write the file: {e}") from None
        if why_not:
            warnings.warn(f"{p}: {why_not}", MocapWarning, stacklevel=4)

    atomic_write_path(p, _write, suffix=".c3d")
    return p


def _source_copy(motion: Motion, labels: list[str], T: int) -> tuple[Any, np.ndarray | None, str | None]:
    """The motion's source C3D file as an ezc3d object, its analog channels, events,
    force-plate and other parameters kept, cut to the frames the motion holds, ready for
    :func:`write` to put the points in, and the file's point index of each joint (None:
    the joints are all the file's points); or (None, None, why) when it cannot be used --
    why is None when there is nothing to keep (the motion did not come from a C3D file).
    The file's model outputs (``POINT:ANGLES`` ..., not read as joints) stay as they are.

    Used when the motion has the source's points in the source's order and at its rate,
    and knows which frames of the file it holds (``source['per_frame']['frame']``,
    contiguous: :meth:`Motion.slice` keeps it, :meth:`Motion.resample` and
    :meth:`Motion.select` drop it). A slice moves the header's first frame with it (and
    ``TRIAL:ACTUAL_START_FIELD`` / ``END_FIELD`` where the file has them), so the
    events' times, which C3D counts from the capture's start, still fall on their frames.
    """
    import ezc3d

    src = motion.source
    meta = src.get("c3d") if src.get("format") == "c3d" else None
    if meta is None or not src.get("path"):
        return None, None, None
    lost = (f"its {meta.get('analog_channels', 0)} analog channels, events and other parameters"
            if meta.get("analog_channels") else "its events and other parameters")
    frames = src.get("per_frame", {}).get("frame")

    def refuse(why: str) -> tuple[None, None, str]:
        return None, None, f"written without the source file's data other than the points ({lost}): {why}"

    if frames is None or np.shape(frames) != (T,) or (T > 1 and not np.all(np.diff(frames) == 1)):
        return refuse("the motion's frames are not a stretch of the source's (resampled, or joints "
                      "selected)")
    if not np.isclose(float(motion.fps), float(meta.get("rate", np.nan))):
        return refuse(f"the motion is at {motion.fps:g} fps, the source at {meta.get('rate')} fps")
    if _unique_names([str(x) for x in meta.get("labels", [])], len(meta.get("labels", []))) != \
            list(motion.skeleton.names):
        return refuse("the motion's joints are not the source's points")
    path = Path(src["path"])
    try:
        _header(path)
        c = ezc3d.c3d(str(path), extract_forceplat_data=False)
    except (MocapFormatError, RuntimeError, OSError, ValueError, IndexError, MemoryError):
        return refuse(f"{path} can no longer be read")
    data, params = c["data"], c["parameters"]
    T0, N = int(np.shape(data["points"])[2]), int(np.shape(data["points"])[1])
    first = int(c["header"]["points"]["first_frame"])
    i0 = int(frames[0]) - first
    idx = meta.get("marker_points")
    file_labels = _labels(params, N)
    file_labels += [""] * (N - len(file_labels))
    if (N != meta.get("points_in_file", len(labels)) or first != meta.get("first_frame") or i0 < 0
            or i0 + T > T0 or (idx is not None and [file_labels[i] for i in idx] != list(labels))):
        return refuse(f"{path} has changed since it was read")
    if idx is None:
        file_labels = list(labels)
    else:
        idx = np.asarray(idx, dtype=int)
        data["points"] = np.asarray(data["points"])[..., i0:i0 + T]
        data["meta_points"]["residuals"] = np.asarray(data["meta_points"]["residuals"])[..., i0:i0 + T]
    for key in ("analogs", "rotations"):
        A = data.get(key)
        if A is None or np.size(A) == 0:
            continue
        r = np.shape(A)[-1] / T0                   # samples per point frame
        if r != int(r):
            return refuse(f"its {key} do not hold a whole number of samples per frame")
        data[key] = np.asarray(A)[..., i0 * int(r):(i0 + T) * int(r)]
    data["meta_points"]["camera_masks"] = np.asarray(data["meta_points"]["camera_masks"])[..., i0:i0 + T]
    c["header"]["points"]["first_frame"] = first + i0
    trial = params.get("TRIAL", {})
    for key, frame in (("ACTUAL_START_FIELD", first + i0 + 1), ("ACTUAL_END_FIELD", first + i0 + T)):
        if key in trial:                              # two 16-bit words, 1-based frame numbers
            trial[key]["value"] = [frame % 65536, frame // 65536]
    # one entry per point / channel: ezc3d refuses longer lists, which some files carry
    # (c3d.org's Eb015pr: 48 point labels for 26 points, 32 analog labels for 16 channels)
    point = params["POINT"]
    for key in [k for k in point if k[:6] in ("LABELS", "DESCRI") and k not in ("LABELS", "DESCRIPTIONS")]:
        del point[key]
    desc = [str(x) for x in point.get("DESCRIPTIONS", {}).get("value", [])]
    point["LABELS"]["value"] = tuple(file_labels)
    if "DESCRIPTIONS" in point:
        point["DESCRIPTIONS"]["value"] = tuple((desc + [""] * N)[:N])
    n_an = int(np.shape(data["analogs"])[1]) if np.ndim(data["analogs"]) == 3 else 0
    analog = params.get("ANALOG", {})
    for key in ("LABELS", "DESCRIPTIONS", "UNITS", "SCALE", "OFFSET"):
        v = analog.get(key, {}).get("value")
        if v is not None and len(v) > n_an:
            analog[key]["value"] = v[:n_an]
    return c, idx, None
