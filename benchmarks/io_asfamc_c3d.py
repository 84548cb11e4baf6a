"""Measure the ASF/AMC and C3D readers and writers on ../shared/data and write the
"ASF/AMC/C3D" section of docs/results/io.md (other sections of that file are kept).

    .venv/bin/python benchmarks/io_asfamc_c3d.py [--data DIR] [--out docs/results/io.md] [--fuzz N]

Takes a few minutes on 2 cores (most of it the IK write-backs and the C3D fuzzing, which
runs each corrupted file in a subprocess so that a crash would be seen). Every number in
the section comes from this run.
"""
from __future__ import annotations

import argparse
import os
import platform
import random
import re
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from mocapkit import io
from mocapkit.datasets import bundled, shared_data_dir
from mocapkit.errors import MocapFormatError
from mocapkit.io import _kinematics
from mocapkit.io.units import CMU_CM_PER_UNIT

from _report import replace_section

BEGIN, END = "<!-- BEGIN ASF/AMC/C3D -->", "<!-- END ASF/AMC/C3D -->"


def _best(fn, n=3):
    best = float("inf")
    out = None
    for _ in range(n):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def heights_section(data: Path) -> list[str]:
    rows = defaultdict(list)
    t0 = time.perf_counter()
    n_frames = 0
    for p in sorted(data.rglob("*.amc")):
        m = io.read(p)
        n_frames += m.n_frames
        key = ("CMU " + p.parent.name) if "/cmu/" in str(p) else ("HDM05 " + re.search(r"HDM_(\w\w)_", p.name).group(1))
        rows[key].append((p.stem, m.height(), m.source["skeleton_path"]))
    total = time.perf_counter() - t0
    lines = ["### Heights (cm)", "",
             "*rest*: vertical (Y) extent of the ASF rest pose (root + bone end points: toe tips to the end of "
             "the head bone); *height()*: `Motion.height()` (90th percentile over frames of the largest "
             "axis extent of the joints) per clip, median / min / max over the clips of the subject.", "",
             "| subject | clips | rest | height() median | min | max |", "|---|---|---|---|---|---|"]
    for key in sorted(rows, key=lambda k: (k.split()[0], k.split()[1].zfill(3))):
        hs = rows[key]
        rest = io.read(hs[0][2])
        stature = float(np.ptp(rest.positions[0, :, 1]))
        v = [h for _, h, _ in hs]
        lo = min(hs, key=lambda x: x[1])
        hi = max(hs, key=lambda x: x[1])
        lines.append(f"| {key} | {len(hs)} | {stature:.1f} | {np.median(v):.1f} | {lo[1]:.1f} ({lo[0]}) | "
                     f"{hi[1]:.1f} ({hi[0]}) |")
    lines += ["", f"All {sum(len(v) for v in rows.values())} AMC files ({n_frames} frames) read in {total:.1f} s "
              f"({n_frames / total:,.0f} frames/s, skeleton lookup + parse + FK).", ""]
    lines += ["Units: every ASF here (CMU and HDM05) states `:units length 0.45`, i.e. file lengths are "
              "inches x 0.45, so 1 unit = 2.54/0.45 = 5.644444 cm for both. With it the CMU subjects' median "
              "clip heights are 150-190 cm and the HDM05 actors' 158-180 cm; single clips go outside that "
              "band only for crouched or arms-overhead actions (sneaking, martial-arts stances, arm "
              "rotations). The rest-pose extent misses the top of the head above the head bone's end and the "
              "sole below the toe tip, so it reads a few cm short of stature.", ""]
    return lines


