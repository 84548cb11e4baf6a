"""Real occlusion masks: transplant the missing-sample pattern of one capture onto another.

Synthetic corruption (random missing entries, random blocks) is easy to fill; real
optical occlusions are not: a marker hidden behind the body disappears for seconds,
several markers of one segment vanish together, gaps touch the start or end of the
take, and some frames lose every marker. To measure fills on such patterns *with known
truth*, the observed/missing mask of a capture that has real gaps (the *source*) is laid
over a gap-free capture (the *target*) by :func:`transplant_mask`:

1. **Time.** The source mask is resampled so that its duration in seconds maps onto the
   target's frame rate: target-rate frame ``i`` (time ``i / fps_target``) takes the
   nearest source frame ``round(i * fps_source / fps_target)`` (:func:`resample_mask`).
   A 30 s source at 120 Hz becomes 1,500 frames at 50 Hz; gap lengths in seconds are kept.
2. **One time offset** ``o`` (seeded) is drawn per case: the target's ``T`` frames take
   source frames ``o .. o + T - 1`` of the resampled mask, or, when the resampled source
   is shorter than the target, ``(o + i) mod T_source`` (the mask wraps around). All
   markers share the offset, so markers that were occluded together stay occluded
   together (co-missing structure, edge gaps and whole-frame drop-outs are kept).
3. **Columns.** Source marker columns are assigned to target markers by a seeded random
   permutation. When the target has more markers than the source, the source columns
   are used again, in blocks of ``J_source`` target markers: block ``b`` takes another
   seeded permutation and another seeded time offset (a second, independent copy of the
   source's occlusion pattern; inside a block the co-missing structure is intact).
4. **No invented black-outs.** A target frame may have every marker missing only if the
   source frames it was drawn from (in every block) have every marker missing. When the
   column subset would black out a frame the source did not (target with fewer markers
   than the source), one seeded target marker of that frame is kept observed.

Everything is deterministic given ``seed`` (``numpy.random.default_rng``). Masks are
bool arrays ``(T, J)`` with True = observed, as :attr:`mocapkit.motion.Motion.observed`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import MocapValueError
from .motion import Motion


def resample_mask(observed: np.ndarray, fps_source: float, fps_target: float) -> np.ndarray:
    """Nearest-frame resampling of a (T, J) observed mask from ``fps_source`` to ``fps_target``.

    The output has ``max(1, round(T * fps_target / fps_source))`` frames (same duration in
    seconds); output frame ``i`` copies source frame ``round(i * fps_source / fps_target)``
    (clipped to ``T - 1``).
    """
    observed = np.asarray(observed, dtype=bool)
    if observed.ndim != 2 or observed.shape[0] == 0:
        raise MocapValueError(f"mask must have shape (T, J) with T >= 1, got {observed.shape}")
    fps_source, fps_target = float(fps_source), float(fps_target)
    if not (fps_source > 0 and fps_target > 0):
        raise MocapValueError(f"frame rates must be positive, got {fps_source}, {fps_target}")
    T = observed.shape[0]
    n = max(1, int(round(T * fps_target / fps_source)))
    idx = np.clip(np.rint(np.arange(n) * fps_source / fps_target).astype(int), 0, T - 1)
    return observed[idx]


@dataclass
class Transplant:
    """A transplanted mask and how it was made.

    ``observed``: (T, J) bool, True = observed. ``offsets``: time offset (frames at the
    target rate) of each column block; ``columns``: (J,) source column used by each
    target marker; ``blocks``: (J,) block of each target marker; ``wrapped``: whether the
    resampled source was shorter than the target; ``kept_visible``: number of frames
    where one marker was kept observed to avoid a black-out the source did not have.
    """

    observed: np.ndarray
    offsets: list[int]
    columns: np.ndarray
    blocks: np.ndarray
    wrapped: bool
    source_frames: int
    kept_visible: int = 0
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def missing_fraction(self) -> float:
        return float(1.0 - self.observed.mean())


def transplant_mask(source_observed: np.ndarray, source_fps: float, n_frames: int,
                    n_markers: int, target_fps: float, seed: int = 0) -> Transplant:
    """Lay a real (T_s, J_s) observed mask over a target of ``n_frames`` x ``n_markers``.

    See the module docstring for the protocol (time resampling, one offset per block of
    markers, seeded column permutation, no invented black-outs).

    Parameters
    ----------
    source_observed : (T_s, J_s) bool, True = observed (the source capture's mask).
    source_fps, target_fps : frame rates (Hz).
    n_frames, n_markers : target shape.
    seed : integer seed; the result is a pure function of the inputs.

    Returns
    -------
    :class:`Transplant` with ``observed`` of shape (n_frames, n_markers).
    """
    if n_frames < 1 or n_markers < 1:
        raise MocapValueError(f"target needs >= 1 frame and marker, got {n_frames} x {n_markers}")
    R = resample_mask(source_observed, source_fps, target_fps)          # (Ts, Js)
    Ts, Js = R.shape
    rng = np.random.default_rng(seed)
    n_blocks = -(-n_markers // Js)
    wrapped = Ts < n_frames
    offsets, windows = [], []
    for _ in range(n_blocks):
        if wrapped:
            o = int(rng.integers(0, Ts))
            rows = (o + np.arange(n_frames)) % Ts
        else:
            o = int(rng.integers(0, Ts - n_frames + 1))
            rows = o + np.arange(n_frames)
        offsets.append(o)
        windows.append(R[rows])                                           # (T, Js)
    # target markers in a random order take block 0's permuted columns, then block 1's ...
    order = rng.permutation(n_markers)
    cols_all = np.concatenate([rng.permutation(Js) for _ in range(n_blocks)])[:n_markers]
    blocks_all = np.repeat(np.arange(n_blocks), Js)[:n_markers]
    columns = np.empty(n_markers, dtype=int)
    blocks = np.empty(n_markers, dtype=int)
    columns[order] = cols_all
    blocks[order] = blocks_all
    W = np.stack(windows)                                                 # (B, T, Js)
    obs = W[blocks, :, columns].T.copy()                                  # (T, J)
    # a black-out only where every block's source frame was a black-out
    src_blackout = (~W).all(axis=2).all(axis=0)                           # (T,)
    bad = np.flatnonzero(~obs.any(axis=1) & ~src_blackout)
    if len(bad):
        obs[bad, rng.integers(0, n_markers, size=len(bad))] = True
    return Transplant(obs, offsets, columns, blocks, wrapped, Ts, int(len(bad)))


def apply_mask(motion: Motion, observed: np.ndarray) -> Motion:
    """``motion`` with entries hidden where ``observed`` is False (and where already missing)."""
    observed = np.asarray(observed, dtype=bool)
    if observed.shape != motion.observed.shape:
        raise MocapValueError(
            f"mask shape {observed.shape} does not match the motion's {motion.observed.shape}")
    return motion.with_observed(motion.observed & observed)


def fully_observed_markers(motion: Motion) -> Motion:
    """``motion`` restricted to the markers observed in every frame (truth for a benchmark)."""
    keep = [n for n, ok in zip(motion.skeleton.names, motion.observed.all(axis=0)) if ok]
    if not keep:
        raise MocapValueError("no marker is observed in every frame")
    if len(keep) == motion.n_joints:
        return motion
    return motion.select(keep)


def drop_duplicate_markers(motion: Motion, tol_cm: float = 1e-6) -> tuple[Motion, list[str]]:
    """Drop markers whose trajectory is an exact copy of another marker's.

    A copy hands the truth to any fill that looks at other markers (HDM05's unlabelled
    ``*0``-``*2`` duplicate LFWT, CLAV and LFHD). Labelled names are kept in preference to
    unlabelled ones (names starting with ``*``). Returns the motion and the dropped names.
    """
    names = motion.skeleton.names
    order = sorted(range(len(names)), key=lambda j: (names[j].startswith("*"), j))
    P = motion.positions
    kept: list[int] = []
    dropped: list[str] = []
    for j in order:
        both = motion.observed[:, j][:, None] & motion.observed[:, kept]          # (T, K)
        diff = np.abs(P[:, [j]] - P[:, kept]).max(axis=2) if kept else np.zeros((len(P), 0))
        same = [k for i, k in enumerate(kept) if both[:, i].any()
                and np.all(np.where(both[:, i], diff[:, i], 0.0) <= tol_cm)
                and np.array_equal(motion.observed[:, j], motion.observed[:, k])]
        if same:
            dropped.append(names[j])
        else:
            kept.append(j)
    if not dropped:
        return motion, []
    return motion.select([names[j] for j in sorted(kept)]), dropped
