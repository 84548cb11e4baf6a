"""BVH (Biovision hierarchy) reader and writer.

Reading
-------
``read(path, *, units=None, end_sites=False)`` parses HIERARCHY/MOTION, runs forward
kinematics over all frames at once (numpy, one loop over joints, none over frames) and
returns a :class:`~mocapkit.motion.Motion` with joint positions in **cm**.

* **Channels.** Any order of ``Xrotation/Yrotation/Zrotation`` per joint (CMU conversions
  mix ``Zrotation Yrotation Xrotation`` and ``Zrotation Xrotation Yrotation``); the local
  rotation is the product of the axis rotations *in the order listed*
  (``R = R_1 R_2 R_3``, column vectors, degrees), the usual BVH convention. Position
  channels are allowed on any joint (not only the root): when present they *replace*
  the matching OFFSET component as the joint's translation from its parent (the
  MotionBuilder 7.5 conversion writes the root OFFSET equal to frame 0's position
  channels, which confirms this reading). Translation is applied before rotation.
* **End Sites** are not joints of the returned Motion (they carry no channels and
  no data of their own); they are kept in ``motion.source['bvh']['nodes']`` so
  :func:`write` reproduces them. ``read(..., end_sites=True)`` adds them as joints named
  ``<parent>_End`` (positions from FK) for users who want every node of the file.
* **Units.** The file does not state its unit. ``units=`` takes a factor to cm or a
  name (``'cm'``, ``'mm'``, ``'m'``, ``'inch'``, ``'cmu'``; CMU unit = 1/0.45 inch =
  5.644444 cm, used by the cgspeed conversions). By default the unit is inferred: the
  rest-pose extent of the skeleton (largest of its three axis spans, end sites included)
  is converted with each candidate unit and the one closest (in log scale) to a 175 cm
  adult is chosen; candidates differ by at least a factor 2.2, so a 150-200 cm person
  is never ambiguous. The factor and how it was chosen are in
  ``motion.source['units']``.
* **Metadata.** ``motion.source['bvh']`` holds the hierarchy (every node: name, parent
  node, OFFSET in file units, channel list, whether it is an End Site), the frame
  time, and which node each Motion joint is; ``motion.source['per_frame']['channels']``
  holds the raw (T, C) channel values (degrees / file units) so ``Motion.slice`` keeps
  them aligned with the frames. All frames are kept (the first frame of the cgspeed
  files is a T-pose; it is not guessed away).
* **Errors.** Malformed input raises :class:`~mocapkit.errors.MocapFormatError` with
  the file, the line and what was expected: unknown keyword, missing OFFSET/CHANNELS,
  unbalanced braces, duplicate joint names, missing MOTION section, ``Frames: 0``,
  truncated data, a frame line with the wrong number of values, NaN/inf/garbage, a
  ``Frame Time`` outside :data:`FRAME_TIME_RANGE` (1e-4 .. 10 s per frame, i.e.
  10,000 .. 0.1 fps; 0, negative, ``1e-300`` and ``inf`` are refused with the line).

Writing
-------
``write(motion, path, *, hierarchy='auto', units=None)`` keeps the hierarchy and every
joint's channel order. Rotations are recovered from the positions by per-joint inverse
kinematics, top-down and vectorised over frames:

1. each joint starts from its original local rotation ``L0`` when the motion still
   carries the per-frame channels of its own frames (``source['per_frame']``; kept by
   ``with_positions`` and ``slice``), else from identity (rest pose);
2. its global rotation is corrected by the rotation ``Q`` that best maps the bone
   vectors to its children as predicted by ``L0`` onto the vectors to the children's
   target positions: the minimal (shortest-arc) rotation for one child, the
   Kabsch/SVD rotation for several (hips, chest). Children at zero offset (CMU
   ``LHipJoint``, ``LowerBack`` ...) are looked through to their own children; rigidly
   attached children decide first and the looked-through ones only fix what those leave
   free (the twist about a single bone), since the zero-length joint in between corrects
   its own subtree; children with position channels are skipped (their translation is
   solved exactly instead); a leaf keeps ``L0``;
3. ``L = G_parent^T Q G_parent L0`` is converted back to Euler angles in the joint's own
   channel order (the branch and 360-degree turn nearest to the original value, or
   unwrapped over time without one).

Root translation (and any joint's position channels) come from the target positions.
If the positions are unchanged the written file re-reads to ~1e-9 cm; values are written
with 9 decimals (trailing zeros trimmed). Motions with missing entries are refused (fill
gaps first), as are motions whose joints do not match the stored hierarchy (pass
``hierarchy='skeleton'`` to build a new hierarchy from ``motion.skeleton``: root with 6
channels, other joints ``Zrotation Xrotation Yrotation``, an End Site on each leaf).
"""
from __future__ import annotations

import io
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._rotations import axis_rotation
from ..errors import MocapFormatError, MocapValueError
from ..motion import Motion
from ..skeleton import Skeleton
from ._atomic import atomic_write
from ._text import float_rows, parse_float, parse_int, read_text

__all__ = ["read", "write", "node_positions", "UNITS"]

#: unit name -> factor to cm
UNITS: dict[str, float] = {
    "cm": 1.0,
    "mm": 0.1,
    "m": 100.0,
    "inch": 2.54,
    "cmu": 2.54 / 0.45,
}
_UNIT_ALIASES = {"in": "inch", "inches": "inch", "centimeter": "cm", "centimetre": "cm",
                 "millimeter": "mm", "millimetre": "mm", "meter": "m", "metre": "m",
                 "cmu_unit": "cmu", "cmu units": "cmu"}
