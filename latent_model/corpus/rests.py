"""Rest configurations: the poses a character may stand in as its "neutral" (arms at the sides, A, T…).

A rest configuration is a set of joint rotations from anny's bind pose, given by four angles
(degrees, added to the bind pose, the same on both sides):
- ``arms``: both upper arms about the forward axis: + raises them toward a T-pose (about +45), -
  lowers them toward hanging at the sides (about -40);
- ``elbows``: both elbows about their bind-pose hinge: - straightens them (the bind pose has ~43
  degrees of flexion, so -43 is straight);
- ``legs``: both hips about the forward axis: + apart, - together;
- ``spine``: the spine about the lateral axis: + bent forward, - upright.
A pose is applied on top of a rest configuration, as a rig does (`Rig.bone_transforms(..., base=)`):
elbowBentLf on a T-pose character flexes its elbow 47 degrees from where the rest has it.

``split`` says who stands in it: ``train`` configurations are seen in training (the bind one too),
``val`` ones only by the validation identities (design choices are judged on rests no training state
uses without looking at the test ones), ``test`` ones only by the held-out identities.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from latent_model.corpus.poses import JointRotation, mirror_joints
from latent_model.errors import look_up

RestSplit = Literal["train", "val", "test"]


@dataclass(frozen=True)
class RestConfig:
    name: str
    arms: float = 0.0
    elbows: float = 0.0
    legs: float = 0.0
    spine: float = 0.0
    split: RestSplit = "train"

    @property
    def joints(self) -> tuple[JointRotation, ...]:
        """The rotations from the bind pose, left side first, then its mirror, then the spine."""
        left = []
        if self.arms:
            left.append(JointRotation("upperarm01.L", "-y", self.arms))
        if self.elbows:
            left.append(JointRotation("lowerarm01.L", "hinge", self.elbows))
        if self.legs:
            left.append(JointRotation("upperleg01.L", "-y", self.legs))
        centre = [JointRotation(b, "+x", self.spine / 2) for b in ("spine03", "spine01")] if self.spine else []
        return tuple(left) + mirror_joints(tuple(left)) + tuple(centre)

    @property
    def is_bind(self) -> bool:
        return not self.joints

    def line(self) -> str:
        """One line for `lrr corpus info`: name, split and the four angles."""
        return (f"{self.name:12s} {self.split:5s} arms {self.arms:+5.0f}  elbows {self.elbows:+5.0f}  "
                f"legs {self.legs:+4.0f}  spine {self.spine:+4.0f}")


BIND = RestConfig("bind")
REST_CONFIGS: dict[str, RestConfig] = {r.name: r for r in (
    BIND,
    RestConfig("armsDown", arms=-40.0, elbows=-30.0),  # hanging at the sides, elbows nearly straight
    RestConfig("armsLow", arms=-15.0, legs=-5.0),
    RestConfig("armsHigh", arms=15.0, legs=6.0),
    RestConfig("armsWide", arms=38.0, elbows=-38.0, legs=4.0),  # close to a T, not quite
    RestConfig("stoop", arms=-8.0, spine=8.0, legs=10.0),  # legs apart, bent a little forward
    RestConfig("upright", arms=-25.0, elbows=-15.0, spine=-5.0),
    # validation only: unseen in training, and not the test rests either
    RestConfig("armsSides", arms=-35.0, elbows=-10.0, split="val"),
    RestConfig("armsUp35", arms=35.0, elbows=-30.0, legs=3.0, split="val"),
    # held out: no training or validation state stands like these
    RestConfig("armsDown30", arms=-30.0, split="test"),
    RestConfig("armsUp25", arms=25.0, elbows=-20.0, split="test"),
    RestConfig("tpose", arms=45.0, elbows=-43.0, legs=5.0, split="test"),  # a DCC T-pose: arms level and straight
)}
TRAIN_RESTS: tuple[str, ...] = tuple(n for n, r in REST_CONFIGS.items() if r.split == "train")
VAL_RESTS: tuple[str, ...] = tuple(n for n, r in REST_CONFIGS.items() if r.split == "val")
TEST_RESTS: tuple[str, ...] = tuple(n for n, r in REST_CONFIGS.items() if r.split == "test")


def get_rest(name: str) -> RestConfig:
    """The rest configuration called `name`; unknown names raise with the valid ones."""
    return look_up(REST_CONFIGS, name, "rest configuration")
