"""Record every registered method's output on fixed inputs, and compare two recordings.

The behaviour-unchanged check of a restructuring (issue #16): record before the change
(e.g. in a ``git worktree`` of the old commit), record after, compare. Inputs: the bundled
CMU 16_15 walk (240 frames) with 2 cm Gaussian noise, and with 1 cm noise + 5 % spikes +
10 % missing; the first 300 frames of a real marker capture with occlusions (kineticstoolkit
tennis serve) when ../shared/data is present. Data-driven methods are trained on frames
240-600 of the same clip (not on the marker file).

    cd OLD_TREE && python /path/to/benchmarks/method_outputs.py record old.npz
    cd NEW_TREE && python benchmarks/method_outputs.py record new.npz
    python benchmarks/method_outputs.py compare old.npz new.npz     # max |diff| per output, cm

``record`` imports mocapkit from the current directory (so it measures that tree). One BLAS
thread; ~30 s on one core.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import numpy as np

MARKERS = "../shared/data/markers/kineticstoolkit/kinematics_tennis_serve_nan.c3d"


def _inputs():
    from mocapkit import corrupt, datasets, io

    walk = io.read(datasets.bundled("16_15.amc"))
    clean = walk.slice(0, 240)
    cases = {"gauss": corrupt.combine(clean, "gaussian:sigma_cm=2", seed=1)[0],
             "mixed": corrupt.combine(clean, "gaussian:sigma_cm=1,outliers:ratio=0.05,missing:ratio=0.1",
                                      seed=2)[0]}
    if os.path.exists(MARKERS):
        m = io.read(MARKERS)
        cases["markers"] = m.slice(0, min(300, m.n_frames))
    return cases, [walk.slice(240, 600)]


def record(out: str, names: list[str]) -> None:
    sys.path.insert(0, os.getcwd())
    warnings.simplefilter("ignore")
    from mocapkit.denoise import available, get

    cases, train = _inputs()
    res: dict[str, np.ndarray] = {}
    for n in names or sorted(available()):
        cls = available()[n]
        for c, mot in cases.items():
            if c == "markers" and cls.needs_training:
                continue
            try:
                den = get(n)
                if cls.needs_training:
                    den.fit(train)
                t = time.perf_counter()
                res[f"{n}|{c}"] = den.denoise(mot).matrix()
                print(f"{n:22s} {c:8s} ok {time.perf_counter() - t:6.2f} s", flush=True)
            except Exception as e:                      # recorded: a refusal must stay a refusal
                res[f"{n}|{c}|ERR"] = np.array(repr(e)[:300])
                print(f"{n:22s} {c:8s} ERR {e!r:.150}", flush=True)
    np.savez(out, **res)


def compare(a_path: str, b_path: str, tol: float = 1e-6) -> int:
    a, b = np.load(a_path), np.load(b_path)
    bad = 0
    for k in sorted(set(a) | set(b)):
        if k not in a or k not in b:
            print(f"only in {'new' if k in b else 'old'}: {k}")
            bad += 1
            continue
        x, y = a[k], b[k]
        if x.dtype.kind in "US":
            if str(x) != str(y):
                print(f"error text differs: {k}")
                bad += 1
            continue
        d = float(np.nanmax(np.abs(x - y))) if x.size and x.shape == y.shape else np.inf
        nan = int((np.isnan(x) != np.isnan(y)).sum()) if x.shape == y.shape else -1
        if d > tol or nan:
            print(f"{k}: max |diff| {d:.3g} cm, NaN pattern differs in {nan} samples")
            bad += 1
    print(f"{bad} of {len(set(a) | set(b))} outputs differ by more than {tol:g} cm")
    return bad


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("out")
    r.add_argument("methods", nargs="*")
    c = sub.add_parser("compare")
    c.add_argument("old")
    c.add_argument("new")
    c.add_argument("--tol", type=float, default=1e-6)
    a = ap.parse_args()
    if a.cmd == "record":
        record(a.out, a.methods)
    else:
        compare(a.old, a.new, a.tol)


if __name__ == "__main__":
    main()
