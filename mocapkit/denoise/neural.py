"""Neural refinement: BRA and BRA-P (Li et al. 2020, seed 002; torch, optional).

``bra-p``
    Li, Zhu, Zheng & Li 2020, "A perceptual-based noise-agnostic 3D skeleton motion data
    refinement network" (IEEE Access 8). A perceptual autoencoder (E_p, D_p), eqs.
    (1)-(2), trained on clean clips with eq. (8); then a denoising autoencoder
    (E_d, D_d) trained on the mixed-noise set DS_syn with eq. (9): reproduction (3),
    smoothness (5)-(6), bone length (7) and perceptual (4) losses. At run time the
    output is ``Y_R = D_p(E_p(D_d(E_d(X_N))))`` (``postprocess=True``; False gives the
    BRA-P-D ablation of Table 2).
``bra``
    Li et al. 2019 (the paper's [13]; Table 2 row BRA(512)): the denoising autoencoder
    alone, trained with eq. (9) without the perceptual term.

Other Table 2 ablations are training options: EBD = ``bra`` with
``train_options={"lambdas_denoise": (1, 0, 0, 0)}``; EBD-P = ``bra-p`` with
``train_options={"lambdas_denoise": (1, 0, 0, 10)}``; BRA-P(256) = ``hidden=256``.

Data handling (``mocapkit.neural.clips``): 60 fps, the 21-joint CMU subset, root-local
ground frame, mean/std normalisation, 120-frame clips overlapping by 60 with a linear
cross-fade; the output has the input's skeleton, frames and fps, joints outside the
subset are the input's own GCV-smoothed tracks where it observes them, else carried by
their nearest refined ancestor (:func:`mocapkit.neural.clips.attach_dropped`). A motion whose skeleton lacks
one of the 21 joints is refused with a MocapValueError naming them.

Without a trained model, ``bra-p`` and ``bra`` load the ONNX networks shipped in
``mocapkit/neural/pretrained/`` and run them with onnxruntime (no torch needed; trained
by ``benchmarks/train_neural.py``, measured in ``docs/results/bra.md``), so they need no
training step. ``fit(motions)`` trains a new model on clean motions with torch
(defaults: the shipped models' settings, :data:`mocapkit.neural.train.OPERATING_POINT`
-- residual output on the input's GCV smoothing spline, bridged + masked input,
augmentation, cosine learning rate -- and the paper's 300 epochs per network: hours on
a CPU; ``train_options=dict(residual=False, fill_input=False, mask_input=False,
base_sigma=0, augment=False, lr_schedule='constant', grad_clip=0, reproduction='mse')``
is the paper's original network). ``train_options`` holds every other
:class:`~mocapkit.neural.train.TrainConfig` field (dropout, batch size, loss weights,
learning rates and schedule, input handling, augmentation), taken over
:data:`~mocapkit.neural.train.OPERATING_POINT`; the constructor keeps what a user sets
for a run (model, post-processing, width, training length, seed, threads, device).

``postprocess=None`` uses the model's own setting: the shipped bra-p skips the
perceptual post-processing D_p(E_p(.)) (measured: it adds the perceptual autoencoder's
reconstruction error, docs/results/bra.md), i.e. it is Table 2's BRA-P-D trained with the
perceptual loss; ``postprocess=True`` applies it. ``turns`` (default 1): the network's
output is averaged over that many rotations of the clip about the vertical
(:meth:`mocapkit.neural.bundle.Bundle.run_turned`; networks trained with rotation
augmentation only); ``turns=4`` measured 1 % lower error on the held-out subjects at 4x
the network time (docs/results/bra.md), so one pass is the default. ``constant_bones`` (default
True): the network's bones are set to their median length over the clip
(:func:`mocapkit.neural.clips.project_bones`; skeleton bones are rigid, the network's
residual error stretches them frame by frame).

Guard rails: inputs outside 24-1000 fps, without the 21 joints, or with a body far from
the training bodies' size get one MocapValueError; the markers a result moves beyond the
input's estimated noise are written as measured, with a TrainingMismatchWarning
(:func:`mocapkit.denoise.base.check_model_fit`, recorded in the result's ``source["model_fit"]``).

``threads``: torch threads for training (None: every core this process may use) and
threads for inference (None: 1).

Models are ``.onnx`` (inference only) or ``.pt`` (torch; trainable, resumable) files
(:mod:`mocapkit.neural.bundle`), not ``.npz``; ``save('x.onnx')`` exports (needs torch
and onnx). Without torch, training and ``.pt`` models raise MissingDependencyError
("pip install mocapkit[neural]").
"""
from __future__ import annotations

import os
from typing import Any, Sequence

from ..errors import MocapFormatError, MocapValueError
from ..motion import Motion
from ..neural import pretrained_path, require_torch
from .base import Denoiser, register, register_model_format
from . import constraints
from .constraints import Integral, Interval, Numbers, Options, Real
from ..neural.clips import BASE_FILTERS

