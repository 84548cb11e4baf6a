"""The one ``.npz`` layout of every classifier model (skeleton, MiniRocket, NMC).

A JSON ``header`` (format name, version, parameters) plus arrays; the linear read-out that
all three share (feature ``mean`` / ``scale``, ``coef``, ``intercept``, ``classes`` and the
training ``joints``) is written and read here once. No pickle.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import MocapFormatError

_HEAD = ("mean", "scale", "coef", "intercept")


def write_model(model: Any, path: str | os.PathLike, header: dict, arrays: dict | None = None, *,
                overwrite: bool = False) -> Path:
    """Write ``header`` + the model's linear read-out + extra ``arrays`` atomically; refuses
    to overwrite unless ``overwrite`` (and never an input, see ``check_output_path``)."""
    from ..io._atomic import atomic_write, check_output_path

    p = check_output_path(path, overwrite=overwrite)
    out = dict(header=np.array(json.dumps(header)),
               classes=np.array(model.classes_, dtype=str),
               joints=np.array(getattr(model, "joints_", []), dtype=str),
               **{k: getattr(model, f"{k}_") for k in _HEAD}, **(arrays or {}))
    atomic_write(p, lambda f: np.savez(f, **out), binary=True)
    return p


def read_head(model: Any, header: dict, st: dict, path, version: int) -> Any:
    """Check the header's version and set the linear read-out on ``model``; returns it."""
    if header.get("version") != version:
        raise MocapFormatError(path, f"classifier format {header.get('format')} v{header.get('version')} "
                                     f"is not supported (expected v{version})")
    for k in _HEAD:
        setattr(model, f"{k}_", st[k])
    model.classes_ = st["classes"].astype(str)
    model.joints_ = st["joints"].astype(str) if "joints" in st else np.array([], dtype=str)
    return model
