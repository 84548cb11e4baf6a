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


def test_joint_hierarchy_round_trip_and_fixed_bones(tmp_path):
    """AMC -> C3D -> C3D keeps the hierarchy, the offsets and the bones the AMC fixed; a
    built motion's bones are written as not fixed; a group that does not fit the points
    is ignored with one warning naming the parameter."""
    from mocapkit.datasets import bundled
    from mocapkit.denoise import is_marker_capture
    from mocapkit.errors import MocapWarning
    from mocapkit.rigid import fixed_bones

    amc = io.read(bundled("16_15.amc")).slice(0, 20)
    b = io.read(io.write(io.read(io.write(amc, tmp_path / "j.c3d")), tmp_path / "j2.c3d"))
    assert b.skeleton.names == amc.skeleton.names
    np.testing.assert_array_equal(b.skeleton.parents, amc.skeleton.parents)
    np.testing.assert_allclose(b.skeleton.offsets, amc.skeleton.offsets, atol=1e-4)
    (pa, la), (pb, lb) = fixed_bones(amc), fixed_bones(b)
    assert len(pa) == 30 and np.array_equal(pa, pb) and np.allclose(la, lb, atol=1e-4)
    assert not is_marker_capture(b)
    sk = Skeleton(("a", "b"), [-1, 0], np.array([[0, 0, 0], [0, 10.0, 0]]))
    built = io.read(io.write(Motion(np.ones((4, 2, 3)), sk, 30.0), tmp_path / "built.c3d"))
    assert list(built.skeleton.parents) == [-1, 0] and len(fixed_bones(built)[0]) == 0
    c = ezc3d.c3d(str(tmp_path / "built.c3d"))
    c.add_parameter("MOCAPKIT", "PARENTS", [-1, 5])          # a parent that is no point
    c.write(str(tmp_path / "bad.c3d"))
    with pytest.warns(MocapWarning, match="MOCAPKIT:PARENTS"):
        bad = io.read(tmp_path / "bad.c3d")
    assert list(bad.skeleton.parents) == [-1, -1] and is_marker_capture(bad)


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


# ------------------------------------------------------------------------------------
# issue 18: header vs data, POINT:SCALE, no leaked warnings, vendor files
# ------------------------------------------------------------------------------------
import struct  # noqa: E402
import warnings  # noqa: E402

from mocapkit.errors import HeaderMismatchWarning, MocapWarning  # noqa: E402


def _param_data_offset(raw: bytes, group: str, name: str) -> int:
    """Byte offset of the data of parameter GROUP:NAME in a little-endian C3D file."""
    start = (raw[0] - 1) * 512
    sec = raw[start:start + 512 * raw[start + 2]]
    i, groups, found = 4, {}, {}
    while i + 2 <= len(sec):
        nlen, gid = struct.unpack("bb", sec[i:i + 2])
        if nlen == 0:
            break
        nm = sec[i + 2:i + 2 + abs(nlen)].decode()
        j = i + 2 + abs(nlen)
        off = struct.unpack("<h", sec[j:j + 2])[0]
        if gid < 0:
            groups[-gid] = nm
        else:
            found[(gid, nm)] = start + j + 4 + sec[j + 3]       # offset, type, ndims, dims
        if off == 0:
            break
        i = j + off
    gid = next(g for g, n in groups.items() if n == group)
    return found[(gid, name)]


