"""Non-convergence reporting of the iterative solvers (issue 10).

svt / rpca / slra (mocapkit.solvers.lowrank), lou-chai (mocapkit.solvers.robust_bases) and the
thesis solvers tsmc / trnn (mocapkit.solvers.completion) record ``source["convergence"]`` on the
Denoiser and emit exactly one ConvergenceWarning per denoise() call when they stop at max_iter.
Measured status at default settings: docs/results/reliability.md (benchmarks/reliability_memory.py).
"""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from mocapkit import cli, corrupt, datasets, denoise, gaps
from mocapkit import io as mio
from mocapkit.denoise.base import report_convergence
from mocapkit.errors import ConvergenceWarning
from mocapkit.solvers import completion as cp
from mocapkit.solvers import lowrank as lr
from mocapkit.solvers.info import SolveInfo

ITERATIVE = ["svt", "rpca", "slra", "tsmc", "trnn", "lou-chai"]
# default settings on the bundled clips (1 cm noise, 5 % missing): these converge ...
CONVERGE_AT_DEFAULTS = ["rpca", "slra", "tsmc", "trnn"]
# ... and these do not (a finding, documented in docs/results/reliability.md; do not hide it
# by loosening tol -- if a change makes them converge, move them up and update the doc)
NOT_CONVERGED_AT_DEFAULTS = ["svt", "lou-chai"]


def _noisy(m, seed=0, missing=0.05):
    """1 cm noise and ``missing`` of the joint entries removed (uniformly), as the benchmark."""
    steps = [("gaussian", {"sigma_cm": 1.0})] + (
        [("missing", {"ratio": missing, "per_frame": False})] if missing else [])
    return corrupt.combine(m, steps, seed=seed)[0]


@pytest.fixture(scope="module")
def clip():
    return mio.read(datasets.bundled("16_15.amc"))


@pytest.fixture(scope="module")
def lou_chai_model():
    train = mio.read(datasets.bundled("07_05.amc"))
    return denoise.get("lou-chai").fit([train])


def _method(name, model, **params):
    if name == "lou-chai":                          # shared fitted model: default max_iter = 20
        return model.set_params(max_iter=params.get("max_iter", 20),
                                warn_convergence=params.get("warn_convergence", False))
    return denoise.get(name, **params)


def _run(d, motion):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = d.denoise(motion)
    conv = [w for w in caught if issubclass(w.category, ConvergenceWarning)]
    return out, conv


@pytest.mark.parametrize("name", ITERATIVE)
def test_max_iter_1_warns_once_and_records(clip, lou_chai_model, name):
    kw = {"warn_convergence": True} if name == "lou-chai" else {}
    d = _method(name, lou_chai_model, max_iter=1, **kw)
    out, conv = _run(d, _noisy(clip.slice(0, 120)))
    assert len(conv) == 1, [str(w.message) for w in conv]
    msg = str(conv[0].message)
    assert msg.startswith(f"{name}: ") and "not converged after 1 iterations" in msg
    assert "max_iter" in msg and "tol" in msg
    s = d.last_report_["convergence"]
    assert s["method"] == name and s["converged"] is False
    assert s["iterations"] == 1 and s["max_iter"] == 1 and s["n_not_converged"] >= 1
    # one iteration is not a solution, but never garbage: an estimate far from the data
    # (tsmc / trnn / svt / rpca after 1 iteration: every marker near the origin, 14-80 cm
    # off) is replaced by the measured samples + linear gaps, with a MocapWarning
    # (issue 18); whatever the gap policy leaves missing is NaN
    inp = _noisy(clip.slice(0, 120))
    assert out.observed[inp.observed].all()
    assert np.isfinite(out.positions[out.observed]).all()
    assert np.isnan(out.positions[~out.observed]).all()
    d = (out.positions - inp.positions)[inp.observed]
    assert np.sqrt(np.mean(d ** 2)) < 5.0, name
    json.dumps(s)                                     # JSON-able, so Denoiser.save can keep it


