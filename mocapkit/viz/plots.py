"""Static figures with matplotlib: trajectories before/after, error per frame, bench charts, GIFs.

Every function writes one file (PNG, SVG or PDF by extension; GIF for animations)
atomically and returns its path. The Agg backend is used, so no display is needed.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import MocapValueError
from ..motion import Motion

_COLORS = ["k", "#d6604d", "#2b7bba", "#1a9850", "#8073ac", "#e08214"]
_AXES = {"x": 0, "y": 1, "z": 2}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | os.PathLike) -> Path:
    from ..io._atomic import atomic_write_path

    p = Path(path)
    fmt = p.suffix.lstrip(".").lower() or "png"
    atomic_write_path(p, lambda tmp: fig.savefig(tmp, dpi=120, format=fmt))
    _plt().close(fig)
    return p


def plot_trajectories(path: str | os.PathLike, motions: Sequence[Motion], labels: Sequence[str],
                      joints: Sequence[str], axis: str = "y") -> Path:
    """One panel per joint: coordinate ``axis`` (cm) against time (s) for every motion."""
    if axis not in _AXES:
        raise MocapValueError(f"axis must be x, y or z, got {axis!r}")
    plt = _plt()
    fig, axes = plt.subplots(len(joints), 1, figsize=(9, 2.4 * len(joints)), sharex=True, squeeze=False)
    for ax, jn in zip(axes[:, 0], joints):
        for k, (m, lab) in enumerate(zip(motions, labels)):
            j = m.skeleton.index(jn)
            t = np.arange(m.n_frames) / m.fps
            style = dict(lw=1.0) if k != 1 else dict(lw=0, marker=".", ms=2)
            ax.plot(t, m.positions[:, j, _AXES[axis]], color=_COLORS[k % 6], label=lab, **style)
        ax.set_ylabel(f"{jn} {axis} (cm)")
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("time (s)")
    fig.tight_layout()
    return _save(fig, path)


def plot_error(path: str | os.PathLike, truth: Motion, estimates: Sequence[Motion], labels: Sequence[str]) -> Path:
    """Mean joint error (cm) per frame of each estimate against the truth."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 3.2))
    t = np.arange(truth.n_frames) / truth.fps
    for k, (m, lab) in enumerate(zip(estimates, labels)):
        if m.n_frames != truth.n_frames or m.n_joints != truth.n_joints:
            raise MocapValueError(f"{lab}: shape {m.positions.shape} differs from the truth {truth.positions.shape}")
        err = np.nanmean(np.linalg.norm(m.positions - truth.positions, axis=2), axis=1)
        ax.plot(t, err, color=_COLORS[(k + 1) % 6], lw=1, label=f"{lab} (mean {np.nanmean(err):.2f} cm)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("mean joint error (cm)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return _save(fig, path)


def plot_bench(path: str | os.PathLike, rows_json: str | os.PathLike, metric: str | None = None) -> Path:
    """Grouped bar chart of a bench JSON: one group per condition, one bar per method.

    Values are averaged over clips; the paper's value, where given, is drawn as a marker.
    """
    rows = json.loads(Path(rows_json).read_text())
    if not rows:
        raise MocapValueError(f"{rows_json}: no rows")
    metric = metric or rows[0]["metric"]
    rows = [r for r in rows if r["metric"] == metric]
    if not rows:
        raise MocapValueError(f"{rows_json}: no rows with metric {metric!r}")
    conds = list(dict.fromkeys(r["condition"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    val = np.full((len(conds), len(methods)), np.nan)
    pap = np.full_like(val, np.nan)
    for i, c in enumerate(conds):
        for j, m in enumerate(methods):
            sel = [r for r in rows if r["condition"] == c and r["method"] == m]
            if sel:
                val[i, j] = np.mean([r["value"] for r in sel])
                pv = [r["paper_value"] for r in sel if r.get("paper_value") is not None]
                if pv:
                    pap[i, j] = np.mean(pv)
    plt = _plt()
    fig, ax = plt.subplots(figsize=(max(6, 1.2 * len(conds) * max(1, len(methods)) / 3), 4))
    w = 0.8 / len(methods)
    x = np.arange(len(conds))
    for j, m in enumerate(methods):
        ax.bar(x + j * w, val[:, j], w, label=m)
        ok = np.isfinite(pap[:, j])
        if ok.any():
            ax.plot((x + j * w)[ok], pap[ok, j], "k_", ms=12, mew=2)
    ax.set_xticks(x + 0.4 - w / 2, conds, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel(f"{metric} ({rows[0]['unit']})")
    ax.set_title(f"{rows[0]['protocol']}  (black dash: paper)")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    return _save(fig, path)


def animate_gif(path: str | os.PathLike, motions: Sequence[Motion], labels: Sequence[str], *,
                fps: float = 15.0, max_frames: int = 300, elev: float = 15, azim: float = -60) -> Path:
    """Skeleton animation (GIF via Pillow), motions side by side; at most ``max_frames`` frames."""
    plt = _plt()
    from matplotlib.animation import FuncAnimation, PillowWriter

    ref = motions[0]
    step = max(1, int(round(ref.fps / fps)))
    idx = np.arange(0, ref.n_frames, step)[:max_frames]
    allp = np.concatenate([m.positions[idx].reshape(-1, 3) for m in motions])
    lo, hi = np.nanmin(allp, axis=0), np.nanmax(allp, axis=0)
    c, r = (lo + hi) / 2, np.nanmax(hi - lo) / 2
    fig = plt.figure(figsize=(3.2 * len(motions), 3.6))
    axes, lines = [], []
    for k, (m, lab) in enumerate(zip(motions, labels)):
        ax = fig.add_subplot(1, len(motions), k + 1, projection="3d")
        ax.set_title(lab, fontsize=9)
        # data Y is up: plot (x, z, y)
        ax.set_xlim(c[0] - r, c[0] + r); ax.set_ylim(c[2] - r, c[2] + r); ax.set_zlim(c[1] - r, c[1] + r)
        ax.view_init(elev, azim); ax.set_axis_off()
        ls = [ax.plot([], [], [], color=_COLORS[k % 6] if k else "#333", lw=1.5)[0] for _ in m.skeleton.bones()]
        axes.append(ax); lines.append(ls)

    def update(fi: int):
        for m, ls in zip(motions, lines):
            P = m.positions[idx[fi]]
            for ln, (a, b) in zip(ls, m.skeleton.bones()):
                ln.set_data_3d([P[a, 0], P[b, 0]], [P[a, 2], P[b, 2]], [P[a, 1], P[b, 1]])
        return [ln for ls in lines for ln in ls]

    anim = FuncAnimation(fig, update, frames=len(idx), blit=False)
    from ..io._atomic import atomic_write_path

    atomic_write_path(path, lambda tmp: anim.save(tmp, writer=PillowWriter(fps=fps)), suffix=".gif")
    plt.close(fig)
    return Path(path)
