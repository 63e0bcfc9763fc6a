"""The semantic pose vocabulary: one table, in the paper's naming style.

A pose config has a skeletal part (joint rotations relative to the *bind* pose) and a
blendshape part (Face Units weights, optionally masked to one side of the face). Every
left-side ("Lf") pose has a right-side ("Rt") mirror generated from it, so the two are
true mirrors by construction (see `rig.resolve_axis` for how axes mirror).

Axis rules (resolved per identity from its own rest skeleton, see `rig.py`):
- ``"hinge"``: flexion axis of the joint, cross(parent segment, child segment); positive
  angles bend the joint further in the direction it is already bent (elbow). Not for the
  knee: its ~10 deg bind-pose flexion is of the order of a knock-knee or bow-leg angle, so
  the cross product swung up to 64 deg out of the lateral axis from identity to identity
  (standard corpus: median 14 deg; feet moved up to 42 cm sideways, 2 of 14 held-out legs bent
  mostly sideways). The knee flexes about the fixed lateral axis instead.
- ``"along"``: the parent segment (a twist about it, e.g. the hand about the forearm).
- ``"palm"``: the hand's flexion axis (across the knuckles, index to pinky), oriented so
  positive angles curl the fingers toward the palm.
- ``"+x" "-x" "+y" "-y" "+z" "-z"``: fixed axes of the rest frame (Z up, faces -Y, +X =
  character's left), stated for the left side; the right side uses the mirrored axis.
"""
from __future__ import annotations

from dataclasses import dataclass

from latent_model.errors import look_up
from latent_model.types import PoseGroup

SIDES = ("Lf", "Rt")


@dataclass(frozen=True)
class JointRotation:
    """Rotate `bone` (and its descendants) about its rest head by `degrees` about `axis`."""

    bone: str  # anny bone label, with ".L"/".R" for sided bones
    axis: str  # an axis rule (module docstring)
    degrees: float
    mirrored: bool = False  # a right-side mirror: fixed axes are reflected across X


@dataclass(frozen=True)
class FaceWeight:
    """A Face Units blendshape at `weight`; `side` masks a symmetric unit to one half."""

    unit: str  # anny facial action label, e.g. "browDownLeft"
    weight: float = 1.0
    side: str | None = None  # "L" | "R" | None (whole face)


@dataclass(frozen=True)
class PoseConfig:
    name: str
    group: PoseGroup
    joints: tuple[JointRotation, ...] = ()
    face: tuple[FaceWeight, ...] = ()
    components: tuple[str, ...] = ()  # for combined poses: the single poses combined

    @property
    def is_combo(self) -> bool:
        return bool(self.components)

    @property
    def has_skeletal(self) -> bool:
        return bool(self.joints)


# ----------------------------------------------------------------------------- singles
# Left-side definitions; Rt mirrors are derived. Angles are added to the bind pose, which
# already has ~43 deg elbow and ~10 deg knee flexion (elbow +47 -> 90 deg, +97 -> 140 deg).
_BODY_LEFT: dict[str, tuple[JointRotation, ...]] = {
    "elbowBent": (JointRotation("lowerarm01.L", "hinge", 47.0),),
    "elbowSuperBent": (JointRotation("lowerarm01.L", "hinge", 97.0),),
    "kneeBent": (JointRotation("lowerleg01.L", "+x", 80.0),),  # shank backwards; Rt mirrors to +x too
    "clavicleDownward": (JointRotation("clavicle.L", "+y", 20.0),),
    "shoulderRaise": (JointRotation("upperarm01.L", "-y", 50.0),),
    "shoulderForward": (JointRotation("upperarm01.L", "-x", 60.0),),
    "hipFlex": (JointRotation("upperleg01.L", "-x", 55.0),),
    "wristFlex": (JointRotation("wrist.L", "palm", 50.0),),
    "spineTwist": (JointRotation("spine03", "+z", 15.0), JointRotation("spine01", "+z", 15.0)),
    "neckTurn": (JointRotation("neck01", "+z", 25.0), JointRotation("neck03", "+z", 20.0)),
}
_BODY_CENTRE: dict[str, tuple[JointRotation, ...]] = {
    "spineBendFw": (JointRotation("spine03", "+x", 15.0), JointRotation("spine01", "+x", 15.0)),
    "neckBendFw": (JointRotation("neck01", "+x", 20.0), JointRotation("neck03", "+x", 15.0)),
}
# Finger knuckles: A..D = index..pinky (anny finger2..finger5), 01..03 = joint level.
_FINGER_LETTERS = {"A": 2, "B": 3, "C": 4, "D": 5}
_KNUCKLE_DEGREES = {1: 70.0, 2: 85.0, 3: 60.0}

