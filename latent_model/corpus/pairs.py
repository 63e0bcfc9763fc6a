"""Source -> target pairs of the paper's four kinds, with exact definitions.

For an identity i, a pose config p and its variants (see states.py):
- ``neutral_to_pose``: (i, neutral) -> (i, p, skinning_plus_blendshape), every pose p (single
  or combined): the whole rig output from the rest shape.
- ``skinning_to_skinning_plus_blendshape``: (i, p, skinning) -> (i, p, skinning_plus_blendshape),
  poses with a skeletal part: the pose-space correctives (+ facial part) on top of skinning.
- ``blendshape_to_skinning_plus_blendshape``: (i, p, blendshape) -> (i, p, skinning_plus_blendshape),
  poses with a skeletal part: the skeletal motion on top of the shapes.
- ``source_to_combo``: (i, a, skinning_plus_blendshape) -> (i, c, skinning_plus_blendshape) for
  every combined pose c and each of its components a: adding the other components.
Face-only poses have no skinning/blendshape pairs: their source would equal the neutral or
the target (identical geometry), so those pairs would duplicate neutral_to_pose or be empty.
"""
from __future__ import annotations

from dataclasses import dataclass

from latent_model.corpus.poses import get_pose

PAIR_KINDS = (
    "neutral_to_pose",
    "skinning_to_skinning_plus_blendshape",
    "blendshape_to_skinning_plus_blendshape",
    "source_to_combo",
)
FINAL = "skinning_plus_blendshape"


@dataclass(frozen=True)
class Pair:
    kind: str
    identity: int
    pose: str  # the target pose config
    source: tuple[str | None, str]  # (pose or None for neutral, variant)
    target: tuple[str, str]


def pairs_for_identity(identity: int, poses: tuple[str, ...], kinds: tuple[str, ...] = PAIR_KINDS) -> list[Pair]:
    unknown = [k for k in kinds if k not in PAIR_KINDS]
    if unknown:
        raise ValueError(f"unknown pair kind(s) {unknown}; valid: {', '.join(PAIR_KINDS)}")
    out: list[Pair] = []
    available = set(poses)
    for name in poses:
        p = get_pose(name)
        if "neutral_to_pose" in kinds:
            out.append(Pair("neutral_to_pose", identity, name, (None, "neutral"), (name, FINAL)))
        if p.has_skeletal:
            if "skinning_to_skinning_plus_blendshape" in kinds:
                out.append(Pair("skinning_to_skinning_plus_blendshape", identity, name, (name, "skinning"), (name, FINAL)))
            if "blendshape_to_skinning_plus_blendshape" in kinds:
                out.append(Pair("blendshape_to_skinning_plus_blendshape", identity, name, (name, "blendshape"), (name, FINAL)))
        if p.is_combo and "source_to_combo" in kinds:
            for comp in dict.fromkeys(p.components):
                if comp in available:
                    out.append(Pair("source_to_combo", identity, name, (comp, FINAL), (name, FINAL)))
    return out


def enumerate_pairs(identities: list[int], poses: tuple[str, ...], kinds: tuple[str, ...] = PAIR_KINDS) -> list[Pair]:
    """All pairs of the given kinds for the identities (e.g. a split's indices)."""
    return [pair for i in identities for pair in pairs_for_identity(i, poses, kinds)]
