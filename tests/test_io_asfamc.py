"""ASF/AMC reader and writer: hand-computed FK, skeleton lookup, round trips, IK, malformed input.

Uses the bundled CMU clips (mocapkit/data), so it runs without ../shared/data.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from mocapkit import io
from mocapkit.datasets import bundled
from mocapkit.errors import MocapFormatError, MocapValueError
from mocapkit.io import _kinematics as kin
from mocapkit.io import _rotations as rot
from mocapkit.io import amc as amc_io
from mocapkit.io import asf as asf_io
from mocapkit.io import bvh as bvh_io

CM = 2.54 / 0.45          # cm per CMU length unit


@pytest.fixture(scope="module")
def walk():
    return io.read(bundled("16_15.amc"))


@pytest.fixture
def pair(tmp_path):
    """A writable copy of the bundled 16.asf + 16_15.amc (text lines of the AMC returned too)."""
    asf = tmp_path / "16.asf"
    amc = tmp_path / "16_15.amc"
    shutil.copy(bundled("16.asf"), asf)
    shutil.copy(bundled("16_15.amc"), amc)
    return asf, amc, amc.read_text().splitlines()


# ------------------------------------------------------------------------------------
# a tiny hand-made skeleton: FK by hand
# ------------------------------------------------------------------------------------
TINY_ASF = """:version 1.10
:name tiny
:units
  mass 1.0
  length 0.45
  angle deg
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name up
     direction 0 1 0
     length 2
     axis 0 0 0 XYZ
    dof rx ry rz
    limits (-180 180)
           (-180 180)
           (-180 180)
  end
  begin
     id 2
     name fore
     direction 0 1 0
     length 1
     axis 0 0 90 XYZ
    dof rx
    limits (-180 180)
  end
  begin
     id 3
     name side
     direction 1 0 0
     length 1
     axis 0 0 0 XYZ
  end
:hierarchy
  begin
    root up side
    up fore
  end
