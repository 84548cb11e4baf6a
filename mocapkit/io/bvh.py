"""BVH (Biovision hierarchy) reader and writer.

Reading
-------
``read(path, *, units=None, end_sites=False)`` parses HIERARCHY/MOTION, runs forward
kinematics over all frames at once (numpy, one loop over joints, none over frames, in
chunks of :data:`_CHUNK` frames so temporaries stay small) and returns a
:class:`~mocapkit.motion.Motion` with joint positions in **cm**. Frame lines are read in
blocks of 4 MB by ``np.loadtxt`` (numpy's C reader; a block it refuses is re-read with
each line's value count taken from the bytes and ``np.fromstring``, which finds the error)
(:func:`_parse_fast`; speed in docs/results/io_speed.md); files that are not plain ASCII
with LF/CR-LF line ends go through the line parser (:func:`_parse`); both report every
error identically (same message, line and precedence).

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
  files is a T-pose; it is not guessed away); such a reference pose is recognised from
  the channels (:func:`mocapkit.denoise.bases.reference_frames`) and every method keeps
  it as read.
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
kinematics, top-down and vectorised over frames, then polished per frame:

1. each joint starts from its original local rotation ``L0`` when the motion still
   carries the per-frame channels of its own frames (``source['per_frame']``; kept by
   ``with_positions`` and ``slice``), else from identity (rest pose);
2. its global rotation is corrected by the rotation ``Q`` that best maps the bone
   vectors to its children as predicted by ``L0`` onto the vectors to the children's
   target positions: the minimal (shortest-arc) rotation for one child, the Kabsch
   rotation for several (hips, chest; a Newton polar iteration, SVD for ill-conditioned
   frames). Children at zero offset (CMU ``LHipJoint``, ``LowerBack`` ...) are looked through to their own children; rigidly
   attached children decide first and the looked-through ones only fix what those leave
   free (the twist about a single bone), since the zero-length joint in between corrects
   its own subtree; children with position channels are skipped (their translation is
   solved exactly instead); a leaf keeps ``L0``;
3. ``L = G_parent^T Q G_parent L0`` is converted back to Euler angles in the joint's own
   channel order (the branch and 360-degree turn nearest to the original value, or
   unwrapped over time without one);
4. a Levenberg-Marquardt polish of every channel of a frame at once
   (:mod:`mocapkit.io._bvh_polish`, the normal equations of the AMC writer's polish,
   :func:`mocapkit.io._kinematics._ik_normal_equations`), on the frames steps 1-3 leave
   further off than the targets' own bone-length mismatch explains (3 x the largest,
   capped at 0.5 cm) and where most bones are off their length (the median by over 0.01
   cm: noise; one misfit bone keeps the closed form, which leaves every other joint
   exact): the least-squares pose of the frame.

Steps 1-3 alone crumple a chain when the targets are off the skeleton (noise): every bone
takes its noisy direction from where its parent was put, and the error of every joint above
passes down. Measured (2026-12-05, twelfth session; held-out CMU clips written through the
hierarchy the writer builds, white noise on the positions, file against the truth; steps
1-3 alone -> with the polish): 1 cm noise 1.00 -> 0.70 cm, 3 cm 3.05 -> 2.02 cm, and the
clip-mean offset of a joint (what no smoother of the file takes out) 1.56 -> 0.68 cm at 3 cm
on 49_19; writing 960 noisy frames 0.06 -> 1.2-1.7 s (one thread). Through files corrupted
that way, ``mocapkit denoise`` (auto) comes out 0.95-1.14 -> 0.66-0.80 cm at 3 cm / 120 fps
(docs/results/auto_files.md). Positions the hierarchy holds (clean data, a motion whose
bones are held: auto's output) skip the polish and are written exactly; a filter's output
whose bones are a little short mostly skips it too (kalman-cv on CMU 131_02: the same file,
same time). An earlier try (eighth session): least-squares sweeps of subtree Kabsch
rotations, top-down -- the spine converged slowly (the head 3.6 cm off after 3 sweeps, 3.1
after 40) and a write of 10,000 frames took 0.35 -> 1.8 s.

The IK runs in chunks of :data:`_CHUNK` frames (bounded memory, unwrapping continued
across chunks) in the (3, 3, T) rotation layout; values are formatted by
:func:`mocapkit.io._numfmt.fixed_rows` (vectorised ``%.9f``, trailing zeros trimmed).
Root translation (and any joint's position channels) come from the target positions.
If the positions are unchanged the written file re-reads to ~1e-9 cm; values are written
with 9 decimals (trailing zeros trimmed). Motions with missing entries are refused (fill
gaps first), as are motions whose joints do not match the stored hierarchy (pass
``hierarchy='skeleton'`` to build a new hierarchy from ``motion.skeleton``: root with 6
channels, other joints ``Zrotation Xrotation Yrotation``, an End Site on each leaf).
A BVH joint turns the offsets of all its children together; where a skeleton's bones
that share a start point turn separately in the motion (ASF/AMC: CMU's thorax -> lower
neck and both clavicles; :func:`_turn_apart`), the built hierarchy hangs each of them
from a zero-offset joint ``<child>_base`` of its own, as CMU's own BVH conversions have
``LHipJoint`` / ``LowerBack``: the positions are held (CMU 16_15 AMC -> BVH: 1e-9 cm;
without them 0.51 cm mean, 2.2 cm at the lower neck), and the file read back has those
joints too (41 for CMU's 31). Whatever the hierarchy cannot hold beyond what the bone
lengths explain, the writer says in one :class:`~mocapkit.errors.MocapWarning` with the
mean and largest distance (:func:`_unreachable`).
"""
from __future__ import annotations