# Face: (unit for the Lf pose, unit for the Rt pose, weight, masked?) — masked units are
# symmetric Face Units restricted to one side with a smooth mask.
_FACE_SIDED: dict[str, tuple[str, str, float, bool]] = {
    "browDw": ("browDownLeft", "browDownRight", 1.0, False),
    "browUp": ("browOuterUpLeft", "browOuterUpRight", 1.0, False),
    "blink": ("eyeBlinkLeft", "eyeBlinkRight", 1.0, False),
    "puff": ("cheekPuff", "cheekPuff", 1.0, True),
    "cornerUp": ("mouthSmileLeft", "mouthSmileRight", 1.0, False),
    "cornerPucker": ("mouthPucker", "mouthPucker", 1.0, True),
    "cornerStretch": ("mouthStretchLeft", "mouthStretchRight", 1.0, False),
}
_FACE_CENTRE: dict[str, tuple[FaceWeight, ...]] = {
    "jawOpen": (FaceWeight("jawOpen", 1.0),),
}

# Combined poses, by their components (single pose names).
_COMBOS: tuple[tuple[str, ...], ...] = (
    ("browDwLf", "browDwRt"),
    ("browUpLf", "browUpRt"),
    ("blinkLf", "blinkRt"),
    ("puffLf", "puffRt"),
    ("cornerUpLf", "cornerUpRt"),
    ("cornerPuckerLf", "cornerPuckerRt"),
    ("cornerStretchLf", "cornerStretchRt"),
    ("jawOpen", "cornerUpLf", "cornerUpRt"),
    ("elbowBentLf", "kneeBentLf"),
    ("elbowBentRt", "kneeBentRt"),
    ("elbowBentLf", "kneeBentRt"),
    ("elbowBentLf", "elbowBentRt"),
    ("kneeBentLf", "kneeBentRt"),
    ("shoulderRaiseLf", "elbowBentLf"),
    ("hipFlexLf", "kneeBentLf"),
    ("clavicleDownwardLf", "shoulderForwardLf"),
    ("neckTurnLf", "jawOpen"),
)
_FISTS = ("fistLf", "fistRt")  # all twelve knuckles of one hand


def _mirror_bone(bone: str) -> str:
    if bone.endswith(".L"):
        return bone[:-2] + ".R"
    if bone.endswith(".R"):
        return bone[:-2] + ".L"
    return bone


def mirror_joints(joints: tuple[JointRotation, ...]) -> tuple[JointRotation, ...]:
    """The right-side mirror of left-side rotations: the same axis rule and angle on the mirrored
    bone; `rig.resolve_axis` mirrors the axis."""
    return tuple(JointRotation(_mirror_bone(j.bone), j.axis, j.degrees, True) for j in joints)


def _sided(name: str, joints: tuple[JointRotation, ...], side: str) -> tuple[str, tuple[JointRotation, ...]]:
    return (name + "Lf", joints) if side == "Lf" else (name + "Rt", mirror_joints(joints))


