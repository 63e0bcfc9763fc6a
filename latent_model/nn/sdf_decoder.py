"""DeepSDF-style conditional implicit decoder D(z, x) -> s with a latent skip connection."""
from __future__ import annotations

import torch
from torch import nn

from latent_model.config import ModelConfig
from latent_model.nn.common import fourier_features


class SdfDecoder(nn.Module):
    """An MLP on [z, enc(x)] with [z, enc(x)] re-injected at the middle layer (DeepSDF).

    A linear layer on a concatenation splits exactly into W_z z + W_x x; the z part is computed
    once per shape and broadcast over its query points, which makes a 512-d latent affordable
    on a CPU without changing the function class.
    """

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        d_x = 3 + 6 * cfg.enc_fourier
        H = cfg.sdf_hidden
        self.skip_at = cfg.sdf_layers // 2
        self.z_in = nn.Linear(cfg.latent, H)  # z part of layer 0 (carries the bias)
        self.x_in = nn.Linear(d_x, H, bias=False)
        self.z_skip = nn.Linear(cfg.latent, H)  # z part of the skip layer
        self.x_skip = nn.Linear(d_x, H, bias=False)
        self.layers = nn.ModuleList(nn.Linear(H, H, bias=(i != self.skip_at)) for i in range(1, cfg.sdf_layers))
        self.last = nn.Linear(H, 1)

    def forward(self, z: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """z (B, Z), x (B, Q, 3) -> s_hat (B, Q) in metres."""
        xe = fourier_features(x, self.cfg.enc_fourier)
        h = torch.nn.functional.silu(self.z_in(z)[:, None] + self.x_in(xe))
        for i, layer in enumerate(self.layers, start=1):
            pre = layer(h)
            if i == self.skip_at:
                pre = pre + self.z_skip(z)[:, None] + self.x_skip(xe)
            h = torch.nn.functional.silu(pre)
        return self.last(h)[..., 0] * 0.1  # output scale: metres, small at init
