"""Reading mocapkit's own ``.npz`` files (models, indexes): one place for the checks."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..errors import MocapFormatError


def read_npz(path: str | os.PathLike, what: str) -> tuple[dict, dict]:
    """(header, arrays) of a mocapkit ``.npz`` file with a JSON ``header`` array.

    ``what`` names the kind of file in the errors ("classifier model", "index file"); a
    missing file, a file that is not an npz archive (no pickle is ever loaded) or one
    without a readable header raise MocapFormatError naming the file.
    """
    p = Path(path)
    if not p.is_file():
        raise MocapFormatError(p, f"{what} not found")
    try:
        with np.load(p, allow_pickle=False) as z:
            st = {k: z[k] for k in z.files}
    except Exception as e:                                    # not an npz archive
        raise MocapFormatError(p, f"not a mocapkit {what} ({type(e).__name__})") from None
    try:
        header = json.loads(str(st["header"]))
    except (KeyError, ValueError):
        raise MocapFormatError(p, f"not a mocapkit {what} (no header)") from None
    if not isinstance(header, dict):
        raise MocapFormatError(p, f"not a mocapkit {what} (bad header)")
    return header, st
