"""The one ``.npz`` layout of every classifier model (skeleton, MiniRocket, NMC).

A JSON ``header`` (format name, version, parameters) plus arrays; the linear read-out that
all three share (feature ``mean`` / ``scale``, ``coef``, ``intercept``, ``classes`` and the
training ``joints``) is written and read here once. No pickle. Each classifier module
registers its header format (:func:`register_format`); :func:`load_model` dispatches on it,
so this module imports none of them.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..errors import MocapFormatError, MocapValueError
from ..motion import Motion

_HEAD = ("mean", "scale", "coef", "intercept")

#: classifier classes by header ``format`` (each has ``from_arrays(header, arrays, path)``)
_FORMATS: dict[str, type] = {}


def register_format(fmt: str, cls: type) -> None:
    """Make :func:`load_model` read files whose header format is ``fmt`` with ``cls``."""
    _FORMATS[fmt] = cls


def load_model(path: str | os.PathLike):
    """The classifier a model file holds: :class:`~mocapkit.recognition.classifier.SkeletonClassifier`,
    :class:`~mocapkit.recognition.rocket.RocketClassifier` or
    :class:`~mocapkit.recognition.nmc.NMCClassifier`; MocapFormatError for anything else."""
    from ..io._npz import read_npz

    p = Path(path)
    header, st = read_npz(p, "classifier model")
    fmt = header.get("format")
    if fmt not in _FORMATS:
        raise MocapFormatError(p, f"not a mocapkit classifier model (it holds a {fmt!r}); "
                                  "train one with 'mocapkit classify train DATA -o MODEL'")
    try:
        return _FORMATS[fmt].from_arrays(header, st, p)
    except MocapFormatError:
        raise
    except Exception as e:
        raise MocapFormatError(p, f"damaged {fmt} model ({type(e).__name__}: {e})") from None


def check_joint_set(joints: Sequence[str], motion: Motion) -> None:
    """Raise MocapValueError when ``motion``'s joint names are not ``joints`` (the training
    skeleton's); an empty ``joints`` (a model file from before joint sets were stored)
    accepts any motion."""
    mine = tuple(str(j) for j in joints)
    if not mine:
        return
    names = tuple(motion.skeleton.names)
    if names != mine:
        src = str(motion.source.get("path", ""))
        raise MocapValueError(
            f"{src + ': ' if src else ''}the model was trained on a {len(mine)}-joint skeleton "
            f"({', '.join(mine[:4])}, ...) but this motion has {len(names)} joints "
            f"({', '.join(names[:4])}, ...); train a model on clips of this skeleton kind "
            "('mocapkit classify train DATA -o MODEL')")


def joint_set_of(motions: Sequence[Motion]) -> tuple[str, ...]:
    """The one joint-name tuple of ``motions``; MocapValueError when they mix skeleton kinds."""
    sets = {m.skeleton.names for m in motions}
    if len(sets) > 1:
        desc = "; ".join(f"{len(s)} joints ({', '.join(s[:3])}, ...)" for s in sorted(sets, key=len))
        raise MocapValueError(f"training motions have {len(sets)} different joint sets ({desc}); "
                              "train one model per skeleton kind")
    return next(iter(sets))


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
