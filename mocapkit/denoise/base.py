"""The common Denoiser interface, the method registry and model save/load.

Every method is one class deriving from :class:`Denoiser`, registered with
``@register``. Following scikit-learn's estimator pattern:

* ``__init__`` only stores its keyword parameters unchanged (no work, no validation
  beyond what is free);
* ``fit(motions)`` learns state into trailing-underscore attributes and returns self
  (training-free methods inherit the no-op);
* ``denoise(motion)`` returns a new Motion with the same frames, joints and skeleton;
  observed samples stay observed (denoised), missing ones are filled where the gap
  policy allows (:mod:`mocapkit.gaps`).

The base class wraps every subclass's ``denoise`` once (:func:`_guard`, as scikit-learn
wraps ``transform`` for ``set_output``) so the rules shared by all methods live in one
place: the input is moved near the origin before the method and back after it (when it lies
more than 50 m away, by whole 10 m steps: data in a normal capture volume is untouched
and a clip 100 m away gives the same result shifted), a never-observed joint gets a placeholder the method may use
and is returned missing, and the result goes through :func:`mocapkit.gaps.apply_policy`
(fills without evidence or far outside the capture volume are left missing, fills are
flagged in ``Motion.filled`` and summarised in ``source['gap_report']``).

Models are saved as ``.npz`` (see :meth:`Denoiser.save`): a JSON header with the method
name, its parameters and the format version, plus every fitted array attribute.
Neural methods override save/load to use torch state dicts.
"""
from __future__ import annotations

import contextvars
import functools
import inspect
import json
import os
from typing import Any, ClassVar, Iterable, Sequence

import numpy as np

from ..errors import MocapFormatError, MocapValueError, NotFittedError
from ..motion import Motion

MODEL_FORMAT_VERSION = 1

_REGISTRY: dict[str, type["Denoiser"]] = {}


def register(cls: type["Denoiser"]) -> type["Denoiser"]:
    """Class decorator adding a Denoiser to the registry under ``cls.name``."""
    if not getattr(cls, "name", None):
        raise TypeError(f"{cls.__name__} needs a class attribute 'name'")
    if cls.name in _REGISTRY and _REGISTRY[cls.name] is not cls:
        raise TypeError(f"method name {cls.name!r} registered twice")
    _REGISTRY[cls.name] = cls
    return cls


def available() -> dict[str, type["Denoiser"]]:
    """Registered methods by name (sorted)."""
    from . import _load_families  # noqa: F401  (ensures every family module is imported)

    return dict(sorted(_REGISTRY.items()))


def get(name: str, **params: Any) -> "Denoiser":
    """Instantiate the method ``name`` with ``params``; clear error for unknown names/params."""
    methods = available()
    if name not in methods:
        raise MocapValueError(f"unknown method {name!r}; available: {', '.join(methods)}")
    cls = methods[name]
    accepted = cls._param_names()
    bad = sorted(set(params) - set(accepted))
    if bad:
        raise MocapValueError(
            f"method {name!r} has no parameter(s) {bad}; it accepts: {', '.join(accepted) or 'none'}")
    return cls(**params)


#: whole steps (cm) by which the base class moves an input towards the origin, and the
#: distance of the capture volume's centre from the origin beyond which it does (50 m: a
#: clip in any real capture volume, or scaled x10, is left where it is, so every method
#: keeps its own behaviour there; a clip 100 m or 10 km away is solved as if at home)
RECENTRE_STEP_CM = 1000.0
RECENTRE_BEYOND_CM = 5000.0

_INSIDE = contextvars.ContextVar("mocapkit_denoise_depth", default=0)


def _recentre_offset(motion: Motion) -> np.ndarray:
    """(3,) offset, a whole number of RECENTRE_STEP_CM per axis, that brings the centre of
    the observed capture volume within half a step of the origin (0 for normal data)."""
    P = motion.positions[motion.observed]
    if len(P) == 0:
        return np.zeros(3)
    centre = 0.5 * (P.min(axis=0) + P.max(axis=0))
    if np.abs(centre).max() <= RECENTRE_BEYOND_CM:
        return np.zeros(3)
    return np.round(centre / RECENTRE_STEP_CM) * RECENTRE_STEP_CM