import io as _io
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import _bvh_polish
from ._numfmt import fixed_rows
from ._rotations import (axis_angle, euler_from_matrix_t, kabsch, min_rotation,
                         mm_t, normalize, rotate_right_t, wrap_near)
from ..errors import MocapFormatError, MocapValueError, MocapWarning
from ..motion import Motion
from ..skeleton import Skeleton
from ..windows import spaced_frames
from ._atomic import atomic_write
from ._kinematics import require_complete
from ._text import float_rows, parse_float, parse_int, read_bytes
from .units import LENGTH_UNITS, UNIT_LABELS, unit_name

__all__ = ["read", "write", "node_positions"]

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
# rotations and forward kinematics (vectorised over frames, in frame chunks)
# ----------------------------------------------------------------------------------------
#: frames per chunk of the forward/inverse kinematics: bounds the temporary rotation
#: stacks (72 bytes per frame and node) whatever the clip length
_CHUNK = 8192


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


def _local_rot_t(axes, cols, ch: np.ndarray, G: np.ndarray | None = None) -> np.ndarray | None:
    """``G @ R_1 @ R_2 ...`` (channel order) in the (3, 3, T) layout, G = identity when None;
    None for a joint without rotation channels and no G."""
    if not axes:
        return None if G is None else G
    R = np.broadcast_to(np.eye(3)[:, :, None], (3, 3, ch.shape[0])).copy() if G is None else G.copy()
    for ax, c in zip(axes, cols):
        rotate_right_t(R, ax, np.deg2rad(ch[:, c]))
    return R


def _translation(node: _Node, axes, cols, ch: np.ndarray | None, T: int) -> np.ndarray:
    t = np.broadcast_to(node.offset, (T, 3)).copy()
    if ch is not None:
        for ax, c in zip(axes, cols):
            t[:, ax] = ch[:, c]
    return t


def _fk_chunk(nodes: list[_Node], layout, ch: np.ndarray, want_rot: bool,
              chan_axes: np.ndarray | None = None):
    """Positions (N, 3, T) and (if asked) global rotations [(3, 3, T) or None = identity].

    ``G_k = G_parent R_1 R_2 R_3`` (channel order) is built by rotating the parent's
    columns in place (:func:`rotate_right_t`); a node's rotation is dropped once its last
    child is done unless ``want_rot``. ``chan_axes`` (C, 3, T), zeros, receives each
    channel's world axis for the IK polish's Jacobian (:mod:`mocapkit.io._bvh_polish`): a
    rotation's axis just before its turn, a position channel's direction (the parent's
    axis); a childless node's rotations move no node and keep zeros.
    """
    rot, pos, _ = layout
    T = ch.shape[0]
    ch = np.ascontiguousarray(ch.T)                # (C, T): each channel one contiguous row
    X = np.empty((len(nodes), 3, T))
    G: list[np.ndarray | None] = [None] * len(nodes)
    left = [len(n.children) for n in nodes]
    for k, n in enumerate(nodes):
        t = np.empty((3, T))
        t[:] = np.asarray(n.offset, float)[:, None]
        p = n.parent
        Gp = G[p] if p >= 0 else None
        for ax, c in zip(*pos[k]):
            t[ax] = ch[c]
            if chan_axes is not None:
                chan_axes[c] = np.eye(3)[:, ax, None] if Gp is None else Gp[:, ax]
        if p < 0:
            X[k] = t
        elif Gp is None:
            X[k] = X[p] + t
        else:
            X[k] = X[p] + Gp[:, 0] * t[0] + Gp[:, 1] * t[1] + Gp[:, 2] * t[2]
        axes, cols = rot[k]
        if axes and (left[k] or want_rot):
            R = np.broadcast_to(np.eye(3)[:, :, None], (3, 3, T)).copy() if Gp is None else Gp.copy()
            for ax, c in zip(axes, cols):
                if chan_axes is not None:
                    chan_axes[c] = R[:, ax]           # the axis before its own turn (it keeps it)
                rotate_right_t(R, ax, np.deg2rad(ch[c]))
            G[k] = R
        else:
            G[k] = Gp
        if p >= 0:
            left[p] -= 1
            if not left[p] and not want_rot:
                G[p] = None
    return X, (G if want_rot else None)


def forward_kinematics(nodes: list[_Node], ch: np.ndarray, rotations: bool = True):
    """Global positions (T, N, 3) and rotations (T, N, 3, 3) of every node, file units.

    One loop over nodes per chunk of :data:`_CHUNK` frames, none over frames. With
    ``rotations=False`` the second value is None (saves 72 bytes per frame and node).
    """
    ch = np.asarray(ch, float)
    T, N = ch.shape[0], len(nodes)
    layout = _layout(nodes)
    X = np.empty((T, N, 3))
    G = np.empty((T, N, 3, 3)) if rotations else None
    for a in range(0, T, _CHUNK):
        Xc, Gc = _fk_chunk(nodes, layout, ch[a:a + _CHUNK], rotations)
        X[a:a + _CHUNK] = np.transpose(Xc, (2, 0, 1))
        if rotations:
            for k, g in enumerate(Gc):
                G[a:a + _CHUNK, k] = np.eye(3) if g is None else np.transpose(g, (2, 0, 1))
    return X, G


def _fk_positions(nodes: list[_Node], ch: np.ndarray, keep: list[int], factor: float,
                  check: bool = False) -> np.ndarray | None:
    """Positions (T, len(keep), 3) of the nodes ``keep``, times ``factor``; chunked, so the
    only full-length array is the result. ``check``: None if any node's position (kept
    or not) is not finite."""
    T = ch.shape[0]
    layout = _layout(nodes)
    out = np.empty((T, len(keep), 3))
    for a in range(0, T, _CHUNK):
        Xc, _ = _fk_chunk(nodes, layout, ch[a:a + _CHUNK], False)
        if factor != 1.0:
            Xc *= factor
        if check and not np.isfinite(Xc).all():
            return None
        out[a:a + _CHUNK] = np.transpose(Xc[keep], (2, 0, 1))
    return out


