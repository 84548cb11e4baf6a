"""Acclaim ASF/AMC reader and writer (CMU and HDM05 variants); own parser, no dependency.

ASF (skeleton)
--------------
Sections ``:version``, ``:name``, ``:units`` (``mass``, ``length``, ``angle deg|rad``),
``:documentation``, ``:root`` (``order`` of the AMC root channels, ``axis`` rotation
order, ``position``, ``orientation``), ``:bonedata`` (``begin … end`` blocks with ``id``,
``name``, ``direction`` (unit vector in the global rest frame), ``length``,
``axis ax ay az ORDER``, ``dof`` (rotational ``rx ry rz``; translational bone dofs are
refused), ``limits`` (one ``(lo hi)`` pair per dof, possibly over several lines)) and
``:hierarchy`` (``begin``, ``parent child child …`` lines, ``end``). Unknown keywords
(``bodymass``, ``cofmass``, ``:namespace`` …) are kept and ignored.

AMC (motion)
------------
Header keywords (``:FULLY-SPECIFIED``, ``:DEGREES`` / ``:RADIANS``), then frames: a frame
number line followed by one line per bone, ``name v1 v2 …`` with one value per dof in the
ASF's ``dof`` order (``root``: one per channel of the ASF ``order``). Frame numbers must
increase by one. In a ``:FULLY-SPECIFIED`` file every frame must list every bone that has
dofs; otherwise a missing bone keeps its previous value (zero in the first frame).

Forward kinematics (the Acclaim convention, vectorised over frames)
-------------------------------------------------------------------
For each bone ``b`` with parent ``p`` (``p`` = root for the top bones)::

    C_b = R(axis_b)                                   # rotation of the bone's 'axis'
    M_b = R(dof values of the frame)                  # zeros for absent dofs
    L_b = L_p · C_b · M_b · C_b^-1                    # global rotation of the bone
    end_b = end_p + L_b · (direction_b · length_b)    # bone vector in the global rest frame

``R(angles)`` applies the elementary rotations in the order of the bone's ``axis`` string
(``XYZ``: first about X, then Y, then Z, i.e. ``R = Rz · Ry · Rx`` for column vectors);
the three angles of ``axis`` are listed in that same order. The root uses
``L_root = C_root · M_root · C_root^-1`` with ``C_root`` from ``orientation`` and the
root ``axis`` order; the root joint sits at the AMC root translation (the AMC gives an
absolute position; the ASF ``position`` is the rest position used by
:func:`read_asf_motion`). The loop runs over bones only.

Joints of the returned Motion: ``root`` plus the end point of every bone, named by the
bone (31 joints for CMU, 31 for HDM05); parents follow the ``:hierarchy``; rest offsets
are ``direction · length`` in cm.

Units
-----
``:units length s`` means that ASF/AMC lengths are *inches × s*: CMU and HDM05 both state
``length 0.45``, so one file unit is ``1/0.45`` inch = ``2.54/0.45`` = **5.644444 cm**
(the factor applied to bone lengths and root translations). In general the factor is
``2.54 / s`` cm per unit; ``read(..., units=f)`` overrides it with ``f`` cm per unit.
With this factor CMU subjects stand 150-200 cm tall, and so do the HDM05 actors (see
``docs/results/io.md``). Angles are kept in the file's unit (``:DEGREES`` in the AMC,
else the ASF ``angle``).

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
(:func:`inverse_kinematics`), top-down and vectorised over frames:

1. every rotating node (root, and each bone with rotational dofs) starts from its
   stored local rotation (when ``per_frame['dofs']`` still aligns with the frames) or
   from the rest pose;
2. its global rotation is corrected by the *minimal* rotation that maps its predicted
   bone vector onto the vector from the already-solved parent end point to its target
   end point; bones without dofs hanging from it (CMU ``lhipjoint``/``rhipjoint`` on the
   root) are fitted together with it (Kabsch/SVD when several vectors); the free twist of
   a 3-dof bone about its own axis is chosen so that its children, predicted with their
   stored rotations, come closest to their targets (keeping the stored twist when the
   children are nearly collinear with the bone);
3. the local rotation ``M = C^-1 · L_p^T · L_b · C`` is converted to the bone's Euler
   angles (the branch and 360° turn nearest to the start value). Bones with fewer than
   3 rotational dofs get the closest representable rotation: the angles of their own
   dofs that best align their bone vector (and dof-less descendants) with the targets
   (exact for one dof; for two, a scan over the first angle with the second in closed
   form, then a golden-section refinement), the other angles zero;
4. a Levenberg-Marquardt polish of all dofs of each frame at once (analytic Jacobian,
   at most 12 iterations, only on frames whose error exceeds 1e-6 cm, a step kept only
   if it lowers that frame's squared position error) fixes what the top-down pass cannot
   see, e.g. a femur twist when no stored dofs exist.

The root translation is taken from the root target. Missing (NaN) targets keep the
start rotation (write a fully observed motion: fill gaps first). Accuracy on CMU 16_15
(``docs/results/io.md``): poses the skeleton can reach (every stored angle + N(0, 2°))
come back to < 0.001 cm, with N(0, 10°) to 0.7 cm max (mean 0.0004 cm); without stored
dofs (e.g. after ``resample``) clean positions come back within 0.12 cm (mean 0.007 cm);
noisy positions give the skeleton's least-squares fit (i.i.d. 1 cm noise: 0.65 cm RMS
from the targets, 0.76 cm from the clean motion).

A written AMC needs its ASF: when the skeleton lookup for the output file would not
find an identical skeleton, ``<output stem>.asf`` is written beside it
(``write_asf=False`` to skip, or a path to choose where).
"""
from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ._rotations import axis_rotation
from ..errors import MocapFormatError, MocapValueError
from ..motion import Motion
from ..skeleton import Skeleton
from ._atomic import atomic_write
from ._text import read_text as _read_text

__all__ = ["read", "read_asf", "read_asf_motion", "write", "write_asf", "find_skeleton",
           "forward_kinematics", "inverse_kinematics", "cm_per_unit", "CMU_CM_PER_UNIT"]

#: cm per ASF length unit for ``:units length 0.45`` (CMU, HDM05): 2.54 / 0.45.
CMU_CM_PER_UNIT = 2.54 / 0.45
_ROT_DOFS = ("rx", "ry", "rz")
_TRANS_DOFS = ("tx", "ty", "tz", "l")
_ROOT_CHANNELS = ("TX", "TY", "TZ", "RX", "RY", "RZ")
_UNCHANGED_TOL_CM = 1e-7
_CHILD_W = 0.3          # sqrt of the weight of predicted child vectors in the partial-dof fit
_SEARCH_PARENT_LEVELS = 2


# ======================================================================================
# ASF parsing
# ======================================================================================


def _num(tok: str, path, line: int, what: str) -> float:
    try:
        v = float(tok)
    except ValueError:
        raise MocapFormatError(path, f"expected a number for {what}, found {tok!r}", line) from None
    if not math.isfinite(v):
        raise MocapFormatError(path, f"{what} is {tok!r}; only finite numbers are allowed", line)
    return v


def _nums(toks: Sequence[str], n: int, path, line: int, what: str) -> list[float]:
    if len(toks) != n:
        raise MocapFormatError(path, f"{what} needs {n} numbers, found {len(toks)}", line)
    return [_num(t, path, line, what) for t in toks]


