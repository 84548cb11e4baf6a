"""Declarative parameter constraints of the denoisers (scikit-learn's
``_parameter_constraints`` idea, with a vocabulary of our own).

Each :class:`~mocapkit.denoise.base.Denoiser` declares, for every constructor parameter,
the list of constraints a value may satisfy (any one is enough)::

    _parameter_constraints = {
        "sigma_frames": [Interval(Real, 0, None, closed="neither"), None],
        "mode": [Options("odd", "even", "nearest")],
        "robust": [bool],
    }

A constraint is ``None`` (the value None), a type (``bool``: True/False, numpy bools too;
``str``; ``object``: anything) or one of the classes below. The base class checks the
parameters once per entry point (:func:`check` from ``get``, ``set_params``, ``fit`` and
``denoise``) and raises one :class:`~mocapkit.errors.MocapValueError` naming the method, the
parameter, the value and what is allowed. :func:`coerce` is the CLI's conversion of the
values it parses (``3.0`` for an integer parameter, ``2`` for a real one, lists).

One spelling for the options several families share: ``center`` is a string everywhere
(``'none'`` / ``'mean'``, and ``'median'`` in the low-rank family) -- a bool cannot name the
median, and ``'mean'`` says what is subtracted; the random seed is ``seed`` everywhere
(``corrupt``, psc, trnn, tsmc, bra, and xiao-sparse, formerly ``random_state``). Model files
written with the old spellings (the shipped xiao-sparse and lou-chai models among them)
still load: :meth:`~mocapkit.denoise.base.Denoiser._upgrade_params` (:func:`center_as_string`).

Numbers: booleans are never numbers; NaN and infinities are never allowed (no parameter
has a meaning for them). An integral float (``3.0``) satisfies an integer constraint,
as the methods always accepted it (they convert with ``int``).
"""
from __future__ import annotations

import math
from numbers import Integral, Real
from typing import Any, Iterable, Mapping

import numpy as np

from ..errors import MocapValueError

__all__ = ["Interval", "Options", "Odd", "Numbers", "Integral", "Real", "check", "coerce", "describe",
           "center_as_string"]


def _is_number(v: Any) -> bool:
    return isinstance(v, (Real, np.floating, np.integer)) and not isinstance(v, (bool, np.bool_))


def _is_integer(v: Any) -> bool:
    return _is_number(v) and math.isfinite(float(v)) and float(v).is_integer()


class Interval:
    """A number of ``kind`` (``Integral`` or ``Real``) between ``left`` and ``right`` (None:
    unbounded); ``closed`` is "both", "left", "right" or "neither" (which ends belong)."""

    def __init__(self, kind: type, left: float | None, right: float | None, *, closed: str = "both"):
        if kind not in (Integral, Real) or closed not in ("both", "left", "right", "neither"):
            raise TypeError(f"Interval({kind}, closed={closed!r})")
        self.kind, self.left, self.right, self.closed = kind, left, right, closed

    def accepts(self, v: Any) -> bool:
        if not (_is_integer(v) if self.kind is Integral else _is_number(v) and math.isfinite(float(v))):
            return False
        x = float(v)
        if self.left is not None and (x < self.left or (x == self.left and self.closed in ("right", "neither"))):
            return False
        return not (self.right is not None
                    and (x > self.right or (x == self.right and self.closed in ("left", "neither"))))

    def __str__(self) -> str:
        what = "an integer" if self.kind is Integral else "a number"
        lo_in, hi_in = self.closed in ("both", "left"), self.closed in ("both", "right")
        if self.left is None and self.right is None:
            return what
        if self.right is None:
            return f"{what} {'>=' if lo_in else '>'} {self.left:g}"
        if self.left is None:
            return f"{what} {'<=' if hi_in else '<'} {self.right:g}"
        return f"{what} in {'[' if lo_in else '('}{self.left:g}, {self.right:g}{']' if hi_in else ')'}"


