"""Clean whole libraries: every supported file under a folder, mirrored into another.

* Local worker processes by default; a Dask distributed cluster when given a scheduler
  address (``tcp://host:port``) — the same task function runs in both.
* A corrupt file is reported (with the reader's one-line reason) and the rest go on; so is
  a file whose worker process dies (the worker is replaced).
* Resumable: ``OUT_DIR/.mocapkit-batch.json`` records, per input, the method, its
  parameters, the model's checksum and the SHA-256 of the output written. A rerun skips
  an input whose output still has that checksum and whose input and settings are
  unchanged; anything else is redone. Outputs are written atomically, so an interrupted
  run leaves either a complete, verified output or none.
* Interrupt (Ctrl-C, SIGINT or SIGTERM): the workers are stopped at once, temporary files
  of the files in flight are removed, and the manifest lists exactly the outputs on disk
  (an output completed while stopping is verified and recorded); rerun to resume.
* One batch per output folder: ``OUT_DIR/.mocapkit-batch.lock`` holds the owner's pid; a
  second batch on the folder is refused, a lock left by a dead process is removed.
* Inputs are never overwritten: OUT_DIR may not be IN_DIR, inside it or around it, every
  output path goes through :func:`mocapkit.io._atomic.check_output_path`, and an existing
  file in OUT_DIR is only replaced when an earlier batch wrote it (listed in the manifest).
* ASF skeleton files are copied beside the mirrored AMC outputs so they can be re-read.
"""
from __future__ import annotations

import fnmatch
import hashlib
import json
import os
import shutil
import signal
import socket
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from .errors import MocapError, MocapFormatError, MocapValueError

MANIFEST = ".mocapkit-batch.json"
LOG = "batch.log"
LOCK = ".mocapkit-batch.lock"
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
    note: str = ""               # "ok": what the gap policy filled and left, the warnings