def _axis_order(tok: str, path, line: int, what: str) -> str:
    o = tok.upper()
    if sorted(o) != ["X", "Y", "Z"]:
        raise MocapFormatError(path, f"{what} must be a permutation of XYZ, found {tok!r}", line)
    return o


def read_asf(path: str | os.PathLike) -> dict[str, Any]:
    """Parse an ASF file into a plain description (lists, floats, strings).

    Returns
    -------
    dict with ``version``, ``name``, ``units`` ({'mass', 'length', 'angle'} as in the file),
    ``documentation`` (lines), ``root`` ({'order', 'axis', 'position', 'orientation'}),
    ``bones`` (list of {'id', 'name', 'direction', 'length', 'axis', 'axis_order', 'dof',
    'limits'}) in file order, ``hierarchy`` (list of [parent, [children]]) and ``extra``
    (unknown header lines, kept verbatim).

    Raises
    ------
    MocapFormatError naming the line: missing/cyclic hierarchy, unknown bone in the
    hierarchy, duplicate bone names, bad numbers, missing :bonedata, translational dofs.
    """
    text = _read_text(path)
    lines = text.splitlines()
    asf: dict[str, Any] = {"version": "", "name": "", "units": {"mass": 1.0, "length": 1.0, "angle": "deg"},
                           "documentation": [], "root": None, "bones": [], "hierarchy": [], "extra": []}
    section = None
    bone: dict | None = None
    bone_line = 0
    in_limits = False
    hier_begun = False
    hier_ended = False
    seen_bonedata = False
    hier_lines: list[tuple[int, list[str]]] = []
    bone_lines: dict[str, int] = {}
    root = {"order": list(_ROOT_CHANNELS), "axis": "XYZ", "position": [0.0, 0.0, 0.0],
            "orientation": [0.0, 0.0, 0.0]}
    root_seen = False

    for ln, raw in enumerate(lines, 1):
        s = raw.split("#", 1)[0].strip()
        if not s:
            continue
        toks = s.split()
        key = toks[0].lower()
        if s.startswith(":"):
            if bone is not None:
                raise MocapFormatError(path, f"bone block opened at line {bone_line} has no 'end'", ln)
            in_limits = False
            section = key
            rest = s[len(toks[0]):].strip()
            if key == ":version":
                asf["version"] = rest
            elif key == ":name":
                asf["name"] = rest
            elif key == ":bonedata":
                seen_bonedata = True
            elif key == ":root":
                root_seen = True
            elif key not in (":units", ":documentation", ":hierarchy"):
                asf["extra"].append(raw.rstrip())
            continue
        if section is None:
            raise MocapFormatError(path, f"expected a ':keyword' section header, found {s!r}", ln)
        if section == ":units":
            if len(toks) != 2:
                raise MocapFormatError(path, f"units line must be 'name value', found {s!r}", ln)
            if key == "angle":
                a = toks[1].lower()
                if a not in ("deg", "rad", "degree", "degrees", "radian", "radians"):
                    raise MocapFormatError(path, f"angle unit must be deg or rad, found {toks[1]!r}", ln)
                asf["units"]["angle"] = "rad" if a.startswith("rad") else "deg"
            elif key in ("mass", "length"):
                v = _num(toks[1], path, ln, f"units {key}")
                if v <= 0:
                    raise MocapFormatError(path, f"units {key} must be positive, found {toks[1]}", ln)
                asf["units"][key] = v
            else:
                asf["units"][key] = toks[1]
        elif section == ":documentation":
            asf["documentation"].append(raw.strip())
        elif section == ":root":
            if key == "order":
                order = [t.upper() for t in toks[1:]]
                bad = [t for t in order if t not in _ROOT_CHANNELS]
                if bad or len(set(order)) != len(order) or not order:
                    raise MocapFormatError(path, f"root order must list distinct channels from "
                                           f"{' '.join(_ROOT_CHANNELS)}, found {' '.join(toks[1:])!r}", ln)
                root["order"] = order
            elif key == "axis":
                if len(toks) != 2:
                    raise MocapFormatError(path, "root axis needs one rotation order, e.g. XYZ", ln)
                root["axis"] = _axis_order(toks[1], path, ln, "root axis")
            elif key in ("position", "orientation"):
                root[key] = _nums(toks[1:], 3, path, ln, f"root {key}")
            else:
                raise MocapFormatError(path, f"unknown :root keyword {toks[0]!r} (expected order, "
                                       f"axis, position, orientation)", ln)
        elif section == ":bonedata":
            if key == "begin":
                if bone is not None:
                    raise MocapFormatError(path, f"'begin' inside the bone block opened at line {bone_line}", ln)
                bone = {"id": None, "name": None, "direction": None, "length": None,
                        "axis": [0.0, 0.0, 0.0], "axis_order": "XYZ", "dof": [], "limits": [],
                        "extra": []}
                bone_line = ln
                in_limits = False
                continue
            if bone is None:
                raise MocapFormatError(path, f"expected 'begin' of a bone block, found {s!r}", ln)
            if key == "end":
                for req in ("name", "direction", "length"):
                    if bone[req] is None:
                        raise MocapFormatError(path, f"bone block has no '{req}'", bone_line)
                if bone["name"] in bone_lines or bone["name"].lower() == "root":
                    raise MocapFormatError(path, f"duplicate bone name {bone['name']!r}", bone_line)
                if bone["limits"] and len(bone["limits"]) != len(bone["dof"]):
                    raise MocapFormatError(path, f"bone {bone['name']!r} has {len(bone['dof'])} dofs "
                                           f"but {len(bone['limits'])} limits", ln)
                bone_lines[bone["name"]] = bone_line
                asf["bones"].append(bone)
                bone = None
                in_limits = False
                continue
            if s.startswith("("):
                if not in_limits:
                    raise MocapFormatError(path, f"limit {s!r} outside a 'limits' entry", ln)
                bone["limits"].extend(_parse_limits(s, path, ln))
                continue
            in_limits = False
            if key == "id":
                bone["id"] = toks[1] if len(toks) > 1 else ""
            elif key == "name":
                if len(toks) != 2:
                    raise MocapFormatError(path, f"bone name must be one word, found {s!r}", ln)
                bone["name"] = toks[1]
            elif key == "direction":
                d = _nums(toks[1:], 3, path, ln, "direction")
                if not any(abs(x) > 0 for x in d):
                    raise MocapFormatError(path, "bone direction is the zero vector", ln)
                bone["direction"] = d
            elif key == "length":
                v = _nums(toks[1:], 1, path, ln, "length")[0]
                if v < 0:
                    raise MocapFormatError(path, f"bone length must be >= 0, found {toks[1]}", ln)
                bone["length"] = v
            elif key == "axis":
                if len(toks) != 5:
                    raise MocapFormatError(path, "axis needs three angles and an order, e.g. "
                                           "'axis 0 0 20 XYZ'", ln)
                bone["axis"] = _nums(toks[1:4], 3, path, ln, "axis")
                bone["axis_order"] = _axis_order(toks[4], path, ln, "axis order")
            elif key == "dof":
                dofs = [t.lower() for t in toks[1:]]
                for d in dofs:
                    if d in _TRANS_DOFS:
                        raise MocapFormatError(path, f"translational dof {d!r} on a bone is not "
                                               f"supported (only rx ry rz)", ln)
                    if d not in _ROT_DOFS:
                        raise MocapFormatError(path, f"unknown dof {d!r} (expected rx, ry, rz)", ln)
                if len(set(dofs)) != len(dofs):
                    raise MocapFormatError(path, f"repeated dof in {s!r}", ln)
                bone["dof"] = dofs
            elif key == "limits":
                in_limits = True
                rest = s[len(toks[0]):].strip()
                if rest:
                    bone["limits"].extend(_parse_limits(rest, path, ln))
            else:
                bone["extra"].append(s)
        elif section == ":hierarchy":
            if key == "begin":
                hier_begun = True
                continue
            if key == "end":
                hier_ended = True
                continue
            if not hier_begun or hier_ended:
                raise MocapFormatError(path, f"hierarchy line outside begin/end: {s!r}", ln)
            hier_lines.append((ln, toks))
        else:
            asf["extra"].append(raw.rstrip())
    if bone is not None:
        raise MocapFormatError(path, f"bone block opened at line {bone_line} has no 'end' (truncated file?)",
                               len(lines))
    if not seen_bonedata:
        raise MocapFormatError(path, "no :bonedata section (is this an ASF file?)", len(lines) or None)
    if not root_seen:
        raise MocapFormatError(path, "no :root section", len(lines) or None)
    if not hier_lines:
        raise MocapFormatError(path, "no :hierarchy (or an empty one): the bones cannot be connected",
                               len(lines) or None)
    if not hier_ended:
        raise MocapFormatError(path, ":hierarchy has no 'end' (truncated file?)", len(lines))
    asf["root"] = root
    # -- hierarchy: each bone exactly one parent; no cycles; every bone reachable ------------
    known = set(bone_lines) | {"root"}
    parent_of: dict[str, tuple[str, int]] = {}
    for ln, toks in hier_lines:
        par = toks[0]
        if par not in known:
            raise MocapFormatError(path, f"hierarchy names unknown bone {par!r}", ln)
        for ch in toks[1:]:
            if ch not in known or ch == "root":
                raise MocapFormatError(path, f"hierarchy names unknown bone {ch!r}" if ch != "root"
                                       else "root cannot be a child in the hierarchy", ln)
            if ch in parent_of:
                raise MocapFormatError(path, f"bone {ch!r} has two parents ({parent_of[ch][0]!r} at line "
                                       f"{parent_of[ch][1]} and {par!r})", ln)
            if ch == par:
                raise MocapFormatError(path, f"bone {ch!r} is its own parent (cyclic hierarchy)", ln)
            parent_of[ch] = (par, ln)
        asf["hierarchy"].append([par, list(toks[1:])])
    for name, bl in bone_lines.items():
        if name not in parent_of:
            raise MocapFormatError(path, f"bone {name!r} is missing from the :hierarchy", bl)
        # walk up: must reach root without revisiting
        seen = {name}
        cur = name
        while cur != "root":
            cur, hl = parent_of[cur]
            if cur in seen:
                raise MocapFormatError(path, f"cyclic hierarchy through bone {cur!r}", hl)
            seen.add(cur)
    return asf


