"""Batch cleaning of a folder: mirror tree, broken file reported, resume, Dask LocalCluster;
path safety, one batch per output folder (lock), Ctrl-C with workers (issue 18)."""
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mocapkit import io
from mocapkit.batch import LOCK, MANIFEST, BatchLock, run_batch, sha256
from mocapkit.cli import main
from mocapkit.datasets import bundled
from mocapkit.errors import MocapValueError

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def library(tmp_path):
    src = tmp_path / "lib"
    (src / "walks" / "deep").mkdir(parents=True)
    amc = bundled("16_15.amc")
    shutil.copy(amc, src / "walks" / "16_15.amc")
    shutil.copy(amc.parent / "16.asf", src / "walks" / "16.asf")
    bvh = bundled("16_15.bvh")
    shutil.copy(bvh, src / "walks" / "deep" / "16_15.bvh")
    (src / "walks" / "deep" / "broken.bvh").write_text("HIERARCHY\nROOT Hips\n{\n")
    return src


def test_batch_mirrors_reports_and_resumes(library, tmp_path):
    out = tmp_path / "out"
    s = run_batch(library, out, method="gaussian", workers=1, progress=False)
    assert (s.ok, s.failed, s.skipped) == (2, 1, 0)
    failed = [r for r in s.results if r.status == "failed"][0]
    assert failed.input.endswith("broken.bvh") and "broken.bvh" in failed.reason
    cleaned = io.read(out / "walks" / "16_15.amc")           # ASF copied beside it
    assert cleaned.n_frames == io.read(library / "walks" / "16_15.amc").n_frames
    assert (out / "walks" / "deep" / "16_15.bvh").exists()
    assert "broken.bvh" in (out / "batch.log").read_text()
    # rerun: verified outputs are skipped, the broken file is retried
    s2 = run_batch(library, out, method="gaussian", workers=1, progress=False)
    assert (s2.ok, s2.failed, s2.skipped) == (0, 1, 2)
    # a tampered output is redone
    (out / "walks" / "deep" / "16_15.bvh").write_text("garbage")
    s3 = run_batch(library, out, method="gaussian", workers=1, progress=False)
    assert (s3.ok, s3.skipped) == (1, 1)
    # other settings: everything is redone
    s4 = run_batch(library, out, method="spline", workers=1, progress=False)
    assert s4.ok == 2
    assert json.loads((out / MANIFEST).read_text())["files"]


def test_batch_refuses_same_folder(library):
    from mocapkit.errors import MocapValueError
    with pytest.raises(MocapValueError):
        run_batch(library, library, method="gaussian", progress=False)


def test_batch_on_dask_local_cluster(library, tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  host="127.0.0.1", dashboard_address=None) as cluster:
        s = run_batch(library, tmp_path / "out", method="gaussian", scheduler=cluster.scheduler_address,
                      progress=False)
    assert (s.ok, s.failed) == (2, 1)


# ---------------------------------------------------------------------------------------
# issue 18: path safety, one batch per folder, Ctrl-C
# ---------------------------------------------------------------------------------------


