"""Every motion file listed in ../shared/data/MANIFEST.tsv reads through ``mocapkit.io.read``.

Parametrised over the manifest rows by format (AMC, ASF, BVH, C3D, TRC; 40 evenly spaced
MSR-Action3D Kinect files). Each read is checked against the manifest (frame count, frame
rate, joint/point count where stated) and for sane units; the CMU subjects and HDM05 actors
must stand 150-200 cm. A format whose reader module does not exist yet is skipped.
Files are read once per session (cached summaries) to keep the module fast.
"""
from __future__ import annotations

import functools
import importlib
import re
import warnings
from collections import defaultdict

import numpy as np
import pytest

from mocapkit import io
from mocapkit.datasets import shared_data_dir
from mocapkit.errors import MocapFormatError

DATA = shared_data_dir()
MODULE = {"AMC": "amc", "ASF": "amc", "BVH": "bvh", "C3D": "c3d", "TRC": "trc", "TXT": "kinect"}
MSR_SAMPLE = 40
# CMU walking trials present as ASF/AMC (README "Labels")
CMU_WALKS = ("05_01", "07_03", "07_05", "16_15", "35_01", "131_01", "131_02", "131_09", "131_11",
             "131_12", "131_14")


def _manifest() -> list[dict]:
    if DATA is None or not (DATA / "MANIFEST.tsv").is_file():
        return []
    lines = (DATA / "MANIFEST.tsv").read_text(encoding="utf-8").splitlines()
    head = lines[0].split("\t")
    return [dict(zip(head, ln.split("\t"))) for ln in lines[1:] if ln.strip()]


ROWS = _manifest()


def _rows(fmt: str) -> list[dict]:
    rows = [r for r in ROWS if r["format"] == fmt]
    if fmt == "TXT":
        rows = [r for r in rows if r["path"].startswith("msr_action3d/skeleton3d/")]
        if len(rows) > MSR_SAMPLE:
            idx = np.linspace(0, len(rows) - 1, MSR_SAMPLE).round().astype(int)
            rows = [rows[i] for i in idx]
    return rows


def _params(fmt: str):
    rows = _rows(fmt)
    if not rows:
        return [pytest.param(None, marks=pytest.mark.skip(reason="shared data set not found"))]
    return [pytest.param(r, id=r["path"]) for r in rows]


@functools.lru_cache(maxsize=None)
def _summary(rel: str) -> dict:
    m = io.read(DATA / rel)
    P = m.positions
    with warnings.catch_warnings():          # frames with every marker missing (basket sprint)
        warnings.simplefilter("ignore", RuntimeWarning)
        height = m.height()
    return {"frames": m.n_frames, "joints": m.n_joints, "fps": m.fps, "height": height,
            "finite_where_observed": bool(np.isfinite(P[m.observed]).all()),
            "nan_where_missing": bool(np.isnan(P[~m.observed]).all()),
            "missing": m.missing_fraction, "names": m.skeleton.names}


def _check(row: dict) -> dict:
    pytest.importorskip(f"mocapkit.io.{MODULE[row['format']]}")
    s = _summary(row["path"])
    notes = row.get("notes", "")
    assert s["frames"] >= 1 and s["finite_where_observed"] and s["nan_where_missing"]
    m = re.match(r"(\d+) frames", notes)
    if m:
        # the cgspeed/Daz BVH notes count the T-pose frame too, as the file does
        assert s["frames"] == int(m.group(1)), notes
    m = re.search(r"(\d+) (?:joints|points)", notes)
    if m and row["format"] in ("BVH", "C3D"):
        assert s["joints"] == int(m.group(1)), notes
    rate = re.match(r"^\s*([\d.]+)\s*$", row.get("frame_rate", "") or "")
    if rate and row["format"] != "AMC":
        assert s["fps"] == pytest.approx(float(rate.group(1)), rel=1e-3)
    # units sanity: a body (or a marker set) is tens of cm to a few metres across, never
    # the x10 / x100 of a unit mistake
    assert 50 < s["height"] < 400, s["height"]
    return s


@pytest.mark.parametrize("row", _params("AMC"))
def test_amc(row):
    s = _check(row)
    assert s["joints"] == 31 and s["missing"] == 0.0 and s["fps"] == 120.0


@pytest.mark.parametrize("row", _params("ASF"))
def test_asf(row):
    s = _check(row)
    assert s["frames"] == 1 and s["joints"] == 31


@pytest.mark.parametrize("row", _params("BVH"))
def test_bvh(row):
    _check(row)


@pytest.mark.parametrize("row", _params("C3D"))
def test_c3d(row):
    if "no 3D points" in row.get("notes", ""):
        # analog-only vendor files (C3DRotationExample.c3d, Kistler.c3d): a Motion needs
        # points, so the reader refuses them with one clear error
        pytest.importorskip("mocapkit.io.c3d")
        with pytest.raises(MocapFormatError, match="no 3D points"):
            io.read(DATA / row["path"])
        return
    s = _check(row)
    m = re.search(r"([\d.]+)% marker samples missing", row.get("notes", ""))
    if m:
        assert 100 * s["missing"] == pytest.approx(float(m.group(1)), abs=0.006)


@pytest.mark.parametrize("row", _params("TRC"))
def test_trc(row):
    _check(row)


@pytest.mark.parametrize("row", _params("TXT"))
def test_kinect(row):
    s = _check(row)
    assert s["joints"] in (20, 25)


# ------------------------------------------------------------------------------------
# heights: CMU subjects and HDM05 actors stand 150-200 cm
# ------------------------------------------------------------------------------------
def _amc_heights(key) -> dict[str, list[tuple[str, float]]]:
    out = defaultdict(list)
    for r in _rows("AMC"):
        out[key(r["path"])].append((r["path"], _summary(r["path"])["height"]))
    return out


def test_cmu_heights(shared_data):
    """Median ``Motion.height()`` over each subject's clips, and every walking clip, in 150-200 cm.

    (Single non-walking clips may go below: crouched martial-arts stances (135_08: 129 cm).)
    """
    groups = _amc_heights(lambda p: p.split("/")[2] if p.startswith("cmu/") else None)
    groups.pop(None, None)
    assert len(groups) == 10
    for subject, hs in groups.items():
        med = float(np.median([h for _, h in hs]))
        assert 150 <= med <= 200, (subject, med)
        for p, h in hs:
            if p.rsplit("/", 1)[-1][:-4] in CMU_WALKS:
                assert 150 <= h <= 200, (p, h)


def test_hdm05_heights(shared_data):
    """Median ``Motion.height()`` over each HDM05 actor's clips, and every jogging clip, in 150-200 cm."""
    groups = _amc_heights(lambda p: re.search(r"HDM_(\w\w)_", p).group(1) if p.startswith("hdm05/") else None)
    groups.pop(None, None)
    assert sorted(groups) == ["bd", "bk", "dg", "mm", "tr"]
    for actor, hs in groups.items():
        med = float(np.median([h for _, h in hs]))
        assert 150 <= med <= 200, (actor, med)
        for p, h in hs:
            if "jogLeftCircle" in p:
                assert 150 <= h <= 200, (p, h)


def test_every_manifest_format_is_covered():
    if not ROWS:
        pytest.skip("shared data set not found")
    formats = {r["format"] for r in ROWS}
    assert formats - {"CSV"} <= set(MODULE), formats
    for fmt in MODULE:
        if importlib.util.find_spec(f"mocapkit.io.{MODULE[fmt]}") is None:
            pytest.skip(f"reader mocapkit.io.{MODULE[fmt]} not written yet")