def int_c3d(path: Path, xyz_int: np.ndarray, scale: float, rate: float = 100.0,
            residual_byte=None, units: str = "mm") -> Path:
    """A minimal *integer-storage* C3D (Intel), written byte by byte (ezc3d only writes
    float storage): header, one parameter block (POINT: USED, SCALE, RATE, FRAMES,
    DATA_START, LABELS, UNITS), int16 x/y/z and the camera-mask / residual bytes."""
    T, N, _ = xyz_int.shape
    res = np.ones((T, N), np.int8) if residual_byte is None else np.asarray(residual_byte, np.int8)

    def rec(nm, gid, body):
        b = nm.encode()
        return struct.pack("<bb", len(b), gid) + b, body

    def par(nm, typ, dims, data):
        return rec(nm, 1, struct.pack("<bB", typ, len(dims)) + bytes(dims) + data + b"\x00")

    labels = b"".join(f"M{i:<3d}"[:4].encode() for i in range(N))
    recs = [rec("POINT", -1, b"\x00"), par("USED", 2, [], struct.pack("<h", N)),
            par("SCALE", 4, [], struct.pack("<f", scale)), par("RATE", 4, [], struct.pack("<f", rate)),
            par("FRAMES", 2, [], struct.pack("<h", T)), par("DATA_START", 2, [], struct.pack("<h", 3)),
            par("LABELS", -1, [4, N], labels), par("UNITS", -1, [len(units)], units.encode())]
    sec = bytes([1, 0x50, 1, 84])
    for k, (head, body) in enumerate(recs):
        sec += head + struct.pack("<h", 0 if k == len(recs) - 1 else 2 + len(body)) + body
    head = bytearray(512)
    head[0], head[1] = 2, 0x50
    struct.pack_into("<HHHHHfHHf", head, 2, N, 0, 1, T, 10, scale, 3, 0, rate)
    data = b"".join(struct.pack("<hhhBb", *(int(v) for v in xyz_int[t, i]), 0, int(res[t, i]))
                    for t in range(T) for i in range(N))
    path.write_bytes(bytes(head) + sec.ljust(512, b"\x00") + data)
    return path


