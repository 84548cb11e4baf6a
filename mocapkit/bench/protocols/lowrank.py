"""Protocols of the low-rank family: SLRA (seed 004) Tables 2 and 3, and a noise sweep.

* ``slra-table2`` -- seed 004 Table 2: three CMU sequences, the first N frames, p of them
  corrupted by eq. 7 (Gaussian of mean eps = 1 and sigma = 1.2 on a random half of the
  entries of p random frames), FD = ||A - X||_F / sqrt(mn) (eq. 8) in CMU ASF units (1
  unit = 5.6444 cm; eps and sigma are in the paper's unit, the noise scaled to cm) and in
  cm. The methods run on the clip in cm, as a user's clip comes from a reader: the gap
  policy's floors are in cm (a spike is at least 1 cm off its neighbours), and on the clip
  in ASF units they were 5.6 times too large -- the misfit check took eq.-7 offsets under
  5.6 cm for a model's misfits and gave them back (found 2026-12-06); methods slra (the paper's segment counts), tsvd (k =
  10), svt, rpca; plus our variants (blended overlap, short segments).  10 seeds,
  mean +- std.  The paper's trials 14_46, 13_27 and 14_06 are not in ../shared/data;
  the closest available clips of at least the same length are used, named in the row's
  clip ("131_05 (for 14_46)"): 131_05 "start, duck underneath, stop" (walk + crouch,
  for walk/sit/stand), 131_09 "start, walk left" (for direct traffic / wave / point),
  135_06 martial-arts kata Heian Shodan (for jumping jacks / jog / squats / twists).
* ``slra-table3`` -- FD versus segment count on the same three sequences (Table 3 grid).
* ``lowrank-noise`` -- every low-rank method and the classical baselines present in the
  registry on 6 varied CMU clips (walk 16_15, run 09_06, jumps 01_01, modern dance 05_02,
  front kick 135_04, one-leg balance 49_18; frames 2-601 at 120 fps, see NOISE_START) under Gaussian noise (1, 2,
  4 cm), spikes (5, 10, 20 % of markers, 15 cm) and missing markers (10, 30 %); RMSE in cm
  over all entries and over the corrupted entries.

``ctx.quick``: one clip, fewer frames, 2 seeds (well under a minute).
"""
from __future__ import annotations

from typing import Any, Iterator

import numpy as np

from ...datasets import bundled, cmu_amc
from ...io.units import CMU_CM_PER_UNIT
from ..core import Context, Row, Timer, protocol


# (our clip, paper's clip, frames, noisy frames, segments, paper FD: ours/TSVD/SVT/RPCA)
TABLE2 = (
    ("131_05", "14_46", 1200, 400, 6, {"slra": 0.1031, "tsvd": 0.2574, "svt": 0.2673, "rpca": 0.2768}),
    ("131_09", "13_27", 2000, 700, 5, {"slra": 0.1785, "tsvd": 0.4578, "svt": 0.4126, "rpca": 0.3972}),
    ("135_06", "14_06", 2800, 900, 7, {"slra": 0.2455, "tsvd": 0.4623, "svt": 0.4986, "rpca": 0.5238}),
)
# Table 3: (segment frames, segment count, paper FD) per sequence
TABLE3 = {
    "14_46": ((200, 6, 0.1031), (300, 4, 0.1219), (400, 3, 0.1526), (600, 2, 0.2213)),
    "13_27": ((200, 10, 0.1127), (400, 5, 0.1785), (500, 4, 0.2556), (1000, 2, 0.3492)),
    "14_06": ((200, 14, 0.1026), (400, 7, 0.2456), (700, 4, 0.2519), (1400, 2, 0.3862)),
}
EPS, SIGMA = 1.0, 1.2
SEEDS = 10

#: our best setting of the family (chosen on 01_01, 05_06, 131_01, 131_02 -- none of them a
#: Table 2 clip): short segments with half-segment blended overlap
SHORT = {"segment": 24, "overlap": 12, "tol": 1e-5}

