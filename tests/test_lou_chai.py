"""Lou & Chai 2010 filter bases (mocapkit.solvers.robust_bases, denoise 'lou-chai') and the
heading frame (mocapkit.frames)."""
import numpy as np
import pytest

from mocapkit import Motion, Skeleton, denoise, windows
from mocapkit.frames import find_hips, heading_frame, mirror_local, mirror_permutation
from mocapkit.errors import MocapError, MocapValueError, NotFittedError
from mocapkit.solvers import robust_bases as rb


@pytest.fixture(autouse=True, scope="module")
def _one_blas_thread():
    """Keep BLAS to one thread: the machine is shared (2 cores) and these are small problems."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        yield


# ---------------------------------------------------------------------------------------
# synthetic data
# ---------------------------------------------------------------------------------------
def sinusoids(T, L, freqs, seed=0, phase0=0.0, fps=30.0):
    """(T, L) sum of sinusoids: each channel a random mix of sin/cos of ``freqs`` (Hz)."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / fps + phase0
    basis = np.concatenate([np.stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)], 1)
                            for f in freqs], axis=1)                   # (T, 2F)
    mix = np.random.default_rng(1).normal(size=(basis.shape[1], L)) * 5.0
    return basis @ mix + 0.0 * rng.normal(size=(T, L))


NAMES = ("root", "lhip", "lknee", "lfoot", "rhip", "rknee", "rfoot", "spine", "head",
         "lshoulder", "lhand", "rshoulder", "rhand")
PARENTS = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 7, 9, 7, 11)


def walker(T=300, fps=30.0, seed=0, turn=0.3, speed=100.0, phase=0.0, amp=1.0):
    """A toy walker (cm): a rest pose + sinusoidal limb motion at 1 Hz in the body frame,
    moved along a curved path with a turning heading (Y up)."""
    rest = np.array([[0, 90, 0], [0, 90, 10], [0, 50, 10], [0, 5, 10], [0, 90, -10], [0, 50, -10],
                     [0, 5, -10], [0, 130, 0], [0, 165, 0], [0, 145, 18], [0, 100, 22],
                     [0, 145, -18], [0, 100, -22]], float)
    t = np.arange(T) / fps
    ph = 2 * np.pi * 1.0 * t + phase
    P = np.repeat(rest[None], T, axis=0)
    sw = amp * 20 * np.sin(ph)                  # leg / arm swing along x (forward)
    for j, sgn in ((2, 1), (3, 1), (5, -1), (6, -1), (10, -1), (12, 1)):
        P[:, j, 0] += sgn * sw * (1.5 if j in (3, 6) else 1.0)
    P[:, 0, 1] += 2 * np.cos(2 * ph)            # bounce
    P[:, [3, 6], 1] += 5 * np.clip(np.sin(ph)[:, None] * np.array([1, -1]), 0, None)
    # global path: heading theta(t), rotate about Y and translate
    theta = turn * t + 0.2 * seed
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros((T, 3, 3))
    R[:, 1, 1] = 1
    R[:, 0, 0], R[:, 0, 2], R[:, 2, 0], R[:, 2, 2] = c, s, -s, c
    fwd = np.stack([c, np.zeros(T), -s], 1)
    O = np.cumsum(fwd * speed / fps, axis=0) + np.array([seed * 50.0, 0, 0])
    O[:, 1] = 0
    W = np.einsum("tij,tkj->tki", R, P) + O[:, None]
    sk = Skeleton.from_positions(NAMES, PARENTS, rest)
    return Motion(W, sk, fps)


# ---------------------------------------------------------------------------------------
# solver: training
# ---------------------------------------------------------------------------------------
def test_lag_covariance_methods_match_explicit_trajectory_matrix():
    rng = np.random.default_rng(0)
    clips = [rng.normal(size=(40, 3)), rng.normal(size=(25, 3)), rng.normal(size=(4, 3))]
    M = 6
    # eqs. 1-2 literally: channel-major D = (X_1 ... X_L), then permute to frame-major
    D = np.concatenate([np.concatenate([np.stack([X[s:s + M, l] for s in range(len(X) - M + 1)])
                                        for l in range(3)], axis=1) for X in clips[:2]])
    perm = np.array([l * M + m for m in range(M) for l in range(3)])
    ref = (D.T @ D)[np.ix_(perm, perm)]
    for method in ("lag", "chunked", "dense"):
        G, S = rb.lag_covariance(clips, M, method=method, chunk=7)
        assert S == 35 + 20
        np.testing.assert_allclose(G, ref, atol=1e-10)


