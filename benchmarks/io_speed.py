"""Speed and memory of the readers/writers (issue #21, items 3-4 and the io part of 5).

Measures, on one core (OMP/OpenBLAS 1 thread), and writes docs/results/io_speed.md + .json:

1. ``mocapkit info`` and ``mocapkit denoise --method kalman-cv`` on a 200,000-frame BVH
   (the bundled CMU 16_15 MotionBuilder BVH tiled to 200k frames, ~128 MB): wall and CPU
   seconds, peak RSS (``/usr/bin/time -v``), each command in its own process.
2. Write-back: AMC (CMU 131_02, 1,247 frames) and BVH (CMU 131_02 cgspeed, 1,247
   frames) of the kalman-cv cleaned clip: IK frames/s and whole ``io.write`` frames/s.
3. IK accuracy on real clips (AMC: 131_02, 16_15, 05_01): max / mean joint error (cm)
   between the targets and the FK of the recovered dofs, for kalman-cv output, exactly
   reachable poses (stored dofs + N(0, 2 deg)), no stored dofs, and 1 cm noise;
   BVH: read -> write -> read round trip of the cleaned clips.
4. ``mocapkit batch`` (``run_batch``) of 8 CMU AMC clips with 2 local worker processes
   and on a local Dask cluster (2 worker processes, 1 thread each): frames/s and frames/s
   per worker (``run_batch`` as in ``benchmarks/batch_speed.py``; kalman-cv, gate 5).

``--reference DIR``: DIR/mocapkit is the package before this change (e.g. a ``git
worktree`` of the previous commit); it is copied to a temporary ``mocapkit_ref`` and
every measurement is repeated with it ("before" columns). ``--reference-denoise``
also runs the (slow: minutes) old ``denoise`` on the 200k-frame file.

    .venv/bin/python benchmarks/io_speed.py [--data DIR] [--reference DIR] [--reference-denoise]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
OUT_MD = ROOT / "docs" / "results" / "io_speed.md"
OUT_JSON = ROOT / "docs" / "results" / "io_speed.json"
BIG_FRAMES = 200_000
AMC_CLIPS = ["131/131_02", "16/16_15", "05/05_01"]
BATCH_CLIPS = ["131/131_02", "16/16_15", "05/05_01", "07/07_05", "09/09_06", "11/11_01", "131/131_07",
               "49/49_19"]
BVH_CLIP = "cmu/bvh/cgspeed_3dsmax/131_02.bvh"


def make_reference(src: Path, tmp: Path) -> Path:
    """Copy src/mocapkit to tmp/mocapkit_ref with its absolute imports renamed."""
    dst = tmp / "mocapkit_ref"
    shutil.copytree(src / "mocapkit", dst, ignore=shutil.ignore_patterns("data", "__pycache__"))
    os.symlink(src / "mocapkit" / "data", dst / "data")
    for p in dst.rglob("*.py"):
        t = p.read_text()
        t2 = re.sub(r"\b(from|import) mocapkit\b", r"\1 mocapkit_ref", t)
        if t2 != t:
            p.write_text(t2)
    return tmp


def tile_bvh(src: Path, dst: Path, frames: int) -> None:
    """A BVH with ``frames`` frames: src's header, its frame lines repeated."""
    lines = src.read_text().splitlines()
    i = next(k for k, s in enumerate(lines) if s.strip().lower().startswith("frame time"))
    head = [re.sub(r"(?i)^(\s*frames\s*:\s*)\d+", lambda m: m.group(1) + str(frames), s) for s in lines[:i + 1]]
    body = [s for s in lines[i + 1:] if s.strip()]
    with open(dst, "w") as f:
        f.write("\n".join(head) + "\n")
        n = 0
        while n < frames:
            chunk = body[:frames - n]
            f.write("\n".join(chunk) + "\n")
            n += len(chunk)


