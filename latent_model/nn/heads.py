"""Auxiliary heads that shape the latent space in Phase A (not the product)."""
from __future__ import annotations

import torch
from torch import nn

from latent_model.config import ModelConfig


class CharacterClassifier(nn.Module):
    """mu (B, Z) -> logits over the training identities."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Linear(cfg.latent, 256), nn.SiLU(), nn.Linear(256, cfg.n_identities))

    def forward(self, mu: torch.Tensor) -> torch.Tensor:
        return self.net(mu)


class PoseClassifier(nn.Module):
    """Normalised pose delta (B, Z) -> logits over the pose vocabulary of the corpus."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Linear(cfg.latent, 256), nn.SiLU(), nn.Linear(256, cfg.n_poses))

    def forward(self, delta_dir: torch.Tensor) -> torch.Tensor:
        return self.net(delta_dir)
