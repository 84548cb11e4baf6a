"""Fuzzing every reader (issue 10): malformed input ends in MocapError or a valid Motion.

Each reader gets small valid seed files (bundled CMU clips cut to a few frames, or tiny
synthetic files written by mocapkit's own writers) and hypothesis applies random
mutations: truncation, byte flips, line deletion / duplication / swaps, tokens replaced
by huge numbers, NaN/inf text, garbage, unknown keywords and channels, and inserted
bytes. Targeted cases cover duplicate joint names, cyclic and empty hierarchies, zero
frames, wrong counts and mismatched ASF/AMC pairs.

Contract checked for every case: the read either raises :class:`mocapkit.errors.MocapError`
or returns a Motion with consistent shapes, ``fps > 0``, finite positions wherever
``observed`` and NaN elsewhere - never another exception, within a per-example deadline.
Memory is bounded by checking the process's peak RSS growth over the whole run.

C3D files go through ezc3d (C++), which can crash the interpreter on corrupt input, so C3D
cases are read in a separate worker process; a crash shows up as a failed example, not as
a dead test run.

The contract also forbids leaked warnings: a read may emit mocapkit's own warnings
(:class:`mocapkit.errors.MocapWarning`, e.g. a header count that disagrees with the data)
but no numpy ``RuntimeWarning`` or any other warning.

Determinism: in ``make test`` the property tests run *derandomised* (profile
``mocapkit-deterministic``: ``derandomize=True``, ``database=None``, no deadline, no health
check can fail the run), so the same examples run every time and a passing suite stays
passing. ``make fuzz`` sets ``MOCAPKIT_FUZZ_RANDOM=1`` (profile ``mocapkit-fuzz``: random
examples, 10 s deadline per example) and ``MOCAPKIT_FUZZ_EXAMPLES=2000``; setting only
``MOCAPKIT_FUZZ_EXAMPLES`` also selects the random run. The profiles are applied per test
(``settings(parent=...)``), never loaded globally, so other test modules are unaffected.
Strategies build valid mutations directly (no ``filter``/``assume``), so no example is
ever rejected.

Example counts: ``fuzz_examples()`` from conftest (``MOCAPKIT_FUZZ_EXAMPLES``; ``make fuzz``
sets 2000). A case that ever failed is stored under ``tests/fuzz_regressions/<format>/``
(the fuzz test writes the failing input there as ``_last_failure.*``; rename it after the
fix) and replayed by ``test_fuzz_regressions_replay``.
"""
from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os
import resource
import tempfile
import warnings
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import mocapkit.io as mio
from mocapkit.errors import MocapError, MocapWarning
from mocapkit.motion import Motion
from mocapkit.skeleton import Skeleton

from conftest import fuzz_examples

DATA = Path(mio.__file__).resolve().parents[1] / "data" / "cmu"
REG = Path(__file__).parent / "fuzz_regressions"
N_EXAMPLES = fuzz_examples(40)
RANDOM = os.environ.get("MOCAPKIT_FUZZ_RANDOM",
                        "1" if os.environ.get("MOCAPKIT_FUZZ_EXAMPLES") else "0").strip() == "1"
settings.register_profile("mocapkit-deterministic", derandomize=True, database=None, deadline=None,
                          suppress_health_check=list(HealthCheck), print_blob=True)
settings.register_profile("mocapkit-fuzz", derandomize=False, database=None,
                          deadline=timedelta(seconds=10),
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
                          print_blob=True)
PROFILE = settings.get_profile("mocapkit-fuzz" if RANDOM else "mocapkit-deterministic")
EXT = {"bvh": ".bvh", "amc": ".amc", "asf": ".asf", "c3d": ".c3d", "trc": ".trc", "kinect": ".txt"}


# ---------------------------------------------------------------------------------------
# seeds
# ---------------------------------------------------------------------------------------
def _cut_bvh(text: str, n: int) -> str:
    lines = text.splitlines()
    k = next(i for i, s in enumerate(lines) if s.strip().upper() == "MOTION")
    head = lines[:k + 1] + [f"Frames: {n}", lines[k + 2]]
    return "\n".join(head + lines[k + 3:k + 3 + n]) + "\n"


