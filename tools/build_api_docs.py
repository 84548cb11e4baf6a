"""Write docs/api.md: the API reference, generated from the package's docstrings.

Run: .venv/bin/python tools/build_api_docs.py
Covers the public modules, their public functions/classes (signature + docstring) and
every registered method with its parameters and defaults.
"""
from __future__ import annotations

import importlib
import inspect
from pathlib import Path

MODULES = ["mocapkit.motion", "mocapkit.skeleton", "mocapkit.frames", "mocapkit.io", "mocapkit.corrupt", "mocapkit.metrics",
           "mocapkit.signal", "mocapkit.signal.filters", "mocapkit.signal.noise",
           "mocapkit.signal.statespace", "mocapkit.signal.rts", "mocapkit.gaps", "mocapkit.windows",
           "mocapkit.detect", "mocapkit.denoise.base", "mocapkit.denoise.constraints", "mocapkit.batch",
           "mocapkit.bench.core", "mocapkit.viz.report", "mocapkit.viz.plots", "mocapkit.datasets",
           "mocapkit.retrieval", "mocapkit.recognition", "mocapkit.diagnose", "mocapkit.shipped",
           "mocapkit.solvers.info", "mocapkit.solvers.gcv_spline", "mocapkit.solvers.mssa"]


def _doc(obj) -> str:
    return inspect.cleandoc(obj.__doc__ or "").strip()


def main() -> None:
    out = ["# mocapkit API reference", "",
           "Generated from docstrings by `tools/build_api_docs.py`; positions are in cm.", ""]
    for name in MODULES:
        try:
            mod = importlib.import_module(name)
        except ImportError:
            continue
        out += [f"## `{name}`", "", _doc(mod), ""]
        for attr, obj in sorted(vars(mod).items()):
            if attr.startswith("_") or getattr(obj, "__module__", None) != name:
                continue
            if inspect.isfunction(obj) or inspect.isclass(obj):
                try:
                    sig = str(inspect.signature(obj))
                except (TypeError, ValueError):
                    sig = "(...)"
                kind = "class" if inspect.isclass(obj) else "def"
                out += [f"### `{kind} {attr}{sig}`", "", _doc(obj), ""]
    from mocapkit import denoise

    out += ["## Registered methods (`mocapkit.denoise.get(name, **params)`)", ""]
    for mname, cls in denoise.available().items():
        sig = inspect.signature(cls.__init__)
        params = ", ".join(f"`{p.name}={p.default!r}`" for p in sig.parameters.values()
                           if p.name != "self" and p.default is not inspect.Parameter.empty)
        out += [f"### `{mname}` ({cls.__module__}.{cls.__name__})", "",
                f"{cls.description}  ", f"training: {'yes' if cls.needs_training else 'no'}; "
                f"keeps observed entries: {'yes' if cls.keeps_observed else 'no'}  ",
                f"parameters: {params or 'none'}", "", _doc(cls), ""]
    Path(__file__).resolve().parent.parent.joinpath("docs", "api.md").write_text("\n".join(out) + "\n")


if __name__ == "__main__":
    main()
