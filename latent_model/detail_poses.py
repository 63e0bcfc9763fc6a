"""Which region of local detail a pose moves: its face parts the head, its finger parts that side's hand.

A body part (an elbow, a neck turn) is decoder v2's; the local stage adds what a pose does inside a region
beyond the region's rigid motion, so a pose is the local stage's where a part of it is a face or finger pose.
"""
from __future__ import annotations

from latent_model.corpus.poses import get_pose


def detail_regions_of(pose: str) -> tuple[str, ...]:
    """The regions (`regions.REGIONS` names) whose local detail a pose (a vocabulary name) moves, in order."""
    p = get_pose(pose)
    out: list[str] = []
    for part in p.components or (p.name,):
        group = get_pose(part).group
        region = "head" if group == "face" else (("hand_left" if part.endswith("Lf") else "hand_right")
                                                 if group == "finger" else None)
        if region is not None and region not in out:
            out.append(region)
    return tuple(out)


def region_label(pose: str, region: str) -> str:
    """What a pose does inside a region, as a name: its parts there, finger parts without their side (one hand
    network reads both hands, the left mirrored), so fistLf on the left hand, fistRt on the right and
    elbowBentLf+fistLf on the left are one label; a pose with no part there (a neck turn) is its own."""
    p = get_pose(pose)
    parts = [c for c in (p.components or (p.name,)) if region in detail_regions_of(c)]
    if not parts:
        return pose
    if region != "head":
        parts = [c[:-2] for c in parts]
    return "+".join(parts)


def region_poses(poses: tuple[str, ...], kind: str) -> dict[str, tuple[str, ...]]:
    """{region: its poses among `poses`} for a region kind ("head" or "hand"): the poses with a part there, and
    the body poses that bend the region from outside (the neck for the head, the wrist for a hand), so its
    code learns them as deformations of their own."""
    regions = ("head",) if kind == "head" else ("hand_left", "hand_right")
    bending = {"head": ("neckTurnLf", "neckTurnRt", "neckBendFw"), "hand_left": ("wristFlexLf",),
               "hand_right": ("wristFlexRt",)}
    return {r: tuple(p for p in poses if r in detail_regions_of(p) or p in bending[r]) for r in regions}


def finger_chains(poses: list[str] | tuple[str, ...]) -> tuple[tuple[int, ...], ...]:
    """Indices into `poses` of the knuckle turns of each finger, proximal first (from the rig's bones
    `finger<n>-<level>.<side>`): the joints whose turns compose rather than add (`detail_fields.compose_turns`).
    Poses turning one finger bone each; anything else belongs to no chain."""
    import re

    fingers: dict[tuple[str, str], list[tuple[int, int]]] = {}
    for i, name in enumerate(poses):
        p = get_pose(name)
        if p.components or len(p.joints) != 1:
            continue
        m = re.fullmatch(r"(finger\d+)-(\d+)\.([LR])", p.joints[0].bone)
        if m:
            fingers.setdefault((m.group(1), m.group(3)), []).append((int(m.group(2)), i))
    return tuple(tuple(i for _, i in sorted(levels)) for _, levels in sorted(fingers.items()))
