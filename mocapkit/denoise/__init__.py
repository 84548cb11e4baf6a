"""Denoising, outlier removal and gap filling methods behind one interface.

>>> from mocapkit import denoise
>>> sorted(denoise.available())          # doctest: +SKIP
>>> clean = denoise.get("gaussian", sigma_frames=2).denoise(noisy)   # doctest: +SKIP

One module per family; each registers its classes with ``@register``. The list below
is the only place a family is wired in.
"""
from __future__ import annotations

import importlib

from .base import Denoiser, available, get, register  # noqa: F401

DEFAULT_METHOD = "gaussian"
"""Method used by ``mocapkit denoise`` when none is named (see docs/methods.md)."""

_FAMILIES = ("filters", "kalman", "lowrank", "bases", "sparse", "wavelet", "thesis", "neural")


def _import_families() -> None:
    for fam in _FAMILIES:
        try:
            importlib.import_module(f"{__name__}.{fam}")
        except ModuleNotFoundError as e:  # a family not written yet; never hide a real missing import
            if e.name != f"{__name__}.{fam}":
                raise


_import_families()
_load_families = True
