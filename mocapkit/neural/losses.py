"""Training losses of BRA / BRA-P (Li et al. 2020, seed 002, Sec. III.C), torch.

All take batches (B, f, d) (d = 3J channels, joint-major ``x0 y0 z0 x1 ...``) and return a
scalar tensor (mean over the batch).

Reading of ``||.||_2`` (decision): eq. (3) is introduced as "the mean square loss (MSE)",
so the training losses (3), (4) and (6) are mean *squared* errors with the paper's
normalisers ``1/(f d)``, ``1/(f 512)`` and ``1/((f+2) d)``. Eq. (7) is written out
explicitly (mean absolute bone-length deviation) and is used as written. The *reported*
R, B and S (``mocapkit.metrics.brap_*``) use the mean-absolute reading in cm.

Units: the losses act on the network's normalised data; the bone-length loss needs
positions with the right geometry, so it takes ``Z + mean/std`` (positions in units of
the normalisation std, :func:`denormalised`).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from . import require_torch


def smoothness_matrix(f: int) -> np.ndarray:
    """The (f+2) x (f+2) matrix O of eq. (5): rows [-1, 1], [1, -2, 1] ..., [1, -1]."""
    n = f + 2
    O = np.zeros((n, n))
    O[0, :2] = (-1.0, 1.0)
    O[-1, -2:] = (1.0, -1.0)
    for i in range(1, n - 1):
        O[i, i - 1:i + 2] = (1.0, -2.0, 1.0)
    return O


def border_repeat(x: Any) -> Any:
    """X' of Sec. III.C.3: (B, f, d) -> (B, f+2, d) with the first and last frame repeated."""
    torch = require_torch()
    return torch.cat([x[:, :1], x, x[:, -1:]], dim=1)


def reproduction(y: Any, x: Any) -> Any:
    """Eq. (3), L_R(Y, X) = (1/(f d)) ||Y - X||^2 (MSE), mean over the batch."""
    return ((y - x) ** 2).mean()


def reproduction_rms(y: Any, x: Any, eps: float = 1e-4) -> Any:
    """Eq. (3) with ``||.||_2`` read as the norm itself (not squared): the per-clip RMS
    ``sqrt((1/(f d)) ||Y - X||^2 + eps)``, averaged over the batch (issue 20).

    With a batch mixing 1 dB (~14 cm) and near-clean clips, the MSE is all but the
    heavy-noise clips' error, so a network trained on it neglects small errors (measured:
    a residual network at 400 steps made 3 cm clips worse than its own input low-pass);
    the per-clip RMS weights every clip's error by 1 / its size, i.e. it minimises the
    mean per-clip error that Table 1's R reports. ``eps`` (normalised units^2) keeps the
    gradient finite at a perfect clip.
    """
    return (((y - x) ** 2).mean(dim=tuple(range(1, y.dim()))) + eps).sqrt().mean()


def perceptual(h_r: Any, h_c: Any) -> Any:
    """Eq. (4), L_P = (1/(f h)) ||E_p(X_R) - E_p(X_C)||^2 (MSE of the hidden units)."""
    return ((h_r - h_c) ** 2).mean()


def smoothness(x: Any) -> Any:
    """Eqs. (5)-(6), L_S(X) = (1/((f+2) d)) ||O X'||^2 with X' border-repeated.

    Computed as second differences of X' (rows 2..f+1 of O X'; rows 1 and f+2 are
    identically zero because X'_1 = X'_2 and X'_{f+1} = X'_{f+2}), divided by (f+2) d.
    """
    xp = border_repeat(x)
    inner = xp[:, :-2] - 2 * xp[:, 1:-1] + xp[:, 2:]            # (B, f, d)
    B, f, d = x.shape
    return (inner ** 2).sum() / (B * (f + 2) * d)


def bone_lengths(x: Any, bones: Any, eps: float = 1e-8) -> Any:
    """Bone lengths (B, f, nb) of positions x (B, f, 3J) for (child, parent) pairs (nb, 2)."""
    B, f, d = x.shape
    p = x.reshape(B, f, d // 3, 3)
    v = p[:, :, bones[:, 0]] - p[:, :, bones[:, 1]]
    return ((v ** 2).sum(-1) + eps).sqrt()


def bone_length(x: Any, bones: Any, ref: Any) -> Any:
    """Eq. (7), L_B = (1/(f (J-1))) sum_i sum_b | ||p_b^{i,1} - p_b^{i,2}|| - l_b |.

    Parameters
    ----------
    x : (B, f, 3J) positions (units of your choice, e.g. :func:`denormalised`).
    bones : (J-1, 2) long tensor of (child, parent) joint indices.
    ref : (B, J-1) reference lengths l_b per sample (same units), e.g. the mean length of
        each bone over the clean clip.
    """
    return (bone_lengths(x, bones) - ref[:, None, :]).abs().mean()


def denormalised(z: Any, mean_over_std: Any) -> Any:
    """Positions in units of the normalisation std: Z + mean / std (shape-preserving)."""
    return z + mean_over_std
