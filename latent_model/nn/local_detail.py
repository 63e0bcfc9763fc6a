"""Local detail networks: a region SDF-VAE per region kind (the head's or a hand's code, at the region's own scale).
What a region delta does to the region's vertices is `detail_fields.py`'s.

It works in region-local coordinates in radius units (`latent_model/regions.py`), so one head network reads
every head and one hand network both hands (the left mirrored), whatever the body's rest pose.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from latent_model.config import ModelConfig
from latent_model.nn.encoder import SdfSetEncoder
from latent_model.nn.sdf_decoder import SdfDecoder

KINDS = ("head", "hand")


@dataclass(frozen=True)
class LocalDetailConfig:
    """Sizes of the region networks (one set per region kind)."""

    latent: int = 64  # a region's code
    enc_hidden: tuple[int, ...] = (64, 128)
    enc_out_hidden: int = 256
    sdf_hidden: int = 128
    sdf_layers: int = 4
    fourier: int = 6  # frequencies of the local position (radius units: down to 1/64 of the radius)

    def codec_config(self) -> ModelConfig:
        return ModelConfig(latent=self.latent, enc_fourier=self.fourier, enc_hidden=self.enc_hidden,
                           enc_out_hidden=self.enc_out_hidden, sdf_hidden=self.sdf_hidden, sdf_layers=self.sdf_layers)

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "LocalDetailConfig":
        d = dict(d)
        d["enc_hidden"] = tuple(d["enc_hidden"])
        return LocalDetailConfig(**d)


class RegionCodec(nn.Module):
    """A region's SDF samples (B, K, 3)/(B, K) -> (mu, logvar) (B, Z), and the SDF decoder that shapes the code."""

    def __init__(self, cfg: LocalDetailConfig) -> None:
        super().__init__()
        self.encoder = SdfSetEncoder(cfg.codec_config())
        self.sdf_decoder = SdfDecoder(cfg.codec_config())


class LocalDetail(nn.Module):
    """Every region kind's codec, with the codes' standardisation (a buffer per kind)."""

    def __init__(self, cfg: LocalDetailConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.codecs = nn.ModuleDict({k: RegionCodec(cfg) for k in KINDS})
        for k in KINDS:
            self.register_buffer(f"mean_{k}", torch.zeros(cfg.latent))
            self.register_buffer(f"scale_{k}", torch.ones(cfg.latent))

    def standardise(self, kind: str, mu: torch.Tensor) -> torch.Tensor:
        return (mu - getattr(self, f"mean_{kind}")) / getattr(self, f"scale_{kind}")

    @torch.no_grad()
    def encode(self, kind: str, points: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        """Standardised posterior means (B, Z) of region sample sets (B, K, 3)/(B, K)."""
        enc = self.codecs[kind].encoder
        was = enc.training
        enc.eval()
        mu = enc(points, values)[0]
        enc.train(was)
        return self.standardise(kind, mu)
