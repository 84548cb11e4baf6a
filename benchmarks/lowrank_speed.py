"""Throughput (frames/s, one thread) of the low-rank methods on a 5000-frame CMU clip.

Usage: ``python benchmarks/lowrank_speed.py [--data DIR] [--frames 5000] [--repeats 3]``

The clip is CMU 135_02 (5202 frames, 31 joints = 93 coordinates, 120 fps), cut to the
first 5000 frames and corrupted with the SLRA noise of eq. 7 in CMU units (1/3 of the
frames; the clip stays in cm and the noise is scaled to cm, as in the protocol
``slra-table2``: the gap policy's floors are in cm; FD is reported in CMU units); without the shared data set a bundled clip is tiled to 5000 frames.  Each method
runs ``repeats`` times under a one-thread BLAS limit and the median CPU time (process time,
so other processes on a shared machine do not count) is reported (denoise() only, Motion
handling included).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mocapkit import denoise, io  # noqa: E402
from mocapkit.datasets import bundled, cmu_amc, shared_data_dir  # noqa: E402
from mocapkit.io.units import CMU_CM_PER_UNIT  # noqa: E402


METHODS = (
    ("slra (paper: 200-frame segments, tol 1e-7)", "slra", {}),
    ("slra (200-frame segments, tol 1e-4)", "slra", {"tol": 1e-4}),
    ("slra(seg=24,ov=12) (tol 1e-5)", "slra", {"segment": 24, "overlap": 12, "tol": 1e-5}),
    ("slra(seg=24,ov=0) (tol 1e-5)", "slra", {"segment": 24, "tol": 1e-5}),
    ("rpca (whole clip, tol 1e-7)", "rpca", {}),
    ("tsvd (k=10)", "tsvd", {}),
    ("svt (closed form, noise estimated)", "svt", {}),
)


def load_clip(frames: int = 5000, data_dir: str | None = None):
    """(clip name, clean motion in cm, noisy motion) with ``frames`` frames."""
    from mocapkit import corrupt

    path = cmu_amc("135_02", shared_data_dir(data_dir))
    if path is not None:
        m = io.read(path)
        name = "135_02"
    else:
        m = io.read(bundled("16_15.amc"))
        name = "16_15 (tiled)"
    if m.n_frames < frames:
        reps = int(np.ceil(frames / m.n_frames))
        P = np.concatenate([m.positions] * reps)[:frames]
        m = m.with_positions(P)
    m = m.slice(0, frames)
    noisy, _ = corrupt.slra_noise(m, n_frames=frames // 3, eps=1.0, sigma=1.2, seed=0, scale=CMU_CM_PER_UNIT)
    return name, m, noisy


def measure(frames: int = 5000, repeats: int = 3, data_dir: str | None = None) -> tuple[str, list[dict]]:
    """Median-of-``repeats`` CPU frames/s per method (one BLAS thread)."""
    from threadpoolctl import threadpool_limits

    from mocapkit import metrics

    name, clean, noisy = load_clip(frames, data_dir)
    out = []
    with threadpool_limits(1):
        for label, method, params in METHODS:
            d = denoise.get(method, **params)
            ts = []
            for _ in range(repeats):
                t0 = time.process_time()
                est = d.denoise(noisy)
                ts.append(time.process_time() - t0)
            best = float(np.median(ts))
            out.append({"method": label, "seconds": best, "frames_per_s": frames / best,
                        "fd": float(metrics.frobenius_distance(clean, est)) / CMU_CM_PER_UNIT})
    return name, out


def to_markdown(name: str, rows: list[dict], frames: int) -> str:
    import os

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [f"Clip {name}, first {frames} frames x 93 coordinates, eq.-7 noise on 1/3 of the "
             f"frames (CMU units); one BLAS thread; CPU seconds, median of 3 runs; {os.cpu_count()} CPUs, "
             f"1-min load average {load:.1f} when the table was written (the machine is "
             f"shared: a load above the CPU count still slows these CPU times through the "
             f"shared caches).", "",
             "| method | seconds | frames/s | FD (CMU units) |", "|---|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['method']} | {r['seconds']:.3f} | {r['frames_per_s']:,.0f} | {r['fd']:.4f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None)
    ap.add_argument("--frames", type=int, default=5000)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args(argv)
    name, rows = measure(a.frames, a.repeats, a.data)
    print(to_markdown(name, rows, a.frames))
    return 0


if __name__ == "__main__":
    from _report import method_time

    raise SystemExit(method_time(main))