def test_bases_reproduce_sum_of_sinusoids():
    freqs = (0.5, 1.0, 1.7)
    X = sinusoids(400, 5, freqs)
    E, ev, S = rb.learn_bases([X], 20, energy=0.999999)
    # 3 frequencies = 6 sin/cos patterns carry all the energy
    assert E.shape[1] <= 6
    assert ev[:6].sum() / ev.sum() > 1 - 1e-9
    np.testing.assert_allclose(E.T @ E, np.eye(E.shape[1]), atol=1e-10)
    # an unseen stretch of the same signal (other phase) is reconstructed exactly
    Y = sinusoids(120, 5, freqs, phase0=3.21)
    A = rb.WindowProjector(E, 20, 5, 120, "direct")(Y)
    np.testing.assert_allclose(A / windows.counts(120, 20)[:, None], Y, atol=1e-6)
    # energy fraction -> K
    assert rb.choose_k(np.array([5.0, 3, 1, 1]), 0.8) == 2
    assert rb.choose_k(np.array([5.0, 3, 1, 1]), 0.5) == 1
    assert rb.choose_k(np.array([5.0, 3, 1, 1]), None, n_bases=3) == 3


@pytest.mark.parametrize("T,L,M,K", [(30, 2, 3, 2), (20, 3, 7, 4), (7, 2, 7, 5), (260, 4, 20, 30)])
def test_window_projector_implementations_agree(T, L, M, K):
    rng = np.random.default_rng(T)
    E = np.linalg.qr(rng.normal(size=(M * L, K)))[0]
    Z = rng.normal(size=(T, L))
    ref = np.zeros((T, L))
    for s in range(T - M + 1):                       # sum_s S_s^T E E^T S_s z, literally
        ref[s:s + M] += (E @ (E.T @ Z[s:s + M].ravel())).reshape(M, L)
    for method, tol in (("direct", 1e-12), ("fft", 1e-11), ("fft32", 1e-4)):
        np.testing.assert_allclose(rb.WindowProjector(E, M, L, T, method)(Z), ref, atol=tol)
    C = rb.coefficients(Z, rb._split_bases(E, M, L))
    np.testing.assert_allclose(C, windows.lagged(Z, M) @ E, atol=1e-12)


def test_welsch():
    r = np.array([0.0, 1.0, 3.0, 30.0])
    np.testing.assert_allclose(rb.welsch(r, 3.0), 4.5 * (1 - np.exp(-r ** 2 / 9)))
    np.testing.assert_allclose(rb.welsch_weight(r, 3.0), np.exp(-r ** 2 / 9))
    np.testing.assert_allclose(rb.welsch(r, np.inf), r ** 2 / 2)
    assert rb.welsch(np.array(1e-3), 3.0) == pytest.approx(0.5e-6, rel=1e-5)   # ~ r²/2 near 0


# ---------------------------------------------------------------------------------------
# solver: denoising
# ---------------------------------------------------------------------------------------
def _tiny_problem(seed=0, T=14, L=2, M=4, K=3):
    rng = np.random.default_rng(seed)
    E = np.linalg.qr(rng.normal(size=(M * L, K)))[0]
    Y = rng.normal(size=(T, L)) * 3
    mask = rng.random((T, L)) > 0.2
    return Y, E, M, mask


