"""Batch cleaning of a folder: mirror tree, broken file reported, resume, Dask LocalCluster."""
import json
import shutil

import pytest

from mocapkit import io
from mocapkit.batch import MANIFEST, run_batch
from mocapkit.datasets import bundled


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
