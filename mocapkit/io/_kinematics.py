"""Acclaim kinematics: the compiled skeleton, forward kinematics and the write-back IK.

Rotation helpers are shared with the BVH module (:mod:`mocapkit.io._rotations`); the
file formats are :mod:`mocapkit.io.asf` and :mod:`mocapkit.io.amc`.

Forward kinematics (the Acclaim convention, vectorised over frames)
-------------------------------------------------------------------
For each bone ``b`` with parent ``p`` (``p`` = root for the top bones)::

    C_b = R(axis_b)                                   # rotation of the bone's 'axis'
    M_b = R(dof values of the frame)                  # zeros for absent dofs
    L_b = L_p · C_b · M_b · C_b^-1                    # global rotation of the bone
    end_b = end_p + L_b · (direction_b · length_b)    # bone vector in the global rest frame

``R(angles)`` applies the elementary rotations in the order of the bone's ``axis`` string
(``XYZ``: first about X, then Y, then Z, i.e. ``R = Rz · Ry · Rx`` for column vectors);
the three angles of ``axis`` are listed in that same order. The root uses
``L_root = C_root · M_root · C_root^-1`` with ``C_root`` from ``orientation`` and the
root ``axis`` order; the root joint sits at the AMC root translation (the AMC gives an
absolute position; the ASF ``position`` is the rest position used by
:func:`mocapkit.io.amc.read_asf_motion`). The loop runs over tree levels (all bones of a
depth at once), in blocks of frames.

Joints of the returned Motion: ``root`` plus the end point of every bone, named by the
bone (31 joints for CMU, 31 for HDM05); parents follow the ``:hierarchy``; rest offsets
are ``direction · length`` in cm.

Inverse kinematics (the AMC write-back)
---------------------------------------
:func:`inverse_kinematics` recovers the dofs from target positions per bone, top-down
and vectorised over frames:

1. every rotating node (root, and each bone with rotational dofs) starts from its
   stored local rotation (when ``per_frame['dofs']`` still aligns with the frames) or
   from the rest pose;
2. its global rotation is corrected by the *minimal* rotation that maps its predicted
   bone vector onto the vector from the already-solved parent end point to its target
   end point; bones without dofs hanging from it (CMU ``lhipjoint``/``rhipjoint`` on the
   root) are fitted together with it (Kabsch when several vectors: a scaled Newton
   polar iteration, SVD only for ill-conditioned frames); the free twist of a 3-dof bone
   about its own axis comes in closed form from a one-dof child (knee, elbow): the
   twist that puts the child's target on the cone its hinge allows
   (``A + B cos t + C sin t = cos g``; of the two roots the one whose hinge angle is
   inside the ASF limits, then the one nearer the twist its children predicted with
   their stored rotations give); other children: that least-squares twist;
3. the local rotation ``M = C^-1 · L_p^T · L_b · C`` is converted to the bone's Euler
   angles (the branch and 360° turn nearest to the start value). Bones with fewer than
   3 rotational dofs get the closest representable rotation, in closed form: one dof,
   the exact single-axis optimum; two dofs, the two exact solutions for the bone vector
   (its first rotation keeps the vector's component along the first axis, the second
   must produce the target's component along the second axis) and the start branch,
   polished by a few 2x2 Gauss-Newton steps when dof-less descendants or low-weight
   children also count; the other angles zero;
4. a Levenberg-Marquardt polish of all dofs of a frame at once (analytic normal
   equations ``J^T J``, ``J^T r`` from per-subtree position moments, without forming
   J; at most 12 iterations, a step kept only if it lowers that frame's squared
   position error) runs only on the frames the closed-form pass leaves more than
   ``min(0.001 cm + 3 x the frame's largest bone-length error of the targets, 0.5 cm)``
   off: the error a target set no pose can reach explains is not chased.

The root translation is taken from the root target. Missing (NaN) targets keep the
start rotation (write a fully observed motion: fill gaps first). Speed and accuracy
against the previous IK (scan + golden-section partial fits and LM on every frame) on
real CMU clips are in ``docs/results/io_speed.md`` (``benchmarks/io_speed.py``): on
kalman-cv output the same max/mean error at several times the speed; poses the
skeleton can reach (stored angles + N(0, 2°)) come back to ~0.001 cm; without stored
dofs clean positions come back within ~0.15 cm (the previous IK: up to 9 cm on 131_02);
noisy positions give the skeleton's least-squares fit, as before.
"""
from __future__ import annotations

import numpy as np

from ..errors import MocapValueError
from ..skeleton import Skeleton
from . import _rotations as rot
from ._rotations import axis_rotation
from ..windows import frame_blocks

__all__ = ["forward_kinematics", "inverse_kinematics"]

_CHILD_W = 0.3          # sqrt of the weight of predicted child vectors in the partial-dof fit


# ======================================================================================
# compiled skeleton: joint order, matrices, dof layout
# ======================================================================================
def _euler_matrix(order: str, angles_xyz: np.ndarray) -> np.ndarray:
    """R for angles given per axis (…, 3) as (x, y, z) radians, applied in ``order`` (first letter first)."""
    axes = ["XYZ".index(c) for c in reversed(order)]
    return rot.euler_to_matrix(axes, np.asarray(angles_xyz, float)[..., axes])


def _parents_first(bones: list[dict], parent: dict[str, str]) -> list[str]:
    """Bone names in a stable topological order of the bonedata order (parents first)."""
    placed = {"root"}
    order: list[str] = []
    pending = [b["name"] for b in bones]
    while pending:
        nxt = [n for n in pending if parent[n] in placed]
        if not nxt:                      # read_asf guarantees this cannot happen
            raise MocapValueError("ASF hierarchy is cyclic")
        for n in pending:
            if parent[n] in placed:
                placed.add(n)
                order.append(n)
        pending = [n for n in pending if n not in placed]
    return order


