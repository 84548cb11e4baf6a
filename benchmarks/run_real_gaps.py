"""Run the ``real-gaps`` protocol (issue #15) and write docs/results/real_gaps.json + .md.

Usage: ``python benchmarks/run_real_gaps.py [--quick] [--data DIR] [--seed N] [--out docs/results/real_gaps.md]``

Runs :mod:`mocapkit.bench.protocols.real_gaps` through :func:`mocapkit.bench.run` with one
BLAS thread, writes its rows as JSON next to the Markdown file and renders the Markdown
from that JSON (``--render-only`` re-renders an existing JSON). Nothing in the Markdown is
typed by hand.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections import defaultdict  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mocapkit import bench  # noqa: E402
from mocapkit.bench.protocols import real_gaps as P  # noqa: E402
from mocapkit.datasets import shared_data_dir  # noqa: E402


def _f(x, nd: int = 3) -> str:
    if x is None:
        return ""
    if isinstance(x, float) and not math.isfinite(x):
        return "n/a"
    if isinstance(x, float):
        return f"{x:.{nd}g}" if abs(x) < 10 ** nd else f"{x:.0f}"
    return str(x)


def _round(x):
    if isinstance(x, float):
        return x if not math.isfinite(x) or x == 0 else float(f"{x:.6g}")
    if isinstance(x, dict):
        return {k: _round(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_round(v) for v in x]
    return x


def _slim(r: dict) -> dict:
    """A row as stored: 6 significant digits, no None fields, no extra that only repeats
    the case's missing % (kept on its ``rmse`` and ``mask`` rows)."""
    r = {k: _round(v) for k, v in r.items() if v is not None}
    ex = r.get("extra")
    if ex is not None and r["metric"] not in ("rmse", "missing_pct") and set(ex) <= {"missing_pct"}:
        r.pop("extra")
    return r


def _index(rows: list[dict]) -> dict:
    by = {}
    for r in rows:
        by[(r["clip"], r["condition"], r["method"], r["metric"])] = r
    return by


