"""ASF skeleton files (Acclaim; CMU and HDM05 variants): parser, writer, comparison,
the skeleton lookup for an AMC, and the length unit.

The motion side is :mod:`mocapkit.io.amc`, the forward/inverse kinematics
:mod:`mocapkit.io._kinematics`; own parser, no dependency.

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

Units
-----
``:units length s`` means that ASF/AMC lengths are *inches × s*: CMU and HDM05 both state
``length 0.45``, so one file unit is ``1/0.45`` inch = ``2.54/0.45`` = **5.644444 cm**
(the factor applied to bone lengths and root translations). In general the factor is
``2.54 / s`` cm per unit (:func:`cm_per_unit`); ``mocapkit.io.read(..., units=f)``
overrides it with ``f`` cm per unit or a unit name (:mod:`mocapkit.io.units`).
With this factor CMU subjects stand 150-200 cm tall, and so do the HDM05 actors (see
``docs/results/io.md``). Angles are kept in the file's unit (``:DEGREES`` in the AMC,
else the ASF ``angle``).
"""
from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..errors import MocapFormatError, MocapValueError
from ._atomic import atomic_write
from ._text import read_text as _read_text
from .units import LENGTH_UNITS, unit_name

__all__ = ["read_asf", "write_asf", "find_skeleton", "cm_per_unit"]

_ROT_DOFS = ("rx", "ry", "rz")
_TRANS_DOFS = ("tx", "ty", "tz", "l")
_ROOT_CHANNELS = ("TX", "TY", "TZ", "RX", "RY", "RZ")
_SEARCH_PARENT_LEVELS = 2
_ANGLE_UNITS = ("deg", "rad", "degree", "degrees", "radian", "radians")


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
    lines = _read_text(path).splitlines()
    parser = _AsfParser(path)
    for ln, raw in enumerate(lines, 1):
        parser.line(ln, raw)
    return parser.finish(len(lines))


