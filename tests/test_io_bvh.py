"""BVH reader/writer: FK against an independent reference, round trips, IK write-back,
malformed files, and the real CMU conversions in ../shared/data."""
from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import mocapkit.io as mio
from mocapkit import Motion, Skeleton
from mocapkit.errors import MocapFormatError, MocapValueError
from mocapkit.io import bvh

# --------------------------------------------------------------------------------------
# a small synthetic file: mixed channel orders, a 6-channel non-root joint, End Sites,
# a zero-length joint (like CMU LHipJoint) and a joint with 3 children (hips).
# --------------------------------------------------------------------------------------
# (name, parent, offset, channels); End Sites have channels None
SYNTH = [
    ("Hips", -1, (0.0, 0.0, 0.0), "Xposition Yposition Zposition Zrotation Yrotation Xrotation"),
    ("LHipJoint", 0, (0.0, 0.0, 0.0), "Zrotation Xrotation Yrotation"),
    ("LeftUpLeg", 1, (9.0, -6.0, 1.0), "Zrotation Yrotation Xrotation"),
    ("LeftLeg", 2, (0.0, -42.0, 1.5), "Xrotation Yrotation Zrotation"),
    ("LeftFoot", 3, (0.0, -41.0, -2.0), "Yrotation Xrotation Zrotation"),
    ("LeftFoot_End", 4, (0.0, -4.0, 12.0), None),
    ("RightUpLeg", 0, (-9.0, -6.0, 1.0), "Zrotation Xrotation Yrotation"),
    ("RightLeg", 6, (0.0, -42.0, 1.5), "Zrotation Yrotation Xrotation"),
    ("RightLeg_End", 7, (0.0, -41.0, 0.0), None),
    ("Spine", 0, (0.0, 12.0, -1.0), "Xrotation Zrotation Yrotation"),
    ("Chest", 9, (0.0, 20.0, 0.5), "Xposition Yposition Zposition Yrotation Zrotation Xrotation"),
    ("Neck", 10, (0.0, 22.0, 0.0), "Zrotation Xrotation Yrotation"),
    ("Head", 11, (0.0, 9.0, 1.0), "Zrotation Xrotation Yrotation"),
    ("Head_End", 12, (0.0, 18.0, 0.0), None),
    ("LeftArm", 10, (17.0, 18.0, 0.0), "Yrotation Xrotation Zrotation"),
    ("LeftForeArm", 14, (28.0, 0.0, 0.0), "Zrotation Yrotation Xrotation"),
    ("LeftForeArm_End", 15, (25.0, 0.0, 0.0), None),
    ("RightArm", 10, (-17.0, 18.0, 0.0), "Zrotation Xrotation Yrotation"),
    ("RightArm_End", 17, (-28.0, 0.0, 0.0), None),
]
JOINTS = [s[0] for s in SYNTH if s[3] is not None]


def _n_channels():
    return sum(len(s[3].split()) for s in SYNTH if s[3] is not None)