def _cut_amc(text: str, n: int) -> str:
    out, frame = [], 0
    for s in text.splitlines():
        if s.strip().isdigit():
            frame += 1
            if frame > n:
                break
        out.append(s)
    return "\n".join(out) + "\n"


def _marker_motion() -> Motion:
    rng = np.random.default_rng(1)
    P = rng.uniform(-80, 80, (4, 3, 3)) + np.array([0, 100, 0])
    P[1, 2] = np.nan
    sk = Skeleton(("LASI", "RASI", "HEAD"), [-1, -1, -1], np.zeros((3, 3)))
    return Motion(P, sk, 100.0)


def _kinect_text(frames: int = 2) -> str:
    rng = np.random.default_rng(2)
    base = np.column_stack([rng.uniform(-0.3, 0.3, 20), np.linspace(-0.8, 0.8, 20), np.full(20, 2.6)])
    rows = []
    for t in range(frames):
        for j in range(20):
            x, y, z = base[j] + 0.01 * t
            rows.append(f"{x:.6f} {y:.6f} {z:.6f} {int(j % 3 != 0)}")
    return "\n".join(rows) + "\n"


_SEEDS: dict | None = None


def seeds() -> dict[str, list[dict[str, bytes]]]:
    """format -> list of seed cases; a case maps file role ('main', 'asf') to bytes."""
    global _SEEDS
    if _SEEDS is not None:
        return _SEEDS
    from mocapkit.io import c3d, trc
    bvh = (DATA / "bvh" / "motionbuilder75" / "16_15.bvh").read_text()
    asf16 = (DATA / "asfamc" / "16" / "16.asf").read_bytes()
    amc16 = _cut_amc((DATA / "asfamc" / "16" / "16_15.amc").read_text(), 3).encode()
    asf07 = (DATA / "asfamc" / "07" / "07.asf").read_bytes()
    amc07 = _cut_amc((DATA / "asfamc" / "07" / "07_05.amc").read_text(), 2).encode()
    m = _marker_motion()
    with tempfile.TemporaryDirectory() as d:
        trc.write(m, Path(d) / "s.trc")
        c3d.write(m, Path(d) / "s.c3d")
        trc_b = (Path(d) / "s.trc").read_bytes()
        c3d_b = (Path(d) / "s.c3d").read_bytes()
    tiny_bvh = ("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition "
                "Zrotation Xrotation Yrotation\n JOINT Spine\n {\n  OFFSET 0 50 0\n  CHANNELS 3 "
                "Zrotation Xrotation Yrotation\n  End Site\n  {\n   OFFSET 0 40 0\n  }\n }\n}\n"
                "MOTION\nFrames: 2\nFrame Time: 0.01\n0 90 0 0 0 0 10 0 0\n1 90 0 0 5 0 20 0 0\n")
    _SEEDS = {
        "bvh": [{"main": _cut_bvh(bvh, 2).encode()}, {"main": tiny_bvh.encode()}],
        "amc": [{"main": amc16, "asf": asf16}, {"main": amc07, "asf": asf07},
                {"main": amc16, "asf": asf07}],          # mismatched pair (other subject's ASF)
        "asf": [{"main": asf16}],
        "trc": [{"main": trc_b}],
        "kinect": [{"main": _kinect_text(2).encode()}],
        "c3d": [{"main": c3d_b}],
    }
    return _SEEDS


# ---------------------------------------------------------------------------------------
# reading one case and checking the contract
# ---------------------------------------------------------------------------------------
def _write_case(d: Path, fmt: str, case: dict[str, bytes]) -> tuple[Path, dict]:
    main = d / f"case{EXT[fmt]}"
    main.write_bytes(case["main"])
    opts = {}
    if "asf" in case:
        (d / "case.asf").write_bytes(case["asf"])
        opts["skeleton"] = d / "case.asf"
    return main, opts