class _AsfParser:
    """One pass over the lines of an ASF file: section state, the open bone block, and the
    hierarchy lines kept for :func:`_link_hierarchy` (every error names its line)."""

    def __init__(self, path):
        self.path = path
        self.asf: dict[str, Any] = {"version": "", "name": "",
                                    "units": {"mass": 1.0, "length": 1.0, "angle": "deg"},
                                    "documentation": [], "root": None, "bones": [], "hierarchy": [],
                                    "extra": []}
        self.root = {"order": list(_ROOT_CHANNELS), "axis": "XYZ", "position": [0.0, 0.0, 0.0],
                     "orientation": [0.0, 0.0, 0.0]}
        self.section: str | None = None
        self.bone: dict | None = None           # the open 'begin ... end' block
        self.bone_line = 0
        self.in_limits = False                  # '(lo hi)' lines continue a 'limits' entry
        self.hier_begun = self.hier_ended = False
        self.seen_bonedata = self.root_seen = False
        self.hier_lines: list[tuple[int, list[str]]] = []
        self.bone_lines: dict[str, int] = {}    # bone name -> line of its 'begin'
        self.body = {":units": self.units_line, ":root": self.root_line, ":bonedata": self.bone_data_line,
                     ":hierarchy": self.hierarchy_line}

    def line(self, ln: int, raw: str) -> None:
        s = raw.split("#", 1)[0].strip()
        if not s:
            return
        toks = s.split()
        key = toks[0].lower()
        if s.startswith(":"):
            self.section_header(ln, raw, s, toks, key)
        elif self.section is None:
            raise MocapFormatError(self.path, f"expected a ':keyword' section header, found {s!r}", ln)
        elif self.section == ":documentation":
            self.asf["documentation"].append(raw.strip())
        elif self.section in self.body:
            self.body[self.section](ln, s, toks, key)
        else:
            self.asf["extra"].append(raw.rstrip())

    def section_header(self, ln: int, raw: str, s: str, toks: list[str], key: str) -> None:
        if self.bone is not None:
            raise MocapFormatError(self.path, f"bone block opened at line {self.bone_line} has no 'end'", ln)
        self.in_limits = False
        self.section = key
        rest = s[len(toks[0]):].strip()
        if key == ":version":
            self.asf["version"] = rest
        elif key == ":name":
            self.asf["name"] = rest
        elif key == ":bonedata":
            self.seen_bonedata = True
        elif key == ":root":
            self.root_seen = True
        elif key not in (":units", ":documentation", ":hierarchy"):
            self.asf["extra"].append(raw.rstrip())

    def units_line(self, ln: int, s: str, toks: list[str], key: str) -> None:
        path, units = self.path, self.asf["units"]
        if len(toks) != 2:
            raise MocapFormatError(path, f"units line must be 'name value', found {s!r}", ln)
        if key == "angle":
            a = toks[1].lower()
            if a not in _ANGLE_UNITS:
                raise MocapFormatError(path, f"angle unit must be deg or rad, found {toks[1]!r}", ln)
            units["angle"] = "rad" if a.startswith("rad") else "deg"
        elif key in ("mass", "length"):
            v = _num(toks[1], path, ln, f"units {key}")
            if v <= 0:
                raise MocapFormatError(path, f"units {key} must be positive, found {toks[1]}", ln)
            units[key] = v
        else:
            units[key] = toks[1]

    def root_line(self, ln: int, s: str, toks: list[str], key: str) -> None:
        path, root = self.path, self.root
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

    def bone_data_line(self, ln: int, s: str, toks: list[str], key: str) -> None:
        if key == "begin":
            if self.bone is not None:
                raise MocapFormatError(self.path, f"'begin' inside the bone block opened at line "
                                                  f"{self.bone_line}", ln)
            self.bone = {"id": None, "name": None, "direction": None, "length": None,
                         "axis": [0.0, 0.0, 0.0], "axis_order": "XYZ", "dof": [], "limits": [], "extra": []}
            self.bone_line = ln
            self.in_limits = False
        elif self.bone is None:
            raise MocapFormatError(self.path, f"expected 'begin' of a bone block, found {s!r}", ln)
        elif key == "end":
            self.close_bone(ln)
        elif s.startswith("("):
            if not self.in_limits:
                raise MocapFormatError(self.path, f"limit {s!r} outside a 'limits' entry", ln)
            self.bone["limits"].extend(_parse_limits(s, self.path, ln))
        else:
            self.in_limits = _bone_field(self.bone, self.path, ln, s, toks, key)

    def close_bone(self, ln: int) -> None:
        """The 'end' of a bone block: required fields, unique name, one limit per dof."""
        bone, path = self.bone, self.path
        for req in ("name", "direction", "length"):
            if bone[req] is None:
                raise MocapFormatError(path, f"bone block has no '{req}'", self.bone_line)
        if bone["name"] in self.bone_lines or bone["name"].lower() == "root":
            raise MocapFormatError(path, f"duplicate bone name {bone['name']!r}", self.bone_line)
        if bone["limits"] and len(bone["limits"]) != len(bone["dof"]):
            raise MocapFormatError(path, f"bone {bone['name']!r} has {len(bone['dof'])} dofs "
                                   f"but {len(bone['limits'])} limits", ln)
        self.bone_lines[bone["name"]] = self.bone_line
        self.asf["bones"].append(bone)
        self.bone = None
        self.in_limits = False

    def hierarchy_line(self, ln: int, s: str, toks: list[str], key: str) -> None:
        if key == "begin":
            self.hier_begun = True
        elif key == "end":
            self.hier_ended = True
        elif not self.hier_begun or self.hier_ended:
            raise MocapFormatError(self.path, f"hierarchy line outside begin/end: {s!r}", ln)
        else:
            self.hier_lines.append((ln, toks))

    def finish(self, n_lines: int) -> dict[str, Any]:
        """Whole-file checks (open block, missing sections), then the hierarchy links."""
        path, last = self.path, n_lines or None
        if self.bone is not None:
            raise MocapFormatError(path, f"bone block opened at line {self.bone_line} has no 'end' "
                                         f"(truncated file?)", n_lines)
        if not self.seen_bonedata:
            raise MocapFormatError(path, "no :bonedata section (is this an ASF file?)", last)
        if not self.root_seen:
            raise MocapFormatError(path, "no :root section", last)
        if not self.hier_lines:
            raise MocapFormatError(path, "no :hierarchy (or an empty one): the bones cannot be connected",
                                   last)
        if not self.hier_ended:
            raise MocapFormatError(path, ":hierarchy has no 'end' (truncated file?)", n_lines)
        self.asf["root"] = self.root
        self.asf["hierarchy"] = _link_hierarchy(path, self.hier_lines, self.bone_lines)
        return self.asf