def _read_strict(path, **kw):
    """io.read with every non-mocapkit warning turned into an error."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.simplefilter("default", MocapWarning)
        return io.read(path, **kw)


def test_integer_storage_file_reads_like_ezc3d(tmp_path, rng):
    X = rng.integers(-3000, 3000, (6, 3, 3))
    r = np.ones((6, 3))
    r[2, 1] = -1                                              # missing
    m = _read_strict(int_c3d(tmp_path / "int.c3d", X, 0.1, residual_byte=r))
    ref = ezc3d.c3d(str(tmp_path / "int.c3d"))["data"]["points"][:3]
    np.testing.assert_allclose(m.positions[m.observed], np.transpose(ref, (2, 1, 0))[m.observed] * 0.1)
    np.testing.assert_allclose(m.positions[0], X[0] * 0.1 * 0.1, rtol=1e-6)    # scale, then mm -> cm
    assert m.observed.sum() == 17 and not m.observed[2, 1]


@pytest.mark.parametrize("scale", [0.0, float("nan"), float("inf")])
def test_integer_file_with_bad_point_scale_is_refused(tmp_path, rng, scale):
    """POINT:SCALE 0 / NaN in an integer file: one clear error, not '100 % missing'."""
    X = rng.integers(-3000, 3000, (5, 2, 3))
    p = int_c3d(tmp_path / "bad_scale.c3d", X, scale)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(MocapFormatError, match="POINT:SCALE") as ei:
            io.read(p)
    assert "bad_scale.c3d" in str(ei.value)


@pytest.mark.parametrize("scale", [float("nan"), -float("nan"), 0.0, -0.0, float("-inf")])
def test_float_file_with_bad_point_scale_is_refused(synthetic, tmp_path, scale):
    path, _ = synthetic
    raw = bytearray(path.read_bytes())
    k = _param_data_offset(bytes(raw), "POINT", "SCALE")
    raw[k:k + 4] = struct.pack("<f", scale)
    bad = tmp_path / "nan_scale.c3d"
    bad.write_bytes(bytes(raw))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(MocapFormatError, match="POINT:SCALE"):
            io.read(bad)


@pytest.mark.parametrize("keep", [0, 100, 511, 512, 700, 1500])
def test_truncated(synthetic, tmp_path, keep):
    """Cut inside the header or the parameter section: MocapFormatError naming the file."""
    path, _ = synthetic
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(path.read_bytes()[:keep])
    with pytest.raises(MocapFormatError) as ei:
        io.read(cut)
    assert "cut.c3d" in str(ei.value)


@pytest.mark.parametrize("keep", [3000, -1000, -10])
def test_truncated_data_reads_the_complete_frames_and_warns(synthetic, tmp_path, keep):
    """Cut inside the point data (``-k``: k bytes before its end): the complete frames are
    read, with one HeaderMismatchWarning naming both frame counts (issue 18)."""
    path, xyz = synthetic
    raw = path.read_bytes()
    info = c3d._header(path)
    dstart = (info["data_start"] - 1) * 512
    data_end = dstart + info["frames"] * info["points"] * 16   # float32 x, y, z, residual word
    assert data_end <= len(raw)
    end = keep if keep >= 0 else data_end + keep
    n_complete = (end - dstart) // (info["points"] * 16)
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(raw[:end])
    with pytest.warns(HeaderMismatchWarning) as rec:
        m = _read_strict(cut)
    msgs = [str(w.message) for w in rec if issubclass(w.category, HeaderMismatchWarning)]
    assert len(msgs) == 1 and "40 frames" in msgs[0] and f"hold {n_complete}" in msgs[0]
    assert m.n_frames == n_complete and "cut.c3d" in msgs[0]
    full = io.read(path)
    np.testing.assert_array_equal(m.observed, full.observed[:n_complete])
    np.testing.assert_allclose(m.positions[m.observed], full.positions[:n_complete][m.observed])


def test_header_announcing_fewer_frames_than_the_data(synthetic, tmp_path):
    path, _ = synthetic
    raw = bytearray(path.read_bytes())
    raw[8:10] = struct.pack("<H", 25)              # header last frame 25 of 40
    p = tmp_path / "short_header.c3d"
    p.write_bytes(bytes(raw))
    with pytest.warns(HeaderMismatchWarning, match=r"announces 25 frames .* hold 40"):
        m = io.read(p)
    assert m.n_frames == 40 and any("25" in w for w in m.source["warnings"])


def test_parameter_names_with_spaces_are_accepted(synthetic, tmp_path):
    """Qualisys writes parameters such as 'Uncropped Measurement Length' (issue 18)."""
    path, _ = synthetic
    raw = bytearray(path.read_bytes())
    k = _param_data_offset(bytes(raw), "POINT", "RATE")
    start = (raw[0] - 1) * 512
    i = raw.index(b"RATE", start)
    assert i + 4 + 4 == k
    raw[i:i + 4] = b"R TE"                             # same length, a space inside
    p = tmp_path / "spaced.c3d"
    p.write_bytes(bytes(raw))
    assert "R TE" in ezc3d.c3d(str(p))["parameters"]["POINT"]
    m = _read_strict(p)
    assert m.n_frames == 40


def test_control_bytes_in_a_parameter_name_are_still_refused(synthetic, tmp_path):
    path, _ = synthetic
    raw = bytearray(path.read_bytes())
    i = raw.index(b"RATE", (raw[0] - 1) * 512)
    raw[i + 1] = 0x01
    p = tmp_path / "ctrl.c3d"
    p.write_bytes(bytes(raw))
    with pytest.raises(MocapFormatError, match="bad name/group id"):
        io.read(p)


def test_no_numpy_warning_from_the_c3d_reader(tmp_path, rng):
    """Huge float coordinates, NaN coordinates with a valid residual, negative zero:
    read with warnings as errors."""
    xyz = rng.uniform(-1, 1, (5, 3, 3))
    xyz[0, 0] = 3e38                                  # near float32 max, in metres -> cm
    xyz[1, 1] = np.nan
    xyz[2, 2] = -0.0
    m = _read_strict(_make_c3d(tmp_path / "w.c3d", xyz, "m"))
    assert not m.observed[1, 1] and m.observed[0, 0]
    assert np.isfinite(m.positions[m.observed]).all()


# ------------------------------------------------------------------------------------
# filled flags: residual 0 = filled, -1 = missing, > 0 measured (issue 15 item 4)
# ------------------------------------------------------------------------------------
def test_reader_flags_residual_zero_only_when_the_file_has_real_residuals(tmp_path, rng):
    X = rng.integers(-3000, 3000, (6, 3, 3))
    r = np.full((6, 3), 3)
    r[1, 0] = 0                                       # filled
    r[2, 2] = 0                                       # filled
    r[4, 1] = -1                                      # missing
    m = _read_strict(int_c3d(tmp_path / "res.c3d", X, 0.1, residual_byte=r))
    expect = np.zeros((6, 3), bool)
    expect[1, 0] = expect[2, 2] = True
    np.testing.assert_array_equal(m.filled, expect)
    assert m.source["c3d"]["residuals"].startswith("measured")
    np.testing.assert_allclose(m.source["per_frame"]["residuals"][0], 0.3, rtol=1e-6)   # 3 x |scale|
    # every valid residual 0 (mocapkit 0.1, many exporters): nothing is read as filled
    z = np.where(r < 0, -1, 0)
    m0 = _read_strict(int_c3d(tmp_path / "zero.c3d", X, 0.1, residual_byte=z))
    assert not m0.filled.any() and m0.observed.sum() == 17
    assert m0.source["c3d"]["residuals"].startswith("none")


def _motion_with_flags(rng, T=30, J=4):
    P = rng.uniform(-500, 500, (T, J, 3))
    obs = np.ones((T, J), bool)
    obs[3:7, 1] = False
    filled = np.zeros((T, J), bool)
    filled[10:14, 2] = True
    filled[0, 0] = filled[-1, 3] = True
    sk = Skeleton(tuple(f"M{j}" for j in range(J)), -np.ones(J, int), np.zeros((J, 3)))
    return Motion(P, sk, 100.0, obs, filled=filled)


def test_filled_flags_survive_a_c3d_round_trip(tmp_path, rng):
    m = _motion_with_flags(rng)
    out = io.write(m, tmp_path / "flags.c3d")
    raw = ezc3d.c3d(str(out))
    res = raw["data"]["meta_points"]["residuals"][0].T                 # (T, J)
    assert (res[~m.observed] == -1).all()
    assert (res[m.filled] == 0).all()
    measured = m.observed & ~m.filled
    assert (res[measured] > 0).all()                                     # never 0: 0 means filled
    np.testing.assert_allclose(res[measured], c3d.RESIDUAL_STEP_CM / 0.1, rtol=1e-5)   # one step, mm
    b = _read_strict(out)
    np.testing.assert_array_equal(b.filled, m.filled)
    np.testing.assert_array_equal(b.observed, m.observed)
    # and again (read -> write -> read): flags, mask and residuals are stable
    b2 = _read_strict(io.write(b, tmp_path / "flags2.c3d"))
    np.testing.assert_array_equal(b2.filled, m.filled)
    np.testing.assert_allclose(b2.source["per_frame"]["residuals"], b.source["per_frame"]["residuals"],
                               rtol=1e-5)


def test_measured_residuals_are_kept_and_converted(tmp_path, rng):
    X = rng.integers(-3000, 3000, (8, 3, 3))
    r = rng.integers(1, 120, (8, 3))
    r[5, 2] = 0
    src = _read_strict(int_c3d(tmp_path / "r.c3d", X, 0.05, residual_byte=r))   # residual r x 0.05 mm
    kept = src.source["per_frame"]["residuals"]
    b = _read_strict(io.write(src, tmp_path / "r_mm.c3d"))
    np.testing.assert_array_equal(b.filled, src.filled)
    assert b.filled[5, 2] and b.filled.sum() == 1
    meas = src.observed & ~src.filled
    np.testing.assert_allclose(b.source["per_frame"]["residuals"][meas], kept[meas], rtol=1e-6)   # same step
    bm = _read_strict(io.write(src, tmp_path / "r_m.c3d", units="m"))          # same residuals in m
    np.testing.assert_allclose(bm.source["per_frame"]["residuals"][meas] * 1000, kept[meas], rtol=1e-5)
    np.testing.assert_array_equal(bm.filled, src.filled)


def test_large_residuals_coarsen_the_step_instead_of_wrapping(tmp_path, rng):
    """The residual field is one byte: a 40 mm residual must not wrap to 0 (= filled)."""
    m = _motion_with_flags(rng)
    res = np.where(m.observed, 1.0, -1.0)
    res[20, 0] = 40.0                                                    # mm
    m = m.with_source(format="c3d", units={"file": "mm", "cm_per_unit": 0.1},
                      per_frame={"residuals": res})
    b = _read_strict(io.write(m, tmp_path / "big.c3d"))
    np.testing.assert_array_equal(b.filled, m.filled)
    got = b.source["per_frame"]["residuals"]
    assert got[20, 0] == pytest.approx(40.0, rel=0.01)
    meas = m.observed & ~m.filled
    np.testing.assert_allclose(got[meas], res[meas], atol=40.0 / 255)


# ------------------------------------------------------------------------------------
# real and vendor files against ezc3d itself
# ------------------------------------------------------------------------------------
def test_every_shared_c3d_matches_ezc3d(shared_data):
    """Every C3D under markers/: where ezc3d reads points, mocapkit reads the same positions
    (file units -> cm) and the same missing mask; analog-only files: 'no 3D points'."""
    files = sorted((shared_data / "markers").rglob("*.c3d"))
    assert len(files) >= 16
    checked = []
    for f in files:
        try:
            raw = ezc3d.c3d(str(f), extract_forceplat_data=False)
        except Exception:                           # noqa: BLE001 - ezc3d cannot: nothing to compare
            with pytest.raises(MocapFormatError):
                io.read(f)
            continue
        pts = np.asarray(raw["data"]["points"], float)
        if pts.shape[1] == 0:
            with pytest.raises(MocapFormatError, match="no 3D points"):
                io.read(f)
            checked.append((f.name, "no points"))
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            warnings.simplefilter("default", HeaderMismatchWarning)
            m = io.read(f, zero_missing=False)
            m0 = io.read(f)
        xyz = np.transpose(pts[:3], (2, 1, 0))
        unit = str(raw["parameters"]["POINT"]["UNITS"]["value"][0]).strip().lower() \
            if len(raw["parameters"]["POINT"].get("UNITS", {}).get("value", [])) else "mm"
        f_cm = {"mm": 0.1, "cm": 1.0, "m": 100.0}[unit]
        ez_obs = np.isfinite(xyz).all(axis=2)
        assert m.positions.shape == xyz.shape, f.name
        np.testing.assert_array_equal(m.observed, ez_obs, err_msg=f.name)
        np.testing.assert_array_equal(m0.observed, ez_obs & ~(xyz == 0).all(axis=2), err_msg=f.name)
        np.testing.assert_allclose(m.positions[ez_obs], xyz[ez_obs] * f_cm, rtol=1e-12, err_msg=f.name)
        assert m.fps == pytest.approx(float(raw["parameters"]["POINT"]["RATE"]["value"][0]))
        checked.append((f.name, "same"))
    names = dict(checked)
    assert names.get("Qualisys.c3d") == "same" and names.get("Optotrak.c3d") == "same"
    assert names.get("Kistler.c3d") == "no points" and names.get("C3DRotationExample.c3d") == "no points"


def test_vendor_files_qualisys_and_optotrak(shared_data):
    q = _read_strict(shared_data / "markers/ezc3d/Qualisys.c3d")
    assert (q.n_frames, q.n_joints, q.fps) == (340, 55, 200.0)
    with pytest.warns(HeaderMismatchWarning, match=r"1149 frames.*hold 29"):
        o = io.read(shared_data / "markers/ezc3d/Optotrak.c3d")
    assert (o.n_frames, o.n_joints, o.fps) == (29, 54, 30.0)
    assert o.source["c3d"]["header_frames"] == 1149


# ------------------------------------------------------------------------------------
# writing back: the source file's analog channels, events and parameters are kept
# ------------------------------------------------------------------------------------
def _with_analogs(path: Path, T: int = 30, ratio: int = 10, first: int = 40) -> Path:
    """A marker file as a lab exports one: 3 points, 2 analog channels (force plate) at
    ``ratio`` samples per frame, events, a subject, and a first frame other than 0."""
    rng = np.random.default_rng(5)
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [100.0]
    c["parameters"]["POINT"]["LABELS"]["value"] = ("A", "B", "C")
    c["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c["parameters"]["ANALOG"]["RATE"]["value"] = [100.0 * ratio]
    c["parameters"]["ANALOG"]["LABELS"]["value"] = ("Fz1", "Fz2")
    c["parameters"]["ANALOG"]["UNITS"]["value"] = ("N", "N")
    pts = np.ones((4, 3, T))
    pts[:3] = rng.uniform(-500, 500, (3, 3, T))
    c["data"]["points"] = pts
    c["data"]["meta_points"]["residuals"] = np.full((1, 3, T), 0.5)
    c["data"]["meta_points"]["camera_masks"] = np.zeros((7, 3, T), dtype=bool)
    c["data"]["analogs"] = rng.normal(0, 100, (1, 2, T * ratio))
    c["header"]["points"]["first_frame"] = first
    c.add_parameter("EVENT", "LABELS", ["Foot Strike", "Foot Off"])
    c.add_parameter("EVENT", "TIMES", np.array([[0.0, 0.0], [0.55, 0.61]]))
    c.add_parameter("SUBJECTS", "NAMES", ["P01"])
    c.write(str(path))
    return path


def test_write_keeps_the_sources_analogs_events_and_first_frame(tmp_path):
    src = _with_analogs(tmp_path / "lab.c3d")
    m = io.read(src)
    out = io.write(m.with_positions(m.positions + 1.0), tmp_path / "clean.c3d")
    a, b = ezc3d.c3d(str(src)), ezc3d.c3d(str(out))
    np.testing.assert_array_equal(b["data"]["analogs"], a["data"]["analogs"])
    assert list(b["parameters"]["ANALOG"]["LABELS"]["value"]) == ["Fz1", "Fz2"]
    assert list(b["parameters"]["EVENT"]["LABELS"]["value"]) == ["Foot Strike", "Foot Off"]
    np.testing.assert_allclose(b["parameters"]["EVENT"]["TIMES"]["value"][1], [0.55, 0.61])
    assert list(b["parameters"]["SUBJECTS"]["NAMES"]["value"]) == ["P01"]
    assert b["header"]["points"]["first_frame"] == 40
    back = io.read(out)                          # the points are the new ones
    np.testing.assert_allclose(back.positions, m.positions + 1.0, atol=1e-3)
    np.testing.assert_array_equal(back.source["per_frame"]["frame"], np.arange(40, 70))


def test_write_of_a_slice_cuts_the_analogs_and_moves_the_first_frame(tmp_path):
    src = _with_analogs(tmp_path / "lab.c3d")
    out = io.write(io.read(src).slice(7, 19), tmp_path / "part.c3d")
    a, b = ezc3d.c3d(str(src)), ezc3d.c3d(str(out))
    np.testing.assert_array_equal(b["data"]["analogs"], a["data"]["analogs"][..., 70:190])
    assert b["header"]["points"]["first_frame"] == 47 and b["data"]["points"].shape[2] == 12
    back = io.read(out)
    np.testing.assert_array_equal(back.source["per_frame"]["frame"], np.arange(47, 59))


def test_write_says_what_it_cannot_keep(tmp_path):
    """A resampled motion (or one whose joints changed) has no place in the source's
    analog samples: written with the points only, and one warning says so."""
    m = io.read(_with_analogs(tmp_path / "lab.c3d"))
    for changed in (m.resample(50.0), m.select(["A", "B"])):
        with pytest.warns(MocapWarning, match="without the source file's data other than the points "
                                              r"\(its 2 analog channels"):
            out = io.write(changed, tmp_path / "x.c3d", overwrite=True)
        assert ezc3d.c3d(str(out))["data"]["analogs"].shape[1] == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")               # a motion not read from a C3D: nothing to say
        io.write(Motion(np.zeros((4, 1, 3)), Skeleton(("p",), np.array([-1]), np.zeros((1, 3))), 30.0),
                 tmp_path / "plain.c3d")


def test_real_files_keep_their_force_plates_through_denoise(shared_data, tmp_path):
    """c3d.org's Eb015pr lists 48 point labels for 26 points and 32 analog labels for 16
    channels (integer storage); Qualisys starts at frame 704: the cleaned files keep every
    analog sample, the force-plate parameters and the first frame."""
    from mocapkit.cli import main

    for rel in ("markers/c3d_org/Eb015pr.c3d", "markers/ezc3d/Qualisys.c3d"):
        src = shared_data / rel
        out = tmp_path / Path(rel).name
        assert main(["denoise", str(src), str(out), "--method", "gaussian", "-q"]) == 0
        a, b = ezc3d.c3d(str(src)), ezc3d.c3d(str(out))
        np.testing.assert_allclose(b["data"]["analogs"], a["data"]["analogs"], rtol=1e-6, atol=1e-6)
        assert b["header"]["points"]["first_frame"] == a["header"]["points"]["first_frame"]
        np.testing.assert_array_equal(b["parameters"]["FORCE_PLATFORM"]["CHANNEL"]["value"],
                                      a["parameters"]["FORCE_PLATFORM"]["CHANNEL"]["value"])


def _with_model_outputs(path: Path, T: int = 20) -> tuple[Path, np.ndarray]:
    """A Vicon-style export: markers interleaved with Plug-in Gait outputs stored as points
    (knee angles in degrees, a ground reaction force), named by POINT:ANGLES / FORCES."""
    rng = np.random.default_rng(3)
    labels = ["LASI", "LKneeAngles", "RASI", "LGroundReactionForce", "LKNE", "RKneeAngles"]
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [100.0]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    c["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    pts = np.ones((4, 6, T))
    pts[:3] = rng.uniform(-90, 90, (3, 6, T))
    c["data"]["points"] = pts
    c["data"]["meta_points"]["residuals"] = np.full((1, 6, T), 0.5)
    c["data"]["meta_points"]["camera_masks"] = np.zeros((7, 6, T), dtype=bool)
    c.add_parameter("POINT", "ANGLES", ["LKneeAngles", "RKneeAngles"])
    c.add_parameter("POINT", "FORCES", ["LGroundReactionForce"])
    c.write(str(path))
    return path, pts


def test_model_outputs_are_not_markers_and_are_written_back_untouched(tmp_path):
    src, pts = _with_model_outputs(tmp_path / "pig.c3d")
    m = io.read(src)
    assert m.skeleton.names == ("LASI", "RASI", "LKNE")
    assert m.source["c3d"]["model_outputs"] == {"ANGLES": 2, "FORCES": 1}
    np.testing.assert_allclose(m.positions[:, 1], pts[:3, 2].T / 10, atol=1e-4)
    out = io.write(m.with_positions(m.positions + 2.0).slice(3, 15), tmp_path / "clean.c3d")
    b = ezc3d.c3d(str(out))
    assert list(b["parameters"]["POINT"]["LABELS"]["value"]) == ["LASI", "LKneeAngles", "RASI",
                                                                 "LGroundReactionForce", "LKNE", "RKneeAngles"]
    np.testing.assert_allclose(b["data"]["points"][:3, [1, 3, 5]], pts[:3, [1, 3, 5], 3:15], atol=1e-4)
    np.testing.assert_allclose(b["data"]["points"][:3, [0, 2, 4]], pts[:3, [0, 2, 4], 3:15] + 20, atol=1e-3)
    assert io.read(out).skeleton.names == ("LASI", "RASI", "LKNE")


def test_a_file_of_model_outputs_only_is_refused(tmp_path):
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [100.0]
    c["parameters"]["POINT"]["LABELS"]["value"] = ("LKneeAngles",)
    c["data"]["points"] = np.ones((4, 1, 5))
    c["data"]["meta_points"]["residuals"] = np.zeros((1, 1, 5))
    c["data"]["meta_points"]["camera_masks"] = np.zeros((7, 1, 5), dtype=bool)
    c.add_parameter("POINT", "ANGLES", ["LKneeAngles"])
    c.write(str(tmp_path / "a.c3d"))
    with pytest.raises(MocapFormatError, match="no marker trajectories.*1 angles"):
        io.read(tmp_path / "a.c3d")
