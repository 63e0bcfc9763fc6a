"""The whole LatentReRig model: encoder, SDF decoder, heads (Phase A), vertex decoder and pose fields (Phase B)."""
from __future__ import annotations

import torch
from torch import nn

from latent_model.config import ModelConfig
from latent_model.nn.encoder import SdfSetEncoder
from latent_model.nn.heads import CharacterClassifier, PoseClassifier
from latent_model.nn.motion_decoder import MotionDecoder
from latent_model.nn.pose_fields import PoseFields
from latent_model.nn.sdf_decoder import SdfDecoder
from latent_model.nn.vertex_decoder import VertexDecoder

PHASE_A_PARTS = ("encoder", "sdf_decoder", "char_head", "pose_head")


class LatentReRig(nn.Module):
    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.encoder = SdfSetEncoder(cfg)
        self.sdf_decoder = SdfDecoder(cfg)
        self.char_head = CharacterClassifier(cfg)
        self.pose_head = PoseClassifier(cfg)
        self.vertex_decoder = VertexDecoder(cfg)
        self.pose_fields = PoseFields(cfg)
        m = cfg.motion
        # only when enabled: checkpoints without it (the shipped one) keep their exact key set
        self.motion_decoder = MotionDecoder(cfg.latent, cfg.n_pair_kinds, m.hidden, m.cond, m.layers, m.world,
                                            m.mu_dims, m.mu_noise, m.local_inputs, m.delta_dims, m.delta_noise,
                                            m.limb_direction, m.averaged_input, m.carried_arms) \
            if m.enabled else None

    def phase_a_parameters(self):
        for part in PHASE_A_PARTS:
            yield from getattr(self, part).parameters()

    @torch.no_grad()
    def encode_mu(self, points: torch.Tensor, values: torch.Tensor, chunk: int = 64) -> torch.Tensor:
        """Deterministic posterior means (B, Z) of SDF sample sets (B, K, 3)/(B, K), encoder in eval mode."""
        was = self.encoder.training
        self.encoder.eval()
        out = torch.cat([self.encoder(points[i:i + chunk], values[i:i + chunk])[0]
                         for i in range(0, len(points), chunk)])
        self.encoder.train(was)
        return out
