"""CLI path safety and one-line errors (issue 18).

One rule (``mocapkit.io._atomic.check_output_path``) for every file a command writes: never
an input (motion, the ASF skeleton an AMC resolves to, training clips, models), never a
folder, never a non-regular file, never two outputs of one command on one path, and
``--force`` only replaces an existing regular file. Every refusal is one stderr line with
exit code 2 and leaves every file as it was.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mocapkit import io
from mocapkit.cli import main
from mocapkit.datasets import bundled

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def work(tmp_path, monkeypatch):
    """tmp folder (the cwd) with in.bvh, dir/16_15.amc + dir/16.asf, and trn/ (07_05 + 07.asf)."""
    monkeypatch.chdir(tmp_path)
    shutil.copy(bundled("16_15.bvh"), tmp_path / "in.bvh")
    amc = bundled("16_15.amc")
    (tmp_path / "dir").mkdir()
    shutil.copy(amc, tmp_path / "dir" / "16_15.amc")
    shutil.copy(amc.parent / "16.asf", tmp_path / "dir" / "16.asf")
    trn = tmp_path / "trn"
    trn.mkdir()
    seven = bundled("07_05.amc")
    shutil.copy(seven, trn / "07_05.amc")
    shutil.copy(seven.parent / "07.asf", trn / "07.asf")
    return tmp_path


def _snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _refused(capsys, argv, *, must_say: str = "") -> str:
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2, (argv, rc, err)
    assert err.count("\n") == 0 and err.startswith(f"mocapkit {argv[0]}: error:"), err
    assert "Traceback" not in err
    if must_say:
        assert must_say in err, err
    return err


def _unchanged(work, before, argv, capsys, must_say=""):
    err = _refused(capsys, argv, must_say=must_say)
    assert _snapshot(work) == before, f"{argv} changed files"
    return err


# ---------------------------------------------------------------------------------------
# inputs are never overwritten
# ---------------------------------------------------------------------------------------
def test_corrupt_mask_never_an_input_nor_the_output(work, capsys):
    before = _snapshot(work)
    base = ["corrupt", "in.bvh", "n2.bvh", "--gaussian-cm", "2", "-q"]
    _unchanged(work, before, base + ["--mask", "in.bvh"], capsys, "input file")
    _unchanged(work, before, base + ["--mask", "in.bvh", "--force"], capsys, "input file")
    _unchanged(work, before, base + ["--mask", "n2.bvh"], capsys, "another output")
    _unchanged(work, before, base + ["--mask", "./n2.bvh", "--force"], capsys, "another output")
    _unchanged(work, before, base + ["--mask", "m.txt"], capsys, ".npy")
    # an existing mask is only replaced with --force
    (work / "m.npy").write_bytes(b"mine")
    before = _snapshot(work)
    _unchanged(work, before, base + ["--mask", "m.npy"], capsys, "exists")
    assert main(base + ["--mask", "m.npy", "--force"]) == 0
    assert np.load(work / "m.npy").shape == io.read(work / "in.bvh").observed.shape


@pytest.mark.parametrize("cmd", ["denoise", "corrupt"])
def test_amc_skeleton_is_an_input(work, capsys, cmd):
    extra = ["--gaussian-cm", "1"] if cmd == "corrupt" else ["--method", "median"]
    before = _snapshot(work)
    # the .asf found beside the AMC
    _unchanged(work, before, [cmd, "dir/16_15.amc", "dir/16.asf", "--force", "-q"] + extra, capsys, "input file")
    _unchanged(work, before, [cmd, "dir/16_15.amc", "dir/../dir/16.asf", "--force", "-q"] + extra, capsys,
               "input file")
    # the one given with --skeleton
    shutil.copy(work / "dir" / "16.asf", work / "sk.asf")
    before = _snapshot(work)
    _unchanged(work, before, [cmd, "dir/16_15.amc", "sk.asf", "--skeleton", "sk.asf", "--force", "-q"] + extra,
               capsys, "input file")


def test_asf_output_refused_not_filled_with_amc_text(work, capsys):
    """`denoise x.asf out.asf` wrote AMC text into out.asf."""
    before = _snapshot(work)
    for src in ("dir/16.asf", "dir/16_15.amc"):
        err = _unchanged(work, before, ["denoise", src, "out.asf", "--method", "median", "-q"], capsys)
        assert "skeleton" in err and ".amc" in err
    assert not (work / "out.asf").exists()


def test_train_never_overwrites_a_training_clip(work, capsys):
    before = _snapshot(work)
    base = ["train", "--method", "kalman-learned", "-q", "--force"]
    _unchanged(work, before, base + ["--data", "trn", "-o", "trn/07_05.amc"], capsys, "input file")
    _unchanged(work, before, base + ["--data", "trn", "-o", "trn/07.asf"], capsys, "input file")
    _unchanged(work, before, base + ["trn/07_05.amc", "-o", "trn/07.asf"], capsys, "input file")
    _unchanged(work, before, base + ["in.bvh", "-o", "in.bvh"], capsys, "input file")
    _unchanged(work, before, base + ["--data", "trn", "-o", "trn"], capsys, "folder")


def test_reports_and_detect_never_overwrite_the_skeleton(work, capsys):
    before = _snapshot(work)
    _unchanged(work, before, ["detect", "dir/16_15.amc", "-o", "dir/16.asf", "--force"], capsys, "input file")
    _unchanged(work, before, ["report", "dir/16_15.amc", "-o", "dir/16.asf", "--force"], capsys, "input file")
    _unchanged(work, before, ["index", "build", "trn", "-o", "trn/07.asf", "--force", "-q"], capsys, "input file")
    _unchanged(work, before, ["index", "build", "trn", "-o", "trn/07_05.amc", "--force", "-q"], capsys,
               "input file")
    _unchanged(work, before, ["classify", "train", "trn", "-o", "trn/07_05.amc", "--force", "-q"], capsys,
               "input file")


def test_bench_outputs_checked_before_running(work, capsys):
    (work / "r.json").write_text("[]")
    before = _snapshot(work)
    _unchanged(work, before, ["bench", "smoke", "--quick", "--out", "r.json", "-q"], capsys, "exists")
    _unchanged(work, before, ["bench", "smoke", "--quick", "--out", "r.md", "-q"], capsys, "another output")
    _unchanged(work, before, ["bench", "smoke", "--quick", "--out", "dir", "-q"], capsys, "folder")
    _unchanged(work, before, ["bench", "no-such-protocol", "--out", "x.json", "-q"], capsys, "unknown protocol")


# ---------------------------------------------------------------------------------------
# folders, special files, --force
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv", [
    ["denoise", "in.bvh", "{d}", "--method", "median", "-q"],
    ["denoise", "in.bvh", "{d}/", "--method", "median", "-q", "--force"],
    ["corrupt", "in.bvh", "{d}", "--gaussian-cm", "1", "-q", "--force"],
    ["corrupt", "in.bvh", "n.bvh", "--gaussian-cm", "1", "--mask", "{d}", "--force"],
    ["detect", "in.bvh", "-o", "{d}", "--force"],
    ["report", "in.bvh", "-o", "{d}", "--force"],
    ["plot", "in.bvh", "-o", "{d}.png", "--force"],
    ["train", "--method", "kalman-learned", "in.bvh", "-o", "{d}", "--force", "-q"],
    ["index", "build", "trn", "-o", "{d}", "--force", "-q"],
    ["classify", "train", "trn", "-o", "{d}", "--force", "-q"],
])
def test_output_that_is_a_folder_is_one_line(work, capsys, argv):
    (work / "od").mkdir()
    (work / "od.png").mkdir()
    before = _snapshot(work)
    _unchanged(work, before, [a.format(d="od") for a in argv], capsys, "folder")


def test_force_never_replaces_a_special_file(work, capsys):
    fifo = work / "pipe.bvh"
    os.mkfifo(fifo)
    _refused(capsys, ["denoise", "in.bvh", "pipe.bvh", "--method", "median", "--force", "-q"],
             must_say="not a regular file")
    assert fifo.is_fifo()


def test_unknown_output_type_refused_before_work(work, capsys):
    _refused(capsys, ["denoise", "in.bvh", "out.xyz", "--method", "median", "-q"], must_say="unknown file type")
    _refused(capsys, ["plot", "in.bvh", "-o", "fig.asf"], must_say="figure type")
    _refused(capsys, ["plot", "in.bvh", "-o", "fig.png", "--gif"], must_say=".gif")


# ---------------------------------------------------------------------------------------
# tracebacks -> one line
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv,says", [
    (["denoise", "in.bvh", "o.bvh", "--param", "min_noise_cm=abc"], ["min_noise_cm", "number"]),
    (["denoise", "in.bvh", "o.bvh", "--method", "median", "--param", "window=2.5"], ["window", "integer"]),
    (["denoise", "in.bvh", "o.bvh", "--method", "hampel", "--param", "joint_test=3"], ["joint_test", "true or false"]),
    (["denoise", "in.bvh", "o.bvh", "--method", "gaussian", "--param", "sigma_frames=[1,2]"], ["sigma_frames"]),
    (["train", "--method", "kalman-learned", "in.bvh", "-o", "m.npz", "--param", "ridge=x"], ["ridge", "number"]),
])
def test_param_of_wrong_type(work, capsys, argv, says):
    err = _refused(capsys, argv + ["-q"])
    for s in says:
        assert s in err
    assert not (work / "o.bvh").exists() and not (work / "m.npz").exists()


def test_param_right_type_still_works(work, capsys):
    assert main(["denoise", "in.bvh", "o.bvh", "--method", "median", "--param", "window=3.0", "-q"]) == 0
    assert main(["denoise", "in.bvh", "o2.bvh", "--param", "min_noise_cm=0.3", "-q"]) == 0


def test_eval_mask_not_a_valid_npy(work, capsys):
    assert main(["corrupt", "in.bvh", "n.bvh", "--gaussian-cm", "1", "--mask", "m.npy", "-q"]) == 0
    capsys.readouterr()
    (work / "notes.txt").write_text("my notes\n")
    np.save(work / "wrong.npy", np.ones((3, 4), bool))
    shape = io.read(work / "in.bvh").observed.shape
    np.savez(work / "arch.npz", m=np.ones(shape, bool))
    np.save(work / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    np.save(work / "floats.npy", np.full(shape, 0.5))
    for mask, says in [("notes.txt", "not a .npy"), ("wrong.npy", "shape"), ("arch.npz", "not a .npy"),
                       ("obj.npy", "damaged"), ("floats.npy", "boolean"), ("nope.npy", "not found"),
                       ("dir", "not a regular file")]:
        _refused(capsys, ["eval", "in.bvh", "n.bvh", "--mask", mask], must_say=says)
    assert main(["eval", "in.bvh", "n.bvh", "--mask", "m.npy", "--json"]) == 0


def test_classify_train_needs_two_labels(work, capsys):
    lib = work / "lib" / "walk"
    lib.mkdir(parents=True)
    shutil.copy(work / "in.bvh", lib / "a.bvh")
    shutil.copy(work / "in.bvh", lib / "b.bvh")
    _refused(capsys, ["classify", "train", "lib", "-o", "c.npz", "-q"], must_say="at least two")
    assert not (work / "c.npz").exists()


def test_info_json_into_a_closed_pipe_exits_quietly(work):
    """`mocapkit info X --json | head -n 1`: no BrokenPipeError traceback (Python docs' recipe)."""
    p = subprocess.Popen([sys.executable, "-m", "mocapkit", "info", "in.bvh", "--json"], cwd=work,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, env={**os.environ, "PYTHONPATH": str(REPO)})
    p.stdout.close()                               # the reader is gone before anything is written
    err = p.stderr.read().decode()
    rc = p.wait(timeout=60)
    assert "Traceback" not in err and "BrokenPipe" not in err and "Exception ignored" not in err, err
    assert rc == 1


def test_unexpected_exception_is_one_line(work, capsys, monkeypatch):
    from mocapkit import metrics

    def boom(*a, **k):
        raise ZeroDivisionError("simulated bug")

    monkeypatch.setattr(metrics, "all_metrics", boom)
    rc = main(["eval", "in.bvh", "in.bvh"])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and err.count("\n") == 0 and "internal error" in err and "simulated bug" in err
    monkeypatch.setenv("MOCAPKIT_DEBUG", "1")
    with pytest.raises(ZeroDivisionError):
        main(["eval", "in.bvh", "in.bvh"])


def test_amc_companion_skeleton_of_another_motion_never_replaced(work, capsys):
    """The .asf written beside an AMC output is not named by the user: an existing one
    holding another skeleton is refused even with --force."""
    out = work / "o"
    out.mkdir()
    shutil.copy(work / "dir" / "16.asf", out / "07.asf")      # subject 16's skeleton under 07's name
    before = _snapshot(work)
    _unchanged(work, before, ["corrupt", "trn/07_05.amc", "o/07.amc", "--gaussian-cm", "1", "--force", "-q"],
               capsys, "not this motion's skeleton")
