"""Thesis (seed 003, Ch. 3-4) measurements: Table 4.1 run time, protocol tables, decisions.

Usage::

    python benchmarks/thesis_speed.py [--data DIR] [--parts speed,protocols,decisions]
                                      [--frames 600] [--repeats 2] [--quick]

Parts (each writes ``docs/results/thesis_<part>.json``; ``docs/results/thesis.md`` is then
rebuilt from every part's JSON present, so parts can be run separately):

* ``speed`` -- the ``thesis-runtime`` protocol: TSMC and TrNN seconds (one BLAS thread,
  20 % random missing markers) on clips of the lengths of Table 4.1 (152 ... 17,799
  frames, cut from CMU subject 135's trials concatenated), against the thesis' Matlab
  seconds, plus the log-log slope of seconds against frames (1 = linear).
* ``protocols`` -- ``thesis-missing-random``, ``thesis-missing-blocks`` and
  ``thesis-corrupt4``, reduced to the first ``--frames`` frames of each clip and
  ``--repeats`` repeats (the full setting -- whole clips, 20 repeats -- takes hours on
  two cores); tables per clip and averaged over clips.
* ``tdd`` -- trust-data detection on the clean protocol clips and with 15 cm spikes.
* ``decisions`` -- the measurements behind the documented deviations, on CMU clips that
  are *not* protocol clips (131_01, 07_05, 05_02, 135_06; first 600 frames; one seed):
  unit of the thesis weights (cm / CMU unit / m), factor width (full vs the
  last-significant-jump rule), PSC's residual refinement and dictionary training, and
  DynaMMo's latent dimension and E-step.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mocapkit.bench import core  # noqa: E402
from mocapkit.datasets import shared_data_dir  # noqa: E402

OUT_DIR = Path(__file__).resolve().parent.parent / "docs" / "results"
DECISION_CLIPS = ("131_01", "07_05", "05_02", "135_06")


# --------------------------------------------------------------------------------------
# parts
# --------------------------------------------------------------------------------------
def run_speed(data: Path | None, quick: bool) -> dict:
    ctx = core.Context(data, quick=quick, progress=False)
    t0 = time.time()
    rows = core.run("thesis-runtime", ctx)
    return {"rows": [r.to_dict() for r in rows], "wall_s": time.time() - t0}


def run_protocols(data: Path | None, frames: int, repeats: int, quick: bool) -> dict:
    opts = {"frames": frames, "repeats": repeats}
    out = {"frames": frames, "repeats": repeats, "quick": quick, "protocols": {}}
    for name in ("thesis-missing-random", "thesis-missing-blocks", "thesis-corrupt4"):
        ctx = core.Context(data, quick=quick, progress=False, options=dict(opts))
        t0 = time.time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rows = core.run(name, ctx)
        out["protocols"][name] = {"rows": [r.to_dict() for r in rows], "wall_s": time.time() - t0}
        print(f"{name}: {time.time() - t0:.0f} s", file=sys.stderr)
    return out


def run_decisions(data: Path | None) -> dict:
    from mocapkit import corrupt, denoise, io, metrics
    from mocapkit.datasets import cmu_amc

    clips = []
    for c in DECISION_CLIPS:
        p = cmu_amc(c, data)
        if p is not None:
            clips.append((c, io.read(p).slice(0, 600)))
    conds = (("mr=0.2", ("missing", {"ratio": 0.2})), ("mr=0.6", ("missing", {"ratio": 0.6})),
             ("ml=20", ("block_gaps", {"n_markers": 10, "length": 20})),
             ("ml=60", ("block_gaps", {"n_markers": 10, "length": 60})))
    variants = [
        ("linear", "linear", {}),
        ("spline", "spline", {}),
        ("trnn unit=cm", "trnn", {"unit_cm": 1.0}),
        ("trnn unit=CMU (default)", "trnn", {}),
        ("trnn unit=m", "trnn", {"unit_cm": 100.0}),
        ("trnn d=lsj", "trnn", {"d": "lsj"}),
        ("tsmc unit=cm", "tsmc", {"unit_cm": 1.0}),
        ("tsmc unit=CMU (default)", "tsmc", {}),
        ("tsmc unit=m", "tsmc", {"unit_cm": 100.0}),
        ("tsmc rank=lsj", "tsmc", {"rank": "lsj"}),
        ("dynammo k=16", "dynammo", {"k": 16}),
        ("dynammo k=48 (default)", "dynammo", {}),
        ("dynammo estep=observed", "dynammo", {"estep": "observed"}),
    ]
    rows = []
    psc_rows = []
    for clip, clean in clips:
        for cond, step in conds:
            noisy, miss = corrupt.combine(clean, [step], seed=0)
            for label, name, params in variants:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    t0 = time.time()
                    est = denoise.get(name, **params).denoise(noisy)
                    dt = time.time() - t0
                rows.append({"clip": clip, "condition": cond, "variant": label,
                             "rmse_missing": metrics.rmse(clean, est, miss), "seconds": dt})
    # PSC variants: train on 131_02/131_11 (walks, same subject) and test on 131_01
    train_ids = ("131_02", "131_11", "131_12")
    train = [io.read(cmu_amc(t, data)) for t in train_ids if cmu_amc(t, data) is not None]
    test = dict(clips).get("131_01")
    if train and test is not None:
        for label, params in (("psc k-means only (n_iter=0)", {"n_iter": 0}),
                              ("psc (default: trained, refine)", {}),
                              ("psc refine=False (thesis output)", {"refine": False})):
            t0 = time.time()
            model = denoise.get("psc", **params).fit(train)
            fit_s = time.time() - t0
            for cond, step in conds:
                noisy, miss = corrupt.combine(test, [step], seed=0)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    est = model.denoise(noisy)
                psc_rows.append({"clip": "131_01", "condition": cond, "variant": label,
                                 "rmse_missing": metrics.rmse(test, est, miss),
                                 "fit_seconds": fit_s, "train_error": model.train_error_})
    return {"rows": rows, "psc_rows": psc_rows, "psc_train": list(train_ids)}


def run_tdd(data: Path | None) -> dict:
    """Trust-data detection on the clean protocol clips, and on them with 15 cm spikes."""
    from mocapkit import corrupt, io
    from mocapkit.bench.protocols.thesis import CLIPS
    from mocapkit.datasets import cmu_amc
    from mocapkit.detect import detect_report, trust_data

    rows = []
    for ours, _ in CLIPS:
        p = cmu_amc(ours, data)
        if p is None:
            continue
        m = io.read(p)
        t0 = time.time()
        rep = detect_report(m)
        dt = time.time() - t0
        noisy, spikes = corrupt.outliers(m, ratio=0.05, mode="spike", magnitude_cm=15.0, seed=0)
        flagged = trust_data(noisy)
        clean_flags = trust_data(m)
        new = spikes & ~clean_flags
        rows.append({"clip": ours, "frames": m.n_frames, "seconds": dt,
                     "clean_flagged": rep["n_flagged"], "clean_frames_flagged": rep["frames_flagged"],
                     "clean_markers": {k: v["runs"] for k, v in rep["markers"].items()},
                     "spikes": int(spikes.sum()),
                     "recall": float((flagged & spikes).sum() / max(spikes.sum(), 1)),
                     "false_alarms": int((flagged & ~spikes & ~clean_flags).sum()),
                     "recall_new": float((flagged & new).sum() / max(new.sum(), 1))})
    return {"rows": rows}


# --------------------------------------------------------------------------------------
# Markdown
# --------------------------------------------------------------------------------------
def _f(x, nd=3):
    return "" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{nd}g}"


def md_speed(part: dict) -> str:
    rows = part["rows"]
    by = {}
    for r in rows:
        by.setdefault(int(r["condition"].split("=")[1]), {})[r["method"]] = r
    lines = ["## Run time against clip length (thesis Table 4.1)", "",
             "CMU subject 135's eight trials concatenated and cut to each length of Table 4.1 "
             "(the thesis' clips are other CMU actions of those lengths); 20 % of the markers "
             "of every frame removed; `denoise()` wall time with one BLAS thread; thesis: "
             "Matlab 7.10 on an Intel Core i5 2.4 GHz. Iterations = ALM iterations to the "
             "1e-4 stopping criterion. Speed-up = thesis seconds / our wall seconds (in brackets: "
             "/ our CPU seconds; the process is single-threaded, so CPU time is what the wall time "
             "would be on an idle machine). Best of 3 runs (1 run for 17,799 frames).", "",
             "| frames | thesis action | TSMC wall s | TSMC CPU s | TSMC thesis s | speed-up (CPU) | TrNN wall s | TrNN CPU s | TrNN thesis s | speed-up (CPU) | iterations (TSMC/TrNN) | RMSE missing cm (TSMC/TrNN) |",
             "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---|"]
    for n in sorted(by):
        a, b = by[n].get("tsmc"), by[n].get("trnn")
        if a is None or b is None:
            continue
        ca, cb = a["extra"]["cpu_seconds"], b["extra"]["cpu_seconds"]
        lines.append(
            f"| {n} | {a['clip'].split('(')[1].rstrip(')')} | {a['value']:.3f} | {ca:.3f} | "
            f"{a['paper_value']:.2f} | {a['paper_value'] / a['value']:.0f}x ({a['paper_value'] / ca:.0f}x) | "
            f"{b['value']:.3f} | {cb:.3f} | {b['paper_value']:.2f} | "
            f"{b['paper_value'] / b['value']:.0f}x ({b['paper_value'] / cb:.0f}x) | "
            f"{a['extra']['iterations']}/{b['extra']['iterations']} | "
            f"{a['extra']['rmse_missing_cm']:.3f}/{b['extra']['rmse_missing_cm']:.3f} |")
    band = [n for n in sorted(by) if "trnn(mstep=banded)" in by[n]]
    if band:
        lines += ["", "Same solvers with the banded M-step (`mstep=\"banded\"`, an exact O(T) "
                  "solve of the same system instead of the DCT):", "",
                  "| frames | TSMC wall s | TSMC CPU s | speed-up (CPU) | TrNN wall s | TrNN CPU s | speed-up (CPU) |",
                  "|---:|---:|---:|---:|---:|---:|---:|"]
        for n in band:
            a, b = by[n]["tsmc(mstep=banded)"], by[n]["trnn(mstep=banded)"]
            ca, cb = a["extra"]["cpu_seconds"], b["extra"]["cpu_seconds"]
            lines.append(f"| {n} | {a['value']:.3f} | {ca:.3f} | {a['paper_value'] / ca:.0f}x | "
                         f"{b['value']:.3f} | {cb:.3f} | {b['paper_value'] / cb:.0f}x |")
    ns = np.array(sorted(by))
    for meth in ("tsmc", "trnn", "tsmc(mstep=banded)", "trnn(mstep=banded)"):
        nm = np.array([n for n in ns if meth in by[n]])
        secs = np.array([by[n][meth]["extra"]["cpu_seconds"] for n in nm])
        if len(secs) >= 3:
            big = nm >= 1000
            if big.sum() >= 2:
                slope = np.polyfit(np.log(nm[big]), np.log(secs[big]), 1)[0]
                lines.append("")
                lines.append(f"{meth}: log-log slope of CPU seconds against frames over "
                             f"{int(nm[big].min())}-{int(nm[big].max())} frames = {slope:.2f} "
                             f"(1 = linear); CPU seconds per 1000 frames: "
                             + ", ".join(f"{1000 * s / n:.2f}" for n, s in zip(nm, secs)))
    lines.append("")
    lines.append(f"Measured {part.get('when', '')}; load average at the start "
                 f"{part.get('load', '')} on {part.get('cpus', '')} CPUs (other jobs shared "
                 f"the machine, so these are upper bounds). The 17,799-frame clip crosses seven "
                 f"trial seams (position jumps), hence its larger RMSE.")
    return "\n".join(lines) + "\n"


def _mean_table(rows: list[dict], metric: str, title: str) -> list[str]:
    methods = []
    for r in rows:
        if r["metric"] == metric and r["method"] not in methods:
            methods.append(r["method"])
    conds = []
    for r in rows:
        if r["metric"] == metric and r["condition"] not in conds:
            conds.append(r["condition"])
    lines = [f"### {title}", "", "| condition | " + " | ".join(methods) + " |",
             "|---|" + "---:|" * len(methods)]
    for c in conds:
        vals = []
        for m in methods:
            v = [r["value"] for r in rows if r["condition"] == c and r["method"] == m and r["metric"] == metric]
            vals.append(_f(float(np.mean(v))) if v else "")
        lines.append(f"| {c} | " + " | ".join(vals) + " |")
    # mean seconds per method
    secs = []
    for m in methods:
        s = [r["seconds"] for r in rows if r["method"] == m and r["metric"] == metric and r["seconds"] is not None]
        secs.append(_f(float(np.mean(s))) if s else "")
    lines.append("| mean seconds | " + " | ".join(secs) + " |")
    lines.append("")
    return lines


def _clip_table(rows: list[dict], metric: str) -> list[str]:
    lines = ["| clip | condition | method | RMSE cm | std | n | s | note |", "|---|---|---|---:|---:|---:|---:|---|"]
    for r in rows:
        if r["metric"] != metric:
            continue
        ex = r.get("extra", {}) or {}
        note = []
        if ex.get("converged") and not str(ex["converged"]).startswith(str(r["n"])):
            note.append(f"converged {ex['converged']}")
        lines.append(f"| {r['clip']} | {r['condition']} | {r['method']} | {_f(r['value'])} | "
                     f"{_f(r['std'], 2)} | {r['n']} | {_f(r['seconds'], 2)} | {'; '.join(note)} |")
    return lines


def md_protocols(part: dict) -> str:
    P = part["protocols"]
    red = (f"**Reduced run**: the first {part['frames']} frames of each clip and "
           f"{part['repeats']} repeats (the thesis: whole clips, 20 repeats)"
           + (", quick mode" if part.get("quick") else "") + ".")
    lines = ["## Missing-data protocols (thesis Sec. 4.2.3, Fig. 4.10 / 4.11)", "", red, "",
             "Clips (substitutes for the thesis' trials, see `mocapkit/bench/protocols/thesis.py`): "
             "05_07 for 05_13 (dance), 16_15 for 12_02 (walk), 131_03 for 49_02 (hop), 01_01 for "
             "13_13 (forward jump), 11_01 for 10_01 (soccer kick), 135_09 for 13_17 (boxing). "
             "PSC is trained per clip on other CMU trials of the same kind (the training set "
             "is named in the JSON rows). RMSE over the missing coordinates, cm.", ""]
    for name, title, metric in (("thesis-missing-random", "Random missing markers (mr = ratio of markers per frame), mean over clips", "rmse_missing"),
                                ("thesis-missing-blocks", "10 markers missing for ml consecutive frames, mean over clips", "rmse_missing")):
        if name in P:
            lines += _mean_table(P[name]["rows"], metric, title)
            lines.append(f"({name}: {P[name]['wall_s'] / 60:.1f} min)")
            lines.append("")
    if "thesis-corrupt4" in P:
        rows = P["thesis-corrupt4"]["rows"]
        lines += ["## Four corruption cases (thesis Sec. 4.1.3, Fig. 4.1-4.4)", "",
                  "rdcrypt: sigma = 2 cm on a random 30 % of marker entries; rdloss: 30 % of "
                  "markers missing per frame; mxcrypt: both (noise on 30 % of the remaining "
                  "entries); rgloss: blocks of 10 markers x 60 frames removing ~30 % of the "
                  "entries. RMSE over the imperfect (missing + noisy) entries (eq. 4.16), cm; "
                  "`corrupted-input` = RMSE of the noisy observed entries before cleaning.", ""]
        imp = [dict(r, metric="rmse_imperfect") if r["metric"] == "rmse_noisy_observed" else r
               for r in rows if r["metric"] in ("rmse_imperfect", "rmse_noisy_observed")]
        lines += _mean_table(imp, "rmse_imperfect", "RMSE on imperfect entries, mean over clips")
        lines += _mean_table([r for r in rows if r["metric"] == "rmse_all"], "rmse_all",
                             "RMSE on all entries, mean over clips")
    lines += ["## Per-clip results", ""]
    for name in ("thesis-missing-random", "thesis-missing-blocks"):
        if name in P:
            lines += [f"### {name}", ""] + _clip_table(P[name]["rows"], "rmse_missing") + [""]
    if "thesis-corrupt4" in P:
        lines += ["### thesis-corrupt4", ""] + _clip_table(P["thesis-corrupt4"]["rows"], "rmse_imperfect") + [""]
    return "\n".join(lines) + "\n"


def md_targets(parts: dict) -> str:
    """The issue's targets, checked against the measured rows (computed, not typed)."""
    lines = ["## Targets of the issue, checked on these measurements", ""]
    P = parts.get("protocols", {}).get("protocols", {})
    for name in ("thesis-missing-random", "thesis-missing-blocks"):
        if name not in P:
            continue
        rows = [r for r in P[name]["rows"] if r["metric"] == "rmse_missing"]
        keys = sorted({(r["clip"], r["condition"]) for r in rows})
        val = {(r["clip"], r["condition"], r["method"]): r["value"] for r in rows}
        hold_tt = sum(val.get((c, k, "trnn"), np.inf) <= val.get((c, k, "tsmc"), -np.inf) for c, k in keys)
        hold_ts = sum(val.get((c, k, "tsmc"), np.inf) <= val.get((c, k, "svt"), -np.inf) for c, k in keys)
        best = {}
        for c, k in keys:
            cand = {m: v for (cc, kk, m), v in val.items() if cc == c and kk == k}
            b = min(cand, key=cand.get)
            best[b] = best.get(b, 0) + 1
        lines.append(f"- {name}: trnn <= tsmc in {hold_tt}/{len(keys)} (clip, condition) cases, "
                     f"tsmc <= svt in {hold_ts}/{len(keys)}; best method per case: "
                     + ", ".join(f"{m} {n}" for m, n in sorted(best.items(), key=lambda x: -x[1])) + ".")
        hi = [(c, k) for c, k in keys if k in ("mr=0.5", "mr=0.6", "ml=50", "ml=60")]
        if hi:
            psc_best = [f"{c.split()[0]} {k}" for c, k in hi
                        if min(((m, v) for (cc, kk, m), v in val.items() if cc == c and kk == k),
                               key=lambda x: x[1])[0] == "psc"]
            lines.append(f"  psc best at the two highest ratios/lengths in {len(psc_best)}/{len(hi)} cases"
                         + (f" ({', '.join(psc_best)})" if psc_best else "") + ".")
    if "speed" in parts:
        rows = parts["speed"]["rows"]
        for meth in ("tsmc", "trnn"):
            rr = [r for r in rows if r["method"] == meth]
            if not rr:
                continue
            wall = [r["paper_value"] / r["value"] for r in rr]
            cpu = [r["paper_value"] / r["extra"]["cpu_seconds"] for r in rr]
            longest = max(rr, key=lambda r: int(r["condition"].split("=")[1]))
            lines.append(f"- {meth} speed-up over the thesis' Matlab: CPU time {min(cpu):.0f}x-{max(cpu):.0f}x "
                         f"({sum(c >= 20 for c in cpu)}/{len(cpu)} lengths >= 20x), wall time "
                         f"{min(wall):.0f}x-{max(wall):.0f}x ({sum(w >= 20 for w in wall)}/{len(wall)} >= 20x); "
                         f"{longest['condition']}: {longest['value']:.1f} s wall, "
                         f"{longest['extra']['cpu_seconds']:.1f} s CPU.")
    return "\n".join(lines) + "\n"


