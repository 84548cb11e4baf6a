"""Kinect-style skeleton text files (MSR Action3D ``*_skeleton3D.txt``; Kinect v1/v2).

Format: one line per joint, ``x y z confidence`` (or ``x y z``), J lines per frame,
frames one after another, no header. J = 20 (MSR Action3D / Kinect v1) or 25
(Kinect v2); ``n_joints=`` chooses, otherwise it is detected: the line count must be a
multiple of exactly one of 20 and 25, and when it is a multiple of both (every 100
lines) the layout whose joints move least from frame to frame wins (a wrong J mixes
different body joints in one trajectory and jumps by tens of cm every frame).

What we found in the MSR Action3D data (567 files in ``../shared/data``; reproduced by
``benchmarks/io_bvh_text.py``, numbers in ``docs/results/io.md``):

* **Units**: all three axes are metres in a camera frame (y up, z = depth ~2.6 m).
  A per-axis total-least-squares fit of constant bone lengths on the arm and shin bones
  gives y/x = 0.97-1.00 and z/x = 0.99-1.00 scale ratios, i.e. one common scale (the
  estimated hip joints fit the constant-length model badly and say nothing); bone
  lengths are anatomical in metres
  (upper arm 28 cm, shin 43 cm, thigh 55 cm) and head-to-foot is 1.6 m (median). So
  the factor is 100 cm per unit. ``units='auto'`` picks m / cm / mm from the body size
  (median per-frame extent, closest to 160 cm); ``units=`` takes a name, a factor to cm
  or a 3-tuple of per-axis factors for non-metric (screen + depth) variants.
* **Joint order**: the order usually quoted for MSR Action3D (1 right shoulder, 2 left
  shoulder, 3 neck, 4 spine, 5 right hip, 6 left hip, 7 hip centre, 8/9 elbows,
  10/11 wrists, 12/13 hands, 14/15 knees, 16/17 ankles, 18/19 feet, 20 head) has the
  right structure (joint 20 is the top of the body, left/right pairs have equal bone
  lengths to 0.1 cm, within-clip bone length std 0-2 cm) but its **sides are mirrored**:
  in 295 of the 297 one-arm (a01-a09: high/horizontal wave, hammer, catch, punch, throw,
  draw x/tick/circle) and kick (a14, a15) clips the limb that moves more is the
  even-numbered one (joints 2, 9, 11, 13 / 6, 15, 17, 19), and the dataset's subjects
  were told to use the right arm/leg; in the right-handed camera frame (y up, subject
  facing -z: toes are nearer the camera than ankles) the subject's right is +x, which is
  where the even joints are. So joint 1 is ``ShoulderLeft``, 2 ``ShoulderRight``,
  5 ``HipLeft``, 6 ``HipRight`` etc. (``MSR20_FILE_ORDER``). Pass ``names=`` (20 names in
  file order) to use another labelling.
* **Confidence** is not a missing-data mask: 29% of all entries have confidence 0,
  among them joints (neck, spine, hip centre) whose positions are as consistent as the
  others: the joint-to-parent length deviates from its clip median by 0.28 cm on
  average where confidence is 0 and by 0.32 cm elsewhere. It is kept in
  ``source['per_frame']['confidence']`` and not used. **Missing data** in MSR files are
  whole frames written as ``0 0 0`` (1113 frames in 20 files; one file,
  ``a13_s09_e02``, has no tracked frame at all): a joint at exactly (0, 0, 0) - the
  camera centre - is read as missing (``observed`` False).

The Motion's joints use Kinect SDK names (``HipCenter``, ``ShoulderLeft``, ``ElbowRight``,
``Head`` ...) in a parent-first order (Kinect v1 SDK order; v2 SDK order with
``SpineShoulder`` moved before its children), so :meth:`Skeleton.body_parts` classifies
them; the file order is kept in ``source['kinect']['file_order']`` and used by the writer.
Rest offsets are the per-coordinate median bone vectors of the clip (cm), falling back
to the MSR data-set median for joints never observed. fps defaults to 15 (MSR Action3D),
``fps=`` overrides. Axes are kept as in the file.

The writer writes the same format (file joint order, metres by default, ``0 0 0`` for
missing joints, confidence from the source when it is aligned with the frames - as read,
missing joints included - else 1 for observed / 0 for missing; 3 columns if the source
had 3), atomically.
"""
from __future__ import annotations

import io
import os
import re
import warnings
from pathlib import Path

import numpy as np

from ..errors import MocapFormatError, MocapValueError
from ..motion import Motion
from ..skeleton import Skeleton
from ._atomic import atomic_write
from ._text import float_rows, read_text

