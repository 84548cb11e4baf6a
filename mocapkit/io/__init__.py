"""Read and write motion files; the format is chosen by extension (overridable).

=========  ==========================  =====================================================
format     extensions                  module
=========  ==========================  =====================================================
bvh        .bvh                        :mod:`mocapkit.io.bvh` (FK; IK on write-back)
amc        .amc (+ .asf skeleton)      :mod:`mocapkit.io.amc`, :mod:`mocapkit.io.asf`
asf        .asf (rest pose, 1 frame)   :mod:`mocapkit.io.amc` (``read_asf_motion``)
c3d        .c3d                        :mod:`mocapkit.io.c3d` (ezc3d)
trc        .trc                        :mod:`mocapkit.io.trc`
kinect     .txt (MSR-Action3D style)   :mod:`mocapkit.io.kinect`
=========  ==========================  =====================================================

Every reader returns a :class:`~mocapkit.motion.Motion` in cm or raises
:class:`~mocapkit.errors.MocapFormatError` naming the file, line and what was expected.
Every writer writes atomically and refuses to overwrite the motion's own source file.

Filled samples (``Motion.filled``)
----------------------------------
A sample computed by a gap fill rather than measured is flagged in ``Motion.filled``.
C3D carries the flag natively (residual 0 = filled, -1 = missing, > 0 measured; see
:mod:`mocapkit.io.c3d`). TRC, BVH, AMC and Kinect text have no such field, so
:func:`write` puts the flags in a **sidecar file** next to the output, and :func:`read`
reads it back when it sits next to the file:

* name: ``<output file name>.filled.tsv`` (``walk.trc`` -> ``walk.trc.filled.tsv``;
  :func:`filled_sidecar_path`);
* content: UTF-8, tab-separated, ``\n`` line ends; line 1 the joint / marker names in
  the motion's order; then one line per frame, one cell per joint: ``1`` = filled
  (computed), ``0`` = measured or missing (missingness is the motion file's own business:
  a ``1`` on a missing sample is ignored);
* written (atomically, like every output) only when the motion has at least one filled
  sample; it follows the output's overwrite rule (an existing sidecar is replaced only
  with ``overwrite=True``, and never when it is one of the motion's inputs); writing a
  motion without filled samples over an output removes that output's stale sidecar;
* read by :func:`read` (``sidecar=False`` to ignore it): a sidecar whose names or frame
  count do not match the file, or with a cell other than 0/1, is a MocapFormatError
  naming the sidecar and the line. ``source['filled_sidecar']`` records which file was
  used.
"""
from __future__ import annotations

import importlib
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import MocapFormatError, MocapValueError
from ..motion import Motion
from ._atomic import atomic_write, check_output_path

# format -> (module, extensions)
FORMATS: dict[str, tuple[str, tuple[str, ...]]] = {
    "bvh": ("bvh", (".bvh",)),
    "amc": ("amc", (".amc",)),
    "asf": ("amc", (".asf",)),
    "c3d": ("c3d", (".c3d",)),
    "trc": ("trc", (".trc",)),
    "kinect": ("kinect", (".txt",)),
}
SUPPORTED_EXTENSIONS = tuple(e for _, exts in FORMATS.values() for e in exts)
#: formats whose filled flags go to a sidecar file (C3D has its own; ASF holds no frames)
SIDECAR_FORMATS = ("bvh", "amc", "trc", "kinect")
SIDECAR_SUFFIX = ".filled.tsv"


def filled_sidecar_path(path: str | os.PathLike) -> Path:
    """Where the filled-sample flags of a TRC/BVH/AMC/Kinect file live: ``<path>.filled.tsv``."""
    p = Path(path)
    return p.with_name(p.name + SIDECAR_SUFFIX)


def _read_sidecar(side: Path, motion: Motion) -> np.ndarray:
    """(T, J) bool flags from a sidecar (format in the module docstring)."""
    from ._text import float_rows, read_text

    lines = read_text(side).splitlines()
    names = tuple(lines[0].split("\t")) if lines else ()
    if names != tuple(motion.skeleton.names):
        raise MocapFormatError(side, f"the filled-flag sidecar names {len(names)} joints "
                                     f"({', '.join(names[:4])}...) but {motion.source.get('path')} has "
                                     f"{motion.n_joints} ({', '.join(motion.skeleton.names[:4])}...); "
                                     f"delete the stale sidecar or pass sidecar=False", 1)
    nos = [k + 1 for k in range(1, len(lines)) if lines[k].strip()]
    if len(nos) != motion.n_frames:
        raise MocapFormatError(side, f"the filled-flag sidecar has {len(nos)} frame lines but "
                                     f"{motion.source.get('path')} has {motion.n_frames} frames; delete "
                                     f"the stale sidecar or pass sidecar=False", nos[-1] if nos else 1)
    A = float_rows([lines[k - 1].split("\t") for k in nos], nos, motion.n_joints, side,
                   "filled flags (0 or 1, one per joint)")
    bad = np.flatnonzero(~np.isin(A, (0.0, 1.0)).all(axis=1))
    if len(bad):
        raise MocapFormatError(side, "filled flags must be 0 or 1", nos[int(bad[0])])
    return A.astype(bool)


