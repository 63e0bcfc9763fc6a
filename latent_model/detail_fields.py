"""Displacement fields of the local detail stage: what each face or finger pose does inside a region.

A region delta (the head's or a hand's latent delta) is read as a non-negative mix of the training poses'
mean region deltas (`RegionFields.read`), and the region moves by the same mix of those poses' displacement
fields (`RegionFields.displacement`). A field is pooled over the training characters on one anchor region:
each character's region (local coordinates, radius units) is first aligned to the anchor by an affine ICP
(`affine_align`), because faces differ in proportion more than a mouth corner moves: pooled without it, a
mouth corner's motion lands a few millimetres off on the next face (0.24 of the motion explained on the
validation characters, 0.55 with it). Topology-free: a target is placed by its own vertices' positions.

Knuckle turns do not add: bending a finger's base knuckle carries its middle and tip joints along, so the turn
of a tip knuckle, measured on a straight finger, lands in the wrong place once the base is bent (a fist as its
twelve fields summed explained 0.13 on the validation characters). Each knuckle's field is therefore also kept as
a turn about a pivot that each anchor point follows by a weight, plus what that leaves (`fit_turn`), and the
turns of one finger compose from the tip to the base as a skeleton's do (`compose_turns`; the fist: 0.86).

A source already standing in some of the region's poses (`source_to_combo`: a bent knuckle, an open jaw) is placed
on the anchor posed the same way (`place(..., held)`), and moves by what the combination's composed turns do
beyond that pose: a fist from a bent base knuckle turns the middle and tip joints about where they now are.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.optimize import nnls
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

ALIGN_ITERATIONS = 30
NEIGHBOURS = 4  # anchor points a target vertex reads, by inverse distance
# poses whose mean deltas point this much apart are antagonists: a mix holds one of them (validation, one
# character's own face deltas: 0.33 explained with both allowed, 0.45-0.51 at -0.7; at -0.6 a jaw drops its smile)
ANTAGONIST = -0.7
# a knuckle's turn is fitted on the points moving at least this fraction of its field's largest displacement: the
# outer part of the finger, which turns whole (the skin near the joint blends between the bones)
TURN_CORE = 0.3
FIT_MAX = 2.0  # an example's region motion read as pose weights up to twice each pose (`RegionFields.fit`)
FIT_DROP = 0.05  # ... a weight under this is dropped (what an example's still hand reads as)


def affine_align(x: np.ndarray, anchor: np.ndarray, iterations: int = ALIGN_ITERATIONS) -> tuple[np.ndarray, np.ndarray]:
    """(A (3, 3), b (3,)) with x @ A.T + b lying on the anchor cloud (N, 3): affine ICP over nearest pairs taken
    both ways (each x to the anchor, each anchor point to x), from the identity."""
    x = np.asarray(x, dtype=np.float64)
    anchor = np.asarray(anchor, dtype=np.float64)
    tree = cKDTree(anchor)
    xh = np.c_[x, np.ones(len(x))]
    m = np.r_[np.eye(3), np.zeros((1, 3))]  # (4, 3): y = xh @ m
    pairs = None
    for _ in range(iterations):
        y = xh @ m
        _, to_anchor = tree.query(y)
        _, to_x = cKDTree(y).query(anchor)
        if pairs is not None and np.array_equal(pairs[0], to_anchor) and np.array_equal(pairs[1], to_x):
            break  # the same pairs give the same fit: converged exactly (a hand after ~15 of 30 iterations)
        pairs = (to_anchor, to_x)
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
    (M, k)) of its M vertices among the anchor's points; `held` (P,): the pose weights the target already stands
    in (it was placed on the anchor posed so), or None."""

    A: np.ndarray
    b: np.ndarray
    index: np.ndarray
    weight: np.ndarray
    held: np.ndarray | None = None


@dataclass
class Turn:
    """A displacement field (N, 3) as a rotation (rotation vector (3,)) about `pivot` (3,) that each anchor point
    follows by its `weight` (N,), plus the `residual` (N, 3): field = weight * (R (x - pivot) + pivot - x) +
    residual."""

    rotvec: np.ndarray
    pivot: np.ndarray
    weight: np.ndarray
    residual: np.ndarray


def fit_turn(points: np.ndarray, displacement: np.ndarray, core: float = TURN_CORE) -> Turn:
    """The turn that makes `displacement` (N, 3) of `points` (N, 3): Kabsch on the points moving at least `core`
    of the largest displacement, the pivot on the rotation's axis nearest their centre, each point's weight the
    share of that rotation's motion its displacement makes (in [0, 1])."""
    x, d = np.asarray(points, np.float64), np.asarray(displacement, np.float64)
    length = np.linalg.norm(d, axis=1)
    if length.max() <= 0:
        return Turn(np.zeros(3), x.mean(axis=0), np.zeros(len(x)), d)
    outer = length >= core * length.max()
    a, b = x[outer], x[outer] + d[outer]
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    r = vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))]) @ u.T
    shift = cb - ca @ r.T  # b ~ r a + shift; the pivot p solves (I - r) p = shift (a line: the point nearest ca)
    pivot = ca + np.linalg.lstsq(np.eye(3) - r, shift - (np.eye(3) - r) @ ca, rcond=None)[0]
    full = (x - pivot) @ r.T + pivot - x
    sq = (full * full).sum(axis=1)
    weight = np.where(sq > 1e-12, np.clip((d * full).sum(axis=1) / np.maximum(sq, 1e-12), 0.0, 1.0), 0.0)
    return Turn(Rotation.from_matrix(r).as_rotvec(), pivot, weight, d - weight[:, None] * full)


