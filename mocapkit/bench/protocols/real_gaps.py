"""``real-gaps``: gap filling on real occlusion patterns with known truth (issue #15, item 1).

Protocol
--------
*Mask sources*: every capture under ``<data>/markers`` that has real gaps (C3D: missing =
negative residual, read with :func:`mocapkit.io.read`), more than 2 frames, and is not a
byte-identical copy of another source (``ezc3d/Vicon.c3d`` = ``pyomeca/markers_analogs.c3d``)
or, for TRC, a copy of another source's mask. With the shared data set these are
``kineticstoolkit/kinematics_basket_sprint.c3d`` (26 markers, 120 Hz, 39 % missing),
``kineticstoolkit/kinematics_tennis_serve_nan.c3d`` (39 markers, 0.3 %),
``c3d_org/Eb015pr.c3d`` (26 markers, 1.9 %), ``pyomeca/markers_analogs.c3d``
(51 markers, 1.0 %), ``ezc3d/BTS.c3d`` (22 markers, 52 %, 239 frames without any
marker) and ``ezc3d/Optotrak.c3d`` (54 markers, 3.8 %; a truncated file of which the
reader recovers 29 frames, so its 1 s mask wraps around on every target); files that
cannot be read, have no gaps or <= 2 frames are skipped and listed in the setup row.

*Targets* with known truth, gap-free real captures: ``kinematics_tennis_serve.c3d``
(39 markers, 50 Hz), ``kinematics_tennis_serve_2players.c3d`` (78 markers),
``hdm05/HDM_dg_06-03_03_120.c3d`` (44 markers, 120 Hz) and four CMU clips read as
*virtual markers* (the 31 joint positions of the ASF/AMC file, 120 Hz, presented as an
unlinked marker set like a C3D: no hierarchy, ``source['format'] = 'virtual-markers'``):
16_15 walk, 09_06 run, 05_02 dance, 135_04 front kick. A target marker that is not
observed in every frame is dropped, and so is one that is an exact copy of another
marker (HDM05's unlabelled ``*0``-``*2`` repeat LFWT, CLAV and LFHD: a copy would hand
the truth to any fill that reads other markers), so HDM05 has 41 markers here.

*Transplant* (:func:`mocapkit.occlusion.transplant_mask`): the source mask is resampled
to the target frame rate (nearest frame, duration in seconds kept), one seeded time
offset per case (per block of source columns when the target has more markers than the
source) keeps the co-missing structure, source columns go to target markers by a seeded
permutation, no black-out frame is invented. One case = (source, target); seed =
``ctx.seed`` mixed with the CRC-32 of the pair's names.

*Methods* in the same run: peers ``linear`` (per-marker linear interpolation, leading and
trailing gaps held at the nearest observed value), ``cubic`` (scipy ``CubicSpline``
through the observed frames of each marker, edges held), ``kineticstoolkit``
(``TimeSeries.fill_missing_samples(0)``, its defaults: linear, edges extrapolated;
skipped with a note when kineticstoolkit is not installed); mocapkit methods by
registry name (``kalman-cv``, ``svt``, ``trnn``, ``tsmc``, ``dynammo``, ``auto`` and
whichever of ``fill-rigid``, ``fill-pattern``, ``fill-pca``, ``fill-auto`` are registered) with their
default settings, and ``default`` = ``denoise.default()`` (when that is a registered method with the same settings that
already ran on the case, its result is reused rather than computed twice). Each is called
as ``method.denoise(masked_motion)``; an exception is recorded as a failure row (``metric = 'failed'``) and the run goes on. The mocapkit
methods run under the user-facing gap policy (:data:`mocapkit.gaps.DEFAULT_POLICY`, the
protocol is registered with ``fill_all=False``): what a method cannot support is left
missing, and ``coverage`` says how much it filled. The peers are plain functions of this
module, outside that policy (what the tools practitioners use do). A peer leaves
a marker with fewer than 2 (linear, cubic, kineticstoolkit) observed frames missing.

*Scores* per case and pooled, over the hidden samples (observed in the truth, hidden by
the mask):

- ``rmse`` (cm): per-coordinate RMSE (:func:`mocapkit.metrics.rmse` convention) over the
  hidden samples the method filled (output observed there); ``coverage`` (%) = filled /
  hidden; methods may leave unsupported samples missing.
- ``gross_pct`` (%): filled samples whose 3-D error exceeds 20 cm; ``max_err`` (cm):
  largest 3-D error; ``outside_1m``: filled samples more than 1 m (Euclidean) outside the
  axis-aligned bounding box of the target's observed samples (the capture volume).
- ``ratio_best_peer``: the method's RMSE divided by the best peer's RMSE, both on exactly
  the samples the method filled (and every peer filled), so unequal coverage compares
  like with like; the peers' RMSE on those samples are in the row's ``extra``.
- ``rmse_all_hidden`` (cm): RMSE over every hidden sample, only where the method filled
  them all.
- ``missing_pct`` (method ``mask``): share of the case's samples that are missing.
- ``estimate_ratio``: for a method that estimates its own error (``auto``, ``fill-auto``:
  :func:`own_estimate`), that estimate divided by the true RMSE over what it covers
  (``auto``: every sample written, the measured ones included; ``fill-auto``: its fills);
  the target rows give the share of scored cases within a factor
  :data:`ESTIMATE_FACTOR` (issue #19's test of the estimate, here on real occlusions).

The targets of issue #15 are read on the cases with at most 60 % missing
(:data:`SCORED_MAX_MISSING`): rows with ``clip = 'targets'``.

*Vendor fill*: ``kinematics_tennis_serve.c3d`` is the vendor's gap-filled twin of
``kinematics_tennis_serve_nan.c3d``. For the real gaps of the ``_nan`` file each method's
RMS distance to the vendor's fill is reported (``rms_to_vendor_fill``, cm). The vendor's
fill is not ground truth: this says how far a method is from what the vendor's software
produced, not how right it is.

``ctx.quick``: two sources x two targets cropped to 200 frames and the vendor row on a
200-frame window, in seconds. ``ctx.options``: ``methods`` (list of names to run, peers
included), ``sources`` / ``targets`` (lists of keys), ``max_frames`` (crop), ``log`` (a
callable receiving one progress line per finished case).
"""
from __future__ import annotations

