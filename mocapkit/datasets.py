"""Where the data is: bundled clips and the shared real data set.

The shared data set (CMU, HDM05, markers, MSR-Action3D; see its README) is found at,
in order: the ``data_dir`` argument, ``$MOCAPKIT_DATA``, ``../shared/data`` relative to
the repository root. Tests and benchmarks that need it skip or fail with a clear
message when it is absent.
"""
from __future__ import annotations

import os
from pathlib import Path

from .errors import MocapValueError

BUNDLED_DIR = Path(__file__).parent / "data"
_REPO_ROOT = Path(__file__).resolve().parent.parent


def shared_data_dir(data_dir: str | os.PathLike | None = None) -> Path | None:
    """The shared data folder, or None when it cannot be found."""
    for cand in (data_dir, os.environ.get("MOCAPKIT_DATA"), _REPO_ROOT.parent / "shared" / "data"):
        if cand and Path(cand).is_dir():
            return Path(cand)
    return None


def bundled(name: str) -> Path:
    """Path of a clip shipped in ``mocapkit/data`` (e.g. ``'16_15.amc'``)."""
    hits = sorted(BUNDLED_DIR.rglob(name))
    if not hits:
        have = sorted(p.name for p in BUNDLED_DIR.rglob("*") if p.is_file())
        raise MocapValueError(f"no bundled file {name!r}; bundled: {', '.join(have)}")
    return hits[0]


def cmu_amc(trial: str, data_dir: str | os.PathLike | None = None) -> Path | None:
    """Path of CMU trial ``'SS_TT'`` as ASF/AMC in the shared (or bundled) data, else None."""
    subject = trial.split("_")[0]
    roots = [d for d in (shared_data_dir(data_dir),) if d is not None]
    for root in roots:
        p = root / "cmu" / "asfamc" / subject / f"{trial}.amc"
        if p.is_file():
            return p
    hits = sorted(BUNDLED_DIR.rglob(f"{trial}.amc"))
    return hits[0] if hits else None


def cmu_trials(data_dir: str | os.PathLike | None = None) -> list[str]:
    """All CMU ASF/AMC trial ids present in the shared data."""
    root = shared_data_dir(data_dir)
    if root is None:
        return []
    return sorted(p.stem for p in (root / "cmu" / "asfamc").rglob("*.amc"))
