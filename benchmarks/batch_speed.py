"""Measure `mocapkit batch` throughput (files/s, frames/s) for 1 and 2 local workers.

Input: a copy of part of the shared data set (MSR-Action3D skeletons, the marker files,
the CMU BVH files) plus one deliberately broken BVH; default method. Writes
docs/results/batch.md. Run: .venv/bin/python benchmarks/batch_speed.py [--data DIR]
"""
from __future__ import annotations

import argparse
import os
import platform
import shutil
import tempfile
import time
from pathlib import Path

from mocapkit import denoise
from mocapkit.batch import run_batch
from mocapkit.datasets import shared_data_dir

OUT = Path(__file__).resolve().parent.parent / "docs" / "results" / "batch.md"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data")
    a = ap.parse_args()
    data = shared_data_dir(a.data)
    if data is None:
        raise SystemExit("shared data not found (--data DIR)")
    with tempfile.TemporaryDirectory() as tmp:
        lib = Path(tmp) / "lib"
        for sub in ("msr_action3d/skeleton3d", "markers", "cmu/bvh/cgspeed_motionbuilder", "cmu/bvh/daz_friendly"):
            shutil.copytree(data / sub, lib / sub)
        (lib / "broken.bvh").write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n")
        rows = []
        for workers in (1, 2):
            out = Path(tmp) / f"out{workers}"
            t0 = time.perf_counter()
            s = run_batch(lib, out, method=denoise.DEFAULT_METHOD, params=dict(denoise.DEFAULT_PARAMS),
                          workers=workers, progress=False)
            wall = time.perf_counter() - t0
            failed = [r for r in s.results if r.status == "failed"]
            rows.append((workers, s.ok, s.failed, s.frames, wall, failed))
            # resume check: a second run does nothing but verify
            t1 = time.perf_counter()
            s2 = run_batch(lib, out, method=denoise.DEFAULT_METHOD, params=dict(denoise.DEFAULT_PARAMS),
                           workers=workers, progress=False)
            rows[-1] += (s2.skipped, s2.ok, time.perf_counter() - t1)
    load = os.getloadavg()[0]
    lines = ["# Batch cleaning throughput", "",
             f"Produced by `benchmarks/batch_speed.py` on {time.strftime('%Y-%m-%d')} ({platform.machine()}, "
             f"{os.cpu_count()} cores, load average {load:.1f} at the end; other jobs may have been running). "
             f"Library: MSR-Action3D skeleton files, the marker files (C3D/TRC), the CMU cgspeed and Daz BVH "
             f"files from the shared data set, plus one deliberately broken BVH. Method: "
             f"`{denoise.DEFAULT_METHOD}` {denoise.DEFAULT_PARAMS}. Wall time includes reading, cleaning and "
             f"atomic writing (BVH write-back runs IK).", "",
             "| workers | files ok | failed | frames | wall s | files/s | frames/s | rerun: skipped / redone | rerun s |",
             "|---:|---:|---:|---:|---:|---:|---:|---|---:|"]
    for w, ok, fail, frames, wall, failed, sk, redo, rerun in rows:
        lines.append(f"| {w} | {ok} | {fail} | {frames} | {wall:.1f} | {(ok + fail) / wall:.2f} | "
                     f"{frames / wall:.0f} | {sk} / {redo} | {rerun:.1f} |")
    lines += ["", "Files reported as failed (one line each, the rest went on):", ""]
    for r in rows[0][5]:
        lines.append(f"- `{r.input}`: {r.reason}")
    OUT.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
