"""Where a vertex is on a humanoid, whatever its rest pose: intrinsic coordinates and limb frames.

A decoder that reads world positions learns "the forearm is at this place of the bounding box", which
fails as soon as the arms stand elsewhere. Surface (geodesic) distances hardly change when a limb
turns at a joint, so they locate a body part in any rest pose; a frame that turns with the limb lets a
motion learnt in one rest be expressed in another. For a mesh (V, 3) + faces:

- ``coords`` (V, 6): geodesic distances, divided by the height, from the torso centre and from the five
  extremities (head top, left and right hand, left and right foot), found as the farthest points of
  the surface from the centre and named by where they are (the head highest, the feet lowest, left is
  +X, the character's left, as in anny);
- ``frames`` (V, 3, 3): columns (t, u, w): t along the limb, away from the centre (the smoothed surface
  gradient of the centre distance), u the character's forward axis made orthogonal to t, w = t x u;
- ``medial`` (V, 3): the centre of each vertex's cross-section (vertices near it at the same six
  distances), a point on the limb's axis about which a joint's rotation is expressed.
Distances run over the mesh's edges (Dijkstra); parts the body surface does not reach (eyes, teeth,
a separate shell of a user's mesh) take the values of their nearest reached vertex. Any topology.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

VERSION = 4  # of what surface_features computes (caches of it are keyed by it); 3: the torso patch alone as the centre;
# 4: the head named by its height less its sideways offset, not its height alone
FORWARD = np.array([0.0, -1.0, 0.0])  # anny faces -Y (Z up); imported meshes are brought to this frame
EXTREMITIES = ("head", "hand_left", "hand_right", "foot_left", "foot_right")


@dataclass
class SurfaceFeatures:
    """Per-vertex intrinsic coordinates (V, 6), limb frames (V, 3, 3) and medial points (V, 3), float32."""

    coords: np.ndarray
    frames: np.ndarray
    medial: np.ndarray
    extremities: dict[str, int]  # name -> vertex index


# A hand no farther from the torso over the surface than this many times the head's (extremity to the torso centre)
# is joined to the body elsewhere than at the shoulder: a remesh or a scan that fused a hand to the thigh makes the
# path from the torso to the hand run down the leg, and the arm's motion then carries the thigh. The corpus's training
# and validation characters: 1.05-1.42 (128 in their rests, median 1.22); validation characters remeshed by marching
# cubes at 7 mm, arms at the sides, hands fused to the thighs: 0.88 and 0.96 (arm poses 0.58 explained, 0.81 unfused)
HAND_REACH_MIN = 1.0


def joined_hands(features: SurfaceFeatures) -> dict[str, float]:
    """{hand: its reach from the torso over the head's} for the hands reaching less than `HAND_REACH_MIN`: hands the
    surface joins to the body elsewhere than at the shoulder."""
    if not {"head", "hand_left", "hand_right"} <= features.extremities.keys():
        return {}  # features kept without their extremities (`surface_cache`: corpus states, not a user's mesh)
    reach = lambda k: float(features.coords[features.extremities[k], 0])  # noqa: E731  centre distance / height
    head = max(reach("head"), 1e-6)
    return {k: reach(k) / head for k in ("hand_left", "hand_right") if reach(k) / head < HAND_REACH_MIN}


def _edge_graph(vertices: np.ndarray, faces: np.ndarray):
    import scipy.sparse as sp

    from latent_model.topology import mesh_edges

    e = mesh_edges(faces)
    w = np.linalg.norm(vertices[e[:, 0]] - vertices[e[:, 1]], axis=1) + 1e-9
    n = len(vertices)
    return sp.coo_matrix((np.concatenate([w, w]), (np.concatenate([e[:, 0], e[:, 1]]),
                                                    np.concatenate([e[:, 1], e[:, 0]]))), shape=(n, n)).tocsr()


def _distances(graph, sources: np.ndarray, offsets: np.ndarray | None = None) -> np.ndarray:
    """(V,) shortest edge-path distance from the nearest of `sources` (plus its start offset)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import dijkstra

    if offsets is None and len(sources) == 1:
        return dijkstra(graph, indices=int(sources[0]))
    n = graph.shape[0]
    off = np.zeros(len(sources)) if offsets is None else offsets
    # a virtual node joined to every source by its offset: one run gives the min over sources
    link = sp.coo_matrix((off + 1e-9, (np.full(len(sources), n), sources)), shape=(n + 1, n + 1))
    g = sp.bmat([[graph, None], [None, sp.csr_matrix((1, 1))]]).tocsr() + link.tocsr()
    return dijkstra(g, indices=n)[:n]


def _cross_section_pairs(v: np.ndarray, dist: np.ndarray, sub: np.ndarray, radius: float, band: float
                         ) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols): the pairs (vertex, subsample point) within `radius` in space whose six distances (V, 6) all
    differ by less than `band`, in no particular order. One k-d tree query over positions and distances together
    (a box of half-width `radius` in space, `band` in each distance, scaled alike) finds a superset of them, 0.6 of the
    pairs a ball query in space alone returns, and the exact tests keep the same pairs as that query filtered column by
    column (the band test only where the box's edge is within rounding)."""
    from scipy.spatial import cKDTree

    scale = radius / band
    points = np.concatenate([v, dist * scale], axis=1)
    box = cKDTree(points).sparse_distance_matrix(cKDTree(points[sub]), radius * (1 + 1e-9), p=np.inf,
                                                 output_type="coo_matrix")
    row, col = box.row, box.col
    d = v[row] - v[sub][col]
    keep = np.einsum("ij,ij->i", d, d) <= radius * radius
    edge = np.flatnonzero(keep & (box.data >= radius * (1 - 1e-9)))  # inside the box by less than rounding:
    for k in range(dist.shape[1]):  # the exact distance test (the others are well inside every band)
        keep[edge] &= np.abs(dist[row[edge], k] - dist[sub, k][col[edge]]) < band
    return row[keep], col[keep]


def _fill_unreached(vertices: np.ndarray, values: np.ndarray, reached: np.ndarray) -> np.ndarray:
    from scipy.spatial import cKDTree

    if reached.all():
        return values
    _, j = cKDTree(vertices[reached]).query(vertices[~reached])
    out = values.copy()
    out[~reached] = values[reached][j]
    return out


def surface_features(vertices: np.ndarray, faces: np.ndarray, smooth: int = 20) -> SurfaceFeatures:
    """Intrinsic coordinates, limb frames and medial points of a humanoid mesh (Z up, facing -Y)."""
    import scipy.sparse as sp
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    height = float(np.ptp(v[:, 2])) or 1.0
    graph = _edge_graph(v, f)
    # the torso centre: surface points near the body's area centroid (not the vertex mean: heads and
    # hands are densely meshed), each starting at its distance to it
    area = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    centroid = (area[:, None] * v[f].mean(axis=1)).sum(axis=0) / area.sum()
    d0 = np.linalg.norm(v - centroid, axis=1)
    near = _torso_patch(graph, d0 < d0.min() + 0.08 * height, int(np.argmin(d0)))
    d_c = _distances(graph, near, d0[near] - d0[near].min())
    reached = np.isfinite(d_c)
    # the body surface is the component of the centre; extremities: farthest points of it, in turn
    picks, fields = [], []
    nearest = d_c.copy()
    for _ in range(len(EXTREMITIES)):
        i = int(np.argmax(np.where(reached, nearest, -np.inf)))
        d = _distances(graph, np.array([i]))
        picks.append(i)
        fields.append(d)
        nearest = np.minimum(nearest, d)
    order = _name_extremities(v[picks], centroid)
    extremities = {name: picks[k] for name, k in zip(EXTREMITIES, order)}
    dist = np.stack([d_c] + [fields[k] for k in order], axis=1)
    dist = _fill_unreached(v, dist, reached)
    coords = dist / height
    # t: the surface gradient of the centre distance, averaged over neighbourhoods (limb scale)
    import igl

    grad = igl.grad(v, f) @ coords[:, 0]  # (F*3,) per-face gradient, stacked x then y then z
    gf = grad.reshape(3, -1).T
    rows = np.repeat(np.arange(len(f)), 3)
    vf = sp.coo_matrix((np.repeat(area, 3), (f.ravel(), rows)), shape=(len(v), len(f))).tocsr()
    t = vf @ gf
    adj = (graph > 0).astype(np.float64)
    adj = sp.diags(1.0 / (adj.sum(axis=1).A1 + 1.0)) @ (adj + sp.eye(len(v)))  # mean over self + neighbours
    for _ in range(smooth):
        t = adj @ t
    t = _fill_unreached(v, t, reached & (np.linalg.norm(t, axis=1) > 1e-12))
    t /= np.linalg.norm(t, axis=1, keepdims=True) + 1e-12
    u = FORWARD[None] - (t @ FORWARD)[:, None] * t
    weak = np.linalg.norm(u, axis=1) < 0.3  # t along the forward axis (a foot): fall back to up
    up = np.array([0.0, 0.0, 1.0])
    u[weak] = up[None] - (t[weak] @ up)[:, None] * t[weak]
    u /= np.linalg.norm(u, axis=1, keepdims=True) + 1e-12
    frames = np.stack([t, u, np.cross(t, u)], axis=2)
    # medial points: the mean of nearby vertices at about the same centre distance (a cross-section),
    # over a seeded subsample of the surface (one sparse product instead of a ball query per vertex)
    radius, band = 0.06 * height, 0.025 * height
    sub = np.random.default_rng(0).choice(len(v), size=min(len(v), 4000), replace=False)
    row, col = _cross_section_pairs(v, dist, sub, radius, band)
    count = np.bincount(row, minlength=len(v))  # sums by bincount: a sparse matrix of the 1.5M pairs took 3x as long
    total = np.stack([np.bincount(row, weights=v[sub, k][col], minlength=len(v)) for k in range(3)], axis=1)
    medial = np.where(count[:, None] > 0, total / np.maximum(count, 1)[:, None], v)
    # smoothed over the surface as t is: raw cross-section means jump by cm between neighbours, and a
    # joint's pivot that jumps turns neighbouring vertices about different points (a crumpled hand)
    for _ in range(smooth):
        medial = adj @ medial
    return SurfaceFeatures(coords.astype(np.float32), frames.astype(np.float32), medial.astype(np.float32),
                           extremities)


def _torso_patch(graph, band: np.ndarray, seed: int) -> np.ndarray:
    """Indices of the vertices of `band` (V,) bool connected within it to `seed`: the torso's surface near the
    centroid. Arms hanging at the sides lie in the band too, but apart from the torso's patch; taken as the centre,
    their fingertips were as near to it as the navel and the shoulders became the "hands"."""
    from scipy.sparse.csgraph import connected_components

    idx = np.flatnonzero(band)
    _, label = connected_components(graph[idx][:, idx], directed=False)
    return idx[label == label[np.searchsorted(idx, seed)]]


def _name_extremities(points: np.ndarray, centre: np.ndarray) -> list[int]:
    """Indices of (head, hand left, hand right, foot left, foot right) among five extremity points (5, 3):
    the two lowest are the feet; of the other three the head stands highest counting twice its sideways offset
    from the body's centre (3,) against it. Not the highest alone (a hand raised above the head was named the
    head), nor the nearest the torso over the surface (a hand against the thigh, joined to it by a remesh, is)."""
    by_z = list(np.argsort(points[:, 2]))
    feet, upper = by_z[:2], by_z[2:]
    head = max(upper, key=lambda k: float(points[k, 2] - 2.0 * abs(points[k, 0] - centre[0])))
    hands = [k for k in upper if k != head]
    feet.sort(key=lambda k: -points[k, 0])
    hands.sort(key=lambda k: -points[k, 0])
    return [int(head), int(hands[0]), int(hands[1]), int(feet[0]), int(feet[1])]


# How far (geodesic, over the height) a detail region reaches: the head from its top over the face (the path runs
# over the brow and nose) to below the chin (an open jaw moves skin at 0.23 H on anny); a hand from its extremity
# down the arm to the wrist (0.11 H), measured as distance from the torso centre, so every finger of the hand is in.
DETAIL_REACH = {"head": 0.24, "hand_left": 0.12, "hand_right": 0.12}
# A hand's vertices lie this near (geodesic, over the height) to its extremity: the farthest fingertip and thumb of a
# large hand are 0.15-0.2 H away over the palm, so a ball of 0.12 H about the middle fingertip (the regions before)
# left half of a large hand's little finger out of the region.
HAND_BALL = 0.25


def detail_depth(coords: np.ndarray) -> dict[str, np.ndarray]:
    """{region: (V,) depth}: > 0 inside the region of local detail (the head, each hand), 1 at its extremity, 0 at
    its boundary (the neck, the wrist), <= 0 outside; from `SurfaceFeatures.coords` (V, 6), so in any rest pose
    and topology. The head is a ball about its top; a hand is cut across the wrist: what lies within
    DETAIL_REACH of the extremity's distance from the torso centre."""
    out = {}
    for name, reach in DETAIL_REACH.items():
        own = coords[:, 1 + EXTREMITIES.index(name)].astype(np.float64)
        if name == "head":
            out[name] = 1.0 - own / reach
        else:
            centre = coords[:, 0].astype(np.float64)
            tip = centre[int(np.argmin(own))]
            out[name] = np.where(own < HAND_BALL, np.minimum(1.0 - (tip - centre) / reach, 1.0), -1.0)
    return out


def detail_regions(coords: np.ndarray) -> dict[str, np.ndarray]:
    """(V,) bool masks of the regions of local detail (the head, each hand): `detail_depth` > 0."""
    return {name: depth > 0 for name, depth in detail_depth(coords).items()}