import hashlib
import warnings
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from ...errors import MocapError
from ...motion import Motion
from ...occlusion import apply_mask, drop_duplicate_markers, fully_observed_markers, transplant_mask
from ..core import Context, Row, Timer, progress, protocol

PROTOCOL = "real-gaps"
SCORED_MAX_MISSING = 60.0
GROSS_CM = 20.0
OUTSIDE_CM = 100.0
PEERS = ("linear", "cubic", "kineticstoolkit")
#: issue #19: a self-validating method's estimated error within this factor of the true one
ESTIMATE_FACTOR = 1.5
MOCAPKIT_METHODS = ("kalman-cv", "svt", "trnn", "tsmc", "dynammo",
                    "fill-rigid", "fill-pattern", "fill-pca", "fill-auto", "auto")
PREFERRED_SOURCES = ("kineticstoolkit/kinematics_basket_sprint.c3d",
                     "kineticstoolkit/kinematics_tennis_serve_nan.c3d",
                     "c3d_org/Eb015pr.c3d",
                     "pyomeca/markers_analogs.c3d",
                     "pyomeca/markers.trc",
                     "ezc3d/BTS.c3d")
MARKER_TARGETS = ("kineticstoolkit/kinematics_tennis_serve.c3d",
                  "kineticstoolkit/kinematics_tennis_serve_2players.c3d",
                  "hdm05/HDM_dg_06-03_03_120.c3d")
CMU_TARGETS = ("16_15", "09_06", "05_02", "135_04")
QUICK_SOURCES = ("kineticstoolkit/kinematics_basket_sprint.c3d", "c3d_org/Eb015pr.c3d")
QUICK_TARGETS = ("kineticstoolkit/kinematics_tennis_serve.c3d", "cmu:16_15")
QUICK_FRAMES = 200
VENDOR_FILLED = "kineticstoolkit/kinematics_tennis_serve.c3d"
VENDOR_GAPS = "kineticstoolkit/kinematics_tennis_serve_nan.c3d"


# ---------------------------------------------------------------------------------------
# data
# ---------------------------------------------------------------------------------------
def find_sources(data_dir: Path, keys: Any = None) -> tuple[list[tuple[str, Motion]], list[str]]:
    """Mask sources ``[(key, motion)]`` under ``data_dir/markers`` and notes on skipped files.

    Keeps files with > 2 frames and some missing sample; drops byte-identical copies and
    TRC/C3D files whose mask equals an earlier source's.
    """
    from ... import io

    root = Path(data_dir) / "markers"
    found = sorted(str(p.relative_to(root)) for p in root.rglob("*")
                   if p.is_file() and p.suffix.lower() in (".c3d", ".trc"))
    order = [k for k in PREFERRED_SOURCES if k in found] + [k for k in found if k not in PREFERRED_SOURCES]
    if keys is not None:
        order = [k for k in order if k in set(keys)]
    out: list[tuple[str, Motion]] = []
    notes: list[str] = []
    digests: dict[str, str] = {}
    for key in order:
        path = root / key
        dig = hashlib.sha256(path.read_bytes()).hexdigest()
        if dig in digests:
            notes.append(f"{key}: skipped, byte-identical to {digests[dig]}")
            continue
        digests[dig] = key
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")     # header mismatches etc. are the file's business
                m = io.read(path)
        except MocapError as e:
            notes.append(f"{key}: skipped, unreadable ({str(e).splitlines()[0][:120]})")
            continue
        if m.n_frames <= 2:
            notes.append(f"{key}: skipped, {m.n_frames} frames")
            continue
        if m.observed.all():
            notes.append(f"{key}: skipped, no gaps")
            continue
        same = [k for k, s in out if s.observed.shape == m.observed.shape
                and np.array_equal(s.observed, m.observed)]
        if same:
            notes.append(f"{key}: skipped, same mask as {same[0]}")
            continue
        out.append((key, m))
    return out, notes