def timed_cli(args: list[str], pkg: str, ref_path: Path | None) -> dict:
    """Run ``python -m <pkg>.cli ARGS`` under /usr/bin/time -v: wall, CPU, peak RSS."""
    code = "import sys; sys.argv[0] = 'mocapkit'; from {0}.cli import main; sys.exit(main())".format(pkg)
    env = dict(os.environ)
    if ref_path is not None:
        env["PYTHONPATH"] = str(ref_path) + os.pathsep + env.get("PYTHONPATH", "")
    cmd = ["/usr/bin/time", "-v", sys.executable, "-c", code] + args
    t = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t
    err = r.stderr

    def grab(key):
        m = re.search(rf"{key}:\s*([\d.:]+)", err)
        return m.group(1) if m else None
    rss = grab(r"Maximum resident set size \(kbytes\)")
    return {"rc": r.returncode, "wall_s": round(wall, 2),
            "cpu_s": round(float(grab(r"User time \(seconds\)") or 0) + float(grab(r"System time \(seconds\)") or 0), 2),
            "peak_rss_mb": round(int(rss) / 1024, 1) if rss else None,
            "tail": (r.stdout + err).strip().splitlines()[-1][:200] if r.returncode else ""}


def big_bvh_rows(tmp: Path, ref: Path | None, ref_denoise: bool) -> list[dict]:
    from mocapkit.datasets import bundled

    big = tmp / "big200k.bvh"
    tile_bvh(bundled("16_15.bvh"), big, BIG_FRAMES)
    rows = []
    for impl, pkg, path in [("after", "mocapkit", None)] + ([("before", "mocapkit_ref", ref)] if ref else []):
        info = timed_cli(["info", str(big)], pkg, path)
        rows.append({"what": "info", "impl": impl, "frames": BIG_FRAMES, "mb": round(big.stat().st_size / 1e6, 1), **info})
        if impl == "after" or ref_denoise:
            out = tmp / f"den_{impl}.bvh"
            d = timed_cli(["denoise", str(big), str(out), "--method", "kalman-cv", "--force", "-q"], pkg, path)
            rows.append({"what": "denoise kalman-cv", "impl": impl, "frames": BIG_FRAMES,
                         "mb": round(big.stat().st_size / 1e6, 1), **d})
        print(rows[-2:], flush=True)
    return rows


def _cpu(fn, n: int = 3):
    """Best-of-n process CPU seconds and the last result."""
    best, out = float("inf"), None
    for _ in range(n):
        t = time.process_time()
        out = fn()
        best = min(best, time.process_time() - t)
    return best, out


def _mods(pkg: str):
    """(io, AMC kinematics with ``cm_per_unit``, bvh, denoise) of ``pkg``; a ``--reference``
    from before issue #16 has them all in ``io.asfamc``."""
    io = __import__(f"{pkg}.io", fromlist=["read"])
    try:
        asfamc = __import__(f"{pkg}.io.asfamc", fromlist=["read"])
    except ImportError:
        kin = __import__(f"{pkg}.io._kinematics", fromlist=["read"])
        asf = __import__(f"{pkg}.io.asf", fromlist=["read"])
        asfamc = SimpleNamespace(_Compiled=kin._Compiled, forward_kinematics=kin.forward_kinematics,
                                 inverse_kinematics=kin.inverse_kinematics, cm_per_unit=asf.cm_per_unit)
    bvh = __import__(f"{pkg}.io.bvh", fromlist=["read"])
    den = __import__(f"{pkg}.denoise", fromlist=["get"])
    return io, asfamc, bvh, den


def amc_cases(asfamc, m, cleaned):
    comp = asfamc._Compiled(m.source["asf"])
    cm = asfamc.cm_per_unit(m.source["asf"])
    rng = np.random.default_rng(0)
    D = m.source["per_frame"]["dofs"]
    D1 = D + rng.normal(0, 2.0, D.shape) * (np.arange(D.shape[1]) >= 3)
    return comp, cm, {"kalman-cv output": (cleaned.positions, D),
                      "reachable (stored dofs + N(0, 2 deg))": (asfamc.forward_kinematics(comp, D1, False, cm), D),
                      "no stored dofs (clean positions)": (m.positions, None),
                      "1 cm i.i.d. noise": (m.positions + rng.normal(0, 1.0, m.positions.shape), D)}


