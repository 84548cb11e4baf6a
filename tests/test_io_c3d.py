"""C3D reader/writer (ezc3d): units, occlusion mask, round trips, malformed files.

Synthetic files are written with ezc3d itself so most tests run without ../shared/data;
the real-file checks take the ``shared_data`` fixture.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

ezc3d = pytest.importorskip("ezc3d")

from mocapkit import io  # noqa: E402
from mocapkit.errors import MocapFormatError  # noqa: E402
from mocapkit.io import c3d  # noqa: E402
from mocapkit.motion import Motion  # noqa: E402
from mocapkit.skeleton import Skeleton  # noqa: E402


def _make_c3d(path: Path, xyz: np.ndarray, units: str = "mm", rate: float = 100.0,
              labels=None, residuals=None) -> Path:
    """Write (T, N, 3) points in file units with ezc3d (residual -1 = missing)."""
    T, N, _ = xyz.shape
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels or [f"m{i}" for i in range(N)])
    c["parameters"]["POINT"]["UNITS"]["value"] = [units]
    pts = np.ones((4, N, T))
    pts[:3] = np.transpose(xyz, (2, 1, 0))
    c["data"]["points"] = pts
    res = np.zeros((1, N, T)) if residuals is None else residuals.T[None]
    c["data"]["meta_points"]["residuals"] = res
    c["data"]["meta_points"]["camera_masks"] = np.zeros((7, N, T), dtype=bool)
    c.write(str(path))
    return path


@pytest.fixture
def synthetic(tmp_path, rng):
    xyz = rng.uniform(-800, 800, size=(40, 5, 3))
    res = np.zeros((40, 5))
    res[5:9, 2] = -1                      # a 4-frame gap on marker 2
    xyz[5:9, 2] = np.nan
    xyz[20, 4] = 0.0                      # an exporter-style (0, 0, 0) gap
    return _make_c3d(tmp_path / "syn.c3d", xyz, "mm", 100.0, ["LASI", "RASI", "LKNE", "RKNE", "LANK"], res), xyz


def test_units_labels_rate_and_mask(synthetic):
    path, xyz = synthetic
    m = io.read(path)
    assert m.skeleton.names == ("LASI", "RASI", "LKNE", "RKNE", "LANK")
    assert list(m.skeleton.parents) == [-1] * 5 and not m.skeleton.offsets.any()
    assert m.fps == 100.0 and m.source["units"]["file"] == "mm"
    expect_obs = np.ones((40, 5), bool)
    expect_obs[5:9, 2] = False
    expect_obs[20, 4] = False
    assert np.array_equal(m.observed, expect_obs)
    np.testing.assert_allclose(m.positions[expect_obs], xyz[expect_obs] / 10.0, rtol=1e-6)   # mm -> cm
    assert np.isnan(m.positions[~expect_obs]).all()
    # zero_missing=False keeps an exact (0, 0, 0) sample
    assert io.read(path, zero_missing=False).observed[20, 4]


@pytest.mark.parametrize("unit,factor", [("m", 100.0), ("cm", 1.0), ("mm", 0.1)])
def test_unit_conversion(tmp_path, rng, unit, factor):
    xyz = rng.uniform(-2, 2, size=(6, 2, 3))
    m = io.read(_make_c3d(tmp_path / f"u_{unit}.c3d", xyz, unit))
    np.testing.assert_allclose(m.positions, xyz * factor, rtol=1e-6)
    assert m.source["units"]["cm_per_unit"] == factor


def test_round_trip_keeps_everything(synthetic, tmp_path):
    path, _ = synthetic
    m = io.read(path)
    out = io.write(m, tmp_path / "back.c3d")
    b = io.read(out)
    assert b.skeleton.names == m.skeleton.names
    assert b.fps == m.fps and b.source["units"]["file"] == "mm"
    assert np.array_equal(b.observed, m.observed)
    np.testing.assert_allclose(b.positions[b.observed], m.positions[m.observed], atol=1e-4)


def test_write_changed_mask_and_other_units(synthetic, tmp_path):
    path, _ = synthetic
    m = io.read(path)
    obs = m.observed.copy()
    obs[30:33, 0] = False                                    # new gap
    P = np.where(np.isfinite(m.positions), m.positions, 0.0) + 1.0
    obs[5:9, 2] = True                                       # the old gap is now filled
    edited = m.with_positions(P, obs)
    b = io.read(io.write(edited, tmp_path / "edit.c3d", units="m"))
    assert b.source["units"]["file"] == "m"
    assert np.array_equal(b.observed, obs)
    np.testing.assert_allclose(b.positions[obs], P[obs], atol=1e-4)


def test_write_non_c3d_motion_uses_joint_names(tmp_path):
    sk = Skeleton(("a", "b"), [-1, 0], np.array([[0, 0, 0], [0, 10.0, 0]]))
    m = Motion(np.arange(24, dtype=float).reshape(4, 2, 3), sk, 30.0)
    b = io.read(io.write(m, tmp_path / "plain.c3d"))
    assert b.skeleton.names == ("a", "b") and b.fps == 30.0 and b.source["units"]["file"] == "mm"
    np.testing.assert_allclose(b.positions, m.positions, atol=1e-5)


def test_duplicate_and_blank_labels(tmp_path, rng):
    xyz = rng.uniform(1, 2, size=(3, 3, 3))
    m = io.read(_make_c3d(tmp_path / "lab.c3d", xyz, labels=["X", "X", " "]))
    assert m.skeleton.names == ("X", "X_2", "M003")
    assert m.source["c3d"]["labels"] == ["X", "X", " "] or m.source["c3d"]["labels"][0] == "X"


# ------------------------------------------------------------------------------------
# malformed files: MocapFormatError, never a crash or a partial Motion
# ------------------------------------------------------------------------------------
@pytest.mark.parametrize("keep", [0, 100, 511, 512, 700, 1500, 3000, -1000, -10])
def test_truncated(synthetic, tmp_path, keep):
    """Cut at fixed offsets, or ``-k``: k bytes before the end of the point data."""
    path, _ = synthetic
    raw = path.read_bytes()
    info = c3d._header(path)
    data_end = (info["data_start"] - 1) * 512 + info["frames"] * info["points"] * 16   # float32 x,y,z,res
    assert data_end <= len(raw)
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(raw[:keep] if keep >= 0 else raw[:data_end + keep])
    with pytest.raises(MocapFormatError) as ei:
        io.read(cut)
    assert "cut.c3d" in str(ei.value)


def test_not_a_c3d(tmp_path):
    p = tmp_path / "text.c3d"
    p.write_text("this is not a C3D file\n" * 50)
    with pytest.raises(MocapFormatError, match="not a C3D file"):
        io.read(p)


def test_corrupted_parameter_section(synthetic, tmp_path):
    """A parameter record with an impossible data type (ezc3d would crash or hang on some)."""
    path, _ = synthetic
    raw = bytearray(path.read_bytes())
    start = (raw[0] - 1) * 512
    i = raw.index(b"RATE", start)            # POINT:RATE record: name, offset (2), type (1)
    raw[i + 4 + 2] = 7
    bad = tmp_path / "bad.c3d"
    bad.write_bytes(bytes(raw))
    with pytest.raises(MocapFormatError, match="corrupted C3D parameters"):
        io.read(bad)


def test_bad_header_fields(synthetic, tmp_path):
    path, _ = synthetic
    raw = bytearray(path.read_bytes())
    bad = tmp_path / "bad.c3d"
    r = raw.copy()
    r[0] = 200                                # parameter section past the end
    bad.write_bytes(bytes(r))
    with pytest.raises(MocapFormatError, match="truncated C3D"):
        io.read(bad)
    r = raw.copy()
    r[(raw[0] - 1) * 512 + 3] = 99            # unknown processor type
    bad.write_bytes(bytes(r))
    with pytest.raises(MocapFormatError, match="processor type 99"):
        io.read(bad)


# ------------------------------------------------------------------------------------
# real files
# ------------------------------------------------------------------------------------
def _manifest_missing(shared_data) -> dict[str, float]:
    out = {}
    for line in (shared_data / "MANIFEST.tsv").read_text().splitlines()[1:]:
        f = line.split("\t")
        if len(f) > 9 and f[6] == "C3D":
            m = re.search(r"([\d.]+)% marker samples missing", f[9])
            if m:
                out[f[0]] = float(m.group(1))
    return out


def test_real_files_missing_fraction_and_units(shared_data):
    """Each real C3D: frames/points and the % missing stated in MANIFEST.tsv; units to cm."""
    expected = _manifest_missing(shared_data)
    assert len(expected) == 7
    for rel, pct in expected.items():
        m = io.read(shared_data / rel)
        assert 100 * m.missing_fraction == pytest.approx(pct, abs=0.006), rel
        raw = ezc3d.c3d(str(shared_data / rel))
        pts = np.transpose(raw["data"]["points"][:3], (2, 1, 0))
        f = {"mm": 0.1, "m": 100.0}[raw["parameters"]["POINT"]["UNITS"]["value"][0].strip()]
        np.testing.assert_allclose(m.positions[m.observed], pts[m.observed] * f)


def test_real_round_trip_with_gaps(shared_data, tmp_path):
    for rel in ("markers/c3d_org/Eb015pr.c3d", "markers/kineticstoolkit/kinematics_tennis_serve_nan.c3d",
                "markers/pyomeca/markers_analogs.c3d"):
        m = io.read(shared_data / rel)
        b = io.read(io.write(m, tmp_path / Path(rel).name))
        assert b.skeleton.names == m.skeleton.names and b.fps == m.fps
        assert b.source["units"]["file"] == m.source["units"]["file"]
        assert np.array_equal(b.observed, m.observed) and (~m.observed).any()
        np.testing.assert_allclose(b.positions[b.observed], m.positions[m.observed], atol=1e-4)
    assert io.read(shared_data / "markers/pyomeca/markers_analogs.c3d").source["c3d"]["analog_channels"] == 38
