"""The anny body model as a rig: identity -> rest shape; joint rotations -> skinned vertices.

Posing is relative to the *bind* pose (anny's `local-ref` zero pose is a reference pose,
up to 5.5 cm off): each posed bone rotates about its rest head in rest-world axes and the
chain is composed by our own forward kinematics; skinning uses anny's weights.
Units metres, Z up, faces -Y, +X = character's left.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import roma
import torch
from scipy.spatial.transform import Rotation

from latent_model.corpus.poses import JointRotation

# Reflection across the YZ plane (character's left <-> right).
MIRROR = np.diag([-1.0, 1.0, 1.0])
_FIXED_AXES = {
    "+x": (1.0, 0.0, 0.0), "-x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0), "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0), "-z": (0.0, 0.0, -1.0),
}


@dataclass
class RestShape:
    """An identity in its bind pose (float64 numpy)."""

    vertices: np.ndarray  # (V, 3)
    heads: np.ndarray  # (J, 3) rest bone heads (joint centres)


def _anny_model():
    os.environ.setdefault("WARP_CACHE_PATH", os.path.join(os.path.expanduser("~"), ".cache", "warp"))
    import anny  # heavy import (warp, torch) kept local

    return anny.Anny(local_changes="default", facial_actions="all", skinning_method="lbs")


class Rig:
    """One anny model shared by every identity. Construction takes < 1 s once anny's cache
    exists (the first construction on a machine builds it, ~40-60 s)."""

    def __init__(self) -> None:
        with torch.no_grad():
            self.model = _anny_model()
        m = self.model
        self.bone_labels: list[str] = list(m.bone_labels)
        self.bone_index = {b: i for i, b in enumerate(self.bone_labels)}
        self.parents = np.asarray([int(p) for p in m.bone_parents])
        assert all(self.parents[i] < i for i in range(1, len(self.parents))), "bones not topologically sorted"
        self.children: list[list[int]] = [[] for _ in self.bone_labels]
        for i, p in enumerate(self.parents[1:], start=1):
            self.children[p].append(i)
        self.faces = m.get_triangular_faces().cpu().numpy().astype(np.int64)  # (F, 3)
        self.weights = m.vertex_bone_weights.cpu().numpy()  # (V, 9)
        self.weight_bones = m.vertex_bone_indices.cpu().numpy().astype(np.int64)  # (V, 9)
        self.phenotype_labels: list[str] = list(m.phenotype_labels)
        self.local_change_labels: list[str] = list(m.local_change_labels)
        self.facial_labels: list[str] = list(m.facial_action_labels)

    # ------------------------------------------------------------------ identities
    def rest(self, phenotypes: dict[str, float], local_changes: dict[str, float]) -> RestShape:
        """Rest vertices and joint centres of an identity."""
        unknown = [k for k in local_changes if k not in self.local_change_labels]
        if unknown:
            raise ValueError(f"unknown anny local changes {unknown}")
        with torch.no_grad():
            out = self.model(phenotype_kwargs=dict(phenotypes), local_changes_kwargs=dict(local_changes))
        return RestShape(out["rest_vertices"][0].numpy().astype(np.float64),
                         out["rest_bone_heads"][0].numpy().astype(np.float64))

    @cached_property
    def base_rest(self) -> RestShape:
        """The base mesh (all sliders at their defaults): the frame Face Units are authored in."""
        return self.rest({}, {})

    def facial_offsets(self, unit: str) -> np.ndarray:
        """(V, 3) rest-space offsets of one Face Unit at weight 1 on the base mesh."""
        return self._facial_offsets[unit]

    @cached_property
    def _facial_offsets(self) -> dict[str, np.ndarray]:
        base = self.base_rest.vertices
        out = {}
        for unit in self.facial_labels:
            with torch.no_grad():
                posed = self.model(facial_actions={unit: 1.0})["rest_vertices"][0].numpy()
            out[unit] = posed - base
        return out

    @cached_property
    def mirror_map(self) -> np.ndarray:
        """(V,) index of each vertex's left/right mirror partner on the base mesh."""
        from scipy.spatial import cKDTree

        v = self.base_rest.vertices
        _, idx = cKDTree(v).query(v @ MIRROR)
        return idx.astype(np.int64)

    # ------------------------------------------------------------------ posing
    def _first_child(self, b: int) -> int | None:
        kids = self.children[b]
        return kids[0] if kids else None

    def resolve_axis(self, rest: RestShape, j: JointRotation) -> np.ndarray:
        """Unit rotation axis (3,) in rest-world coordinates for a joint rotation."""
        h = rest.heads
        b = self.bone_index[j.bone]
        if j.axis in _FIXED_AXES:
            a = np.asarray(_FIXED_AXES[j.axis])
            # For a mirrored pose, R' = M R M is the rotation about -M a by the same angle.
            return -(MIRROR @ a) if j.mirrored else a
        if j.axis == "hinge":
            c = self._first_child(b)
            parent_seg = h[b] - h[self.parents[b]]
            child_seg = h[c] - h[b]
            a = np.cross(parent_seg, child_seg)
            n = np.linalg.norm(a)
            if n < 1e-9:
                raise ValueError(f"joint {j.bone} is straight in the bind pose; hinge axis undefined")
            return a / n
        if j.axis == "along":
            a = h[b] - h[self.parents[b]]  # the parent segment: a twist of the bone about it
            a = a / np.linalg.norm(a)
            return -a if j.mirrored else a  # M R(a) M = R(-M a): the mirrored bone's segment is M a
        if j.axis == "palm":
            side = j.bone[-1]
            idx = lambda name: self.bone_index[f"{name}.{side}"]  # noqa: E731
            across = h[idx("finger5-1")] - h[idx("finger2-1")]
            across /= np.linalg.norm(across)
            # Orient by the fingers' own bind-pose curl, so + curls toward the palm.
            curl = np.zeros(3)
            for f in (2, 3, 4, 5):
                p1, p2, p3 = (h[idx(f"finger{f}-{k}")] for k in (1, 2, 3))
                curl += np.cross(p2 - p1, p3 - p2)
            return across if float(across @ curl) >= 0 else -across
        raise ValueError(f"unknown axis rule {j.axis!r} for {j.bone}")

    def _rotation(self, rest: RestShape, j: JointRotation) -> tuple[int, np.ndarray]:
        b = self.bone_index.get(j.bone)
        if b is None:
            raise ValueError(f"unknown bone {j.bone!r}")
        rotvec = self.resolve_axis(rest, j) * np.deg2rad(j.degrees)
        return b, Rotation.from_rotvec(rotvec).as_matrix()  # roma's through torch gave the same to 1e-15, 12x slower

    def bone_transforms(self, rest: RestShape, joints: tuple[JointRotation, ...],
                        base: tuple[JointRotation, ...] = ()) -> np.ndarray:
        """(J, 4, 4) transforms T_c mapping rest-world points to posed-world points.

        T_c = T_parent . [L_c | h_c - L_c h_c], L_c the bone's own rotation (identity if unposed).
        `base`: a rest configuration's rotations, applied first; `joints` then act in each bone's
        rest-configured frame (L_c = L_base L_joints), as a rig's local rotations do.
        """
        J = len(self.bone_labels)
        local = np.tile(np.eye(3), (J, 1, 1))
        for j in joints:
            b, R = self._rotation(rest, j)
            local[b] = R @ local[b]  # compose if a combo rotates one bone twice
        if base:
            rest_local = np.tile(np.eye(3), (J, 1, 1))
            for j in base:
                b, R = self._rotation(rest, j)
                rest_local[b] = R @ rest_local[b]
            local = rest_local @ local
        T = np.zeros((J, 4, 4))
        h = rest.heads
        for c in range(J):
            K = np.eye(4)
            K[:3, :3] = local[c]
            K[:3, 3] = h[c] - local[c] @ h[c]
            T[c] = K if c == 0 else T[self.parents[c]] @ K
        return T

    def blended_linear(self, T: np.ndarray) -> np.ndarray:
        """(V, 3, 3) LBS-blended linear part A_v = sum_k w_vk R_k (for rest-space correctives)."""
        R = T[self.weight_bones, :3, :3]  # (V, 9, 3, 3)
        return np.einsum("vk,vkij->vij", self.weights, R)

    def lbs(self, vertices: np.ndarray, T: np.ndarray) -> np.ndarray:
        """(V, 3) linear blend skinning of rest-space `vertices` (V, 3)."""
        M = np.einsum("vk,vkij->vij", self.weights, T[self.weight_bones, :3, :])  # (V, 3, 4)
        return np.einsum("vij,vj->vi", M[:, :, :3], vertices) + M[:, :, 3]

    def dqs(self, vertices: np.ndarray, T: np.ndarray) -> np.ndarray:
        """(V, 3) dual-quaternion skinning with the same weights (volume-preserving reference)."""
        Tt = torch.as_tensor(T)
        q = roma.rotmat_to_unitquat(Tt[:, :3, :3])  # (J, 4) xyzw
        t = torch.cat([Tt[:, :3, 3], torch.zeros(len(T), 1, dtype=Tt.dtype)], dim=1)
        d = 0.5 * roma.quat_product(t, q)  # dual part
        qv, dv = q[self.weight_bones], d[self.weight_bones]  # (V, 9, 4)
        w = torch.as_tensor(self.weights)[..., None]
        sign = torch.sign((qv * qv[:, :1]).sum(-1, keepdim=True))  # antipodal fix vs first bone
        sign[sign == 0] = 1.0
        qb, db = (w * sign * qv).sum(1), (w * sign * dv).sum(1)
        n = torch.linalg.norm(qb, dim=-1, keepdim=True)
        qb, db = qb / n, db / n
        tr = 2.0 * roma.quat_product(db, roma.quat_conjugation(qb))[:, :3]
        return (roma.quat_action(qb, torch.as_tensor(vertices)) + tr).numpy()