@pytest.mark.parametrize("method", ["direct", "fft"])
def test_solver_matches_dense_quadratic_reference(method):
    Y, E, M, mask = _tiny_problem()
    lam = 0.3
    ref = rb.dense_quadratic_reference(Y, E, M, mask=mask, lam=lam)
    Z, info = rb.robust_filter(np.where(mask, Y, np.nan), E, M, mask=mask, lam=lam, p=np.inf,
                               max_iter=3000, tol=0.0, method=method, return_info=True)
    np.testing.assert_allclose(Z, ref, atol=1e-7)
    c = info.extra["cost"]
    assert np.all(np.diff(c) <= 1e-9 * c[0])           # never increases
    # the reference really is the minimiser: its cost is below a perturbed one
    n_t = windows.counts(len(Y), M)
    P = rb.WindowProjector(E, M, Y.shape[1], len(Y), "direct")
    J = lambda Z: rb.objective(Z, np.where(mask, Y, 0), mask, P(Z), n_t, lam, np.inf)  # noqa: E731
    assert J(ref) < J(ref + 1e-3 * np.random.default_rng(1).normal(size=ref.shape))
    assert abs(J(ref) - c[-1]) < 1e-8 * c[0]


def test_robust_cost_decreases_and_fill_step_is_exact():
    Y, E, M, mask = _tiny_problem(seed=3, T=40, L=3, M=5, K=4)
    Y[5, 1] += 40.0                                              # a spike
    Z, info = rb.robust_filter(Y, E, M, mask=mask, lam=0.1, p=3.0, max_iter=50, tol=0.0,
                               return_info=True)
    c = info.extra["cost"]
    assert np.all(np.diff(c) <= 1e-8 * c[0])
    assert info.extra["fill_cg_iter"] > 0
    # after the final fill step the missing entries minimise the bases term exactly:
    # gradient ((N - A) z)_m = 0
    n_t = windows.counts(len(Y), M)
    A = rb.WindowProjector(E, M, 3, len(Y), "direct")(Z)
    grad = n_t[:, None] * Z - A
    assert np.abs(grad[~mask]).max() < 1e-3 * np.abs(grad[mask]).max() + 1e-8


def test_robust_ignores_spikes_better_than_least_squares():
    freqs = (0.4, 0.9, 1.5)
    E, _, _ = rb.learn_bases([sinusoids(600, 6, freqs, seed=2)], 20, n_bases=6)
    truth = sinusoids(300, 6, freqs, phase0=1.7)
    rng = np.random.default_rng(5)
    Y = truth + rng.normal(scale=0.3, size=truth.shape)
    spikes = rng.random(truth.shape) < 0.1
    Y[spikes] += rng.choice([-1, 1], spikes.sum()) * 25.0
    rob = rb.robust_filter(Y, E, 20, lam=0.1, p=3.0, max_iter=30)
    ls = rb.robust_filter(Y, E, 20, lam=0.1, p=np.inf, max_iter=30)
    e_rob = np.sqrt(np.mean((rob - truth) ** 2))
    e_ls = np.sqrt(np.mean((ls - truth) ** 2))
    e_in = np.sqrt(np.mean((Y - truth) ** 2))
    assert e_rob < 0.3 * e_ls and e_rob < 0.05 * e_in
    assert e_rob < 0.4


def test_missing_frames_filled_from_bases():
    freqs = (0.4, 0.9, 1.5)
    E, _, _ = rb.learn_bases([sinusoids(600, 6, freqs, seed=2)], 20, n_bases=6)
    truth = sinusoids(200, 6, freqs, phase0=0.4)
    mask = np.ones(truth.shape, bool)
    mask[60:100, :3] = False               # 40-frame gap in half the channels
    mask[:, 5] = False                     # one channel never observed
    Y = np.where(mask, truth, np.nan)
    Z = rb.robust_filter(Y, E, 20, mask=mask)
    assert np.isfinite(Z).all()
    lin = np.sqrt(np.mean((np.interp(np.arange(60, 100), [59, 100], truth[[59, 100], 0]) - truth[60:100, 0]) ** 2))
    err_gap = np.sqrt(np.mean((Z - truth)[~mask] ** 2))
    assert err_gap < 0.05 * lin and err_gap < 0.1
    # the paper's plain alternation (no exact fill step) is far slower on the same gap
    Z0 = rb.robust_filter(Y, E, 20, mask=mask, fill_iter=0)
    assert np.sqrt(np.mean((Z0 - truth)[~mask] ** 2)) > err_gap


