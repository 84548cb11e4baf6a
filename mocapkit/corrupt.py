"""Controlled, seeded corruption of clean motions (for experiments and benchmarks).

Every function takes a :class:`~mocapkit.motion.Motion` and a ``seed`` (an ``int``, a
``numpy.random.Generator`` or a ``numpy.random.SeedSequence``; there is no default, so
every experiment is reproducible) and returns ``(corrupted, mask)``:

* ``corrupted`` is a new Motion (same skeleton, fps and source metadata; the source
  gets a ``"corruption"`` list describing the steps). The input is never modified.
* ``mask`` is a bool array (T, J) of the **joint entries** that were corrupted: entry
  (t, j) is True when at least one coordinate of joint j in frame t was changed or
  removed by this call. Entries that were already missing in the input are never
  marked (nothing can be done to them) and stay missing.

Units: positions are in cm, so ``sigma_cm`` / ``magnitude_cm`` are in cm. A motion
that was rescaled to another unit (e.g. CMU ASF units, 1 unit = 5.6444 cm) is
corrupted in *its* units: the numbers are applied to the stored coordinates as they are.

Corruptions
-----------
:func:`gaussian`
    iid Gaussian noise per coordinate, by ``sigma_cm`` or by ``snr_db`` (SNR definition
    below).
:func:`outliers`
    a ratio of joint (or coordinate) entries made outliers: ``'scale'`` is Xiao et al.
    2015's rule (entries multiplied by 1.4 in the root-centred frame), ``'spike'`` adds a
    spike of fixed length in a random direction.
:func:`missing`
    random missing markers, ``round(ratio * J)`` per frame (thesis protocol) or a ratio
    of all entries.
:func:`block_gaps`
    ``n_markers`` markers missing for ``length`` consecutive frames (thesis "continuous
    missing"), or whole joints for the whole clip (Lou & Chai's both-arms case).
:func:`label_swaps`
    pairs of nearby markers that trade labels for a stretch of frames (an optical
    labeller's error; :mod:`mocapkit.swaps` puts them back).
:func:`label_jumps`
    a label that takes a neighbour's marker while its own is hidden, the neighbour's label
    missing meanwhile (:func:`mocapkit.swaps.repair_swaps` puts it back).
:func:`slra_noise`
    the SLRA paper's partial-frame noise (seed 004, eq. 7).
:func:`combine` / :func:`parse_spec`
    several steps in order with derived seeds; union of the masks.

SNR definition (used by :func:`gaussian`)
-----------------------------------------
The signal is the **root-relative** position of every non-root joint,
``s = p_j - p_root`` (cm), so the global trajectory (which would make any walk look
"loud") does not count. Its power per coordinate is::

    P_signal = mean over observed (t, j != root, axis) of (p_j[t] - p_root[t])**2

(frames whose root is missing are skipped). Noise of standard deviation ``sigma`` per
coordinate has power ``sigma**2``, and ``SNR_dB = 10 log10(P_signal / sigma**2)``; hence
``sigma = sqrt(P_signal / 10**(SNR_dB / 10))``. For a CMU walk P_signal is about
(35 cm)**2, so 20 dB is about 3.5 cm and 40 dB about 0.35 cm.
"""
from __future__ import annotations

import inspect
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from .errors import MocapValueError
from .motion import Motion

__all__ = ["gaussian", "outliers", "missing", "block_gaps", "label_swaps", "label_jumps", "slra_noise", "combine",
           "parse_spec", "signal_power", "snr_to_sigma", "STEPS"]

# ----------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------
def _rng(seed: Any) -> np.random.Generator:
    """A Generator from an int / Generator / SeedSequence (no implicit entropy)."""
    if isinstance(seed, np.random.Generator):
        return seed
    if isinstance(seed, np.random.SeedSequence):
        return np.random.default_rng(seed)
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise MocapValueError(
            f"seed must be a non-negative int or a numpy Generator, got {seed!r}")
    if seed < 0:
        raise MocapValueError(f"seed must be a non-negative int, got {seed}")
    return np.random.default_rng(int(seed))


def _check_motion(motion: Any) -> Motion:
    if not isinstance(motion, Motion):
        raise MocapValueError(f"expected a Motion, got {type(motion).__name__}")
    return motion


def _ratio(value: Any, name: str = "ratio") -> float:
    try:
        r = float(value)
    except (TypeError, ValueError):
        raise MocapValueError(f"{name} must be a number between 0 and 1, got {value!r}") from None
    if not np.isfinite(r) or r < 0 or r > 1:
        raise MocapValueError(f"{name} must be between 0 and 1, got {value!r}")
    return r


