"""The ``mocapkit`` command line.

Every command reads any supported format (see ``mocapkit.io``), writes to a new file,
prints one-line errors and exits with code 2 on bad input. Positions are in cm.
"""
from __future__ import annotations

import argparse
import ast
import json
import os
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from .diagnose import cm_text, count_text
from .errors import MocapError, MocapFormatError, MocapValueError

EXIT_BAD_INPUT = 2


# -- helpers ---------------------------------------------------------------------------
@contextmanager
def stage(desc: str, enable: bool = True, after_s: float = 2.0) -> Iterator[None]:
    """Show an elapsed-time progress line on stderr if the block takes over ``after_s`` seconds."""
    if not enable:
        yield
        return
    done = threading.Event()

    def _ticker() -> None:
        if done.wait(after_s):
            return
        from tqdm import tqdm

        with tqdm(desc=desc, bar_format="{desc}: {elapsed}", file=sys.stderr, leave=False,
                  disable=None) as bar:                    # None: off when stderr is not a terminal
            while not done.wait(0.5):
                bar.refresh()

    th = threading.Thread(target=_ticker, daemon=True)
    th.start()
    t0 = time.perf_counter()
    try:
        yield
    finally:
        done.set()
        th.join()
        dt = time.perf_counter() - t0
        if dt > after_s:
            print(f"{desc}: done in {dt:.1f} s", file=sys.stderr)


