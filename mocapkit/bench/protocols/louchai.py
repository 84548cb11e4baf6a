"""Protocols of Lou & Chai 2010 (seed 001): ``louchai-noise``, ``louchai-outliers``,
``louchai-missing``, ``louchai-window``.

Setting (paper Sec. 4): behaviour-specific training, a test clip pulled out of the
training set, data down-sampled 120 -> 30 fps, simulated corruption, error per degree of
freedom per frame. Here:

* Data: CMU ASF/AMC from ../shared/data, each clip's first 8 frames (at 120 fps) dropped
  (CMU 16_15 has a 92 cm left-arm glitch at frame 1), then every 4th frame (30 fps,
  :func:`mocapkit.denoise.bases.decimate`; the paper's 120 -> 30 fps).
* Behaviours and folds (each fold trains on every other clip of the behaviour):
  walking -- the 11 ASF/AMC walks 05_01, 07_03, 07_05, 16_15, 35_01, 131_01, 131_02,
  131_09, 131_11, 131_12, 131_14 (six subjects; 02_01 exists only as BVH with another
  skeleton and is left out); test folds 35_01, 131_02, 05_01 (quick: 35_01).
  Running -- the only CMU run is 09_06 (141 frames); the 15 HDM05
  ``jogLeftCircle4StepsRstart`` clips (five actors, same ASF joint names) make the
  running set: folds "HDM_tr_<n>" (the last jog of HDM05 actor tr held out, the other
  actor-tr jog stays in training) and "09_06" (the CMU run, trained on all HDM05 jogs:
  another database and subject). Hopping/jumping (for
  Fig. 9b) -- CMU 131_03 (test), trained on 131_04, 131_07, 131_08, 01_01.
  Skeletons of different subjects are handled by the body frame and the height
  normalisation of ``lou-chai`` (one model per behaviour, not per skeleton; the paper's
  "large walking database" setting).
* Methods (the paper's Fig. 7 comparison): ``lou-chai`` with the paper's settings (M=20,
  99% energy, lam=0.1, p=3), ``lou-chai*`` = our setting (99.9% energy, training clips
  also mirrored left/right; position space) -- chosen on leave-one-out over the walking
  clips 16_15, 131_12 and 07_05 (not the test folds above; running/hopping were not used
  for tuning) --, ``gaussian`` (window 11 frames at 30 fps, per channel, the paper's
  setting), ``kalman-identity`` and ``kalman-learned`` (trained on the same clips).
* Metric: RMSE in cm over all coordinates (the paper: average squared distance per DOF
  per frame), or over the removed coordinates for gap filling; angle space: RMSE in
  degrees over the non-root joint-angle channels.

Protocols
---------
``louchai-noise`` -- Gaussian noise sigma 0.5, 1, 2, 3, 4, 6 cm on every coordinate
(Fig. 7 left), 3 seeds; plus, on AMC input in joint-angle space, sigma 1, 3, 5 degrees on
the joint-angle channels (walking fold 35_01), where ``lou-chai`` runs with
``space='angle'`` (paper 99% and our 99.99% energy) and the baselines run on the angle
channels as if they were coordinates.
``louchai-outliers`` -- 0, 5, 10, 15, 20, 25% of the joint positions replaced by 15 cm
spikes in random directions on top of 1 cm Gaussian noise (Fig. 7 right); 3 seeds.
``louchai-missing`` -- both arms (every joint of the two arm chains) missing for the
whole clip (Fig. 6); random block gaps (4 blocks of 5 markers x 1 s); 20% of the markers
missing in every frame. RMSE over the removed coordinates. Per-channel methods cannot
fill a joint never observed: their rows carry NaN and the error message in ``extra``.
``louchai-window`` -- error against window size M = 5, 10, 15, 20, 30, 40 (Fig. 9):
(a) walking, sigma = 3 cm (position) and 3 degrees (angle space); (b) gap filling
(block gaps) in the hopping/jumping test clip.

``ctx.quick``: one walking fold, one seed, fewer levels, no running/angle rows, M = 10
and 20 only (well under a minute).
"""
from __future__ import annotations

import functools
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from ..core import Context, Row, Timer, protocol

WALK = ("05_01", "07_03", "07_05", "16_15", "35_01", "131_01", "131_02", "131_09",
        "131_11", "131_12", "131_14")
WALK_TESTS = ("35_01", "131_02", "05_01")
HOP_TRAIN = ("131_04", "131_07", "131_08", "01_01")
HOP_TEST = "131_03"
JOG_DIR = "hdm05/asfamc/jogLeftCircle4StepsRstart"
TRIM = 8                       # frames dropped at the start (120 fps)
DECIM = 4                      # 120 -> 30 fps

