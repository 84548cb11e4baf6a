"""The one report every iterative solver returns: :class:`SolveInfo`.

Every iterative solver of :mod:`mocapkit.solvers` (IALM, ADMM, ALM, EM, K-SVD, ...) that
is asked for its diagnostics returns one ``SolveInfo`` -- never a dict with its own key
names -- so a caller reads ``info.n_iter`` / ``info.converged`` / ``info.residual``
whatever the solver, and :func:`mocapkit.denoise.base.report_convergence` turns any of
them into the method's convergence summary and the one warning.

>>> from mocapkit.solvers.info import SolveInfo
>>> info = SolveInfo(n_iter=12, converged=True, residual=3.2e-8,
...                  criterion="max relative residual", extra={"rank": 4})
>>> info.n_iter, info.converged, info.extra["rank"]
(12, True, 4)
>>> info.as_dict()["criterion"]
'max relative residual'
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ..errors import ConvergenceWarning

__all__ = ["SolveInfo", "warn_not_converged"]


@dataclass(frozen=True)
class SolveInfo:
    """How an iterative solve ended.

    Parameters
    ----------
    n_iter : iterations run (for several independent solves -- SLRA segments, Lou-Chai
        phases -- the array of one count per solve).
    converged : whether the stopping test was met (bool, or one per solve).
    residual : final value of the quantity the stopping test compares with ``tol``
        (float, or one per solve); its meaning is ``criterion``.
    criterion : what ``residual`` measures, in words (e.g. "relative change of the filled
        values"); it appears in the convergence warning.
    extra : solver-specific diagnostics (JSON scalars or small arrays), e.g. the final
        rank or the penalty.
    """

    n_iter: Any
    converged: Any
    residual: Any
    criterion: str
    extra: Mapping[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON-friendly dict (numpy scalars and arrays converted) of all fields."""
        def plain(v: Any) -> Any:
            if isinstance(v, np.ndarray):
                return v.tolist()
            return v.item() if isinstance(v, np.generic) else v

        return {"n_iter": plain(self.n_iter), "converged": plain(self.converged),
                "residual": plain(self.residual), "criterion": self.criterion,
                **{k: plain(v) for k, v in self.extra.items()}}


def warn_not_converged(name: str, info: SolveInfo, tol: float, max_iter: int,
                       advice: str | None = None, *, stacklevel: int = 1) -> None:
    """The one warning of a solver that stopped at ``max_iter`` above ``tol``.

    Every solver of :mod:`mocapkit.solvers` that warns about its own convergence calls
    this (a :class:`~mocapkit.errors.ConvergenceWarning`; the method-level summary and
    warning of a Denoiser is :func:`mocapkit.denoise.base.report_convergence`).

    Parameters
    ----------
    name : the solver (or method) named at the start of the message.
    info : the solve's report; ``n_iter``, ``residual`` and ``criterion`` (scalars) are
        quoted.
    tol, max_iter : the stopping settings the solve ran with.
    advice : what to change; default "raise max_iter (e.g. max_iter=2 max_iter) or tol".
    stacklevel : frames above the caller of this function that the warning points at
        (1: the solver's caller; add one per wrapping decorator).

    >>> import warnings
    >>> info = SolveInfo(n_iter=3, converged=False, residual=2.5e-3,
    ...                  criterion="relative change")
    >>> with warnings.catch_warnings(record=True) as w:
    ...     warnings.simplefilter("always")
    ...     warn_not_converged("demo", info, tol=1e-4, max_iter=3)
    >>> print(w[0].message)
    demo: not converged after 3 iterations (max_iter=3; final relative change 2.50e-03 > tol 1.0e-04); raise max_iter (e.g. max_iter=6) or tol
    """
    max_iter = int(max_iter)
    warnings.warn(f"{name}: not converged after {int(info.n_iter)} iterations (max_iter={max_iter}; "
                  f"final {info.criterion} {float(info.residual):.2e} > tol {float(tol):.1e}); "
                  + (advice or f"raise max_iter (e.g. max_iter={2 * max(max_iter, 1)}) or tol"),
                  ConvergenceWarning, stacklevel=stacklevel + 2)
