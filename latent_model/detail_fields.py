"""Displacement fields of the local detail stage: what each face or finger pose does inside a region.

A region delta (the head's or a hand's latent delta) is read as a non-negative mix of the training poses'
mean region deltas (`RegionFields.read`), and the region moves by the same mix of those poses' displacement
fields (`RegionFields.displacement`). A field is pooled over the training characters on one anchor region:
each character's region (local coordinates, radius units) is first aligned to the anchor by an affine ICP
(`affine_align`), because faces differ in proportion more than a mouth corner moves: pooled without it, a
mouth corner's motion lands a few millimetres off on the next face (0.24 of the motion explained on the
validation characters, 0.55 with it). Topology-free: a target is placed by its own vertices' positions.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls
from scipy.spatial import cKDTree

ALIGN_ITERATIONS = 30
NEIGHBOURS = 4  # anchor points a target vertex reads, by inverse distance
# poses whose mean deltas point this much apart are antagonists: a mix holds one of them (validation, one
# character's own face deltas: 0.33 explained with both allowed, 0.45-0.51 at -0.7; at -0.6 a jaw drops its smile)
ANTAGONIST = -0.7


def affine_align(x: np.ndarray, anchor: np.ndarray, iterations: int = ALIGN_ITERATIONS) -> tuple[np.ndarray, np.ndarray]:
    """(A (3, 3), b (3,)) with x @ A.T + b lying on the anchor cloud (N, 3): affine ICP over nearest pairs taken
    both ways (each x to the anchor, each anchor point to x), from the identity."""
    x = np.asarray(x, dtype=np.float64)
    anchor = np.asarray(anchor, dtype=np.float64)
    tree = cKDTree(anchor)
    xh = np.c_[x, np.ones(len(x))]
    m = np.r_[np.eye(3), np.zeros((1, 3))]  # (4, 3): y = xh @ m
    for _ in range(iterations):
        y = xh @ m
        _, to_anchor = tree.query(y)
        _, to_x = cKDTree(y).query(anchor)
        m, *_ = np.linalg.lstsq(np.r_[xh, xh[to_x]], np.r_[anchor[to_anchor], anchor], rcond=None)
    return m[:3].T, m[3]


def _interpolation(points: np.ndarray, at: np.ndarray, k: int = NEIGHBOURS) -> tuple[np.ndarray, np.ndarray]:
    """(index (M, k), weight (M, k)): inverse-distance weights of `at`'s k nearest `points`."""
    d, i = cKDTree(points).query(at, k)
    i, d = i.reshape(len(at), -1), d.reshape(len(at), -1)
    w = 1.0 / np.maximum(d, 1e-9)
    return i, w / w.sum(axis=1, keepdims=True)


@dataclass
class Placement:
    """A target region on the anchor: its affine map (A (3, 3), b (3,)) and interpolation weights (index, weight
    (M, k)) of its M vertices among the anchor's points."""

    A: np.ndarray
    b: np.ndarray
    index: np.ndarray
    weight: np.ndarray


@dataclass
class RegionFields:
    """The anchor region's points (N, 3) (local coordinates, radius units), the poses its fields belong to, and the
    fields (P, N, 3): each pose's displacement averaged over the training characters, in anchor coordinates."""

    anchor: np.ndarray
    poses: list[str]
    values: np.ndarray

    def place(self, local: np.ndarray) -> Placement:
        """Where a region's vertices (M, 3), local coordinates, lie on the anchor."""
        A, b = affine_align(local, self.anchor)
        index, weight = _interpolation(self.anchor, np.asarray(local, np.float64) @ A.T + b)
        return Placement(A, b, index, weight)

    @staticmethod
    def read(delta: np.ndarray, basis: np.ndarray, floor: float) -> np.ndarray:
        """(P,) non-negative weights of the poses whose mean deltas are `basis` (P, Z) that best make `delta` (Z,).
        A pose contributing less than the noise floor of one delta is dropped and the rest refitted: one
        character's delta (a nearest identity, an example pair) otherwise fills its noise with small amounts of
        every other pose, and a jaw at 2 % still moves a chin by a millimetre. Of two antagonists (mean deltas
        at cosine < ANTAGONIST: a brow down and up) only the larger stays: together they cancel in the latent but
        not on the face, and one character's delta read as browDw 0.6 + browUp 0.6 moved a brow that stays still.
        The largest contribution stays whatever its size: whether a delta is signal at all is the noise gate's
        to say (`LocalDetailModel.gate`)."""
        c, _ = nnls(basis.T.astype(np.float64), np.asarray(delta, np.float64))
        length = np.linalg.norm(basis, axis=1)
        contribution = c * length
        unit = basis / np.maximum(length, 1e-12)[:, None]
        for a, b in zip(*np.nonzero(np.triu(unit @ unit.T < ANTAGONIST, 1))):
            if contribution[a] > 0 and contribution[b] > 0:
                contribution[b if contribution[a] >= contribution[b] else a] = 0.0
        keep = contribution >= floor
        keep[np.argmax(contribution)] |= contribution.max() > 0
        out = np.zeros(len(basis))
        if keep.any():
            out[keep], _ = nnls(basis[keep].T.astype(np.float64), np.asarray(delta, np.float64))
        return out

    def displacement(self, placement: Placement, weights: np.ndarray) -> np.ndarray:
        """(M, 3) displacement of the placed region's vertices (their local coordinates) for pose weights (P,)."""
        field = np.tensordot(weights, self.values, axes=1)  # (N, 3), anchor coordinates
        moved = (field[placement.index] * placement.weight[..., None]).sum(axis=1)
        return np.linalg.solve(placement.A, moved.T).T  # back through the affine map's linear part


def build_fields(characters: list[tuple[np.ndarray, dict[str, np.ndarray]]], poses: list[str]) -> RegionFields:
    """Fields of `poses` from training characters [(neutral local vertices (M_i, 3), {pose: posed local vertices
    (M_i, 3)})], on the first character's region as the anchor."""
    anchor = np.asarray(characters[0][0], np.float64)
    values = np.zeros((len(poses), len(anchor), 3))
    for x0, posed in characters:
        A, b = affine_align(x0, anchor)
        # each anchor point reads the character's vertices nearest to it once both are aligned
        index, weight = _interpolation(np.asarray(x0, np.float64) @ A.T + b, anchor)
        for n, p in enumerate(poses):
            disp = (np.asarray(posed[p], np.float64) - x0) @ A.T
            values[n] += (disp[index] * weight[..., None]).sum(axis=1)
    return RegionFields(anchor.astype(np.float32), list(poses), (values / len(characters)).astype(np.float32))
