"""``auto``: does ``--method auto`` clean clips without tuning as well as the best that could
be chosen with the truth in hand (issue #19, item 4)?

Protocol
--------
*Clips*: one per behaviour of ../shared/data -- CMU (original ASF/AMC) walk 16_15, run
09_06, jump 131_03, dance 05_02, martial arts 135_02, soccer kick 11_01, balance 49_18,
duck under 131_05, and HDM05 kickLFront1Reps and hopBothLegs1hops (first file of each folder).
Each is cropped to 1 s .. 1 s + ``max_seconds`` (8 s; the first second of several CMU
files holds a T-pose or a one-frame jump; clips under 3 s start at frame 2) and
resampled to 30 and to 120 fps.

*Conditions* (:func:`mocapkit.corrupt.combine`, seed = ``ctx.seed`` + clip index):
``clean``; ``gauss1`` / ``gauss3`` (Gaussian 1 / 3 cm per coordinate); ``spikes`` (10 %
of joint samples moved 15 cm in a random direction); ``mixed`` (2 cm + 10 % x 15 cm);
``missing30`` (30 % of the joints removed in every frame); ``gaps10x60`` (ten gaps of
60 frames, each on one random joint; skipped on clips under 120 frames).

*Methods*, same run: ``auto`` (default settings); ``kalman-cv-gate5`` (the default of
0.1); ``oracle-classical`` -- gaps filled by a cubic spline, then a running median of
1/3/5/7 frames followed by a Gaussian of sigma 0.5-8 frames or none, the best of the
grid *chosen on the truth* (the best any classical filter can do); and the candidates
``gcv-spline``, ``gcv-spline`` robust, ``mssa``, ``gaussian``, ``kalman-cv``,
``fill-auto`` (not on ``missing30``: its per-gap validation takes ~60 s per 600 frames
there), ``trnn`` at their defaults (``svt`` was never the best in a first run and is
left out to keep the run short). ``best`` = the lowest-RMSE candidate per case.
The protocol runs with every gap filled (FILL_ALL) so every method is scored on every
sample; a method that still leaves samples missing (``fill-auto`` leaves a gap no fill
validated under 5 cm) gets a NaN RMSE there and is not a ``best`` candidate in that case;
auto, which since 2026-12-05 leaves such gaps missing too, is scored on the samples it
wrote (its estimate covers the same samples) and those cases are kept out of the ratios
and counted apart (``cases_left_missing``).
A method that raises is a ``failed`` row (and counted in the summary).

*Scores*: RMSE (cm, all coordinates) per case; auto's estimated RMSE
(``source['auto']['estimated_rmse_cm']``) beside it, and the share of auto's squared
error on the glitches of the ground truth (:func:`truth_glitches`), and on ``missing30``
auto's, the oracle's and the best candidate's RMSE with those samples left out of the
score (the oracle re-chosen and the best candidate taken on the rest); seconds. Summary
rows (``clip = 'summary'``), per frame rate and condition: median and worst over clips of auto /
oracle-classical and auto / best; on ``clean`` the error auto adds; over the corrupted
conditions the share of cases whose estimate is within a factor 1.5 of the truth; auto's
time over the time of the last method it ran (see :func:`_picked`) and over the summed
times of the candidate methods its chain is made of (:func:`_chain_methods`; a case whose
chain has a method the run skipped -- fill-auto on ``missing30`` -- is left out).

``ctx.quick``: two clips, 30 fps, three conditions, 4 s crops.
"""
from __future__ import annotations

import time
import warnings
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ... import corrupt, gaps, io, metrics, signal
from ...errors import MocapValueError
from ...motion import Motion
from ..core import Context, Row, protocol