PAPER: dict[str, Any] = {}
TUNED: dict[str, Any] = {"energy": 0.999, "mirror": True, "lam": 0.2}
TUNED_ANGLE: dict[str, Any] = {"energy": 0.9999}
LOU = (("lou-chai", {}), ("lou-chai*", TUNED))
BASELINES = (("gaussian", "gaussian", {"window": 11}),
             ("kalman-identity", "kalman-identity", {}),
             ("kalman-learned", "kalman-learned", {}))

_CLIPS: dict[str, Any] = {}
_MODELS: dict[tuple, Any] = {}


# ---------------------------------------------------------------------------------------
# data
# ---------------------------------------------------------------------------------------
def _load(path: Path):
    from ... import io
    from ...denoise.bases import decimate

    key = str(path)
    if key not in _CLIPS:
        m = io.read(path)
        _CLIPS[key] = decimate(m.slice(TRIM), DECIM)
    return _CLIPS[key]


def _cmu(trial: str, ctx: Context):
    root = ctx.need_data()
    p = root / "cmu" / "asfamc" / trial.split("_")[0] / f"{trial}.amc"
    return _load(p) if p.is_file() else None


def _jogs(ctx: Context) -> dict[str, Any]:
    d = ctx.need_data() / JOG_DIR
    out = {}
    for p in sorted(d.glob("*.amc")):
        parts = p.stem.split("_")            # HDM, actor, class, number, 120
        out[f"HDM_{parts[1]}_{parts[3]}"] = _load(p)
    return out


def _folds(behaviour: str, ctx: Context) -> list[tuple[str, Any, list]]:
    """(test name, test clip, training clips) per fold."""
    if behaviour == "walking":
        clips = {t: _cmu(t, ctx) for t in WALK}
        clips = {t: m for t, m in clips.items() if m is not None}
        tests = WALK_TESTS[:1] if ctx.quick else WALK_TESTS
        return [(t, clips[t], [m for s, m in clips.items() if s != t]) for t in tests if t in clips]
    if behaviour == "running":
        jogs = _jogs(ctx)
        folds = []
        held = [k for k in jogs if k.startswith("HDM_tr")]
        if held:
            k = held[-1]
            folds.append((k, jogs[k], [m for s, m in jogs.items() if s != k]))
        run = _cmu("09_06", ctx)
        if run is not None and jogs:
            folds.append(("09_06", run, list(jogs.values())))
        return folds
    if behaviour == "hopping":
        test = _cmu(HOP_TEST, ctx)
        train = [m for m in (_cmu(t, ctx) for t in HOP_TRAIN) if m is not None]
        return [(HOP_TEST, test, train)] if (test is not None and train) else []
    raise ValueError(behaviour)


def _fitted(name: str, params: dict, fold: str, train: list):
    from ... import denoise

    key = (name, tuple(sorted((k, repr(v)) for k, v in params.items())), fold)
    if key not in _MODELS:
        m = denoise.get(name, **params)
        if type(m).needs_training:
            m.fit(train)
        _MODELS[key] = m
    return _MODELS[key]


def _methods(fold: str, train: list) -> list[tuple[str, Any]]:
    out = [(label, _fitted("lou-chai", p, fold, train)) for label, p in LOU]
    out += [(label, _fitted(name, p, fold, train)) for label, name, p in BASELINES]
    return out


def _score(truth, est, mask=None) -> float:
    from ... import metrics

    return float(metrics.rmse(truth, est, mask))


def _run(method, noisy):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with Timer() as t:
            out = method.denoise(noisy)
    return out, t.seconds


def _rows_for(proto: str, fold: str, cond: str, results: dict, unit: str, metric: str,
              extra: dict | None = None) -> Iterator[Row]:
    for label, (vals, secs, err) in results.items():
        v = np.array(vals, float)
        row = Row(proto, fold, cond, label, metric, unit,
                  float(np.mean(v)) if len(v) else float("nan"),
                  seconds=float(np.mean(secs)) if secs else None,
                  std=float(np.std(v)) if len(v) > 1 else None, n=len(v))
        if err:
            row.extra = {"error": err}
        if extra:
            row.extra.update(extra)
        yield row


def _sweep(proto: str, ctx: Context, behaviour: str, conditions, mask_kind: str = "all",
           seeds: int = 3) -> Iterator[Row]:
    """Run every method on every fold x condition x seed; one row per (fold, cond, method)."""
    from ... import corrupt
    from ...errors import MocapError

    for fold, truth, train in _folds(behaviour, ctx):
        methods = _methods(fold, train)
        for cond, steps in conditions:
            res: dict[str, tuple[list, list, str]] = {label: ([], [], "") for label, _ in methods}
            for seed in range(1 if ctx.quick else seeds):
                noisy, cmask = corrupt.combine(truth, steps, seed=1000 * seed + 7) if steps else (truth, None)
                score_mask = cmask if mask_kind == "corrupted" else None
                for label, m in methods:
                    try:
                        out, s = _run(m, noisy)
                    except MocapError as e:
                        res[label] = (res[label][0], res[label][1], str(e).split(";")[0])
                        continue
                    res[label][0].append(_score(truth, out, score_mask))
                    res[label][1].append(s)
            metric = "rmse_missing" if mask_kind == "corrupted" else "rmse"
            yield from _rows_for(proto, f"{behaviour}:{fold}", cond, res, "cm", metric)


