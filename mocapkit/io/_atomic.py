"""Atomic output: write to a temporary file beside the target, then rename.

A failure midway (exception, interrupt) leaves no partial output and never touches an
existing file at the target path.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import IO, Callable, Iterable

from ..errors import MocapValueError


def _umask_mode() -> int:
    """Permissions a normally created file gets (mkstemp would make it 0600)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def _same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether two paths name one file (same spelling after normalisation, same target of
    symbolic links, or the same inode: hard links, case-insensitive file systems)."""
    if os.path.abspath(a) == os.path.abspath(b) or os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _inside(path: str | os.PathLike, tree: str | os.PathLike) -> bool:
    """Whether ``path`` is ``tree`` or lies below it (symbolic links resolved)."""
    p, t = os.path.realpath(path), os.path.realpath(tree)
    return p == t or p.startswith(t.rstrip(os.sep) + os.sep)


def check_output_path(path: str | os.PathLike, inputs: Iterable = (), overwrite: bool = False, *,
                      input_trees: Iterable = (), claimed: Iterable = ()) -> Path:
    """The one rule for every file mocapkit writes; returns ``Path(path)`` or raises
    :class:`MocapValueError` with a one-line reason.

    An output path is refused when it

    * is a folder (or ends with a path separator), or exists and is not a regular file;
    * names one of ``inputs`` (the files the command reads: motions, the ASF skeletons
      they resolve to, training clips, models, masks), however spelled (relative,
      ``..``, symbolic or hard link);
    * lies inside one of ``input_trees`` (folders the command reads recursively, e.g.
      a batch's input folder);
    * names one of ``claimed`` (the other outputs of the same command: motion, mask,
      skeleton companion, checkpoint...);
    * exists and ``overwrite`` is false (CLI: ``--force`` replaces an existing regular
      file the command would produce, never one of the above);
    * is in a folder that does not exist.
    """
    p = Path(path)
    text = os.fspath(path)
    if not text or text.endswith(("/", os.sep)) or p.is_dir():
        raise MocapValueError(f"{text or '(empty)'}: is a folder; give an output file name")
    exists = os.path.lexists(p)
    if exists and p.exists() and not p.is_file():
        raise MocapValueError(f"{p}: exists and is not a regular file; refusing to replace it")
    for src in inputs:
        if src and _same_file(p, src):
            raise MocapValueError(f"{p}: refusing to overwrite the input file {src}; choose a new output path")
    for tree in input_trees:
        if tree and _inside(p, tree):
            raise MocapValueError(f"{p}: refusing to write inside the input folder {tree}; "
                                  f"choose an output outside it")
    for other in claimed:
        if other and _same_file(p, other):
            raise MocapValueError(f"{p}: this command already writes another output to this path; "
                                  f"give each output its own file name")
    if exists and not overwrite:
        raise MocapValueError(f"{p}: output exists; pass overwrite=True (CLI: --force) to replace it")
    parent = p.parent
    if not parent.exists():
        raise MocapValueError(f"{p}: output folder {parent} does not exist")
    if not parent.is_dir():
        raise MocapValueError(f"{p}: {parent} is not a folder")
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