_UNIT_LABEL = {"cm": "centimetre", "mm": "millimetre", "m": "metre", "inch": "inch",
               "cmu": "CMU unit (1/0.45 inch = 5.644444 cm)"}
_TYPICAL_HEIGHT_CM = 175.0

_CHANNELS = {"xposition": "Xposition", "yposition": "Yposition", "zposition": "Zposition",
             "xrotation": "Xrotation", "yrotation": "Yrotation", "zrotation": "Zrotation"}
_AXIS = {"X": 0, "Y": 1, "Z": 2}
_EPS_LEN = 1e-9


# ----------------------------------------------------------------------------------------
# hierarchy
# ----------------------------------------------------------------------------------------
@dataclass
class _Node:
    name: str
    parent: int                     # node index, -1 for a root
    line: int
    offset: np.ndarray | None = None
    channels: tuple[str, ...] | None = None
    end_site: bool = False
    children: list[int] = field(default_factory=list)


def _tokens(lines: list[str], start: int, stop: int):
    """(token, 1-based line) for lines[start:stop]; braces are split off names."""
    out = []
    for i in range(start, stop):
        s = lines[i]
        if "{" in s or "}" in s:
            s = s.replace("{", " { ").replace("}", " } ")
        for t in s.split():
            out.append((t, i + 1))
    return out


class _HierarchyParser:
    def __init__(self, path, toks, last_line: int):
        self.path, self.toks, self.i, self.last_line = path, toks, 0, last_line
        self.nodes: list[_Node] = []
        self.names: dict[str, int] = {}

    def err(self, msg, line=None):
        raise MocapFormatError(self.path, msg, line)

    def peek(self):
        return self.toks[self.i] if self.i < len(self.toks) else (None, self.last_line)

    def take(self, expected: str | None = None, context: str = ""):
        tok, line = self.peek()
        if tok is None:
            self.err(f"file ends inside the hierarchy{context}; expected {expected or 'more'}"
                     f" (unbalanced braces or missing MOTION section?)", self.last_line)
        if expected is not None and tok != expected:
            self.err(f"expected {expected!r}{context}, found {tok!r}", line)
        self.i += 1
        return tok, line

    def parse(self):
        tok, line = self.peek()
        if tok is None:
            self.err("empty file; expected a BVH file starting with HIERARCHY", 1)
        if tok.upper() != "HIERARCHY":
            self.err(f"expected 'HIERARCHY' at the start of a BVH file, found {tok!r}", line)
        self.i += 1
        while True:
            tok, line = self.peek()
            if tok is None:
                self.err("missing MOTION section (the file ends after the hierarchy)", self.last_line)
            up = tok.upper()
            if up == "ROOT":
                self.i += 1
                self.joint(-1, "ROOT", line)
            elif up == "MOTION":
                break
            elif tok == "}":
                self.err("unbalanced braces: '}' without a matching '{'", line)
            else:
                self.err(f"unknown keyword {tok!r} in HIERARCHY; expected ROOT or MOTION", line)
        if not self.nodes:
            self.err("the hierarchy has no ROOT joint", line)
        return self.nodes

    def joint(self, parent: int, kind: str, line0: int, end_site: bool = False):
        if end_site:
            pname = self.nodes[parent].name
            name = f"{pname}_End"
        else:
            name, ln = self.take(context=f" (the name of a {kind})")
            if name in ("{", "}"):
                self.err(f"{kind} without a name", ln)
            if name in self.names:
                self.err(f"duplicate joint name {name!r} (first defined on line "
                         f"{self.nodes[self.names[name]].line})", ln)
        idx = len(self.nodes)
        node = _Node(name=name, parent=parent, line=line0, end_site=end_site)
        self.nodes.append(node)
        if not end_site:
            self.names[name] = idx
        if parent >= 0:
            self.nodes[parent].children.append(idx)
        _, open_line = self.take("{", context=f" after {kind} {name if not end_site else ''}".rstrip())
        while True:
            tok, line = self.peek()
            if tok is None:
                self.err(f"unbalanced braces: '{{' of {kind} {name!r} (line {open_line}) is never "
                         f"closed", self.last_line)
            up = tok.upper()
            if tok == "}":
                self.i += 1
                break
            self.i += 1
            if up == "OFFSET":
                if node.offset is not None:
                    self.err(f"second OFFSET in {kind} {name!r}", line)
                vals = [parse_float(self.take(context=" (OFFSET needs 3 numbers)")[0], self.path, line,
                                    "an OFFSET number") for _ in range(3)]
                node.offset = np.array(vals)
            elif up == "CHANNELS":
                if end_site:
                    self.err("an End Site cannot have CHANNELS", line)
                if node.channels is not None:
                    self.err(f"second CHANNELS in {kind} {name!r}", line)
                n = parse_int(self.take(context=" (CHANNELS count)")[0], self.path, line,
                              "the CHANNELS count", minimum=0)
                chans = []
                for _ in range(n):
                    t, ln = self.take(context=f" (CHANNELS {n} needs {n} channel names)")
                    c = _CHANNELS.get(t.lower())
                    if c is None:
                        self.err(f"unknown channel {t!r}; expected one of "
                                 f"{', '.join(_CHANNELS.values())} (CHANNELS {n} declares {n})", ln)
                    chans.append(c)
                if len(set(chans)) != len(chans):
                    self.err(f"repeated channel in CHANNELS of {name!r}: {' '.join(chans)}", line)
                node.channels = tuple(chans)
            elif up == "JOINT":
                if end_site:
                    self.err("an End Site cannot have child joints", line)
                self.joint(idx, "JOINT", line)
            elif up == "END":
                if end_site:
                    self.err("an End Site cannot contain another End Site", line)
                self.take("Site", context=" after 'End'")
                self.joint(idx, "End Site", line, end_site=True)
            elif up == "MOTION":
                self.err(f"unbalanced braces: MOTION reached while {kind} {name!r} (opened on line "
                         f"{open_line}) is still open", line)
            elif up in ("ROOT", "HIERARCHY"):
                self.err(f"unexpected {tok!r} inside {kind} {name!r}", line)
            else:
                self.err(f"unknown keyword {tok!r} in {kind} {name!r}; expected OFFSET, CHANNELS, "
                         f"JOINT, End Site or '}}'", line)
        if node.offset is None:
            self.err(f"{kind} {name!r} has no OFFSET", line0)
        if node.channels is None:
            if end_site:
                node.channels = ()
            else:
                self.err(f"{kind} {name!r} has no CHANNELS line", line0)
        return idx


