"""Measure the BVH / TRC / Kinect readers and writers on ../shared/data and write the
"BVH/TRC/Kinect" section of docs/results/io.md (other sections of that file are kept).

    .venv/bin/python benchmarks/io_bvh_text.py [--data DIR] [--out docs/results/io.md]

Takes about a minute on 2 cores. Every number in the section comes from this run.
"""
from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from mocapkit.datasets import shared_data_dir
from mocapkit.io import bvh, kinect, trc

from _report import replace_section

BEGIN, END = "<!-- BEGIN BVH/TRC/Kinect -->", "<!-- END BVH/TRC/Kinect -->"


def standing_height(m) -> float:
    """90th percentile over frames of the vertical (Y) extent of all nodes incl. End Sites."""
    P = m.positions
    return float(np.percentile(P[..., 1].max(1) - P[..., 1].min(1), 90))


def best_of(f, n=3):
    ts = []
    for _ in range(n):
        t = time.perf_counter()
        r = f()
        ts.append(time.perf_counter() - t)
    return min(ts), r


def bvh_section(data: Path, tmp: Path) -> list[str]:
    out = ["### BVH", "",
           "Every BVH file under `cmu/bvh`. *unit*: inferred file unit; *stand*: 90th percentile "
           "over frames of the vertical extent with End Sites (head top to toe tip), cm; "
           "*height()*: `Motion.height()` of the default read (joints only, no End Sites), cm; "
           "*rt*: max |re-read - original| after write-back with the original rotations (cm); "
           "*ik0*: same when the writer starts from identity rotations (no per-frame channels); "
           "*read*: frames/s, best of 3.", "",
           "| file | frames | joints | unit | stand | height() | rt (cm) | ik0 (cm) | read (frames/s) | write (s) |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    files = sorted((data / "cmu" / "bvh").rglob("*.bvh"))
    rts, biggest = [], max(files, key=lambda f: f.stat().st_size)
    for f in files:
        dt, m = best_of(lambda: bvh.read(f))
        me = bvh.read(f, end_sites=True)
        o1, o2 = tmp / f"{f.stem}_rt.bvh", tmp / f"{f.stem}_ik0.bvh"
        for o in (o1, o2):
            if o.exists():
                o.unlink()
        t = time.perf_counter()
        bvh.write(m, o1)
        tw = time.perf_counter() - t
        rt = float(np.abs(bvh.read(o1).positions - m.positions).max())
        bvh.write(m.with_source(per_frame={}), o2)
        ik0 = float(np.abs(bvh.read(o2).positions - m.positions).max())
        rts.append(rt)
        out.append(f"| {f.parent.name}/{f.name} | {m.n_frames} | {m.n_joints} | {m.source['units']['name']} | "
                   f"{standing_height(me):.1f} | {m.height():.1f} | {rt:.1e} | {ik0:.1e} | "
                   f"{m.n_frames / dt:,.0f} | {tw:.2f} |")
    mb = bvh.read(biggest)
    dt, _ = best_of(lambda: bvh.read(biggest))
    out += ["", f"Largest file: `{biggest.name}` ({biggest.stat().st_size / 1e6:.1f} MB, {mb.n_frames} frames x "
                f"{mb.n_joints} joints): read in {dt:.3f} s = **{mb.n_frames / dt:,.0f} frames/s** "
                f"(parse + vectorised FK). Worst write-back round trip over all files: **{max(rts):.1e} cm**.", ""]
    # pybvh
    try:
        import pybvh
        f = data / "cmu" / "bvh" / "cgspeed_motionbuilder" / "02_01.bvh"
        m = bvh.read(f)
        o = tmp / "pybvh.bvh"
        bvh.write(m, o)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            b = pybvh.read_bvh_file(o)
        d = np.abs(b.joint_positions() * m.source["units"]["factor_to_cm"] - bvh.read(o).positions).max()
        out.append(f"pybvh {pybvh.__version__} FK of our written `02_01.bvh` vs ours: max difference {d:.1e} cm.")
    except ImportError:
        out.append("pybvh not installed: cross-check skipped.")
    # units cross-check with the AMC twin
    amc = data / "cmu" / "asfamc" / "16" / "16_15.amc"
    if amc.exists():
        m = bvh.read(data / "cmu" / "bvh" / "motionbuilder75" / "16_15.bvh")
        roots = np.array([[float(v) for v in ln.split()[1:4]]
                          for ln in amc.read_text().splitlines() if ln.startswith("root ")])
        n = min(len(roots), m.n_frames)
        ratio = m.positions[:n, 0] / roots[:n]
        ok = np.abs(roots[:n]) > 1.0
        out.append(f"Units: MotionBuilder 7.5 `16_15.bvh` (inferred cm) root / `16_15.amc` root = "
                   f"{np.median(ratio[ok]):.4f} (min {ratio[ok].min():.4f}, max {ratio[ok].max():.4f}) over "
                   f"{n} frames; the DESIGN's CMU unit is 2.54/0.45 = {2.54 / 0.45:.4f} cm.")
    # IK after noise
    from scipy.ndimage import gaussian_filter1d
    m = bvh.read(data / "cmu" / "bvh" / "cgspeed_motionbuilder" / "02_01.bvh")
    rng = np.random.default_rng(0)
    rows = []
    for sigma in (0.5, 2.0):
        nse = gaussian_filter1d(rng.normal(size=m.positions.shape), 3, axis=0)
        nse *= sigma / nse.std()
        mn = m.with_positions(m.positions + nse)
        o = tmp / f"noise{sigma}.bvh"
        bvh.write(mn, o)
        r = bvh.read(o)
        rms = lambda a: float(np.sqrt((a ** 2).sum(2).mean()))
        rows.append(f"| {sigma} | {rms(nse):.3f} | {rms(r.positions - mn.positions):.3f} | "
                    f"{rms(r.positions - m.positions):.3f} |")
    out += ["", "IK write-back of `02_01.bvh` after smooth Gaussian noise (sigma per coordinate, "
                "temporal smoothing 3 frames); RMS joint distance in cm:", "",
            "| sigma | noise | written vs noisy target | written vs clean |", "|---|---|---|---|"] + rows
    cg = [standing_height(bvh.read(f, end_sites=True)) for f in files if "cgspeed" in str(f)]
    daz = [f for f in files if "daz" in str(f)]
    daz_rest = bvh.read(daz[0]).source["units"].get("rest_extent_file_units", float("nan")) if daz else float("nan")
    out += ["", f"Heights: with the DESIGN's CMU unit (5.6444 cm) the cgspeed subjects stand "
                f"{min(cg):.0f}-{max(cg):.0f} cm (head-top End Site to toe tip), partly below the 150-200 cm "
                f"adult band; `Motion.height()` of the default read (no End Sites: no head top, no toe "
                f"tip) is lower still. The Daz-friendly files share one figure whose rest pose spans "
                f"{daz_rest:.1f} cm.", ""]
    return out


def trc_section(data: Path, tmp: Path) -> list[str]:
    f = data / "markers" / "pyomeca" / "markers.trc"
    if not f.exists():
        return []
    dt, m = best_of(lambda: trc.read(f))
    o = tmp / "rt.trc"
    trc.write(m, o)
    m2 = trc.read(o)
    err = float(np.nanmax(np.abs(m2.positions - m.positions)))
    return ["### TRC", "",
            f"`markers/pyomeca/markers.trc`: {m.n_frames} frames x {m.n_joints} markers at {m.fps:g} Hz, "
            f"unit {m.source['units']['name']}, read in {dt * 1000:.1f} ms; warnings: "
            f"{'; '.join(m.source.get('warnings', [])) or 'none'}. Write (mm, tab-separated) and re-read: "
            f"max error {err:.1e} cm, missing pattern identical: {bool(np.array_equal(m2.observed, m.observed))}.",
            ""]


def kinect_section(data: Path, tmp: Path) -> list[str]:
    d = data / "msr_action3d" / "skeleton3d"
    files = sorted(d.glob("*_skeleton3D.txt"))
    if not files:
        return []
    t = time.perf_counter()
    ms = [kinect.read(f) for f in files]
    dt = time.perf_counter() - t
    units = sorted({m.source["units"]["name"] for m in ms})
    both = sum("smoother" in m.source["kinect"]["n_joints_chosen_by"] for m in ms)
    miss_frames = sum(int((~m.observed.any(1)).sum()) for m in ms)
    miss_files = sum(bool((~m.observed).any()) for m in ms)
    partial = sum(int((m.observed.any(1) & ~m.observed.all(1)).sum()) for m in ms)
    empty = [f.name for f, m in zip(files, ms) if not m.observed.any()]
    # per-axis scale: L^2 = a x^2 + b y^2 + c z^2 constant per bone and clip (mean removed);
    # (a, b, c) = smallest right singular vector (total least squares), per bone group.
    groups = {"upper arm": [("ShoulderLeft", "ElbowLeft"), ("ShoulderRight", "ElbowRight")],
              "forearm": [("ElbowLeft", "WristLeft"), ("ElbowRight", "WristRight")],
              "shin": [("KneeLeft", "AnkleLeft"), ("KneeRight", "AnkleRight")],
              "thigh": [("HipLeft", "KneeLeft"), ("HipRight", "KneeRight")]}
    grows = {g: [] for g in groups}
    conf0, conf_other = [], []
    heights, right_more, n_single = [], 0, 0
    head_top, head_top_kick = [], []
    for f, m in zip(files, ms):
        P = m.positions[m.observed.all(1)]
        if len(P) < 5:
            continue
        ix = m.skeleton.index
        for g, bones in groups.items():
            for a, b in bones:
                v = (P[:, ix(b)] - P[:, ix(a)]) ** 2
                grows[g].append(v - v.mean(0))
        heights.append(np.median(P[:, ix("Head"), 1] - P[:, [ix("FootLeft"), ix("FootRight")], 1].min(1)))
        act = int(f.name[1:3])
        if act <= 9 or act in (14, 15):
            limb = "Hand" if act <= 9 else "Foot"
            hc = P[:, ix("HipCenter")]
            sr = np.std(P[:, ix(limb + "Right")] - hc, axis=0).sum()
            sl = np.std(P[:, ix(limb + "Left")] - hc, axis=0).sum()
            right_more += sr > sl
            n_single += 1
        if act == 13:
            head_top.append(np.mean(np.argmax(P[..., 1], 1) == ix("Head")))
        if act in (14, 15, 16):
            head_top_kick.append(np.mean(np.argmax(P[..., 1], 1) == ix("Head")))
        conf = m.source["per_frame"]["confidence"][m.observed.all(1)]
        for j, p in enumerate(m.skeleton.parents):
            if p < 0:
                continue
            L = np.linalg.norm(P[:, j] - P[:, p], axis=1)
            dev = np.abs(L - np.median(L))
            conf0.append(dev[conf[:, j] == 0])
            conf_other.append(dev[conf[:, j] > 0])
    scale_txt = []
    for g, rr in grows.items():
        R = np.concatenate(rr)
        _, S, Vt = np.linalg.svd(R, full_matrices=False)
        w = Vt[-1] / Vt[-1][0]
        sy, sz = np.sqrt(np.abs(w[1:]))
        scale_txt.append(f"{g} y/x {sy:.3f}, z/x {sz:.3f} (conditioning s3/s1 {S[2] / S[0]:.2f})")
    allconf = np.concatenate([m.source["per_frame"]["confidence"].ravel() for m in ms])
    c0, c1 = np.concatenate(conf0), np.concatenate(conf_other)
    heights = np.array(heights)
    o = tmp / "rt.txt"
    kinect.write(ms[0], o)
    same = np.array_equal(np.loadtxt(o), np.loadtxt(files[0]))
    return ["### Kinect / MSR Action3D", "",
            f"All {len(files)} files of `msr_action3d/skeleton3d` read in {dt:.2f} s "
            f"({dt / len(files) * 1000:.1f} ms/file); unit chosen: {', '.join(units)}; joints per frame: "
            f"{sorted({m.n_joints for m in ms})}; {both} files have a line count divisible by both 20 and 25 "
            f"(resolved by trajectory smoothness, all to 20).",
            f"- Missing data: {miss_frames} whole frames written as `0 0 0` in {miss_files} files, "
            f"{partial} partially zero frames; files with no tracked frame: {', '.join(empty) or 'none'}.",
            f"- Per-axis scale (constant bone length, total least squares over all clips): "
            f"{'; '.join(scale_txt)}. The well-tracked bones give ratios within a few % of 1 -> one "
            f"metric scale (metres); the thigh (the hip joints are estimated) fits the "
            f"constant-length model badly (large s3/s1) and says nothing.",
            f"- Head joint to lowest foot joint, median per clip: median {np.median(heights) * 1:.1f} cm, "
            f"5-95% {np.percentile(heights, 5):.1f}-{np.percentile(heights, 95):.1f} cm.",
            f"- Sides: in {right_more} of {n_single} single-limb clips (a01-a09 arm, a14-a15 leg) the limb "
            f"labelled Right (file joints 2/9/11/13, 6/15/17/19) moves more than the Left one -> the usual "
            f"MSR joint list is mirrored; we label by the data.",
            f"- Head is the highest joint in {100 * np.mean(head_top_kick):.0f}% of the frames of the "
            f"a14-a16 (kicks, jogging) clips and {100 * np.mean(head_top):.0f}% of the a13 (bend) clips.",
            f"- Confidence: {100 * np.mean(allconf == 0):.1f}% of entries are 0, {100 * np.mean(allconf == 1):.1f}% "
            f"are 1; |bone length - clip median| (joint to parent) averages {np.mean(c0):.2f} cm "
            f"(95th pct {np.percentile(c0, 95):.2f}) where the joint's confidence is 0 and {np.mean(c1):.2f} cm "
            f"(95th pct {np.percentile(c1, 95):.2f}) elsewhere -> not a validity mask, not used.",
            f"- Write-back of `{files[0].name}` re-reads to the same numbers: {same}.", ""]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data", default=None)
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent.parent / "docs" / "results" / "io.md"))
    a = ap.parse_args(argv)
    data = shared_data_dir(a.data)
    if data is None:
        raise SystemExit("shared data not found (pass --data DIR)")
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        lines = ["## BVH/TRC/Kinect", "",
                 f"Written by `benchmarks/io_bvh_text.py` on {platform.machine()} "
                 f"({os.cpu_count()} CPUs, shared with other jobs; timings are indicative), "
                 f"{time.strftime('%Y-%m-%d')}.", ""]
        lines += bvh_section(data, tmp)
        lines += trc_section(data, tmp)
        lines += kinect_section(data, tmp)
    print(replace_section(Path(a.out), BEGIN, END, lines))


if __name__ == "__main__":
    main()