@pytest.mark.parametrize("name", CONVERGE_AT_DEFAULTS)
def test_defaults_converge_without_warning(clip, name):
    d = denoise.get(name)
    _, conv = _run(d, _noisy(clip))
    assert conv == []
    s = d.last_report_["convergence"]
    assert s["converged"] is True and s["n_not_converged"] == 0
    assert 1 <= s["iterations"] < s["max_iter"] and s["residual"] < s["tol"]


@pytest.mark.parametrize("name", NOT_CONVERGED_AT_DEFAULTS)
def test_defaults_known_non_convergence_is_reported(clip, lou_chai_model, name):
    d = _method(name, lou_chai_model)
    _, conv = _run(d, _noisy(clip))
    # lou-chai: the paper's fixed 10-20 iterations are the method (more iterations raise the
    # error, see LouChai's docstring) -> recorded, warned only with warn_convergence=True
    assert len(conv) == (0 if name == "lou-chai" else 1)
    assert d.last_report_["convergence"]["converged"] is False
    assert d.last_report_["convergence"]["iterations"] == d.last_report_["convergence"]["max_iter"]
    if name == "lou-chai":
        _, conv = _run(_method(name, lou_chai_model, warn_convergence=True), _noisy(clip))
        assert len(conv) == 1


def test_svt_fully_observed_is_closed_form(clip):
    d = denoise.get("svt")
    _, conv = _run(d, _noisy(clip, missing=0.0))
    assert conv == [] and d.last_report_["convergence"]["converged"] is True and d.last_report_["convergence"]["iterations"] == 0


def test_reporting_does_not_change_results(clip):
    m = _noisy(clip.slice(0, 200))
    X, M = m.matrix(), m.matrix_mask()
    A0, E0 = lr.slra(X, 50, mask=M, tol=1e-5)
    A1, E1, info = lr.slra(X, 50, mask=M, tol=1e-5, return_info=True)
    np.testing.assert_array_equal(A0, A1)
    assert (info.residual[info.converged] < 1e-5).all()
    with gaps.use_policy(move_margin_cm=None, misfit_factor=None):
        # (the default policy gives back the 3 measured samples slra moves 10-15 cm at
        # its segment boundary at frames 98-100, where the walk is smooth, and the misfit
        # check those it moves far at frames 49-50, one by one: local misfits)
        out = denoise.get("slra", segment=50, tol=1e-5, missing="free").denoise(m)
    np.testing.assert_array_equal(out.matrix(), A0)
    B0, _ = lr.rpca_ialm(X, mask=M, max_iter=3)
    B1, _, inf1 = lr.rpca_ialm(X, mask=M, max_iter=3, return_info=True)
    np.testing.assert_array_equal(B0, B1)
    assert inf1.converged is False and inf1.residual >= 1e-7
    # the residual reported is the real one: ||D - A - E|| / ||D|| on observed entries
    B2, E2, inf2 = lr.rpca_ialm(X, mask=M, tol=1e-3, return_info=True)
    D = np.where(M, X, 0.0)
    rel = np.linalg.norm(np.where(M, D - B2 - E2, 0.0)) / np.linalg.norm(D)
    assert inf2.converged and rel < 1e-3 and inf2.residual < 1e-3


def test_vectorised_summary_reports_worst_segment():
    class Dummy:
        name = "slra"

    d = Dummy()
    with pytest.warns(ConvergenceWarning, match=r"slra: 2 of 3 segments not converged after 10 "
                                                r"iterations \(max_iter=10; .*3\.00e-05"):
        s = report_convergence(d, SolveInfo([4, 10, 10], [True, False, False], [1e-8, 3e-5, 2e-5],
                                            "relative residual"), tol=1e-7, max_iter=10)
    assert s == d.last_report_["convergence"]
    assert s["n_solves"] == 3 and s["n_not_converged"] == 2 and s["residual"] == 3e-5
    assert s["iterations"] == 10 and s["converged"] is False


