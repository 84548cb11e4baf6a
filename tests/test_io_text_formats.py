"""TRC and Kinect/MSR-Action3D text formats: synthetic files with known values, round
trips, malformed inputs, and the real files in ../shared/data."""
from __future__ import annotations

import re

import numpy as np
import pytest

import mocapkit.io as mio
from mocapkit import Motion, Skeleton
from mocapkit.errors import HeaderMismatchWarning, MocapFormatError, MocapValueError
from mocapkit.io import _text, kinect, trc


# --------------------------------------------------------------------------------------
# _text helpers
# --------------------------------------------------------------------------------------
def test_float_rows_names_the_bad_line():
    rows = [["1", "2"], ["3", "4"], ["5", "x"]]
    with pytest.raises(MocapFormatError) as e:
        _text.float_rows(rows, [7, 8, 9], 2, "f.txt", "values")
    assert e.value.line == 9 and "'x'" in e.value.message
    with pytest.raises(MocapFormatError) as e:
        _text.float_rows([["1", "2"], ["3"]], [1, 2], 2, "f.txt", "values")
    assert e.value.line == 2 and "expected 2 values, found 1" in e.value.message
    with pytest.raises(MocapFormatError, match="'NaN'"):
        _text.float_rows([["1", "NaN"]], [1], 2, "f.txt")
    A = _text.float_rows([["1", "NaN"]], [1], 2, "f.txt", allow_nan=True)
    assert np.isnan(A[0, 1]) and A[0, 0] == 1.0
    with pytest.raises(MocapFormatError, match="finite"):
        _text.float_rows([["1", "inf"]], [1], 2, "f.txt", allow_nan=True)
    assert _text.parse_float("2.5", "f", 1) == 2.5
    with pytest.raises(MocapFormatError):
        _text.parse_float("nan", "f", 1)
    with pytest.raises(MocapFormatError):
        _text.parse_int("3.0", "f", 1)


# --------------------------------------------------------------------------------------
# TRC
# --------------------------------------------------------------------------------------
def trc_text(sep="\t", units="m", n_frames_header=None):
    names = ["RASI", "LASI", "C7"]
    P = np.array([[[0.1, 0.9, 0.2], [0.3, 0.91, 0.2], [0.2, 1.4, 0.1]],
                  [[0.11, 0.9, 0.2], [0.31, 0.91, 0.2], [0.21, 1.41, 0.1]],
                  [[0.12, 0.9, 0.2], [0.32, 0.91, 0.2], [0.22, 1.42, 0.1]]])
    rows = [
        sep.join(["PathFileType", "4", "(X/Y/Z)", "x.trc"]),
        sep.join(["DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate",
                  "OrigDataStartFrame", "OrigNumFrames"]),
        sep.join(["50", "50", str(n_frames_header or 3), "3", units, "50", "1", "3"]),
        sep.join(["Frame#", "Time"] + [c for n in names for c in (n, "", "")]),
        sep.join(["", ""] + [f"{a}{i + 1}" for i in range(3) for a in "XYZ"]),
        "",
    ]
    for t in range(3):
        cells = [str(t + 1), f"{t / 50:.3f}"] + [f"{v:.4f}" for v in P[t].ravel()]
        if t == 1:
            cells[2 + 3:2 + 6] = ["", "", ""]            # LASI missing in frame 2
        if t == 2:
            cells[2 + 6:2 + 9] = ["NaN", "NaN", "NaN"]    # C7 missing (OpenSim style)
        rows.append(sep.join(cells))
    return "\n".join(rows) + "\n", P, names


@pytest.mark.parametrize("sep", ["\t", ","])
def test_trc_read_known_values(tmp_path, sep):
    text, P, names = trc_text(sep)
    p = tmp_path / "a.trc"
    p.write_text(text)
    m = mio.read(p)
    assert m.skeleton.names == tuple(names) and m.fps == 50
    assert list(m.skeleton.parents) == [-1, -1, -1] and not m.skeleton.offsets.any()
    np.testing.assert_allclose(m.positions[0], P[0] * 100)            # m -> cm
    assert not m.observed[1, 1] and not m.observed[2, 2] and m.observed.sum() == 7
    np.testing.assert_allclose(m.source["per_frame"]["time"], [0, 0.02, 0.04])
    assert m.source["units"]["factor_to_cm"] == 100.0