# ----------------------------------------------------------------------------------------
# rotations
# ----------------------------------------------------------------------------------------
def _axis_rot(axis: int, deg: np.ndarray) -> np.ndarray:
    """Rotation matrices (T, 3, 3) about one coordinate axis by ``deg`` degrees (T,)."""
    return axis_rotation(axis, np.deg2rad(deg))


def _layout(nodes: list[_Node]):
    """Per node: (rotation axes, their columns), (position axes, their columns); total C."""
    col = 0
    rot, pos = [], []
    for n in nodes:
        ra, rc, pa, pc = [], [], [], []
        for ch in n.channels:
            ax = _AXIS[ch[0]]
            if ch.endswith("rotation"):
                ra.append(ax), rc.append(col)
            else:
                pa.append(ax), pc.append(col)
            col += 1
        rot.append((ra, rc))
        pos.append((pa, pc))
    return rot, pos, col


def _local_rot(axes, cols, ch: np.ndarray | None, T: int) -> np.ndarray:
    """Local rotation (T, 3, 3) = product of the axis rotations in channel order."""
    R = np.broadcast_to(np.eye(3), (T, 3, 3)).copy()
    if ch is None or not axes:
        return R
    for ax, c in zip(axes, cols):
        R = R @ _axis_rot(ax, ch[:, c])
    return R


def _translation(node: _Node, axes, cols, ch: np.ndarray | None, T: int) -> np.ndarray:
    t = np.broadcast_to(node.offset, (T, 3)).copy()
    if ch is not None:
        for ax, c in zip(axes, cols):
            t[:, ax] = ch[:, c]
    return t


def forward_kinematics(nodes: list[_Node], ch: np.ndarray):
    """Global positions (T, N, 3) and rotations (T, N, 3, 3) of every node, file units."""
    T = ch.shape[0]
    rot, pos, _ = _layout(nodes)
    N = len(nodes)
    X = np.zeros((T, N, 3))
    G = np.zeros((T, N, 3, 3))
    for k, n in enumerate(nodes):
        t = _translation(n, *pos[k], ch, T)
        L = _local_rot(*rot[k], ch, T)
        if n.parent < 0:
            X[:, k] = t
            G[:, k] = L
        else:
            Gp = G[:, n.parent]
            X[:, k] = X[:, n.parent] + np.einsum("tij,tj->ti", Gp, t)
            G[:, k] = Gp @ L
    return X, G


# ----------------------------------------------------------------------------------------
# units
# ----------------------------------------------------------------------------------------
def _resolve_units(units, nodes: list[_Node], path) -> dict[str, Any]:
    if units is not None and not (isinstance(units, str) and units.lower() == "auto"):
        if isinstance(units, str):
            key = _UNIT_ALIASES.get(units.lower(), units.lower())
            if key not in UNITS:
                raise MocapValueError(f"unknown BVH unit {units!r}; use a factor to cm or one of "
                                      f"{', '.join(UNITS)}")
            return {"name": key, "label": _UNIT_LABEL[key], "factor_to_cm": UNITS[key],
                    "chosen_by": "user (units=)"}
        f = float(units)
        if not np.isfinite(f) or f <= 0:
            raise MocapValueError(f"units must be a positive factor to cm or a unit name, got {units!r}")
        return {"name": "custom", "label": f"custom ({f:g} cm per file unit)", "factor_to_cm": f,
                "chosen_by": "user (units=)"}
    # rest pose (all rotations zero, offsets only), end sites included
    P = np.zeros((len(nodes), 3))
    for k, n in enumerate(nodes):
        P[k] = n.offset + (P[n.parent] if n.parent >= 0 else 0.0)
    extent = float(np.max(P.max(0) - P.min(0)))
    if not extent > 0:
        return {"name": "cm", "label": _UNIT_LABEL["cm"], "factor_to_cm": 1.0,
                "chosen_by": "default (the rest skeleton has no extent to infer a unit from)",
                "rest_extent_file_units": extent}
    best = min(UNITS, key=lambda u: abs(np.log(extent * UNITS[u] / _TYPICAL_HEIGHT_CM)))
    return {"name": best, "label": _UNIT_LABEL[best], "factor_to_cm": UNITS[best],
            "chosen_by": (f"inferred: rest skeleton extent {extent:.4g} file units is "
                          f"{extent * UNITS[best]:.1f} cm in {best}, the candidate unit closest to a "
                          f"{_TYPICAL_HEIGHT_CM:g} cm adult (override with units=)"),
            "rest_extent_file_units": extent}


# ----------------------------------------------------------------------------------------
# reader
# ----------------------------------------------------------------------------------------
#: accepted ``Frame Time`` (seconds per frame): 10,000 fps down to 0.1 fps. Capture systems
#: run at 24-2,000 fps; a value outside this range (0, negative, 1e-300, 1e300) is a broken
#: file, and read as-is it would make every velocity-based method nonsense.
FRAME_TIME_RANGE = (1e-4, 10.0)