def speed_section(data: Path) -> list[str]:
    p = data / "cmu" / "asfamc" / "135" / "135_02.amc"
    t, m = _best(lambda: io.read(p))
    mb = p.stat().st_size / 1e6
    comp = _kinematics._Compiled(m.source["asf"])
    D = m.source["per_frame"]["dofs"]
    tf, _ = _best(lambda: _kinematics.forward_kinematics(comp, D, False, CMU_CM_PER_UNIT))
    return ["### Read speed", "",
            f"`135_02.amc` ({mb:.1f} MB, {m.n_frames} frames x {m.n_joints} joints): read in **{t:.2f} s** "
            f"(best of 3; {m.n_frames / t:,.0f} frames/s, {mb / t:.1f} MB/s), of which forward kinematics "
            f"{tf:.2f} s.", ""]


def round_trip_section(data: Path, tmp: Path) -> list[str]:
    files = sorted((data / "cmu" / "asfamc").rglob("*.amc")) + sorted((data / "hdm05").rglob("*.amc"))[::10]
    worst = 0.0
    same = 0
    tw = 0.0
    for i, p in enumerate(files):
        m = io.read(p)
        out = tmp / f"rt{i}.amc"
        t = time.perf_counter()
        io.write(m, out)
        tw += time.perf_counter() - t
        b = io.read(out)
        same += int(np.array_equal(b.source["per_frame"]["dofs"], m.source["per_frame"]["dofs"]))
        worst = max(worst, float(np.max(np.abs(b.positions - m.positions))))
    return ["### AMC round trips", "",
            f"Unchanged motions, read -> write -> read, {len(files)} files (all CMU, every 10th HDM05): dof "
            f"values identical in {same}/{len(files)}; max position difference {worst:.1e} cm "
            f"(stored dofs written as shortest round-trip text; writes took {tw:.1f} s in all).", ""]


def ik_section(tmp: Path) -> list[str]:
    walk = io.read(bundled("16_15.amc"))
    comp = _kinematics._Compiled(walk.source["asf"])
    f = CMU_CM_PER_UNIT
    D = walk.source["per_frame"]["dofs"]
    T = walk.n_frames
    rng = np.random.default_rng(0)
    lines = ["### AMC write-back after changed positions (IK)", "",
             f"CMU `16_15.amc` ({T} frames). Positions changed, written with `io.write` (per-bone IK + "
             "Levenberg-Marquardt polish), re-read; distances per joint and frame in cm.", "",
             "| change | start dofs | max | mean | write (s) |", "|---|---|---|---|---|"]
    for sig in (2.0, 10.0):
        D1 = D + rng.normal(0, sig, D.shape) * (np.arange(D.shape[1]) >= 3)
        P1 = _kinematics.forward_kinematics(comp, D1, False, f)
        for start in ("stored", "none"):
            m = walk.with_positions(P1)
            if start == "none":
                src = dict(m.source)
                src.pop("per_frame")
                m = type(m)(m.positions, m.skeleton, m.fps, None, src)
            out = tmp / f"ik_{sig}_{start}.amc"
            t = time.perf_counter()
            io.write(m, out)
            tw = time.perf_counter() - t
            e = np.linalg.norm(io.read(out).positions - P1, axis=2)
            lines.append(f"| all angles + N(0, {sig:g} deg) (reachable poses) | {start} | {e.max():.3f} | "
                         f"{e.mean():.4f} | {tw:.1f} |")
    src = dict(walk.source)
    src.pop("per_frame")
    bare = type(walk)(walk.positions, walk.skeleton, walk.fps, None, src)
    t = time.perf_counter()
    io.write(bare, tmp / "ik_clean_none.amc")
    tw = time.perf_counter() - t
    e = np.linalg.norm(io.read(tmp / "ik_clean_none.amc").positions - walk.positions, axis=2)
    lines.append(f"| none (clean positions) | none | {e.max():.3f} | {e.mean():.4f} | {tw:.1f} |")
    lines += ["", "Noisy positions (i.i.d. Gaussian per coordinate; they are not reachable, so the written "
              "motion is the skeleton's least-squares fit; RMS over coordinates, cm):", "",
              "| sigma | written vs noisy target | written vs clean | write (s) |", "|---|---|---|---|"]
    for sig in (0.5, 1.0, 2.0):
        noisy = walk.positions + rng.normal(0, sig, walk.positions.shape)
        out = tmp / f"noisy_{sig}.amc"
        t = time.perf_counter()
        io.write(walk.with_positions(noisy), out)
        tw = time.perf_counter() - t
        b = io.read(out).positions
        lines.append(f"| {sig:g} | {np.sqrt(np.mean((b - noisy) ** 2)):.3f} | "
                     f"{np.sqrt(np.mean((b - walk.positions) ** 2)):.3f} | {tw:.1f} |")
    return lines + [""]


