"""auto's low-rank refinement of short holes, on and off (issue #19).

Usage: ``python benchmarks/auto_lowrank.py [--data DIR] [--render-only]``.
Writes docs/results/auto_lowrank.json + .md. One BLAS thread.

``auto`` refines the short holes of a noise-free clip by iterative low-rank imputation
(:func:`mocapkit.denoise.auto._lowrank_fill`). Here it runs with the refinement (the
default) and without it (``LOWRANK_PASSES = 0``: the validation run does nothing, so no
point takes it) on -- both with the validated bone step that follows it in ASF/AMC files
(:func:`mocapkit.denoise.auto._bone_fill`, since 2026-12-05; without the refinement it
starts from the spline and partner fills) -- on:

* ten CMU clips that neither the ``auto`` protocol nor its held-out set uses, and that
  took part in no choice of the refinement (05_01, 05_05, 07_05, 131_01 / 04 / 09 / 14,
  135_03 / 06 / 11; they were one of the three sets the 4-frame step below 60 fps,
  ``LOWRANK_WINDOW_LOW_FPS``, was checked on before it was kept, 2026-12-05), first 8 s at 120 fps and resampled to 30 fps, with the protocol's
  ``missing30`` (30 % of the joints removed in every frame) and ``spikes`` (10 % of the
  samples moved 15 cm), seed = clip index, every gap fillable (``FILL_ALL``) as in the
  protocol: RMSE (cm, all coordinates auto wrote: a hole no fill validated under 5 cm is
  left missing and not scored, as in the protocol), auto's estimate,
  the oracle-tuned classical filter (:func:`mocapkit.bench.protocols.auto.oracle_classical`);
* speed: CMU 131_03 tiled to 10,000 frames (120 fps, 31 joints; every other tile played
  backwards, so that the tiles join without a jump), 30 % missing, CPU seconds of
  ``denoise()`` (best of 2), frames/s.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mocapkit import corrupt, io, metrics  # noqa: E402
from mocapkit.bench.protocols import auto as P  # noqa: E402
from mocapkit.datasets import shared_data_dir  # noqa: E402
from mocapkit.denoise import auto as A, get  # noqa: E402
from mocapkit.gaps import FILL_ALL, use_policy  # noqa: E402
from mocapkit.motion import Motion  # noqa: E402

OUT = ROOT / "docs" / "results" / "auto_lowrank.md"
CLIPS = tuple((c, f"cmu/asfamc/{c.split('_')[0]}/{c}.amc")
              for c in "05_01 05_05 07_05 131_01 131_04 131_09 131_14 135_03 135_06 135_11".split())
CONDITIONS = ("missing30", "spikes")


def _auto(noisy: Motion, passes: int, bones: bool = True) -> tuple[Motion, float]:
    """auto with ``passes`` validation passes (0: no refinement), with or without the bone
    step (:func:`mocapkit.denoise.auto._bone_fill`), and its CPU seconds."""
    keep, keep_bones = A.LOWRANK_PASSES, A._bone_fill
    A.LOWRANK_PASSES = passes
    if not bones:
        A._bone_fill = lambda motion, usable, X, kept, out, *a: (out, None)
    try:
        t0 = time.process_time()
        with warnings.catch_warnings(), use_policy(FILL_ALL):     # as the auto protocol
            warnings.simplefilter("ignore")
            out = get("auto").denoise(noisy)
        return out, time.process_time() - t0
    finally:
        A.LOWRANK_PASSES, A._bone_fill = keep, keep_bones


def run(data: Path) -> dict:
    rows = []
    for i, (label, clip) in enumerate(P.load_clips(data, False, 8.0, CLIPS)):
        for fps in (30, 120):
            truth = clip if fps == 120 else clip.resample(float(fps))
            for cond in CONDITIONS:
                noisy, _ = corrupt.combine(truth, P.CONDITIONS[cond], seed=i)
                row = {"clip": f"{label}@{fps}", "condition": cond, "fps": fps,
                       "oracle": P.oracle_classical(truth, noisy)}
                for tag, passes in (("off", 0), ("on", A.LOWRANK_PASSES)):
                    out, dt = _auto(noisy, passes)
                    row[tag] = metrics.rmse(truth, out, mask=out.observed)   # what it wrote
                    row[tag + "_est"] = out.source["auto"]["estimated_rmse_cm"]
                    row[tag + "_s"] = dt
                rows.append(row)
                print(row, flush=True)
    clip = io.read(data / "cmu" / "asfamc" / "131" / "131_03.amc")
    T = 10_000
    # tiled forwards and backwards, so that the tiles join without a jump (tiled forwards
    # only, the body jumps back at each seam and auto -- since 2026-12-05 -- cleans each
    # tile on its own: whole_body_jumps)
    reps = int(np.ceil(T / clip.n_frames))
    pos = np.concatenate([clip.positions if k % 2 == 0 else clip.positions[::-1] for k in range(reps)])[:T]
    long = Motion(pos, clip.skeleton, clip.fps, np.ones(pos.shape[:2], bool), dict(clip.source))
    noisy, _ = corrupt.combine(long, P.CONDITIONS["missing30"], seed=0)
    speed = {}
    for tag, passes, bones in (("off", 0, True), ("on", A.LOWRANK_PASSES, True),
                               ("on_no_bones", A.LOWRANK_PASSES, False)):
        speed[tag] = min(_auto(noisy, passes, bones)[1] for _ in range(2))
    return {"rows": rows, "speed": {"frames": T, **speed}}


def _in(e, v) -> bool:
    return e is not None and v > 0 and 1 / 1.5 <= e / v <= 1.5


def render(doc: dict) -> str:
    rows, sp = doc["rows"], doc["speed"]
    out = ["# auto: low-rank refinement of short holes, on and off (issue #19)", "",
           "Generated by `benchmarks/auto_lowrank.py` from auto_lowrank.json (see its docstring: ten CMU "
           "clips in neither clip set of the `auto` protocol and used for no choice, 8 s, one BLAS thread). "
           "RMSE in cm over all coordinates.", "",
           "| condition | n | mean RMSE off | on | worst on / off | worst auto / oracle off | on | "
           "estimate within 1.5x off | on |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for cond in CONDITIONS:
        for fps in (30, 120):
            rs = [r for r in rows if r["condition"] == cond and r["fps"] == fps]
            if not rs:
                continue
            out.append(f"| {cond}@{fps} | {len(rs)} | {np.mean([r['off'] for r in rs]):.4f} | "
                       f"{np.mean([r['on'] for r in rs]):.4f} | {max(r['on'] / r['off'] for r in rs):.3f} | "
                       f"{max(r['off'] / r['oracle'] for r in rs):.2f} | {max(r['on'] / r['oracle'] for r in rs):.2f} | "
                       f"{sum(_in(r['off_est'], r['off']) for r in rs)} | {sum(_in(r['on_est'], r['on']) for r in rs)} |")
    out += ["", f"Speed ({sp['frames']:,} frames of CMU 131_03 tiled forwards and backwards, 120 fps, 31 joints, 30 % missing; CPU "
                f"seconds, best of 2): off {sp['off']:.2f} s ({sp['frames'] / sp['off']:,.0f} frames/s), "
                f"on {sp['on']:.2f} s ({sp['frames'] / sp['on']:,.0f} frames/s)"
                + (f"; on without the bone step that follows it {sp['on_no_bones']:.2f} s "
                   f"({sp['frames'] / sp['on_no_bones']:,.0f} frames/s)" if "on_no_bones" in sp else "")
                + ". (Both columns above run the bone step after the fills, where it validates.)", "",
            "| clip | condition | oracle | off | on | est. off | est. on |", "|---|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['clip']} | {r['condition']} | {r['oracle']:.4f} | {r['off']:.4f} | {r['on']:.4f} | "
                   f"{r['off_est']:.4f} | {r['on_est']:.4f} |")
    return "\n".join(out) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=None)
    ap.add_argument("--render-only", action="store_true")
    a = ap.parse_args()
    js = OUT.with_suffix(".json")
    if not a.render_only:
        data = a.data or shared_data_dir()
        if data is None:
            sys.exit("auto_lowrank: ../shared/data not found (--data DIR)")
        js.write_text(json.dumps(run(Path(data)), indent=1))
    OUT.write_text(render(json.loads(js.read_text())))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
