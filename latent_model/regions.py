"""Regions of local detail (the head, each hand) sampled as signed distances at their own scale.

The body's SDF samples put a few hundred points on a face and its reconstruction error (~6 mm) is larger
than a brow's motion: the global code cannot see a face or a finger. Here each region is located on the
surface (`surface.detail_depth`: any rest pose, any topology), given a frame that turns with it (the head:
the mean of its vertices' limb frames; a hand: its own principal axes, so a hand held anywhere reads the
same) and a scale (its area-weighted RMS radius), and sampled inside that frame: points are region-local and
in units of the radius, signed distances too. The left hand is mirrored (its lateral axis negated) so one hand encoder reads both hands.

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
FOLLOW_TOLERANCE = 0.01  # of a region's radius: a vertex this close to its rigid motion counts as still
# a hand's principal axes need this ratio between successive spreads (length / width, width / thickness) to be
# told apart; anny's hands: >= 1.43 and >= 6 (a hand that is not, e.g. a ball of a fist, keeps its limb frame)
AXES_SEPARATION = 1.15


@dataclass(frozen=True)
class RegionSampling:
    """SDF samples per region state: near the region's vertices (Gaussian offsets, as fractions of its radius)
    and uniform in its frame's box [-box, box]^3 (radius units)."""

    k: int = 2048
    near_sigmas: tuple[float, float] = (0.01, 0.05)
    near_fractions: tuple[float, float] = (0.45, 0.45)
    box: float = 1.6
    # a hand's near samples drawn in proportion to depth ** this (0: every vertex alike), so the fingers, not the
    # palm and wrist, get most of them
    hand_depth_power: float = 0.0

    def __post_init__(self) -> None:
        if isinstance(self.k, bool) or not isinstance(self.k, (int, np.integer)) or self.k < 1:
            raise ValueError(f"RegionSampling.k must be a positive integer, got {self.k!r}")
        if not (math.isfinite(self.hand_depth_power) and self.hand_depth_power >= 0):
            raise ValueError(f"RegionSampling.hand_depth_power must be >= 0, got {self.hand_depth_power!r}")
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
        """This frame carried by the rigid motion of the region's still part from `rest` (V, 3) to `moved`
        (V, 3), the same mesh deformed (`rigid_motion`): a head turned, a hand carried by the forearm, leave
        its local coordinates unchanged, and a brow or a curled finger does not tilt them, so a region's code
        and its local displacement hold the deformation only."""
        r, t = rigid_motion(rest[self.vertices], moved[self.vertices], self.depth, FOLLOW_TOLERANCE * self.radius)
        return replace(self, centre=r @ self.centre + t, rotation=r @ self.rotation)

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


def _weighted_fit(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    w = w / w.sum()
    ca, cb = w @ a, w @ b
    r = _nearest_rotation(((b - cb) * w[:, None]).T @ (a - ca))
    return r, cb - r @ ca


def principal_frame(points: np.ndarray, weights: np.ndarray, limb: np.ndarray) -> np.ndarray:
    """(3, 3) rotation whose columns are the principal axes of `points` (N, 3) under `weights` (N,) (summing to
    1), longest first, each signed to agree with the same column of `limb` (3, 3) (t along the limb, u forward);
    `limb` itself when the spreads are too alike to order (`AXES_SEPARATION`). A hand's limb frame takes its
    forward axis from the world, so it turned 6-17° about the hand between rest poses (arms raised, T-pose) while
    the hand itself stayed rigid; the hand's own axes turn with it (0.2-5°)."""
    d = points - weights @ points
    spread, axes = np.linalg.eigh((d * weights[:, None]).T @ d)  # ascending
    if spread[2] < AXES_SEPARATION * spread[1] or spread[1] < AXES_SEPARATION * spread[0]:
        return limb
    t, u = axes[:, 2], axes[:, 1]
    t = t if t @ limb[:, 0] >= 0 else -t
    u = u if u @ limb[:, 1] >= 0 else -u
    return np.stack([t, u, np.cross(t, u)], axis=1)


def rigid_motion(a: np.ndarray, b: np.ndarray, depth: np.ndarray, tolerance: float,
                 iterations: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), t (3,)) taking the largest near-rigid part of points `a` (N, 3) onto `b` (N, 3): b ~ a R^T + t.

    A plain least-squares fit of a whole region tilts with whatever moves inside it (a mouth corner, a fist) and
    spreads that tilt over the still skin. Iteratively reweighted fits (Gaussian weights at twice the 10 % quantile
    of the residuals) lock onto a rigid part; two starts (all points, and the region's base: low `depth`, where a
    curled hand is still) and the one with more points within `tolerance` (metres) wins."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    best, best_count = None, -1
    for w in (np.ones(len(a)), np.exp(-(np.asarray(depth, np.float64) / 0.25) ** 2) + 1e-6):
        for _ in range(iterations):
            r, t = _weighted_fit(a, b, w)
            res = np.linalg.norm(a @ r.T + t - b, axis=1)
            s = max(2.0 * float(np.quantile(res, 0.1)), 0.1 * tolerance)
            w = np.exp(-((res / s) ** 2)) + 1e-9
        count = int((res < tolerance).sum())
        if count > best_count:
            best, best_count = (r, t), count
    return best


def region_frames(vertices: np.ndarray, faces: np.ndarray, features=None) -> dict[str, RegionFrame]:
    """The head's and both hands' frames on a humanoid mesh (V, 3) in the canonical frame (Z up, facing -Y).
    `features`: its `surface.SurfaceFeatures` if already computed."""
    from latent_model.surface import detail_depth, surface_features

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    sf = features if features is not None else surface_features(v, f)
    depths = detail_depth(sf.coords)
    areas = _vertex_areas(v, f)
    out = {}
    for name in REGIONS:
        idx = np.flatnonzero(depths[name] > 0)
        if len(idx) < 16:
            raise ValueError(f"the {name.replace('_', ' ')} region has {len(idx)} vertices: the mesh is not a "
                             "humanoid the surface features can read")
        w = areas[idx] / areas[idx].sum()
        centre = w @ v[idx]
        rotation = _nearest_rotation(np.einsum("n,nij->ij", w, sf.frames[idx].astype(np.float64)))
        if REGION_KIND[name] == "hand":
            rotation = principal_frame(v[idx], w, rotation)
        radius = float(np.sqrt(w @ ((v[idx] - centre) ** 2).sum(axis=1)))
        depth = depths[name][idx]
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
    if cfg.hand_depth_power > 0 and frame.name.startswith("hand"):
        w = np.asarray(frame.depth, np.float64) ** cfg.hand_depth_power
        picks = frame.vertices[rng.choice(len(frame.vertices), n0 + n1, p=w / w.sum())]
    else:
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
