"""Identity-dependent facial shapes: Face Units carried onto each identity's own head.

anny adds the *same* facial offsets to every identity. A production character's shapes
are sculpted on its own face, so we (1) carry each offset through the local deformation
from the base mesh to the identity's rest shape (a per-vertex 3x3 map fitted to the
neighbourhood, which scales with head size and follows the local orientation), and
(2) apply a seeded per-identity style: intensity, spread (smoother/wider or sharper),
slight left/right asymmetry and a gentle spatial modulation of strength.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from latent_model.corpus.identities import FaceStyle
from latent_model.corpus.poses import FaceWeight
from latent_model.corpus.rig import Rig

SIDE_MASK_WIDTH = 0.006  # metres: sigmoid width of one-sided masks (leak < 0.7 mm measured)
_JACOBIAN_K = 16
_RIDGE = 1e-6  # regularises the 3x3 fits toward the identity map on degenerate patches


def side_mask(x: np.ndarray, side: str | None) -> np.ndarray:
    """(V,) smooth weight of one face half from x (+X = character's left)."""
    if side is None:
        return np.ones(len(x))
    s = 1.0 if side == "L" else -1.0
    return 1.0 / (1.0 + np.exp(-s * x / SIDE_MASK_WIDTH))


class FaceCarrier:
    """Carries base-mesh facial offsets onto identities (shared per rig)."""

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        base = rig.base_rest.vertices
        support = np.zeros(len(base), dtype=bool)
        for unit in rig.facial_labels:
            support |= np.linalg.norm(rig.facial_offsets(unit), axis=1) > 1e-7
        # Grow the support a little so smoothing (spread) has room to widen the shapes.
        tree = cKDTree(base)
        near = tree.query_ball_point(base[support], r=0.015)
        grown = np.zeros(len(base), dtype=bool)
        grown[np.unique(np.concatenate([np.asarray(n, dtype=np.int64) for n in near]))] = True
        self.idx = np.flatnonzero(grown)  # (S,) facial region vertices
        _, nbr = tree.query(base[self.idx], k=_JACOBIAN_K + 1)
        self.nbr = nbr[:, 1:]  # (S, k) spatial neighbours for the local maps
        self.base_edges = base[self.nbr] - base[self.idx][:, None]  # (S, k, 3)
        # Mesh-topology averaging operator for spread (never crosses the lip or eyelid gap).
        f = rig.faces
        n = len(base)
        A = sp.coo_matrix((np.ones(6 * len(f)), (f[:, [0, 1, 2, 1, 2, 0]].ravel(), f[:, [1, 2, 0, 0, 1, 2]].ravel())), shape=(n, n)).tocsr()
        A.data[:] = 1.0
        deg = np.asarray(A.sum(axis=1)).ravel()
        self.avg = sp.diags(1.0 / np.maximum(deg, 1)) @ A

    def local_maps(self, rest_vertices: np.ndarray) -> np.ndarray:
        """(S, 3, 3) per-vertex linear maps J with J (b_u - b_v) ~ (r_u - r_v)."""
        E_b = self.base_edges
        E_r = rest_vertices[self.nbr] - rest_vertices[self.idx][:, None]
        scale = np.einsum("skc,skc->s", E_b, E_b)[:, None, None] / _JACOBIAN_K
        lhs = np.einsum("ski,skj->sij", E_b, E_b) + _RIDGE * scale * np.eye(3)
        rhs = np.einsum("ski,skj->sij", E_b, E_r) + _RIDGE * scale * np.eye(3)
        J = np.linalg.solve(lhs, rhs).transpose(0, 2, 1)
        # Robustness: a badly conditioned patch (inner mouth, eyelid folds) must not amplify a
        # shape; keep each map's rotation and clip its stretches to a band around its mean scale.
        U, S, Vt = np.linalg.svd(J)
        scale = np.exp(np.log(np.clip(S, 1e-6, None)).mean(axis=1, keepdims=True))
        scale = np.clip(scale, 0.6, 1.6)  # local size change vs the base mesh
        S = np.clip(S, 0.8 * scale, 1.25 * scale)
        return np.einsum("sij,sj,sjk->sik", U, S, Vt)

    def offsets(self, rest_vertices: np.ndarray, face: tuple[FaceWeight, ...], style: FaceStyle) -> np.ndarray:
        """(V, 3) rest-space facial offsets of a pose's blendshape part on this identity."""
        out = np.zeros_like(rest_vertices)
        if not face:
            return out
        base = self.rig.base_rest.vertices
        d = np.zeros_like(base)
        for fw in face:
            d += fw.weight * side_mask(base[:, 0], fw.side)[:, None] * self.rig.facial_offsets(fw.unit)
        # Spread: blend with a smoothed copy (negative = unsharp mask, i.e. sharper shapes).
        smooth = d
        for _ in range(4):
            smooth = self.avg @ smooth
        d = (1.0 - style.spread) * d + style.spread * smooth
        J = self.local_maps(rest_vertices)
        carried = np.einsum("sij,sj->si", J, d[self.idx])
        x = rest_vertices[self.idx]
        amp, wavelength, azimuth, phase = style.wave
        direction = np.array([np.cos(azimuth), 0.0, np.sin(azimuth)])
        gain = style.intensity * (1.0 + style.asymmetry * np.tanh(x[:, 0] / 0.02))
        if amp:
            gain *= 1.0 + amp * np.sin(2 * np.pi * (x @ direction) / wavelength + phase)
        out[self.idx] = carried * gain[:, None]
        return out