def write_rows(data: Path, tmp: Path, impls: list[str]) -> tuple[list[dict], list[dict]]:
    speed, acc = [], []
    for impl in impls:
        pkg = "mocapkit" if impl == "after" else "mocapkit_ref"
        io, asfamc, bvh, den = _mods(pkg)
        for clip in AMC_CLIPS:
            m = io.read(data / "cmu" / "asfamc" / (clip + ".amc"))
            k = den.get("kalman-cv", gate=5.0).denoise(m)
            comp, cm, cases = amc_cases(asfamc, m, k)
            for case, (P, S) in cases.items():
                dt, out = _cpu(lambda: asfamc.inverse_kinematics(comp, P, cm, False, S), 1 if clip != AMC_CLIPS[0] else 3)
                e = np.linalg.norm(asfamc.forward_kinematics(comp, out, False, cm) - P, axis=2)
                acc.append({"format": "amc", "clip": clip.split("/")[1], "case": case, "impl": impl,
                            "max_cm": float(e.max()), "mean_cm": float(e.mean()), "ik_frames_per_s": m.n_frames / dt})
            if clip == AMC_CLIPS[0]:
                dt_w, _ = _cpu(lambda: io.write(k, tmp / f"w_{impl}.amc", overwrite=True))
                dt_ik = min(a["ik_frames_per_s"] for a in acc if a["impl"] == impl and a["case"] == "kalman-cv output"
                            and a["clip"] == clip.split("/")[1])
                speed.append({"format": "amc", "clip": clip.split("/")[1], "impl": impl, "frames": m.n_frames,
                              "ik_frames_per_s": dt_ik, "write_frames_per_s": m.n_frames / dt_w})
            print(acc[-4:], flush=True)
        m = io.read(data / BVH_CLIP)
        k = den.get("kalman-cv", gate=5.0).denoise(m)
        meta = m.source["bvh"]
        nodes, jn = bvh._meta_to_nodes(meta["nodes"]), list(meta["joint_nodes"])
        ch0 = np.asarray(m.source["per_frame"]["channels"])
        N = len(nodes)
        tg = np.full((m.n_frames, N, 3), np.nan)
        tg[:, jn] = k.positions
        have = np.zeros(N, bool)
        have[jn] = True
        dt_ik, _ = _cpu(lambda: bvh._inverse_kinematics(nodes, tg, have, ch0))
        dt_w, _ = _cpu(lambda: io.write(k, tmp / f"w_{impl}.bvh", overwrite=True))
        back = io.read(tmp / f"w_{impl}.bvh")
        e = np.linalg.norm(back.positions - k.positions, axis=2)
        speed.append({"format": "bvh", "clip": "131_02 (cgspeed)", "impl": impl, "frames": m.n_frames,
                      "ik_frames_per_s": m.n_frames / dt_ik, "write_frames_per_s": m.n_frames / dt_w})
        acc.append({"format": "bvh", "clip": "131_02 (cgspeed)", "case": "kalman-cv output, write -> read",
                    "impl": impl, "max_cm": float(e.max()), "mean_cm": float(e.mean()),
                    "ik_frames_per_s": m.n_frames / dt_ik})
        print(speed[-2:], flush=True)
    return speed, acc


