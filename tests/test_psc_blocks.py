"""psc on a clip longer than one block (issue 21): the windows coded a block at a time,
the local frame and the refinement applied by blocks give exactly the numbers of one
block -- with gaps, outliers and a body part missing for longer than a window."""
import numpy as np

from mocapkit import Motion, corrupt, denoise, io
from mocapkit.datasets import bundled
from mocapkit import windows


def test_blocked_psc_equals_one_block(monkeypatch):
    clip = io.read(bundled("16_15.amc"))
    model = denoise.get("psc", n_atoms=32, n_iter=1, max_windows=400).fit([clip])
    m = Motion(np.tile(clip.positions, (3, 1, 1)), clip.skeleton, clip.fps)   # 1,413 frames
    m, _ = corrupt.combine(m, [("gaussian", {"sigma_cm": 0.5}), ("missing", {"ratio": 0.1}),
                               ("outliers", {"ratio": 0.01, "magnitude_cm": 20.0})], seed=2)
    obs = m.observed.copy()
    arm = model.parts_[model.part_names_.index("left_arm")]
    obs[300:340, arm] = False                    # a whole part missing for > one window
    m = m.with_positions(np.where(obs[..., None], m.positions, np.nan), obs)
    monkeypatch.setattr(windows, "BLOCK_BYTES", 2 ** 40)
    monkeypatch.setattr(windows, "FRAME_BLOCK", 10 ** 9)
    one = model.denoise(m)
    monkeypatch.setattr(windows, "BLOCK_BYTES", 1)            # 256 windows per block
    monkeypatch.setattr(windows, "FRAME_BLOCK", 100)
    many = model.denoise(m)
    assert np.isfinite(one.positions[one.observed]).all()
    np.testing.assert_allclose(many.positions, one.positions, rtol=0, atol=1e-9)   # bit-equal here; BLAS may round differently elsewhere
    np.testing.assert_array_equal(many.observed, one.observed)
