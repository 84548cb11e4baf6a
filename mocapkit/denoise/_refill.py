"""What the thesis' refinement methods share (Z. Wang 2017, seed 003): which samples they
trust, how a (T, 3J) estimate becomes the output Motion, the guard against an ALM iterate
stopped far from the data, and the solver report.

Used by :mod:`mocapkit.denoise.psc` (Ch. 3) and :mod:`mocapkit.denoise.completion` (Ch. 4).
"""
from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from .. import gaps
from ..detect import trust_data
from ..errors import MocapValueError
from ..motion import Motion
from ..solvers.evidence import far_from_data
from ..solvers.info import SolveInfo
from .base import Denoiser, report_convergence


def check_motion(motion: Motion, method: str) -> Motion:
    """``motion`` if it has an observed sample (the base class already checked the type)."""
    if not motion.observed.any():
        raise MocapValueError(f"{method}: the motion has no observed entries")
    return motion


def known_mask(motion: Motion, detect: bool, threshold_cm: float) -> np.ndarray:
    """(T, J) samples the method may trust: observed, minus TDD outliers when ``detect``."""
    known = motion.observed.copy()
    if detect:
        known &= ~trust_data(motion, threshold_cm)
        if not known.any():
            known = motion.observed.copy()
    return known



def output(motion: Motion, A: np.ndarray, known: np.ndarray, keep: bool,
            solver: dict[str, Any]) -> Motion:
    """Motion from a (T, 3J) estimate; ``keep``: trusted observed entries unchanged."""
    X = motion.matrix(copy=False)                   # read only
    km = np.repeat(known, 3, axis=1)
    if not np.isfinite(A).all():                    # defensive: never return NaN
        lin = gaps.fill(X, km, never_observed=0.0)
        bad = ~np.isfinite(A)
        A[bad] = lin[bad]
    if keep:
        A[km] = X[km]
    out = motion.with_matrix(A, handover=True)      # A is the caller's to give: no copy
    return out.with_source(solver=solver)


def unusable_guard(method: str, A: np.ndarray, X: np.ndarray, km: np.ndarray,
                    lin: np.ndarray, info: SolveInfo) -> tuple[np.ndarray, SolveInfo]:
    """Replace a stopped-early ALM iterate that is nowhere near the data.

    The thesis' ALM starts with a tiny penalty (eta0 = 1e-5) and its iterates only approach
    the data as the penalty grows: after 1-10 iterations A B^T is ~0, every marker near
    the origin (80 cm RMSE on a CMU walk), which the gap policy cannot catch on measured
    samples.  When the solver did not converge and the estimate is far from the measured
    samples (:func:`mocapkit.solvers.evidence.far_from_data`), the measured samples are
    kept and the gaps linearly interpolated, with a :class:`~mocapkit.errors.MocapWarning`
    (the returned info then has ``extra["fallback"] = "linear"``).
    """
    far, resid, spread = far_from_data(A, X, km)
    if far:
        _warn_unusable(method, int(info.n_iter), resid, spread)
        A = np.where(km, X, lin)
        info = dataclasses.replace(info, extra={**info.extra, "fallback": "linear"})
    return A, info


def _warn_unusable(method: str, iterations: int, resid: float, spread: float) -> None:
    import warnings

    from ..errors import MocapWarning

    warnings.warn(f"{method}: stopped after {iterations} iterations far from the data (RMS "
                  f"{resid:.3g} cm from the measured samples, whose spread is {spread:.3g} cm): "
                  f"measured samples kept, gaps interpolated linearly; raise max_iter",
                  MocapWarning, stacklevel=5)


def record(den: Denoiser, info: SolveInfo) -> None:
    """Record the convergence summary of ``den``'s run (the result's
    ``source["convergence"]``) from the solver's report (the solver itself already warned)."""
    report_convergence(den, info, tol=float(den.tol), max_iter=int(den.max_iter), warn=False)


def solver_info(name: str, info: SolveInfo) -> dict[str, Any]:
    """``source["solver"]`` of the output: the method, ``n_iter``, ``converged``,
    ``residual``, ``criterion`` and the scalar extras of the solver's report."""
    fields = {"n_iter": info.n_iter, "converged": info.converged, "residual": info.residual,
              "criterion": info.criterion, **info.extra}
    return {"method": name, **{k: (v.item() if isinstance(v, np.generic) else v)
                               for k, v in fields.items() if np.isscalar(v)}}