@dataclass
class Summary:
    ok: int
    failed: int
    skipped: int
    frames: int
    seconds: float
    results: list[FileResult]
    interrupted: bool = False
    remaining: int = 0           # inputs not processed because the run was interrupted

    @property
    def files_per_s(self) -> float:
        done = self.ok + self.failed
        return done / self.seconds if self.seconds > 0 else 0.0

    @property
    def frames_per_s(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0


class BatchInterrupted(KeyboardInterrupt):
    """Raised by :func:`run_batch` after a clean stop on Ctrl-C / SIGTERM (``.summary``)."""

    def __init__(self, summary: Summary):
        super().__init__("batch interrupted")
        self.summary = summary


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


# -- writing one motion: every file it produces goes through the one path rule ---------------
def motion_inputs(motion) -> tuple[str, ...]:
    """The files a read motion came from: the file itself and, for AMC, its ASF skeleton."""
    src = motion.source
    return tuple(str(p) for p in (src.get("path"), src.get("skeleton_path")) if p)


def amc_companion(motion, out: str | os.PathLike) -> Path | None:
    """The ASF that :func:`mocapkit.io.amc.write` writes beside the AMC ``out`` (same rule:
    none when the skeleton lookup for ``out`` already finds an identical skeleton)."""
    from .io.asf import _same_skeleton, find_skeleton, read_asf

    asf = motion.source.get("asf")
    if not isinstance(asf, dict) or "bones" not in asf:
        return None                       # the writer refuses this motion with its own message
    try:
        found = find_skeleton(out)
        if _same_skeleton(read_asf(found), asf):
            return None
    except MocapFormatError:
        pass
    return Path(out).with_suffix(".asf")


def _holds_skeleton(path: Path, asf: dict) -> bool:
    from .io.asf import _same_skeleton, read_asf

    try:
        return _same_skeleton(read_asf(path), asf)
    except (MocapError, OSError, UnicodeDecodeError):
        return False


def plan_motion_write(motion, out: str | os.PathLike, *, inputs: Iterable = (), overwrite: bool = False,
                      claimed: Iterable = (), input_trees: Iterable = ()) -> tuple[dict[str, Any], list[Path]]:
    """Check every file that writing ``motion`` to ``out`` produces, before anything is written.

    Returns ``(options for mocapkit.io.write, [paths that will be written])``. Refuses (one
    line) an output format that cannot hold what is written (``.asf``: a skeleton, no
    motion), and applies :func:`~mocapkit.io._atomic.check_output_path` to the output and
    to the ASF skeleton written beside an AMC output.
    """
    from .io import detect_format
    from .io._atomic import check_output_path

    inputs = tuple(inputs) + motion_inputs(motion)
    claimed = list(claimed)
    trees = tuple(input_trees)
    p = check_output_path(out, inputs, overwrite, claimed=claimed, input_trees=trees)
    fmt = detect_format(out)
    if fmt == "asf":
        raise MocapValueError(f"{out}: an .asf file holds a skeleton, not a motion; write the motion as "
                              f".amc (its .asf is written beside it), .bvh, .c3d or .trc")
    written = [p]
    opts: dict[str, Any] = {}
    if fmt == "amc":
        comp = amc_companion(motion, p)
        if comp is not None:
            check_output_path(comp, inputs, overwrite, claimed=claimed + [p], input_trees=trees)
            if os.path.lexists(comp) and not _holds_skeleton(comp, motion.source["asf"]):
                # not named by the user: never replaced, even with --force (as the AMC writer)
                raise MocapValueError(f"{comp} exists and is not this motion's skeleton (an AMC output needs "
                                      f"its .asf beside it); choose another output name")
            opts["write_asf"] = comp
            written.append(comp)
        elif isinstance(motion.source.get("asf"), dict):
            opts["write_asf"] = False
    return opts, written


#: method name meaning "the default" (:func:`mocapkit.denoise.default`)
DEFAULT = "default"


def process_one(in_path: str, out_path: str, method: str, params: dict[str, Any],
                model: str | None, policy: dict[str, Any] | None = None) -> dict[str, Any]:
    """Read, clean and write one file. Runs in a worker process; never raises for bad input.
    ``policy``: changes to the gap policy (:func:`mocapkit.gaps.use_policy`), e.g.
    ``{"max_gap_s": 0.5}``."""
    import warnings

    from . import denoise, io
    from .errors import MocapWarning
    from .gaps import summary_line, use_policy

    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", MocapWarning)    # kept for the note, shown below
            m = io.read(in_path)
        opts, written = plan_motion_write(m, out_path, inputs=(in_path,), overwrite=True)
        if model:
            den = denoise.base.Denoiser.load(model)
            if params:
                den.set_params(**params)
        elif method == DEFAULT:
            den = denoise.default()
        else:
            den = denoise.get(method, **params)
            if den.needs_training:                # the shipped general model, if one fits
                from . import shipped

                den = shipped.load(method, m, **params)
                if den is None:
                    raise MocapError(f"method {method!r}: no shipped model fits this file's joint "
                                     f"set; give --model")
        with warnings.catch_warnings(record=True) as more, use_policy(**(policy or {})):
            warnings.simplefilter("always", MocapWarning)
            out = den.denoise(m)
        caught += more
        io.write(out, out_path, overwrite=True, **opts)
        # what a user reads in the CLI's lines, in the log and manifest: what was left
        # missing or given back as measured, and why; the warnings also shown as they came
        from .swaps import summary_line as swaps_line

        notes = [x for x in [swaps_line(out.source.get("swaps"))] if x]
        notes += [summary_line(out.source.get("gap_report"))] if not m.observed.all() else []
        notes += [f"warning: {w.message}" for w in caught if issubclass(w.category, MocapWarning)]
        for w in caught:
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
        return {"status": "ok", "frames": m.n_frames, "seconds": time.perf_counter() - t0,
                "output_sha256": sha256(Path(out_path)), "extra": [str(p) for p in written[1:]],
                "note": "; ".join(notes)}
    except MocapError as e:
        return {"status": "failed", "reason": str(e), "seconds": time.perf_counter() - t0}
    except Exception as e:  # a bug in a method must not stop a library run; report it plainly
        return {"status": "failed", "reason": f"internal error: {type(e).__name__}: {e}",
                "seconds": time.perf_counter() - t0}


def _settings_key(method: str, params: dict[str, Any], model: str | None,
                  policy: dict[str, Any] | None = None) -> str:
    key = {"method": method, "params": params, "model": sha256(Path(model)) if model else None}
    if policy:                              # (absent when default: earlier manifests stay valid)
        key["policy"] = policy
    return json.dumps(key, sort_keys=True, default=str)


# -- one batch per output folder --------------------------------------------------------------
def _start_time(pid: int) -> str | None:
    """Kernel start time of ``pid`` (Linux /proc), to tell a live owner from a reused pid."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[19].decode()
    except (OSError, IndexError):
        return None


def _alive(pid: int, start: str | None) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass                                  # exists, owned by another user
    except OSError:
        return False
    now = _start_time(pid)
    return not (start and now and now != start)


class BatchLock:
    """``OUT_DIR/.mocapkit-batch.lock``: created atomically (hard link of a complete file, so
    it is never seen half-written), holding ``{pid, host, start, time}``. A lock whose
    process is gone (on this host) is stale and removed; any other existing lock refuses."""

    def __init__(self, folder: Path):
        self.path = Path(folder) / LOCK
        self.me = {"pid": os.getpid(), "host": socket.gethostname(), "start": _start_time(os.getpid()),
                   "time": time.strftime("%Y-%m-%d %H:%M:%S")}
        self.held = False

    def _read(self) -> tuple[bytes | None, dict | None]:
        try:
            raw = self.path.read_bytes()
        except FileNotFoundError:
            return None, None
        except OSError as e:
            raise MocapValueError(f"{self.path}: cannot read the batch lock ({e.strerror})") from None
        try:
            info = json.loads(raw)
            return raw, info if isinstance(info, dict) else None
        except ValueError:
            return raw, None

    def _stale(self, info: dict | None) -> bool:
        if info is None:
            return True                       # unreadable: never written by a live batch
        pid = info.get("pid")
        if not isinstance(pid, int) or pid <= 0:
            return True
        if info.get("host") != self.me["host"]:
            return False                      # cannot check a process on another machine
        if pid == os.getpid():
            return False
        return not _alive(pid, info.get("start"))

    def _create(self) -> bool:
        tmp = self.path.with_name(f"{LOCK}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(self.me))
        try:
            os.link(tmp, self.path)
            return True
        except FileExistsError:
            return False
        except OSError:                         # no hard links here: exclusive create
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                return False
            with os.fdopen(fd, "w") as f:
                f.write(json.dumps(self.me))
            return True
        finally:
            tmp.unlink(missing_ok=True)

    def _break(self, raw: bytes) -> None:
        """Remove the stale lock ``raw`` without ever removing a fresh one taken meanwhile."""
        aside = self.path.with_name(f"{LOCK}.{os.getpid()}.stale")
        try:
            os.rename(self.path, aside)
        except FileNotFoundError:
            return
        if aside.read_bytes() != raw:           # someone took the lock in between: put it back
            try:
                os.link(aside, self.path)
            except OSError:
                pass
        aside.unlink(missing_ok=True)

    def acquire(self) -> "BatchLock":
        for _ in range(20):
            if self._create():
                self.held = True
                return self
            raw, info = self._read()
            if raw is None:
                continue
            if not self._stale(info):
                who = (f"pid {info.get('pid')}" + (f" on {info.get('host')}" if info.get("host") != self.me["host"]
                                                   else "") + f", since {info.get('time', '?')}")
                raise MocapValueError(f"{self.path.parent} is in use by another mocapkit batch ({who}); "
                                      f"wait for it to finish (remove {self.path} only if no batch is running)")
            self._break(raw)
        raise MocapValueError(f"{self.path}: could not take the batch lock (contended)")

    def release(self) -> None:
        if not self.held:
            return
        raw, info = self._read()
        if info and info.get("pid") == self.me["pid"] and info.get("start") == self.me["start"]:
            self.path.unlink(missing_ok=True)
        self.held = False

    def __enter__(self) -> "BatchLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


# -- local worker processes ----------------------------------------------------------------------
def _worker_loop(conn, method: str, params: dict[str, Any], model: str | None,
                 policy: dict[str, Any] | None = None) -> None:
    """A local worker: receive ``(rel, in, out)``, send back ``(rel, result)``; ``None`` ends."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)     # the parent stops the workers itself
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        while True:
            task = conn.recv()
            if task is None:
                return
            rel, i, o = task
            conn.send((rel, process_one(i, o, method, params, model, policy)))
    except (EOFError, OSError, KeyboardInterrupt):
        return


def _temp_files(out: Path) -> list[Path]:
    """Temporary files :mod:`mocapkit.io._atomic` may have left for ``out`` (and its .asf)."""
    found = []
    for target in (out, out.with_suffix(".asf")):
        try:
            found += [q for q in target.parent.glob(f".{target.name}.*") if q.is_file()]
        except OSError:
            pass
    return found


def _stat(p: Path) -> tuple | None:
    try:
        st = p.stat()
        return (st.st_ino, st.st_size, st.st_mtime_ns)
    except OSError:
        return None


class _Stop:
    """Ctrl-C / SIGTERM while the batch runs: raise KeyboardInterrupt at once, except while
    the manifest is being updated (then the loop stops right after)."""

    def __init__(self) -> None:
        self.requested = False
        self.protect = 0
        self._old: dict[int, Any] = {}

    def __enter__(self) -> "_Stop":
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc) -> None:
        for sig, h in self._old.items():
            signal.signal(sig, h)

    def _handler(self, signum, frame) -> None:
        self.requested = True
        if not self.protect:
            raise KeyboardInterrupt

    def check(self) -> None:
        if self.requested:
            raise KeyboardInterrupt


