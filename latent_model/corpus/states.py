"""Geometry of every state of an identity: neutral and each pose in three variants.

Variants of a pose config with skeletal part S (bone transforms T), facial offsets F and
pose-space corrective C (all rest-space offsets):
- ``skinning``                 = LBS_T(rest)              (skeletal part only)
- ``blendshape``               = rest + F + C             (shapes, no bones)
- ``skinning_plus_blendshape`` = LBS_T(rest + F + C)      (the final rig output)
A face-only pose has T = identity, so its `skinning` state *is* the neutral geometry and
its `skinning_plus_blendshape` state *is* its `blendshape` geometry: the store keeps one
copy (several states may point at one geometry row).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from latent_model.corpus.correctives import pose_corrective
from latent_model.corpus.face import FaceCarrier
from latent_model.corpus.identities import IdentitySpec
from latent_model.corpus.poses import PoseConfig, get_pose
from latent_model.corpus.rests import get_rest
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

    @property
    def faces(self) -> np.ndarray:
        return self.rig.faces

    def rest(self, spec: IdentitySpec) -> tuple[RestShape, np.ndarray]:
        """Rest shape and rest vertex normals (V, 3) of an identity (last one cached)."""
        if self._cache is None or self._cache[0] != repr(spec):
            rest = self.rig.rest(spec.phenotypes, spec.local_changes)
            self._cache = (repr(spec), rest, vertex_normals(rest.vertices, self.rig.faces).astype(np.float64))
        return self._cache[1], self._cache[2]

    def neutral(self, spec: IdentitySpec, rest: str = "bind") -> np.ndarray:
        """(V, 3) the identity standing in a rest configuration (the bind one: its rest shape)."""
        if rest == "bind":
            return self.rest(spec)[0].vertices
        r = get_rest(rest)
        shape, normals = self.rest(spec)
        T = self.rig.bone_transforms(shape, r.joints)
        C = pose_corrective(self.rig, shape, normals, r.joints, T,
                            spec.phenotypes.get("muscle", 0.5), spec.phenotypes.get("weight", 0.5))
        return self.rig.lbs(shape.vertices + C, T)

    def pose(self, spec: IdentitySpec, pose: PoseConfig | str, rest: str = "bind") -> PoseGeometry:
        """A pose on top of a rest configuration: the pose's rotations act in the rest-configured
        skeleton; correctives follow every rotation in effect (the rest's and the pose's)."""
        p = get_pose(pose) if isinstance(pose, str) else pose
        base = get_rest(rest).joints
        shape, normals = self.rest(spec)
        rig = self.rig
        T = rig.bone_transforms(shape, p.joints, base)
        C = pose_corrective(rig, shape, normals, base + p.joints, T,
                            spec.phenotypes.get("muscle", 0.5), spec.phenotypes.get("weight", 0.5))
        F = self.carrier.offsets(shape.vertices, p.face, spec.face_style)
        shaped = shape.vertices + F + C
        if p.has_skeletal or base:
            skin = rig.lbs(shape.vertices, T)
            final = rig.lbs(shaped, T)
        else:
            skin = shape.vertices.copy()
            final = shaped.copy()
        return PoseGeometry(skin, shaped, final, C, F, T)

    def state(self, spec: IdentitySpec, pose: str | None, variant: str, rest: str = "bind") -> np.ndarray:
        """(V, 3) float64 vertices of one state; `pose` None means the neutral state (of `rest`)."""
        if variant not in VARIANTS:
            raise ValueError(f"unknown variant {variant!r}; valid: {', '.join(VARIANTS)}")
        if variant == "neutral" or pose is None:
            if variant != "neutral" or pose is not None:
                raise ValueError("the neutral state has no pose, and a pose needs a posed variant")
            return self.neutral(spec, rest)
        return getattr(self.pose(spec, pose, rest), variant)
