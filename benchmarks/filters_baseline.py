"""Accuracy and speed of the classical baselines (filters + Kalman) on real CMU clips.

Writes docs/results/filters.md (and filters.json with every measured row).

Protocol
--------
* Clips: six CMU ASF/AMC trials of different actions (walk, run, hop, martial arts,
  dance, soccer kick), ``--frames`` frames (default 1200 = 10 s at 120 fps) from frame 10
  on (16_15 starts with a ~90 cm jump in frames 0-2, a capture artefact that would
  count against every method that removes it),
  native 120 fps and resampled to 30 fps (Lou & Chai's rate, where the Gaussian
  window of 11 frames was chosen).
* Conditions (all seeded; per coordinate, cm):
  - ``gauss2``: i.i.d. Gaussian noise sigma = 2 cm on every coordinate;
  - ``spikes10``: 10 % of the (frame, joint) entries displaced by 15 cm in a uniformly
    random 3-D direction, no other noise;
  - ``gauss2+miss20``: 2 cm noise and 20 % of the (frame, joint) entries missing.
* Methods: every registered classical baseline with its defaults, plus two tuned
  variants (gaussian with a 5-frame median pre-pass; kalman-cv with a 5-sigma
  innovation gate). kalman-learned is trained once per frame rate on six other clips
  (07_03, 131_01, 131_03, 135_03, 05_03, 01_01), none of them a test clip.
* Metrics: RMSE in cm over all T x J x 3 entries against the clean clip (missing
  entries included); frames/s = frames / wall time of ``denoise`` (single thread,
  median over all runs of the method at that frame rate).

Run:  .venv/bin/python benchmarks/filters_baseline.py [--quick] [--data DIR]
"""
from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mocapkit import denoise, io  # noqa: E402
from mocapkit.datasets import cmu_amc, shared_data_dir  # noqa: E402

CLIPS = [("16_15", "walk"), ("09_06", "run"), ("131_04", "hop"), ("135_02", "martial arts"),
         ("05_02", "dance"), ("11_01", "soccer kick")]
TRAIN = ["07_03", "131_01", "131_03", "135_03", "05_03", "01_01"]
METHODS = [
    ("gaussian", {}), ("gaussian", {"median": 5}), ("butterworth", {}), ("savgol", {}),
    ("median", {}), ("hampel", {}), ("spline", {}), ("linear", {}),
    ("kalman-cv", {}), ("kalman-cv", {"gate": 5.0}), ("kalman-identity", {}), ("kalman-learned", {}),
]
CONDITIONS = ("gauss2", "spikes10", "gauss2+miss20")
SKIP = 10   # first frames skipped: CMU 16_15 starts with a ~90 cm jump in frames 0-2 (capture artefact)


def label(name: str, params: dict) -> str:
    return name + ("" if not params else " (" + ", ".join(f"{k}={v}" for k, v in params.items()) + ")")


def corrupt(clean, cond: str, seed: int):
    rng = np.random.default_rng(seed)
    P = np.array(clean.positions)
    T, J, _ = P.shape
    obs = np.ones((T, J), bool)
    if cond in ("gauss2", "gauss2+miss20"):
        P += rng.normal(0.0, 2.0, P.shape)
    if cond == "spikes10":
        sel = rng.random((T, J)) < 0.10
        d = rng.normal(size=(T, J, 3))
        d /= np.linalg.norm(d, axis=2, keepdims=True)
        P[sel] += 15.0 * d[sel]
    if cond == "gauss2+miss20":
        obs = rng.random((T, J)) >= 0.20
        obs[0] = True            # every joint seen at least once (per-channel methods need it)
    return clean.with_positions(P).with_observed(obs)


def rmse(a, b) -> float:
    return float(np.sqrt(np.mean((a.positions - b.positions) ** 2)))


