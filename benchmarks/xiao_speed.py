"""Speed of the Xiao et al. 2015 implementation (xiao-sparse), one CPU core.

Usage: ``python benchmarks/xiao_speed.py [--data DIR] [--out FILE.md]``

Measures, with one BLAS thread (threadpoolctl):

1. K-SVD training of the five poselet dictionaries (K = 512, M = 21, T_s = 8, 10
   iterations, <= 8000 windows per poselet) on the dance training clips (CMU 05_02,
   05_03, 05_07), serial (``n_jobs=1``) and with two processes (``n_jobs=2``);
2. denoising throughput (frames per second, wall clock and process CPU time, best of 3)
   on CMU 05_05 (915 frames at 120 fps) for each noise model: Gaussian (l2/l1 ADMM),
   outliers (l1/l1 ADMM), mixed (both), and ``noise='auto'`` (detection included);
3. the solvers alone: Batch-OMP (ours, vectorised) vs scikit-learn's
   ``orthogonal_mp_gram`` on 2000 training windows; lasso ADMM vs FISTA -- relative
   objective gap to a 5000-iteration ADMM solution after k iterations, on every third
   left-arm window of the 20 dB test clip.

Numbers are machine dependent (this project's machine: 2 shared cores; the process CPU
time column is less sensitive to other load than the wall clock).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def _best(fn, reps: int = 3) -> tuple[float, float]:
    """(best wall s, best CPU s) over ``reps`` calls."""
    walls, cpus = [], []
    for _ in range(reps):
        w, c = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - w)
        cpus.append(time.process_time() - c)
    return min(walls), min(cpus)


def run(data_dir=None, log=print) -> tuple[str, list[dict]]:
    from threadpoolctl import threadpool_limits

    from mocapkit import corrupt, denoise, io
    from mocapkit.datasets import shared_data_dir
    from mocapkit.denoise.sparse import RANK_TOL

    root = shared_data_dir(data_dir)
    if root is None:
        raise SystemExit("needs the shared data set (--data DIR or MOCAPKIT_DATA)")
    d05 = root / "cmu" / "asfamc" / "05"
    train = [io.read(d05 / f"05_0{i}.amc") for i in (2, 3, 7)]
    test = io.read(d05 / "05_05.amc")
    rows: list[dict] = []
    lines = ["### Training (K-SVD, 5 poselets, K = 512, M = 21, T_s = 8, 10 iterations)", "",
             "| n_jobs | training windows / poselet | seconds (wall) |", "|---:|---:|---:|"]
    model = None
    for n_jobs in (1, 2):
        with threadpool_limits(1):
            m = denoise.get("xiao-sparse", n_jobs=n_jobs)
            t = time.perf_counter()
            m.fit(train)
            secs = time.perf_counter() - t
        nwin = sum(t.n_frames - m.window + 1 for t in train) // m.train_stride_
        lines.append(f"| {n_jobs} | {nwin} (stride {m.train_stride_}) | {secs:.1f} |")
        rows.append({"what": "train", "n_jobs": n_jobs, "seconds": secs, "windows": nwin})
        log(f"train n_jobs={n_jobs}: {secs:.1f} s")
        model = model or m
    ranks = [sv.rank for sv in model._solvers()]
    lines += ["", f"Truncated dictionary ranks used for coding (RANK_TOL = {RANK_TOL:g}): "
              f"{', '.join(f'{n} {r}' for n, r in zip(model.part_names_, ranks))} (of K = 512).", ""]

    lines += ["### Denoising throughput (CMU 05_05, 915 frames, one core)", "",
              "| noise model | condition | frames/s (wall) | frames/s (CPU) | detected |",
              "|---|---|---:|---:|---|"]
    conds = {"gaussian": [("gaussian", {"snr_db": 20})],
             "outliers": [("outliers", {"ratio": 0.1, "mode": "scale", "factor": 1.4})],
             "mixed": [("gaussian", {"snr_db": 20}), ("outliers", {"ratio": 0.1, "mode": "scale", "factor": 1.4})]}
    noisy = {k: corrupt.combine(test, v, seed=3)[0] for k, v in conds.items()}
    with threadpool_limits(1):
        model.denoise(noisy["gaussian"].slice(0, 50))                  # warm-up (SVD cache)
        for mode, key in (("gaussian", "gaussian"), ("outliers", "outliers"), ("mixed", "mixed"),
                          ("auto", "gaussian"), ("auto", "outliers"), ("auto", "mixed")):
            model.set_params(noise=mode)
            w, c = _best(lambda: model.denoise(noisy[key]))
            det = model.last_info.get("type")
            fw, fc = test.n_frames / w, test.n_frames / c
            lines.append(f"| {mode} | {key} | {fw:.0f} | {fc:.0f} | {det} |")
            rows.append({"what": "denoise", "noise": mode, "condition": key, "fps_wall": fw, "fps_cpu": fc,
                         "detected": det})
            log(f"denoise {mode}/{key}: {fw:.0f} fps wall, {fc:.0f} fps cpu")
        model.set_params(noise="auto")

    lines += ["", "### Solvers", ""]
    lines += _solver_bench(model, train, noisy["gaussian"], rows, log)
    return "\n".join(lines) + "\n", rows


def _solver_bench(model, train, noisy, rows, log) -> list[str]:
    import warnings

    from sklearn.linear_model import orthogonal_mp_gram
    from threadpoolctl import threadpool_limits

    from mocapkit.windows import lagged
    from mocapkit.signal import estimate_noise
    from mocapkit.frames import pelvis_neck_frame
    from mocapkit.solvers.ksvd import batch_omp
    from mocapkit.solvers.sparse_coding import lasso_admm, lasso_fista, lasso_objective

    i = model.part_names_.index("left_arm")
    D = np.asarray(model.dictionaries_[i])
    joints = np.asarray(model.parts_[i])
    s = model.frame_smooth_s

    def local(m):
        f = pelvis_neck_frame(m.positions, m.skeleton, m.fps, median_s=2 * s, sigma_s=s)
        return f.to_local(m.positions)

    def windows(m):
        L = local(m)
        return lagged(L[:, joints].reshape(m.n_frames, -1), model.window) - model.means_[i]

    Y = windows(train[0])[::max(1, (train[0].n_frames - 14) // 2000)][:2000]
    G, Xy = D.T @ D, Y @ D
    out = ["| Batch-OMP, 2000 windows, K = 512, T_s = 8 | seconds |", "|---|---:|"]
    with threadpool_limits(1), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        w_np, _ = _best(lambda: batch_omp(Xy, G, 8), 2)
        w_sk, _ = _best(lambda: orthogonal_mp_gram(G, Xy.T, n_nonzero_coefs=8), 1)
    out += [f"| ours (vectorised over windows) | {w_np:.2f} |",
            f"| scikit-learn orthogonal_mp_gram | {w_sk:.2f} |", ""]
    rows.append({"what": "omp", "ours_s": w_np, "sklearn_s": w_sk})
    log(f"omp: ours {w_np:.2f} s, sklearn {w_sk:.2f} s")

    Z = windows(noisy)[::3]
    sigma = estimate_noise(local(noisy).reshape(noisy.n_frames, -1), pool="median", fallback=0.0)
    lam = model.lam_factor * sigma ** 2
    with threadpool_limits(1):
        ref = lasso_admm(Z, D, lam, n_iter=5000, tol=0.0)
        f_ref = float(lasso_objective(Z, D, ref, lam).sum())
        out += [f"| iterations | lasso ADMM: objective gap | FISTA: objective gap |", "|---:|---:|---:|"]
        for k in (10, 20, 40, 100, 300):
            fa = float(lasso_objective(Z, D, lasso_admm(Z, D, lam, n_iter=k, tol=0.0), lam).sum())
            ff = float(lasso_objective(Z, D, lasso_fista(Z, D, lam, n_iter=k, tol=0.0), lam).sum())
            out.append(f"| {k} | {(fa - f_ref) / f_ref:.2e} | {(ff - f_ref) / f_ref:.2e} |")
            rows.append({"what": "lasso_gap", "iterations": k, "admm": (fa - f_ref) / f_ref,
                         "fista": (ff - f_ref) / f_ref})
    out += ["", f"(every 3rd left-arm window of the 20 dB clip, {Z.shape[0]} windows x {Z.shape[1]} values, "
                f"lambda = {lam:.3g} cm, float64, full-rank dictionary; objective gap relative to 5000 ADMM "
                f"iterations)"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data")
    ap.add_argument("--out", type=Path)
    a = ap.parse_args()
    md, _ = run(a.data)
    if a.out:
        a.out.write_text(md)
    print(md)


if __name__ == "__main__":
    from _report import method_time

    method_time(main)
