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

DEFAULT_METHOD = "auto"
DEFAULT_PARAMS: dict = {}
"""Method (and settings) used when none is named for skeleton data: ``auto`` (diagnose,
remove spikes, smooth by the best of GCV spline / MSSA by SURE, fill long gaps by
fill-auto), measured better than the previous default ``kalman-cv`` with ``gate=5`` in the
``auto`` protocol (docs/results/auto.md). Marker captures get ``fill-auto``
(:func:`default_for`)."""


def default(**params):
    """The default method, with ``params`` overriding its default settings."""
    return get(DEFAULT_METHOD, **{**DEFAULT_PARAMS, **params})


def default_for(motion):
    """The method used when none is named, chosen for ``motion``: ``fill-auto`` for marker
    captures (fill the gaps, keep the measured samples), :func:`default` for skeleton data
    (see :func:`mocapkit.denoise.fill_auto.default_for`)."""
    from .fill_auto import default_for as _default_for

    return _default_for(motion)

_FAMILIES = ("filters", "fill", "kalman", "lowrank", "bases", "sparse", "wavelet", "psc", "completion", "neural", "fill_auto",
             "mssa", "auto")


def _import_families() -> None:
    for fam in _FAMILIES:
        try:
            importlib.import_module(f"{__name__}.{fam}")
        except ModuleNotFoundError as e:  # a family not written yet; never hide a real missing import
            if e.name != f"{__name__}.{fam}":
                raise


_import_families()
_load_families = True