def load(trial: str, data_dir, frames: int, fps: float):
    p = cmu_amc(trial, data_dir)
    if p is None:
        return None
    m = io.read(p)
    start = SKIP if m.n_frames > SKIP + 50 else 0
    m = m.slice(start, min(m.n_frames, start + frames))
    return m if np.isclose(fps, m.fps) else m.resample(fps)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=None)
    ap.add_argument("--quick", action="store_true", help="2 clips, 1 seed, 400 frames")
    ap.add_argument("--frames", type=int, default=1200)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "filters.md"))
    a = ap.parse_args(argv)
    data = shared_data_dir(a.data)
    if data is None:
        print("shared data set not found: pass --data DIR or set MOCAPKIT_DATA", file=sys.stderr)
        return 2
    clips = CLIPS[:2] if a.quick else CLIPS
    frames = 400 if a.quick else a.frames
    seeds = range(1 if a.quick else a.seeds)
    rows = []
    t_start = time.perf_counter()
    for fps in (120.0, 30.0):
        tests = [(t, act, load(t, data, frames, fps)) for t, act in clips]
        tests = [x for x in tests if x[2] is not None]
        train = [m for m in (load(t, data, 10 ** 9, fps) for t in TRAIN) if m is not None]
        fitted = {}
        for name, params in METHODS:
            m = denoise.get(name, **params)
            if m.needs_training:
                t0 = time.perf_counter()
                m.fit(train)
                print(f"[{fps:g} fps] trained {name} on {len(train)} clips "
                      f"({sum(x.n_frames for x in train)} frames) in {time.perf_counter() - t0:.1f} s", flush=True)
            fitted[label(name, params)] = m
        for clip_idx, (trial, act, clean) in enumerate(tests):
            for cond in CONDITIONS:
                for seed in seeds:
                    noisy = corrupt(clean, cond, 1000 * seed + 17 * clip_idx + CONDITIONS.index(cond))
                    shown = np.where(noisy.observed[..., None], noisy.positions, clean.positions)
                    rows.append(dict(fps=fps, clip=trial, action=act, condition=cond, seed=seed,
                                     method="noisy input", rmse=rmse(clean.with_positions(shown), clean),
                                     seconds=None, frames=clean.n_frames))
                    for lab, m in fitted.items():
                        with warnings.catch_warnings():
                            warnings.simplefilter("ignore")
                            t0 = time.perf_counter()
                            try:
                                out = m.denoise(noisy)
                            except Exception as e:      # report, keep going
                                print(f"  {trial} {cond} {lab}: {type(e).__name__}: {e}", flush=True)
                                continue
                            dt = time.perf_counter() - t0
                        rows.append(dict(fps=fps, clip=trial, action=act, condition=cond, seed=seed,
                                         method=lab, rmse=rmse(out, clean), seconds=dt, frames=clean.n_frames))
                print(f"[{fps:g} fps] {trial} {cond} done ({time.perf_counter() - t_start:.0f} s)", flush=True)
    out_md = Path(a.out)
    out_md.parent.mkdir(parents=True, exist_ok=True)
    out_md.with_suffix(".json").write_text(json.dumps(rows, indent=1))
    out_md.write_text(report(rows, a, clips, frames, list(seeds), time.perf_counter() - t_start))
    print(f"wrote {out_md} and {out_md.with_suffix('.json')}")
    return 0


def _frames(rows, clip, fps):
    v = [r["frames"] for r in rows if r["clip"] == clip and r["fps"] == fps]
    return v[0] if v else "-"


def report(rows, a, clips, frames, seeds, total_s) -> str:
    import collections

    methods = ["noisy input"] + [label(n, p) for n, p in METHODS]
    L = ["# Classical baselines: accuracy and speed on real CMU clips", "",
         f"Produced by `benchmarks/filters_baseline.py{' --quick' if a.quick else ''}` "
         f"(do not edit by hand). Machine: {platform.processor() or platform.machine()}, "
         f"Python {platform.python_version()}, numpy {np.__version__}, one thread; "
         f"total run time {total_s:.0f} s; load average at the end {os.getloadavg()[0]:.1f} on "
         f"{os.cpu_count()} cores (the machine is shared: frames/s are indicative, lower than on "
         f"an idle core).", "",
         "Frames per test clip (120 / 30 fps): " + ", ".join(
             f"{t} {_frames(rows, t, 120.0)} / {_frames(rows, t, 30.0)}" for t, _ in clips) + ".", "",
         f"Clips: {', '.join(f'{t} ({act})' for t, act in clips)}; up to {frames} frames of each from frame {SKIP} on "
         f"(at 120 fps; the same span resampled to 30 fps). Seeds per condition: {len(seeds)}. "
         "Conditions: `gauss2` = 2 cm i.i.d. Gaussian noise per coordinate; `spikes10` = 10 % of "
         "(frame, joint) entries moved 15 cm in a random 3-D direction, no other noise; "
         "`gauss2+miss20` = 2 cm noise + 20 % of (frame, joint) entries missing. "
         "RMSE in cm over all entries (missing ones included) against the clean clip; "
         "the `noisy input` row is the corruption itself (missing entries counted as exact). "
         "kalman-learned is trained on 07_03, 131_01, 131_03, 135_03, 05_03, 01_01 (not test clips). "
         "frames/s: median over all runs of the method at that rate (wall time of `denoise`). "
         "All methods at their defaults unless parameters are shown.", ""]
    for fps in (120.0, 30.0):
        R = [r for r in rows if r["fps"] == fps]
        if not R:
            continue
        L += [f"## {fps:g} fps: mean RMSE (cm) over clips and seeds", "",
              "| method | " + " | ".join(CONDITIONS) + " | frames/s |",
              "|---|" + "---:|" * (len(CONDITIONS) + 1)]
        for m in methods:
            cells = []
            for c in CONDITIONS:
                v = [r["rmse"] for r in R if r["method"] == m and r["condition"] == c]
                cells.append(f"{np.mean(v):.3f}" if v else "–")
            sp = [r["frames"] / r["seconds"] for r in R if r["method"] == m and r["seconds"]]
            cells.append(f"{np.median(sp):,.0f}" if sp else "")
            L.append(f"| {m} | " + " | ".join(cells) + " |")
        L.append("")
        for c in CONDITIONS:
            L += [f"### {fps:g} fps, {c}: RMSE (cm) per clip", "",
                  "| method | " + " | ".join(t for t, _ in clips) + " |",
                  "|---|" + "---:|" * len(clips)]
            by = collections.defaultdict(list)
            for r in R:
                if r["condition"] == c:
                    by[(r["method"], r["clip"])].append(r["rmse"])
            for m in methods:
                L.append(f"| {m} | " + " | ".join(
                    f"{np.mean(by[(m, t)]):.2f}" if by[(m, t)] else "–" for t, _ in clips) + " |")
            L.append("")
    return "\n".join(L) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
