"""Read and write motion files; the format is chosen by extension (overridable).

=========  ==========================  =====================================================
format     extensions                  module
=========  ==========================  =====================================================
bvh        .bvh                        :mod:`mocapkit.io.bvh` (FK; IK on write-back)
amc        .amc (+ .asf skeleton)      :mod:`mocapkit.io.asfamc`
asf        .asf (rest pose, 1 frame)   :mod:`mocapkit.io.asfamc`
c3d        .c3d                        :mod:`mocapkit.io.c3d` (ezc3d)
trc        .trc                        :mod:`mocapkit.io.trc`
kinect     .txt (MSR-Action3D style)   :mod:`mocapkit.io.kinect`
=========  ==========================  =====================================================

Every reader returns a :class:`~mocapkit.motion.Motion` in cm or raises
:class:`~mocapkit.errors.MocapFormatError` naming the file, line and what was expected.
Every writer writes atomically and refuses to overwrite the motion's own source file.
"""
from __future__ import annotations

import importlib
import os
from pathlib import Path
from typing import Any

from ..errors import MocapFormatError, MocapValueError
from ..motion import Motion
from ._atomic import check_output_path

# format -> (module, extensions)
FORMATS: dict[str, tuple[str, tuple[str, ...]]] = {
    "bvh": ("bvh", (".bvh",)),
    "amc": ("asfamc", (".amc",)),
    "asf": ("asfamc", (".asf",)),
    "c3d": ("c3d", (".c3d",)),
    "trc": ("trc", (".trc",)),
    "kinect": ("kinect", (".txt",)),
}
SUPPORTED_EXTENSIONS = tuple(e for _, exts in FORMATS.values() for e in exts)


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
    **options : format-specific options (e.g. ``skeleton=`` for AMC, ``units=`` for BVH).
    """
    p = Path(path)
    fmt = format or detect_format(p)
    if not p.is_file():
        raise MocapFormatError(p, "file not found" if not p.exists() else "not a regular file")
    mod = _module(fmt)
    try:
        return mod.read(p, **options) if fmt != "asf" else mod.read_asf_motion(p, **options)
    except MocapFormatError:
        raise
    except UnicodeDecodeError as e:
        raise MocapFormatError(p, f"not a text {fmt.upper()} file (undecodable byte at offset {e.start})") from None


def write(motion: Motion, path: str | os.PathLike, format: str | None = None, *,
          overwrite: bool = False, **options: Any) -> Path:
    """Write ``motion`` to ``path`` atomically; refuses to overwrite the motion's source file.

    Returns the path written.
    """
    p = Path(path)
    fmt = format or detect_format(p)
    check_output_path(p, (motion.source.get("path"),), overwrite=overwrite)
    mod = _module(fmt)
    if not hasattr(mod, "write"):
        raise MocapValueError(f"writing {fmt} files is not supported")
    mod.write(motion, p, **options)
    return p
