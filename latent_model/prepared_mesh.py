"""A mesh prepared for prediction: what the predictors read from it, each derived once, when first read."""
from __future__ import annotations

from functools import cached_property
from typing import Callable

import numpy as np
import torch

from latent_model.corpus.sdf import vertex_normals
from latent_model.nn.vertex_decoder import knn_graph


class PreparedMesh:
    """A mesh in the model frame (metres, Z up, faces -Y) and what the predictors read from it,
    each derived on first read and cached: normals, neighbourhoods, the latent mean of its SDF
    samples, and the per-device feature caches of the pose fields and the decoder network."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, sdf_faces: np.ndarray, knn_k: int,
                 encode: Callable[[np.ndarray, np.ndarray], np.ndarray], mu: np.ndarray | None = None,
                 surface=None) -> None:
        self.vertices = vertices  # (V, 3) float32
        self.faces = faces  # (F, 3) int64
        self.sdf_faces = sdf_faces  # (F', 3) the closed shell its SDF is sampled on
        self._knn_k = knn_k
        self._encode = encode
        if mu is not None:
            self.__dict__["mu"] = np.asarray(mu, np.float32)
        if surface is not None:
            self.__dict__["surface"] = surface
        self._caches: dict[tuple[str, str], object] = {}

    @cached_property
    def mu(self) -> np.ndarray:
        """(Z,) posterior mean of the mesh's SDF samples."""
        return np.asarray(self._encode(self.vertices, self.sdf_faces), np.float32)

    @cached_property
    def normals(self) -> np.ndarray:
        """(V, 3) unit vertex normals."""
        return vertex_normals(self.vertices, self.faces)

    @cached_property
    def surface(self):
        """`surface.SurfaceFeatures`: geodesic coordinates, limb frames, medial points (the motion decoder's)."""
        from latent_model.surface import surface_features

        return surface_features(self.vertices, self.faces)

    @cached_property
    def knn(self) -> np.ndarray:
        """(V, K) each vertex's nearest other vertices (the decoder's refinement neighbourhoods)."""
        return knn_graph(self.vertices, self._knn_k)

    def derived(self) -> set[str]:
        """Which of mu, normals, knn, surface have been computed (or given)."""
        return {k for k in ("mu", "normals", "knn", "surface") if k in self.__dict__}

    def cached(self, name: str, device: torch.device | str) -> bool:
        """Whether `cache(name, device, ...)` is already made."""
        return (name, str(device)) in self._caches

    def cache(self, name: str, device: torch.device | str, make: Callable[[], object]):
        """A per-device cache entry (`make()` on first use); `device` may name an owner too (a model's weights, a
        bank) where the entry depends on it."""
        key = (name, str(device))
        if key not in self._caches:
            self._caches[key] = make()
        return self._caches[key]
