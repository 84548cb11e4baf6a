"""Shipped general models: data-driven methods that work without ``train`` (issue #19).

``xiao-sparse``, ``psc`` and ``lou-chai`` were trained once (``benchmarks/train_shipped.py``)
on the ASF/AMC clips of the shared data set -- CMU and HDM05, every behaviour present --
except the held-out evaluation subjects (CMU 01, 05, 09, 16, 35, 49, 135 and HDM05 actor
mm, see :func:`describe`), and are stored in ``mocapkit/data/models/`` as float16 ``.npz``
files (:meth:`mocapkit.denoise.base.Denoiser.save` format) with an ``index.json``.
Accuracy against same-behaviour models, classical filters and the float64 originals is in
docs/results/shipped_models.md.

* :func:`available` -- methods with a shipped model;
* :func:`load` ``(name, motion)`` -- a fitted estimator for ``motion`` or None when no
  shipped model fits its joint set;
* :func:`describe` ``(name)`` -- one line: what it was trained on.

Joint set: a model works on the 31-joint Acclaim skeleton of CMU / HDM05 ASF files (joint
names ``root, lhipjoint, lfemur, ..., rthumb``; ``xiao-sparse`` accepts them in any order,
``psc`` / ``lou-chai`` in the ASF order, which every Acclaim file read by
:mod:`mocapkit.io` has). Anything else (marker files, BVH conversions, other skeletons)
gets None. The cgspeed BVH conversions of CMU are not mapped: their 31 joints are the bone
*start* points and lack the five leaf end points, so no renaming gives the ASF joint set.

Frame rate (measured, docs/results/shipped_models.md "frame rate"): ``xiao-sparse`` and
``psc`` have one model per rate (30 and 120 fps); a clip at exactly one of those rates gets
that model as is. ``lou-chai`` has one 30 fps model and filters a clip at k x 30 fps as its
k interleaved 30 fps phases by itself. Other rates go through :class:`RateAdapter`:
``psc`` resamples the clip (cubic spline) up to the next higher model rate, filters it and
interpolates back to the clip's own frames; ``xiao-sparse`` splits a clip at an integer
multiple k of a model rate (60 fps = 2 x 30) into its k phases (every sample is used,
nothing is interpolated), filters each at the model rate and interleaves them again (the
largest such model rate), and resamples any other rate to the nearest model rate. One
model per rate is measurably better than one model plus resampling: the 30 fps xiao-sparse
model on 120 fps clips (4 phases) gives 1.08 cm on 3 cm noise where the 120 fps model gives
0.78, and the 120 fps model on 30 fps clips (upsampled) 1.53 where the 30 fps model gives
1.12.

Loading reads one ~2 MB file and casts it to float64 (well under 0.5 s); no training data
is needed.
"""
from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Any

import numpy as np

from .denoise.base import Denoiser
from .errors import MocapValueError
from .motion import Motion

__all__ = ["MODELS_DIR", "RateAdapter", "available", "choose", "describe", "load"]

MODELS_DIR = Path(__file__).parent / "data" / "models"

#: methods that do better on a clip between two model rates when it is resampled up to the
#: higher one than when it is split into phases of the lower one (measured at 60 fps,
#: docs/results/shipped_models.md "frame rate": psc 0.61 vs 0.78 cm on spikes, 2.69 vs
#: 2.94 cm on 3 cm noise; xiao-sparse the other way on noise, 1.22 vs 1.07 cm)
_RESAMPLE_UP = frozenset({"psc"})

#: relative tolerance when comparing frame rates (120.005 fps files count as 120)
FPS_RTOL = 1e-3


@functools.lru_cache(maxsize=1)
def _index() -> dict[str, dict[str, Any]]:
    p = MODELS_DIR / "index.json"
    if not p.is_file():
        return {}
    idx = json.loads(p.read_text())
    return {f: e for f, e in idx.items() if (MODELS_DIR / f).is_file()}


def _entries(name: str) -> list[tuple[str, dict[str, Any]]]:
    return sorted(((f, e) for f, e in _index().items() if e["method"] == name),
                  key=lambda fe: fe[1]["fps"])


def available() -> list[str]:
    """Names of the methods that have a shipped model (sorted)."""
    return sorted({e["method"] for e in _index().values()})


def describe(name: str) -> str:
    """One line: what the shipped model of method ``name`` was trained on."""
    ent = _entries(name)
    if not ent:
        raise MocapValueError(f"no shipped model for {name!r}; shipped: {', '.join(available()) or 'none'}")
    e = ent[0][1]
    rates = "/".join(f"{x['fps']:g}" for _, x in ent)
    ds = e["datasets"]
    frames = ", ".join(f"{x['n_frames']} frames at {x['fps']:g} fps" for _, x in ent)
    return (f"{name}: general model for the 31-joint CMU/HDM05 Acclaim skeleton at {rates} fps, "
            f"trained on {e['n_clips']} clips ({frames}) of CMU subjects {', '.join(ds['cmu'])} "
            f"and HDM05 actors {', '.join(ds['hdm05'])} ({', '.join(e['behaviours'])}); "
            f"held out: {', '.join(e['held_out']) or 'none'}; {e['dtype']}")


def _joints_match(name: str, entry: dict, motion: Motion) -> bool:
    want = list(entry["joint_names"])
    have = list(motion.skeleton.names)
    if name == "xiao-sparse":                  # looks joints up by name
        return sorted(want) == sorted(have)
    return want == have


def _ratio(fps: float, base: float) -> int | None:
    r = fps / base
    k = int(round(r))
    return k if k >= 1 and abs(r - k) <= FPS_RTOL * r else None