def run_batch(in_dir: str | os.PathLike, out_dir: str | os.PathLike, *, method: str,
              params: dict[str, Any] | None = None, model: str | None = None, workers: int = 1,
              scheduler: str | None = None, patterns: Iterable[str] = DEFAULT_PATTERNS,
              progress: bool = True, log: Callable[[str], None] | None = None,
              policy: dict[str, Any] | None = None) -> Summary:
    """Clean every supported file under ``in_dir`` into the mirrored tree ``out_dir``.

    Returns a :class:`Summary`; also writes ``out_dir/batch.log`` (one line per file) and
    the resume manifest. ``workers`` local processes (1 = in this process), or tasks on
    the Dask cluster at ``scheduler``. Raises :class:`BatchInterrupted` (a
    KeyboardInterrupt) after stopping cleanly on Ctrl-C / SIGTERM, and MocapValueError
    when the folders overlap or another batch holds ``out_dir``.
    """
    from . import denoise

    params = dict(params or {})
    src, dst = Path(in_dir).resolve(), Path(out_dir).resolve()
    if not src.is_dir():
        raise MocapValueError(f"{in_dir}: input folder not found")
    if dst == src:
        raise MocapValueError(f"{out_dir}: output folder must differ from the input folder")
    if src in dst.parents:
        raise MocapValueError(f"{out_dir}: output folder is inside the input folder {in_dir}; "
                              f"choose one outside it (its files would be read as inputs or overwritten)")
    if dst in src.parents:
        raise MocapValueError(f"{out_dir}: output folder contains the input folder {in_dir}; "
                              f"choose one outside it")
    if os.path.lexists(dst) and not dst.is_dir():
        raise MocapValueError(f"{out_dir}: exists and is not a folder")
    from .denoise.base import params_from_text

    # the method, its parameters (names and types) and the model are checked once, before any work
    if model is None and method == DEFAULT:
        if params:
            raise MocapValueError("--param needs --method (the default method depends on each file)")
    elif model is None:
        cls = denoise.available().get(method)
        if cls is None:
            raise MocapValueError(f"unknown method {method!r}; available: {', '.join(denoise.available())}")
        from . import shipped

        if cls.needs_training and method not in shipped.available():
            raise MocapValueError(f"method {method!r} needs --model (no shipped general model)")
        params = params_from_text(method, params)
        denoise.get(method, **params)
    else:
        if not Path(model).is_file():
            raise MocapValueError(f"{model}: model file not found")
        den = denoise.base.Denoiser.load(model)
        if params:
            params = params_from_text(den.name, params, type(den))
            den.set_params(**params)
    from .io import SUPPORTED_EXTENSIONS

    pats = tuple(patterns)
    inputs = [p for p in find_inputs(src, pats)
              if p.suffix.lower() in SUPPORTED_EXTENSIONS and p.suffix.lower() != ".asf"]
    if not inputs:
        raise MocapValueError(f"{in_dir}: no motion files to clean (patterns {' '.join(pats)}; .asf skeletons "
                              f"are copied, not cleaned)")
    try:
        dst.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise MocapValueError(f"{out_dir}: cannot create the output folder ({e.strerror})") from None
    with BatchLock(dst):
        return _run_locked(src, dst, inputs, method=method, params=params, model=model, workers=workers,
                           scheduler=scheduler, progress=progress, log=log, policy=policy)


