"""Rotation helpers shared by the BVH and ASF/AMC kinematics (one place, issue #16).

Conventions: column vectors (``R @ v``), right-handed, angles in **radians**; stacks of
matrices are ``(T, 3, 3)`` unless a name ends in ``_t``, which uses the ``(3, 3, T)``
layout (nine length-T component arrays: about 3x faster than ``np.matmul`` on small
stacks). An *axis sequence* ``axes = (a1, a2, a3)`` (0 = X, 1 = Y, 2 = Z) means the
product ``R = R_a1(t1) @ R_a2(t2) @ R_a3(t3)``; BVH channel order is such a sequence,
an Acclaim ``axis`` / ``order`` string ``"XYZ"`` (first letter applied first) is the
reversed one (``R = R_z R_y R_x``).

Functions
---------
axis_rotation(axis, ang)          (..., 3, 3) rotation about one coordinate axis
rot_t(axis, ang), mm_t(A, B)      the same and a product in the (3, 3, T) layout
rotate_right_t(R, axis, ang)      R @ R_axis(ang) in place, (3, 3, T) layout
euler_to_matrix(axes, angles)     product of axis rotations; angles (..., n) per listed axis
rotate_left_t(R, axis, ang)       R_axis(ang) @ R in place, (3, 3, T) layout
euler_from_matrix_t(R, axes)      the three angles of R (3, 3, T) for three distinct axes (+ other branch)
min_rotation(a, b)                shortest-arc rotations taking directions a onto b
kabsch(A, B)                      least-squares rotations Q a_k ~ b_k (+ degenerate mask)
axis_angle(axis, theta)           Rodrigues rotations
twist_angle(axis, U, W, reg)      the angle about ``axis`` best rotating vectors U onto W
wrap_near(ang, ref, period)       ``ang`` moved by whole turns next to ``ref``
"""
from __future__ import annotations

import numpy as np

__all__ = ["axis_rotation", "rot_t", "mm_t", "euler_to_matrix", "min_rotation",
           "kabsch", "rotate_right_t", "rotate_left_t", "euler_from_matrix_t", "axis_angle", "twist_angle", "wrap_near", "normalize", "skew"]


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


def rot_t(axis: int, ang: np.ndarray) -> np.ndarray:
    """Rotation about axis 0/1/2 by ``ang`` (T,) radians in the (3, 3, T) layout."""
    c, s = np.cos(ang), np.sin(ang)
    R = np.zeros((3, 3) + np.shape(ang))
    i, j = (axis + 1) % 3, (axis + 2) % 3
    R[axis, axis] = 1.0
    R[i, i] = c
    R[j, j] = c
    R[i, j] = -s
    R[j, i] = s
    return R