def parse_value(text: str) -> Any:
    """'3' -> 3, '0.5' -> 0.5, 'true' -> True, '[1,2]' -> [1, 2], else the string."""
    low = text.strip().lower()
    if low in ("true", "false"):
        return low == "true"
    if low in ("none", "null"):
        return None
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def parse_params(items: Sequence[str] | None) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for it in items or ():
        if "=" not in it:
            raise MocapError(f"--param expects NAME=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        out[k.strip().replace("-", "_")] = parse_value(v)
    return out


def method_params(name: str, params: dict[str, Any], cls: Any = None) -> dict[str, Any]:
    """``params`` parsed from ``--param`` for method ``name`` (or the class ``cls`` of a
    loaded model) converted to the kinds the method declares
    (:func:`mocapkit.denoise.base.params_from_text`); ``denoise.get`` / ``set_params`` check them."""
    from .denoise.base import params_from_text

    return params_from_text(name, params, cls)


def _params_for(name: str, items: Sequence[str] | None) -> dict[str, Any]:
    return method_params(name, parse_params(items))


# -- which files a command reads (outputs may never be one of them) --------------------------
def _supported_files_under(folder: str | Path) -> list[str]:
    """Every file under ``folder`` that mocapkit can read (skeletons included)."""
    from .io import SUPPORTED_EXTENSIONS

    out = []
    for root, _dirs, files in os.walk(folder):
        out += [os.path.join(root, f) for f in files if Path(f).suffix.lower() in SUPPORTED_EXTENSIONS]
    return out


def _declared_inputs(paths: Sequence[str], skeleton: str | None = None) -> list[str]:
    """``paths`` plus the ASF skeleton each AMC among them resolves to (``--skeleton`` or
    the one found beside it, as the reader does), plus every readable file under a folder."""
    from .io.asf import find_skeleton

    out: list[str] = []
    for p in paths:
        if not p:
            continue
        if Path(p).is_dir():
            out += _supported_files_under(p)
            continue
        out.append(str(p))
        if Path(p).suffix.lower() == ".amc":
            if skeleton:
                out.append(str(skeleton))
            else:
                try:
                    out.append(str(find_skeleton(p)))
                except MocapError:
                    pass
    return out


def _plan_output(motion, output: str, force: bool, extra_inputs: Sequence[str | None] = (),
                 claimed: Sequence = ()) -> tuple[dict[str, Any], list[Path]]:
    """Check every file writing ``motion`` to ``output`` produces (see batch.plan_motion_write)."""
    from .batch import plan_motion_write

    return plan_motion_write(motion, output, inputs=[x for x in extra_inputs if x], overwrite=force,
                             claimed=claimed)


def _load_mask(path: str) -> np.ndarray:
    """A corrupted-entry mask saved by ``corrupt --mask``: a bool .npy (no pickles)."""
    if not Path(path).is_file():
        raise MocapFormatError(path, "mask file not found" if not Path(path).exists() else "not a regular file")
    hint = "save one with 'mocapkit corrupt --mask M.npy'"
    with open(path, "rb") as f:
        magic = f.read(6)
    if magic != b"\x93NUMPY":
        raise MocapFormatError(path, f"not a .npy mask file ({hint})")
    try:
        mask = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:
        raise MocapFormatError(path, f"damaged .npy mask file ({str(e).splitlines()[0] if str(e) else type(e).__name__})") from None
    if mask.dtype != bool:
        if mask.dtype.kind in "iuf" and np.isin(mask, (0, 1)).all():
            mask = mask.astype(bool)
        else:
            raise MocapFormatError(path, f"mask must be boolean (True = corrupted entry), got {mask.dtype}")
    return mask


def _read(path: str, skeleton: str | None = None, fmt: str | None = None):
    from . import io

    opts = {"skeleton": skeleton} if skeleton else {}
    return io.read(path, format=fmt, **opts)


def _method(name: str, params: dict[str, Any], model: str | None, motion=None, quiet: bool = True):
    """The estimator to run: a saved model, a shipped general model (data-driven methods
    without --model, :mod:`mocapkit.shipped`), or a fresh one."""
    from . import denoise

    if model:
        if not Path(model).is_file():
            raise MocapFormatError(model, "model file not found")
        m = denoise.base.Denoiser.load(model)
        if m.name != name and name != "auto":
            raise MocapError(f"--model {model} is a {m.name!r} model, not {name!r}")
        if params:
            m.set_params(**method_params(m.name, params, type(m)))
        return m
    params = method_params(name, params)
    m = denoise.get(name, **params)
    if m.needs_training and motion is not None:
        from . import shipped

        fitted = shipped.load(name, motion, **params)
        if fitted is not None:
            if not quiet:
                print(f"using the shipped general {name} model ({shipped.describe(name)}); "
                      f"train one on your own clips with: mocapkit train --method {name}")
            return fitted
    if m.needs_training:
        raise MocapError(f"method {name!r} needs a trained model: pass --model PATH "
                         f"(train one with: mocapkit train --method {name} CLIPS... -o model.npz)"
                         + ("" if motion is None else "; no shipped model fits this clip's joint set"))
    return m


# -- commands ------------------------------------------------------------------------------
def cmd_info(a: argparse.Namespace) -> int:
    m = _read(a.file, a.skeleton, a.format)
    info = {
        "file": str(a.file),
        "format": m.source.get("format", ""),
        "frames": m.n_frames,
        "fps": m.fps,
        "duration_s": round(m.duration, 3),
        "joints": m.n_joints,
        "height_cm": round(height, 1) if np.isfinite(height := m.height()) else None,    # no joint seen
        "missing_percent": round(100 * m.missing_fraction, 2),
        "units": m.source.get("units", ""),
    }
    from .denoise.bases import reference_frames, reference_words

    ref = reference_frames(m)
    if ref:
        info["reference_frame"] = f"{reference_words(ref)}: every method keeps {'it' if ref == 1 else 'them'} as read"
    c3 = m.source.get("c3d") if m.source.get("format") == "c3d" else None
    if c3:                                   # what the file holds besides the markers
        info["first_frame"] = c3.get("first_frame")
        if c3.get("analog_channels"):
            info["analog"] = (f"{c3['analog_channels']} channels at {c3.get('analog_rate', 0):g} Hz "
                              f"(not cleaned; kept in a C3D output)")
        if c3.get("model_outputs"):
            from .io.c3d import outputs_text

            info["model_outputs"] = (outputs_text(c3["model_outputs"])
                                     + " (points that are not markers: left out; kept in a C3D output)")
    table = None
    diag = None
    if a.diagnose:
        from .diagnose import diagnose

        diag = diagnose(m)
        info["diagnosis"] = diag.as_dict()
        from .swaps import repair_labels

        rep = repair_labels(m)[1]
        if rep is not None and "flips" in rep:          # a Kinect skeleton
            info["side_flips"] = rep["flips"]
        elif rep is not None:
            info["label_swap_steps"] = [{**e, "step_cm": round(e["step_cm"], 1)} for e in rep["events"]]
            if rep.get("hidden_pairs"):
                info["label_swaps_hidden"] = rep["hidden_pairs"]
        from .denoise.auto import whole_body_jumps

        # where the whole body jumps (an edit point, two takes in one file, a loop seam): auto
        # cleans each side on its own, and a user had no way to see it before
        info["whole_body_jumps"] = [j for j in whole_body_jumps(m) if j > ref]
    if a.gaps:
        from .gaps import find_gaps, gap_table

        table = gap_table(m)
        found = find_gaps(m.observed)
        info["gaps"] = len(found)
        info["edge_gaps"] = sum(g.kind in ("leading", "trailing", "never") for g in found)
        info["longest_gap_s"] = round(max((g.length for g in found), default=0) / m.fps, 3)
        info["filled_percent"] = round(100 * float(m.filled.mean()), 2)
    if a.json:
        info["joint_names"] = list(m.skeleton.names)
        if table is not None:
            info["markers"] = table
        print(json.dumps(info, indent=1, default=str))
    else:
        for k, v in info.items():
            if k == "height_cm" and v is None:
                v = "n/a (no joint seen)"
            if k == "side_flips":
                v = (f"at frame {', '.join(map(str, v))} (the tracker exchanged the body's sides; "
                     f"`mocapkit denoise` puts them back)") if v else "none"
            if k == "label_swap_steps":
                v = (f"{len(v)} (" + ", ".join(f"{'/'.join(x['markers'])} at frame {x['frame']}" for x in v[:4])
                     + (", ..." if len(v) > 4 else "") + "; `mocapkit denoise` puts back the stretches it can tell)"
                     ) if v else "none"
            if k == "label_swaps_hidden":
                k, v = "hidden swaps", (", ".join("/".join(x) for x in v)
                                        + " (came back exchanged after a gap both share; `mocapkit denoise` "
                                          "puts back the stretches their distances tell)")
            if k == "whole_body_jumps":
                k, v = "jumps", ((f"whole body at frame {', '.join(map(str, v[:8]))}{', ...' if len(v) > 8 else ''} "
                                  f"(an edit point or two takes in one file? `auto` cleans each side on its own)")
                                 if v else "none")
            if k != "diagnosis":
                print(f"{k:>16}: {v}")
        for line in (diag.lines() if diag is not None else []):
            print(f"{'diagnosis':>16}: {line}")
        if table is None:
            print(f"{'joint names':>16}: {', '.join(m.skeleton.names)}")
        else:
            w = max(len(r["marker"]) for r in table)
            print(f"{'marker':<{w}}  missing%  gaps  longest(s)  leading(fr)  trailing(fr)  filled(fr)")
            for r in table:
                print(f"{r['marker']:<{w}}  {r['missing_percent']:8.2f}  {r['gaps']:4d}  "
                      f"{r['longest_gap_s']:10.3f}  {r['leading_frames']:11d}  {r['trailing_frames']:12d}  "
                      f"{r['filled_frames']:10d}" + ("  never observed" if r["never_observed"] else ""))
    return 0


def cmd_corrupt(a: argparse.Namespace) -> int:
    from . import corrupt, io

    from .io._atomic import check_output_path

    m = _read(a.input, a.skeleton)
    opts, written = _plan_output(m, a.output, a.force)      # every output checked before any is written
    if a.mask:
        from .batch import motion_inputs

        check_output_path(a.mask, motion_inputs(m), a.force, claimed=written)
        if Path(a.mask).suffix.lower() != ".npy":
            raise MocapValueError(f"--mask {a.mask}: the mask is saved as NumPy .npy; give a name ending in .npy")
    steps: list[tuple[str, dict[str, Any]]] = []
    if a.gaussian_cm is not None:
        steps.append(("gaussian", {"sigma_cm": a.gaussian_cm}))
    if a.snr_db is not None:
        steps.append(("gaussian", {"snr_db": a.snr_db}))
    if a.outliers is not None:
        steps.append(("outliers", {"ratio": a.outliers, "mode": a.outlier_mode,
                                   "magnitude_cm": a.outlier_cm}))
    if a.missing is not None:
        steps.append(("missing", {"ratio": a.missing}))
    if a.gaps is not None:
        n, length = a.gaps
        steps.append(("block_gaps", {"n_markers": int(n), "length": int(length)}))
    if a.spec:
        steps += corrupt.parse_spec(a.spec)
    if not steps:
        raise MocapError("nothing to do: give --gaussian-cm, --snr-db, --outliers, --missing, --gaps or --spec")
    out, mask = corrupt.combine(m, steps, seed=a.seed)
    io.write(out, a.output, overwrite=a.force, **opts)
    if a.mask:
        from .io._atomic import atomic_write

        atomic_write(a.mask, lambda f: np.save(f, mask), binary=True)
    print(f"wrote {a.output}: {int(mask.sum())} of {mask.size} joint entries corrupted "
          f"({100 * mask.mean():.1f}%), {100 * out.missing_fraction:.1f}% missing")
    return 0


def _positive_seconds(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds (a positive number), got {text!r}") from None
    if not (v > 0 and np.isfinite(v)):
        raise argparse.ArgumentTypeError(f"expected seconds (a positive number), got {text!r}")
    return v


def cmd_denoise(a: argparse.Namespace) -> int:
    from . import denoise, gaps, io

    m = _read(a.input, a.skeleton)
    if a.method is None and a.model is None:
        method = denoise.default(**_params_for(denoise.DEFAULT_METHOD, a.param))
    else:
        method = _method(a.method or "auto", parse_params(a.param), a.model, m, a.quiet)
    opts, _ = _plan_output(m, a.output, a.force, (a.input, a.model))
    with gaps.use_policy(**_policy_changes(a)), \
            stage(f"denoising {m.n_frames} frames with {method.name}", enable=not a.quiet):
        t0 = time.perf_counter()
        out = method.denoise(m)
        dt = time.perf_counter() - t0
    io.write(out, a.output, overwrite=a.force, **opts)
    if not a.quiet:
        print(f"wrote {a.output} ({method.name}, {m.n_frames} frames in {dt:.2f} s, "
              f"{m.n_frames / max(dt, 1e-9):.0f} frames/s)")
        from .swaps import summary_line

        swaps = summary_line(out.source.get("swaps"))
        if swaps:
            print(swaps)
        if out.source.get("reference_frames"):
            from .denoise.bases import reference_words

            print(f"{reference_words(out.source['reference_frames'])}: written back as read, the motion "
                  "after it cleaned")
        if not m.observed.all():
            print(gaps.summary_line(out.source.get("gap_report")))
        _print_auto(out.source.get("auto"), out.source.get("gap_report"))
        auto = out.source.get("fill_auto") or (out.source.get("auto") or {}).get("fill_auto")
        if auto and auto.get("estimated_rmse_cm") is not None:
            chose = ", ".join(f"{k} {v}" for k, v in sorted(auto["chosen"].items(), key=lambda kv: -kv[1]))
            n, left = auto["gaps"], auto["left_gaps"]
            print(f"fill-auto: {count_text(n, 'gap')}, best validated fill per gap: {chose or 'none'}; "
                  f"estimated fill error {cm_text(auto['estimated_rmse_cm'])} cm RMSE (from observed stretches "
                  "hidden like the file's own gaps)"
                  + (f"; {count_text(left, 'gap')} left missing (no fill validated under "
                     f"{auto['max_error_cm']:g} cm)" if left else "")
                  + _pooled_note(auto.get("pooled_share")))
    return 0


def _pooled_note(share: float | None) -> str:
    """The fill-auto line's caution when most fills were judged only by the file's other gaps
    (:data:`mocapkit.denoise.fill_auto.POOLED_WARN_SHARE`)."""
    from .denoise.fill_auto import POOLED_WARN_SHARE

    if share is None or share < POOLED_WARN_SHARE:
        return ""
    return (f"; {100 * share:.0f} % of the fills had no observed stretch next to their own gap to be "
            f"judged on, only the file's other gaps: the estimate may run low (on real occlusions, "
            f"scaled for such fills, it was a median three quarters of the true error)")


def _print_auto(src: dict | None, report: dict | None = None) -> None:
    """One line: what ``auto`` chose and its estimated error. ``report``: the gap policy's
    report of the written result (:func:`mocapkit.gaps.apply_policy`), whose count of
    samples left missing -- auto's own refusals plus the fills the policy then dropped --
    is the one printed, so that the two lines agree."""
    if not src:
        return
    d = src.get("diagnosis") or {}
    chain = " -> ".join(src.get("chain") or []) or "nothing to do (kept as measured)"
    est = src.get("estimated_rmse_cm")
    facts = []
    if d:
        facts.append(f"noise {cm_text(d['noise_cm'])} cm")
        facts.append(f"spikes {100 * d['spike_rate']:.1f} %")
        if d.get("n_gaps"):
            facts.append(count_text(d["n_gaps"], "gap"))
    line = f"auto: {chain} ({', '.join(facts)}); estimated error " + (
        f"{cm_text(est)} cm RMSE ({src.get('how', '')})" if est is not None else "not available")
    left, lim = src.get("left_missing") or 0, src.get("max_fill_error_cm")
    if report:
        left = report.get("left_missing", left)
    if left and lim is not None:
        line += (f"; {left} missing samples not filled (no fill validated under {lim:g} cm, no "
                 f"evidence, or implausible; --param max_fill_error_cm=... to accept more)")
    elif left:
        line += f"; {left} missing samples not filled (no fill had evidence)"
    off = src.get("bones_off")
    if off:
        from .denoise.auto import BONE_OFF_CM

        line += (f"; {off['frames']} frames write a bone more than {BONE_OFF_CM:g} cm off its length (worst "
                 f"{off['worst_cm']:.0f} cm, {off['joint']} at frame {off['frame']}): fills there are uncertain")
    print(line)


def cmd_train(a: argparse.Namespace) -> int:
    from . import denoise
    from .io._atomic import check_output_path

    params = parse_params(a.param)
    sources = list(a.clips) + ([a.data] if a.data else [])
    if not sources:
        raise MocapError("give training clips (CLIPS...) or --data DIR")
    if a.data and not Path(a.data).is_dir():
        raise MocapValueError(f"--data {a.data}: not a folder")
    # never write over a training clip, its skeleton, or any motion file under --data
    protected = _declared_inputs(sources, a.skeleton)
    check_output_path(a.output, protected, overwrite=a.force or a.resume)
    cls = denoise.available().get(a.method)
    if cls is None:
        denoise.get(a.method)                   # the unknown-method message
    params = method_params(a.method, params)
    for suffix in cls.training_side_files:      # e.g. the neural trainer's checkpoint
        check_output_path(str(a.output) + suffix, protected, overwrite=True, claimed=[a.output])
    if cls.train_files(sources, a.output, params=params, resume=a.resume, progress=not a.quiet,
                       exclude=a.exclude or ()):
        return 0                                # the method's own trainer wrote the model
    method = denoise.get(a.method, **params)
    if Path(a.output).suffix.lower() in denoise.base.model_suffixes():
        raise MocapValueError(f"-o {a.output}: {a.method} models are saved as .npz "
                              f"({Path(a.output).suffix} is another method family's format)")
    from .batch import find_inputs

    paths: list[str] = []
    for src in sources:
        paths += [str(p) for p in find_inputs(Path(src))] if Path(src).is_dir() else [src]
    paths = [p for p in paths if Path(p).stem not in set(a.exclude or ())]
    if not paths:
        raise MocapValueError(f"no training clips found in {', '.join(sources)}")
    motions = [_read(p, a.skeleton) for p in paths]
    from .batch import motion_inputs

    check_output_path(a.output, [x for m in motions for x in motion_inputs(m)], overwrite=a.force or a.resume)
    with stage(f"training {a.method} on {len(motions)} clips", enable=not a.quiet):
        method.fit(motions)
    method.save(a.output)
    print(f"wrote {a.output} ({a.method} trained on {len(motions)} clips, "
          f"{sum(m.n_frames for m in motions)} frames)")
    return 0


def cmd_eval(a: argparse.Namespace) -> int:
    from . import metrics

    truth = _read(a.truth, a.skeleton)
    est = _read(a.estimate, a.skeleton)
    mask = _load_mask(a.mask) if a.mask else None
    res = metrics.all_metrics(truth, est, mask)
    if a.json:
        print(json.dumps({k: {"value": v, "unit": u} for k, (v, u) in res.items()}, indent=1))
    else:
        for k, (v, u) in res.items():
            print(f"{k:>28}: {v:10.4f} {u}")
    return 0


def cmd_methods(a: argparse.Namespace) -> int:
    from . import denoise, shipped

    have = set(shipped.available())
    for name, cls in denoise.available().items():
        # "model": a shipped general model is used unless --model is given
        flag = ("model" if name in have else "train") if cls.needs_training else "     "
        settings = ", ".join(f"{k}={v}" for k, v in denoise.DEFAULT_PARAMS.items())
        default = (f" (the default{', ' + settings if settings else ''})"
                   if name == denoise.DEFAULT_METHOD else "")
        print(f"{name:<22} {flag}  {cls.description}{default}")
    print("\ntrain: needs `mocapkit train` first; model: a shipped general model is used unless "
          "--model is given (mocapkit.shipped). The default serves marker files (C3D/TRC) too: on a "
          "clean capture it keeps the measured samples and fills gaps of 3+ frames by fill-auto.")
    return 0


def cmd_bench(a: argparse.Namespace) -> int:
    from . import bench
    from .datasets import shared_data_dir

    if a.list:
        for name, p in bench.available().items():
            print(f"{name:<24} {p.description}")
        return 0
    if not a.protocol:
        raise MocapError("name a protocol (mocapkit bench --list shows them)")
    from .io._atomic import check_output_path

    if a.protocol not in bench.available():
        raise MocapError(f"unknown protocol {a.protocol!r} (mocapkit bench --list shows them)")
    if a.data and not Path(a.data).is_dir():
        raise MocapValueError(f"--data {a.data}: not a folder")
    data = shared_data_dir(a.data)
    out = Path(a.out or f"{a.protocol}.json")
    md_out = out.with_suffix(".md")
    trees = [data] if data else []
    check_output_path(out, overwrite=a.force, input_trees=trees)
    check_output_path(md_out, overwrite=a.force, input_trees=trees, claimed=[out])
    ctx = bench.Context(data_dir=data, quick=a.quick, seed=a.seed, progress=not a.quiet)
    t0 = time.perf_counter()
    rows = bench.run(a.protocol, ctx)
    bench.to_json(rows, out)
    md = bench.to_markdown(rows, title=f"{a.protocol}{' (quick)' if a.quick else ''}")
    from .io._atomic import atomic_write

    atomic_write(md_out, lambda f: f.write(md))
    if not a.quiet:
        print(md)
    print(f"wrote {out} and {out.with_suffix('.md')} ({len(rows)} rows, {time.perf_counter() - t0:.1f} s)")
    return 0


def cmd_detect(a: argparse.Namespace) -> int:
    from . import detect

    from .batch import motion_inputs
    from .io._atomic import check_output_path

    m = _read(a.input, a.skeleton)
    if a.output:
        check_output_path(a.output, motion_inputs(m), overwrite=a.force)
    rep = detect.detect_report(m, threshold_cm=a.threshold_cm) if a.threshold_cm else detect.detect_report(m)
    text = json.dumps(rep, indent=1, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
    if a.output:
        from .io._atomic import atomic_write

        atomic_write(a.output, lambda f: f.write(text))
        print(f"wrote {a.output}")
    else:
        print(text)
    return 0


def cmd_report(a: argparse.Namespace) -> int:
    from .viz.report import write_report

    from .batch import motion_inputs
    from .io._atomic import check_output_path

    check_output_path(a.output, _declared_inputs(a.files, a.skeleton), overwrite=a.force)
    motions = [_read(p, a.skeleton) for p in a.files]
    check_output_path(a.output, [x for m in motions for x in motion_inputs(m)], overwrite=a.force)
    write_report(a.output, motions, labels=[Path(p).name for p in a.files],
                 truth_first=not a.no_truth, overwrite=a.force)
    print(f"wrote {a.output}")
    return 0


def cmd_batch(a: argparse.Namespace) -> int:
    from .batch import DEFAULT, DEFAULT_PATTERNS, run_batch

    from . import denoise

    from .batch import BatchInterrupted

    params = parse_params(a.param)
    if a.workers < 1:
        raise MocapValueError(f"--workers {a.workers}: give 1 or more")
    # parameters (names and types) and the model are checked once, before any file is done
    if a.model:
        method = _method(a.method or "auto", params, a.model)
        params = method_params(method.name, params, type(method)) if params else params
        name = a.method or method.name
    elif a.method is None and not params:
        name = DEFAULT                          # denoise.default() for every file
    else:
        name = a.method or denoise.DEFAULT_METHOD
        if a.method is None:
            params = {**denoise.DEFAULT_PARAMS, **params}
        params = method_params(name, params)
    try:
        policy = _policy_changes(a)
        summ = run_batch(a.in_dir, a.out_dir, method=name,
                         params=params, model=a.model, workers=a.workers,
                         scheduler=a.scheduler, patterns=a.include or DEFAULT_PATTERNS,
                         progress=not a.quiet, policy=policy or None)
    except BatchInterrupted as e:
        s = e.summary
        print(f"mocapkit batch: interrupted: {s.ok} ok, {s.failed} failed, {s.remaining} not done; "
              f"the manifest lists every finished output; rerun the same command to resume",
              file=sys.stderr)
        return 130
    for r in summ.results:
        if r.status == "failed":
            print(f"FAILED {r.input}: {r.reason}")
    warned = [r for r in summ.results if r.status == "ok" and "warning: " in r.note]
    if warned:
        print(f"{len(warned)} file(s) with warnings (a header at odds with its data, a solver not "
              f"converged, measured samples given back, ...): see their lines in the log")
    print(f"{summ.ok} ok, {summ.failed} failed, {summ.skipped} already done; "
          f"{summ.frames} frames in {summ.seconds:.1f} s ({summ.files_per_s:.2f} files/s, "
          f"{summ.frames_per_s:.0f} frames/s); log: {Path(a.out_dir) / 'batch.log'}")
    return 0 if summ.failed == 0 else 1


def cmd_plot(a: argparse.Namespace) -> int:
    from .io._atomic import check_output_path
    from .viz import plots

    ext = Path(a.output).suffix.lower().lstrip(".")
    if a.gif:
        if ext != "gif":
            raise MocapValueError(f"-o {a.output}: --gif writes a GIF animation; give a name ending in .gif")
    else:
        import matplotlib

        matplotlib.use("Agg")
        from matplotlib.figure import Figure

        kinds = Figure().canvas.get_supported_filetypes()
        if ext not in kinds:
            raise MocapValueError(f"-o {a.output}: unsupported figure type {ext or '(none)'!r}; use one of "
                                  f"{', '.join(sorted(kinds))} (or --gif with .gif)")
    check_output_path(a.output, _declared_inputs(a.files, a.skeleton), overwrite=a.force)
    if a.max_frames < 1:
        raise MocapValueError(f"--max-frames {a.max_frames}: give 1 or more")
    if a.bench:
        _check_bench_json(a.files[0])
        path = plots.plot_bench(a.output, a.files[0], a.metric)
    else:
        motions = [_read(p, a.skeleton) for p in a.files]
        labels = [Path(p).name for p in a.files]
        if a.gif:
            path = plots.animate_gif(a.output, motions, labels, max_frames=a.max_frames)
        elif a.error:
            if len(motions) < 2:
                raise MocapError("--error needs TRUTH and at least one ESTIMATE")
            path = plots.plot_error(a.output, motions[0], motions[1:], labels[1:])
        else:
            joints = a.joints.split(",") if a.joints else [motions[0].skeleton.names[-1]]
            path = plots.plot_trajectories(a.output, motions, labels, joints, a.axis)
    print(f"wrote {path}")
    return 0


def _check_bench_json(path: str) -> None:
    """A 'mocapkit bench' JSON: a list of rows with the keys the chart needs."""
    need = {"protocol", "condition", "method", "metric", "unit", "value"}
    if not Path(path).is_file():
        raise MocapFormatError(path, "file not found" if not Path(path).exists() else "not a regular file")
    try:
        rows = json.loads(Path(path).read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError):
        rows = None
    if not isinstance(rows, list) or not all(isinstance(r, dict) and need <= set(r) for r in rows):
        raise MocapFormatError(path, f"not a 'mocapkit bench' JSON (a list of rows with "
                                     f"{', '.join(sorted(need))})")


def cmd_index(a: argparse.Namespace) -> int:
    from .retrieval.index import build_index

    from .io._atomic import check_output_path

    d: Any = parse_value(a.d) if a.d != "auto" else "auto"
    if not (d == "auto" or (isinstance(d, (int, float)) and not isinstance(d, bool) and d > 0)):
        raise MocapValueError(f"--d {a.d}: give a count, a fraction of the features (0-1) or 'auto'")
    if a.words < 1:
        raise MocapValueError(f"--words {a.words}: give 1 or more")
    check_output_path(a.output, _declared_inputs([a.source]), overwrite=a.force)
    res = build_index(a.source, a.output, progress=not a.quiet, method=a.method, d=d,
                      n_words=a.words, overwrite=a.force, seed=a.seed)
    print(f"wrote {res['output']} ({res['n_indexed']} clips, {res['d']} selected features, "
          f"{len(res['skipped'])} skipped, {res['seconds']:.1f} s)")
    return 0


def cmd_search(a: argparse.Namespace) -> int:
    from .retrieval.index import MotionIndex, describe

    index = MotionIndex.load(a.index)
    t0 = time.perf_counter()
    hits = index.search(describe(_read(a.query, a.skeleton)), k=a.k)
    dt = time.perf_counter() - t0
    if a.json:
        print(json.dumps([{"rank": i + 1, "path": p, "distance": d} for i, (p, d) in enumerate(hits)], indent=1))
        return 0
    labels = dict(zip(index.paths, index.labels))
    w = max([len(labels.get(p, "")) for p, _ in hits] + [5])
    print(f"{'rank':>4}  {'distance':>9}  {'label':<{w}}  file")
    for i, (p, d) in enumerate(hits, 1):
        print(f"{i:>4}  {d:9.4f}  {labels.get(p, ''):<{w}}  {p}")
    if not a.quiet:
        print(f"({len(index)} clips searched in {dt * 1000:.0f} ms)", file=sys.stderr)
    return 0


def cmd_classify(a: argparse.Namespace) -> int:
    from .recognition import load_model, train_classifier

    if a.model == "train":
        if not a.output:
            raise MocapError("classify train DATA -o MODEL: give -o/--output for the model file")
        from .io._atomic import check_output_path
        from .retrieval.index import find_motion_files, label_of

        check_output_path(a.output, _declared_inputs([a.file]), overwrite=a.force)
        labels = sorted({label_of(f) for f in find_motion_files(a.file)})
        if len(labels) < 2:
            raise MocapValueError(f"classify train {a.file}: the clips carry {len(labels)} label"
                                  f"{'' if len(labels) == 1 else 's'} ({', '.join(labels) or 'none'}); a "
                                  f"classifier needs at least two (labels come from the file names "
                                  f"aAA_sSS_eEE / HDM_xx_<class>_..., else the parent folder)")
        if not a.C > 0:
            raise MocapValueError(f"--C {a.C}: give a positive number")
        try:
            res = train_classifier(a.file, a.output, progress=not a.quiet, C=a.C, overwrite=a.force,
                                   method=a.method)
        except ValueError as e:             # scikit-learn's, e.g. one class left after skipped files
            if isinstance(e, MocapError):
                raise
            raise MocapValueError(f"classify train {a.file}: {e}") from None
        print(f"wrote {res['output']} ({res['n_train']} clips, {len(res['classes'])} classes, "
              f"training accuracy {res['train_accuracy']:.3f}, {len(res['skipped'])} skipped)")
        return 0
    label, conf = load_model(a.model).predict(_read(a.file, a.skeleton))
    print(json.dumps({"label": label, "confidence": conf}) if a.json else f"{label}\t{conf:.3f}")
    return 0


# -- parser ----------------------------------------------------------------------------------
def _policy_changes(a: argparse.Namespace) -> dict:
    """The gap-policy changes the switches of :func:`_policy_options` ask for."""
    return {**({"max_gap_s": a.max_gap} if a.max_gap else {}),
            **({"move_margin_cm": None, "misfit_factor": None} if a.keep_moves else {}),
            **({"validate_cm": None} if a.keep_unvalidated else {}),
            **({"swaps": False} if a.keep_swaps else {})}


def _policy_options(s: argparse.ArgumentParser) -> None:
    """The gap policy's switches, for ``denoise`` and ``batch`` alike."""
    s.add_argument("--max-gap", type=_positive_seconds, metavar="SECONDS",
                   help="fill no gap longer than this (as Vicon/QTM's maximum gap); longer gaps stay "
                        "missing and are reported. Default: no limit (gaps are still filled only from "
                        "evidence: never extrapolated)")
    s.add_argument("--keep-moves", action="store_true",
                   help="write the method's values for every measured sample, even where it moved a "
                        "stretch by more than 5 cm with no spike to remove, or where a model-based method moved "
                        "a marker by more than twice the input's noise (by default those are written as "
                        "measured, with a warning)")
    s.add_argument("--keep-swaps", action="store_true",
                   help="on a marker file, leave label swaps (two markers that traded labels for a "
                        "stretch of frames, or a label that took a hidden marker's neighbour) as read; "
                        "by default they are put back before the method runs, and a line says where")
    s.add_argument("--keep-unvalidated", action="store_true",
                   help="write a method's fills of gaps longer than 2 frames even where its own "
                        "self-validation on the file (observed stretches next to each gap hidden and "
                        "filled by it: two more runs) puts them over 5 cm RMSE; by default those are "
                        "left missing and counted. auto and fill-auto validate their own fills "
                        "(--param max_fill_error_cm / max_error_cm)")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mocapkit",
        description="Clean, evaluate and inspect motion-capture files (BVH, ASF/AMC, C3D, TRC, "
                    "Kinect text). Positions are in centimetres; outputs are always new files.")
    p.add_argument("--version", action="version", version=f"mocapkit {__import__('mocapkit').__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def common(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--skeleton", help="ASF skeleton for AMC input (default: found beside the AMC)")
        sp.add_argument("--force", action="store_true", help="replace an existing output (never the input)")
        sp.add_argument("-q", "--quiet", action="store_true", help="no progress output")

    s = sub.add_parser("info", help="format, frames, fps, joints, height (cm), %% missing")
    s.add_argument("file")
    s.add_argument("--format", help="override the format chosen by extension")
    s.add_argument("--json", action="store_true")
    s.add_argument("--gaps", action="store_true",
                   help="per marker: missing %%, number of gaps, longest gap, edge gaps, filled frames")
    s.add_argument("--diagnose", action="store_true",
                   help="estimated noise (cm), spike rate, gaps by length and position, frame rate")
    s.add_argument("--skeleton")
    s.set_defaults(func=cmd_info)

    s = sub.add_parser("corrupt", help="add controlled noise/outliers/gaps (seeded) for experiments")
    s.add_argument("input")
    s.add_argument("output")
    s.add_argument("--gaussian-cm", type=float, help="Gaussian noise sigma in cm per coordinate")
    s.add_argument("--snr-db", type=float, help="Gaussian noise by SNR in dB (root-relative signal power)")
    s.add_argument("--outliers", type=float, help="fraction of joint entries made outliers (0-1)")
    s.add_argument("--outlier-mode", default="spike", choices=["spike", "scale"],
                   help="spike: additive spike of --outlier-cm; scale: Xiao's x1.4 in the root frame")
    s.add_argument("--outlier-cm", type=float, default=15.0, help="spike magnitude in cm (default 15)")
    s.add_argument("--missing", type=float, help="fraction of markers removed per frame (0-1)")
    s.add_argument("--gaps", nargs=2, type=float, metavar=("N_MARKERS", "FRAMES"),
                   help="block gap: N markers missing for FRAMES consecutive frames")
    s.add_argument("--spec", help="corruption steps, e.g. 'gaussian:sigma_cm=2,missing:ratio=0.1'")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--mask", help="also save the corrupted-entry mask (T, J) as .npy")
    common(s)
    s.set_defaults(func=cmd_corrupt)

    s = sub.add_parser("denoise", help="clean a file with a method (default: see 'mocapkit methods')")
    s.add_argument("input")
    s.add_argument("output")
    s.add_argument("--method", help="method name (mocapkit methods lists them)")
    s.add_argument("--param", action="append", metavar="NAME=VALUE", help="method parameter (repeatable)")
    s.add_argument("--model", help="trained model file for data-driven methods")
    _policy_options(s)
    common(s)
    s.set_defaults(func=cmd_denoise)

    s = sub.add_parser("train", help="train a data-driven method on clean clips and save the model")
    s.add_argument("clips", nargs="*", help="clean training clips")
    s.add_argument("--data", help="folder of training clips (searched recursively)")
    s.add_argument("--method", required=True)
    s.add_argument("--param", action="append", metavar="NAME=VALUE")
    s.add_argument("--exclude", action="append", metavar="STEM", help="hold out clips by file stem")
    s.add_argument("--resume", action="store_true", help="neural methods: continue from OUTPUT.ckpt")
    s.add_argument("-o", "--output", required=True)
    common(s)
    s.set_defaults(func=cmd_train)

    s = sub.add_parser("eval", help="compare an estimate with the truth: all metrics")
    s.add_argument("truth")
    s.add_argument("estimate")
    s.add_argument("--mask", help="corrupted-entry mask .npy from 'mocapkit corrupt --mask'")
    s.add_argument("--json", action="store_true")
    s.add_argument("--skeleton")
    s.set_defaults(func=cmd_eval)

    s = sub.add_parser("methods", help="list methods, whether they need training")
    s.set_defaults(func=cmd_methods)

    s = sub.add_parser("bench", help="run a benchmark protocol, write JSON + Markdown")
    s.add_argument("protocol", nargs="?")
    s.add_argument("--data", help="data folder (default: $MOCAPKIT_DATA or ../shared/data)")
    s.add_argument("--out", help="output JSON (default PROTOCOL.json)")
    s.add_argument("--quick", action="store_true", help="reduced run (seconds to a minute)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--list", action="store_true", help="list protocols")
    s.add_argument("--force", action="store_true", help="replace existing output files")
    s.add_argument("-q", "--quiet", action="store_true")
    s.set_defaults(func=cmd_bench)

    s = sub.add_parser("detect", help="flag untrusted entries (trust-data detection)")
    s.add_argument("input")
    s.add_argument("-o", "--output", help="write the report as JSON")
    s.add_argument("--threshold-cm", type=float, help="distance from the robust fit (default 6 cm)")
    common(s)
    s.set_defaults(func=cmd_detect)

    s = sub.add_parser("batch", help="clean every supported file under IN_DIR into OUT_DIR (resumable)")
    s.add_argument("in_dir")
    s.add_argument("out_dir")
    s.add_argument("--method", help="method name (default: the default method)")
    s.add_argument("--param", action="append", metavar="NAME=VALUE")
    s.add_argument("--model", help="trained model for data-driven methods")
    s.add_argument("--workers", type=int, default=1, help="local worker processes (default 1)")
    s.add_argument("--scheduler", help="Dask scheduler address tcp://host:port (runs on that cluster)")
    _policy_options(s)
    s.add_argument("--include", action="append", metavar="GLOB",
                   help="file patterns (default: *.bvh *.amc *.c3d *.trc *skeleton*.txt)")
    s.add_argument("-q", "--quiet", action="store_true")
    s.set_defaults(func=cmd_batch)

    s = sub.add_parser("plot", help="figures: joint trajectories, error per frame, bench charts, --gif animation")
    s.add_argument("files", nargs="+", help="motion files (first = truth/reference), or a bench JSON with --bench")
    s.add_argument("-o", "--output", required=True, help="PNG, SVG or PDF (GIF with --gif)")
    s.add_argument("--joints", help="comma-separated joint names for trajectories (default: last joint)")
    s.add_argument("--axis", default="y", choices=["x", "y", "z"])
    s.add_argument("--error", action="store_true", help="error per frame of each file against the first")
    s.add_argument("--gif", action="store_true", help="skeleton animation, files side by side")
    s.add_argument("--max-frames", type=int, default=300)
    s.add_argument("--bench", action="store_true", help="chart of a 'mocapkit bench' JSON")
    s.add_argument("--metric", help="bench metric to chart (default: the first)")
    common(s)
    s.set_defaults(func=cmd_plot)

    s = sub.add_parser("report", help="self-contained HTML report: input, cleaned (and truth)")
    s.add_argument("files", nargs="+", help="TRUTH_OR_INPUT [CLEANED ...]")
    s.add_argument("-o", "--output", required=True)
    s.add_argument("--no-truth", action="store_true", help="the first file is an input, not the truth")
    common(s)
    s.set_defaults(func=cmd_report)

    s = sub.add_parser("index", help="index a motion library for similarity search: index build DIR -o lib.idx")
    s.add_argument("action", choices=["build"])
    s.add_argument("source", help="folder of motion files (searched recursively)")
    s.add_argument("-o", "--output", required=True, help="index file to write (.idx)")
    s.add_argument("--method", default="amfs",
                   help="feature selection: amfs (default), hod, gpf, concat, laplacian, spec, udfs")
    s.add_argument("--d", default="0.3", help="selected features: count, fraction of all, or 'auto' "
                   "(leave-one-out mAP on labels taken from file names)")
    s.add_argument("--words", type=int, default=128, help="pose codebook size (default 128)")
    s.add_argument("--seed", type=int, default=0)
    common(s)
    s.set_defaults(func=cmd_index)

    s = sub.add_parser("search", help="the k indexed clips most similar to a query file")
    s.add_argument("index", help="index file from 'mocapkit index build'")
    s.add_argument("query", help="motion file")
    s.add_argument("-k", type=int, default=10, help="number of results (default 10)")
    s.add_argument("--json", action="store_true")
    common(s)
    s.set_defaults(func=cmd_search)

    s = sub.add_parser("classify", help="action label and confidence of a file: classify MODEL FILE "
                                        "(train a model: classify train DATA_DIR -o model.npz)")
    s.add_argument("model", help="model file (.npz), or 'train'")
    s.add_argument("file", help="motion file to classify (with 'train': folder of labelled clips)")
    s.add_argument("-o", "--output", help="with 'train': model file to write")
    s.add_argument("--method", choices=("minirocket", "skeleton", "nmc"), default="minirocket",
                   help="with 'train': minirocket (default; MultiRocket + HYDRA features of joints and "
                        "arms + ridge), skeleton (hand-made features + logistic regression) or nmc (the thesis' NMC)")
    s.add_argument("--C", type=float, default=1.0,
                   help="with 'train --method skeleton|nmc': inverse L2 strength (default 1)")
    s.add_argument("--json", action="store_true")
    common(s)
    s.set_defaults(func=cmd_classify)
    return p


@contextmanager
def _one_line_warnings(command: str) -> Iterator[None]:
    """Show mocapkit's own warnings (ConvergenceWarning, TrainingMismatchWarning) as one
    ``mocapkit CMD: warning: ...`` line on stderr (no file name / source line) inside the
    block; other warnings keep Python's format."""
    import warnings

    from .errors import MocapWarning

    with warnings.catch_warnings():
        original = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if issubclass(category, MocapWarning):
                print(f"mocapkit {command}: warning: {message}", file=sys.stderr)
            else:
                original(message, category, filename, lineno, file, line)

        warnings.showwarning = show
        yield


def _stdout_gone() -> int:
    """stdout's reader went away (``mocapkit info X | head -n 1``): as the Python docs advise
    for SIGPIPE, point stdout at devnull so the exit flush cannot fail again, exit quietly."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass
    return 1


def _no_hugepages() -> None:
    """Turn off numpy's transparent-huge-page advice for this process (the command line
    owns its process; the library never changes it). Its page faults zero 2 MB at a time,
    and on this kind of kernel that cost more than it saved: reading a 200,000-frame BVH,
    1.4 s of system time with it, 0.2 s without (wall 4.6-5.4 s -> 2.9-3.4 s). The same
    switch as numpy's ``NUMPY_MADVISE_HUGEPAGE=0``, which the user's setting overrides."""
    if os.environ.get("NUMPY_MADVISE_HUGEPAGE") is not None:
        return
    os.environ["NUMPY_MADVISE_HUGEPAGE"] = "0"          # worker processes (batch) inherit it
    try:
        from numpy._core.multiarray import _set_madvise_hugepage
    except ImportError:                       # another numpy layout: keep its default
        return
    _set_madvise_hugepage(False)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    a = parser.parse_args(argv)
    _no_hugepages()
    try:
        with _one_line_warnings(a.command):
            rc = int(a.func(a) or 0)
        sys.stdout.flush()                  # a closed pipe shows up here, not at exit
        return rc
    except BrokenPipeError:
        return _stdout_gone()
    except MocapError as e:
        print(f"mocapkit {a.command}: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"mocapkit {a.command}: interrupted (no partial output written)", file=sys.stderr)
        return 130
    except OSError as e:                    # permissions, full disk, ...: the user's to fix
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        print(f"mocapkit {a.command}: error: {where}{e.strerror or e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as e:  # noqa: BLE001 - a bug: one line, the traceback on request
        if os.environ.get("MOCAPKIT_DEBUG"):
            raise
        if type(e) is ValueError:           # a library's plain "bad value" (e.g. a parameter's range)
            print(f"mocapkit {a.command}: error: {e}", file=sys.stderr)
            return EXIT_BAD_INPUT
        print(f"mocapkit {a.command}: internal error: {type(e).__name__}: {e} (this is a bug; "
              f"MOCAPKIT_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
