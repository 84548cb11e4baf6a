"""Clean whole libraries: every supported file under a folder, mirrored into another.

* Local worker processes by default; a Dask distributed cluster when given a scheduler
  address (``tcp://host:port``) — the same task function runs in both.
* A corrupt file is reported (with the reader's one-line reason) and the rest go on.
* Resumable: ``OUT_DIR/.mocapkit-batch.json`` records, per input, the method, its
  parameters, the model's checksum and the SHA-256 of the output written. A rerun skips
  an input whose output still has that checksum and whose input and settings are
  unchanged; anything else is redone. Outputs are written atomically, so an interrupted
  run leaves either a complete, verified output or none.
* Inputs are never overwritten: OUT_DIR may not be IN_DIR, and every output path is
  checked against its input.
* ASF skeleton files are copied beside the mirrored AMC outputs so they can be re-read.
"""
from __future__ import annotations

import fnmatch
import hashlib
import json
import os
import shutil
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from .errors import MocapError, MocapValueError

MANIFEST = ".mocapkit-batch.json"
LOG = "batch.log"
DEFAULT_PATTERNS = ("*.bvh", "*.amc", "*.c3d", "*.trc", "*skeleton*.txt")


@dataclass
class FileResult:
    input: str                   # path relative to IN_DIR
    status: str                  # "ok", "failed", "skipped" (already done and verified)
    reason: str = ""
    frames: int = 0
    seconds: float = 0.0
    output_sha256: str = ""
    input_stamp: list = field(default_factory=list)   # [size, mtime_ns] of the input


