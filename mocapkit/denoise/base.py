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
place: on a marker capture, label swaps (two markers that traded labels for a stretch) are
put back first (:mod:`mocapkit.swaps`; :attr:`mocapkit.gaps.GapPolicy.swaps`); the input is
moved near the origin before the method and back after it (when it lies
more than 50 m away, by whole 10 m steps: data in a normal capture volume is untouched
and a clip 100 m away gives the same result shifted), a never-observed joint gets a placeholder the method may use
and is returned missing, and the result goes through :func:`mocapkit.gaps.apply_policy`
(fills without evidence or far outside the capture volume are left missing, fills are
flagged in ``Motion.filled`` and summarised in ``source['gap_report']``).

Parameters are declared in ``_parameter_constraints`` (:mod:`mocapkit.denoise.constraints`)
and checked once, by the base class, in :func:`get`, :meth:`Denoiser.set_params` and before
``fit`` and ``denoise``. Diagnostics of a run (solver convergence, training match) go to the
returned Motion's ``source`` and to ``last_report_``, which :meth:`Denoiser.save` never writes.

Models are saved as ``.npz`` (see :meth:`Denoiser.save`): a JSON header with the method
name, its parameters and the format version, plus every fitted array attribute. Other
formats register a loader per file suffix (:func:`register_model_format`; the neural
family's ``.pt`` / ``.onnx``), which :meth:`Denoiser.load` dispatches on.
"""
from __future__ import annotations

import contextvars
import functools
import json
import os
from pathlib import Path
from typing import Any, Callable, ClassVar, Iterable, Sequence

import numpy as np

from .._params import init_param_names, store_params
from ..errors import MocapFormatError, MocapValueError, NotFittedError
from ..motion import Motion
from . import constraints

MODEL_FORMAT_VERSION = 1

_REGISTRY: dict[str, type["Denoiser"]] = {}

#: loaders of the model file formats other than .npz, by lower-case suffix
_MODEL_LOADERS: dict[str, Callable[[str | os.PathLike, type], "Denoiser"]] = {}


def register_model_format(suffixes: Sequence[str], loader: Callable[[str | os.PathLike, type], "Denoiser"]) -> None:
    """Make :meth:`Denoiser.load` read files ending in ``suffixes`` (e.g. ``(".pt", ".onnx")``)
    with ``loader(path, cls)``, which returns the Denoiser (an instance of ``cls``)."""
    for suf in suffixes:
        _MODEL_LOADERS[suf.lower()] = loader


def register(cls: type["Denoiser"]) -> type["Denoiser"]:
    """Class decorator adding a Denoiser to the registry under ``cls.name``."""
    if not getattr(cls, "name", None):
        raise TypeError(f"{cls.__name__} needs a class attribute 'name'")
    if cls.name in _REGISTRY and _REGISTRY[cls.name] is not cls:
        raise TypeError(f"method name {cls.name!r} registered twice")
    _REGISTRY[cls.name] = cls
    return cls


def model_suffixes() -> tuple[str, ...]:
    """File suffixes of the model formats other than .npz (:func:`register_model_format`)."""
    return tuple(sorted(_MODEL_LOADERS))


def available() -> dict[str, type["Denoiser"]]:
    """Registered methods by name (sorted). Every family module is imported with the
    package (``mocapkit.denoise``), which Python imports before this module."""
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
    obj = cls(**params)
    obj._validate_params("get()")
    return obj


def params_from_text(name: str, params: dict[str, Any], cls: type["Denoiser"] | None = None) -> dict[str, Any]:
    """``params`` of method ``name`` (or of the class ``cls`` of a loaded model) as parsed from
    text (CLI ``--param``, batch) converted to the declared kinds: ``3.0`` -> 3 for an
    integer parameter, 2 -> 2.0 for a real one, lists -> tuples of floats
    (:func:`mocapkit.denoise.constraints.coerce`). Not checked here: :func:`get` and
    :meth:`Denoiser.set_params` check them (and report unknown methods and names)."""
    cls = cls or available().get(name)
    return params if cls is None else cls.coerce_params(params)


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
    if not motion.observed.any():
        return np.zeros(3)
    # NaN where unobserved (a Motion's rule), so fmin / fmax reduce the observed samples
    # without gathering them into a copy
    P = motion.positions.reshape(-1, 3)
    centre = 0.5 * (np.fmin.reduce(P, axis=0) + np.fmax.reduce(P, axis=0))
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
        from ..gaps import fill, frame_centroid

        c, n = frame_centroid(P, obs)
        c = fill(c, (n > 0)[:, None].repeat(3, axis=1))
        P = P.copy()
        P[:, never] = c[:, None, :]
        obs = obs | never[None, :]
    return Motion(P, motion.skeleton, motion.fps, obs, motion.source, motion.filled), off


def trained_joint_map(joints: Sequence[str], motion: Motion) -> np.ndarray | None:
    """Index array ``idx`` such that ``motion.positions[:, idx]`` are a trained model's
    ``joints`` in the model's order, or None when the motion's joints are not those.

    The names match exactly, or one-to-one by their bare names
    (:func:`mocapkit.skeleton.bare_name`): Vicon writes ``Subject:LASI``, so a lab's model
    trained on one subject's takes meets ``Viktor:LASI`` where it learned ``Derrick:LASI``.
    A skeleton with a hierarchy must keep its joint order (a parent comes before its
    children); a marker set (no hierarchy) may list its markers in any order, as two takes
    exported by the same software sometimes do.
    """
    from ..skeleton import bare_name

    names, joints = list(motion.skeleton.names), [str(j) for j in joints]
    if names == joints:
        return np.arange(len(names))
    if len(names) != len(joints):
        return None
    for key in (str, bare_name):
        where = {key(n): i for i, n in enumerate(names)}
        if len(where) == len(names) and len({key(j) for j in joints}) == len(joints) \
                and all(key(j) in where for j in joints):
            idx = np.array([where[key(j)] for j in joints])
            return idx if motion.skeleton.is_flat or np.array_equal(idx, np.arange(len(idx))) else None
    return None


def check_trained_joints(den: "Denoiser", motion: Motion) -> None:
    """The one check of a data-driven method's joints against its model's (``joint_names_``):
    MocapValueError naming what is missing and extra. :meth:`Denoiser.denoise` has already
    renamed and reordered a motion :func:`trained_joint_map` matches, so this raises only for
    another joint set (or a call from inside another method's denoise)."""
    joints = [str(j) for j in den.joint_names_]
    names = list(motion.skeleton.names)
    if names == joints:
        return
    from ..skeleton import bare_name

    def diff(key):
        a, b = {key(n) for n in names}, {key(j) for j in joints}
        return [key(j) for j in joints if key(j) not in a], [key(n) for n in names if key(n) not in b]

    # by bare names when those tell more ('Derrick:RWRA' against 'Viktor:...': RWRA is missing)
    missing, extra = min(diff(str), diff(bare_name), key=lambda d: len(d[0]) + len(d[1]))
    what = "; ".join(f"{label} {', '.join(v[:6])}{' ...' if len(v) > 6 else ''}"
                     for label, v in (("missing", missing), ("extra", extra)) if v) \
        or "the same joints in another order"
    raise MocapValueError(
        f"{den.name}: the model was trained on {len(joints)} joints, this motion has {len(names)} "
        f"({what}); train a model on clips of this skeleton or marker set "
        f"(mocapkit train --method {den.name} CLIPS... -o model.npz)")


def _as_trained(den: "Denoiser", motion: Motion) -> tuple[Motion, np.ndarray | None]:
    """``motion`` with a trained model's joint names and order where
    :func:`trained_joint_map` matches them, and the index map to undo it (None: as it is)."""
    joints = getattr(den, "joint_names_", None)
    if joints is None or list(motion.skeleton.names) == [str(j) for j in joints]:
        return motion, None
    idx = trained_joint_map(joints, motion)
    if idx is None:
        return motion, None
    from ..skeleton import Skeleton

    sk = motion.skeleton
    inv = np.argsort(idx)
    parents = np.where(sk.parents[idx] >= 0, inv[np.maximum(sk.parents[idx], 0)], -1)
    renamed = Skeleton(tuple(str(j) for j in joints), parents, sk.offsets[idx])
    return Motion(motion.positions[:, idx], renamed, motion.fps, motion.observed[:, idx], motion.source,
                  motion.filled[:, idx]), idx


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

        self._validate_params("denoise()")
        self.last_report_ = {}
        from ..gaps import current_policy

        pol = current_policy()
        swaps = None
        if pol.restrict and pol.swaps:
            from ..swaps import repair_labels

            # labels two markers traded (a Kinect skeleton's sides): put back before any
            # method sees them, so that each works on each marker's own path; the rest of
            # the guard judges the method against the input so repaired
            motion, swaps = repair_labels(motion)
        from .bases import reference_as_read, reference_frames

        # a file's reference pose (a BVH's T-pose first frame) is no capture: the method sees
        # the first frame of the motion in its place (no step to smooth across), and it is
        # written back as read below
        ref = reference_frames(motion)
        work, off = _prepare(_edge_held(motion, ref) if ref else motion)
        work, idx = _as_trained(self, work)
        limit = pol.validate_cm if pol.restrict else None
        token = _INSIDE.set(1)
        try:
            raw = fn(self, work, *args, **kwargs)
            misfit = None
            if self.misfit_check:           # (the gap policy warns, with what it gave back)
                misfit = check_model_fit(self, work, raw, factor=pol.misfit_factor,
                                         give_back=pol.restrict and pol.misfit_factor is not None, warn=False)
            unvalidated = None
            if limit is not None and not self.validates_fills and (~work.observed & raw.observed).any():
                from .fill_auto import unvalidated_fills

                # the validation's runs report too: the real run's report is the one kept
                run_report = dict(self.__dict__.get("last_report_", {}))
                unvalidated = unvalidated_fills(self, work, raw, float(limit))
                self.last_report_ = run_report
        finally:
            _INSIDE.reset(token)
        if idx is not None:                 # back to the motion's own names and order
            inv = np.argsort(idx)
            raw = Motion(raw.positions[:, inv], motion.skeleton, raw.fps, raw.observed[:, inv], raw.source,
                         raw.filled[:, inv])
            unvalidated = None if unvalidated is None else unvalidated[:, inv]
            misfit = None if misfit is None else misfit[:, inv]
        if raw.positions.shape != motion.positions.shape:
            raise RuntimeError(f"{self.name}: output shape {raw.positions.shape} != input "
                               f"{motion.positions.shape}")
        if off.any():
            Q = raw.positions + off
            if self.keeps_observed:         # bit-identical measured samples, whatever the shift
                Q[motion.observed] = motion.positions[motion.observed]
            raw = raw.with_positions(Q, raw.observed)
        if ref:
            raw = reference_as_read(raw, motion, ref)
        fit = self.last_report_.get("model_fit") if self.misfit_check and getattr(self, "warn", True) else None
        out = self._after_policy(apply_policy(motion, raw, evidence=self.fill_evidence, method=self.name,
                                              unvalidated=unvalidated, misfit=misfit, fit=fit))
        if swaps is not None and (swaps["events"] or swaps.get("repaired")):
            out = out.with_source(swaps=swaps)
        if ref:
            out = out.with_source(reference_frames=ref)
        return out.with_source(**self.last_report_) if self.last_report_ else out

    denoise._gap_policy_guard = True
    return denoise


def _edge_held(motion: Motion, n: int) -> Motion:
    """``motion`` with its first ``n`` frames replaced by frame ``n`` (positions, observed):
    what a method sees of a file whose first frames are its reference pose. Smoothed
    across the T-pose, cgspeed's 01_01 had its frame 1 moved 22 cm by kalman-cv."""
    P, obs = motion.positions.copy(), motion.observed.copy()
    P[:n], obs[:n] = P[n], obs[n]
    return Motion(P, motion.skeleton, motion.fps, obs, motion.source, motion.filled)


def _checked_fit(fn):
    """Wrap a subclass's ``fit`` so that its parameters are checked first (once)."""
    @functools.wraps(fn)
    def fit(self, *args, **kwargs):
        self._validate_params("fit()")
        return fn(self, *args, **kwargs)

    fit._params_checked = True
    return fit


class Denoiser:
    """Base class of every denoising / gap-filling method.

    Subclasses set ``name``, ``description`` (one line, shown by ``mocapkit methods``),
    ``needs_training``, ``fill_evidence``, ``_parameter_constraints`` (every constructor
    parameter, :mod:`mocapkit.denoise.constraints`) and implement :meth:`denoise` (and
    :meth:`fit` if data-driven). ``denoise`` may fill every missing sample; the base class
    keeps only what the gap policy allows (module docstring). Parameters are checked by
    the base class before ``fit`` and ``denoise`` run; rules between parameters go in
    :meth:`_check_combination`. A result's run diagnostics (``source["convergence"]``,
    ``source["model_fit"]``) are also in ``last_report_``, which is never saved.
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    needs_training: ClassVar[bool] = False
    #: evidence a fill uses (:func:`mocapkit.gaps.supported`): "interp" (the ends of the gap,
    #: per channel) or "markers" (other markers observed in the same frame)
    fill_evidence: ClassVar[str] = "interp"
    #: whether a fill's error grows with the gap's length even with other markers as
    #: evidence (fill-pattern: a donor's shape offset to meet the gap's ends; trnn, tsmc,
    #: dynammo: a temporal model); fill-auto then judges it, like an ``"interp"`` fill, only
    #: by gaps at least half as long as the one it fills
    #: (:func:`mocapkit.denoise.fill_auto._pooled`), and the gap policy leaves its edge gaps
    #: without a stretch of their own missing (:func:`mocapkit.denoise.fill_auto.unvalidated_fills`)
    fill_drifts: ClassVar[bool] = False

    #: constraints of every constructor parameter (:mod:`mocapkit.denoise.constraints`):
    #: name -> list of constraints, any one of which a value must satisfy
    _parameter_constraints: ClassVar[dict[str, list]] = {}

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        fn = cls.__dict__.get("denoise")
        if fn is not None and not getattr(fn, "_gap_policy_guard", False):
            cls.denoise = _guard(fn)
        fit = cls.__dict__.get("fit")
        if fit is not None and not getattr(fit, "_params_checked", False):
            cls.fit = _checked_fit(fit)
    #: whether observed, trusted entries are returned unchanged (property tests check it)
    keeps_observed: ClassVar[bool] = False
    #: whether the result is a model's reconstruction of the motion rather than a filter the
    #: user chose: ``"learned"`` from other clips (xiao-sparse, psc, lou-chai,
    #: kalman-learned, the networks) or ``"fitted"`` to the clip (the low-rank methods,
    #: dynammo). The guard gives back, as measured, the samples of a marker the model moved
    #: beyond the input's noise (:func:`check_model_fit`); None: not checked
    misfit_check: ClassVar[str | None] = None
    #: whether the method validates its own fills on the file (auto, fill-auto): the gap
    #: policy's ``validate_cm`` check then does not run it again
    validates_fills: ClassVar[bool] = False

    #: RMSE (cm) within which a clean real clip must come back (property tests)
    clean_tolerance_cm: ClassVar[float] = 1.0

    def _after_policy(self, out: Motion) -> Motion:
        """Hook: the result after the gap policy (``source['gap_report']``), for a method
        whose report depends on what is written (auto's and fill-auto's error estimates)."""
        return out

    @classmethod
    def quick_params(cls) -> dict[str, Any]:
        """Cheap settings (small dictionaries, few iterations) for property tests and demos."""
        return {}

    # -- parameters (scikit-learn style) -------------------------------------------------
    def _store_params(self, values: dict[str, Any]) -> None:
        """Store every ``__init__`` parameter unchanged (:func:`mocapkit._params.store_params`):
        call it as ``self._store_params(locals())``. Like scikit-learn, ``__init__`` only
        stores; validation (``_parameter_constraints``) and work happen later, so
        ``get_params``/``set_params``/``clone`` round-trip exactly."""
        store_params(self, values)

    @classmethod
    def _param_names(cls) -> list[str]:
        return init_param_names(cls)

    def get_params(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self._param_names()}

    def set_params(self, **params: Any) -> "Denoiser":
        for k, v in params.items():
            if k not in self._param_names():
                raise MocapValueError(f"method {self.name!r} has no parameter {k!r}")
        self.check_params(params, "set_params()")
        for k, v in params.items():
            setattr(self, k, v)
        return self

    @classmethod
    def check_params(cls, params: dict[str, Any], where: str = "") -> None:
        """Raise MocapValueError naming the method, the parameter, its value and what is
        allowed when a value of ``params`` breaks ``_parameter_constraints``."""
        constraints.check(cls.name, cls._parameter_constraints, params, where)

    @classmethod
    def coerce_params(cls, params: dict[str, Any]) -> dict[str, Any]:
        """``params`` as parsed from text (CLI) converted to the declared kinds
        (:func:`mocapkit.denoise.constraints.coerce`), not checked."""
        return constraints.coerce(cls._parameter_constraints, params)

    def _validate_params(self, where: str) -> None:
        """Every parameter against its constraints, then the rules between parameters."""
        self.check_params(self.get_params(), where)
        self._check_combination()

    def _check_combination(self) -> None:
        """Rules that involve several parameters (MocapValueError); none by default."""

    @classmethod
    def _upgrade_params(cls, params: dict[str, Any]) -> dict[str, Any]:
        """Parameters read from a model file written by an older version, in today's
        spelling (identity unless a method renamed a parameter)."""
        return params

    # -- training from files (CLI ``mocapkit train``) ----------------------------------------
    #: files ``train`` writes next to the model (suffixes appended to the output path)
    training_side_files: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def train_files(cls, sources: Sequence[str], output: str | os.PathLike, *, params: dict[str, Any],
                    resume: bool, progress: bool, exclude: Sequence[str]) -> bool:
        """Train from motion files or folders with the method's own trainer and write the
        model to ``output``. Returns False when the method has none: the caller then reads
        the clips, calls :meth:`fit` and :meth:`save`."""
        return False

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
        """Fitted state: trailing-underscore attributes, except the diagnostics of the last
        run (``last_report_``), which are never saved."""
        return {k: v for k, v in vars(self).items()
                if k.endswith("_") and not k.startswith("_") and k != "last_report_"}

    def report(self, **items: Any) -> None:
        """Record diagnostics of the current run (JSON-able values) in ``last_report_``;
        the outermost ``denoise`` copies them to its result's ``source``."""
        self.__dict__.setdefault("last_report_", {}).update(items)

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
        """Load a model saved by :meth:`save`. ``Denoiser.load`` picks the right class;
        files of a registered format (:func:`register_model_format`) go to its loader."""
        loader = _MODEL_LOADERS.get(Path(path).suffix.lower())
        if loader is not None:
            return loader(path, cls)
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
        obj = target(**target._upgrade_params(header["params"]))
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


def report_convergence(den: Denoiser, info: Any, *, tol: float, max_iter: int,
                       unit: str = "segment", warn: bool = True, stacklevel: int = 3,
                       extra: dict[str, Any] | None = None, detail: str = "",
                       param: str | None = None) -> dict[str, Any]:
    """Record an iterative solve in ``den.last_report_["convergence"]`` (the guard of
    ``denoise`` copies it to the result's ``source["convergence"]``) and warn once if it
    stopped early.

    ``info`` is the solver's :class:`~mocapkit.solvers.info.SolveInfo` -- scalars, or one
    value per independent solve (SLRA segments) -- or a sequence of them (Lou-Chai phases,
    Xiao's ADMM solves); its ``criterion`` names the residual in the summary and the
    warning (several distinct ones are joined by " / ").  ``tol`` and ``max_iter`` are the
    method's stopping settings.  The summary keeps the worst solve: the largest
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
    from ..solvers.info import SolveInfo

    infos = [info] if isinstance(info, SolveInfo) else list(info)

    def per_solve(field: str, dtype: type) -> np.ndarray:
        return np.concatenate([np.atleast_1d(np.asarray(getattr(i, field), dtype=dtype))
                               for i in infos] or [np.zeros(0, dtype=dtype)])

    it, cv, rs = per_solve("n_iter", int), per_solve("converged", bool), per_solve("residual", float)
    criterion = " / ".join(dict.fromkeys(i.criterion for i in infos)) or "relative residual"
    bad = ~cv
    pick = bad if bad.any() else np.ones_like(cv)
    worst = float(np.max(rs[pick])) if rs.size else 0.0
    summary = {"method": den.name, "converged": bool(cv.all()), "iterations": int(it.max(initial=0)),
               "max_iter": int(max_iter), "residual": worst, "tol": float(tol),
               "criterion": criterion, "n_solves": int(cv.size), "n_not_converged": int(bad.sum()),
               **(extra or {})}
    den.__dict__.setdefault("last_report_", {})["convergence"] = summary
    if warn and bad.any():
        what = (f"{int(bad.sum())} of {cv.size} {unit}s not converged after"
                if cv.size > 1 else "not converged after")
        warnings.warn(
            f"{den.name}: {what} {int(it[bad].max())} iterations (max_iter={int(max_iter)}; "
            f"final {criterion} {worst:.2e}, tol {float(tol):.1e}{detail}); "
            + (param or f"raise max_iter (e.g. max_iter={2 * max(int(max_iter), 1)}) or tol"),
            ConvergenceWarning, stacklevel=stacklevel)
    return summary


def check_model_fit(den: "Denoiser", inp: Motion, out: Motion, *, factor: float | None = None,
                    give_back: bool = True, warn: bool = True, stacklevel: int = 3) -> np.ndarray | None:
    """Flag the markers a model-based method moved beyond the input's noise; the samples to give back.

    A denoiser moves a measured coordinate by about its noise; a model that moves a
    marker's samples by more than ``factor`` times the input's robust noise level
    (:func:`mocapkit.signal.estimate_noise`, ``pool="all"``), RMS over the samples where
    the input shows no spike, is replacing that marker's motion rather than cleaning it --
    a learned model whose training clips do not cover this motion, a low-rank model that
    does not fit the clip -- and its result there is further from the truth than the
    measurement (:func:`mocapkit.gaps.model_misfit`, which holds the reasoning and what was
    measured). Called by the guard for the methods with a ``misfit_check``, with the gap
    policy's ``misfit_factor`` (None: the default policy's) and ``give_back`` False under
    :data:`mocapkit.gaps.FILL_ALL` or ``--keep-moves`` (the markers are reported, the
    model's values written).

    Records ``den.last_report_["model_fit"]`` (the result's ``source["model_fit"]``)
    = {noise_cm, threshold_cm, markers (the names flagged), n_markers, kind (the method's
    ``misfit_check``), moved_rms_cm and worst_marker (the largest RMS move of a judged
    marker, cm, and its name), samples (to give back), given_back, mismatch (markers
    flagged), local_samples / local_markers / local_threshold_cm / local_max_cm (the local
    misfits on the other markers, given back one by one)} and, when ``mismatch`` or local
    misfits of 1 mm or more (:func:`mocapkit.gaps.local_said`) and ``warn``, emits one
    TrainingMismatchWarning (a learned model) or ModelMisfitWarning
    (:func:`mocapkit.gaps.misfit_warning`; the guard leaves it to
    :func:`mocapkit.gaps.apply_policy`, which knows what it gave back). Returns the (T, J)
    samples to give back as measured, or None.

    >>> import numpy as np
    >>> from mocapkit import corrupt, datasets, io
    >>> clip = io.read(datasets.bundled("09_06.amc"))
    >>> noisy = corrupt.gaussian(clip, sigma_cm=1.0, seed=0)[0]
    >>> class Model: name = "model"
    >>> model = Model()
    >>> back = check_model_fit(model, noisy, clip.with_positions(clip.positions + 3.0), warn=False)
    >>> int(back.any(axis=0).sum()), model.last_report_["model_fit"]["markers"][:2]
    (31, ['root', 'lhipjoint'])
    """
    from ..gaps import DEFAULT_POLICY, local_said, local_threshold, misfit_warning, model_misfit
    from ..signal import estimate_noise

    sigma = estimate_noise(inp.matrix(copy=False), inp.matrix_mask(), pool="all", fallback=0.0)
    f = float(DEFAULT_POLICY.misfit_factor if factor is None else factor)
    mask, rms, local = model_misfit(inp.positions, inp.observed, out.positions, sigma, f)
    whole = (mask & ~local).any(axis=0)            # markers judged misfits as a whole
    names = [inp.skeleton.names[j] for j in np.flatnonzero(whole)]
    alone = local & ~whole[None, :]                # samples given back one by one elsewhere
    judged = np.isfinite(rms).any()
    info = {"noise_cm": float(sigma), "threshold_cm": f * float(sigma), "markers": names,
            "n_markers": inp.n_joints, "kind": getattr(den, "misfit_check", None) or "learned",
            "moved_rms_cm": float(np.nanmax(rms)) if judged else 0.0,
            "worst_marker": inp.skeleton.names[int(np.nanargmax(rms))] if judged else None,
            "samples": int(mask.sum()) if give_back else 0, "given_back": bool(give_back),
            "mismatch": bool(names), "local_samples": int(alone.sum()),
            "local_markers": int(alone.any(axis=0).sum()),
            "local_threshold_cm": local_threshold(sigma),
            "local_max_cm": float(np.linalg.norm(out.positions[alone] - inp.positions[alone], axis=1).max())
            if alone.any() else 0.0}
    den.__dict__.setdefault("last_report_", {})["model_fit"] = info
    if warn and (names or local_said(info)):
        misfit_warning(den.name, info, info["samples"], stacklevel=stacklevel + 1)
    return mask if give_back else None


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
