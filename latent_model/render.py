"""Small orthographic mesh renderer on matplotlib (painter's algorithm, Lambert shading).

Used for contact sheets and report figures: no GPU or VTK needed, ~0.3 s per 27k-face mesh.
"""
from __future__ import annotations

import numpy as np

# View name -> (right, up) axes of the image plane in model coordinates (Z up, faces -Y).
VIEWS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "front": ((1, 0, 0), (0, 0, 1)),  # looking along +Y at the character's face
    "side": ((0, -1, 0), (0, 0, 1)),  # from the character's left (+X)
    "back": ((-1, 0, 0), (0, 0, 1)),
}


def project(vertices: np.ndarray, view: str) -> tuple[np.ndarray, np.ndarray]:
    """(V, 2) image coordinates and (V,) depth (larger = nearer the viewer)."""
    right, up = (np.asarray(a, dtype=np.float64) for a in VIEWS[view])
    toward_viewer = np.cross(right, up)
    return np.stack([vertices @ right, vertices @ up], axis=1), vertices @ toward_viewer


def draw_mesh(ax, vertices: np.ndarray, faces: np.ndarray, view: str = "front",
              values: np.ndarray | None = None, cmap: str = "viridis",
              vmin: float | None = None, vmax: float | None = None,
              base_color=(0.78, 0.74, 0.70)) -> None:
    """Draw a shaded mesh (V, 3)/(F, 3) on a matplotlib Axes; optional per-vertex `values`
    (V,) are colour-mapped instead of the base colour."""
    import matplotlib
    from matplotlib.collections import PolyCollection

    xy, depth = project(vertices, view)
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
    right, up = (np.asarray(a, dtype=np.float64) for a in VIEWS[view])
    toward = np.cross(right, up)
    facing = n @ toward
    keep = facing > 0  # back-face culling (closed meshes)
    light = 0.25 + 0.75 * np.clip(n[keep] @ (0.35 * right + 0.45 * up + toward) / np.linalg.norm(0.35 * right + 0.45 * up + toward), 0, 1)
    order = np.argsort(depth[faces[keep]].mean(axis=1))
    if values is None:
        rgb = np.tile(np.asarray(base_color), (keep.sum(), 1))
    else:
        fv = values[faces[keep]].mean(axis=1)
        lo = np.nanmin(fv) if vmin is None else vmin
        hi = np.nanmax(fv) if vmax is None else vmax
        rgb = matplotlib.colormaps[cmap](np.clip((fv - lo) / max(hi - lo, 1e-12), 0, 1))[:, :3]
    rgb = np.clip(rgb * light[:, None], 0, 1)
    polys = xy[faces[keep]][order]
    ax.add_collection(PolyCollection(polys, facecolors=rgb[order], edgecolors="none", antialiased=False))
    ax.set_xlim(xy[:, 0].min(), xy[:, 0].max())
    ax.set_ylim(xy[:, 1].min(), xy[:, 1].max())
    ax.set_aspect("equal")
    ax.axis("off")