def _parse_limits(s: str, path, ln: int) -> list[list[float]]:
    out = []
    for m in re.finditer(r"\(([^()]*)\)", s):
        parts = m.group(1).replace(",", " ").split()
        if len(parts) != 2:
            raise MocapFormatError(path, f"a limit needs '(lo hi)', found {m.group(0)!r}", ln)
        vals = []
        for p in parts:
            try:
                vals.append(float(p))           # 'inf' / '-inf' are legal limits
            except ValueError:
                raise MocapFormatError(path, f"bad limit value {p!r}", ln) from None
        out.append(vals)
    leftover = re.sub(r"\(([^()]*)\)", "", s).strip()
    if leftover or not out:
        raise MocapFormatError(path, f"malformed limits {s!r}; expected '(lo hi)' pairs", ln)
    return out


def cm_per_unit(asf: dict, units: float | str | None = None) -> float:
    """Centimetres per ASF/AMC length unit: ``2.54 / length`` (``length 0.45`` → 5.644444).

    ``units`` overrides: a number (cm per unit) or ``'cmu'``/``'cm'``/``'mm'``/``'m'``/``'inch'``.
    """
    if units is None:
        return 2.54 / float(asf["units"]["length"])
    if isinstance(units, str):
        named = {"cmu": CMU_CM_PER_UNIT, "cm": 1.0, "mm": 0.1, "m": 100.0, "inch": 2.54, "in": 2.54}
        if units.lower() not in named:
            raise MocapValueError(f"units must be a number (cm per file unit) or one of "
                                  f"{', '.join(named)}, got {units!r}")
        return named[units.lower()]
    f = float(units)
    if not np.isfinite(f) or f <= 0:
        raise MocapValueError(f"units must be a positive number of cm per file unit, got {units!r}")
    return f