def targets_section(rows: list[dict], methods: list[str]) -> str:
    by = _index(rows)
    cond = f"cases <= {P.SCORED_MAX_MISSING:g}% missing"

    def v(m, metric):
        r = by.get(("targets", cond, m, metric))
        return None if r is None else r["value"]

    n_scored = len({(r["clip"], r["condition"]) for r in rows
                    if r["metric"] == "missing_pct" and r["method"] == "mask"
                    and r["clip"] != "tennis_serve_vendor" and r["value"] <= P.SCORED_MAX_MISSING})
    n_all = len({(r["clip"], r["condition"]) for r in rows
                 if r["metric"] == "missing_pct" and r["clip"] != "tennis_serve_vendor"})
    ran = list(dict.fromkeys(r["extra"]["ran"] for r in rows if r["method"] == "default"
                             and r["metric"] == "rmse" and r.get("extra", {}).get("ran")))
    out = [f"## Targets (issue #15), {n_scored} of {n_all} cases with <= {P.SCORED_MAX_MISSING:g} % missing", ""]
    if "default" in methods:
        med, worst = v("default", "median_ratio_best_peer"), v("default", "worst_ratio_best_peer")
        gross, outside, crashes = v("default", "gross_pct"), v("default", "outside_1m"), v("default", "crashes")
        worse = v("default", "cases_worse_than_best_peer")
        wcase = by.get(("targets", cond, "default", "worst_ratio_best_peer"), {}).get("extra", {}).get("case", "")
        cov = v("default", "coverage")

        def ok(x, good):
            return "" if x is None else ("met" if good(x) else "**not met**")

        zero = v("default", "zero_fills")
        out += ["`default` (`denoise.default()`) ran as "
                + " / ".join(f"`{x}`" for x in ran) + ".", "",
                "| target | default | goal | |", "|---|---:|---:|---|",
                f"| median ratio of gap RMSE to the best of linear / cubic / kineticstoolkit (same samples) "
                f"| {_f(med)} | <= 0.5 | {ok(med, lambda x: x <= 0.5)} |",
                f"| worst case ratio ({wcase}) | {_f(worst)} | <= 1 | {ok(worst, lambda x: x <= 1.0)} |",
                f"| cases worse than the best peer | {_f(worse)} | 0 | {ok(worse, lambda x: x == 0)} |",
                f"| gross fills (> {P.GROSS_CM:g} cm), % of filled | {_f(gross)} | <= 5 | {ok(gross, lambda x: x <= 5)} |",
                f"| fills > 1 m outside the capture volume | {_f(outside)} | 0 | {ok(outside, lambda x: x == 0)} |",
                f"| crashes (all cases) | {_f(crashes)} | 0 | {ok(crashes, lambda x: x == 0)} |",
                f"| fills exactly (0, 0, 0) (all cases) | {_f(zero)} | 0 | {ok(zero, lambda x: x == 0)} |",
                f"| coverage (% of hidden samples filled) | {_f(cov)} | | |", ""]
    out += ["Every method on the same scored cases (ratio = method RMSE / best peer RMSE on exactly the "
            "samples the method filled; median and worst over cases):", "",
            "| method | median ratio | worst ratio | cases worse than best peer | gross % | coverage % "
            "| outside 1 m (scored / all cases) | (0,0,0) fills | crashes |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for m in methods:
        o = by.get(("targets", cond, m, "outside_1m"))
        out.append(f"| {m} | {_f(v(m, 'median_ratio_best_peer'))} | {_f(v(m, 'worst_ratio_best_peer'))} | "
                   f"{_f(v(m, 'cases_worse_than_best_peer'))} | {_f(v(m, 'gross_pct'))} | "
                   f"{_f(v(m, 'coverage'))} | {_f(v(m, 'outside_1m'))} / "
                   f"{_f(o['extra'].get('all_cases') if o else None)} | {_f(v(m, 'zero_fills'))} | "
                   f"{_f(v(m, 'crashes'))} |")
    est = [(m, by.get(("targets", cond, m, "estimate_within_1.5x"))) for m in methods]
    est = [(m, r) for m, r in est if r]
    if est:
        out += ["", "Self-estimated error (issue #19): the method's own estimate of its error against the "
                "true RMSE over what it covers (auto: every sample written; fill-auto: its fills), on the "
                "same scored cases:", "",
                "| method | within 1.5x, % of cases | cases | under (< 1/1.5) | over (> 1.5) | median estimate / true |",
                "|---|---:|---:|---:|---:|---:|"]
        out += [f"| {m} | {_f(r['value'])} | {r.get('n')} | {r['extra'].get('under')} | {r['extra'].get('over')} | "
                f"{_f(r['extra'].get('median_ratio'))} |" for m, r in est]
    return "\n".join(out) + "\n"


def pooled_section(rows: list[dict], methods: list[str]) -> str:
    by = _index(rows)
    out = []
    for cond in ("all cases", f"cases <= {P.SCORED_MAX_MISSING:g}% missing"):
        out += [f"### Pooled, {cond}", "",
                "| method | RMSE cm | coverage % | gross % | outside 1 m | max err cm | "
                "ratio vs linear | vs cubic | vs kineticstoolkit | RMSE all hidden (cases) | crashes | s (total) |",
                "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for m in methods:
            g = lambda k: by.get(("pooled", cond, m, k))  # noqa: E731
            val = lambda k: None if g(k) is None else g(k)["value"]  # noqa: E731
            ra = g("rmse_all_hidden")
            ra_s = "" if ra is None else f"{_f(ra['value'])} ({ra['extra']['cases']})"
            sec = g("rmse").get("seconds") if g("rmse") else None
            out.append(f"| {m} | {_f(val('rmse'))} | {_f(val('coverage'))} | {_f(val('gross_pct'))} | "
                       f"{_f(val('outside_1m'))} | {_f(val('max_err'))} | {_f(val('ratio_linear'))} | "
                       f"{_f(val('ratio_cubic'))} | {_f(val('ratio_kineticstoolkit'))} | {ra_s} | "
                       f"{_f(val('crashes'))} | {_f(sec)} |")
        out.append("")
    return "\n".join(out)


def vendor_section(rows: list[dict], methods: list[str]) -> str:
    vr = [r for r in rows if r["clip"] == "tennis_serve_vendor"]
    if not vr:
        return ""
    miss = next((r["value"] for r in vr if r["metric"] == "missing_pct"), None)
    by = {r["method"]: r for r in vr if r["metric"] in ("rms_to_vendor_fill", "failed")}
    out = ["## Tennis serve: distance to the vendor's own fill", "",
           "`kinematics_tennis_serve.c3d` is the vendor's gap-filled twin of "
           f"`kinematics_tennis_serve_nan.c3d` ({_f(miss)} % of samples missing, real gaps). "
           "There is **no ground truth** for these gaps: the numbers say how far each method's fill "
           "is from the vendor's, not how right it is.", "",
           "| method | RMS distance to vendor fill, cm | max distance cm | coverage % | s |",
           "|---|---:|---:|---:|---:|"]
    for m in methods:
        r = by.get(m)
        if r is None:
            continue
        if r["metric"] == "failed":
            out.append(f"| {m} | failed: {r['extra'].get('error', '')} | | | |")
        else:
            e = r.get("extra", {})
            out.append(f"| {m} | {_f(r['value'])} | {_f(e.get('max_dist'))} | {_f(e.get('coverage'))} | "
                       f"{_f(r.get('seconds'))} |")
    return "\n".join(out) + "\n"


def cases_section(rows: list[dict], methods: list[str]) -> str:
    case_keys = list(dict.fromkeys((r["clip"], r["condition"]) for r in rows
                                   if r["method"] == "mask" and r["clip"] != "tennis_serve_vendor"))
    by = _index(rows)
    peers = [p for p in P.PEERS if p in methods]
    out = ["## Per case", "",
           "RMSE over the hidden samples each method filled; ratio = its RMSE / the best peer's on exactly "
           "those samples (best peer named); peer columns: each peer's RMSE on those same samples.", "",
           "| target | mask source | missing % | method | RMSE cm | coverage % | gross % | outside 1 m | "
           "max err cm | ratio (best peer) | " + " | ".join(f"{p} same" for p in peers) + " | s |",
           "|---|---|---:|---|---:|---:|---:|---:|---:|---:|" + "---:|" * len(peers) + "---:|"]
    for clip, cond in case_keys:
        miss = by[(clip, cond, "mask", "missing_pct")]["value"]
        for m in methods:
            g = lambda k: by.get((clip, cond, m, k))  # noqa: E731
            if g("failed"):
                out.append(f"| {clip} | {cond[5:]} | {_f(miss)} | {m} | failed: "
                           f"{g('failed')['extra'].get('error', '')[:120]} |" + " |" * (6 + len(peers)))
                continue
            r = g("rmse")
            if r is None:
                continue
            val = lambda k: None if g(k) is None else g(k)["value"]  # noqa: E731
            rb = g("ratio_best_peer")
            ratio = "" if rb is None else f"{_f(rb['value'])} ({rb['extra']['best_peer']})"
            ps = r["extra"].get("peer_rmse_same", {})
            out.append(f"| {clip} | {cond[5:]} | {_f(miss)} | {m} | {_f(val('rmse'))} | {_f(val('coverage'))} | "
                       f"{_f(val('gross_pct'))} | {_f(val('outside_1m'))} | {_f(val('max_err'))} | {ratio} | "
                       + " | ".join(_f(ps.get(p)) for p in peers) + f" | {_f(r.get('seconds'))} |")
    return "\n".join(out) + "\n"


def render(rows: list[dict], meta: dict) -> str:
    setup = next((r for r in rows if r["clip"] == "setup" and r["metric"] == "notes"), {"extra": {}})
    ex = setup.get("extra", {})
    methods = ex.get("methods") or list(dict.fromkeys(r["method"] for r in rows if r["method"] not in ("mask", "-")))
    fails = [r for r in rows if r["metric"] == "failed"]
    parts = [
        f"# Real-occlusion gap filling (`mocapkit bench real-gaps`){' — QUICK run' if ex.get('quick') else ''}",
        "",
        "Generated by `python benchmarks/run_real_gaps.py"
        f"{' --quick' if ex.get('quick') else ''}` from `real_gaps.json` (seed {meta.get('seed', 0)}, "
        f"one BLAS thread, {meta.get('seconds', float('nan')):.0f} s on this machine). "
        "Protocol: the docstring of `mocapkit/bench/protocols/real_gaps.py` (real missing-sample masks of "
        "the shared marker captures, resampled in time and laid over gap-free real captures with known "
        "truth; one time offset per case keeps co-missing markers together). RMSE is per coordinate "
        "(cm), gross = 3-D error > 20 cm, outside = filled sample > 1 m outside the bounding box of the "
        "target's observed samples. Methods may leave samples they cannot support missing: coverage says "
        "how many hidden samples each filled, and ratios compare with the peers on exactly those samples.",
        "",
        targets_section(rows, methods),
        "## Setup", "",
        f"- mask sources: {', '.join('`' + s + '`' for s in ex.get('sources', []))}",
        f"- targets: {', '.join('`' + s + '`' for s in ex.get('targets', []))}",
        f"- methods: {', '.join('`' + s + '`' for s in methods)}",
    ]
    parts += [f"- note: {n}" for n in ex.get("notes", [])]
    skipped = next((r for r in rows if r["clip"] == "setup" and r["metric"] == "skipped"), None)
    if skipped:
        parts.append(f"- {skipped['extra'].get('cases')} cases scored; skipped: "
                     + ("; ".join(skipped["extra"].get("notes", [])) or "none"))
    parts += ["", pooled_section(rows, methods), vendor_section(rows, methods)]
    if fails:
        parts += ["## Failures", "", "| target | mask | method | error |", "|---|---|---|---|"]
        parts += [f"| {r['clip']} | {r['condition']} | {r['method']} | {r['extra'].get('error', '')} |"
                  for r in fails]
        parts.append("")
    parts.append(cases_section(rows, methods))
    return "\n".join(parts)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--data", default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "real_gaps.md"))
    ap.add_argument("--render-only", action="store_true", help="re-render the Markdown from the JSON")
    a = ap.parse_args(argv)
    out = Path(a.out)
    js = out.with_suffix(".json")
    out.parent.mkdir(parents=True, exist_ok=True)
    if a.render_only:
        rows = json.loads(js.read_text())
        meta = {}
    else:
        from threadpoolctl import threadpool_limits

        t0 = time.perf_counter()

        def log(msg: str) -> None:
            print(f"[{time.perf_counter() - t0:6.0f} s] {msg}", file=sys.stderr, flush=True)

        ctx = bench.Context(data_dir=shared_data_dir(a.data), quick=a.quick, seed=a.seed, progress=True,
                            options={"log": log})
        with threadpool_limits(1):
            rows_obj = bench.run("real-gaps", ctx)
        meta = {"seed": a.seed, "quick": a.quick, "seconds": time.perf_counter() - t0}
        rows = json.loads(json.dumps([r.to_dict() for r in rows_obj]))    # plain JSON types
        # run metadata rides on the setup row so one JSON file holds everything
        for r in rows:
            if r["clip"] == "setup" and r["metric"] == "notes":
                r.setdefault("extra", {})["run"] = meta
        rows = [_slim(r) for r in rows]
        js.write_text("[\n" + ",\n".join(json.dumps(r) for r in rows) + "\n]\n")
    if not meta:
        meta = next((r.get("extra", {}).get("run", {}) for r in rows
                     if r["clip"] == "setup" and r["metric"] == "notes"), {})
    out.write_text(render(rows, meta))
    print(f"wrote {js} and {out} ({len(rows)} rows, {meta.get('seconds', float('nan')):.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
