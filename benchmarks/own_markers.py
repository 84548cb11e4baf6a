"""Does training on a lab's own marker set pay? Models trained on one subject's take, run on
another subject's capture of the same motion, against ``auto`` (no training). Writes
docs/results/own_markers.json + .md.

Usage: ``python benchmarks/own_markers.py [--data DIR] [--render-only]``

Data (kineticstoolkit's tennis serves, Vicon Plug-in Gait names, 39 markers, 50 Hz):

* **training take**: ``kinematics_tennis_serve.c3d`` -- Derrick, 1,092 frames (the vendor's
  gap-filled take; ``mocapkit train`` as a lab would run it, defaults);
* **test capture**: Viktor's 39 markers of ``kinematics_tennis_serve_2players.c3d`` -- 599
  frames, nothing missing, markers named ``Viktor:...`` (the models learned ``Derrick:...``:
  they are matched by bare name, :func:`mocapkit.denoise.base.trained_joint_map`).

Conditions on Viktor's capture (the truth): the ``auto`` protocol's Gaussian 1 / 3 cm,
spikes and mixed noise (:data:`mocapkit.bench.protocols.auto.CONDITIONS`, seed 0), and the
real occlusion patterns of the ``real-gaps`` protocol's sources laid over it
(:func:`mocapkit.occlusion.transplant_mask`, the protocol's seeds). Every method runs as
``mocapkit denoise`` would (the default gap policy: a fill it cannot support is left
missing, a measured sample moved without cause is given back). Scores: RMSE (cm) over
every sample for noise; for gaps, RMSE over the hidden samples the method filled and the
share it filled (coverage). One BLAS thread; about 2 minutes.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from collections import defaultdict  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from _report import run_or_render  # noqa: E402
from mocapkit import corrupt, io  # noqa: E402
from mocapkit.bench.protocols import auto as A  # noqa: E402
from mocapkit.bench.protocols import real_gaps as R  # noqa: E402
from mocapkit.denoise import get  # noqa: E402
from mocapkit.errors import MocapError  # noqa: E402
from mocapkit.occlusion import apply_mask, transplant_mask  # noqa: E402

OUT = ROOT / "docs" / "results" / "own_markers.md"
TRAINED = ("xiao-sparse", "psc", "lou-chai", "kalman-learned")
NOISE = ("gauss1", "gauss3", "spikes", "mixed")


def _quiet(fn, *a):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fn(*a)


def run(data: Path, args) -> dict:
    k = data / "markers" / "kineticstoolkit"
    train = _quiet(io.read, k / "kinematics_tennis_serve.c3d")
    both = _quiet(io.read, k / "kinematics_tennis_serve_2players.c3d")
    test = both.select([n for n in both.skeleton.names if n.startswith("Viktor:")])
    models, train_s = {}, {}
    for name in TRAINED:
        t0 = time.perf_counter()
        models[name] = _quiet(get(name).fit, [train])
        train_s[name] = time.perf_counter() - t0
    methods = {"auto": get("auto"), **models}
    rows = []
    truth = test.positions

    def score(cond: str, kind: str, inp, hidden=None):
        for name, den in methods.items():
            t0 = time.perf_counter()
            try:
                out = _quiet(den.denoise, inp)
            except MocapError as e:
                rows.append({"condition": cond, "kind": kind, "method": name, "error": str(e)[:160]})
                continue
            dt = time.perf_counter() - t0
            sel = out.observed if hidden is None else out.observed & hidden
            err = (out.positions - truth)[sel]
            n_all = int(np.count_nonzero(hidden if hidden is not None else np.ones_like(out.observed)))
            rows.append({"condition": cond, "kind": kind, "method": name,
                         "rmse": float(np.sqrt(np.mean(err ** 2))) if err.size else None,
                         "sse": float(np.sum(err ** 2)), "n": int(err.shape[0]), "n_all": n_all,
                         "seconds": dt})
            print(rows[-1], flush=True)

    for cond in NOISE:
        noisy, _ = corrupt.combine(test, A.CONDITIONS[cond], seed=0)
        score(cond, "noise", noisy)
    sources, _ = R.find_sources(data)
    for skey, src in sources:
        seed = R.case_seed(0, skey, "viktor")
        tr = transplant_mask(src.observed, src.fps, test.n_frames, test.n_joints, test.fps, seed=seed)
        inp = apply_mask(test, tr.observed)
        if (~inp.observed).any():
            score(f"mask={R.short(skey)} ({100 * inp.missing_fraction:.1f} % missing)", "gaps", inp,
                  ~inp.observed)
    return {"rows": rows, "train_seconds": train_s, "train_frames": train.n_frames,
            "test_frames": test.n_frames, "markers": test.n_joints}


def render(doc: dict) -> str:
    rows = doc["rows"]
    names = ["auto", *TRAINED]
    by = defaultdict(dict)
    for r in rows:
        by[(r["kind"], r["condition"])][r["method"]] = r
    lines = ["# Training on a lab's own marker set: one subject's take, another subject's capture", "",
             f"Generated by `python benchmarks/own_markers.py` from own_markers.json ({doc['seconds']:.0f} s, one "
             "BLAS thread); see the script's docstring. Trained on Derrick's tennis serve "
             f"({doc['train_frames']} frames), run on Viktor's ({doc['test_frames']} frames, "
             f"{doc['markers']} Plug-in Gait markers, 50 Hz) under the default gap policy. Training time (s): "
             + ", ".join(f"{k} {v:.1f}" for k, v in doc["train_seconds"].items()) + ".", "",
             "## Noise: RMSE (cm) over every sample", "",
             "| condition | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for (kind, cond), d in by.items():
        if kind == "noise":
            lines.append(f"| {cond} | " + " | ".join(
                (f"{d[m]['rmse']:.3f}" if d.get(m, {}).get("rmse") is not None else "refused")
                for m in names) + " |")
    lines += ["", "## Real occlusion patterns: RMSE (cm) of the fills written, and coverage", "",
              "| mask | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    pooled = defaultdict(lambda: [0.0, 0, 0])
    for (kind, cond), d in by.items():
        if kind != "gaps":
            continue
        cells = []
        for m in names:
            r = d.get(m, {})
            if r.get("n"):
                cells.append(f"{r['rmse']:.2f} ({100 * r['n'] / r['n_all']:.0f} %)")
                pooled[m][0] += r["sse"]
                pooled[m][1] += r["n"]
            else:
                cells.append("refused" if "error" in r else f"- (0 %)")
            pooled[m][2] += r.get("n_all", 0)
        lines.append(f"| {cond} | " + " | ".join(cells) + " |")
    lines.append("| **pooled** | " + " | ".join(
        f"**{np.sqrt(p[0] / (3 * p[1])):.2f} ({100 * p[1] / max(p[2], 1):.0f} %)**" if p[1] else "-"
        for p in (pooled[m] for m in names)) + " |")
    errs = [f"{r['method']} on {r['condition']}: {r['error']}" for r in rows if "error" in r]
    if errs:
        lines += ["", "Refused: " + "; ".join(errs)]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(run_or_render(OUT, run, render, __doc__.splitlines()[0]))