_FRAMES_RE = re.compile(r"^\s*frames\s*:\s*(\S*)\s*$", re.IGNORECASE)
_FTIME_RE = re.compile(r"^\s*frame\s+time\s*:\s*(\S*)\s*$", re.IGNORECASE)


def _parse(path, text: str):
    lines = text.splitlines()
    # locate MOTION (first line whose first token is MOTION)
    motion_line = None
    for i, s in enumerate(lines):
        st = s.lstrip()
        if st[:6].upper() == "MOTION" and (len(st) == 6 or st[6].isspace()):
            motion_line = i
            break
    stop = motion_line if motion_line is not None else len(lines)
    toks = _tokens(lines, 0, stop)
    if motion_line is not None:
        toks.append(("MOTION", motion_line + 1))
    nodes = _HierarchyParser(path, toks, max(len(lines), 1)).parse()
    if motion_line is None:           # parse() raises first, kept for clarity
        raise MocapFormatError(path, "missing MOTION section", len(lines))
    if lines[motion_line].split()[1:]:
        raise MocapFormatError(path, f"unexpected text after MOTION: {lines[motion_line].strip()!r}",
                               motion_line + 1)

    def next_nonblank(i):
        while i < len(lines) and not lines[i].strip():
            i += 1
        return i

    i = next_nonblank(motion_line + 1)
    if i >= len(lines):
        raise MocapFormatError(path, "file ends after MOTION; expected 'Frames: N'", len(lines))
    m = _FRAMES_RE.match(lines[i])
    if not m:
        raise MocapFormatError(path, f"expected 'Frames: N' after MOTION, found {lines[i].strip()!r}", i + 1)
    n_frames = parse_int(m.group(1), path, i + 1, "the frame count")
    if n_frames <= 0:
        raise MocapFormatError(path, f"'Frames: {n_frames}': the file holds no motion (at least 1 frame "
                                     f"is needed)", i + 1)
    i = next_nonblank(i + 1)
    if i >= len(lines):
        raise MocapFormatError(path, "file ends after 'Frames:'; expected 'Frame Time: seconds'", len(lines))
    m = _FTIME_RE.match(lines[i])
    if not m:
        raise MocapFormatError(path, f"expected 'Frame Time: seconds', found {lines[i].strip()!r}", i + 1)
    frame_time = parse_float(m.group(1), path, i + 1, "the frame time")
    if not FRAME_TIME_RANGE[0] <= frame_time <= FRAME_TIME_RANGE[1]:
        raise MocapFormatError(path, f"'Frame Time: {m.group(1)}' is outside the supported range "
                                     f"{FRAME_TIME_RANGE[0]:g} .. {FRAME_TIME_RANGE[1]:g} s per frame "
                                     f"({1 / FRAME_TIME_RANGE[0]:g} .. {1 / FRAME_TIME_RANGE[1]:g} frames "
                                     f"per second)", i + 1)
    first = i + 1
    rows, line_nos = [], []
    for k in range(first, len(lines)):
        r = lines[k].split()
        if r:
            rows.append(r)
            line_nos.append(k + 1)
    _, _, C = _layout(nodes)
    if len(rows) < n_frames:
        raise MocapFormatError(path, f"truncated file: 'Frames: {n_frames}' but only {len(rows)} frame "
                                     f"line(s) follow", len(lines))
    if len(rows) > n_frames:
        raise MocapFormatError(path, f"'Frames: {n_frames}' but more frame lines follow (extra line "
                                     f"{line_nos[n_frames]})", line_nos[n_frames])
    if C == 0:
        raise MocapFormatError(path, "the hierarchy declares no channels", nodes[0].line)
    ch = float_rows(rows, line_nos, C, path, f"channel values (the hierarchy declares {C} channels)")
    return nodes, ch, frame_time


def _joint_table(nodes: list[_Node], end_sites: bool):
    """Motion joints: node indices, names, parents (joint indices)."""
    keep = [k for k, n in enumerate(nodes) if end_sites or not n.end_site]
    pos = {k: j for j, k in enumerate(keep)}
    names, taken = [], {n.name for n in nodes if not n.end_site}
    for k in keep:
        nm = nodes[k].name
        if nodes[k].end_site:
            base, s = nm, 1
            while nm in taken:
                s += 1
                nm = f"{base}{s}"
            taken.add(nm)
        names.append(nm)
    parents = [pos[nodes[k].parent] if nodes[k].parent >= 0 else -1 for k in keep]
    return keep, names, parents


def _nodes_to_meta(nodes: list[_Node]) -> list[dict]:
    return [{"name": n.name, "parent": n.parent, "offset": tuple(float(v) for v in n.offset),
             "channels": tuple(n.channels), "end_site": n.end_site} for n in nodes]


def _meta_to_nodes(meta) -> list[_Node]:
    nodes = []
    for k, d in enumerate(meta):
        nodes.append(_Node(name=str(d["name"]), parent=int(d["parent"]), line=0,
                           offset=np.asarray(d["offset"], float), channels=tuple(d["channels"]),
                           end_site=bool(d.get("end_site", False))))
        if nodes[-1].parent >= 0:
            nodes[nodes[-1].parent].children.append(k)
    return nodes


