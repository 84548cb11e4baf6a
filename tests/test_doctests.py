"""Every ``>>>`` example in the package runs and prints what its docstring says.

The public entry points carry numpydoc ``Examples`` (``io.read``/``io.write``,
``denoise.get(...).denoise``, ``corrupt.combine``, ``metrics.rmse``, one solver per
family); this collects every module's doctests so an example that drifts from the code
fails the suite. ``# doctest: +SKIP`` marks the few that need data outside the package.
"""
from __future__ import annotations

import doctest
import importlib
import pkgutil
import warnings

import numpy as np
import pytest

import mocapkit

MODULES = sorted(m.name for m in pkgutil.walk_packages(mocapkit.__path__, "mocapkit.")
                 if not m.name.endswith("__main__"))

# public entry points that must carry at least one runnable example
MUST_HAVE = ("mocapkit.corrupt", "mocapkit.metrics", "mocapkit.denoise", "mocapkit.io",
             "mocapkit.solvers.info", "mocapkit.solvers.lowrank", "mocapkit.solvers.completion",
             "mocapkit.solvers.sparse_coding", "mocapkit.solvers.robust_bases", "mocapkit.signal.filters",
             "mocapkit.gaps", "mocapkit.windows", "mocapkit.frames")


def _examples(module) -> int:
    finder = doctest.DocTestFinder(exclude_empty=True)
    return sum(len(t.examples) for t in finder.find(module))


@pytest.mark.parametrize("name", MODULES)
def test_module_examples_run(name):
    module = importlib.import_module(name)
    opts = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE
    with warnings.catch_warnings(), np.printoptions(legacy=False):
        warnings.simplefilter("ignore")
        result = doctest.testmod(module, optionflags=opts, report=True, verbose=False)
    assert result.failed == 0, f"{result.failed} doctest example(s) of {name} failed (output above)"


@pytest.mark.parametrize("name", MUST_HAVE)
def test_entry_points_have_examples(name):
    assert _examples(importlib.import_module(name)) > 0, f"{name} has no runnable example"
