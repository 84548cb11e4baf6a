"""scikit-learn-style estimator parameters: ``__init__`` stores, nothing else.

One place for the rule every estimator of the package follows (denoisers, retrieval
models, action classifiers): the constructor's parameters are stored under their own
names, so ``get_params`` (read from the signature) and saved models round-trip exactly.

>>> class Model:
...     def __init__(self, k: int = 5, levels=(1, 2)):
...         store_params(self, locals(), tuples=("levels",))
>>> m = Model(levels=[1, 2, 4])
>>> m.k, m.levels, init_param_names(Model)
(5, (1, 2, 4), ['k', 'levels'])
"""
from __future__ import annotations

import inspect
from typing import Any, Iterable

__all__ = ["init_param_names", "store_params"]


def init_param_names(cls: type) -> list[str]:
    """Names of ``cls.__init__``'s parameters (positional-or-keyword and keyword-only)."""
    sig = inspect.signature(cls.__init__)
    return [p.name for p in sig.parameters.values()
            if p.name != "self" and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]


def store_params(obj: Any, values: dict[str, Any], *, tuples: Iterable[str] = ()) -> None:
    """Set every ``__init__`` parameter of ``type(obj)`` from ``values`` (pass ``locals()``);
    parameters named in ``tuples`` are stored as tuples (sequences given as lists stay
    hashable and compare equal after a save/load)."""
    as_tuple = set(tuples)
    for name in init_param_names(type(obj)):
        v = values[name]
        setattr(obj, name, tuple(v) if name in as_tuple else v)