def test_trc_round_trip_and_units(tmp_path):
    text, P, names = trc_text(units="mm")
    p = tmp_path / "a.trc"
    p.write_text(text)
    m = trc.read(p)
    np.testing.assert_allclose(m.positions[0], P[0] / 10)               # mm -> cm
    out = tmp_path / "b.trc"
    mio.write(m, out)
    txt = out.read_text()
    assert "\tmm\t" in txt.splitlines()[2]                               # OpenSim style
    m2 = trc.read(out)
    np.testing.assert_array_equal(m2.observed, m.observed)
    np.testing.assert_allclose(m2.positions[m.observed], m.positions[m.observed], atol=1e-7)
    out_m = tmp_path / "c.trc"
    trc.write(m, out_m, units="m")
    np.testing.assert_allclose(trc.read(out_m).positions[m.observed], m.positions[m.observed], atol=1e-7)
    with pytest.raises(MocapValueError, match="unit"):
        trc.write(m, tmp_path / "d.trc", units="furlong")


@pytest.mark.parametrize("block", [1, 2, 3])
def test_trc_blocked_parsing_same_result_and_lines(tmp_path, monkeypatch, block):
    """read() converts data rows in blocks (trc._READ_BLOCK): any block size gives the same
    motion, and errors in a later block still name the right line."""
    text, _, _ = trc_text()
    p = tmp_path / "a.trc"
    p.write_text(text)
    ref = trc.read(p)
    monkeypatch.setattr(trc, "_READ_BLOCK", block)
    m = trc.read(p)
    np.testing.assert_array_equal(m.observed, ref.observed)
    np.testing.assert_array_equal(np.nan_to_num(m.positions), np.nan_to_num(ref.positions))
    np.testing.assert_array_equal(m.source["per_frame"]["frame"], [1, 2, 3])
    lines = text.splitlines()
    lines[8] = lines[8].replace("0.1200", "oops", 1)     # frame 3 = file line 9
    bad = tmp_path / "bad.trc"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(MocapFormatError) as e:
        trc.read(bad)
    assert e.value.line == 9 and "'oops'" in e.value.message
    lines = text.splitlines()
    lines[7] = "\t".join(lines[7].split("\t")[:4])       # frame 2 cut inside a triple
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(MocapFormatError, match="inside a marker triple") as e:
        trc.read(bad)
    assert e.value.line == 8


def test_trc_malformed(tmp_path):
    text, _, _ = trc_text()
    lines = text.splitlines()
    cases = {
        "cut inside a marker": (lines[:-1] + [lines[-1].rsplit("\t", 1)[0]], 9, "inside a marker triple"),
        "garbage": (lines[:7] + [lines[7].replace("0.1100", "0.11x")] + lines[8:], 8, "'0.11x'"),
        "inf": (lines[:7] + [lines[7].replace("0.1100", "inf")] + lines[8:], 8, "finite"),
        "units": (lines[:2] + [lines[2].replace("\tm\t", "\tfeet\t")] + lines[3:], 3, "Units 'feet'"),
        "no data": (lines[:6], 6, "no data rows"),
        "not trc": (["hello"] + lines[1:], 1, "PathFileType"),
        "no names": (lines[:3] + ["x\ty"] + lines[4:], 4, "Frame#"),
        "too many cells": (lines[:7] + [lines[7] + "\t1\t2\t3"] + lines[8:], 8, "at most 11 cells"),
        "duplicate names": (lines[:3] + [lines[3].replace("LASI", "RASI")] + lines[4:], 4, "duplicate"),
    }
    for name, (ls, line, msg) in cases.items():
        p = tmp_path / f"{name.replace(' ', '_')}.trc"
        p.write_text("\n".join(ls) + "\n")
        with pytest.raises(MocapFormatError) as e:
            trc.read(p)
        assert e.value.line == line, (name, e.value)
        assert re.search(msg, e.value.message), (name, e.value.message)


def test_trc_header_mismatch_is_reported(tmp_path):
    text, _, _ = trc_text(n_frames_header=10)
    p = tmp_path / "a.trc"
    p.write_text(text)
    with pytest.warns(HeaderMismatchWarning):
        m = trc.read(p)
    assert m.n_frames == 3 and "NumFrames=10" in m.source["warnings"][0]


