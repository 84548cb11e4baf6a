"""Elementary rotation matrices shared by the BVH and ASF/AMC kinematics."""
from __future__ import annotations

import numpy as np


def axis_rotation(axis: int, radians: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) about coordinate axis 0/1/2 by ``radians`` (...,).

    Column-vector convention: ``R @ v`` rotates ``v`` counter-clockwise about the axis.
    """
    c, s = np.cos(radians), np.sin(radians)
    R = np.zeros(np.shape(radians) + (3, 3))
    i, j = (axis + 1) % 3, (axis + 2) % 3
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    return R