__all__ = ["read", "write", "LAYOUTS", "MSR20_FILE_ORDER"]

# parent of every Kinect joint (None for the root)
_PARENT = {
    # v1 / MSR
    "HipCenter": None, "Spine": "HipCenter", "ShoulderCenter": "Spine", "Head": "ShoulderCenter",
    "ShoulderLeft": "ShoulderCenter", "ElbowLeft": "ShoulderLeft", "WristLeft": "ElbowLeft",
    "HandLeft": "WristLeft", "ShoulderRight": "ShoulderCenter", "ElbowRight": "ShoulderRight",
    "WristRight": "ElbowRight", "HandRight": "WristRight", "HipLeft": "HipCenter",
    "KneeLeft": "HipLeft", "AnkleLeft": "KneeLeft", "FootLeft": "AnkleLeft", "HipRight": "HipCenter",
    "KneeRight": "HipRight", "AnkleRight": "KneeRight", "FootRight": "AnkleRight",
}
_PARENT_V2 = {
    "SpineBase": None, "SpineMid": "SpineBase", "SpineShoulder": "SpineMid", "Neck": "SpineShoulder",
    "Head": "Neck", "ShoulderLeft": "SpineShoulder", "ElbowLeft": "ShoulderLeft",
    "WristLeft": "ElbowLeft", "HandLeft": "WristLeft", "HandTipLeft": "HandLeft",
    "ThumbLeft": "WristLeft", "ShoulderRight": "SpineShoulder", "ElbowRight": "ShoulderRight",
    "WristRight": "ElbowRight", "HandRight": "WristRight", "HandTipRight": "HandRight",
    "ThumbRight": "WristRight", "HipLeft": "SpineBase", "KneeLeft": "HipLeft", "AnkleLeft": "KneeLeft",
    "FootLeft": "AnkleLeft", "HipRight": "SpineBase", "KneeRight": "HipRight",
    "AnkleRight": "KneeRight", "FootRight": "AnkleRight",
}

#: MSR Action3D file order (1-based joint k is entry k-1), sides as found in the data
MSR20_FILE_ORDER = (
    "ShoulderLeft", "ShoulderRight", "ShoulderCenter", "Spine", "HipLeft", "HipRight", "HipCenter",
    "ElbowLeft", "ElbowRight", "WristLeft", "WristRight", "HandLeft", "HandRight", "KneeLeft",
    "KneeRight", "AnkleLeft", "AnkleRight", "FootLeft", "FootRight", "Head")
_V1_ORDER = (
    "HipCenter", "Spine", "ShoulderCenter", "Head", "ShoulderLeft", "ElbowLeft", "WristLeft",
    "HandLeft", "ShoulderRight", "ElbowRight", "WristRight", "HandRight", "HipLeft", "KneeLeft",
    "AnkleLeft", "FootLeft", "HipRight", "KneeRight", "AnkleRight", "FootRight")
_V2_FILE_ORDER = (
    "SpineBase", "SpineMid", "Neck", "Head", "ShoulderLeft", "ElbowLeft", "WristLeft", "HandLeft",
    "ShoulderRight", "ElbowRight", "WristRight", "HandRight", "HipLeft", "KneeLeft", "AnkleLeft",
    "FootLeft", "HipRight", "KneeRight", "AnkleRight", "FootRight", "SpineShoulder", "HandTipLeft",
    "ThumbLeft", "HandTipRight", "ThumbRight")
_V2_ORDER = (
    "SpineBase", "SpineMid", "SpineShoulder", "Neck", "Head", "ShoulderLeft", "ElbowLeft",
    "WristLeft", "HandLeft", "HandTipLeft", "ThumbLeft", "ShoulderRight", "ElbowRight", "WristRight",
    "HandRight", "HandTipRight", "ThumbRight", "HipLeft", "KneeLeft", "AnkleLeft", "FootLeft",
    "HipRight", "KneeRight", "AnkleRight", "FootRight")

#: layout name -> (file order, motion order, parents by name)
LAYOUTS = {
    "msr20": (MSR20_FILE_ORDER, _V1_ORDER, _PARENT),
    "kinect_v1": (_V1_ORDER, _V1_ORDER, _PARENT),
    "kinect_v2": (_V2_FILE_ORDER, _V2_ORDER, _PARENT_V2),
}
_DEFAULT_LAYOUT = {20: "msr20", 25: "kinect_v2"}

