"""``fill-auto``: the fill chosen per gap by self-validation on the file itself.

No single gap fill is best: interpolation wins short gaps, a rigid-body or pattern fill
wins where a marker's segment-mates are seen, a low-rank/PCA fill in the body frame wins
long and edge gaps (../shared/specs/METHODS.md §6). Without truth the only evidence is the
file, so (decision, METHODS.md §6 "self-validation"):

1. For every real gap of marker *j* (length *L* frames), hide an **observed** stretch of
   the same marker and length next to it: just before the gap (round 1) and just after
   it (round 2) for an interior gap, the *L* frames that continue an edge gap for a
   leading/trailing one (so the hidden stretch is an edge gap too, twice as deep: a
   conservative test). Hides of one marker never touch each other or a real gap; all
   hides of a round are hidden together, so each candidate runs once per round.
2. Every candidate fills the hidden file; its RMSE on each hidden stretch (cm) scores it
   for the gap the stretch was shaped after. A gap without a usable stretch (a marker
   seen too little) borrows the pooled scores of the validated gaps of the same kind
   (interior/edge) and a similar length (factor-2 bins, nearest bin if its own is empty).
3. On the real file every candidate runs once more; each gap takes the values of its
   best candidate (per frame, the next best where the best has none). A gap whose best
   validated error exceeds ``max_error_cm`` is left missing: no fill is trusted there.

Each candidate keeps to its own evidence (:func:`mocapkit.gaps.supported` with its
``fill_evidence``: interpolation never extrapolates beyond the policy's edge horizon).
The result's ``source['fill_auto']`` says what was chosen, how often, and the estimated
RMSE of the fill (the validated errors of the chosen candidates, weighted by gap length);
``source['fill_codes']`` (the candidate behind each sample) feeds the gap report.

Example
-------
>>> from mocapkit import datasets, denoise, corrupt          # doctest: +SKIP
>>> noisy, _ = corrupt.combine(datasets.load("16_15"), [("block_gaps", {"n_markers": 4, "length": 60})], seed=0)
>>> out = denoise.get("fill-auto").denoise(noisy)
>>> out.source["fill_auto"]["estimated_rmse_cm"]
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import MocapValueError
from ..gaps import Gap, current_policy, find_gaps, supported
from ..motion import Motion
from .base import Denoiser, available, get, register

#: candidates tried by default, cheapest first (names in the registry; missing ones skipped)
DEFAULT_CANDIDATES = ("linear", "spline", "fill-pattern", "fill-rigid", "fill-pca")


def _candidate_fill(method: Denoiser, motion: Motion) -> np.ndarray:
    """(T, J, 3) positions: ``motion``'s observed samples, the method's fills where its own
    evidence supports them, NaN elsewhere. Called inside ``fill-auto``'s denoise, so the
    method runs unguarded (the outer guard has already prepared the motion)."""
    try:
        out = method.denoise(motion)
    except MocapValueError:
        return np.array(motion.positions)
    X = np.array(out.positions, dtype=float)
    obs = motion.observed
    allowed = supported(obs, motion.fps, method.fill_evidence, current_policy())
    X[~obs & ~allowed] = np.nan
    X[obs] = motion.positions[obs]
    return X


def _free(used: np.ndarray, j: int, a: int, b: int) -> bool:
    """Frames a-1 .. b of marker j (the stretch and one frame each side) are still free."""
    return not used[max(a - 1, 0):min(b + 1, used.shape[0]), j].any()


def _hides(obs: np.ndarray, gaps: Sequence[Gap], rounds: int) -> list[list[tuple[int, int, int, int]]]:
    """Per round, the hidden stretches (gap index, joint, start, stop) -- see the module
    docstring. A stretch must be observed, with an observed frame on each side where the
    stretch is meant to be interior, and keep clear of other hides and real gaps."""
    T = obs.shape[0]
    out = []
    for r in range(rounds):
        used = ~obs.copy()                       # real gaps are off limits
        chosen = []
        for gi, g in enumerate(gaps):
            L = g.length
            if g.kind == "interior":
                a, b = (g.start - 1 - L, g.start - 1) if r == 0 else (g.stop + 1, g.stop + 1 + L)
                if a < 1 or b > T - 1:
                    continue
                if not obs[a - 1:b + 1, g.joint].all() or not _free(used, g.joint, a, b):
                    continue
            elif g.kind == "leading" and r == 0:
                a, b = g.stop, g.stop + L
                if b > T - 1 or not obs[a:b + 1, g.joint].all() or used[a:b + 1, g.joint].any():
                    continue
            elif g.kind == "trailing" and r == 0:
                a, b = g.start - L, g.start
                if a < 1 or not obs[a - 1:b, g.joint].all() or used[a - 1:b, g.joint].any():
                    continue
            else:
                continue
            used[a:b, g.joint] = True
            chosen.append((gi, g.joint, a, b))
        out.append(chosen)
    return out


def _pooled(err: np.ndarray, gaps: Sequence[Gap]) -> np.ndarray:
    """Scores for gaps without their own validation: mean over validated gaps of the same
    kind class (interior / edge) and length bin (factor 2; the nearest non-empty bin)."""
    out = err.copy()
    have = np.isfinite(err).any(axis=1)
    if have.all() or not have.any():
        return out
    edge = np.array([g.kind != "interior" for g in gaps])
    lbin = np.floor(np.log2(np.maximum([g.length for g in gaps], 1))).astype(int)
    for cls in (False, True):
        src = have & (edge == cls)
        if not src.any():
            src = have
        bins = np.unique(lbin[src])
        table = {b: np.nanmean(err[src & (lbin == b)], axis=0) for b in bins}
        for gi in np.flatnonzero(~have & (edge == cls)):
            b = bins[np.argmin(np.abs(bins - lbin[gi]))]
            out[gi] = table[b]
    return out


@register
class FillAuto(Denoiser):
    """Per-gap choice of fill, self-validated on the file (module docstring).

    Parameters
    ----------
    candidates : registry names of the fills to choose from (default
        :data:`DEFAULT_CANDIDATES`; names not registered are skipped).
    max_error_cm : a gap whose best validated RMSE is above this (cm) is left missing;
        None fills every supported gap.
    rounds : validation rounds (1: stretches before interior gaps only; 2: before and
        after).

    Observed samples are returned unchanged.
    """

    name = "fill-auto"
    description = ("per-gap choice among interpolation, pattern, rigid-body and body-frame PCA "
                   "fills, self-validated on the file; observed samples unchanged")
    needs_training = False
    keeps_observed = True
    fill_evidence = "markers"
    clean_tolerance_cm = 1e-9

    def __init__(self, candidates: Sequence[str] = DEFAULT_CANDIDATES,
                 max_error_cm: float | None = 10.0, rounds: int = 2):
        self.candidates = candidates
        self.max_error_cm = max_error_cm
        self.rounds = rounds

    def _methods(self) -> list[tuple[str, Denoiser]]:
        names = [self.candidates] if isinstance(self.candidates, str) else list(self.candidates)
        known = available()
        bad = [n for n in names if n not in known and not n.startswith("fill-")]
        if bad or self.name in names:
            raise MocapValueError(f"fill-auto: unknown or invalid candidate(s) {bad or [self.name]}")
        out = [(n, get(n)) for n in names if n in known]
        if not out:
            raise MocapValueError("fill-auto: no candidate fill is available")
        return out

    def denoise(self, motion: Motion) -> Motion:
        if self.max_error_cm is not None and not float(self.max_error_cm) > 0:
            raise MocapValueError(f"fill-auto: max_error_cm must be positive, got {self.max_error_cm!r}")
        if int(self.rounds) not in (1, 2):
            raise MocapValueError(f"fill-auto: rounds must be 1 or 2, got {self.rounds!r}")
        obs = motion.observed
        gaps = [g for g in find_gaps(obs) if g.kind != "never"]
        if not gaps:
            return motion
        methods = self._methods()
        P = motion.positions
        K = len(methods)
        sq = np.zeros((len(gaps), K))
        cnt = np.zeros((len(gaps), K))
        tot = np.zeros(len(gaps))
        for hide in _hides(obs, gaps, int(self.rounds)):
            if not hide:
                continue
            mask = obs.copy()
            for _, j, a, b in hide:
                mask[a:b, j] = False
            trial = motion.with_observed(mask)
            for k, (_, m) in enumerate(methods):
                X = _candidate_fill(m, trial)
                for gi, j, a, b in hide:
                    d = X[a:b, j] - P[a:b, j]
                    ok = np.isfinite(d).all(axis=1)
                    sq[gi, k] += float((d[ok] ** 2).sum())
                    cnt[gi, k] += ok.sum()
            for gi, j, a, b in hide:
                tot[gi] += b - a
        with np.errstate(invalid="ignore", divide="ignore"):
            err = np.sqrt(sq / (3 * cnt))
            # a candidate that covers little of the hidden stretch is not validated for it
            err[cnt < 0.9 * tot[:, None]] = np.inf
        err[tot == 0] = np.nan
        err = _pooled(err, gaps)
        fills = [_candidate_fill(m, motion) for _, m in methods]
        return self._assemble(motion, gaps, methods, fills, err)

    def _assemble(self, motion: Motion, gaps: Sequence[Gap], methods, fills, err: np.ndarray) -> Motion:
        """Each gap from its best-validated candidate (next best per frame where it has none)."""
        Y = np.array(motion.positions)
        names = [n for n, _ in methods]
        codes = np.full(motion.observed.shape, -1, dtype=np.int8)
        chosen = dict.fromkeys(names, 0)
        est_sq, est_n, left_gaps, unvalidated = 0.0, 0, 0, 0
        for gi, g in enumerate(gaps):
            e = err[gi]
            if not np.isfinite(e).any():
                unvalidated += 1
                order = list(range(len(methods)))[::-1]     # no evidence: the richest fill first
            else:
                order = [int(k) for k in np.argsort(np.where(np.isnan(e), np.inf, e))]
            best = e[order[0]] if np.isfinite(e[order[0]]) else np.nan
            if self.max_error_cm is not None and not (best <= float(self.max_error_cm)):
                left_gaps += 1
                continue
            seg = np.full((g.length, 3), np.nan)
            for k in order:
                Xk = fills[k][g.start:g.stop, g.joint]
                take = ~np.isfinite(seg).all(axis=1) & np.isfinite(Xk).all(axis=1)
                if take.any():
                    seg[take] = Xk[take]
                    codes[g.start:g.stop, g.joint][take] = k
            chosen[names[order[0]]] += 1
            Y[g.start:g.stop, g.joint] = seg
            n = int(np.isfinite(seg).all(axis=1).sum())
            if n and np.isfinite(best):
                est_sq += best ** 2 * n
                est_n += n
        src = dict(motion.source)
        src["fill_codes"] = {"names": names, "codes": codes}
        src["fill_auto"] = {
            "gaps": len(gaps), "chosen": {k: v for k, v in chosen.items() if v},
            "left_gaps": left_gaps, "unvalidated_gaps": unvalidated,
            "estimated_rmse_cm": float(np.sqrt(est_sq / est_n)) if est_n else None,
            "how": "RMSE of each gap's chosen fill on observed stretches of the same marker and "
                   "length hidden next to the gap (pooled by gap length where none fits)",
            "max_error_cm": self.max_error_cm,
        }
        return Motion(Y, motion.skeleton, motion.fps, np.isfinite(Y).all(axis=2), src, motion.filled)


def default_for(motion: Motion) -> Denoiser:
    """The method mocapkit uses when none is named: ``fill-auto`` for marker captures
    (C3D/TRC, or any motion whose joints have no hierarchy) -- fill the gaps, leave the
    measured samples as they are -- and the package default (:data:`DEFAULT_METHOD`) for
    skeleton data."""
    from . import default

    markers = motion.source.get("format") in ("c3d", "trc") or bool(
        np.all(np.asarray(motion.skeleton.parents) < 0) and motion.n_joints > 1)
    return get("fill-auto") if markers else default()