def bvh_agreement_section() -> list[str]:
    walk = io.read(bundled("16_15.amc"))
    b = io.read(bundled("16_15.bvh"))
    parent = {c: p for p, cs in walk.source["asf"]["hierarchy"] for c in cs}
    pairs = [(n, "root" if n == "root" else parent[n]) for n in b.skeleton.names]
    d = np.linalg.norm(b.positions[:, b.skeleton.indices([p for p, _ in pairs])]
                       - walk.positions[:, walk.skeleton.indices([q for _, q in pairs])], axis=2)
    keyed = d[::4]
    inter = np.delete(d, np.arange(0, len(d), 4), axis=0)
    fm = d.max(1)
    worst = int(np.argmax(fm))
    return ["### Same trial as BVH and as ASF/AMC", "",
            f"`cmu/bvh/motionbuilder75/16_15.bvh` (MotionBuilder 7.5 conversion, read by `mocapkit.io.bvh`, "
            f"unit inferred: {b.source['units'].get('name', '?')}) vs `cmu/asfamc/16/16_15.amc`: both "
            f"{walk.n_frames} frames (no T-pose frame in this conversion). A BVH joint named after ASF bone B "
            f"is the start of B, i.e. our joint named parent(B) (BVH `lfemur` = our `lhipjoint`); "
            f"{len(pairs)} joints compared.", "",
            f"- frames 0, 4, 8, ... ({len(keyed)} frames): max {keyed.max():.1e} cm, mean {keyed.mean():.1e} cm "
            f"(the BVH prints 6 significant digits);",
            f"- the other {len(inter)} frames: mean {inter.mean():.3f} cm, median {np.median(inter):.3f} cm, "
            f"max {inter.max():.1f} cm (frame {worst});",
            "- so the converter keyed every 4th frame (30 Hz) and interpolated the rest; the largest gap is "
            "next to frame 0, whose left-arm angles are all 0 in the AMC (a dropout the converter "
            "interpolated over).", ""]


