"""DeepSDF-style conditional implicit decoder D(z, x) -> s with a latent skip connection."""
from __future__ import annotations

import torch
from torch import nn

from latent_model.config import ModelConfig
from latent_model.nn.common import fourier_features


class SdfDecoder(nn.Module):
    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        d_x = 3 + 6 * cfg.enc_fourier
        d_in = cfg.latent + d_x
        self.skip_at = cfg.sdf_layers // 2
        layers = []
        for i in range(cfg.sdf_layers):
            d = d_in if i == 0 else cfg.sdf_hidden + (d_in if i == self.skip_at else 0)
            layers.append(nn.Linear(d, cfg.sdf_hidden))
        self.layers = nn.ModuleList(layers)
        self.last = nn.Linear(cfg.sdf_hidden, 1)

    def forward(self, z: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """z (B, Z), x (B, Q, 3) -> s_hat (B, Q) in metres."""
        inp = torch.cat([z[:, None].expand(-1, x.shape[1], -1), fourier_features(x, self.cfg.enc_fourier)], dim=-1)
        h = inp
        for i, layer in enumerate(self.layers):
            if i == self.skip_at:
                h = torch.cat([h, inp], dim=-1)
            h = torch.nn.functional.silu(layer(h))
        return self.last(h)[..., 0] * 0.1  # output scale: metres, small at init