NOISE_CLIPS = ("16_15", "09_06", "01_01", "05_02", "135_04", "49_18")
NOISE_START = 2
"""First frame used by ``lowrank-noise``: frames 1-2 of 16_15.amc hold a zeroed left arm
(``lhumerus 0 0 0``, a 90 cm jump), which a robust method rightly "repairs" and would
then be charged for; every clip starts at frame index 2."""
NOISE_CONDITIONS = (
    ("gauss1cm", ("gaussian", {"sigma_cm": 1.0})),
    ("gauss2cm", ("gaussian", {"sigma_cm": 2.0})),
    ("gauss4cm", ("gaussian", {"sigma_cm": 4.0})),
    ("spikes5%", ("outliers", {"ratio": 0.05, "mode": "spike", "magnitude_cm": 15.0})),
    ("spikes10%", ("outliers", {"ratio": 0.10, "mode": "spike", "magnitude_cm": 15.0})),
    ("spikes20%", ("outliers", {"ratio": 0.20, "mode": "spike", "magnitude_cm": 15.0})),
    ("missing10%", ("missing", {"ratio": 0.10})),
    ("missing30%", ("missing", {"ratio": 0.30})),
)
LOWRANK_METHODS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("tsvd", "tsvd", {}),
    ("svt", "svt", {}),
    ("rpca", "rpca", {"tol": 1e-5}),
    ("slra", "slra", {"tol": 1e-5}),
    ("slra(seg=24,ov=12)", "slra", SHORT),
)
CLASSICAL = ("gaussian", "butterworth", "savgol", "median", "hampel", "kalman-cv")
GAP_FILLERS = ("linear", "spline")


def _read(trial: str, ctx: Context):
    from ... import io

    path = cmu_amc(trial, ctx.data_dir)
    if path is None:
        return None
    return io.read(path)


def _slra_noise(motion, n_frames: int, seed: int):
    from ... import corrupt

    return corrupt.slra_noise(motion, n_frames=n_frames, eps=EPS, sigma=SIGMA, seed=seed,
                              scale=CMU_CM_PER_UNIT)


def _fd(a, b) -> float:
    """FD (eq. 8) in CMU ASF units of two motions in cm."""
    from ... import metrics

    return float(metrics.frobenius_distance(a, b)) / CMU_CM_PER_UNIT


