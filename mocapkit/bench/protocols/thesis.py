"""Protocols of the thesis' refinement chapters (seed 003, Ch. 3-4).

* ``thesis-missing-random`` -- Sec. 4.2.3 / Fig. 4.10-4.11: six CMU sequences, ``mr``
  = 0.2 ... 0.6 of the markers removed in every frame (:func:`mocapkit.corrupt.missing`),
  RMSE over the missing entries (cm, ``||(X - X~)|_Omega^c||_F / sqrt(|Omega^c|)``);
  methods psc, tsmc, trnn, svt, dynammo, spline (+ linear); 20 repeats.
* ``thesis-missing-blocks`` -- the same with ``ml`` = 20 ... 60 consecutive frames missing
  for 10 random markers (:func:`mocapkit.corrupt.block_gaps`).
* ``thesis-corrupt4`` -- Sec. 4.1.3 / Fig. 4.1-4.4: rdcrypt (Gaussian sigma = 2 cm on a
  random 30 % of the marker entries), rdloss (30 % of the markers of every frame
  missing), mxcrypt (30 % missing, then sigma = 2 cm on 30 % of the remaining entries),
  rgloss (blocks of 10 markers x 60 frames until about 30 % of the entries are gone);
  tsmc vs trnn; RMSE over the imperfect (missing + noisy) entries (eq. 4.16) and over all.
* ``thesis-runtime`` -- Table 4.1: TSMC and TrNN seconds against clip length (152 ...
  17,799 frames, 20 % random missing markers), one BLAS thread, best of 3 runs (1 for
  the longest), wall time as the value and the process CPU time in ``extra`` (on a shared
  machine wall time also counts other jobs); from 2,000 frames on also with the banded
  M-step (``mstep="banded"``); clips of the table's
  lengths are cut from the concatenation of CMU subject 135's eight ASF/AMC trials
  (19,875 frames of martial arts, one skeleton); the paper's Matlab seconds (i5 2.4 GHz)
  in ``paper_value``.

Clips: the thesis' six trials (footnote of Sec. 4.2.3) are not in ../shared/data except
as substitutes; each row names its substitute as ``"ours (for theirs)"``:

=========  ==========================================  ============================================
thesis     action                                      ours (CMU ASF/AMC, 120 fps)
=========  ==========================================  ============================================
05_13      dance: small jetes, pirouette               05_07 dance: small jetes, attitude, pirouette
12_02      walk                                        16_15 walk
49_02      jump up and down, hop on one foot           131_03 start, hop, stop
13_13      forward jump                                01_01 playground: forward jumps, turn around
10_01      soccer: kick ball                           11_01 soccer: kick ball (10_01 exists only as
                                                       a 43-joint Daz BVH)
13_17      boxing                                      135_09 martial arts: Oiduki (lunge punch)
=========  ==========================================  ============================================

PSC needs training data: for every test clip it is trained (leave-the-clip-out) on other
CMU trials of the same kind (``PSC_TRAIN``), all with the CMU 31-joint skeleton.

Options (``ctx.options``): ``frames`` (cap every clip to its first N frames), ``repeats``,
``clips`` (list of our clip ids), ``psc`` (dict of PSC parameters).  ``ctx.quick``: one
clip (16_15, 240 frames), two conditions, 2 repeats, a small PSC: well under a minute.
"""
from __future__ import annotations

import time
import warnings
from typing import Any, Iterator

import numpy as np

from ...datasets import bundled, cmu_amc
from ...errors import MocapError
from ..core import Context, Row, Timer, protocol

