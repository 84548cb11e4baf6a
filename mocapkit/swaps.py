"""Label swaps: two markers that trade labels for a stretch of frames, found and put back.

An optical system's labeller that confuses two markers -- a knee and a thigh marker as
the leg bends, two hands as they pass -- writes each one's trajectory under the other's
label for a while: both labels step at the swap, by the same distance in opposite
directions, and step back at its end. Inside the stretch both trajectories are smooth
and measured, so no smoother, spike test or gap fill repairs it: found on
kineticstoolkit's tennis serve (2026-12-06, a swap of LASI and LFIN planted for 5-120
frames), ``auto`` wrote both markers 28-34 cm off for the whole stretch, without a word.

Detection (:func:`find_swaps`). Per marker, the constant-velocity residual
``r_a(t) = |P_a(t) - (2 P_a(t-1) - P_a(t-2))|`` (3-D, cm; three consecutive measured
frames) and its scale ``s_a``, the median of ``r_a`` over the take. A frame where
``r_a(t) > max(floor_cm, factor s_a)`` is a *step* of ``a``. The step is a label swap with
marker ``b`` (also measured at t-2, t-1, t) when exchanging the two samples at ``t``
explains both markers' steps: each lands within that threshold of the other's prediction,
and the two residuals after the exchange sum to at most ``ratio`` of the two before it.
Two markers that pass within the noise of each other are no swap (neither steps).

Repair (:func:`repair_swaps`). Per pair, the events cut the take into stretches of
alternate labelling, and the labelling that holds on most frames is taken as the right
one. A stretch of the other labelling is exchanged back -- samples and missing flags --
when no frame of it has both markers missing (there a swap back could hide unseen) and
their distances to their steadiest partners do not say it is labelled right -- for a
stretch that runs to an end of the take, only where they say it is exchanged: a false
event, or a missed one (a swap back inside a gap, or noise hiding its step), would
otherwise exchange the rest of the take; with the check it costs at most a short stretch
between two events.

Measured (2026-12-06, ``benchmarks/label_swaps.py``, docs/results/swaps.md; swaps of a
marker with its nearest neighbour within 15 cm, 3-100 frames, planted in 7 real captures,
with and without real occlusion masks, 1,424 cases): 2,304 of 2,727 put back exactly --
94 / 95 / 65 % with noise 0 / 0.1 / 0.5 cm per coordinate, 98 / 96 / 58 % of those that
start where a marker reappears after a gap --, no case with more samples wrong after than
before, no event on any shared marker file as it is (before the label jumps below; since
them: 2,317 put back, and 1,608 of 2,101 planted jumps, 94 / 90 / 46 %, none worse; the
basket sprint's real jumps are the only events on the shared files). The first version,
by events alone (the majority labelling, no geometry check), put 1,502 samples wrong where 174 had been on
3-frame swaps: a relaxed event of a tennis serve's elbow pair, or a missed swap back,
exchanged the rest of the take; with the geometry check but stretches to the take's end
put back where it was undecided, 3 cases were worse (a wrist pair's swap in hidden by 0.5
cm noise: its swap back exchanged the last 117 frames). Also measured and not kept: the
step factor 3 instead of 4 (0.5 cm noise 65 -> 67 % put back, nothing else moved); the
exchanged samples allowed 4 x the running median of the residuals of the 11 frames about
them off their predictions rather than the take's threshold, for fast strokes (2,304 ->
2,326 put back, but 12 events with nothing planted instead of 2, the tennis
serve as it is among them). Of the swaps missed without noise or mask, half are of a hand
and a thumb 1.7-1.8 cm apart, under the 2 cm floor; the others' swap back fell in a fast
stroke and was not seen, so the labelling was left as it was.

A Kinect skeleton's body-side flip -- the tracker puts every left joint under the right
label as the subject turns -- is the same event on every left-right pair at once:
:func:`repair_side_flips`.

Every method runs after :func:`repair_swaps` on a marker capture, and after
:func:`repair_side_flips` on a Kinect skeleton (the shared guard,
:mod:`mocapkit.denoise.base`; :attr:`mocapkit.gaps.GapPolicy.swaps`, ``--keep-swaps``).

A label that jumps onto a neighbour whose own label goes missing -- the labeller, its
marker hidden, takes the nearest marker still seen -- is the same exchange with one marker
hidden: its ends are found where one label vanishes or reappears as the other steps onto
its path, and putting the stretch back gives the neighbour its samples and leaves the
jumping label missing there, a gap for the fill. Found in a real capture:
kineticstoolkit's basket sprint, where ForearmL:Marker1 takes Marker4's place at frame
732 as Marker4's label vanishes (to 0.1 cm), and the two labels stay exchanged from frame
1038 to the end -- the distances to the elbow say so (27 against 21 cm).

A stretch to put back with frames where both markers are hidden (a swap back could hide
there) is put back piece by piece between them, each piece only where the distances say
it is exchanged.

A swap at the end of a gap both markers share (up to :data:`SHARED_GAP_FRAMES` frames) --
the labeller lost both and gives each the other's label as they show again -- is found
where each reappearing sample lies where the other's path, extrapolated over the gap,
goes on (:func:`_across_shared_gaps`). Planted so (``benchmarks/label_swaps.py``, 1,019
cases; before the rule below): 512 / 496 / 155 of 682 put back at 0 / 0.1 / 0.5 cm noise,
272 without the rule at 0 cm (and 3 cases worse, none with it); one case at 0.5 cm was
worse after, by a pair toggle the noise made (a tennis serve's elbow pair).

A swap made while the labeller saw neither marker (both hidden, any number of frames)
shows as no event: where the pair has events elsewhere, the stretch it lies in -- taken
as right by the alternation of the events -- is cut where both are hidden, and each piece
after such a cut in which both are measured somewhere is put back where the distances
say it is exchanged (both opinions, :func:`_stretch_states`). Found on the basket sprint
(2026-12-06, twenty-second session): after the repair, ForearmL:Marker1 and Marker4 read
exchanged at frames 2439-2459 (23.8 / 17.6 cm from ArmL:Marker1, against 18-19 / 25-26
on the rest of the take), between gaps both labels share; those frames are now put
back. Measured (``benchmarks/label_swaps.py``): swaps after a 1-5 frame shared gap put
back 512 / 496 / 155 -> 606 / 606 / 311 of 682 at 0 / 0.1 / 0.5 cm noise (the swap back,
an event, puts the pair under judgement; the swapped piece after the gap lies in the
stretch before it), after a 6-60 frame shared gap (new kind) 513 / 499 / 286 of 644;
every other kind unchanged, 0 cases worse but for the new kind's 23, all a 100-frame
swap in the 202-frame HDM05 take, where the swap holds most of the take's frames and its
labelling is taken as right (the same before this rule). Pieces with one marker measured
were put back too at first: a false event on a tennis serve's wrist and finger (0.1 cm
noise, the basket sprint's mask) then exchanged 18 frames of the wrist alone, 8 cases
worse.

A pair whose two labels come back together after a longer shared gap with their samples
exchanged (:func:`hidden_swap_pairs`: the partners' rigid motion over the gap puts each
marker where the other shows) is judged the same way even with no event at all: its
pieces after the frames where both are hidden are put back where the distances say so.
Such a pair gives no event: a change of labels where neither marker is seen breaks the
alternation of events. Planted between two shared gaps of 6-60 frames (``between shared
gaps``, no step of either label seen): 0 -> 394 / 365 / 167 of 604-607 put back at 0 /
0.1 / 0.5 cm noise, 8 cases worse -- again the 202-frame HDM05 take with a 100-frame
swap --, every other kind unchanged (long shared gaps at 0.1 cm 499 -> 501). Measured and not kept: the same reappearances as
events (with a translation from one partner), with the pair's majority counted over the
frames a label is seen (over all frames, the extra events flipped the basket pair's
majority and lost the repairs of frames 684-731 and 1036-1037): long shared gaps 513 ->
527 put back at 0 cm, but 1-5 frame shared gaps 606 -> 598 and 4 cases worse.

Limits: a labelling that holds on most of a take is taken as right, whatever it is (a
100-frame swap in a 202-frame take is put the wrong way); a jump whose other end is
hidden too is not seen; those are the outlier tests' and the gap policy's.

>>> import numpy as np
>>> from mocapkit import Motion, Skeleton
>>> t = np.arange(200)[:, None] / 100.0
>>> P = np.stack([np.hstack([100 * t, 0 * t, 100 + 0 * t]),
...               np.hstack([100 * t, 20 + 0 * t, 100 + 0 * t]),
...               np.hstack([100 * t, 0 * t, 140 + 0 * t])], axis=1)
>>> Q = P.copy(); Q[80:120, [0, 1]] = P[80:120, [1, 0]]        # labels 0 and 1 swapped
>>> m = Motion(Q, Skeleton(("A", "B", "C"), [-1, -1, -1], np.zeros((3, 3))), 100.0)
>>> [(e.frame, e.a, e.b) for e in find_swaps(m.positions, m.observed)]
[(80, 0, 1), (120, 0, 1)]
>>> fixed, report = repair_swaps(m)
>>> bool(np.allclose(fixed.positions, P)), report["repaired"]
(True, [{'markers': ['A', 'B'], 'start': 80, 'stop': 120}])
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from .motion import Motion

__all__ = ["SwapEvent", "find_swaps", "hidden_swap_pairs", "repair_swaps", "repair_side_flips", "repair_labels", "summary_line",
           "SWAP_FACTOR", "SWAP_FLOOR_CM", "SWAP_RATIO"]

#: a step: the constant-velocity residual over this many times the marker's median residual
#: (Gaussian noise alone: the median is about 3.8 sigma, 4 x that ~6 times the chi(3) tail's
#: 1e-8 point)
SWAP_FACTOR = 4.0
#: ... and over this (cm): smaller steps are within what a marker's noise and motion do
SWAP_FLOOR_CM = 2.0
#: the exchange must bring the two markers' residuals to this share of theirs before it
SWAP_RATIO = 0.25


@dataclass(frozen=True)
class SwapEvent:
    """Labels ``a`` and ``b`` trade trajectories from frame ``frame`` on (``step_cm``: the
    larger of their two steps there)."""
    frame: int
    a: int
    b: int
    step_cm: float


def _residuals(P: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T, J) constant-velocity residual (cm, NaN without three measured frames) and the
    (T, J, 3) prediction ``2 P(t-1) - P(t-2)`` (NaN likewise)."""
    T, J, _ = P.shape
    pred = np.full(P.shape, np.nan)
    ok = np.zeros((T, J), bool)
    if T >= 3:
        ok[2:] = observed[2:] & observed[1:-1] & observed[:-2]
        pred[2:] = 2.0 * P[1:-1] - P[:-2]
    pred[~ok] = np.nan
    with np.errstate(invalid="ignore"):
        r = np.sqrt(np.sum((P - pred) ** 2, axis=2))
    return r, pred


