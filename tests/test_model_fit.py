"""A model that does not fit the motion: the markers it moved beyond the input's noise are
given back as measured (mocapkit.denoise.base.check_model_fit, mocapkit.gaps.model_misfit)."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from mocapkit import cli, corrupt, datasets, denoise, gaps
from mocapkit import io as mio
from mocapkit.denoise.base import check_model_fit
from mocapkit.errors import MocapWarning, TrainingMismatchWarning


def _noisy(m, sigma, seed=0):
    return corrupt.gaussian(m, sigma_cm=sigma, seed=seed)[0]


class _Stub:
    name = "stub"


@pytest.fixture(scope="module")
def clip():
    return mio.read(datasets.bundled("09_06.amc"))


def _caught(fn):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        out = fn()
    return out, [x for x in w if issubclass(x.category, TrainingMismatchWarning)]


def test_threshold_on_known_changes(clip):
    inp = _noisy(clip, 1.0)
    d = _Stub()
    back, w = _caught(lambda: check_model_fit(d, inp, clip))     # perfect denoiser: moves by the noise
    info = d.last_report_["model_fit"]
    assert w == [] and not back.any() and info["mismatch"] is False and info["markers"] == []
    assert 0.8 < info["noise_cm"] < 1.2 and info["threshold_cm"] == pytest.approx(2 * info["noise_cm"])
    assert 0.85 < info["moved_rms_cm"] < 1.3               # RMS |N(0, 1)| per coordinate, the worst marker
    assert info["n_markers"] == 31 and info["kind"] == "learned"
    moved = clip.positions.copy()
    moved[:, 5] += 3.0                                     # one marker 3 cm off on every axis
    back, w = _caught(lambda: check_model_fit(d, inp, clip.with_positions(moved)))
    info = d.last_report_["model_fit"]
    assert back[:, 5].all() and not np.delete(back, 5, axis=1).any()
    assert info["markers"] == [clip.skeleton.names[5]] and info["samples"] == clip.n_frames
    assert len(w) == 1 and issubclass(w[0].category, MocapWarning)
    msg = str(w[0].message)
    assert msg.startswith("stub:") and "1 of 31 markers" in msg and "written as measured" in msg
    back, w = _caught(lambda: check_model_fit(d, inp, clip.with_positions(moved), give_back=False))
    assert back is None and "written as the model put them" in str(w[0].message)


def test_spikes_keep_the_model_values():
    """Where the input has a spike the model removed, its value is kept even on a marker
    given back; everywhere else the measurement comes back."""
    rng = np.random.default_rng(0)
    T, J = 200, 4
    t = np.arange(T)[:, None, None] / 60.0
    truth = np.concatenate([np.sin(t * (1 + j)) * 20.0 + j * 10.0 for j in range(J)], axis=1)
    truth = np.broadcast_to(truth[..., :1], (T, J, 3)).copy()
    P = truth + rng.normal(0, 0.05, truth.shape)
    P[50, 0] += 15.0                                       # a spike on marker 0 (frame 50) and the first frame
    P[0, 0] += 15.0
    Q = truth + 0.4                                        # the model: spikes gone, 0.4 cm off everywhere
    Q[:, 1:] = P[:, 1:]                                    # markers 1-3 untouched
    obs = np.ones((T, J), bool)
    back, rms, _ = gaps.model_misfit(P, obs, Q, 0.05, 2.0)
    # the spikes and the samples whose neighbours' cubic they throw off (2.5-10 cm) keep the model's value
    assert set(np.flatnonzero(~back[:, 0])) == {0, 2, 48, 49, 50, 51, 52} and not back[:, 1:].any()
    assert rms[0] == pytest.approx(0.4, abs=0.02) and np.all(rms[1:] == 0)
    obs[8:, 2] = False                                     # too few samples judged: not judged
    Q[:, 2] += 5.0
    back, rms, _ = gaps.model_misfit(P, obs, Q, 0.05, 2.0)
    assert np.isnan(rms[2]) and not back[:, 2].any()


def test_local_misfits_go_back_one_by_one():
    """A model that fits a marker but for a few frames it moved far where the input is
    smooth (beside a jump it smoothed across): those samples go back on their own, the
    marker is judged without them and keeps the model's values elsewhere; a spike the
    model removed stays removed."""
    rng = np.random.default_rng(1)
    T, J = 6000, 3                                         # local: on at most 0.5 % of a marker's samples
    t = np.arange(T)[:, None, None] / 60.0
    truth = np.concatenate([np.sin(t * (1 + j)) * 20.0 + j * 10.0 for j in range(J)], axis=1)
    truth = np.broadcast_to(truth[..., :1], (T, J, 3)).copy()
    truth[300:, 0] += 200.0                                # marker 0 jumps 2 m at frame 300
    P = truth + rng.normal(0, 0.1, truth.shape)
    P[100, 1] += 5.0                                       # a spike on marker 1
    Q = truth + rng.normal(0, 0.03, truth.shape)           # the model: the noise mostly gone
    ramp = np.clip((np.arange(T) - 290) / 20.0, 0, 1)[:, None] * 200.0
    Q[280:320, 0] = truth[280:320, 0] - truth[280:320, 0] + truth[279, 0] + ramp[280:320]  # smoothed across
    obs = np.ones((T, J), bool)
    back, rms, local = gaps.model_misfit(P, obs, Q, 0.1, 2.0)
    far = np.linalg.norm(Q - P, axis=2) > 4 * np.sqrt(3) * 0.1
    assert local[:, 0].sum() > 10 and not local[:, 1:].any()
    assert np.array_equal(back, local)                     # no marker given back as a whole
    assert set(np.flatnonzero(local[:, 0])) <= set(np.flatnonzero(far[:, 0]))
    assert not local[:270, 0].any() and not local[330:, 0].any()
    assert rms[0] < 0.2 and not back[100, 1]               # judged without them; the spike stays removed
    # the same model on a tenth of the take: too many to be local, the marker goes back whole
    short = gaps.model_misfit(P[:600], obs[:600], Q[:600], 0.1, 2.0)[0]
    assert short[:, 0].sum() > 500 and not short[:, 1:].any()
    # the guard's report and its one line
    from mocapkit.motion import Motion
    from mocapkit.skeleton import Skeleton

    sk = Skeleton(("a", "b", "c"), [-1] * 3, np.zeros((3, 3)))
    d = type("Fitted", (), {"name": "fitted", "misfit_check": "fitted"})()
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        got = check_model_fit(d, Motion(P, sk, 60.0), Motion(Q, sk, 60.0))
    info = d.last_report_["model_fit"]
    assert info["markers"] == [] and info["local_samples"] == local.sum() and info["local_markers"] == 1
    assert np.array_equal(got, local)
    msg = str(w[-1].message)
    assert f"{local.sum()} measured samples of 1 markers" in msg and "the input is smooth" in msg, msg
    assert "written as measured" in msg
    # moves under 1 mm (gaps.MISFIT_LOCAL_WARN_CM) go back too, without a line
    P2 = truth + rng.normal(0, 0.004, truth.shape)
    Q2 = truth.copy()
    Q2[1000:1004, 2] += 0.05                               # a 0.9 mm bump where the input is smooth
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        got = check_model_fit(d, Motion(P2, sk, 60.0), Motion(Q2, sk, 60.0))
    info = d.last_report_["model_fit"]
    assert got[1000:1004, 2].all() and info["local_samples"] >= 4 and info["local_max_cm"] < 0.1
    assert not [x for x in w if "the model moved" in str(x.message)]


def test_lou_chai_self_vs_other_behaviour(clip):
    """Trained on other behaviours lou-chai replaces the run: what it moved beyond the
    noise comes back as measured, and the result is then nearer the truth."""
    inp = _noisy(clip, 0.5)
    other = denoise.get("lou-chai").fit([mio.read(datasets.bundled(c + ".amc")) for c in ("16_15", "07_05")])
    with gaps.use_policy(misfit_factor=None):
        kept, _ = _caught(lambda: other.denoise(inp))
    out, w = _caught(lambda: other.denoise(inp))
    info = out.source["model_fit"]
    assert len(w) == 1 and info["mismatch"] and info["given_back"] and info["samples"] > 0
    rep = out.source["gap_report"]       # samples moved more than 5 cm are counted as such first
    assert 0 < rep["kept_measured_misfit"] <= info["samples"] <= rep["kept_measured_misfit"] + rep["kept_measured"]
    # one line for both: the samples moved far are on markers it names, and it counts them
    assert f"{rep['kept_measured_misfit'] + rep['kept_measured']} measured samples are written" in str(w[0].message)
    from mocapkit import metrics
    e_kept, e_out, e_in = (float(metrics.rmse(clip, m)) for m in (kept, out, inp))
    assert e_kept > e_in and e_out < e_kept                 # worse than the input; less so given back
    own = denoise.get("lou-chai").fit([clip])
    out, _ = _caught(lambda: own.denoise(inp))
    assert float(metrics.rmse(clip, out)) < e_in           # cleaned: never worse than the input


def test_fill_all_gives_nothing_back(clip):
    inp = _noisy(clip, 0.5)
    other = denoise.get("lou-chai").fit([mio.read(datasets.bundled("16_15.amc"))])
    with gaps.use_policy(gaps.FILL_ALL):
        out, w = _caught(lambda: other.denoise(inp))
    assert out.source["model_fit"]["mismatch"] and not out.source["model_fit"]["given_back"]
    assert len(w) == 1 and "written as the model put them" in str(w[0].message)


def test_cli_prints_one_line(tmp_path, capsys, clip):
    model = tmp_path / "walk.npz"
    denoise.get("lou-chai").fit([mio.read(datasets.bundled("16_15.amc"))]).save(model)
    src = tmp_path / "in.trc"
    mio.write(_noisy(clip, 0.1), src)
    with warnings.catch_warnings():
        warnings.simplefilter("default")            # independent of pytest's -W options
        rc = cli.main(["denoise", str(src), str(tmp_path / "out.trc"), "--method", "lou-chai",
                       "--model", str(model), "-q"])
    err = capsys.readouterr().err
    assert rc == 0 and (tmp_path / "out.trc").exists()
    lines = [ln for ln in err.splitlines() if "training clips probably do not cover" in ln]
    assert len(lines) == 1 and lines[0].startswith("mocapkit denoise: warning: lou-chai:")
    assert "written as measured" in lines[0]


def test_cli_keep_moves_writes_the_model_values(tmp_path, capsys, clip):
    model = tmp_path / "walk.npz"
    denoise.get("lou-chai").fit([mio.read(datasets.bundled("16_15.amc"))]).save(model)
    src = tmp_path / "in.trc"
    mio.write(_noisy(clip, 0.1), src)
    outs = {}
    for flag in ([], ["--keep-moves"]):
        out = tmp_path / f"out{len(flag)}.trc"
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            assert cli.main(["denoise", str(src), str(out), "--method", "lou-chai", "--model", str(model),
                             "-q", *flag]) == 0
        outs[len(flag)] = mio.read(out).positions
        err = capsys.readouterr().err
        assert ("written as the model put them" in err) == bool(flag)
    given = mio.read(src).positions
    # by default most samples come back as measured; with --keep-moves none does
    assert np.mean(np.all(np.isclose(outs[0], given, atol=1e-3), axis=2)) > 0.5
    assert np.mean(np.all(np.isclose(outs[1], given, atol=1e-3), axis=2)) < 0.1


def test_low_rank_on_a_clean_clip_gives_back(clip):
    """rpca, a low-rank model fitted to the clip, moves a clean clip's markers by far more
    than their noise: those come back as measured (ModelMisfitWarning) and the result is
    nearer the truth; under FILL_ALL (the papers' protocols) its values are written."""
    from mocapkit import metrics
    from mocapkit.errors import ModelMisfitWarning

    rp = denoise.get("rpca")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        out = rp.denoise(clip)
        with gaps.use_policy(gaps.FILL_ALL):
            paper = rp.denoise(clip)
    mis = [x for x in w if issubclass(x.category, ModelMisfitWarning)]
    assert mis and not issubclass(mis[0].category, TrainingMismatchWarning)
    assert "its model does not fit these markers" in str(mis[0].message) and "Use --method auto" in str(mis[0].message)
    assert out.source["model_fit"]["given_back"] and not paper.source["model_fit"]["given_back"]
    assert float(metrics.rmse(clip, out)) < 0.5 * float(metrics.rmse(clip, paper))
