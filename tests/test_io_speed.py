"""Issue #21 readers/writers: the block BVH parser equals the line parser (values and every
error), chunked FK/IK equal unchunked, the fast Kabsch / two-dof fits / number formatter
against references with known answers, and the closed-form AMC IK on synthetic poses."""
from __future__ import annotations

import io as pyio
import re

import numpy as np
import pytest

from mocapkit import io
from mocapkit.datasets import bundled
from mocapkit.errors import MocapFormatError
from mocapkit.io import _kinematics as K
from mocapkit.io import _rotations as R
from mocapkit.io import _kinematics as kin
from mocapkit.io import bvh
from mocapkit.io._numfmt import fixed_rows

CM = 2.54 / 0.45
HEAD = ("HIERARCHY\nROOT A\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation "
        "Yrotation\n JOINT B\n {\n  OFFSET 0 10 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n  End Site\n  {\n"
        "   OFFSET 0 5 0\n  }\n }\n}\nMOTION\nFrames: {T}\nFrame Time: 0.01\n")


def _both(tmp_path, text: str | bytes, block: int, monkeypatch):
    """(block-parser outcome, line-parser outcome): arrays or (message, line)."""
    raw = text if isinstance(text, bytes) else text.encode()
    p = tmp_path / "x.bvh"
    p.write_bytes(raw)
    monkeypatch.setattr(bvh, "_BLOCK_BYTES", block)
    out = []
    for fn in (lambda: bvh._parse_fast(p, raw), lambda: bvh._parse(p, bvh._decode(raw))):
        try:
            r = fn()
            out.append(None if r is None else r[1])
        except MocapFormatError as e:
            out.append((e.message, e.line))
    return out


def _frames(T: int, rng, bad: dict | None = None) -> str:
    rows = [" ".join(f"{v:.6f}" for v in rng.normal(0, 30, 9)) for _ in range(T)]
    for k, v in (bad or {}).items():
        rows[k] = v
    return HEAD.replace("{T}", str(T)) + "\n".join(rows) + "\n"


def test_block_parser_equals_line_parser_on_real_files(shared_data):
    files = [bundled("16_15.bvh")] + sorted((shared_data / "cmu" / "bvh").rglob("*.bvh"))[:4]
    for f in files:
        raw = f.read_bytes()
        a = bvh._parse_fast(f, raw)
        b = bvh._parse(f, bvh._decode(raw))
        assert a is not None, f
        assert np.array_equal(a[1], b[1]) and a[2] == b[2], f
        assert [n.name for n in a[0]] == [n.name for n in b[0]]


@pytest.mark.parametrize("bad, bad_row", [               # the header is 18 lines: row r is line 19 + r
    ({37: "1 2 3 x 5 6 7 8 9"}, 37), ({3: "1 2 3"}, 3), ({50: "1 2 3 4 5 nan 7 8 9"}, 50),
    ({5: "1 2 3 4 5 6 7 8 9 10"}, 5), ({40: "1e500 2 3 4 5 6 7 8 9"}, 40), ({44: "1-2 3 4 5 6 7 8 9 9"}, 44),
    ({9: "1 2 3 4 5 6 7 8 x", 30: "1 2"}, 30),          # a wrong count anywhere wins over garbage
    ({9: "nan 2 3 4 5 6 7 8 9", 30: "1 2 3 x 5 6 7 8 9"}, 30),   # garbage wins over non-finite
])
def test_block_errors_name_the_same_line(tmp_path, monkeypatch, bad, bad_row):
    text = _frames(60, np.random.default_rng(0), bad)
    for block in (64, 700, 1 << 22):
        fast, line = _both(tmp_path, text, block, monkeypatch)
        assert isinstance(fast, tuple) and fast == line, (block, fast, line)
        assert fast[1] == 19 + bad_row