def _nonneg(value: Any, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise MocapValueError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(v) or v < 0:
        raise MocapValueError(f"{name} must be a finite number >= 0, got {value!r}")
    return v


def _root(motion: Motion) -> int:
    """Index of the skeleton root (the first joint without a parent)."""
    return int(np.flatnonzero(motion.skeleton.parents < 0)[0])


def _joint_indices(motion: Motion, joints: Iterable[str | int] | str | int | None) -> np.ndarray:
    """Joint indices from names and/or integer indices (None: every joint)."""
    J = motion.n_joints
    if joints is None:
        return np.arange(J)
    if isinstance(joints, (str, int, np.integer)):
        joints = [joints]
    out = []
    for j in joints:
        if isinstance(j, (int, np.integer)) and not isinstance(j, bool):
            if not -J <= int(j) < J:
                raise MocapValueError(f"joint index {j} out of range for {J} joints")
            out.append(int(j) % J)
        elif isinstance(j, str):
            out.append(motion.skeleton.index(j))
        else:
            raise MocapValueError(f"joints must be names or indices, got {j!r}")
    if not out:
        raise MocapValueError("joints= selects no joint")
    return np.unique(np.asarray(out, dtype=int))


def _frame_mask(motion: Motion, frames: Any) -> np.ndarray:
    """Bool (T,) from None (all), a slice, a bool mask (T,) or frame indices."""
    T = motion.n_frames
    if frames is None:
        return np.ones(T, dtype=bool)
    sel = np.zeros(T, dtype=bool)
    if isinstance(frames, slice):
        sel[frames] = True
        return sel
    f = np.asarray(frames)
    if f.dtype == bool:
        if f.shape != (T,):
            raise MocapValueError(f"frames mask must have shape ({T},), got {f.shape}")
        return f.copy()
    if f.size and not np.issubdtype(f.dtype, np.integer):
        raise MocapValueError("frames= must be a slice, a bool mask or integer frame indices")
    f = f.reshape(-1).astype(int)
    if f.size and (f.min() < -T or f.max() >= T):
        raise MocapValueError(f"frame index out of range for a {T}-frame motion")
    sel[f] = True
    return sel


def _choose(rng: np.random.Generator, candidates: np.ndarray, ratio: float) -> np.ndarray:
    """Bool array like ``candidates`` with round(ratio * candidates.sum()) of them True."""
    flat = np.flatnonzero(candidates.reshape(-1))
    k = int(round(ratio * flat.size))
    out = np.zeros(candidates.size, dtype=bool)
    if k:
        out[rng.choice(flat, size=k, replace=False)] = True
    return out.reshape(candidates.shape)


def _result(motion: Motion, positions: np.ndarray, observed: np.ndarray, step: dict) -> Motion:
    src = dict(motion.source)
    src["corruption"] = list(src.get("corruption", [])) + [step]
    return Motion(positions, motion.skeleton, motion.fps, observed, src)


def _unit_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    """n uniformly distributed unit vectors in 3-D (normalised Gaussians)."""
    v = rng.standard_normal((n, 3))
    nrm = np.linalg.norm(v, axis=1, keepdims=True)
    bad = nrm[:, 0] < 1e-12
    v[bad] = (1.0, 0.0, 0.0)
    nrm[bad] = 1.0
    return v / nrm


# ----------------------------------------------------------------------------------------
# SNR
# ----------------------------------------------------------------------------------------
def signal_power(motion: Motion) -> float:
    """Signal power per coordinate, cm², of the root-relative joint positions.

    ``P = mean over observed (t, j != root, axis) of (p_j[t] - p_root[t])**2``; frames
    whose root is missing are skipped (see the module docstring).

    Raises
    ------
    MocapValueError
        if the motion has a single joint or no frame with both the root and another
        joint observed.
    """
    motion = _check_motion(motion)
    r = _root(motion)
    P = motion.positions
    rel = P - P[:, r:r + 1]                                   # (T, J, 3), NaN where missing
    use = motion.observed & motion.observed[:, r:r + 1]
    use[:, r] = False
    if not use.any():
        raise MocapValueError(
            "cannot compute the signal power: no observed non-root joint in a frame whose root "
            "is observed (SNR needs root-relative positions)")
    return float(np.mean(rel[use] ** 2))


def snr_to_sigma(motion: Motion, snr_db: float) -> float:
    """Noise standard deviation (cm per coordinate) giving ``snr_db`` on this motion."""
    try:
        snr = float(snr_db)
    except (TypeError, ValueError):
        raise MocapValueError(f"snr_db must be a number, got {snr_db!r}") from None
    if not np.isfinite(snr):
        raise MocapValueError(f"snr_db must be finite, got {snr_db!r}")
    return float(np.sqrt(signal_power(motion) / 10.0 ** (snr / 10.0)))


# ----------------------------------------------------------------------------------------
# corruptions
# ----------------------------------------------------------------------------------------
def gaussian(motion: Motion, /, *, sigma_cm: float | None = None, snr_db: float | None = None,
             seed: Any, frames: Any = None, joints: Any = None) -> tuple[Motion, np.ndarray]:
    """Add iid Gaussian noise N(0, sigma²) to every coordinate of the selected entries.

    Parameters
    ----------
    motion : Motion (T, J), cm.
    sigma_cm : noise standard deviation per coordinate, cm (motion units).
    snr_db : alternatively the signal-to-noise ratio in dB; ``sigma`` is derived from the
        root-relative signal power of the whole motion (module docstring, "SNR
        definition"). Give exactly one of ``sigma_cm`` / ``snr_db``.
    seed : int, Generator or SeedSequence.
    frames : optional restriction: a slice, a bool mask (T,) or frame indices.
    joints : optional restriction: joint names and/or indices.

    Returns
    -------
    (Motion, mask) : mask (T, J) bool, True on every observed entry that got noise (the
        selected frames x joints; all observed entries without restrictions).
    """
    motion = _check_motion(motion)
    if (sigma_cm is None) == (snr_db is None):
        raise MocapValueError("gaussian noise needs exactly one of sigma_cm= or snr_db=")
    sigma = _nonneg(sigma_cm, "sigma_cm") if sigma_cm is not None else snr_to_sigma(motion, snr_db)
    rng = _rng(seed)
    sel = np.zeros(motion.observed.shape, dtype=bool)
    sel[np.ix_(_frame_mask(motion, frames), np.isin(np.arange(motion.n_joints),
                                                     _joint_indices(motion, joints)))] = True
    mask = sel & motion.observed
    noise = rng.standard_normal(motion.positions.shape) * sigma
    P = np.where(mask[..., None], motion.positions + noise, motion.positions)
    step = {"step": "gaussian", "sigma_cm": sigma}
    if snr_db is not None:
        step["snr_db"] = float(snr_db)
    if sigma == 0:
        mask = np.zeros_like(mask)
    return _result(motion, P, motion.observed, step), mask


def outliers(motion: Motion, /, *, ratio: float, mode: str = "spike", magnitude_cm: float | None = 15.0,
             factor: float = 1.4, seed: Any, entries: str = "joint") -> tuple[Motion, np.ndarray]:
    """Turn a ratio of the entries into outliers.

    Parameters
    ----------
    motion : Motion (T, J), cm.
    ratio : fraction (0-1) of the *eligible* entries made outliers; exactly
        ``round(ratio * n_eligible)`` are chosen uniformly without replacement. Eligible:
        observed entries (``T*J`` for a complete motion); in ``'scale'`` mode also
        excluding the root joint, frames whose root is missing and entries that coincide
        with the root (the rule leaves those unchanged).
    mode : ``'spike'`` (default): add a vector of length ``magnitude_cm`` in a uniformly
        random direction to each selected joint position. ``'scale'``: Xiao et al. 2015
        (seed 000, Sec. 5: "outliers are generated by multiplying 1.4 to the selected
        entries"), applied in the root-centred frame (METHODS.md decision):
        ``p <- p_root + factor * (p - p_root)``. A uniform scaling about the root is the
        same in any rotated body frame, so this equals Xiao's local-frame rule.
    magnitude_cm : spike length in cm (``'spike'`` only; None means 15).
    factor : scale factor (``'scale'`` only), 1.4 in Xiao et al.
    seed : int, Generator or SeedSequence.
    entries : ``'joint'`` (default): an entry is a joint position (T*J entries).
        ``'coordinate'``: an entry is one coordinate of the (T, 3J) matrix (Xiao's
        literal "entries of the motion data matrix"): ``'scale'`` scales the selected
        root-relative coordinate along the motion's own axes, ``'spike'`` adds
        ``±magnitude_cm`` to it.

    Returns
    -------
    (Motion, mask) : mask (T, J) bool, True on joints with a changed coordinate.
    """
    motion = _check_motion(motion)
    ratio = _ratio(ratio)
    if mode not in ("spike", "scale"):
        raise MocapValueError(f"outlier mode must be 'spike' or 'scale', got {mode!r}")
    if entries not in ("joint", "coordinate"):
        raise MocapValueError(f"entries must be 'joint' or 'coordinate', got {entries!r}")
    rng = _rng(seed)
    P = np.array(motion.positions)
    obs = motion.observed
    T, J, _ = P.shape
    if mode == "scale":
        factor = float(factor)
        if not np.isfinite(factor):
            raise MocapValueError(f"factor must be finite, got {factor!r}")
        r = _root(motion)
        rel = P - P[:, r:r + 1]                                   # (T, J, 3)
        base = obs & obs[:, r:r + 1]
        base[:, r] = False
        if entries == "joint":
            cand = base & (np.linalg.norm(np.nan_to_num(rel), axis=2) > 1e-9)
            sel = _choose(rng, cand, ratio)
            P[sel] = P[:, r:r + 1].repeat(J, axis=1)[sel] + factor * rel[sel]
            mask = sel
        else:
            cand = base[..., None] & (np.abs(np.nan_to_num(rel)) > 1e-9)
            sel = _choose(rng, cand, ratio)                       # (T, J, 3)
            root = np.broadcast_to(P[:, r:r + 1], P.shape)
            P[sel] = root[sel] + factor * rel[sel]
            mask = sel.any(axis=2)
        step = {"step": "outliers", "mode": "scale", "ratio": ratio, "factor": factor,
                "entries": entries}
    else:
        mag = 15.0 if magnitude_cm is None else _nonneg(magnitude_cm, "magnitude_cm")
        if entries == "joint":
            sel = _choose(rng, obs, ratio)
            P[sel] += mag * _unit_vectors(rng, int(sel.sum()))
            mask = sel
        else:
            sel = _choose(rng, np.repeat(obs[..., None], 3, axis=2), ratio)
            P[sel] += mag * rng.choice(np.array([-1.0, 1.0]), size=int(sel.sum()))
            mask = sel.any(axis=2)
        if mag == 0:
            mask = np.zeros_like(mask)
        step = {"step": "outliers", "mode": "spike", "ratio": ratio, "magnitude_cm": mag,
                "entries": entries}
    return _result(motion, P, obs, step), mask


def missing(motion: Motion, /, *, ratio: float, per_frame: bool = True, seed: Any) -> tuple[Motion, np.ndarray]:
    """Remove random markers (set ``observed`` False; the Motion then holds NaN there).

    Parameters
    ----------
    motion : Motion (T, J).
    ratio : with ``per_frame=True`` (default; thesis seed 003 Ch. 4.2 protocol, "randomly
        removing mr markers from each frame"), ``round(ratio * J)`` markers are removed in
        every frame, chosen independently per frame among the markers still observed
        there (fewer if fewer are observed). With ``per_frame=False``,
        ``round(ratio * n_observed)`` entries are removed uniformly among all observed
        (frame, joint) entries.
    seed : int, Generator or SeedSequence.

    Returns
    -------
    (Motion, mask) : mask (T, J) bool, True where a marker was removed by this call.
    """
    motion = _check_motion(motion)
    ratio = _ratio(ratio)
    rng = _rng(seed)
    obs = motion.observed
    T, J = obs.shape
    if per_frame:
        k = int(round(ratio * J))
        keys = rng.random((T, J)) + np.where(obs, 0.0, 2.0)    # observed markers first
        order = np.argsort(keys, axis=1)[:, :k]
        sel = np.zeros((T, J), dtype=bool)
        np.put_along_axis(sel, order, True, axis=1)
        sel &= obs
    else:
        sel = _choose(rng, obs, ratio)
    step = {"step": "missing", "ratio": ratio, "per_frame": bool(per_frame)}
    return _result(motion, motion.positions, obs & ~sel, step), sel


def block_gaps(motion: Motion, /, *, n_markers: int | None = None, length: int | None, n_blocks: int = 1,
               seed: Any, joints: Any = None) -> tuple[Motion, np.ndarray]:
    """Remove blocks of ``n_markers`` markers x ``length`` consecutive frames.

    Thesis (seed 003, Ch. 4.2) "continuously missing data": 10 randomly selected markers
    missing for ``ml`` = 20-60 consecutive frames. Each block is a rectangle: one random
    start frame (uniform in ``[0, T - length]``) shared by its ``n_markers`` distinct
    random markers. Blocks are drawn independently and may overlap.

    Parameters
    ----------
    motion : Motion (T, J).
    n_markers : markers per block (default: every joint in ``joints``).
    length : frames per block, ``1 <= length <= T``; ``None`` means the whole clip
        (start 0). With ``joints=`` names this removes whole joints for the whole clip,
        e.g. both arms as in Lou & Chai 2010 (seed 001, Fig. 6)::

            arms = [sk.names[j] for j in sk.body_parts()["left_arm"][1:] + sk.body_parts()["right_arm"][1:]]
            block_gaps(m, joints=arms, length=None, seed=0)
    n_blocks : number of blocks.
    seed : int, Generator or SeedSequence.
    joints : candidate joints (names and/or indices); default all.

    Returns
    -------
    (Motion, mask) : mask (T, J) bool, True where an observed marker was removed.
    """
    motion = _check_motion(motion)
    rng = _rng(seed)
    T, J = motion.observed.shape
    cand = _joint_indices(motion, joints)
    if n_markers is None:
        n_markers = len(cand)
    try:
        n_markers, n_blocks = int(n_markers), int(n_blocks)
    except (TypeError, ValueError):
        raise MocapValueError("n_markers and n_blocks must be integers") from None
    if not 1 <= n_markers <= len(cand):
        raise MocapValueError(
            f"n_markers must be between 1 and the number of candidate joints ({len(cand)}), got {n_markers}")
    if n_blocks < 1:
        raise MocapValueError(f"n_blocks must be >= 1, got {n_blocks}")
    L = T if length is None else int(length)
    if not 1 <= L <= T:
        raise MocapValueError(f"gap length must be between 1 and the clip length ({T} frames), got {length}")
    starts = rng.integers(0, T - L + 1, size=n_blocks)                    # (B,)
    markers = cand[np.argsort(rng.random((n_blocks, len(cand))), axis=1)[:, :n_markers]]  # (B, n)
    frames = starts[:, None] + np.arange(L)                               # (B, L)
    sel = np.zeros((T, J), dtype=bool)
    sel[frames[:, :, None], markers[:, None, :]] = True
    sel &= motion.observed
    step = {"step": "block_gaps", "n_markers": n_markers, "length": L, "n_blocks": n_blocks}
    return _result(motion, motion.positions, motion.observed & ~sel, step), sel


def _label_args(n: Any, length: Any, what: str, T: int, J: int, longest: int) -> tuple[int, int]:
    """``n`` and ``length`` of :func:`label_swaps` / :func:`label_jumps` as ints, checked
    (``what``: 'swap' or 'jump'; ``longest``: the longest stretch the clip allows)."""
    try:
        n, L = int(n), int(length)
    except (TypeError, ValueError):
        raise MocapValueError(f"n_{what}s and length must be integers") from None
    if n < 1:
        raise MocapValueError(f"n_{what}s must be >= 1, got {n}")
    if not 1 <= L <= longest:
        raise MocapValueError(f"{what} length must be between 1 and {longest} frames (the clip has {T}), "
                              f"got {length}")
    if J < 2:
        raise MocapValueError(f"a label {what} needs at least two markers")
    return n, L


def label_swaps(motion: Motion, /, *, n_swaps: int = 1, length: int = 30, max_distance_cm: float | None = 15.0,
                at_gaps: bool = False, seed: Any) -> tuple[Motion, np.ndarray]:
    """Swap the labels of ``n_swaps`` pairs of markers for ``length`` consecutive frames.

    An optical labeller's typical error (:mod:`mocapkit.swaps`): for each swap a start
    frame is drawn (uniform in ``[0, T - length]``) and a marker, and it trades
    trajectories with the marker nearest to it at that frame -- within
    ``max_distance_cm`` (None: any distance; the swap is skipped where none is that near)
    -- for ``length`` frames. Pairs are drawn independently; a swap that would touch a
    marker already swapped in any of its frames is skipped. Both markers must be observed
    throughout. ``at_gaps``: each swap starts where a marker reappears after a gap (the
    labeller's most common moment: it gives the reappearing marker its neighbour's label),
    drawn among the gap ends with ``length`` observed frames after them, the other marker
    observed for the two frames before too.

    Returns
    -------
    (Motion, mask) : mask (T, J) bool, True on the samples now carrying the other
        marker's trajectory.

    >>> from mocapkit import datasets, io
    >>> clip = io.read(datasets.bundled("16_15.amc"))
    >>> swapped, mask = label_swaps(clip, n_swaps=2, length=20, seed=0)
    >>> int(mask.sum()), int(mask.any(axis=0).sum())
    (80, 4)
    """
    motion = _check_motion(motion)
    rng = _rng(seed)
    P, obs = motion.positions, motion.observed
    T, J = obs.shape
    n_swaps, L = _label_args(n_swaps, length, "swap", T, J, T)
    Q = np.array(P)
    sel = np.zeros((T, J), dtype=bool)
    ends = np.argwhere(obs[1:] & ~obs[:-1]) + [1, 0] if at_gaps else None     # (t, a) reappearing
    if ends is not None:
        ends = ends[ends[:, 0] <= T - L]
    for _ in range(n_swaps):
        if ends is None:
            t0, a = int(rng.integers(0, T - L + 1)), int(rng.integers(0, J))
        elif len(ends):
            t0, a = (int(x) for x in ends[int(rng.integers(0, len(ends)))])
        else:
            break
        span = slice(t0, t0 + L)
        ok = obs[span].all(axis=0) & ~sel[span].any(axis=0)
        if ends is not None:
            ok &= obs[max(t0 - 2, 0):t0].all(axis=0) & (t0 >= 2)
        ok[a] = False
        if not obs[span, a].all() or sel[span, a].any() or not ok.any():
            continue
        d = np.linalg.norm(P[t0] - P[t0, a], axis=1)
        d[~ok] = np.inf
        b = int(np.argmin(d))
        if max_distance_cm is not None and d[b] > float(max_distance_cm):
            continue
        Q[span, a], Q[span, b] = P[span, b], P[span, a]
        sel[span, [a, b]] = True
    step = {"step": "label_swaps", "n_swaps": n_swaps, "length": L, "max_distance_cm": max_distance_cm,
            "at_gaps": bool(at_gaps)}
    return _result(motion, Q, obs, step), sel


def label_jumps(motion: Motion, /, *, n_jumps: int = 1, length: int = 30, max_distance_cm: float | None = 15.0,
                seed: Any) -> tuple[Motion, np.ndarray]:
    """A label that takes its neighbour's marker for ``length`` frames while its own is hidden.

    An optical labeller's other typical error (:func:`mocapkit.swaps.repair_swaps`): marker
    ``a`` is hidden, and its label goes to the marker ``b`` nearest to it (within
    ``max_distance_cm``; None: any distance), still seen; ``b``'s own label is missing
    meanwhile. For each jump a start frame (uniform in ``[2, T - length - 1]``) and a
    marker ``a`` are drawn; over the ``length`` frames ``a`` carries ``b``'s samples and
    ``b`` is missing; ``a``'s own samples are lost, as the hidden marker's are. Both markers
    must be observed from two frames before to one frame after the stretch, and no other
    jump may touch them there; a jump that cannot be placed is skipped.

    Returns
    -------
    (Motion, mask) : mask (T, J) bool, True on the samples now carrying the other
        marker's trajectory (the missing ones are in the Motion's ``observed``).

    >>> from mocapkit import datasets, io
    >>> clip = io.read(datasets.bundled("16_15.amc"))
    >>> jumped, mask = label_jumps(clip, n_jumps=2, length=20, seed=0)
    >>> int(mask.sum()), int((~jumped.observed).sum())
    (40, 40)
    """
    motion = _check_motion(motion)
    rng = _rng(seed)
    P, obs = motion.positions, motion.observed
    T, J = obs.shape
    n_jumps, L = _label_args(n_jumps, length, "jump", T, J, T - 3)
    Q, O = np.array(P), np.array(obs)
    sel = np.zeros((T, J), dtype=bool)
    for _ in range(n_jumps):
        t0, a = int(rng.integers(2, T - L)), int(rng.integers(0, J))
        around = slice(t0 - 2, t0 + L + 1)
        ok = obs[around].all(axis=0) & ~sel[around].any(axis=0)
        if not ok[a]:
            continue
        ok[a] = False
        d = np.linalg.norm(P[t0] - P[t0, a], axis=1)
        d[~ok] = np.inf
        b = int(np.argmin(d))
        if not np.isfinite(d[b]) or (max_distance_cm is not None and d[b] > float(max_distance_cm)):
            continue
        span = slice(t0, t0 + L)
        Q[span, a], Q[span, b], O[span, b] = P[span, b], np.nan, False
        sel[around, b] = True                      # (no other jump touches the pair there)
        sel[around, a] = True
    mask = sel & O & (Q != np.asarray(P)).any(axis=2)
    step = {"step": "label_jumps", "n_jumps": n_jumps, "length": L, "max_distance_cm": max_distance_cm}
    return _result(motion, Q, O, step), mask


def slra_noise(motion: Motion, /, *, n_frames: int, mean: float = 1.0, sigma: float = 1.2,
               seed: Any, scale: float | None = None, eps: float | None = None) -> tuple[Motion, np.ndarray]:
    """SLRA partial-frame noise, Peng et al. (seed 004), Sec. 4.1, eq. (7).

    Literally: pick ``p = n_frames`` distinct random frames; draw ``G`` (p x 3J) from a
    Gaussian with mean ε and standard deviation σ and ``Γ`` (p x 3J) uniform on [0, 1];
    the noisy frames are ``X_p + G * (1 - ((Γ - 0.5) > 0))``, i.e. each *coordinate* of
    a selected frame gets its noise independently with probability 1/2 (a random half in
    expectation, not exactly half). The other frames are unchanged.

    The paper writes "ε 均值、σ 方差" (mean ε, *variance* σ) but uses the symbol σ; we
    read σ as the standard deviation (MATLAB ``normrnd(ε, σ)`` convention). Pass
    ``sigma=sqrt(1.2)`` for the variance reading.

    Units: the protocol ran on CMU data in ASF units (1 unit = 5.6444 cm) with ε=1,
    σ=1.2. The noise is added in the **motion's units** (cm for a Motion from a reader);
    ``scale`` multiplies it (motion units per noise unit), so
    ``slra_noise(m_cm, n_frames=400, scale=5.6444, seed=0)`` applies the paper's noise
    in ASF units to a motion in cm; alternatively divide the positions by 5.6444 first.

    Parameters
    ----------
    motion : Motion (T, J).
    n_frames : number of noisy frames p (0 <= p <= T).
    mean : ε, default 1.0 (``eps=`` is an accepted alias, as in the paper's notation).
    sigma : σ (standard deviation), default 1.2.
    seed : int, Generator or SeedSequence.
    scale : optional factor applied to the noise (see Units).

    Returns
    -------
    (Motion, mask) : mask (T, J) bool, True on observed joints with at least one noisy
        coordinate (so only the ``n_frames`` selected frames have True entries).
    """
    motion = _check_motion(motion)
    try:
        mu = float(mean) if eps is None else float(eps)
    except (TypeError, ValueError):
        raise MocapValueError(f"the noise mean must be a number, got {eps if eps is not None else mean!r}") from None
    if eps is not None and float(mean) not in (1.0, mu):
        raise MocapValueError("give the noise mean as mean= or eps=, not both")
    if not np.isfinite(mu):
        raise MocapValueError(f"mean must be finite, got {mu!r}")
    sd = _nonneg(sigma, "sigma")
    k = 1.0 if scale is None else _nonneg(scale, "scale")
    T, J = motion.observed.shape
    try:
        p = int(n_frames)
    except (TypeError, ValueError):
        raise MocapValueError(f"n_frames must be an integer, got {n_frames!r}") from None
    if not 0 <= p <= T:
        raise MocapValueError(f"n_frames must be between 0 and the clip length ({T}), got {n_frames}")
    rng = _rng(seed)
    rows = np.sort(rng.choice(T, size=p, replace=False))
    G = rng.normal(mu, sd, size=(p, 3 * J)) * k                       # G_{p x n}(ε, σ)
    Gamma = rng.random((p, 3 * J))                                     # Γ_{p x n}(0, 1)
    hit = ~((Gamma - 0.5) > 0)                                         # 1 - ((Γ - 0.5) > 0)
    X = motion.matrix()
    X[rows] += G * hit
    coord = np.zeros((T, 3 * J), dtype=bool)
    coord[rows] = hit
    mask = coord.reshape(T, J, 3).any(axis=2) & motion.observed
    step = {"step": "slra_noise", "n_frames": p, "mean": mu, "sigma": sd, "scale": k}
    return _result(motion, X.reshape(T, J, 3), motion.observed, step), mask


# ----------------------------------------------------------------------------------------
# combination and the CLI spec
# ----------------------------------------------------------------------------------------
STEPS: dict[str, Callable[..., tuple[Motion, np.ndarray]]] = {
    "gaussian": gaussian,
    "outliers": outliers,
    "missing": missing,
    "block_gaps": block_gaps,
    "label_swaps": label_swaps,
    "label_jumps": label_jumps,
    "slra_noise": slra_noise,
}
_ALIASES = {"noise": "gaussian", "outlier": "outliers", "spikes": "outliers", "gaps": "block_gaps",
            "swaps": "label_swaps", "jumps": "label_jumps",
            "gap": "block_gaps", "slra": "slra_noise"}


def _step_func(name: str) -> tuple[str, Callable]:
    key = _ALIASES.get(str(name).strip().lower(), str(name).strip().lower())
    if key not in STEPS:
        raise MocapValueError(f"unknown corruption {name!r}; known: {', '.join(STEPS)}")
    return key, STEPS[key]


def _step_params(func: Callable) -> list[str]:
    return [p.name for p in inspect.signature(func).parameters.values()
            if p.kind == p.KEYWORD_ONLY and p.name != "seed"]


def combine(motion: Motion, steps: Sequence[tuple[str, dict]] | str, seed: Any) -> tuple[Motion, np.ndarray]:
    """Apply several corruptions in order; return the result and the union of the masks.

    Parameters
    ----------
    motion : Motion.
    steps : list of ``(name, kwargs)`` pairs (names: ``gaussian``, ``outliers``,
        ``missing``, ``block_gaps``, ``slra_noise``; aliases ``noise``, ``spikes``,
        ``gaps``, ``slra``), or a spec string for :func:`parse_spec`. ``kwargs`` must not
        contain ``seed``.
    seed : int, Generator or SeedSequence. Step i gets the i-th child of
        ``SeedSequence(seed)`` (for a Generator: the i-th of ``seed.spawn(n)``), so adding
        a step at the end does not change the earlier ones.

    Returns
    -------
    (Motion, mask) : mask (T, J) bool, union of the steps' masks (an entry corrupted and
        later removed stays marked).

    Examples
    --------
    2 cm Gaussian noise on every coordinate, then 10 % of the samples removed:

    >>> from mocapkit import corrupt, datasets, io, metrics
    >>> clean = io.read(datasets.bundled("16_15.amc")).slice(0, 120)
    >>> noisy, mask = corrupt.combine(clean, "gaussian:sigma_cm=2,missing:ratio=0.1", seed=0)
    >>> noisy.n_frames, round(noisy.missing_fraction, 2), bool(mask.all())
    (120, 0.1, True)
    >>> round(metrics.rmse(clean, noisy, noisy.observed), 1)      # cm, on what is left
    2.0
    """
    motion = _check_motion(motion)
    if isinstance(steps, str):
        steps = parse_spec(steps)
    steps = list(steps)
    parsed = []
    for item in steps:
        try:
            name, kwargs = item
        except (TypeError, ValueError):
            raise MocapValueError(f"each step must be a (name, kwargs) pair, got {item!r}") from None
        key, func = _step_func(name)
        kwargs = dict(kwargs or {})
        if "seed" in kwargs:
            raise MocapValueError(f"step {key!r}: give the seed to combine(), not to the step")
        bad = sorted(set(kwargs) - set(_step_params(func)))
        if bad:
            raise MocapValueError(f"corruption {key!r} has no parameter(s) {bad}; it accepts: "
                                  f"{', '.join(_step_params(func))}")
        parsed.append((func, kwargs))
    if isinstance(seed, np.random.Generator):
        children = seed.spawn(len(parsed))
    else:
        if isinstance(seed, np.random.SeedSequence):
            ss = seed
        else:
            _rng(seed)                                                   # validates the seed
            ss = np.random.SeedSequence(int(seed))
        children = [np.random.default_rng(s) for s in ss.spawn(len(parsed))]
    out = motion
    mask = np.zeros(motion.observed.shape, dtype=bool)
    for (func, kwargs), rng in zip(parsed, children):
        out, m = func(out, seed=rng, **kwargs)
        mask |= m
    from .denoise.bases import reference_as_read, reference_frames

    ref = reference_frames(motion)
    if ref:
        # the file's reference pose (a BVH's T-pose first frame) is no capture, and a
        # capture's noise does not reach it: left as it is
        out = reference_as_read(out, motion, ref)
        mask[:ref] = False
    return out, mask


def _parse_value(text: str) -> Any:
    t = text.strip()
    low = t.lower()
    if low in ("none", "null"):
        return None
    if low in ("true", "yes"):
        return True
    if low in ("false", "no"):
        return False
    if "/" in t:
        return [_parse_value(x) for x in t.split("/") if x.strip()]
    try:
        return int(t)
    except ValueError:
        pass
    try:
        return float(t)
    except ValueError:
        return t


def parse_spec(spec: str) -> list[tuple[str, dict[str, Any]]]:
    """Parse a corruption spec string into :func:`combine` steps.

    Grammar: steps separated by ``,`` or ``;``; a step is ``name`` or ``name:key=value``;
    further ``key=value`` items without a ``name:`` prefix belong to the preceding step.
    Values: ints, floats, ``true``/``false``, ``none``, lists with ``/`` (joint names),
    else strings. Example::

        parse_spec("gaussian:sigma_cm=2,outliers:ratio=0.05,mode=scale,missing:ratio=0.1")
        -> [("gaussian", {"sigma_cm": 2}), ("outliers", {"ratio": 0.05, "mode": "scale"}),
            ("missing", {"ratio": 0.1})]
    """
    if not isinstance(spec, str) or not spec.strip():
        raise MocapValueError("empty corruption spec")
    steps: list[tuple[str, dict[str, Any]]] = []
    for raw in spec.replace(";", ",").split(","):
        tok = raw.strip()
        if not tok:
            continue
        if ":" in tok or "=" not in tok:
            name, _, rest = tok.partition(":")
            key, func = _step_func(name)
            steps.append((key, {}))
            tok = rest.strip()
            if not tok:
                continue
        if not steps:
            raise MocapValueError(f"corruption spec {spec!r}: {tok!r} comes before any step name")
        k, eq, v = tok.partition("=")
        k = k.strip()
        if not eq or not k:
            raise MocapValueError(f"corruption spec {spec!r}: expected key=value, got {tok!r}")
        name, params = steps[-1]
        accepted = _step_params(STEPS[name])
        if k not in accepted:
            raise MocapValueError(f"corruption {name!r} has no parameter {k!r}; it accepts: "
                                  f"{', '.join(accepted)}")
        params[k] = _parse_value(v)
    if not steps:
        raise MocapValueError("empty corruption spec")
    return steps