def choose(name: str, motion: Motion) -> dict[str, Any] | None:
    """Which shipped file serves ``motion`` and how: dict(file, model_fps, mode) with mode
    ``'native'`` (the rates agree, or lou-chai's own phase split), ``'phases'`` (k
    interleaved phases, ``k`` in the dict) or ``'resample'``; None when no model fits the
    joint set (or the method has none)."""
    if not isinstance(motion, Motion):
        raise MocapValueError(f"shipped.load needs a mocapkit Motion, got {type(motion).__name__}")
    ent = [(f, e) for f, e in _entries(name) if _joints_match(name, e, motion)]
    if not ent:
        return None
    fps = float(motion.fps)
    for f, e in ent:
        if _ratio(fps, e["fps"]) == 1:
            return {"file": f, "model_fps": e["fps"], "mode": "native"}
    if name == "lou-chai":                      # phases / resampling built into the method
        return {"file": ent[0][0], "model_fps": ent[0][1]["fps"], "mode": "native"}
    if name in _RESAMPLE_UP:
        up = [(f, e) for f, e in ent if e["fps"] > fps]
        if up:
            f, e = min(up, key=lambda fe: fe[1]["fps"])
            return {"file": f, "model_fps": e["fps"], "mode": "resample"}
    multiples = [(f, e, _ratio(fps, e["fps"])) for f, e in ent]
    multiples = [x for x in multiples if x[2] is not None]
    if multiples:
        f, e, k = max(multiples, key=lambda x: x[1]["fps"])
        return {"file": f, "model_fps": e["fps"], "mode": "phases", "k": int(k)}
    f, e = min(ent, key=lambda fe: abs(np.log(fps / fe[1]["fps"])))
    return {"file": f, "model_fps": e["fps"], "mode": "resample"}


@functools.lru_cache(maxsize=8)
def _load_file(fname: str):
    return Denoiser.load(MODELS_DIR / fname)


def _fresh(fname: str):
    """A new estimator with the file's fitted state as float64 arrays (the cached load is
    never handed out, so a caller can change or refit what it gets)."""
    base = _load_file(fname)
    obj = type(base)(**base.get_params())
    for k, v in base._fitted_attrs().items():
        if isinstance(v, np.ndarray):
            v = v.astype(np.float64) if v.dtype.kind == "f" else v.copy()
        elif isinstance(v, list) and v and all(isinstance(a, np.ndarray) for a in v):
            v = [a.astype(np.float64) if a.dtype.kind == "f" else a.copy() for a in v]
        elif isinstance(v, (list, dict)):
            v = json.loads(json.dumps(v))
        setattr(obj, k, v)
    obj.shipped_model_ = fname
    return obj


def load(name: str, motion: Motion, **params):
    """A fitted estimator of method ``name`` for ``motion``, or None.

    ``params`` (already type-checked settings of the method) are set on the fitted model,
    inside the rate adapter where there is one.

    None when ``name`` has no shipped model or none matches the motion's joint set (the
    31-joint CMU/HDM05 Acclaim skeleton). Frame rates: see the module docstring -- at a
    model's own rate the plain fitted estimator is returned; otherwise a
    :class:`RateAdapter` around it (which handles the resampling inside ``denoise``).
    """
    c = choose(name, motion)
    if c is None:
        return None
    model = _fresh(c["file"])
    if params:
        model.set_params(**params)
    if c["mode"] == "native":
        return model
    return RateAdapter(model, float(c["model_fps"]))


class RateAdapter(Denoiser):
    """Run a fitted estimator trained at ``model_fps`` on a clip at another rate.

    A clip at k x ``model_fps`` (integer k) is split into its k interleaved phases
    (frames t, t+k, ...), each filtered at the model rate and interleaved again; any other
    rate is resampled to ``model_fps`` (cubic spline, :meth:`Motion.resample`), filtered
    and interpolated back (cubic spline) to the clip's frames. The wrapped estimator's
    ``name``, ``fill_evidence``, ``keeps_observed`` and ``misfit_check`` are reported as its own (observed
    samples are kept by a keeps_observed method only in the phase mode).
    """

    name = "rate-adapter"
    description = "a shipped model run at another frame rate (phases or resampling)"
    needs_training = False

    def __init__(self, model: Any = None, model_fps: float = 30.0):
        self.model = model
        self.model_fps = model_fps
        if model is not None:
            self.name = model.name
            self.description = model.description
            self.fill_evidence = model.fill_evidence
            self.keeps_observed = model.keeps_observed
            self.misfit_check = model.misfit_check

    def __repr__(self) -> str:
        return f"RateAdapter({self.model!r}, model_fps={self.model_fps:g})"

    def save(self, path) -> None:
        self.model.save(path)

    def denoise(self, motion: Motion) -> Motion:
        from .denoise.bases import decimate

        fps = float(self.model_fps)
        k = _ratio(float(motion.fps), fps)
        if k == 1:
            return self.model.denoise(motion)
        if k is not None and motion.n_frames >= k:
            P = np.empty(motion.positions.shape)
            for ph in range(k):
                part = decimate(motion, k, ph)
                P[ph::k] = self.model.denoise(part).positions
            return motion.with_positions(P)
        from scipy.interpolate import CubicSpline

        low = motion.resample(fps)
        if low.n_frames < 4:
            raise MocapValueError(f"{self.name}: the clip is too short ({motion.n_frames} frames at "
                                  f"{motion.fps:g} fps) to resample to the model's {fps:g} fps")
        den = self.model.denoise(low)
        t_low = np.arange(low.n_frames) / fps
        t = np.clip(np.arange(motion.n_frames) / float(motion.fps), 0.0, t_low[-1])
        Q = CubicSpline(t_low, den.positions.reshape(low.n_frames, -1), axis=0)(t)
        return motion.with_positions(Q.reshape(motion.positions.shape))