def virtual_markers(motion: Motion) -> Motion:
    """Joint positions of a skeletal clip as an unlinked marker set (like a C3D's points)."""
    from ...skeleton import Skeleton

    J = motion.n_joints
    sk = Skeleton(tuple(motion.skeleton.names), -np.ones(J, dtype=int), np.zeros((J, 3)))
    src = {"path": motion.source.get("path", ""), "format": "virtual-markers",
           "units": {"name": "cm", "factor_to_cm": 1.0, "chosen_by": "joint positions"}}
    return Motion(motion.positions, sk, motion.fps, motion.observed, src)


def find_targets(data_dir: Path, keys: Any = None) -> tuple[list[tuple[str, Motion]], list[str]]:
    """Targets ``[(key, motion)]`` restricted to their fully observed markers, and notes."""
    from ... import io
    from ...datasets import cmu_amc

    want = list(MARKER_TARGETS) + [f"cmu:{t}" for t in CMU_TARGETS]
    if keys is not None:
        want = [k for k in want if k in set(keys)] + [k for k in keys if k not in want]
    out, notes = [], []
    for key in want:
        try:
            if key.startswith("cmu:"):
                p = cmu_amc(key[4:], data_dir)
                if p is None or not str(p).startswith(str(data_dir)):
                    notes.append(f"{key}: not in the data set")
                    continue
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    m = virtual_markers(io.read(p))
            else:
                p = Path(data_dir) / "markers" / key
                if not p.is_file():
                    notes.append(f"{key}: not in the data set")
                    continue
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    m = io.read(p)
            n0 = m.n_joints
            m = fully_observed_markers(m)
            n1 = m.n_joints
            m, dup = drop_duplicate_markers(m)
        except MocapError as e:
            notes.append(f"{key}: skipped ({str(e).splitlines()[0][:120]})")
            continue
        if n1 < n0:
            notes.append(f"{key}: dropped {n0 - n1} markers not observed in every frame")
        if dup:
            notes.append(f"{key}: dropped {len(dup)} markers that exactly copy another marker "
                         f"({', '.join(dup)})")
        out.append((key, m))
    return out, notes


def short(key: str) -> str:
    """Display name of a source/target key."""
    return Path(key.replace("cmu:", "cmu_")).stem


