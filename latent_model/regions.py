"""Regions of local detail (the head, each hand) sampled as signed distances at their own scale.

The body's SDF samples put a few hundred points on a face and its reconstruction error (~6 mm) is larger
than a brow's motion: the global code cannot see a face or a finger. Here each region is located on the
surface (`surface.detail_regions`: any rest pose, any topology), given a frame that turns with it (the mean
of its vertices' limb frames, so a hand held anywhere reads the same) and a scale (its area-weighted RMS
radius), and sampled inside that frame: points are region-local and in units of the radius, signed
distances too. The left hand is mirrored (its lateral axis negated) so one hand encoder reads both hands.

Co-moving samples: the near-surface points are drawn as (a seeded region vertex + a seeded offset), so two
states of one mesh topology sampled with one seed and the first state's frame put each point on the same
skin. A pair's delta then holds the motion, not the resampling noise of two independent draws.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
import math

import numpy as np

REGIONS = ("head", "hand_left", "hand_right")
REGION_KIND = {"head": "head", "hand_left": "hand", "hand_right": "hand"}  # which encoder reads a region
MIRRORED = {"hand_left"}  # read as a right hand: one hand encoder for both


@dataclass(frozen=True)
class RegionSampling:
    """SDF samples per region state: near the region's vertices (Gaussian offsets, as fractions of its radius)
    and uniform in its frame's box [-box, box]^3 (radius units)."""

    k: int = 2048
    near_sigmas: tuple[float, float] = (0.01, 0.05)
    near_fractions: tuple[float, float] = (0.45, 0.45)
    box: float = 1.6

    def __post_init__(self) -> None:
        if isinstance(self.k, bool) or not isinstance(self.k, (int, np.integer)) or self.k < 1:
            raise ValueError(f"RegionSampling.k must be a positive integer, got {self.k!r}")
        if any(not (math.isfinite(s) and s > 0) for s in self.near_sigmas) or sum(self.near_fractions) > 1:
            raise ValueError(f"RegionSampling: sigmas must be > 0 and fractions sum to <= 1, got {self!r}")

    def counts(self) -> tuple[int, int, int]:
        near = [int(math.floor(self.k * f + 1e-9)) for f in self.near_fractions]
        return near[0], near[1], self.k - sum(near)


@dataclass(frozen=True)
class RegionFrame:
    """Where a region is: its vertices (indices into the mesh), how deep each lies in it (0 at its boundary, 1
    at its extremity: the head top, a fingertip), centre (3,), rotation (3, 3) whose columns are the region's
    axes in world coordinates, radius (metres) and whether it is read mirrored."""

    name: str
    vertices: np.ndarray = field(repr=False)
    depth: np.ndarray = field(repr=False)
    centre: np.ndarray
    rotation: np.ndarray
    radius: float
    mirrored: bool

    def follow(self, rest: np.ndarray, moved: np.ndarray) -> "RegionFrame":
        """This frame carried by the best rigid motion of its vertices from `rest` (V, 3) to `moved` (V, 3), the
        same mesh deformed: the region's own rigid motion (a head turned, a hand carried by the forearm) leaves
        its local coordinates unchanged, so a region's code sees its deformation only."""
        a, b = rest[self.vertices].astype(np.float64), moved[self.vertices].astype(np.float64)
        ca, cb = a.mean(axis=0), b.mean(axis=0)
        r = _nearest_rotation((b - cb).T @ (a - ca))
        return replace(self, centre=r @ (self.centre - ca) + cb, rotation=r @ self.rotation)

    def to_local(self, x: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> region-local (N, 3) in radius units (mirrored where the frame is)."""
        y = (np.asarray(x, dtype=np.float64) - self.centre) @ self.rotation / self.radius
        if self.mirrored:
            y[:, 2] = -y[:, 2]
        return y


def _vertex_areas(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    return np.bincount(f.ravel(), weights=np.repeat(area / 3.0, 3), minlength=len(v))


def _nearest_rotation(m: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(m)
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] = -u[:, -1]
        r = u @ vt
    return r


def region_frames(vertices: np.ndarray, faces: np.ndarray, features=None) -> dict[str, RegionFrame]:
    """The head's and both hands' frames on a humanoid mesh (V, 3) in the canonical frame (Z up, facing -Y).
    `features`: its `surface.SurfaceFeatures` if already computed."""
    from latent_model.surface import DETAIL_REACH, EXTREMITIES, detail_regions, surface_features

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    sf = features if features is not None else surface_features(v, f)
    masks = detail_regions(sf.coords)
    areas = _vertex_areas(v, f)
    out = {}
    for name in REGIONS:
        idx = np.flatnonzero(masks[name])
        if len(idx) < 16:
            raise ValueError(f"the {name.replace('_', ' ')} region has {len(idx)} vertices: the mesh is not a "
                             "humanoid the surface features can read")
        w = areas[idx] / areas[idx].sum()
        centre = w @ v[idx]
        rotation = _nearest_rotation(np.einsum("n,nij->ij", w, sf.frames[idx].astype(np.float64)))
        radius = float(np.sqrt(w @ ((v[idx] - centre) ** 2).sum(axis=1)))
        depth = 1.0 - sf.coords[idx, 1 + EXTREMITIES.index(name)] / DETAIL_REACH[name]
        out[name] = RegionFrame(name, idx, depth.astype(np.float32), centre, rotation, radius, name in MIRRORED)
    return out


def sample_region(vertices: np.ndarray, body_faces: np.ndarray, frame: RegionFrame, cfg: RegionSampling,
                  seed: int, rest: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(K, 3) region-local points and (K,) signed distances in radius units of the mesh `vertices` (V, 3) in
    `frame`, its neutral's. `rest`: that neutral (V, 3) when `vertices` is a deformed state of it; the frame then
    follows the region's rigid motion and the samples move with its skin (one seed: co-moving). Negative inside."""
    from latent_model.corpus.sdf import signed_distance

    rng = np.random.default_rng(seed)
    n0, n1, nu = cfg.counts()
    v = np.asarray(vertices, dtype=np.float64)
    if rest is not None:
        frame = frame.follow(rest, v)
    picks = frame.vertices[rng.integers(0, len(frame.vertices), n0 + n1)]
    sigma = np.repeat(np.asarray(cfg.near_sigmas), [n0, n1])[:, None] * frame.radius
    # offsets drawn in the region's frame, so a turned region carries them with it
    near = v[picks] + (rng.standard_normal((n0 + n1, 3)) * sigma) @ frame.rotation.T
    local_uniform = rng.uniform(-cfg.box, cfg.box, size=(nu, 3))
    if frame.mirrored:
        local_uniform[:, 2] = -local_uniform[:, 2]
    uniform = frame.centre + (local_uniform * frame.radius) @ frame.rotation.T
    world = np.concatenate([near, uniform])
    values = signed_distance(world, v, body_faces) / frame.radius
    return frame.to_local(world).astype(np.float32), values.astype(np.float32)
