"""AMC motion files (Acclaim; CMU and HDM05 variants): parser (bulk tokeniser + line
parser), reader and writer.

The skeleton side (and the unit rule) is :mod:`mocapkit.io.asf`, the forward kinematics
and the write-back IK :mod:`mocapkit.io._kinematics`.

AMC (motion)
------------
Header keywords (``:FULLY-SPECIFIED``, ``:DEGREES`` / ``:RADIANS``), then frames: a frame
number line followed by one line per bone, ``name v1 v2 …`` with one value per dof in the
ASF's ``dof`` order (``root``: one per channel of the ASF ``order``). Frame numbers must
increase by one. In a ``:FULLY-SPECIFIED`` file every frame must list every bone that has
dofs; otherwise a missing bone keeps its previous value (zero in the first frame).

Metadata
--------
``motion.source``: ``path``, ``format`` (``'amc'`` / ``'asf'``), ``skeleton_path``,
``units`` (file unit description and ``cm_per_unit``), ``asf`` (the whole parsed skeleton
description as plain lists/dicts), ``amc`` (header lines, first frame number, bone order
per frame, angle unit), ``dof_names`` (``'root.TX'``, ``'lfemur.rx'``, …) and
``per_frame['dofs']``: the (T, D) dof values exactly as in the file (D = 62 for CMU).

Writing (AMC)
-------------
:func:`write` needs a motion that carries ``source['asf']`` (read from ASF/AMC). If
its positions still equal the forward kinematics of the stored dofs (within 1e-7 cm),
the stored dofs are written unchanged (shortest round-trip float text), so the file
re-reads identically. Otherwise the dofs are recovered by per-bone inverse kinematics
(:func:`mocapkit.io._kinematics.inverse_kinematics`, described there), top-down and
vectorised over frames.

A written AMC needs its ASF: when the skeleton lookup for the output file would not
find an identical skeleton, ``<output stem>.asf`` is written beside it
(``write_asf=False`` to skip, or a path to choose where).
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ..errors import MocapFormatError, MocapValueError
from ..motion import Motion
from ._atomic import atomic_write
from ._text import read_text as _read_text
from .asf import _asf_text, _num, _same_skeleton, cm_per_unit, find_skeleton, read_asf
from ._kinematics import _Compiled, forward_kinematics, inverse_kinematics, require_complete

__all__ = ["read", "read_asf_motion", "write"]

_UNCHANGED_TOL_CM = 1e-7


# ======================================================================================
# AMC parsing
# ======================================================================================
_HEADER_RE = re.compile(r"(?:[ \t]*(?:[#:][^\n]*)?(?:\r?\n|\r))*")


_FPS_RE = re.compile(r"#\s*fps\s+([0-9]+(?:\.[0-9]*)?)\s*$", re.IGNORECASE)


def _amc_header(text: str):
    m = _HEADER_RE.match(text)
    end = m.end() if m else 0
    head = text[:end]
    head_lines = head.splitlines()
    return end, head_lines


def _parse_amc(path, text: str, comp: _Compiled, asf_path) -> tuple[np.ndarray, bool, dict]:
    """Return (dofs (T, D) as in the file, angles in radians?, AMC metadata).

    The bulk tokeniser handles the usual layout (same bones in the same order in every
    frame); anything else, including every malformed file, goes through the line parser,
    which accepts any bone order and names the offending line.
    """
    start, head_lines = _amc_header(text)
    n_head = len(head_lines)
    keys = [h.strip().upper() for h in head_lines if h.strip().startswith(":")]
    fully = ":FULLY-SPECIFIED" in keys
    if ":RADIANS" in keys:
        angle_rad = True
    elif ":DEGREES" in keys:
        angle_rad = False
    else:
        angle_rad = comp.angle_rad
    meta = {"header": [h.rstrip() for h in head_lines if h.strip()], "fully_specified": fully,
            "angle": "rad" if angle_rad else "deg"}
    for h in head_lines:                       # "# fps 30": mocapkit's writer (read's doc)
        m = _FPS_RE.match(h.strip())
        if m and 0 < float(m.group(1)) < 1e6:
            meta["fps"] = float(m.group(1))
    body = text[start:]
    dofs = None
    try:
        dofs, first, bone_seq = _parse_amc_bulk(body, comp)
    except _BulkFail:
        dofs = None
    if dofs is None:
        dofs, first, bone_seq = _parse_amc_lines(path, body, n_head, comp, fully, asf_path)
    meta["first_frame"] = first
    meta["bone_order"] = bone_seq
    return dofs, angle_rad, meta


class _BulkFail(Exception):
    pass


def _parse_amc_bulk(body: str, comp: _Compiled):
    """Fast path: every frame lists the same bones in the same order (true for CMU/HDM05)."""
    toks = body.split()
    if not toks:
        raise _BulkFail
    # structure of the first frame
    seq: list[str] = []
    i = 1
    while i < len(toks):
        name = toks[i]
        if name not in comp.dof_cols or name in seq:
            if name.lstrip("-").isdigit():
                break
            raise _BulkFail
        seq.append(name)
        i += 1 + len(comp.dof_cols[name])
    n = 1 + sum(1 + len(comp.dof_cols[b]) for b in seq)
    if len(toks) % n or len(toks) < n:
        raise _BulkFail
    need = [b for b in comp.dof_cols if comp.dof_cols[b]]
    if set(need) - set(seq):
        raise _BulkFail
    T = len(toks) // n
    A = np.array(toks, dtype=object).reshape(T, n)
    name_pos, val_pos, val_cols = [], [], []
    k = 1
    for b in seq:
        name_pos.append(k)
        cols = comp.dof_cols[b]
        val_pos += list(range(k + 1, k + 1 + len(cols)))
        val_cols += cols
        k += 1 + len(cols)
    if not (A[:, name_pos] == np.array(seq, dtype=object)[None, :]).all():
        raise _BulkFail
    try:
        frames = A[:, 0].astype(np.int64)
        V = np.array(A[:, val_pos].ravel().tolist(), dtype=np.float64).reshape(T, len(val_pos))
    except (ValueError, TypeError):
        raise _BulkFail from None
    if not np.isfinite(V).all():
        raise _BulkFail
    if not np.array_equal(frames, frames[0] + np.arange(T)):
        raise _BulkFail
    dofs = np.zeros((T, comp.n_dofs))
    dofs[:, val_cols] = V
    return dofs, int(frames[0]), seq


def _parse_amc_lines(path, body: str, line0: int, comp: _Compiled, fully: bool, asf_path):
    """Line-by-line parser: handles any order/omission and names the line of any error."""
    asf_name = Path(asf_path).name if asf_path else "the skeleton"
    rows: list[np.ndarray] = []
    frame_no: list[int] = []
    cur: np.ndarray | None = None
    cur_seen: set[str] = set()
    cur_line = 0
    seq: list[str] = []
    prev = np.zeros(comp.n_dofs)

    def close(ln_end):
        if cur is None:
            return
        if fully:
            missing = [b for b in comp.dof_cols if comp.dof_cols[b] and b not in cur_seen]
            if missing:
                raise MocapFormatError(path, f"frame {frame_no[-1]} (line {cur_line}) is incomplete: "
                                       f"no values for {', '.join(missing[:6])}"
                                       f"{' …' if len(missing) > 6 else ''} (truncated frame?)", ln_end)
        rows.append(cur)

    last_ln = line0
    for ln, raw in enumerate(body.splitlines(), start=line0 + 1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        last_ln = ln
        toks = s.split()
        if s.startswith(":"):
            raise MocapFormatError(path, f"header keyword {toks[0]!r} after the first frame", ln)
        if len(toks) == 1 and re.fullmatch(r"[+-]?\d+", toks[0]):
            num = int(toks[0])
            if frame_no and num != frame_no[-1] + 1:
                raise MocapFormatError(path, f"frame number {num} out of sequence (expected "
                                       f"{frame_no[-1] + 1})", ln)
            close(ln)
            if cur is not None:
                prev = cur
            cur = prev.copy()
            cur_seen = set()
            cur_line = ln
            frame_no.append(num)
            continue
        name = toks[0]
        if cur is None:
            raise MocapFormatError(path, f"expected a frame number, found {s[:40]!r}", ln)
        if len(toks) == 1 and re.fullmatch(r"[+-]?[\d.eE+-]+", name):
            raise MocapFormatError(path, f"expected an integer frame number, found {name!r}", ln)
        if name not in comp.dof_cols:
            raise MocapFormatError(path, f"unknown bone {name!r}: not in {asf_name} "
                                   f"(mismatched ASF/AMC pair?)", ln)
        cols = comp.dof_cols[name]
        dofdesc = " ".join(comp.root_order if name == "root" else comp.bone_dofs[name]) or "none"
        if len(toks) - 1 != len(cols):
            raise MocapFormatError(path, f"bone {name!r} needs {len(cols)} values (dof {dofdesc}), "
                                   f"found {len(toks) - 1}", ln)
        if name in cur_seen:
            raise MocapFormatError(path, f"bone {name!r} appears twice in frame {frame_no[-1]}", ln)
        vals = [_num(t, path, ln, f"value of {name}") for t in toks[1:]]
        cur[cols] = vals
        cur_seen.add(name)
        if len(frame_no) == 1:
            seq.append(name)
    close(last_ln)
    if not rows:
        raise MocapFormatError(path, "no frames (empty motion)", last_ln if last_ln > line0 else None)
    return np.array(rows), frame_no[0], seq


# ======================================================================================
# public readers
# ======================================================================================
def _units_info(asf: dict, f: float, override) -> dict:
    s = asf["units"]["length"]
    return {"file": f"ASF length unit (':units length {s:g}' = inch x {s:g})",
            "cm_per_unit": f, "angle": asf["units"]["angle"],
            "how": "override (units=)" if override is not None else f"2.54 / {s:g}"}


def read(path: str | os.PathLike, *, skeleton: str | os.PathLike | None = None,
         units: float | str | None = None, fps: float | None = None) -> Motion:
    """Read an AMC motion (with its ASF skeleton) into a Motion in cm.

    Parameters
    ----------
    path : the ``.amc`` file.
    skeleton : the ``.asf`` file; default: found by :func:`find_skeleton`.
    units : cm per file length unit (default ``2.54 / ASF length``, 5.644444 for CMU/HDM05).
    fps : frame rate. The AMC format stores none: default the ``# fps N`` header comment
        mocapkit's writer adds (so that a resampled clip comes back at its own rate), else
        120 Hz (CMU and HDM05 record at 120 Hz).

    Returns
    -------
    Motion with joints ``root`` + one per bone (end points), positions (T, J, 3) cm.

    Raises
    ------
    MocapFormatError naming the file and line (see module docstring).
    """
    path = Path(path)
    asf_path = Path(skeleton) if skeleton is not None else find_skeleton(path)
    if not asf_path.is_file():
        raise MocapFormatError(asf_path, "skeleton file not found")
    asf = read_asf(asf_path)
    with np.errstate(over="ignore", invalid="ignore"):
        comp = _Compiled(asf)
    f = cm_per_unit(asf, units)
    text = _read_text(path)
    if text.lstrip().startswith(":version") or ":bonedata" in text[:4096]:
        raise MocapFormatError(path, "this is an ASF skeleton, not an AMC motion", 1)
    dofs, angle_rad, meta = _parse_amc(path, text, comp, asf_path)
    if fps is None:
        fps = meta.get("fps") or 120.0
    P, sk = _finite_pose(path, asf_path, comp, dofs, angle_rad, f)
    src = {"path": str(path), "format": "amc", "skeleton_path": str(asf_path),
           "units": _units_info(asf, f, units), "asf": asf, "amc": meta,
           "dof_names": list(comp.dof_names), "per_frame": {"dofs": dofs}}
    return Motion(P, sk, fps, None, src)


def _finite_pose(path, asf_path, comp: _Compiled, dofs: np.ndarray, angle_rad: bool, f: float):
    """Forward kinematics and skeleton; numbers so large that they overflow are a format error
    (never positions silently turned into missing entries)."""
    with np.errstate(over="ignore", invalid="ignore"):
        P = forward_kinematics(comp, dofs, angle_rad, f)
        sk = comp.skeleton(f)
    if not (np.isfinite(P).all() and np.isfinite(sk.offsets).all()):
        raise MocapFormatError(asf_path if not np.isfinite(sk.offsets).all() else path,
                               "lengths, offsets or angles so large that joint positions overflow")
    return P, sk


def read_asf_motion(path: str | os.PathLike, *, units: float | str | None = None) -> Motion:
    """The ASF rest pose as a 1-frame Motion (root at the ASF ``position``, all angles zero)."""
    path = Path(path)
    asf = read_asf(path)
    with np.errstate(over="ignore", invalid="ignore"):
        comp = _Compiled(asf)
    f = cm_per_unit(asf, units)
    dofs = np.zeros((1, comp.n_dofs))
    for k, ch in enumerate(comp.root_order):
        if ch[0] == "T":
            dofs[0, k] = asf["root"]["position"]["XYZ".index(ch[1])]
    P, sk = _finite_pose(path, path, comp, dofs, comp.angle_rad, f)
    meta = {"header": [":FULLY-SPECIFIED", ":RADIANS" if comp.angle_rad else ":DEGREES"],
            "fully_specified": True, "angle": asf["units"]["angle"], "first_frame": 1,
            "bone_order": ["root"] + [b["name"] for b in asf["bones"] if b["dof"]]}
    src = {"path": str(path), "format": "asf", "skeleton_path": str(path),
           "units": _units_info(asf, f, units), "asf": asf, "amc": meta,
           "dof_names": list(comp.dof_names), "per_frame": {"dofs": dofs}}
    return Motion(P, sk, 120.0, None, src)



# ======================================================================================
# writer
# ======================================================================================
def _amc_text(comp: _Compiled, dofs: np.ndarray, meta: dict, angle_rad: bool, asf_name: str,
              fps: float = 120.0) -> str:
    T = dofs.shape[0]
    first = int(meta.get("first_frame", 1))
    order = [b for b in meta.get("bone_order", []) if b in comp.dof_cols and comp.dof_cols[b]]
    for b in ["root"] + [x["name"] for x in comp.asf["bones"]]:
        if comp.dof_cols[b] and b not in order:
            order.append(b)
    cols = []
    fmt = ["{}"]
    for b in order:
        cols += comp.dof_cols[b]
        fmt.append(b + "".join(" {!r}" for _ in comp.dof_cols[b]))
    line_fmt = "\n".join(fmt) + "\n"
    head = [f"#!OML:ASF {asf_name}", "# written by mocapkit", f"# fps {float(fps):g}",
            ":FULLY-SPECIFIED", ":RADIANS" if angle_rad else ":DEGREES"]
    V = dofs[:, cols] + 0.0                                  # -0.0 -> 0.0 kept as is by repr
    rows = V.tolist()
    body = "".join(line_fmt.format(first + t, *rows[t]) for t in range(T))
    return "\n".join(head) + "\n" + body


def write(motion: Motion, path: str | os.PathLike, *, write_asf: bool | str | os.PathLike | None = None,
          precision: int | None = None) -> Path:
    """Write ``motion`` as an AMC (dofs recovered by IK when the positions changed).

    Parameters
    ----------
    motion : a Motion read from ASF/AMC (``source['asf']``), possibly cleaned/sliced.
    path : output ``.amc``.
    write_asf : ``None`` (default): write ``<stem>.asf`` beside the AMC unless the
        skeleton lookup for the output already finds an identical skeleton; ``False``:
        never; a path: write the ASF there.
    precision : significant digits for IK-recovered values (default: exact shortest
        round-trip text).

    Raises
    ------
    MocapValueError when the motion has no ASF description, its joints do not match it, or
    it has missing samples (:func:`~mocapkit.io._kinematics.require_complete`).
    """
    p = Path(path)
    src = motion.source
    asf = src.get("asf")
    if not isinstance(asf, dict) or "bones" not in asf:
        raise MocapValueError("AMC output needs a motion read from an ASF/AMC file (its skeleton "
                              "description is in source['asf']); write this motion as BVH or C3D instead")
    require_complete(motion, "AMC")
    comp = _Compiled(asf)
    if tuple(motion.skeleton.names) != comp.names:
        raise MocapValueError(f"motion joints do not match its ASF skeleton ({motion.n_joints} joints vs "
                              f"{len(comp.names)}: root + bones); AMC output needs every bone")
    units = src.get("units", {})
    f = float(units.get("cm_per_unit", cm_per_unit(asf)))
    meta = dict(src.get("amc", {}))
    angle_rad = meta.get("angle", asf["units"]["angle"]) == "rad"
    stored = src.get("per_frame", {}).get("dofs")
    T = motion.n_frames
    start = None
    if stored is not None and np.shape(stored) == (T, comp.n_dofs):
        start = np.asarray(stored, float)
        P0 = forward_kinematics(comp, start, angle_rad, f)
        if motion.observed.all() and np.max(np.abs(P0 - motion.positions)) <= _UNCHANGED_TOL_CM:
            dofs = start
        else:
            dofs = inverse_kinematics(comp, motion.positions, f, angle_rad, start)
    else:
        dofs = inverse_kinematics(comp, motion.positions, f, angle_rad, None)
    if precision is not None and dofs is not start:
        dofs = np.array([float(f"{v:.{int(precision)}g}") for v in dofs.ravel()]).reshape(dofs.shape)
    # ASF companion
    asf_out: Path | None = None
    if write_asf is None:
        try:
            found = find_skeleton(p)
            same = _same_skeleton(read_asf(found), asf)
        except MocapFormatError:
            found, same = None, False
        if not same:
            asf_out = p.with_suffix(".asf")
            if asf_out.exists():
                raise MocapValueError(f"{asf_out} exists and is not this motion's skeleton; choose another "
                                      f"output name or pass write_asf=False / write_asf=PATH")
    elif write_asf is not False and write_asf is not True:
        asf_out = Path(write_asf)
    elif write_asf is True:
        asf_out = p.with_suffix(".asf")
    text = _amc_text(comp, dofs, meta, angle_rad, asf_out.name if asf_out else
                     Path(src.get("skeleton_path", "skeleton.asf")).name, motion.fps)
    if asf_out is not None:
        write_asf_file = _asf_text(asf)
        atomic_write(asf_out, lambda fh: fh.write(write_asf_file))
    atomic_write(p, lambda fh: fh.write(text))
    return p