def read(path: str | os.PathLike, *, units: str | float | None = None, end_sites: bool = False) -> Motion:
    """Read a BVH file; positions in cm (see the module docstring for units and End Sites).

    Parameters
    ----------
    path : the .bvh file.
    units : factor from file units to cm, or a unit name (``'cm'``, ``'mm'``, ``'m'``,
        ``'inch'``, ``'cmu'``); ``None``/``'auto'`` infers it from the skeleton size.
    end_sites : also return End Sites as joints named ``<parent>_End``.

    Raises
    ------
    MocapFormatError : malformed file (names the line and what was expected).
    """
    path = Path(path)
    text = read_text(path)
    try:
        nodes, ch, frame_time = _parse(path, text)
    except RecursionError:          # the hierarchy parser recurses once per nesting level
        raise MocapFormatError(path, "the joint hierarchy is nested too deeply (more than several "
                                     "hundred levels)") from None
    unit = _resolve_units(units, nodes, path)
    f = unit["factor_to_cm"]
    with np.errstate(over="ignore", invalid="ignore"):
        X, _ = forward_kinematics(nodes, ch)
        X = X * f
    if not np.isfinite(X).all():
        raise MocapFormatError(path, "offsets or channel values so large that joint positions overflow")
    keep, names, parents = _joint_table(nodes, end_sites)
    offsets = np.array([nodes[k].offset for k in keep]) * f
    skeleton = Skeleton(tuple(names), np.array(parents, dtype=int), offsets)
    meta = {"nodes": _nodes_to_meta(nodes), "joint_nodes": tuple(keep), "frame_time": frame_time,
            "end_sites_as_joints": bool(end_sites)}
    source = {"path": str(path), "format": "bvh", "units": unit, "bvh": meta,
              "per_frame": {"channels": ch}}
    return Motion(X[:, keep], skeleton, 1.0 / frame_time, None, source)


def node_positions(motion: Motion) -> tuple[tuple[str, ...], np.ndarray]:
    """Every hierarchy node of a BVH-read motion, End Sites included: (names, (T, N, 3) cm).

    Needs the hierarchy and the per-frame channels the reader stored (kept by ``slice``;
    dropped by ``resample``/``select``). End Sites are named ``<parent>_End``.
    """
    meta = motion.source.get("bvh")
    ch = motion.source.get("per_frame", {}).get("channels")
    if meta is None or ch is None:
        raise MocapValueError("node_positions needs a motion read from BVH with its per-frame channels")
    nodes = _meta_to_nodes(meta["nodes"])
    X, _ = forward_kinematics(nodes, np.asarray(ch, float))
    return tuple(n.name for n in nodes), X * float(motion.source["units"]["factor_to_cm"])