def batch_rows(data: Path, tmp: Path, impls: list[str]) -> list[dict]:
    from distributed import LocalCluster

    lib = tmp / "batchlib"
    for c in BATCH_CLIPS:
        subj = c.split("/")[0]
        (lib / subj).mkdir(parents=True, exist_ok=True)
        shutil.copy(data / "cmu" / "asfamc" / (c + ".amc"), lib / subj)
        shutil.copy(data / "cmu" / "asfamc" / subj / f"{subj}.asf", lib / subj)
    rows = []
    for impl in impls:
        pkg = "mocapkit" if impl == "after" else "mocapkit_ref"
        run_batch = __import__(f"{pkg}.batch", fromlist=["run_batch"]).run_batch
        for mode in ("2 local workers", "local Dask cluster, 2 workers"):
            out = tmp / f"bout_{impl}_{len(rows)}"
            kw = dict(method="kalman-cv", params={"gate": 5.0}, progress=False)
            t = time.perf_counter()
            if mode.startswith("2 local"):
                s = run_batch(lib, out, workers=2, **kw)
            else:
                with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  env={"OMP_NUM_THREADS": "1", "PYTHONPATH": os.environ.get("PYTHONPATH", "")}) as cl:
                    t = time.perf_counter()
                    s = run_batch(lib, out, workers=2, scheduler=cl.scheduler_address, **kw)
            wall = time.perf_counter() - t
            rows.append({"impl": impl, "mode": mode, "files_ok": s.ok, "failed": s.failed, "frames": s.frames,
                         "wall_s": wall, "frames_per_s": s.frames / wall, "frames_per_s_per_worker": s.frames / wall / 2})
            print(rows[-1], flush=True)
    return rows


