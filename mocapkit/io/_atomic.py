"""Atomic output: write to a temporary file beside the target, then rename.

A failure midway (exception, interrupt) leaves no partial output and never touches an
existing file at the target path.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable, IO

from ..errors import MocapValueError


def _umask_mode() -> int:
    """Permissions a normally created file gets (mkstemp would make it 0600)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def check_output_path(path: str | os.PathLike, inputs: tuple = (), overwrite: bool = False) -> Path:
    """Refuse to write over an input file (or over any existing file unless ``overwrite``)."""
    p = Path(path)
    for src in inputs:
        if src and Path(src).exists() and p.exists() and os.path.samefile(p, src):
            raise MocapValueError(f"{p}: refusing to overwrite the input file; choose a new output path")
        if src and os.path.abspath(p) == os.path.abspath(src):
            raise MocapValueError(f"{p}: refusing to overwrite the input file; choose a new output path")
    if p.exists() and not overwrite:
        raise MocapValueError(f"{p}: output exists; pass overwrite=True (CLI: --force) to replace it")
    if not p.parent.exists():
        raise MocapValueError(f"{p}: output folder {p.parent} does not exist")
    return p


def _finish(tmp: str, target: Path, body: Callable[[], None]) -> None:
    """Run ``body`` (which fills ``tmp``), then give ``tmp`` normal permissions and rename it
    onto ``target``; on any failure remove ``tmp`` and re-raise."""
    try:
        body()
        os.chmod(tmp, _umask_mode())
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def atomic_write(path: str | os.PathLike, write: Callable[[IO], None], *, binary: bool = False) -> None:
    """Call ``write(f)`` on a temp file in the target folder, fsync, then rename to ``path``."""
    p = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent or ".")

    def body() -> None:
        opts = {} if binary else {"encoding": "utf-8", "newline": "\n"}
        with os.fdopen(fd, "wb" if binary else "w", **opts) as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())

    _finish(tmp, p, body)


def atomic_write_path(path: str | os.PathLike, write_to: Callable[[str], None], suffix: str = "") -> None:
    """Like :func:`atomic_write` for libraries that want a file *name* (e.g. ezc3d)."""
    p = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=suffix or p.suffix, dir=p.parent or ".")
    os.close(fd)

    def body() -> None:
        write_to(tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())

    _finish(tmp, p, body)