NAME = "auto"
CLIPS = (("walk", "cmu/asfamc/16/16_15.amc"), ("run", "cmu/asfamc/09/09_06.amc"),
         ("jump", "cmu/asfamc/131/131_03.amc"), ("dance", "cmu/asfamc/05/05_02.amc"),
         ("martial-arts", "cmu/asfamc/135/135_02.amc"), ("kick", "cmu/asfamc/11/11_01.amc"),
         ("balance", "cmu/asfamc/49/49_18.amc"), ("duck", "cmu/asfamc/131/131_05.amc"),
         ("hdm05-kick", "hdm05/asfamc/kickLFront1Reps"), ("hdm05-hop", "hdm05/asfamc/hopBothLegs1hops"))
#: a second set of CMU clips (``--clip-set heldout`` of benchmarks/run_auto.py), none of
#: them in :data:`CLIPS` (walk 01_01, dance 05_03 / 05_07, 07_03, 131_08 / 131_12, martial
#: arts 135_04 / 135_09, 35_01, balance 49_19): whether what auto gains on :data:`CLIPS`
#: holds elsewhere. Used since 2026-12-04 to check each change of auto; choices made on
#: both sets are no longer blind to either (the issue's own check uses clips neither has)
HELDOUT_CLIPS = (("01_01", "cmu/asfamc/01/01_01.amc"), ("05_03", "cmu/asfamc/05/05_03.amc"),
                 ("07_03", "cmu/asfamc/07/07_03.amc"), ("131_08", "cmu/asfamc/131/131_08.amc"),
                 ("135_04", "cmu/asfamc/135/135_04.amc"), ("35_01", "cmu/asfamc/35/35_01.amc"),
                 ("49_19", "cmu/asfamc/49/49_19.amc"), ("135_09", "cmu/asfamc/135/135_09.amc"),
                 ("05_07", "cmu/asfamc/05/05_07.amc"), ("131_12", "cmu/asfamc/131/131_12.amc"))
#: a third set (``--clip-set unseen``), added 2026-12-06 (twenty-fifth session) and used
#: for no choice of auto before its first run: the CMU AMC trials in neither set above nor
#: in benchmarks/auto_lowrank.py (walks 131_02 / 131_11, jumps 131_07, martial arts 135_05 /
#: 135_08) and four HDM05 classes the protocol does not use, each by another actor than its
#: HDM05 clips' -- the issue's own check, on clips no choice was made on
UNSEEN_CLIPS = (("131_02", "cmu/asfamc/131/131_02.amc"), ("131_07", "cmu/asfamc/131/131_07.amc"),
                ("131_11", "cmu/asfamc/131/131_11.amc"), ("135_05", "cmu/asfamc/135/135_05.amc"),
                ("135_08", "cmu/asfamc/135/135_08.amc"),
                ("hdm05-jog", "hdm05/asfamc/jogLeftCircle4StepsRstart/HDM_tr_jogLeftCircle4StepsRstart_014_120.amc"),
                ("hdm05-sneak", "hdm05/asfamc/sneak2StepsLStart/HDM_dg_sneak2StepsLStart_007_120.amc"),
                ("hdm05-arms",
                 "hdm05/asfamc/rotateArmsBothBackward1Reps/HDM_mm_rotateArmsBothBackward1Reps_011_120.amc"),
                ("hdm05-elbow-knee",
                 "hdm05/asfamc/elbowToKnee1RepsLelbowStart/HDM_bk_elbowToKnee1RepsLelbowStart_007_120.amc"))
CLIP_SETS = {"protocol": CLIPS, "heldout": HELDOUT_CLIPS, "unseen": UNSEEN_CLIPS}
SPIKES = ("outliers", {"ratio": 0.1, "magnitude_cm": 15.0})
CONDITIONS = {
    "clean": [],
    "gauss1": [("gaussian", {"sigma_cm": 1.0})],
    "gauss3": [("gaussian", {"sigma_cm": 3.0})],
    "spikes": [SPIKES],
    "mixed": [("gaussian", {"sigma_cm": 2.0}), SPIKES],
    "missing30": [("missing", {"ratio": 0.3})],
    "gaps10x60": [("block_gaps", {"n_markers": 1, "length": 60, "n_blocks": 10})],
}
CANDIDATES = (("gcv-spline", {}), ("gcv-spline-robust", {"robust": True}), ("mssa", {}), ("gaussian", {}),
              ("kalman-cv", {}), ("fill-auto", {}), ("trnn", {}))


