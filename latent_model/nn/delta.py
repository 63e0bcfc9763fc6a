"""The paper's normalisation of a latent delta: Δμ -> (unit direction Δμ̄, magnitude r)."""
from __future__ import annotations

import torch

EPS_NORM = 1e-8


def normalised_delta(delta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(N, Z) raw delta -> (direction (N, Z), magnitude r (N,))."""
    r = delta.norm(dim=-1)
    return delta / (r[:, None] + EPS_NORM), r