def _read_manifest(path: Path) -> dict[str, Any]:
    """The resume manifest of an earlier batch in this folder ({} when none or unreadable)."""
    if not path.exists():
        return {}
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return manifest if isinstance(manifest, dict) else {}


def _copy_skeletons(src: Path, dst: Path, skeletons: dict[str, str]) -> None:
    """Copy the ASF skeletons under ``src`` (not already in ``dst``) so mirrored AMC outputs
    can be read back; records each copy's sha256 in ``skeletons``."""
    from .io._atomic import atomic_write_path

    for asf in sorted(src.rglob("*.asf")):
        rel = str(asf.relative_to(src))
        target = dst / rel
        if any(part.startswith(".") for part in Path(rel).parts[:-1]) or target.exists():
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_path(target, lambda tmp, a=asf: shutil.copy2(a, tmp), suffix=".tmp")
        skeletons[rel] = sha256(target)


def _plan_files(src: Path, dst: Path, inputs: list[Path], files: dict[str, Any], ours: set[str]):
    """``(todo, results, prestate)``: the files to clean as (rel, input, output, stamp), the
    results of those skipped (unchanged since a run with these settings) or refused (an
    output this batch did not write), and the state of each output before the run."""
    todo, results, prestate = [], [], {}
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
        if os.path.lexists(out) and rel not in ours:
            fr = FileResult(rel, "failed", f"{out}: exists and was not written by mocapkit batch; "
                                           f"remove it or choose another output folder", input_stamp=stamp)
            results.append(fr)
            files[rel] = asdict(fr)
            continue
        out.parent.mkdir(parents=True, exist_ok=True)
        prestate[rel] = _stat(out)
        todo.append((rel, str(p), str(out), stamp))
    return todo, results, prestate