def _prepare(motion: Motion) -> tuple[Motion, np.ndarray]:
    """The motion a method sees: recentred; never-observed joints hold a placeholder (the
    centroid of the observed joints of each frame, bridged in time) so that a method that
    needs every joint runs; the policy returns them missing."""
    off = _recentre_offset(motion)
    never = ~motion.observed.any(axis=0)
    if not off.any() and not never.any():
        return motion, off
    P = motion.positions - off
    obs = motion.observed
    if never.any() and obs.any():
        from ..gaps import fill_linear, frame_centroid

        c, n = frame_centroid(P, obs)
        c = fill_linear(c, (n > 0)[:, None].repeat(3, axis=1))
        P = P.copy()
        P[:, never] = c[:, None, :]
        obs = obs | never[None, :]
    return Motion(P, motion.skeleton, motion.fps, obs, motion.source, motion.filled), off


def _guard(fn):
    """Wrap a subclass's ``denoise`` with the shared rules (module docstring). Calls made
    from inside another method's denoise (a chain, a self-validation) are not wrapped again."""
    @functools.wraps(fn)
    def denoise(self, motion: Motion, *args, **kwargs) -> Motion:
        if _INSIDE.get():
            return fn(self, motion, *args, **kwargs)
        if not isinstance(motion, Motion):
            raise MocapValueError(f"{self.name}: denoise() needs a mocapkit Motion "
                                  f"(e.g. mocapkit.io.read(path)), got {type(motion).__name__}")
        from ..gaps import apply_policy

        work, off = _prepare(motion)
        token = _INSIDE.set(1)
        try:
            raw = fn(self, work, *args, **kwargs)
        finally:
            _INSIDE.reset(token)
        if raw.positions.shape != motion.positions.shape:
            raise RuntimeError(f"{self.name}: output shape {raw.positions.shape} != input "
                               f"{motion.positions.shape}")
        if off.any():
            Q = raw.positions + off
            if self.keeps_observed:         # bit-identical measured samples, whatever the shift
                Q[motion.observed] = motion.positions[motion.observed]
            raw = raw.with_positions(Q, raw.observed)
        return apply_policy(motion, raw, evidence=self.fill_evidence, method=self.name)

    denoise._gap_policy_guard = True
    return denoise


