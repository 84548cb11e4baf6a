"""Denoising, outlier removal and gap filling methods behind one interface.

Examples
--------
>>> from mocapkit import corrupt, datasets, denoise, io, metrics
>>> "kalman-cv" in denoise.available() and "auto" in denoise.available()
True
>>> clip = io.read(datasets.bundled("16_15.amc")).slice(120, 360)
>>> noisy, _ = corrupt.combine(clip, "gaussian:sigma_cm=2", seed=0)
>>> out = denoise.get("gaussian", sigma_frames=2).denoise(noisy)
>>> round(metrics.rmse(clip, noisy), 1), metrics.rmse(clip, out) < metrics.rmse(clip, noisy)   # cm
(2.0, True)
>>> denoise.get("gaussian", sigma_frames=-1)
Traceback (most recent call last):
    ...
mocapkit.errors.MocapValueError: gaussian: parameter sigma_frames must be a number > 0 or None, got -1 (checked in get())

One module per family; each registers its classes with ``@register``. The list below
is the only place a family is wired in. The registry is the only place callers (CLI,
batch, benchmarks) learn about a method: its parameters and what they allow
(``_parameter_constraints``, :mod:`mocapkit.denoise.constraints`), its model file formats
(:func:`~mocapkit.denoise.base.register_model_format`) and its trainer
(:meth:`~mocapkit.denoise.base.Denoiser.train_files`).
"""
from __future__ import annotations

import importlib

from .base import Denoiser, available, get, register  # noqa: F401

DEFAULT_METHOD = "auto"
DEFAULT_PARAMS: dict = {}
"""Method (and settings) used when none is named: ``auto`` (diagnose, remove spikes, smooth
by GCV spline / MSSA / Kalman mixed by SURE weights, fill long gaps by fill-auto), measured
better than the previous default ``kalman-cv`` with ``gate=5`` in the ``auto`` protocol
(docs/results/auto.md). For marker captures too (since 2026-12-05; ``fill-auto`` before,
which fills gaps and leaves noise and spikes as they are): on a clean capture ``auto`` keeps
the measured samples and hands gaps of 3 frames and more to fill-auto
(:func:`is_marker_capture`, ``auto.MARKER_SHORT_FRAMES``)."""


def default(**params):
    """The default method, with ``params`` overriding its default settings."""
    return get(DEFAULT_METHOD, **{**DEFAULT_PARAMS, **params})


def is_marker_capture(motion) -> bool:
    """A marker capture: points with no joint hierarchy (read from C3D / TRC, or more than
    one point built so). A C3D that carries the joint hierarchy mocapkit writes
    (:mod:`mocapkit.io.c3d`) holds joint centres, not markers."""
    return motion.skeleton.is_flat and (motion.source.get("format") in ("c3d", "trc") or motion.n_joints > 1)



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
