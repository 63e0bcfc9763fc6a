"""The one loop that encodes SDF sample sets with the frozen encoder: corpus states (stored samples or
an independent re-sampling), geometry rows, or a user's mesh all go through `encode_sample_sets`."""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
import torch

CHUNK = 32  # sample sets per encoder call


@torch.no_grad()
def encode_sample_sets(model, items: Sequence, samples: Callable[[object], tuple[np.ndarray, np.ndarray]],
                       device: torch.device | None = None, progress: bool = False, desc: str = "encoding") -> np.ndarray:
    """(n, Z) posterior means of the sample sets `samples(item)` = (points (K, 3), values (K,)) of
    `items`, CHUNK at a time."""
    from tqdm import tqdm

    device = device or torch.device("cpu")
    out = []
    for i in tqdm(range(0, len(items), CHUNK), disable=not progress, desc=desc, unit="batch"):
        batch = [samples(x) for x in items[i:i + CHUNK]]
        p = torch.from_numpy(np.stack([b[0] for b in batch])).float().to(device)
        v = torch.from_numpy(np.stack([b[1] for b in batch])).float().to(device)
        out.append(model.encode_mu(p, v).cpu().numpy())
    return np.concatenate(out) if out else np.zeros((0, model.cfg.latent), np.float32)


def encode_states(model, corpus, states: list[int], device: torch.device | None = None,
                  resample: int = 0, progress: bool = False) -> np.ndarray:
    """Posterior means (n, Z) of corpus states (stored samples, or an independent re-sampling)."""
    return encode_sample_sets(model, states, lambda s: corpus.resample_sdf(s, resample), device, progress)


def encode_rows(model, corpus, rows: list[int], device: torch.device, progress: bool = True) -> torch.Tensor:
    """Frozen-encoder means (G, Z) indexed by geometry row: the given rows from their stored samples,
    the other rows 0."""
    out = torch.zeros(corpus.manifest["n_geometries"], model.cfg.latent)
    mu = encode_sample_sets(model, rows, corpus.sdf_of_row, device, progress, desc="encoding states")
    if len(rows):
        out[rows] = torch.from_numpy(mu)
    return out