# MSR Action3D data-set median bone vectors (cm, file axes: x right, y up, z depth),
# used only for joints never observed in a clip.
_MSR_TEMPLATE_CM = {
    "HipCenter": (0.0, 0.0, 0.0), "Spine": (-0.8, 21.4, -0.3), "ShoulderCenter": (-1.8, 18.6, -18.5),
    "Head": (1.2, 22.9, -0.5), "ShoulderLeft": (-16.8, -5.3, 12.0), "ElbowLeft": (-5.9, -26.2, -1.0),
    "WristLeft": (1.4, -27.6, -6.8), "HandLeft": (1.0, -6.2, -0.6), "ShoulderRight": (18.6, -4.6, 9.2),
    "ElbowRight": (6.8, -24.1, -2.2), "WristRight": (-0.5, -17.3, -9.8), "HandRight": (-1.3, -4.1, -1.8),
    "HipLeft": (-19.3, -0.1, -10.5), "KneeLeft": (6.9, -53.1, 3.3), "AnkleLeft": (-0.9, -41.1, 7.7),
    "FootLeft": (-1.5, -3.2, -15.5), "HipRight": (16.8, -0.1, -13.4), "KneeRight": (-6.3, -52.8, 6.2),
    "AnkleRight": (0.1, -41.1, 7.8), "FootRight": (-0.8, -3.0, -15.4),
}

_UNITS = {"m": 100.0, "cm": 1.0, "mm": 0.1}
_TYPICAL_EXTENT_CM = 160.0       # head joint to foot joint of a standing adult


def _jumpiness(A: np.ndarray, J: int) -> float:
    """Median frame-to-frame displacement of the joints if the file had J joints a frame."""
    P = A[:, :3].reshape(-1, J, 3)
    ok = np.abs(P).sum(axis=(1, 2)) > 0
    P = P[ok]
    if len(P) < 2:
        return np.inf
    with np.errstate(over="ignore", invalid="ignore"):
        return float(np.median(np.linalg.norm(np.diff(P, axis=0), axis=2)))


def _resolve_units(units, P: np.ndarray, obs: np.ndarray, path):
    if units is None or (isinstance(units, str) and units.lower() == "auto"):
        ext = []
        if obs.any(axis=1).any():
            Q = np.where(obs[..., None], P, np.nan)
            Q = Q[obs.any(axis=1)]
            e = np.nanmax(Q, axis=1) - np.nanmin(Q, axis=1)           # (T', 3)
            e = e[np.isfinite(e).all(axis=1)]
            if len(e):
                ext = np.median(e.max(axis=1))
        if not np.size(ext) or not ext > 0:
            return np.full(3, 100.0), {"name": "m", "factor_to_cm": 100.0,
                                       "chosen_by": "default (no observed joint to infer a unit from)"}
        best = min(_UNITS, key=lambda u: abs(np.log(ext * _UNITS[u] / _TYPICAL_EXTENT_CM)))
        f = _UNITS[best]
        return np.full(3, f), {"name": best, "factor_to_cm": f,
                               "chosen_by": f"inferred: median body extent {ext:.4g} file units is "
                                            f"{ext * f:.0f} cm in {best} (override with units=)"}
    if isinstance(units, str):
        u = units.lower()
        if u not in _UNITS:
            raise MocapValueError(f"unknown Kinect unit {units!r}; use m, cm, mm, a factor to cm or "
                                  f"three per-axis factors")
        return np.full(3, _UNITS[u]), {"name": u, "factor_to_cm": _UNITS[u], "chosen_by": "user (units=)"}
    f = np.asarray(units, dtype=float).reshape(-1)
    if f.size == 1:
        f = np.repeat(f, 3)
    if f.size != 3 or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise MocapValueError(f"units must be a name, a positive factor to cm or three per-axis factors, "
                              f"got {units!r}")
    return f, {"name": "custom", "factor_to_cm": f.tolist() if len(set(f)) > 1 else float(f[0]),
               "chosen_by": "user (units=)"}


