"""Train the shipped general models (issue #19 item 1) into ``mocapkit/data/models/``.

Usage: ``python benchmarks/train_shipped.py [--data DIR] [--out DIR] [--methods ...]
[--rates 30 120] [--all-subjects]``

One model per method and frame rate, trained once on every usable ASF/AMC clip of the
shared data (CMU and HDM05 share the 31-bone Acclaim skeleton: same joint names in the
same order) except the held-out evaluation subjects :data:`HELD_OUT` (``--all-subjects``
trains on them too; the shipped files are trained without them, so that benchmarks on
those subjects measure unseen people). Clips are brought to each model's rate by taking
every k-th frame in all k phases (120 -> 30 fps: four 30 fps clips per clip, no
interpolation; :func:`mocapkit.denoise.bases.decimate`).

The fitted arrays are stored as float16 (``--dtype``; :func:`mocapkit.shipped.load` casts
them back to float64); ``index.json`` next to the files records, per file, the method, frame
rate, joint names, training clips, held-out subjects and size. The cost of float16 is
measured by ``benchmarks/shipped_models.py`` (docs/results/shipped_models.md).

The CMU ``cgspeed`` BVH conversions (31 joints, other names) are *not* mapped: their joints
are the Acclaim bones' start points (``LHipJoint`` sits on ``Hips``, ``LeftUpLeg`` on the
ASF ``lhipjoint`` end point, ...) and the five leaf bones' end points (toes, head, fingers,
thumbs) are BVH end sites that the reader does not return, so no renaming table gives the
ASF joint set.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mocapkit.datasets import shared_data_dir  # noqa: E402

#: held-out evaluation subjects: CMU subject ids and HDM05 actors (never in the shipped models)
HELD_OUT = {"cmu": ("01", "05", "09", "16", "35", "49", "135"), "hdm05": ("mm",)}

#: behaviour of every CMU ASF/AMC trial in the shared data (from its description)
CMU_BEHAVIOUR = {
    "01_01": "jump", "05_01": "walk", "05_02": "dance", "05_03": "dance", "05_05": "dance",
    "05_07": "dance", "07_03": "walk", "07_05": "walk", "09_06": "run", "11_01": "kicks",
    "16_15": "walk", "35_01": "walk", "49_18": "balance", "49_19": "balance",
    "131_01": "walk", "131_02": "walk", "131_03": "jump", "131_04": "jump", "131_05": "duck",
    "131_07": "jump", "131_08": "jump", "131_09": "walk", "131_11": "walk", "131_12": "walk",
    "131_14": "walk", "135_02": "martial arts", "135_03": "martial arts",
    "135_04": "kicks", "135_05": "martial arts", "135_06": "martial arts",
    "135_08": "martial arts", "135_09": "martial arts", "135_11": "kicks",
}

#: HDM05 class -> behaviour group (the class name is kept as its own behaviour too)
HDM05_GROUP = {"jogLeftCircle4StepsRstart": "run", "sneak2StepsLStart": "walk",
               "hopBothLegs1hops": "jump", "kickLFront1Reps": "kicks",
               "rotateArmsBothBackward1Reps": "arms", "elbowToKnee1RepsLelbowStart": "arms"}

#: model settings per method; the rest are the method's defaults. More training windows
#: than the defaults (8000 / 3000) for the general xiao-sparse / psc models. lou-chai:
#: docs/results/lou_chai.md's "better setting for noise and outliers" -- with the paper's
#: 99 % energy the general model keeps 81 bases and is worse than the noisy input on
#: behaviours it never saw (CMU dance 05_02, 30 fps, 3 cm noise: 3.15 cm vs 2.98; martial
#: arts 135_06: 3.40), with 99.9 %, mirrored clips and lam 0.2 (227 bases) 1.25 / 1.39 cm
PARAMS = {
    "xiao-sparse": {"max_train_windows": 16000},
    "psc": {"max_windows": 8000},
    "lou-chai": {"energy": 0.999, "mirror": True, "lam": 0.2},
}
RATES = (30, 120)


def catalogue(data_dir=None) -> list[dict]:
    """Every ASF/AMC clip of the shared data: dict(path, dataset, subject, trial,
    behaviour, group, held_out)."""
    root = shared_data_dir(data_dir)
    if root is None:
        raise SystemExit("shared data not found (../shared/data or $MOCAPKIT_DATA)")
    out = []
    for p in sorted((root / "cmu" / "asfamc").rglob("*.amc")):
        trial = p.stem
        subj = trial.split("_")[0]
        beh = CMU_BEHAVIOUR.get(trial, "other")
        out.append({"path": str(p), "dataset": "cmu", "subject": subj, "trial": trial,
                    "behaviour": beh, "group": beh, "held_out": subj in HELD_OUT["cmu"]})
    for p in sorted((root / "hdm05" / "asfamc").rglob("*.amc")):
        actor = p.name.split("_")[1]
        cls = p.parent.name if p.parent.name != "takes" else "take"
        out.append({"path": str(p), "dataset": "hdm05", "subject": actor, "trial": p.stem,
                    "behaviour": f"HDM05 {cls}", "group": HDM05_GROUP.get(cls, "other"),
                    "held_out": actor in HELD_OUT["hdm05"]})
    return out


def read(path: str):
    import mocapkit.io as mio

    return mio.read(path)


def at_rate(motion, fps: float) -> list:
    """The clip at ``fps``: all phases of an integer decimation, else a resampling."""
    from mocapkit.denoise.bases import decimate

    r = motion.fps / fps
    k = int(round(r))
    if k >= 1 and abs(r - k) < 1e-3 * r:
        return [decimate(motion, k, ph) for ph in range(k)]
    return [motion.resample(fps)]


def training_set(clips: list[dict], fps: float, motions: dict | None = None) -> list:
    """Motions of ``clips`` at ``fps`` (every phase), ``motions`` a path -> Motion cache."""
    out = []
    for c in clips:
        m = motions[c["path"]] if motions is not None and c["path"] in motions else read(c["path"])
        out += at_rate(m, fps)
    return out


def fit(method: str, motions: list, params: dict | None = None):
    from mocapkit import denoise

    return denoise.get(method, **(PARAMS[method] if params is None else params)).fit(motions)


def _cast(a: np.ndarray, dt: np.dtype) -> np.ndarray:
    """``a`` as ``dt`` when it stays finite (float16 ends at 65504; eigenvalues in cm^2 do
    not fit), else as float32."""
    if a.dtype.kind != "f":
        return a
    with np.errstate(over="ignore"):
        b = a.astype(dt)
    return b if np.isfinite(b).all() == np.isfinite(a).all() else a.astype(np.float32)


def to_dtype(model, dtype: str):
    """Cast the model's float fitted arrays (and lists of arrays) to ``dtype`` in place."""
    dt = np.dtype(dtype)
    for k, v in list(model._fitted_attrs().items()):
        if isinstance(v, np.ndarray):
            setattr(model, k, _cast(v, dt))
        elif isinstance(v, list) and v and all(isinstance(a, np.ndarray) for a in v):
            setattr(model, k, [_cast(a, dt) for a in v])
    return model


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None)
    ap.add_argument("--out", default=str(ROOT / "mocapkit" / "data" / "models"))
    ap.add_argument("--methods", nargs="+", default=list(PARAMS))
    ap.add_argument("--rates", nargs="+", type=float, default=list(RATES))
    ap.add_argument("--dtype", default="float16")
    ap.add_argument("--all-subjects", action="store_true")
    ap.add_argument("--keep-f64", default=None, help="also save the float64 models in this folder")
    ap.add_argument("--recast", default=None, help="no training: re-cast the float64 models of "
                    "this folder (saved by --keep-f64) to --dtype into --out and update index.json")
    a = ap.parse_args(argv)
    from mocapkit.io import read as _r  # noqa: F401  (fail early)

    if a.recast:
        from mocapkit.denoise.base import Denoiser

        out = Path(a.out)
        idx_path = out / "index.json"
        index = json.loads(idx_path.read_text())
        for fname in sorted(index):
            src = Path(a.recast) / fname
            if not src.is_file() or index[fname]["method"] not in a.methods:
                continue
            to_dtype(Denoiser.load(src), a.dtype).save(out / fname)
            index[fname].update(dtype=a.dtype, bytes=(out / fname).stat().st_size)
            print(f"{fname}: re-cast to {a.dtype}, {(out / fname).stat().st_size / 1e6:.2f} MB")
        idx_path.write_text(json.dumps(index, indent=1) + "\n")
        return 0
    cat = catalogue(a.data)
    train = [c for c in cat if a.all_subjects or not c["held_out"]]
    held = sorted({f"{c['dataset']} {c['subject']}" for c in cat if c["held_out"]}) if not a.all_subjects else []
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    idx_path = out / "index.json"
    index = json.loads(idx_path.read_text()) if idx_path.is_file() else {}
    cache = {c["path"]: read(c["path"]) for c in train}
    names = list(next(iter(cache.values())).skeleton.names)
    for m in cache.values():
        assert list(m.skeleton.names) == names, m
    behaviours = sorted({c["behaviour"] if c["dataset"] == "cmu" else "HDM05 " + c["group"]
                         for c in train})
    for method in a.methods:
        # lou-chai works at 30 fps and filters a 120 fps clip as its interleaved 30 fps
        # phases by itself: one model serves every multiple of 30 fps
        rates = [30.0] if method == "lou-chai" else a.rates
        for fps in rates:
            mot = training_set(train, fps, cache)
            t0 = time.perf_counter()
            model = fit(method, mot)
            sec = time.perf_counter() - t0
            fname = f"{method}-{int(fps)}fps.npz"
            if a.keep_f64:
                Path(a.keep_f64).mkdir(parents=True, exist_ok=True)
                model.save(Path(a.keep_f64) / fname)
            to_dtype(model, a.dtype)
            model.save(out / fname)
            n_frames = int(sum(m.n_frames for m in mot))
            index[fname] = {
                "method": method, "fps": float(fps), "joint_names": names, "dtype": a.dtype,
                "params": PARAMS[method],
                "n_clips": len(train), "n_frames": n_frames,
                "datasets": {d: sorted({c["subject"] for c in train if c["dataset"] == d})
                             for d in ("cmu", "hdm05")},
                "behaviours": behaviours, "held_out": held,
                "train_seconds": round(sec, 1), "bytes": (out / fname).stat().st_size,
            }
            print(f"{fname}: {len(train)} clips, {n_frames} frames at {fps:g} fps, "
                  f"{sec:.0f} s, {(out / fname).stat().st_size / 1e6:.2f} MB", flush=True)
            idx_path.write_text(json.dumps(index, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