def render(res: dict) -> str:
    L = ["# Reader / writer speed (issue #21, items 3-4)", "",
         f"Produced by `benchmarks/io_speed.py` on {res['date']} ({res['machine']}; OMP/OpenBLAS 1 thread; "
         f"load average {res['load_before']:.1f} before / {res['load_after']:.1f} after the run: the 2 cores were "
         f"shared with other jobs, so wall times are inflated, CPU seconds less so). \"before\" = the package "
         f"before this change (`--reference`), \"after\" = this tree.", "",
         f"## 200,000-frame BVH (CMU 16_15 tiled, one process per command; measured {res.get('big_bvh_date')})", "",
         "| command | impl | frames | MB | wall s | CPU s | peak RSS MB |", "|---|---|---:|---:|---:|---:|---:|"]
    for r in res["big_bvh"]:
        L.append(f"| `{r['what']}` | {r['impl']} | {r['frames']} | {r['mb']} | {r['wall_s']} | {r['cpu_s']} | "
                 f"{r['peak_rss_mb']} |" + (f" rc {r['rc']}: {r['tail']}" if r["rc"] else ""))
    L += ["", "Targets: `info` <= 5 s and <= 600 MB; `denoise` (kalman-cv) <= 30 s end to end.", "",
          "## Write-back speed (kalman-cv output; CPU seconds, best of 3)", "",
          "| format | clip | impl | frames | IK frames/s | whole write frames/s |", "|---|---|---|---:|---:|---:|"]
    for r in res["write_speed"]:
        L.append(f"| {r['format']} | {r['clip']} | {r['impl']} | {r['frames']} | {r['ik_frames_per_s']:.0f} | "
                 f"{r['write_frames_per_s']:.0f} |")
    L += ["", "## IK accuracy: joint error between targets and the written pose (cm)", "",
          "| format | clip | case | impl | max | mean | IK frames/s |", "|---|---|---|---|---:|---:|---:|"]
    for r in sorted(res["accuracy"], key=lambda r: (r["format"], r["clip"], r["case"], r["impl"] != "before")):
        L.append(f"| {r['format']} | {r['clip']} | {r['case']} | {r['impl']} | {r['max_cm']:.4f} | "
                 f"{r['mean_cm']:.5f} | {r['ik_frames_per_s']:.0f} |")
    L += ["", "## `mocapkit batch`: 8 CMU AMC clips, kalman-cv (gate 5)", "",
          "| impl | mode | files ok | failed | frames | wall s | frames/s | frames/s per worker |",
          "|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in res["batch"]:
        L.append(f"| {r['impl']} | {r['mode']} | {r['files_ok']} | {r['failed']} | {r['frames']} | {r['wall_s']:.1f} | "
                 f"{r['frames_per_s']:.0f} | {r['frames_per_s_per_worker']:.0f} |")
    L += ["", "Batch wall time includes reading, cleaning and the atomic AMC write (IK); the Dask row "
          "excludes the cluster start-up.", "",
          "## What changed in the last run's \"after\" (issue #21 item 4; \"before\" = commit 8b1870c)", "",
          "* AMC writer IK (2026-12-02 evening): the Levenberg-Marquardt normal equations J^T J and J^T r "
          "built from per-subtree sums (count, sum p, sum p p^T) instead of a dense 62 x 93 Jacobian, in "
          "reused buffers (`_ik_normal_equations`, tested against the dense Jacobian); one 3x3 product per "
          "bone in the batched FK; component-wise 3x3 products in the closed-form pass, the Euler extraction "
          "and `twist_angle`. Same accuracy table (largest change 1e-9 cm). Batching the closed-form pass "
          "by tree level was measured not to pay (its time is numpy's per-item work on 3x3 stacks).",
          "",
          "Before that: forward kinematics batched by tree level (all bones of one depth at once, blocks "
          "of 8,192 frames), which also gives every dof's world axis; the Levenberg-Marquardt polish builds "
          "its Jacobian from them in one scatter (`w x (p - pivot)`) into a reused buffer and rebuilds the "
          "normal equations only for frames whose last step was accepted; the start rotations of all nodes "
          "at once; a 3-dof bone keeps its fitted rotation instead of re-forming it from its angles. Same "
          "dofs (the accuracy table is unchanged); the LM polish is now about half of the IK time on 131_02 "
          "(187 of 1,247 frames, 12 iterations at most), the closed-form pass the other half.",
          "",
          "Before that (2026-12-02 morning): BVH frame blocks through `np.loadtxt`, the command line without "
          "numpy's huge-page advice, kalman-cv as constant-gain filters on complete data (`denoise` of the "
          "200k-frame BVH 39.9 -> 21.6 s).",
          "",
          "Earlier (the run of 2026-12-01): BVH frame lines in 4 MB blocks by `np.fromstring` with the "
          "token counts from the bytes, chunked (3, 3, T) forward kinematics; BVH writer IK in chunks "
          "with Kabsch by a Newton polar iteration and a vectorised `%.9f` formatter; AMC writer "
          "closed-form top-down IK with Levenberg-Marquardt only where the closed form is off; one "
          "rotation module (`mocapkit/io/_rotations.py`)."]
    return "\n".join(L) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data")
    ap.add_argument("--reference")
    ap.add_argument("--reference-denoise", action="store_true")
    ap.add_argument("--skip-big", action="store_true", help="keep the 200k-frame rows of the last run")
    ap.add_argument("--render-only", action="store_true", help="rewrite the .md from the .json")
    a = ap.parse_args()
    if a.render_only:
        OUT_MD.write_text(render(json.loads(OUT_JSON.read_text())))
        return
    sys.path.insert(0, str(ROOT))
    from mocapkit.datasets import shared_data_dir

    data = shared_data_dir(a.data)
    if data is None:
        raise SystemExit("shared data not found (--data DIR)")
    res = {"date": time.strftime("%Y-%m-%d %H:%M"), "machine": f"{platform.machine()}, {os.cpu_count()} cores",
           "load_before": os.getloadavg()[0]}
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        ref = make_reference(Path(a.reference), tmp / "ref") if a.reference else None
        if ref is not None:
            sys.path.insert(0, str(ref))
            os.environ["PYTHONPATH"] = str(ref) + os.pathsep + os.environ.get("PYTHONPATH", "")
        impls = ["before", "after"] if ref else ["after"]
        if a.skip_big:                     # keep the 200k-frame rows of the previous run
            old = json.loads(OUT_JSON.read_text()) if OUT_JSON.exists() else {}
            res["big_bvh"] = old.get("big_bvh", [])
            res["big_bvh_date"] = old.get("big_bvh_date", old.get("date"))
        else:
            res["big_bvh"] = big_bvh_rows(tmp, ref, a.reference_denoise)
            res["big_bvh_date"] = res["date"]
        res["write_speed"], res["accuracy"] = write_rows(data, tmp, impls)
        res["batch"] = batch_rows(data, tmp, impls)
    res["load_after"] = os.getloadavg()[0]
    OUT_JSON.write_text(json.dumps(res, indent=1) + "\n")
    OUT_MD.write_text(render(res))
    print(render(res))


if __name__ == "__main__":
    main()