# ======================================================================================
# compiled skeleton: joint order, matrices, dof layout
# ======================================================================================
def _axis_rot(axis: int, ang: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) about axis 0/1/2 by ``ang`` radians (column vectors)."""
    return axis_rotation(axis, ang)


def _euler_matrix(order: str, angles_xyz: np.ndarray) -> np.ndarray:
    """R for angles given per axis (…, 3) as (x, y, z) radians, applied in ``order`` (first letter first)."""
    R = None
    for letter in order:
        a = "XYZ".index(letter)
        Ra = _axis_rot(a, angles_xyz[..., a])
        R = Ra if R is None else Ra @ R
    return R


class _Compiled:
    """Everything FK/IK needs, derived once from an ASF description."""

    def __init__(self, asf: dict):
        self.asf = asf
        bones = asf["bones"]
        parent = {}
        for par, children in asf["hierarchy"]:
            for c in children:
                parent[c] = par
        # stable topological order of the bonedata order (parents first)
        placed = {"root"}
        order: list[str] = []
        pending = [b["name"] for b in bones]
        while pending:
            nxt = [n for n in pending if parent[n] in placed]
            if not nxt:                      # read_asf guarantees this cannot happen
                raise MocapValueError("ASF hierarchy is cyclic")
            for n in pending:
                if parent[n] in placed:
                    placed.add(n)
                    order.append(n)
            pending = [n for n in pending if n not in placed]
        self.bone_order = order
        self.names = ("root",) + tuple(order)
        jidx = {n: i for i, n in enumerate(self.names)}
        self.parent_joint = np.array([-1] + [jidx[parent[n]] for n in order])
        self.angle_rad = asf["units"]["angle"] == "rad"
        # root
        r = asf["root"]
        self.root_order = list(r["order"])
        self.root_axis = r["axis"]
        ang = np.asarray(r["orientation"], float)
        ang_xyz = self._to_xyz(ang, self.root_axis)
        self.C_root = _euler_matrix(self.root_axis, self._rad(ang_xyz))
        # dof layout (columns of per_frame['dofs']): root channels, then bones in ASF order
        names: list[str] = [f"root.{c}" for c in self.root_order]
        self.dof_cols: dict[str, list[int]] = {"root": list(range(len(self.root_order)))}
        for b in bones:
            k0 = len(names)
            names += [f"{b['name']}.{d}" for d in b["dof"]]
            self.dof_cols[b["name"]] = list(range(k0, len(names)))
        self.dof_names = names
        self.n_dofs = len(names)
        # per bone: rest vector (file units), C, Cinv, order, dof axis indices
        self.vec = {}
        self.C = {}
        self.order = {}
        self.dof_axes = {}
        for b in bones:
            n = b["name"]
            self.vec[n] = np.asarray(b["direction"], float) * float(b["length"])
            ax = self._to_xyz(np.asarray(b["axis"], float), b["axis_order"])
            self.C[n] = _euler_matrix(b["axis_order"], self._rad(ax))
            self.order[n] = b["axis_order"]
            self.dof_axes[n] = ["xyz".index(d[1]) for d in b["dof"]]
        self.bone_dofs = {b["name"]: list(b["dof"]) for b in bones}
        self.C_is_identity = {n: bool(np.array_equal(C, np.eye(3))) for n, C in self.C.items()}
        self.C_root_is_identity = bool(np.array_equal(self.C_root, np.eye(3)))
        self.children = {n: [] for n in self.names}
        for n in order:
            self.children[parent[n]].append(n)
        self.parent = parent
        self.joint_index = jidx
        # IK tables: dof-less bones rigid with each node, first dof-carrying bones below it
        # (with the dof-less path to them), joints moved by each node, twist regulariser
        self.dofless_desc: dict[str, list[str]] = {}
        self.dof_children: dict[str, list[tuple[str, list[str]]]] = {}
        self.subtree: dict[str, np.ndarray] = {}
        for n in self.names:
            rigid, firsts, stack = [], [], [(c, []) for c in self.children[n]]
            while stack:
                c, path = stack.pop(0)
                if self.dof_axes[c]:
                    firsts.append((c, path))
                else:
                    rigid.append(c)
                    stack.extend((g, path + [c]) for g in self.children[c])
            self.dofless_desc[n] = rigid
            self.dof_children[n] = firsts
            sub, stack = [jidx[n]], list(self.children[n])
            while stack:
                c = stack.pop()
                sub.append(jidx[c])
                stack.extend(self.children[c])
            self.subtree[n] = np.array(sorted(sub))
        self.axis_aligned = {}
        for n in order:
            u = self.C[n].T @ self.vec[n]
            nu = np.linalg.norm(u)
            self.axis_aligned[n] = bool(nu > 0 and any(np.linalg.norm(np.cross(np.eye(3)[a], u)) < 0.3 * nu
                                                       for a in self.dof_axes[n]))
        self.twist_reg = {n: 0.05 * sum(float(self.vec[c] @ self.vec[c]) for c, _ in self.dof_children[n])
                          for n in order}

    @staticmethod
    def _to_xyz(vals: np.ndarray, order: str) -> np.ndarray:
        """Angles listed in ``order`` (value i about letter order[i]) -> (x, y, z)."""
        out = np.zeros(np.shape(vals)[:-1] + (3,))
        for i, letter in enumerate(order):
            out[..., "XYZ".index(letter)] = vals[..., i]
        return out

    def _rad(self, a):
        return np.asarray(a, float) if self.angle_rad else np.deg2rad(a)

    def skeleton(self, f: float) -> Skeleton:
        off = [np.asarray(self.asf["root"]["position"], float) * f]
        off += [self.vec[n] * f for n in self.bone_order]
        return Skeleton(self.names, self.parent_joint, np.array(off))

    # -- root channels ----------------------------------------------------------------
    def root_split(self, dofs: np.ndarray, angle_rad: bool):
        """(translation (T,3) file units, rotation angles (T,3) xyz radians) from root columns."""
        T = dofs.shape[0]
        tr = np.zeros((T, 3))
        rot = np.zeros((T, 3))
        for k, ch in enumerate(self.root_order):
            a = "XYZ".index(ch[1])
            if ch[0] == "T":
                tr[:, a] = dofs[:, k]
            else:
                rot[:, a] = dofs[:, k] if angle_rad else np.deg2rad(dofs[:, k])
        return tr, rot


def _rot_t(axis: int, ang: np.ndarray) -> np.ndarray:
    """Rotation about axis 0/1/2 by ``ang`` (T,) radians, in the (3, 3, T) layout."""
    c, s = np.cos(ang), np.sin(ang)
    R = np.zeros((3, 3) + np.shape(ang))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[axis, axis] = 1.0
    R[i, i] = c
    R[j, j] = c
    R[i, j] = -s
    R[j, i] = s
    return R


def _mm_t(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Product of stacks of 3x3 matrices in the (3, 3, T) layout (either may be a plain 3x3).

    Nine length-T multiply-adds: about 3x faster than ``np.matmul`` on (T, 3, 3) stacks.
    """
    shape = (3, 3) + np.broadcast_shapes(A.shape[2:], B.shape[2:])
    C = np.empty(shape)
    for i in range(3):
        for k in range(3):
            C[i, k] = A[i, 0] * B[0, k] + A[i, 1] * B[1, k] + A[i, 2] * B[2, k]
    return C


def forward_kinematics(comp: _Compiled, dofs: np.ndarray, angle_rad: bool, f: float,
                       return_rotations: bool = False):
    """Joint positions (T, J, 3) in cm from dof values (T, D) (file units, file angles).

    One loop over bones, none over frames: rotations are kept as (3, 3, T) stacks and
    multiplied component-wise. With ``return_rotations`` also the global rotation of every
    node as a dict of (T, 3, 3) arrays.
    """
    dofs = np.asarray(dofs, float)
    T = dofs.shape[0]
    J = len(comp.names)
    P = np.zeros((3, J, T))
    conv = (lambda d: d) if angle_rad else np.deg2rad
    # root: L = C_root · M_root · C_root^T, M from the root rotation channels (axis order)
    M = None
    tr = np.zeros((3, T))
    rot = {}
    for k, ch in enumerate(comp.root_order):
        a = "XYZ".index(ch[1])
        if ch[0] == "T":
            tr[a] = dofs[:, k]
        else:
            rot[a] = conv(dofs[:, k])
    for letter in comp.root_axis:
        a = "XYZ".index(letter)
        if a in rot:
            Ra = _rot_t(a, rot[a])
            M = Ra if M is None else _mm_t(Ra, M)
    if M is None:
        M = np.broadcast_to(np.eye(3)[:, :, None], (3, 3, T))
    Cr = comp.C_root
    L = {"root": M if comp.C_root_is_identity else _mm_t(_mm_t(Cr, M), Cr.T)}
    P[:, 0] = tr
    for j, n in enumerate(comp.bone_order, start=1):
        Lp = L[comp.parent[n]]
        axes = comp.dof_axes[n]
        if axes:
            d = conv(dofs[:, comp.dof_cols[n]])
            # only the axes with a dof rotate (absent dofs are zero), in the 'axis' order
            M = None
            for letter in comp.order[n]:
                a = "XYZ".index(letter)
                if a in axes:
                    Ra = _rot_t(a, d[:, axes.index(a)])
                    M = Ra if M is None else _mm_t(Ra, M)
            C = comp.C[n]
            Lb = _mm_t(Lp, M if comp.C_is_identity[n] else _mm_t(_mm_t(C, M), C.T))
        else:
            Lb = Lp
        L[n] = Lb
        v = comp.vec[n]
        P[:, j] = P[:, comp.parent_joint[j]] + Lb[:, 0] * v[0] + Lb[:, 1] * v[1] + Lb[:, 2] * v[2]
    P = np.ascontiguousarray(np.transpose(P, (2, 1, 0))) * f
    if return_rotations:
        return P, {n: np.transpose(v, (2, 0, 1)) for n, v in L.items()}
    return P


# ======================================================================================
# AMC parsing
# ======================================================================================
_HEADER_RE = re.compile(r"(?:[ \t]*(?:[#:][^\n]*)?(?:\r?\n|\r))*")


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
# skeleton lookup
# ======================================================================================
def _asf_files(folder: Path) -> list[Path]:
    try:
        return sorted(p for p in folder.iterdir() if p.suffix.lower() == ".asf" and p.is_file())
    except OSError:
        return []