def _thresholds(r: np.ndarray, have: np.ndarray, factor: float, floor_cm: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """Per marker (J,): the median constant-velocity residual (cm) and the step threshold
    ``max(floor_cm, factor x median)`` (module docstring)."""
    scale = np.zeros(r.shape[1])
    for j in np.flatnonzero(have.any(axis=0)):      # (a loop over markers, not frames)
        scale[j] = np.median(r[have[:, j], j])
    return scale, np.maximum(float(floor_cm), float(factor) * scale)


def find_swaps(positions: np.ndarray, observed: np.ndarray, *, factor: float = SWAP_FACTOR,
               floor_cm: float = SWAP_FLOOR_CM, ratio: float = SWAP_RATIO,
               partner: np.ndarray | None = None) -> list[SwapEvent]:
    """The label-swap events of a marker capture (module docstring), in time order.

    ``positions`` (T, J, 3) cm, ``observed`` (T, J) bool. ``partner`` (J,): the one marker
    each may swap with (itself: none), e.g. a skeleton's left-right mirror
    (:func:`mocapkit.frames.mirror_permutation`); None: any. First the swaps that stand out
    (a step over the threshold, explained by an exchange with another marker); then, for
    each pair found, every frame at which that pair's exchange explains a step of at least
    the pair's distance (:func:`_pair_toggles`): a swap out that falls just under the
    threshold where its swap in did not (two markers about a threshold apart) would
    otherwise leave the rest of the take exchanged. Also the exchanges with one marker
    hidden: a marker that reappears after a gap under a neighbour's label (the neighbour's
    label steps there, onto its path), and a label that vanishes while another takes up its
    path at that frame (steps onto it, or reappears on it) -- a labeller that gives a
    hidden marker's label to its neighbour, whose own label then goes missing. Vectorised
    over the frames and the steps (blocks of 4,096); the loops run over the pairs and the
    events found.
    """
    P = np.asarray(positions, dtype=float)
    obs = np.asarray(observed, dtype=bool) & np.isfinite(P).all(axis=2)
    T, J = obs.shape
    if T < 3 or J < 2:
        return []
    r, pred = _residuals(P, obs)
    have = np.isfinite(r)
    scale, thr = _thresholds(r, have, factor, floor_cm)
    with np.errstate(invalid="ignore"):
        steps = np.argwhere(r > thr[None, :])
    pairs: set[tuple[int, int]] = set()
    for blk in range(0, len(steps), 4096):         # every step against every marker at once
        t, a = steps[blk:blk + 4096].T
        with np.errstate(invalid="ignore"):
            to_a = np.linalg.norm(P[t] - pred[t, a][:, None], axis=2)       # (N, J): b's sample as a's
            to_b = np.linalg.norm(P[t, a][:, None] - pred[t], axis=2)       # a's sample as b's
            before = r[t, a][:, None] + r[t]
            after = to_a + to_b
            fits = (have[t] & _allowed(a, J, partner) & (to_a <= thr[a][:, None])
                    & (to_b <= thr[None, :]) & (after <= float(ratio) * before))
        hit = fits.any(axis=1)
        b = np.argmin(np.where(fits, after, np.inf), axis=1)
        pairs.update((min(int(x), int(y)), max(int(x), int(y))) for x, y in zip(a[hit], b[hit]))
    events = []
    # a marker that reappears after a gap under the label of a neighbour: the neighbour's
    # label steps onto the reappearing marker's path there, and the reappearing label sits
    # where the neighbour's path goes on (the other half, the reappearing marker's own
    # path, is not seen over its gap)
    back = np.argwhere(obs[1:] & ~obs[:-1]) + [1, 0]                      # (t, a) reappearing
    for blk in range(0, len(back), 4096):
        t, a = back[blk:blk + 4096].T
        with np.errstate(invalid="ignore"):
            to_b = np.linalg.norm(P[t, a][:, None] - pred[t], axis=2)       # (N, J): a's sample as b's
            fits = (have[t] & (r[t] > thr[None, :]) & _allowed(a, J, partner)
                    & (to_b <= thr[None, :]) & (to_b <= float(ratio) * r[t]))
        hit = np.flatnonzero(fits.any(axis=1))
        b = np.argmin(np.where(fits, to_b, np.inf), axis=1)
        for i in hit:
            x, y = int(a[i]), int(b[i])
            pairs.add((min(x, y), max(x, y)))
            events.append(SwapEvent(int(t[i]), min(x, y), max(x, y), float(r[t[i], y])))
    # a label that vanishes while another takes up its path at that frame: the other label
    # steps onto it (a labeller gives a hidden marker's label to the neighbour whose label
    # then goes missing, and back when the hidden marker shows), or reappears on it
    gone = np.argwhere(~obs[2:] & obs[1:-1] & obs[:-2]) + [2, 0]          # (t, x) vanishing
    for blk in range(0, len(gone), 4096):
        t, x = gone[blk:blk + 4096].T
        q = 2.0 * P[t - 1, x] - P[t - 2, x]                                 # x's path at t
        with np.errstate(invalid="ignore"):
            to_x = np.linalg.norm(P[t] - q[:, None], axis=2)                # (N, J): each sample as x's
            took = (have[t] & (r[t] > thr[None, :]) & (to_x <= float(ratio) * r[t])) | (obs[t] & ~obs[t - 1])
            fits = took & _allowed(x, J, partner) & (to_x <= thr[x][:, None])
        hit = np.flatnonzero(fits.any(axis=1))
        y = np.argmin(np.where(fits, to_x, np.inf), axis=1)
        for i in hit:
            u, v = int(x[i]), int(y[i])
            # a label reappearing on the other's path (no step to weigh): only markers that
            # keep further apart than their two thresholds (hand and fingers under noise
            # pass through each other's allowance)
            if not obs[t[i] - 1, v] and not _apart(P, obs, u, v) > thr[u] + thr[v]:
                continue
            pairs.add((min(u, v), max(u, v)))
            events.append(SwapEvent(int(t[i]), min(u, v), max(u, v), float(np.nan_to_num(r[t[i], v]))))
    for ev in _across_shared_gaps(P, obs, thr, float(ratio), partner):
        pairs.add((ev.a, ev.b))
        events.append(ev)
    for a, b in sorted(pairs):
        for t, step in _pair_toggles(P, r, pred, a, b, scale, thr, float(ratio)):
            events.append(SwapEvent(t, a, b, step))
    uniq = {(e.frame, e.a, e.b): e for e in events}
    return sorted(uniq.values(), key=lambda e: (e.frame, e.a, e.b))


#: the longest gap (frames) both markers of a pair may share for a swap across it to be
#: looked for (:func:`_across_shared_gaps`): the paths are extrapolated over it
SHARED_GAP_FRAMES = 5


def _reappearances(obs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every frame ``t`` where marker ``j`` is seen again after a gap, and ``s`` the frame it
    was last seen before (-1: never): (n,) int arrays each."""
    T = obs.shape[0]
    t, j = np.nonzero(obs[1:] & ~obs[:-1])
    t = t + 1
    last = np.maximum.accumulate(np.where(obs, np.arange(T)[:, None], -1), axis=0)
    return t, j, last[t - 1, j]


def _pairs_within(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For a sorted (n,) ``key``: every pair (u, v), u < v, of positions that share a
    value, as two index arrays (vectorised: no loop over the groups)."""
    end = np.searchsorted(key, key, side="right")                          # (n,) each group's end
    count = end - np.arange(len(key)) - 1
    u = np.repeat(np.arange(len(key)), count)
    v = u + 1 + np.arange(len(u)) - np.repeat(np.cumsum(count) - count, count)
    return u, v


def _across_shared_gaps(P: np.ndarray, obs: np.ndarray, thr: np.ndarray, ratio: float,
                        partner: np.ndarray | None) -> list[SwapEvent]:
    """Swaps at the end of a gap both markers share (up to :data:`SHARED_GAP_FRAMES`
    frames): the labeller, having lost both, gives each the other's label as they show
    again. Both labels reappear at frame ``t`` after the same gap of ``g`` frames, each
    marker's path is extrapolated over it at constant velocity from its last two samples,
    and exchanging the two reappearing samples explains both steps: each lands within
    ``(g + 1)`` times the threshold of the marker whose path it continues, and the two
    distances after the exchange are at most ``ratio`` of those before; only markers that
    keep further apart than their two thresholds. Vectorised over every pair of markers
    that reappear at one frame after the same gap (no loop over frames)."""
    t, j, s = _reappearances(obs)                  # j seen again at t, last seen at s
    g = t - 1 - s                                  # the gap's length
    ok = (s >= 1) & (g <= SHARED_GAP_FRAMES)
    ok[ok] &= obs[s[ok] - 1, j[ok]]
    t, j, s, g = t[ok], j[ok], s[ok], g[ok]
    # every pair reappearing at one frame after the same gap: sorted by (t, g)
    key = t * (SHARED_GAP_FRAMES + 1) + g
    order = np.argsort(key, kind="stable")
    t, j, s, g, key = t[order], j[order], s[order], g[order], key[order]
    u, v = _pairs_within(key)
    if not len(u):
        return []
    pred = P[s, j] + (g + 1)[:, None] * (P[s, j] - P[s - 1, j])           # (n, 3) at t
    now = P[t, j]
    own = np.linalg.norm(now - pred, axis=1)
    d_uv = np.linalg.norm(now[v] - pred[u], axis=1)                       # v's sample as u's
    d_vu = np.linalg.norm(now[u] - pred[v], axis=1)
    lim = thr[j] * (g + 1)
    fits = (_may_swap(j[u], j[v], partner) & (d_uv <= lim[u]) & (d_vu <= lim[v])
            & (d_uv + d_vu <= ratio * (own[u] + own[v])))
    out = []
    for x in np.flatnonzero(fits):                 # (the pairs found: a handful)
        a, b = int(j[u[x]]), int(j[v[x]])
        if _apart(P, obs, a, b) > thr[a] + thr[b]:
            out.append(SwapEvent(int(t[u[x]]), min(a, b), max(a, b), float(max(own[u[x]], own[v[x]]))))
    return out


#: :func:`hidden_swap_pairs`: frames (evenly spaced) on which each marker's most rigid
#: partners are picked, and how many of them carry it over a gap
HIDDEN_REF_FRAMES = 512
HIDDEN_PARTNERS = 4


def hidden_swap_pairs(positions: np.ndarray, observed: np.ndarray, *, ratio: float = SWAP_RATIO,
                      partner: np.ndarray | None = None) -> set[tuple[int, int]]:
    """Pairs of markers whose labels may have been exchanged while both were hidden: two
    labels reappear at one frame ``t`` after gaps of which one at least is longer than
    :data:`SHARED_GAP_FRAMES` (too long to extrapolate a path over, as
    :func:`_across_shared_gaps` does), and exchanging the two reappearing samples brings
    each within half their distance of where the other marker's partners put it: its
    :data:`HIDDEN_PARTNERS` most rigid partners (:func:`mocapkit.rigid.rigid_partners` on
    :data:`HIDDEN_REF_FRAMES` frames) seen at both ends of its gap, not the other marker,
    moved rigidly from its last frame to ``t`` (Kabsch with three or more, their mean
    shift with fewer); the two distances at most ``ratio`` of those before the exchange: the
    prediction's own error must be small against the two markers' distance, so no step
    threshold is asked (with it, as for the steps, pairs within 15 cm under 0.5 cm noise
    were never found: 9 of 607 planted put back, against 191 with them). Not events: no step is seen,
    and a labelling that changes where neither marker is seen breaks the alternation of
    events; :func:`repair_swaps` judges such a pair by the distances alone, piece by piece
    between the frames where both are hidden. Vectorised over every pair reappearing at one
    frame."""
    from .rigid import apply_rigid, kabsch, rigid_partners

    P = np.asarray(positions, dtype=float)
    obs = np.asarray(observed, dtype=bool) & np.isfinite(P).all(axis=2)
    T, J = obs.shape
    if T < 3 or J < 3:
        return set()
    t, j, s = _reappearances(obs)
    keep = s >= 0
    t, j, s = t[keep], j[keep], s[keep]
    long = (t - 1 - s) > SHARED_GAP_FRAMES
    hot = np.isin(t, t[long])                 # frames where a marker is back from a long gap
    t, j, s, long = t[hot], j[hot], s[hot], long[hot]
    order = np.argsort(t, kind="stable")
    t, j, s, long = t[order], j[order], s[order], long[order]
    u, v = _pairs_within(t)                   # every pair seen again at one frame
    pick = (long[u] | long[v]) & _may_swap(j[u], j[v], partner)
    u, v = u[pick], v[pick]
    if not len(u):
        return set()
    steady, real, _, _ = rigid_partners(P, obs, n_partners=HIDDEN_PARTNERS, n_ref=HIDDEN_REF_FRAMES)

    def predict(x: np.ndarray, other: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) where marker j[x] should be at t[x], and (n,) whether a partner said:
        the partners' rigid motion from the marker's last frame to t[x] (Kabsch, with
        three or more of them seen at both; their mean shift with fewer)."""
        cand = steady[j[x]]                                                   # (n, K)
        ok = (obs[s[x][:, None], cand] & obs[t[x][:, None], cand] & (cand != j[other][:, None])
              & real[j[x]])
        A, B = P[s[x][:, None], cand], P[t[x][:, None], cand]                 # (n, K, 3)
        R, shift = kabsch(A, B, weights=ok)
        few = ok.sum(axis=1) < 3                     # no rotation from fewer: their mean shift
        if few.any():
            w = ok[few][:, :, None]
            n = np.maximum(w.sum(axis=1), 1)
            R[few] = np.eye(3)
            shift[few] = (np.where(w, B[few], 0.0).sum(axis=1) - np.where(w, A[few], 0.0).sum(axis=1)) / n
        return apply_rigid(R, shift, P[s[x], j[x]]), ok.any(axis=1)

    pu, hu = predict(u, v)
    pv, hv = predict(v, u)
    now_u, now_v = P[t[u], j[u]], P[t[v], j[v]]
    own = np.linalg.norm(now_u - pu, axis=1) + np.linalg.norm(now_v - pv, axis=1)
    d_uv = np.linalg.norm(now_v - pu, axis=1)                             # v's sample as u's
    d_vu = np.linalg.norm(now_u - pv, axis=1)
    sep = np.linalg.norm(now_u - now_v, axis=1)
    fits = hu & hv & (d_uv <= 0.5 * sep) & (d_vu <= 0.5 * sep) & (d_uv + d_vu <= float(ratio) * own)
    return {tuple(sorted((int(j[u[x]]), int(j[v[x]])))) for x in np.flatnonzero(fits)}


def _apart(P: np.ndarray, obs: np.ndarray, a: int, b: int) -> float:
    """Median distance (cm) of markers ``a`` and ``b`` over the frames both are measured
    (0 when never)."""
    both = obs[:, a] & obs[:, b]
    return float(np.median(np.linalg.norm(P[both, a] - P[both, b], axis=1))) if both.any() else 0.0


def _may_swap(a: np.ndarray, b: np.ndarray, partner: np.ndarray | None) -> np.ndarray:
    """Whether marker ``a`` may swap with marker ``b`` (int arrays, broadcast): any other,
    or its ``partner``."""
    if partner is None:
        return a != b
    return (b == partner[a]) & (partner[a] != a)


def _allowed(a: np.ndarray, J: int, partner: np.ndarray | None) -> np.ndarray:
    """(N, J) the markers each of ``a`` (N,) may swap with."""
    return _may_swap(a[:, None], np.arange(J)[None, :], partner)


def _pair_toggles(P: np.ndarray, r: np.ndarray, pred: np.ndarray, a: int, b: int, scale: np.ndarray,
                  lim: np.ndarray, ratio: float) -> list[tuple[int, float]]:
    """Frames at which exchanging markers ``a`` and ``b`` explains a step of both: each
    sample within the other's threshold ``lim`` of its prediction, the residuals after the
    exchange at most ``2 ratio`` of those before, the drop at least the two markers'
    distance on the frame before (a true exchange drops by twice it), and that distance
    over their two residual scales (markers closer than that are no pair a step can tell
    apart). Returns (frame, the larger step in cm)."""
    T = P.shape[0]
    ok = np.isfinite(r[:, a]) & np.isfinite(r[:, b])
    before = r[:, a] + r[:, b]
    with np.errstate(invalid="ignore"):
        to_a = np.linalg.norm(P[:, b] - pred[:, a], axis=1)             # b's sample as a's
        to_b = np.linalg.norm(P[:, a] - pred[:, b], axis=1)
        after = to_a + to_b
        apart = np.full(T, np.nan)
        apart[1:] = np.linalg.norm(P[:-1, a] - P[:-1, b], axis=1)
        hit = (ok & (to_a <= lim[a]) & (to_b <= lim[b]) & (after <= 2.0 * ratio * before)
               & (before - after >= apart) & (apart > scale[a] + scale[b]))
    return [(int(t), float(max(r[t, a], r[t, b]))) for t in np.flatnonzero(hit)]


#: left-right pairs of a skeleton swapping at the same frame that make a body-side flip
#: (:func:`repair_side_flips`)
FLIP_PAIRS = 2
#: reference markers per marker of a pair for the geometry test (:func:`_stretch_states`)
SWAP_REFS = 3
#: frames of the labelling taken as right a reference marker needs, measured with each
#: marker of the pair (:func:`_stretch_states`)
SWAP_REF_FRAMES = 30
#: the shortest piece (frames) of a stretch with both markers hidden in places that is put
#: back where only one of them is measured (:func:`repair_swaps`): on a few frames one
#: marker's distances to weak references can not tell (basket sprint: 1-3 frame pieces of
#: ForearmL Marker2/Marker3 were judged exchanged and were not)
SWAP_PIECE_FRAMES = 5
#: a stretch is told apart by the geometry test when its distances to the reference markers
#: fit one labelling at most this share as far off as the other
SWAP_GEOMETRY = 0.25


def _stretch_states(P: np.ndarray, obs: np.ndarray, a: int, b: int, bounds: np.ndarray,
                    exclude: np.ndarray | None = None, right: np.ndarray | None = None) -> np.ndarray:
    """Per stretch ``bounds[i]:bounds[i+1]`` of markers ``a`` and ``b`` (never both missing
    at a frame of it; one hidden throughout: the other's distances alone): +1 exchanged,
    -1 as labelled, 0 undecided, by their distances to reference markers -- the
    :data:`SWAP_REFS` steadiest partners of each (robust spread of the distance over the
    take) -- against those distances' medians over the take. A label that carries the
    other marker keeps the other marker's distances. ``right`` (T,) bool: the frames whose
    labelling is taken as right (the pair's majority stretches): the medians and spreads
    come from those alone, and a reference needs :data:`SWAP_REF_FRAMES` of them measured
    with each marker -- a stretch does not vote for its own reference (found on the basket
    sprint: a hand-off of ArmL:Marker3 to ForearmL:Marker3 was judged labelled right by a
    sync marker seen with ForearmL:Marker3 on 36 frames, most of them the hand-offs).
    Markers in ``exclude`` (those in a swap of their own: their labels may be exchanged
    too, as in a body-side flip, where every left joint's distance to the others on its
    side holds) are no references."""
    T, J = obs.shape
    others = np.setdiff1d(np.arange(J), [a, b] if exclude is None else np.union1d([a, b], exclude))
    n = len(bounds) - 1
    out = np.zeros(n, int)
    if not len(others):
        return out

    def dist(x: int) -> np.ndarray:
        d = np.linalg.norm(P[:, others] - P[:, x:x + 1], axis=2)          # (T, K)
        d[~(obs[:, others] & obs[:, x:x + 1])] = np.nan
        return d

    da, db = dist(a), dist(b)
    ra, rb = (da, db) if right is None else (da[right], db[right])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")            # all-NaN columns: markers never seen together
        few = (np.isfinite(ra).sum(axis=0) < SWAP_REF_FRAMES) | (np.isfinite(rb).sum(axis=0) < SWAP_REF_FRAMES)
        verdicts = [_verdicts(da, db, ra, rb, few, obs, a, b, bounds)]
        if right is not None:                      # a second opinion from the whole take's medians
            verdicts.append(_verdicts(da, db, da, db, few, obs, a, b, bounds))
    V = np.array(verdicts)
    # exchanged only where every opinion says so; labelled right where any does
    out[(V == 1).all(axis=0)] = 1
    out[(V == -1).any(axis=0)] = -1
    return out


def _verdicts(da: np.ndarray, db: np.ndarray, ra: np.ndarray, rb: np.ndarray, few: np.ndarray,
              obs: np.ndarray, a: int, b: int, bounds: np.ndarray) -> np.ndarray:
    """:func:`_stretch_states`' test with the reference distances' medians and spreads from
    ``ra`` / ``rb`` (rows: the frames they come from), references in ``few`` left out."""
    n = len(bounds) - 1
    out = np.zeros(n, int)
    Da, Db = np.nanmedian(ra, axis=0), np.nanmedian(rb, axis=0)
    sa = 1.4826 * np.nanmedian(np.abs(ra - Da), axis=0)
    sb = 1.4826 * np.nanmedian(np.abs(rb - Db), axis=0)
    sa[few] = sb[few] = np.nan
    pick = np.union1d(np.argsort(np.where(np.isfinite(sa), sa, np.inf))[:SWAP_REFS],
                      np.argsort(np.where(np.isfinite(sb), sb, np.inf))[:SWAP_REFS])
    pick = pick[np.isfinite(sa[pick]) & np.isfinite(sb[pick])]
    if not len(pick):
        return out
    scale = np.maximum(sa[pick] + sb[pick], 0.1)                          # cm
    for i in range(n):                             # (a loop over a pair's stretches: a handful)
        s, e = int(bounds[i]), int(bounds[i + 1])
        if e <= s or _both_hidden(obs, a, b, s, e):
            continue
        # (a marker hidden over the whole stretch: the other one's distances alone)
        ma, mb = np.nanmedian(da[s:e, pick], axis=0), np.nanmedian(db[s:e, pick], axis=0)
        same = np.nansum(np.abs(ma - Da[pick]) / scale) + np.nansum(np.abs(mb - Db[pick]) / scale)
        swap = np.nansum(np.abs(ma - Db[pick]) / scale) + np.nansum(np.abs(mb - Da[pick]) / scale)
        if swap < SWAP_GEOMETRY * same:
            out[i] = 1
        elif same < SWAP_GEOMETRY * swap:
            out[i] = -1
    return out


def repair_swaps(motion: Motion, **options) -> tuple[Motion, dict]:
    """``motion`` with its label swaps put back (module docstring), and a report.

    Per pair of markers with swap events (:func:`find_swaps`): the events cut the take
    into stretches of alternate labelling, and the labelling that holds on most frames is
    taken as the right one. A stretch of the other labelling is put back when its
    distances to the markers' steadiest partners do not say it is labelled right
    (:func:`_stretch_states`): a false event, or a missed one, would otherwise exchange the
    rest of the take -- the geometry of a long stretch tells, and a short one costs little.
    Where both markers are missing at some of its frames (a swap back could hide there),
    each piece between them is put back only where the distances say it is exchanged; so
    is a piece of a stretch of the right labelling that follows such frames and has both
    markers measured in it (a swap made while neither was seen).

    ``options`` go to :func:`find_swaps`, ``ratio`` and ``partner`` (whom each marker may
    swap with) to :func:`hidden_swap_pairs` too. Report: ``events`` (frame, marker names, step cm),
    ``hidden_pairs`` (the pairs of :func:`hidden_swap_pairs`, by name), ``repaired`` (stretches put back:
    markers, start, stop frame), ``unrepaired`` (stretches between two events left as
    measured: both markers missing at a frame inside, or distances that say it is labelled
    right -- a likely swap the repair could not take, which the CLI names), ``doubtful``
    (stretches from one event to an end of the take left as measured: one step of a pair
    is no evidence of a swap). Returns ``motion`` itself when nothing was put back.
    """
    P = np.asarray(motion.positions)
    obs = np.asarray(motion.observed) & np.isfinite(P).all(axis=2)
    names = list(motion.skeleton.names)
    events = find_swaps(P, obs, **options)
    hidden = hidden_swap_pairs(P, obs, **{k: v for k, v in options.items() if k in ("ratio", "partner")})
    report: dict = {"events": [{"frame": e.frame, "markers": [names[e.a], names[e.b]], "step_cm": e.step_cm}
                               for e in events], "repaired": [], "unrepaired": [], "doubtful": [],
                    "hidden_pairs": [[names[a], names[b]] for a, b in sorted(hidden)]}
    pairs = {(e.a, e.b) for e in events} | hidden
    if not pairs:
        return motion, report
    T = P.shape[0]
    filled = np.asarray(motion.filled)
    out_P, out_filled = P.copy(), filled.copy()
    swapping = np.array(sorted({x for pair in pairs for x in pair}))
    for a, b in sorted(pairs):
        bounds, minority = _minority([e.frame for e in events if (e.a, e.b) == (a, b)], T)
        right = np.ones(T, bool)
        for i in minority:
            right[bounds[i]:bounds[i + 1]] = False
        # the stretches cut where both markers are hidden (a swap back could hide there),
        # all judged at once
        hid = ~obs[:, a] & ~obs[:, b]
        fine = np.unique(np.r_[bounds, np.flatnonzero(np.diff(hid.astype(int))) + 1])
        states = _stretch_states(out_P, obs, a, b, fine, exclude=swapping, right=right)
        for i in minority:
            s, e = int(bounds[i]), int(bounds[i + 1])
            # between two events: put back unless the distances say it is labelled right;
            # running to an end of the take (one event: the other may be missed), only
            # where they say it is exchanged; with both hidden in places, each piece between
            # them only where they say it is exchanged (a few frames of one marker alone
            # are too little to judge by)
            closed = 0 < s and e < T
            split = bool(hid[s:e].any())
            for k in range(int(np.searchsorted(fine, s)), int(np.searchsorted(fine, e))):
                p, q, st = int(fine[k]), int(fine[k + 1]), states[k]
                if hid[p]:
                    continue
                one = not (obs[p:q, a].any() and obs[p:q, b].any())
                ok = (st == 1 and not (one and q - p < SWAP_PIECE_FRAMES)) if split else \
                    not (st == -1 or (st == 0 and not closed))
                _exchange(out_P, out_filled, obs, a, b, p, q, names, report, ok=ok,
                          left="unrepaired" if closed else "doubtful")
        # a majority stretch's pieces after a frame where both are hidden: a swap the
        # labeller made while it saw neither marker shows as no event, so each such piece
        # is put back where the distances say it is exchanged (module docstring)
        for i in np.setdiff1d(np.arange(len(bounds) - 1), minority):
            s, e = int(bounds[i]), int(bounds[i + 1])
            after = False
            for k in range(int(np.searchsorted(fine, s)), int(np.searchsorted(fine, e))):
                p, q, st = int(fine[k]), int(fine[k + 1]), states[k]
                after |= bool(hid[p])
                # both measured in it: one marker's distances alone (a hand's wrist without
                # its finger) exchanged pieces of labels a false event had cut
                both = bool((obs[p:q, a] & obs[p:q, b]).any())
                if after and not hid[p] and st == 1 and both:
                    _exchange(out_P, out_filled, obs, a, b, p, q, names, report)
    return _result(motion, out_P, out_filled, obs, report)


def _minority(frames, T: int) -> tuple[np.ndarray, np.ndarray]:
    """The stretches cut by the event ``frames`` (and the take's ends) and the indices of
    those of the labelling that holds on fewer frames (the one taken as wrong)."""
    bounds = np.unique(np.concatenate([[0, T], np.asarray(frames, int)]))
    parity = np.arange(len(bounds) - 1) % 2
    lengths = np.diff(bounds)
    wrong = int(lengths[parity == 1].sum() > lengths[parity == 0].sum())
    return bounds, np.flatnonzero(parity != wrong)


def _exchange(P: np.ndarray, filled: np.ndarray, obs: np.ndarray, a: int, b: int, s: int, e: int,
              names: list, report: dict, ok: bool = True, left: str = "unrepaired") -> None:
    """Exchange markers ``a`` and ``b`` over frames ``s:e`` in place -- samples, observed
    and filled flags -- when ``ok`` and no frame has both hidden (there a swap back could
    hide), and report it as repaired (with the markers ``hidden`` in part of it after the
    exchange: gaps for the fill), else under ``left``."""
    who = [names[a], names[b]]
    if not ok or _both_hidden(obs, a, b, s, e):
        report[left].append({"markers": who, "start": s, "stop": e})
        return
    for X in (P, filled, obs):
        X[s:e, [a, b]] = X[s:e, [b, a]]
    entry = {"markers": who, "start": s, "stop": e}
    hidden = [names[x] for x in (a, b) if not obs[s:e, x].all()]
    if hidden:
        entry["hidden"] = hidden
    report["repaired"].append(entry)


def _both_hidden(obs: np.ndarray, a: int, b: int, s: int, e: int) -> bool:
    """Whether markers ``a`` and ``b`` are both missing at a frame of ``s:e``: a change of
    labels there is not seen (with one of them measured, its label's path shows it)."""
    return bool((~obs[s:e, a] & ~obs[s:e, b]).any())


def _result(motion: Motion, P: np.ndarray, filled: np.ndarray, obs: np.ndarray, report: dict
            ) -> tuple[Motion, dict]:
    """``motion`` itself when nothing was put back, else the repaired one with the report
    in its source."""
    if not report["repaired"]:
        return motion, report
    src = dict(motion.source)
    src["swaps"] = report
    return Motion(P, motion.skeleton, motion.fps, obs, src, filled), report


def repair_side_flips(motion: Motion, **options) -> tuple[Motion, dict]:
    """``motion`` with a depth camera's body-side flips put back, and a report.

    A skeleton tracker that loses which side of the body faces it (Kinect, as the subject
    turns) writes every left joint under the right label and the other way round from one
    frame on. Per left-right pair of the skeleton (:func:`mocapkit.frames.mirror_permutation`),
    :func:`find_swaps` finds the frames where the pair's exchange explains a step of both
    (``partner`` = the mirror); a frame where at least :data:`FLIP_PAIRS` pairs do so is a
    flip. Each pair's own steps at the flips cut the take into stretches of alternate
    sides, and those of the side that holds on fewer frames are exchanged back (a flip may
    take the arms and not the legs). The distance test of :func:`repair_swaps` is not
    used: distances cannot tell a mirrored body from a right one; what stands for it is
    that several pairs step together. A stretch with a missing joint is left
    (``unrepaired``).

    ``options`` go to :func:`find_swaps`. Report: ``events`` (as :func:`repair_swaps`),
    ``flips`` (frames), ``repaired`` / ``unrepaired`` (stretches: the pair's joints, start,
    stop). Returns ``motion`` itself when nothing was put back or the
    skeleton has no left-right pairs.

    Measured (2026-12-06, the 567 MSR-Action3D skeleton files): flips in 7 files, all
    put back; e.g. a17_s03_e02, whose first 6 frames had the two sides exchanged.
    """
    from .frames import mirror_permutation

    names = list(motion.skeleton.names)
    report: dict = {"events": [], "flips": [], "repaired": [], "unrepaired": []}
    mirror = mirror_permutation(motion.skeleton)
    if mirror is None or (mirror == np.arange(len(names))).all():
        return motion, report
    P = np.asarray(motion.positions)
    obs = np.asarray(motion.observed) & np.isfinite(P).all(axis=2)
    events = find_swaps(P, obs, partner=mirror, **options)
    report["events"] = [{"frame": e.frame, "markers": [names[e.a], names[e.b]], "step_cm": e.step_cm}
                        for e in events]
    frames, counts = np.unique([e.frame for e in events], return_counts=True)
    flips = frames[counts >= FLIP_PAIRS] if len(events) else np.zeros(0, int)
    report["flips"] = [int(f) for f in flips]
    if not len(flips):
        return motion, report
    T = P.shape[0]
    out_P, out_filled = P.copy(), np.asarray(motion.filled).copy()
    for a, b in sorted({(e.a, e.b) for e in events}):
        # this pair's own steps at the flips (a flip may take the arms and not the legs)
        mine = [e.frame for e in events if (e.a, e.b) == (a, b) and e.frame in set(report["flips"])]
        if not mine:
            continue
        bounds, minority = _minority(mine, T)
        for i in minority:
            _exchange(out_P, out_filled, obs, a, b, int(bounds[i]), int(bounds[i + 1]), names, report)
    return _result(motion, out_P, out_filled, obs, report)


def repair_labels(motion: Motion) -> tuple[Motion, dict | None]:
    """The label repair that fits the capture: :func:`repair_swaps` on a marker capture
    (:func:`mocapkit.denoise.is_marker_capture`), :func:`repair_side_flips` on a Kinect
    skeleton, none on another skeleton (its joints are forward kinematics of one body:
    no label to trade). Returns the motion and the report (None: not looked at)."""
    from .denoise import is_marker_capture

    if is_marker_capture(motion):
        return repair_swaps(motion)
    if motion.source.get("format") == "kinect":
        return repair_side_flips(motion)
    return motion, None


def summary_line(report: dict | None) -> str | None:
    """One line for a user: the swaps put back and those left (None when there is no event
    and nothing was put back).

    >>> summary_line({"events": [1, 2], "repaired": [{"markers": ["A", "B"], "start": 80, "stop": 120}],
    ...               "unrepaired": []})
    'label swaps: 1 stretch put back (A/B frames 80-119)'
    """
    if not report or not (report.get("events") or report.get("repaired")):
        return None

    def spans(items: list[dict]) -> str:
        # per pair, its stretches (a labeller trades the same two markers back and forth)
        pairs: dict[tuple, list[dict]] = {}
        for x in items:
            pairs.setdefault(tuple(x["markers"]), []).append(x)
        shown = []
        for who, xs in list(pairs.items())[:4]:
            frames = ", ".join(f"{x['start']}" + (f"-{x['stop'] - 1}" if x["stop"] - x["start"] > 1 else "")
                               for x in xs[:4]) + (", ..." if len(xs) > 4 else "")
            hidden = sorted({h for x in xs for h in x.get("hidden", [])})
            shown.append(f"{'/'.join(who)} frames {frames}"
                         + (f", {' and '.join(hidden)} then missing" if hidden else ""))
        return "; ".join(shown) + ("; ..." if len(pairs) > 4 else "")

    rep, left = report.get("repaired", []), report.get("unrepaired", [])
    parts = []
    if report.get("flips"):
        parts.append(f"body-side flip(s) at frame {', '.join(map(str, report['flips'][:6]))}"
                     + (", ..." if len(report["flips"]) > 6 else ""))
    if rep:
        parts.append(f"{len(rep)} stretch{'es' if len(rep) > 1 else ''} put back ({spans(rep)})")
    if left:
        parts.append(f"{len(left)} left as measured (a frame with both hidden, or their distances to their "
                     f"partners say they are labelled right: {spans(left)})")
    if not parts:
        return None                                # a lone step of a pair: no evidence of a swap
    return "label swaps: " + "; ".join(parts)