_POSITIVE = Interval(Real, 0, None, closed="neither")

#: constructor parameters that choose how a trained model runs (not training settings):
#: every other parameter is a :class:`mocapkit.neural.train.TrainConfig` field
_RUN_PARAMS = ("model", "postprocess", "turns", "constant_bones", "progress", "warn", "train_options")
#: the TrainConfig fields that were constructor parameters before ``train_options`` (model
#: files store them flat in their ``denoiser_params``)
_GROUPED = ("dropout", "batch_size", "lambdas_perceptual", "lambdas_denoise", "lr_perceptual", "lr_denoise",
            "random_offsets", "residual", "fill_input", "mask_input", "augment", "lr_schedule",
            "base_sigma", "base_filter", "grad_clip", "reproduction", "wide_fc")


class _NeuralDenoiser(Denoiser):
    """Shared implementation of ``bra`` and ``bra-p`` (see the module docstring)."""

    keeps_observed = False
    misfit_check = "learned"
    fill_evidence = "markers"
    clean_tolerance_cm = 6.0
    _perceptual: bool = True
    training_side_files = (".ckpt",)        # the trainer's checkpoint, next to the model

    _parameter_constraints = {
        "model": [str, os.PathLike, None], "postprocess": [bool, None], "turns": [Interval(Integral, 1, None)],
        "constant_bones": [bool],
        "hidden": [Interval(Integral, 1, None)],
        "epochs_perceptual": [Interval(Real, 0, None)], "epochs_denoise": [Interval(Real, 0, None)],
        "steps_perceptual": [Interval(Integral, 0, None), None],
        "steps_denoise": [Interval(Integral, 0, None), None],
        "seed": [Interval(Integral, 0, None)], "threads": [Interval(Integral, 1, None), None],
        "device": [str], "progress": [bool], "warn": [bool],
        "train_options": [dict, None],          # field names checked by TrainConfig.from_params
    }
    #: the TrainConfig fields :meth:`train_files` also checks (given flat to the trainer,
    #: ``mocapkit train --param``; the other fields are checked by TrainConfig.from_params)
    _training_constraints = {
        "dropout": [Interval(Real, 0, 1, closed="left")], "batch_size": [Interval(Integral, 1, None)],
        "lambdas_perceptual": [Numbers(3)], "lambdas_denoise": [Numbers(4)],
        "lr_perceptual": [_POSITIVE], "lr_denoise": [_POSITIVE],
        "base_sigma": [Interval(Real, 0, None)], "grad_clip": [Interval(Real, 0, None)],
        "base_filter": [Options(*BASE_FILTERS)],
        **{k: [bool] for k in ("random_offsets", "residual", "fill_input", "mask_input", "augment", "wide_fc")},
    }

    @classmethod
    def _upgrade_params(cls, params: dict[str, Any]) -> dict[str, Any]:
        """Model files store the training options flat (the constructor's old spelling)."""
        p = dict(params)
        grouped = {k: p.pop(k) for k in _GROUPED if k in p}
        if grouped:
            p["train_options"] = {**(p.get("train_options") or {}), **grouped}
        return {k: v for k, v in p.items() if k in cls._param_names()}

    def __init__(self, *, model: str | None = None, postprocess: bool | None = None, turns: int = 1,
                 constant_bones: bool = True, hidden: int = 256,
                 epochs_perceptual: float = 300.0, epochs_denoise: float = 300.0,
                 steps_perceptual: int | None = None, steps_denoise: int | None = None,
                 seed: int = 0, threads: int | None = None, device: str = "cpu", progress: bool = False,
                 warn: bool = True, train_options: dict[str, Any] | None = None):
        self._store_params(locals())

    @classmethod
    def quick_params(cls) -> dict[str, Any]:
        return {"hidden": 16, "steps_perceptual": 2, "steps_denoise": 2, "threads": 1}

    # -- model ------------------------------------------------------------------------------
    def is_fitted(self) -> bool:
        return (getattr(self, "bundle_", None) is not None or bool(self.model)
                or pretrained_path(self.name).is_file())

    def _bundle(self):
        b = getattr(self, "bundle_", None)
        if b is not None:
            return b
        from ..neural.bundle import Bundle

        path = self.model or pretrained_path(self.name)
        if not self.model and not os.path.isfile(path):
            self._check_fitted()
            raise MocapValueError(f"no shipped checkpoint for {self.name!r} at {path}; train one "
                                  f"(mocapkit train --method {self.name} ...)")
        b = Bundle.load(path)
        if b.meta.get("method") != self.name:
            raise MocapFormatError(path, f"model is for method {b.meta.get('method')!r}, not {self.name!r}")
        if not b.same_topology:
            raise MocapValueError(f"{path}: a different-topology model ({len(b.joints_in)} -> "
                                  f"{len(b.joints_out)} joints) cannot be a Denoiser; use "
                                  f"mocapkit.neural.bundle.Bundle.refine")
        self.bundle_ = b
        return b

    def _config(self):
        from ..neural.train import TrainConfig

        from ..neural.train import OPERATING_POINT

        p = {**OPERATING_POINT, **(self.train_options or {}),
             **{k: v for k, v in self.get_params().items() if k not in _RUN_PARAMS}}
        if not p["residual"] and "noise" not in (self.train_options or {}):
            del p["noise"]                  # the paper's noise mix for the paper's network
        post = False if self.postprocess is None else bool(self.postprocess)
        return TrainConfig.from_params(perceptual=self._perceptual, postprocess=post and self._perceptual, **p)

    def fit(self, motions: Sequence[Motion]) -> "_NeuralDenoiser":
        """Train on clean motions (each with the 21 CMU joints; any fps) with DS_syn noise."""
        require_torch()
        from ..neural.train import train_motions

        motions = list(motions)
        if not motions:
            raise MocapValueError("fit() needs at least one training motion")
        self.bundle_ = train_motions(motions, self._config(), progress=bool(self.progress))
        self.bundle_.meta["method"] = self.name
        return self

    def denoise(self, motion: Motion) -> Motion:
        b = self._bundle()
        post = None if self.postprocess is None else (bool(self.postprocess) and self._perceptual)
        out = b.refine(motion, postprocess=post, threads=self.threads, turns=int(self.turns),
                       constant_bones=bool(self.constant_bones))
        return out  # checked by the guard (check_model_fit included)

    # -- persistence ------------------------------------------------------------------------
    def save(self, path: str | os.PathLike, *, half: bool = False) -> None:
        """Write the model as ``.pt`` or ``.onnx`` (:mod:`mocapkit.neural.bundle` format)."""
        b = self._bundle()
        b.meta["method"] = self.name
        b.meta["denoiser_params"] = {k: v for k, v in self.get_params().items() if k not in ("model",)}
        b.save(path, half=half)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "_NeuralDenoiser":
        return load_model(path, cls)

    @classmethod
    def train_files(cls, sources, output, *, params, resume, progress, exclude) -> bool:
        """Train with :func:`mocapkit.neural.train.train_cli` (progress bar, checkpoint
        ``output + '.ckpt'``, resume); ``params`` are TrainConfig fields, those that are
        also parameters of this method checked against its constraints."""
        from ..neural.train import train_cli

        constraints.check(cls.name, {**cls._parameter_constraints, **cls._training_constraints}, params, "train")
        train_cli(sources if len(sources) > 1 else sources[0], output, method=cls.name,
                  resume=resume, progress=progress, exclude=exclude, **params)
        return True


