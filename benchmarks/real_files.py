"""Every method the CLI builds, on every readable shared marker file: what it writes, checked
without a truth. Writes docs/results/real_files.json + .md.

Usage: ``python benchmarks/real_files.py [--data DIR] [--out docs/results/real_files.md]
[--render-only]``

The real-occlusion benchmark (run_real_gaps.py) scores fills against a truth by laying real
gap masks over gap-free captures. This sweep runs each method as ``mocapkit denoise FILE
OUT --method NAME`` would (``cli._method``: defaults, the shipped general model where one
fits the file's joints) on the files themselves -- every shared marker file, every
third-party CMU BVH conversion (``cmu/bvh``: cgspeed, Daz, MotionBuilder 7.5) and every
:data:`KINECT_STEP`-th MSR-Action3D Kinect skeleton; their own gaps, noise and glitches --
and records, per file and method:

* ``filled`` / ``implausible`` / ``kept_measured`` / ``kept_misfit``: the gap policy's
  report (:func:`mocapkit.gaps.apply_policy`): samples filled, fills dropped as
  implausible, measured samples a method moved without cause (over 5 cm) and those a
  model-based method moved beyond twice the noise (:func:`mocapkit.gaps.model_misfit`),
  written as measured;
* ``moved_max_cm``: the largest move of a measured sample in what is written;
* ``step_ratio``: the largest step into, inside or out of a fill over the policy's
  allowance (``speed_factor v dt + 2 cm``, :func:`mocapkit.gaps.unreachable_fills`) --
  at most 1 by construction; > 1 would be a policy bug;
* ``outside_1m``: written fills more than 1 m outside the box of the measured samples;
  ``zeros``: written samples at exactly (0, 0, 0) that were not so in the input;
* ``warnings``: the MocapWarnings the run emitted (solver not converged, samples given
  back).

Every check is against the file as every method sees it: with its label swaps put back
(:func:`mocapkit.swaps.repair_labels`, the shared guard's first step: samples the repair
moves between labels are measured, not fills; on the shared files only the basket sprint
has any).

One BLAS thread; about 3 minutes on one core. Nothing in the Markdown is typed by hand.
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

from mocapkit import cli, gaps, io  # noqa: E402
from mocapkit.datasets import shared_data_dir  # noqa: E402
from mocapkit.denoise import available  # noqa: E402
from mocapkit.errors import MocapError, MocapWarning  # noqa: E402
from mocapkit.swaps import repair_labels  # noqa: E402


def _checks(m, out) -> dict:
    P, O = m.positions, m.observed
    Q, W = out.positions, out.observed
    new = W & ~O
    both = W & O
    with np.errstate(invalid="ignore"):
        moved = np.linalg.norm(Q - P, axis=2)[both]
    v = gaps.capture_speed(P, O)
    ratio = 0.0
    if new.any() and np.isfinite(v):
        for j in np.flatnonzero(new.any(axis=0)):
            idx = np.flatnonzero(W[:, j])
            f = new[idx, j]
            step = np.linalg.norm(np.diff(Q[idx, j], axis=0), axis=1)
            allow = 3.0 * v * np.diff(idx) + gaps.SPEED_SLACK_CM
            on = f[1:] | f[:-1]
            if on.any():
                ratio = max(ratio, float((step / allow)[on].max()))
    lo, hi = gaps.capture_volume(P, O)
    outside = int((new & gaps.outside_volume(np.nan_to_num(Q), lo, hi, 100.0)).sum())
    zeros = int((W & (np.abs(np.nan_to_num(Q)).sum(axis=2) == 0) & ~(O & (np.abs(np.nan_to_num(P)).sum(axis=2) == 0))).sum())
    rep = out.source.get("gap_report") or {}
    return {"missing": int((~O).sum()), "filled": int(new.sum()),
            "implausible": int(rep.get("left_implausible", 0)),
            "kept_measured": int(rep.get("kept_measured", 0)),
            "kept_misfit": int(rep.get("kept_measured_misfit", 0)),
            "moved_max_cm": float(moved.max()) if moved.size else 0.0,
            "step_ratio": ratio, "outside_1m": outside, "zeros": zeros}


#: every how-many-th MSR-Action3D skeleton file joins the sweep (Kinect, 15 fps, 20 joints:
#: tracker glitches that throw a limb, a real capture of another kind; 10 of 567)
KINECT_STEP = 57


def run(data: Path) -> dict:
    files = sorted(p for p in (data / "markers").rglob("*") if p.suffix.lower() in (".c3d", ".trc"))
    # the third-party CMU BVH conversions (cgspeed, Daz, MotionBuilder 7.5): real files of
    # other tools, with their own skeletons, scales and quirks (a T-pose first frame)
    files += sorted((data / "cmu" / "bvh").glob("*/*.bvh"))
    kinect = data / "msr_action3d" / "skeleton3d"
    if kinect.is_dir():
        files += sorted(kinect.glob("*_skeleton3D.txt"))[::KINECT_STEP]
    rows = []
    for path in files:
        rel = str(path.relative_to(data / "markers" if "markers" in path.parts else data))
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                m = io.read(path)
        except MocapError as e:
            rows.append({"file": rel, "method": None, "status": "unreadable", "reason": str(e)[:160]})
            continue
        # what every method sees: the take with its label swaps put back (the guard's first
        # step; swaps.md measures the repair itself) -- the checks are against that
        seen, _ = repair_labels(m)
        for name in sorted(available()):
            t0 = time.perf_counter()
            row = {"file": rel, "method": name, "frames": m.n_frames, "markers": m.n_joints}
            try:
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    meth = cli._method(name, {}, None, m, True)
                    out = meth.denoise(m)
                row.update(status="ok", **_checks(seen, out))
                row["warnings"] = [str(w.message)[:200] for w in caught if issubclass(w.category, MocapWarning)]
            except MocapError as e:
                row.update(status="refused", reason=str(e)[:160])
            except Exception as e:          # a crash is a finding, not the end of the sweep
                row.update(status="crash", reason=f"{type(e).__name__}: {e}"[:300])
            row["seconds"] = time.perf_counter() - t0
            rows.append(row)
            print(f"{rel} {name}: {row['status']} {row['seconds']:.1f} s", flush=True)
    return {"rows": rows}


def render(doc: dict, wall: float | None) -> str:
    rows = doc["rows"]
    ok = [r for r in rows if r["status"] == "ok"]
    out = ["# Every method on every shared marker file, the third-party CMU BVH files and a sample of "
           "Kinect skeletons (truth-free checks)", "",
           "Generated by `python benchmarks/real_files.py` from real_files.json"
           + (f" ({wall:.0f} s wall, one BLAS thread)" if wall else "")
           + ". Each method as `mocapkit denoise FILE OUT --method NAME` builds it, on the "
           "file's own gaps and noise; see the script's docstring for the columns.", "",
           "## Summary", "",
           f"- runs: {len(ok)} ok, {sum(r['status'] == 'refused' for r in rows)} refused with a "
           f"message (no shipped model fits the file's joint set), {sum(r['status'] == 'crash' for r in rows)} "
           f"crashed; unreadable files: {', '.join(r['file'] for r in rows if r['status'] == 'unreadable') or 'none'}",
           f"- written fills with a step over the policy's allowance: "
           f"{sum(r['step_ratio'] > 1 + 1e-9 for r in ok)} runs (largest ratio "
           f"{max((r['step_ratio'] for r in ok), default=0):.2f})",
           f"- written fills > 1 m outside the capture volume: {sum(r['outside_1m'] for r in ok)}; "
           f"new samples at exactly (0, 0, 0): {sum(r['zeros'] for r in ok)}",
           f"- fills dropped as implausible: {sum(r['implausible'] for r in ok)} in "
           f"{sum(r['implausible'] > 0 for r in ok)} runs; measured samples written back as "
           f"measured: {sum(r['kept_measured'] for r in ok)} in {sum(r['kept_measured'] > 0 for r in ok)} runs "
           f"(moved over 5 cm without cause), {sum(r.get('kept_misfit', 0) for r in ok)} in "
           f"{sum(r.get('kept_misfit', 0) > 0 for r in ok)} runs (a model moved the marker beyond twice the noise)",
           ""]
    crashes = [r for r in rows if r["status"] == "crash"]
    if crashes:
        out += ["## Crashes", ""] + [f"- {r['file']} / {r['method']}: {r['reason']}" for r in crashes] + [""]
    out += ["## Runs that changed something (ok runs with fills, drops, samples given back or a "
            "measured sample moved over 5 cm)", "",
            "| file | method | missing | filled | implausible | given back (> 5 cm / misfit) | largest move of a measured sample (cm) | step ratio | s | warnings |",
            "|---|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in ok:
        if r["filled"] or r["implausible"] or r["kept_measured"] or r.get("kept_misfit") or r["moved_max_cm"] > 5:
            w = "; ".join(x[:90] for x in r["warnings"])
            out.append(f"| {r['file']} | {r['method']} | {r['missing']} | {r['filled']} | {r['implausible']} | "
                       f"{r['kept_measured']} / {r.get('kept_misfit', 0)} | {r['moved_max_cm']:.1f} | {r['step_ratio']:.2f} | "
                       f"{r['seconds']:.1f} | {w} |")
    return "\n".join(out) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None)
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "real_files.md"))
    ap.add_argument("--render-only", action="store_true")
    a = ap.parse_args()
    md = Path(a.out)
    js = md.with_suffix(".json")
    wall = None
    if a.render_only:
        doc = json.loads(js.read_text())
    else:
        data = Path(a.data) if a.data else shared_data_dir()
        if data is None or not (data / "markers").is_dir():
            print("no shared data (../shared/data/markers)", file=sys.stderr)
            return 1
        t0 = time.perf_counter()
        doc = run(data)
        wall = time.perf_counter() - t0
        doc["wall_s"] = wall
        js.write_text(json.dumps(doc, indent=1))
    md.write_text(render(doc, doc.get("wall_s", wall)))
    print(f"wrote {js} and {md}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
