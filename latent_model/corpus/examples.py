"""Example deformations outside the pose vocabulary: an evaluation set for transfer from an example pair.

Each example is a deformation the rig makes but no pose name covers: amplitudes the vocabulary does
not have, combinations that are not among its combos, and motions of joints or axes no pose uses.
An example pair is (neutral, deformed) of one held-out identity; the same deformation of the other
held-out identities is the truth a transfer of that pair is judged against. Everything is generated
from identity specs through the rig (no corpus needed), reproducibly.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from latent_model.corpus.poses import JointRotation, PoseConfig, get_pose
from latent_model.corpus.rests import get_rest
from latent_model.errors import look_up
from latent_model.types import FINAL


@dataclass(frozen=True)
class ExampleDeformation:
    name: str
    kind: str  # "amplitude" | "combination" | "new motion"
    description: str
    joints: tuple[JointRotation, ...] = ()  # rotations from the bind pose, left side as the vocabulary
    poses: tuple[str, ...] = ()  # vocabulary poses combined (their joints are added to `joints`)

    @property
    def pose(self) -> PoseConfig:
        """The deformation as a (nameless to the vocabulary) pose config."""
        joints = tuple(j for p in self.poses for j in get_pose(p).joints) + self.joints
        return PoseConfig(f"example:{self.name}", "body", joints=joints)


def _amp(name: str, bone: str, axis: str, degrees: float, what: str) -> ExampleDeformation:
    return ExampleDeformation(name, "amplitude", what, (JointRotation(bone, axis, degrees),))


EXAMPLES: dict[str, ExampleDeformation] = {e.name: e for e in (
    _amp("elbow25Lf", "lowerarm01.L", "hinge", 25.0, "elbow bent 25 degrees (vocabulary: 47, 97)"),
    _amp("elbow70Lf", "lowerarm01.L", "hinge", 70.0, "elbow bent 70 degrees"),
    _amp("shoulderRaise25Lf", "upperarm01.L", "-y", 25.0, "upper arm raised 25 degrees (vocabulary: 50)"),
    _amp("shoulderRaise75Lf", "upperarm01.L", "-y", 75.0, "upper arm raised 75 degrees"),
    _amp("knee40Lf", "lowerleg01.L", "+x", 40.0, "knee bent 40 degrees (vocabulary: 80)"),
    _amp("knee110Lf", "lowerleg01.L", "+x", 110.0, "knee bent 110 degrees"),
    ExampleDeformation("elbowLf+shoulderFwdRt+neckLf", "combination", "three joints at once: elbowBentLf + "
                       "shoulderForwardRt + neckTurnLf", poses=("elbowBentLf", "shoulderForwardRt", "neckTurnLf")),
    ExampleDeformation("kneeRt+hipLf+clavicleLf", "combination", "kneeBentRt + hipFlexLf + clavicleDownwardLf",
                       poses=("kneeBentRt", "hipFlexLf", "clavicleDownwardLf")),
    ExampleDeformation("wristTwistLf", "new motion", "the hand twisted 60 degrees about the forearm",
                       (JointRotation("wrist.L", "along", 60.0),)),
    ExampleDeformation("ankleFlexLf", "new motion", "the foot flexed 30 degrees about the lateral axis",
                       (JointRotation("foot.L", "-x", 30.0),)),
    ExampleDeformation("spineSideBendLf", "new motion", "the spine bent 20 degrees to the character's left",
                       (JointRotation("spine03", "+y", 10.0), JointRotation("spine01", "+y", 10.0))),
)}


def get_example(name: str) -> ExampleDeformation:
    """The example deformation called `name`; unknown names raise with the valid ones."""
    return look_up(EXAMPLES, name, "example deformation")


@dataclass
class ExamplePair:
    """One example deformation made on `source` (the pair a user would bring) and on the `targets`
    (their truth). Vertices (V, 3) float32, all in one rest configuration."""

    example: ExampleDeformation
    rest: str
    source: str
    source_neutral: np.ndarray
    source_deformed: np.ndarray
    targets: dict[str, tuple[np.ndarray, np.ndarray]]  # identity -> (neutral, deformed truth)


def example_pair(generator, specs: list, example: str, rest: str = "bind") -> ExamplePair:
    """The example `example` on the first spec (the example pair) and on every other spec (the truth
    of its transfer), in rest configuration `rest`."""
    ex, _ = get_example(example), get_rest(rest)
    if len(specs) < 2:
        raise ValueError("an example pair needs a source identity and at least one target identity")

    def made(spec) -> tuple[np.ndarray, np.ndarray]:
        return (generator.neutral(spec, rest).astype(np.float32),
                getattr(generator.pose(spec, ex.pose, rest), FINAL).astype(np.float32))

    src = made(specs[0])
    return ExamplePair(ex, rest, specs[0].id, src[0], src[1], {s.id: made(s) for s in specs[1:]})