def md_tdd(part: dict) -> str:
    lines = ["## Trust-data detection (6 cm, `mocapkit.detect.trust_data`)", "",
             "On the clean protocol clips (whole clips), and with 15 cm spikes added to 5 % of the "
             "marker entries (`corrupt.outliers`, mode spike). False alarms = flags on "
             "entries that are neither spikes nor flagged in the clean clip.", "",
             "| clip | frames | flags on clean clip | flagged runs on the clean clip (marker: [start, stop) frames) | spikes | recall | false alarms | s |",
             "|---|---:|---:|---|---:|---:|---:|---:|"]
    for r in part["rows"]:
        runs = "; ".join(f"{k}: {v[:3]}{'...' if len(v) > 3 else ''}" for k, v in list(r["clean_markers"].items())[:6])
        lines.append(f"| {r['clip']} | {r['frames']} | {r['clean_flagged']} | {runs} | {r['spikes']} | "
                     f"{r['recall']:.3f} | {r['false_alarms']} | {r['seconds']:.2f} |")
    return "\n".join(lines) + "\n"


def md_decisions(part: dict) -> str:
    rows = part["rows"]
    conds = list(dict.fromkeys(r["condition"] for r in rows))
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    lines = ["## Measurements behind the decisions (non-protocol clips)", "",
             "CMU 131_01, 07_05, 05_02, 135_06 (first 600 frames, 120 fps), one seed; RMSE over "
             "missing coordinates (cm), mean over the four clips.", "",
             "| variant | " + " | ".join(conds) + " | mean s |", "|---|" + "---:|" * (len(conds) + 1)]
    for v in variants:
        vals = [float(np.mean([r["rmse_missing"] for r in rows if r["variant"] == v and r["condition"] == c]))
                for c in conds]
        s = float(np.mean([r["seconds"] for r in rows if r["variant"] == v]))
        lines.append(f"| {v} | " + " | ".join(_f(x) for x in vals) + f" | {_f(s)} |")
    if part.get("psc_rows"):
        pr = part["psc_rows"]
        lines += ["", f"PSC on 131_01 (first 600 frames), trained on {', '.join(part['psc_train'])} "
                      "(same subject, walks):", "",
                  "| variant | " + " | ".join(conds) + " | fit s |", "|---|" + "---:|" * (len(conds) + 1)]
        for v in dict.fromkeys(r["variant"] for r in pr):
            vals = [next(r["rmse_missing"] for r in pr if r["variant"] == v and r["condition"] == c) for c in conds]
            fs = next(r["fit_seconds"] for r in pr if r["variant"] == v)
            lines.append(f"| {v} | " + " | ".join(_f(x) for x in vals) + f" | {_f(fs)} |")
    return "\n".join(lines) + "\n"