@pytest.mark.parametrize("mutate", [
    lambda t: t.replace("Frames: 60", "Frames: 61"),                      # truncated
    lambda t: t.replace("Frames: 60", "Frames: 50"),                      # extra lines
    lambda t: t.replace("Frames: 60", "Frames: 99999999999999"),          # a lying count
    lambda t: t + "\n\n   \n",                                            # trailing blank lines
    lambda t: t.replace("\n", "\r\n"),                                    # CRLF
    lambda t: t[:-1],                                                     # no final newline
    lambda t: t.replace("0.", "0_0.", 1)[:0] + t.replace(t.split("\n")[30], "1_0 2 3 4 5 6 7 8 9"),
    lambda t: t.replace(t.split("\n")[30], "1 2\x0b3 4 5 6 7 8 9"),      # odd control byte: line parser
    lambda t: t.replace(t.split("\n")[40], "\t1 2 3 4 5 6 7 8 9  "),
])
def test_block_parser_edge_cases_match(tmp_path, monkeypatch, mutate):
    text = mutate(_frames(60, np.random.default_rng(1)))
    for block in (50, 1 << 22):
        fast, line = _both(tmp_path, text, block, monkeypatch)
        if fast is None:                                       # handed to the line parser
            continue
        if isinstance(line, tuple):
            assert fast == line
        else:
            assert np.array_equal(fast, line)


def test_fk_chunks_equal_one_chunk(monkeypatch):
    m = io.read(bundled("16_15.bvh"))
    nodes = bvh._meta_to_nodes(m.source["bvh"]["nodes"])
    ch = np.asarray(m.source["per_frame"]["channels"])
    X1, G1 = bvh.forward_kinematics(nodes, ch)
    monkeypatch.setattr(bvh, "_CHUNK", 37)
    X2, G2 = bvh.forward_kinematics(nodes, ch)
    np.testing.assert_allclose(X2, X1, atol=1e-9)
    np.testing.assert_allclose(G2, G1, atol=1e-12)
    # FK by hand for the root and its first child, frame 5: R = Rz Rx Ry (channel order)
    k = nodes[0].children[0]
    Rr = np.eye(3)
    for name, a in zip(nodes[0].channels[3:], ch[5, 3:6]):
        Rr = Rr @ R.axis_rotation("XYZ".index(name[0]), np.deg2rad(a))
    np.testing.assert_allclose(X1[5, k], ch[5, :3] + Rr @ nodes[k].offset, atol=1e-9)


@pytest.mark.parametrize("start", [True, False])
def test_bvh_ik_chunks_equal_one_chunk_and_round_trip(monkeypatch, start):
    m = io.read(bundled("16_15.bvh")).slice(0, 120)
    meta = m.source["bvh"]
    nodes, jn = bvh._meta_to_nodes(meta["nodes"]), list(meta["joint_nodes"])
    ch0 = np.asarray(m.source["per_frame"]["channels"]) if start else None
    P = m.positions
    a = bvh._ik_chunked(nodes, jn, P, 1.0, ch0)
    monkeypatch.setattr(bvh, "_CHUNK", 29)
    b = bvh._ik_chunked(nodes, jn, P, 1.0, ch0)
    np.testing.assert_allclose(a, b, atol=1e-9)                 # unwrapping continues across chunks
    X, _ = bvh.forward_kinematics(nodes, b)
    assert np.abs(X[:, jn] - P).max() < 1e-6                    # exact poses come back exactly


def test_fast_kabsch_equals_svd_kabsch():
    rng = np.random.default_rng(2)
    for K_ in (2, 3, 6):
        A = rng.normal(size=(300, K_, 3))
        Qt = R.euler_to_matrix([0, 1, 2], rng.uniform(-3, 3, (300, 3)))
        B = A @ np.swapaxes(Qt, 1, 2)
        Q, deg = R.kabsch(A, B)
        np.testing.assert_allclose(Q, Qt, atol=1e-10)          # known answer
        assert not deg.any()
        Bn = B + rng.normal(0, 0.5, B.shape)
        Q1, _ = R.kabsch(A, Bn)
        Q2, _ = R._kabsch_svd(np.swapaxes(A, 1, 2) @ Bn)
        np.testing.assert_allclose(Q1, Q2, atol=1e-9)
    # collinear vectors: flagged (and identity when asked not to solve them)
    A = np.array([[[1.0, 0, 0], [-2.0, 0, 0]]] * 4)
    Q, deg = R.kabsch(A, A, degenerate_q=False)
    assert deg.all() and np.allclose(Q, np.eye(3))


