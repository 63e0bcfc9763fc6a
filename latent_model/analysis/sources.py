"""Encoders under analysis, as `LatentSource`s over the same SDF samples:

- the learned encoder (posterior means), standardised with the latent bank's training statistics;
- the no-learning baseline: the state's SDF samples interpolated onto a fixed grid (inverse
  distance weighting of the nearest samples), then PCA fitted on training states, then the same
  standardisation. It consumes exactly the encoder's input, so its noise floor comes from the
  same SDF re-samplings.
"""
from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree

from latent_model.analysis.latent_space import LatentSource, SampleCache, single_poses
from latent_model.corpus.pairs import FINAL
from latent_model.corpus.store import Corpus


def model_source(model, bank, samples: SampleCache, device: torch.device | None = None) -> LatentSource:
    device = device or torch.device("cpu")

    @torch.no_grad()
    def encode(states: list[int], resample: int) -> np.ndarray:
        out = []
        for i in range(0, len(states), 32):
            batch = [samples.get(s, resample) for s in states[i:i + 32]]
            p = torch.from_numpy(np.stack([b[0] for b in batch])).float().to(device)
            v = torch.from_numpy(np.stack([b[1] for b in batch])).float().to(device)
            out.append(model.encode_mu(p, v).cpu().numpy())
        return np.concatenate(out)

    return LatentSource("model", encode, bank.mean, bank.scale)


class SdfGrid:
    """A fixed grid over the corpus' bodies; `values(points, sdf)` interpolates one state's
    samples onto it (inverse-distance weighting of the k nearest samples)."""

    def __init__(self, corpus: Corpus, spacing: float = 0.05, k: int = 8) -> None:
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for i in corpus.split_indices("train"):
            v = corpus.vertices(corpus.state(i, None, "neutral"))
            lo, hi = np.minimum(lo, v.min(0)), np.maximum(hi, v.max(0))
        lo, hi = lo - 0.05, hi + 0.05
        axes = [np.arange(a, b + 1e-9, spacing) for a, b in zip(lo, hi)]
        self.points = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        self.k = k

    def values(self, points: np.ndarray, sdf: np.ndarray) -> np.ndarray:
        d, idx = cKDTree(points).query(self.points, k=self.k)
        w = 1.0 / (d + 1e-4)
        return (w * sdf[idx]).sum(1) / w.sum(1)


def pca_baseline_source(corpus: Corpus, samples: SampleCache, dims: int, fit_ids: int = 12,
                        grid: SdfGrid | None = None) -> LatentSource:
    """Grid SDF -> PCA (`dims` components) fitted on the training neutrals plus every single
    pose of `fit_ids` training identities; standardised on those fitting states."""
    grid = grid or SdfGrid(corpus)
    train = corpus.split_indices("train")
    fit_states = [corpus.state(i, None, "neutral") for i in train]
    fit_states += [corpus.state(i, p, FINAL) for i in train[:fit_ids] for p in single_poses(tuple(corpus.poses))]

    def raw(states: list[int], resample: int) -> np.ndarray:
        return np.stack([grid.values(*samples.get(s, resample)) for s in states]).astype(np.float32)

    X = raw(fit_states, 0)
    centre = X.mean(0)
    dims = min(dims, len(X) - 1)
    _, _, vt = np.linalg.svd(X - centre, full_matrices=False)
    basis = vt[:dims]  # (dims, G)

    def encode(states: list[int], resample: int) -> np.ndarray:
        return (raw(states, resample) - centre) @ basis.T

    codes = (X - centre) @ basis.T
    return LatentSource(f"pca{dims}", encode, codes.mean(0), codes.std(0) + 1e-6)
