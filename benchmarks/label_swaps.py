"""Label swaps planted in real captures: how many :mod:`mocapkit.swaps` puts back, and at what cost.

Usage: ``python benchmarks/label_swaps.py [--data DIR] [--seeds 5] [--render-only]``

Targets: the gap-free real captures of the ``real-gaps`` protocol (kineticstoolkit's two
tennis serves, an HDM05 C3D, four CMU clips read as markers). Per target, seed and swap
length (3, 10, 30, 100 frames), :func:`mocapkit.corrupt.label_swaps` plants 3 swaps of a
marker with the one nearest to it at the swap's start (within 15 cm: what a labeller
confuses); then Gaussian noise of 0, 0.1 or 0.5 cm per coordinate, and optionally a real
occlusion mask (a ``real-gaps`` mask source's missing samples, laid over as that protocol
does) -- with a mask, also swaps that start where a marker reappears after a gap
(``label_swaps(at_gaps=True)``); and, in the same cases, 3 label jumps
(:func:`mocapkit.corrupt.label_jumps`: a label takes its nearest neighbour's marker, within
15 cm, for the swap length while its own marker is hidden; the neighbour's label is
missing meanwhile); and 3 swaps that start where both markers come back from a gap of
1-5 frames they share (``shared gap``: a swap planted anywhere, both markers hidden for
the frames just before it), 3 after a shared gap of 6-60 frames (``long shared gap``), and
3 that start and end in shared gaps of 6-60 frames (``between shared gaps``: no step of
either label is seen).
Scored:

* ``put back``: planted swaps whose every sample carries its own marker's trajectory
  after :func:`mocapkit.swaps.repair_swaps`;
* ``wrong after``: samples carrying another marker's trajectory after the repair (the
  planted ones left, and any the repair moved that were right);
* ``false events``: swap events found on the same capture with nothing planted (same
  noise and mask);
* ``kinect``: the body-side flips :func:`mocapkit.swaps.repair_side_flips` finds and puts
  back in the 567 MSR-Action3D Kinect skeletons as they are (no truth: the summed step
  of the joints into each flip frame, before and after);
* ``speed``: CPU time of :func:`mocapkit.swaps.repair_swaps` on a 59,900-frame, 78-marker
  take;
* ``auto``: RMSE (cm, per coordinate) on the swapped samples of ``mocapkit denoise``'s
  default (``auto``) with the repair (every method's guard does it on a marker capture)
  against the same with ``--keep-swaps``, on the noise-free captures without a mask.

Writes the Markdown file and a JSON file beside it. Nothing in the Markdown is typed by
hand.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mocapkit import corrupt, denoise  # noqa: E402
from mocapkit.bench.protocols import real_gaps as rg  # noqa: E402
from mocapkit.occlusion import apply_mask, transplant_mask  # noqa: E402
from mocapkit.swaps import find_swaps, repair_swaps  # noqa: E402
from _report import run_or_render  # noqa: E402

LENGTHS = (3, 10, 30, 100)
NOISE = (0.0, 0.1, 0.5)
N_SWAPS = 3
MAX_DISTANCE_CM = 15.0


def _carried(truth: np.ndarray, out: np.ndarray) -> np.ndarray:
    """(T, J) True where ``out`` carries its own marker's sample (the truth to 1e-9 cm,
    or both missing)."""
    same = np.all(np.abs(out - truth) <= 1e-9, axis=2)
    both = ~np.isfinite(out).all(axis=2) & ~np.isfinite(truth).all(axis=2)
    return same | both


def run(data: Path, a) -> dict:
    seeds = a.seeds
    sources, _ = rg.find_sources(data)
    targets, _ = rg.find_targets(data)
    masks = [(None, None)] + [(rg.short(k), s) for k, s in sources if "basket" in k or "Eb015" in k]
    rows, auto_rows, false_rows = [], [], []
    for tkey, tgt in targets:
        name = rg.short(tkey)
        for mkey, src in masks:
            for noise in NOISE:
                for seed in range(seeds):
                    base = tgt
                    if noise:
                        base = corrupt.gaussian(base, sigma_cm=noise, seed=1000 + seed)[0]
                    if src is not None:
                        tr = transplant_mask(src.observed, src.fps, tgt.n_frames, tgt.n_joints, tgt.fps,
                                             seed=rg.case_seed(seed, mkey, tkey))
                        base = apply_mask(base, tr.observed)
                    truth = np.where(base.observed[..., None], np.asarray(base.positions), np.nan)
                    if seed == 0:                       # nothing planted: what is found is false
                        false_rows.append({"target": name, "mask": mkey, "noise_cm": noise,
                                           "events": len(find_swaps(base.positions, base.observed))})
                    kinds = ("anywhere",) if src is None else ("anywhere", "at a gap end")
                    for L, kind in [(L, k) for L in LENGTHS
                                    for k in kinds + ("shared gap", "long shared gap", "between shared gaps", "jump")]:
                        if L >= tgt.n_frames // 2:
                            continue
                        sw, planted, swaps, held = _plant(base, L, seed, kind)
                        if not swaps:
                            continue
                        truth = np.where(held.observed[..., None], np.asarray(held.positions), np.nan)
                        fixed, rep = repair_swaps(sw)
                        out = np.where(fixed.observed[..., None], np.asarray(fixed.positions), np.nan)
                        own = _carried(truth, out)
                        if kind == "jump":
                            # wrong: a sample written that is not its marker's; the jumping
                            # label's own samples were lost with its hidden marker
                            wrong = np.isfinite(out).all(axis=2) & ~own
                            back = sum(bool(~wrong[a].any() and own[b].all()) for a, b in swaps)
                            wrong_after = int(wrong.sum())
                        else:
                            back = sum(bool(own[sel].all()) for sel in swaps)
                            wrong_after = int((~own).sum())
                        rows.append({"target": name, "mask": mkey, "noise_cm": noise, "seed": seed, "length": L,
                                     "kind": kind, "planted": len(swaps), "put_back": back,
                                     "planted_samples": int(planted.sum()),
                                     "wrong_after": wrong_after,
                                     "events": len(rep["events"]),
                                     "unrepaired": len(rep["unrepaired"]) + len(rep.get("doubtful", []))})
                        if noise == 0.0 and src is None and seed < 2:
                            auto_rows.append(_auto(sw, tgt, planted, name, L, seed, kind))
        print(f"{name}: done", file=sys.stderr, flush=True)
    return {"rows": rows, "auto": auto_rows, "false": false_rows, "kinect": _kinect(data), "speed": _speed(data)}


def _speed(data: Path) -> dict:
    """CPU seconds (median of 3) of :func:`repair_swaps` on kineticstoolkit's two-player
    tennis serve tiled 100 times (59,900 frames x 78 markers, one BLAS thread)."""
    from mocapkit import io

    m = io.read(data / "markers" / "kineticstoolkit" / "kinematics_tennis_serve_2players.c3d")
    P = np.concatenate([np.asarray(m.positions)] * 100)
    obs = np.concatenate([m.observed] * 100)
    big = m.with_positions(np.where(obs[..., None], P, np.nan))
    ts = []
    for _ in range(3):
        t0 = time.process_time()
        repair_swaps(big)
        ts.append(time.process_time() - t0)
    sec = float(np.median(ts))
    return {"frames": big.n_frames, "markers": big.n_joints, "seconds": sec, "frames_per_s": big.n_frames / sec}


def _kinect(data: Path) -> list[dict]:
    """Body-side flips found and put back in the MSR-Action3D Kinect skeletons as they
    are (:func:`mocapkit.swaps.repair_side_flips`): per file with a flip, the frames and the
    summed per-joint step at them before and after."""
    from mocapkit import io
    from mocapkit.swaps import repair_side_flips

    out = []
    for f in sorted((data / "msr_action3d" / "skeleton3d").glob("*.txt")):
        m = io.read(f)
        fixed, rep = repair_side_flips(m)
        if not rep["flips"]:
            continue
        P, Q = np.asarray(m.positions), np.asarray(fixed.positions)
        step = lambda X: float(sum(np.linalg.norm(X[t] - X[t - 1], axis=1).sum() for t in rep["flips"]))  # noqa: E731
        out.append({"file": f.name, "frames": m.n_frames, "flips": rep["flips"],
                    "pairs_put_back": len(rep["repaired"]), "step_before_cm": step(P), "step_after_cm": step(Q)})
    return out


def _plant(base, L: int, seed: int, kind: str = "anywhere"):
    """Up to :data:`N_SWAPS` swaps (``kind`` 'anywhere', 'at a gap end', 'shared gap': both
    markers hidden for 1-5 frames just before it) or label jumps ('jump'), each of a pair of
    markers no other one touches: the corrupted motion, the union of the samples carrying
    another marker's trajectory, per swap its mask (per jump: the jumping label's mask and
    the mask of the samples its neighbour lost), and the truth (``base``, with a shared
    gap's frames missing)."""
    sw, planted, swaps, held = base, np.zeros(base.observed.shape, bool), [], base
    for i in range(N_SWAPS):
        ss = np.random.SeedSequence([seed, L, i])
        if kind in ("shared gap", "long shared gap", "between shared gaps"):
            nxt, pm = corrupt.label_swaps(sw, n_swaps=1, length=L, max_distance_cm=MAX_DISTANCE_CM, seed=ss)
            if not pm.any() or (pm.any(axis=0) & planted.any(axis=0)).any():
                continue
            rows = np.flatnonzero(pm.any(axis=1))
            s0, e0 = int(rows[0]), int(rows[-1]) + 1
            rng = np.random.default_rng(ss)
            g = (1 if kind == "shared gap" else 6) + int(rng.integers(0, 5 if kind == "shared gap" else 55))
            g2 = 6 + int(rng.integers(0, 55)) if kind == "between shared gaps" else 0
            cols = np.flatnonzero(pm.any(axis=0))
            if s0 - g < 2 or not sw.observed[s0 - g - 2:s0][:, cols].all() or e0 + g2 > sw.n_frames:
                continue
            hide = np.zeros_like(pm)
            hide[s0 - g:s0, cols] = True
            hide[e0:e0 + g2, cols] = True
            sw = nxt.with_positions(np.asarray(nxt.positions), nxt.observed & ~hide)
            held = held.with_positions(np.asarray(held.positions), held.observed & ~hide)
            planted = planted | pm
            swaps.append(pm)
            continue
        if kind == "jump":
            nxt, pm = corrupt.label_jumps(sw, n_jumps=1, length=L, max_distance_cm=MAX_DISTANCE_CM, seed=ss)
            lost = sw.observed & ~nxt.observed
            touched = pm | lost
        else:
            nxt, pm = corrupt.label_swaps(sw, n_swaps=1, length=L, max_distance_cm=MAX_DISTANCE_CM,
                                          at_gaps=kind == "at a gap end", seed=ss)
            touched = pm
        if not pm.any() or (touched.any(axis=0) & planted.any(axis=0)).any():
            continue
        sw, planted = nxt, planted | touched
        swaps.append((pm, lost) if kind == "jump" else pm)
    if kind == "jump":                             # (the planted count: the jumping labels' samples)
        planted = np.any([a for a, _ in swaps], axis=0) if swaps else planted
    return sw, planted, swaps, held


def _auto(sw, truth_motion, planted, name, L, seed, kind="anywhere") -> dict:
    """auto's RMSE (cm) on the swapped samples, with the repair and without it (where it
    wrote them: a jumping label's frames are a gap for the fill after the repair)."""
    from mocapkit.gaps import use_policy

    P0 = np.asarray(truth_motion.positions)
    res = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res["with"] = np.asarray(denoise.get("auto").denoise(sw).positions)
        with use_policy(swaps=False):                  # --keep-swaps
            res["without"] = np.asarray(denoise.get("auto").denoise(sw).positions)

    def rmse(X):
        d = (X - P0)[planted]
        return float(np.sqrt(np.nanmean(d ** 2)))
    return {"target": name, "length": L, "seed": seed, "kind": kind, "input": rmse(np.asarray(sw.positions)),
            "auto_with_repair": rmse(res["with"]), "auto_without": rmse(res["without"]),
            "written_with_repair": float(np.isfinite(res["with"][planted]).all(axis=1).mean())}


_KIND_LABEL = {"jump": "a label jump", "shared gap": "after a gap of both",
               "long shared gap": "after a gap of both, 6-60 frames",
               "between shared gaps": "between two gaps of both, 6-60 frames (no event)"}


def _cases(n: int) -> str:
    return f"{n} case{'' if n == 1 else 's'}"


def to_markdown(res: dict) -> str:
    seconds = res["seconds"]
    rows = res["rows"]
    md = ["# Label swaps in real captures (`mocapkit.swaps`)", "",
          f"Generated by `python benchmarks/label_swaps.py` ({seconds:.0f} s, one BLAS thread); "
          "protocol in the script's docstring. A swap is *put back* when every one of its samples "
          "carries its own marker's trajectory after the repair; a case is *worse after* when "
          "more samples carry another marker's trajectory after the repair than before it. "
          "A label jump (`corrupt.label_jumps`: a label carries its neighbour's marker while its own "
          "is hidden, the neighbour's label missing meanwhile) is put back when its samples are the "
          "neighbour's again and the jumping label writes none that is not its own (it is left "
          "missing there, for the fill). "
          f"Over all {len(rows)} cases: "
          + "; ".join(f"{sum(r['put_back'] for r in rows if (r['kind'] == 'jump') == j)} of "
                      f"{sum(r['planted'] for r in rows if (r['kind'] == 'jump') == j)} {'jumps' if j else 'swaps'} "
                      f"put back, {_cases(sum(r['wrong_after'] > r['planted_samples'] for r in rows if (r['kind'] == 'jump') == j))} "
                      "worse after" for j in (False, True)) + ".", "",
          "## Planted swaps put back", "",
          "| mask | planted | noise (cm) | length (frames) | cases | swaps planted | put back | % | samples wrong before | after | cases worse after | events found | stretches left as measured |",
          "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    order = {"anywhere": 0, "at a gap end": 1, "shared gap": 2, "long shared gap": 3, "between shared gaps": 4,
             "jump": 5}
    keys = sorted({(r["mask"] or "", order[r["kind"]], r["noise_cm"], r["length"]) for r in rows})
    for mk, ko, nz, L in keys:
        kind = next(k for k, v in order.items() if v == ko)
        sel = [r for r in rows if (r["mask"] or "") == mk and r["kind"] == kind
               and r["noise_cm"] == nz and r["length"] == L]
        p = sum(r["planted"] for r in sel)
        b = sum(r["put_back"] for r in sel)
        md.append(f"| {mk or 'none'} | {_KIND_LABEL.get(kind, kind)} | {nz:g} | {L} | {len(sel)} | {p} | {b} | "
                  f"{100 * b / max(p, 1):.0f} | "
                  f"{sum(r['planted_samples'] for r in sel)} | {sum(r['wrong_after'] for r in sel)} | "
                  f"{sum(r['wrong_after'] > r['planted_samples'] for r in sel)} | "
                  f"{sum(r['events'] for r in sel)} | {sum(r['unrepaired'] for r in sel)} |")
    fr = res["false"]
    md += ["", "## Swap events found with nothing planted", "",
           "| mask | noise (cm) | captures | events |", "|---|---:|---:|---:|"]
    for mk, nz in sorted({(r["mask"] or "", r["noise_cm"]) for r in fr}):
        sel = [r for r in fr if (r["mask"] or "") == mk and r["noise_cm"] == nz]
        md.append(f"| {mk or 'none'} | {nz:g} | {len(sel)} | {sum(r['events'] for r in sel)} |")
    kr = res.get("kinect") or []
    md += ["", "## Body-side flips in the MSR-Action3D Kinect skeletons, as they are", "",
           "`mocapkit.swaps.repair_side_flips` on the 567 files (every method runs after it on a Kinect "
           f"file): flips in {len(kr)}. The step is the sum over the joints of their 3-D move into the "
           "flip frame (cm; at 15 fps a joint also moves several cm a frame by itself).", "",
           "| file | frames | flips at | left-right pairs put back | step before | after |",
           "|---|---:|---|---:|---:|---:|"]
    for r in kr:
        md.append(f"| {r['file']} | {r['frames']} | {', '.join(map(str, r['flips']))} | {r['pairs_put_back']} | "
                  f"{r['step_before_cm']:.0f} | {r['step_after_cm']:.0f} |")
    sp = res.get("speed")
    if sp:
        md += ["", "## Speed", "",
               f"`repair_swaps` on kineticstoolkit's two-player tennis serve tiled 100 times ({sp['frames']:,} "
               f"frames x {sp['markers']} markers; the tile joins are whole-body jumps): {sp['seconds']:.2f} CPU s, "
               f"{sp['frames_per_s']:,.0f} frames/s (median of 3, one BLAS thread)."]
    ar = res["auto"]
    if ar:
        md += ["", "## `auto` on the swapped samples (noise-free, no mask; RMSE cm per coordinate)", "",
               "On a label jump the samples scored are the jumping label's: with the repair they are a gap "
               "that auto fills where its validation allows (written: the share it filled).", "",
               "| planted | length (frames) | cases | input | auto without the repair | auto with it | written with it |",
               "|---|---:|---:|---:|---:|---:|---:|"]
        for kind in ("anywhere", "jump"):
            for L in sorted({r["length"] for r in ar}):
                sel = [r for r in ar if r["length"] == L and r.get("kind", "anywhere") == kind]
                if not sel:
                    continue
                m = {k: float(np.sqrt(np.nanmean([r[k] ** 2 for r in sel])))
                     for k in ("input", "auto_without", "auto_with_repair")}
                w = np.mean([r.get("written_with_repair", 1.0) for r in sel])
                md.append(f"| {'a swap' if kind == 'anywhere' else 'a label jump'} | {L} | {len(sel)} | "
                          f"{m['input']:.2f} | {m['auto_without']:.2f} | {m['auto_with_repair']:.3f} | {100 * w:.0f} % |")
    return "\n".join(md) + "\n"


def main(argv: list[str] | None = None) -> int:
    return run_or_render(ROOT / "docs" / "results" / "swaps.md", run, to_markdown, __doc__.splitlines()[0],
                         [("--seeds", {"type": int, "default": 5})], argv)


if __name__ == "__main__":
    raise SystemExit(main())
