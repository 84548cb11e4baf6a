"""BRA / BRA-P (seed 002): clips, losses, model, trainer, checkpoints, shipped model.

Tiny models (hidden 16) and a few steps only; torch tests skip when torch is absent.
"""
from __future__ import annotations

import sys

import numpy as np
import pytest

from mocapkit import Motion, Skeleton, corrupt, denoise
from mocapkit.errors import MissingDependencyError, MocapValueError, TrainingMismatchWarning
from mocapkit.frames import mirror_permutation
from mocapkit.neural import clips as C
from mocapkit.neural import pretrained_path

CMU21_PARENTS = np.array([-1, 0, 1, 2, 3, 0, 5, 6, 7, 0, 9, 10, 11, 10, 13, 14, 15, 10, 17, 18, 19])


def synthetic_cmu(T: int = 300, seed: int = 0, fps: float = 60.0) -> Motion:
    """A 21-joint motion with CMU names: rest pose + smooth joint wobble + a walk-like root path."""
    rng = np.random.default_rng(seed)
    off = rng.normal(0, 8, (21, 3))
    off[0] = (0, 95, 0)
    sk = Skeleton(C.CMU_21, CMU21_PARENTS, off)
    t = np.arange(T) / fps
    rest = sk.rest_positions()
    ph = rng.uniform(0, 2 * np.pi, (21, 3))
    P = rest[None] + 4 * np.sin(2 * np.pi * 1.1 * t[:, None, None] + ph[None])
    P += np.stack([60 * t, 0 * t, 10 * np.sin(t)], axis=1)[:, None, :]
    return Motion(P, sk, fps)


# ----------------------------------------------------------------------------------------
# clips (numpy only)
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("T", [1, 50, 119, 120, 121, 180, 181, 300, 347])
def test_split_and_crossfade_is_exact_for_identity(T):
    X = np.random.default_rng(T).normal(size=(T, 7))
    W, starts, left = C.split_clips(X, 120, 60)
    assert W.shape[1:] == (120, 7)
    assert starts[0] == 0 and starts[-1] + 120 == max(T, 120)
    np.testing.assert_allclose(C.overlap_add(W, starts, T, left), X, rtol=0, atol=1e-12)


def test_crossfade_is_linear_over_the_overlap():
    # window 0 outputs 0, window 1 outputs 1: frames 60..119 ramp linearly from 0 to 1
    Y = np.stack([np.zeros((120, 1)), np.ones((120, 1))])
    out = C.overlap_add(Y, np.array([0, 60]), 180)[:, 0]
    w = C.triangular_window(120)
    expected = w[:60] / (w[60:] + w[:60])           # rising weight of window 1 over the overlap
    np.testing.assert_allclose(out[60:120], expected)
    assert np.all(np.diff(out[60:120]) > 0) and out[0] == 0 and out[-1] == 1
    np.testing.assert_allclose(np.diff(out[60:120]), np.diff(out[60:120])[0])   # straight line


def test_pad_edges_repeats_border_frames():
    X = np.arange(5.0)[:, None]
    P, left = C.pad_edges(X, 10)
    assert left == 2 and P[:2, 0].tolist() == [0, 0] and P[-3:, 0].tolist() == [4, 4, 4]
    np.testing.assert_array_equal(P[left:left + 5], X)


def test_ground_reference_exact_and_with_gaps():
    R = np.stack([np.arange(10.0), np.full(10, 90.0), -np.arange(10.0)], axis=1)
    obs = np.ones(10, bool)
    obs[3:6] = False
    ref = C.ground_reference(np.where(obs[:, None], R, np.nan), obs, sigma=0.0)
    np.testing.assert_allclose(ref[:, [0, 2]], R[:, [0, 2]])      # linear gap bridged exactly
    assert np.all(ref[:, 1] == 0)