"""


def _tiny(tmp_path, frames: str) -> Path:
    (tmp_path / "tiny.asf").write_text(TINY_ASF)
    p = tmp_path / "tiny_01.amc"
    p.write_text(":FULLY-SPECIFIED\n:DEGREES\n" + frames)
    return p


def test_fk_by_hand(tmp_path):
    # frame 1: rest pose at translation (1, 2, 3)
    # frame 2: root rz = 90 (x -> y, y -> -x); 'up' rx = 0; 'fore' rx = 90 about its C axis:
    #   C = Rz(90) maps local x to global y, so M = Rx(90) acts about global y (in the
    #   root frame): L_fore = Rz90 . (Rz90 Rx90 Rz90^-1) = Rz90 . Ry90.
    #   Ry90 (0,1,0) = (0,1,0) -> bone 'fore' (0,1,0) unchanged by its own rotation, then
    #   Rz90 -> (-1, 0, 0).
    # frame 3: 'up' rz = 90 (fore follows), 'fore' rx = 0.
    p = _tiny(tmp_path, "1\nroot 1 2 3 0 0 0\nup 0 0 0\nfore 0\n"
                        "2\nroot 0 0 0 0 0 90\nup 0 0 0\nfore 90\n"
                        "3\nroot 0 0 0 0 0 0\nup 0 0 90\nfore 0\n")
    m = io.read(p)
    assert m.skeleton.names == ("root", "up", "fore", "side")
    assert list(m.skeleton.parents) == [-1, 0, 1, 0]
    P = m.positions / CM
    np.testing.assert_allclose(P[0], [[1, 2, 3], [1, 4, 3], [1, 5, 3], [2, 2, 3]], atol=1e-12)
    np.testing.assert_allclose(P[1], [[0, 0, 0], [-2, 0, 0], [-3, 0, 0], [0, 1, 0]], atol=1e-12)
    np.testing.assert_allclose(P[2], [[0, 0, 0], [-2, 0, 0], [-3, 0, 0], [1, 0, 0]], atol=1e-12)


def test_fk_bone_axis_and_hinge_by_hand(tmp_path):
    """'fore' has axis (0, 0, 90), so C = Rz90 and its rx dof turns about C·x = y.

    'fore' rx = 90 alone: L_fore = C Rx90 C^-1 = Ry90, and Ry90 leaves the bone direction
    y unchanged: fore ends at (0, 3, 0). With 'up' rx = 90 too: L_up = Rx90 (y -> z), so
    up ends at (0, 0, 2) and L_fore = Rx90 Ry90; Ry90 y = y, Rx90 y = z: fore ends at (0, 0, 3).
    """
    p = _tiny(tmp_path, "1\nroot 0 0 0 0 0 0\nup 0 0 0\nfore 90\n"
                        "2\nroot 0 0 0 0 0 0\nup 90 0 0\nfore 90\n")
    P = io.read(p).positions / CM
    np.testing.assert_allclose(P[0, 2], [0, 3, 0], atol=1e-12)
    np.testing.assert_allclose(P[1, 1], [0, 0, 2], atol=1e-12)
    np.testing.assert_allclose(P[1, 2], [0, 0, 3], atol=1e-12)


def test_fk_hinge_axis_matters(tmp_path):
    """A hinge whose rotation axis is not along the bone: 'up' rz = 90 and 'fore' rx = 90.

    L_up = Rz90; L_fore = Rz90 · Ry90. Ry90 y = y, so fore stays along up's direction:
    up ends at Rz90 (0, 2, 0) = (-2, 0, 0), fore at (-3, 0, 0). With 'fore' axis (0,0,0)
    instead (hinge about x), Rz90 Rx90 y = Rz90 z = z: fore would end at (-2, 0, 1).
    """
    p = _tiny(tmp_path, "1\nroot 0 0 0 0 0 0\nup 0 0 90\nfore 90\n")
    np.testing.assert_allclose(io.read(p).positions[0, 2] / CM, [-3, 0, 0], atol=1e-12)
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "tiny.asf").write_text(TINY_ASF.replace("axis 0 0 90 XYZ", "axis 0 0 0 XYZ"))
    q = tmp_path / "b" / "tiny_01.amc"
    q.write_text(":FULLY-SPECIFIED\n:DEGREES\n1\nroot 0 0 0 0 0 0\nup 0 0 90\nfore 90\n")
    np.testing.assert_allclose(io.read(q).positions[0, 2] / CM, [-2, 0, 1], atol=1e-12)


def test_cmu_units_and_offsets(walk):
    asf = walk.source["asf"]
    assert walk.source["units"]["cm_per_unit"] == pytest.approx(5.644444, abs=1e-6)
    b = next(x for x in asf["bones"] if x["name"] == "lfemur")
    np.testing.assert_allclose(walk.skeleton.offsets[walk.skeleton.index("lfemur")],
                               np.array(b["direction"]) * b["length"] * CM)
    assert walk.n_frames == 471 and walk.n_joints == 31 and walk.fps == 120
    assert walk.source["per_frame"]["dofs"].shape == (471, 62)
    # first root line of 16_15.amc: 1.22935 17.2598 -26.9208 (CMU units)
    np.testing.assert_allclose(walk.positions[0, 0], np.array([1.22935, 17.2598, -26.9208]) * CM)
    assert 150 < walk.height() < 200


@pytest.mark.parametrize("name,cm", [("cmu", 2.54 / 0.45), ("CMU", 2.54 / 0.45), ("in", 2.54),
                                     ("inches", 2.54), ("centimetre", 1.0), ("mm", 0.1), ("m", 100.0)])
def test_units_option_takes_the_bvh_unit_names(name, cm):
    """``units=`` of the AMC reader takes the unit names of the BVH reader (one table)."""
    walk1 = io.read(bundled("16_15.amc"), units=name).slice(0, 1)
    bvh_factor = bvh_io._resolve_units(name, [], "x.bvh")["factor_to_cm"]
    assert walk1.source["units"]["cm_per_unit"] == bvh_factor == pytest.approx(cm, rel=1e-15)
    np.testing.assert_allclose(walk1.positions[0, 0], np.array([1.22935, 17.2598, -26.9208]) * cm)


def test_units_option_unknown_name():
    with pytest.raises(MocapValueError, match=r"one of cm, mm, m, inch, cmu, got 'furlong'"):
        io.read(bundled("16_15.amc"), units="furlong")


def test_asf_rest_pose_motion():
    m = io.read(bundled("16.asf"))
    assert m.n_frames == 1 and m.n_joints == 31
    np.testing.assert_allclose(m.positions[0], m.skeleton.rest_positions(), atol=1e-9)
    assert 140 < np.ptp(m.positions[0, :, 1]) < 200         # head to toes, Y up


# ------------------------------------------------------------------------------------
# skeleton lookup
# ------------------------------------------------------------------------------------
def test_lookup_cmu_and_hdm05_layouts(tmp_path):
    src_asf = bundled("16.asf")
    src_amc = bundled("16_15.amc")
    # CMU: 05/05.asf for 05/05_04.amc (prefix in the same folder), beside a decoy
    d = tmp_path / "05"
    d.mkdir()
    shutil.copy(src_asf, d / "05.asf")
    shutil.copy(src_asf, d / "0.asf")                 # shorter prefix: loses to 05.asf
    shutil.copy(src_amc, d / "05_04.amc")
    assert asf_io.find_skeleton(d / "05_04.amc") == d / "05.asf"
    # HDM05: HDM_bd.asf one folder up from hopBothLegs1hops/HDM_bd_....amc
    h = tmp_path / "hdm"
    (h / "hopBothLegs1hops").mkdir(parents=True)
    shutil.copy(src_asf, h / "HDM_bd.asf")
    shutil.copy(src_asf, h / "HDM_mm.asf")
    amc = h / "hopBothLegs1hops" / "HDM_bd_hopBothLegs1hops_001_120.amc"
    shutil.copy(src_amc, amc)
    assert asf_io.find_skeleton(amc) == h / "HDM_bd.asf"
    assert io.read(amc).n_frames == 471
    # the only .asf in the AMC's folder
    o = tmp_path / "only"
    o.mkdir()
    shutil.copy(src_asf, o / "subject.asf")
    shutil.copy(src_amc, o / "clip.amc")
    assert asf_io.find_skeleton(o / "clip.amc") == o / "subject.asf"
    # explicit skeleton=
    assert io.read(o / "clip.amc", skeleton=o / "subject.asf").n_joints == 31


def test_lookup_errors(tmp_path):
    shutil.copy(bundled("16_15.amc"), tmp_path / "clip.amc")
    with pytest.raises(MocapFormatError, match="no .asf skeleton found"):
        io.read(tmp_path / "clip.amc")
    shutil.copy(bundled("16.asf"), tmp_path / "a.asf")
    shutil.copy(bundled("16.asf"), tmp_path / "b.asf")
    with pytest.raises(MocapFormatError, match="cannot tell which skeleton"):
        io.read(tmp_path / "clip.amc")
    with pytest.raises(MocapFormatError, match="skeleton file not found"):
        io.read(tmp_path / "clip.amc", skeleton=tmp_path / "nope.asf")


# ------------------------------------------------------------------------------------
# round trips
# ------------------------------------------------------------------------------------
def test_amc_write_read_identical(walk, tmp_path):
    out = tmp_path / "copy.amc"
    io.write(walk, out)
    assert (tmp_path / "copy.asf").exists()               # companion skeleton written
    back = io.read(out)
    assert np.array_equal(back.source["per_frame"]["dofs"], walk.source["per_frame"]["dofs"])
    assert np.array_equal(back.positions, walk.positions)
    assert back.skeleton == walk.skeleton
    # a second AMC in the same folder finds copy.asf (identical skeleton): no new ASF
    io.write(walk.slice(10, 20), tmp_path / "copy_part.amc")
    assert not (tmp_path / "copy_part.asf").exists()
    part = io.read(tmp_path / "copy_part.amc")
    assert np.array_equal(part.positions, walk.positions[10:20])


def test_amc_keeps_its_frame_rate_through_a_header_comment(walk, tmp_path):
    """AMC stores no frame rate: the writer adds '# fps N', the reader takes it (120 Hz
    without it, or what ``fps=`` says)."""
    half = walk.slice(0, 40).resample(30.0)
    out = io.write(half, tmp_path / "w30.amc")
    assert "# fps 30" in out.read_text().splitlines()[:4]
    assert io.read(out).fps == 30.0
    assert amc_io.read(out, fps=60.0).fps == 60.0
    assert io.read(out.with_name("w30.amc")).n_frames == half.n_frames
    assert walk.fps == 120.0                              # CMU files: no comment, 120 Hz


def test_asf_writer_round_trip(walk, tmp_path):
    p = asf_io.write_asf(walk.source["asf"], tmp_path / "w.asf")
    again = asf_io.read_asf(p)
    assert asf_io._same_skeleton(again, walk.source["asf"])
    assert again["bones"][1]["limits"] == walk.source["asf"]["bones"][1]["limits"]


def test_writer_refuses_input_and_non_amc(walk, tmp_path):
    with pytest.raises(MocapValueError, match="input file"):
        io.write(walk, walk.source["path"])
    bare = walk.with_source(asf=None)
    with pytest.raises(MocapValueError, match="ASF/AMC"):
        io.write(bare, tmp_path / "x.amc")
    with pytest.raises(MocapValueError, match="do not match"):
        io.write(walk.select(["root", "lfemur", "ltibia"]), tmp_path / "y.amc")


def test_ik_recovers_perturbed_dofs(walk, tmp_path):
    """Positions from FK of perturbed dofs (2 degrees on every angle) are re-found by IK."""
    comp = kin._Compiled(walk.source["asf"])
    D = walk.source["per_frame"]["dofs"]
    rng = np.random.default_rng(0)
    D1 = D + rng.normal(0, 2.0, D.shape) * (np.arange(D.shape[1]) >= 3)
    P1 = kin.forward_kinematics(comp, D1, False, CM)[:60]
    moved = walk.slice(0, 60).with_positions(P1)          # stored dofs (unperturbed) kept
    io.write(moved, tmp_path / "ik.amc")
    back = io.read(tmp_path / "ik.amc")
    err = np.linalg.norm(back.positions - P1, axis=2)
    assert err.max() < 0.01 and err.mean() < 1e-3          # measured 2.4e-4 / 3.6e-7 cm
    # bone lengths are those of the skeleton, exactly
    np.testing.assert_allclose(back.bone_lengths(), walk.bone_lengths()[:60], atol=1e-9)


def _dense_ik_jacobian(comp, P, W, usable, angle_rad):
    """Reference transposed Jacobian d positions / d dofs (T, D, 3J) built entry by entry:
    a rotational dof moves each joint of its subtree by ``w x (p_j - pivot)``, a root
    translation moves every joint along its axis; rows of unusable targets are zero."""
    T, J = P.shape[0], P.shape[1]
    scale = 1.0 if angle_rad else np.pi / 180.0
    Jt = np.zeros((T, comp.n_dofs, J, 3))
    trans = dict(comp.fk_trans)
    for d in range(comp.n_dofs):
        if d in trans:
            Jt[:, d, :, trans[d]] = usable
            continue
        for j in np.flatnonzero(comp.dof_subtree[d] > 0):
            Jt[:, d, j] = np.cross(W[:, d], P[:, j] - P[:, comp.dof_pivot[d]]) * (usable[:, j] * scale)[:, None]
    return Jt.reshape(T, comp.n_dofs, 3 * J)


def test_ik_jacobian_matches_finite_differences(walk):
    """The Jacobian the LM normal equations stand for (world dof axes from the level-batched
    FK, ``w x (p_j - pivot)`` over ``dof_subtree``, root translations) equals central
    differences of the FK, with the rows of unusable targets zero."""
    comp = kin._Compiled(walk.source["asf"])
    D = np.asarray(walk.source["per_frame"]["dofs"], float)[::50][:6]
    P, W = kin._fk_block(comp, D, False, axes=True)
    P, W = np.transpose(P, (2, 1, 0)), np.transpose(W, (2, 1, 0))
    usable = np.ones(P.shape[:2], bool)
    usable[1, 5] = False
    Jt = _dense_ik_jacobian(comp, P, W, usable, False)               # (T, D, 3J)
    h = 1e-4
    for c in range(comp.n_dofs):
        e = np.zeros(comp.n_dofs)
        e[c] = h
        fd = (kin.forward_kinematics(comp, D + e, False, 1.0) - kin.forward_kinematics(comp, D - e, False, 1.0)) / (2 * h)
        fd[~usable] = 0.0
        np.testing.assert_allclose(Jt[:, c], fd.reshape(len(D), -1), atol=1e-6, err_msg=comp.dof_names[c])


@pytest.mark.parametrize("angle_rad", [False, True])
def test_ik_normal_equations_match_dense_jacobian(walk, angle_rad):
    """The LM normal equations from subtree moments (no Jacobian) equal Jt Jt^T and Jt r of
    the dense Jacobian, with unusable targets, far from the origin, in both angle units."""
    comp = kin._Compiled(walk.source["asf"])
    D = np.asarray(walk.source["per_frame"]["dofs"], float)[::40][:7]
    if angle_rad:
        D = D.copy()
        D[:, 3:] = np.deg2rad(D[:, 3:])
        D[:, :3] += np.array([300.0, -50.0, 800.0])          # far from the origin
    P, W = kin._fk_block(comp, D, angle_rad, axes=True)
    P, W = np.transpose(P, (2, 1, 0)), np.transpose(W, (2, 1, 0))
    rng = np.random.default_rng(7)
    usable = rng.random(P.shape[:2]) > 0.15
    usable[0] = True
    r = rng.normal(size=P.shape) * usable[..., None]
    Jt = _dense_ik_jacobian(comp, P, W, usable, angle_rad)
    A_ref, g_ref = Jt @ np.swapaxes(Jt, 1, 2), (Jt @ r.reshape(len(D), -1, 1))[..., 0]
    work = (np.full((9, comp.n_dofs, comp.n_dofs), np.nan), np.full((9, comp.n_dofs, comp.n_dofs), np.nan))
    for wk in (None, work):
        A, g = kin._ik_normal_equations(comp, P, W, usable, r, angle_rad, wk)
        scale = np.abs(A_ref).max()
        np.testing.assert_allclose(A, A_ref, rtol=0, atol=1e-11 * scale)
        np.testing.assert_allclose(g, g_ref, rtol=0, atol=1e-11 * np.abs(g_ref).max())
        assert np.count_nonzero(A_ref == 0) and np.all(A[A_ref == 0] == 0)   # disjoint subtrees: exact 0


def test_fk_block_matches_per_bone_reference(walk):
    """The level-batched FK (F = L C frames, one product per bone) and the all-nodes local
    rotations equal a plain per-bone loop of L_b = L_p C_b M_b C_b^T, end_b = end_p + L_b v_b."""
    comp = kin._Compiled(walk.source["asf"])
    D = np.asarray(walk.source["per_frame"]["dofs"], float)[::30][:8]
    P, _ = kin._fk_block(comp, D, False)
    T = len(D)
    loc = kin._local_rotations(comp, D, False)                          # (T, J, 3, 3)
    tr, ang = comp.root_split(D, False)
    Cr = comp.C_root
    L = {"root": Cr @ kin._euler_matrix(comp.root_axis, ang) @ Cr.T}
    np.testing.assert_allclose(loc[:, 0], L["root"], atol=1e-13)
    end = {"root": tr}
    for j, n in enumerate(comp.bone_order, start=1):
        a = np.zeros((T, 3))
        a[:, comp.dof_axes[n]] = np.deg2rad(D[:, comp.dof_cols[n]])
        Mloc = comp.C[n] @ kin._euler_matrix(comp.order[n], a) @ comp.C[n].T
        np.testing.assert_allclose(loc[:, j], Mloc, atol=1e-13, err_msg=n)
        L[n] = L[comp.parent[n]] @ Mloc
        end[n] = end[comp.parent[n]] + L[n] @ comp.vec[n]
        np.testing.assert_allclose(P[:, j].T, end[n], atol=1e-11, err_msg=n)


def test_fast_rotation_helpers_match_matrix_products():
    """The component / (3T, 3)-product helpers of the IK pass equal plain 3x3 matmuls."""
    rng = np.random.default_rng(11)
    T = 25
    R = rot.euler_to_matrix([2, 0, 1], rng.uniform(-3, 3, (T, 3)))
    Lp = rot.euler_to_matrix([0, 1, 2], rng.uniform(-3, 3, (T, 3)))
    C = rot.euler_to_matrix([1, 2, 0], rng.uniform(-3, 3, 3))
    np.testing.assert_allclose(kin._conj_t(C, R), C.T @ R @ C, atol=1e-14)
    v = rng.normal(size=3)
    np.testing.assert_allclose(kin._mv(R, v), np.einsum("tij,j->ti", R, v), atol=1e-14)
    for order, axes in (("XYZ", [0, 2]), ("ZYX", [1]), ("YZX", [0, 1, 2])):
        ang = np.zeros((T, 3))
        ang[:, axes] = rng.uniform(-3, 3, (T, len(axes)))
        ref = Lp @ C @ kin._euler_matrix(order, ang) @ C.T
        np.testing.assert_allclose(kin._compose_local(Lp, C, order, axes, ang), ref, atol=1e-14)
    U, W = rng.normal(size=(T, 4, 3)), rng.normal(size=(T, 4, 3))
    x = rng.uniform(-3, 3, (T, 2))
    for p, q in ((0, 1), (2, 0), (1, 2)):
        Z = np.einsum("tij,tnj->tni", rot.axis_rotation(q, x[:, 1]) @ rot.axis_rotation(p, x[:, 0]), U)
        np.testing.assert_allclose(kin._two_dof_cost(p, q, U, W, x), np.sum((Z - W) ** 2, axis=(1, 2)), rtol=1e-12)
    # the twist angle: the projection formula it replaces, with and without regularisation
    ax, _ = rot.normalize(rng.normal(size=(T, 3)))
    a = ax[:, None, :]
    Up, Wp = U - np.sum(U * a, -1, keepdims=True) * a, W - np.sum(W * a, -1, keepdims=True) * a
    for reg in (0.0, 2.5):
        ref = np.arctan2(np.sum(np.cross(Up, Wp) * a, axis=(1, 2)), np.sum(Up * Wp, axis=(1, 2)) + reg)
        np.testing.assert_allclose(rot.twist_angle(ax, U, W, reg=reg), ref, atol=1e-12)


def test_fk_blocks_join_seamlessly(walk, monkeypatch):
    """FK in blocks of frames gives the same positions as one block."""
    comp = kin._Compiled(walk.source["asf"])
    D = walk.source["per_frame"]["dofs"]
    whole = kin.forward_kinematics(comp, D, False, CM)
    from mocapkit import windows

    monkeypatch.setattr(windows, "FRAME_BLOCK", 37)
    np.testing.assert_array_equal(kin.forward_kinematics(comp, D, False, CM), whole)


def test_ik_without_stored_dofs(walk):
    """No stored dofs (e.g. after resampling): IK from the rest pose still fits clean positions."""
    comp = kin._Compiled(walk.source["asf"])
    P = walk.positions[:60]
    out = kin.inverse_kinematics(comp, P, CM, False, None)
    err = np.linalg.norm(kin.forward_kinematics(comp, out, False, CM) - P, axis=2)
    assert err.max() < 0.5 and err.mean() < 0.03           # measured 0.12 / 0.006 cm


def test_ik_noisy_positions_projects_onto_skeleton(walk, tmp_path):
    rng = np.random.default_rng(1)
    clean = walk.slice(0, 60)
    noisy = clean.positions + rng.normal(0, 1.0, clean.positions.shape)
    io.write(clean.with_positions(noisy), tmp_path / "noisy.amc")
    back = io.read(tmp_path / "noisy.amc")
    rms_noisy = np.sqrt(np.mean((back.positions - noisy) ** 2))
    rms_clean = np.sqrt(np.mean((back.positions - clean.positions) ** 2))
    assert rms_noisy < 1.0          # least-squares fit: closer to the targets than the noise
    assert rms_clean < 1.0          # and closer to the truth than the noisy input


def test_partial_dof_fit_matches_dense_search():
    """Bones with fewer than 3 dofs: the closest representable rotation (dense grid reference)."""
    rng = np.random.default_rng(3)
    T = 40
    U = rng.normal(size=(2, 3))
    W = rng.normal(size=(T, 2, 3))
    for order, axes in (("XYZ", [0]), ("XYZ", [0, 2]), ("ZYX", [1, 2]), ("YZX", [0, 1])):
        ang = kin._fit_partial(order, axes, U, W, np.zeros((T, 3)), np.zeros((T, 3)))

        def cost(A):                                   # A (G, 3) -> (G, T)
            M = kin._euler_matrix(order, A)
            return np.sum((np.einsum("gij,nj->gni", M, U)[:, None] - W[None]) ** 2, axis=(2, 3))
        grid = np.deg2rad(np.arange(-180, 180, 3.0))
        if len(axes) == 1:
            A = np.zeros((len(grid), 3))
            A[:, axes[0]] = grid
        else:
            g1, g2 = np.meshgrid(grid, grid, indexing="ij")
            A = np.zeros((g1.size, 3))
            A[:, axes[0]], A[:, axes[1]] = g1.ravel(), g2.ravel()
        best = cost(A).min(axis=0)                     # dense reference (3 degree grid)
        M = kin._euler_matrix(order, ang)
        got = np.sum((np.einsum("tij,nj->tni", M, U) - W) ** 2, axis=(1, 2))
        assert np.all(got <= best + 1e-9)
        assert np.all(ang[:, [a for a in range(3) if a not in axes]] == 0)


def test_min_rotation_and_kabsch():
    rng = np.random.default_rng(4)
    a, b = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    R = rot.min_rotation(a, b)
    an = a / np.linalg.norm(a, axis=1, keepdims=True)
    bn = b / np.linalg.norm(b, axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum("tij,tj->ti", R, an), bn, atol=1e-12)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-10)
    Rt = kin._euler_matrix("XYZ", rng.uniform(-3, 3, (50, 3)))
    U = rng.normal(size=(50, 4, 3))
    np.testing.assert_allclose(rot.kabsch(U, np.einsum("tij,tnj->tni", Rt, U))[0], Rt, atol=1e-10)


def test_euler_both_branches():
    rng = np.random.default_rng(5)
    for order in ("XYZ", "ZYX", "YZX", "XZY", "YXZ", "ZXY"):
        ang = rng.uniform(-3, 3, (20, 3))
        M = kin._euler_matrix(order, ang)
        for c in kin._euler_from(M, order):
            np.testing.assert_allclose(kin._euler_matrix(order, c), M, atol=1e-12)


# ------------------------------------------------------------------------------------
# malformed input: each raises MocapFormatError naming the line
# ------------------------------------------------------------------------------------
def _line_of(lines, startswith, nth=0):
    hits = [i for i, s in enumerate(lines) if s.strip().startswith(startswith)]
    return hits[nth]


def _expect(path, line, match, **kw):
    with pytest.raises(MocapFormatError, match=match) as ei:
        io.read(path, **kw)
    assert ei.value.line == line, str(ei.value)
    assert str(path) in str(ei.value)
    return ei.value


def test_truncated_frame(pair):
    asf, amc, lines = pair
    cut = len(lines) - 10                      # ends in the middle of the last frame
    amc.write_text("\n".join(lines[:cut]) + "\n")
    _expect(amc, cut, "incomplete")


def test_truncated_line(pair):
    asf, amc, lines = pair
    i = _line_of(lines, "rtibia", 3)
    lines[i] = "rtibia"
    amc.write_text("\n".join(lines) + "\n")
    _expect(amc, i + 1, "needs 1 values")


def test_wrong_value_count(pair):
    asf, amc, lines = pair
    i = _line_of(lines, "lfemur", 5)
    lines[i] += " 4.5"
    amc.write_text("\n".join(lines) + "\n")
    _expect(amc, i + 1, r"bone 'lfemur' needs 3 values \(dof rx ry rz\), found 4")


def test_unknown_bone(pair):
    asf, amc, lines = pair
    i = _line_of(lines, "head", 7)
    lines[i] = lines[i].replace("head", "skull")
    amc.write_text("\n".join(lines) + "\n")
    _expect(amc, i + 1, "unknown bone 'skull'")


def test_nan_and_garbage_text(pair):
    asf, amc, lines = pair
    i = _line_of(lines, "rfoot", 2)
    lines[i] = "rfoot nan 0.5"
    amc.write_text("\n".join(lines) + "\n")
    _expect(amc, i + 1, "only finite numbers")
    lines[i] = "rfoot 1.0 abc"
    amc.write_text("\n".join(lines) + "\n")
    _expect(amc, i + 1, "expected a number")


def test_zero_frames(pair):
    asf, amc, lines = pair
    amc.write_text(":FULLY-SPECIFIED\n:DEGREES\n")
    with pytest.raises(MocapFormatError, match="no frames"):
        io.read(amc)


def test_frame_numbers_out_of_sequence(pair):
    asf, amc, lines = pair
    i = lines.index("5")
    lines[i] = "7"
    amc.write_text("\n".join(lines) + "\n")
    _expect(amc, i + 1, "frame number 7 out of sequence")


def test_mismatched_pair(pair, tmp_path):
    """The AMC names a bone the ASF does not have (skeleton of another layout)."""
    asf, amc, lines = pair
    text = asf.read_text().replace("name lthumb", "name lthumb2").replace("lwrist lhand lthumb", "lwrist lhand lthumb2")
    other = tmp_path / "other.asf"
    other.write_text(text)
    i = _line_of(lines, "lthumb", 0)
    e = _expect(amc, i + 1, "unknown bone 'lthumb': not in other.asf", skeleton=other)
    assert "mismatched" in e.message


def test_bone_order_may_vary_between_frames(pair, walk):
    """Not malformed: bones in another order in frame 2 (line parser), same values."""
    asf, amc, lines = pair
    a, b = lines.index("2"), lines.index("3")
    lines[a + 1:b] = lines[a + 1:b][::-1]
    amc.write_text("\n".join(lines) + "\n")
    m = io.read(amc)
    assert np.array_equal(m.source["per_frame"]["dofs"], walk.source["per_frame"]["dofs"])


def test_asf_cyclic_and_missing_hierarchy(pair):
    asf, amc, lines = pair
    text = asf.read_text()
    alines = text.splitlines()
    # cycle: lfoot becomes the parent of lfemur (lfemur -> ltibia -> lfoot -> lfemur)
    cyc = text.replace("    lhipjoint lfemur\n", "    lhipjoint\n").replace("    lfoot ltoes", "    lfoot ltoes lfemur")
    asf.write_text(cyc)
    with pytest.raises(MocapFormatError, match="cyclic") as ei:
        io.read(amc)
    assert ei.value.line is not None and "16.asf" in str(ei.value)
    # a bone not in the hierarchy
    asf.write_text(text.replace("    lhand lfingers\n", ""))
    i = _line_of(alines, "name lfingers")
    with pytest.raises(MocapFormatError, match="'lfingers' is missing from the :hierarchy") as ei:
        io.read(amc)
    assert ei.value.line == i - 1  # the 1-based line of its block's "begin" (two above "name")
    # no hierarchy at all
    asf.write_text(text[:text.index(":hierarchy")])
    with pytest.raises(MocapFormatError, match="no :hierarchy"):
        io.read(amc)


def test_asf_bad_numbers_and_truncation(pair):
    asf, amc, lines = pair
    text = asf.read_text()
    alines = text.splitlines()
    i = _line_of(alines, "length", 2)
    bad = alines.copy()
    bad[i] = "     length NaN"
    asf.write_text("\n".join(bad) + "\n")
    with pytest.raises(MocapFormatError, match="only finite") as ei:
        io.read(amc)
    assert ei.value.line == i + 1
    asf.write_text(text[: text.index("name lradius")])
    with pytest.raises(MocapFormatError, match="no 'end'"):
        io.read(amc)


def test_asf_is_not_an_amc(pair):
    asf, amc, lines = pair
    with pytest.raises(MocapFormatError, match="ASF skeleton, not an AMC"):
        amc_io.read(asf, skeleton=asf)


# ------------------------------------------------------------------------------------
# the same CMU trial as BVH (MotionBuilder 7.5 conversion) and as ASF/AMC
# ------------------------------------------------------------------------------------
def test_bvh_and_amc_give_the_same_joints(walk):
    """16_15.bvh (motionbuilder75) vs 16_15.amc, both bundled.

    Joint mapping: a BVH joint named after ASF bone B sits at the *start* of B, i.e. at
    the end point of B's parent, which is our joint named parent(B) (BVH 'lfemur' = our
    'lhipjoint', BVH 'root' = our 'root'). Units: the BVH is in cm (root offset
    6.939 = 1.22935 x 5.6444). Same 471 frames, no T-pose frame.
    MotionBuilder keyed every 4th frame and interpolated in between: on frames 0, 4, 8, ...
    the positions agree to the BVH's 6 printed digits (measured max 5.8e-4 cm); over all
    frames the mean difference is 0.12 cm (interpolated frames; frame 1 differs by up to
    42 cm in the left arm because the AMC's first frame has the left-arm angles all 0).
    """
    pytest.importorskip("mocapkit.io.bvh")
    b = io.read(bundled("16_15.bvh"))
    assert b.n_frames == walk.n_frames == 471
    parent = {c: p for p, cs in walk.source["asf"]["hierarchy"] for c in cs}
    pairs = [(n, "root" if n == "root" else parent[n]) for n in b.skeleton.names]
    assert len(pairs) == 29
    d = np.linalg.norm(b.positions[:, b.skeleton.indices([p for p, _ in pairs])]
                       - walk.positions[:, walk.skeleton.indices([q for _, q in pairs])], axis=2)
    keyed = d[::4]
    assert keyed.max() < 0.002                     # cm, measured 5.8e-4
    assert np.median(d) < 0.2 and d[4:].mean() < 0.2   # interpolated frames, measured 0.12 cm mean


def test_amc_writer_refuses_missing_samples(walk, tmp_path):
    """AMC stores joint angles: a missing sample cannot be marked, and an IK that skips it
    drags the joints below (observed ones tens of cm off): one clear error instead."""
    P = walk.positions.copy()
    obs = np.ones(P.shape[:2], bool)
    obs[5:8, 10] = False
    with pytest.raises(MocapValueError, match="cannot write AMC: the motion has 3 missing"):
        io.write(walk.with_positions(P, obs), tmp_path / "gappy.amc")
    assert not (tmp_path / "gappy.amc").exists()