def check_motion(m) -> str | None:
    """None if ``m`` is a valid Motion, else what is wrong."""
    if not isinstance(m, Motion):
        return f"reader returned {type(m).__name__}, not a Motion"
    P, obs = np.asarray(m.positions), np.asarray(m.observed)
    if P.ndim != 3 or P.shape[2] != 3 or P.shape[0] < 1 or P.shape[1] != m.skeleton.n_joints:
        return f"bad positions shape {P.shape} for {m.skeleton.n_joints} joints"
    if obs.shape != P.shape[:2]:
        return f"observed shape {obs.shape} != {P.shape[:2]}"
    if not np.isfinite(P[obs]).all():
        return "non-finite positions where observed"
    if not np.isnan(P[~obs]).all():
        return "missing entries are not NaN"
    if not (np.isfinite(m.fps) and m.fps > 0):
        return f"fps {m.fps!r}"
    return None


def read_outcome(fmt: str, case: dict[str, bytes]) -> str:
    """'ok', 'error: <MocapError message>' or 'BUG: <what>' (any other exception / bad Motion)."""
    with tempfile.TemporaryDirectory() as d:
        path, opts = _write_case(Path(d), fmt, case)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                m = mio.read(path, format=fmt, **opts)
            except MocapError as e:
                m, out = None, f"error: {str(e)[:200]}"
            except RecursionError as e:                     # noqa: F841 - a bug, but say which
                return "BUG: RecursionError"
            except Exception as e:                          # noqa: BLE001 - the point of the test
                return f"BUG: {type(e).__name__}: {e}"[:400]
        leaked = [w for w in caught if not issubclass(w.category, MocapWarning)]
        if leaked:
            w = leaked[0]
            return (f"BUG: leaked {w.category.__name__} ({Path(w.filename).name}:{w.lineno}): "
                    f"{w.message}")[:400]
        if m is None:
            return out
        bad = check_motion(m)
        return "ok" if bad is None else f"BUG: {bad}"


def _worker_read(fmt: str, case: dict[str, bytes]) -> tuple[str, int]:
    out = read_outcome(fmt, case)
    return out, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


_POOL: cf.ProcessPoolExecutor | None = None


def _pool() -> cf.ProcessPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = cf.ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn"))
    return _POOL


def isolated_outcome(fmt: str, case: dict[str, bytes], timeout: float = 60.0) -> str:
    """read_outcome in a worker process: a crash (segfault) or hang is reported as a BUG."""
    global _POOL
    try:
        out, rss_kb = _pool().submit(_worker_read, fmt, case).result(timeout=timeout)
    except cf.process.BrokenProcessPool:
        _POOL = None
        return "BUG: the reader crashed the interpreter (worker process died)"
    except cf.TimeoutError:
        _POOL.shutdown(wait=False, cancel_futures=True)
        for p in list(getattr(_POOL, "_processes", {}).values()):
            p.kill()
        _POOL = None
        return f"BUG: no answer within {timeout:g} s (hang?)"
    if rss_kb > 2_000_000:
        return f"BUG: worker peak memory {rss_kb / 1e6:.1f} GB"
    return out


def record_failure(fmt: str, case: dict[str, bytes], outcome: str) -> None:
    d = REG / fmt
    d.mkdir(parents=True, exist_ok=True)
    (d / f"_last_failure{EXT[fmt]}").write_bytes(case["main"])
    if "asf" in case:
        (d / "_last_failure.asf.skel").write_bytes(case["asf"])
    (d / "_last_failure.txt").write_text(outcome + "\n")


def assert_contract(fmt: str, case: dict[str, bytes], isolated: bool = False) -> str:
    out = isolated_outcome(fmt, case) if isolated else read_outcome(fmt, case)
    if out.startswith("BUG"):
        record_failure(fmt, case, out)
        pytest.fail(f"{fmt}: {out}")
    return out


# ---------------------------------------------------------------------------------------
# mutations
# ---------------------------------------------------------------------------------------
TOKENS = ["nan", "NaN", "inf", "-inf", "1e308", "-1e309", "1e400", "99999999999999999999", "0", "-1",
          "-0", "2147483648", "1.5", "abc", "", "{", "}", "Xrotation", "Wrotation", "Xposition",
          "End", "Site", "JOINT", "ROOT", "MOTION", "Frames:", "root", "begin", "end", ":bonedata",
          ":hierarchy", "dof", "limits", "(-inf", "inf)", "1e-320", "0x10", "\t", ",", "rx", "lfemur",
          "1,5", "٣", "\u00e9", "1e-300", "1e300"]