def test_trc_real_pyomeca(shared_data, tmp_path):
    f = shared_data / "markers" / "pyomeca" / "markers.trc"
    with pytest.warns(HeaderMismatchWarning):
        m = mio.read(f)
    assert (m.n_frames, m.n_joints, m.fps) == (93, 51, 100.0)
    assert m.skeleton.names[:3] == ("ASISl", "ASISr", "PSISl")
    np.testing.assert_allclose(m.positions[0, 0], [73.37041, 8.09832, 19.18668])     # mm -> cm
    assert m.observed.all()
    assert any("NumFrames=652" in w for w in m.source["warnings"])       # header says 652
    out = tmp_path / "pyomeca_rt.trc"
    mio.write(m, out)
    m2 = mio.read(out)
    assert np.abs(m2.positions - m.positions).max() < 1e-6
    assert m2.skeleton.names == m.skeleton.names


# --------------------------------------------------------------------------------------
# Kinect / MSR Action3D
# --------------------------------------------------------------------------------------
def kinect_frames(T=12, J=20, seed=0):
    """Smooth synthetic joints (T, J, 3) in metres, in *file* order of the 20/25 layout."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(-0.8, 0.8, size=(J, 3)) + [0, 0, 2.6]
    base[:, 1] = np.linspace(-0.9, 0.7, J)                          # 1.6 m tall
    t = np.arange(T)[:, None, None]
    return np.round(base + 0.01 * np.sin(0.3 * t + rng.uniform(0, 6, size=(1, J, 3))), 6)


def kinect_text(F, conf=True):
    T, J, _ = F.shape
    rows = []
    for t in range(T):
        for j in range(J):
            x, y, z = F[t, j]
            rows.append(f"{x:.6f} {y:.6f} {z:.6f}" + (f" {((t + j) % 3) / 2:.6f}" if conf else ""))
    return "\n".join(rows) + "\n"


def test_kinect_msr_layout_and_units(tmp_path):
    F = kinect_frames()
    F[4] = 0.0                                                       # untracked frame
    p = tmp_path / "a01_s01_e01_skeleton3D.txt"
    p.write_text(kinect_text(F))
    m = mio.read(p)
    assert m.n_joints == 20 and m.n_frames == 12 and m.fps == 15.0
    assert m.source["units"]["name"] == "m"
    # file line k (1-based) within a frame is MSR20_FILE_ORDER[k-1]
    for k, name in enumerate(kinect.MSR20_FILE_ORDER):
        np.testing.assert_allclose(m.positions[0, m.skeleton.index(name)], F[0, k] * 100, atol=1e-9)
    assert m.skeleton.names[0] == "HipCenter" and m.skeleton.parents[0] == -1
    assert not m.observed[4].any() and m.observed[[0, 5]].all()      # 0 0 0 -> missing
    # confidence kept (motion order) but not used as a mask
    conf = m.source["per_frame"]["confidence"]
    assert conf.shape == (12, 20) and (conf == 0).any()
    # rest offsets are median bone vectors (cm)
    j, par = m.skeleton.index("Head"), m.skeleton.index("ShoulderCenter")
    np.testing.assert_allclose(m.skeleton.offsets[j],
                               np.nanmedian(m.positions[:, j] - m.positions[:, par], axis=0))
    # fps and units options
    assert kinect.read(p, fps=30).fps == 30
    np.testing.assert_allclose(kinect.read(p, units="cm").positions[0], m.positions[0] / 100)
    mm = kinect.read(p, units=(100, 100, 50))
    np.testing.assert_allclose(mm.positions[0, :, 2], m.positions[0, :, 2] / 2)


def test_kinect_body_parts():
    m_names = kinect.LAYOUTS["msr20"][1]
    par = kinect._PARENT
    idx = {n: i for i, n in enumerate(m_names)}
    sk = Skeleton(m_names, [idx[par[n]] if par[n] else -1 for n in m_names], np.ones((20, 3)))
    parts = {k: {sk.names[i] for i in v} for k, v in sk.body_parts().items()}
    assert parts["torso"] == {"HipCenter", "Spine", "ShoulderCenter", "Head"}
    assert parts["left_arm"] == {"ShoulderCenter", "ShoulderLeft", "ElbowLeft", "WristLeft", "HandLeft"}
    assert parts["right_leg"] == {"HipCenter", "HipRight", "KneeRight", "AnkleRight", "FootRight"}
    v2 = kinect.LAYOUTS["kinect_v2"][1]
    idx2 = {n: i for i, n in enumerate(v2)}
    sk2 = Skeleton(v2, [idx2[kinect._PARENT_V2[n]] if kinect._PARENT_V2[n] else -1 for n in v2],
                   np.ones((25, 3)))
    p2 = {k: {sk2.names[i] for i in v} for k, v in sk2.body_parts().items()}
    assert p2["torso"] == {"SpineBase", "SpineMid", "SpineShoulder", "Neck", "Head"}
    assert {"HandTipLeft", "ThumbLeft"} <= p2["left_arm"] and "HipLeft" in p2["left_leg"]


def test_kinect_auto_joint_count(tmp_path):
    # 25 joints x 4 frames = 100 lines: divisible by 20 and 25 -> smoothness decides
    F = kinect_frames(T=4, J=25)
    p = tmp_path / "v2.txt"
    p.write_text(kinect_text(F, conf=False))
    m = kinect.read(p)
    assert m.n_joints == 25 and "smoother" in m.source["kinect"]["n_joints_chosen_by"]
    assert m.source["kinect"]["columns"] == 3 and "confidence" not in m.source["per_frame"]
    np.testing.assert_allclose(m.positions[0, m.skeleton.index("SpineShoulder")], F[0, 20] * 100)
    assert list(m.skeleton.parents[:3]) == [-1, 0, 1]                # parent-first order
    # 20 x 5 frames = 100 lines too
    F20 = kinect_frames(T=5, J=20)
    p20 = tmp_path / "v1.txt"
    p20.write_text(kinect_text(F20))
    assert kinect.read(p20).n_joints == 20
    assert kinect.read(p20, n_joints=25).n_joints == 25             # user knows best
    # 25 x 3 = 75 lines: only 25 fits
    p75 = tmp_path / "v75.txt"
    p75.write_text(kinect_text(kinect_frames(T=3, J=25)))
    assert "only by 25" in kinect.read(p75).source["kinect"]["n_joints_chosen_by"]


def test_kinect_round_trip(tmp_path):
    F = kinect_frames()
    F[3] = 0.0
    p = tmp_path / "in.txt"
    text = kinect_text(F)
    p.write_text(text)
    m = kinect.read(p)
    out = tmp_path / "out.txt"
    mio.write(m, out, format="kinect")
    m2 = kinect.read(out)
    assert np.array_equal(m2.observed, m.observed)
    assert np.nanmax(np.abs(m2.positions - m.positions)) < 1e-6
    np.testing.assert_allclose(np.loadtxt(out), np.loadtxt(p), atol=1e-12)   # same numbers, same order
    # a motion with Kinect joint names but no Kinect source gets the layout from its names
    plain = Motion(m.positions, m.skeleton, m.fps)
    out2 = tmp_path / "plain.txt"
    kinect.write(plain, out2)
    np.testing.assert_allclose(kinect.read(out2).positions, m.positions, atol=1e-6)
    with pytest.raises(MocapValueError, match="Kinect"):
        kinect.write(m.select(["HipCenter", "Spine"]), tmp_path / "x.txt")


def test_kinect_malformed(tmp_path):
    good = kinect_text(kinect_frames(T=3)).splitlines()
    cases = {
        "truncated": (good[:-3], 57, "neither 20 nor 25"),
        "nan": (good[:10] + ["nan 0.1 2.0 1.0"] + good[11:], 11, "'nan'"),
        "garbage": (good[:10] + ["0.1 0.2 abc 1.0"] + good[11:], 11, "'abc'"),
        "wrong count": (good[:10] + ["0.1 0.2 2.0"] + good[11:], 11, "expected 4 values"),
        "five columns": (["1 2 3 4 5"] + good[1:], 1, "3 or 4 values"),
        "empty": ([], 1, "empty file"),
    }
    for name, (ls, line, msg) in cases.items():
        p = tmp_path / f"{name.replace(' ', '_')}.txt"
        p.write_text("\n".join(ls) + ("\n" if ls else ""))
        with pytest.raises(MocapFormatError) as e:
            mio.read(p)
        assert e.value.line == line, (name, e.value)
        assert re.search(msg, e.value.message), (name, e.value.message)
    p = tmp_path / "n.txt"
    p.write_text("\n".join(good) + "\n")
    with pytest.raises(MocapFormatError, match="not a multiple of 25"):
        kinect.read(p, n_joints=25)


def test_kinect_real_msr_all_files(shared_data, tmp_path):
    files = sorted((shared_data / "msr_action3d" / "skeleton3d").glob("*_skeleton3D.txt"))
    assert len(files) == 567
    heights, empty = [], []
    for f in files:
        m = kinect.read(f)
        assert m.n_joints == 20 and m.source["units"]["name"] == "m", f.name
        if m.observed.any():
            P = m.positions[m.observed.all(axis=1)]
            heights.append(np.median(P[:, m.skeleton.index("Head"), 1]
                                     - P[:, [m.skeleton.index("FootLeft"), m.skeleton.index("FootRight")], 1].min(1)))
        else:
            empty.append(f.name)
    assert empty == ["a13_s09_e02_skeleton3D.txt"]              # the one untracked file
    heights = np.array(heights)
    # head joint (centre of the head) to the lowest foot joint, median per clip, cm;
    # a13 (bend) and crouching clips pull the low tail
    assert 150 < np.median(heights) < 175
    assert np.percentile(heights, 95) < 190
    # exact values of the first line of the first file, and a byte-equivalent round trip
    f0 = shared_data / "msr_action3d" / "skeleton3d" / "a01_s01_e01_skeleton3D.txt"
    m0 = kinect.read(f0)
    np.testing.assert_allclose(m0.positions[0, m0.skeleton.index("ShoulderLeft")],
                               [-37.1736, 37.1031, 267.4849])
    out = tmp_path / "rt.txt"
    kinect.write(m0, out)
    np.testing.assert_array_equal(np.loadtxt(out), np.loadtxt(f0))


def test_kinect_msr_sides_and_head(shared_data):
    """The evidence for the labels: single-arm actions move the (relabelled) right hand,
    and the head is the top of the body unless a hand is raised."""
    d = shared_data / "msr_action3d" / "skeleton3d"
    right_wins = total = 0
    for f in sorted(d.glob("a0[1-5]_s0[1-5]_e01_skeleton3D.txt")):
        m = kinect.read(f)
        P = m.positions[m.observed.all(axis=1)]
        hc = P[:, m.skeleton.index("HipCenter")]
        sr = np.nanstd(P[:, m.skeleton.index("HandRight")] - hc, axis=0).sum()
        sl = np.nanstd(P[:, m.skeleton.index("HandLeft")] - hc, axis=0).sum()
        right_wins += sr > sl
        total += 1
    assert total >= 20 and right_wins >= 0.9 * total
    m = kinect.read(d / "a13_s01_e01_skeleton3D.txt")                 # bend: no raised hands
    P = m.positions[m.observed.all(axis=1)]
    top = np.argmax(P[..., 1], axis=1)
    assert np.mean(top == m.skeleton.index("Head")) > 0.9


# --------------------------------------------------------------------------------------
# issue 18: header counts vs data give one warning naming both numbers
# --------------------------------------------------------------------------------------
import warnings  # noqa: E402


def test_trc_numframes_mismatch_warns_once_naming_both(tmp_path):
    text, _, _ = trc_text(n_frames_header=10)
    p = tmp_path / "nf.trc"
    p.write_text(text)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        m = mio.read(p)
    got = [w for w in rec if issubclass(w.category, HeaderMismatchWarning)]
    assert len(got) == 1 and len(rec) == 1
    msg = str(got[0].message)
    assert "NumFrames=10" in msg and "3 complete data rows" in msg and "nf.trc" in msg
    assert m.n_frames == 3


def test_trc_nummarkers_mismatch_warns(tmp_path):
    text, _, _ = trc_text()
    lines = text.splitlines()
    lines[2] = lines[2].replace("\t3\tm\t", "\t7\tm\t")
    p = tmp_path / "nm.trc"
    p.write_text("\n".join(lines) + "\n")
    with pytest.warns(HeaderMismatchWarning, match=r"NumMarkers=7 .*names 3 markers"):
        m = mio.read(p)
    assert m.n_joints == 3


@pytest.mark.parametrize("count", ["inf", "-inf", "nan", "many"])
def test_trc_header_count_not_a_number_is_noted_not_raised(tmp_path, count):
    """A NumFrames that is no finite number ('inf' once raised OverflowError) is noted in
    source['warnings']; the data rows are read."""
    text, _, _ = trc_text()
    lines = text.splitlines()
    lines[2] = lines[2].replace("\t3\t3\tm\t", f"\t{count}\t3\tm\t")
    p = tmp_path / "nf.trc"
    p.write_text("\n".join(lines) + "\n")
    m = mio.read(p)
    assert m.n_frames == 3
    assert m.source["warnings"] == [f"header NumFrames {count!r} is not a number"]


def test_trc_consistent_header_gives_no_warning(tmp_path):
    text, _, _ = trc_text()
    p = tmp_path / "ok.trc"
    p.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mio.read(p)


def test_trc_real_pyomeca_warns_652_vs_93(shared_data):
    with pytest.warns(HeaderMismatchWarning, match=r"NumFrames=652 .*93") as rec:
        m = mio.read(shared_data / "markers" / "pyomeca" / "markers.trc")
    assert m.n_frames == 93
    assert len([w for w in rec if issubclass(w.category, HeaderMismatchWarning)]) == 1


# --------------------------------------------------------------------------------------
# filled flags in a sidecar (issue 15 item 4): <output>.filled.tsv
# --------------------------------------------------------------------------------------
def _flagged_motion(T=12, J=3):
    rng = np.random.default_rng(5)
    P = rng.uniform(-100, 100, (T, J, 3))
    obs = np.ones((T, J), bool)
    obs[2:4, 0] = False
    fil = np.zeros((T, J), bool)
    fil[5:8, 1] = True
    fil[11, 2] = True
    sk = Skeleton(("RASI", "LASI", "C7"), [-1, -1, -1], np.zeros((3, 3)))
    return Motion(P, sk, 50.0, obs, filled=fil)


def test_trc_filled_sidecar_round_trip(tmp_path):
    m = _flagged_motion()
    out = mio.write(m, tmp_path / "walk.trc")
    side = tmp_path / "walk.trc.filled.tsv"
    assert mio.filled_sidecar_path(out) == side and side.is_file()
    lines = side.read_text().splitlines()
    assert lines[0] == "RASI\tLASI\tC7" and len(lines) == 1 + m.n_frames
    assert lines[6] == "0\t1\t0" and lines[1] == "0\t0\t0"               # frame 5 (0-based)
    b = mio.read(out)
    np.testing.assert_array_equal(b.filled, m.filled)
    np.testing.assert_array_equal(b.observed, m.observed)
    assert b.source["filled_sidecar"] == str(side)
    assert not mio.read(out, sidecar=False).filled.any()
    # the TRC itself is unchanged by the convention (other tools read it as before)
    assert "filled" not in out.read_text()


def test_no_sidecar_without_filled_samples_and_stale_one_removed(tmp_path):
    m = _flagged_motion()
    out = mio.write(m, tmp_path / "a.trc")
    side = mio.filled_sidecar_path(out)
    assert side.exists()
    plain = m.with_filled(np.zeros_like(m.filled))
    with pytest.raises(MocapValueError, match="exists"):
        mio.write(plain, out)                                             # no --force
    mio.write(plain, out, overwrite=True)
    assert not side.exists()                                              # stale flags gone
    assert not mio.read(out).filled.any()
    mio.write(plain, tmp_path / "b.trc")
    assert not mio.filled_sidecar_path(tmp_path / "b.trc").exists()


def test_existing_sidecar_needs_overwrite_and_never_replaces_an_input(tmp_path):
    m = _flagged_motion()
    side = tmp_path / "c.trc.filled.tsv"
    side.write_text("something else\n")
    with pytest.raises(MocapValueError, match="exists"):
        mio.write(m, tmp_path / "c.trc")
    assert not (tmp_path / "c.trc").exists() and side.read_text() == "something else\n"
    mio.write(m, tmp_path / "c.trc", overwrite=True)
    np.testing.assert_array_equal(mio.read(tmp_path / "c.trc").filled, m.filled)
    # a motion whose sidecar input is the sidecar the new output would need: refused
    src = mio.read(tmp_path / "c.trc")
    fake = src.with_source(path=str(tmp_path / "other.trc"))
    with pytest.raises(MocapValueError, match="input"):
        mio.write(fake, tmp_path / "c.trc", overwrite=True)


@pytest.mark.parametrize("fmt,ext", [("bvh", ".bvh"), ("kinect", ".txt")])
def test_sidecar_for_other_formats(tmp_path, fmt, ext):
    if fmt == "bvh":
        sk = Skeleton(("Hips", "Spine"), [-1, 0], np.array([[0, 0, 0], [0, 20.0, 0]]))
        P = np.tile(np.array([[0.0, 90, 0], [0, 110, 0]]), (6, 1, 1))
        P[:, :, 0] += np.arange(6)[:, None]
        m = Motion(P, sk, 60.0)
    else:
        m = kinect.read(_kinect_file(tmp_path))
    fil = np.zeros((m.n_frames, m.n_joints), bool)
    fil[1, 1] = fil[-1, 0] = True
    m = m.with_filled(fil)
    out = mio.write(m, tmp_path / f"out{ext}")
    assert mio.filled_sidecar_path(out).is_file()
    np.testing.assert_array_equal(mio.read(out, format=fmt).filled, fil)


def _kinect_file(tmp_path):
    rng = np.random.default_rng(3)
    rows = []
    for t in range(3):
        for j in range(20):
            x, y, z = rng.uniform(-0.5, 0.5), rng.uniform(-0.8, 0.8), 2.5 + 0.01 * t
            rows.append(f"{x:.6f} {y:.6f} {z:.6f} 1")
    p = tmp_path / "k_skeleton.txt"
    p.write_text("\n".join(rows) + "\n")
    return p


@pytest.mark.parametrize("mutate,line,msg", [
    (lambda ls: ["RASI\tLASI"] + ls[1:], 1, "names 2 joints"),
    (lambda ls: ls[:-1], 12, "11 frame lines"),
    (lambda ls: ls[:3] + ["0\t2\t0"] + ls[4:], 4, "0 or 1"),
    (lambda ls: ls[:3] + ["0\t1"] + ls[4:], 4, "expected 3"),
    (lambda ls: ls[:3] + ["0\tx\t1"] + ls[4:], 4, "'x'"),
])
def test_bad_sidecar_is_a_format_error_naming_it(tmp_path, mutate, line, msg):
    out = mio.write(_flagged_motion(), tmp_path / "s.trc")
    side = mio.filled_sidecar_path(out)
    side.write_text("\n".join(mutate(side.read_text().splitlines())) + "\n")
    with pytest.raises(MocapFormatError) as ei:
        mio.read(out)
    assert ei.value.path == str(side) and ei.value.line == line
    assert re.search(msg, ei.value.message), ei.value.message
    assert mio.read(out, sidecar=False).n_frames == 12


def test_trc_write_keeps_the_files_frame_numbers_and_original_fields(tmp_path):
    """A cleaned TRC lines up with the capture it came from: Frame# and the Orig* header
    fields of the source file, also for a slice; a resampled motion describes itself."""
    lines = trc_text(units="mm")[0].splitlines()
    lines[2] = "\t".join(["50", "200", "3", "3", "mm", "200", "101", "900"])
    for t in range(3):                                                  # frames 101..103
        row = lines[6 + t].split("\t")
        row[0] = str(101 + t)
        lines[6 + t] = "\t".join(row)
    p = tmp_path / "a.trc"
    p.write_text("\n".join(lines) + "\n")
    m = trc.read(p)
    out = mio.write(m.slice(1, 3), tmp_path / "b.trc") or tmp_path / "b.trc"
    head = out.read_text().splitlines()
    assert head[2].split("\t") == ["50", "200", "2", "3", "mm", "200", "101", "900"]
    np.testing.assert_array_equal(trc.read(out).source["per_frame"]["frame"], [102, 103])
    trc.write(m.resample(25.0), tmp_path / "c.trc")
    assert (tmp_path / "c.trc").read_text().splitlines()[2].split("\t")[5:] == ["25", "1", "2"]