def _tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_batch_output_inside_or_around_the_input_refused(library, capsys):
    before = _tree(library)
    for argv in (["batch", str(library), str(library / "walks")],          # raw raw/sub
                 ["batch", str(library), str(library / "new")],
                 ["batch", str(library / "walks"), str(library)]):
        assert main(argv + ["-q"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "input folder" in err, err
    assert _tree(library) == before


def test_batch_param_type_checked_once_before_any_work(library, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["batch", str(library), str(out), "--param", "min_noise_cm=abc", "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "min_noise_cm" in err and "number" in err and "internal error" not in err
    assert not out.exists()
    assert main(["batch", str(library), str(out), "--model", str(library / "walks" / "16_15.amc"), "-q"]) == 2
    assert "model" in capsys.readouterr().err


def test_batch_never_replaces_a_file_it_did_not_write(library, tmp_path):
    out = tmp_path / "out"
    (out / "walks").mkdir(parents=True)
    mine = out / "walks" / "16_15.amc"
    mine.write_text("my hand-cleaned take")
    s = run_batch(library, out, method="median", progress=False)
    bad = {r.input: r for r in s.results if r.status == "failed"}
    assert "not written by mocapkit batch" in bad[str(Path("walks") / "16_15.amc")].reason
    assert mine.read_text() == "my hand-cleaned take"
    assert (out / "walks" / "deep" / "16_15.bvh").exists()


def test_batch_worker_death_fails_only_its_file(library, tmp_path, monkeypatch):
    import mocapkit.batch as batch

    real = batch.process_one

    def crashy(i, o, *a):
        if i.endswith("16_15.bvh"):
            os._exit(7)                               # a reader crashing the process (segfault-like)
        return real(i, o, *a)

    monkeypatch.setattr(batch, "process_one", crashy)   # forked workers inherit the patch
    s = run_batch(library, tmp_path / "out", method="median", workers=2, progress=False)
    res = {r.input: r for r in s.results}
    assert "worker process died (exit code 7)" in res[str(Path("walks") / "deep" / "16_15.bvh")].reason
    assert res[str(Path("walks") / "16_15.amc")].status == "ok"
    assert (s.ok, s.failed) == (1, 2)


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_batch_lock_live_refuses_stale_is_removed(library, tmp_path, capsys):
    import socket

    from mocapkit.batch import _start_time

    out = tmp_path / "out"
    out.mkdir()
    lock = out / LOCK
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        lock.write_text(json.dumps({"pid": sleeper.pid, "host": socket.gethostname(),
                                    "start": _start_time(sleeper.pid), "time": "now"}))
        assert main(["batch", str(library), str(out), "--method", "median", "-q"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "in use by another mocapkit batch" in err and str(sleeper.pid) in err
        assert not (out / "walks").exists()                      # no work done
    finally:
        sleeper.kill()
        sleeper.wait()
    # the owner is gone (and a lock with garbage in it): stale, removed, the batch runs
    for stale in (json.dumps({"pid": _dead_pid(), "host": socket.gethostname(), "start": None}), "garbage"):
        lock.write_text(stale)
        s = run_batch(library, out, method="median", progress=False)
        assert s.ok + s.skipped == 2
        assert not lock.exists()
    # a lock held in this process refuses a second batch on the folder
    with BatchLock(out):
        with pytest.raises(MocapValueError, match="in use"):
            run_batch(library, out, method="median", progress=False)
    assert not lock.exists()


@pytest.fixture
def slow_library(tmp_path):
    """16 AMC clips of 240 frames (IK on write: a few tenths of a second each), so a
    batch runs for a while."""
    src = tmp_path / "slow"
    src.mkdir()
    amc = bundled("16_15.amc")
    shutil.copy(amc.parent / "16.asf", src / "16.asf")
    lines = amc.read_text().splitlines(keepends=True)
    frame_starts = [i for i, ln in enumerate(lines) if ln.strip().isdigit()]
    short = "".join(lines[:frame_starts[240]])             # header + the first 240 frames
    for k in range(16):
        (src / f"c{k:02d}.amc").write_text(short)
    return src


def _manifest_ok(out: Path) -> dict:
    try:
        files = json.loads((out / MANIFEST).read_text())["files"]
    except (OSError, ValueError, KeyError):
        return {}
    return {k: v for k, v in files.items() if v["status"] == "ok"}


def _group_gone(pgid: int, wait_s: float = 10.0) -> bool:
    t = time.monotonic()
    while time.monotonic() - t < wait_s:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    return False


@pytest.mark.parametrize("whole_group", [True, False], ids=["ctrl-c-group", "sigint-parent"])
def test_batch_ctrl_c_stops_workers_manifest_matches_disk(slow_library, tmp_path, capsys, whole_group):
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "mocapkit", "batch", str(slow_library), str(out),
                             "--workers", "2", "--method", "median", "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                            env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        t0 = time.monotonic()
        while not _manifest_ok(out):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() - t0 < 120, "no file finished"
            time.sleep(0.05)
        # a second batch on the same folder is refused while the first runs
        assert main(["batch", str(slow_library), str(out), "--method", "median", "-q"]) == 2
        err2 = capsys.readouterr().err.strip()
        assert err2.count("\n") == 0 and "in use by another mocapkit batch" in err2
        if whole_group:
            os.killpg(proc.pid, signal.SIGINT)                 # what a terminal's Ctrl-C does
        else:
            os.kill(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=20)                  # hang guard only, no timing assertion
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    err = err.decode()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "interrupted" in err, err
    assert _group_gone(proc.pid), "a worker process outlived the batch"
    ok = _manifest_ok(out)
    on_disk = {str(p.relative_to(out)) for p in out.rglob("*.amc")}
    assert set(ok) == on_disk                                   # every output listed, none missing
    assert 0 < len(ok) < 16                                     # it really stopped early
    for rel, entry in ok.items():
        assert sha256(out / rel) == entry["output_sha256"]
        assert io.read(out / rel).n_frames == 240
    leftovers = sorted(p.name for p in out.rglob(".*") if p.name != MANIFEST)
    assert leftovers == [], leftovers                          # no temp files, no lock


def test_batch_notes_what_the_policy_gave_back(library, tmp_path, capsys):
    """A worker has no terminal: what the CLI prints as warnings (one iteration of rpca
    moves the walk by tens of cm; the gap policy writes the measured samples back) goes
    into the file's note, the manifest and the batch log."""
    out = tmp_path / "out"
    s = run_batch(library, out, method="rpca", params={"max_iter": 1}, workers=1, progress=False)
    ok = [r for r in s.results if r.status == "ok"]
    assert len(ok) == 2
    for r in ok:
        assert "not converged" in r.note and "written as measured" in r.note
    files = json.loads((out / MANIFEST).read_text())["files"]
    assert all("written as measured" in files[r.input]["note"] for r in ok)
    assert "written as measured" in (out / "batch.log").read_text()
    out2 = tmp_path / "out2"
    assert main(["batch", str(library), str(out2), "--method", "rpca", "--param", "max_iter=1", "-q"]) == 1
    assert "2 file(s) with warnings" in capsys.readouterr().out
    # the gap policy's switches as for denoise: --keep-moves writes rpca's values; other
    # settings, so the outputs are redone, and the note has no sample given back
    assert main(["batch", str(library), str(out2), "--method", "rpca", "--param", "max_iter=1",
                 "--keep-moves", "-q"]) == 1
    files = json.loads((out2 / MANIFEST).read_text())["files"]
    ok2 = [e for e in files.values() if e["status"] == "ok"]
    assert len(ok2) == 2 and not any("written as measured" in e["note"] for e in ok2)
    assert all("not converged" in e["note"] for e in ok2)