HEADER = """# Thesis refinement methods (seed 003, Ch. 3-4): measured results

Written by `benchmarks/thesis_speed.py` (every number below comes from a run of that
script; nothing is typed by hand). Methods: `psc` (Ch. 3), `tsmc` (Sec. 4.1), `trnn`
(Sec. 4.2), `dynammo` (Li et al. 2009), against `svt` (low-rank family), `spline` and
`linear` gap filling. Positions in cm, CMU ASF/AMC clips at 120 fps.

Settings: thesis values (tsmc: alpha 1, beta 100, lambda 1e-5, gamma 1.4; trnn: lambda
100/sqrt(max(m, n)), mu 100, rho 1.4, eta0 1e-5, eps 1e-4, r = 15; psc: M = 10, K = 1024,
lambda = 10, TDD 6 cm) with the documented decisions: the weights are read in CMU length
units (data divided by 5.6444 cm before solving), the factor width is min(T, 3J) instead of
the last-significant-jump rank (which gives 2-3 on raw mocap matrices), PSC adds its
coding residual interpolated across the holes (`refine=True`), DynaMMo uses k = 48.
"""


def plot_speed(part: dict, path: Path) -> bool:
    """Log-log plot of seconds against frames (ours CPU and wall, the thesis' Matlab)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:                                    # pragma: no cover
        return False
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    styles = {"tsmc": "tab:red", "trnn": "tab:blue"}
    for meth, col in styles.items():
        rr = sorted((r for r in part["rows"] if r["method"] == meth),
                    key=lambda r: int(r["condition"].split("=")[1]))
        n = [int(r["condition"].split("=")[1]) for r in rr]
        ax.loglog(n, [r["paper_value"] for r in rr], "s--", color=col, alpha=0.6,
                  label=f"{meth.upper()} thesis (Matlab)")
        ax.loglog(n, [r["extra"]["cpu_seconds"] for r in rr], "o-", color=col,
                  label=f"{meth.upper()} ours (CPU s)")
        ax.loglog(n, [r["value"] for r in rr], "o:", color=col, alpha=0.5, ms=3,
                  label=f"{meth.upper()} ours (wall s)")
    ax.set_xlabel("frames (93 coordinates, 20% markers missing)")
    ax.set_ylabel("seconds")
    ax.set_title("Table 4.1 run time: thesis vs mocapkit (one BLAS thread)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def write_md(parts: dict) -> Path:
    text = [HEADER, md_targets(parts)]
    if "speed" in parts and plot_speed(parts["speed"], OUT_DIR / "thesis_runtime.png"):
        text.append("![run time against frames](thesis_runtime.png)\n")
    if "protocols" in parts:                               # flat row lists, one per protocol
        for name, v in parts["protocols"]["protocols"].items():
            (OUT_DIR / f"{name}.json").write_text(json.dumps(v["rows"], indent=1))
    if "speed" in parts:
        text.append(md_speed(parts["speed"]))
    if "protocols" in parts:
        text.append(md_protocols(parts["protocols"]))
    if "tdd" in parts:
        text.append(md_tdd(parts["tdd"]))
    if "decisions" in parts:
        text.append(md_decisions(parts["decisions"]))
    path = OUT_DIR / "thesis.md"
    path.write_text("\n".join(text))
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None)
    ap.add_argument("--parts", default="speed,protocols,tdd,decisions")
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--md-only", action="store_true", help="rebuild thesis.md from the JSON parts")
    a = ap.parse_args(argv)
    data = shared_data_dir(a.data)
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    if not a.md_only:
        for part in [p.strip() for p in a.parts.split(",") if p.strip()]:
            t0 = time.time()
            load0 = f"{os.getloadavg()[0]:.1f}"
            if part == "speed":
                res = run_speed(data, a.quick)
            elif part == "protocols":
                res = run_protocols(data, a.frames, a.repeats, a.quick)
            elif part == "decisions":
                res = run_decisions(data)
            elif part == "tdd":
                res = run_tdd(data)
            else:
                raise SystemExit(f"unknown part {part!r}")
            res["when"] = time.strftime("%Y-%m-%d %H:%M")
            res["load"] = load0
            res["cpus"] = os.cpu_count()
            res["python"] = platform.python_version()
            (OUT_DIR / f"thesis_{part}.json").write_text(json.dumps(res, indent=1, default=float))
            print(f"{part}: {time.time() - t0:.0f} s", file=sys.stderr)
    parts = {}
    for part in ("speed", "protocols", "tdd", "decisions"):
        p = OUT_DIR / f"thesis_{part}.json"
        if p.exists():
            parts[part] = json.loads(p.read_text())
    print(write_md(parts))
    return 0


if __name__ == "__main__":
    from _report import method_time

    raise SystemExit(method_time(main))