def synth_channels(T=40, seed=0, amp=40.0):
    """Smooth random channel values (T, C): angles in degrees, positions in cm."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, T)[:, None]
    cols = []
    for name, parent, off, ch in SYNTH:
        if ch is None:
            continue
        for c in ch.split():
            a, f, ph = rng.uniform(0.3, 1) * amp, rng.uniform(0.5, 2.0), rng.uniform(0, 6.28)
            if c.endswith("position"):
                base = (np.array(off) if parent >= 0 else np.array([10.0, 95.0, -30.0]))["XYZ".index(c[0])]
                cols.append(base + (3.0 if parent >= 0 else 40.0) * np.sin(6.28 * f * t[:, 0] + ph))
            else:
                cols.append(a * np.sin(6.28 * f * t[:, 0] + ph) + rng.uniform(-30, 30))
    return np.stack(cols, axis=1)


def synth_text(ch, frame_time=1 / 60, fmt="%.6f"):
    lines = ["HIERARCHY"]
    kids = {i: [k for k, s in enumerate(SYNTH) if s[1] == i] for i in range(len(SYNTH))}

    def emit(i, d):
        name, parent, off, chans = SYNTH[i]
        ind = "  " * d
        lines.append(f"{ind}{'End Site' if chans is None else ('ROOT ' if parent < 0 else 'JOINT ') + name}")
        lines.append(f"{ind}{{")
        lines.append(f"{ind}  OFFSET {off[0]} {off[1]} {off[2]}")
        if chans is not None:
            lines.append(f"{ind}  CHANNELS {len(chans.split())} {chans}")
        for k in kids[i]:
            emit(k, d + 1)
        lines.append(f"{ind}}}")

    emit(0, 0)
    lines += ["MOTION", f"Frames: {len(ch)}", f"Frame Time: {frame_time}"]
    lines += [" ".join(fmt % v for v in row) for row in ch]
    return "\n".join(lines) + "\n"


def reference_fk(ch):
    """Independent FK with scipy Rotation (intrinsic Euler = product in channel order)."""
    T = len(ch)
    col = 0
    pos, rot = {}, {}
    for i, (name, parent, off, chans) in enumerate(SYNTH):
        t = np.tile(np.array(off, float), (T, 1))
        R = Rotation.identity(T)
        if chans is not None:
            names = chans.split()
            rseq, rang = "", []
            for k, c in enumerate(names):
                if c.endswith("position"):
                    t[:, "XYZ".index(c[0])] = ch[:, col + k]
                else:
                    rseq += c[0]
                    rang.append(ch[:, col + k])
            if rseq:
                R = Rotation.from_euler(rseq, np.stack(rang, 1), degrees=True)
            col += len(names)
        if parent < 0:
            pos[i], rot[i] = t, R
        else:
            pos[i] = pos[parent] + rot[parent].apply(t)
            rot[i] = rot[parent] * R
    return np.stack([pos[i] for i, s in enumerate(SYNTH) if s[3] is not None], axis=1)


@pytest.fixture
def synth_file(tmp_path):
    ch = synth_channels()
    p = tmp_path / "synth.bvh"
    p.write_text(synth_text(ch))
    return p, np.round(ch, 6)


# --------------------------------------------------------------------------------------
def test_read_fk_matches_reference(synth_file):
    p, ch = synth_file
    m = bvh.read(p, units="cm")
    assert m.skeleton.names == tuple(JOINTS)                   # End Sites dropped
    assert m.n_frames == len(ch) and m.fps == pytest.approx(60.0)
    np.testing.assert_allclose(m.positions, reference_fk(ch), atol=1e-9)
    np.testing.assert_allclose(m.source["per_frame"]["channels"], ch)
    meta = m.source["bvh"]
    assert sum(n["end_site"] for n in meta["nodes"]) == 5
    # non-root joint with position channels: its translation follows the channels
    assert m.source["units"]["factor_to_cm"] == 1.0


def test_read_end_sites_as_joints(synth_file):
    p, ch = synth_file
    m = bvh.read(p, units="cm", end_sites=True)
    assert "Head_End" in m.skeleton.names and m.n_joints == len(SYNTH)
    head, end = m.skeleton.index("Head"), m.skeleton.index("Head_End")
    np.testing.assert_allclose(np.linalg.norm(m.positions[:, end] - m.positions[:, head], axis=1), 18.0)
    names, X = bvh.node_positions(bvh.read(p, units="cm").slice(3, 9))
    assert names == tuple(s[0] for s in SYNTH)
    np.testing.assert_allclose(X, m.positions[3:9], atol=1e-9)


def test_units_inferred_and_overridden(synth_file, tmp_path):
    p, _ = synth_file
    m = bvh.read(p)                                    # ~170 cm skeleton -> cm
    assert m.source["units"]["name"] == "cm" and "inferred" in m.source["units"]["chosen_by"]
    q = tmp_path / "metres.bvh"                         # same skeleton in metres
    txt = p.read_text()
    txt = re.sub(r"OFFSET (\S+) (\S+) (\S+)",
                 lambda mo: "OFFSET " + " ".join(str(float(v) / 100) for v in mo.groups()), txt)
    q.write_text(txt)
    mq = bvh.read(q)
    assert mq.source["units"]["name"] == "m"
    m_mm = bvh.read(p, units="mm")
    assert m_mm.source["units"]["factor_to_cm"] == 0.1
    np.testing.assert_allclose(bvh.read(p, units=2.0).skeleton.offsets, 2 * m.skeleton.offsets)
    with pytest.raises(MocapValueError, match="unknown BVH unit"):
        bvh.read(p, units="furlong")


@pytest.mark.parametrize("order", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"])
def test_euler_extraction_all_orders(order):
    rng = np.random.default_rng(1)
    ang = rng.uniform(-180, 180, size=(200, 3))
    ang[:, 1] = rng.uniform(-89.9, 89.9, size=200)
    ang[:5, 1] = [90.0, -90.0, 89.9999999, -89.9999999, 0.0]          # gimbal lock
    R = Rotation.from_euler(order, ang, degrees=True).as_matrix()
    axes = ["XYZ".index(c) for c in order]
    got = bvh._angles_for(R, axes, None)
    R2 = Rotation.from_euler(order, got, degrees=True).as_matrix()
    np.testing.assert_allclose(R2, R, atol=1e-9)
    # with reference angles the original values come back (branch and 360-degree turn)
    ref = ang + 360.0 * rng.integers(-1, 2, size=ang.shape)
    R3 = Rotation.from_euler(order, ref, degrees=True).as_matrix()
    np.testing.assert_allclose(bvh._angles_for(R3, axes, ref)[5:], ref[5:], atol=1e-7)


def test_round_trip_synthetic(synth_file, tmp_path):
    p, ch = synth_file
    m = bvh.read(p, units="cm")
    out = tmp_path / "rt.bvh"
    mio.write(m, out)
    m2 = mio.read(out, units="cm")
    assert np.abs(m2.positions - m.positions).max() < 1e-6
    np.testing.assert_allclose(m2.source["per_frame"]["channels"], ch, atol=1e-7)
    assert m2.skeleton == m.skeleton
    # the written hierarchy keeps channel orders and End Sites
    txt = out.read_text()
    assert "CHANNELS 6 Xposition Yposition Zposition Yrotation Zrotation Xrotation" in txt
    assert txt.count("End Site") == 5
    # writing in another unit rescales offsets and translations, rotations unchanged
    out_m = tmp_path / "rt_m.bvh"
    bvh.write(m, out_m, units="m")
    mm = bvh.read(out_m)
    assert mm.source["units"]["name"] == "m"
    assert np.abs(mm.positions - m.positions).max() < 1e-6
    rot_cols = [k for k, c in enumerate(" ".join(s[3] for s in SYNTH if s[3]).split()) if "rotation" in c]
    np.testing.assert_allclose(mm.source["per_frame"]["channels"][:, rot_cols], ch[:, rot_cols], atol=1e-7)
    # a sliced motion keeps its per-frame channels aligned and still round-trips
    s = m.slice(7, 30)
    out2 = tmp_path / "slice.bvh"
    bvh.write(s, out2)
    s2 = bvh.read(out2, units="cm")
    assert np.abs(s2.positions - s.positions).max() < 1e-6
    np.testing.assert_allclose(s2.source["per_frame"]["channels"], ch[7:30], atol=1e-7)


def test_ik_from_identity_reproduces_fk_positions(synth_file, tmp_path):
    """Positions made by FK of known rotations, written with no starting rotations."""
    p, ch = synth_file
    m = bvh.read(p, units="cm")
    bare = m.with_source(per_frame={})               # as if it came from C3D/denoiser
    out = tmp_path / "ik.bvh"
    bvh.write(bare, out)
    m2 = bvh.read(out, units="cm")
    assert np.abs(m2.positions - m.positions).max() < 1e-4
    # also with the End Sites as joints (leaf rotations are then determined too)
    me = bvh.read(p, units="cm", end_sites=True).with_source(per_frame={})
    out2 = tmp_path / "ik_end.bvh"
    bvh.write(me, out2)
    me2 = bvh.read(out2, units="cm", end_sites=True)
    assert np.abs(me2.positions - me.positions).max() < 1e-4


def test_ik_after_position_noise(synth_file, tmp_path):
    from scipy.ndimage import gaussian_filter1d

    p, _ = synth_file
    m = bvh.read(p, units="cm")
    rng = np.random.default_rng(3)
    noise = gaussian_filter1d(rng.normal(size=m.positions.shape), 2.0, axis=0)
    noise *= 0.5 / noise.std()                              # 0.5 cm per coordinate
    noisy = m.with_positions(m.positions + noise)
    rms_noise = np.sqrt((noise ** 2).sum(2).mean())
    for start, mm in (("original", noisy), ("identity", noisy.with_source(per_frame={}))):
        out = tmp_path / f"noisy_{start}.bvh"
        bvh.write(mm, out)
        r = bvh.read(out, units="cm")
        rms_vs_noisy = np.sqrt(((r.positions - noisy.positions) ** 2).sum(2).mean())
        rms_vs_clean = np.sqrt(((r.positions - m.positions) ** 2).sum(2).mean())
        assert rms_vs_noisy < 1.5 * rms_noise, start
        assert rms_vs_clean < 1.5 * rms_noise, start
        # bone lengths are the hierarchy's, whatever the noise (except Chest, whose
        # position channels let it follow its noisy target: the least-squares polish
        # trades some of that for its subtree's targets)
        keep = [b for b, (c, _) in enumerate(m.skeleton.bones()) if m.skeleton.names[c] != "Chest"]
        np.testing.assert_allclose(r.bone_lengths()[:, keep], m.bone_lengths()[:, keep], atol=1e-6)
        chest = m.skeleton.index("Chest")
        off = np.sqrt(((r.positions[:, chest] - noisy.positions[:, chest]) ** 2).sum(1).mean())
        assert off < 1.5 * rms_vs_noisy, (start, off, rms_vs_noisy)


def test_writer_refusals(synth_file, tmp_path):
    p, _ = synth_file
    m = bvh.read(p, units="cm")
    obs = np.ones((m.n_frames, m.n_joints), bool)
    obs[3, 2] = False
    with pytest.raises(MocapValueError, match="missing.*fill the gaps"):
        bvh.write(m.with_observed(obs), tmp_path / "gap.bvh")
    sub = m.select(["Hips", "LeftUpLeg", "LeftLeg", "Spine", "Chest", "Head"])
    with pytest.raises(MocapValueError, match="does not match the BVH hierarchy"):
        bvh.write(sub, tmp_path / "sub.bvh")
    bvh.write(sub, tmp_path / "sub.bvh", hierarchy="skeleton")        # new hierarchy: fine
    r = bvh.read(tmp_path / "sub.bvh", units="cm")
    # LeftUpLeg (under the dropped LHipJoint) and Spine turn apart under Hips: each hangs
    # from a zero-offset joint of its own, and the leg is held (Chest had position
    # channels, and Neck is dropped: two of the three bones between joints the motion
    # keeps cannot follow, 0.4-2.8 cm. The least-squares polish shares that out -- the
    # spine 1.1-1.3 cm off in a few frames -- and the whole is closer than the closed-form
    # IK alone, which holds the leg exactly and leaves all of it to the chest and head)
    assert [n for n in r.skeleton.names if not n.endswith("_base")] == list(sub.skeleton.names)
    assert {"LeftUpLeg_base", "Spine_base"} <= set(r.skeleton.names)
    leg = ["Hips", "LeftUpLeg", "LeftLeg", "Spine"]
    names = list(sub.skeleton.names)
    sq = float(((r.positions[:, [r.skeleton.index(n) for n in names]] - sub.positions) ** 2).sum())
    from mocapkit.io import _bvh_polish
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(_bvh_polish, "polish", lambda nodes, layout, ch, *a, **k: ch)
        bvh.write(sub, tmp_path / "sub_closed.bvh", hierarchy="skeleton")
    rc = bvh.read(tmp_path / "sub_closed.bvh", units="cm")
    np.testing.assert_allclose(rc.positions[:, [rc.skeleton.index(n) for n in leg]],
                               sub.positions[:, [sub.skeleton.index(n) for n in leg]], atol=1e-5)
    assert sq < float(((rc.positions[:, [rc.skeleton.index(n) for n in names]] - sub.positions) ** 2).sum())
    with pytest.raises(MocapValueError, match="refusing to overwrite the input"):
        mio.write(m, p, overwrite=True)
    assert not list(tmp_path.glob(".*.tmp"))                        # atomic: no leftovers


def test_write_from_plain_skeleton(synth_file, tmp_path):
    """A Motion with no BVH metadata (e.g. from C3D) but a tree skeleton."""
    p, _ = synth_file
    m = bvh.read(p, units="cm")
    plain = Motion(m.positions, m.skeleton, m.fps, None, {"format": "c3d"})
    out = tmp_path / "plain.bvh"
    bvh.write(plain, out)
    r = bvh.read(out, units="cm")
    assert r.skeleton.names == m.skeleton.names
    # joints outside the Chest subtree are reproduced exactly; Chest lost its position
    # channels (a new hierarchy has rotations only below the root), so its subtree is
    # off by at most the amplitude of those channels (3 cm) plus the resulting lever
    chest_tree = {"Chest", "Neck", "Head", "LeftArm", "LeftForeArm", "RightArm"}
    rest = [j for j, n in enumerate(m.skeleton.names) if n not in chest_tree]
    assert np.abs(r.positions[:, rest] - m.positions[:, rest]).max() < 1e-4
    assert np.abs(r.positions - m.positions).max() < 15.0
    txt = out.read_text()
    assert txt.count("CHANNELS 6") == 1 and txt.count("End Site") == 5
    markers = Skeleton(m.skeleton.names, -np.ones(m.n_joints, int), np.zeros((m.n_joints, 3)))
    with pytest.raises(MocapValueError, match="roots"):
        bvh.write(Motion(m.positions, markers, m.fps), tmp_path / "markers.bvh")


# --------------------------------------------------------------------------------------
# malformed files
# --------------------------------------------------------------------------------------
def _line_of(text, needle, nth=0):
    hits = [i + 1 for i, s in enumerate(text.splitlines()) if needle in s]
    return hits[nth]


def _mutations(text):
    lines = text.splitlines()
    motion = _line_of(text, "MOTION")
    first_frame = motion + 3
    frame5 = first_frame + 5

    def sub_line(i, new):
        ls = list(lines)
        ls[i - 1] = new
        return "\n".join(ls) + "\n"

    def drop_line(i):
        ls = list(lines)
        del ls[i - 1]
        return "\n".join(ls) + "\n"

    row = lines[frame5 - 1].split()
    C = len(row)
    return [
        ("truncated", "\n".join(lines[:-2]) + "\n", len(lines) - 2, r"truncated.*Frames: 40.*38"),
        ("short row", sub_line(frame5, " ".join(row[:-1])), frame5, rf"expected {C} channel values.*found {C - 1}"),
        ("long row", sub_line(frame5, " ".join(row + ["1.0"])), frame5, rf"expected {C} channel values.*found {C + 1}"),
        ("nan", sub_line(frame5, " ".join(["nan"] + row[1:])), frame5, "'nan'.*finite"),
        ("inf", sub_line(frame5, " ".join(row[:3] + ["-inf"] + row[4:])), frame5, "'-inf'.*finite"),
        ("garbage", sub_line(frame5, " ".join(row[:2] + ["1.2.3"] + row[3:])), frame5, "number.*'1.2.3'"),
        ("unknown keyword", sub_line(4, "  OFFSETS 0 0 0"), 4, "unknown keyword 'OFFSETS'"),
        ("frames 0", sub_line(motion + 1, "Frames: 0"), motion + 1, "Frames: 0"),
        ("no motion", "\n".join(lines[:motion - 1]) + "\n", motion - 1, "missing MOTION"),
        ("duplicate", sub_line(_line_of(text, "JOINT RightArm"), "  JOINT LeftArm"),
         _line_of(text, "JOINT RightArm"), "duplicate joint name 'LeftArm'"),
        ("missing close brace", drop_line(motion - 1), motion - 1, "unbalanced braces"),
        ("extra close brace", sub_line(motion, "}\nMOTION"), motion, "unbalanced braces"),
        ("unknown channel", sub_line(5, "  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Wrotation"),
         5, "unknown channel 'Wrotation'"),
        ("bad channel count", sub_line(5, "  CHANNELS six Xposition"), 5, "CHANNELS count"),
        ("offset garbage", sub_line(4, "  OFFSET 0 zero 0"), 4, "OFFSET number.*'zero'"),
        ("extra frames", text + " ".join(row) + "\n", len(lines) + 1, "more frame lines"),
        ("frame time", sub_line(motion + 2, "Frame Time: -0.01"), motion + 2, "outside the supported range"),
        ("no frame time", sub_line(motion + 2, "Frame Tim: 0.01"), motion + 2, "Frame Time"),
        ("not bvh", "hello world\n", 1, "HIERARCHY"),
        ("empty", "", 1, "empty file"),
    ]


def test_malformed_files_name_the_line(tmp_path):
    text = synth_text(synth_channels())
    for name, bad, line, msg in _mutations(text):
        p = tmp_path / f"{name.replace(' ', '_')}.bvh"
        p.write_text(bad)
        with pytest.raises(MocapFormatError) as ei:
            mio.read(p)
        e = ei.value
        assert e.line == line, (name, e)
        assert re.search(msg, e.message), (name, e.message)
        assert str(p) in str(e)


@pytest.mark.parametrize("value,msg", [
    ("1e-300", "outside the supported range 0.0001 .. 10 s"),      # fps 1e300 (issue 18)
    ("0", "outside the supported range"), ("-0", "outside the supported range"),
    ("-0.0083333", "outside the supported range"), ("0.00009", "outside the supported range"),
    ("10.5", "outside the supported range"), ("1e300", "outside the supported range"),
    ("inf", "only finite numbers"), ("-inf", "only finite numbers"), ("nan", "only finite numbers")])
def test_absurd_frame_time_is_refused_with_the_line(tmp_path, value, msg):
    """Frame Time outside 1e-4 .. 10 s per frame: one MocapFormatError naming file and line."""
    text = synth_text(synth_channels())
    lines = text.splitlines()
    k = next(i for i, s in enumerate(lines) if s.startswith("Frame Time:"))
    lines[k] = f"Frame Time: {value}"
    p = tmp_path / "ft.bvh"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(MocapFormatError) as ei:
        mio.read(p)
    assert ei.value.line == k + 1 and str(p) in str(ei.value)
    assert re.search(msg, ei.value.message), ei.value.message


@pytest.mark.parametrize("value", ["0.0001", "10", "0.0083333", "0.033333"])
def test_frame_time_range_bounds_are_accepted(tmp_path, value):
    p = tmp_path / "ok.bvh"
    p.write_text(synth_text(synth_channels(), frame_time=value))
    assert mio.read(p).fps == pytest.approx(1 / float(value))
    assert bvh.FRAME_TIME_RANGE == (1e-4, 10.0)


def test_writer_refuses_a_frame_rate_the_reader_would_refuse(tmp_path):
    sk = Skeleton(("a", "b"), [-1, 0], np.array([[0, 0, 0], [0, 10.0, 0]]))
    P = np.tile(np.array([[0.0, 90, 0], [0, 100, 0]]), (3, 1, 1))
    with pytest.raises(MocapValueError, match="outside"):
        bvh.write(Motion(P, sk, 1e6), tmp_path / "fast.bvh")
    bvh.write(Motion(P, sk, 120.0), tmp_path / "ok.bvh")
    assert mio.read(tmp_path / "ok.bvh").fps == pytest.approx(120.0)


def test_binary_garbage_is_a_format_error(tmp_path):
    p = tmp_path / "bin.bvh"
    p.write_bytes(b"HIERARCHY\x00\x01\x02\xff")
    with pytest.raises(MocapFormatError):
        mio.read(p)


# --------------------------------------------------------------------------------------
# real data
# --------------------------------------------------------------------------------------
def _standing_height(m: Motion) -> float:
    """90th percentile over frames of the vertical (Y) extent, End Sites included (cm)."""
    P = m.positions
    return float(np.percentile(P[..., 1].max(1) - P[..., 1].min(1), 90))


def test_every_shared_bvh_reads(shared_data):
    files = sorted((shared_data / "cmu" / "bvh").rglob("*.bvh"))
    assert len(files) >= 19
    for f in files:
        m = bvh.read(f, end_sites=True)
        assert m.observed.all() and np.isfinite(m.positions).all()
        unit = m.source["units"]["name"]
        assert unit == ("cmu" if "cgspeed" in str(f) else "cm"), (f, unit)
        h = _standing_height(m)
        # CMU units (DESIGN.md) make subjects 131 and 02 ~140-145 cm (their ASF says so too)
        assert 135 <= h <= 200, (f.name, h)
        assert m.source["per_frame"]["channels"].shape[0] == m.n_frames


def test_real_round_trip_and_pybvh(shared_data, tmp_path):
    import pybvh

    f = shared_data / "cmu" / "bvh" / "cgspeed_motionbuilder" / "02_01.bvh"
    m = bvh.read(f)
    out = tmp_path / "02_01_rt.bvh"
    bvh.write(m, out)
    m2 = bvh.read(out)
    assert m2.source["units"]["name"] == "cmu"
    assert np.abs(m2.positions - m.positions).max() < 1e-6
    # an independent parser/FK agrees with ours on our written file
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b = pybvh.read_bvh_file(out)
    jp = b.joint_positions() * m.source["units"]["factor_to_cm"]
    assert jp.shape == m.positions.shape
    assert np.abs(jp - m2.positions).max() < 0.5
    # and on the original file
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b0 = pybvh.read_bvh_file(f)
    assert np.abs(b0.joint_positions() * m.source["units"]["factor_to_cm"] - m.positions).max() < 0.5


def test_real_ik_from_identity(shared_data, tmp_path):
    f = shared_data / "cmu" / "bvh" / "motionbuilder75" / "16_15.bvh"
    m = bvh.read(f).slice(0, 120)
    out = tmp_path / "16_15_ik.bvh"
    bvh.write(m.with_source(per_frame={}), out)
    assert np.abs(bvh.read(out).positions - m.positions).max() < 1e-4


def test_motionbuilder_bvh_is_cmu_units_in_cm(shared_data):
    """MB 7.5's 16_15.bvh root = 5.6444 x the AMC root (cm), the DESIGN's CMU unit."""
    m = bvh.read(shared_data / "cmu" / "bvh" / "motionbuilder75" / "16_15.bvh")
    amc = (shared_data / "cmu" / "asfamc" / "16" / "16_15.amc").read_text().splitlines()
    root = [ln for ln in amc if ln.startswith("root ")][:2]
    amc_root = np.array([[float(v) for v in ln.split()[1:4]] for ln in root])
    np.testing.assert_allclose(m.positions[:2, 0], amc_root * 2.54 / 0.45, rtol=2e-4)


def test_a_bvh_t_pose_first_frame_is_the_reference_every_method_keeps(shared_data, tmp_path):
    """cgspeed's and Daz's first frame is a T-pose (cgspeed: the joint angles zero; Daz: the
    rest pose): found, not in other files nor after a slice; corrupt leaves it alone, every
    method writes it as read, a corrupted file written back keeps it recognisable, and the
    classifier's input leaves it out."""
    from mocapkit import corrupt
    from mocapkit.denoise import get
    from mocapkit.denoise.bases import reference_frames

    root = shared_data / "cmu" / "bvh"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cg = bvh.read(root / "cgspeed_motionbuilder" / "01_01.bvh").slice(0, 200)
        daz = bvh.read(root / "daz_friendly" / "10_03.bvh").slice(0, 200)
        plain = [bvh.read(root / "cgspeed_3dsmax" / "131_01.bvh"), bvh.read(root / "motionbuilder75" / "16_15.bvh")]
    # Daz: the T-pose and the converter's blend out of it (frames 1-4, 14-22 cm a frame)
    assert reference_frames(cg) == 1 and reference_frames(daz) == 5
    assert [reference_frames(m) for m in plain] == [0, 0] and reference_frames(cg.slice(1, None)) == 0
    dn, dmask = corrupt.combine(daz, "gaussian:sigma_cm=3", seed=0)
    assert np.array_equal(dn.positions[:5], daz.positions[:5]) and not dmask[:5].any() and dmask[5:].all()
    noisy, mask = corrupt.combine(cg, "gaussian:sigma_cm=1,outliers:ratio=0.1,magnitude_cm=15", seed=0)
    assert np.array_equal(noisy.positions[0], cg.positions[0]) and not mask[0].any() and mask[1:].any()
    for name in ("auto", "kalman-cv", "median"):
        out = get(name).denoise(noisy)
        assert np.array_equal(out.positions[0], cg.positions[0]), name
    # the method sees the motion's first frame in its place: the clean take's frame 1 stays
    # (kalman-cv had smoothed it 22 cm towards the T-pose)
    assert np.abs(get("kalman-cv").denoise(cg).positions[1:3] - cg.positions[1:3]).max() < 0.5
    out = get("auto").denoise(noisy)
    assert out.source["reference_frames"] == 1 and "jumps" not in out.source["auto"]
    # the T-pose arms are no spikes: the motion after it was cleaned as the rest of the clip
    e = np.linalg.norm(out.positions - cg.positions, axis=2)
    assert e[1:4].max() < 8.0 and e.max() < 10.0
    mio.write(noisy, tmp_path / "n.bvh")
    assert reference_frames(bvh.read(tmp_path / "n.bvh")) == 1
    from mocapkit.recognition.rocket import trajectories     # nor is it part of an action

    assert np.array_equal(trajectories(daz, 32), trajectories(daz.slice(5, None), 32))