class _Run:
    """The bookkeeping of one batch run: results, the manifest (written after every file so
    an interrupted run resumes where it stopped) and the log lines."""

    def __init__(self, dst: Path, key: str, files: dict, skeletons: dict, ours: set, todo: list,
                 results: list, stop: _Stop, log: Callable[[str], None] | None):
        self.dst, self.key, self.files, self.skeletons, self.ours = dst, key, files, skeletons, ours
        self.todo, self.results, self.stop, self.log = todo, results, stop, log
        self.pending: set[str] = set()
        self.done: set[str] = set()
        self.log_lines: list[str] = []
        self.stamps = {r: s for r, _, _, s in todo}
        self.outs = {r: Path(o) for r, _, o, _ in todo}
        self.bar = None

    def save_manifest(self) -> None:
        _write_json(self.dst / MANIFEST, {"settings": self.key, "files": self.files,
                                          "skeletons": self.skeletons, "pending": sorted(self.pending)})

    def record(self, rel: str, res: dict[str, Any]) -> None:
        """Record one file's result (from :func:`process_one`), uninterruptibly."""
        self.stop.protect += 1
        try:
            fr = FileResult(rel, res["status"], res.get("reason", ""), res.get("frames", 0),
                            res.get("seconds", 0.0), res.get("output_sha256", ""), self.stamps[rel],
                            res.get("note", ""))
            out = self.outs[rel]
            if fr.status != "ok":
                for tmp in _temp_files(out):    # a worker that died mid-write
                    tmp.unlink(missing_ok=True)
            if fr.status != "ok" and rel in self.ours and os.path.lexists(out):
                # an earlier batch's output for other settings or input: remove it, so the
                # folder never holds an output the manifest does not vouch for
                out.unlink(missing_ok=True)
            self.results.append(fr)
            self.files[rel] = asdict(fr)
            self.pending.discard(rel)
            self.done.add(rel)
            line = f"{fr.status:<7} {rel}  {fr.frames} frames {fr.seconds:.2f} s {fr.reason or fr.note}".rstrip()
            self.log_lines.append(line)
            if self.log:
                self.log(line)
            self.bar.update()
            self.save_manifest()
        finally:
            self.stop.protect -= 1

    def close(self, procs: list, interrupted: bool, prestate: dict, header: str) -> None:
        """Stop the workers, reconcile files in flight after an interrupt, write the
        manifest and append ``header`` and the log lines to the batch log."""
        for p in procs:
            if p.is_alive():
                p.kill()
        for p in procs:
            p.join(1.0)
        self.bar.close()
        if interrupted:
            _reconcile(self.todo, self.done, prestate, self.outs, self.files, self.stamps, self.results,
                       self.pending, self.ours)
        self.pending.difference_update(self.done)
        self.save_manifest()
        with open(self.dst / LOG, "a", encoding="utf-8") as f:
            f.write(header)
            f.writelines(line + "\n" for line in self.log_lines)

    def summary(self, elapsed: float, interrupted: bool) -> Summary:
        results = sorted(self.results, key=lambda r: r.input)
        return Summary(ok=sum(r.status == "ok" for r in results),
                       failed=sum(r.status == "failed" for r in results),
                       skipped=sum(r.status == "skipped" for r in results),
                       frames=sum(r.frames for r in results if r.status == "ok"),
                       seconds=elapsed, results=results, interrupted=interrupted,
                       remaining=sum(1 for r, _, _, _ in self.todo if r not in self.done))