def test_wrong_skeleton_names_missing_joints():
    m = synthetic_cmu(60)
    keep = [n for n in C.CMU_21 if n not in ("lhand", "rtibia")]
    bad = m.select(keep)
    with pytest.raises(MocapValueError, match="lacks 2 of the 21 joints.*rtibia, lhand"):
        C.check_joints(bad.skeleton, C.CMU_21)


def test_attach_dropped_is_exact_for_a_rigid_motion():
    # chain root -> a -> b (dropped, on the segment a-c) -> c, plus a dropped leaf d under c
    rest_off = np.array([[0, 0, 0], [0, 10, 0], [0, 5, 0], [0, 5, 0], [3, 0, 0]], float)
    sk = Skeleton(("root", "a", "b", "c", "d"), [-1, 0, 1, 2, 3], rest_off)
    rest = sk.rest_positions()
    th = np.linspace(0, 1.2, 7)
    Rz = np.zeros((7, 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = np.cos(th), -np.sin(th), np.sin(th), np.cos(th), 1
    P = np.einsum("tij,kj->tki", Rz, rest) + np.array([5.0, 0, 2])
    out = C.attach_dropped(P[:, [0, 1, 3]], sk, ["root", "a", "c"])
    np.testing.assert_allclose(out[:, 2], P[:, 2], atol=1e-9)       # b: exact (on the segment)
    np.testing.assert_allclose(out[:, 4], P[:, 4], atol=1e-9)       # d: rotation about z is minimal here


def test_attach_dropped_keeps_the_inputs_own_motion_of_a_dropped_joint():
    # d wiggles about c (a hand about its wrist): the rigid rule cannot follow it, the
    # input's smoothed track does; where d is not observed the rigid rule fills in
    rest_off = np.array([[0, 0, 0], [0, 10, 0], [0, 5, 0], [0, 5, 0], [3, 0, 0]], float)
    sk = Skeleton(("root", "a", "b", "c", "d"), [-1, 0, 1, 2, 3], rest_off)
    T = 120
    P = np.repeat(sk.rest_positions()[None], T, axis=0)
    P[:, 4, 2] += 2.0 * np.sin(np.linspace(0, 3 * np.pi, T))
    rigid = C.attach_dropped(P[:, [0, 1, 3]], sk, ["root", "a", "c"])
    assert np.abs(rigid[:, 4] - P[:, 4]).max() > 1.5
    obs = np.ones((T, 5), bool)
    obs[50:60, 4] = False
    out = C.attach_dropped(P[:, [0, 1, 3]], sk, ["root", "a", "c"], source=P, source_observed=obs)
    np.testing.assert_allclose(out[obs[:, 4], 4], P[obs[:, 4], 4], atol=0.02)
    np.testing.assert_allclose(out[50:60, 4], rigid[50:60, 4])


def test_model_input_bridges_masks_and_splits_base():
    Z = np.arange(10.0)[:, None] * np.ones((1, 6))          # 2 joints, linear in time
    obs = np.ones((10, 2), bool)
    obs[3:6, 1] = False
    Zn = Z.copy()
    Zn[3:6, 3:] = 99.0                                       # garbage where missing
    X = C.model_input(Zn, obs, fill=True, mask=True)
    np.testing.assert_allclose(X[:, :6], Z)                  # the linear bridge is exact
    np.testing.assert_array_equal(X[:, 6:], obs.astype(float))
    X0 = C.model_input(Zn, obs, fill=False, mask=False)      # the paper: zero (mean pose)
    assert X0.shape == (10, 6) and np.all(X0[3:6, 3:] == 0)
    Xb = C.model_input(Zn, obs, fill=True, mask=True, base_sigma=1.0)
    assert Xb.shape == (10, 14)
    np.testing.assert_allclose(Xb[:, :6] + Xb[:, 6:12], Z, atol=1e-12)   # base + high-pass = input
    np.testing.assert_allclose(Xb[5:-5, :6], Z[5:-5], atol=1e-9)         # a line is kept inside


def test_base_smooth_removes_a_spike_and_keeps_a_line():
    x = np.linspace(0, 9, 40)[:, None]
    y = x.copy()
    y[20] += 15.0
    b = C.base_smooth(y, 1.0, median=5)
    # the median of [x18, x19, x20 + 15, x21, x22] is x21: one step (0.23) off, not 15
    assert np.abs(b[15:26] - x[15:26]).max() < 0.25
    np.testing.assert_allclose(b[4:15], x[4:15], atol=1e-4)
    np.testing.assert_allclose(b[26:-4], x[26:-4], atol=1e-4)


def test_gcv_base_smooths_noise_keeps_a_clean_curve_and_ignores_missing():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 4 * np.pi, 200)[:, None]
    clean = np.hstack([np.sin(t), np.cos(0.5 * t), 0.1 * t])
    noisy = clean + rng.normal(0, 0.1, clean.shape)
    b = C.base_smooth(noisy, 1.0, kind="gcv")
    rms = lambda e: float(np.sqrt(np.mean(e ** 2)))
    assert rms(b - clean) < 0.4 * rms(noisy - clean)           # GCV removes most of the noise
    assert rms(C.base_smooth(clean, 1.0, kind="gcv") - clean) < 1e-3     # and keeps a clean curve
    obs = np.ones(clean.shape, bool)
    obs[50:60, 0] = False
    bad = noisy.copy()
    bad[50:60, 0] = 99.0                                     # garbage where missing is not fitted
    bm = C.base_smooth(bad, 1.0, kind="gcv", observed=obs)
    assert np.abs(bm[50:60, 0] - clean[50:60, 0]).max() < 0.3
    joint = obs.all(axis=1, keepdims=True)                   # (T, 1): the one joint's mask
    Xb = C.model_input(bad, joint, fill=True, mask=False, base_sigma=1.0, base_filter="gcv")
    np.testing.assert_allclose((Xb[:, :3] + Xb[:, 3:6])[joint[:, 0]], bad[joint[:, 0]], atol=1e-12)
    assert np.abs(Xb[50:60, :3] - clean[50:60]).max() < 0.3   # the base never saw the garbage
    with pytest.raises(MocapValueError, match="base filter"):
        C.base_smooth(noisy, 1.0, kind="kalman")


def test_mirror_permutation_swaps_left_and_right():
    perm = mirror_permutation(C.CMU_21)
    names = [C.CMU_21[i] for i in perm]
    assert names[C.CMU_21.index("lhumerus")] == "rhumerus" and names[C.CMU_21.index("rfoot")] == "lfoot"
    assert names[C.CMU_21.index("lowerback")] == "lowerback" and names[0] == "root"
    assert sorted(perm) == list(range(21))


# ----------------------------------------------------------------------------------------
# torch
# ----------------------------------------------------------------------------------------
def test_missing_torch_raises_clear_error_for_training_only(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "torch", None)          # `import torch` now fails
    with pytest.raises(MissingDependencyError, match=r"pip install mocapkit\[neural\]"):
        denoise.get("bra-p", model=str(tmp_path / "x.pt")).denoise(synthetic_cmu(60))
    with pytest.raises(MissingDependencyError, match=r"mocapkit\[neural\]"):
        denoise.get("bra", hidden=16).fit([synthetic_cmu(60)])
    from mocapkit.neural import model

    with pytest.raises(MissingDependencyError):
        model.build(63, 63, 16)


torch = pytest.importorskip("torch")
from mocapkit.neural import losses as L  # noqa: E402
from mocapkit.neural import train as TR  # noqa: E402
from mocapkit.neural.bundle import Bundle  # noqa: E402
from mocapkit.neural.model import build  # noqa: E402


def test_forward_shapes_different_in_out():
    net = build(45, 63, hidden=16, dropout=0.2).eval()
    y, h = net(torch.zeros(2, 120, 45))
    assert tuple(y.shape) == (2, 120, 63) and tuple(h.shape) == (2, 120, 16)
    widths = [l.out_features for l in net.enc_fc] + [l.out_features for l in net.dec_fc]
    assert widths == [4, 8, 16, 8, 4, 63]                  # m -> h/4 -> h/2 -> h, mirrored


def test_smoothness_matrix_and_loss_by_hand():
    O = C_O = L.smoothness_matrix(2)
    np.testing.assert_array_equal(C_O, [[-1, 1, 0, 0], [1, -2, 1, 0], [0, 1, -2, 1], [0, 0, 1, -1]])
    x = torch.tensor([[[0.0], [1.0], [4.0]]])             # f = 3, d = 1
    # X' = [0, 0, 1, 4, 4]; O X' = [0, 1, 2, -3, 0]; sum of squares 14; / ((f + 2) d) = 2.8
    assert float(L.smoothness(x)) == pytest.approx(2.8)
    Xp = L.border_repeat(x)[0].numpy()
    np.testing.assert_allclose(L.smoothness_matrix(3) @ Xp, [[0], [1], [2], [-3], [0]])
    assert O.shape == (4, 4)


def test_bone_length_reproduction_perceptual_by_hand():
    # two joints, one bone (1 -> 0); frame 1 length 5, frame 2 length 2; reference 4
    x = torch.tensor([[[0, 0, 0, 3, 4, 0], [0, 0, 0, 0, 0, 2]]], dtype=torch.float32)
    bones = torch.tensor([[1, 0]])
    assert float(L.bone_length(x, bones, torch.tensor([[4.0]]))) == pytest.approx((1 + 2) / 2, rel=1e-6)
    y = torch.zeros(1, 2, 2)
    t = torch.tensor([[[1.0, 0.0], [3.0, 0.0]]])
    assert float(L.reproduction(y, t)) == pytest.approx((1 + 9) / 4)
    assert float(L.perceptual(y, t)) == pytest.approx((1 + 9) / 4)


def _tiny_cfg(**kw):
    base = dict(hidden=16, dropout=0.0, batch_size=4, lr_perceptual=1e-2, lr_denoise=1e-2, threads=1,
                steps_perceptual=2, steps_denoise=3, random_offsets=True, checkpoint_every=2, seed=3)
    base.update(kw)
    return TR.TrainConfig(**base)


@pytest.fixture(scope="module")
def source():
    return TR.SyntheticSource([synthetic_cmu(300, 0), synthetic_cmu(200, 1, fps=120.0)])


def test_synthetic_source_is_root_local_and_normalised(source):
    assert source.n_clips == 4 + 1                      # 300 frames -> 4 clips; 100 frames @ 60 -> 1 padded
    L0 = source.local[0]
    np.testing.assert_allclose(L0[:, 0, [0, 2]], 0, atol=1e-9)      # root on the vertical axis
    assert L0[:, 0, 1].mean() > 50                                   # height kept
    b = source.noisy_batch(np.random.default_rng(0), 8, _tiny_cfg(), [])
    assert b["x_in"].shape == b["x_clean"].shape == (8, 120, 63) and np.isfinite(b["x_in"]).all()
    assert (b["x_in"] == 0).any()                                    # missing joints zeroed (some draws)


def test_augmentation_rotates_mirrors_and_scales_rigidly(source):
    X = np.stack([source.local[0][:120], source.local[0][60:180]])
    rng = np.random.default_rng(4)
    Y = source.augment(X, rng, (0.8, 1.2))
    b = source.bones
    lx = np.linalg.norm(X[:, :, b[:, 0]] - X[:, :, b[:, 1]], axis=-1)
    ly = np.linalg.norm(Y[:, :, b[:, 0]] - Y[:, :, b[:, 1]], axis=-1)
    ratio = ly / lx
    for k in range(2):                                    # one scale per clip, every bone, frame
        s = np.median(ratio[k])
        assert 0.8 <= s <= 1.2
        # mirrored clips swap l/r bones: compare sorted length profiles
        np.testing.assert_allclose(np.sort(ly[k], axis=1), np.sort(s * lx[k], axis=1), rtol=1e-9)
    np.testing.assert_allclose(Y[:, :, 0, [0, 2]], 0, atol=1e-9)    # root stays on the vertical
    np.testing.assert_allclose(Y[..., 1], X[..., 1] * np.median(ratio, axis=(1, 2))[:, None, None], rtol=1e-9)


def test_cosine_schedule_and_residual_identity(source):
    cfg = _tiny_cfg(lr_denoise=1e-2, lr_schedule="cosine", lr_floor=0.1, steps_perceptual=0, steps_denoise=10,
                    perceptual=False, residual=True)
    tr = TR.Trainer(source, cfg, progress=False)
    tr.phase = "denoise"
    assert tr.learning_rate() == pytest.approx(1e-2)
    tr.step = 5
    assert tr.learning_rate() == pytest.approx(1e-2 * (0.1 + 0.9 * 0.5))
    tr.step = 10
    assert tr.learning_rate() == pytest.approx(1e-3)
    x = torch.randn(2, 120, 63)
    y, _ = tr.denoise.eval()(x)
    torch.testing.assert_close(y, x)                      # an untrained residual network is the identity


def test_training_reduces_loss(source):
    cfg = _tiny_cfg(steps_perceptual=40, steps_denoise=0)
    tr = TR.Trainer(source, cfg, progress=False)
    batch = source.clean_batch(np.random.default_rng(9), 8, cfg, [])
    tr.perceptual.eval()
    before = tr._losses_perceptual(batch)[1]["loss"]
    for _ in range(40):
        tr.train_step()
    tr.perceptual.eval()
    after = tr._losses_perceptual(batch)[1]["loss"]
    assert after < 0.7 * before


def test_resume_continues_step_count_and_reproduces(source, tmp_path, monkeypatch):
    cfg = _tiny_cfg(steps_perceptual=2, steps_denoise=5)
    full = TR.Trainer(source, cfg, progress=False).run()

    ck = tmp_path / "m.pt.ckpt"
    crashing = TR.Trainer(source, cfg, checkpoint=ck, progress=False)
    orig = TR.Trainer.train_step

    def step_then_crash(self):
        if self.phase == "denoise" and self.step == 3:
            raise KeyboardInterrupt
        return orig(self)

    monkeypatch.setattr(TR.Trainer, "train_step", step_then_crash)
    with pytest.raises(KeyboardInterrupt):
        crashing.run()
    monkeypatch.setattr(TR.Trainer, "train_step", orig)

    resumed = TR.Trainer(source, cfg, checkpoint=ck, progress=False).load_checkpoint(ck)
    assert resumed.phase == "denoise" and resumed.step == 2          # last checkpoint (every 2 steps)
    resumed.run()
    assert resumed.phase == "done" and resumed.step == 5
    for a, b in zip(full.denoise.state_dict().values(), resumed.denoise.state_dict().values()):
        torch.testing.assert_close(a, b, rtol=0, atol=0)

    more = TR.Trainer(source, _tiny_cfg(steps_perceptual=2, steps_denoise=7), checkpoint=ck, progress=False)
    more.load_checkpoint(ck).run()
    assert more.step == 7 and [h["step"] for h in more.history if h["phase"] == "denoise"][-1] == 7
    with pytest.raises(MocapValueError, match="other settings"):
        TR.Trainer(source, _tiny_cfg(hidden=8), progress=False).load_checkpoint(ck)


def test_bundle_save_load_roundtrip_and_denoiser(source, tmp_path):
    tr = TR.Trainer(source, _tiny_cfg(), progress=False).run()
    b = tr.bundle()
    Z = np.random.default_rng(0).normal(size=(3, 120, 63))
    ref = b.run_windows(Z)
    b.save(tmp_path / "m.pt")
    b2 = Bundle.load(tmp_path / "m.pt")
    np.testing.assert_allclose(b2.run_windows(Z), ref, atol=1e-6)
    b.save(tmp_path / "h.pt", half=True)
    np.testing.assert_allclose(Bundle.load(tmp_path / "h.pt").run_windows(Z), ref, atol=0.05)
    # through the Denoiser interface and the base-class dispatcher used by the CLI
    m = denoise.base.Denoiser.load(tmp_path / "m.pt")
    assert m.name == "bra-p" and m.is_fitted()
    mo = synthetic_cmu(150, 2, fps=120.0)
    noisy, _ = corrupt.missing(corrupt.gaussian(mo, sigma_cm=1.0, seed=0)[0], ratio=0.2, seed=0)
    with pytest.warns(TrainingMismatchWarning, match="training clips probably do not cover"):   # 5 steps: garbage
        out = m.denoise(noisy)
    assert out.skeleton == mo.skeleton and out.positions.shape == mo.positions.shape
    # a 5-step network moves measured samples far on a smooth clip: the gap policy gives
    # them back, and the fills it then can not join to them are left missing, reported
    rep = out.source["gap_report"]
    assert out.observed[noisy.observed].all() and rep["kept_measured"] > 0
    assert (~out.observed).sum() == rep["left_missing"]
    keep = [n for n in C.CMU_21 if n != "rtibia"]
    with pytest.raises(MocapValueError, match="lacks 1 of the 21 joints this model needs: rtibia"):
        m.denoise(mo.select(keep))
    m.save(tmp_path / "d.pt")
    with pytest.raises(Exception, match="bra-p"):
        denoise.available()["bra"].load(tmp_path / "d.pt")


def test_different_topology_15_to_21(tmp_path):
    clean = [synthetic_cmu(240, s) for s in (4, 5)]
    drop = ("lhand", "rhand", "lfoot", "rfoot", "lowerneck", "upperneck")
    joints_in = [j for j in C.CMU_21 if j not in drop]
    rng = np.random.default_rng(0)
    inputs, targets = [], []
    for m in clean:
        P = m.positions - C.ground_reference(m.positions[:, 0], sigma=0)[:, None]
        idx = m.skeleton.indices(joints_in)
        inputs.append((P[:, idx] + rng.normal(0, 2, (len(P), 15, 3))).reshape(len(P), -1))
        targets.append(P.reshape(len(P), -1))
    src = TR.PairedSource(inputs, targets, joints_in, C.CMU_21, CMU21_PARENTS)
    assert (src.m, src.n) == (45, 63)
    cfg = _tiny_cfg(steps_perceptual=5, steps_denoise=30)
    tr = TR.Trainer(src, cfg, progress=False)
    batch = src.noisy_batch(np.random.default_rng(1), 6, cfg, [])
    tr.denoise.eval()
    before = tr._losses_denoise(batch)[1]["R"]
    tr.run()
    tr.denoise.eval()
    assert tr._losses_denoise(batch)[1]["R"] < before
    b = tr.bundle(method="bra-p")
    b.save(tmp_path / "topo.pt")
    b2 = Bundle.load(tmp_path / "topo.pt")
    assert not b2.same_topology
    noisy15 = clean[0].select(joints_in)
    out = b2.refine(noisy15)
    assert out.skeleton.names == C.CMU_21 and out.n_frames == noisy15.n_frames


@pytest.mark.skipif(not pretrained_path("bra-p").is_file(), reason="no shipped bra-p checkpoint")
def test_shipped_checkpoint_denoises_a_bundled_clip():
    from mocapkit import io, metrics
    from mocapkit.datasets import BUNDLED_DIR, bundled

    if not list(BUNDLED_DIR.rglob("16_15.amc")):
        pytest.skip("bundled clip 16_15.amc not present")
    m = denoise.get("bra-p")
    assert not type(m).needs_training
    truth = io.read(bundled("16_15.amc")).slice(0, 240)
    noisy, _ = corrupt.gaussian(truth, sigma_cm=6.0, seed=1)
    out = m.denoise(noisy)
    assert out.skeleton == truth.skeleton and out.fps == truth.fps and out.observed.all()
    assert metrics.rmse(truth, out) < 0.8 * metrics.rmse(truth, noisy)
    noisy2, _ = corrupt.missing(noisy, ratio=0.3, seed=2)
    out2 = m.denoise(noisy2)
    # the gap policy's self-validation leaves a few fills missing (9 of 2,160 samples)
    assert np.isfinite(out2.positions[out2.observed]).all() and out2.observed.mean() > 0.99
    assert metrics.rmse(truth, out2, out2.observed) < metrics.rmse(truth, noisy)


@pytest.mark.skipif(not pretrained_path("bra").is_file(), reason="no shipped bra checkpoint")
def test_network_refuses_a_body_in_other_units():
    """Issue 18 (scale sanity): a clip in metres or millimetres given as cm came back
    ~30 cm (in cm) off; now it is refused with one clear error naming the size ratio."""
    from mocapkit import io
    from mocapkit.datasets import bundled
    from mocapkit.errors import MocapValueError

    truth = io.read(bundled("16_15.amc")).slice(0, 120)
    m = denoise.get("bra")
    assert m.denoise(truth).observed.all()
    for s, word in ((0.01, "0.0"), (10.0, "(9|10|11)")):
        with pytest.raises(MocapValueError, match=f"body is {word}.* times the size.*units"):
            m.denoise(truth.with_positions(truth.positions * s))
    m.denoise(truth.with_positions(truth.positions * 0.7))        # a child: still fine


def test_train_cli_small_run_writes_checkpoint_and_resumes(tmp_path):
    from mocapkit.datasets import BUNDLED_DIR

    clips = sorted(BUNDLED_DIR.rglob("09_06.amc")) + sorted(BUNDLED_DIR.rglob("16_15.amc"))
    if not clips:
        pytest.skip("bundled CMU clips not present")
    out = tmp_path / "m.pt"
    logs: list[str] = []
    TR.train_cli(clips, out, method="bra", hidden=8, steps_denoise=3, checkpoint_every=2, threads=1,
                 random_offsets=True, progress=False, log=logs.append, exclude=["16_15"])
    assert out.is_file() and (tmp_path / "m.pt.ckpt").is_file()
    m = denoise.base.Denoiser.load(out)
    assert m.name == "bra" and m.bundle_.meta["training"]["motions"] == ["09_06"]
    TR.train_cli(clips, out, method="bra", hidden=8, steps_denoise=5, checkpoint_every=2, threads=1,
                 random_offsets=True, progress=False, log=logs.append, exclude=["16_15"], resume=True)
    assert any("resumed from" in s and "step 3" in s for s in logs)
    assert Bundle.load(out).meta["training"]["steps_denoise"] == 5


def test_project_bones_makes_every_bone_its_median_length_and_keeps_a_rigid_clip():
    rng = np.random.default_rng(0)
    parents = np.array([-1, 0, 1, 1, 3])
    P = np.cumsum(rng.normal(size=(50, 5, 3)), axis=1)           # bones of varying length
    Q = C.project_bones(P, parents)
    L = np.linalg.norm(Q[:, 1:] - Q[:, parents[1:]], axis=2)
    want = np.median(np.linalg.norm(P[:, 1:] - P[:, parents[1:]], axis=2), axis=0)
    np.testing.assert_allclose(L, np.broadcast_to(want, L.shape), atol=1e-9)
    np.testing.assert_array_equal(Q[:, 0], P[:, 0])              # the root stays
    rest = np.array([[0, 0, 0], [0, 10, 0], [0, 5, 0], [3, 5, 0], [0, 9, 0]], float)
    R = np.repeat(rest[None], 7, axis=0) + rng.normal(size=(7, 1, 3))  # a rigid clip, moving
    np.testing.assert_allclose(C.project_bones(R, parents), R, atol=1e-9)
