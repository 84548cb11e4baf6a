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


def kinect_skeleton():
    """The 20-joint Kinect (MSR-Action3D) skeleton, standing, in cm (a plain function:
    ``from conftest import kinect_skeleton``)."""
    from mocapkit.skeleton import Skeleton

    names = ["HipCenter", "Spine", "ShoulderCenter", "Head", "ShoulderLeft", "ElbowLeft",
             "WristLeft", "HandLeft", "ShoulderRight", "ElbowRight", "WristRight", "HandRight",
             "HipLeft", "KneeLeft", "AnkleLeft", "FootLeft", "HipRight", "KneeRight",
             "AnkleRight", "FootRight"]
    parents = [-1, 0, 1, 2, 2, 4, 5, 6, 2, 8, 9, 10, 0, 12, 13, 14, 0, 16, 17, 18]
    rest = np.array([[0, 100, 0], [0, 120, 0], [0, 145, 0], [0, 165, 0], [-18, 142, 0],
                     [-20, 115, 0], [-21, 90, 0], [-21, 82, 0], [18, 142, 0], [20, 115, 0],
                     [21, 90, 0], [21, 82, 0], [-10, 95, 0], [-10, 52, 0], [-10, 10, 0],
                     [-10, 2, 8], [10, 95, 0], [10, 52, 0], [10, 10, 0], [10, 2, 8]], float)
    return Skeleton.from_positions(names, parents, rest)
