"""Neural motion refinement: BRA and BRA-P (Li et al. 2020, seed 002).

Modules
-------
:mod:`~mocapkit.neural.clips`   clip preparation (numpy only): the 21-joint CMU subset,
                                root-local ground coordinates, 120-frame clips with
                                linear cross-fade reassembly, joints outside the subset.
:mod:`~mocapkit.neural.model`   the motion autoencoder of eqs. (1)-(2) (torch).
:mod:`~mocapkit.neural.losses`  losses of eqs. (3)-(7) (torch).
:mod:`~mocapkit.neural.train`   the two-stage trainer, checkpoints, ``train_cli`` (torch).

Inference runs the shipped ONNX networks (``pretrained/<method>.onnx``) with onnxruntime,
a core dependency, so ``--method bra-p`` works without torch. torch is an optional
dependency (``pip install mocapkit[neural]``) needed only to train, to use ``.pt`` models
and to export ONNX; everything that needs it imports it lazily and raises
:class:`~mocapkit.errors.MissingDependencyError` when it is absent.
The Denoisers ``bra`` and ``bra-p`` live in :mod:`mocapkit.denoise.neural`.
"""
from __future__ import annotations

from pathlib import Path

from ..errors import MissingDependencyError

PRETRAINED_DIR = Path(__file__).parent / "pretrained"

INSTALL_HINT = "pip install mocapkit[neural]"


def require_torch():
    """Import and return torch, or raise MissingDependencyError with install advice."""
    try:
        import torch  # noqa: F401
    except ImportError:
        raise MissingDependencyError(
            "the neural methods (bra, bra-p) need PyTorch, which is not installed: "
            f"{INSTALL_HINT} (prefer a CPU build of torch 2.13.0)") from None
    return torch


def pretrained_path(method: str = "bra-p") -> Path:
    """Path of the ONNX model shipped for ``method`` (may not exist)."""
    return PRETRAINED_DIR / f"{method}.onnx"
