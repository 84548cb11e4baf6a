"""Run the action-recognition protocols and write docs/results/recognition.md.

Usage: ``python benchmarks/run_recognition.py [--run] [--quick] [--data DIR]``

With ``--run`` the protocols ``recognition-msr-half``, ``recognition-msr-cross-subject`` and
``recognition-hdm05-cross-actor`` (``mocapkit/bench/protocols/retrieval.py``) run through
:func:`mocapkit.bench.run` with one BLAS thread (about 5 min on 2 cores) and their rows are
saved as ``docs/results/recognition_{msr_half,msr_cross_subject,hdm05}.json``, the confusion
matrices of MiniRocket as ``docs/results/recognition_confusion_*.png``; without it the
Markdown is rendered from those JSON files. Every number in the Markdown comes from the
JSON; only the explanatory text is fixed here.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mocapkit import bench  # noqa: E402
from mocapkit.bench.protocols.retrieval import MSR_ACTIONS, RECOG_PNG  # noqa: E402
from mocapkit.datasets import shared_data_dir  # noqa: E402

RES = ROOT / "docs" / "results"
FILES = {"recognition-msr-half": "recognition_msr_half.json",
         "recognition-msr-cross-subject": "recognition_msr_cross_subject.json",
         "recognition-hdm05-cross-actor": "recognition_hdm05.json"}
LABEL = {"minirocket": "**MiniRocket** + ridge (default of `mocapkit classify train`)",
         "minirocket-heading-start": "MiniRocket, heading from the Kinect hips (ablation)",
         "classifier": "skeleton classifier (HOD + pose statistics + logistic regression)",
         "nmc": "NMC (thesis method; our windows M = 10, stride 5; transductive)",
         "nmc-thesis-window": "NMC with the thesis' stated windows (M = 60, stride 30)"}
TARGETS = {("recognition-msr-half", "minirocket"): 0.9333, ("recognition-msr-cross-subject", "minirocket"): 0.90,
           ("recognition-hdm05-cross-actor", "minirocket"): 0.95, ("recognition-msr-half", "nmc"): 0.9333}

SETTING = """\
* **Data** (`../shared/data`): MSR-Action3D skeletons (Kinect, 20 joints, 15 fps), the 557
  sequences of `files_used_in_cvpr12_paper.txt` (the list the data set's authors used; the
  older protocols in `retrieval.md` use all 566 readable files), 20 actions by 10 subjects;
  HDM05 ASF/AMC (31 joints, 120 fps), the 140 cut clips of 6 classes by 5 actors (the uncut take
  in `takes/` is left out: it is no class).