def test_two_dof_closed_form_known_answers():
    rng = np.random.default_rng(3)
    T = 200
    for order, axes in (("XYZ", [0, 2]), ("ZYX", [1, 2]), ("YZX", [0, 1])):
        ang = np.zeros((T, 3))
        ang[:, axes] = rng.uniform(-2.5, 2.5, (T, 2))
        u = rng.normal(size=3)
        W = (K._euler_matrix(order, ang) @ u)[:, None, :]
        got = K._fit_partial_fast(order, axes, np.broadcast_to(u, (T, 1, 3)), W, np.zeros((T, 3)), np.zeros((T, 3)))
        np.testing.assert_allclose(K._euler_matrix(order, got) @ u, W[:, 0], atol=1e-9)
        assert np.all(got[:, [a for a in range(3) if a not in axes]] == 0)


def test_fixed_rows_equals_printf_and_trim():
    rng = np.random.default_rng(4)
    A = np.concatenate([rng.normal(0, 80, (50, 7)), np.round(rng.normal(0, 80, (50, 7)), 2),
                        np.array([[0.0, -0.0, 1e-10, -1e-10, 100.0, -8999999.25, 12345678.5]])])
    buf = pyio.StringIO()
    np.savetxt(buf, A, fmt="%.9f", delimiter=" ")
    ref = re.sub(r"(\.\d*?)0+(?=[ \n]|$)", r"\1", buf.getvalue())
    ref = re.sub(r"(?<![\d.])-0(?=[ \n]|$)", "0", re.sub(r"\.(?=[ \n]|$)", "", ref))
    assert fixed_rows(A).decode() == ref


def test_amc_ik_closed_form_recovers_random_poses_without_start():
    """No stored dofs at all: random poses (within the ASF limits) come back to < 0.5 cm
    (old IK: 9.3 cm max on 131_02 without start, see docs/results/io_speed.md)."""
    m = io.read(bundled("16_15.amc"))
    comp = kin._Compiled(m.source["asf"])
    D = m.source["per_frame"]["dofs"][:80]
    P = kin.forward_kinematics(comp, D, False, CM)
    out = kin.inverse_kinematics(comp, P, CM, False, None)
    err = np.linalg.norm(kin.forward_kinematics(comp, out, False, CM) - P, axis=2)
    assert err.max() < 0.5 and err.mean() < 0.02
    # the top-down pass alone (no Levenberg-Marquardt) is already close
    out0 = kin.inverse_kinematics(comp, P, CM, False, None, refine=0)
    err0 = np.linalg.norm(kin.forward_kinematics(comp, out0, False, CM) - P, axis=2)
    assert err0.mean() < 0.05


def test_hinge_twist_picks_the_bend_inside_the_limits():
    """A straight-start femur twist is fixed by the knee's cone in closed form: every
    recovered knee angle lies inside the ASF limits (-10, 170) degrees."""
    m = io.read(bundled("16_15.amc"))
    comp = kin._Compiled(m.source["asf"])
    D = m.source["per_frame"]["dofs"][:80]
    out = kin.inverse_kinematics(comp, kin.forward_kinematics(comp, D, False, CM), CM, False, None,
                                    refine=0)
    for knee in ("ltibia", "rtibia"):
        col = comp.dof_cols[knee][0]
        assert np.all((out[:, col] > -10.5) & (out[:, col] < 170.5))
        np.testing.assert_allclose(out[:, col], D[:, col], atol=0.5)
