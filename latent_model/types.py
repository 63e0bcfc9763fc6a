"""Every named choice of the project as a `Literal` alias, in one module (as anny's `typing.py`),
with the tuple of its values and the one check that turns a bad value into a clear message.

Slider bounds live here too: the Transfer API, `lrr predict` and the explorer check them through
`check_magnitude` / `check_blend`, so the three agree.
"""
from __future__ import annotations

from typing import Literal, get_args

PresetName = Literal[
    "tiny",  # a few identities and poses: the tests (seconds)
    "standard",  # the shipped model, sized for a 2-core CPU
    "paper",  # the shipped design at the paper's sizes (a GPU)
]
Variant = Literal[
    "neutral",  # the identity's rest shape
    "skinning",  # LBS of the rest shape: the skeletal part only
    "blendshape",  # rest + facial + corrective offsets, no bones
    "skinning_plus_blendshape",  # LBS of (rest + offsets): the final rig output
]
PairKind = Literal[
    "neutral_to_pose",  # neutral -> final state, every pose
    "skinning_to_skinning_plus_blendshape",  # the correctives (+ facial part) on top of skinning
    "blendshape_to_skinning_plus_blendshape",  # the skeletal motion on top of the shapes
    "source_to_combo",  # a component's final state -> the combined pose's final state
]
BaseStrategy = Literal[
    "mean_pose_delta",  # the pose's delta averaged over the training identities
    "nearest_identity_delta",  # the delta of the training identity nearest to the mesh in latent space
    "oracle",  # the target's own delta (analysis only: needs the true posed latent)
]
# A strategy is a BaseStrategy or "identity:<id>" (a chosen training identity's delta).
Strategy = str
Predictor = Literal[
    "correctives",  # the corrective fields (corrective_fields.py): skinning -> skinning+blendshape
    "pose_fields",  # the closed-form pose fields alone (nn/pose_fields.py)
    "network",  # the vertex decoder network (nn/vertex_decoder.py), which reads the fields too
    "motion",  # the motion decoder (nn/motion_decoder.py): a per-vertex rigid motion in the limb's frame
]
PoseGroup = Literal["body", "finger", "face", "mixed"]
ColourBy = Literal["error", "displacement"]  # what colours the explorer's prediction view
UpAxis = Literal["auto", "y", "z"]
Units = Literal["auto", "m", "cm", "mm"]
Facing = Literal["auto", "+x", "-x", "+y", "-y", "+z", "-z"]  # the file axis a character faces

PRESETS: tuple[str, ...] = get_args(PresetName)
VARIANTS: tuple[str, ...] = get_args(Variant)
FINAL: Variant = "skinning_plus_blendshape"
PAIR_KINDS: tuple[str, ...] = get_args(PairKind)
BASE_STRATEGIES: tuple[str, ...] = get_args(BaseStrategy)
STRATEGY_ALIASES = {"mean": "mean_pose_delta", "nearest": "nearest_identity_delta"}
COLOURS: tuple[str, ...] = get_args(ColourBy)

MAGNITUDE_RANGE = (0.0, 2.0)  # scale of the delta's magnitude r: 0 = no motion, 1 = as conditioned
BLEND_RANGE = (0.0, 1.0)  # 0 = pose A, 1 = pose B


def check_choice(what: str, value: str, valid: tuple[str, ...]) -> str:
    """`value` if it is one of `valid`, else ValueError naming `what` and the valid values."""
    if value not in valid:
        raise ValueError(f"unknown {what} {value!r}; valid: {', '.join(valid)}")
    return value


def check_pair_kind(kind: str) -> PairKind:
    return check_choice("pair kind", kind, PAIR_KINDS)  # type: ignore[return-value]


def parse_strategy(text: str) -> Strategy:
    """A strategy name or alias (mean, nearest) -> its canonical form; ValueError otherwise."""
    s = STRATEGY_ALIASES.get(text, text)
    if s in BASE_STRATEGIES or (s.startswith("identity:") and len(s) > len("identity:")):
        return s
    raise ValueError(f"unknown strategy {text!r}; valid: mean_pose_delta (mean), nearest_identity_delta (nearest), "
                     f"identity:<id>, oracle")


def _check_range(what: str, value: float, bounds: tuple[float, float]) -> float:
    lo, hi = bounds
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number in [{lo:g}, {hi:g}], got {value!r}") from None
    if not lo <= x <= hi:  # also false for NaN
        raise ValueError(f"{what} must lie in [{lo:g}, {hi:g}], got {value}")
    return x


def check_magnitude(value: float) -> float:
    """The magnitude slider's value (scales r; 1 = as conditioned) as a float in MAGNITUDE_RANGE."""
    return _check_range("magnitude", value, MAGNITUDE_RANGE)


def check_blend(value: float) -> float:
    """The pose-blend slider's value as a float in BLEND_RANGE."""
    return _check_range("blend", value, BLEND_RANGE)
