"""Scaling benchmark (issue 21, item 5): frames/s and peak memory of every registered method
at 1k, 10k, 100k (and 1M where it fits) frames, one thread, each run in its own process.

Usage::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/scaling.py [--frames 1000 10000 100000 1000000]
        [--methods slra trnn ...] [--budget 40] [--out docs/results/scaling]

Input: CMU 135_02 (31 joints = 93 coordinates, 120 fps; bundled 16_15 without the shared
data) tiled in time to N frames, 0.5 cm Gaussian noise on every coordinate (cm).  Matrix
size = N x 93 x 8 bytes (7.4 MB at 10k frames).  Methods that need training are fitted on
1,000 frames of a different clip (CMU 16_15) with their ``quick_params`` before the timed
call (fit time not counted).  Each (method, N) runs in a fresh subprocess with
OMP/OpenBLAS/MKL at 1 thread; the timed call is ``denoise()`` (CPU seconds, median of 3
below 2 s per run, else one run).  Memory: the kernel's resident high-water mark is reset
(/proc/self/clear_refs) after the input is built, so "peak" is the peak RSS during
``denoise()``; "growth / input" = (peak - RSS before the call) / matrix bytes.
A size is skipped when the previous size predicts more than ``--budget`` seconds per run
or more than 4 GB.  Low-rank methods report the FLOP model of docs/results/scaling.md
(``flops`` from :func:`flop_model`) and ideal frames/s at the measured dgemm rate.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# one thread; and numpy's transparent-huge-page advice off, as the command line sets it
# (mocapkit.cli._no_hugepages): with it, this VM's 2 MB page faults made one 100k-frame
# butterworth run take 0.9-2.3 s CPU from run to run (44k-143k frames/s), without it 0.9-1.1 s
ENV1 = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
        "NUMPY_MADVISE_HUGEPAGE": "0"}
VARIANTS = {"slra(seg=24,ov=12)": ("slra", {"segment": 24, "overlap": 12, "tol": 1e-5})}
SKIP_HEAVY = {"bra", "bra-p"}          # neural nets (torch): training beyond a quick fit
C3D = "markers/kineticstoolkit/kinematics_basket_sprint.c3d"
"""Real 26-marker C3D with gaps (38.8 % of the entries missing, 3,678 frames) for the rows
``<method>@c3d`` (frames = the file's own)."""


def _status_bytes(key: str) -> int:
    """A /proc/self/status size field (``"VmRSS:"`` now, ``"VmHWM:"`` peak) in bytes; 0 if absent."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key):
                return int(line.split()[1]) * 1024
    return 0


def _rss_now() -> int:
    return _status_bytes("VmRSS:")


def _rss_peak() -> int:
    return _status_bytes("VmHWM:")


def _reset_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def make_clip(frames: int, seed: int = 0):
    """(motion in cm, N frames) -- CMU 135_02 tiled, 0.5 cm Gaussian noise."""
    from mocapkit import io
    from mocapkit.datasets import bundled, cmu_amc, shared_data_dir
    from mocapkit.motion import Motion

    path = cmu_amc("135_02", shared_data_dir()) or bundled("16_15.amc")
    m = io.read(path)
    reps = -(-frames // m.n_frames)
    P = np.tile(m.positions, (reps, 1, 1))[:frames]
    P += np.random.default_rng(seed).normal(0.0, 0.5, P.shape)
    return Motion(P, m.skeleton, m.fps)


def _method(label: str):
    from mocapkit import denoise

    name, params = _variant(label)
    cls = denoise.available()[name]
    if cls.needs_training:
        params = {**cls.quick_params(), **params}
    return denoise.get(name, **params), cls.needs_training


def _train(den) -> None:
    from mocapkit import io
    from mocapkit.datasets import bundled

    m = io.read(bundled("16_15.amc")).slice(0, 1000)
    den.fit([m])


def child(label: str, frames: int) -> dict:
    """Run one measurement in this process and return its row."""
    import resource

    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
    den, trained = _method(label)
    if trained:
        _train(den)
    if label.endswith("@c3d"):
        from mocapkit import io
        from mocapkit.datasets import shared_data_dir

        motion = io.read(shared_data_dir() / C3D)
        frames = motion.n_frames
    else:
        motion = make_clip(frames)
    warm, _ = _method(label)                 # warm-up on a tiny clip (imports, caches)
    if trained:
        warm = den
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        warm.denoise(make_clip(200))
        rss0 = _rss_now()
        reset = _reset_peak()
        times, walls = [], []
        for _ in range(3):
            t0, w0 = time.process_time(), time.perf_counter()
            den.denoise(motion)
            times.append(time.process_time() - t0)
            walls.append(time.perf_counter() - w0)
            if times[-1] > 2.0:
                break
    peak = _rss_peak() if reset else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    nbytes = motion.n_frames * motion.n_joints * 3 * 8
    sec = float(np.median(times))
    row = {"method": label, "frames": frames, "cpu_s": sec, "wall_s": float(np.median(walls)),
           "runs": len(times), "frames_per_s": frames / sec, "peak_rss_mb": peak / 1e6,
           "rss_before_mb": rss0 / 1e6, "input_mb": nbytes / 1e6,
           "growth_over_input": (peak - rss0) / nbytes, "peak_reset": reset,
           "coords": motion.n_joints * 3, "observed": float(motion.observed.mean()),
           "trained": trained}
    conv = (getattr(den, "last_report_", None) or {}).get("convergence")   # of the last run
    if isinstance(conv, dict) and "iterations" in conv:
        row["iterations"] = conv["iterations"]
    if _variant(label)[0] in ("rpca", "slra"):
        row.update(_ialm_counts(den, motion))
    return row


def _variant(label: str) -> tuple[str, dict]:
    """(method name, parameters) of a row label such as ``slra(seg=24,ov=12)@c3d``."""
    base = label.split("@")[0]
    return VARIANTS.get(base, (base, {}))


def _ialm_counts(den, motion) -> dict:
    """One more, untimed ``denoise()`` that counts per IALM matrix (segment) the iterations
    and those done by the spectral first phase (``lowrank._ialm_spectral_phase``, no
    ``eigh``): their means over the matrices, for :func:`flop_model`."""
    from mocapkit.solvers import lowrank

    its, phase = [], []
    batch, spectral = lowrank._ialm_batch, getattr(lowrank, "_ialm_spectral_phase", None)

    def count_batch(*a, **k):
        out = batch(*a, **k)
        its.append(np.asarray(out[2]))
        return out

    def count_phase(*a, **k):
        out = spectral(*a, **k)
        phase.append(np.asarray(out[0]))
        return out

    lowrank._ialm_batch = count_batch
    if spectral is not None:
        lowrank._ialm_spectral_phase = count_phase
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            den.denoise(motion)
    finally:
        lowrank._ialm_batch = batch
        if spectral is not None:
            lowrank._ialm_spectral_phase = spectral
    n = sum(len(i) for i in its)
    if not n:
        return {}
    return {"iterations_mean": float(sum(i.sum() for i in its) / n),
            "spectral_iterations_mean": float(sum(p.sum() for p in phase) / n)}


def dgemm_rate() -> float:
    """Measured FLOP/s (CPU time, like the frames/s) of batched (200 x 93)^T (200 x 93)
    products, one thread."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
    M = np.random.default_rng(0).standard_normal((32, 200, 93))
    best = np.inf
    for _ in range(5):
        t0 = time.process_time()
        for _ in range(10):
            np.matmul(np.swapaxes(M, 1, 2), M)
        best = min(best, time.process_time() - t0)
    return 10 * 32 * 2 * 200 * 93 * 93 / best


def flop_model(label: str, frames: int, iterations: float, n: int = 93,
               spectral: float | None = None) -> float | None:
    """FLOPs of the IALM of rpca / slra: per iteration and segment (L x n, k = min(L, n))
    ``2 L n k`` (Gram) + ``2 L n k`` (product with the shrinkage matrix) + ``2 k^3``
    (V f V^T) + ``4.7 k^3`` (eigh, LAPACK syevd with vectors, counted as issue 21 does);
    times segments x mean iterations.  Elementwise passes are not counted.  With
    ``spectral`` (mean iterations per segment done by the spectral first phase of
    mocapkit.solvers.lowrank, measured in an untimed run) those iterations cost
    ``2 L n min(k, 32)`` each (the rank-<=32 product that forms R; an upper bound) instead,
    plus once per segment the phase's basis: ``2 L n k + 4.7 k^3`` (Gram and eigh of D)
    and ``2 L n min(k, 32)`` (the other side's vectors); without it (rows measured before
    the phase existed, or the "pre-phase model" column) every iteration is a full one.
    The iteration mean is the measured mean over segments where the row has it, else the
    convergence report's (the worst segment's) count.

    tsmc / trnn (ALM of the thesis, Gram-form factor steps; segments of
    mocapkit.denoise.completion's layout, L x n each, factor width d = min(L, n)): per
    iteration ``2 L n d`` (Gram) + ``2 L n d`` (the product, in place) + ``6 L n r`` (trnn's
    P, Q steps and its rank-r term, r = 15) + ``5 L n log2 L`` (the two DCTs of the M-step,
    counted as FFTs: 2.5 L log2 L per row each) + ``10 d^3`` (the d x d steps); the ~24
    elementwise passes of the ALM are not counted, and the DCTs run far below the dgemm
    rate, so measured / ideal reads how much of an iteration is not dgemm work."""
    from mocapkit.solvers.lowrank import segment_layout

    name, params = _variant(label)
    if name == "rpca":
        L, p = frames, 1
    elif name == "slra":
        st, sp = segment_layout(frames, params.get("segment", 200), params.get("overlap", 0))
        L, p = float(np.mean(sp - st)), len(st)
    elif name in ("tsmc", "trnn"):
        from mocapkit.denoise.completion import SEGMENT_FRAMES, SEGMENT_OVERLAP_DIVISOR

        st, sp = segment_layout(frames, SEGMENT_FRAMES, SEGMENT_FRAMES // SEGMENT_OVERLAP_DIVISOR, fast=True)
        L, p = float(np.mean(sp - st)), len(st)
        d = min(L, n)
        r = 15 if name == "trnn" else 0
        per = 4 * L * n * d + 6 * L * n * r + 5 * L * n * np.log2(L) + 10 * d ** 3
        return p * iterations * per
    else:
        return None
    k = min(L, n)
    full = 4 * L * n * k + 6.7 * k ** 3
    if not spectral:
        return p * iterations * full
    kt = min(k, 32)
    basis = 2 * L * n * k + 4.7 * k ** 3 + 2 * L * n * kt
    return p * ((iterations - spectral) * full + spectral * 2 * L * n * kt + basis)


def _run_child(label: str, frames: int, timeout: float) -> dict:
    cmd = [sys.executable, __file__, "--child", label, str(frames)]
    env = {**os.environ, **ENV1}
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        return {"method": label, "frames": frames, "error": f"timeout {timeout:.0f} s"}
    if out.returncode != 0:
        return {"method": label, "frames": frames, "error": out.stderr.strip()[-300:]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def run_all(methods: list[str], sizes: list[int], budget: float, save=None) -> list[dict]:
    """One subprocess per (method, size); ``save(rows)`` after every row (partial results)."""
    rows = []
    for label in methods:
        prev = None
        for N in ([0] if label.endswith("@c3d") else sizes):
            if prev is not None and "error" not in prev:
                pred_s = prev["cpu_s"] * N / prev["frames"]
                pred_mb = prev["rss_before_mb"] + (prev["peak_rss_mb"] - prev["rss_before_mb"]) \
                    * N / prev["frames"]
                if pred_s > budget or pred_mb > 4000:
                    rows.append({"method": label, "frames": N, "skipped":
                                 f"predicted {pred_s:.0f} s, {pred_mb:.0f} MB"})
                    print(rows[-1], flush=True)
                    break
            elif prev is not None:
                break
            prev = _run_child(label, N, timeout=max(60.0, 4 * budget))
            rows.append(prev)
            if save is not None:
                save(rows)
            print({k: (round(v, 3) if isinstance(v, float) else v) for k, v in prev.items()},
                  flush=True)
    return rows


def _c3d_note(r: dict) -> str:
    if not r["method"].endswith("@c3d"):
        return ""
    return f" (basket-sprint C3D, {r['coords']} coords, {100 * (1 - r['observed']):.0f} % missing)"


def _fmt(v: float) -> str:
    return f"{v:,.0f}"


def to_markdown(rows: list[dict], rate: float, meta: dict) -> str:
    from mocapkit.denoise import available

    lines = ["# Scaling: frames/s and peak memory versus clip length", "",
             f"Generated by `python benchmarks/scaling.py` on {meta['date']} ({meta['note']}). "
             f"Input: {meta['clip']} tiled to N frames, 0.5 cm Gaussian noise, 93 coordinates; "
             "one thread, numpy's huge-page advice off as in the command line "
             "(`NUMPY_MADVISE_HUGEPAGE=0`); CPU seconds of `denoise()` (median of 3 runs when a run is < 2 s); "
             "each (method, N) in its own process.  peak = resident high-water mark during "
             "the call; growth = (peak - RSS before the call) / matrix bytes (N x 93 x 8).  "
             f"Machine: {os.cpu_count()} shared cores; dgemm (200x93 Gram, CPU time) "
             f"{rate / 1e9:.1f} GFLOP/s.  Raw rows: scaling.json.", "",
             "Growth includes the copies of the shared `Denoiser` wrapper (input check, "
             "re-centring, output Motion): compare with the `linear` row, a method that does "
             "almost nothing.  A size is skipped when the previous one predicts more than the "
             "time budget per run or more than 4 GB.", "",
             "| method | frames | frames/s | peak RSS MB | growth / input | iterations | "
             "ideal frames/s (FLOP model) | measured / ideal | measured / ideal (pre-phase model) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        if "error" in r or "skipped" in r:
            why = r.get("error", r.get("skipped"))
            lines.append(f"| {r['method']} | {r['frames']:,} | -- | -- | -- | -- | -- | "
                         f"{'skipped: ' + why if 'skipped' in r else 'failed: ' + why[:80]} | |")
            continue
        it = r.get("iterations_mean", r.get("iterations"))
        it_mean = float(np.mean(it)) if it is not None else None
        ph = r.get("spectral_iterations_mean")
        fl = (flop_model(r["method"], r["frames"], it_mean, r.get("coords", 93), ph)
              if it_mean is not None else None)
        fl0 = (flop_model(r["method"], r["frames"], it_mean, r.get("coords", 93))
               if it_mean is not None and ph is not None else None)
        ideal = r["frames"] / (fl / rate) if fl else None
        ideal0 = r["frames"] / (fl0 / rate) if fl0 else None
        lines.append(
            f"| {r['method']}{' (quick fit)' if r.get('trained') else ''}"
            f"{_c3d_note(r)} | {r['frames']:,} | "
            f"{_fmt(r['frames_per_s'])} | {r['peak_rss_mb']:.0f} | {r['growth_over_input']:.1f}x | "
            f"{'' if it_mean is None else format(it_mean, '.1f')} | "
            f"{'' if ideal is None else _fmt(ideal)} | "
            f"{'' if ideal is None else format(r['frames_per_s'] / ideal, '.2f')} | "
            f"{'' if ideal0 is None else format(r['frames_per_s'] / ideal0, '.2f')} |")
    ran = {r["method"] for r in rows}
    heavy = sorted(SKIP_HEAVY - ran)
    other = sorted(set(available()) - ran - SKIP_HEAVY)
    doc = " ".join((flop_model.__doc__ or "").split())
    lines += ["", f"Not run: {', '.join(heavy) or 'none'} (neural denoisers: they need real "
              "training data, not a quick fit)" + (f"; not requested in this run: "
                                                   f"{', '.join(other)}" if other else ""), "",
              "FLOP model (low-rank IALM; tsmc / trnn): " + doc, ""]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--child", nargs=2, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--frames", nargs="+", type=int, default=[1000, 10000, 100000, 1000000])
    ap.add_argument("--methods", nargs="+", default=None)
    ap.add_argument("--budget", type=float, default=40.0, help="seconds allowed per run")
    ap.add_argument("--note", default="full run")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "scaling"))
    ap.add_argument("--render", action="store_true",
                    help="only re-render <out>.md from <out>.json (dgemm rate re-measured)")
    ap.add_argument("--merge", action="store_true",
                    help="replace only the rows of --methods at --frames in an existing <out>.json")
    a = ap.parse_args(argv)
    if a.child:
        print(json.dumps(child(a.child[0], int(a.child[1]))))
        return 0
    from mocapkit.denoise import available

    if a.render:
        old = json.loads(Path(a.out + ".json").read_text())
        rate = dgemm_rate()
        old["dgemm_flops"] = rate
        Path(a.out + ".json").write_text(json.dumps(old, indent=1))
        Path(a.out + ".md").write_text(to_markdown(old["rows"], rate, old["meta"]))
        return 0
    methods = a.methods or ([m for m in available() if m not in SKIP_HEAVY] + list(VARIANTS)
                            + [f"{m}@c3d" for m in ("svt", "slra", "trnn", "tsmc")])
    t0 = time.perf_counter()
    partial = Path(a.out + ".partial.json")
    rows = run_all(methods, sorted(a.frames), a.budget,
                   save=lambda r: partial.write_text(json.dumps(r, indent=1)))
    if a.merge and Path(a.out + ".json").is_file():
        old = json.loads(Path(a.out + ".json").read_text())
        # only the (method, size) pairs of this run are replaced: a run at one size keeps
        # the method's rows at the others
        redo = {(r["method"], r["frames"]) for r in rows}
        rows = [r for r in old["rows"] if (r["method"], r["frames"]) not in redo] + rows
        order = {m: i for i, m in enumerate(dict.fromkeys(r["method"] for r in old["rows"]))}
        rows.sort(key=lambda r: (order.get(r["method"], len(order)), r["frames"]))
        a.note = old["meta"]["note"] + f"; rows of {', '.join(methods)} re-measured: {a.note}"
    rate = dgemm_rate()
    meta = {"date": time.strftime("%Y-%m-%d"), "clip": "CMU 135_02",
            "note": f"{a.note}; {time.perf_counter() - t0:.0f} s in all"}
    Path(a.out + ".json").write_text(json.dumps({"meta": meta, "dgemm_flops": rate,
                                                 "rows": rows}, indent=1))
    Path(a.out + ".md").write_text(to_markdown(rows, rate, meta))
    partial.unlink(missing_ok=True)
    print(to_markdown(rows, rate, meta))
    return 0


if __name__ == "__main__":
    from _report import method_time

    raise SystemExit(method_time(main))