def c3d_section(data: Path, tmp: Path, n_fuzz: int) -> list[str]:
    manifest = {}
    for ln in (data / "MANIFEST.tsv").read_text().splitlines()[1:]:
        f = ln.split("\t")
        mm = re.search(r"([\d.]+)% marker samples missing", f[9] if len(f) > 9 else "")
        if f[6] == "C3D" and mm:
            manifest[f[0]] = float(mm.group(1))
    lines = ["### C3D", "",
             "*missing*: % of marker samples not observed (negative residual, NaN or (0, 0, 0)) vs the "
             "manifest; *rt*: read -> write -> read keeps labels, rate, units and mask (all yes below), "
             "max position difference.", "",
             "| file | frames | markers | Hz | units | missing % (manifest) | analog ch. | read (ms) | rt max (cm) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for rel, pct in manifest.items():
        t, m = _best(lambda: io.read(data / rel))
        b = io.read(io.write(m, tmp / Path(rel).name))
        ok = (b.skeleton.names == m.skeleton.names and b.fps == m.fps and np.array_equal(b.observed, m.observed)
              and b.source["units"]["file"] == m.source["units"]["file"])
        dmax = float(np.max(np.abs(b.positions[b.observed] - m.positions[m.observed]))) if m.observed.any() else 0.0
        lines.append(f"| {rel.split('/', 1)[1]} | {m.n_frames} | {m.n_joints} | {m.fps:g} | "
                     f"{m.source['units']['file']} | {100 * m.missing_fraction:.2f} ({pct:.2f}) | "
                     f"{m.source['c3d']['analog_channels']} | {1000 * t:.0f} | "
                     f"{dmax:.1e}{'' if ok else ' (KEPT: NO)'} |")
    if n_fuzz:
        lines += ["", fuzz(data, tmp, n_fuzz)]
    return lines + [""]


_PROBE = """
import sys
from mocapkit.io import c3d
from mocapkit.errors import MocapFormatError
try:
    c3d.read(sys.argv[1]); print("OK")
except MocapFormatError:
    print("MFE")
except Exception as e:
    print("OTHER", type(e).__name__)
"""


def fuzz(data: Path, tmp: Path, n: int) -> str:
    files = sorted(data.rglob("*.c3d"))
    counts = defaultdict(int)
    for seed in range(n):
        rnd = random.Random(seed)
        src = rnd.choice(files)
        b = bytearray(src.read_bytes())
        ps = (b[0] - 1) * 512
        nb = b[ps + 2]
        mode = rnd.choice(["truncate", "header", "parameters", "data"])
        if mode == "truncate":
            b = b[:rnd.randrange(0, len(b))]
        elif mode == "header":
            for _ in range(rnd.choice([1, 3])):
                b[rnd.randrange(0, 24)] = rnd.randrange(256)
        elif mode == "parameters":
            for _ in range(rnd.choice([1, 3, 20])):
                b[rnd.randrange(ps + 4, ps + 512 * nb)] = rnd.randrange(256)
        else:
            for _ in range(50):
                b[rnd.randrange(ps + 512 * nb, len(b))] = rnd.randrange(256)
        f = tmp / f"fuzz{seed}.c3d"
        f.write_bytes(bytes(b))
        try:
            r = subprocess.run([sys.executable, "-c", _PROBE, str(f)], capture_output=True, text=True, timeout=60)
            res = r.stdout.strip() if r.returncode == 0 else f"exit {r.returncode}"
        except subprocess.TimeoutExpired:
            res = "hang"
        counts[(mode, res.split()[0] if res else "?")] += 1
    summary = ", ".join(f"{m}: " + " / ".join(f"{k} {counts[(m, k)]}" for k in ("OK", "MFE") if counts[(m, k)])
                        for m in ("truncate", "header", "parameters", "data"))
    bad = {k: v for k, v in counts.items() if k[1] not in ("OK", "MFE")}
    return (f"Corruption fuzzing, {n} files (random real C3D; truncated, or random bytes in the header, "
            f"parameter section or data; each read in a subprocess): {summary} (OK = read, MFE = "
            f"MocapFormatError); crashes, hangs or other exceptions: {sum(bad.values())}"
            f"{' ' + str(bad) if bad else ''}.")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data", default=None)
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent.parent / "docs" / "results" / "io.md"))
    ap.add_argument("--fuzz", type=int, default=100, help="corrupted C3D files to try (0: skip)")
    a = ap.parse_args(argv)
    data = shared_data_dir(a.data)
    if data is None:
        raise SystemExit("shared data not found (pass --data DIR)")
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        lines = ["## ASF/AMC/C3D", "",
                 f"Written by `benchmarks/io_asfamc_c3d.py` on {platform.machine()} "
                 f"({os.cpu_count()} CPUs, shared with other jobs; timings are indicative), "
                 f"{time.strftime('%Y-%m-%d')}.", ""]
        lines += heights_section(data)
        lines += speed_section(data)
        lines += round_trip_section(data, tmp)
        lines += ik_section(tmp)
        lines += bvh_agreement_section()
        lines += c3d_section(data, tmp, a.fuzz)
    print(replace_section(Path(a.out), BEGIN, END, lines))


if __name__ == "__main__":
    try:
        main()
    except MocapFormatError as e:
        raise SystemExit(str(e))