# ---------------------------------------------------------------------------------------
# joint-angle space
# ---------------------------------------------------------------------------------------
def _angle_as_motion(V: np.ndarray, fps: float):
    """Angle channels (T, C) as a fake Motion (C padded to 3k) so the registry's
    per-coordinate baselines run on them unchanged (units: degrees instead of cm)."""
    from ...motion import Motion
    from ...skeleton import Skeleton

    T, C = V.shape
    k = -(-C // 3)
    P = np.zeros((T, 3 * k))
    P[:, :C] = V
    sk = Skeleton(tuple(f"c{i}" for i in range(k)), -np.ones(k, int), np.zeros((k, 3)))
    return Motion(P.reshape(T, k, 3), sk, fps)


def _angle_rmse(Vo, V, joint, period) -> float:
    """RMSE over the joint-angle channels, differences wrapped to one turn."""
    d = (np.asarray(Vo) - V)[:, joint]
    d = d - period * np.round(d / period)
    return float(np.sqrt(np.mean(d * d)))


def _angle_rows(proto: str, ctx: Context, fold: str, truth, train, sigmas, seeds: int,
                window: int | None = None) -> Iterator[Row]:
    from ... import denoise
    from ...denoise.bases import angle_channels

    V, names, info = angle_channels(truth)
    V = V.copy()
    rot = info["rotation"]
    V[:, rot] = np.unwrap(V[:, rot], axis=0, period=info["period"])
    joint = rot & ~info["root"]
    C = V.shape[1]
    extra_p = {} if window is None else {"window": window}
    lous = [("lou-chai(angle)", _fitted("lou-chai", {"space": "angle", **extra_p}, fold, train)),
            ("lou-chai*(angle)", _fitted("lou-chai", {"space": "angle", **TUNED_ANGLE, **extra_p}, fold, train))]
    base = []
    if window is None:
        tr_fake = []
        for m in train:
            W, _, inf = angle_channels(m)
            W = W.copy()
            W[:, inf["rotation"]] = np.unwrap(W[:, inf["rotation"]], axis=0, period=inf["period"])
            tr_fake.append(_angle_as_motion(W, m.fps))
        for label, name, p in BASELINES:
            p = dict(p)
            if name == "kalman-learned":
                p["frame"] = "global"
            m = denoise.get(name, **p)
            if type(m).needs_training:
                m.fit(tr_fake)
            base.append((label, m))
    for sig in sigmas:
        res: dict[str, tuple[list, list, str]] = {label: ([], [], "") for label, _ in lous + base}
        for seed in range(1 if ctx.quick else seeds):
            rng = np.random.default_rng(1000 * seed + 11)
            Vn = V.copy()
            Vn[:, joint] += rng.normal(scale=sig, size=(len(V), int(joint.sum())))
            from ...denoise.bases import angle_fk

            noisy = truth.with_positions(angle_fk(truth, Vn)).with_source(
                per_frame={info["key"]: Vn})
            for label, m in lous:
                out, s = _run(m, noisy)
                Vo = np.asarray(out.source["per_frame"][info["key"]])
                res[label][0].append(_angle_rmse(Vo, V, joint, info["period"]))
                res[label][1].append(s)
            fake = _angle_as_motion(Vn, truth.fps)
            for label, m in base:
                out, s = _run(m, fake)
                Vo = out.positions.reshape(len(V), -1)[:, :C]
                res[label][0].append(_angle_rmse(Vo, V, joint, info["period"]))
                res[label][1].append(s)
        cond = f"gauss{sig:g}deg" + ("" if window is None else f",M={window}")
        yield from _rows_for(proto, f"walking:{fold}", cond, res, "deg", "rmse_angle")


# ---------------------------------------------------------------------------------------
# protocols
# ---------------------------------------------------------------------------------------
def _one_thread(func: Callable[[Context], Iterator[Row]]) -> Callable[[Context], Iterator[Row]]:
    """Run a protocol with BLAS limited to one thread: timings are per core, and on a
    small shared machine multithreaded BLAS on these small matrices only thrashes."""

    @functools.wraps(func)
    def wrapper(ctx: Context) -> Iterator[Row]:
        from ...solvers._linalg import blas_limit

        with blas_limit():
            yield from func(ctx)

    return wrapper


@protocol("louchai-noise", "Lou & Chai 2010 Fig. 7 left: error vs Gaussian noise (cm; degrees in "
                           "angle space), behaviour-specific training, 30 fps")
@_one_thread
def noise(ctx: Context) -> Iterator[Row]:
    sig = (1.0, 2.0, 4.0) if ctx.quick else (0.5, 1.0, 2.0, 3.0, 4.0, 6.0)
    conds = [(f"gauss{s:g}cm", [("gaussian", {"sigma_cm": s})]) for s in sig]
    yield from _sweep("louchai-noise", ctx, "walking", conds)
    if ctx.quick:
        return
    yield from _sweep("louchai-noise", ctx, "running", conds)
    fold = WALK_TESTS[0]
    for name, truth, train in _folds("walking", ctx):
        if name == fold:
            yield from _angle_rows("louchai-noise", ctx, fold, truth, train, (1.0, 3.0, 5.0), seeds=3)


@protocol("louchai-outliers", "Lou & Chai 2010 Fig. 7 right: error vs percentage of 15 cm outliers "
                              "(+1 cm noise), 30 fps")
@_one_thread
def outliers(ctx: Context) -> Iterator[Row]:
    ratios = (0.0, 0.10, 0.20) if ctx.quick else (0.0, 0.05, 0.10, 0.15, 0.20, 0.25)
    conds = [(f"outliers{100 * r:g}%", [("gaussian", {"sigma_cm": 1.0})]
              + ([("outliers", {"ratio": r, "mode": "spike", "magnitude_cm": 15.0})] if r else []))
             for r in ratios]
    yield from _sweep("louchai-outliers", ctx, "walking", conds)
    if not ctx.quick:
        yield from _sweep("louchai-outliers", ctx, "running", conds)


def _arm_joints(motion) -> list[str]:
    parts = motion.skeleton.body_parts()
    names = motion.skeleton.names
    return [names[j] for j in parts["left_arm"][1:] + parts["right_arm"][1:]]


@protocol("louchai-missing", "Lou & Chai 2010 Fig. 6: both arms missing for the whole clip; random "
                             "block gaps; random missing markers (RMSE on the removed entries)")
@_one_thread
def missing(ctx: Context) -> Iterator[Row]:
    folds = _folds("walking", ctx)
    if not folds:
        return
    arms = _arm_joints(folds[0][1])
    conds = [("both-arms-missing", [("block_gaps", {"joints": arms, "length": None})]),
             ("blocks4x5x1s", [("block_gaps", {"n_markers": 5, "length": 30, "n_blocks": 4})]),
             ("missing20%/frame", [("missing", {"ratio": 0.2})])]
    if ctx.quick:
        conds = conds[:2]
    yield from _sweep("louchai-missing", ctx, "walking", conds, mask_kind="corrupted", seeds=2)
    if not ctx.quick:
        yield from _sweep("louchai-missing", ctx, "running", conds[:2], mask_kind="corrupted", seeds=2)


@protocol("louchai-window", "Lou & Chai 2010 Fig. 9: error vs window size M (walking sigma = 3 cm / "
                            "3 degrees; gap filling in a hopping clip)")
@_one_thread
def window(ctx: Context) -> Iterator[Row]:
    from ... import corrupt
    from ...errors import MocapError

    Ms = (10, 20) if ctx.quick else (5, 10, 15, 20, 30, 40)
    seeds = 1 if ctx.quick else 3
    walk = [f for f in _folds("walking", ctx) if f[0] == WALK_TESTS[0]]
    hop = [] if ctx.quick else _folds("hopping", ctx)
    cases = [("walking", f, "gauss3cm", [("gaussian", {"sigma_cm": 3.0})], None) for f in walk]
    cases += [("hopping", f, "blocks4x5x1s", [("block_gaps", {"n_markers": 5, "length": 30, "n_blocks": 4})],
               "corrupted") for f in hop]
    for beh, (fold, truth, train), cond, steps, mk in cases:
        for M in Ms:
            for label, p in LOU:
                m = _fitted("lou-chai", {**p, "window": M}, fold, train)
                vals, secs, err = [], [], ""
                for seed in range(seeds):
                    noisy, cmask = corrupt.combine(truth, steps, seed=1000 * seed + 7)
                    try:
                        out, s = _run(m, noisy)
                    except MocapError as e:
                        err = str(e)
                        continue
                    vals.append(_score(truth, out, cmask if mk else None))
                    secs.append(s)
                yield from _rows_for("louchai-window", f"{beh}:{fold}", f"{cond},M={M}",
                                     {label: (vals, secs, err)}, "cm",
                                     "rmse_missing" if mk else "rmse",
                                     extra={"window": M, "n_bases": int(m.n_bases_)})
    if not ctx.quick:
        for fold, truth, train in walk:
            for M in Ms:
                yield from _angle_rows("louchai-window", ctx, fold, truth, train, (3.0,), seeds=seeds, window=M)