CLIPS = (
    ("05_07", "05_13"),
    ("16_15", "12_02"),
    ("131_03", "49_02"),
    ("01_01", "13_13"),
    ("11_01", "10_01"),
    ("135_09", "13_17"),
)
PSC_TRAIN = {
    "05_07": ("05_02", "05_03", "05_05"),
    "16_15": ("07_03", "07_05", "35_01", "05_01"),
    "131_03": ("131_04", "131_07", "131_08"),
    "01_01": ("131_03", "131_04", "131_07", "131_08"),
    "11_01": ("135_04", "135_11", "135_08"),
    "135_09": ("135_02", "135_03", "135_05"),
}
METHODS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("psc", "psc", {}),
    ("tsmc", "tsmc", {}),
    ("trnn", "trnn", {}),
    ("svt", "svt", {}),
    ("dynammo", "dynammo", {}),
    ("spline", "spline", {}),
    ("linear", "linear", {}),
)
RATIOS = (0.2, 0.3, 0.4, 0.5, 0.6)
LENGTHS = (20, 30, 40, 50, 60)
REPEATS = 20
QUICK_PSC = {"n_atoms": 128, "n_iter": 2, "max_windows": 800}
SUBJECT_135 = ("135_02", "135_03", "135_04", "135_05", "135_06", "135_08", "135_09", "135_11")
# Table 4.1: (action, frames, TSMC s, TrNN s)
TABLE41 = (
    ("running", 152, 1.61, 2.69), ("walk", 343, 2.99, 4.35), ("jump", 439, 4.07, 6.13),
    ("gymnastics", 575, 7.63, 8.17), ("score", 801, 8.95, 10.19), ("dance", 1095, 21.23, 14.84),
    ("varied", 2085, 111.69, 36.30), ("punch", 2251, 93.33, 33.36),
    ("acrobatics", 2422, 121.93, 34.09), ("boxing", 4840, 267.29, 73.75),
    ("basketball", 4905, 286.25, 102.42), ("taichi", 17799, 2094.8, 564.85),
)


# --------------------------------------------------------------------------------------
# data
# --------------------------------------------------------------------------------------
def _read(trial: str, ctx: Context):
    from ... import io

    path = cmu_amc(trial, ctx.data_dir)
    return None if path is None else io.read(path)


def _clips(ctx: Context) -> list[tuple[str, str, Any]]:
    """(our id, thesis id, clean Motion) per available clip, capped as the options say."""
    if ctx.quick:
        wanted = [("16_15", "12_02")]
        cap = 240
    else:
        sel = ctx.options.get("clips")
        wanted = [c for c in CLIPS if sel is None or c[0] in sel]
        cap = ctx.options.get("frames")
    out = []
    for ours, theirs in wanted:
        m = _read(ours, ctx) if ctx.data_dir is not None else None
        if m is None and ours == "16_15":
            from ... import io

            try:
                m = io.read(bundled("16_15.amc"))
            except MocapError:                         # bundled clip missing too
                m = None
        if m is None:
            continue
        if cap:
            m = m.slice(0, min(m.n_frames, int(cap)))
        out.append((ours, theirs, m))
    return out


_PSC_CACHE: dict[tuple, tuple[Any, str]] = {}


def _psc_model(ours: str, clean, ctx: Context):
    """PSC trained on PSC_TRAIN[ours] (falls back to the clip's other frames when absent).

    Models are cached per (clip, frames, parameters, data folder) within one process, so
    the random and block protocols share them.
    """
    params = dict(QUICK_PSC if ctx.quick else ctx.options.get("psc", {}))
    key = (ours, clean.n_frames, tuple(sorted(params.items())), str(ctx.data_dir), ctx.quick)
    if key not in _PSC_CACHE:
        _PSC_CACHE[key] = _train_psc(ours, clean, ctx, params)
    return _PSC_CACHE[key]


