"""Connectivity of a triangle mesh, whatever it is (numpy only: the bottom layer, read by the corpus, the networks,
the surface features and the metrics)."""
from __future__ import annotations

import numpy as np


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """(E, 2) int64 the undirected edges of triangles (F, 3), each once as (lower, higher) index, sorted: what
    ``np.unique(np.sort(edges, axis=1), axis=0)`` gives, from a 1-D key (several times faster than rows)."""
    f = np.asarray(faces, dtype=np.int64)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    n = int(e.max()) + 1 if len(e) else 1
    key = np.unique(e[:, 0] * n + e[:, 1])
    return np.stack([key // n, key % n], axis=1)