def _path(data: Path, rel: str) -> Path | None:
    p = data / rel
    if p.is_dir():
        files = sorted(p.glob("*.amc"))
        return files[0] if files else None
    return p if p.is_file() else None


def load_clips(data: Path, quick: bool, max_seconds: float, clips=CLIPS) -> Iterator[tuple[str, Motion]]:
    """(label, clip at 120 fps, cropped) for every clip of ``clips`` whose file exists."""
    chosen = clips[:2] if quick else clips
    for label, rel in chosen:
        p = _path(data, rel)
        if p is None:
            continue
        m = io.read(p)
        m = m if m.fps == 120 else m.resample(120.0)
        start = int(m.fps) if m.n_frames >= 3 * m.fps else 2
        yield label, m.slice(start, min(m.n_frames, start + int(max_seconds * m.fps)))


def oracle_classical(truth: Motion, noisy: Motion, mask: np.ndarray | None = None) -> float:
    """Lowest RMSE of spline fill + median(1/3/5/7) + Gaussian(0.5-8 frames or none), scored
    on the (T, J) ``mask`` (default all samples)."""
    X = gaps.fill(noisy.matrix(), noisy.matrix_mask(), kind="cubic")
    best = np.inf
    for k in (1, 3, 5, 7):
        Xm = signal.median(X, window=k) if k > 1 else X
        best = min(best, metrics.rmse(truth, noisy.with_matrix(Xm), mask=mask))
        for sg in (0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0):
            best = min(best, metrics.rmse(truth, noisy.with_matrix(signal.gaussian(Xm, sigma=sg)), mask=mask))
    return float(best)


#: the issue's test of auto's estimated error: within this factor of the true error
ESTIMATE_FACTOR = 1.5


def estimate_within(estimate: float | None, true: float) -> bool:
    """Whether ``estimate`` is within :data:`ESTIMATE_FACTOR` of the ``true`` error (cm);
    False with no estimate or no error to compare with -- the one test every auto
    benchmark counts.

    >>> estimate_within(0.6, 0.5), estimate_within(0.3, 0.5), estimate_within(None, 0.5)
    (True, False, False)
    """
    return bool(estimate) and true > 0 and 1 / ESTIMATE_FACTOR <= estimate / true <= ESTIMATE_FACTOR


#: a truth sample whose position is further than this (cm, by frame rate) from the cubic
#: through its two neighbours on each side is a *glitch* of the ground truth (CMU thumb,
#: hand and toe joints that step 3-10 cm in one frame and back or on): at 120 fps smooth
#: human motion stays under 1 cm there (0.6 % of the samples are over 1 cm, 0.14 % over
#: 2 cm, 0.07 % over 3 cm on the protocol's clips); at 30 fps fast limbs reach 3-5 cm
GLITCH_CM = {30: 5.0, 120: 2.0}


def truth_glitches(truth: Motion) -> np.ndarray:
    """(T, J) True on the glitch samples of ``truth`` (:data:`GLITCH_CM`, the nearest frame
    rate's threshold) and their neighbours in time: a step or a one-frame jump of the ground
    truth, which no fill can know and which then rules a case's error."""
    from ...gaps import neighbour_deviation

    d = neighbour_deviation(truth.positions, np.ones(truth.positions.shape[:2], bool))
    thr = GLITCH_CM[min(GLITCH_CM, key=lambda f: abs(f - truth.fps))]
    g = np.nan_to_num(d) > thr
    out = g.copy()
    out[1:] |= g[:-1]
    out[:-1] |= g[1:]
    return out