def find_skeleton(amc_path: str | os.PathLike) -> Path:
    """The ASF that belongs to ``amc_path``.

    Rule: the ``.asf`` whose file-name stem is a prefix of the AMC's file name, looked for in
    the AMC's folder, then its parent, then the grandparent (nearest folder wins; inside a
    folder the longest stem wins, a stem followed by a non-alphanumeric character
    (``05`` + ``_04``) before one that runs into the name; comparison ignores case);
    else the only ``.asf`` in the AMC's folder. Raises MocapFormatError when there is
    none or the choice is ambiguous.
    """
    amc = Path(amc_path)
    stem = amc.stem.lower()
    folder = amc.parent
    searched = []
    for _level in range(_SEARCH_PARENT_LEVELS + 1):
        searched.append(str(folder))
        cands = []
        for p in _asf_files(folder):
            s = p.stem.lower()
            if s and stem.startswith(s):
                nxt = stem[len(s):len(s) + 1]
                boundary = (nxt == "") or not nxt.isalnum()
                cands.append(((boundary, len(s)), p))
        if cands:
            cands.sort(key=lambda c: c[0], reverse=True)
            best = [p for r, p in cands if r == cands[0][0]]
            if len(best) > 1:
                raise MocapFormatError(amc, f"ambiguous skeleton: {', '.join(p.name for p in best)} all "
                                       f"match; pass skeleton=PATH")
            return best[0]
        if folder.parent == folder:
            break
        folder = folder.parent
    local = _asf_files(amc.parent)
    if len(local) == 1:
        return local[0]
    if len(local) > 1:
        raise MocapFormatError(amc, f"cannot tell which skeleton belongs to this AMC: "
                               f"{', '.join(p.name for p in local)} in its folder and none is a "
                               f"prefix of its name; pass skeleton=PATH")
    raise MocapFormatError(amc, f"no .asf skeleton found (looked for a file whose name prefixes "
                           f"{amc.name!r} in {', '.join(searched)}, and for a single .asf in "
                           f"{amc.parent}); pass skeleton=PATH")


# ======================================================================================
# public readers
# ======================================================================================
def _units_info(asf: dict, f: float, override) -> dict:
    s = asf["units"]["length"]
    return {"file": f"ASF length unit (':units length {s:g}' = inch x {s:g})",
            "cm_per_unit": f, "angle": asf["units"]["angle"],
            "how": "override (units=)" if override is not None else f"2.54 / {s:g}"}


def read(path: str | os.PathLike, *, skeleton: str | os.PathLike | None = None,
         units: float | str | None = None, fps: float = 120.0) -> Motion:
    """Read an AMC motion (with its ASF skeleton) into a Motion in cm.

    Parameters
    ----------
    path : the ``.amc`` file.
    skeleton : the ``.asf`` file; default: found by :func:`find_skeleton`.
    units : cm per file length unit (default ``2.54 / ASF length``, 5.644444 for CMU/HDM05).
    fps : frame rate; AMC files do not store one (CMU and HDM05 record at 120 Hz).

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
# inverse kinematics
# ======================================================================================
def _normalize(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 1e-12, n, 1.0), n[..., 0]


def _skew(v: np.ndarray) -> np.ndarray:
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return K


def _min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Shortest-arc rotations (T, 3, 3) taking directions a (T, 3) onto b (T, 3)."""
    a, na = _normalize(a)
    b, nb = _normalize(b)
    c = np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)
    K = _skew(np.cross(a, b))
    anti = c < -1 + 1e-9
    R = np.eye(3) + K + (K @ K) / np.where(anti, 1.0, 1.0 + c)[..., None, None]
    if anti.any():                       # half turn about an axis perpendicular to a
        aa = a[anti]
        ax, _ = _normalize(np.cross(aa, np.eye(3)[np.argmin(np.abs(aa), axis=1)]))
        R[anti] = 2 * ax[:, :, None] * ax[:, None, :] - np.eye(3)
    R[(na < 1e-12) | (nb < 1e-12)] = np.eye(3)
    return R


