"""Exceptions raised by mocapkit.

Every error a user can cause with bad input is a :class:`MocapError`; the CLI turns
these into one-line messages and exit code 2.
"""
from __future__ import annotations

import os


class MocapError(Exception):
    """Base class of every error mocapkit raises on purpose."""


class MocapFormatError(MocapError, ValueError):
    """A file could not be read (or written) because its content is malformed.

    Parameters
    ----------
    path : file the problem is in.
    message : what was found and what was expected.
    line : 1-based line number for text formats (None when not applicable).
    """

    def __init__(self, path: str | os.PathLike | None, message: str, line: int | None = None):
        self.path = None if path is None else os.fspath(path)
        self.line = line
        self.message = message
        where = self.path or "<input>"
        if line is not None:
            where = f"{where}, line {line}"
        super().__init__(f"{where}: {message}")


class MocapValueError(MocapError, ValueError):
    """An argument (parameter, mask, motion) is invalid for the requested operation."""


class NotFittedError(MocapError, RuntimeError):
    """A data-driven method was used before ``fit`` (or ``load``)."""


class MissingDependencyError(MocapError, ImportError):
    """An optional dependency (e.g. torch for the neural methods) is not installed."""


class MocapWarning(UserWarning):
    """Base class of the warnings mocapkit emits on purpose (the CLI prints them as one line)."""


class ModelMisfitWarning(MocapWarning):
    """A model-based method (low-rank, dynamical) moved some markers' measured samples far
    beyond their noise: its model does not fit them; they were written as measured (see
    :func:`mocapkit.denoise.base.check_model_fit`)."""


class TrainingMismatchWarning(ModelMisfitWarning):
    """A learned model moved some markers' measured samples far beyond their noise: its
    training clips probably do not cover the input's motion; they were written as measured
    (see :func:`mocapkit.denoise.base.check_model_fit`)."""


class MeasuredKeptWarning(MocapWarning):
    """A method moved stretches of measured samples far beyond the noise where the capture
    shows no spike: they were written as measured (see
    :func:`mocapkit.gaps.moved_without_cause`); the message names the method, how many,
    the largest move and where."""


class ConvergenceWarning(MocapWarning):
    """An iterative solver stopped at its iteration cap before meeting its tolerance.

    The result is still returned (finite, usable) but may be less accurate; the message
    names the method, the iterations used, the final residual vs. the tolerance and the
    parameter to raise (usually ``max_iter``).
    """


class HeaderMismatchWarning(MocapWarning):
    """A file's header disagrees with its data (e.g. a TRC ``NumFrames``/``NumMarkers`` or a
    C3D header frame count): the data were read as they are and the message names both
    numbers."""