def glitch_share(truth: Motion, out: Motion) -> float:
    """The share of ``out``'s squared error (over the samples it wrote) on the glitch
    samples of ``truth`` (:func:`truth_glitches`)."""
    e2 = np.sum((out.positions - truth.positions) ** 2, axis=2)
    fin = np.isfinite(e2)
    tot = float(e2[fin].sum())
    return float(e2[fin & truth_glitches(truth)].sum()) / tot if tot > 0 else 0.0


def _method(name: str, params: dict):
    from ...denoise import get

    base = "gcv-spline" if name.startswith("gcv-spline") else name
    if name == "kalman-cv-gate5":
        return get("kalman-cv", gate=5.0)
    return get(base, **params)


def _run(truth: Motion, noisy: Motion, name: str, params: dict, partial: bool = False
         ) -> tuple[float, float, Motion | str]:
    """(RMSE, seconds, output) -- or (NaN, seconds, the error's text) when the method fails.
    An output that leaves samples missing scores NaN, or with ``partial`` its RMSE over the
    samples it wrote (auto, which leaves a long gap no fill validated under 5 cm)."""
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = _method(name, params).denoise(noisy)
    except Exception as e:                   # recorded as a 'failed' row; the run goes on
        return float("nan"), time.perf_counter() - t0, f"{type(e).__name__}: {e}"
    dt = time.perf_counter() - t0
    if not out.observed.all():
        return (metrics.rmse(truth, out, mask=out.observed) if partial else float("nan")), dt, out
    return metrics.rmse(truth, out), dt, out


def _case(ctx_seed: int, label: str, fps: int, truth: Motion, cond: str, steps: list) -> Iterator[Row]:
    noisy, _ = corrupt.combine(truth, steps, seed=ctx_seed) if steps else (truth, None)
    clip = f"{label}@{fps}"
    res = {}
    clear = None                    # missing30: the samples off the truth's glitches
    for name, params in (("auto", {}), ("kalman-cv-gate5", {})) + CANDIDATES:
        if name == "fill-auto" and cond == "missing30":
            continue                 # thousands of 1-3 frame gaps: ~60 s per 600 frames
        e, dt, out = _run(truth, noisy, name, params, partial=(name == "auto"))
        res[name] = (e, dt, out)
        if isinstance(out, str):
            yield Row(NAME, clip, cond, name, "failed", "", float("nan"), seconds=dt, extra={"error": out})
            continue
        extra: dict[str, Any] = {}
        if name == "auto":
            a = out.source.get("auto", {})
            extra = {"estimate": a.get("estimated_rmse_cm"), "chain": a.get("chain"),
                     "left": int((~out.observed).sum()), "glitch_share": glitch_share(truth, out)}
            if cond == "missing30":         # scored without the truth's glitches (module doc)
                clear = out.observed & ~truth_glitches(truth)
                extra["rmse_no_glitch"] = metrics.rmse(truth, out, mask=clear)
                extra["oracle_no_glitch"] = oracle_classical(truth, noisy, mask=clear)
        yield Row(NAME, clip, cond, name, "rmse", "cm", e, seconds=dt, extra=extra)
    t0 = time.perf_counter()
    yield Row(NAME, clip, cond, "oracle-classical", "rmse", "cm", oracle_classical(truth, noisy),
              seconds=time.perf_counter() - t0)
    cands = {n: res[n][0] for n, _ in CANDIDATES if n in res and np.isfinite(res[n][0])}
    if cands:
        b = min(cands, key=cands.get)
        extra = {"method": b}
        if clear is not None:               # the best candidate on the same samples
            extra["no_glitch"] = min(metrics.rmse(truth, res[n][2], mask=clear) for n in cands)
        yield Row(NAME, clip, cond, "best", "rmse", "cm", cands[b], extra=extra)


@protocol(NAME, "auto vs the old default, the oracle-tuned classical filter and the best "
                "candidate per case: 10 behaviours x 30/120 fps x 7 conditions")