def mm_t(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Product of stacks of 3x3 matrices in the (3, 3, T) layout (either may be a plain 3x3)."""
    shape = (3, 3) + np.broadcast_shapes(A.shape[2:], B.shape[2:])
    C = np.empty(shape)
    for i in range(3):
        for k in range(3):
            C[i, k] = A[i, 0] * B[0, k] + A[i, 1] * B[1, k] + A[i, 2] * B[2, k]
    return C


def rotate_right_t(R: np.ndarray, axis: int, ang: np.ndarray) -> np.ndarray:
    """``R @ R_axis(ang)`` for R (3, 3, T) in place (only two columns change; 12 products).

    Returns R. Chaining it over a joint's channels turns a parent's global rotation into
    the child's without forming the local matrices.
    """
    c, s = np.cos(ang), np.sin(ang)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    Ri, Rj = R[:, i].copy(), R[:, j]
    R[:, i] = Ri * c + Rj * s
    R[:, j] = Rj * c - Ri * s
    return R


def euler_to_matrix(axes, angles: np.ndarray) -> np.ndarray:
    """``R_a1(angles[..., 0]) @ R_a2(angles[..., 1]) @ ...`` (..., 3, 3); no axes: identity."""
    angles = np.asarray(angles, float)
    R = np.zeros((3, 3) + angles.shape[:-1])                 # built in the (3, 3, ...) layout:
    R[0, 0] = R[1, 1] = R[2, 2] = 1.0                         # each step changes two columns
    for i, a in enumerate(axes):
        rotate_right_t(R, a, angles[..., i])
    return np.ascontiguousarray(np.moveaxis(R, (0, 1), (-2, -1)))


def _is_cyclic(i: int, j: int, k: int) -> bool:
    return (i, j, k) in ((0, 1, 2), (1, 2, 0), (2, 0, 1))


def rotate_left_t(R: np.ndarray, axis: int, ang: np.ndarray) -> np.ndarray:
    """``R_axis(ang) @ R`` for R (3, 3, T) in place (only two rows change). Returns R."""
    c, s = np.cos(ang), np.sin(ang)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    Ri, Rj = R[i].copy(), R[j]
    R[i] = c * Ri - s * Rj
    R[j] = s * Ri + c * Rj
    return R


def euler_from_matrix_t(R: np.ndarray, axes) -> tuple[np.ndarray, np.ndarray]:
    """Both angle sets (T, 3) radians with ``R = R_a1 R_a2 R_a3`` for three distinct axes,
    R in the (3, 3, T) layout.

    The middle angle comes from the well-conditioned atan2 form, the first from the last
    column, the third from the residual rotation ``(R_a1 R_a2)^T R``, so the angles
    reproduce R to round-off even next to gimbal lock (the first angle is set to 0 at
    exact lock). The second set is the other branch ``(t1 + pi, pi - t2, t3 + pi)``.
    """
    i, j, k = axes
    s = 1.0 if _is_cyclic(i, j, k) else -1.0
    cb = np.hypot(R[i, i], R[i, j])
    beta = np.arctan2(s * R[i, k], cb)
    alpha = np.where(cb < 1e-12, 0.0, np.arctan2(-s * R[j, k], R[k, k]))
    M = R.copy()
    rotate_left_t(M, i, -alpha)                       # (R_i(a) R_j(b))^T R = R_j(-b) R_i(-a) R
    rotate_left_t(M, j, -beta)
    k1, k2 = (k + 1) % 3, (k + 2) % 3
    gamma = np.arctan2(M[k2, k1], M[k1, k1])
    e1 = np.stack([alpha, beta, gamma], axis=1)
    e2 = np.stack([alpha + np.pi, np.pi - beta, gamma + np.pi], axis=1)
    return e1, e2


def normalize(v: np.ndarray, eps: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors along the last axis (zero where the norm is <= eps) and the norms."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > eps, n, 1.0), n[..., 0]


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices (..., 3, 3) of vectors (..., 3)."""
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return K


def min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Shortest-arc rotations (T, 3, 3) taking directions a (T, 3) onto b (T, 3).

    ``R = c I + [v]x + v v^T / (1 + c)`` with ``v = a x b``, ``c = a . b`` (unit vectors).
    Antiparallel pairs: a half turn about an axis perpendicular to a; a zero vector: identity.
    """
    an, na = normalize(a, 1e-300)
    bn, nb = normalize(b, 1e-300)
    c = np.clip(np.sum(an * bn, axis=-1), -1.0, 1.0)
    v = np.cross(an, bn)
    anti = c < -1.0 + 1e-12
    R = skew(v)
    R += (v[:, :, None] * (v / np.where(anti, 1.0, 1.0 + c)[:, None])[:, None, :])
    R += c[:, None, None] * np.eye(3)
    if anti.any():
        ai = an[anti]
        ref = np.eye(3)[np.argmin(np.abs(ai), axis=1)]
        u, _ = normalize(np.cross(ai, ref))
        R[anti] = 2 * u[:, :, None] * u[:, None, :] - np.eye(3)
    R[(na <= 1e-300) | (nb <= 1e-300)] = np.eye(3)
    return R


def kabsch(A: np.ndarray, B: np.ndarray, degenerate_q: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Rotations Q (T, 3, 3) minimising sum_k |Q a_k - b_k|^2 for A, B (T, K, 3), and a
    (T,) mask of frames whose vectors are (nearly) collinear (rotation not determined).

    ``Q = V diag(1, 1, det) U^T`` for ``H = sum_k a_k b_k^T = U S V^T`` (Kabsch 1976).
    Frames with ``det H > 1e-12 |H|^3``, where Q is the orthogonal polar
    factor of ``H^T``) take a scaled Newton iteration (:func:`_polar`, a few 3x3 products,
    ~20x faster than a batched SVD); the others, and any that do not converge, the SVD.
    With exactly two vectors (H of rank 2) the normals ``a_1 x a_2 -> b_1 x b_2`` are
    added to H first, which leaves the solution unchanged and makes H invertible.
    ``degenerate_q=False``: the collinear frames (``|cof H| <= 1e-9 |H|^2``, i.e.
    ``s_2 <= ~1e-9 s_1``) get the identity instead of an SVD answer (for callers that
    replace them anyway).
    """
    H = np.swapaxes(A, 1, 2) @ B
    if A.shape[1] == 2:
        na, _ = normalize(np.cross(A[:, 0], A[:, 1]))
        nb, _ = normalize(np.cross(B[:, 0], B[:, 1]))
        w = np.sqrt(np.sum(H * H, axis=(1, 2)))
        H = H + w[:, None, None] * na[:, :, None] * nb[:, None, :]
    Q = np.empty_like(H)
    deg = np.zeros(H.shape[0], bool)
    fro = np.sqrt(np.sum(H * H, axis=(1, 2)))
    good = np.linalg.det(H) > 1e-12 * fro ** 3
    if good.any():
        Qg, ok = _polar(np.swapaxes(H[good], 1, 2))
        Q[good] = Qg
        good[np.flatnonzero(good)[~ok]] = False
    bad = ~good
    if bad.any() and not degenerate_q:
        Hb = H[bad]
        cof = np.cross(Hb[:, [1, 2, 0]], Hb[:, [2, 0, 1]])           # the 2x2 minors
        col = np.sqrt(np.sum(cof * cof, axis=(1, 2))) <= 1e-9 * fro[bad] ** 2
        idx = np.flatnonzero(bad)
        Q[idx[col]] = np.eye(3)
        deg[idx[col]] = True
        bad[idx[col]] = False
    if bad.any():
        Q[bad], deg[bad] = _kabsch_svd(H[bad])
    return Q, deg


def _kabsch_svd(H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    U, S, Vt = np.linalg.svd(H)
    V, Ut = np.swapaxes(Vt, 1, 2), np.swapaxes(U, 1, 2)
    d = np.sign(np.linalg.det(V @ Ut))
    d[d == 0] = 1.0
    Q = (V * np.stack([np.ones_like(d), np.ones_like(d), d], axis=1)[:, None, :]) @ Ut
    deg = S[:, 1] <= 1e-9 * np.maximum(S[:, 0], 1e-300)
    return Q, deg


def _polar(M: np.ndarray, iters: int = 30, tol: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """Orthogonal polar factors (T, 3, 3) of M with det M > 0, by the Frobenius-scaled
    Newton iteration ``X <- (g X + X^-T / g) / 2`` (Higham 1986), and a (T,) converged mask.

    Component arithmetic on the nine (T,) entries (no batched LAPACK, no np.cross).
    """
    x = [M[:, i, j] / np.sqrt(np.sum(M * M, axis=(1, 2))) for i in range(3) for j in range(3)]
    T = len(M)
    live = np.arange(T)
    out = np.empty((T, 9))
    conv = np.zeros(T, bool)
    for _ in range(iters):
        a, b, c, d, e, f, g, h, i = x
        co = [e * i - f * h, f * g - d * i, d * h - e * g,       # cofactor matrix = det * X^-T
              c * h - b * i, a * i - c * g, b * g - a * h,
              b * f - c * e, c * d - a * f, a * e - b * d]
        det = a * co[0] + b * co[1] + c * co[2]
        nx = sum(v * v for v in x)
        ni = sum(v * v for v in co) / (det * det)
        gam = np.sqrt(np.sqrt(ni / nx))
        p, q = 0.5 * gam, 0.5 / (gam * det)
        xn = [p * v + q * w for v, w in zip(x, co)]
        delta = np.max(np.abs(np.stack(xn) - np.stack(x)), axis=0)
        x = xn
        fin = delta < tol
        if fin.any():                                          # retire the converged frames
            out[live[fin]] = np.stack([v[fin] for v in x], axis=1)
            conv[live[fin]] = True
            keep = ~fin
            live, x = live[keep], [v[keep] for v in x]
            if not len(live):
                break
    if len(live):
        out[live] = np.stack(x, axis=1)
    X = out.reshape(T, 3, 3)
    return X, conv & (np.abs(np.sum(X * X, axis=(1, 2)) - 3.0) < 1e-9)


def axis_angle(axis: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Rotations (T, 3, 3) by ``theta`` (T,) radians about unit axes (T, 3) (Rodrigues)."""
    K = skew(axis)
    s, c = np.sin(theta)[..., None, None], np.cos(theta)[..., None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def twist_angle(axis: np.ndarray, U: np.ndarray, W: np.ndarray, reg: float | np.ndarray = 0.0) -> np.ndarray:
    """Angle (T,) about unit ``axis`` (T, 3) best rotating vectors U onto W (T, n, 3).

    Exact least squares: ``atan2(sum a.(u_perp x w_perp), sum u_perp.w_perp + reg)``;
    ``reg`` >= 0 pulls towards zero when the projections nearly vanish.
    With a unit axis, ``a.(u_perp x w_perp) = a.(u x w)`` and ``u_perp.w_perp = u.w -
    (u.a)(w.a)``: computed so, on the (T, n) component planes (no (T, n, 3) temporaries).
    """
    a0, a1, a2 = (axis[:, k, None] for k in range(3))
    u0, u1, u2 = (U[..., k] for k in range(3))
    w0, w1, w2 = (W[..., k] for k in range(3))
    s = a0 * (u1 * w2 - u2 * w1) + a1 * (u2 * w0 - u0 * w2) + a2 * (u0 * w1 - u1 * w0)
    c = u0 * w0 + u1 * w1 + u2 * w2 - (a0 * u0 + a1 * u1 + a2 * u2) * (a0 * w0 + a1 * w1 + a2 * w2)
    return np.arctan2(s.sum(axis=-1), c.sum(axis=-1) + reg)


def wrap_near(ang: np.ndarray, ref: np.ndarray, period: float = 2 * np.pi) -> np.ndarray:
    """``ang`` shifted by whole periods to lie within half a period of ``ref``."""
    return ang + period * np.round((ref - ang) / period)