def _bone_field(bone: dict, path, ln: int, s: str, toks: list[str], key: str) -> bool:
    """Store one ``key values`` line of a bone block; True when it opens a ``limits`` entry."""
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
            raise MocapFormatError(path, "axis needs three angles and an order, e.g. 'axis 0 0 20 XYZ'", ln)
        bone["axis"] = _nums(toks[1:4], 3, path, ln, "axis")
        bone["axis_order"] = _axis_order(toks[4], path, ln, "axis order")
    elif key == "dof":
        bone["dof"] = _parse_dofs(toks[1:], path, ln, s)
    elif key == "limits":
        rest = s[len(toks[0]):].strip()
        if rest:
            bone["limits"].extend(_parse_limits(rest, path, ln))
        return True
    else:
        bone["extra"].append(s)
    return False


def _parse_dofs(toks: list[str], path, ln: int, s: str) -> list[str]:
    """The rotational dofs of a ``dof`` line (``rx ry rz``, each at most once)."""
    dofs = [t.lower() for t in toks]
    for d in dofs:
        if d in _TRANS_DOFS:
            raise MocapFormatError(path, f"translational dof {d!r} on a bone is not "
                                   f"supported (only rx ry rz)", ln)
        if d not in _ROT_DOFS:
            raise MocapFormatError(path, f"unknown dof {d!r} (expected rx, ry, rz)", ln)
    if len(set(dofs)) != len(dofs):
        raise MocapFormatError(path, f"repeated dof in {s!r}", ln)
    return dofs


def _link_hierarchy(path, hier_lines: list[tuple[int, list[str]]],
                    bone_lines: dict[str, int]) -> list[list]:
    """``[parent, [children]]`` per hierarchy line, checked: every bone has exactly one
    parent, known names only, no cycle, every bone reachable from the root."""
    known = set(bone_lines) | {"root"}
    parent_of: dict[str, tuple[str, int]] = {}
    out = []
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
        out.append([par, list(toks[1:])])
    for name, bl in bone_lines.items():
        if name not in parent_of:
            raise MocapFormatError(path, f"bone {name!r} is missing from the :hierarchy", bl)
        seen = {name}                   # walk up: must reach root without revisiting
        cur = name
        while cur != "root":
            cur, hl = parent_of[cur]
            if cur in seen:
                raise MocapFormatError(path, f"cyclic hierarchy through bone {cur!r}", hl)
            seen.add(cur)
    return out


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

    ``units`` overrides: a number (cm per unit) or a unit name of
    :data:`mocapkit.io.units.LENGTH_UNITS` (``'cmu'``, ``'cm'``, ``'mm'``, ``'m'``,
    ``'inch'``, or an alias such as ``'in'``), the names the BVH reader takes.
    """
    if units is None:
        return 2.54 / float(asf["units"]["length"])
    if isinstance(units, str):
        key = unit_name(units)
        if key is None:
            raise MocapValueError(f"units must be a number (cm per file unit) or one of "
                                  f"{', '.join(LENGTH_UNITS)}, got {units!r}")
        return LENGTH_UNITS[key]
    f = float(units)
    if not np.isfinite(f) or f <= 0:
        raise MocapValueError(f"units must be a positive number of cm per file unit, got {units!r}")
    return f


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
# ASF writer and comparison
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
