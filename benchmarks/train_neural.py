"""Train the shipped BRA-P / BRA networks (issue 20) and export them to ONNX.

Usage (one thread; run in the background, resumable)::

    OMP_NUM_THREADS=1 nohup python benchmarks/train_neural.py train --method bra-p \\
        --steps-perceptual 1000 --steps-denoise 4000 --work /tmp/neural/bra-p --resume \\
        > /tmp/neural/bra-p.log 2>&1 &
    python benchmarks/train_neural.py export --method bra-p --work /tmp/neural/bra-p
    python benchmarks/train_neural.py plot --work /tmp/neural

Data: every CMU ASF/AMC trial and every HDM05 cut motion in ``../shared/data`` (the 21
CMU joints, HDM05 uses the same ASF bone names), resampled to 60 fps, except the held-out
subjects :data:`HOLDOUT_SUBJECTS` and the held-out trials of ``bra-table1``
(:data:`mocapkit.bench.protocols.bra.HELD_OUT`). Settings: :data:`OPERATING_POINT`
(the paper's losses and lambdas, residual output, linear bridge + mask input,
rotation / mirror / scale augmentation, cosine learning-rate decay).

``train`` writes ``<work>/model.pt`` (torch bundle) and ``<work>/ckpt.pt`` (checkpoint,
every 200 steps; ``--resume`` continues from it). ``export`` writes
``mocapkit/neural/pretrained/<method>.onnx`` (+ ``<method>.perceptual.onnx`` for
bra-p) from ``model.pt``. ``plot`` draws ``docs/results/bra_training.png`` from the
checkpoints' loss history.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

HOLDOUT_SUBJECTS = ("09", "16", "35", "49", "HDM_tr")
"""Subjects never seen in training: CMU 09 (run), 16 (walk), 35 (walk), 49 (balance) and
HDM05 actor tr (all six classes)."""

from mocapkit.neural.train import OPERATING_POINT  # noqa: E402  (the shipped settings)

OPERATING_POINT = dict(OPERATING_POINT, checkpoint_every=200, threads=1, seed=0)


def subject_of(stem: str) -> str:
    """'135_04' -> '135'; 'HDM_tr_kickLFront1Reps_003_120' -> 'HDM_tr'."""
    if stem.startswith("HDM_"):
        return "_".join(stem.split("_")[:2])
    return stem.split("_")[0]


def data_files(data_dir: Path) -> list[Path]:
    return (sorted(Path(p) for p in glob.glob(str(data_dir / "cmu/asfamc/*/*.amc")))
            + sorted(Path(p) for p in glob.glob(str(data_dir / "hdm05/asfamc/*/*.amc"))))


def split(data_dir: Path) -> tuple[list[Path], list[Path]]:
    """(training files, held-out files)."""
    from mocapkit.bench.protocols.bra import HELD_OUT

    train, held = [], []
    for f in data_files(data_dir):
        out = subject_of(f.stem) in HOLDOUT_SUBJECTS or f.stem in HELD_OUT
        (held if out else train).append(f)
    return train, held


def load_motions(files):
    from mocapkit import io
    from mocapkit.neural import clips as C

    out, names = [], []
    for f in files:
        m = io.read(f)
        C.check_joints(m.skeleton, C.CMU_21)
        out.append(m)
        names.append(f.stem)
    return out, names


def make_trainer(a, log=None):
    """(Trainer, training_info) for the method and data of ``a`` (checkpoint <work>/ckpt.pt)."""
    import torch

    torch.set_num_threads(1)
    torch.set_flush_denormal(True)      # denormal floats made some CPU steps 10x slower
    from mocapkit.neural import clips as C
    from mocapkit.neural.train import SyntheticSource, TrainConfig, Trainer

    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    train_files, held = split(Path(a.data))
    t0 = time.time()
    motions, names = load_motions(train_files)
    print(f"{len(motions)} training motions ({sum(m.duration for m in motions):.0f} s), "
          f"held out {len(held)}: {', '.join(sorted({subject_of(f.stem) for f in held}))} subjects / trials "
          f"{', '.join(f.stem for f in held if subject_of(f.stem) not in HOLDOUT_SUBJECTS)}; "
          f"read in {time.time() - t0:.1f} s", flush=True)
    params = dict(OPERATING_POINT, perceptual=a.method == "bra-p", postprocess=a.method == "bra-p",
                  steps_perceptual=a.steps_perceptual if a.method == "bra-p" else 0,
                  steps_denoise=a.steps_denoise)
    if a.hidden:
        params["hidden"] = a.hidden
    for kv in getattr(a, "set", None) or ():
        k, v = kv.split("=", 1)
        params[k] = json.loads(v)
    cfg = TrainConfig.from_params(**params)
    src = SyntheticSource(motions, C.CMU_21, cfg.clip_frames, augment=cfg.augment, mask_input=cfg.mask_input,
                          base_sigma=cfg.base_sigma, base_filter=cfg.base_filter)
    tr = Trainer(src, cfg, checkpoint=work / "ckpt.pt", progress=False, log=log)
    info = {"motions": names, "held_out": [f.stem for f in held], "held_out_subjects": list(HOLDOUT_SUBJECTS)}
    return tr, info


def cmd_train(a) -> None:
    tr, info = make_trainer(a, log=lambda s: print(s, flush=True))
    ck = tr.checkpoint
    if a.resume and ck.is_file():
        tr.load_checkpoint(ck)
        print(f"resumed from {ck}: phase {tr.phase}, step {tr.step}", flush=True)
    elif a.init_perceptual and tr.perceptual is not None:
        import torch

        d = torch.load(a.init_perceptual, map_location="cpu", weights_only=True)
        old = json.loads(d["meta"])
        tr.perceptual.load_state_dict(d["perceptual"])
        tr.history = [h for h in old["history"] if h["phase"] == "perceptual"]
        tr.seconds = float(tr.history[-1]["seconds"]) if tr.history and "seconds" in tr.history[-1] else 0.0
        tr._enter_denoise()
        info["perceptual_from"] = f"{a.init_perceptual} ({len(tr.history) * 50} steps, same data and settings)"
        print(f"perceptual AE taken from {a.init_perceptual}; stage 2 from step 0", flush=True)
    w0 = time.time()
    tr.run()
    b = tr.bundle(method=a.method, training_info=info)
    work = Path(a.work)
    b.save(work / "model.pt")
    print(f"done: {tr.seconds:.0f} s of training ({time.time() - w0:.0f} s this run); wrote {work / 'model.pt'}",
          flush=True)


def cmd_export(a) -> None:
    from mocapkit.neural import pretrained_path
    from mocapkit.neural.bundle import Bundle

    if a.ckpt:     # training cut short: the last checkpoint
        a.steps_perceptual, a.steps_denoise, a.hidden = 800, 0, None
        tr, info = make_trainer(a)
        tr.load_checkpoint(tr.checkpoint)
        info["cut_short_at"] = {"phase": tr.phase, "step": tr.step}
        b = tr.bundle(method=a.method, training_info=info)
        b.meta["training"]["steps_denoise"] = tr.step if tr.phase == "denoise" else b.meta["training"]["steps_denoise"]
    else:
        b = Bundle.load(Path(a.work) / "model.pt")
    if a.postprocess is not None:
        b.meta["postprocess"] = a.postprocess == "on"
        b.meta["params"]["postprocess"] = b.meta["postprocess"]
    out = Path(a.out) if a.out else pretrained_path(a.method)
    files = b.export_onnx(out)
    print("wrote", ", ".join(f"{f} ({os.path.getsize(f) / 1e6:.2f} MB)" for f in files))


def cmd_plot(a) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    import torch

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    info = {}
    for method in ("bra-p", "bra"):
        ck = Path(a.work) / method / "ckpt.pt"
        if not ck.is_file():
            continue
        meta = json.loads(torch.load(ck, map_location="cpu", weights_only=True)["meta"])
        h = meta["history"]
        std = None
        for phase, ax in (("perceptual", axes[0]), ("denoise", axes[1])):
            rows = [r for r in h if r["phase"] == phase]
            if not rows:
                continue
            st = np.array([r["step"] for r in rows])
            what = "per-clip RMS" if phase == "denoise" and meta["config"].get("reproduction") == "rms" else "MSE"
            ax.semilogy(st, [r["R"] for r in rows], label=f"{method} L_R (normalised {what})")
            if "P" in rows[0]:
                ax.semilogy(st, [r["P"] for r in rows], label=f"{method} L_P", alpha=0.7)
            ax.semilogy(st, [r["B"] for r in rows], label=f"{method} L_B", alpha=0.5)
            ax.set_title(f"{phase} autoencoder" if phase == "perceptual" else "denoising autoencoder")
            ax.set_xlabel("step (batch 16)")
        info[method] = {"seconds": meta["seconds"], "phase": meta["phase"], "step": meta["step"]}
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("BRA / BRA-P training (1 CPU thread): " + "; ".join(
        f"{k} {v['seconds'] / 60:.0f} min" for k, v in info.items()), fontsize=9)
    fig.tight_layout()
    out = ROOT / "docs/results/bra_training.png"
    fig.savefig(out, dpi=90)
    print("wrote", out, info)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("train")
    t.add_argument("--method", choices=("bra-p", "bra"), required=True)
    t.add_argument("--data", default=str(ROOT.parent / "shared/data"))
    t.add_argument("--work", required=True)
    t.add_argument("--steps-perceptual", type=int, default=1000)
    t.add_argument("--steps-denoise", type=int, default=4000)
    t.add_argument("--hidden", type=int, default=None)
    t.add_argument("--resume", action="store_true")
    t.add_argument("--set", action="append", default=[], metavar="KEY=JSON",
                   help="override a TrainConfig field of OPERATING_POINT (e.g. highpass_gain=8)")
    t.add_argument("--init-perceptual", default=None,
                   help="take the trained perceptual AE of this checkpoint (same data) and start stage 2")
    e = sub.add_parser("export")
    e.add_argument("--method", choices=("bra-p", "bra"), required=True)
    e.add_argument("--work", required=True)
    e.add_argument("--out", default=None)
    e.add_argument("--data", default=str(ROOT.parent / "shared/data"))
    e.add_argument("--set", action="append", default=[], metavar="KEY=JSON")
    e.add_argument("--ckpt", action="store_true", help="export the last checkpoint (training cut short)")
    e.add_argument("--postprocess", choices=("on", "off"), default=None,
                   help="the model's default for the perceptual post-processing (bra-p)")
    p = sub.add_parser("plot")
    p.add_argument("--work", default="/tmp/neural")
    a = ap.parse_args(argv)
    {"train": cmd_train, "export": cmd_export, "plot": cmd_plot}[a.cmd](a)


if __name__ == "__main__":
    main()