def _write_sidecar(motion: Motion, side: Path) -> None:
    names = motion.skeleton.names
    bad = [n for n in names if any(ch in n for ch in "\t\r\n")]
    if bad:
        raise MocapValueError(f"{side}: joint names with tabs or newlines cannot be written to the "
                              f"filled-flag sidecar: {bad[:3]}")
    F = motion.filled.astype(np.uint8)

    def body(f):
        f.write("\t".join(names) + "\n")
        row = "\t".join(["%d"] * motion.n_joints) + "\n"
        for a in range(0, motion.n_frames, 4096):
            blk = F[a:a + 4096]
            f.write((row * len(blk)) % tuple(blk.ravel().tolist()))

    atomic_write(side, body)


def detect_format(path: str | os.PathLike) -> str:
    ext = Path(path).suffix.lower()
    for fmt, (_, exts) in FORMATS.items():
        if ext in exts:
            return fmt
    raise MocapValueError(
        f"{path}: unknown file type {ext!r}; supported: {', '.join(SUPPORTED_EXTENSIONS)} "
        f"(or pass format=...)")


def _module(fmt: str):
    if fmt not in FORMATS:
        raise MocapValueError(f"unknown format {fmt!r}; supported: {', '.join(FORMATS)}")
    return importlib.import_module(f"{__name__}.{FORMATS[fmt][0]}")


def read(path: str | os.PathLike, format: str | None = None, **options: Any) -> Motion:
    """Read a motion file into a Motion (positions in cm).

    Parameters
    ----------
    path : file to read.
    format : one of ``FORMATS`` keys; default from the extension.
    **options : format-specific options (e.g. ``skeleton=`` for AMC, ``units=`` for BVH);
        ``sidecar=False`` ignores a filled-flag sidecar (module docstring).

    Returns
    -------
    Motion with positions (T, J, 3) in cm, NaN where ``observed`` is False; what the file
    said (units, header, raw channels) is in ``motion.source``.

    Raises
    ------
    MocapFormatError naming the file, line and what was expected; MocapValueError for an
    unknown format or a bad option.

    Examples
    --------
    The bundled CMU walk (an AMC; its ASF skeleton is found beside it):

    >>> from mocapkit import datasets, io
    >>> walk = io.read(datasets.bundled("16_15.amc"))
    >>> walk.n_frames, walk.n_joints, walk.fps
    (471, 31, 120.0)
    >>> walk.skeleton.names[:3], round(walk.source["units"]["cm_per_unit"], 6)
    (('root', 'lhipjoint', 'lfemur'), 5.644444)
    """
    p = Path(path)
    fmt = format or detect_format(p)
    if not p.is_file():
        raise MocapFormatError(p, "file not found" if not p.exists() else "not a regular file")
    mod = _module(fmt)
    use_sidecar = bool(options.pop("sidecar", True))
    try:
        m = mod.read(p, **options) if fmt != "asf" else mod.read_asf_motion(p, **options)
    except MocapFormatError:
        raise
    except UnicodeDecodeError as e:
        raise MocapFormatError(p, f"not a text {fmt.upper()} file (undecodable byte at offset {e.start})") from None
    side = filled_sidecar_path(p)
    if use_sidecar and fmt in SIDECAR_FORMATS and side.is_file():
        m = m.with_filled(_read_sidecar(side, m)).with_source(filled_sidecar=str(side))
    return m


def write(motion: Motion, path: str | os.PathLike, format: str | None = None, *,
          overwrite: bool = False, **options: Any) -> Path:
    """Write ``motion`` to ``path`` atomically; refuses to overwrite the motion's source file.

    Parameters
    ----------
    motion : the Motion to write (positions in cm).
    path : output file; its extension chooses the format unless ``format`` is given.
    format : one of ``FORMATS`` keys.
    overwrite : replace an existing output (never the motion's own source files).
    **options : format-specific options (e.g. ``units=`` for TRC/BVH, ``write_asf=`` for AMC).

    Returns
    -------
    The path written. Filled flags go to a sidecar beside it (module docstring).

    Examples
    --------
    An AMC whose positions are unchanged is written with its stored joint angles and
    re-reads exactly; its ASF skeleton is written beside it:

    >>> import tempfile
    >>> from pathlib import Path
    >>> import numpy as np
    >>> from mocapkit import datasets, io
    >>> walk = io.read(datasets.bundled("16_15.amc")).slice(0, 10)
    >>> with tempfile.TemporaryDirectory() as d:
    ...     out = io.write(walk, Path(d) / "walk.amc")
    ...     files = sorted(p.name for p in Path(d).iterdir())
    ...     back = io.read(out)
    ...     trc = io.read(io.write(walk, Path(d) / "walk.trc"))     # markers, mm, 6 decimals
    >>> files
    ['walk.amc', 'walk.asf']
    >>> bool(np.array_equal(back.positions, walk.positions))
    True
    >>> bool(np.abs(trc.positions - walk.positions).max() < 1e-6)
    True
    """
    p = Path(path)
    fmt = format or detect_format(p)
    inputs = (motion.source.get("path"), motion.source.get("filled_sidecar"))
    check_output_path(p, inputs, overwrite=overwrite)
    mod = _module(fmt)
    if not hasattr(mod, "write"):
        raise MocapValueError(f"writing {fmt} files is not supported")
    side = filled_sidecar_path(p) if fmt in SIDECAR_FORMATS else None
    want = side is not None and bool(motion.filled.any())
    if side is not None and (want or side.exists() or side.is_symlink()):
        if side.is_dir():
            raise MocapValueError(f"{side}: the filled-flag sidecar path is a directory")
        check_output_path(side, inputs, overwrite=overwrite)
    mod.write(motion, p, **options)
    if want:
        _write_sidecar(motion, side)
    elif side is not None and (side.exists() or side.is_symlink()):
        side.unlink()                   # the stale flags of the file just replaced
    return p