def _run_locked(src: Path, dst: Path, inputs: list[Path], *, method: str, params: dict[str, Any],
                model: str | None, workers: int, scheduler: str | None, progress: bool,
                log: Callable[[str], None] | None, policy: dict[str, Any] | None = None) -> Summary:
    manifest = _read_manifest(dst / MANIFEST)
    key = _settings_key(method, params, model, policy)
    old_files = manifest.get("files", {}) if isinstance(manifest.get("files"), dict) else {}
    same_settings = manifest.get("settings") == key
    # files an earlier batch wrote here (any settings): the only existing files it may replace
    ours = {rel for rel, e in old_files.items() if isinstance(e, dict) and e.get("status") == "ok"}
    ours |= set(manifest.get("pending", []) or [])
    files: dict[str, Any] = dict(old_files) if same_settings else {}
    skeletons: dict[str, str] = dict(manifest.get("skeletons", {}) or {})
    stop = _Stop()
    _copy_skeletons(src, dst, skeletons)
    todo, results, prestate = _plan_files(src, dst, inputs, files, ours)
    run = _Run(dst, key, files, skeletons, ours, todo, results, stop, log)
    t0 = time.perf_counter()
    from tqdm import tqdm

    run.bar = tqdm(total=len(todo), desc=f"batch {method}", unit="file", disable=None if progress else True,
                   leave=False)                                 # None: off when stderr is not a terminal
    interrupted = False
    procs: list = []
    with stop:
        try:
            stop.protect += 1
            run.pending.update(r for r, _, _, _ in todo)
            run.save_manifest()             # outputs about to be written are ours if we get killed
            stop.protect -= 1
            stop.check()
            if scheduler:
                _run_dask(scheduler, todo, method, params, model, run.record, stop, policy)
            elif workers <= 1:
                for r, i, o, s in todo:
                    stop.check()
                    run.record(r, process_one(i, o, method, params, model, policy))
            else:
                _run_local(workers, todo, method, params, model, run.record, stop, procs, policy)
        except KeyboardInterrupt:
            interrupted = True
        finally:
            stop.protect += 1               # no second interrupt while cleaning up
            try:
                run.close(procs, interrupted, prestate,
                          f"# {time.strftime('%Y-%m-%d %H:%M:%S')} method={method} params={params} "
                          f"model={model}{' (interrupted)' if interrupted else ''}\n")
            finally:
                stop.protect -= 1
    summ = run.summary(time.perf_counter() - t0, interrupted)
    if interrupted:
        raise BatchInterrupted(summ)
    return summ