def compose_turns(points: np.ndarray, turns: list[Turn], amounts: np.ndarray) -> np.ndarray:
    """(N, 3) displacement of `points` (N, 3) under the turns of one chain (base first), each at its amount (its
    angle scaled; the residual too): the tip's turn first, then each joint nearer the base carries what the ones
    beyond it moved, as forward kinematics does. One turn at amount 1 gives its field back exactly."""
    x = np.asarray(points, np.float64)
    y = x.copy()
    for t, a in reversed(list(zip(turns, amounts))):
        if a == 0:
            continue
        r = Rotation.from_rotvec(t.rotvec * a).as_matrix()
        y += t.weight[:, None] * ((y - t.pivot) @ r.T + t.pivot - y)
    return y - x + sum(a * t.residual for t, a in zip(turns, amounts))


@dataclass
class RegionFields:
    """The anchor region's points (N, 3) (local coordinates, radius units), the poses its fields belong to, and the
    fields (P, N, 3): each pose's displacement averaged over the training characters, in anchor coordinates.
    `chains`: indices of the poses whose turns compose (a finger's knuckles, base first; `detail_poses.finger_chains`)."""

    anchor: np.ndarray
    poses: list[str]
    values: np.ndarray
    chains: tuple[tuple[int, ...], ...] = ()

    @cached_property
    def turns(self) -> dict[int, Turn]:
        """{pose index: its field as a turn} of the poses in chains."""
        return {i: fit_turn(self.anchor, self.values[i]) for chain in self.chains for i in chain}

    def mixed(self, weights: np.ndarray) -> np.ndarray:
        """(N, 3) the displacement of the anchor for pose weights (P,): the fields added, except within a chain,
        whose turns compose."""
        w = np.asarray(weights, np.float64)
        chained = [i for chain in self.chains for i in chain]
        free = np.ones(len(w), bool)
        free[chained] = False
        out = np.tensordot(np.where(free, w, 0.0), self.values, axes=1)
        for chain in self.chains:
            if any(w[i] != 0 for i in chain):
                out = out + compose_turns(self.anchor, [self.turns[i] for i in chain], w[list(chain)])
        return out

    def weights_of(self, poses: tuple[str, ...] | list[str]) -> np.ndarray:
        """(P,) weight 1 for each of `poses` this region has a field of, 0 elsewhere."""
        return np.array([1.0 if p in poses else 0.0 for p in self.poses])

    def place(self, local: np.ndarray, held: np.ndarray | None = None) -> Placement:
        """Where a region's vertices (M, 3), local coordinates, lie on the anchor — on the anchor moved by the pose
        weights `held` (P,) when the region already stands in those poses (a bent finger's tip is then found where
        the anchor's bent tip is, not on the next finger)."""
        held = None if held is None or not np.any(held) else np.asarray(held, np.float64)
        target = self.anchor if held is None else self.anchor + self.mixed(held)
        A, b = affine_align(local, target)
        index, weight = _interpolation(target, np.asarray(local, np.float64) @ A.T + b)
        return Placement(A, b, index, weight, held)

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

    def fit(self, placement: Placement, displacement: np.ndarray) -> np.ndarray:
        """(P,) pose weights in [0, FIT_MAX] whose displacement of the placed region best makes `displacement` (M, 3,
        its local coordinates): an example pair's own motion read through the fields. Least squares through the
        composed turns from two starts (the fields' linear read, and every pose at half), the better kept; a weight
        under FIT_DROP is dropped. A fist's twelve knuckles come back at about 1 each, where the hand's latent
        delta read as two knuckles."""
        from scipy.optimize import least_squares

        target = np.asarray(displacement, np.float64).ravel()
        columns = np.stack([self.displacement(placement, e).ravel() for e in np.eye(len(self.poses))], axis=1)
        linear, _ = nnls(columns, target)
        best = None
        for start in (np.clip(linear, 0.0, FIT_MAX), np.full(len(self.poses), 0.5), np.ones(len(self.poses))):
            r = least_squares(lambda w: self.displacement(placement, w).ravel() - target, start, bounds=(0.0, FIT_MAX))
            if best is None or r.cost < best.cost:
                best = r
        return np.where(best.x >= FIT_DROP, best.x, 0.0)

    def displacement(self, placement: Placement, weights: np.ndarray) -> np.ndarray:
        """(M, 3) displacement of the placed region's vertices (their local coordinates) for pose weights (P,) added
        to what the region holds (`Placement.held`): the composed motion of both less the held poses' own."""
        held = placement.held
        if held is None:
            field = self.mixed(weights)  # (N, 3), anchor coordinates
        else:
            field = self.mixed(held + np.asarray(weights, np.float64)) - self.mixed(held)
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
