"""Source -> target pairs of the paper's four kinds: the one definition (`pair_states`).

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

A source_to_combo pair is named by its combo *and* component: the latent bank keys it
``combo<component>`` (`bank_key`, `split_bank_key`).
"""
from __future__ import annotations

from dataclasses import dataclass

from latent_model.corpus.poses import get_pose
from latent_model.types import FINAL, PAIR_KINDS, PairKind, check_pair_kind


StateRef = tuple  # (pose name or None for the neutral, variant)


def pair_states(kind: PairKind, pose: str, source_pose: str | None = None) -> tuple[StateRef, StateRef]:
    """((source pose or None, variant), (target pose, variant)) of a pair kind.
    `source_pose` names the component for `source_to_combo` (default: the combo's first one).
    A pose the kind does not apply to raises ValueError saying which kind to use."""
    check_pair_kind(kind)
    p = get_pose(pose)
    if kind == "neutral_to_pose":
        return (None, "neutral"), (pose, FINAL)
    if kind in ("skinning_to_skinning_plus_blendshape", "blendshape_to_skinning_plus_blendshape"):
        if not p.has_skeletal:
            raise ValueError(f"pose {pose!r} has no skeletal part, so it has no {kind} pair; use neutral_to_pose")
        return (pose, kind.split("_to_")[0]), (pose, FINAL)
    if not p.is_combo:
        raise ValueError(f"pose {pose!r} is not a combined pose, so it has no source_to_combo pair")
    comp = source_pose or p.components[0]
    if comp not in p.components:
        raise ValueError(f"{comp!r} is not a component of {pose!r}; components: {', '.join(p.components)}")
    return (comp, FINAL), (pose, FINAL)


def source_state_label(kind: PairKind, pose: str, source_pose: str | None = None) -> str:
    """In words, the state a pair kind's source is in: what a user's mesh is taken to be when it is the source."""
    (src, variant), _ = pair_states(kind, pose, source_pose)
    if variant == "neutral":
        return "a neutral"
    if variant == "skinning":
        return f"skinned in {pose} (no correctives)"
    if variant == "blendshape":
        return f"unposed, with {pose}'s correctives"
    return f"posed in {src}"


def bank_key(kind: PairKind, pose: str, component: str | None = None) -> str:
    """The latent bank's key of a pair: the pose, or ``combo<component>`` for source_to_combo."""
    if kind == "source_to_combo":
        (comp, _), _ = pair_states(kind, pose, component)
        return f"{pose}<{comp}"
    return pose


def split_bank_key(kind: PairKind, key: str) -> tuple[str, str | None]:
    """A bank key -> (pose, source component or None); the inverse of `bank_key`."""
    if kind == "source_to_combo" and "<" in key:
        pose, comp = key.split("<", 1)
        return pose, comp
    return key, None


@dataclass(frozen=True)
class Pair:
    kind: PairKind
    identity: int
    pose: str  # the target pose config
    source: StateRef  # (pose or None for neutral, variant)
    target: StateRef

    @property
    def component(self) -> str | None:
        """The source component of a source_to_combo pair (None for the other kinds)."""
        return self.source[0] if self.kind == "source_to_combo" else None

    @property
    def bank_key(self) -> str:
        return bank_key(self.kind, self.pose, self.component)


def _applies(kind: str, pose: str) -> bool:
    """Whether `pose` has a pair of this kind (`pair_states` is the one definition)."""
    try:
        pair_states(kind, pose)
        return True
    except ValueError:
        return False


def pairs_for_identity(identity: int, poses: tuple[str, ...], kinds: tuple[str, ...] = PAIR_KINDS) -> list[Pair]:
    """Every pair of the given kinds of one identity, pose by pose (kinds in PAIR_KINDS order);
    a combo's source_to_combo pairs only for components among `poses`."""
    for k in kinds:
        check_pair_kind(k)
    out: list[Pair] = []
    available = set(poses)
    for name in poses:
        for kind in (k for k in PAIR_KINDS if k in kinds and _applies(k, name)):
            comps = [c for c in dict.fromkeys(get_pose(name).components) if c in available] \
                if kind == "source_to_combo" else [None]
            for comp in comps:
                src, tgt = pair_states(kind, name, comp)
                out.append(Pair(kind, identity, name, src, tgt))
    return out


def enumerate_pairs(identities: list[int], poses: tuple[str, ...], kinds: tuple[str, ...] = PAIR_KINDS) -> list[Pair]:
    """All pairs of the given kinds for the identities (e.g. a split's indices)."""
    return [pair for i in identities for pair in pairs_for_identity(i, poses, kinds)]