def _train_psc(ours: str, clean, ctx: Context, params: dict[str, Any]):
    from ... import denoise

    train = []
    if not ctx.quick:
        for t in PSC_TRAIN.get(ours, ()):
            m = _read(t, ctx) if ctx.data_dir is not None else None
            if m is not None and m.skeleton.names == clean.skeleton.names:
                train.append(m)
    note = "trained on " + ", ".join(PSC_TRAIN.get(ours, ())) if train else ""
    if not train:
        # no same-kind clips: train on the rest of the same trial (beyond the test frames)
        full = _read(ours, ctx) if ctx.data_dir is not None else None
        if full is not None and full.n_frames > clean.n_frames + 60:
            train = [full.slice(clean.n_frames, full.n_frames)]
            note = f"trained on {ours} frames {clean.n_frames}-{full.n_frames}"
        else:
            return None, "no training data"
    with Timer() as t:
        model = denoise.get("psc", **params).fit(train)
    return model, f"{note} ({t.seconds:.1f} s)"


def _method_objects(ours: str, clean, ctx: Context, labels: tuple[str, ...] | None = None):
    from ... import denoise

    have = denoise.available()
    objs, notes = {}, {}
    for label, name, params in METHODS:
        if labels is not None and label not in labels:
            continue
        if name not in have:
            continue
        if name == "psc":
            model, note = _psc_model(ours, clean, ctx)
            notes[label] = note
            if model is None:
                continue
            objs[label] = model
        else:
            objs[label] = denoise.get(name, **params)
    return objs, notes


# --------------------------------------------------------------------------------------
# running
# --------------------------------------------------------------------------------------
def _evaluate(proto: str, clip: str, clean, conditions, objs, notes, n_rep: int,
              ctx: Context) -> Iterator[Row]:
    """For each (label, steps-maker) condition: corrupt n_rep times, run every method."""
    from ... import metrics

    for cond, make in conditions:
        acc: dict[str, list[tuple[float, float, int]]] = {}
        for rep in range(n_rep):
            noisy, scored = make(clean, ctx.seed + 1000 * rep)
            for label, method in objs.items():
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    with Timer() as t:
                        est = method.denoise(noisy)
                conv = not any("not converged" in str(w.message) for w in caught)
                acc.setdefault(label, []).append(
                    (metrics.rmse(clean, est, scored), t.seconds, int(conv)))
        for label, vals in acc.items():
            v = np.asarray(vals, dtype=float)
            extra = {"frames": clean.n_frames, "converged": f"{int(v[:, 2].sum())}/{len(v)}"}
            if notes.get(label):
                extra["training"] = notes[label]
            yield Row(proto, clip, cond, label, "rmse_missing", "cm", float(v[:, 0].mean()),
                      None, float(v[:, 1].mean()), float(v[:, 0].std()), len(v), extra)


def _random_missing(ratio: float):
    from ... import corrupt

    def make(clean, seed):
        noisy, mask = corrupt.missing(clean, ratio=ratio, per_frame=True, seed=seed)
        return noisy, mask
    return make


def _block_missing(length: int, n_markers: int = 10):
    from ... import corrupt

    def make(clean, seed):
        L = min(length, clean.n_frames)
        noisy, mask = corrupt.block_gaps(clean, n_markers=min(n_markers, clean.n_joints),
                                         length=L, seed=seed)
        return noisy, mask
    return make


def _n_repeats(ctx: Context) -> int:
    return 2 if ctx.quick else int(ctx.options.get("repeats", REPEATS))


def _missing_protocol(name: str, ctx: Context, values: tuple, label: str, make) -> Iterator[Row]:
    """Fig. 4.10/4.11 on every clip: one condition per value (``label % v``, ``make(v)``)."""
    for ours, theirs, clean in _clips(ctx):
        objs, notes = _method_objects(ours, clean, ctx)
        conds = [(label % v, make(v)) for v in values]
        yield from _evaluate(name, f"{ours} (for {theirs})", clean, conds, objs, notes,
                             _n_repeats(ctx), ctx)


@protocol("thesis-missing-random", "thesis Fig. 4.10/4.11: 6 CMU clips, 20-60% of markers missing "
                                   "per frame; psc/tsmc/trnn/svt/dynammo/spline; RMSE on missing (cm)")