class Odd(Interval):
    """An odd integer >= ``minimum`` (a window length in frames with a centre sample)."""

    def __init__(self, minimum: int = 1):
        super().__init__(Integral, minimum, None, closed="left")

    def accepts(self, v: Any) -> bool:
        return super().accepts(v) and int(v) % 2 == 1

    def __str__(self) -> str:
        return f"an odd integer >= {self.left:g} (frames)"


class Options:
    """One of the listed values (compared with ``==``; strings are case-sensitive)."""

    def __init__(self, *values: Any):
        self.values = values

    def accepts(self, v: Any) -> bool:
        same_kind = isinstance(v, str) if isinstance(self.values[0], str) else _is_number(v)
        return same_kind and any(v == x for x in self.values)

    def __str__(self) -> str:
        return "one of " + ", ".join(repr(x) for x in self.values)


class Numbers:
    """A list or tuple of finite numbers (``length`` of them when given)."""

    def __init__(self, length: int | None = None):
        self.length = length

    def accepts(self, v: Any) -> bool:
        return (isinstance(v, (list, tuple)) and all(_is_number(x) and math.isfinite(float(x)) for x in v)
                and (self.length is None or len(v) == self.length))

    def __str__(self) -> str:
        return f"a list of {self.length or ''} numbers".replace("  ", " ")


_TYPE_NAMES = {bool: "true or false", str: "a string", object: "anything"}


def _accepts(c: Any, v: Any) -> bool:
    if c is None:
        return v is None
    if c is bool:
        return isinstance(v, (bool, np.bool_))
    if isinstance(c, type):
        return isinstance(v, c)
    return c.accepts(v)


def _word(c: Any) -> str:
    if c is None:
        return "None"
    return _TYPE_NAMES.get(c, c.__name__) if isinstance(c, type) else str(c)


def describe(constraints: Iterable[Any]) -> str:
    """What ``constraints`` allow, in words ("a number > 0 or None")."""
    return " or ".join(_word(c) for c in constraints)


def check(owner: str, constraints: Mapping[str, list], params: Mapping[str, Any], where: str = "") -> None:
    """Raise MocapValueError for the first parameter of ``params`` no constraint of
    ``constraints[name]`` accepts (names without constraints are not checked)."""
    for k, v in params.items():
        cs = constraints.get(k)
        if cs is None or any(_accepts(c, v) for c in cs):
            continue
        at = f" (checked in {where})" if where else ""
        raise MocapValueError(f"{owner}: parameter {k} must be {describe(cs)}, got {v!r}{at}")


def coerce(constraints: Mapping[str, list], params: Mapping[str, Any]) -> dict[str, Any]:
    """``params`` as the CLI parses them, converted where the constraints say how: an
    integral float for an integer-only parameter becomes an int, an int for a real one a
    float, a list for a list of numbers a tuple of floats. Nothing is checked here."""
    out = dict(params)
    for k, v in params.items():
        cs = constraints.get(k) or []
        kinds = {c.kind for c in cs if isinstance(c, Interval)}
        if kinds == {Integral} and isinstance(v, float) and _is_integer(v):
            out[k] = int(v)
        elif Real in kinds and Integral not in kinds and isinstance(v, int) and not isinstance(v, bool):
            out[k] = float(v)
        elif any(isinstance(c, Numbers) for c in cs) and isinstance(v, list) and all(map(_is_number, v)):
            out[k] = tuple(float(x) for x in v)
    return out


def center_as_string(params: dict[str, Any]) -> dict[str, Any]:
    """Model-file parameters with a boolean ``center`` (lou-chai and xiao-sparse before the
    option took the low-rank family's string spelling) as ``'mean'`` / ``'none'``."""
    c = params.get("center")
    if isinstance(c, (bool, np.bool_)):
        return {**params, "center": "mean" if c else "none"}
    return params