def load_model(path: str | os.PathLike, cls: type | None = None) -> "_NeuralDenoiser":
    """Load a ``.onnx`` / ``.pt`` model written by ``bra`` / ``bra-p`` (``save``, ``train_cli``)."""
    from ..neural.bundle import Bundle

    b = Bundle.load(path)
    method = b.meta.get("method")
    target = {"bra-p": BRAP, "bra": BRA}.get(method)
    if target is None:
        raise MocapFormatError(path, f"model is for unknown method {method!r}")
    if cls is not None and cls is not Denoiser and not issubclass(target, cls):
        raise MocapFormatError(path, f"model is for method {method!r}, not {getattr(cls, 'name', cls)!r}")
    params = target._upgrade_params(b.meta.get("denoiser_params", {}))
    if not params:   # written by train_cli: take the training configuration
        tp = b.meta.get("params", {})
        params = target._upgrade_params({k: tp[k] for k in (*target._param_names(), *_GROUPED)
                                         if k in tp and k not in _RUN_PARAMS})
        params["postprocess"] = None
    obj = target(**params)
    obj.model = os.fspath(path)
    obj.bundle_ = b
    return obj


register_model_format((".pt", ".onnx"), load_model)


@register
class BRAP(_NeuralDenoiser):
    """BRA-P (Li et al. 2020): denoising BiLSTM autoencoder + perceptual loss + perceptual
    post-processing; eqs. (1)-(9). Parameters: see the module docstring and
    :class:`mocapkit.neural.train.TrainConfig` (paper defaults)."""

    name = "bra-p"
    description = ("BRA-P BiLSTM autoencoder with perceptual loss and perceptual post-processing "
                   "(Li et al. 2020; shipped ONNX model, onnxruntime)")
    needs_training = not pretrained_path("bra-p").is_file()
    _perceptual = True


@register
class BRA(_NeuralDenoiser):
    """BRA (Li et al. 2019, Table 2 of Li et al. 2020): the denoising BiLSTM autoencoder
    with smoothness and bone-length losses, no perceptual term. ``postprocess`` is ignored."""

    name = "bra"
    description = ("BRA BiLSTM denoising autoencoder with smoothness and bone-length losses "
                   "(Li et al. 2019; shipped ONNX model, onnxruntime)")
    needs_training = not pretrained_path("bra").is_file()
    _perceptual = False