def missing_random(ctx: Context) -> Iterator[Row]:
    ratios = (0.2, 0.6) if ctx.quick else tuple(ctx.options.get("ratios", RATIOS))
    yield from _missing_protocol("thesis-missing-random", ctx, ratios, "mr=%.1f", _random_missing)


@protocol("thesis-missing-blocks", "thesis Fig. 4.10/4.11: 6 CMU clips, 10 markers missing for "
                                   "20-60 consecutive frames; same methods; RMSE on missing (cm)")
def missing_blocks(ctx: Context) -> Iterator[Row]:
    lengths = (20, 60) if ctx.quick else tuple(ctx.options.get("lengths", LENGTHS))
    yield from _missing_protocol("thesis-missing-blocks", ctx, lengths, "ml=%d", _block_missing)


# --------------------------------------------------------------------------------------
# the four corruption cases of Sec. 4.1.3
# --------------------------------------------------------------------------------------
def _noise_on(motion, ratio: float, sigma: float, seed: int):
    """sigma-cm Gaussian noise on a random ``ratio`` of the observed marker entries."""
    from ... import corrupt

    rng = np.random.default_rng(seed)
    noisy, _ = corrupt.gaussian(motion, sigma_cm=sigma, seed=rng)
    obs = motion.observed
    sel = obs & (rng.random(obs.shape) < ratio)
    P = np.where(sel[..., None], noisy.positions, motion.positions)
    return motion.with_positions(P, observed=obs), sel


def _case(name: str):
    from ... import corrupt

    def make(clean, seed):
        if name == "rdcrypt":
            return _noise_on(clean, 0.3, 2.0, seed)
        if name == "rdloss":
            return corrupt.missing(clean, ratio=0.3, per_frame=True, seed=seed)
        if name == "mxcrypt":
            m1, miss = corrupt.missing(clean, ratio=0.3, per_frame=True, seed=seed)
            m2, noise = _noise_on(m1, 0.3, 2.0, seed + 1)
            return m2, miss | noise
        if name == "rgloss":
            T, J = clean.observed.shape
            L = min(60, T)
            n = max(1, int(round(0.3 * T * J / (10 * L))))
            return corrupt.block_gaps(clean, n_markers=min(10, J), length=L, n_blocks=n,
                                      seed=seed)
        raise ValueError(name)
    return make


CASES = ("rdcrypt", "rdloss", "mxcrypt", "rgloss")


@protocol("thesis-corrupt4", "thesis Fig. 4.1-4.4: rdcrypt / rdloss / mxcrypt / rgloss on 6 CMU "
                             "clips; tsmc vs trnn; RMSE on imperfect entries and on all (cm)")
def corrupt4(ctx: Context) -> Iterator[Row]:
    from ... import denoise, metrics

    cases = ("rdcrypt", "rgloss") if ctx.quick else CASES
    methods = {"tsmc": denoise.get("tsmc"), "trnn": denoise.get("trnn")}
    n_rep = _n_repeats(ctx)
    for ours, theirs, clean in _clips(ctx):
        clip = f"{ours} (for {theirs})"
        for case in cases:
            make = _case(case)
            acc: dict[str, list[tuple[float, float, float]]] = {}
            for rep in range(n_rep):
                noisy, scored = make(clean, ctx.seed + 1000 * rep)
                acc.setdefault("corrupted-input", []).append(
                    (metrics.rmse(clean, noisy, scored & noisy.observed)
                     if (scored & noisy.observed).any() else np.nan, np.nan, 0.0))
                for label, method in methods.items():
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        with Timer() as t:
                            est = method.denoise(noisy)
                    acc.setdefault(label, []).append(
                        (metrics.rmse(clean, est, scored), metrics.rmse(clean, est), t.seconds))
            for label, vals in acc.items():
                v = np.asarray(vals, dtype=float)
                if label == "corrupted-input":
                    if np.isfinite(v[:, 0]).all():
                        yield Row("thesis-corrupt4", clip, case, label, "rmse_noisy_observed",
                                  "cm", float(v[:, 0].mean()), None, 0.0, float(v[:, 0].std()),
                                  len(v))
                    continue
                yield Row("thesis-corrupt4", clip, case, label, "rmse_imperfect", "cm",
                          float(v[:, 0].mean()), None, float(v[:, 2].mean()),
                          float(v[:, 0].std()), len(v), {"frames": clean.n_frames})
                yield Row("thesis-corrupt4", clip, case, label, "rmse_all", "cm",
                          float(v[:, 1].mean()), None, float(v[:, 2].mean()),
                          float(v[:, 1].std()), len(v))


