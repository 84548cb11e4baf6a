"""Skeleton: joint names, hierarchy and rest offsets.

Body parts (the five "poselets" of Xiao et al.: torso, left arm, right arm, left leg,
right leg) are resolved from joint *names*, so the same code works for CMU ASF names
(``lhumerus``), cgspeed BVH names (``LeftArm``), Daz names (``lShldr``) and Kinect names
(``ElbowLeft``).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from .errors import MocapValueError

BODY_PARTS = ("torso", "left_arm", "right_arm", "left_leg", "right_leg")

# Keywords that put a joint on a limb; matched case-insensitively in the joint name
# after the side marker is removed. Order matters only for readability.
_ARM_WORDS = ("clavicle", "shoulder", "collar", "shldr", "humerus", "arm", "elbow",
              "radius", "wrist", "hand", "finger", "thumb", "index", "middle", "ring",
              "pinky", "carpal", "mid", "pinky")
_LEG_WORDS = ("hipjoint", "hip", "femur", "thigh", "upleg", "leg", "knee", "tibia",
              "shin", "ankle", "foot", "toe", "heel", "buttock")
#: Names of the body's root on the midline, some with a limb keyword ("Hips", "hip"): not a
#: leg joint (:func:`_limb`), and a flat marker set's root (:mod:`mocapkit.frames`).
MIDLINE_ROOTS = frozenset({"hips", "hip", "hipcenter", "hip_center", "pelvis", "root"})


def bare_name(name: str) -> str:
    """The name without a namespace prefix: Vicon Nexus writes marker labels as
    ``Subject:LASI``, Mixamo rigs name joints ``mixamorig:LeftUpLeg``."""
    return name.rsplit(":", 1)[-1].strip()


def _side(name: str) -> str | None:
    """Return 'left', 'right' or None from a joint name (lfemur, LeftArm, ElbowLeft, l_knee,
    lThigh, LThumb; ``Subject:LASI`` and ``mixamorig:LeftArm`` by their bare name,
    :func:`bare_name`)."""
    if ":" in name:
        side = _side(bare_name(name))
        if side is not None:
            return side
    n = name.strip()
    low = n.lower()
    if low.startswith("left") or low.endswith("left") or re.search(r"(^|[_\.\s])l([_\.\s]|$)", low):
        return "left"
    if low.startswith("right") or low.endswith("right") or re.search(r"(^|[_\.\s])r([_\.\s]|$)", low):
        return "right"
    # single-letter prefix: lfemur, LThumb, lShldr, l_hip
    if len(n) > 1 and n[0] in "lL" and (n[1].isupper() or n[1] == "_" or low[1:].startswith(_ARM_WORDS + _LEG_WORDS)):
        return "left"
    if len(n) > 1 and n[0] in "rR" and (n[1].isupper() or n[1] == "_" or low[1:].startswith(_ARM_WORDS + _LEG_WORDS)):
        return "right"
    return None


#: The package's one joint-name alias table, by role (matched case-insensitively):
#:
#: * ``hip``, ``shoulder`` -- words looked for inside the name of a joint that has a side
#:   (:func:`_side`); the shallowest such joint wins (:func:`mocapkit.frames.find_hips`:
#:   the heading and pelvis-neck frames, the retrieval key points);
#: * ``neck`` -- whole names of the midline joint at the top of the spine, in order of
#:   preference (Xiao et al.'s "upper neck": CMU ASF ``upperneck``, cgspeed BVH
#:   ``Neck1``/``Neck``, Daz ``neck``, Kinect ``ShoulderCenter``/``SpineShoulder``, else
#:   the head);
#: * ``upper_arm`` -- side-stripped names of the shoulder joint at the top of the upper arm
#:   (retrieval key points), tried in order, exact name first, then contained (cgspeed
#:   ``LeftArm``, Daz ``lShldr``).
#:
#: Left/right partners (:func:`mocapkit.frames.mirror_permutation`) are names equal after
#: :func:`strip_side`.
JOINT_ALIASES: dict[str, tuple[str, ...]] = {
    # thigh joints: lfemur/rfemur (CMU ASF), LeftUpLeg/RightUpLeg (cgspeed BVH), lThigh/rThigh
    # (Daz BVH), HipLeft/HipRight (Kinect); lhipjoint/rhipjoint are the hip centres in ASF
    # marker sets: LASI/RASI (Plug-in Gait and most lab sets: the anterior superior iliac
    # spines), L_IAS/R_IAS (Qualisys' sports marker set)
    "hip": ("hipjoint", "upleg", "femur", "thigh", "hip", "asi", "ias"),
    "shoulder": ("clavicle", "collar", "shoulder", "shldr", "humerus", "upperarm", "arm"),
    # marker sets, last: C7 (Plug-in Gait), CV7 (Qualisys), CLAV (the clavicle notch)
    "neck": ("upperneck", "neck1", "neck", "neck2", "shouldercenter", "spineshoulder", "head", "c7", "cv7",
             "clav"),
    "upper_arm": ("arm", "shldr", "shoulder", "clavicle"),
}


def strip_side(name: str) -> str:
    """Joint name without its left/right marker (lowercase): 'lfemur' -> 'femur',
    'LeftUpLeg' -> 'upleg', 'HipLeft' -> 'hip', 'l_knee' -> 'knee', 'Subject:LASI' ->
    'asi' (a namespace prefix goes with the side when the bare name has one)."""
    if ":" in name and _side(bare_name(name)) is not None:
        name = bare_name(name)
    low = name.strip().lower()
    for pre in ("left", "right"):
        if low.startswith(pre):
            return low[len(pre):].lstrip("_. ")
        if low.endswith(pre):
            return low[:-len(pre)].rstrip("_. ")
    m = re.match(r"^[lr][_\.\s](.+)$", low) or re.match(r"^(.+)[_\.\s][lr]$", low)
    if m:
        return m.group(1)
    return low[1:] if low[:1] in ("l", "r") else low


def _limb(name: str) -> str | None:
    low = re.sub(r"left|right", "", name.lower())
    if low in MIDLINE_ROOTS and low == name.lower():   # 'HipLeft'/'LeftHip' keep their side: a leg joint
        return None
    if any(w in low for w in _LEG_WORDS if w not in ("hip",)) or low.endswith("hip") or low.startswith(("hip", "lhip", "rhip")):
        # 'hip' alone counts only with a side (HipLeft, lhipjoint, LHip)
        return "leg"
    if any(w in low for w in _ARM_WORDS):
        return "arm"
    return None


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A kinematic tree.

    Attributes
    ----------
    names : joint names, unique, length J.
    parents : int array (J,), parent index of each joint, -1 for the root(s); a parent
        always comes before its children.
    offsets : float array (J, 3), rest offset of each joint from its parent in cm
        (the root's is its rest position).
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    _index: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        names = tuple(str(n) for n in self.names)
        parents = np.asarray(self.parents, dtype=np.int64).reshape(-1)
        offsets = np.asarray(self.offsets, dtype=np.float64)
        J = len(names)
        if J == 0:
            raise MocapValueError("a skeleton needs at least one joint")
        if len(set(names)) != J:
            dup = sorted({n for n in names if names.count(n) > 1})
            raise MocapValueError(f"duplicate joint names: {dup}")
        if parents.shape != (J,):
            raise MocapValueError(f"parents must have one entry per joint ({J}), got {parents.shape}")
        if offsets.shape != (J, 3):
            raise MocapValueError(f"offsets must have shape ({J}, 3), got {offsets.shape}")
        for j, p in enumerate(parents):
            if p >= j or p < -1:
                raise MocapValueError(
                    f"joint {names[j]!r}: parent index {p} must be -1 or an earlier joint")
        parents.setflags(write=False)
        offsets = offsets.copy()
        offsets.setflags(write=False)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "parents", parents)
        object.__setattr__(self, "offsets", offsets)
        object.__setattr__(self, "_index", {n: i for i, n in enumerate(names)})

    # -- basic queries -------------------------------------------------------------
    @property
    def is_flat(self) -> bool:
        """No joint has a parent: a marker set (C3D, TRC), not a skeleton's joint centres."""
        return not bool((self.parents >= 0).any())

    @property
    def n_joints(self) -> int:
        return len(self.names)

    def __len__(self) -> int:
        return len(self.names)

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, Skeleton) and self.names == other.names
                and np.array_equal(self.parents, other.parents)
                and np.allclose(self.offsets, other.offsets))

    def __hash__(self) -> int:
        return hash((self.names, tuple(self.parents.tolist())))

    def index(self, name: str) -> int:
        """Index of joint ``name``; raises MocapValueError naming the known joints."""
        try:
            return self._index[name]
        except KeyError:
            raise MocapValueError(
                f"unknown joint {name!r}; this skeleton has: {', '.join(self.names)}") from None

    def indices(self, names: Iterable[str]) -> list[int]:
        return [self.index(n) for n in names]

    def bones(self) -> list[tuple[int, int]]:
        """(child, parent) index pairs, one per non-root joint."""
        return [(j, int(p)) for j, p in enumerate(self.parents) if p >= 0]

    def bone_lengths(self) -> np.ndarray:
        """Rest bone lengths in cm, one per :meth:`bones` entry."""
        return np.array([np.linalg.norm(self.offsets[c]) for c, _ in self.bones()])

    def depths(self) -> np.ndarray:
        """Depth of each joint in the tree (J,) int: 0 for a root, parent's depth + 1."""
        d = np.zeros(self.n_joints, dtype=int)
        for j, p in enumerate(self.parents):
            d[j] = d[p] + 1 if p >= 0 else 0
        return d

    def children(self, j: int) -> list[int]:
        return [int(c) for c in np.flatnonzero(self.parents == j)]

    def rest_positions(self) -> np.ndarray:
        """Rest-pose joint positions (J, 3) in cm: offsets accumulated down the tree."""
        P = np.zeros((self.n_joints, 3))
        for j, p in enumerate(self.parents):
            P[j] = self.offsets[j] + (P[p] if p >= 0 else 0.0)
        return P

    # -- body parts ----------------------------------------------------------------
    def body_parts(self) -> dict[str, list[int]]:
        """The five poselets by joint name: torso, left/right arm, left/right leg.

        A limb contains every joint classified to it from its name plus the joint it
        hangs from (e.g. thorax for an arm, root for a leg), so neighbouring parts share
        one joint, as in Xiao et al. 2015 (shared joints are averaged by the caller).
        Joints that belong to no limb form the torso.
        """
        label: list[str] = []
        for n in self.names:
            limb, side = _limb(n), _side(n)
            label.append(f"{side}_{limb}" if (limb and side) else "torso")
        # a joint whose parent is on a limb of the same side inherits it (e.g. 'LThumb'
        # is found by keyword anyway; 'lfingers' too; this catches odd names)
        for j, p in enumerate(self.parents):
            if p >= 0 and label[j] == "torso" and label[p] != "torso" and _side(self.names[j]) in (None, label[p].split("_")[0]):
                label[j] = label[p]
        parts: dict[str, list[int]] = {k: [] for k in BODY_PARTS}
        for j, lab in enumerate(label):
            parts[lab].append(j)
        for part in BODY_PARTS[1:]:
            members = parts[part]
            if not members:
                continue
            first = min(members)
            attach = int(self.parents[first])
            if attach >= 0 and attach not in members:
                members.insert(0, attach)
            parts[part] = sorted(members)
        return parts

    # -- derived skeletons -------------------------------------------------------------
    def subset(self, names: Sequence[str]) -> "Skeleton":
        """Skeleton on a subset of joints (kept in this skeleton's order).

        Each kept joint is re-parented to its nearest kept ancestor; its rest offset is
        the sum of the offsets along the removed chain.
        """
        keep = sorted(set(self.indices(names)))
        new_index = {old: i for i, old in enumerate(keep)}
        rest = self.rest_positions()
        parents, offsets = [], []
        for old in keep:
            p = int(self.parents[old])
            while p >= 0 and p not in new_index:
                p = int(self.parents[p])
            parents.append(new_index[p] if p >= 0 else -1)
            offsets.append(rest[old] - rest[p] if p >= 0 else rest[old])
        return Skeleton(tuple(self.names[i] for i in keep), np.array(parents), np.array(offsets))

    def scaled(self, factor: float) -> "Skeleton":
        return Skeleton(self.names, self.parents, self.offsets * factor)

    @classmethod
    def from_positions(cls, names: Sequence[str], parents: Sequence[int], positions: np.ndarray) -> "Skeleton":
        """Build a skeleton whose rest offsets are taken from one pose (J, 3) in cm."""
        P = np.asarray(positions, dtype=float)
        par = np.asarray(parents)
        off = np.where(par[:, None] >= 0, P - P[np.maximum(par, 0)], P)
        return cls(tuple(names), par, off)
