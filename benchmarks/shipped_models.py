"""Shipped general models vs same-behaviour models, on held-out subjects (issue #19 item 1).

Usage: ``python benchmarks/shipped_models.py [--data DIR] [--out docs/results/shipped_models.md]
[--seeds 1] [--cache DIR] [--quick]``

For every behaviour of the shared data, on clips of subjects the shipped models never saw
(:data:`train_shipped.HELD_OUT`), at 30 and 120 fps, with Gaussian noise of 1 and 3 cm and
10 % of the joint entries turned into 15 cm spikes (:mod:`mocapkit.corrupt`), the RMSE (cm,
per coordinate, over all entries, against the clean clip) of

* the shipped general model (:func:`mocapkit.shipped.load`) of xiao-sparse, psc and lou-chai;
* a same-behaviour model of the same method, trained on the other clips of that behaviour
  (the paper protocol; for CMU these are mostly clips of the same subject, i.e. "the user's
  own clips");
* ``gaussian`` and ``kalman-cv`` with their defaults, and the noisy input.

Also: the frame-rate decision (one model per rate vs one model and phases / resampling), the
cost of float16 storage (when the float64 models of ``train_shipped.py --keep-f64`` are in
``--f64``), and the load time. Writes the Markdown file and a JSON file of all rows next to
it. Nothing in the Markdown file is typed by hand except the fixed text in this script.

Reduced protocol (to stay under ~15 min on one core): CMU test clips are cut to their first
10 s (1200 frames at 120 fps), HDM05 classes use the first clip of actor mm, one noise
seed per (clip, condition) unless ``--seeds``; same-behaviour xiao-sparse models use
``max_train_windows=3000, n_iter=5`` and psc ``max_windows=2000`` (their defaults are 8000 /
10 and 3000; lou-chai the shipped settings); the general models use the shipped settings (train_shipped.PARAMS). The
float64 originals are run in the Gaussian 3 cm condition only; the frame-rate study uses
three clips and one seed.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from collections import defaultdict
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import train_shipped as ts  # noqa: E402
from mocapkit import corrupt, denoise, metrics, shipped  # noqa: E402

METHODS = ("xiao-sparse", "psc", "lou-chai")
RATES = (30, 120)
CONDITIONS = {
    "gauss1": ("Gaussian 1 cm", [("gaussian", {"sigma_cm": 1.0})]),
    "gauss3": ("Gaussian 3 cm", [("gaussian", {"sigma_cm": 3.0})]),
    "spikes": ("10 % x 15 cm spikes", [("outliers", {"ratio": 0.10, "magnitude_cm": 15.0})]),
}
SAME_PARAMS = {"xiao-sparse": {"max_train_windows": 3000, "n_iter": 5},
               "psc": {"max_windows": 2000}, "lou-chai": dict(ts.PARAMS["lou-chai"])}
#: CMU test clips (held-out subjects) and the behaviour whose other clips train the
#: same-behaviour model
CMU_TESTS = {"walk": ["16_15", "35_01"], "run": ["09_06"], "jump": ["01_01"], "dance": ["05_02"],
             "martial arts": ["135_06"], "kicks": ["135_04"], "balance": ["49_18"]}
MAX_FRAMES_120 = 1200


def cases(cat: list[dict], quick: bool) -> list[dict]:
    """Test cases: behaviour, test clips, same-behaviour training clips."""
    by_trial = {c["trial"]: c for c in cat}
    out = []
    for beh, tests in CMU_TESTS.items():
        test = [by_trial[t] for t in tests if t in by_trial]
        if not test:
            continue
        names = {c["trial"] for c in test}
        if beh == "run":           # the only CMU run: HDM05 jogging of the other actors
            train = [c for c in cat if c["dataset"] == "hdm05" and c["group"] == "run" and not c["held_out"]]
        elif beh == "kicks":
            train = [c for c in cat if c["group"] == "kicks" and c["trial"] not in names and not
                     (c["dataset"] == "hdm05" and c["held_out"])]
        else:
            train = [c for c in cat if c["dataset"] == "cmu" and c["behaviour"] == beh and c["trial"] not in names]
        out.append({"behaviour": beh, "test": test, "train": train})
    classes = sorted({c["behaviour"] for c in cat if c["dataset"] == "hdm05" and c["behaviour"] != "HDM05 take"})
    for cls in classes:
        test = [c for c in cat if c["behaviour"] == cls and c["held_out"]][:1]
        train = [c for c in cat if c["behaviour"] == cls and not c["held_out"]]
        if test and train:
            out.append({"behaviour": cls, "test": test, "train": train})
    if quick:
        out = [c for c in out if c["behaviour"] in ("walk", "dance", "HDM05 kickLFront1Reps")]
    return out


def test_motion(clip: dict, fps: int):
    m = ts.read(clip["path"])
    if clip["dataset"] == "cmu" and m.n_frames > MAX_FRAMES_120:
        m = _crop(m, MAX_FRAMES_120)
    return ts.at_rate(m, fps)[0]


def _crop(m, n):
    from mocapkit.motion import Motion

    return Motion(m.positions[:n], m.skeleton, m.fps, m.observed[:n], {"path": m.source.get("path")})


def corrupted(m, cond: str, seed: int):
    steps = CONDITIONS[cond][1]
    return corrupt.combine(m, steps, seed=seed)[0]


def rmse(truth, est) -> float:
    return float(metrics.rmse(truth, est))


def run_den(model, noisy):
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = model.denoise(noisy)
    return out, time.perf_counter() - t0


def same_model(method: str, case: dict, fps: int, cache: Path | None):
    key = f"{method}-{case['behaviour'].replace(' ', '_')}-{fps}.npz"
    if cache is not None and (cache / key).is_file():
        from mocapkit.denoise.base import Denoiser

        return Denoiser.load(cache / key), 0.0
    mot = ts.training_set(case["train"], 30 if method == "lou-chai" else fps)
    t0 = time.perf_counter()
    model = ts.fit(method, mot, SAME_PARAMS[method])
    sec = time.perf_counter() - t0
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        model.save(cache / key)
    return model, sec


def f64_model(method: str, motion, f64dir: Path | None):
    """The float64 original of the shipped model ``load`` picks, or None."""
    if f64dir is None:
        return None
    c = shipped.choose(method, motion)
    if c is None or not (f64dir / c["file"]).is_file():
        return None
    from mocapkit.denoise.base import Denoiser

    model = Denoiser.load(f64dir / c["file"])
    return model if c["mode"] == "native" else shipped.RateAdapter(model, c["model_fps"])


def forced(method: str, model_fps: int):
    """The shipped model of ``model_fps`` wrapped to run at any rate (rate study)."""
    fname = f"{method}-{model_fps}fps.npz"
    return shipped.RateAdapter(shipped._fresh(fname), float(model_fps))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None)
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "shipped_models.md"))
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--cache", default=None, help="folder for the same-behaviour models")
    ap.add_argument("--f64", default=None, help="folder of the float64 general models")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--render", action="store_true", help="only re-render the Markdown from the JSON next to --out")
    a = ap.parse_args(argv)
    if a.render:
        out = Path(a.out)
        d = json.loads(out.with_suffix(".json").read_text())
        out.write_text(render(d["rows"], d["meta"]))
        print(f"wrote {out}")
        return 0
    t_start = time.perf_counter()
    cat = ts.catalogue(a.data)
    cs = cases(cat, a.quick)
    cache = Path(a.cache) if a.cache else None
    f64dir = Path(a.f64) if a.f64 else None
    rows: list[dict] = []

    def row(**kw):
        rows.append(kw)

    # -- load time ----------------------------------------------------------------------
    probe = test_motion(cs[0]["test"][0], 120)
    load_s = {}
    for method in METHODS:
        shipped._load_file.cache_clear()
        t0 = time.perf_counter()
        mdl = shipped.load(method, probe)
        load_s[method] = time.perf_counter() - t0
        assert mdl is not None, method
    sizes = {f: (shipped.MODELS_DIR / f).stat().st_size for f in shipped._index()}

    # -- main table -----------------------------------------------------------------------
    gauss, kal = denoise.get("gaussian"), denoise.get("kalman-cv")
    train_s = {}
    for case in cs:
        beh = case["behaviour"]
        for fps in RATES:
            same = {}
            for method in METHODS:
                same[method], train_s[(method, beh, fps)] = same_model(method, case, fps, cache)
            for clip in case["test"]:
                truth = test_motion(clip, fps)
                gen = {m: shipped.load(m, truth) for m in METHODS}
                g64 = {m: f64_model(m, truth, f64dir) for m in METHODS}
                for cond in CONDITIONS:
                    for seed in range(a.seeds):
                        noisy = corrupted(truth, cond, seed)
                        base = dict(behaviour=beh, clip=clip["trial"], fps=fps, condition=cond, seed=seed)
                        row(**base, method="input", model="-", rmse=rmse(truth, noisy), seconds=0.0)
                        for name, mdl in (("gaussian", gauss), ("kalman-cv", kal)):
                            out, s = run_den(mdl, noisy)
                            row(**base, method=name, model="-", rmse=rmse(truth, out), seconds=s)
                        for method in METHODS:
                            for kind, mdl in (("general", gen[method]), ("same", same[method]),
                                              ("general-f64", g64[method] if cond == "gauss3" else None)):
                                if mdl is None:
                                    continue
                                out, s = run_den(mdl, noisy)
                                row(**base, method=method, model=kind, rmse=rmse(truth, out), seconds=s)
                print(f"{beh} {clip['trial']} {fps} fps done ({time.perf_counter() - t_start:.0f} s)", flush=True)

    # -- frame-rate study -------------------------------------------------------------------
    rate_cases = [c for c in cs if c["behaviour"] in ("walk", "dance", "HDM05 kickLFront1Reps")]
    for case in rate_cases:
        clip = case["test"][0]
        for fps in (30, 60, 120):
            truth = test_motion(clip, fps)
            for cond in ("gauss3", "spikes"):
                noisy = corrupted(truth, cond, 100)
                base = dict(behaviour=case["behaviour"], clip=clip["trial"], fps=fps, condition=cond, seed=100)
                row(**base, method="input", model="rate-study", rmse=rmse(truth, noisy), seconds=0.0)
                for method in ("xiao-sparse", "psc"):
                    for mf in (30, 120):
                        out, s = run_den(forced(method, mf), noisy)
                        row(**base, method=method, model=f"rate-study {mf}fps-model", rmse=rmse(truth, out), seconds=s)
        print(f"rate study {case['behaviour']} done ({time.perf_counter() - t_start:.0f} s)", flush=True)

    total = time.perf_counter() - t_start
    meta = {"load_seconds": load_s, "sizes_bytes": sizes, "total_seconds": total,
            "seeds": a.seeds, "quick": a.quick, "same_params": SAME_PARAMS,
            "general_params": ts.PARAMS, "held_out": ts.HELD_OUT,
            "train_seconds_same": {f"{m}|{b}|{f}": s for (m, b, f), s in train_s.items()},
            "cases": [{"behaviour": c["behaviour"], "test": [x["trial"] for x in c["test"]],
                       "train": [x["trial"] for x in c["train"]]} for c in cs],
            "describe": {m: shipped.describe(m) for m in shipped.available()}}
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    out.write_text(render(rows, meta))
    print(f"wrote {out} ({total:.0f} s)")
    return 0


# ---------------------------------------------------------------------------------------
def _mean(rows, **sel):
    v = [r["rmse"] for r in rows if all(r[k] == x for k, x in sel.items())]
    return float(np.mean(v)) if v else float("nan")


def render(rows: list[dict], meta: dict) -> str:
    main = [r for r in rows if not r["model"].startswith("rate-study")]
    behs = list(dict.fromkeys(r["behaviour"] for r in main))
    L = ["# Shipped general models (issue #19 item 1)", "",
         "Written by `benchmarks/shipped_models.py` (models trained by `benchmarks/train_shipped.py`).", ""]
    L += ["## The models", ""]
    for m, d in meta["describe"].items():
        L.append(f"- {d}")
    L += ["", "| file | MB | load s |", "|---|---:|---:|"]
    for f, b in sorted(meta["sizes_bytes"].items()):
        meth = f.rsplit("-", 1)[0]
        L.append(f"| {f} | {b / 1e6:.2f} | {meta['load_seconds'].get(meth, float('nan')):.3f} |")
    tot = sum(meta["sizes_bytes"].values()) / 1e6
    L += ["", f"Total {tot:.2f} MB. Load time = `mocapkit.shipped.load(method, clip)` with a cold file "
          "cache of the module (read + cast to float64). General-model settings: "
          f"`{json.dumps(meta['general_params'])}`; same-behaviour: `{json.dumps(meta['same_params'])}`.", ""]
    L += ["## Protocol", "",
          f"Held-out subjects (in no shipped model): CMU {', '.join(meta['held_out']['cmu'])}; HDM05 actor "
          f"{', '.join(meta['held_out']['hdm05'])}. Test clips and same-behaviour training clips:", ""]
    for c in meta["cases"]:
        L.append(f"- **{c['behaviour']}**: test {', '.join(c['test'])}; same-behaviour model trained on "
                 f"{len(c['train'])} clips ({', '.join(c['train'][:8])}{', ...' if len(c['train']) > 8 else ''})")
    L += ["", f"RMSE in cm per coordinate over all entries against the clean clip, mean over test clips and "
          f"{meta['seeds']} noise seed(s). CMU test clips: first 10 s. 30 fps = every 4th frame of the 120 fps "
          "files (phase 0). `gen` = shipped general model, `same` = same-behaviour model; **bold** = best "
          "of the row. Reduced protocol, see the script docstring.", ""]
    cols = [(m, k) for m in METHODS for k in ("general", "same")] + [("gaussian", "-"), ("kalman-cv", "-"), ("input", "-")]
    head = ["xiao gen", "xiao same", "psc gen", "psc same", "lou-chai gen", "lou-chai same", "gaussian",
            "kalman-cv", "input"]
    for fps in RATES:
        for cond, (label, _) in CONDITIONS.items():
            L += [f"### {fps} fps, {label}", "", "| behaviour | " + " | ".join(head) + " |",
                  "|---|" + "---:|" * len(head)]
            for b in behs:
                vals = [_mean(main, behaviour=b, fps=fps, condition=cond, method=m, model=k) for m, k in cols]
                best = np.nanmin(vals[:-1])
                cells = [(f"**{v:.2f}**" if v == best else f"{v:.2f}") for v in vals]
                L.append(f"| {b} | " + " | ".join(cells) + " |")
            L.append("")
    # summary: general / same ratio
    L += ["## When does `train` on the user's own clips pay?", "",
          "Ratio same-behaviour RMSE / general RMSE (below 1: training on the behaviour is better), "
          "median over behaviours, and the behaviours where training gains more than 10 %:", "",
          "| method | fps | condition | median ratio | train gains > 10 % on |", "|---|---:|---|---:|---|"]
    allrat: dict[str, list] = {}
    for m in METHODS:
        for fps in RATES:
            for cond, (label, _) in CONDITIONS.items():
                rat, win = [], []
                for b in behs:
                    g = _mean(main, behaviour=b, fps=fps, condition=cond, method=m, model="general")
                    s = _mean(main, behaviour=b, fps=fps, condition=cond, method=m, model="same")
                    if np.isfinite(g) and np.isfinite(s) and g > 0:
                        rat.append(s / g)
                        if s / g < 0.9:
                            win.append(f"{b} ({s / g:.2f})")
                L.append(f"| {m} | {fps} | {label} | {np.median(rat):.2f} | {', '.join(win) or '-'} |")
                allrat.setdefault(m, []).extend(rat)
    L.append("")
    for m, rat in allrat.items():
        rat = np.asarray(rat)
        L.append(f"- {m}: the same-behaviour model is more than 10 % better than the general one in "
                 f"{int((rat < 0.9).sum())} of {rat.size} (behaviour, rate, condition) cells, within 10 % in "
                 f"{int(((rat >= 0.9) & (rat <= 1.1)).sum())}, more than 10 % worse in {int((rat > 1.1).sum())} "
                 f"(median ratio {np.median(rat):.2f}).")
    L += ["", "Caveats: the same-behaviour xiao-sparse / psc models are trained with reduced settings (script "
          "docstring) and on 1-33 clips, the general ones on 135 clips; psc keeps every observation "
          "its trust-data test accepts (6 cm), so under Gaussian noise it returns nearly the input whatever "
          "its training -- it is a gap / spike method. For CMU the same-behaviour clips are mostly the test "
          "subject's own other clips (dance, martial arts, kicks, balance), i.e. what a user who runs "
          "`mocapkit train` on their own takes gets.", ""]
    # best general model vs classical
    L += ["## General models against the classical filters", "",
          "Mean over behaviours of the RMSE (cm):", "",
          "| fps | condition | xiao gen | psc gen | lou-chai gen | best same | gaussian | kalman-cv | input |",
          "|---:|---|---:|---:|---:|---:|---:|---:|---:|"]
    for fps in RATES:
        for cond, (label, _) in CONDITIONS.items():
            def mb(**s):
                return np.nanmean([_mean(main, behaviour=b, fps=fps, condition=cond, **s) for b in behs])
            best_same = np.nanmean([min(_mean(main, behaviour=b, fps=fps, condition=cond, method=m, model="same")
                                        for m in METHODS) for b in behs])
            L.append(f"| {fps} | {label} | {mb(method='xiao-sparse', model='general'):.2f} | "
                     f"{mb(method='psc', model='general'):.2f} | {mb(method='lou-chai', model='general'):.2f} | "
                     f"{best_same:.2f} | {mb(method='gaussian'):.2f} | {mb(method='kalman-cv'):.2f} | "
                     f"{mb(method='input'):.2f} |")
    L.append("")
    # float16 cost
    f64 = [r for r in main if r["model"] == "general-f64"]
    if f64:
        L += ["## Cost of float16 storage", "",
              "Mean RMSE (cm) over the Gaussian 3 cm test cells of the shipped float16 model and of its float64 original:", "",
              "| method | float16 | float64 | largest difference |", "|---|---:|---:|---:|"]
        for m in METHODS:
            pairs = defaultdict(dict)
            for r in main:
                if r["method"] == m and r["model"] in ("general", "general-f64"):
                    pairs[(r["behaviour"], r["clip"], r["fps"], r["condition"], r["seed"])][r["model"]] = r["rmse"]
            pr = [(p["general"], p["general-f64"]) for p in pairs.values() if len(p) == 2]
            if pr:
                a16, a64 = np.array(pr).T
                L.append(f"| {m} | {a16.mean():.4f} | {a64.mean():.4f} | {np.abs(a16 - a64).max():.4f} |")
        L.append("")
    # rate study
    rs = [r for r in rows if r["model"].startswith("rate-study")]
    if rs:
        L += ["## Frame rate: one model per rate, or one model and phases / resampling?", "",
              "The 30 fps and the 120 fps shipped models run on the same clips at 30, 60 and 120 fps "
              "(`RateAdapter`: k interleaved phases when the clip rate is k x the model rate, else cubic "
              "resampling to the model rate and back). RMSE cm, mean over the clips "
              f"({', '.join(dict.fromkeys(r['clip'] for r in rs))}), one seed:", "",
              "| method | clip fps | condition | 30 fps model | 120 fps model | input |", "|---|---:|---|---:|---:|---:|"]
        for m in ("xiao-sparse", "psc"):
            for fps in (30, 60, 120):
                for cond in ("gauss3", "spikes"):
                    a30 = _mean(rs, method=m, fps=fps, condition=cond, model="rate-study 30fps-model")
                    a120 = _mean(rs, method=m, fps=fps, condition=cond, model="rate-study 120fps-model")
                    inp = _mean(rs, method="input", fps=fps, condition=cond)
                    L.append(f"| {m} | {fps} | {CONDITIONS[cond][0]} | {a30:.2f} | {a120:.2f} | {inp:.2f} |")
        L.append("")
    cached = sum(1 for v in meta["train_seconds_same"].values() if v == 0.0)
    L += [f"Benchmark run time {meta['total_seconds']:.0f} s (one core of a shared 2-core machine"
          + (f"; {cached} of {len(meta['train_seconds_same'])} same-behaviour models came from the "
             "--cache of an earlier run" if cached else "") + ").", ""]
    return "\n".join(L)


if __name__ == "__main__":
    raise SystemExit(main())