# ----------------------------------------------------------------------------------------
# units
# ----------------------------------------------------------------------------------------
def _resolve_units(units, nodes: list[_Node], path) -> dict[str, Any]:
    if units is not None and not (isinstance(units, str) and units.lower() == "auto"):
        if isinstance(units, str):
            key = unit_name(units)
            if key is None:
                raise MocapValueError(f"unknown BVH unit {units!r}; use a factor to cm or one of "
                                      f"{', '.join(LENGTH_UNITS)}")
            return {"name": key, "label": UNIT_LABELS[key], "factor_to_cm": LENGTH_UNITS[key],
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
        return {"name": "cm", "label": UNIT_LABELS["cm"], "factor_to_cm": 1.0,
                "chosen_by": "default (the rest skeleton has no extent to infer a unit from)",
                "rest_extent_file_units": extent}
    best = min(LENGTH_UNITS, key=lambda u: abs(np.log(extent * LENGTH_UNITS[u] / _TYPICAL_HEIGHT_CM)))
    return {"name": best, "label": UNIT_LABELS[best], "factor_to_cm": LENGTH_UNITS[best],
            "chosen_by": (f"inferred: rest skeleton extent {extent:.4g} file units is "
                          f"{extent * LENGTH_UNITS[best]:.1f} cm in {best}, the candidate unit closest to a "
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
#: bytes of frame lines parsed per numpy call by the block reader
_BLOCK_BYTES = 1 << 22


def _find_motion(lines: list[str]) -> int | None:
    """Index of the first line whose first token is MOTION."""
    for i, s in enumerate(lines):
        st = s.lstrip()
        if st[:6].upper() == "MOTION" and (len(st) == 6 or st[6].isspace()):
            return i
    return None


def _keyword_line(path, lines: list[str], i: int, regex: re.Pattern, n_lines: int, expected: str,
                  at_end: str) -> tuple[re.Match, int]:
    """The match of ``regex`` on the first non-blank line from index ``i``, and its index."""
    while i < len(lines) and not lines[i].strip():
        i += 1
    if i >= len(lines):
        raise MocapFormatError(path, at_end, n_lines)
    m = regex.match(lines[i])
    if not m:
        raise MocapFormatError(path, f"expected {expected}, found {lines[i].strip()!r}", i + 1)
    return m, i


def _parse_header(path, lines: list[str], n_lines: int):
    """(nodes, frames, frame time, index of the first frame line) from the lines of a file
    (all of them, or at least up to the ``Frame Time`` line); ``n_lines`` = lines in the file."""
    motion_line = _find_motion(lines)
    stop = motion_line if motion_line is not None else len(lines)
    toks = _tokens(lines, 0, stop)
    if motion_line is not None:
        toks.append(("MOTION", motion_line + 1))
    nodes = _HierarchyParser(path, toks, max(n_lines, 1)).parse()
    if motion_line is None:           # parse() raises first, kept for clarity
        raise MocapFormatError(path, "missing MOTION section", n_lines)
    if lines[motion_line].split()[1:]:
        raise MocapFormatError(path, f"unexpected text after MOTION: {lines[motion_line].strip()!r}",
                               motion_line + 1)
    m, i = _keyword_line(path, lines, motion_line + 1, _FRAMES_RE, n_lines, "'Frames: N' after MOTION",
                         "file ends after MOTION; expected 'Frames: N'")
    n_frames = parse_int(m.group(1), path, i + 1, "the frame count")
    if n_frames <= 0:
        raise MocapFormatError(path, f"'Frames: {n_frames}': the file holds no motion (at least 1 frame "
                                     f"is needed)", i + 1)
    m, i = _keyword_line(path, lines, i + 1, _FTIME_RE, n_lines, "'Frame Time: seconds'",
                         "file ends after 'Frames:'; expected 'Frame Time: seconds'")
    frame_time = parse_float(m.group(1), path, i + 1, "the frame time")
    if not FRAME_TIME_RANGE[0] <= frame_time <= FRAME_TIME_RANGE[1]:
        raise MocapFormatError(path, f"'Frame Time: {m.group(1)}' is outside the supported range "
                                     f"{FRAME_TIME_RANGE[0]:g} .. {FRAME_TIME_RANGE[1]:g} s per frame "
                                     f"({1 / FRAME_TIME_RANGE[0]:g} .. {1 / FRAME_TIME_RANGE[1]:g} frames "
                                     f"per second)", i + 1)
    return nodes, n_frames, frame_time, i + 1


def _frame_count_checks(path, nodes, n_frames: int, n_rows: int, extra_line: int | None, n_lines: int) -> int:
    """The frame-count errors, in the order the reader reports them; returns C."""
    _, _, C = _layout(nodes)
    if n_rows < n_frames:
        raise MocapFormatError(path, f"truncated file: 'Frames: {n_frames}' but only {n_rows} frame "
                                     f"line(s) follow", n_lines)
    if n_rows > n_frames:
        raise MocapFormatError(path, f"'Frames: {n_frames}' but more frame lines follow (extra line "
                                     f"{extra_line})", extra_line)
    if C == 0:
        raise MocapFormatError(path, "the hierarchy declares no channels", nodes[0].line)
    return C


def _parse(path, text: str):
    """Line parser (the reference; used for files the block parser hands over)."""
    lines = text.splitlines()
    nodes, n_frames, frame_time, first = _parse_header(path, lines, len(lines))
    rows, line_nos = [], []
    for k in range(first, len(lines)):
        r = lines[k].split()
        if r:
            rows.append(r)
            line_nos.append(k + 1)
    extra = line_nos[n_frames] if len(rows) > n_frames else None
    C = _frame_count_checks(path, nodes, n_frames, len(rows), extra, len(lines))
    ch = float_rows(rows, line_nos, C, path, f"channel values (the hierarchy declares {C} channels)")
    return nodes, ch, frame_time


def _head_end(raw: bytes) -> tuple[int, int] | None:
    """(byte offset after the ``Frame Time`` line, lines up to there) or None when the
    MOTION line and the two lines after it are not all there."""
    pos, n, motion, after = 0, 0, False, 0
    while pos < len(raw):
        nl = raw.find(b"\n", pos)
        end = len(raw) if nl < 0 else nl + 1
        line = raw[pos:end]
        pos, n = end, n + 1
        if not motion:
            st = line.lstrip()
            motion = st[:6].upper() == b"MOTION" and (len(st) == 6 or st[6:7].isspace())
        elif line.strip():
            after += 1
            if after == 2:
                return pos, n
    return None


def _parse_fast(path, raw: bytes):
    """Block parser for plain-ASCII files with \\n or \\r\\n line ends; None = use :func:`_parse`.

    The header goes through :func:`_parse_header` (any error there: None, so the line
    parser reports it exactly as before); the frame lines are converted in blocks of
    :data:`_BLOCK_BYTES` by ``np.loadtxt`` (:meth:`_BodyReader._clean_block`); a block it
    refuses is re-read by ``np.fromstring`` with the token count of every line taken
    from the bytes, and every error the line parser reports is reported the same way
    (same message, same line number, same precedence).
    """
    if not raw.isascii():
        return None
    head = _head_end(raw)
    if head is None:
        return None
    off, n_head = head
    if _plain_lines(raw[:off]) < 0:
        return None
    try:
        nodes, n_frames, frame_time, first = _parse_header(path, raw[:off].decode("ascii").splitlines(), 0)
    except MocapFormatError:
        return None
    _, _, C = _layout(nodes)
    body = _BodyReader(path, n_frames, max(C, 1), f"channel values (the hierarchy declares {C} channels)",
                       (len(raw) - off) // (2 * max(C, 1)) + 1)       # a frame line holds >= 2C bytes
    try:
        n_lines = n_head + body.run(raw, off, n_head + 1)
    except _NotPlain:
        return None
    _frame_count_checks(path, nodes, n_frames, body.rows, body.extra_line, n_lines)
    body.raise_first()
    return nodes, body.out, frame_time


class _NotPlain(Exception):
    """A block holds a control character other than tab / CR-LF / LF (the line parser's case)."""


def _plain_lines(blk: bytes) -> int:
    """The block's LF count when it holds no control bytes but tab, LF and CR-LF (so bytes
    lines = str.splitlines lines), else -1.  Each count is one C pass over the block;
    the LF count is the caller's line count too (200,000-frame BVH: 4 of its 6 passes)."""
    n_lf, n_cr = blk.count(b"\n"), blk.count(b"\r")
    if n_cr and n_cr != blk.count(b"\r\n"):
        return -1
    n_ctrl = blk.count(b"\t") + n_lf + n_cr
    return n_lf if int(np.count_nonzero(np.frombuffer(blk, np.uint8) < 32)) == n_ctrl else -1


class _BodyReader:
    """Frame lines -> (frames, C) array, block by block (see :func:`_parse_fast`).

    Errors are kept, first of each kind, and raised by :meth:`raise_first` in the line
    parser's order (a wrong value count anywhere, then a token that is not a number, then
    a non-finite number), after the frame-count checks; a line beyond ``Frames:`` stops
    the reading (that error comes first).
    """

    def __init__(self, path, n_frames: int, C: int, what: str, max_lines: int):
        self.path, self.n_frames, self.C, self.what = path, n_frames, C, what
        self.out = np.empty((min(n_frames, max_lines), C))    # a lying 'Frames:' allocates no more
        self.rows = 0
        self.extra_line: int | None = None
        self.errors: dict[str, MocapFormatError] = {}

    def run(self, raw: bytes, pos: int, line_no: int) -> int:
        """Read the frame lines from byte ``pos`` (file line ``line_no``); returns how many
        lines there are from ``pos`` to the end (the file's line count minus the header's)."""
        n, start = 0, pos
        while pos < len(raw):
            target = pos + _BLOCK_BYTES
            nl = raw.find(b"\n", target) if target < len(raw) else -1
            end = len(raw) if nl < 0 else nl + 1
            blk = raw[pos:end]
            n_lf = _plain_lines(blk)
            if n_lf < 0:
                raise _NotPlain
            if self.extra_line is None:
                self._block(blk, line_no + n)
            n += n_lf
            pos = end
        return n + (1 if pos > start and not raw.endswith(b"\n") else 0)

    def raise_first(self) -> None:
        for kind in ("count", "garbage", "nonfinite"):
            if kind in self.errors:
                raise self.errors[kind]

    def _token_counts(self, blk: bytes) -> tuple[np.ndarray, int]:
        """Tokens per line of the block (bytes.split semantics) and the token count."""
        a = np.frombuffer(blk, np.uint8)
        ws = a <= 32
        st = np.flatnonzero(ws[:-1] & ~ws[1:]) + 1
        if not ws[0]:
            st = np.concatenate([[0], st])
        ends = np.searchsorted(st, np.flatnonzero(a == 10))
        if not blk.endswith(b"\n"):
            ends = np.concatenate([ends, [len(st)]])
        return np.diff(np.concatenate([[0], ends])), len(st)

    def _block(self, blk: bytes, line_no: int) -> None:
        if not self.errors and self._clean_block(blk):
            return
        counts, n_tok = self._token_counts(blk)
        full = counts > 0
        k = int(np.count_nonzero(full))
        line_nos = line_no + np.flatnonzero(full)
        if self.rows + k > self.n_frames:
            self.extra_line = int(line_nos[self.n_frames - self.rows])
            self.rows += k
            return
        bad = np.flatnonzero(counts[full] != self.C)
        if len(bad) and "count" not in self.errors:
            i = int(bad[0])
            self.errors["count"] = MocapFormatError(
                self.path, f"expected {self.C} {self.what}, found {int(counts[full][i])}", int(line_nos[i]))
        if "count" not in self.errors and "garbage" not in self.errors:
            v = None
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("error")
                    v = np.fromstring(blk, dtype=np.float64, sep=" ")
            except (ValueError, DeprecationWarning):
                pass
            if v is not None and v.size == n_tok and np.isfinite(v).all():
                self.out[self.rows:self.rows + k] = v.reshape(k, self.C)
            else:
                self._slow(blk, line_no)
                return
        self.rows += k

    def _clean_block(self, blk: bytes) -> bool:
        """The common case in one C pass: every non-blank line holds C finite numbers and
        the block ends within ``Frames:``. ``np.loadtxt`` (numpy's C reader, about twice
        the speed of ``fromstring`` here) checks the counts itself; anything else --
        another count, a token it refuses, NaN/inf, a line beyond ``Frames:`` -- returns
        False and the block goes through the token-counting path, which reports it."""
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")               # "input contained no data"
                v = np.loadtxt(_io.BytesIO(blk), dtype=np.float64, comments=None, ndmin=2)
        except (ValueError, UserWarning):
            return False
        k = v.shape[0]
        if v.shape[1] != self.C or self.rows + k > self.n_frames or not np.isfinite(v).all():
            return False
        self.out[self.rows:self.rows + k] = v
        self.rows += k
        return True

    def _slow(self, blk: bytes, line_no: int) -> None:
        """The line parser's conversion of one block (error path, or tokens numpy refuses
        and Python's float accepts, e.g. ``1_000``)."""
        lines = blk.decode("latin-1").splitlines()
        rows, nos = [], []
        for i, s in enumerate(lines):
            r = s.split()
            if r:
                rows.append(r)
                nos.append(line_no + i)
        if self.rows + len(rows) > self.n_frames:
            self.extra_line = nos[self.n_frames - self.rows]
            self.rows += len(rows)
            return
        if "count" not in self.errors and "garbage" not in self.errors:
            try:
                self.out[self.rows:self.rows + len(rows)] = float_rows(rows, nos, self.C, self.path, self.what)
            except MocapFormatError as e:
                kind = "nonfinite" if "only finite numbers" in e.message else "garbage"
                self.errors.setdefault(kind, e)
        self.rows += len(rows)


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
    raw = read_bytes(path)
    try:
        parsed = _parse_fast(path, raw)
        if parsed is None:
            parsed = _parse(path, _decode(raw))
    except RecursionError:          # the hierarchy parser recurses once per nesting level
        raise MocapFormatError(path, "the joint hierarchy is nested too deeply (more than several "
                                     "hundred levels)") from None
    del raw
    nodes, ch, frame_time = parsed
    unit = _resolve_units(units, nodes, path)
    f = unit["factor_to_cm"]
    keep, names, parents = _joint_table(nodes, end_sites)
    with np.errstate(over="ignore", invalid="ignore"):
        X = _fk_positions(nodes, ch, keep, f, check=True)
    if X is None:
        raise MocapFormatError(path, "offsets or channel values so large that joint positions overflow")
    offsets = np.array([nodes[k].offset for k in keep]) * f
    skeleton = Skeleton(tuple(names), np.array(parents, dtype=int), offsets)
    meta = {"nodes": _nodes_to_meta(nodes), "joint_nodes": tuple(keep), "frame_time": frame_time,
            "end_sites_as_joints": bool(end_sites)}
    source = {"path": str(path), "format": "bvh", "units": unit, "bvh": meta,
              "per_frame": {"channels": ch}}
    if X.base is None and X.flags.c_contiguous:
        X.setflags(write=False)            # handed over: the Motion shares it, no 140 MB copy
    return Motion(X, skeleton, 1.0 / frame_time, None, source)


def _decode(raw: bytes) -> str:
    """As :func:`mocapkit.io._text.read_text`: UTF-8, else latin-1; BOM removed."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    return text.lstrip("\ufeff")


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
    X = _fk_positions(nodes, np.asarray(ch, float), list(range(len(nodes))),
                      float(motion.source["units"]["factor_to_cm"]))
    return tuple(n.name for n in nodes), X


# ----------------------------------------------------------------------------------------
# inverse kinematics
# ----------------------------------------------------------------------------------------
def _twist(Q1: np.ndarray, b_axis: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Rotate Q1 about the (already matched) direction b_axis by the angle that best
    aligns the other vectors (Q1 a_k with b_k, projected on the plane normal to the axis)."""
    n, _ = normalize(b_axis, 1e-300)
    U = np.einsum("tij,tkj->tki", Q1, A)
    U = U - np.einsum("tki,ti->tk", U, n)[..., None] * n[:, None, :]
    W = B - np.einsum("tki,ti->tk", B, n)[..., None] * n[:, None, :]
    num = np.einsum("tki,ti->t", np.cross(U, W), n)
    den = np.einsum("tki,tki->t", U, W)
    scale = np.einsum("tk,tk->t", np.linalg.norm(A, axis=2), np.linalg.norm(B, axis=2))
    # (products of) off-axis components at round-off level: no twist information, keep Q1
    weak = np.hypot(num, den) <= 1e-12 * scale + 1e-300
    theta = np.where(weak, 0.0, np.arctan2(num, den))
    return axis_angle(n, theta) @ Q1


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
        Q = min_rotation(Ap[:, 0], Bp[:, 0])
        deg = np.ones(T, bool)
        anchor = Bp[:, 0]
    else:
        Q, deg = kabsch(Ap, Bp, degenerate_q=False)
        k = np.argmax(np.linalg.norm(Ap, axis=2), axis=1)
        t = np.arange(T)
        if deg.any():
            Q[deg] = min_rotation(Ap[t, k][deg], Bp[t, k][deg])
        anchor = Bp[t, k]
    if K > 1 and deg.any():
        Q[deg] = _twist(Q[deg], anchor[deg], A[deg], B[deg])
    return Q


def _wrap_near(angle: np.ndarray, ref: np.ndarray) -> np.ndarray:
    return wrap_near(angle, ref, 360.0)


def _angles_for(R: np.ndarray, axes: list[int], ref: np.ndarray | None,
                prev: np.ndarray | None = None) -> np.ndarray:
    """Channel angles (T, n) in degrees reproducing R (T, 3, 3) as closely as the channels
    allow. With ``ref`` (T, n): the branch and 360-degree turn nearest to it; without,
    unwrapped over time, continuing from ``prev`` (n,) (the frame before, for chunked calls)."""
    return _angles_for_t(np.transpose(R, (1, 2, 0)), axes, ref, prev)


def _angles_for_t(R: np.ndarray, axes: list[int], ref: np.ndarray | None,
                  prev: np.ndarray | None = None) -> np.ndarray:
    """:func:`_angles_for` for R in the (3, 3, T) layout."""
    n = len(axes)
    T = R.shape[2]
    if n == 0:
        return np.zeros((T, 0))
    if n == 1:
        a = axes[0]
        p, q = (a + 1) % 3, (a + 2) % 3
        ang = np.rad2deg(np.arctan2(R[q, p] - R[p, q], R[p, p] + R[q, q]))[:, None]
    elif n == 2:
        third = ({0, 1, 2} - set(axes)).pop()
        ang = np.rad2deg(euler_from_matrix_t(R, list(axes) + [third])[0][:, :2])
    else:
        e1, e2 = (np.rad2deg(e) for e in euler_from_matrix_t(R, list(axes)))
        if ref is not None:
            e1 = _wrap_near(e1, ref)
            e2 = _wrap_near(e2, ref)
            use2 = np.abs(e2 - ref).sum(1) < np.abs(e1 - ref).sum(1)
            ang = np.where(use2[:, None], e2, e1)
        else:
            ang = e1
    if ref is not None:
        return _wrap_near(ang, ref)
    if prev is None:
        return np.rad2deg(np.unwrap(np.deg2rad(ang), axis=0))
    return np.rad2deg(np.unwrap(np.deg2rad(np.concatenate([prev[None], ang])), axis=0))[1:]


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


def _mv_t(G: np.ndarray | None, v: np.ndarray) -> np.ndarray:
    """G v for G (3, 3, T) (None = identity) and v (3, T) or (3,)."""
    v = v if v.ndim == 2 else v[:, None]
    if G is None:
        return v
    return G[:, 0] * v[0] + G[:, 1] * v[1] + G[:, 2] * v[2]


def _mtv_t(G: np.ndarray | None, v: np.ndarray) -> np.ndarray:
    """G^T v for G (3, 3, T) (None = identity) and v (3, T)."""
    if G is None:
        return v
    return G[0] * v[0] + G[1] * v[1] + G[2] * v[2]


class _LazyLocal:
    """``L0[k]``: node k's start rotation (3, 3, T) from the channels ``ch0`` (None =
    identity), computed on first use (only look-through joints and leaves need it)."""

    def __init__(self, rot, ch0: np.ndarray | None):
        self.rot, self.ch0, self.cache = rot, ch0, {}

    def __getitem__(self, k: int) -> np.ndarray | None:
        if self.ch0 is None:
            return None
        if k not in self.cache:
            self.cache[k] = _local_rot_t(*self.rot[k], self.ch0)
        return self.cache[k]


class _IKPlan:
    """What the IK needs per node, independent of the frames: channel layout, the
    children that constrain each rotation (:func:`_effective_children`) and whether
    they are direct."""

    def __init__(self, nodes: list[_Node], have: np.ndarray):
        self.rot, self.pos, self.C = _layout(nodes)
        self.has_pos = np.array([len(p[0]) > 0 for p in self.pos])
        self.eff = [_effective_children(nodes, k, have, self.has_pos) for k in range(len(nodes))]
        self.direct = [np.array([len(path) == 1 for _, path in e], bool) for e in self.eff]
        for k, n in enumerate(nodes):
            ra = self.rot[k][0]
            if len(ra) == 3 and len(set(ra)) != 3:
                raise MocapValueError(f"joint {n.name!r}: repeated rotation axes "
                                      f"({' '.join(n.channels)}) are not supported by the BVH writer")


def _correction(nodes, plan: _IKPlan, k: int, GL0, L0, t0, Xk, Xt, T: int) -> np.ndarray:
    """Q (T, 3, 3) best mapping node k's predicted child vectors onto the targets."""
    eff = plan.eff[k]
    A = np.empty((T, len(eff), 3))
    B = np.empty((T, len(eff), 3))
    for e, (d, path) in enumerate(eff):
        r = np.asarray(nodes[path[-1]].offset, float)[:, None]
        for c in reversed(path[:-1]):                  # zero-length joints in between
            r = t0[c] + _mv_t(L0[c], r)
        A[:, e] = _mv_t(GL0, r).T
        B[:, e] = (Xt[d] - Xk).T
    return _solve_rotation(A, B, plan.direct[k])


def _inverse_kinematics(nodes: list[_Node], targets: np.ndarray, have: np.ndarray,
                        ch0: np.ndarray | None, plan: _IKPlan | None = None,
                        prev: np.ndarray | None = None) -> np.ndarray:
    """Channel values (T, C) placing the nodes at ``targets`` (T, N, 3), file units.

    ``have[k]`` says whether node k has a target; ``ch0`` are the original channels
    (starting rotations/translations) or None (identity rotations, OFFSET translations);
    ``prev`` (C,): the channels of the frame before (continuity of chunked calls).
    One loop over nodes, none over frames; rotations in the (3, 3, T) layout.
    """
    T = targets.shape[0]
    plan = plan or _IKPlan(nodes, have)
    rot, pos = plan.rot, plan.pos
    out = np.zeros((T, plan.C))
    Xt = np.transpose(targets, (1, 2, 0))                        # (N, 3, T)
    L0 = _LazyLocal(rot, ch0)
    t0 = [_translation(nodes[k], *pos[k], ch0, T).T for k in range(len(nodes))]
    G: list[np.ndarray | None] = [None] * len(nodes)
    X = np.zeros((len(nodes), 3, T))
    for k, n in enumerate(nodes):
        Gp = G[n.parent] if n.parent >= 0 else None
        Xp = X[n.parent] if n.parent >= 0 else 0.0
        t = t0[k].copy()
        if plan.has_pos[k] and have[k]:
            t_solved = _mtv_t(Gp, Xt[k] - Xp)                    # Gp^T (x - xp)
            for ax in pos[k][0]:
                t[ax] = t_solved[ax]
        for ax, c in zip(*pos[k]):
            out[:, c] = t[ax]
        X[k] = Xp + _mv_t(Gp, t)
        if n.end_site:
            G[k] = Gp
            continue
        G[k] = _solve_node(nodes, plan, k, Gp, L0, t0, X[k], Xt, ch0, prev, out, T)
    return out


def _solve_node(nodes, plan: _IKPlan, k: int, Gp, L0, t0, Xk, Xt, ch0, prev, out, T: int):
    """Node k's rotation channels (written to ``out``); returns its global rotation (3, 3, T)."""
    ra, rc = plan.rot[k]
    if not ra:
        return Gp
    GL0 = Gp if ch0 is None else _local_rot_t(ra, rc, ch0, Gp)          # Gp L0
    if plan.eff[k]:
        Q = np.ascontiguousarray(np.transpose(_correction(nodes, plan, k, GL0, L0, t0, Xk, Xt, T), (1, 2, 0)))
        QG = Q if GL0 is None else mm_t(Q, GL0)
        L = QG if Gp is None else mm_t(np.transpose(Gp, (1, 0, 2)), QG)        # Gp^T Q Gp L0
    else:
        L = L0[k] if L0[k] is not None else np.broadcast_to(np.eye(3)[:, :, None], (3, 3, T))
    ref = ch0[:, rc] if ch0 is not None else None
    ang = _angles_for_t(L, ra, ref, None if prev is None else prev[rc])
    out[:, rc] = ang
    R = np.broadcast_to(np.eye(3)[:, :, None], (3, 3, T)).copy() if Gp is None else Gp.copy()
    for i, ax in enumerate(ra):                                   # what the file will hold
        rotate_right_t(R, ax, np.deg2rad(ang[:, i]))
    return R


# ----------------------------------------------------------------------------------------
# writer
# ----------------------------------------------------------------------------------------
def _unique_name(name: str, taken: set[str]) -> str:
    """``name``, or with ``_2``, ``_3`` ... appended when taken; added to ``taken``."""
    out, k = name, 2
    while out in taken:
        out, k = f"{name}_{k}", k + 1
    taken.add(out)
    return out


def _turn_apart(positions: np.ndarray | None, offsets: np.ndarray, kids: list[int]) -> bool:
    """Whether sibling joints stray from their rest offsets' shape in ``positions`` (T, J,
    3) cm: a distance between two of them off the distance of their rest offsets (cm) by
    more than :data:`UNREACHABLE_CM` in some frame. A BVH joint holds its children's
    offsets rigid, so such siblings each need a joint of their own; siblings that keep
    their rest shape (a BVH source, a rigid pelvis) do not, and the hierarchy keeps the
    motion's joints one to one."""
    if positions is None:
        return False
    P = positions[:, kids]
    i, j = np.triu_indices(len(kids), 1)
    d = np.linalg.norm(P[:, i] - P[:, j], axis=2)
    rest = np.linalg.norm(offsets[kids][i] - offsets[kids][j], axis=1)
    return bool(np.any(np.abs(d - rest) > UNREACHABLE_CM))


def _hierarchy_from_skeleton(sk: Skeleton, factor: float, positions: np.ndarray | None = None
                             ) -> tuple[list[_Node], list[int]]:
    """Nodes of a new hierarchy for ``sk`` (and the node of each joint): root with 6
    channels, other joints 3 rotations, an End Site per leaf; children that move apart in
    ``positions`` (:func:`_turn_apart`) each hang from a zero-offset joint ``<child>_base``."""
    roots = [j for j in range(sk.n_joints) if sk.parents[j] < 0]
    if len(roots) != 1:
        raise MocapValueError(
            f"BVH needs one kinematic tree but this skeleton has {len(roots)} roots "
            f"(marker data without a hierarchy cannot be written as BVH; use C3D or TRC)")
    nodes: list[_Node] = []
    joint_nodes = [0] * sk.n_joints
    taken = set(sk.names)

    def add(j, parent_node):
        k = len(nodes)
        joint_nodes[j] = k
        chans = (("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
                 if parent_node < 0 else ("Zrotation", "Xrotation", "Yrotation"))
        nodes.append(_Node(sk.names[j], parent_node, 0, sk.offsets[j] / factor, chans))
        if parent_node >= 0:
            nodes[parent_node].children.append(k)
        kids = sk.children(j)
        split = len(kids) > 1 and _turn_apart(positions, np.asarray(sk.offsets, float), kids)
        for c in kids:
            if split:
                # a zero-offset joint per child bone: a BVH joint turns all its children's
                # offsets together, and a skeleton's bones that share a start point (ASF/AMC:
                # CMU's thorax -> lower neck and both clavicles) turn separately -- without
                # these AMC -> BVH put CMU 16_15's joints 0.51 cm off on average, 2.2 cm at
                # the lower neck (as CMU's own BVH conversions have LHipJoint, LowerBack)
                b = len(nodes)
                nodes.append(_Node(_unique_name(f"{sk.names[c]}_base", taken), k, 0, np.zeros(3),
                                   ("Zrotation", "Xrotation", "Yrotation")))
                nodes[k].children.append(b)
                add(c, b)
            else:
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
    if ch.shape[1] == 0:
        f.write("\n" * ch.shape[0])
        return
    for a in range(0, ch.shape[0], 65536):            # 9 decimals, trailing zeros trimmed
        f.write(fixed_rows(ch[a:a + 65536], 9).decode("ascii"))


def _ik_chunked(nodes: list[_Node], joint_nodes: list[int], positions: np.ndarray, factor: float,
                ch0: np.ndarray | None) -> np.ndarray:
    """:func:`_inverse_kinematics` over chunks of :data:`_CHUNK` frames (bounded memory;
    the chunks join seamlessly, angles without a reference are unwrapped across them)."""
    T, N = positions.shape[0], len(nodes)
    have = np.zeros(N, bool)
    have[joint_nodes] = True
    plan = _IKPlan(nodes, have)
    ch = np.empty((T, plan.C))
    for a in range(0, T, _CHUNK):
        b = min(a + _CHUNK, T)
        targets = np.full((b - a, N, 3), np.nan)
        targets[:, joint_nodes] = positions[a:b] / factor
        ch[a:b] = _inverse_kinematics(nodes, targets, have, None if ch0 is None else ch0[a:b], plan,
                                      ch[a - 1] if a else None)
        ch[a:b] = _bvh_polish.polish(nodes, (plan.rot, plan.pos, plan.C), ch[a:b], targets, have,
                                     above=1e-3 / factor, cap=0.5 / factor, spread=0.01 / factor)
    return ch


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
    require_complete(motion, "BVH")
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
        nodes, joint_nodes = _hierarchy_from_skeleton(motion.skeleton, factor, motion.positions)
        frame_time = 1.0 / motion.fps
    if not FRAME_TIME_RANGE[0] <= frame_time <= FRAME_TIME_RANGE[1]:
        raise MocapValueError(f"cannot write BVH at {motion.fps:g} fps: the frame time {frame_time:g} s "
                              f"is outside {FRAME_TIME_RANGE[0]:g} .. {FRAME_TIME_RANGE[1]:g} s (the "
                              f"range the reader accepts); resample the motion first")
    N = len(nodes)
    ch = _ik_chunked(nodes, joint_nodes, motion.positions, factor, ch0)
    if not np.isfinite(ch).all():
        raise MocapValueError("inverse kinematics produced non-finite channel values")
    atomic_write(path, lambda f: _write_text(f, nodes, ch, frame_time))
    # the check on at most UNREACHABLE_FRAMES evenly spaced frames: what a hierarchy cannot
    # hold shows in many (the FK and the check of every frame were 15 % of the write)
    frames = spaced_frames(T, UNREACHABLE_FRAMES)
    miss = _unreachable(motion, frames, _fk_positions(nodes, ch[frames], joint_nodes, factor))
    if miss:
        warnings.warn(f"{path}: {miss}", MocapWarning, stacklevel=2)


#: cm a written joint may sit off the motion's position, beyond what its bone lengths
#: explain, before :func:`write` says so; checked on this many evenly spaced frames at most
UNREACHABLE_CM = 0.1
UNREACHABLE_FRAMES = 2048


def _unreachable(motion: Motion, frames: np.ndarray, P: np.ndarray) -> str | None:
    """One line when the written rotations put joints off the motion's positions -- P (F, J,
    3) cm, the FK of the written ``frames`` (F,) -- by more than ``UNREACHABLE_CM`` + 3 x
    the frame's largest bone-length mismatch (the part no pose can reach): e.g. a stored
    hierarchy whose joint turns children together that the motion moves apart (before the
    zero-offset joints of :func:`_hierarchy_from_skeleton`, CMU 16_15 AMC -> BVH was 0.51
    cm off on average, 2.2 cm at the lower neck, silently). None when every frame is held."""
    from ..rigid import bone_lengths

    X = motion.positions[frames]
    err = np.linalg.norm(P - X, axis=2)                                    # (F, J)
    sk = motion.skeleton
    kids = np.flatnonzero(np.asarray(sk.parents) >= 0)
    par = np.asarray(sk.parents)[kids]
    rest = np.linalg.norm(np.asarray(sk.offsets)[kids], axis=1)
    mis = np.abs(bone_lengths(X, np.stack([kids, par], axis=1)) - rest).max(axis=1) if len(kids) else 0.0
    off = err.max(axis=1) > UNREACHABLE_CM + 3.0 * mis
    if not off.any():
        return None
    t, j = np.unravel_index(int(np.argmax(np.where(off[:, None], err, 0.0))), err.shape)
    return (f"the BVH rotations hold the motion's joint positions only to {err[off].mean():.2f} cm mean, "
            f"{err[t, j]:.2f} cm at most ({sk.names[j]}, frame {int(frames[t])}) in {int(off.sum())} of "
            f"{len(off)} frames checked: a BVH joint turns all its children together and keeps each bone's "
            f"length (hierarchy='skeleton' builds one from these positions; C3D / TRC keep them as they are)")