def test_writing_a_skeleton_bvh_holds_amc_or_says_how_far_off(tmp_path):
    """ASF/AMC turns the bones that share a start point (CMU thorax -> lower neck and both
    clavicles) separately; a BVH joint turns its children together: the writer gives each
    such bone a zero-offset joint and holds the positions; a BVH read back and written
    again is held too; positions no pose reaches get one warning saying how far off."""
    from mocapkit.datasets import bundled
    from mocapkit.errors import MocapWarning

    amc = mio.read(bundled("16_15.amc")).slice(0, 40)
    with warnings.catch_warnings():
        warnings.simplefilter("error", MocapWarning)
        mio.write(amc, tmp_path / "a.bvh")               # zero-offset joints: held exactly
    back = mio.read(tmp_path / "a.bvh")
    keep = [back.skeleton.index(n) for n in amc.skeleton.names]
    assert back.n_joints > amc.n_joints and "lowerneck_base" in back.skeleton.names
    assert float(np.abs(back.positions[:, keep] - amc.positions).max()) < 1e-5
    with warnings.catch_warnings():
        warnings.simplefilter("error", MocapWarning)
        mio.write(back, tmp_path / "b.bvh")
    # the guard behind it: written joints off the motion's positions by more than their
    # bone lengths explain make one line saying how far (a head 1 cm sideways of its bone
    # keeps its length to 0.02 cm)
    P = amc.positions.copy()
    h = amc.skeleton.index("head")
    frames = np.arange(amc.n_frames)
    assert bvh._unreachable(amc, frames, P) is None
    P[:, h] += np.cross(amc.positions[:, h] - amc.positions[:, amc.skeleton.parents[h]], [0.0, 1.0, 0.0])
    P[:, h] = amc.positions[:, h] + (P[:, h] - amc.positions[:, h]) / np.linalg.norm(
        P[:, h] - amc.positions[:, h], axis=1, keepdims=True)
    assert re.search(r"only to .* cm mean, 1\.00 cm at most \(head", bvh._unreachable(amc, frames, P))