def test_solver_errors():
    E = np.linalg.qr(np.random.default_rng(0).normal(size=(8, 2)))[0]
    with pytest.raises(MocapValueError):
        rb.robust_filter(np.zeros((3, 2)), E, 4)                 # shorter than the window
    with pytest.raises(MocapValueError):
        rb.robust_filter(np.zeros((10, 3)), E, 4)                # bases do not fit
    with pytest.raises(MocapValueError):
        rb.robust_filter(np.zeros((10, 2)), E, 4, p=0)
    with pytest.raises(MocapValueError):
        rb.learn_bases([np.zeros((3, 2))], 4)                    # no window


# ---------------------------------------------------------------------------------------
# body frame
# ---------------------------------------------------------------------------------------
def test_body_frame_round_trip_exact_and_invariant():
    m = walker(seed=1)
    tr = heading_frame(m)
    local = tr.to_local(m.positions)
    np.testing.assert_allclose(tr.to_world(local), m.positions, atol=1e-9)
    np.testing.assert_allclose(tr.to_world(local.reshape(m.n_frames, -1)), m.matrix(), atol=1e-9)
    with pytest.raises(MocapValueError, match="positions must be"):
        tr.to_local(m.positions[1:])
    # the same motion elsewhere has the same local positions; facing another way too, up
    # to the per-coordinate running median of the root track (not rotation-equivariant)
    shifted = m.with_positions(m.positions + np.array([300.0, 0, -50.0]))
    np.testing.assert_allclose(heading_frame(shifted).to_local(shifted.positions), local, atol=1e-9)
    th = 1.1
    R = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    turned = m.with_positions(m.positions @ R.T)
    local2 = heading_frame(turned).to_local(turned.positions)
    np.testing.assert_allclose(local2, local, atol=0.1)
    assert np.abs(local2 - local).mean() < 0.01
    # lateral axis: left hip on +Z (first horizontal axis after Y), hips level in X
    li, ri = find_hips(m.skeleton)
    assert np.all(local[:, li, 2] - local[:, ri, 2] > 15)
    # missing joints stay NaN and the frame is still estimated
    gappy = m.with_observed(np.random.default_rng(0).random(m.observed.shape) > 0.3)
    trg = heading_frame(gappy)
    lg = trg.to_local(gappy.positions)
    assert np.array_equal(np.isnan(lg).any(axis=2), ~gappy.observed)
    assert np.isfinite(trg.origin).all() and np.isfinite(trg.rotation).all()


def test_find_hips_and_mirror_by_name():
    sk = Skeleton.from_positions(
        ("Hips", "LHipJoint", "LeftUpLeg", "LeftLeg", "RHipJoint", "RightUpLeg", "RightLeg", "Spine"),
        (-1, 0, 1, 2, 0, 4, 5, 0),
        np.array([[0, 90, 0], [0, 90, 0], [0, 88, 9], [0, 50, 9], [0, 90, 0], [0, 88, -9], [0, 50, -9],
                  [0, 110, 0]], float))
    # LHipJoint sits on the root (cgspeed BVH): the UpLeg joints are the hips
    assert find_hips(sk) == (2, 5)
    sk2 = Skeleton.from_positions(("root", "lhipjoint", "lfemur", "rhipjoint", "rfemur"),
                                  (-1, 0, 1, 0, 3),
                                  np.array([[0, 90, 0], [0, 88, 9], [0, 50, 9], [0, 88, -9], [0, 50, -9]], float))
    assert find_hips(sk2) == (1, 3)      # CMU ASF end points: lhipjoint is the hip centre
    perm = mirror_permutation(sk)
    assert [sk.names[i] for i in perm] == ["Hips", "RHipJoint", "RightUpLeg", "RightLeg", "LHipJoint",
                                           "LeftUpLeg", "LeftLeg", "Spine"]
    m = walker()
    local = heading_frame(m).to_local(m.positions)
    p = mirror_permutation(m.skeleton)
    np.testing.assert_allclose(mirror_local(mirror_local(local, p, 1), p, 1), local)


