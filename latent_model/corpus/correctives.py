"""Pose-space corrective blendshapes for skeletal poses, as a production rig carries them.

Two rest-space terms, summed:
1. LBS -> DQS volume fix: d = A_v^-1 (x_dqs - x_lbs), A_v the vertex's blended LBS matrix, so
   that LBS(rest + d) = DQS(rest) (fixes candy-wrapper collapse at elbows and knees).
2. A procedural flesh term per posed joint: a muscle bulge on the flexor side of the parent
   segment (biceps, hamstring, deltoid, trapezius...) and crease compression on the inner side
   of the joint, scaled by the identity's muscle and weight and by the bend angle.
Both are localised (Gaussian falloffs, skin-weight masks) and identity-dependent.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from latent_model.corpus.poses import JointRotation
from latent_model.corpus.rig import RestShape, Rig


@dataclass(frozen=True)
class Flesh:
    """Procedural flesh parameters of one joint family (metres at a 1.75 m stature)."""

    bulge: float  # muscle bulge amplitude at the reference angle
    bulge_at: float  # bulge centre, distance back from the joint along the parent segment
    bulge_sigma: float
    crease: float  # inner-side compression amplitude at the reference angle
    crease_sigma: float
    ref_degrees: float = 90.0


# Keyed by bone-label prefix (before the side suffix).
FLESH: dict[str, Flesh] = {
    "lowerarm01": Flesh(0.010, 0.11, 0.045, 0.008, 0.030),  # biceps bulge, elbow crease
    "lowerleg01": Flesh(0.008, 0.12, 0.060, 0.010, 0.045),  # hamstring/calf, back of the knee
    "upperarm01": Flesh(0.007, 0.05, 0.045, 0.006, 0.050, 60.0),  # deltoid/trapezius bunching
    "clavicle": Flesh(0.006, 0.04, 0.040, 0.004, 0.040, 20.0),  # trapezius
    "upperleg01": Flesh(0.006, 0.08, 0.060, 0.008, 0.060, 60.0),  # groin crease, lower belly
    "wrist": Flesh(0.002, 0.04, 0.030, 0.003, 0.020, 50.0),
    "finger": Flesh(0.0012, 0.015, 0.008, 0.0015, 0.008, 80.0),  # knuckle skin
    "spine": Flesh(0.003, 0.06, 0.050, 0.004, 0.050, 15.0),
    "neck": Flesh(0.002, 0.03, 0.030, 0.003, 0.030, 20.0),
}


def _family(bone: str) -> Flesh | None:
    stem = bone.split(".")[0]
    for prefix, flesh in FLESH.items():
        if stem.startswith(prefix):
            return flesh
    return None


def _subtree(rig: Rig, b: int) -> list[int]:
    out, stack = [], [b]
    while stack:
        c = stack.pop()
        out.append(c)
        stack.extend(rig.children[c])
    return out


def _weight_on(rig: Rig, bones: list[int]) -> np.ndarray:
    """(V,) total skin weight of each vertex on a set of bones."""
    sel = np.isin(rig.weight_bones, bones)
    return (rig.weights * sel).sum(axis=1)


def dqs_volume_fix(rig: Rig, rest_vertices: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(V, 3) rest-space corrective d with LBS(rest + d) = DQS(rest)."""
    A = rig.blended_linear(T)
    diff = rig.dqs(rest_vertices, T) - rig.lbs(rest_vertices, T)
    moving = np.linalg.norm(diff, axis=1) > 1e-7
    d = np.zeros_like(rest_vertices)
    if moving.any():
        d[moving] = np.linalg.solve(A[moving], diff[moving][..., None])[..., 0]
    return d


def flesh_corrective(rig: Rig, rest: RestShape, normals: np.ndarray, joints: tuple[JointRotation, ...],
                     muscle: float, weight: float) -> np.ndarray:
    """(V, 3) procedural bulge + crease offsets (rest space) for the posed joints."""
    x = rest.vertices
    size = (x[:, 2].max() - x[:, 2].min()) / 1.75
    out = np.zeros_like(x)
    for j in joints:
        fl = _family(j.bone)
        if fl is None:
            continue
        b = rig.bone_index[j.bone]
        h = rest.heads[b]
        parent = rig.parents[b]
        u_p = h - rest.heads[parent]
        u_p /= np.linalg.norm(u_p)
        kids = rig.children[b]
        # mean of the children: a branching bone (spine01 -> clavicles + neck) stays symmetric
        u_c = rest.heads[kids].mean(axis=0) - h if kids else u_p.copy()
        u_c /= np.linalg.norm(u_c)
        axis = rig.resolve_axis(rest, j)
        if np.linalg.norm(np.cross(axis, u_c)) < 0.3:  # a twist: no flexor side, no crease
            continue
        s = float(np.clip(j.degrees / fl.ref_degrees, 0.0, 1.8))
        grand = rig.parents[parent] if rig.parents[parent] >= 0 else parent
        mask = _weight_on(rig, _subtree(rig, grand))
        on_child = _weight_on(rig, _subtree(rig, b)) > 0.5
        p = x - h
        u = np.where(on_child[:, None], u_c, u_p)
        axial = np.einsum("vi,vi->v", p, u)
        axial = np.where(on_child, axial, -axial)  # distance from the joint along the segment
        radial = p - axial[:, None] * np.where(on_child[:, None], u, -u)
        radial /= np.linalg.norm(radial, axis=1, keepdims=True) + 1e-12
        flex_side = np.cross(axis, u)
        flex_side /= np.linalg.norm(flex_side, axis=1, keepdims=True) + 1e-12
        side = np.einsum("vi,vi->v", radial, flex_side)  # +1 on the inner (closing) side
        inner = 0.5 * (1.0 + np.tanh(4.0 * (side - 0.2)))
        crease = fl.crease * s * (0.5 + weight) * size * np.exp(-0.5 * (axial / (fl.crease_sigma * size)) ** 2)
        bulge_w = np.exp(-0.5 * ((axial - fl.bulge_at * size) / (fl.bulge_sigma * size)) ** 2)
        bulge = fl.bulge * s * (0.35 + 1.3 * muscle) * size * bulge_w * (~on_child)
        soft_inner = 0.5 * (1.0 + np.tanh(3.0 * side))
        out += normals * (mask * (bulge * soft_inner - crease * inner))[:, None]
    return out


def pose_corrective(rig: Rig, rest: RestShape, normals: np.ndarray, joints: tuple[JointRotation, ...],
                    T: np.ndarray, muscle: float, weight: float) -> np.ndarray:
    """(V, 3) total rest-space corrective of a skeletal pose (zeros if no joints)."""
    if not joints:
        return np.zeros_like(rest.vertices)
    return dqs_volume_fix(rig, rest.vertices, T) + flesh_corrective(rig, rest, normals, joints, muscle, weight)
