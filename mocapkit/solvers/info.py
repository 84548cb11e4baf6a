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

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

__all__ = ["SolveInfo"]


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
