"""Run the Xiao et al. 2015 protocols and the speed benchmark; write docs/results/xiao.md.

Usage: ``python benchmarks/run_xiao.py [--quick] [--data DIR] [--out docs/results/xiao.md]
[--skip-speed] [--protocols NAMES --reuse]``

Runs ``xiao-table1``, ``xiao-table2`` and ``xiao-params`` through :func:`mocapkit.bench.run`
(one BLAS thread per process; K-SVD training with two processes), writes their rows as
JSON next to the Markdown file (``xiao_<protocol>.json``) and renders the summary tables,
the full row tables (:func:`mocapkit.bench.to_markdown`) and the speed tables of
``benchmarks/xiao_speed.py``.  Nothing in the Markdown file is typed by hand except the
fixed explanatory text in this script.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from mocapkit import bench  # noqa: E402
from mocapkit.datasets import shared_data_dir  # noqa: E402

PROTOCOLS = ("xiao-table1", "xiao-table2", "xiao-params")
METHOD_ORDER = ("xiao-sparse", "lou-chai", "gaussian", "wavelet", "kalman-cv", "noisy-input")


def table1_summary(rows: list[bench.Row]) -> str:
    rows = [r for r in rows if r.metric == "per_frame_rmse"]
    actions = list(dict.fromkeys(r.clip for r in rows))
    conds = list(dict.fromkeys(r.condition for r in rows))
    methods = [m for m in METHOD_ORDER if any(r.method == m for r in rows)]
    by = {(r.clip, r.condition, r.method): r for r in rows}
    out = []
    ranks = []
    for a in actions:
        out += [f"**{a}** (test clips: {', '.join(next((r.extra.get('test_clips', []) for r in rows if r.clip == a and r.method == 'xiao-sparse'), []))})", "",
                "| method | " + " | ".join(conds) + " |", "|---|" + "---:|" * len(conds)]
        order: dict[str, list[str]] = {}
        for c in conds:
            cand = {m: by[(a, c, m)].value for m in methods if (a, c, m) in by and m != "noisy-input"}
            order[c] = sorted(cand, key=cand.get)
            if "xiao-sparse" in cand:
                ranks.append((a, c, order[c].index("xiao-sparse") + 1, order[c][0]))
        for m in methods:
            cells = []
            for c in conds:
                r = by.get((a, c, m))
                if r is None:
                    cells.append("")
                    continue
                txt = f"{r.value:.2f} ± {r.std:.2f}"
                if m != "noisy-input" and order[c] and m == order[c][0]:
                    txt = f"**{txt}**"
                elif m != "noisy-input" and len(order[c]) > 1 and m == order[c][1]:
                    txt = f"_{txt}_"
                cells.append(txt)
            out.append(f"| {m} | " + " | ".join(cells) + " |")
        out.append("")
    n = len(ranks)
    top2 = sum(1 for _, _, k, _ in ranks if k <= 2)
    first = sum(1 for _, _, k, _ in ranks if k == 1)
    out.append(f"Per-frame RMSE over the corrupted markers, cm, mean ± std over frames; **best**, _second_. "
               f"xiao-sparse is best in {first} of {n} (action, condition) cells and best or second in "
               f"{top2} of {n}.")
    miss = [f"{a}/{c} (rank {k}, best {b})" for a, c, k, b in ranks if k > 2]
    if miss:
        out.append("Cells where it is neither: " + "; ".join(miss) + ".")
    below = [(a, c, by[(a, c, 'xiao-sparse')].value) for a in actions for c in conds
             if c.startswith("outliers") and int(c[8:]) < 20 and (a, c, "xiao-sparse") in by]
    if below:
        ok = all(v < 5.0 for _, _, v in below)
        out.append(f"Paper claim \"below 5 cm/frame for outlier ratios under 20 %\": "
                   f"{'holds' if ok else 'FAILS'} here (xiao-sparse: "
                   + ", ".join(f"{a} {c} {v:.2f} cm" for a, c, v in below) + ").")
    tuned = defaultdict(set)
    for r in rows:
        if r.extra.get("tuned") is not None:
            tuned[r.method].add(str(r.extra["tuned"]))
    if tuned:
        out.append("")
        out.append("Baseline settings chosen per condition on a training clip (see `extra.tuned` in the JSON): "
                   + "; ".join(f"{m}: {len(v)} distinct" for m, v in tuned.items()) + ".")
    fps = defaultdict(list)
    for r in rows:
        if r.extra.get("frames_per_s"):
            fps[r.method].append(r.extra["frames_per_s"])
    if fps:
        out.append("Median denoising speed over the cells (frames/s, one core, wall clock): "
                   + ", ".join(f"{m} {np.median(v):.0f}" for m, v in fps.items()) + ".")
    return "\n".join(out) + "\n"


def table2_summary(rows: list[bench.Row]) -> str:
    acc = [r for r in rows if r.metric == "per_frame_rmse"]
    tr = {(r.clip, r.method): r.value for r in rows if r.metric == "train_time"}
    out = ["| action | representation | atoms | overcomplete (K >= dM) | mean RMSE (cm) | denoise s | "
           "ideal parallel s | frames/s | train s |",
           "|---|---|---:|---|---:|---:|---:|---:|---:|"]
    for r in acc:
        ip = r.extra.get("ideal_parallel_s")
        out.append(f"| {r.clip} | {r.method} | {r.extra.get('n_atoms')} | {'yes' if r.extra.get('overcomplete') else 'no'} | "
                   f"{r.value:.2f} ± {r.std:.2f} | {r.seconds:.2f} | {'' if ip is None else f'{ip:.2f}'} | "
                   f"{r.extra.get('frames_per_s')} | {tr.get((r.clip, r.method), float('nan')):.1f} |")
    cond = acc[0].condition if acc else ""
    out.append("")
    out.append(f"Mean over {cond.replace('mean over ', '')}. Denoising with one BLAS thread; \"2 processes\": the five "
               "poselets coded in two forked worker processes (the paper's parallel mode; on this shared 2-core "
               "machine the second core is often busy with other jobs); \"ideal parallel\": one worker per poselet "
               "without overhead, from the per-poselet coding times of the serial run. K-SVD training of the "
               "poselets in two processes, of the full pose in one (a single dictionary).")
    lines = []
    for a in dict.fromkeys(r.clip for r in acc):
        p1 = next((r for r in acc if r.clip == a and r.method == "poselets"), None)
        p2 = next((r for r in acc if r.clip == a and r.method == "poselets, 2 processes"), None)
        for f in (r for r in acc if r.clip == a and r.method.startswith("full-pose")):
            if p1 is None:
                continue
            t = f"{a}, vs {f.method}: error {'lower' if p1.value < f.value else 'HIGHER'} ({p1.value:.2f} vs {f.value:.2f} cm); " \
                f"denoising on one core {'faster' if p1.seconds < f.seconds else 'SLOWER'} ({p1.seconds:.2f} vs {f.seconds:.2f} s)"
            if p2 is not None:
                t += f", in 2 processes {'faster' if p2.seconds < f.seconds else 'SLOWER'} ({p2.seconds:.2f} s)"
            ip = p1.extra.get("ideal_parallel_s")
            if ip is not None:
                t += f", ideal parallel {'faster' if ip < f.seconds else 'SLOWER'} ({ip:.2f} s)"
            lines.append(t)
    if lines:
        out.append("")
        out += [f"- {x}" for x in lines]
    return "\n".join(out) + "\n"


def params_summary(rows: list[bench.Row]) -> str:
    out = []
    for param, label in (("window", "window M (frames at 120 fps)"), ("n_atoms", "dictionary size K")):
        sel = [r for r in rows if r.extra.get("param") == param]
        if not sel:
            continue
        conds = list(dict.fromkeys(r.condition for r in sel))
        vals = list(dict.fromkeys(r.extra[param] for r in sel))
        by = {(r.extra[param], r.condition): r for r in sel}
        out += [f"**{label}** ({sel[0].clip})", "", f"| {param} | " + " | ".join(conds) + " | train s |",
                "|---:|" + "---:|" * (len(conds) + 1)]
        for v in vals:
            out.append(f"| {v} | " + " | ".join(f"{by[(v, c)].value:.2f}" for c in conds if (v, c) in by)
                       + f" | {by[(v, conds[0])].extra.get('train_s', '')} |")
        out.append("")
    for param in ("lam_factor", "lam_l1"):
        sel = [r for r in rows if r.extra.get("param") == param]
        if not sel:
            continue
        vals = list(dict.fromkeys(r.extra[param] for r in sel))
        keys = list(dict.fromkeys((r.clip, r.condition) for r in sel))
        by = {(r.clip, r.condition, r.extra[param]): r.value for r in sel}
        unit = "per cm: lambda = lam_factor x sigma^2" if param == "lam_factor" else "dimensionless"
        out += [f"**{param}** ({unit})", "", "| validation clip | condition | " + " | ".join(f"{v:g}" for v in vals) + " | best |",
                "|---|---|" + "---:|" * (len(vals) + 1)]
        score = defaultdict(list)
        for (clip, cond) in keys:
            cells = [by.get((clip, cond, v), np.nan) for v in vals]
            best = vals[int(np.nanargmin(cells))]
            ref = np.nanmin(cells)
            for v, x in zip(vals, cells):
                score[v].append(x / ref)
            out.append(f"| {clip} | {cond} | " + " | ".join(f"{x:.2f}" for x in cells) + f" | {best:g} |")
        mean_ratio = {v: float(np.mean(s)) for v, s in score.items()}
        worst = {v: float(np.max(s)) for v, s in score.items()}
        chosen = min(worst, key=worst.get)
        out.append("")
        out.append("Error relative to the best value of each row, mean / worst over the rows: "
                   + ", ".join(f"{v:g}: {mean_ratio[v]:.3f} / {worst[v]:.3f}" for v in vals)
                   + f". Rule (fixed before the sweep): the value with the smallest worst-case ratio, "
                     f"robust to the unknown noise level / outlier ratio -> **{param} = {chosen:g}** "
                     f"(smallest mean ratio: {min(mean_ratio, key=mean_ratio.get):g}).")
        out.append("")
    return "\n".join(out) + "\n"


def targets_summary(speed_rows: list[dict], t2_rows: list[bench.Row]) -> str:
    """Which of issue #5's speed targets are met, from the saved measurements."""
    out = []
    den = [r for r in speed_rows if r.get("what") == "denoise" and r.get("noise") == r.get("condition")]
    for r in den:
        w, c = r["fps_wall"], r["fps_cpu"]
        verdict = "MET" if w >= 1000 else ("met in CPU time only" if c >= 1000 else "MISSED")
        out.append(f"- Denoising >= 1,000 frames/s on one core (K = 512), {r['noise']} noise: {w:.0f} frames/s "
                   f"wall, {c:.0f} CPU -> **{verdict}**")
    acc = [r for r in t2_rows if r.metric == "per_frame_rmse"]
    for a in dict.fromkeys(r.clip for r in acc):
        p1 = next((r for r in acc if r.clip == a and r.method == "poselets"), None)
        f = next((r for r in acc if r.clip == a and r.method == "full-pose K=512"), None)
        if p1 is None or f is None:
            continue
        ok = p1.seconds < f.seconds
        verdict = "MET" if ok else "MISSED"
        if ok and p1.seconds > f.seconds / 1.3:
            verdict += " only within the ~30 % wall-clock noise"
        out.append(f"- Poselets faster than the full pose at K = 512 ({a}, one core): {p1.seconds:.2f} vs "
                   f"{f.seconds:.2f} s -> **{verdict}** (poselet error {p1.value:.2f} vs "
                   f"{f.value:.2f} cm)")
        # the paper requires overcomplete dictionaries (K > d M); a full-pose K = 512 is not
        # (d M = 3 J x 21 for J ~ 30 joints), so the fair comparison is the K = 2048 one
        big = next((r for r in acc if r.clip == a and r.method == "full-pose K=2048"), None)
        if big is not None:
            ok2 = p1.seconds < big.seconds and p1.value < big.value
            out.append(f"- Poselets beat an overcomplete full-pose dictionary (K = 2048; the full-pose "
                       f"K = 512 is undercomplete) in time and error ({a}, one core): "
                       f"{p1.seconds:.2f} vs {big.seconds:.2f} s, {p1.value:.2f} vs {big.value:.2f} cm "
                       f"-> **{'MET' if ok2 else 'MISSED'}**")
    if not out:
        return ""
    return "\n".join(out) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--data")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "xiao.md")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--protocols", default=",".join(PROTOCOLS),
                    help="protocols to run (comma-separated); with --reuse the others come from their JSON")
    ap.add_argument("--reuse", action="store_true",
                    help="take protocols not run (and the speed tables with --skip-speed) from the saved JSON")
    a = ap.parse_args()
    data = shared_data_dir(a.data)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    ctx = bench.Context(data_dir=data, quick=a.quick, progress=False)
    results: dict[str, list[bench.Row]] = {}
    timing: dict[str, float] = {}
    suffix = "_quick" if a.quick else ""
    todo = a.protocols.split(",")
    for name in PROTOCOLS:
        path = a.out.parent / f"xiao_{name.replace('xiao-', '')}{suffix}.json"
        if name in todo:
            t = time.perf_counter()
            rows = bench.run(name, ctx)
            timing[name] = round(time.perf_counter() - t)
            bench.to_json(rows, path)
            print(f"{name}: {len(rows)} rows in {timing[name]:.0f} s", flush=True)
        elif a.reuse and path.is_file():
            saved = json.loads(path.read_text())
            rows = [bench.Row(**r) for r in saved]
            timing[name] = f"reused {path.name}"
        else:
            continue
        results[name] = rows
    speed_path = a.out.parent / f"xiao_speed{suffix}.json"
    speed_md = ""
    speed_rows: list[dict] = []
    if not a.skip_speed:
        import xiao_speed

        t = time.perf_counter()
        speed_md, speed_rows = xiao_speed.run(a.data)
        timing["xiao_speed"] = round(time.perf_counter() - t)
        speed_path.write_text(json.dumps({"markdown": speed_md, "rows": speed_rows}, indent=1))
    elif a.reuse and speed_path.is_file():
        saved = json.loads(speed_path.read_text())
        speed_md, speed_rows = saved["markdown"], saved.get("rows", [])
        timing["xiao_speed"] = f"reused {speed_path.name}"

    md = [f"# Xiao et al. 2015 -- sparse motion bases selection: results{' (quick run)' if a.quick else ''}", "",
          "Generated by `python benchmarks/run_xiao.py" + (" --quick" if a.quick else "") + "` "
          "(protocols in `mocapkit/bench/protocols/xiao.py`, method in `mocapkit/denoise/sparse.py`). "
          "Run times of this generation: " + ", ".join(f"{k} {v} s" if isinstance(v, (int, float)) else f"{k} {v}"
                                                        for k, v in timing.items()) + ".",
          "", "## Setting", "",
          "* Data: CMU/HDM05 ASF/AMC at 120 fps, positions in cm. The paper's clips 09_04 (run), 05_16 "
          "(dance) and 06_13 (basketball) are not in the shared data: **run** = HDM05 `jogLeftCircle4StepsRstart` "
          "(14 training jogs; test: CMU 09_06, the only CMU run, + 3 jogs), **dance** = CMU 05_02/05_03/05_07 "
          "-> 05_05, **martial arts** (basketball substitute) = CMU 135_02/03/05/06/08/09 -> 135_04, 135_11.",
          "* Corruption: Gaussian SNR 40/30/20/10 dB (root-relative signal power), outliers = 10-25 % of the "
          "joint entries scaled by 1.4 about the root, mixed = 20 dB + 10 %. Metric: per-frame RMSE over the "
          "corrupted markers (paper eq. 6), cm; mean ± std over the frames of all test clips (one seed).",
          "* xiao-sparse: M = 21 frames, K = 512 atoms per poselet, T_s = 8, 10 K-SVD iterations on <= 8000 "
          "windows per poselet, lambda = 0.1 sigma^2 (eq. 4, sigma estimated per clip), lambda_l1 = 0.1 "
          "(eq. 5), 12 / 24 over-relaxed (alpha = 1.8) ADMM iterations on the rank_tol = 1e-6 truncated dictionaries, the l1/l1 pass (and the l2/l1 pass after it for mixed noise) on "
          "every 2nd window (`l1_stride = 2`), noise model detected automatically. Baselines tuned per "
          "condition on a training clip (the paper tuned all competitors by cross-validation on training data).",
          ""]
    targets = targets_summary(speed_rows, results.get("xiao-table2", []))
    if targets:
        md += ["## Summary: issue #5 speed targets", "",
               "(Speed: `benchmarks/xiao_speed.py`, CMU 05_05, best of 3; poselets vs full pose: Table 2 "
               "below. Wall-clock numbers on this shared 2-core machine vary by up to ~30 % between runs "
               "with the load of other jobs.)", "", targets]
    if "xiao-table1" in results:
        md += ["## Table 1: per-frame RMSE (cm)", "", table1_summary(results["xiao-table1"])]
    if "xiao-table2" in results:
        md += ["## Table 2: poselets vs full pose", "", table2_summary(results["xiao-table2"])]
    if "xiao-params" in results:
        md += ["## Fig. 10: parameters (validation folds inside the training clips)", "",
               "The lambda rows are how the defaults were chosen: dictionaries learned on part of the "
               "training clips, scored on a held-out training clip (never the test clips).", "",
               params_summary(results["xiao-params"])]
    if speed_md:
        md += ["## Speed (benchmarks/xiao_speed.py)", "", speed_md]
    md += ["## All rows", ""]
    for name, rows in results.items():
        md.append(bench.to_markdown(rows, title=name))
    a.out.write_text("\n".join(md))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