frac = st.floats(0, 1, allow_nan=False)
mutation = st.one_of(
    st.tuples(st.just("truncate"), frac),
    st.tuples(st.just("flip"), frac, st.integers(0, 255)),
    st.tuples(st.just("delete_line"), frac),
    st.tuples(st.just("dup_line"), frac),
    st.tuples(st.just("swap_lines"), frac, frac),
    st.tuples(st.just("token"), frac, frac, st.sampled_from(TOKENS)),
    st.tuples(st.just("insert"), frac, st.binary(min_size=1, max_size=8)),
)


def _at(f: float, n: int) -> int:
    return min(int(f * n), max(n - 1, 0))


def mutate(data: bytes, muts) -> bytes:
    for m in muts:
        kind = m[0]
        if kind == "truncate":
            data = data[:_at(m[1], len(data) + 1)]
        elif kind == "flip" and data:
            i = _at(m[1], len(data))
            data = data[:i] + bytes([m[2]]) + data[i + 1:]
        elif kind == "insert":
            i = _at(m[1], len(data) + 1)
            data = data[:i] + m[2] + data[i:]
        else:
            lines = data.split(b"\n")
            if kind == "delete_line" and len(lines) > 1:
                del lines[_at(m[1], len(lines))]
            elif kind == "dup_line":
                i = _at(m[1], len(lines))
                lines.insert(i, lines[i])
            elif kind == "swap_lines":
                i, j = _at(m[1], len(lines)), _at(m[2], len(lines))
                lines[i], lines[j] = lines[j], lines[i]
            elif kind == "token":
                i = _at(m[1], len(lines))
                toks = lines[i].split()
                if toks:
                    toks[_at(m[2], len(toks))] = m[3].encode()
                    lines[i] = b" ".join(toks)
            data = b"\n".join(lines)
    return data


def _mutated_case(fmt: str, seed_i: int, muts, target_asf: bool):
    base = seeds()[fmt][seed_i % len(seeds()[fmt])]
    case = dict(base)
    key = "asf" if (target_asf and "asf" in case) else "main"
    case[key] = mutate(case[key], muts)
    return case


FUZZ = settings(parent=PROFILE, max_examples=N_EXAMPLES)
case_args = dict(seed_i=st.integers(0, 5), muts=st.lists(mutation, min_size=1, max_size=4),
                 target_asf=st.booleans())

_rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
OUTCOMES: dict[str, dict[str, int]] = {}


def _count(fmt: str, out: str) -> None:
    c = OUTCOMES.setdefault(fmt, {"ok": 0, "error": 0})
    c["ok" if out == "ok" else "error"] += 1


# ---------------------------------------------------------------------------------------
# tests
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("fmt", ["bvh", "amc", "asf", "trc", "kinect"])
def test_fuzz_seeds_read(fmt):
    """The unmutated seeds are valid files (else the fuzzing would only test error paths)."""
    for i, case in enumerate(seeds()[fmt]):
        out = read_outcome(fmt, case)
        if fmt == "amc" and i == 2:                     # 16_15.amc on subject 07's skeleton
            assert not out.startswith("BUG"), out
        else:
            assert out == "ok", out


@pytest.mark.parametrize("fmt", ["bvh", "amc", "asf", "trc", "kinect"])
@FUZZ
@given(**case_args)
def test_fuzz_text_readers(fmt, seed_i, muts, target_asf):
    case = _mutated_case(fmt, seed_i, muts, target_asf)
    _count(fmt, assert_contract(fmt, case))


C3D_HEADER_FIELDS = [0, 1, 2, 4, 6, 8, 10, 12, 16, 512, 514, 515]  # pointer, key, counts, scale, data start, param head
c3d_mutation = st.one_of(                 # byte-level mutations built directly (no filter)
    st.tuples(st.just("truncate"), frac),
    st.tuples(st.just("flip"), frac, st.integers(0, 255)),
    st.tuples(st.just("insert"), frac, st.binary(min_size=1, max_size=8)),
    st.tuples(st.just("word"), st.sampled_from(C3D_HEADER_FIELDS + list(range(516, 700, 2))),
              st.sampled_from([0, 1, 2, 0x7FFF, 0x8000, 0xFFFF, 255, 256])),
)