def auto_protocol(ctx: Context) -> Iterator[Row]:
    data = ctx.need_data()
    quick = ctx.quick
    max_s = float(ctx.options.get("max_seconds", 4.0 if quick else 8.0))
    conds = {k: CONDITIONS[k] for k in (("clean", "gauss3", "spikes") if quick else CONDITIONS)}
    rows: list[Row] = []
    log = ctx.options.get("log")
    name = ctx.options.get("clip_set", "protocol")
    if name not in CLIP_SETS:
        raise MocapValueError(f"clip_set must be one of {', '.join(CLIP_SETS)}, got {name!r}")
    for i, (label, clip) in enumerate(load_clips(data, quick, max_s, CLIP_SETS[name])):
        for fps in ((30,) if quick else (30, 120)):
            truth = clip if fps == 120 else clip.resample(float(fps))
            for cond, steps in conds.items():
                if cond == "gaps10x60" and truth.n_frames < 120:
                    continue                        # a 60-frame gap needs a longer clip
                case = list(_case(ctx.seed + i, label, fps, truth, cond, steps))
                rows.extend(case)
                yield from case
                if log:
                    log(f"{label}@{fps} {cond}: " + ", ".join(
                        f"{r.method}={r.value:.3f}" for r in case if r.method in ("auto", "oracle-classical", "best"))
                        + f" est={case[0].extra.get('estimate')} {case[0].extra.get('chain')} best={case[-1].extra.get('method')}")
    yield from summarise(rows)


def _picked(case: dict[str, Row]) -> str:
    """The candidate auto's chain ran (for the time ratio): the last of its steps that is
    a method of the run (fill-auto, mssa, kalman-cv, gcv-spline robust or plain)."""
    chain = case["auto"].extra.get("chain") or []
    if "fill-auto" in chain:
        return "fill-auto"
    if any("mssa" in c for c in chain):
        return "mssa"
    if any("kalman" in c for c in chain):
        return "kalman-cv"
    return "gcv-spline-robust" if "gcv-spline-robust" in _chain_methods(case) else "gcv-spline"


#: a step of auto's chain (its report's words) -> the candidate method that does that
#: work on its own (:func:`_chain_methods`); the holds (bones, rigid groups) are auto's own
CHAIN_METHODS = (("spike removal", "gcv-spline-robust"), ("spike test", "gcv-spline-robust"),
                 ("spline fill", "gcv-spline"),
                 ("low-rank fill", "mssa"), ("mssa", "mssa"), ("gcv-spline", "gcv-spline"),
                 ("kalman-cv", "kalman-cv"), ("fill-auto", "fill-auto"))


def _chain_methods(case: dict[str, Row]) -> list[str]:
    """The candidate methods whose work auto's chain is made of: the robust spline for
    spike removal, each smoother of the SURE mix (``mssa 0.70 + gcv-spline 0.28 +
    kalman-cv 0.01``), the spline for short fills, MSSA for the low-rank fill (iterated
    MSSA), fill-auto -- what a user would run by hand to get what auto picked; the second
    time ratio of the summary (``time_ratio_chain_median``) is auto's time over their
    summed times. Each method counts once."""
    names: list[str] = []
    for step in case["auto"].extra.get("chain") or []:
        for words, method in CHAIN_METHODS:
            # a method's name as a word of the step ('gcv-spline 0.28', not 'spline fill')
            if (words in step if " " in words else words in step.split()) and method not in names:
                names.append(method)
    return names