# ----------------------------------------------------------------------------------------
# inverse kinematics
# ----------------------------------------------------------------------------------------
def _min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Shortest-arc rotations (T, 3, 3) taking directions a (T, 3) to b (T, 3)."""
    an = a / np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-300)
    bn = b / np.maximum(np.linalg.norm(b, axis=1, keepdims=True), 1e-300)
    v = np.cross(an, bn)
    c = np.einsum("ti,ti->t", an, bn)
    K = np.zeros(a.shape[:1] + (3, 3))
    K[:, 0, 1], K[:, 0, 2] = -v[:, 2], v[:, 1]
    K[:, 1, 0], K[:, 1, 2] = v[:, 2], -v[:, 0]
    K[:, 2, 0], K[:, 2, 1] = -v[:, 1], v[:, 0]
    anti = c < -1.0 + 1e-12
    denom = np.where(anti, 1.0, 1.0 + c)
    R = np.eye(3) + K + (K @ K) / denom[:, None, None]
    if anti.any():                       # 180 degrees about any axis perpendicular to a
        ai = an[anti]
        ref = np.where(np.abs(ai[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
        u = np.cross(ai, ref)
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        R[anti] = 2 * u[:, :, None] * u[:, None, :] - np.eye(3)
    # zero-length input: no information, identity
    zero = (np.linalg.norm(a, axis=1) < 1e-300) | (np.linalg.norm(b, axis=1) < 1e-300)
    R[zero] = np.eye(3)
    return R


def _kabsch(A: np.ndarray, B: np.ndarray):
    """Kabsch rotations (T, 3, 3) minimising sum_k |Q a_k - b_k|^2 and a (T,) mask of frames
    where the vectors are (nearly) collinear, i.e. the rotation is not determined."""
    H = np.einsum("tki,tkj->tij", A, B)
    U, S, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, 1, 2)
    Ut = np.swapaxes(U, 1, 2)
    d = np.sign(np.linalg.det(V @ Ut))
    d[d == 0] = 1.0
    Q = (V * np.stack([np.ones_like(d), np.ones_like(d), d], axis=1)[:, None, :]) @ Ut
    deg = S[:, 1] <= 1e-9 * np.maximum(S[:, 0], 1e-300)
    return Q, deg


def _axis_angle(axis: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Rotations (T, 3, 3) by theta (T,) radians about unit axes (T, 3) (Rodrigues)."""
    K = np.zeros(axis.shape[:1] + (3, 3))
    K[:, 0, 1], K[:, 0, 2] = -axis[:, 2], axis[:, 1]
    K[:, 1, 0], K[:, 1, 2] = axis[:, 2], -axis[:, 0]
    K[:, 2, 0], K[:, 2, 1] = -axis[:, 1], axis[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def _twist(Q1: np.ndarray, b_axis: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Rotate Q1 about the (already matched) direction b_axis by the angle that best
    aligns the other vectors (Q1 a_k with b_k, projected on the plane normal to the axis)."""
    n = b_axis / np.maximum(np.linalg.norm(b_axis, axis=1, keepdims=True), 1e-300)
    U = np.einsum("tij,tkj->tki", Q1, A)
    U = U - np.einsum("tki,ti->tk", U, n)[..., None] * n[:, None, :]
    W = B - np.einsum("tki,ti->tk", B, n)[..., None] * n[:, None, :]
    num = np.einsum("tki,ti->t", np.cross(U, W), n)
    den = np.einsum("tki,tki->t", U, W)
    scale = np.einsum("tk,tk->t", np.linalg.norm(A, axis=2), np.linalg.norm(B, axis=2))
    # (products of) off-axis components at round-off level: no twist information, keep Q1
    weak = np.hypot(num, den) <= 1e-12 * scale + 1e-300
    theta = np.where(weak, 0.0, np.arctan2(num, den))
    return _axis_angle(n, theta) @ Q1


def _solve_rotation(A: np.ndarray, B: np.ndarray, direct: np.ndarray) -> np.ndarray:
    """Correction rotations Q (T, 3, 3) with Q a_k ~ b_k; A, B (T, K, 3).

    Bone vectors to *direct* children (rigidly attached: no rotating joint in between)
    decide the rotation when they determine it (two or more non-collinear ones: Kabsch;
    one: the shortest-arc rotation). The remaining rotational freedom (a single or
    collinear direct bones: the twist about them) and the case without direct children
    use every vector: least-squares twist about the matched bone, or Kabsch over all.
    Descendants seen through zero-length joints are corrected later by those joints, so
    this keeps positions exact when the starting rotations are wrong (identity start).
    """
    T, K, _ = A.shape
    P = np.flatnonzero(direct) if direct.any() else np.arange(K)
    Ap, Bp = A[:, P], B[:, P]
    if len(P) == 1:
        Q = _min_rotation(Ap[:, 0], Bp[:, 0])
        deg = np.ones(T, bool)
        anchor = Bp[:, 0]
    else:
        Q, deg = _kabsch(Ap, Bp)
        if deg.any():
            k = np.argmax(np.linalg.norm(Ap, axis=2), axis=1)
            t = np.arange(T)
            Q[deg] = _min_rotation(Ap[t, k][deg], Bp[t, k][deg])
        anchor = Bp[np.arange(T), np.argmax(np.linalg.norm(Ap, axis=2), axis=1)]
    if K > 1 and deg.any():
        Q[deg] = _twist(Q[deg], anchor[deg], A[deg], B[deg])
    return Q


def _is_cyclic(i, j, k):
    return (i, j, k) in ((0, 1, 2), (1, 2, 0), (2, 0, 1))


def _euler_from_matrix(R: np.ndarray, axes: list[int]) -> list[np.ndarray]:
    """Angles (degrees) of R = R_a1(alpha) R_a2(beta) R_a3(gamma), three distinct axes.

    beta from the well-conditioned atan2 form, alpha from the last column, then gamma
    from the residual rotation (R_a1 R_a2)^T R, so the three angles reproduce R to
    round-off even next to gimbal lock (where alpha alone is ill-determined and set to 0
    at exact lock).
    """
    i, j, k = axes
    s = 1.0 if _is_cyclic(i, j, k) else -1.0
    cb = np.hypot(R[:, i, i], R[:, i, j])
    beta = np.arctan2(s * R[:, i, k], cb)
    alpha = np.arctan2(-s * R[:, j, k], R[:, k, k])
    alpha = np.where(cb < 1e-12, 0.0, alpha)
    a_deg, b_deg = np.rad2deg(alpha), np.rad2deg(beta)
    M = np.swapaxes(_axis_rot(i, a_deg) @ _axis_rot(j, b_deg), 1, 2) @ R
    k1, k2 = (k + 1) % 3, (k + 2) % 3
    gamma = np.arctan2(M[:, k2, k1], M[:, k1, k1])
    return [a_deg, b_deg, np.rad2deg(gamma)]


def _wrap_near(angle: np.ndarray, ref: np.ndarray) -> np.ndarray:
    return angle + 360.0 * np.round((ref - angle) / 360.0)


def _angles_for(R: np.ndarray, axes: list[int], ref: np.ndarray | None) -> np.ndarray:
    """Channel angles (T, n) in degrees reproducing R as closely as the channels allow."""
    n = len(axes)
    T = R.shape[0]
    if n == 0:
        return np.zeros((T, 0))
    if n == 1:
        a = axes[0]
        p, q = (a + 1) % 3, (a + 2) % 3
        ang = np.rad2deg(np.arctan2(R[:, q, p] - R[:, p, q], R[:, p, p] + R[:, q, q]))[:, None]
    elif n == 2:
        third = ({0, 1, 2} - set(axes)).pop()
        ang = np.stack(_euler_from_matrix(R, list(axes) + [third])[:2], axis=1)
    else:
        e1 = np.stack(_euler_from_matrix(R, list(axes)), axis=1)
        # the other branch: (a + 180, 180 - b, c + 180)
        e2 = np.stack([e1[:, 0] + 180.0, 180.0 - e1[:, 1], e1[:, 2] + 180.0], axis=1)
        if ref is not None:
            e1 = _wrap_near(e1, ref)
            e2 = _wrap_near(e2, ref)
            use2 = np.abs(e2 - ref).sum(1) < np.abs(e1 - ref).sum(1)
            ang = np.where(use2[:, None], e2, e1)
        else:
            ang = e1
    if ref is not None:
        ang = _wrap_near(ang, ref)
    else:
        ang = np.rad2deg(np.unwrap(np.deg2rad(ang), axis=0))
    return ang


def _effective_children(nodes, k, have, has_pos):
    """(descendant, path) pairs whose bone vector constrains node k's rotation."""
    out = []

    def visit(c, path):
        n = nodes[c]
        if has_pos[c]:
            return                                  # free translation: no information
        if np.linalg.norm(n.offset) > _EPS_LEN:
            if have[c]:
                out.append((c, path + [c]))
            return
        for g in n.children:                        # zero-length child: look through it
            visit(g, path + [c])

    for c in nodes[k].children:
        visit(c, [])
    return out


def _inverse_kinematics(nodes: list[_Node], targets: np.ndarray, have: np.ndarray,
                        ch0: np.ndarray | None) -> np.ndarray:
    """Channel values (T, C) placing the nodes at ``targets`` (T, N, 3), file units.

    ``have[k]`` says whether node k has a target; ``ch0`` are the original channels
    (starting rotations/translations) or None (identity rotations, OFFSET translations).
    """
    T = targets.shape[0]
    rot, pos, C = _layout(nodes)
    N = len(nodes)
    out = np.zeros((T, C))
    L0 = [_local_rot(*rot[k], ch0, T) for k in range(N)]
    t0 = [_translation(nodes[k], *pos[k], ch0, T) for k in range(N)]
    has_pos = np.array([len(pos[k][0]) > 0 for k in range(N)])
    G = np.zeros((T, N, 3, 3))
    X = np.zeros((T, N, 3))
    eye = np.broadcast_to(np.eye(3), (T, 3, 3))
    for k, n in enumerate(nodes):
        p = n.parent
        Gp = G[:, p] if p >= 0 else eye
        Xp = X[:, p] if p >= 0 else np.zeros((T, 3))
        # translation / position
        t = t0[k].copy()
        if has_pos[k] and have[k]:
            t_solved = np.einsum("tji,tj->ti", Gp, targets[:, k] - Xp)   # Gp^T (x - xp)
            pa, pc = pos[k]
            for ax, c in zip(pa, pc):
                t[:, ax] = t_solved[:, ax]
        for ax, c in zip(*pos[k]):
            out[:, c] = t[:, ax]
        X[:, k] = Xp + np.einsum("tij,tj->ti", Gp, t)
        if n.end_site:
            G[:, k] = Gp
            continue
        # rotation
        GL0 = Gp @ L0[k]
        eff = _effective_children(nodes, k, have, has_pos)
        if eff and rot[k][0]:
            A = np.empty((T, len(eff), 3))
            B = np.empty((T, len(eff), 3))
            direct = np.array([len(path) == 1 for _, path in eff])
            for e, (d, path) in enumerate(eff):
                r = np.broadcast_to(nodes[path[-1]].offset, (T, 3)).copy()
                for c in reversed(path[:-1]):          # zero-length joints in between
                    r = t0[c] + np.einsum("tij,tj->ti", L0[c], r)
                A[:, e] = np.einsum("tij,tj->ti", GL0, r)
                B[:, e] = targets[:, d] - X[:, k]
            Q = _solve_rotation(A, B, direct)
            L = np.swapaxes(Gp, 1, 2) @ Q @ GL0
        else:
            L = L0[k]
        ra, rc = rot[k]
        if ra:
            if len(ra) == 3 and len(set(ra)) != 3:
                raise MocapValueError(f"joint {n.name!r}: repeated rotation axes "
                                      f"({' '.join(n.channels)}) are not supported by the BVH writer")
            ref = ch0[:, rc] if ch0 is not None else None
            ang = _angles_for(L, ra, ref)
            out[:, rc] = ang
            L = _local_rot(ra, list(range(len(ra))), ang, T)   # what the file will hold
        G[:, k] = Gp @ L
    return out


# ----------------------------------------------------------------------------------------
# writer
# ----------------------------------------------------------------------------------------
def _hierarchy_from_skeleton(sk: Skeleton, factor: float) -> tuple[list[_Node], list[int]]:
    roots = [j for j in range(sk.n_joints) if sk.parents[j] < 0]
    if len(roots) != 1:
        raise MocapValueError(
            f"BVH needs one kinematic tree but this skeleton has {len(roots)} roots "
            f"(marker data without a hierarchy cannot be written as BVH; use C3D or TRC)")
    nodes: list[_Node] = []
    joint_nodes = [0] * sk.n_joints

    def add(j, parent_node):
        k = len(nodes)
        joint_nodes[j] = k
        chans = (("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
                 if parent_node < 0 else ("Zrotation", "Xrotation", "Yrotation"))
        nodes.append(_Node(sk.names[j], parent_node, 0, sk.offsets[j] / factor, chans))
        if parent_node >= 0:
            nodes[parent_node].children.append(k)
        kids = sk.children(j)
        for c in kids:
            add(c, k)
        if not kids:
            off = sk.offsets[j] / factor
            L = np.linalg.norm(off)
            end = off * 0.25 if (parent_node >= 0 and L > 0) else np.array([0.0, 0.0, 0.0])
            e = len(nodes)
            nodes.append(_Node(f"{sk.names[j]}_End", k, 0, end, (), end_site=True))
            nodes[k].children.append(e)

    add(roots[0], -1)
    order = [joint_nodes[j] for j in range(sk.n_joints)]
    return nodes, order


def _fmt(x: float) -> str:
    s = np.format_float_positional(float(x), precision=10, unique=True, trim="-")
    return "0" if s in ("-0", "-0.0") else s


def _write_text(f, nodes: list[_Node], ch: np.ndarray, frame_time: float) -> None:
    out = ["HIERARCHY"]

    def emit(k, depth):
        n = nodes[k]
        ind = "\t" * depth
        if n.end_site:
            out.append(f"{ind}End Site")
        else:
            out.append(f"{ind}{'ROOT' if n.parent < 0 else 'JOINT'} {n.name}")
        out.append(f"{ind}{{")
        out.append(f"{ind}\tOFFSET {' '.join(_fmt(v) for v in n.offset)}")
        if not n.end_site:
            out.append(f"{ind}\tCHANNELS {len(n.channels)} {' '.join(n.channels)}".rstrip())
        for c in n.children:
            emit(c, depth + 1)
        out.append(f"{ind}}}")

    for k, n in enumerate(nodes):
        if n.parent < 0:
            emit(k, 0)
    out += ["MOTION", f"Frames: {ch.shape[0]}", f"Frame Time: {frame_time!r}"]
    f.write("\n".join(out) + "\n")
    buf = io.StringIO()
    np.savetxt(buf, ch, fmt="%.9f", delimiter=" ")
    body = buf.getvalue()
    body = re.sub(r"(\.\d*?)0+(?=[ \n]|$)", r"\1", body)
    body = re.sub(r"\.(?=[ \n]|$)", "", body)
    body = re.sub(r"(?<![\d.])-0(?=[ \n]|$)", "0", body)
    f.write(body)


def write(motion: Motion, path: str | os.PathLike, *, hierarchy: str = "auto",
          units: str | float | None = None) -> None:
    """Write ``motion`` as BVH (rotations by per-joint IK; see the module docstring).

    Parameters
    ----------
    motion : fully observed Motion (cm).
    path : output file (written atomically).
    hierarchy : ``'auto'`` (the hierarchy stored by the BVH reader if any, else one built
        from ``motion.skeleton``), ``'source'`` (require the stored one) or ``'skeleton'``.
    units : file unit (factor to cm or a name); default the unit the file was read in,
        cm for a new hierarchy.

    Raises
    ------
    MocapValueError : missing entries, or joints that do not match the hierarchy.
    """
    if hierarchy not in ("auto", "source", "skeleton"):
        raise MocapValueError(f"hierarchy must be 'auto', 'source' or 'skeleton', got {hierarchy!r}")
    if not motion.observed.all():
        n_miss = int((~motion.observed).sum())
        raise MocapValueError(
            f"cannot write BVH: the motion has {n_miss} missing joint entries "
            f"({100 * motion.missing_fraction:.1f}%); BVH has no way to mark them - fill the gaps "
            f"first (e.g. mocapkit.denoise.get('spline').denoise(motion))")
    src = motion.source
    meta = src.get("bvh")
    if isinstance(units, str) and units.lower() == "auto":
        units = None
    use_source = meta is not None and hierarchy in ("auto", "source")
    if hierarchy == "source" and meta is None:
        raise MocapValueError("this motion carries no BVH hierarchy (it was not read from a BVH file); "
                              "use hierarchy='skeleton'")
    T = motion.n_frames
    ch0 = None
    if use_source:
        nodes = _meta_to_nodes(meta["nodes"])
        joint_nodes = list(meta["joint_nodes"])
        exp_names = [nodes[k].name for k in joint_nodes]
        sk = motion.skeleton
        if len(joint_nodes) != sk.n_joints or tuple(sk.names) != tuple(
                _joint_table(nodes, bool(meta.get("end_sites_as_joints")))[1]):
            raise MocapValueError(
                f"the motion's skeleton ({sk.n_joints} joints) does not match the BVH hierarchy stored "
                f"with it ({len(joint_nodes)} joints: {', '.join(exp_names[:6])}...); pass "
                f"hierarchy='skeleton' to write a new hierarchy built from motion.skeleton")
        node_to_joint = {k: j for j, k in enumerate(joint_nodes)}
        exp_par = [node_to_joint.get(nodes[k].parent, -1) if nodes[k].parent >= 0 else -1
                   for k in joint_nodes]
        if list(sk.parents) != exp_par:
            raise MocapValueError("the motion's skeleton parents do not match the stored BVH hierarchy; "
                                  "pass hierarchy='skeleton'")
        read_factor = float(src.get("units", {}).get("factor_to_cm", 1.0))
        factor = read_factor if units is None else _resolve_units(units, nodes, path)["factor_to_cm"]
        pf = src.get("per_frame", {}).get("channels")
        _, pos_layout, C = _layout(nodes)
        if pf is not None and np.shape(pf) == (T, C):
            ch0 = np.array(pf, dtype=float)
        if factor != read_factor:               # new file unit: rescale lengths
            scale = read_factor / factor
            for n in nodes:
                n.offset = n.offset * scale
            if ch0 is not None:
                for _, cols in pos_layout:
                    ch0[:, cols] *= scale
        ft = float(meta.get("frame_time", 1.0 / motion.fps))
        frame_time = ft if abs(1.0 / ft - motion.fps) <= 1e-9 * motion.fps else 1.0 / motion.fps
    else:
        factor = 1.0 if units is None else _resolve_units(units, [], path)["factor_to_cm"]
        nodes, joint_nodes = _hierarchy_from_skeleton(motion.skeleton, factor)
        frame_time = 1.0 / motion.fps
    if not FRAME_TIME_RANGE[0] <= frame_time <= FRAME_TIME_RANGE[1]:
        raise MocapValueError(f"cannot write BVH at {motion.fps:g} fps: the frame time {frame_time:g} s "
                              f"is outside {FRAME_TIME_RANGE[0]:g} .. {FRAME_TIME_RANGE[1]:g} s (the "
                              f"range the reader accepts); resample the motion first")
    N = len(nodes)
    targets = np.full((T, N, 3), np.nan)
    have = np.zeros(N, bool)
    targets[:, joint_nodes] = motion.positions / factor
    have[joint_nodes] = True
    ch = _inverse_kinematics(nodes, targets, have, ch0)
    if not np.isfinite(ch).all():
        raise MocapValueError("inverse kinematics produced non-finite channel values")
    atomic_write(path, lambda f: _write_text(f, nodes, ch, frame_time))
