"""Lou & Chai 2010 (``lou-chai``): speed on one core, then the four protocols; writes
docs/results/lou_chai.md and docs/results/lou_chai.json.

Usage::

    python benchmarks/lou_chai_speed.py [--data DIR] [--quick] [--no-protocols]

Speed (BLAS limited to one thread; CPU time of the process is reported beside wall time,
because the 2-core machine is shared and wall time depends on its load):

* denoising: a 10,000-frame, 30 fps walking clip (CMU 131_09 at 30 fps, repeated),
  1 cm noise + 10% 15 cm spikes, M = 20, with the paper's settings and ours, for each
  implementation of the coefficient/overlap-add step; the same with 10% missing markers;
* training: the 10 walking clips other than 35_01 as read (120 fps: each contributes its 4
  phases at 30 fps), paper settings; also the three ways of accumulating the grand
  lag-covariance on the same data and the eigendecomposition alone.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mocapkit import corrupt, denoise, io  # noqa: E402
from mocapkit.bench import core  # noqa: E402
from mocapkit.bench.protocols import louchai as P  # noqa: E402
from mocapkit.datasets import shared_data_dir  # noqa: E402
from mocapkit.denoise.bases import decimate  # noqa: E402
from mocapkit.solvers import robust_bases as rb  # noqa: E402

PROTOCOLS = ("louchai-noise", "louchai-outliers", "louchai-missing", "louchai-window")


class Clock:
    def __enter__(self):
        self.c0, self.w0 = time.process_time(), time.perf_counter()
        return self

    def __exit__(self, *a):
        self.cpu = time.process_time() - self.c0
        self.wall = time.perf_counter() - self.w0


def _clip(data: Path, trial: str):
    return io.read(data / "cmu" / "asfamc" / trial.split("_")[0] / f"{trial}.amc").slice(P.TRIM)


def speed(data: Path, frames: int = 10_000) -> dict:
    walks = [t for t in P.WALK if t != "35_01"]
    raw = [_clip(data, t) for t in walks]
    out: dict = {"train": {}, "denoise": []}
    # -- training ---------------------------------------------------------------------------
    with Clock() as c:
        model = denoise.get("lou-chai").fit(raw)
    out["train"]["fit"] = {"clips": len(raw), "frames_120fps": int(sum(m.n_frames for m in raw)),
                           "frames_30fps_all_phases": int(model.n_frames_), "windows": int(model.n_windows_),
                           "K": int(model.n_bases_), "cpu_s": c.cpu, "wall_s": c.wall}
    Y = [a for a in (model._to_array(decimate(m, 4, k), model.up_axis_)[0]
                     for m in raw for k in range(4))]
    Y = [y - model.mean_ for y in Y]
    for method in ("lag", "chunked", "dense"):
        with Clock() as c:
            G, S = rb.lag_covariance(Y, 20, method=method)
        out["train"][f"lag_covariance[{method}]"] = {"cpu_s": c.cpu, "wall_s": c.wall}
    with Clock() as c:
        np.linalg.eigh(G / S)
    out["train"]["eigh"] = {"n": int(G.shape[0]), "cpu_s": c.cpu, "wall_s": c.wall}
    # -- denoising ----------------------------------------------------------------------------
    base = decimate(_clip(data, "131_09"), 4)
    reps = -(-frames // base.n_frames)
    from mocapkit.motion import Motion

    clip = Motion(np.concatenate([base.positions] * reps)[:frames], base.skeleton, 30.0)
    noisy, _ = corrupt.combine(clip, [("gaussian", {"sigma_cm": 1.0}),
                                      ("outliers", {"ratio": 0.1, "magnitude_cm": 15.0})], seed=0)
    gappy, _ = corrupt.combine(noisy, [("missing", {"ratio": 0.1})], seed=1)
    train30 = [decimate(m, 4) for m in raw]
    for label, params in (("paper", {}), ("ours", P.TUNED)):
        m = denoise.get("lou-chai", **params).fit(train30)
        for method in ("direct", "fft", "fft32"):
            for cond, x in (("noise+outliers", noisy), ("+10% missing", gappy)):
                if method == "direct" and cond != "noise+outliers":
                    continue
                m.set_params(method=method)
                m.denoise(x.slice(0, 300))                     # warm-up (imports, caches)
                with Clock() as c:
                    m.denoise(x)
                out["denoise"].append({"settings": label, "K": int(m.n_bases_), "method": method,
                                       "condition": cond, "frames": frames,
                                       "fps_cpu": frames / c.cpu, "fps_wall": frames / c.wall})
    return out


# ---------------------------------------------------------------------------------------
# Markdown
# ---------------------------------------------------------------------------------------
def _fmt(v, std=None):
    if v is None or not np.isfinite(v):
        return "fails"
    s = f"{v:.3g}"
    return s + (f" ± {std:.2g}" if std else "")


def pivot(rows: list[dict], methods: list[str]) -> str:
    """One line per (clip, condition), one column per method; best value in bold."""
    keys, table = [], {}
    for r in rows:
        k = (r["clip"], r["condition"], r["metric"], r["unit"])
        if k not in table:
            keys.append(k)
            table[k] = {}
        table[k][r["method"]] = r
    cols = [m for m in methods if any(m in table[k] for k in keys)]
    lines = ["| clip | condition | unit | " + " | ".join(cols) + " |",
             "|---|---|---|" + "---:|" * len(cols)]
    for k in keys:
        vals = {m: table[k][m]["value"] for m in cols if m in table[k]}
        finite = [v for v in vals.values() if v is not None and np.isfinite(v)]
        best = min(finite) if finite else None
        cells = []
        for m in cols:
            if m not in table[k]:
                cells.append("")
                continue
            r = table[k][m]
            c = _fmt(r["value"], r.get("std"))
            cells.append(f"**{c}**" if best is not None and r["value"] == best else c)
        lines.append(f"| {k[0]} | {k[1]} | {k[3]} ({k[2]}) | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def claims(rows: list[dict]) -> str:
    """Where is a lou-chai variant the best of the compared methods?"""
    out = []
    groups: dict = {}
    for r in rows:
        if r["protocol"] in ("louchai-noise", "louchai-outliers", "louchai-missing"):
            groups.setdefault((r["protocol"], r["clip"], r["condition"]), []).append(r)
    n_paper = n_ours = n_any = 0
    broken = []
    for (proto, clip, cond), rs in groups.items():
        vals = {r["method"]: r["value"] for r in rs if r["value"] is not None and np.isfinite(r["value"])}
        if not vals:
            continue
        best = min(vals, key=vals.get)
        lou = {m: v for m, v in vals.items() if m.startswith("lou-chai")}
        others = {m: v for m, v in vals.items() if not m.startswith("lou-chai")}
        if not others or not lou:
            continue
        best_other = min(others.values())
        paper = [v for m, v in lou.items() if not m.startswith("lou-chai*")]
        ours = [v for m, v in lou.items() if m.startswith("lou-chai*")]
        n_any += 1
        n_paper += bool(paper) and min(paper) < best_other
        n_ours += bool(ours) and min(ours) < best_other
        if min(lou.values()) >= best_other:
            broken.append(f"{proto} {clip} {cond}: best {best} {vals[best]:.3g} vs "
                          f"lou-chai {min(lou.values()):.3g}")
    out.append(f"- conditions compared: {n_any}; the paper-setting lou-chai is the best method in "
               f"{n_paper}, our setting (lou-chai*) in {n_ours}.")
    # the paper's claim: best in every condition up to 15% outliers
    sub = [(k, rs) for k, rs in groups.items() if k[0] == "louchai-outliers"
           and float(k[2].replace("outliers", "").rstrip("%")) <= 15]
    for tag, pick in (("lou-chai (paper settings)", lambda m: m == "lou-chai"),
                      ("lou-chai* (our settings)", lambda m: m == "lou-chai*")):
        wins, lost = 0, []
        for (proto, clip, cond), rs in sub:
            vals = {r["method"]: r["value"] for r in rs if r["value"] is not None and np.isfinite(r["value"])}
            mine = [v for m, v in vals.items() if pick(m)]
            others = {m: v for m, v in vals.items() if not m.startswith("lou-chai")}
            if not mine or not others:
                continue
            if min(mine) < min(others.values()):
                wins += 1
            else:
                b = min(others, key=others.get)
                lost.append(f"{clip} {cond} ({b} {others[b]:.3g} vs {min(mine):.3g})")
        out.append(f"- paper's claim (best of the four methods in every condition up to 15% outliers), "
                   f"{tag}: best in {wins} of {wins + len(lost)} outlier conditions"
                   + (f"; not in: {'; '.join(lost)}" if lost else "") + ".")
    if broken:
        out.append("- conditions where no lou-chai variant is the best:")
        out += [f"  - {b}" for b in broken]
    return "\n".join(out) + "\n"


def write_markdown(path: Path, sp: dict | None, rows: list[dict], quick: bool, proto_s: dict,
                   load0: float) -> None:
    L = ["# Lou & Chai 2010 example-based robust filter bases (`lou-chai`) -- measured results", "",
         "Produced by `python benchmarks/lou_chai_speed.py" + (" --quick" if quick else "") + "` "
         f"on {platform.machine()} ({os.cpu_count()} CPUs, shared; 1-min load average at the "
         f"start {load0:.1f}); BLAS limited to one thread. Numbers are not typed "
         "by hand.", ""]
    if quick:
        L += ["**Reduced run (`--quick`)**: one walking fold, one seed, fewer levels.", ""]
    if sp:
        t = sp["train"]
        f = t["fit"]
        L += ["## Speed (one core)", "",
              f"Training (paper settings, M = 20, 99% energy): {f['clips']} walking clips, "
              f"{f['frames_120fps']} frames at 120 fps = {f['frames_30fps_all_phases']} frames at 30 fps "
              f"over the 4 phases, {f['windows']} windows, K = {f['K']}: "
              f"**{f['cpu_s']:.1f} s CPU** ({f['wall_s']:.1f} s wall; target: under a minute).", "",
              "| training step (same data) | CPU s | wall s |", "|---|---:|---:|"]
        for k, v in t.items():
            if k != "fit":
                L.append(f"| {k}{' (n = %d)' % v['n'] if 'n' in v else ''} | {v['cpu_s']:.2f} | {v['wall_s']:.2f} |")
        L += ["", "Denoising a 10,000-frame 30 fps clip (31 joints, L = 93 channels, M = 20; "
              "target >= 5,000 frames/s on one core):", "",
              "| settings | K | implementation | input | frames/s (CPU time) | frames/s (wall) |",
              "|---|---:|---|---|---:|---:|"]
        for d in sp["denoise"]:
            L.append(f"| {d['settings']} | {d['K']} | {d['method']} | {d['condition']} | "
                     f"{d['fps_cpu']:,.0f} | {d['fps_wall']:,.0f} |")
        L += ["", "`direct` is the paper's literal scheme (c_s = Eᵀ z_s as M matrix products, then "
              "the overlap-add); `fft`/`fft32` apply the same linear map as one multichannel FIR "
              "filter in the frequency domain (exact; `fft32` in single precision), "
              "`auto` (default) picks `fft32` for long clips. With missing markers the exact "
              "conjugate-gradient fill steps add projector applications.", ""]
    methods = ["lou-chai", "lou-chai*", "gaussian", "kalman-identity", "kalman-learned",
               "lou-chai(angle)", "lou-chai*(angle)"]
    L += ["## Does lou-chai win? (noise, outliers, missing)", "", claims(rows)]
    L += ["## Setting (from `mocapkit/bench/protocols/louchai.py`)", "", P.__doc__.strip(), ""]
    for name in PROTOCOLS:
        rs = [r for r in rows if r["protocol"] == name]
        if not rs:
            continue
        L += [f"## `{name}` ({proto_s.get(name, 0):.0f} s)", "",
              core.available()[name].description + ".", "", pivot(rs, methods)]
        if name == "louchai-window":
            L += ["Number of bases K kept per window size (99% / 99.9% energy): " +
                  ", ".join(sorted({f"M={r['extra']['window']}: K={r['extra']['n_bases']} ({r['method']})"
                                    for r in rs if r.get('extra', {}).get('n_bases')})), ""]
        errs = sorted({f"{r['method']}: {r['extra']['error']}" for r in rs if r.get("extra", {}).get("error")})
        if errs:
            L += ["Failures (reported as 'fails'):", ""] + [f"- {e}" for e in errs] + [""]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(L))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=None)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-protocols", action="store_true")
    ap.add_argument("--no-speed", action="store_true")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "lou_chai.md"))
    args = ap.parse_args(argv)
    data = shared_data_dir(args.data)
    if data is None:
        print("shared data set not found (--data DIR or MOCAPKIT_DATA)", file=sys.stderr)
        return 2
    from threadpoolctl import threadpool_limits

    load0 = os.getloadavg()[0]
    with threadpool_limits(1):
        sp = None if args.no_speed else speed(data)
        if sp:
            print(json.dumps(sp, indent=1))
        rows: list[dict] = []
        proto_s: dict = {}
        if not args.no_protocols:
            ctx = core.Context(data, quick=args.quick, progress=False)
            for name in PROTOCOLS:
                t0 = time.perf_counter()
                rows += [r.to_dict() for r in core.run(name, ctx)]
                proto_s[name] = time.perf_counter() - t0
                print(f"{name}: {proto_s[name]:.0f} s", flush=True)
    out = Path(args.out)
    js = out.with_suffix(".json")
    js.parent.mkdir(parents=True, exist_ok=True)
    js.write_text(json.dumps({"speed": sp, "rows": rows, "load_average_start": load0,
                              "protocol_seconds": proto_s}, indent=1, allow_nan=True))
    write_markdown(out, sp, rows, args.quick, proto_s, load0)
    print(f"wrote {out} and {js}")
    return 0


if __name__ == "__main__":
    from _report import method_time

    raise SystemExit(method_time(main))