def read(path: str | os.PathLike, *, n_joints: int | None = None, fps: float = 15.0,
         units: str | float | tuple | None = None, layout: str | None = None,
         names: tuple[str, ...] | None = None) -> Motion:
    """Read a Kinect / MSR Action3D skeleton text file (positions in cm).

    Parameters
    ----------
    path : text file, J lines of ``x y z [confidence]`` per frame.
    n_joints : 20 or 25; default detected (see module docstring).
    fps : frame rate (the files do not store it); 15 for MSR Action3D.
    units : ``'auto'`` (default), ``'m'``/``'cm'``/``'mm'``, a factor to cm, or 3 factors.
    layout : ``'msr20'`` (default for 20 joints), ``'kinect_v1'`` or ``'kinect_v2'``.
    names : joint names in file order, overriding the layout's labels (same name set).
    """
    path = Path(path)
    A, line_nos = _joint_lines(path, read_text(path))
    n, ncol = A.shape
    J, chosen = _joints_per_frame(path, A, line_nos, n_joints, layout)
    lay = layout or _DEFAULT_LAYOUT[J]
    file_order, motion_order, parents_by_name = _layout(lay, J, names)
    T = n // J
    F = A.reshape(T, J, ncol)
    perm = [file_order.index(nm) for nm in motion_order]
    F = F[:, perm]
    raw = F[..., :3]
    obs = ~(raw == 0).all(axis=2)
    with np.errstate(over="ignore", invalid="ignore"):
        f, unit = _resolve_units(units, raw, obs, path)
        P = raw * f
    if not np.isfinite(P[obs]).all():
        raise MocapFormatError(path, "coordinates so large that they overflow when converted to cm")
    P = np.where(obs[..., None], P, np.nan)
    skeleton = _median_skeleton(P, obs, motion_order, parents_by_name)
    per_frame = {}
    if ncol == 4:
        per_frame["confidence"] = F[..., 3].copy()
    source = {"path": str(path), "format": "kinect", "units": unit,
              "kinect": {"layout": lay, "file_order": tuple(file_order), "columns": ncol,
                         "n_joints_chosen_by": chosen},
              "per_frame": per_frame}
    if not obs.any():
        source["warnings"] = ["no tracked joint in the whole file (every line is 0 0 0)"]
    return Motion(P, skeleton, fps, obs, source)


def _joint_lines(path: Path, text: str) -> tuple[np.ndarray, list[int]]:
    """(n, 3 or 4) values of the non-blank lines and their line numbers."""
    rows, line_nos = [], []
    for i, s in enumerate(text.splitlines()):
        r = s.split()
        if r:
            rows.append(r)
            line_nos.append(i + 1)
    if not rows:
        raise MocapFormatError(path, "empty file; expected lines of 'x y z confidence'", 1)
    ncol = len(rows[0])
    if ncol not in (3, 4):
        raise MocapFormatError(path, f"expected 3 or 4 values per line (x y z [confidence]), found "
                                     f"{ncol}", line_nos[0])
    A = float_rows(rows, line_nos, ncol, path,
                   "values (x y z confidence)" if ncol == 4 else "values (x y z)")
    return A, line_nos


def _joints_per_frame(path: Path, A: np.ndarray, line_nos: list[int], n_joints, layout) -> tuple[int, str]:
    """Joints per frame (20 or 25) and how it was chosen: ``n_joints=``, the layout, or the
    line count (both divide it: the smoother trajectories win)."""
    n = len(A)
    chosen = "user (n_joints=)"
    if n_joints is None and layout is not None:
        if layout not in LAYOUTS:
            raise MocapValueError(f"unknown layout {layout!r}; use one of {', '.join(LAYOUTS)}")
        n_joints = len(LAYOUTS[layout][0])
        chosen = f"layout {layout!r}"
    if n_joints is not None:
        J = int(n_joints)
        if J not in (20, 25):
            raise MocapValueError(f"n_joints must be 20 or 25, got {n_joints!r}")
        if n % J:
            raise MocapFormatError(path, f"{n} joint lines is not a multiple of {J} joints per frame "
                                         f"(truncated file?)", line_nos[-1])
        return J, chosen
    cands = [J for J in (20, 25) if n % J == 0]
    if not cands:
        raise MocapFormatError(path, f"{n} joint lines is a multiple of neither 20 nor 25 joints per "
                                     f"frame: truncated file? (or pass n_joints=)", line_nos[-1])
    if len(cands) == 1:
        return cands[0], f"auto: {n} lines divide only by {cands[0]}"
    jump = {J: _jumpiness(A, J) for J in cands}
    J = min(cands, key=lambda c: (jump[c], c))
    return J, (f"auto: {n} lines divide by 20 and 25; {J} joints give the smoother trajectories "
               f"(median frame-to-frame step {jump[20]:.4g} for 20 vs {jump[25]:.4g} for 25)")


def _layout(lay: str, J: int, names) -> tuple[tuple[str, ...], tuple[str, ...], dict]:
    """(file joint order, Motion joint order, parent by name) of layout ``lay``; ``names``
    (a permutation of the layout's names) relabels the file order."""
    if lay not in LAYOUTS:
        raise MocapValueError(f"unknown layout {lay!r}; use one of {', '.join(LAYOUTS)}")
    file_order, motion_order, parents_by_name = LAYOUTS[lay]
    if len(file_order) != J:
        raise MocapValueError(f"layout {lay!r} has {len(file_order)} joints, the file has {J} per frame")
    if names is not None:
        names = tuple(str(x) for x in names)
        if sorted(names) != sorted(file_order):
            raise MocapValueError(f"names= must be a permutation of the {lay} joint names: "
                                  f"{', '.join(file_order)}")
        file_order = names
    return file_order, motion_order, parents_by_name


