"""Permutation-invariant set encoder over SDF samples (x, s) -> (mu, log sigma^2)."""
from __future__ import annotations

import torch
from torch import nn

from latent_model.config import ModelConfig
from latent_model.nn.common import fourier_features, mlp

SDF_INPUT_SCALE = 10.0  # s in metres x 10: near-surface values of a few mm stay informative
SDF_INPUT_CLIP = 1.0


class SdfSetEncoder(nn.Module):
    """Per-point MLP on (Fourier(x), s), then multi-head attention pooling.

    Attention pooling is a softmax-weighted *mean* over points, so the code does not depend
    on the number of samples (train on subsets, encode all K at inference) and can focus on
    informative regions (hands, face) that plain mean pooling would drown.
    """

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        d_in = 3 + 6 * cfg.enc_fourier + 1
        widths = [d_in, *cfg.enc_hidden]
        self.point = mlp(widths, final_act=True)
        h = widths[-1]
        self.score = nn.Linear(h, cfg.enc_heads)
        self.out = mlp([h * cfg.enc_heads, cfg.enc_out_hidden, 2 * cfg.latent])
        # Start with a narrow posterior (sigma ~ 0.05): with sigma ~ 1 the sampled z drowns mu
        # and the SDF decoder learns to ignore the code (posterior collapse).
        with torch.no_grad():
            self.out[-1].bias[cfg.latent:] = -6.0

    def forward(self, points: torch.Tensor, values: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """points (B, K, 3), values (B, K) -> mu (B, Z), logvar (B, Z)."""
        s = (values * SDF_INPUT_SCALE).clamp(-SDF_INPUT_CLIP, SDF_INPUT_CLIP)[..., None]
        f = self.point(torch.cat([fourier_features(points, self.cfg.enc_fourier), s], dim=-1))  # (B, K, H)
        w = torch.softmax(self.score(f), dim=1)  # (B, K, heads)
        pooled = torch.einsum("bkh,bkc->bhc", w, f).flatten(1)  # (B, heads*H)
        mu, logvar = self.out(pooled).chunk(2, dim=-1)
        return mu, logvar.clamp(-12.0, 6.0)


def reparameterise(mu: torch.Tensor, logvar: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """z = mu + sigma * eps (training only; analyses and conditioning use mu)."""
    eps = torch.randn(mu.shape, generator=generator, dtype=mu.dtype, device=mu.device)
    return mu + torch.exp(0.5 * logvar) * eps