class _Compiled:
    """Everything FK/IK needs, derived once from an ASF description."""

    def __init__(self, asf: dict):
        self.asf = asf
        bones = asf["bones"]
        parent = {c: par for par, children in asf["hierarchy"] for c in children}
        order = _parents_first(bones, parent)
        self.bone_order = order
        self.names = ("root",) + tuple(order)
        jidx = {n: i for i, n in enumerate(self.names)}
        self.parent_joint = np.array([-1] + [jidx[parent[n]] for n in order])
        self.angle_rad = asf["units"]["angle"] == "rad"
        # root
        r = asf["root"]
        self.root_order = list(r["order"])
        self.root_axis = r["axis"]
        ang_xyz = self._to_xyz(np.asarray(r["orientation"], float), self.root_axis)
        self.C_root = _euler_matrix(self.root_axis, self._rad(ang_xyz))
        self._dof_layout(bones)
        self._bone_frames(bones)
        self.children = {n: [] for n in self.names}
        for n in order:
            self.children[parent[n]].append(n)
        self.parent = parent
        self.joint_index = jidx
        self._ik_tables()
        self._fk_tables()

    def _dof_layout(self, bones: list[dict]) -> None:
        """Columns of ``per_frame['dofs']``: the root channels, then the bones in ASF order."""
        names: list[str] = [f"root.{c}" for c in self.root_order]
        self.dof_cols: dict[str, list[int]] = {"root": list(range(len(self.root_order)))}
        for b in bones:
            k0 = len(names)
            names += [f"{b['name']}.{d}" for d in b["dof"]]
            self.dof_cols[b["name"]] = list(range(k0, len(names)))
        self.dof_names = names
        self.n_dofs = len(names)
        self.bone_dofs = {b["name"]: list(b["dof"]) for b in bones}

    def _bone_frames(self, bones: list[dict]) -> None:
        """Per bone: rest vector (file units), its ``axis`` rotation C, order, dof axis indices."""
        self.vec, self.C, self.order, self.dof_axes = {}, {}, {}, {}
        for b in bones:
            n = b["name"]
            self.vec[n] = np.asarray(b["direction"], float) * float(b["length"])
            ax = self._to_xyz(np.asarray(b["axis"], float), b["axis_order"])
            self.C[n] = _euler_matrix(b["axis_order"], self._rad(ax))
            self.order[n] = b["axis_order"]
            self.dof_axes[n] = ["xyz".index(d[1]) for d in b["dof"]]

    def _ik_tables(self) -> None:
        """IK tables: the dof-less bones rigid with each node, the first dof-carrying bones
        below it (with the dof-less path to them), the joints each node moves, whether a
        bone lies near one of its dof axes, and the twist regulariser."""
        jidx = self.joint_index
        self.dofless_desc: dict[str, list[str]] = {}
        self.dof_children: dict[str, list[tuple[str, list[str]]]] = {}
        self.subtree: dict[str, np.ndarray] = {}
        for n in self.names:
            rigid, firsts, stack = [], [], [(c, []) for c in self.children[n]]
            while stack:
                c, path = stack.pop(0)
                if self.dof_axes[c]:
                    firsts.append((c, path))
                else:
                    rigid.append(c)
                    stack.extend((g, path + [c]) for g in self.children[c])
            self.dofless_desc[n] = rigid
            self.dof_children[n] = firsts
            sub, stack = [jidx[n]], list(self.children[n])
            while stack:
                c = stack.pop()
                sub.append(jidx[c])
                stack.extend(self.children[c])
            self.subtree[n] = np.array(sorted(sub))
        self.axis_aligned = {}
        for n in self.bone_order:
            u = self.C[n].T @ self.vec[n]
            nu = np.linalg.norm(u)
            self.axis_aligned[n] = bool(nu > 0 and any(np.linalg.norm(np.cross(np.eye(3)[a], u)) < 0.3 * nu
                                                       for a in self.dof_axes[n]))
        self.twist_reg = {n: 0.05 * sum(float(self.vec[c] @ self.vec[c]) for c, _ in self.dof_children[n])
                          for n in self.bone_order}

    def _fk_tables(self) -> None:
        """Tables of the level-batched FK (:func:`_fk_block`) and the IK Jacobian.

        ``fk_levels``: per tree depth ``(joints, parent joints or None for the root,
        groups)``, a group ``(axis, positions in the level or None for all, dof columns)``
        per rotation step (last letter of the ``axis`` order first) and axis;
        ``fk_K``,
        ``fk_U``: the fixed ``C_parent^T C`` and ``C^T vec`` of :func:`_fk_block`;
        ``local_groups``: the groups of all nodes at once (:func:`_local_rotations`);
        ``dof_pivot``, ``dof_subtree``, ``nest_lo``, ``nest_hi``: see
        :func:`_ik_normal_equations`."""
        J = len(self.names)
        self.fk_C = np.zeros((3, 3, J))
        vec = np.zeros((3, J))
        self.fk_C[:, :, 0] = self.C_root
        rcol = {"XYZ".index(ch[1]): k for k, ch in enumerate(self.root_order) if ch[0] == "R"}
        steps = [[(a, rcol[a]) for a in ("XYZ".index(x) for x in reversed(self.root_axis)) if a in rcol]]
        depth = np.zeros(J, int)
        for j, n in enumerate(self.bone_order, start=1):
            self.fk_C[:, :, j] = self.C[n]
            vec[:, j] = self.vec[n]
            ax = self.dof_axes[n]
            steps.append([(a, self.dof_cols[n][ax.index(a)])
                          for a in ("XYZ".index(x) for x in reversed(self.order[n])) if a in ax])
            depth[j] = depth[self.parent_joint[j]] + 1
        self.fk_CT = np.ascontiguousarray(np.transpose(self.fk_C, (1, 0, 2)))
        # FK in the frames F_b = L_b C_b: F_child = F_parent K_child with the fixed
        # K_child = C_parent^T C_child, end_child = end_parent + F_child (C_child^T vec_child)
        K = [self.fk_C[:, :, 0]] + [self.fk_CT[:, :, self.parent_joint[j]] @ self.fk_C[:, :, j] for j in range(1, J)]
        self.fk_K = np.stack(K, axis=2)
        self.fk_U = np.einsum("jib,jb->ib", self.fk_C, vec)
        self.fk_trans = [(k, "XYZ".index(ch[1])) for k, ch in enumerate(self.root_order) if ch[0] == "T"]

        def groups_of(idx):
            groups = []
            for s in range(3):
                for a in range(3):
                    k = [i for i, j in enumerate(idx) if len(steps[j]) > s and steps[j][s][0] == a]
                    if k:
                        cols = np.array([steps[idx[i]][s][1] for i in k])
                        groups.append((a, None if len(k) == len(idx) else np.array(k), cols))
            return groups
        self.fk_levels = []
        for d in range(depth.max() + 1):
            idx = np.flatnonzero(depth == d)
            self.fk_levels.append((idx, None if d == 0 else self.parent_joint[idx], groups_of(idx)))
        self.local_groups = groups_of(np.arange(J))      # local rotations need no tree order
        # tables of the normal equations without the Jacobian (:func:`_ik_normal_equations`):
        # the pivot joint of every dof column, the joints each column moves and which
        # column pairs share joints (nested subtrees)
        node = np.zeros(self.n_dofs, np.intp)
        pivot = np.zeros(self.n_dofs, np.intp)
        for j in range(1, J):
            node[self.dof_cols[self.names[j]]] = j
            pivot[self.dof_cols[self.names[j]]] = self.parent_joint[j]
        self.dof_pivot = pivot
        sub = np.zeros((J, J))
        for j, n in enumerate(self.names):
            sub[j, self.subtree[n]] = 1.0
        self.dof_subtree = np.ascontiguousarray(sub[node])       # (D, J): the joints each column moves
        inside = sub[node][:, node] > 0                   # [d, e]: node(e) in the subtree of node(d)
        self.nest_lo = inside.astype(float)
        self.nest_hi = (inside.T & ~inside).astype(float)

    @staticmethod
    def _to_xyz(vals: np.ndarray, order: str) -> np.ndarray:
        """Angles listed in ``order`` (value i about letter order[i]) -> (x, y, z)."""
        out = np.zeros(np.shape(vals)[:-1] + (3,))
        for i, letter in enumerate(order):
            out[..., "XYZ".index(letter)] = vals[..., i]
        return out

    def _rad(self, a):
        return np.asarray(a, float) if self.angle_rad else np.deg2rad(a)

    def skeleton(self, f: float) -> Skeleton:
        off = [np.asarray(self.asf["root"]["position"], float) * f]
        off += [self.vec[n] * f for n in self.bone_order]
        return Skeleton(self.names, self.parent_joint, np.array(off))

    # -- root channels ----------------------------------------------------------------
    def root_split(self, dofs: np.ndarray, angle_rad: bool):
        """(translation (T,3) file units, rotation angles (T,3) xyz radians) from root columns."""
        T = dofs.shape[0]
        tr = np.zeros((T, 3))
        ang = np.zeros((T, 3))
        for k, ch in enumerate(self.root_order):
            a = "XYZ".index(ch[1])
            if ch[0] == "T":
                tr[:, a] = dofs[:, k]
            else:
                ang[:, a] = dofs[:, k] if angle_rad else np.deg2rad(dofs[:, k])
        return tr, ang


def forward_kinematics(comp: _Compiled, dofs: np.ndarray, angle_rad: bool, f: float) -> np.ndarray:
    """Joint positions (T, J, 3) in cm from dof values (T, D) (file units, file angles).

    Bones of the same depth are rotated together (one pass per tree level, none over
    frames or bones), in blocks of frames (:func:`mocapkit.windows.frame_blocks`: the (3, 3,
    bones, block) stacks stay in cache); see :func:`_fk_block`.
    """
    dofs = np.asarray(dofs, float)
    T = dofs.shape[0]
    P = np.empty((T, len(comp.names), 3))
    for sl in frame_blocks(T):
        Pb, _ = _fk_block(comp, dofs[sl], angle_rad)
        P[sl] = np.transpose(Pb, (2, 1, 0))
    P *= f
    return P


