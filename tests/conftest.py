"""Shared fixtures. Tests needing ../shared/data use ``shared_data`` and skip cleanly without it."""
from __future__ import annotations

import os

import numpy as np
import pytest

from mocapkit.datasets import shared_data_dir


@pytest.fixture(scope="session")
def shared_data():
    d = shared_data_dir()
    if d is None:
        pytest.skip("shared data set not found (set MOCAPKIT_DATA or place it at ../shared/data)")
    return d


@pytest.fixture
def rng():
    return np.random.default_rng(0)


def fuzz_examples(default: int = 60) -> int:
    """Hypothesis example count: small in `make test`, large in `make fuzz`."""
    return int(os.environ.get("MOCAPKIT_FUZZ_EXAMPLES", default))
