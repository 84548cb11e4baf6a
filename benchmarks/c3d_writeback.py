"""What a cleaned C3D file keeps of its source: every shared C3D marker file through
``mocapkit denoise IN OUT`` (no options), the output compared with the input by ezc3d.
Writes docs/results/c3d_writeback.json + .md.

Usage: ``python benchmarks/c3d_writeback.py [--data DIR] [--render-only]``

Per file: the analog channels (count, samples, largest difference), the header's first
frame, the events (``EVENT:LABELS`` / ``TIMES``), the parameter groups and the parameters
of the source missing from the output or with other values -- leaving out those the writer
sets on purpose (:data:`WRITER_SETS`: the points' labels, unit, scale and storage, and the
per-channel lists ezc3d requires cut to one entry per channel) -- and the model outputs and
markers read. One BLAS thread; under a minute.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import sys  # noqa: E402
import tempfile  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from _report import run_or_render  # noqa: E402
from mocapkit import cli, io  # noqa: E402
from mocapkit.errors import MocapError  # noqa: E402

OUT = ROOT / "docs" / "results" / "c3d_writeback.md"
#: parameters the writer sets (its points, their unit and float storage) or ezc3d rewrites
#: (block pointers, frame counts, integer-storage fields of float files), not compared
WRITER_SETS = {("POINT", k) for k in ("LABELS", "LABELS2", "DESCRIPTIONS", "DESCRIPTIONS2", "UNITS", "SCALE",
                                       "DATA_START", "FRAMES", "USED", "LONG_FRAMES")} | \
              {("ANALOG", k) for k in ("LABELS", "DESCRIPTIONS", "UNITS", "SCALE", "OFFSET", "FORMAT", "BITS",
                                        "USED")} | {("EZC3D", "VERSION")}


def _values(c) -> dict:
    out = {}
    for g, grp in c["parameters"].items():
        if not isinstance(grp, dict):
            continue
        for k, v in grp.items():
            if k != "__METADATA__" and isinstance(v, dict):
                out[(g, k)] = np.asarray(v.get("value"), dtype=object).ravel().tolist()
    return out


def _compare(src: Path, out: Path) -> dict:
    import ezc3d

    a, b = ezc3d.c3d(str(src), extract_forceplat_data=False), ezc3d.c3d(str(out), extract_forceplat_data=False)
    A, B = np.asarray(a["data"]["analogs"]), np.asarray(b["data"]["analogs"])
    va, vb = _values(a), _values(b)
    missing = sorted(f"{g}:{k}" for g, k in va if (g, k) not in vb and (g, k) not in WRITER_SETS)
    differ = sorted(f"{g}:{k}" for (g, k), v in va.items()
                    if (g, k) in vb and (g, k) not in WRITER_SETS and str(vb[(g, k)]) != str(v))
    ev = ("EVENT", "LABELS"), ("EVENT", "TIMES")
    return {"analog_in": int(A.shape[1]) if A.ndim == 3 else 0,
            "analog_out": int(B.shape[1]) if B.ndim == 3 else 0,
            "analog_samples_equal": bool(A.shape == B.shape and np.array_equal(A, B, equal_nan=True)),
            "analog_max_diff": float(np.nanmax(np.abs(A - B))) if A.shape == B.shape and A.size else None,
            "first_in": int(a["header"]["points"]["first_frame"]),
            "first_out": int(b["header"]["points"]["first_frame"]),
            "events_in": len(va.get(ev[0], [])), "events_equal": all(str(va.get(k)) == str(vb.get(k)) for k in ev),
            "groups_missing": sorted(set(a["parameters"].keys()) - set(b["parameters"].keys())),
            "params_missing": missing, "params_differ": differ,
            "points_in": int(np.shape(a["data"]["points"])[1]), "points_out": int(np.shape(b["data"]["points"])[1])}


def run(data: Path, args) -> dict:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for src in sorted((data / "markers").rglob("*.c3d")):
            rel = str(src.relative_to(data / "markers"))
            row = {"file": rel}
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    m = io.read(src)
            except MocapError as e:
                rows.append({**row, "refused": str(e).split(": ", 1)[-1][:120]})
                continue
            out = Path(tmp) / src.name
            with warnings.catch_warnings(record=True) as w:
                warnings.simplefilter("always")
                rc = cli.main(["denoise", str(src), str(out), "-q"])
            row.update(rc=rc, markers=m.n_joints, frames=m.n_frames,
                       model_outputs=m.source["c3d"].get("model_outputs", {}),
                       warnings=sorted({str(x.message).split(": ", 1)[-1][:100] for x in w
                                        if "written without" in str(x.message)}))
            if rc == 0:
                row.update(_compare(src, out))
            rows.append(row)
            print(row, flush=True)
    return {"rows": rows}


def render(doc: dict) -> str:
    rows = doc["rows"]
    ok = [r for r in rows if r.get("rc") == 0]
    lines = ["# What a cleaned C3D file keeps of its source", "",
             f"Generated by `python benchmarks/c3d_writeback.py` from c3d_writeback.json ({doc['seconds']:.0f} s). "
             "Every shared C3D marker file through `mocapkit denoise IN OUT` (no options: auto), the output "
             "compared with the input by ezc3d; see the script's docstring for what is compared.", "",
             f"- files cleaned: {len(ok)}; refused on reading: {len(rows) - len(ok)} "
             f"({', '.join(r['file'] for r in rows if 'refused' in r)})",
             f"- analog channels kept: {sum(r['analog_out'] for r in ok)} of {sum(r['analog_in'] for r in ok)}, "
             f"every sample equal in {sum(r['analog_samples_equal'] for r in ok if r['analog_in'])} of "
             f"{sum(1 for r in ok if r['analog_in'])} files with analogs",
             f"- first frame kept: {sum(r['first_in'] == r['first_out'] for r in ok)} of {len(ok)}; "
             f"events kept: {sum(r['events_equal'] for r in ok)} of {len(ok)}",
             f"- parameter groups lost: {sum(len(r['groups_missing']) for r in ok)}; other parameters lost: "
             f"{sum(len(r['params_missing']) for r in ok)}, changed: {sum(len(r['params_differ']) for r in ok)}",
             "- before this writer (until 2026-12-05) a cleaned file started from an empty one: no analog "
             "channel, event, subject or force-plate parameter, first frame 0", "",
             "| file | markers | model outputs | frames | analog in / out | samples equal | first frame in / out "
             "| events | groups lost | parameters lost / changed | warnings |",
             "|---|---:|---|---:|---:|---|---:|---:|---|---|---|"]
    for r in rows:
        if r.get("rc") != 0:
            lines.append(f"| {r['file']} | refused: {r.get('refused', 'exit ' + str(r.get('rc')))} |  |  |  |  |  |  |  |  |  |")
            continue
        mo = ", ".join(f"{n} {k.lower()}" for k, n in r["model_outputs"].items()) or "-"
        lost = ", ".join(r["params_missing"] + [p + " (changed)" for p in r["params_differ"]]) or "-"
        lines.append(f"| {r['file']} | {r['markers']} | {mo} | {r['frames']} | {r['analog_in']} / {r['analog_out']} | "
                     f"{'yes' if r['analog_samples_equal'] else 'no'} | {r['first_in']} / {r['first_out']} | "
                     f"{r['events_in']} {'kept' if r['events_equal'] else 'LOST'} | "
                     f"{', '.join(r['groups_missing']) or '-'} | {lost} | {'; '.join(r['warnings']) or '-'} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(run_or_render(OUT, run, render, __doc__.splitlines()[0]))
