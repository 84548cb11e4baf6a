"""Error measures between a ground-truth motion and an estimate, in documented units.

Inputs: :class:`~mocapkit.motion.Motion` objects or plain arrays of positions, either
(T, J, 3) or the (T, 3J) frame-by-coordinate matrix (cm). Bone-based measures need a
skeleton, taken from whichever argument is a Motion; ``acceleration_error`` needs a
frame rate (from a Motion or ``fps=``).

Conventions shared by every function:

* **Truth gaps.** Entries missing in the truth (``observed`` False / NaN) cannot be
  scored and are left out of every mean (documented per function where it matters).
* **Estimate gaps.** An estimate must have a finite value wherever a measure needs one;
  otherwise :class:`~mocapkit.errors.MocapValueError` says how many values are missing
  and where the first one is (frame, joint). Fill gaps before scoring.
* **Mismatch.** Different numbers of frames/joints, different skeletons (joint names or
  hierarchy) or different frame rates raise MocapValueError.
* **Masks.** ``mask`` selects the scored entries: joint level (T, J) (all three
  coordinates of each selected joint) or coordinate level (T, 3J) / (T, J, 3). The masks
  returned by :mod:`mocapkit.corrupt` are joint level.

Measures (value, unit)
----------------------
:func:`rmse`                 root mean square over *coordinates*, cm (= cm/channel)
:func:`mean_joint_error`     mean Euclidean distance per joint (MPJPE), cm
:func:`per_frame_rmse`       Xiao 2015 eq. (6) / thesis eq. (3.18), one value per frame, cm
:func:`frobenius_distance`   SLRA FD = ||A - X*||_F / sqrt(mn), motion units (cm)
:func:`joint_angle_error`    angle between bone directions, degrees
:func:`bone_length_error`    mean |len_est - len_truth|, cm/bone
:func:`smoothness`           mean norm of the second difference, cm/frame²
:func:`acceleration_error`   mean norm of the acceleration difference, cm/s²
:func:`brap_reproduction_error` / :func:`brap_bone_error` / :func:`brap_smoothness_error`
                             BRA-P (Li et al. 2020, seed 002) R eq. (3), B eq. (7), S eq. (6)
:func:`all_metrics`          all of the above as ``{name: (value, unit)}`` (CLI ``eval``)
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .errors import MocapValueError
from .motion import Motion
from .rigid import bone_lengths
from .skeleton import Skeleton

__all__ = ["rmse", "mean_joint_error", "per_frame_rmse", "per_frame_rmse_stats",
           "frobenius_distance", "joint_angle_error", "bone_length_error", "smoothness",
           "acceleration_error", "brap_reproduction_error", "brap_bone_error",
           "brap_smoothness_error", "all_metrics"]


# ----------------------------------------------------------------------------------------
# input handling
# ----------------------------------------------------------------------------------------
class _Data:
    """Positions (T, J, 3), observed (T, J), skeleton or None, fps or None."""

    __slots__ = ("P", "obs", "skeleton", "fps")

    def __init__(self, x: Any, what: str):
        if isinstance(x, Motion):
            self.P, self.obs, self.skeleton, self.fps = x.positions, x.observed, x.skeleton, x.fps
            return
        try:
            P = np.asarray(x, dtype=float)
        except (TypeError, ValueError):
            raise MocapValueError(f"{what}: expected a Motion or an array of positions, "
                                  f"got {type(x).__name__}") from None
        if P.ndim == 2 and P.shape[1] % 3 == 0 and P.shape[1] > 0:
            P = P.reshape(P.shape[0], -1, 3)
        if P.ndim != 3 or P.shape[2] != 3 or P.shape[0] == 0 or P.shape[1] == 0:
            raise MocapValueError(f"{what}: positions must have shape (T, J, 3) or (T, 3J), got {np.shape(x)}")
        self.P, self.obs, self.skeleton, self.fps = P, np.isfinite(P).all(axis=2), None, None


def _pair(truth: Any, est: Any) -> tuple[_Data, _Data, Skeleton | None, float | None]:
    t, e = _Data(truth, "truth"), _Data(est, "estimate")
    if t.P.shape != e.P.shape:
        raise MocapValueError(
            f"truth and estimate differ in shape: {t.P.shape[0]} frames x {t.P.shape[1]} joints "
            f"vs {e.P.shape[0]} frames x {e.P.shape[1]} joints")
    if t.skeleton is not None and e.skeleton is not None:
        a, b = t.skeleton, e.skeleton
        if a.names != b.names or not np.array_equal(a.parents, b.parents):
            diff = [f"{x}/{y}" for x, y in zip(a.names, b.names) if x != y][:3]
            raise MocapValueError(
                "truth and estimate have different skeletons"
                + (f" (joint names differ: {', '.join(diff)})" if diff else " (hierarchy differs)"))
    if t.fps is not None and e.fps is not None and not np.isclose(t.fps, e.fps, rtol=1e-3):
        raise MocapValueError(f"truth and estimate differ in frame rate: {t.fps:g} vs {e.fps:g} fps")
    sk = t.skeleton if t.skeleton is not None else e.skeleton
    fps = t.fps if t.fps is not None else e.fps
    return t, e, sk, fps


def _coord_mask(mask: Any, T: int, J: int) -> np.ndarray:
    """Mask (T, J) / (T, 3J) / (T, J, 3) -> bool (T, J, 3); None -> all True."""
    if mask is None:
        return np.ones((T, J, 3), dtype=bool)
    m = np.asarray(mask)
    if m.dtype != bool:
        if not np.isin(m, (0, 1)).all():
            raise MocapValueError("mask must be boolean (True = scored entry)")
        m = m.astype(bool)
    if m.shape == (T, J):
        return np.repeat(m[:, :, None], 3, axis=2)
    if m.shape == (T, 3 * J):
        return m.reshape(T, J, 3)
    if m.shape == (T, J, 3):
        return m.copy()
    raise MocapValueError(f"mask must have shape ({T}, {J}) (joints) or ({T}, {3 * J}) (coordinates), "
                          f"got {m.shape}")


def _name(sk: Skeleton | None, j: int) -> str:
    return repr(sk.names[j]) if sk is not None else str(j)


def _need_finite(values: np.ndarray, where: np.ndarray, sk: Skeleton | None, metric: str,
                 what: str = "estimate") -> None:
    """Raise if ``values`` (T, J[, 3]) is not finite somewhere ``where`` is True."""
    if values.ndim == 3 and where.ndim == 2:
        where = where[:, :, None]
    bad = where & ~np.isfinite(values)
    if bad.ndim == 3:
        bad = bad.any(axis=2)
    if bad.any():
        t, j = np.argwhere(bad)[0]
        raise MocapValueError(
            f"{metric}: the {what} has {int(bad.sum())} missing/non-finite joint value(s) where a value "
            f"is needed (first at frame {t}, joint {_name(sk, j)}); fill the gaps first")


def _bones(sk: Skeleton | None, metric: str) -> tuple[np.ndarray, np.ndarray]:
    if sk is None:
        raise MocapValueError(f"{metric} needs a skeleton: pass a Motion as truth or estimate")
    b = np.array(sk.bones(), dtype=int).reshape(-1, 2)
    if len(b) == 0:
        raise MocapValueError(f"{metric}: the skeleton has no bones (a single joint)")
    return b[:, 0], b[:, 1]


def _empty(metric: str) -> MocapValueError:
    return MocapValueError(f"{metric}: no entries to score (mask empty or truth missing there)")


# ----------------------------------------------------------------------------------------
# position errors
# ----------------------------------------------------------------------------------------
def rmse(truth: Any, est: Any, mask: Any = None) -> float:
    """Root mean square error over coordinates, cm.

    ``sqrt(mean over scored coordinates c of (est_c - truth_c)**2)``: every scored joint
    contributes its x, y and z errors separately (so for isotropic errors this is the
    per-coordinate error, "cm per channel"; mean Euclidean joint errors are
    :func:`mean_joint_error`). Equal to the thesis' completion RMSE
    ``||(X - X~)|_Ω||_F / sqrt(|Ω|)`` (seed 003, Ch. 4.2) with Ω the scored coordinates.

    Parameters
    ----------
    truth, est : Motion or array (T, J, 3) / (T, 3J), cm.
    mask : optional bool (T, J) joints or (T, 3J) / (T, J, 3) coordinates to score
        (default all); entries missing in the truth are never scored.

    Returns
    -------
    float, cm.

    Examples
    --------
    >>> import numpy as np
    >>> from mocapkit import metrics
    >>> truth = np.zeros((2, 1, 3))                    # 2 frames, 1 joint
    >>> est = truth + [[[3.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]]]
    >>> metrics.rmse(truth, est)                       # sqrt(9 / 6)
    1.224744871391589
    >>> metrics.rmse(truth, est, mask=np.array([[False], [True]]))
    0.0
    """
    t, e, sk, _ = _pair(truth, est)
    sel = _coord_mask(mask, *t.obs.shape) & t.obs[:, :, None]
    if not sel.any():
        raise _empty("rmse")
    _need_finite(e.P, sel, sk, "rmse")
    d = e.P[sel] - t.P[sel]
    return float(np.sqrt(np.mean(d * d)))


def mean_joint_error(truth: Any, est: Any, mask: Any = None) -> float:
    """Mean Euclidean distance between corresponding joints (MPJPE), cm.

    ``mean over scored (t, j) of ||est[t, j] - truth[t, j]||``. A coordinate-level mask
    scores a joint when any of its coordinates is selected.

    Parameters
    ----------
    truth, est : Motion or array (T, J, 3) / (T, 3J), cm.
    mask : optional bool mask (see :func:`rmse`).

    Returns
    -------
    float, cm.
    """
    t, e, sk, _ = _pair(truth, est)
    sel = _coord_mask(mask, *t.obs.shape).any(axis=2) & t.obs
    if not sel.any():
        raise _empty("mean_joint_error")
    _need_finite(e.P, sel[:, :, None], sk, "mean_joint_error")
    return float(np.mean(np.linalg.norm(e.P[sel] - t.P[sel], axis=1)))


def per_frame_rmse(truth: Any, est: Any, mask: Any = None) -> np.ndarray:
    """Per-frame RMSE over the corrupted markers (Xiao 2015 eq. (6); thesis eq. (3.18)), cm.

    For frame i with scored markers S_i (``n_e = |S_i|``, "the total number of noisy /
    missing markers in" frame i)::

        RMSE_i = sqrt( (1/n_e) * sum_{j in S_i} ||p_ij - p^_ij||² )

    i.e. the root of the mean *squared Euclidean* marker error in that frame. Papers
    plot it against the frame index and report its mean (and std) over frames
    ("cm/frame"); see :func:`per_frame_rmse_stats`. (Xiao et al. print metres; we use cm.)

    Parameters
    ----------
    truth, est : Motion or array (T, J, 3) / (T, 3J), cm.
    mask : the corrupted markers, bool (T, J) (coordinate masks are reduced with
        "any"); default every marker. Markers missing in the truth are left out.

    Returns
    -------
    array (T,), cm; NaN for frames with no scored marker.
    """
    t, e, sk, _ = _pair(truth, est)
    sel = _coord_mask(mask, *t.obs.shape).any(axis=2) & t.obs            # (T, J)
    _need_finite(e.P, sel[:, :, None], sk, "per_frame_rmse")
    d2 = np.where(sel, np.sum((np.where(sel[..., None], e.P - t.P, 0.0)) ** 2, axis=2), 0.0)
    n = sel.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.sqrt(d2.sum(axis=1) / n)
    out[n == 0] = np.nan
    return out


def per_frame_rmse_stats(truth: Any, est: Any, mask: Any = None) -> tuple[float, float]:
    """Mean and standard deviation over frames of :func:`per_frame_rmse` (cm).

    Only frames with at least one scored marker count (Xiao et al. Table 1 reports mean
    and std of this per-frame RMSE).

    Returns
    -------
    (mean, std), cm.
    """
    r = per_frame_rmse(truth, est, mask)
    r = r[np.isfinite(r)]
    if r.size == 0:
        raise _empty("per_frame_rmse")
    return float(r.mean()), float(r.std())


def frobenius_distance(truth: Any, est: Any) -> float:
    """SLRA Frobenius distance FD = ||A - X*||_F / sqrt(m n) (Peng et al., seed 004, Sec. 4.2).

    A is the denoised m x n matrix (m frames, n = 3J coordinates), X* the original. This
    is the RMSE over all m*n coordinates, in the motion's units (cm for a Motion from a
    reader; the paper's Table 2 values are in CMU ASF units, 1 unit = 5.6444 cm).

    Parameters
    ----------
    truth, est : Motion (its (T, 3J) matrix is used), positions (T, J, 3) (flattened to
        (T, 3J)) or any other array; same shapes.

    Returns
    -------
    float, motion units (cm).

    Raises
    ------
    MocapValueError if the shapes differ or either matrix has a non-finite entry (FD
    needs every entry; say which).
    """
    def mat(x: Any, what: str) -> np.ndarray:
        if isinstance(x, Motion):
            return x.matrix()
        try:
            a = np.asarray(x, dtype=float)
        except (TypeError, ValueError):
            raise MocapValueError(f"frobenius_distance: {what} must be a Motion or an array") from None
        return a.reshape(a.shape[0], -1) if a.ndim == 3 and a.shape[2] == 3 else a

    if isinstance(truth, Motion) and isinstance(est, Motion):
        _pair(truth, est)
    A, X = mat(est, "estimate"), mat(truth, "truth")
    if A.shape != X.shape:
        raise MocapValueError(f"frobenius_distance: shapes differ: truth {X.shape} vs estimate {A.shape}")
    if A.size == 0:
        raise _empty("frobenius_distance")
    for M, what in ((X, "truth"), (A, "estimate")):
        bad = ~np.isfinite(M)
        if bad.any():
            first = np.argwhere(bad)[0]
            raise MocapValueError(f"frobenius_distance: the {what} has {int(bad.sum())} non-finite "
                                  f"entries (first at index {tuple(int(i) for i in first)}); FD needs every entry")
    return float(np.linalg.norm(A - X) / np.sqrt(A.size))


# ----------------------------------------------------------------------------------------
# skeleton measures
# ----------------------------------------------------------------------------------------
def joint_angle_error(truth: Any, est: Any, *, min_length_cm: float = 1e-3) -> float:
    """Mean angle between corresponding bone directions, degrees.

    For every bone (child c, parent p) and frame t, ``u = truth[t,c] - truth[t,p]`` and
    ``v = est[t,c] - est[t,p]``; the angle is ``atan2(||u x v||, u . v)`` (numerically
    stable for small angles), in [0, 180]. Mean over bones and frames.

    Left out: frames where a truth end point is missing, and truth bones shorter than
    ``min_length_cm`` (no direction; e.g. the zero-length hip joints of some CMU BVH
    conversions). An estimated bone of zero length has no direction and counts as 90°.

    Parameters
    ----------
    truth, est : Motion (at least one, for the skeleton) or array (T, J, 3), cm.

    Returns
    -------
    float, degrees.
    """
    t, e, sk, _ = _pair(truth, est)
    c, p = _bones(sk, "joint_angle_error")
    u = t.P[:, c] - t.P[:, p]                                           # (T, B, 3)
    v = e.P[:, c] - e.P[:, p]
    valid = t.obs[:, c] & t.obs[:, p]
    valid &= np.linalg.norm(np.nan_to_num(u), axis=2) >= min_length_cm
    if not valid.any():
        raise _empty("joint_angle_error")
    _need_finite(e.P, _joint_need(valid, c, p, e.P.shape[1]), sk, "joint_angle_error")
    u, v = u[valid], v[valid]
    cross = np.linalg.norm(np.cross(u, v), axis=1)
    dot = np.sum(u * v, axis=1)
    ang = np.degrees(np.arctan2(cross, dot))
    ang[np.linalg.norm(v, axis=1) < 1e-12] = 90.0
    return float(ang.mean())


def _joint_need(valid: np.ndarray, c: np.ndarray, p: np.ndarray, J: int) -> np.ndarray:
    """(T, J) joints needed by the bones marked in ``valid`` (T, B)."""
    need = np.zeros((valid.shape[0], J), dtype=bool)
    rows = np.nonzero(valid)
    need[rows[0], c[rows[1]]] = True
    need[rows[0], p[rows[1]]] = True
    return need


def bone_length_error(truth: Any, est: Any, *, per_bone: bool = False) -> float | np.ndarray:
    """Mean absolute bone-length difference, cm/bone.

    ``mean over (t, b) of | ||est_c - est_p|| - ||truth_c - truth_p|| |`` for every bone
    b = (c, p) and frame t whose truth end points are observed.

    Parameters
    ----------
    truth, est : Motion (at least one, for the skeleton) or array (T, J, 3), cm.
    per_bone : return the mean per bone (B,) (order of ``skeleton.bones()``; NaN for a
        bone never scored) instead of the overall mean.

    Returns
    -------
    float (or array (B,) with ``per_bone``), cm/bone.
    """
    t, e, sk, _ = _pair(truth, est)
    c, p = _bones(sk, "bone_length_error")
    bp = np.stack([c, p], axis=1)
    valid = t.obs[:, c] & t.obs[:, p]
    if not valid.any():
        raise _empty("bone_length_error")
    _need_finite(e.P, _joint_need(valid, c, p, e.P.shape[1]), sk, "bone_length_error")
    d = np.where(valid, np.abs(np.nan_to_num(bone_lengths(e.P, bp)) - np.nan_to_num(bone_lengths(t.P, bp))), 0.0)
    if per_bone:
        n = valid.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = d.sum(axis=0) / n
        out[n == 0] = np.nan
        return out
    return float(d.sum() / valid.sum())


def smoothness(motion: Any) -> float:
    """Mean norm of the second difference of joint positions, cm/frame².

    ``mean over t = 1..T-2 and joints j of ||p[t+1,j] - 2 p[t,j] + p[t-1,j]||``.
    Second differences that involve a missing sample are left out. A property of one
    motion (compare the estimate's value with the truth's); multiply by fps² for cm/s².

    Parameters
    ----------
    motion : Motion or array (T, J, 3) / (T, 3J), cm; T >= 3.

    Returns
    -------
    float, cm/frame².
    """
    d = _Data(motion, "motion")
    if d.P.shape[0] < 3:
        raise MocapValueError(f"smoothness needs at least 3 frames, got {d.P.shape[0]}")
    a = np.linalg.norm(d.P[2:] - 2 * d.P[1:-1] + d.P[:-2], axis=2)    # (T-2, J), NaN where missing
    a = a[np.isfinite(a)]
    if a.size == 0:
        raise _empty("smoothness")
    return float(a.mean())


def acceleration_error(truth: Any, est: Any, *, fps: float | None = None, mask: Any = None) -> float:
    """Mean Euclidean norm of the acceleration difference, cm/s².

    Accelerations by central second differences, ``a[t] = (p[t+1] - 2 p[t] + p[t-1]) *
    fps²`` for t = 1..T-2; value = mean over t and joints of ``||a_est[t,j] - a_truth[t,j]||``.
    Frames whose truth second difference involves a missing sample are left out.

    Parameters
    ----------
    truth, est : Motion or array (T, J, 3) / (T, 3J), cm; T >= 3.
    fps : frame rate, needed only when neither argument is a Motion.
    mask : optional joint mask (T, J) applied to the centre frame t.

    Returns
    -------
    float, cm/s².
    """
    t, e, sk, mfps = _pair(truth, est)
    rate = fps if fps is not None else mfps
    if rate is None:
        raise MocapValueError("acceleration_error needs a frame rate: pass fps= or a Motion")
    rate = float(rate)
    if not np.isfinite(rate) or rate <= 0:
        raise MocapValueError(f"fps must be a positive number, got {rate!r}")
    T, J = t.obs.shape
    if T < 3:
        raise MocapValueError(f"acceleration_error needs at least 3 frames, got {T}")
    valid = t.obs[2:] & t.obs[1:-1] & t.obs[:-2]
    valid &= _coord_mask(mask, T, J).any(axis=2)[1:-1]
    if not valid.any():
        raise _empty("acceleration_error")
    need = np.zeros((T, J), dtype=bool)
    need[2:] |= valid
    need[1:-1] |= valid
    need[:-2] |= valid
    _need_finite(e.P, need[:, :, None], sk, "acceleration_error")
    at = t.P[2:] - 2 * t.P[1:-1] + t.P[:-2]
    ae = e.P[2:] - 2 * e.P[1:-1] + e.P[:-2]
    return float(np.mean(np.linalg.norm(ae[valid] - at[valid], axis=1)) * rate * rate)


# ----------------------------------------------------------------------------------------
# BRA-P (Li et al. 2020, seed 002, Sec. III.C and IV)
# ----------------------------------------------------------------------------------------
def brap_reproduction_error(truth: Any, est: Any) -> float:
    """BRA-P reproduction error R, eq. (3): ``(1/(f d)) ||Y - X||``, cm/channel.

    f frames, d = 3J channels. Decision: the paper reports R in "cm/channel", which only
    the entry-wise reading of its ``||.||_2`` gives (the Frobenius norm divided by f*d
    would shrink with clip size), so R is the mean absolute coordinate error::

        R = (1/(f d)) * sum_{t,c} |Y[t,c] - X[t,c]|

    The paper first scales skeletons to 175 cm (neutral pose); we score in the motions'
    own cm. Truth-missing entries are left out.

    Returns
    -------
    float, cm/channel.
    """
    t, e, sk, _ = _pair(truth, est)
    sel = np.repeat(t.obs[:, :, None], 3, axis=2)
    if not sel.any():
        raise _empty("brap_reproduction_error")
    _need_finite(e.P, sel, sk, "brap_reproduction_error")
    return float(np.mean(np.abs(e.P[sel] - t.P[sel])))


def brap_bone_error(truth: Any, est: Any, *, lengths: np.ndarray | None = None) -> float:
    """BRA-P bone-length error B, eq. (7), cm/bone.

    ::

        B = (1/(f (J-1))) * sum_{i=1..f} sum_{b=1..J-1} | ||p_b^{i,1} - p_b^{i,2}|| - l_b |

    over every frame i of the estimate and every bone b (J-1 bones of a tree), with l_b
    the reference length of bone b. Unlike :func:`bone_length_error` it compares with one
    fixed length per bone, so it also measures bone-length *consistency*.

    Parameters
    ----------
    truth : Motion or array giving the reference lengths: l_b = median over the truth's
        observed frames of its length of bone b (for FK data: the skeleton's bone
        length). May be None when ``lengths`` is given (then ``est`` must be a Motion).
    est : Motion or array (T, J, 3), cm; must be complete.
    lengths : optional reference lengths (B,) in cm, order of ``skeleton.bones()``.

    Returns
    -------
    float, cm/bone.
    """
    if truth is None:
        if lengths is None or not isinstance(est, Motion):
            raise MocapValueError("brap_bone_error needs the truth (or lengths= and an estimate Motion)")
        e = _Data(est, "estimate")
        sk = e.skeleton
    else:
        _, e, sk, _ = _pair(truth, est)
    c, p = _bones(sk, "brap_bone_error")
    bp = np.stack([c, p], axis=1)
    if lengths is None:
        t = _Data(truth, "truth")
        Lt = np.where(t.obs[:, c] & t.obs[:, p], bone_lengths(t.P, bp), np.nan)
        if np.isnan(Lt).all(axis=0).any():
            b = int(np.flatnonzero(np.isnan(Lt).all(axis=0))[0])
            raise MocapValueError(f"brap_bone_error: bone {_name(sk, int(c[b]))} is never observed in the truth")
        ref = np.nanmedian(Lt, axis=0)
    else:
        ref = np.asarray(lengths, dtype=float).reshape(-1)
        if ref.shape != c.shape or not np.isfinite(ref).all():
            raise MocapValueError(f"lengths must be {len(c)} finite bone lengths (cm), got shape {ref.shape}")
    _need_finite(e.P, np.ones(e.P.shape, dtype=bool), sk, "brap_bone_error")
    return float(np.mean(np.abs(bone_lengths(e.P, bp) - ref)))


def brap_smoothness_error(motion: Any) -> float:
    """BRA-P smoothness error S, eqs. (5)-(6), cm/frame² per channel.

    The clip X (f x d) is extended by repeating its border frames, X' = [x_1; X; x_f]
    ((f+2) x d), and multiplied by the (f+2) x (f+2) matrix O of eq. (5) (rows [-1, 1],
    [1, -2, 1] ..., [1, -1]); then ``S = (1/((f+2) d)) ||O X'||`` with the same
    entry-wise (mean absolute) reading of the norm as :func:`brap_reproduction_error`.
    The first and last rows of O X' are zero; rows 2 and f+1 are first differences at
    the clip ends, the others second differences. A property of one motion (the
    estimate); the paper applies it to 120-frame clips, we to the whole motion.

    Parameters
    ----------
    motion : Motion or array (T, J, 3) / (T, 3J), cm; must be complete.

    Returns
    -------
    float, cm/frame² (per channel).
    """
    d = _Data(motion, "motion")
    _need_finite(d.P, np.ones(d.P.shape, dtype=bool), d.skeleton, "brap_smoothness_error", "motion")
    X = d.P.reshape(d.P.shape[0], -1)
    Xp = np.concatenate([X[:1], X, X[-1:]], axis=0)                    # X' (f+2, d)
    inner = Xp[:-2] - 2 * Xp[1:-1] + Xp[2:]                            # rows 2..f+1 of O X'
    f, ch = X.shape
    return float(np.abs(inner).sum() / ((f + 2) * ch))


# ----------------------------------------------------------------------------------------
# everything at once (CLI `eval`)
# ----------------------------------------------------------------------------------------
def all_metrics(truth: Any, est: Any, corrupted_mask: Any = None) -> dict[str, tuple[float, str]]:
    """Every applicable measure as ``{name: (value, unit)}`` (insertion-ordered).

    Keys: ``rmse``, ``mean_joint_error`` (cm, all entries the truth observes);
    with a non-empty ``corrupted_mask`` also ``rmse_corrupted``,
    ``mean_joint_error_corrupted``; ``per_frame_rmse`` and ``per_frame_rmse_std`` (cm;
    over the corrupted markers, or all markers without a mask); ``frobenius_distance``
    (cm; only when the truth is complete); with a skeleton ``joint_angle_error`` (deg),
    ``bone_length_error`` (cm/bone), ``brap_B`` (cm/bone); ``brap_R`` (cm/channel);
    ``brap_S`` (cm/frame²); with at least 3 frames ``smoothness`` and
    ``smoothness_truth`` (cm/frame²) and, with a frame rate, ``acceleration_error`` (cm/s²).

    Parameters
    ----------
    truth, est : Motion or arrays (T, J, 3), cm. The estimate must be complete.
    corrupted_mask : optional bool (T, J) (e.g. from :mod:`mocapkit.corrupt`).

    Raises
    ------
    MocapValueError on mismatched inputs or an estimate with missing values.
    """
    t, e, sk, fps = _pair(truth, est)
    T, J = t.obs.shape
    _need_finite(e.P, np.ones(e.P.shape, dtype=bool), sk, "metrics")
    out: dict[str, tuple[float, str]] = {}
    out["rmse"] = (rmse(truth, est), "cm")
    out["mean_joint_error"] = (mean_joint_error(truth, est), "cm")
    mask = None
    if corrupted_mask is not None:
        mask = _coord_mask(corrupted_mask, T, J).any(axis=2) & t.obs
        if mask.any():
            out["rmse_corrupted"] = (rmse(truth, est, mask), "cm")
            out["mean_joint_error_corrupted"] = (mean_joint_error(truth, est, mask), "cm")
        else:
            mask = None
    if mask is not None or corrupted_mask is None:
        m, s = per_frame_rmse_stats(truth, est, mask)
        out["per_frame_rmse"] = (m, "cm")
        out["per_frame_rmse_std"] = (s, "cm")
    if t.obs.all():
        out["frobenius_distance"] = (frobenius_distance(t.P.reshape(T, -1), e.P.reshape(T, -1)), "cm")
    if sk is not None and J > 1:
        try:
            out["joint_angle_error"] = (joint_angle_error(truth, est), "deg")
        except MocapValueError:
            pass
        out["bone_length_error"] = (bone_length_error(truth, est), "cm/bone")
        try:
            out["brap_B"] = (brap_bone_error(truth, est), "cm/bone")
        except MocapValueError:
            pass
    out["brap_R"] = (brap_reproduction_error(truth, est), "cm/channel")
    out["brap_S"] = (brap_smoothness_error(est), "cm/frame^2")
    if T >= 3:
        out["smoothness"] = (smoothness(est), "cm/frame^2")
        try:
            out["smoothness_truth"] = (smoothness(truth), "cm/frame^2")
        except MocapValueError:
            pass
        if fps is not None:
            try:
                out["acceleration_error"] = (acceleration_error(truth, est), "cm/s^2")
            except MocapValueError:
                pass
    return out
