"""Small building blocks shared by the networks."""
from __future__ import annotations

import math

import torch
from torch import nn


def fourier_features(x: torch.Tensor, n_freq: int) -> torch.Tensor:
    """(..., 3) -> (..., 3 + 6 n_freq): x, sin(2^k pi x), cos(2^k pi x). Positions are in metres
    (a body spans ~2 m), so k = 0..n_freq-1 resolves ~2 m down to ~2 m / 2^n_freq."""
    if n_freq <= 0:
        return x
    freqs = (2.0 ** torch.arange(n_freq, dtype=x.dtype, device=x.device)) * math.pi
    xf = x[..., None] * freqs  # (..., 3, F)
    return torch.cat([x, torch.sin(xf).flatten(-2), torch.cos(xf).flatten(-2)], dim=-1)


def mlp(sizes: list[int], final_act: bool = False) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2 or final_act:
            layers.append(nn.SiLU())
    return nn.Sequential(*layers)