def summarise(rows: list[Row]) -> Iterator[Row]:
    """The summary rows of the module docstring, from the case rows."""
    by: dict[tuple, dict[str, Row]] = {}
    failed = [r for r in rows if r.metric == "failed"]
    if failed:
        yield Row(NAME, "summary", "all", "any", "failed_runs", "n", float(len(failed)),
                  extra={"runs": [f"{r.method} on {r.clip} {r.condition}: {r.extra['error']}" for r in failed]})
    for r in rows:
        if r.metric == "rmse":
            by.setdefault((r.clip, r.condition), {})[r.method] = r
    groups: dict[tuple, list[dict[str, Row]]] = {}
    for (clip, cond), d in by.items():
        groups.setdefault((clip.split("@")[1], cond), []).append(d)
    est_ok = []
    for (fps, cond), cases in sorted(groups.items()):
        # a case where auto left samples missing scores only what it wrote: not comparable
        # with the full outputs of the others, so outside the ratios and counted apart
        full = [d for d in cases if not d["auto"].extra.get("left")]
        ro = [d["auto"].value / d["oracle-classical"].value for d in full
              if d["oracle-classical"].value > 0 and np.isfinite(d["auto"].value)]
        rb = [d["auto"].value / d["best"].value for d in full if "best" in d and d["best"].value > 0]
        cond_fps = f"{cond}@{fps}"
        if len(full) < len(cases):
            yield Row(NAME, "summary", cond_fps, "auto", "cases_left_missing", "n", float(len(cases) - len(full)),
                      n=len(cases), extra={"samples": int(sum(d["auto"].extra.get("left", 0) for d in cases)),
                                           "cases": [d["auto"].clip for d in cases if d["auto"].extra.get("left")]})
        if ro:
            yield Row(NAME, "summary", cond_fps, "auto", "ratio_oracle_median", "x", float(np.median(ro)), n=len(ro))
            yield Row(NAME, "summary", cond_fps, "auto", "ratio_oracle_worst", "x", float(np.max(ro)), n=len(ro))
        rg = [d["auto"].extra["rmse_no_glitch"] / d["auto"].extra["oracle_no_glitch"] for d in full
              if d["auto"].extra.get("oracle_no_glitch")]
        if rg:
            yield Row(NAME, "summary", cond_fps, "auto", "ratio_oracle_worst_no_glitch", "x", float(np.max(rg)),
                      n=len(rg))
        if rb:
            yield Row(NAME, "summary", cond_fps, "auto", "ratio_best_median", "x", float(np.median(rb)), n=len(rb))
            yield Row(NAME, "summary", cond_fps, "auto", "ratio_best_worst", "x", float(np.max(rb)), n=len(rb))
        rbg = [d["auto"].extra["rmse_no_glitch"] / d["best"].extra["no_glitch"] for d in full
               if "best" in d and d["auto"].extra.get("rmse_no_glitch") and d["best"].extra.get("no_glitch")]
        if rbg:
            yield Row(NAME, "summary", cond_fps, "auto", "ratio_best_worst_no_glitch", "x", float(np.max(rbg)),
                      n=len(rbg))
        if cond == "clean":
            yield Row(NAME, "summary", cond_fps, "auto", "added_worst", "cm",
                      float(np.nanmax([d["auto"].value for d in cases])), n=len(cases))
        else:
            for d in cases:
                est = d["auto"].extra.get("estimate")
                if est and d["auto"].value > 0:
                    est_ok.append(estimate_within(est, d["auto"].value))
        t = [d["auto"].seconds / d[_picked(d)].seconds for d in cases
             if d["auto"].seconds and d.get(_picked(d)) and d[_picked(d)].seconds]
        if t:
            yield Row(NAME, "summary", cond_fps, "auto", "time_ratio_picked_median", "x", float(np.median(t)), n=len(t))
        tc = [d["auto"].seconds / sum(d[m].seconds for m in _chain_methods(d)) for d in cases
              if d["auto"].seconds and _chain_methods(d)
              and all(d.get(m) is not None and d[m].seconds for m in _chain_methods(d))]
        if tc:
            yield Row(NAME, "summary", cond_fps, "auto", "time_ratio_chain_median", "x", float(np.median(tc)),
                      n=len(tc))
    if est_ok:
        yield Row(NAME, "summary", "corrupted", "auto", "estimate_within_1.5x", "%",
                  100.0 * float(np.mean(est_ok)), n=len(est_ok))
