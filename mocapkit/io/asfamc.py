"""Acclaim ASF/AMC reader and writer (CMU and HDM05 variants); own parser, no dependency.

ASF (skeleton)
--------------
Sections ``:version``, ``:name``, ``:units`` (``mass``, ``length``, ``angle deg|rad``),
``:documentation``, ``:root`` (``order`` of the AMC root channels, ``axis`` rotation
order, ``position``, ``orientation``), ``:bonedata`` (``begin … end`` blocks with ``id``,
``name``, ``direction`` (unit vector in the global rest frame), ``length``,
``axis ax ay az ORDER``, ``dof`` (rotational ``rx ry rz``; translational bone dofs are
refused), ``limits`` (one ``(lo hi)`` pair per dof, possibly over several lines)) and
``:hierarchy`` (``begin``, ``parent child child …`` lines, ``end``). Unknown keywords
(``bodymass``, ``cofmass``, ``:namespace`` …) are kept and ignored.

AMC (motion)
------------
Header keywords (``:FULLY-SPECIFIED``, ``:DEGREES`` / ``:RADIANS``), then frames: a frame
number line followed by one line per bone, ``name v1 v2 …`` with one value per dof in the
ASF's ``dof`` order (``root``: one per channel of the ASF ``order``). Frame numbers must
increase by one. In a ``:FULLY-SPECIFIED`` file every frame must list every bone that has
dofs; otherwise a missing bone keeps its previous value (zero in the first frame).

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
:func:`read_asf_motion`). The loop runs over bones only.

Joints of the returned Motion: ``root`` plus the end point of every bone, named by the
bone (31 joints for CMU, 31 for HDM05); parents follow the ``:hierarchy``; rest offsets
are ``direction · length`` in cm.

Units
-----
``:units length s`` means that ASF/AMC lengths are *inches × s*: CMU and HDM05 both state
``length 0.45``, so one file unit is ``1/0.45`` inch = ``2.54/0.45`` = **5.644444 cm**
(the factor applied to bone lengths and root translations). In general the factor is
``2.54 / s`` cm per unit; ``read(..., units=f)`` overrides it with ``f`` cm per unit.
With this factor CMU subjects stand 150-200 cm tall, and so do the HDM05 actors (see
``docs/results/io.md``). Angles are kept in the file's unit (``:DEGREES`` in the AMC,
else the ASF ``angle``).

Metadata
--------
``motion.source``: ``path``, ``format`` (``'amc'`` / ``'asf'``), ``skeleton_path``,
``units`` (file unit description and ``cm_per_unit``), ``asf`` (the whole parsed skeleton
description as plain lists/dicts), ``amc`` (header lines, first frame number, bone order
per frame, angle unit), ``dof_names`` (``'root.TX'``, ``'lfemur.rx'``, …) and
``per_frame['dofs']``: the (T, D) dof values exactly as in the file (D = 62 for CMU).

Writing (AMC)
-------------
:func:`write` needs a motion that carries ``source['asf']`` (read from ASF/AMC). If
its positions still equal the forward kinematics of the stored dofs (within 1e-7 cm),
the stored dofs are written unchanged (shortest round-trip float text), so the file
re-reads identically. Otherwise the dofs are recovered by per-bone inverse kinematics
(:func:`inverse_kinematics`), top-down and vectorised over frames:

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
4. a Levenberg-Marquardt polish of all dofs of a frame at once (analytic Jacobian, at
   most 12 iterations, a step kept only if it lowers that frame's squared position
   error) runs only on the frames the closed-form pass leaves more than
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

Implementation: :mod:`mocapkit.io.asf` (skeleton files), :mod:`mocapkit.io.amc` (motion
files), :mod:`mocapkit.io._kinematics` (FK/IK), :mod:`mocapkit.io._rotations` (rotation
maths shared with the BVH module); this module re-exports their names.

A written AMC needs its ASF: when the skeleton lookup for the output file would not
find an identical skeleton, ``<output stem>.asf`` is written beside it
(``write_asf=False`` to skip, or a path to choose where).
"""
from __future__ import annotations

# The implementation lives in three modules (issue #21): the ASF side, the AMC side and
# the kinematics; every name (public and the private ones other modules and the tests
# use) is re-exported here so ``mocapkit.io.asfamc`` keeps working unchanged.
from .asf import (CMU_CM_PER_UNIT, _asf_files, _asf_text, _axis_order, _fmt_asf_num, _num, _nums,
                  _parse_limits, _same_skeleton, cm_per_unit, find_skeleton, read_asf, write_asf)
from ._kinematics import (_Compiled, _axis_angle_fit, _euler_from, _euler_matrix, _fit_partial, _kabsch,
                          _min_rotation, _mm_t, _rot_t, _start_angles, forward_kinematics,
                          inverse_kinematics)
from .amc import _amc_text, _finite_pose, _parse_amc, read, read_asf_motion, write

__all__ = ["read", "read_asf", "read_asf_motion", "write", "write_asf", "find_skeleton",
           "forward_kinematics", "inverse_kinematics", "cm_per_unit", "CMU_CM_PER_UNIT"]
