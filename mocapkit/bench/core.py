"""Benchmark protocols: registry, result rows, JSON and Markdown output.

A protocol is a function ``f(ctx: Context) -> Iterable[Row]`` registered with
``@protocol(name, description)``. It reads clips from ``ctx.data_dir`` (the shared
data set or a user's copy), corrupts them with seeded corruption, runs methods and
yields one :class:`Row` per (clip, condition, method, metric). ``ctx.quick`` asks for a
reduced run (fewer clips/seeds/frames) that finishes in seconds to a minute; the full
run reproduces the paper's setting.

Output JSON is a list of rows::

    {protocol, clip, condition, method, metric, unit, value, paper_value, seconds, ...}

plus a Markdown table (mean over rows that share clip/condition/method/metric is left
to the protocol: it yields whatever it reports).
"""
from __future__ import annotations

import functools
import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

from ..errors import MocapValueError


@dataclass
class Row:
    """One measured number.

    ``value``/``paper_value`` are in ``unit``; ``seconds`` is the method's wall time for
    this row (denoise only, not corruption or I/O); ``std`` and ``n`` describe repeats
    when ``value`` is a mean.
    """

    protocol: str
    clip: str
    condition: str
    method: str
    metric: str
    unit: str
    value: float
    paper_value: float | None = None
    seconds: float | None = None
    std: float | None = None
    n: int | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        if not d["extra"]:
            d.pop("extra")
        return d


@dataclass
class Context:
    data_dir: Path | None
    quick: bool = False
    seed: int = 0
    progress: bool = True
    options: dict[str, Any] = field(default_factory=dict)

    def need_data(self) -> Path:
        if self.data_dir is None or not Path(self.data_dir).is_dir():
            raise MocapValueError(
                "this protocol needs the mocap data set: pass --data DIR or set MOCAPKIT_DATA "
                "(the repository expects it at ../shared/data)")
        return Path(self.data_dir)


@dataclass
class Protocol:
    """A registered protocol. ``fill_all``: run under :data:`mocapkit.gaps.FILL_ALL` (the
    papers' synthetic protocols score every entry, as the papers do); False runs under
    the user-facing gap policy (real-capture protocols)."""

    name: str
    description: str
    func: Callable[[Context], Iterable[Row]]
    fill_all: bool = True


PROTOCOLS: dict[str, Protocol] = {}


def protocol(name: str, description: str, *, fill_all: bool = True) -> Callable:
    """Decorator registering a protocol function under ``name`` (see :class:`Protocol`).

    The function itself runs under the protocol's gap policy whoever calls it (``run``,
    a benchmark script, a test).
    """

    def deco(func: Callable[[Context], Iterable[Row]]) -> Callable:
        if name in PROTOCOLS:
            raise TypeError(f"protocol {name!r} registered twice")

        @functools.wraps(func)
        def under_policy(ctx: Context) -> list[Row]:
            from ..gaps import DEFAULT_POLICY, FILL_ALL, use_policy

            with use_policy(FILL_ALL if fill_all else DEFAULT_POLICY):
                return list(func(ctx))

        PROTOCOLS[name] = Protocol(name, description, under_policy, fill_all)
        return under_policy

    return deco


def available() -> dict[str, Protocol]:
    from . import protocols  # noqa: F401  (imports every protocol module)

    return dict(sorted(PROTOCOLS.items()))


def run(name: str, ctx: Context) -> list[Row]:
    protos = available()
    if name not in protos:
        raise MocapValueError(f"unknown protocol {name!r}; available: {', '.join(protos)}")
    return list(protos[name].func(ctx))


class Timer:
    """Context manager measuring wall time: ``with Timer() as t: ...; t.seconds``."""

    def __enter__(self) -> "Timer":
        self._t0 = time.perf_counter()
        self.seconds = 0.0
        return self

    def __exit__(self, *exc: object) -> None:
        self.seconds = time.perf_counter() - self._t0


def to_json(rows: Iterable[Row], path: Path) -> None:
    from ..io._atomic import atomic_write

    data = [r.to_dict() for r in rows]
    atomic_write(path, lambda f: json.dump(data, f, indent=1, allow_nan=True))


def to_markdown(rows: list[Row], title: str | None = None) -> str:
    """Markdown table: one line per row, paper value beside ours."""
    lines = []
    if title:
        lines += [f"## {title}", ""]
    lines.append("| clip | condition | method | metric | value | std | paper | unit | s |")
    lines.append("|---|---|---|---|---:|---:|---:|---|---:|")

    def f(x: float | None, nd: int = 4) -> str:
        return "" if x is None else f"{x:.{nd}g}"

    for r in rows:
        lines.append(f"| {r.clip} | {r.condition} | {r.method} | {r.metric} | {f(r.value)} | "
                     f"{f(r.std, 3)} | {f(r.paper_value)} | {r.unit} | {f(r.seconds, 3)} |")
    return "\n".join(lines) + "\n"


def progress(it: Iterable, total: int | None = None, desc: str = "", enable: bool = True) -> Iterator:
    """tqdm progress bar on stderr (disabled when not wanted, and when stderr is not a
    terminal: a log file would fill with carriage-return redraws)."""
    from tqdm import tqdm

    return iter(tqdm(it, total=total, desc=desc, disable=None if enable else True, leave=False))