class Denoiser:
    """Base class of every denoising / gap-filling method.

    Subclasses set ``name``, ``description`` (one line, shown by ``mocapkit methods``),
    ``needs_training``, ``fill_evidence`` and implement :meth:`denoise` (and :meth:`fit`
    if data-driven). ``denoise`` may fill every missing sample; the base class keeps only
    what the gap policy allows (module docstring).
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    needs_training: ClassVar[bool] = False
    #: evidence a fill uses (:func:`mocapkit.gaps.supported`): "interp" (the ends of the gap,
    #: per channel) or "markers" (other markers observed in the same frame)
    fill_evidence: ClassVar[str] = "interp"

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        fn = cls.__dict__.get("denoise")
        if fn is not None and not getattr(fn, "_gap_policy_guard", False):
            cls.denoise = _guard(fn)
    #: whether observed, trusted entries are returned unchanged (property tests check it)
    keeps_observed: ClassVar[bool] = False

    #: RMSE (cm) within which a clean real clip must come back (property tests)
    clean_tolerance_cm: ClassVar[float] = 1.0

    @classmethod
    def quick_params(cls) -> dict[str, Any]:
        """Cheap settings (small dictionaries, few iterations) for property tests and demos."""
        return {}

    # -- parameters (scikit-learn style) -------------------------------------------------
    @classmethod
    def _param_names(cls) -> list[str]:
        sig = inspect.signature(cls.__init__)
        return [p.name for p in sig.parameters.values()
                if p.name != "self" and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]

    def get_params(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self._param_names()}

    def set_params(self, **params: Any) -> "Denoiser":
        for k, v in params.items():
            if k not in self._param_names():
                raise MocapValueError(f"method {self.name!r} has no parameter {k!r}")
            setattr(self, k, v)
        return self

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"

    # -- the interface -------------------------------------------------------------------
    def fit(self, motions: Sequence[Motion]) -> "Denoiser":
        """Learn from clean training motions. Training-free methods do nothing."""
        return self

    def denoise(self, motion: Motion) -> Motion:  # pragma: no cover - abstract
        raise NotImplementedError

    def fit_denoise(self, motion: Motion) -> Motion:
        return self.fit([motion]).denoise(motion)

    # -- fitted state ------------------------------------------------------------------------
    def _fitted_attrs(self) -> dict[str, Any]:
        return {k: v for k, v in vars(self).items()
                if k.endswith("_") and not k.startswith("_")}

    def is_fitted(self) -> bool:
        return (not self.needs_training) or bool(self._fitted_attrs())

    def _check_fitted(self) -> None:
        if not self.is_fitted():
            raise NotFittedError(
                f"method {self.name!r} needs training: call fit(motions) or load a model "
                f"(CLI: mocapkit train --method {self.name} CLIPS... -o model.npz, then --model)")

    # -- persistence -----------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> None:
        """Save parameters and fitted arrays to ``path`` (.npz), atomically.

        Fitted attributes must be numpy arrays, numbers, strings, or lists/dicts of
        those (stored as JSON); anything else is a programming error.
        """
        from ..io._atomic import atomic_write

        arrays: dict[str, np.ndarray] = {}
        scalars: dict[str, Any] = {}
        for k, v in self._fitted_attrs().items():
            if isinstance(v, np.ndarray):
                arrays[k] = v
            elif isinstance(v, (list, tuple)) and v and all(isinstance(a, np.ndarray) for a in v):
                for i, a in enumerate(v):
                    arrays[f"{k}#{i}"] = a
                scalars[k] = {"__array_list__": len(v)}
            else:
                scalars[k] = v
        header = {"method": self.name, "version": MODEL_FORMAT_VERSION,
                  "params": _jsonable(self.get_params()), "state": _jsonable(scalars)}

        def _write(f):
            np.savez_compressed(f, __header__=np.array(json.dumps(header)), **arrays)

        atomic_write(path, _write, binary=True)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Denoiser":
        """Load a model saved by :meth:`save`. ``Denoiser.load`` picks the right class."""
        if str(path).lower().endswith((".pt", ".onnx")):   # models of the neural family
            from .neural import load_model

            return load_model(path, cls)
        try:
            with np.load(path, allow_pickle=False) as z:
                header = json.loads(str(z["__header__"]))
                arrays = {k: z[k] for k in z.files if k != "__header__"}
        except (OSError, ValueError, KeyError, json.JSONDecodeError) as e:
            raise MocapFormatError(path, f"not a mocapkit model file ({e})") from None
        if header.get("version") != MODEL_FORMAT_VERSION:
            raise MocapFormatError(path, f"model format version {header.get('version')} "
                                         f"is not supported (expected {MODEL_FORMAT_VERSION})")
        methods = available()
        name = header.get("method")
        if name not in methods:
            raise MocapFormatError(path, f"model is for unknown method {name!r}")
        target = methods[name]
        if cls is not Denoiser and not issubclass(target, cls):
            raise MocapFormatError(path, f"model is for method {name!r}, not {cls.name!r}")
        obj = target(**header["params"])
        state = header.get("state", {})
        for k, v in state.items():
            if isinstance(v, dict) and "__array_list__" in v:
                v = [arrays.pop(f"{k}#{i}") for i in range(v["__array_list__"])]
            setattr(obj, k, v)
        for k, v in arrays.items():
            setattr(obj, k, v)
        return obj


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return obj


def report_convergence(den: Denoiser, *, iterations: Any, converged: Any, residual: Any,
                       tol: float, max_iter: int, criterion: str = "relative residual",
                       unit: str = "segment", warn: bool = True, stacklevel: int = 3,
                       extra: dict[str, Any] | None = None, detail: str = "",
                       param: str | None = None) -> dict[str, Any]:
    """Record an iterative solve in ``den.convergence_`` and warn once if it stopped early.

    ``iterations``, ``converged``, ``residual`` are scalars or one value per independent
    solve (SLRA segments, Lou-Chai phases).  The summary keeps the worst solve: the largest
    iteration count and the largest final residual among the solves that did not converge
    (or among all when every one did), plus how many did not converge.  Only JSON numbers
    and strings, so :meth:`Denoiser.save` can store it.  One :class:`ConvergenceWarning`
    (category) is emitted per call when any solve missed ``tol``; ``extra`` (JSON scalars)
    is added to the summary and ``detail`` to the message; ``param`` replaces the advice
    "raise max_iter (e.g. ...) or tol" for methods whose iteration budget has other names.
    Shared by the low-rank, thesis, Lou-Chai and Xiao methods.
    """
    import warnings

    from ..errors import ConvergenceWarning

    it = np.atleast_1d(np.asarray(iterations, dtype=int))
    cv = np.atleast_1d(np.asarray(converged, dtype=bool))
    rs = np.atleast_1d(np.asarray(residual, dtype=float))
    bad = ~cv
    pick = bad if bad.any() else np.ones_like(cv)
    worst = float(np.max(rs[pick])) if rs.size else 0.0
    summary = {"method": den.name, "converged": bool(cv.all()), "iterations": int(it.max(initial=0)),
               "max_iter": int(max_iter), "residual": worst, "tol": float(tol),
               "criterion": criterion, "n_solves": int(cv.size), "n_not_converged": int(bad.sum()),
               **(extra or {})}
    den.convergence_ = summary
    if warn and bad.any():
        what = (f"{int(bad.sum())} of {cv.size} {unit}s not converged after"
                if cv.size > 1 else "not converged after")
        warnings.warn(
            f"{den.name}: {what} {int(it[bad].max())} iterations (max_iter={int(max_iter)}; "
            f"final {criterion} {worst:.2e}, tol {float(tol):.1e}{detail}); "
            + (param or f"raise max_iter (e.g. max_iter={2 * max(int(max_iter), 1)}) or tol"),
            ConvergenceWarning, stacklevel=stacklevel)
    return summary


#: thresholds of :func:`check_training_match` (median change of the observed entries)
MISMATCH_NOISE_FACTOR = 2.0
MISMATCH_FLOOR_CM = 1.0


def check_training_match(den: "Denoiser", inp: Motion, out: Motion, *, warn: bool = True,
                         stacklevel: int = 3) -> dict[str, float]:
    """Flag a data-driven result that moved the observed markers far beyond their noise.

    A denoiser should move an observed coordinate by about its noise (median |noise| =
    0.67 sigma for Gaussian noise; outliers are a minority and do not move the median).
    When the median |out - in| over the observed coordinates exceeds
    ``max(MISMATCH_NOISE_FACTOR * sigma, MISMATCH_FLOOR_CM)`` -- sigma the robust noise
    level of the input (:func:`mocapkit.solvers.lowrank.noise_level` with ``robust=True``, cm) --
    the learnt model is replacing the motion rather than cleaning it, typically because
    it was trained on another behaviour.  Measured with ``lou-chai`` on the bundled CMU
    clips 16_15, 07_05, 09_06, 131_07 (1 cm noise + 5 % missing, 0.1 cm noise, 20 %
    outliers): trained on the clip itself the median change is 0.16-0.81 cm (RMSE 0.4-4.2
    cm) and none of the 12 cases warns; trained on the three other clips it is 1.2-6.6 cm
    (RMSE 3.5-15 cm) and 10 of the 12 cases warn -- not 16_15 and 07_05 with 1 cm noise
    (RMSE 3.6 / 4.3 cm, median change 1.4 / 1.85 cm under the 2 cm threshold).

    Records ``den.training_match_`` = {median_change_cm, noise_cm, threshold_cm,
    mismatch} and, when ``mismatch`` and ``warn``, emits one TrainingMismatchWarning.
    """
    import warnings

    from ..errors import TrainingMismatchWarning

    from ..solvers.lowrank import noise_level

    X, ok = inp.matrix(), inp.matrix_mask()
    d = np.abs(out.matrix() - X)[ok]
    sigma = noise_level(X, ok, robust=True)
    med = float(np.median(d)) if d.size else 0.0
    thr = max(MISMATCH_NOISE_FACTOR * sigma, MISMATCH_FLOOR_CM)
    info = {"median_change_cm": med, "noise_cm": sigma, "threshold_cm": thr,
            "mismatch": bool(med > thr)}
    den.training_match_ = info
    if warn and info["mismatch"]:
        warnings.warn(
            f"{den.name}: the result moves the observed markers by {med:.2f} cm (median) while "
            f"the input's noise is about {sigma:.2f} cm: the training clips probably do not "
            f"cover this motion; train on clean clips of the same behaviour",
            TrainingMismatchWarning, stacklevel=stacklevel)
    return info


def training_matrices(motions: Iterable[Motion]) -> list[np.ndarray]:
    """(T, 3J) matrices of training motions, checking they are fully observed."""
    mats = []
    for m in motions:
        if not m.observed.all():
            raise MocapValueError(f"training motion {m!r} has missing entries; fill them first")
        mats.append(m.matrix())
    if not mats:
        raise MocapValueError("fit() needs at least one training motion")
    return mats