@dataclass
class Summary:
    ok: int
    failed: int
    skipped: int
    frames: int
    seconds: float
    results: list[FileResult]

    @property
    def files_per_s(self) -> float:
        done = self.ok + self.failed
        return done / self.seconds if self.seconds > 0 else 0.0

    @property
    def frames_per_s(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def find_inputs(in_dir: Path, patterns: Iterable[str] = DEFAULT_PATTERNS) -> list[Path]:
    """Supported files under ``in_dir`` (recursive, sorted, hidden folders skipped)."""
    pats = tuple(patterns)
    out = []
    for root, dirs, files in os.walk(in_dir):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for f in sorted(files):
            if any(fnmatch.fnmatch(f.lower(), p.lower()) for p in pats):
                out.append(Path(root) / f)
    return out


def process_one(in_path: str, out_path: str, method: str, params: dict[str, Any],
                model: str | None) -> dict[str, Any]:
    """Read, clean and write one file. Runs in a worker process; never raises for bad input."""
    from . import denoise, io

    t0 = time.perf_counter()
    try:
        m = io.read(in_path)
        den = denoise.base.Denoiser.load(model) if model else denoise.get(method, **params)
        if model and params:
            den.set_params(**params)
        out = den.denoise(m)
        io.write(out, out_path, overwrite=True)
        return {"status": "ok", "frames": m.n_frames, "seconds": time.perf_counter() - t0,
                "output_sha256": sha256(Path(out_path))}
    except MocapError as e:
        return {"status": "failed", "reason": str(e), "seconds": time.perf_counter() - t0}
    except Exception as e:  # a bug in a method must not stop a library run; report it plainly
        return {"status": "failed", "reason": f"internal error: {type(e).__name__}: {e}",
                "seconds": time.perf_counter() - t0}


def _settings_key(method: str, params: dict[str, Any], model: str | None) -> str:
    return json.dumps({"method": method, "params": params,
                       "model": sha256(Path(model)) if model else None}, sort_keys=True, default=str)


def run_batch(in_dir: str | os.PathLike, out_dir: str | os.PathLike, *, method: str,
              params: dict[str, Any] | None = None, model: str | None = None, workers: int = 1,
              scheduler: str | None = None, patterns: Iterable[str] = DEFAULT_PATTERNS,
              progress: bool = True, log: Callable[[str], None] | None = None) -> Summary:
    """Clean every supported file under ``in_dir`` into the mirrored tree ``out_dir``.

    Returns a :class:`Summary`; also writes ``out_dir/batch.log`` (one line per file) and
    the resume manifest. ``workers`` local processes (1 = in this process), or tasks on
    the Dask cluster at ``scheduler``.
    """
    from . import denoise

    params = dict(params or {})
    src, dst = Path(in_dir).resolve(), Path(out_dir).resolve()
    if not src.is_dir():
        raise MocapValueError(f"{in_dir}: input folder not found")
    if dst == src:
        raise MocapValueError(f"{out_dir}: output folder must differ from the input folder")
    if model is None:
        cls = denoise.available().get(method)
        if cls is None:
            raise MocapValueError(f"unknown method {method!r}; available: {', '.join(denoise.available())}")
        if cls.needs_training:
            raise MocapValueError(f"method {method!r} needs --model")
        denoise.get(method, **params)   # validate parameters once, before any work
    dst.mkdir(parents=True, exist_ok=True)
    inputs = [p for p in find_inputs(src, patterns) if dst not in p.resolve().parents]
    manifest_path = dst / MANIFEST
    manifest: dict[str, Any] = {}
    if manifest_path.exists():
        try:
            manifest = json.loads(manifest_path.read_text())
        except (OSError, json.JSONDecodeError):
            manifest = {}
    key = _settings_key(method, params, model)
    files = manifest.get("files", {}) if manifest.get("settings") == key else {}

    # copy ASF skeletons so mirrored AMC outputs can be read back
    for asf in src.rglob("*.asf"):
        target = dst / asf.relative_to(src)
        if not target.exists():
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(asf, target)

    todo, results = [], []
    for p in inputs:
        rel = str(p.relative_to(src))
        out = dst / rel
        st = p.stat()
        stamp = [st.st_size, st.st_mtime_ns]
        prev = files.get(rel)
        if (prev and prev.get("status") == "ok" and prev.get("input_stamp") == stamp and out.exists()
                and sha256(out) == prev.get("output_sha256")):
            results.append(FileResult(rel, "skipped", frames=0, output_sha256=prev["output_sha256"],
                                      input_stamp=stamp))
            continue
        out.parent.mkdir(parents=True, exist_ok=True)
        todo.append((rel, str(p), str(out), stamp))

    t0 = time.perf_counter()
    log_lines: list[str] = []

    def record(rel: str, stamp: list, res: dict[str, Any]) -> None:
        fr = FileResult(rel, res["status"], res.get("reason", ""), res.get("frames", 0),
                        res.get("seconds", 0.0), res.get("output_sha256", ""), stamp)
        results.append(fr)
        files[rel] = asdict(fr)
        line = f"{fr.status:<7} {rel}  {fr.frames} frames {fr.seconds:.2f} s {fr.reason}".rstrip()
        log_lines.append(line)
        if log:
            log(line)
        # persist progress after every file so an interrupted run resumes where it stopped
        _write_json(manifest_path, {"settings": key, "files": files})

    from tqdm import tqdm

    bar = tqdm(total=len(todo), desc=f"batch {method}", unit="file", disable=None if progress else True,
               leave=False)                                 # None: off when stderr is not a terminal
    try:
        if scheduler:
            from dask.distributed import Client, as_completed as dask_completed

            with Client(scheduler) as client:
                futs = {client.submit(process_one, i, o, method, params, model, pure=False): (r, s)
                        for r, i, o, s in todo}
                for fut in dask_completed(futs):
                    r, s = futs[fut]
                    record(r, s, fut.result())
                    bar.update()
        elif workers <= 1:
            for r, i, o, s in todo:
                record(r, s, process_one(i, o, method, params, model))
                bar.update()
        else:
            with ProcessPoolExecutor(max_workers=workers) as ex:
                futs = {ex.submit(process_one, i, o, method, params, model): (r, s) for r, i, o, s in todo}
                for fut in as_completed(futs):
                    r, s = futs[fut]
                    record(r, s, fut.result())
                    bar.update()
    finally:
        bar.close()
        with open(dst / LOG, "a", encoding="utf-8") as f:
            f.write(f"# {time.strftime('%Y-%m-%d %H:%M:%S')} method={method} params={params} model={model}\n")
            f.writelines(line + "\n" for line in log_lines)
    elapsed = time.perf_counter() - t0
    results.sort(key=lambda r: r.input)
    return Summary(ok=sum(r.status == "ok" for r in results),
                   failed=sum(r.status == "failed" for r in results),
                   skipped=sum(r.status == "skipped" for r in results),
                   frames=sum(r.frames for r in results if r.status == "ok"),
                   seconds=elapsed, results=results)


def _write_json(path: Path, obj: Any) -> None:
    from .io._atomic import atomic_write

    atomic_write(path, lambda f: json.dump(obj, f, indent=1))