def _kabsch(U: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Rotations R (T, 3, 3) minimising sum_i |R u_i - w_i|^2 for U, W (T, n, 3)."""
    H = np.einsum("tni,tnj->tij", U, W)
    Us, _, Vt = np.linalg.svd(H)
    V, Ut = np.swapaxes(Vt, 1, 2), np.swapaxes(Us, 1, 2)
    d = np.sign(np.linalg.det(V @ Ut))
    D = np.broadcast_to(np.eye(3), H.shape).copy()
    D[:, 2, 2] = np.where(d == 0, 1.0, d)
    return V @ D @ Ut


def _rodrigues(axis: np.ndarray, ang: np.ndarray) -> np.ndarray:
    """Rotations about unit axes (T, 3) by angles (T,) radians."""
    K = _skew(axis)
    s, c = np.sin(ang)[..., None, None], np.cos(ang)[..., None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def _axis_angle_fit(axis: np.ndarray, U: np.ndarray, W: np.ndarray, reg: float | np.ndarray = 0.0) -> np.ndarray:
    """Angle about unit ``axis`` (T, 3) best rotating vectors U onto W (T, n, 3), least squares.

    Exact: the angle maximising sum_i w_i · R(θ) u_i is atan2(Σ a·(u⊥ × w⊥), Σ u⊥·w⊥).
    ``reg`` (>= 0) pulls towards zero when the projections nearly vanish.
    """
    a = axis[:, None, :]
    Up = U - np.sum(U * a, axis=-1, keepdims=True) * a
    Wp = W - np.sum(W * a, axis=-1, keepdims=True) * a
    s = np.sum(np.cross(Up, Wp) * a, axis=(-1, -2))
    c = np.sum(Up * Wp, axis=(-1, -2)) + reg
    return np.arctan2(s, c)


def _euler_from(M: np.ndarray, order: str) -> list[np.ndarray]:
    """Both Euler solutions, as (x, y, z) angles in radians, of M = R(angles) for ``order``."""
    from scipy.spatial.transform import Rotation

    a = Rotation.from_matrix(M).as_euler(order.lower())     # extrinsic: first letter first
    b = np.stack([a[:, 0] + np.pi, np.pi - a[:, 1], a[:, 2] + np.pi], axis=1)
    out = []
    for e in (a, b):
        xyz = np.zeros_like(e)
        for i, letter in enumerate(order):
            xyz[:, "XYZ".index(letter)] = e[:, i]
        out.append(xyz)
    return out


def _wrap_near(ang: np.ndarray, ref: np.ndarray) -> np.ndarray:
    return ang + 2 * np.pi * np.round((ref - ang) / (2 * np.pi))


def _angles_near(cands: list[np.ndarray], ref: np.ndarray) -> np.ndarray:
    """Of the candidate (T, 3) angle sets, each wrapped by 2π turns nearest ``ref``, the closest."""
    best, best_d = None, None
    for c in cands:
        w = _wrap_near(c, ref)
        d = np.sum((w - ref) ** 2, axis=1)
        if best is None:
            best, best_d = w, d
        else:
            take = d < best_d
            best = np.where(take[:, None], w, best)
            best_d = np.minimum(d, best_d)
    return best


def _after_rot(order: str, ang: np.ndarray, a: int) -> np.ndarray:
    """Product of the rotations applied after axis ``a`` in ``order`` (T, 3, 3)."""
    R = np.broadcast_to(np.eye(3), ang.shape[:-1] + (3, 3)).copy()
    k = order.index("XYZ"[a])
    for letter in order[k + 1:]:
        b = "XYZ".index(letter)
        R = _axis_rot(b, ang[..., b]) @ R
    return R


def _before_rot(order: str, ang: np.ndarray, a: int) -> np.ndarray:
    R = np.broadcast_to(np.eye(3), ang.shape[:-1] + (3, 3)).copy()
    k = order.index("XYZ"[a])
    for letter in order[:k]:
        b = "XYZ".index(letter)
        R = _axis_rot(b, ang[..., b]) @ R
    return R


def _fit_partial(order: str, axes: list[int], U: np.ndarray, W: np.ndarray, ang: np.ndarray,
                 ang0: np.ndarray, iters: int = 40, scan: int = 36) -> np.ndarray:
    """Angles of the present ``axes`` minimising Σ_i |M(ang) u_i - w_i|² (other angles zero).

    U (n, 3) or (T, n, 3) rest vectors and W (T, n, 3) targets, both in the bone's local
    (C) frame (scale a pair by sqrt(weight) to weight it). One dof: the exact single-axis optimum (:func:`_axis_angle_fit`). Two dofs
    (``M = R_q(β) R_p(α)``, p applied first): for every α the best β is exact, so the
    cost is scanned over ``scan`` values of α, then refined by ``iters`` golden-section
    steps within one scan step of the best value (global to the scan resolution, then
    precise to ~1e-8 rad); the same refinement runs around the start ``ang`` and wins
    when it fits as well, so equally good solutions do not flip branches between frames.
    Angles are returned on the 2π turn nearest ``ang0``.
    """
    present = [("XYZ".index(c)) for c in order if "XYZ".index(c) in axes]
    T = ang.shape[0]
    e = np.eye(3)
    out = np.zeros_like(ang)
    U = np.broadcast_to(U, W.shape)
    if len(present) == 1:
        a = present[0]
        th = _axis_angle_fit(np.broadcast_to(e[a], (T, 3)), U, W)
        out[:, a] = _wrap_near(th, ang0[:, a])
        return out
    p, q = present
    # scan α (axis p) with the best β (axis q) in closed form for each, then a golden-section
    # search on α around the best scan point
    def best_beta(alpha):                                  # alpha (..., T) -> beta, cost
        sh = alpha.shape
        Ua = np.einsum("...tij,tnj->...tni", _axis_rot(p, alpha), U)          # (..., T, n, 3)
        Wb = np.broadcast_to(W, sh + W.shape[1:])
        m = int(np.prod(sh))
        beta = _axis_angle_fit(np.broadcast_to(e[q], (m, 3)), Ua.reshape(m, -1, 3),
                               Wb.reshape(m, -1, 3)).reshape(sh)
        fit = np.einsum("...ij,...nj->...ni", _axis_rot(q, beta), Ua)
        return beta, np.sum((fit - Wb) ** 2, axis=(-2, -1))

    step = 2 * np.pi / scan
    alphas = np.linspace(-np.pi, np.pi, scan, endpoint=False)[:, None] + np.zeros((1, T))
    _, cost = best_beta(alphas)
    center = np.stack([alphas[np.argmin(cost, axis=0), np.arange(T)], ang[:, p]])   # (2, T)
    lo, hi = center - step, center + step
    g = (np.sqrt(5) - 1) / 2
    x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
    f1, f2 = best_beta(x1)[1], best_beta(x2)[1]
    for _ in range(iters):
        left = f1 < f2                       # minimum in [lo, x2]
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
        nx1 = np.where(left, hi - g * (hi - lo), x2)
        nx2 = np.where(left, x1, lo + g * (hi - lo))
        fn = best_beta(np.where(left, nx1, nx2))[1]
        f1, f2 = np.where(left, fn, f2), np.where(left, f1, fn)
        x1, x2 = nx1, nx2
    al = 0.5 * (lo + hi)                                   # (2, T): scan branch, start branch
    be, c = best_beta(al)
    # prefer the branch of the start angles when it fits as well (no flips between frames)
    k = np.where(c[1] <= c[0] + 1e-9 * (1.0 + c[0]), 1, 0)
    cur = np.zeros((T, 3))
    cur[:, p] = al[k, np.arange(T)]
    cur[:, q] = be[k, np.arange(T)]
    out[:, p] = _wrap_near(cur[:, p], ang0[:, p])
    out[:, q] = _wrap_near(cur[:, q], ang0[:, q])
    return out


def _start_angles(S: np.ndarray, comp: _Compiled, n: str, to_rad) -> np.ndarray:
    ang = np.zeros((S.shape[0], 3))
    if n == "root":
        for k, ch in enumerate(comp.root_order):
            if ch[0] == "R":
                ang[:, "XYZ".index(ch[1])] = to_rad(S[:, k])
    elif comp.dof_axes[n]:
        ang[:, comp.dof_axes[n]] = to_rad(S[:, comp.dof_cols[n]])
    return ang


def inverse_kinematics(comp: _Compiled, target_cm: np.ndarray, f: float, angle_rad: bool,
                       start: np.ndarray | None = None, *, refine: int = 12) -> np.ndarray:
    """Dof values (T, D) (file units and angle unit) whose FK follows ``target_cm`` (T, J, 3).

    Stage 1: per-bone IK, top-down, vectorised over frames (module docstring, steps 1-3).
    Stage 2 (``refine`` > 0): up to ``refine`` Levenberg-Marquardt iterations on all dofs
    of each frame at once (analytic Jacobian ``ω × (p_k - pivot)``), minimising the sum of
    squared joint-position errors; it only runs on frames whose error after stage 1 exceeds
    1e-6 cm and only accepts steps that lower that frame's error, so it can fix a twist
    the per-bone pass could not see (e.g. a femur twist without stored dofs) but never
    makes a frame worse. ``start`` (T, D): dofs to start from; default rest pose, with
    the recovered angles unwrapped over time. Missing (NaN) targets are ignored (their
    bones keep the start rotation).
    """
    X = np.asarray(target_cm, float) / f                   # file units
    T = X.shape[0]
    have_start = start is not None
    S = np.zeros((T, comp.n_dofs)) if start is None else np.array(start, float)
    out = S.copy()
    to_rad = (lambda a: a) if angle_rad else np.deg2rad
    from_rad = (lambda a: a) if angle_rad else np.rad2deg
    ji = comp.joint_index
    done = np.zeros((T, len(comp.names), 3))               # achieved (FK) end points
    L: dict[str, np.ndarray] = {}

    def tgt(k: int, base: np.ndarray, fallback: np.ndarray) -> np.ndarray:
        w = X[:, k] - base
        return np.where(np.isfinite(w).all(axis=1)[:, None], w, fallback)

    def rigid_vectors(node: str, Ln: np.ndarray, end: np.ndarray):
        """Predicted/target vectors of the dof-less bones moving rigidly with ``node``."""
        U, W, pos = [], [], {node: end}
        for d in comp.dofless_desc[node]:
            u = Ln @ comp.vec[d]
            base = pos[comp.parent[d]]
            U.append(u)
            W.append(tgt(ji[d], base, u))
            pos[d] = base + u
        return U, W

    # ---- root ---------------------------------------------------------------------------
    for k, ch in enumerate(comp.root_order):
        if ch[0] == "T":
            v = X[:, 0, "XYZ".index(ch[1])]
            out[:, k] = np.where(np.isfinite(v), v, S[:, k])
    tr, _ = comp.root_split(out, angle_rad)
    done[:, 0] = tr
    Cr = comp.C_root
    ang0 = _start_angles(S, comp, "root", to_rad)
    L0 = Cr @ _euler_matrix(comp.root_axis, ang0) @ Cr.T
    U, W = rigid_vectors("root", L0, tr)
    if len(U) < 2:
        for c, path in comp.dof_children[comp.names[0]]:
            base = tr + sum((L0 @ comp.vec[d] for d in path), np.zeros(3))
            Ac = comp.C[c] @ _euler_matrix(comp.order[c], _start_angles(S, comp, c, to_rad)) @ comp.C[c].T
            u = L0 @ Ac @ comp.vec[c]
            U.append(u)
            W.append(tgt(ji[c], base, u))
    if len(U) >= 2:
        Q = _kabsch(np.stack(U, 1), np.stack(W, 1))
    elif len(U) == 1:
        Q = _min_rotation(U[0], W[0])
    else:
        Q = np.broadcast_to(np.eye(3), (T, 3, 3))
    rot_cols = [k for k, ch in enumerate(comp.root_order) if ch[0] == "R"]
    if rot_cols:
        ang = _angles_near(_euler_from(Cr.T @ (Q @ L0) @ Cr, comp.root_axis), ang0)
        if not have_start:
            ang = np.unwrap(ang, axis=0)
        for k in rot_cols:
            out[:, k] = from_rad(ang[:, "XYZ".index(comp.root_order[k][1])])
    L["root"] = Cr @ _euler_matrix(comp.root_axis, _start_angles(out, comp, "root", to_rad)) @ Cr.T

    # ---- bones, top-down ----------------------------------------------------------------
    for j, n in enumerate(comp.bone_order, start=1):
        Lp = L[comp.parent[n]]
        pj = comp.parent_joint[j]
        axes = comp.dof_axes[n]
        if not axes:
            L[n] = Lp
            done[:, j] = done[:, pj] + Lp @ comp.vec[n]
            continue
        C, order, cols = comp.C[n], comp.order[n], comp.dof_cols[n]
        ang0 = _start_angles(S, comp, n, to_rad)
        Ls = Lp @ (C @ _euler_matrix(order, ang0) @ C.T)
        # 1) own vector (+ rigid dof-less descendants): minimal rotation / Kabsch
        u = Ls @ comp.vec[n]
        U, W = [u], [tgt(j, done[:, pj], u)]
        end_s = done[:, pj] + u
        Ur, Wr = rigid_vectors(n, Ls, end_s)
        if Ur:
            Q = _kabsch(np.stack(U + Ur, 1), np.stack(W + Wr, 1))
        else:
            Q = _min_rotation(U[0], W[0])
        Lb = Q @ Ls
        if len(axes) == 3 and comp.dof_children[n]:
            # 2) free twist about the bone axis from the children (predicted with start rotations)
            ax, ln = _normalize(Lb @ comp.vec[n])
            end_b = done[:, pj] + Lb @ comp.vec[n]
            Uc, Wc = [], []
            for c, path in comp.dof_children[n]:
                base = end_b + sum((Lb @ comp.vec[d] for d in path), np.zeros(3))
                Ac = comp.C[c] @ _euler_matrix(comp.order[c], _start_angles(S, comp, c, to_rad)) @ comp.C[c].T
                uc = Lb @ Ac @ comp.vec[c]
                Uc.append(uc)
                Wc.append(tgt(ji[c], base, uc))
            tw = _axis_angle_fit(ax, np.stack(Uc, 1), np.stack(Wc, 1), reg=comp.twist_reg[n])
            Lb = _rodrigues(ax, np.where(ln > 1e-12, tw, 0.0)) @ Lb
        M = C.T @ np.swapaxes(Lp, 1, 2) @ Lb @ C
        ang = _angles_near(_euler_from(M, order), ang0)
        if len(axes) < 3:
            # 3) closest representable rotation for a bone with fewer than 3 dofs
            keep = np.zeros(3, bool)
            keep[axes] = True
            ang = np.where(keep, ang, 0.0)

            def local(v):                                     # C^T Lp^T v for v (T, 3)
                return np.einsum("tji,tj->ti", Lp, v) @ C
            Ul, Wl = [np.broadcast_to(C.T @ comp.vec[n], (T, 3))], [local(W[0])]
            for d, wd in zip(comp.dofless_desc[n], Wr):
                Ul.append(np.broadcast_to(C.T @ comp.vec[d], (T, 3)))
                Wl.append(local(wd))
            # children, predicted with their start rotations, at a low weight, for a bone whose
            # own vector (nearly) lies on one of its dof axes and so cannot fix that angle
            # (CMU/HDM05 wrists twist about themselves)
            for c, path in (comp.dof_children[n] if comp.axis_aligned[n] else []):
                Ac = comp.C[c] @ _euler_matrix(comp.order[c], _start_angles(S, comp, c, to_rad)) @ comp.C[c].T
                uc = np.einsum("tij,j->ti", Ac, comp.vec[c]) @ C           # C^T Ac vec_c
                wc = X[:, ji[c]] - X[:, ji[comp.parent[c]]]
                wc = np.where(np.isfinite(wc).all(axis=1)[:, None], local(wc), uc)
                Ul.append(_CHILD_W * uc)
                Wl.append(_CHILD_W * wc)
            ang = _fit_partial(order, axes, np.stack(Ul, 1), np.stack(Wl, 1), ang, ang0)
        for i, a in enumerate(axes):
            out[:, cols[i]] = from_rad(ang[:, a])
        if not have_start:
            out[:, cols] = from_rad(np.unwrap(to_rad(out[:, cols]), axis=0))
        L[n] = Lp @ (C @ _euler_matrix(order, _start_angles(out, comp, n, to_rad)) @ C.T)
        done[:, j] = done[:, pj] + L[n] @ comp.vec[n]
    if refine:
        out = _ik_refine(comp, X, out, angle_rad, int(refine))
    return out


def _ik_jacobian(comp: _Compiled, dofs: np.ndarray, P: np.ndarray, L: dict, angle_rad: bool) -> np.ndarray:
    """d positions / d dofs, (T, 3J, D), file units per file unit (degrees when the file uses them)."""
    T, J = P.shape[0], P.shape[1]
    Jm = np.zeros((T, J, 3, comp.n_dofs))
    scale = 1.0 if angle_rad else np.pi / 180.0
    to_rad = (lambda a: a) if angle_rad else np.deg2rad
    eye = np.eye(3)
    for k, ch in enumerate(comp.root_order):
        if ch[0] == "T":
            Jm[:, :, "XYZ".index(ch[1]), k] = 1.0
    nodes = [("root", np.broadcast_to(eye, (T, 3, 3)), P[:, 0], comp.C_root, comp.root_axis,
              [(k, "XYZ".index(ch[1])) for k, ch in enumerate(comp.root_order) if ch[0] == "R"])]
    for j, n in enumerate(comp.bone_order, start=1):
        if comp.dof_axes[n]:
            nodes.append((n, L[comp.parent[n]], P[:, comp.parent_joint[j]], comp.C[n], comp.order[n],
                          list(zip(comp.dof_cols[n], comp.dof_axes[n]))))
    for n, Lp, pivot, C, order, colaxes in nodes:
        if not colaxes:
            continue
        ang = _start_angles(dofs, comp, n, to_rad)
        sub = comp.subtree[n]
        arm = P[:, sub] - pivot[:, None, :]
        LpC = Lp @ C
        for col, a in colaxes:
            w = (LpC @ _after_rot(order, ang, a))[:, :, a]            # world axis (T, 3)
            Jc = Jm[..., col]                                             # view (T, J, 3)
            Jc[:, sub] = np.cross(w[:, None, :], arm) * scale
    return Jm.reshape(T, 3 * J, comp.n_dofs)


def _ik_refine(comp: _Compiled, X: np.ndarray, dofs: np.ndarray, angle_rad: bool, iters: int,
               chunk: int = 512, tol_cm: float = 1e-6, rel_tol: float = 1e-3) -> np.ndarray:
    """Levenberg-Marquardt polish of ``dofs`` towards targets X (file units), per frame.

    Each frame has its own damping; a step is kept only if it lowers that frame's sum of
    squared position errors; a frame leaves the active set once its error is below
    ``tol_cm`` or a step gains less than ``rel_tol`` of it.
    """
    dofs = dofs.copy()
    Wm = np.isfinite(X).all(axis=2)                                 # (T, J) usable targets
    Xf = np.where(Wm[..., None], X, 0.0)
    tol = (tol_cm / 5.0) ** 2
    eye = np.eye(comp.n_dofs)

    def cost_of(D, idx):
        P, Lr = forward_kinematics(comp, D, angle_rad, 1.0, return_rotations=True)
        r = (P - Xf[idx]) * Wm[idx][..., None]
        return np.sum(r ** 2, axis=(1, 2)), r, P, Lr

    for s in range(0, X.shape[0], chunk):
        idx = np.arange(s, min(s + chunk, X.shape[0]))
        D = dofs[idx]
        cost, r, P, Lr = cost_of(D, idx)
        lam = np.full(len(idx), 1e-3)
        live = cost > tol
        for _ in range(iters):
            if not live.any():
                break
            k = np.flatnonzero(live)
            Lk = {n: v[k] for n, v in Lr.items()}
            Jm = _ik_jacobian(comp, D[k], P[k], Lk, angle_rad) * np.repeat(Wm[idx[k]], 3, axis=1)[..., None]
            Jt = np.swapaxes(Jm, 1, 2)
            A = Jt @ Jm                                              # batched BLAS
            g = (Jt @ r[k].reshape(len(k), -1, 1))[..., 0]
            diag = np.einsum("tii->ti", A)
            step = -np.linalg.solve(A + (lam[k, None] * (diag + 1e-9))[:, :, None] * eye, g[..., None])[..., 0]
            newc, newr, newP, newL = cost_of(D[k] + step, idx[k])
            ok = newc < cost[k]
            gain = np.where(ok, (cost[k] - newc) / np.maximum(cost[k], 1e-300), 0.0)
            acc = k[ok]
            D[acc] += step[ok]
            cost[acc], r[acc], P[acc] = newc[ok], newr[ok], newP[ok]
            for n in Lr:
                Lr[n][acc] = newL[n][ok]
            lam[k] = np.where(ok, np.maximum(lam[k] / 5, 1e-9), lam[k] * 8)
            live[k] = np.where(ok, (newc > tol) & (gain > rel_tol), lam[k] < 1e6)
        dofs[idx] = D
    return dofs


# ======================================================================================
# writers
# ======================================================================================
def _fmt_asf_num(x: float) -> str:
    return repr(float(x))


def _asf_text(asf: dict) -> str:
    out = ["# ASF written by mocapkit", f":version {asf.get('version') or '1.10'}",
           f":name {asf.get('name') or 'mocapkit'}"]
    out += [e for e in asf.get("extra", []) if e.strip().startswith(":")]
    u = asf["units"]
    out += [":units", f"  mass {_fmt_asf_num(u.get('mass', 1.0))}",
            f"  length {_fmt_asf_num(u['length'])}", f"  angle {u.get('angle', 'deg')}"]
    if asf.get("documentation"):
        out += [":documentation"] + ["  " + d for d in asf["documentation"]]
    r = asf["root"]
    out += [":root", "  order " + " ".join(r["order"]), "  axis " + r["axis"],
            "  position " + " ".join(_fmt_asf_num(v) for v in r["position"]),
            "  orientation " + " ".join(_fmt_asf_num(v) for v in r["orientation"]), ":bonedata"]
    for b in asf["bones"]:
        out += ["  begin", f"    id {b.get('id') or 0}", f"    name {b['name']}",
                "    direction " + " ".join(_fmt_asf_num(v) for v in b["direction"]),
                f"    length {_fmt_asf_num(b['length'])}",
                "    axis " + " ".join(_fmt_asf_num(v) for v in b["axis"]) + " " + b["axis_order"]]
        if b["dof"]:
            out.append("    dof " + " ".join(b["dof"]))
        if b.get("limits"):
            lims = [f"({_fmt_asf_num(lo)} {_fmt_asf_num(hi)})" for lo, hi in b["limits"]]
            out.append("    limits " + lims[0])
            out += ["           " + x for x in lims[1:]]
        out.append("  end")
    out += [":hierarchy", "  begin"]
    out += ["    " + " ".join([par] + list(ch)) for par, ch in asf["hierarchy"]]
    out += ["  end"]
    return "\n".join(out) + "\n"


def write_asf(asf: dict, path: str | os.PathLike) -> Path:
    """Write an ASF skeleton description (as returned by :func:`read_asf`) atomically."""
    p = Path(path)
    text = _asf_text(asf)
    atomic_write(p, lambda fh: fh.write(text))
    return p


def _same_skeleton(a: dict, b: dict) -> bool:
    try:
        if a["units"]["length"] != b["units"]["length"] or a["units"]["angle"] != b["units"]["angle"]:
            return False
        if a["root"]["order"] != b["root"]["order"] or a["root"]["axis"] != b["root"]["axis"]:
            return False
        if not np.allclose(a["root"]["orientation"], b["root"]["orientation"]):
            return False
        if len(a["bones"]) != len(b["bones"]):
            return False
        for x, y in zip(a["bones"], b["bones"]):
            if (x["name"] != y["name"] or x["dof"] != y["dof"] or x["axis_order"] != y["axis_order"]
                    or not np.allclose(x["direction"], y["direction"])
                    or not np.isclose(x["length"], y["length"]) or not np.allclose(x["axis"], y["axis"])):
                return False
        pa = {c: p for p, cs in a["hierarchy"] for c in cs}
        pb = {c: p for p, cs in b["hierarchy"] for c in cs}
        return pa == pb
    except (KeyError, TypeError, ValueError):
        return False


def _amc_text(comp: _Compiled, dofs: np.ndarray, meta: dict, angle_rad: bool, asf_name: str) -> str:
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
    head = [f"#!OML:ASF {asf_name}", "# written by mocapkit",
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
    MocapValueError when the motion has no ASF description or its joints do not match it.
    """
    p = Path(path)
    src = motion.source
    asf = src.get("asf")
    if not isinstance(asf, dict) or "bones" not in asf:
        raise MocapValueError("AMC output needs a motion read from an ASF/AMC file (its skeleton "
                              "description is in source['asf']); write this motion as BVH or C3D instead")
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
                     Path(src.get("skeleton_path", "skeleton.asf")).name)
    if asf_out is not None:
        write_asf_file = _asf_text(asf)
        atomic_write(asf_out, lambda fh: fh.write(write_asf_file))
    atomic_write(p, lambda fh: fh.write(text))
    return p