def test_list_of_solves_is_one_summary():
    """A list of SolveInfo (Lou-Chai phases, Xiao's ADMM solves) is summarised as one batch."""
    class Dummy:
        name = "demo"

    infos = [SolveInfo(3, True, 1e-6, "relative change of J"),
             SolveInfo(np.array([5, 9]), np.array([False, True]), np.array([2e-3, 1e-7]),
                       "relative change of J")]
    with pytest.warns(ConvergenceWarning, match=r"demo: 1 of 3 phases not converged after 5 "
                                                r"iterations .*final relative change of J 2\.00e-03"):
        s = report_convergence(Dummy(), infos, tol=1e-4, max_iter=9, unit="phase")
    assert s["n_solves"] == 3 and s["iterations"] == 9 and s["residual"] == 2e-3
    assert s["criterion"] == "relative change of J"


@pytest.mark.parametrize("solve", [
    lambda X: cp.tsmc(X, max_iter=1, return_info=True),
    lambda X: cp.trnn(X, max_iter=1, return_info=True),
    lambda X: cp.lds_em_complete(X, np.random.default_rng(0).random(X.shape) > 0.2, k=4,
                                 max_iter=1, return_info=True)])
def test_solver_warning_is_one_convergence_warning(solve):
    """The solvers' own warning (one path, mocapkit.solvers.info.warn_not_converged) is a
    ConvergenceWarning -- not a RuntimeWarning, which means a numpy problem -- naming the
    iterations, max_iter and the criterion with its final value, at the caller's line."""
    X = np.sin(np.arange(60)[:, None] / 7.0 + np.arange(6)) * 10
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _, info = solve(X)
    assert len(caught) == 1 and caught[0].category is ConvergenceWarning, caught
    assert not issubclass(caught[0].category, RuntimeWarning)
    msg = str(caught[0].message)
    assert "not converged after 1 iterations (max_iter=1;" in msg
    assert f"final {info.criterion} {info.residual:.2e}" in msg and not info.converged
    assert caught[0].filename == __file__              # points at the caller


def test_convergence_summary_on_the_result_never_saved(clip, tmp_path):
    d = denoise.get("slra", max_iter=2)
    with pytest.warns(ConvergenceWarning):
        out = d.denoise(_noisy(clip.slice(0, 60)))
    assert out.source["convergence"] == d.last_report_["convergence"]
    assert out.source["convergence"]["converged"] is False
    d.save(tmp_path / "m.npz")
    back = denoise.Denoiser.load(tmp_path / "m.npz")
    assert not hasattr(back, "last_report_") and not hasattr(back, "convergence_")


def test_cli_shows_one_line_warning(tmp_path, capsys):
    src = datasets.bundled("16_15.bvh")
    with warnings.catch_warnings():
        warnings.simplefilter("default", ConvergenceWarning)     # whatever -W the run uses
        rc = cli.main(["denoise", str(src), str(tmp_path / "out.bvh"), "--method", "rpca",
                       "--param", "max_iter=1", "-q"])
    assert rc == 0
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    # one line per warning: the solver's, and the guard's -- one iteration of rpca moves
    # every marker by tens of cm where the walk is smooth: written as measured (the
    # samples moved over 5 cm are among them: no second line about those)
    assert len(lines) == 2, err
    assert lines[0].startswith("mocapkit denoise: warning: rpca: not converged after 1 iterations")
    assert lines[1].startswith("mocapkit denoise: warning: rpca: the model moved 29 of 29 markers")
    assert "written as measured" in lines[1]
    # --keep-moves: the method's values as they are (the solver's warning only)
    with warnings.catch_warnings():
        warnings.simplefilter("default", ConvergenceWarning)
        rc = cli.main(["denoise", str(src), str(tmp_path / "raw.bvh"), "--method", "rpca",
                       "--param", "max_iter=1", "--keep-moves", "-q"])
    err = capsys.readouterr().err
    assert rc == 0 and "written as measured" not in err and "not converged" in err
    assert "Traceback" not in err and ".py:" not in err
