"""Geometry of every state of an identity: neutral and each pose in three variants.

Variants of a pose config with skeletal part S (bone transforms T), facial offsets F and
pose-space corrective C (all rest-space offsets):
- ``skinning``                 = LBS_T(rest)              (skeletal part only)
- ``blendshape``               = rest + F + C             (shapes, no bones)
- ``skinning_plus_blendshape`` = LBS_T(rest + F + C)      (the final rig output)
A face-only pose has T = identity, so its `skinning` state *is* the neutral geometry and
its `skinning_plus_blendshape` state *is* its `blendshape` geometry: the store keeps one
copy (several states may point at one geometry row).

In a rest configuration R (bones T_R, its own corrective C_R, see rests.py) the character as it
stands is neutral = LBS_{T_R}(rest + C_R), as a DCC export bakes it; a pose adds its rotations in
the rest-configured skeleton (T) and the corrective follows every rotation in effect (C):
- ``skinning``                 = LBS_T(rest + C_R)        (the standing character, bones moved)
- ``blendshape``               = LBS_{T_R}(rest + F + C)  (the pose's shapes, bones as they stand)
- ``skinning_plus_blendshape`` = LBS_T(rest + F + C)
so the same sharing holds in every rest, and the bind rest (T_R = I, C_R = 0) is the rule above.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from latent_model.corpus.correctives import pose_corrective
from latent_model.corpus.face import FaceCarrier
from latent_model.corpus.identities import IdentitySpec
from latent_model.corpus.poses import PoseConfig, get_pose
from latent_model.corpus.rests import RestConfig, get_rest
from latent_model.corpus.rig import RestShape, Rig
from latent_model.corpus.sdf import vertex_normals
from latent_model.types import VARIANTS



@dataclass
class PoseGeometry:
    """float64 (V, 3) vertices of each posed variant, plus the parts they are made of."""

    skinning: np.ndarray
    blendshape: np.ndarray
    skinning_plus_blendshape: np.ndarray
    corrective: np.ndarray  # C, rest space
    face: np.ndarray  # F, rest space
    transforms: np.ndarray  # (J, 4, 4)


class StateGenerator:
    """identity spec (+ pose) -> vertices. One instance per process; cheap per identity."""

    def __init__(self, rig: Rig | None = None) -> None:
        self.rig = rig or Rig()
        self.carrier = FaceCarrier(self.rig)
        self._cache: tuple[str, RestShape, np.ndarray] | None = None
        self._standing: dict[RestConfig, tuple[np.ndarray, np.ndarray]] = {}

    @property
    def faces(self) -> np.ndarray:
        return self.rig.faces

    def rest(self, spec: IdentitySpec) -> tuple[RestShape, np.ndarray]:
        """Rest shape and rest vertex normals (V, 3) of an identity (last one cached)."""
        key = repr((spec.phenotypes, spec.local_changes))  # the rest shape ignores the rest configuration
        if self._cache is None or self._cache[0] != key:
            rest = self.rig.rest(spec.phenotypes, spec.local_changes)
            self._cache = (key, rest, vertex_normals(rest.vertices, self.rig.faces).astype(np.float64))
            self._standing = {}
        return self._cache[1], self._cache[2]

    def _corrective(self, spec: IdentitySpec, joints, T: np.ndarray) -> np.ndarray:
        shape, normals = self.rest(spec)
        return pose_corrective(self.rig, shape, normals, joints, T,
                               spec.phenotypes.get("muscle", 0.5), spec.phenotypes.get("weight", 0.5))

    def standing(self, spec: IdentitySpec, rest: str | RestConfig) -> tuple[np.ndarray, np.ndarray]:
        """(T_R (J, 4, 4), C_R (V, 3)): bones and corrective of the identity in a non-bind rest (cached)."""
        shape, _ = self.rest(spec)
        config = _rest_config(rest)
        if config not in self._standing:
            joints = config.joints
            T = self.rig.bone_transforms(shape, joints)
            self._standing[config] = (T, self._corrective(spec, joints, T))
        return self._standing[config]

    def neutral(self, spec: IdentitySpec, rest: str | RestConfig | None = None) -> np.ndarray:
        """(V, 3) the identity standing in a rest configuration (a name or a `RestConfig`; default: its spec's;
        bind: its rest shape)."""
        rest = spec.rest if rest is None else rest
        if _rest_config(rest).is_bind:
            return self.rest(spec)[0].vertices
        T_R, C_R = self.standing(spec, rest)
        return self.rig.lbs(self.rest(spec)[0].vertices + C_R, T_R)

    def pose(self, spec: IdentitySpec, pose: PoseConfig | str, rest: str | RestConfig | None = None) -> PoseGeometry:
        """A pose on top of a rest configuration (default: the spec's): the pose's rotations act in the
        rest-configured skeleton; correctives follow every rotation in effect (the rest's and the pose's)."""
        p = get_pose(pose) if isinstance(pose, str) else pose
        rest = spec.rest if rest is None else rest
        base = _rest_config(rest).joints
        shape, _ = self.rest(spec)
        rig = self.rig
        T = rig.bone_transforms(shape, p.joints, base)
        C = self._corrective(spec, base + p.joints, T)
        F = self.carrier.offsets(shape.vertices, p.face, spec.face_style)
        shaped = shape.vertices + F + C
        if not base:  # bind rest: T_R = I, C_R = 0 (kept exact: no skinning by identity transforms)
            if p.has_skeletal:
                return PoseGeometry(rig.lbs(shape.vertices, T), shaped, rig.lbs(shaped, T), C, F, T)
            return PoseGeometry(shape.vertices.copy(), shaped, shaped.copy(), C, F, T)
        T_R, C_R = self.standing(spec, rest)
        skin = rig.lbs(shape.vertices + C_R, T)
        final = rig.lbs(shaped, T)
        return PoseGeometry(skin, rig.lbs(shaped, T_R), final, C, F, T)

    def state(self, spec: IdentitySpec, pose: str | None, variant: str, rest: str | None = None) -> np.ndarray:
        """(V, 3) float64 vertices of one state; `pose` None means the neutral state (of `rest`, default
        the spec's)."""
        if variant not in VARIANTS:
            raise ValueError(f"unknown variant {variant!r}; valid: {', '.join(VARIANTS)}")
        if variant == "neutral" or pose is None:
            if variant != "neutral" or pose is not None:
                raise ValueError("the neutral state has no pose, and a pose needs a posed variant")
            return self.neutral(spec, rest)
        return getattr(self.pose(spec, pose, rest), variant)


def _rest_config(rest: str | RestConfig) -> RestConfig:
    return rest if isinstance(rest, RestConfig) else get_rest(rest)