def mutate_c3d(data: bytes, muts) -> bytes:
    for m in muts:
        if m[0] == "word":
            i = m[1]
            if i + 2 <= len(data):
                data = data[:i] + int(m[2]).to_bytes(2, "little") + data[i + 2:]
        else:
            data = mutate(data, [m])
    return data


@settings(parent=PROFILE, max_examples=max(10, N_EXAMPLES // 2), deadline=None)
@given(muts=st.lists(c3d_mutation, min_size=1, max_size=4))
def test_fuzz_c3d_isolated(muts):
    case = {"main": mutate_c3d(seeds()["c3d"][0]["main"], muts)}
    _count("c3d", assert_contract("c3d", case, isolated=True))


def test_fuzz_c3d_seed_isolated():
    assert isolated_outcome("c3d", seeds()["c3d"][0]) == "ok"


# targeted cases ----------------------------------------------------------------------------
_BVH_HEAD = "HIERARCHY\nROOT A\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\n"
TARGETED = {
    "bvh": [
        ("empty", ""),
        ("empty-hierarchy", "HIERARCHY\nMOTION\nFrames: 1\nFrame Time: 0.1\n0 0 0\n"),
        ("duplicate-joint", _BVH_HEAD + " JOINT A\n {\n  OFFSET 0 1 0\n  CHANNELS 1 Xrotation\n }\n}\n"
                            "MOTION\nFrames: 1\nFrame Time: 0.1\n0 0 0 0\n"),
        ("unknown-channel", _BVH_HEAD.replace("Zposition", "Wposition") + "}\nMOTION\nFrames: 1\n"
                            "Frame Time: 0.1\n0 0 0\n"),
        ("zero-frames", _BVH_HEAD + "}\nMOTION\nFrames: 0\nFrame Time: 0.1\n"),
        ("huge-frames", _BVH_HEAD + "}\nMOTION\nFrames: 99999999999999\nFrame Time: 0.1\n0 0 0\n"),
        ("huge-channels", "HIERARCHY\nROOT A\n{\n OFFSET 0 0 0\n CHANNELS 999999999 Xposition\n}\n"
                          "MOTION\nFrames: 1\nFrame Time: 0.1\n0\n"),
        ("nan-value", _BVH_HEAD + "}\nMOTION\nFrames: 1\nFrame Time: 0.1\n0 nan 0\n"),
        ("inf-offset", _BVH_HEAD.replace("OFFSET 0 0 0", "OFFSET 0 inf 0") + "}\nMOTION\nFrames: 1\n"
                       "Frame Time: 0.1\n0 0 0\n"),
        ("huge-values", _BVH_HEAD + " JOINT B\n {\n  OFFSET 0 1e308 0\n  CHANNELS 1 Xrotation\n  }\n}\n"
                        "MOTION\nFrames: 1\nFrame Time: 0.1\n1e308 1e308 1e308 1e308\n"),
        ("zero-frame-time", _BVH_HEAD + "}\nMOTION\nFrames: 1\nFrame Time: 0\n0 0 0\n"),
        ("deep-nesting", "HIERARCHY\nROOT J0\n{\n OFFSET 0 0 0\n CHANNELS 1 Xrotation\n"
         + "".join(f"JOINT J{i}\n{{\n OFFSET 0 1 0\n CHANNELS 1 Xrotation\n" for i in range(1, 3000))
         + "}\n" * 3000 + "MOTION\nFrames: 1\nFrame Time: 0.1\n" + "0 " * 3000 + "\n"),
    ],
    "kinect": [
        ("empty", ""),
        ("one-line", "0.1 0.2 2.5 1\n"),
        ("19-lines", "0.1 0.2 2.5 1\n" * 19),
        ("all-zero", "0 0 0 0\n" * 20),
        ("nan", "nan nan nan 1\n" * 20),
        ("huge", "1e308 1e308 1e308 1\n" * 20),
        ("mixed-columns", "0.1 0.2 2.5 1\n" * 10 + "0.1 0.2 2.5\n" * 10),
    ],
    "trc": [
        ("empty", ""),
        ("header-only", "PathFileType\t4\t(X/Y/Z)\tx.trc\n"),
        ("zero-markers", "PathFileType\t4\t(X/Y/Z)\tx.trc\nDataRate\tCameraRate\tNumFrames\tNumMarkers\t"
                         "Units\n100\t100\t1\t0\tmm\nFrame#\tTime\n\t\n\n1\t0\n"),
        ("zero-rate", "PathFileType\t4\t(X/Y/Z)\tx.trc\nDataRate\tCameraRate\tNumFrames\tNumMarkers\t"
                      "Units\n0\t0\t1\t1\tmm\nFrame#\tTime\tA\t\t\n\t\tX1\tY1\tZ1\n\n1\t0\t1\t2\t3\n"),
        ("dup-marker", "PathFileType\t4\t(X/Y/Z)\tx.trc\nDataRate\tCameraRate\tNumFrames\tNumMarkers\t"
                       "Units\n100\t100\t1\t2\tmm\nFrame#\tTime\tA\t\t\tA\t\t\n\t\tX1\tY1\tZ1\tX2\tY2\tZ2\n"
                       "\n1\t0\t1\t2\t3\t4\t5\t6\n"),
    ],
}


def _asf_cyclic() -> bytes:
    t = (DATA / "asfamc" / "16" / "16.asf").read_text()
    return t.replace("lfoot ltoes", "lfoot ltoes lhipjoint").encode()


def _asf_self_parent() -> bytes:
    t = (DATA / "asfamc" / "16" / "16.asf").read_text()
    return t.replace("lfoot ltoes", "lfoot lfoot").encode()


def _asf_empty_hierarchy() -> bytes:
    t = (DATA / "asfamc" / "16" / "16.asf").read_text()
    i, j = t.index(":hierarchy"), t.index("  end", t.index(":hierarchy"))
    return (t[:i] + ":hierarchy\n  begin\n" + t[j:]).encode()


def _asf_dup_bone() -> bytes:
    t = (DATA / "asfamc" / "16" / "16.asf").read_text()
    return t.replace("name rfemur", "name lfemur").encode()


def _targeted_cases():
    out = []
    for fmt, items in TARGETED.items():
        for name, text in items:
            out.append(pytest.param(fmt, {"main": text.encode()}, id=f"{fmt}-{name}"))
    amc = seeds()["amc"][0]
    for name, asf in [("cyclic", _asf_cyclic()), ("self-parent", _asf_self_parent()),
                      ("empty-hierarchy", _asf_empty_hierarchy()), ("duplicate-bone", _asf_dup_bone())]:
        out.append(pytest.param("asf", {"main": asf}, id=f"asf-{name}"))
        out.append(pytest.param("amc", {"main": amc["main"], "asf": asf}, id=f"amc-asf-{name}"))
    out += [
        pytest.param("amc", {"main": b"", "asf": amc["asf"]}, id="amc-empty"),
        pytest.param("amc", {"main": b":FULLY-SPECIFIED\n:DEGREES\n", "asf": amc["asf"]}, id="amc-zero-frames"),
        pytest.param("amc", {"main": amc["main"], "asf": b""}, id="amc-empty-asf"),
        pytest.param("amc", {"main": amc["asf"], "asf": amc["asf"]}, id="amc-is-asf"),
        pytest.param("amc", {"main": amc["main"].replace(b"lfemur", b"nosuchbone"), "asf": amc["asf"]},
                     id="amc-unknown-bone"),
        pytest.param("amc", {"main": amc["main"].replace(b"\n2\n", b"\n7\n"), "asf": amc["asf"]},
                     id="amc-frame-numbering"),
        pytest.param("amc", {"main": seeds()["amc"][1]["main"], "asf": amc["asf"]}, id="amc-mismatched-07-on-16"),
    ]
    return out


@pytest.mark.parametrize("fmt,case", _targeted_cases())
def test_fuzz_targeted(fmt, case):
    out = assert_contract(fmt, case)
    _count(fmt, out)


@pytest.mark.parametrize("name,mut", [("truncated-header", [("truncate", 0.3)]),
                                      ("no-frames", [("word", 6, 5), ("word", 8, 1)]),
                                      ("huge-points", [("word", 2, 0xFFFF)]),
                                      ("bad-key", [("word", 0, 0xFFFF)]),
                                      ("huge-last-frame", [("word", 8, 0xFFFF)]),
                                      ("data-before-params", [("word", 16, 1)])])
def test_fuzz_c3d_targeted(name, mut):
    case = {"main": mutate_c3d(seeds()["c3d"][0]["main"], mut)}
    assert_contract("c3d", case, isolated=True)


# regressions --------------------------------------------------------------------------------
def _regression_cases():
    out = []
    if not REG.is_dir():
        return out
    for d in sorted(p for p in REG.iterdir() if p.is_dir()):
        fmt = d.name
        for f in sorted(d.glob(f"*{EXT.get(fmt, '.none')}")):
            if f.name.startswith("_"):
                continue
            case = {"main": f.read_bytes()}
            skel = f.with_name(f.stem + ".asf.skel")
            if skel.exists():
                case["asf"] = skel.read_bytes()
            out.append(pytest.param(fmt, case, id=f"{fmt}/{f.name}"))
    return out


@pytest.mark.parametrize("fmt,case", _regression_cases() or [pytest.param(None, None, marks=pytest.mark.skip)])
def test_fuzz_regressions_replay(fmt, case):
    """Every stored case now ends in a MocapFormatError (they are all malformed files)."""
    out = assert_contract(fmt, case, isolated=(fmt == "c3d"))
    assert out.startswith("error"), f"{fmt}: expected a format error, got {out}"


def test_fuzz_memory_bounded():
    """Peak RSS growth of this process over all the in-process fuzzing stays bounded."""
    grown_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - _rss0
    assert grown_kb < 1_500_000, f"peak memory grew by {grown_kb / 1e6:.2f} GB while fuzzing"


def test_fuzz_report_counts():
    """Writes the per-reader case counts of this run (used by docs/results/reliability.md)."""
    out = os.environ.get("MOCAPKIT_FUZZ_REPORT")
    if out:
        import json
        Path(out).write_text(json.dumps(OUTCOMES, indent=1, sort_keys=True))


def teardown_module(module):
    global _POOL
    if _POOL is not None:
        _POOL.shutdown(wait=True, cancel_futures=True)
        _POOL = None


# determinism (issue 18) -----------------------------------------------------------------------
def _given_tests():
    return [test_fuzz_text_readers, test_fuzz_c3d_isolated]


@pytest.mark.skipif(RANDOM, reason="the random run (make fuzz) is meant to be random")
def test_fuzz_suite_is_deterministic():
    """In ``make test`` every property test is derandomised, uses no example database and
    cannot fail on a health check (a FailedHealthCheck once failed a fresh clone's run)."""
    for fn in _given_tests():
        s = getattr(fn, "_hypothesis_internal_use_settings")
        assert s.derandomize is True, fn.__name__
        assert s.database is None, fn.__name__
        assert s.deadline is None, fn.__name__
        assert set(s.suppress_health_check) == set(HealthCheck), fn.__name__


def test_c3d_mutations_are_built_without_rejection():
    """The C3D mutation strategy must not filter: drawing with every health check active
    (and a strict filter budget) never rejects an example."""
    seen = []

    @settings(max_examples=200, derandomize=True, database=None, deadline=None,
              suppress_health_check=[])
    @given(muts=st.lists(c3d_mutation, min_size=1, max_size=4))
    def draw(muts):
        seen.append(muts)

    for strat in (mutation, c3d_mutation, *case_args.values()):
        assert ".filter(" not in repr(strat), repr(strat)[:200]
    draw()
    assert len(seen) == 200
    kinds = {m[0] for ms in seen for m in ms}
    assert kinds == {"truncate", "flip", "insert", "word"}


def test_fuzz_contract_rejects_leaked_numpy_warnings(monkeypatch):
    """read_outcome reports a numpy RuntimeWarning escaping a reader as a BUG."""
    def noisy(*a, **k):
        np.log(np.zeros(1))                           # RuntimeWarning: divide by zero
        raise MocapError("x")

    monkeypatch.setattr(mio, "read", noisy)
    out = read_outcome("trc", seeds()["trc"][0])
    assert out.startswith("BUG: leaked RuntimeWarning"), out