def test_marker_set_without_hierarchy_gets_the_same_frames():
    """One joint rule for both frames: the same clip as a flat marker set (TRC/C3D: no
    parents, zero offsets) finds the same hips and neck, so it gets the same frames."""
    from mocapkit.frames import frame_joints, pelvis_neck_frame

    names = ("root", "lhipjoint", "lfemur", "rhipjoint", "rfemur", "lowerback", "upperneck", "head")
    P0 = np.array([[0, 90, 0], [0, 88, 9], [0, 50, 9], [0, 88, -9], [0, 50, -9], [0, 110, 0],
                   [0, 150, 0], [0, 165, 0]], float)
    sk = Skeleton.from_positions(names, (-1, 0, 1, 0, 3, 0, 5, 6), P0)
    flat = Skeleton(names, -np.ones(len(names), int), np.zeros((len(names), 3)))
    assert find_hips(flat) == find_hips(sk) == (1, 3)
    assert frame_joints(flat) == frame_joints(sk)
    rng = np.random.default_rng(3)
    th = np.linspace(0, 2, 90)
    R = np.zeros((90, 3, 3))
    R[:, 1, 1] = 1
    R[:, 0, 0], R[:, 0, 2], R[:, 2, 0], R[:, 2, 2] = np.cos(th), np.sin(th), -np.sin(th), np.cos(th)
    W = np.einsum("tij,kj->tki", R, P0) + rng.normal(0, 0.3, (90, len(names), 3))
    m, mf = Motion(W, sk, 30.0), Motion(W, flat, 30.0)
    a, b = heading_frame(m), heading_frame(mf)
    np.testing.assert_array_equal(a.rotation, b.rotation)
    assert np.ptp(np.unwrap(a.heading(1))) > 1.5          # the heading follows the turn
    np.testing.assert_array_equal(pelvis_neck_frame(W, flat, 30.0).rotation,
                                  pelvis_neck_frame(W, sk, 30.0).rotation)


# ---------------------------------------------------------------------------------------
# the Denoiser
# ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def trained():
    train = [walker(T=240, seed=s, turn=0.2 * s, amp=1 + 0.1 * s) for s in range(3)]
    return denoise.get("lou-chai", window=10, energy=0.9999).fit(train)


def test_denoiser_removes_spikes_and_fills_gaps(trained):
    from mocapkit import corrupt, metrics

    truth = walker(T=200, seed=5, turn=-0.25, amp=1.05, phase=0.7)
    noisy, _ = corrupt.combine(truth, [("gaussian", {"sigma_cm": 1.0}),
                                       ("outliers", {"ratio": 0.1, "magnitude_cm": 15.0}),
                                       ("missing", {"ratio": 0.1})], seed=1)
    out = trained.denoise(noisy)
    assert out.positions.shape == truth.positions.shape and out.observed.all()
    e_in = metrics.rmse(truth, noisy, noisy.observed)
    e_out = metrics.rmse(truth, out)
    from mocapkit import gaps

    with gaps.use_policy(gaps.FILL_ALL):           # the paper's baseline fills every entry
        e_gauss = metrics.rmse(truth, denoise.get("gaussian", window=11).denoise(noisy))
    assert e_out < 0.2 * e_in and e_out < 0.5 * e_gauss
    # 120 fps input: split into 4 phases of the 30 fps model, same quality
    fast = walker(T=800, fps=120.0, seed=5, turn=-0.25, amp=1.05, phase=0.7)
    nf, _ = corrupt.combine(fast, [("gaussian", {"sigma_cm": 1.0})], seed=2)
    of = trained.denoise(nf)
    assert metrics.rmse(fast, of) < 0.6 * metrics.rmse(fast, nf)
    # 50 fps (not a multiple): resampled internally, still fine
    mid = walker(T=300, fps=50.0, seed=5, turn=-0.25, amp=1.05, phase=0.7)
    nm, _ = corrupt.combine(mid, [("gaussian", {"sigma_cm": 1.0})], seed=2)
    assert metrics.rmse(mid, trained.denoise(nm)) < 0.8 * metrics.rmse(mid, nm)
    # short clip (fewer frames than the window): padded with missing frames
    short = trained.denoise(noisy.slice(0, 4))
    assert short.positions.shape == (4, truth.n_joints, 3) and np.isfinite(short.positions).all()