def _table2_methods(n_seg: int, frames: int) -> list[tuple[str, str, dict[str, Any]]]:
    L = frames // n_seg
    return [
        ("slra", "slra", {"n_segments": n_seg}),
        ("tsvd", "tsvd", {"k": 10}),
        ("svt", "svt", {}),
        ("rpca", "rpca", {}),
        ("slra(center=mean)", "slra", {"n_segments": n_seg, "center": "mean"}),
        (f"slra(ov={L // 4})", "slra", {"n_segments": n_seg, "overlap": L // 4}),
        ("slra(seg=24,ov=0)", "slra", {**SHORT, "overlap": 0}),
        ("slra(seg=24,ov=12)", "slra", SHORT),
    ]


def _repeat(clean, noisy_list, methods, ctx) -> dict[str, tuple[list[float], list[float]]]:
    """FD (ASF units) and seconds per method over the noisy versions."""
    from ... import denoise

    out: dict[str, tuple[list[float], list[float]]] = {}
    for label, name, params in methods:
        fds, secs = [], []
        method = denoise.get(name, **params)
        for noisy in noisy_list:
            with Timer() as t:
                est = method.denoise(noisy)
            fds.append(_fd(clean, est))
            secs.append(t.seconds)
        out[label] = (fds, secs)
    return out


def _stat_rows(proto, clip, cond, label, fds, secs, paper, frames) -> Iterator[Row]:
    fds = np.asarray(fds)
    yield Row(proto, clip, cond, label, "FD", "CMU unit", float(fds.mean()), paper,
              float(np.mean(secs)), float(fds.std()), len(fds), {"frames": frames})
    yield Row(proto, clip, cond, label, "FD_cm", "cm", float(fds.mean() * CMU_CM_PER_UNIT),
              None if paper is None else paper * CMU_CM_PER_UNIT, float(np.mean(secs)),
              float(fds.std() * CMU_CM_PER_UNIT), len(fds))


def _sequences(ctx: Context):
    """(clip label, clean motion (cm), paper clip, frames, noisy frames, segments, paper)."""
    for ours, paper_clip, frames, p, n_seg, paper in TABLE2:
        m = _read(ours, ctx)
        if m is None:
            continue
        if ctx.quick:                       # a third of the frames, noisy frames and segments
            frames, p, n_seg = frames // 3, p // 3, max(1, n_seg // 3)
        if m.n_frames < frames:
            raise RuntimeError(f"{ours} has {m.n_frames} frames, need {frames}")
        yield f"{ours} (for {paper_clip})", m.slice(0, frames), paper_clip, frames, p, n_seg, paper
        if ctx.quick:
            return


def _noisy_sequences(ctx: Context):
    """:func:`_sequences` plus the eq.-7 noisy copies (2 seeds quick, else ``SEEDS``)."""
    ctx.need_data()
    n_seeds = 2 if ctx.quick else SEEDS
    for label, clean, paper_clip, frames, p, n_seg, paper in _sequences(ctx):
        noisy = [_slra_noise(clean, p, ctx.seed + s)[0] for s in range(n_seeds)]
        yield label, clean, paper_clip, frames, p, n_seg, paper, noisy


@protocol("slra-table2", "SLRA Table 2: eq.-7 noise (eps=1, sigma=1.2) on 3 CMU sequences; "
                         "slra/tsvd/svt/rpca (+ our variants); FD in CMU units and cm; 10 seeds")
def slra_table2(ctx: Context) -> Iterator[Row]:
    for label, clean, paper_clip, frames, p, n_seg, paper, noisy in _noisy_sequences(ctx):
        cond = f"eq7 p={p}/{frames} segs={n_seg}"
        yield from _stat_rows("slra-table2", label, cond, "noisy-input",
                              [_fd(clean, n) for n in noisy], [0.0], None, frames)
        res = _repeat(clean, noisy, _table2_methods(n_seg, frames), ctx)
        for mlabel, (fds, secs) in res.items():
            yield from _stat_rows("slra-table2", label, cond, mlabel, fds, secs,
                                  paper.get(mlabel), frames)


@protocol("slra-table3", "SLRA Table 3: FD vs segment count (200..1400-frame segments) on the "
                         "Table 2 sequences; 10 seeds")
def slra_table3(ctx: Context) -> Iterator[Row]:
    for label, clean, paper_clip, frames, p, n_seg, paper, noisy in _noisy_sequences(ctx):
        grid = TABLE3[paper_clip]
        if ctx.quick:
            grid = tuple((frames // k, k, None) for k in (n_seg, max(1, n_seg // 2)))
        methods, papers = [], {}
        for seg_len, k, pfd in grid:
            lab = f"slra {k}x{seg_len}"
            methods.append((lab, "slra", {"n_segments": k}))
            papers[lab] = pfd
            ov = (frames // k) // 4
            methods.append((f"slra {k}x{seg_len} ov={ov}", "slra", {"n_segments": k, "overlap": ov}))
        res = _repeat(clean, noisy, methods, ctx)
        cond = f"eq7 p={p}/{frames}"
        for mlabel, (fds, secs) in res.items():
            yield from _stat_rows("slra-table3", label, cond, mlabel, fds, secs,
                                  papers.get(mlabel), frames)


def _noise_methods() -> list[tuple[str, str, dict[str, Any]]]:
    from ... import denoise

    have = denoise.available()
    ms = [m for m in LOWRANK_METHODS]
    ms += [(n, n, {}) for n in CLASSICAL if n in have]
    return ms


@protocol("lowrank-noise", "low-rank family + classical filters on 6 CMU clips: Gaussian 1/2/4 cm, "
                           "15 cm spikes 5/10/20%, missing markers 10/30%; RMSE cm (all, corrupted)")
def lowrank_noise(ctx: Context) -> Iterator[Row]:
    from ... import corrupt, denoise, metrics

    clips = []
    for trial in (NOISE_CLIPS[:1] if ctx.quick else NOISE_CLIPS):
        m = _read(trial, ctx) if ctx.data_dir is not None else None
        if m is None and trial == "16_15":
            from ... import io

            m = io.read(bundled("16_15.amc"))
        if m is not None:
            n = 240 if ctx.quick else 600
            clips.append((trial, m.slice(NOISE_START, min(m.n_frames, NOISE_START + n))))
    n_seeds = 1 if ctx.quick else 2
    conds = NOISE_CONDITIONS[::3] if ctx.quick else NOISE_CONDITIONS
    methods = _noise_methods()
    gap = [(n, n, {}) for n in GAP_FILLERS if n in denoise.available()]
    for trial, clean in clips:
        for cond, step in conds:
            ms = methods + (gap if step[0] == "missing" else [])
            if step[0] == "missing":
                ms = ms + [(f"{lab}+keep", name, {**p, "keep_observed": True})
                           for lab, name, p in LOWRANK_METHODS if name in ("svt", "slra")]
            acc: dict[str, list[tuple[float, float, float]]] = {}
            for s in range(n_seeds):
                noisy, cmask = corrupt.combine(clean, [step], seed=ctx.seed + s)
                acc.setdefault("noisy-input", []).append(
                    (metrics.rmse(clean, noisy, noisy.observed), np.nan, 0.0))
                for label, name, params in ms:
                    method = denoise.get(name, **params)
                    with Timer() as t:
                        est = method.denoise(noisy)
                    acc.setdefault(label, []).append(
                        (metrics.rmse(clean, est), metrics.rmse(clean, est, cmask), t.seconds))
            for label, vals in acc.items():
                v = np.asarray(vals, dtype=float)
                yield Row("lowrank-noise", trial, cond, label, "rmse", "cm", float(v[:, 0].mean()),
                          None, float(v[:, 2].mean()), float(v[:, 0].std()), len(v),
                          {"frames": clean.n_frames})
                if label != "noisy-input":
                    yield Row("lowrank-noise", trial, cond, label, "rmse_corrupted", "cm",
                              float(v[:, 1].mean()), None, float(v[:, 2].mean()),
                              float(v[:, 1].std()), len(v))