# ---------------------------------------------------------------------------------------
# peers
# ---------------------------------------------------------------------------------------
def fill_linear(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation per marker, edges held (the package's one gap filler,
    :func:`mocapkit.gaps.fill`, without the gap policy); markers with < 2 observed
    frames left missing."""
    from ...gaps import fill as _fill

    few = motion.observed.sum(axis=0) < 2
    X = _fill(motion.matrix(), motion.matrix_mask() & ~np.repeat(few, 3)[None, :])
    obs = np.isfinite(X).reshape(motion.n_frames, motion.n_joints, 3).all(axis=2)
    return X.reshape(motion.positions.shape), obs


def fill_cubic(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """scipy CubicSpline (not-a-knot) through each marker's observed frames; edges held."""
    from scipy.interpolate import CubicSpline

    P = np.array(motion.positions)
    obs = motion.observed.copy()
    t = np.arange(motion.n_frames)
    for j in np.flatnonzero(~obs.all(axis=0)):
        m = motion.observed[:, j]
        if m.sum() < 2:
            continue
        to = t[m]
        miss = np.flatnonzero(~m)
        inner = miss[(miss > to[0]) & (miss < to[-1])]
        if len(inner):
            P[inner, j] = CubicSpline(to, P[m, j], axis=0)(inner)
        P[miss[miss < to[0]], j] = P[to[0], j]
        P[miss[miss > to[-1]], j] = P[to[-1], j]
        obs[:, j] = True
    return P, obs


def kineticstoolkit_available() -> bool:
    try:
        import kineticstoolkit  # noqa: F401
    except Exception:  # noqa: BLE001  (any import problem: the peer is skipped)
        return False
    return True


def fill_kineticstoolkit(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """``ktk.TimeSeries.fill_missing_samples(0)`` (defaults: linear, edges extrapolated)."""
    import kineticstoolkit as ktk

    P = np.array(motion.positions)
    obs = motion.observed.copy()
    ts = ktk.TimeSeries(time=np.arange(motion.n_frames) / motion.fps)
    names = {}
    for j in np.flatnonzero(~obs.all(axis=0)):
        if motion.observed[:, j].sum() >= 2:
            names[f"m{j}"] = j
            ts.data[f"m{j}"] = P[:, j].copy()
    if names:
        out = ts.fill_missing_samples(0)
        for k, j in names.items():
            P[:, j] = out.data[k]
            obs[:, j] = np.isfinite(P[:, j]).all(axis=1)
    return P, obs


PEER_FUNCS: dict[str, Callable[[Motion], tuple[np.ndarray, np.ndarray]]] = {
    "linear": fill_linear, "cubic": fill_cubic, "kineticstoolkit": fill_kineticstoolkit}


def method_list(ctx: Context) -> tuple[list[str], list[str]]:
    """Method names of this run (peers first) and notes on what is skipped."""
    from ... import denoise

    have = denoise.available()
    notes = []
    names = ["linear", "cubic"]
    if kineticstoolkit_available():
        names.append("kineticstoolkit")
    else:
        notes.append("kineticstoolkit: not installed, peer skipped (pip install 'mocapkit[bench]')")
    for n in MOCAPKIT_METHODS:
        if n in have:
            names.append(n)
        elif not n.startswith("fill-"):
            notes.append(f"{n}: not registered, skipped")
    names.append("default")
    want = ctx.options.get("methods")
    if want is not None:
        names = [n for n in names if n in set(want)]
    return names, notes


#: what a runner returns: positions (T, J, 3), observed (T, J), the method's own error
#: estimate (:func:`own_estimate`; None for a peer or a method without one)
RunResult = tuple[np.ndarray, np.ndarray, "tuple[float, str] | None"]


def make_runner(name: str, motion: Motion) -> tuple[Callable[[Motion], RunResult], str]:
    """A callable filling ``motion`` for method ``name`` and a description of what ran."""
    if name in PEER_FUNCS:
        peer = PEER_FUNCS[name]
        return (lambda m: (*peer(m), None)), name
    from ... import denoise

    if name == "default":
        meth = denoise.default()
    else:
        meth = denoise.get(name)

    def run(m: Motion) -> RunResult:
        est = meth.denoise(m)
        if not isinstance(est, Motion) or est.positions.shape != m.positions.shape:
            shape = getattr(getattr(est, "positions", None), "shape", type(est).__name__)
            raise MocapError(f"returned {shape}, expected a Motion of shape {m.positions.shape}")
        return np.asarray(est.positions), np.asarray(est.observed), own_estimate(est)

    return run, repr(meth)


def own_estimate(out: Motion) -> tuple[float, str] | None:
    """The error a self-validating method says its result has, and over what: ``auto``'s
    ``estimated_rmse_cm`` (every sample it wrote: ``'written'``) or ``fill-auto``'s (its
    fills: ``'fills'``); None for a method that gives none."""
    a = out.source.get("auto")
    if isinstance(a, dict) and a.get("estimated_rmse_cm") is not None:
        return float(a["estimated_rmse_cm"]), "written"
    f = out.source.get("fill_auto")
    if isinstance(f, dict) and f.get("estimated_rmse_cm") is not None:
        return float(f["estimated_rmse_cm"]), "fills"
    return None


# ---------------------------------------------------------------------------------------
# scoring
# ---------------------------------------------------------------------------------------
def capture_box(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounding box (lo, hi), cm, of the observed samples of ``motion``."""
    P = motion.positions[motion.observed]
    return P.min(axis=0), P.max(axis=0)


@dataclass
class Fill:
    """Per-sample scoring of one method on one case (arrays (T, J))."""

    hidden: np.ndarray
    filled: np.ndarray
    err2: np.ndarray           # squared 3-D error, NaN where not filled
    outside: np.ndarray        # filled and > OUTSIDE_CM outside the box
    zero: np.ndarray           # filled with exactly (0, 0, 0)
    measured_sse: float = 0.0  # squared 3-D error summed over the measured samples written
    n_measured: int = 0

    def true_error(self, scope: str) -> float:
        """RMSE per coordinate (cm) over what an estimate of ``scope`` covers: the fills, or
        every sample written (fills and measured samples)."""
        if scope == "fills":
            return _rmse(self.sse(), self.n_filled)
        return _rmse(self.sse() + self.measured_sse, self.n_filled + self.n_measured)

    @property
    def n_hidden(self) -> int:
        return int(self.hidden.sum())

    @property
    def n_filled(self) -> int:
        return int(self.filled.sum())

    def sse(self, sel: np.ndarray | None = None) -> float:
        s = self.filled if sel is None else sel
        return float(self.err2[s].sum())

    def summary(self) -> dict[str, Any]:
        n = self.n_filled
        e = np.sqrt(self.err2[self.filled])
        return {"n_hidden": self.n_hidden, "n_filled": n,
                "coverage": 100.0 * n / max(self.n_hidden, 1),
                "rmse": float(np.sqrt(self.sse() / (3 * n))) if n else float("nan"),
                "n_gross": int((e > GROSS_CM).sum()),
                "gross_pct": 100.0 * float((e > GROSS_CM).mean()) if n else float("nan"),
                "outside_1m": int(self.outside.sum()),
                "max_err": float(e.max()) if n else float("nan"),
                "zero_fills": int(self.zero.sum())}


def score_fill(truth: np.ndarray, hidden: np.ndarray, est: np.ndarray, est_observed: np.ndarray,
               box: tuple[np.ndarray, np.ndarray]) -> Fill:
    """Score a fill against the truth.

    Parameters
    ----------
    truth : (T, J, 3) cm, finite where scored.
    hidden : (T, J) bool, samples hidden from the method (scored).
    est, est_observed : (T, J, 3) cm and (T, J) bool, the method's output; a hidden
        sample counts as filled where ``est_observed`` is True and ``est`` finite.
    box : (lo, hi) (3,) cm, the capture volume.
    """
    hidden = np.asarray(hidden, dtype=bool) & np.isfinite(truth).all(axis=2)
    est = np.asarray(est, dtype=float)
    filled = hidden & np.asarray(est_observed, dtype=bool) & np.isfinite(est).all(axis=2)
    d = np.where(filled[..., None], est - truth, np.nan)
    err2 = np.sum(d * d, axis=2)
    lo, hi = (np.asarray(b, dtype=float) for b in box)
    with np.errstate(invalid="ignore"):
        out = np.maximum(np.maximum(lo - est, est - hi), 0.0)
        dist = np.sqrt(np.sum(out * out, axis=2))
    outside = filled & (dist > OUTSIDE_CM)
    zero = filled & (np.where(filled[..., None], est, 1.0) == 0.0).all(axis=2)
    measured = ~hidden & np.asarray(est_observed, dtype=bool) & np.isfinite(truth).all(axis=2) \
        & np.isfinite(est).all(axis=2)
    msse = float(np.sum((est[measured] - truth[measured]) ** 2))
    return Fill(hidden, filled, err2, outside, zero, msse, int(measured.sum()))


def _rmse(sse: float, n: int) -> float:
    return float(np.sqrt(sse / (3 * n))) if n else float("nan")


# ---------------------------------------------------------------------------------------
# the protocol
# ---------------------------------------------------------------------------------------
@dataclass
class CaseResult:
    clip: str
    condition: str
    missing_pct: float
    fills: dict[str, Fill] = field(default_factory=dict)
    errors: dict[str, str] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    ran: dict[str, str] = field(default_factory=dict)
    estimates: dict[str, tuple[float, str]] = field(default_factory=dict)   # own_estimate


def case_seed(seed: int, source: str, target: str) -> int:
    return (int(seed) * 1_000_003 + zlib.crc32(f"{source}|{target}".encode())) % (2 ** 32)


def run_methods(case: CaseResult, truth: np.ndarray, inp: Motion, hidden: np.ndarray,
                methods: list[str]) -> None:
    """Run every method on ``inp`` and score it into ``case`` (failures recorded, not raised)."""
    box = capture_box(inp)
    for name in methods:
        if name == "default":
            same = _same_as_registered(inp, case)
            if same is not None:
                # the default is a registered method with the same settings that already
                # ran on this very input: deterministic, so its fill is the default's fill
                case.ran[name] = f"{case.ran[same]} (= {same}, result reused)"
                case.seconds[name] = case.seconds[same]
                case.fills[name] = case.fills[same]
                if same in case.estimates:
                    case.estimates[name] = case.estimates[same]
                continue
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                runner, desc = make_runner(name, inp)
                with Timer() as t:
                    P, obs, estimate = runner(inp)
            case.ran[name] = desc
            case.seconds[name] = t.seconds
            case.fills[name] = score_fill(truth, hidden, P, obs, box)
            if estimate is not None:
                case.estimates[name] = estimate
        except Exception as e:  # noqa: BLE001  (a crash is a result)
            msg = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"[:300]
            case.errors[name] = msg


def _same_as_registered(inp: Motion, case: CaseResult) -> str | None:
    """Name of an already-run registered method identical (class and settings) to the default."""
    from ... import denoise

    try:
        meth = denoise.default()
    except Exception:  # noqa: BLE001  (run_methods records the failure)
        return None
    for name, desc in case.ran.items():
        if name in case.fills and name == getattr(meth, "name", None) and desc == repr(meth):
            return name
    return None


def case_rows(case: CaseResult, methods: list[str]) -> Iterator[Row]:
    """Per-case rows: mask missing %, and per method rmse, coverage, gross %, outside, max, ratio."""
    base = {"missing_pct": round(case.missing_pct, 3)}
    yield Row(PROTOCOL, case.clip, case.condition, "mask", "missing_pct", "%", case.missing_pct,
              extra=dict(base))
    peers = [p for p in PEERS if p in case.fills]
    for name in methods:
        if name in case.errors:
            yield Row(PROTOCOL, case.clip, case.condition, name, "failed", "", 1.0,
                      extra={**base, "error": case.errors[name]})
            continue
        if name not in case.fills:
            continue
        f = case.fills[name]
        s = f.summary()
        sec = case.seconds[name]
        sel = f.filled.copy()
        for p in peers:
            sel &= case.fills[p].filled
        n_sel = int(sel.sum())
        peer_same = {p: _rmse(case.fills[p].sse(sel), n_sel) for p in peers}
        own_same = _rmse(f.sse(sel), n_sel)
        ex = {**base, "n_hidden": s["n_hidden"], "n_filled": s["n_filled"],
              "zero_fills": s["zero_fills"], "n_same": n_sel, "rmse_same": own_same,
              "peer_rmse_same": peer_same}
        if name == "default":
            ex["ran"] = case.ran[name]
        yield Row(PROTOCOL, case.clip, case.condition, name, "rmse", "cm", s["rmse"],
                  seconds=sec, n=s["n_filled"], extra=ex)
        yield Row(PROTOCOL, case.clip, case.condition, name, "coverage", "%", s["coverage"],
                  seconds=sec, n=s["n_hidden"], extra=dict(base))
        yield Row(PROTOCOL, case.clip, case.condition, name, "gross_pct", "%", s["gross_pct"],
                  n=s["n_filled"], extra=dict(base))
        yield Row(PROTOCOL, case.clip, case.condition, name, "outside_1m", "samples",
                  float(s["outside_1m"]), extra=dict(base))
        yield Row(PROTOCOL, case.clip, case.condition, name, "max_err", "cm", s["max_err"],
                  extra=dict(base))
        if n_sel and peers:
            best = min(peers, key=lambda p: peer_same[p])
            ratio = own_same / peer_same[best] if peer_same[best] > 0 else float("nan")
            yield Row(PROTOCOL, case.clip, case.condition, name, "ratio_best_peer", "x", ratio,
                      n=n_sel, extra={**base, "best_peer": best})
        if s["n_filled"] == s["n_hidden"]:
            yield Row(PROTOCOL, case.clip, case.condition, name, "rmse_all_hidden", "cm", s["rmse"],
                      n=s["n_hidden"], extra=dict(base))
        if name in case.estimates and s["n_filled"]:
            value, scope = case.estimates[name]
            true = f.true_error(scope)
            yield Row(PROTOCOL, case.clip, case.condition, name, "estimate_ratio", "x",
                      value / true if true > 0 else float("nan"),
                      extra={**base, "estimate_cm": value, "true_cm": true, "over": scope})


def pooled_rows(cases: list[CaseResult], methods: list[str], clip: str, condition: str) -> Iterator[Row]:
    """Pooled over ``cases``: sums of squared errors and counts, then the same metrics."""
    for name in methods:
        crashes = sum(name in c.errors for c in cases)
        got = [c for c in cases if name in c.fills]
        if not got:
            if crashes:
                yield Row(PROTOCOL, clip, condition, name, "crashes", "cases", float(crashes), n=len(cases))
            continue
        sse = n_f = n_h = n_g = n_out = n_zero = 0
        mx = 0.0
        sse_own = {p: 0.0 for p in PEERS}
        sse_peer = {p: 0.0 for p in PEERS}
        n_same = {p: 0 for p in PEERS}
        full_sse = full_n = full_cases = 0
        secs = 0.0
        for c in got:
            f = c.fills[name]
            s = f.summary()
            sse += f.sse()
            n_f += s["n_filled"]
            n_h += s["n_hidden"]
            n_g += s["n_gross"]
            n_out += s["outside_1m"]
            n_zero += s["zero_fills"]
            secs += c.seconds[name]
            if s["n_filled"]:
                mx = max(mx, s["max_err"])
            if s["n_filled"] == s["n_hidden"]:
                full_sse += f.sse()
                full_n += s["n_filled"]
                full_cases += 1
            for p in PEERS:
                if p in c.fills:
                    sel = f.filled & c.fills[p].filled
                    sse_own[p] += f.sse(sel)
                    sse_peer[p] += c.fills[p].sse(sel)
                    n_same[p] += int(sel.sum())
        ex = {"cases": len(got), "zero_fills": n_zero}
        yield Row(PROTOCOL, clip, condition, name, "rmse", "cm", _rmse(sse, n_f), seconds=secs, n=n_f,
                  extra=ex)
        yield Row(PROTOCOL, clip, condition, name, "coverage", "%", 100.0 * n_f / max(n_h, 1), n=n_h)
        yield Row(PROTOCOL, clip, condition, name, "gross_pct", "%",
                  100.0 * n_g / n_f if n_f else float("nan"), n=n_f)
        yield Row(PROTOCOL, clip, condition, name, "outside_1m", "samples", float(n_out))
        yield Row(PROTOCOL, clip, condition, name, "max_err", "cm", mx if n_f else float("nan"))
        yield Row(PROTOCOL, clip, condition, name, "crashes", "cases", float(crashes), n=len(cases))
        if full_cases:
            yield Row(PROTOCOL, clip, condition, name, "rmse_all_hidden", "cm", _rmse(full_sse, full_n),
                      n=full_n, extra={"cases": full_cases})
        for p in PEERS:
            if n_same[p] and sse_peer[p] > 0:
                yield Row(PROTOCOL, clip, condition, name, f"ratio_{p}", "x",
                          float(np.sqrt(sse_own[p] / sse_peer[p])), n=n_same[p],
                          extra={"rmse_same": _rmse(sse_own[p], n_same[p]),
                                 "peer_rmse_same": _rmse(sse_peer[p], n_same[p])})


def target_rows(cases: list[CaseResult], methods: list[str]) -> Iterator[Row]:
    """The issue-#15 targets per method on the cases with <= 60 % missing."""
    cond = f"cases <= {SCORED_MAX_MISSING:g}% missing"
    scored = [c for c in cases if c.missing_pct <= SCORED_MAX_MISSING]
    for name in methods:
        ratios, est, worst_case = [], [], ""
        for c in scored:
            rows = {r.metric: r for r in case_rows(c, [name])}
            r = rows.get("ratio_best_peer")
            if r is not None and np.isfinite(r.value):
                ratios.append(r.value)
                if r.value >= max(ratios):
                    worst_case = f"{c.clip} / {c.condition}"
            r = rows.get("estimate_ratio")
            if r is not None and np.isfinite(r.value):
                est.append(r.value)
        crashes = sum(name in c.errors for c in scored)
        n_f = sum(c.fills[name].n_filled for c in scored if name in c.fills)
        n_h = sum(c.fills[name].n_hidden for c in scored if name in c.fills)
        n_g = sum(c.fills[name].summary()["n_gross"] for c in scored if name in c.fills)
        n_out = sum(int(c.fills[name].outside.sum()) for c in scored if name in c.fills)
        n_out_all = sum(int(c.fills[name].outside.sum()) for c in cases if name in c.fills)
        if ratios:
            yield Row(PROTOCOL, "targets", cond, name, "median_ratio_best_peer", "x",
                      float(np.median(ratios)), n=len(ratios))
            yield Row(PROTOCOL, "targets", cond, name, "worst_ratio_best_peer", "x",
                      float(max(ratios)), n=len(ratios), extra={"case": worst_case})
            yield Row(PROTOCOL, "targets", cond, name, "cases_worse_than_best_peer", "cases",
                      float(sum(r > 1.0 + 1e-9 for r in ratios)), n=len(ratios))
        if est:
            est_ = np.asarray(est)
            yield Row(PROTOCOL, "targets", cond, name, "estimate_within_1.5x", "%",
                      100.0 * float(np.mean((est_ >= 1 / ESTIMATE_FACTOR) & (est_ <= ESTIMATE_FACTOR))),
                      n=len(est), extra={"under": int((est_ < 1 / ESTIMATE_FACTOR).sum()),
                                         "over": int((est_ > ESTIMATE_FACTOR).sum()),
                                         "median_ratio": float(np.median(est_))})
        yield Row(PROTOCOL, "targets", cond, name, "gross_pct", "%",
                  100.0 * n_g / n_f if n_f else float("nan"), n=n_f)
        yield Row(PROTOCOL, "targets", cond, name, "coverage", "%", 100.0 * n_f / n_h if n_h else float("nan"),
                  n=n_h)
        yield Row(PROTOCOL, "targets", cond, name, "outside_1m", "samples", float(n_out),
                  extra={"all_cases": n_out_all})
        yield Row(PROTOCOL, "targets", cond, name, "zero_fills", "samples",
                  float(sum(int(c.fills[name].zero.sum()) for c in cases if name in c.fills)),
                  extra={"note": "filled samples exactly (0, 0, 0), all cases"})
        yield Row(PROTOCOL, "targets", cond, name, "crashes", "cases",
                  float(sum(name in c.errors for c in cases)), n=len(cases),
                  extra={"scored_cases": crashes})


def vendor_rows(ctx: Context, data: Path, methods: list[str], max_frames: int | None) -> Iterator[Row]:
    """RMS distance of each method's fill to the vendor's fill on the real gaps of the _nan file."""
    from ... import io

    pf, pg = data / "markers" / VENDOR_FILLED, data / "markers" / VENDOR_GAPS
    if not (pf.is_file() and pg.is_file()):
        return
    ref, gap = io.read(pf), io.read(pg)
    if ref.skeleton.names != gap.skeleton.names or ref.n_frames != gap.n_frames:
        return
    if max_frames is not None and gap.n_frames > max_frames:
        first = int(np.flatnonzero((~gap.observed).any(axis=1))[0])
        a = max(0, min(first - max_frames // 4, gap.n_frames - max_frames))
        ref, gap = ref.slice(a, a + max_frames), gap.slice(a, a + max_frames)
    hidden = ~gap.observed & ref.observed
    cond = "real gaps; distance to the vendor's fill (not truth)"
    case = CaseResult("tennis_serve_vendor", cond, 100.0 * gap.missing_fraction)
    run_methods(case, np.asarray(ref.positions), gap, hidden, methods)
    base = {"missing_pct": round(case.missing_pct, 3), "note": "the vendor fill is not ground truth"}
    yield Row(PROTOCOL, case.clip, cond, "mask", "missing_pct", "%", case.missing_pct, extra=dict(base))
    for name in methods:
        if name in case.errors:
            yield Row(PROTOCOL, case.clip, cond, name, "failed", "", 1.0,
                      extra={**base, "error": case.errors[name]})
        elif name in case.fills:
            s = case.fills[name].summary()
            yield Row(PROTOCOL, case.clip, cond, name, "rms_to_vendor_fill", "cm", s["rmse"],
                      seconds=case.seconds[name], n=s["n_filled"],
                      extra={**base, "coverage": s["coverage"], "max_dist": s["max_err"]})


@protocol(PROTOCOL, "real occlusion masks transplanted onto gap-free real captures; gap RMSE, "
                    "gross %, out-of-volume fills vs linear/cubic/kineticstoolkit (issue #15)",
          fill_all=False)
def real_gaps(ctx: Context) -> Iterator[Row]:
    data = ctx.need_data()
    opts = ctx.options
    src_keys = opts.get("sources", QUICK_SOURCES if ctx.quick else None)
    tgt_keys = opts.get("targets", QUICK_TARGETS if ctx.quick else None)
    max_frames = opts.get("max_frames", QUICK_FRAMES if ctx.quick else None)
    sources, notes_s = find_sources(data, src_keys)
    targets, notes_t = find_targets(data, tgt_keys)
    methods, notes_m = method_list(ctx)
    notes = notes_s + notes_t + notes_m
    yield Row(PROTOCOL, "setup", "notes", "-", "notes", "", float(len(notes)),
              extra={"notes": notes, "sources": [k for k, _ in sources], "targets": [k for k, _ in targets],
                     "methods": methods, "quick": bool(ctx.quick)})
    cases: list[CaseResult] = []
    skipped: list[str] = []
    pairs = [(s, t) for s in sources for t in targets]
    for (skey, src), (tkey, tgt) in progress(pairs, total=len(pairs), desc=PROTOCOL, enable=ctx.progress):
        if max_frames is not None and tgt.n_frames > max_frames:
            tgt = tgt.slice(0, max_frames)
        seed = case_seed(ctx.seed, skey, tkey)
        tr = transplant_mask(src.observed, src.fps, tgt.n_frames, tgt.n_joints, tgt.fps, seed=seed)
        inp = apply_mask(tgt, tr.observed)
        hidden = ~inp.observed
        if not hidden.any():
            skipped.append(f"{short(tkey)} / mask={short(skey)}: the mask window hides no sample")
            continue
        case = CaseResult(short(tkey), f"mask={short(skey)}", 100.0 * inp.missing_fraction)
        run_methods(case, np.asarray(tgt.positions), inp, hidden, methods)
        cases.append(case)
        if callable(opts.get("log")):
            opts["log"](f"{case.clip} {case.condition}: {case.missing_pct:.1f} % missing, "
                        f"{sum(case.seconds.values()):.1f} s in methods, {len(case.errors)} failures")
        yield from case_rows(case, methods)
    yield Row(PROTOCOL, "setup", "skipped cases", "-", "skipped", "cases", float(len(skipped)),
              extra={"notes": skipped, "cases": len(cases)})
    yield from pooled_rows(cases, methods, "pooled", "all cases")
    scored = [c for c in cases if c.missing_pct <= SCORED_MAX_MISSING]
    yield from pooled_rows(scored, methods, "pooled", f"cases <= {SCORED_MAX_MISSING:g}% missing")
    yield from target_rows(cases, methods)
    yield from vendor_rows(ctx, data, methods, max_frames)
