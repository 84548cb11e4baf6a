"""Least-squares polish of the BVH writer's inverse kinematics (:func:`polish`).

The writer's closed-form IK (:func:`mocapkit.io.bvh._inverse_kinematics`) points every
bone from where its parent was put towards its child's target. On positions the
hierarchy can hold (clean data, a motion whose bones are held) that is exact; on
positions off the skeleton (noise, a filter that shortened the bones) every joint takes
the error of the joints above it too, and the chain crumples: with 3 cm of white noise
on CMU 49_19 at 120 fps the written file was 3.06 cm RMS off the truth (the head 3.6),
and 5 cm off *on average over the clip* at the head -- an error that no smoother of the
file takes out. The AMC writer fits all of a frame's dofs at once (Levenberg-Marquardt,
:mod:`mocapkit.io._kinematics`): 2.2 cm from the same noise. This module does
the same for BVH: Levenberg-Marquardt on every channel of a frame, started from the
closed-form IK, on the frames that IK leaves off their targets.

Jacobian (file units, degrees): channel c of node k moves each node j of k's subtree
(k itself included) by

* a rotation channel about the world axis ``w_c`` (the column of ``G_parent R_1 .. R_{i-1}``
  for the channel's axis -- the channels of a node apply in their listed order):
  ``(pi / 180) w_c x (x_j - x_k)``;
* a position channel along axis a: ``G_parent e_a`` (the translation is in the parent's
  frame).

Its normal equations ``J J^T``, ``J r`` come without forming J, from per-subtree position
moments (:func:`mocapkit.io._kinematics._ik_normal_equations`, shared with the AMC
writer), and the Levenberg-Marquardt loop is the AMC polish's
(:func:`mocapkit.io._kinematics.lm_frames`).
"""
from __future__ import annotations

import numpy as np

from ._kinematics import bone_mismatch, lm_frames, polish_gate

__all__ = ["polish"]

#: frames per block of the polish (memory: a few block x channels^2 arrays of 8 B,
#: 256 x 126^2 -> 33 MB each for the 41-joint CMU hierarchy the writer builds)
BLOCK = 256


class _Columns:
    """The tables :func:`mocapkit.io._kinematics._ik_normal_equations` reads, for a BVH
    hierarchy: per channel column its node's subtree (D, N), pivot node, the nested-subtree
    masks, and the position channels (``trans_cols``: translations along the parent's axis,
    whose world direction :func:`_fk_axes` puts in W)."""

    def __init__(self, nodes, layout):
        rot, pos, C = layout
        N = len(nodes)
        sub = np.eye(N)
        for j in range(N - 1, -1, -1):                    # parents come first in ``nodes``
            if nodes[j].parent >= 0:
                sub[nodes[j].parent] = np.maximum(sub[nodes[j].parent], sub[j])
        node = np.zeros(C, np.intp)
        for k in range(N):
            node[rot[k][1]] = k
            node[pos[k][1]] = k
        self.n_dofs = C
        self.fk_trans: list = []
        self.trans_cols = np.array([c for k in range(N) for c in pos[k][1]], np.intp)
        self.dof_pivot = node
        self.dof_subtree = np.ascontiguousarray(sub[node])
        inside = sub[node][:, node] > 0
        self.nest_lo = inside.astype(float)
        self.nest_hi = (inside.T & ~inside).astype(float)