def _fk_block(comp: _Compiled, dofs: np.ndarray, angle_rad: bool,
              axes: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """FK of one block: positions (3, J, T) in file units and, with ``axes``, the world
    axis (3, D, T) of every rotational dof (zero for translations) for the IK Jacobian.

    Per tree level ``X = L_parent · C = F_parent · K`` (``F = L · C`` of the parent,
    ``K = C_parent^T C`` fixed) is formed for all its bones at once, then right-multiplied
    by the elementary rotations of their dofs, last letter of the ``axis`` order first
    (``M = R_last ... R_first``), which gives ``F = L · C``; just before the rotation of a
    dof is applied, column ``a`` of ``X`` is that dof's world axis (``L_p C R_last ...
    e_a``); ``end = end_parent + L · vec = end_parent + F · (C^T vec)``. (One 3x3 product
    per bone instead of forming ``L = X · C^T`` as well.)
    """
    T = dofs.shape[0]
    A = np.ascontiguousarray(dofs.T)
    ang = A if angle_rad else np.deg2rad(A)
    F = np.empty((3, 3, len(comp.names), T))
    P = np.empty((3, len(comp.names), T))
    W = np.zeros((3, comp.n_dofs, T)) if axes else None
    for idx, par, groups in comp.fk_levels:
        if par is None:                                              # the root
            X = np.repeat(comp.fk_C[:, :, :1, None], T, axis=3)
        else:
            X = rot.mm_t(F[:, :, par], comp.fk_K[:, :, idx, None])
        _rotate_level(X, groups, ang, W)
        F[:, :, idx] = X
        if par is None:
            P[:, 0] = 0.0
            for col, a in comp.fk_trans:
                P[a, 0] = dofs[:, col]
        else:
            v = comp.fk_U[:, idx, None]
            P[:, idx] = P[:, par] + X[:, 0] * v[0] + X[:, 1] * v[1] + X[:, 2] * v[2]
    return P, W


def _rotate_level(X: np.ndarray, groups: list, ang: np.ndarray, W: np.ndarray | None) -> None:
    """Right-multiply the (3, 3, bones, T) stack X of one tree level by its bones' dof
    rotations in place (``comp.fk_levels`` groups; ang (D, T) radians), recording each
    dof's world axis in W (3, D, T) first when given."""
    for a, k, cols in groups:
        Xk = X if k is None else X[:, :, k]
        if W is not None:
            W[:, cols] = Xk[:, a]
        rot.rotate_right_t(Xk, a, ang[cols])
        if k is not None:
            X[:, :, k] = Xk


def _local_rotations(comp: _Compiled, dofs: np.ndarray, angle_rad: bool) -> np.ndarray:
    """Local rotation ``C · M(dofs) · C^T`` of every node (T, J, 3, 3) (the root's: C_root
    M C_root^T), all nodes at once (the same products per node as level by level)."""
    A = np.ascontiguousarray(np.asarray(dofs, float).T)
    ang = A if angle_rad else np.deg2rad(A)
    T = A.shape[1]
    X = np.repeat(comp.fk_C[:, :, :, None], T, axis=3)
    _rotate_level(X, comp.local_groups, ang, None)
    return np.ascontiguousarray(np.transpose(rot.mm_t(X, comp.fk_CT[:, :, :, None]), (3, 2, 0, 1)))


# ======================================================================================
# inverse kinematics: helpers (the rotation maths is shared: mocapkit.io._rotations)
# ======================================================================================
def _euler_from(M: np.ndarray, order: str) -> list[np.ndarray]:
    """Both Euler solutions, as (x, y, z) angles in radians, of M = R(angles) for ``order``
    (Acclaim order: first letter applied first, i.e. the axis sequence reversed); M (T, 3,
    3), read through a (3, 3, T) view (the component formulas, no 3x3 stacks)."""
    axes = ["XYZ".index(c) for c in reversed(order)]
    out = []
    for e in rot.euler_from_matrix_t(np.moveaxis(M, 0, 2), axes):
        xyz = np.zeros_like(e)
        xyz[:, axes] = e
        out.append(xyz)
    return out


def _angles_near(cands: list[np.ndarray], ref: np.ndarray) -> np.ndarray:
    """Of the candidate (T, 3) angle sets, each wrapped by 2π turns nearest ``ref``, the closest."""
    best, best_d = None, None
    for c in cands:
        w = rot.wrap_near(c, ref)
        d = np.sum((w - ref) ** 2, axis=1)
        if best is None:
            best, best_d = w, d
        else:
            take = d < best_d
            best = np.where(take[:, None], w, best)
            best_d = np.minimum(d, best_d)
    return best


def _fit_partial(order: str, axes: list[int], U: np.ndarray, W: np.ndarray, ang: np.ndarray,
                 ang0: np.ndarray, iters: int = 40, scan: int = 36) -> np.ndarray:
    """Angles of the present ``axes`` minimising Σ_i |M(ang) u_i - w_i|² (other angles zero).

    U (n, 3) or (T, n, 3) rest vectors and W (T, n, 3) targets, both in the bone's local
    (C) frame (scale a pair by sqrt(weight) to weight it). One dof: the exact single-axis
    optimum (:func:`~mocapkit.io._rotations.twist_angle`). Two dofs
    (``M = R_q(β) R_p(α)``, p applied first): for every α the best β is exact, so the
    cost is scanned over ``scan`` values of α, then refined by ``iters`` golden-section
    steps within one scan step of the best value (global to the scan resolution, then
    precise to ~1e-8 rad); the same refinement runs around the start ``ang`` and wins
    when it fits as well, so equally good solutions do not flip branches between frames.
    Angles are returned on the 2π turn nearest ``ang0``.
    """
    present = [("XYZ".index(c)) for c in order if "XYZ".index(c) in axes]
    T = ang.shape[0]
    e = np.eye(3)
    out = np.zeros_like(ang)
    U = np.broadcast_to(U, W.shape)
    if len(present) == 1:
        a = present[0]
        th = rot.twist_angle(np.broadcast_to(e[a], (T, 3)), U, W)
        out[:, a] = rot.wrap_near(th, ang0[:, a])
        return out
    p, q = present
    # scan α (axis p) with the best β (axis q) in closed form for each, then a golden-section
    # search on α around the best scan point
    def best_beta(alpha):                                  # alpha (..., T) -> beta, cost
        sh = alpha.shape
        Ua = np.einsum("...tij,tnj->...tni", axis_rotation(p, alpha), U)          # (..., T, n, 3)
        Wb = np.broadcast_to(W, sh + W.shape[1:])
        m = int(np.prod(sh))
        beta = rot.twist_angle(np.broadcast_to(e[q], (m, 3)), Ua.reshape(m, -1, 3),
                               Wb.reshape(m, -1, 3)).reshape(sh)
        fit = np.einsum("...ij,...nj->...ni", axis_rotation(q, beta), Ua)
        return beta, np.sum((fit - Wb) ** 2, axis=(-2, -1))

    step = 2 * np.pi / scan
    alphas = np.linspace(-np.pi, np.pi, scan, endpoint=False)[:, None] + np.zeros((1, T))
    _, cost = best_beta(alphas)
    center = np.stack([alphas[np.argmin(cost, axis=0), np.arange(T)], ang[:, p]])   # (2, T)
    lo, hi = center - step, center + step
    g = (np.sqrt(5) - 1) / 2
    x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
    f1, f2 = best_beta(x1)[1], best_beta(x2)[1]
    for _ in range(iters):
        left = f1 < f2                       # minimum in [lo, x2]
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
        nx1 = np.where(left, hi - g * (hi - lo), x2)
        nx2 = np.where(left, x1, lo + g * (hi - lo))
        fn = best_beta(np.where(left, nx1, nx2))[1]
        f1, f2 = np.where(left, fn, f2), np.where(left, f1, fn)
        x1, x2 = nx1, nx2
    al = 0.5 * (lo + hi)                                   # (2, T): scan branch, start branch
    be, c = best_beta(al)
    # prefer the branch of the start angles when it fits as well (no flips between frames)
    k = np.where(c[1] <= c[0] + 1e-9 * (1.0 + c[0]), 1, 0)
    cur = np.zeros((T, 3))
    cur[:, p] = al[k, np.arange(T)]
    cur[:, q] = be[k, np.arange(T)]
    out[:, p] = rot.wrap_near(cur[:, p], ang0[:, p])
    out[:, q] = rot.wrap_near(cur[:, q], ang0[:, q])
    return out


def _start_angles(S: np.ndarray, comp: _Compiled, n: str, to_rad) -> np.ndarray:
    ang = np.zeros((S.shape[0], 3))
    if n == "root":
        for k, ch in enumerate(comp.root_order):
            if ch[0] == "R":
                ang[:, "XYZ".index(ch[1])] = to_rad(S[:, k])
    elif comp.dof_axes[n]:
        ang[:, comp.dof_axes[n]] = to_rad(S[:, comp.dof_cols[n]])
    return ang


def _mv(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R v for R (T, 3, 3) and v (3,) or (T, 3) -> (T, 3); a fixed v as one (3T, 3) x (3,)
    product (a stacked matmul costs ~30 ns per 3x3 matrix, several times more)."""
    if v.ndim == 1:
        return (R.reshape(-1, 3) @ v).reshape(R.shape[:-1])
    return (R @ v[..., None])[..., 0]


def _conj_t(C: np.ndarray, R: np.ndarray) -> np.ndarray:
    """``C^T R C`` (T, 3, 3) (a strided view) for a fixed C (3, 3) and R (T, 3, 3): two
    plain (3T, 3) x (3, 3) products instead of stacked 3x3 matmuls."""
    T = R.shape[0]
    RC = (R.reshape(-1, 3) @ C).reshape(T, 3, 3)                    # [t, i, k] = (R C)[i, k]
    Y = C.T @ np.transpose(RC, (1, 0, 2)).reshape(3, -1)            # [i, (t, k)] = (C^T R C)[i, k]
    return np.transpose(Y.reshape(3, T, 3), (1, 0, 2))


def _compose_local(Lp: np.ndarray, C: np.ndarray, order: str, axes: list[int], ang: np.ndarray) -> np.ndarray:
    """``Lp C E(ang) C^T`` (T, 3, 3) for a bone whose only nonzero Euler angles (T, 3)
    (x, y, z radians) are on ``axes``: ``Lp C`` in the (3, 3, T) layout right-multiplied
    by the elementary rotations of the present axes only (a zero angle is an exact no-op),
    last letter of ``order`` first as in ``E = R_last ... R_first``."""
    T = Lp.shape[0]
    X = np.ascontiguousarray(np.transpose((Lp.reshape(-1, 3) @ C).reshape(T, 3, 3), (1, 2, 0)))
    for a in ("XYZ".index(ch) for ch in reversed(order)):
        if a in axes:
            rot.rotate_right_t(X, a, ang[:, a])
    X = np.ascontiguousarray(np.transpose(X, (2, 0, 1)))
    return (X.reshape(-1, 3) @ C.T).reshape(T, 3, 3)


def _local(Lp: np.ndarray, C: np.ndarray, v: np.ndarray) -> np.ndarray:
    """C^T Lp^T v for v (T, 3): a world vector in a bone's C frame."""
    return (v[:, None, :] @ Lp)[:, 0] @ C


class _IKState:
    """Targets, start dofs, results and the achieved pose of a top-down IK pass."""

    def __init__(self, comp: _Compiled, target_cm: np.ndarray, f: float, angle_rad: bool,
                 start: np.ndarray | None):
        self.comp = comp
        self.X = np.asarray(target_cm, float) / f                     # file units
        self.T = self.X.shape[0]
        self.have_start = start is not None
        self.S = np.zeros((self.T, comp.n_dofs)) if start is None else np.array(start, float)
        self.out = self.S.copy()
        self.angle_rad = angle_rad
        self.to_rad = (lambda a: a) if angle_rad else np.deg2rad
        self.from_rad = (lambda a: a) if angle_rad else np.rad2deg
        self.done = np.zeros((self.T, len(comp.names), 3))            # achieved (FK) end points
        self.L: dict[str, np.ndarray] = {}
        self.ok = np.isfinite(self.X).all(axis=2)                      # (T, J) usable targets
        self._start_locals: np.ndarray | None = None

    def tgt(self, k: int, base: np.ndarray, fallback: np.ndarray) -> np.ndarray:
        """Target vector of joint k from ``base``; ``fallback`` where the target is missing."""
        return np.where(self.ok[:, k, None], self.X[:, k] - base, fallback)

    def start_local(self, n: str) -> np.ndarray:
        """Local rotation C E(start) C^T of node n (T, 3, 3)."""
        if self._start_locals is None:                 # all nodes at once, on first use
            self._start_locals = _local_rotations(self.comp, self.S, self.angle_rad)
        return self._start_locals[:, self.comp.joint_index[n]]

    def rigid_vectors(self, node: str, Ln: np.ndarray, end: np.ndarray):
        """Predicted/target vectors of the dof-less bones moving rigidly with ``node``."""
        c = self.comp
        U, W, pos = [], [], {node: end}
        for d in c.dofless_desc[node]:
            u = _mv(Ln, c.vec[d])
            base = pos[c.parent[d]]
            U.append(u)
            W.append(self.tgt(c.joint_index[d], base, u))
            pos[d] = base + u
        return U, W


def _fit_vectors(U: list, W: list, T: int) -> np.ndarray:
    """Kabsch for two or more vector pairs, the shortest arc for one, identity for none."""
    if len(U) >= 2:
        return rot.kabsch(np.stack(U, 1), np.stack(W, 1))[0]
    if len(U) == 1:
        return rot.min_rotation(U[0], W[0])
    return np.broadcast_to(np.eye(3), (T, 3, 3))


def _ik_root(st: _IKState) -> None:
    """Root translation from its target; rotation from the rigid bones on it (+ the first
    dof bones, predicted with their start rotations, when fewer than two)."""
    c, T = st.comp, st.T
    for k, ch in enumerate(c.root_order):
        if ch[0] == "T":
            v = st.X[:, 0, "XYZ".index(ch[1])]
            st.out[:, k] = np.where(np.isfinite(v), v, st.S[:, k])
    tr, _ = c.root_split(st.out, st.angle_rad)
    st.done[:, 0] = tr
    Cr = c.C_root
    ang0 = _start_angles(st.S, c, "root", st.to_rad)
    L0 = st.start_local("root")
    U, W = st.rigid_vectors("root", L0, tr)
    if len(U) < 2:
        for ch_, path in c.dof_children["root"]:
            base = tr + sum((_mv(L0, c.vec[d]) for d in path), np.zeros(3))
            u = _mv(L0 @ st.start_local(ch_), c.vec[ch_])
            U.append(u)
            W.append(st.tgt(c.joint_index[ch_], base, u))
    Q = _fit_vectors(U, W, T)
    rot_cols = [k for k, ch in enumerate(c.root_order) if ch[0] == "R"]
    if rot_cols:
        ang = _angles_near(_euler_from(_conj_t(Cr, Q @ L0), c.root_axis), ang0)
        if not st.have_start:
            ang = np.unwrap(ang, axis=0)
        for k in rot_cols:
            st.out[:, k] = st.from_rad(ang[:, "XYZ".index(c.root_order[k][1])])
    st.L["root"] = Cr @ _euler_matrix(c.root_axis, _start_angles(st.out, c, "root", st.to_rad)) @ Cr.T


def _ik_bone(st: _IKState, j: int, n: str) -> None:
    """One bone, given its parent's achieved rotation and end point (steps 1-3 of the
    module docstring)."""
    c = st.comp
    Lp, pj, axes = st.L[c.parent[n]], c.parent_joint[j], c.dof_axes[n]
    if not axes:
        st.L[n] = Lp
        st.done[:, j] = st.done[:, pj] + _mv(Lp, c.vec[n])
        return
    C, order, cols = c.C[n], c.order[n], c.dof_cols[n]
    ang0 = _start_angles(st.S, c, n, st.to_rad)
    Ls = Lp @ st.start_local(n)
    u = _mv(Ls, c.vec[n])
    w = st.tgt(j, st.done[:, pj], u)
    Ur, Wr = st.rigid_vectors(n, Ls, st.done[:, pj] + u)
    Lb = _fit_vectors([u] + Ur, [w] + Wr, st.T) @ Ls
    if len(axes) == 3 and c.dof_children[n]:
        Lb = _twist_from_children(st, n, j, Lb)
    ang = _angles_near(_euler_from(_conj_t(C, np.swapaxes(Lp, 1, 2) @ Lb), order), ang0)
    if len(axes) < 3:
        ang = _partial_angles(st, n, Lp, w, Wr, ang, ang0)
    for i, a in enumerate(axes):
        st.out[:, cols[i]] = st.from_rad(ang[:, a])
    if not st.have_start:
        st.out[:, cols] = st.from_rad(np.unwrap(st.to_rad(st.out[:, cols]), axis=0))
    # three dofs represent Lb exactly (the Euler angles reproduce M to round-off); fewer
    # give the closest representable rotation, which the children must start from
    st.L[n] = Lb if len(axes) == 3 else _compose_local(Lp, C, order, axes, _start_angles(st.out, c, n, st.to_rad))
    st.done[:, j] = st.done[:, pj] + _mv(st.L[n], c.vec[n])


def _twist_from_children(st: _IKState, n: str, j: int, Lb: np.ndarray) -> np.ndarray:
    """The free twist of a 3-dof bone about its own axis, from its dof children predicted
    with their start rotations (least squares, regularised); a hinge child (one dof)
    fixes it in closed form instead where it can (:func:`_hinge_twist`)."""
    c = st.comp
    ax, ln = rot.normalize(_mv(Lb, c.vec[n]))
    end_b = st.done[:, c.parent_joint[j]] + _mv(Lb, c.vec[n])
    Uc, Wc = [], []
    for ch_, path in c.dof_children[n]:
        base = end_b + sum((_mv(Lb, c.vec[d]) for d in path), np.zeros(3))
        uc = _mv(Lb @ st.start_local(ch_), c.vec[ch_])
        Uc.append(uc)
        Wc.append(st.tgt(c.joint_index[ch_], base, uc))
    tw = rot.twist_angle(ax, np.stack(Uc, 1), np.stack(Wc, 1), reg=c.twist_reg[n])
    tw = _hinge_twist(st, n, Lb, ax, end_b, tw)
    return rot.axis_angle(ax, np.where(ln > 1e-12, tw, 0.0)) @ Lb


def _hinge_twist(st: _IKState, n: str, Lb, ax, end_b, tw) -> np.ndarray:
    """Twist angles that put the target of a direct one-dof child (knee, elbow) on the
    cone its hinge allows: ``h(theta) . w = cos(gamma)``, solved as
    ``A + B cos(theta) + C sin(theta) = cos(gamma)``; of the two roots the one whose
    hinge angle lies inside the dof limits, then the one nearer ``tw`` (the estimate from
    the start rotations; 0 without start dofs). Frames where the child is (nearly) in line
    with the bone keep ``tw``."""
    c = st.comp
    hinges = [ch_ for ch_, path in c.dof_children[n] if not path and len(c.dof_axes[ch_]) == 1]
    if not hinges:
        return tw
    ch_ = hinges[0]
    e_h = np.eye(3)[c.dof_axes[ch_][0]]
    uc = c.C[ch_].T @ c.vec[ch_]
    cos_g = float(e_h @ uc) / max(float(np.linalg.norm(uc)), 1e-300)
    wh, wn = rot.normalize(st.X[:, c.joint_index[ch_]] - end_b)
    h0 = _mv(Lb, c.C[ch_] @ e_h)
    hpar = np.sum(h0 * ax, axis=1)
    hperp = h0 - hpar[:, None] * ax
    A = hpar * np.sum(ax * wh, axis=1)
    B = np.sum(hperp * wh, axis=1)
    Cc = np.sum(np.cross(ax, hperp) * wh, axis=1)
    rho = np.hypot(B, Cc)
    d = np.arccos(np.clip((cos_g - A) / np.maximum(rho, 1e-300), -1.0, 1.0))
    phi0 = np.arctan2(Cc, B)
    ref = tw if st.have_start else np.zeros_like(tw)
    cands = [rot.wrap_near(phi0 + d, ref), rot.wrap_near(phi0 - d, ref)]
    score = [np.abs(t - ref) + 10.0 * ~_hinge_in_limits(st, ch_, Lb, ax, t, wh) for t in cands]
    best = np.where(score[0] <= score[1], cands[0], cands[1])
    usable = (rho > 0.1) & np.isfinite(best) & (wn > 1e-12)
    return np.where(usable, best, tw)


def _hinge_in_limits(st: _IKState, ch_: str, Lb, ax, theta, wh) -> np.ndarray:
    """Whether the hinge angle child ``ch_`` needs after a twist ``theta`` is inside its
    ASF limits (True where no limits are given)."""
    c = st.comp
    lim = next((b.get("limits") for b in c.asf["bones"] if b["name"] == ch_), None)
    if not lim:
        return np.ones(len(theta), bool)
    a = c.dof_axes[ch_][0]
    L2 = rot.axis_angle(ax, theta) @ Lb
    t_loc = _local(L2, c.C[ch_], wh)
    u = c.C[ch_].T @ c.vec[ch_]
    p, q = (a + 1) % 3, (a + 2) % 3
    phi = np.arctan2(t_loc[:, q], t_loc[:, p]) - np.arctan2(u[q], u[p])
    deg = st.from_rad(rot.wrap_near(phi, 0.0))
    lo, hi = lim[0]
    return (deg >= lo - 1e-9) & (deg <= hi + 1e-9)


def _partial_angles(st: _IKState, n: str, Lp, w, Wr, ang, ang0) -> np.ndarray:
    """Closest representable rotation of a bone with 1 or 2 dofs (step 3): the bone
    vector, its rigid descendants and (for a bone along one of its dof axes) its
    children predicted with their start rotations at weight ``_CHILD_W**2``."""
    c = st.comp
    C, axes = c.C[n], c.dof_axes[n]
    keep = np.zeros(3, bool)
    keep[axes] = True
    ang = np.where(keep, ang, 0.0)
    Ul = [np.broadcast_to(C.T @ c.vec[n], (st.T, 3)), ]
    Wl = [_local(Lp, C, w)]
    for d, wd in zip(c.dofless_desc[n], Wr):
        Ul.append(np.broadcast_to(C.T @ c.vec[d], (st.T, 3)))
        Wl.append(_local(Lp, C, wd))
    for ch_, path in (c.dof_children[n] if c.axis_aligned[n] else []):
        uc = _mv(st.start_local(ch_), c.vec[ch_]) @ C
        wc = st.X[:, c.joint_index[ch_]] - st.X[:, c.joint_index[c.parent[ch_]]]
        wc = np.where(np.isfinite(wc).all(axis=1)[:, None], _local(Lp, C, np.nan_to_num(wc)), uc)
        Ul.append(_CHILD_W * uc)
        Wl.append(_CHILD_W * wc)
    return _fit_partial_fast(c.order[n], axes, np.stack(Ul, 1), np.stack(Wl, 1), ang, ang0)


def _fit_partial_fast(order: str, axes: list[int], U: np.ndarray, W: np.ndarray, ang: np.ndarray,
                      ang0: np.ndarray, iters: int = 4) -> np.ndarray:
    """Angles of the present ``axes`` minimising sum_i |M(ang) u_i - w_i|^2 (other angles 0),
    in closed form: U, W (T, n, 3) in the bone's C frame, the first pair the bone's own.

    One dof: the exact single-axis optimum. Two dofs (``M = R_q(b) R_p(a)``, p applied
    first): the two exact solutions for the own vector (:func:`_two_dof_candidates`) and
    the start branch ``ang``; with more vectors than the own one, the better exact
    solution and the start branch are polished by ``iters`` damped Gauss-Newton steps on
    the whole cost (2x2 normal equations per frame). The lowest cost wins; on a tie
    (1e-9 relative) the angles nearest the start branch. Angles are returned on the 2 pi turn nearest ``ang0``. (The dense-scan
    reference is :func:`_fit_partial`.)
    """
    present = [("XYZ".index(c)) for c in order if "XYZ".index(c) in axes]
    T = ang.shape[0]
    out = np.zeros_like(ang)
    if len(present) == 1:
        a = present[0]
        th = rot.twist_angle(np.broadcast_to(np.eye(3)[a], (T, 3)), U, W)
        out[:, a] = rot.wrap_near(th, ang0[:, a])
        return out
    p, q = present
    cands = _two_dof_candidates(p, q, U[:, 0], W[:, 0]) + [np.stack([ang[:, p], ang[:, q]], axis=1)]
    costs = [_two_dof_cost(p, q, U, W, x) for x in cands]
    if U.shape[1] > 1:                   # more than the own vector: polish the best exact
        k = np.where(costs[0] <= costs[1], 0, 1)   # solution and the start branch
        x0 = np.where(k[:, None] == 0, cands[0], cands[1])
        cands = [_gauss_newton_two(p, q, U, W, x, iters) for x in (x0, cands[2])]
        cands, costs = [c[0] for c in cands], [c[1] for c in cands]
    best, best_c = cands[0], costs[0]
    for x, cost in zip(cands[1:], costs[1:]):
        dist = lambda y: np.sum(np.abs(rot.wrap_near(y - cands[-1], 0.0)), axis=1)
        tie = np.abs(cost - best_c) <= 1e-9 * (1.0 + best_c)
        take = (cost < best_c) & ~tie | tie & (dist(x) < dist(best))
        best = np.where(take[:, None], x, best)
        best_c = np.where(take, cost, best_c)
    out[:, p] = rot.wrap_near(best[:, 0], ang0[:, p])
    out[:, q] = rot.wrap_near(best[:, 1], ang0[:, q])
    return out


def _rotate_vectors(a: int, ang: np.ndarray, V: np.ndarray) -> np.ndarray:
    """``R_a(ang) v`` for every vector of V (T, n, 3), ang (T,) radians: only the two
    components off the axis change (no 3x3 matrices)."""
    c, s = np.cos(ang)[:, None], np.sin(ang)[:, None]
    i, j = (a + 1) % 3, (a + 2) % 3
    out = V.copy()
    out[..., i] = c * V[..., i] - s * V[..., j]
    out[..., j] = s * V[..., i] + c * V[..., j]
    return out


def _two_dof_cost(p: int, q: int, U: np.ndarray, W: np.ndarray, x: np.ndarray) -> np.ndarray:
    """sum_i |R_q(b) R_p(a) u_i - w_i|^2 (T,) for x = (a, b) (T, 2)."""
    r = _rotate_vectors(q, x[:, 1], _rotate_vectors(p, x[:, 0], U)) - W
    r *= r
    return r.reshape(len(r), -1).sum(axis=1)


def _plane_angle(a: int, x: np.ndarray) -> np.ndarray:
    """Angle of x (T, 3) about axis a (measured from axis a+1 towards a+2)."""
    return np.arctan2(x[:, (a + 2) % 3], x[:, (a + 1) % 3])


def _two_dof_candidates(p: int, q: int, u: np.ndarray, w: np.ndarray) -> list[np.ndarray]:
    """Both (a, b) (T, 2) with ``R_q(b) R_p(a) u`` along w: ``v = R_p(a) u`` keeps u's p
    component and must share w's q component (w scaled to |u|), which fixes v up to the
    sign of its third component; a and b are then plane angles."""
    nu = np.linalg.norm(u, axis=1)
    wn = w * (nu / np.maximum(np.linalg.norm(w, axis=1), 1e-300))[:, None]
    r = 3 - p - q
    s = np.sqrt(np.maximum(nu ** 2 - u[:, p] ** 2 - wn[:, q] ** 2, 0.0))
    out = []
    for sign in (1.0, -1.0):
        v = np.empty_like(u)
        v[:, p], v[:, q], v[:, r] = u[:, p], wn[:, q], sign * s
        out.append(np.stack([_plane_angle(p, v) - _plane_angle(p, u),
                             _plane_angle(q, wn) - _plane_angle(q, v)], axis=1))
    return out


def _cross_axis(a: int, Y: np.ndarray) -> np.ndarray:
    """e_a x y for every vector of Y (..., 3)."""
    out = np.zeros_like(Y)
    i, j = (a + 1) % 3, (a + 2) % 3
    out[..., i] = -Y[..., j]
    out[..., j] = Y[..., i]
    return out


def _gauss_newton_two(p: int, q: int, U: np.ndarray, W: np.ndarray, x: np.ndarray, iters: int):
    """Damped Gauss-Newton on (a, b) for sum_i |R_q(b) R_p(a) u_i - w_i|^2; returns (x, cost)."""
    def pose(x):
        Y = U @ np.swapaxes(axis_rotation(p, x[:, 0]), 1, 2)
        Rq_t = np.swapaxes(axis_rotation(q, x[:, 1]), 1, 2)
        Z = Y @ Rq_t
        return Y, Z, Rq_t, np.sum((Z - W) ** 2, axis=(1, 2))

    x = np.array(x, float)
    Y, Z, Rq_t, cost = pose(x)
    lam = np.full(len(x), 1e-6)
    for _ in range(iters):
        r = Z - W
        dA = _cross_axis(p, Y) @ Rq_t
        dB = _cross_axis(q, Z)
        a11, a12, a22 = (np.sum(dA * dA, axis=(1, 2)), np.sum(dA * dB, axis=(1, 2)),
                         np.sum(dB * dB, axis=(1, 2)))
        g1, g2 = np.sum(dA * r, axis=(1, 2)), np.sum(dB * r, axis=(1, 2))
        a11, a22 = a11 * (1 + lam) + 1e-12, a22 * (1 + lam) + 1e-12
        det = a11 * a22 - a12 * a12
        step = np.stack([-(a22 * g1 - a12 * g2) / det, -(a11 * g2 - a12 * g1) / det], axis=1)
        xn = x + step
        Yn, Zn, Rn, cn = pose(xn)
        ok = cn < cost
        x = np.where(ok[:, None], xn, x)
        Y, Z, Rq_t = (np.where(ok[:, None, None], Yn, Y), np.where(ok[:, None, None], Zn, Z),
                      np.where(ok[:, None, None], Rn, Rq_t))
        cost = np.where(ok, cn, cost)
        lam = np.where(ok, lam * 0.1, lam * 10.0)
    return x, cost


def _ik_pass(comp: _Compiled, target_cm: np.ndarray, f: float, angle_rad: bool,
             start: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """One top-down pass (steps 1-3): dofs (T, D) and each frame's worst joint error (cm)."""
    st = _IKState(comp, target_cm, f, angle_rad, start)
    _ik_root(st)
    for j, n in enumerate(comp.bone_order, start=1):
        _ik_bone(st, j, n)
    err = np.where(st.ok, np.linalg.norm(st.done - np.nan_to_num(st.X), axis=2), 0.0) * f
    return st.out, err.max(axis=1)


def bone_mismatch(X: np.ndarray, bones: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """(T, B) difference between each target bone's length in X (T, J, 3) and the
    hierarchy's ``lengths`` (B,), bones (B, 2) (child, parent); 0 where an end is missing.
    What no pose can remove, so the writers' least-squares polish (AMC here, BVH in
    :mod:`mocapkit.io._bvh_polish`) does not chase it."""
    from ..rigid import bone_lengths

    d = np.abs(bone_lengths(X, bones) - lengths)
    return np.where(np.isfinite(d), d, 0.0)


def polish_gate(mismatch: np.ndarray, above: float, cap: float, factor: float = 3.0) -> np.ndarray:
    """(T,) how far off (file units or cm) the closed-form IK may leave a frame's worst joint
    before the polish refines it: ``min(above + factor * m, cap)``, m the frame's largest
    bone-length ``mismatch`` (T, B) (:func:`bone_mismatch`)."""
    m = mismatch.max(axis=1) if mismatch.shape[1] else np.zeros(mismatch.shape[0])
    return np.minimum(above + factor * m, cap)


def require_complete(motion, fmt: str) -> None:
    """Raise MocapValueError when ``motion`` has missing samples: a skeleton format (BVH,
    AMC) stores joint angles, so it has no way to mark a missing one, and an inverse
    kinematics that skips a missing joint target leaves its bone at the start rotation and
    drags every joint below it (measured: 10 % missing at 30 fps put observed joints up to
    62 cm off)."""
    if not motion.observed.all():
        n_miss = int((~motion.observed).sum())
        raise MocapValueError(
            f"cannot write {fmt}: the motion has {n_miss} missing joint entries "
            f"({100 * motion.missing_fraction:.1f}%); {fmt} has no way to mark them - fill the gaps "
            f"first (e.g. mocapkit.denoise.get('spline').denoise(motion)) or write C3D / TRC, "
            f"which keep them missing")


def inverse_kinematics(comp: _Compiled, target_cm: np.ndarray, f: float, angle_rad: bool,
                       start: np.ndarray | None = None, *, refine: int = 12,
                       refine_above_cm: float = 0.001, refine_cap_cm: float = 0.5,
                       mismatch_factor: float = 3.0) -> np.ndarray:
    """Dof values (T, D) (file units and angle unit) whose FK follows ``target_cm`` (T, J, 3).

    Stage 1: per-bone IK in closed form, top-down, vectorised over frames (module
    docstring, steps 1-3). Stage 2 (``refine`` > 0): up to
    ``refine`` Levenberg-Marquardt iterations on all dofs of a frame at once (analytic
    Jacobian), only on the frames stage 1 leaves more than
    ``min(refine_above_cm + mismatch_factor * m, refine_cap_cm)`` off, ``m`` the frame's
    largest ``| |x_j - x_parent| - length_j |`` (the part of the error no pose can
    remove is not chased); it only accepts steps that lower the frame's squared position
    error. ``start`` (T, D): dofs to start from; default rest pose, with the recovered
    angles unwrapped over time. Missing (NaN) targets are ignored (their bones keep the
    start rotation).
    """
    X = np.asarray(target_cm, float)
    out, err = _ik_pass(comp, X, f, angle_rad, start)
    bones = np.column_stack([np.arange(1, X.shape[1]), comp.parent_joint[1:]])
    lengths = np.array([np.linalg.norm(comp.vec[n]) for n in comp.bone_order]) * f
    gate = polish_gate(bone_mismatch(X, bones, lengths), refine_above_cm, refine_cap_cm, mismatch_factor)
    idx = np.flatnonzero(err > gate) if refine else []
    if len(idx):
        out[idx] = _ik_refine(comp, X[idx] / f, out[idx], angle_rad, int(refine))
    return out


def _cross_planes(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> np.ndarray:
    """a x b for component planes (3, ...) into ``out`` (3, ...) (not aliasing a or b)."""
    np.multiply(a[1], b[2], out=out[0])
    out[0] -= a[2] * b[1]
    np.multiply(a[2], b[0], out=out[1])
    out[1] -= a[0] * b[2]
    np.multiply(a[0], b[1], out=out[2])
    out[2] -= a[1] * b[0]
    return out


def _ik_normal_equations(comp: _Compiled, P: np.ndarray, W: np.ndarray, usable: np.ndarray,
                         r: np.ndarray, angle_rad: bool,
                         work: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``Jt Jt^T`` (T, D, D) and ``Jt r`` (T, D) of the LM polish without forming ``Jt``
    (the tests' dense Jacobian gives the same values to round-off).

    P (T, J, 3) joint positions, W (T, D, 3) world dof axes (from :func:`_fk_block`),
    usable (T, J) target mask, r (T, J, 3) residuals (file units); ``comp.trans_cols``, where
    a caller has it (the BVH polish), lists translation columns whose unit direction W holds
    (``xi = (0, W_d)``). A rotational dof d
    with unit axis w about pivot c moves joint j by ``w x (p_j - c) = m + w x p_j`` with
    the moment ``m = c x w`` (Plücker coordinates ``xi = (w, m)``; a root translation
    along e_a is ``xi = (0, e_a)``; both scaled by pi/180 for degree files), for the
    joints j of its node's subtree S only. So

        (Jt Jt^T)[d, e] = xi_d . Lam_S xi_e,   S the smaller of the two nested subtrees,
        Lam_S xi = (tr(M) w - M w + s x m,  n m - s x w)

    with the subtree sums ``n = sum u_j``, ``s = sum u_j p_j``, ``M = sum u_j p_j p_j^T``
    (u the usable mask), and 0 for columns whose subtrees are disjoint (a tree: subtrees
    are nested or disjoint); likewise ``(Jt r)[d] = m . sum r_j + w . sum p_j x r_j``.
    The subtree sums of all columns come from one product with ``comp.dof_subtree``: per
    frame O(J) sums and a (D, 6) x (6, D) product instead of the (D, 3J) x (3J, D) one.
    Positions are taken relative to the root joint (smaller moments, less cancellation).
    ``work``: two (>= T, D, D) buffers; the first holds the returned matrices (fresh
    multi-MB temporaries cost more in page faults than the arithmetic).
    """
    T, J = usable.shape
    D = comp.n_dofs
    u = usable.astype(float)
    # component planes (xyz first, frames, joints or columns last): contiguous (T, J) / (T, D)
    # arrays instead of (..., 3) stacks, which numpy handles slowly
    p = np.moveaxis(P - P[:, :1], 2, 0)                            # (3, T, J)
    q = np.empty((19, T, J))                    # per joint: u, u p, u p p^T, u r, p x u r
    q[0] = u
    np.multiply(p, u, out=q[1:4])
    np.multiply(q[1:4, None], p[None], out=q[4:13].reshape(3, 3, T, J))
    np.multiply(np.moveaxis(r, 2, 0), u, out=q[13:16])
    _cross_planes(p, q[13:16], q[16:19])
    Q = (q.reshape(-1, J) @ comp.dof_subtree.T).reshape(19, T, D)   # sums over each column's subtree
    n, s, M = Q[0], Q[1:4], Q[4:13].reshape(3, 3, T, D)
    xi = np.empty((6, T, D))                    # Plücker coordinates (w, m) of every column
    w, m = xi[:3], xi[3:]
    np.multiply(np.moveaxis(W, 2, 0), 1.0 if angle_rad else np.pi / 180.0, out=w)
    _cross_planes(p[:, :, comp.dof_pivot], w, m)
    for col, a in comp.fk_trans:
        m[:, :, col] = 0.0
        m[a, :, col] = 1.0
    tc = getattr(comp, "trans_cols", None)       # translations along W's per-frame direction
    if tc is not None and len(tc):               # (BVH position channels: the parent's axes)
        m[:, :, tc] = np.moveaxis(W[:, tc], 2, 0)
        w[:, :, tc] = 0.0
    H = np.empty((6, T, D))                     # Lam_S xi, S the column's own subtree
    trM = M[0, 0] + M[1, 1] + M[2, 2]
    _cross_planes(s, m, H[:3])
    for a in range(3):
        H[a] += trM * w[a] - M[a, 0] * w[0] - M[a, 1] * w[1] - M[a, 2] * w[2]
    _cross_planes(s, w, H[3:])
    np.subtract(n * m, H[3:], out=H[3:])
    g = np.sum(m * Q[13:16] + w * Q[16:19], axis=0)
    # [d, e] = xi_d . H_e is the entry when node(e) lies in node(d)'s subtree, xi_e . H_d
    # (a second small product: no strided transpose) when node(d) lies strictly in node(e)'s
    # subtree, 0 for disjoint subtrees
    A, GT = (np.empty((T, D, D)), np.empty((T, D, D))) if work is None else (work[0][:T], work[1][:T])
    xi_t, H_t = np.moveaxis(xi, 0, 2).copy(), np.moveaxis(H, 0, 2).copy()        # (T, D, 6)
    np.matmul(xi_t, np.swapaxes(H_t, 1, 2), out=A)
    np.matmul(H_t, np.swapaxes(xi_t, 1, 2), out=GT)
    A *= comp.nest_lo                           # 0/1 masks: arithmetic beats copyto(where=)
    GT *= comp.nest_hi
    A += GT
    return A, g


def _ik_refine(comp: _Compiled, X: np.ndarray, dofs: np.ndarray, angle_rad: bool, iters: int,
               chunk: int = 512, tol_cm: float = 1e-6, rel_tol: float = 1e-3) -> np.ndarray:
    """Levenberg-Marquardt polish of ``dofs`` towards targets X (file units), per frame.

    Each frame has its own damping; a step is kept only if it lowers that frame's sum of
    squared position errors; a frame leaves the active set once its error is below
    ``tol_cm`` or a step gains less than ``rel_tol`` of it. Per iteration: the normal
    equations of the live frames (:func:`_ik_normal_equations`, into two reused (T, D, D)
    buffers), damped on their diagonal in place (Marquardt: ``lam diag``), one batched ``np.linalg.solve``, the FK
    of the trial dofs (:func:`_fk_block`, which also gives the next axes).

    Damping measured and not kept (2026-12-03, CMU 131_02 / 16_15, 12 iterations): on 1 cm
    i.i.d. noisy targets the short finger / thumb bones (diagonal ~2e-6 of the largest)
    take steps of tens of degrees that get the whole frame's step rejected, and a
    Levenberg term ``lam mean(diag)`` added to Marquardt's lowers the max error 5.6 -> 4.1
    cm (RMS 1.123 -> 1.114); but it slows the realistic write-back of cleaned output 16 %
    (kalman-cv output 7,503 -> 6,293 frames/s), reachable poses 2x, and leaves clean
    positions without stored dofs 1.5-2.4x further off (mean 0.0075 -> 0.0117 cm).  Per-dof
    step clipping (5-20 deg), a whole-step trust radius, a relative floor on the diagonal
    (1e-3 - 1e-1 of its mean) and the Levenberg term only after a rejection each lost on
    at least one of these cases as well. A looser stop (``rel_tol`` 1e-2 instead of 1e-3;
    2026-12-04) was 2-23 % faster (kalman-cv output of 16_15 / 05_01 / 131_02: 8,230 /
    9,724 / 12,091 -> 8,620 / 9,899 / 13,727 frames/s) but raised the max error on 1 cm
    noisy targets 5.7 -> 8.3 cm (16_15) and 6.5 -> 9.3 (05_01): not kept.
    """
    dofs = dofs.copy()
    Wm = np.isfinite(X).all(axis=2)                                 # (T, J) usable targets
    Xf = np.where(Wm[..., None], X, 0.0)
    tol = (tol_cm / 5.0) ** 2
    nd = comp.n_dofs

    def cost_of(D, idx):
        Pb, Wb = _fk_block(comp, D, angle_rad, axes=True)
        P, Wa = np.transpose(Pb, (2, 1, 0)), np.transpose(Wb, (2, 1, 0))
        r = (P - Xf[idx]) * Wm[idx][..., None]
        return np.sum(r ** 2, axis=(1, 2)), r, P, Wa

    for s in range(0, X.shape[0], chunk):
        idx = np.arange(s, min(s + chunk, X.shape[0]))
        D = dofs[idx]
        cost, r, P, Wa = cost_of(D, idx)
        P, Wa = P.copy(), Wa.copy()                                  # updated in place below
        work = (np.empty((len(idx), nd, nd)), np.empty((len(idx), nd, nd)))    # reused
        dofs[idx] = lm_frames(comp, D, P, Wa, Wm[idx], r, cost, lambda Dt, k: cost_of(Dt, idx[k]),
                              iters=iters, angle_rad=angle_rad, rel_tol=rel_tol, tol=tol, work=work)
    return dofs


def lm_frames(comp, D: np.ndarray, P: np.ndarray, W: np.ndarray, usable: np.ndarray, r: np.ndarray,
              cost: np.ndarray, evaluate, *, iters: int, angle_rad: bool, rel_tol: float,
              tol: float = 0.0, work: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Levenberg-Marquardt on a block of frames, each with its own Marquardt damping: the
    AMC polish (:func:`_ik_refine`) and the BVH writer's (:mod:`mocapkit.io._bvh_polish`).

    D (F, dofs) the start; P (F, J, 3), W (F, dofs, 3), r (F, J, 3) and cost (F,) its FK,
    world axes, residuals and squared error (updated in place); usable (F, J) the target
    mask; ``evaluate(D_trial, k)`` -> (cost, r, P, W) of trial dofs for the block's frames
    ``k``. A step is kept only if it lowers the frame's cost; a frame stops once its cost
    is under ``tol`` or a step gains less than ``rel_tol`` of it. Returns D (F, dofs).
    """
    lam = np.full(len(D), 1e-3)
    live = cost > tol
    for _ in range(iters):
        if not live.any():
            break
        k = np.flatnonzero(live)
        # the normal equations of every live frame (cheap without the Jacobian: also
        # rebuilt, identically, for frames whose last step was rejected), damped in place
        A, g = _ik_normal_equations(comp, P[k], W[k], usable[k], r[k], angle_rad, work)
        nd = A.shape[1]
        diag = A.reshape(len(k), -1)[:, ::nd + 1]                # a view of the diagonals
        diag += lam[k, None] * (diag + 1e-9)
        step = -np.linalg.solve(A, g[..., None])[..., 0]
        newc, newr, newP, newW = evaluate(D[k] + step, k)
        ok = newc < cost[k]
        gain = np.where(ok, (cost[k] - newc) / np.maximum(cost[k], 1e-300), 0.0)
        acc = k[ok]
        D[acc] += step[ok]
        cost[acc], r[acc], P[acc], W[acc] = newc[ok], newr[ok], newP[ok], newW[ok]
        lam[k] = np.where(ok, np.maximum(lam[k] / 5, 1e-9), lam[k] * 8)
        live[k] = np.where(ok, (newc > tol) & (gain > rel_tol), lam[k] < 1e6)
    return D
