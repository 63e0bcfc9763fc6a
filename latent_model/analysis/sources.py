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
from sklearn.decomposition import PCA

from latent_model.analysis.latent_space import LatentSource, SampleCache, single_poses
from latent_model.types import FINAL
from latent_model.corpus.store import Corpus
from latent_model.encoding import encode_sample_sets


def model_source(model, bank, samples: SampleCache, device: torch.device | None = None) -> LatentSource:
    def encode(states: list[int], resample: int) -> np.ndarray:
        return encode_sample_sets(model, states, lambda s: samples.get(s, resample), device)

    return LatentSource("model", encode, bank.mean, bank.scale)


class SdfGrid:
    """A fixed grid over the corpus' bodies; `values(points, sdf)` interpolates one state's
    samples onto it (inverse-distance weighting of the k nearest samples); `of_state` memoises that
    per (state, resample), so the PCA baselines of every size share one interpolation per state."""

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
        self._memo: dict[tuple[int, int], np.ndarray] = {}

    def of_state(self, samples: SampleCache, state: int, resample: int) -> np.ndarray:
        """(G,) grid values of a state's stored (resample 0) or re-drawn samples."""
        key = (state, resample)
        if key not in self._memo:
            self._memo[key] = self.values(*samples.get(state, resample)).astype(np.float32)
        return self._memo[key]

    def values(self, points: np.ndarray, sdf: np.ndarray) -> np.ndarray:
        d, idx = cKDTree(points).query(self.points, k=self.k, workers=-1)
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
        return np.stack([grid.of_state(samples, s, resample) for s in states])

    X = raw(fit_states, 0)
    dims = min(dims, len(X) - 1)
    pca = PCA(n_components=dims, svd_solver="full").fit(X)

    def encode(states: list[int], resample: int) -> np.ndarray:
        return pca.transform(raw(states, resample))

    codes = pca.transform(X)
    return LatentSource(f"pca{dims}", encode, codes.mean(0), codes.std(0) + 1e-6)
