"""``smoke``: three real CMU clips, Gaussian 2 cm + 5% outliers + 10% missing; gaussian and spline.

A quick end-to-end check of readers, corruption, methods and metrics on real data.
Uses the bundled clips when the shared data set is absent.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

from ...datasets import bundled, cmu_amc
from ..core import Context, Row, Timer, protocol

CLIPS = ("16_15", "09_06", "07_05")
STEPS = [("gaussian", {"sigma_cm": 2.0}),
         ("outliers", {"ratio": 0.05, "mode": "spike", "magnitude_cm": 15.0}),
         ("missing", {"ratio": 0.10})]
METHODS = ("gaussian", "spline")


def _clip_paths(ctx: Context) -> list[Path]:
    paths = []
    for trial in CLIPS:
        p = cmu_amc(trial, ctx.data_dir)
        if p is not None:
            paths.append(p)
    if not paths:
        paths = [bundled("16_15.amc")]
    return paths


@protocol("smoke", "3 CMU clips; Gaussian 2 cm + 5% 15 cm spikes + 10% missing; gaussian vs spline; RMSE cm")
def smoke(ctx: Context) -> Iterator[Row]:
    from ... import corrupt, denoise, io, metrics

    for path in _clip_paths(ctx):
        clean = io.read(path)
        if ctx.quick:
            clean = clean.slice(0, min(clean.n_frames, 300))
        noisy, mask = corrupt.combine(clean, STEPS, seed=ctx.seed)
        cond = "gauss2cm+out5%+miss10%"
        yield Row("smoke", path.stem, cond, "noisy-input", "rmse_observed", "cm",
                  metrics.rmse(clean, noisy, noisy.observed))
        for name in METHODS:
            method = denoise.get(name)
            with Timer() as t:
                est = method.denoise(noisy)
            yield Row("smoke", path.stem, cond, name, "rmse", "cm", metrics.rmse(clean, est),
                      seconds=t.seconds, extra={"frames": clean.n_frames})
            yield Row("smoke", path.stem, cond, name, "rmse_missing", "cm",
                      metrics.rmse(clean, est, ~noisy.observed), seconds=t.seconds)