def _reconcile(todo, done, prestate, outs, files, stamps, results, pending, ours) -> None:
    """After a stop: remove temp files of the files in flight; an output that was completed
    (renamed into place) but not yet reported is verified and recorded, so the manifest
    lists exactly the outputs on disk."""
    for rel, _, _, _ in todo:
        if rel in done:
            continue
        out = outs[rel]
        for tmp in _temp_files(out):
            tmp.unlink(missing_ok=True)
        now = _stat(out)
        if now is not None and now != prestate.get(rel):
            try:
                fr = FileResult(rel, "ok", "finished while stopping", 0, 0.0, sha256(out), stamps[rel])
            except OSError:
                continue
            results.append(fr)
            files[rel] = asdict(fr)
            done.add(rel)
        elif now is None:
            pending.discard(rel)            # nothing written: not ours to vouch for


def _run_local(workers, todo, method, params, model, record, stop: _Stop, procs: list,
               policy: dict[str, Any] | None = None) -> None:
    """``workers`` processes fed one file at a time over pipes (no queue threads to join),
    so a stop can kill them at once; a worker that dies fails its file and is replaced."""
    import multiprocessing as mp
    from multiprocessing.connection import wait

    ctx = mp.get_context()
    queue = list(reversed(todo))
    slots: list[dict[str, Any]] = []

    def start() -> dict[str, Any]:
        parent, child = ctx.Pipe()
        p = ctx.Process(target=_worker_loop, args=(child, method, params, model, policy), daemon=True)
        p.start()
        child.close()
        procs.append(p)
        slot = {"proc": p, "conn": parent, "task": None}
        slots.append(slot)
        return slot

    def feed(slot) -> None:
        task = queue.pop() if queue else None
        try:
            slot["conn"].send(task[:3] if task else None)
            slot["task"] = task[0] if task else None
        except OSError:                         # the worker is gone: the file goes back
            if task:
                queue.append(task)
            slot["task"] = None

    for _ in range(min(workers, len(todo))):
        feed(start())
    while slots:
        stop.check()
        ready = wait([s["conn"] for s in slots] + [s["proc"].sentinel for s in slots], timeout=0.2)
        for s in list(slots):
            if s["conn"] in ready:
                try:
                    rel, res = s["conn"].recv()
                except (EOFError, OSError):
                    s["eof"] = True             # exited or died: handled below
                else:
                    s["task"] = None
                    record(rel, res)
                    if s["proc"].is_alive():
                        feed(s)
                    stop.check()
            if s.get("eof") and s["proc"].exitcode is None:
                s["proc"].join(1.0)             # closed its end: let it finish exiting
            if s["proc"].exitcode is not None and (s.get("eof") or not s["conn"].poll()):
                code = s["proc"].exitcode
                slots.remove(s)
                s["conn"].close()
                if s["task"] is not None:
                    why = f"signal {-code}" if code < 0 else f"exit code {code}"
                    record(s["task"], {"status": "failed", "reason": f"worker process died ({why}) on this file"})
                if queue:
                    feed(start())


def _run_dask(scheduler, todo, method, params, model, record, stop: _Stop,
              policy: dict[str, Any] | None = None) -> None:
    from dask.distributed import Client, as_completed as dask_completed

    with Client(scheduler) as client:
        futs = {client.submit(process_one, i, o, method, params, model, policy, pure=False): r
                for r, i, o, _ in todo}
        try:
            for fut in dask_completed(futs):
                try:
                    res = fut.result()
                except Exception as e:  # noqa: BLE001 - a lost worker fails its file only
                    res = {"status": "failed", "reason": f"cluster error: {type(e).__name__}: {e}"}
                record(futs[fut], res)
                stop.check()
        except KeyboardInterrupt:
            client.cancel(list(futs))
            raise


def _write_json(path: Path, obj: Any) -> None:
    from .io._atomic import atomic_write

    atomic_write(path, lambda f: json.dump(obj, f, indent=1))