* **MiniRocket** (`mocapkit/recognition/rocket.py`; Dempster, Schmidt & Webb, KDD 2021, written
  in numpy because `aeon` 1.5/1.6 needs `numba < 0.64`, i.e. `numpy < 2.4`, and would downgrade the
  pinned numpy and scikit-learn): every joint of the skeleton, gaps bridged, up axis found, joints
  relative to the hip centre (the root keeps its own path from its first position), divided by
  the body size (median head-root distance + mean leg length), resampled to 64 samples; channels
  = the 3J joint coordinates. 84 fixed kernels x dilations, ~10,000 PPV features on the series and
  ~10,000 on its first difference (MultiRocket's second representation), standardised,
  `RidgeClassifierCV` (alphas 1e-3..1e3, leave-one-out). Heading: Kinect files keep the camera's
  horizontal axes (`heading='auto'`; the ablation row shows the hip-based heading), other files are
  turned to face +z from the hips over the first 0.5 s. Seeded; one BLAS thread.
* **Skeleton classifier** and **NMC**: as in `retrieval.md` (NMC: graph-regularised orthogonal NMF
  bag of words; transductive, i.e. the test clips join the clustering, as the thesis does).
* **Protocols**: MSR-Action3D half/half = a random half of each class for training, the rest for
  testing, 5 splits (seeds 0-4); cross-subject = subjects 1,3,5,7,9 train, 2,4,6,8,10 test (one
  split; MiniRocket and NMC over 3 seeds, the skeleton classifier is deterministic); HDM05 leave one
  actor out (5 folds) and 2 actors train / 3 test (all 10 pairs, the thesis' retrieval setting).
* **Time**: training seconds per training clip = fit time / n_train + feature time per clip;
  inference ms per test clip = (prediction time / n_test + feature time per clip), from a loaded
  Motion (file reading excluded); for the transductive NMC the clustering is in the training time.
"""


def load(name: str) -> list[bench.Row]:
    p = RES / FILES[name]
    return [bench.Row(**d) for d in json.loads(p.read_text())] if p.is_file() else []


def pct(r: bench.Row | None) -> str:
    if r is None:
        return ""
    s = f"{100 * r.value:.1f}"
    return s + (f" ± {100 * r.std:.1f}" if r.std is not None else "")


def cname(c: str) -> str:
    return f"{MSR_ACTIONS[int(c[1:]) - 1]} ({c})" if len(c) == 3 and c[0] == "a" and c[1:].isdigit() else c


def summary(rows: dict[str, list[bench.Row]]) -> str:
    out = ["| protocol | condition | method | accuracy % | train s / clip | inference ms / clip |",
           "|---|---|---|---:|---:|---:|"]
    for name, rs in rows.items():
        by = {(r.condition, r.method, r.metric): r for r in rs}
        for cond in dict.fromkeys(r.condition for r in rs):
            for meth in dict.fromkeys(r.method for r in rs if r.condition == cond):
                a = by.get((cond, meth, "accuracy"))
                t = by.get((cond, meth, "train_s_per_clip"))
                i = by.get((cond, meth, "inference_ms_per_clip"))
                out.append(f"| {name.replace('recognition-', '')} | {cond} | {LABEL.get(meth, meth)} | {pct(a)} | "
                           f"{t.value:.3f} | {i.value:.1f} |" if t and i else
                           f"| {name} | {cond} | {meth} | {pct(a)} | | |")
    return "\n".join(out)


def verdicts(rows: dict[str, list[bench.Row]]) -> str:
    out = []
    for (name, meth), target in TARGETS.items():
        rs = [r for r in rows.get(name, []) if r.method == meth and r.metric == "accuracy"]
        if not rs:
            continue
        r = rs[0]                                   # first condition (HDM05: leave one actor out)
        ok = r.value >= target
        extra = ""
        if name == "recognition-hdm05-cross-actor" and len(rs) > 1:
            extra = f"; 2 actors train / 3 test: {pct(rs[1])} %"
        out.append(f"- {name.replace('recognition-', '')}, {meth}: {pct(r)} % vs target {100 * target:.2f} % — "
                   f"{'met' if ok else 'missed'} ({r.condition}{extra}); per split: "
                   f"{', '.join(f'{100 * v:.1f}' for v in r.extra.get('per_split', []))}.")
    return "\n".join(out)


def errors(rows: dict[str, list[bench.Row]]) -> str:
    out = []
    for name, rs in rows.items():
        for r in rs:
            if r.method != "minirocket" or r.metric != "accuracy":
                continue
            ex = r.extra
            n_err = sum(ex["errors_by_group"].values())
            tested = ex["tested_by_group"]
            conf = ", ".join(f"{cname(a)} → {cname(b)} ×{n}" for a, b, n in ex["top_confusions"][:6])
            order = sorted(tested, key=lambda g: (0, int(g), "") if g.isdigit() else (1, 0, g))
            grp = ", ".join(f"{g}: {ex['errors_by_group'].get(g, 0)}/{tested[g]}" for g in order)
            out.append(f"- **{name.replace('recognition-', '')}, {r.condition}**: {n_err} errors in "
                       f"{sum(tested.values())} test predictions (summed over splits/seeds). Most frequent: "
                       f"{conf or 'none'}. Errors per test {'subject' if 'msr' in name else 'actor'}: {grp}.")
    cs = [r for r in rows.get("recognition-msr-cross-subject", []) if r.method == "minirocket" and r.metric == "accuracy"]
    if cs:
        ex = cs[0].extra
        e, t = ex["errors_by_group"], ex["tested_by_group"]
        worst = max(t, key=lambda g: e.get(g, 0) / t[g])
        n_e, n_t = sum(e.values()), sum(t.values())
        rest = 1 - (n_e - e.get(worst, 0)) / (n_t - t[worst])
        out += ["", f"Cross-subject, one subject carries the gap: subject {worst} makes {e.get(worst, 0)} of the "
                f"{n_e} errors ({100 * e.get(worst, 0) / n_e:.0f} %; {100 * (1 - e.get(worst, 0) / t[worst]):.1f} % "
                f"correct on that subject); on the other four test subjects MiniRocket is {100 * rest:.1f} % correct. "
                "Subject 2's clips are consistently recognised as another action on all three repetitions "
                "(hammer, forward punch and high throw as tennis swing, hand catch as side-boxing, pick up & "
                "throw as bend). Inspecting the clips: in this subject's high throws and pick-up-and-throws the "
                "throwing hand never rises above the head, as it does for the training subjects, so the clips "
                "look like other classes of the training subjects. No input change we measured (heading, centring on the torso or the clip mean, bone "
                "directions, bone-length retargeting, per-channel scaling, smoothing, 32/96 samples, "
                "augmentation by rotation/scale/cropping, MultiRocket poolings, more features, 4-seed "
                "ensembles, HYDRA features and fusion with the skeleton classifier; exploratory runs, "
                "not part of this table) raised the cross-subject accuracy by more than the seed-to-seed "
                "spread (about ±1 point; several lowered it).",
                "",
                "Half/half: the errors sit in the drawing actions (draw x against draw circle and hammer), "
                "pick up & throw against bend, forward punch against high throw, hand catch against "
                "side-boxing; subject 2 again has the most errors per tested clip."]
    return "\n".join(out)


def nmc_note(rows: dict[str, list[bench.Row]]) -> str:
    by = {r.method: r for r in rows.get("recognition-msr-half", []) if r.metric == "accuracy"}
    a, b = by.get("nmc"), by.get("nmc-thesis-window")
    if a is None or b is None:
        return ""
    return (f"NMC, the thesis method, on its own protocol (557 clips): {pct(a)} % with our windows (M = 10, "
            f"stride 5 at 15 fps) and {pct(b)} % with the thesis' stated windows (M = 60, stride M/2 = 30), "
            f"against the thesis' {100 * a.paper_value:.2f} %. The stated windows are longer than most "
            "MSR-Action3D clips (13-100 frames at 15 fps, median 39), so a clip gives one or two windows "
            "and the bag of words degenerates; with the 16 settings of `benchmarks/nmc_sweep.py` "
            "(`retrieval.md`) none closes the gap either, so the target stays missed for the measured reason "
            "documented there: the thesis' number is not reproduced by its stated settings.")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", action="store_true", help="run the protocols (else render from JSON)")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--data")
    ap.add_argument("--only", choices=list(FILES), action="append", help="with --run: run only these protocols")
    ap.add_argument("--out", type=Path, default=RES / "recognition.md")
    a = ap.parse_args()
    times = {}
    if a.run:
        import tempfile

        from threadpoolctl import threadpool_limits

        dest = RES if not a.quick else Path(tempfile.mkdtemp(prefix="mocapkit-recognition-"))
        ctx = bench.Context(data_dir=shared_data_dir(a.data), quick=a.quick, progress=False,
                            options={} if not a.quick else {"figures_dir": str(dest)})
        with threadpool_limits(1):
            for name, fn in FILES.items():
                if a.only and name not in a.only:
                    continue
                t0 = time.perf_counter()
                rows = bench.run(name, ctx)
                times[name] = time.perf_counter() - t0
                bench.to_json(rows, dest / fn)
        if a.quick:
            print(f"quick run written under {dest}; docs not re-rendered")
            return
    rows = {n: load(n) for n in FILES}
    figs = " · ".join(f"[{n.replace('recognition-', '')}]({RECOG_PNG[n]})" for n in FILES)
    md = ["# Action recognition: MiniRocket (default), skeleton classifier, NMC — results", "",
          "Generated by `python benchmarks/run_recognition.py` from the JSON rows of the protocols "
          "`recognition-msr-half`, `recognition-msr-cross-subject` and `recognition-hdm05-cross-actor` in "
          "`mocapkit/bench/protocols/retrieval.py` (run them with `--run`, ~5 min on 2 cores).", "",
          "## Setting", "", SETTING, "## Accuracy and time", "", summary(rows), "",
          "Accuracy: mean ± std over splits (and seeds). Published skeleton-only results on the MSR-Action3D "
          "cross-subject split for scale: Lie group 89.5 %, HBRNN 94.5 %.", "",
          "## Targets", "", verdicts(rows), "",
          nmc_note(rows), "",
          "## Where the remaining errors are (MiniRocket)", "", errors(rows), "",
          f"Confusion matrices of MiniRocket (summed over splits/seeds): {figs}.", "",
          "## All rows", "", bench.to_markdown([r for rs in rows.values() for r in rs])]
    a.out.write_text("\n".join(md) + "\n")
    print(f"wrote {a.out}" + (f" (protocols: {', '.join(f'{k} {v:.0f} s' for k, v in times.items())})"
                              if times else ""))


if __name__ == "__main__":
    main()