def _median_skeleton(P: np.ndarray, obs: np.ndarray, motion_order, parents_by_name: dict) -> Skeleton:
    """Parent-first skeleton whose offsets are the per-coordinate median bone vectors (cm);
    a bone never observed takes the MSR template offset (zero for the root)."""
    J = len(motion_order)
    idx = {nm: j for j, nm in enumerate(motion_order)}
    par = np.array([idx[parents_by_name[nm]] if parents_by_name[nm] else -1 for nm in motion_order])
    V = np.where((par >= 0)[None, :, None], P - P[:, np.maximum(par, 0)], P)
    if obs.any():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)        # all-NaN joints
            offsets = np.nanmedian(V, axis=0)
    else:
        offsets = np.full((J, 3), np.nan)
    for j, nm in enumerate(motion_order):
        if not np.isfinite(offsets[j]).all():
            offsets[j] = _MSR_TEMPLATE_CM.get(nm, (0.0, 0.0, 0.0)) if par[j] >= 0 else 0.0
    return Skeleton(tuple(motion_order), par, offsets)


def write(motion: Motion, path: str | os.PathLike, *, layout: str | None = None,
          units: str | float = "m", confidence: bool | None = None) -> None:
    """Write ``motion`` in the Kinect / MSR text format (see module docstring).

    Parameters
    ----------
    layout : joint order in the file; default the source's layout, else the layout whose
        joint names the motion has (20 joints: ``'msr20'``).
    units : ``'m'`` (default, like MSR), ``'cm'``, ``'mm'`` or a factor to cm.
    confidence : write the 4th column; default: as in the source (4 columns if unknown).
    """
    src = motion.source
    meta = src.get("kinect") if src.get("format") == "kinect" else None
    names = tuple(motion.skeleton.names)
    if layout is None and meta is not None:
        file_order = tuple(meta["file_order"])
    else:
        if layout is None:
            fits = [k for k, (fo, _, _) in LAYOUTS.items() if sorted(fo) == sorted(names)]
            if not fits:
                raise MocapValueError(
                    f"the motion's joints ({len(names)}: {', '.join(names[:5])}...) are not a Kinect "
                    f"20/25-joint skeleton; the Kinect text format needs those joint names")
            layout = fits[0]
        if layout not in LAYOUTS:
            raise MocapValueError(f"unknown layout {layout!r}; use one of {', '.join(LAYOUTS)}")
        file_order = LAYOUTS[layout][0]
    if sorted(file_order) != sorted(names):
        missing = sorted(set(file_order) - set(names))
        raise MocapValueError(f"the motion's joints do not match the Kinect layout (missing: "
                              f"{', '.join(missing[:5]) or '-'}); the file needs exactly these joints: "
                              f"{', '.join(file_order)}")
    if isinstance(units, str):
        if units.lower() not in _UNITS:
            raise MocapValueError(f"unknown Kinect unit {units!r}; use m, cm or mm")
        f = _UNITS[units.lower()]
    else:
        f = float(units)
        if not np.isfinite(f) or f <= 0:
            raise MocapValueError(f"units must be a positive factor to cm, got {units!r}")
    perm = [names.index(nm) for nm in file_order]
    T, J = motion.n_frames, motion.n_joints
    X = np.where(motion.observed[..., None], motion.positions, 0.0)[:, perm] / f
    obs = motion.observed[:, perm]
    X[~obs] = 0.0
    if confidence is None:
        confidence = (meta or {}).get("columns", 4) == 4
    cols = [X[..., 0], X[..., 1], X[..., 2]]
    if confidence:
        conf = src.get("per_frame", {}).get("confidence")
        if conf is not None and np.shape(conf) == (T, J) and meta is not None:
            # stored in motion order; reorder to file order
            c = np.asarray(conf, float)[:, perm]
        else:
            c = obs.astype(float)
        cols.append(c)
    M = np.stack(cols, axis=-1).reshape(T * J, len(cols))

    def body(fh):
        buf = io.StringIO()
        np.savetxt(buf, M, fmt="%.9f", delimiter=" ")
        s = buf.getvalue()
        s = re.sub(r"(\.\d*?[1-9])0+(?=[ \n])", r"\1", s)
        s = re.sub(r"\.0+(?=[ \n])", ".0", s)
        fh.write(s)

    atomic_write(path, body)