def _build_table() -> dict[str, PoseConfig]:
    table: dict[str, PoseConfig] = {}

    def add(p: PoseConfig) -> None:
        if p.name in table:
            raise AssertionError(f"duplicate pose name {p.name}")
        table[p.name] = p

    for base, joints in _BODY_LEFT.items():
        for side in SIDES:
            name, js = _sided(base, joints, side)
            add(PoseConfig(name, "body", joints=js))
    for name, joints in _BODY_CENTRE.items():
        add(PoseConfig(name, "body", joints=joints))
    for letter, finger in _FINGER_LETTERS.items():
        for level, deg in _KNUCKLE_DEGREES.items():
            left = (JointRotation(f"finger{finger}-{level}.L", "palm", deg),)
            for side in SIDES:
                name, js = _sided(f"fingerKnuckle{letter}{level:02d}", left, side)
                add(PoseConfig(name, "finger", joints=js))
    for base, (unit_l, unit_r, w, masked) in _FACE_SIDED.items():
        add(PoseConfig(base + "Lf", "face", face=(FaceWeight(unit_l, w, "L" if masked else None),)))
        add(PoseConfig(base + "Rt", "face", face=(FaceWeight(unit_r, w, "R" if masked else None),)))
    for name, face in _FACE_CENTRE.items():
        add(PoseConfig(name, "face", face=face))

    singles = dict(table)

    def combo(name: str, components: tuple[str, ...]) -> PoseConfig:
        joints: list[JointRotation] = []
        face: list[FaceWeight] = []
        for c in components:
            joints.extend(singles[c].joints)
            face.extend(singles[c].face)
        groups = {singles[c].group for c in components}
        group = groups.pop() if len(groups) == 1 else "mixed"
        return PoseConfig(name, group, joints=tuple(joints), face=tuple(face), components=components)

    for comps in _COMBOS:
        add(combo("+".join(comps), comps))
    for fist in _FISTS:
        side = fist[-2:]
        comps = tuple(f"fingerKnuckle{l}{lv:02d}{side}" for l in _FINGER_LETTERS for lv in _KNUCKLE_DEGREES)
        add(combo(fist, comps))
    # A combo of a single pose and a combo: components are single poses only.
    fist_lf = table["fistLf"]
    add(PoseConfig("elbowBentLf+fistLf", "body",
                   joints=singles["elbowBentLf"].joints + fist_lf.joints,
                   components=("elbowBentLf",) + fist_lf.components))
    return table


POSES: dict[str, PoseConfig] = _build_table()
SINGLE_POSES: tuple[str, ...] = tuple(n for n, p in POSES.items() if not p.is_combo)
COMBO_POSES: tuple[str, ...] = tuple(n for n, p in POSES.items() if p.is_combo)
PAPER_POSES: tuple[str, ...] = (
    "elbowBentLf", "elbowSuperBentLf", "kneeBentLf", "clavicleDownwardLf",
    "fingerKnuckleD03Lf", "fingerKnuckleD02Lf", "browDwLf", "browDwRt", "puffLf",
    "cornerUpLf", "cornerPuckerLf", "cornerStretchLf", "jawOpen",
)


def get_pose(name: str) -> PoseConfig:
    """The pose config called `name`; unknown names raise with the list of valid ones."""
    return look_up(POSES, name, "pose")


def mirror_pose(name: str) -> str | None:
    """The other side's single pose of a sided single pose ("elbowBentLf" -> "elbowBentRt"), else None."""
    for a, b in (("Lf", "Rt"), ("Rt", "Lf")):
        if name.endswith(a) and "+" not in name and name[:-2] + b in POSES:
            return name[:-2] + b
    return None


def pose_line(p: PoseConfig) -> str:
    """One human-readable line: name, single/combo, skeletal and blendshape parts."""
    kind = "combo" if p.is_combo else "single"
    skel = ", ".join(f"{j.bone}:{j.axis}:{j.degrees:+.0f}" for j in p.joints) or "-"
    face = ", ".join(f"{f.unit}{'[' + f.side + ']' if f.side else ''}:{f.weight:g}" for f in p.face) or "-"
    return f"{p.name:40s} {kind:6s} {p.group:6s} skeletal[{skel}] blendshape[{face}]"