def _fk_axes(nodes, layout, ch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Node positions (T, N, 3) and every channel's world axis (T, C, 3), file units
    (:func:`mocapkit.io.bvh._fk_chunk`)."""
    from .bvh import _fk_chunk                      # bvh imports this module

    W = np.zeros((layout[2], 3, ch.shape[0]))
    X, _ = _fk_chunk(nodes, layout, ch, False, chan_axes=W)
    return np.transpose(X, (2, 0, 1)), np.transpose(W, (2, 0, 1))


def _mismatch(nodes, targets: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """(T, B) :func:`~mocapkit.io._kinematics.bone_mismatch` of the hierarchy's fixed bones
    (a node and its parent, both with targets, no position channels: the OFFSET's length)."""
    pairs = [(j, n.parent, float(np.linalg.norm(n.offset))) for j, n in enumerate(nodes)
             if n.parent >= 0 and usable[j] and usable[n.parent]
             and not any(c.lower().endswith("position") for c in (n.channels or ()))]
    if not pairs:
        return np.zeros((targets.shape[0], 0))
    j, p, L = (np.array(v) for v in zip(*pairs))
    return bone_mismatch(targets, np.column_stack([j, p]), L)


def polish(nodes, layout, ch: np.ndarray, targets: np.ndarray, have: np.ndarray, *,
           iters: int = 8, above: float = 1e-3, cap: float = 0.5, spread: float = 0.01,
           rel_tol: float = 1e-3) -> np.ndarray:
    """Channels (T, C) refined so that the FK of the nodes with a target (``have`` (N,))
    is nearest their ``targets`` (T, N, 3) in the least-squares sense, per frame.

    ``ch`` (T, C): the closed-form IK's channels (degrees, file units), the start. Only
    frames where it leaves a node further off its target than ``min(above + 3 m, cap)``
    (file units; m the frame's largest bone-length mismatch of the targets) and the median
    bone of the frame is off its length by more than ``spread`` (noise, not one misfit
    bone) are refined;
    each frame has its own Marquardt damping, keeps a step only if it lowers its squared
    error and stops once a step gains less than ``rel_tol`` of it. A channel no target
    constrains (a twist no child shows) gets no step.

    >>> import numpy as np
    >>> from mocapkit.io.bvh import _Node, _layout, forward_kinematics
    >>> nodes = [_Node("root", -1, 0, np.zeros(3), ("Xposition", "Yposition", "Zposition",
    ...                "Zrotation", "Xrotation", "Yrotation"), children=[1]),
    ...          _Node("a", 0, 0, np.array([0.0, 10, 0]), ("Zrotation", "Xrotation", "Yrotation"), children=[2]),
    ...          _Node("b", 1, 0, np.array([0.0, 10, 0]), (), end_site=True)]
    >>> tgt = np.array([[[0.0, 0, 0], [0, 10, 0], [0, 18, 8]]])    # b 1.3 cm beyond a's reach
    >>> start = np.zeros((1, 9))                                     # the rest pose
    >>> def sq(c): return float(np.sum((forward_kinematics(nodes, c, rotations=False)[0][0] - tgt[0]) ** 2))
    >>> out = polish(nodes, _layout(nodes), start, tgt, np.ones(3, bool))
    >>> round(sq(start), 2), round(sq(out), 2)     # the optimum (scipy, 20 starts): 0.996
    (68.0, 1.0)
    """
    ch = np.array(ch, dtype=float, copy=True)
    usable = np.asarray(have, bool)
    if not usable.any() or not layout[2]:
        return ch
    cols = _Columns(nodes, layout)
    tgt = np.where(usable[None, :, None], targets, 0.0)

    def fk(c, frames=slice(None)):
        """(cost, residuals, positions, axes) of channels ``c`` for ``frames``: as
        :func:`lm_frames` takes them."""
        X, W = _fk_axes(nodes, layout, c)
        r = (X - tgt[frames]) * usable[None, :, None]
        return np.sum(r ** 2, axis=(1, 2)), r, X, W

    cost, r, X, W = fk(ch)
    # as the AMC writer (:func:`mocapkit.io._kinematics.inverse_kinematics`): a frame is
    # polished where the closed-form IK leaves a joint further off than the targets' own
    # bone-length mismatch explains (3 x the largest, capped at ``cap``): what no pose can
    # reach is not chased. And only where most bones are off their length (the median
    # over ``spread``): noise. Where one or two are (a joint whose position channels a
    # new hierarchy drops, a skeleton whose bone differs from the data's), the closed form
    # keeps every other joint exact and the misfit where it is, which the least squares
    # would share out over the joints around it
    worst = np.sqrt(np.max(np.sum(r ** 2, axis=2), axis=1))
    mis = _mismatch(nodes, targets, usable)
    m_med = np.median(mis, axis=1) if mis.shape[1] else np.zeros(len(worst))
    live = np.flatnonzero((worst > polish_gate(mis, above, cap)) & (m_med > spread))
    for a in range(0, len(live), BLOCK):
        f = live[a:a + BLOCK]
        ch[f] = lm_frames(cols, ch[f], X[f], W[f], np.broadcast_to(usable, (len(f), len(usable))), r[f],
                          cost[f], lambda D, k: fk(D, f[k]), iters=iters, angle_rad=False,
                          rel_tol=rel_tol)
    return ch