def test_save_load_round_trip(trained, tmp_path):
    from mocapkit.denoise.base import Denoiser

    truth = walker(T=120, seed=4)
    path = tmp_path / "walk.npz"
    trained.save(path)
    back = Denoiser.load(path)
    assert type(back) is type(trained) and back.get_params() == trained.get_params()
    np.testing.assert_array_equal(back.bases_, trained.bases_)
    assert back.joint_names_ == trained.joint_names_ and back.window_ == 10
    np.testing.assert_array_equal(back.denoise(truth).positions, trained.denoise(truth).positions)


def test_denoiser_errors(trained):
    with pytest.raises(NotFittedError):
        denoise.get("lou-chai").denoise(walker(T=50))
    with pytest.raises(MocapValueError):
        denoise.get("lou-chai", space="joint").fit([walker(T=50)])
    other = Motion(np.zeros((30, 2, 3)), Skeleton(("a", "b"), (-1, 0), np.zeros((2, 3))), 30)
    with pytest.raises(MocapValueError, match="skeleton"):
        trained.denoise(other)
    with pytest.raises(MocapValueError, match="space='angle'"):   # no joint-angle channels
        denoise.get("lou-chai", space="angle").fit([walker(T=50)])
    with pytest.raises(MocapError):
        denoise.get("lou-chai", window=100).fit([walker(T=50)])


# ---------------------------------------------------------------------------------------
# real data
# ---------------------------------------------------------------------------------------
def test_real_walk_position_and_angle_space(shared_data):
    pytest.importorskip("mocapkit.io.amc")
    from mocapkit import corrupt, io, metrics
    from mocapkit.denoise.bases import angle_channels, decimate

    def clip(t):
        return decimate(io.read(shared_data / "cmu" / "asfamc" / t.split("_")[0] / f"{t}.amc").slice(8), 4)

    train = [clip(t) for t in ("131_01", "131_09", "131_14", "07_03")]
    truth = clip("131_02")
    noisy, _ = corrupt.combine(truth, [("gaussian", {"sigma_cm": 1.0}),
                                       ("outliers", {"ratio": 0.1, "magnitude_cm": 15.0})], seed=0)
    lc = denoise.get("lou-chai", window=10, energy=0.999).fit(train)
    out = lc.denoise(noisy)
    e_in, e_out = metrics.rmse(truth, noisy), metrics.rmse(truth, out)
    e_g = metrics.rmse(truth, denoise.get("gaussian", window=11).denoise(noisy))
    assert e_out < 0.35 * e_in and e_out < e_g
    # joint-angle space: denoise the AMC dofs, FK through the reader, channels carried along
    la = denoise.get("lou-chai", window=10, space="angle", energy=0.9999).fit(train)
    V, names, info = angle_channels(truth)
    joint = info["rotation"] & ~info["root"]
    Vn = V.copy()
    Vn[:, joint] += np.random.default_rng(0).normal(scale=3.0, size=(len(V), joint.sum()))
    from mocapkit.denoise.bases import angle_fk

    noisy_a = truth.with_positions(angle_fk(truth, Vn)).with_source(per_frame={"dofs": Vn})
    out_a = la.denoise(noisy_a)
    Vo = out_a.source["per_frame"]["dofs"]
    d = (Vo - V)[:, joint]
    assert np.abs(d).max() < 180                       # same turn as the file's values
    assert np.sqrt(np.mean(d ** 2)) < 0.8 * 3.0
    np.testing.assert_allclose(angle_fk(truth, Vo), out_a.positions, atol=1e-9)
    # 120 fps input in angle space (4 phases) keeps channels aligned with frames
    full = io.read(shared_data / "cmu" / "asfamc" / "131" / "131_02.amc").slice(8, 208)
    o120 = la.denoise(full)
    assert o120.source["per_frame"]["dofs"].shape == full.source["per_frame"]["dofs"].shape
    assert metrics.rmse(full, o120) < 3.0