def test_noisy_positions_are_written_as_the_least_squares_pose(tmp_path, monkeypatch):
    """White noise on every joint of a CMU clip written to BVH (the hierarchy the writer
    builds, zero-offset ``_base`` joints included): the polish (:mod:`mocapkit.io._bvh_polish`)
    fits all of a frame's channels to all of its targets, so the file is nearer the given
    positions than the closed-form IK alone, which points each bone from where its parent
    was put and passes the error down the chains -- and nearer the truth than the noise
    (1 cm: 0.70 against 1.00). Positions the hierarchy holds are written exactly either way."""
    from mocapkit import corrupt, io
    from mocapkit.datasets import bundled
    from mocapkit.io import _bvh_polish

    clean = io.read(bundled("16_15.amc")).slice(2, 122)
    truth = io.read(io.write(clean, tmp_path / "clean.bvh"))
    noisy, _ = corrupt.combine(truth, [("gaussian", {"sigma_cm": 1.0})], seed=0)

    def rms(a, b):
        return float(np.sqrt(np.mean((a.positions - b.positions) ** 2)))
    polished = io.read(io.write(noisy, tmp_path / "polished.bvh"))
    assert np.abs(io.read(io.write(truth, tmp_path / "again.bvh")).positions - truth.positions).max() < 1e-4
    monkeypatch.setattr(_bvh_polish, "polish", lambda nodes, layout, ch, *a, **k: ch)
    closed = io.read(io.write(noisy, tmp_path / "closed.bvh"))
    assert rms(polished, noisy) < 0.9 * rms(closed, noisy)
    assert rms(polished, truth) < 0.8 < rms(closed, truth)