# --------------------------------------------------------------------------------------
# Table 4.1 run time
# --------------------------------------------------------------------------------------
def long_sequence(ctx: Context, frames: int):
    """First ``frames`` frames of CMU subject 135's trials concatenated (one skeleton).

    Without the shared data, the bundled walk is tiled.  Seams jump (each trial starts
    elsewhere); that does not matter for timing.
    """
    from ... import io

    parts, total = [], 0
    for trial in SUBJECT_135:
        m = _read(trial, ctx) if ctx.data_dir is not None else None
        if m is None:
            continue
        parts.append(m)
        total += m.n_frames
        if total >= frames:
            break
    if total < frames:
        parts = [io.read(bundled("16_15.amc"))] if not parts else parts
        reps = int(np.ceil(frames / sum(p.n_frames for p in parts)))
        parts = parts * reps
    first = parts[0]
    P = np.concatenate([p.positions for p in parts])[:frames]
    return first.with_positions(P)


@protocol("thesis-runtime", "thesis Table 4.1: TSMC and TrNN seconds vs clip length (152..17,799 "
                            "frames, 20% missing markers), one BLAS thread; Matlab seconds as paper")
def runtime(ctx: Context) -> Iterator[Row]:
    from ...solvers._linalg import blas_limit

    from ... import corrupt, denoise, metrics

    table = TABLE41[:3] if ctx.quick else TABLE41
    sel = ctx.options.get("max_frames")
    if sel:
        table = tuple(r for r in table if r[1] <= int(sel))
    methods = {"tsmc": denoise.get("tsmc"), "trnn": denoise.get("trnn")}
    banded = {"tsmc(mstep=banded)": denoise.get("tsmc", mstep="banded"),
              "trnn(mstep=banded)": denoise.get("trnn", mstep="banded")}
    n_rep = 1 if ctx.quick else int(ctx.options.get("timing_repeats", 3))
    for action, frames, p_tsmc, p_trnn in table:
        clean = long_sequence(ctx, frames)
        noisy, miss = corrupt.missing(clean, ratio=0.2, per_frame=True, seed=ctx.seed)
        todo = dict(methods)
        if frames >= 2000 and not ctx.quick:
            todo.update(banded)
        for label, method in todo.items():
            wall, cpu = np.inf, np.inf
            for _ in range(n_rep if frames < 10000 else 1):
                with blas_limit(), warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    c0 = time.process_time()
                    with Timer() as t:
                        est = method.denoise(noisy)
                    cpu = min(cpu, time.process_time() - c0)
                wall = min(wall, t.seconds)
            info = est.source.get("solver", {})
            paper = p_tsmc if label.startswith("tsmc") else p_trnn
            yield Row("thesis-runtime", f"135_* ({action})", f"frames={frames}", label, "seconds",
                      "s", float(wall), paper, float(wall), None, 1,
                      {"cpu_seconds": float(cpu), "iterations": info.get("n_iter"),
                       "converged": info.get("converged"),
                       "speedup_vs_paper": paper / wall if wall > 0 else None,
                       "speedup_vs_paper_cpu": paper / cpu if cpu > 0 else None,
                       "rmse_missing_cm": metrics.rmse(clean, est, miss)})
