"""Closed-form pose fields: a per-(pair kind, pose) displacement field of the source positions,
chosen and scaled by the conditioning delta. This is what predicts the kinds in
`PoseFieldsConfig.only_kinds` (`neutral_to_pose` in the shipped model) on its own; the vertex
decoder network reads it (prototype weights in its condition, the displacement as its start) for
the other kinds.

- pose prototypes: the unit mean training delta of every (kind, pose), and its length;
- prototype weights: softmax of the delta's cosine to each prototype of its kind (temperature
  `proto_temp`): near one-hot for a recognised pose, a mixture for blends;
- fields: per (kind, pose) a linear read-out (D + 1, 3) of D fixed random Fourier features of the
  source positions, centred on the mesh's bounding box and divided by its height (the same body
  part of a short and a tall character reads nearly the same features);
- displacement = sum_p weight_p * amount_p * field_p(V), amount_p = (delta . prototype_p) / |mean
  delta_p| (1 for the mean delta, linear in the magnitude slider), capped at `coef_max`.
Prototypes and read-outs are set from the training pairs before Phase B
(`latent_model/train/fit_pose_fields.py`) and saved with the model. Needs no topology: any mesh works.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import nn

from latent_model.config import ModelConfig


@dataclass
class FieldCache:
    """The fields' displacements on one mesh, per kind: computed on the first prediction of a kind
    and reused by every later one (the explorer's sliders, the evaluation). 3 numbers per vertex
    and fitted pose instead of D + 1 features. Valid while the read-outs are unchanged."""

    vertices: torch.Tensor  # (B, V, 3) the source
    by_kind: dict[int, tuple[torch.Tensor, torch.Tensor]] = field(default_factory=dict)  # kind -> (poses (F,), (B, F, V*3))


class PoseFields(nn.Module):
    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg.fields
        K, P, Z, D = cfg.n_pair_kinds, cfg.n_poses, cfg.latent, cfg.fields.features
        # unit mean training direction per (pair kind, pose); zero rows: no prototype
        self.register_buffer("prototypes", torch.zeros(K, P, Z))
        # |mean training delta| per (kind, pose): the mean delta's amount is 1
        self.register_buffer("proto_r", torch.ones(K, P))
        g = torch.Generator().manual_seed(self.cfg.rff_seed)
        self.register_buffer("rff", torch.randn(3, D // 2, generator=g) * self.cfg.rff_sigma * torch.pi)
        self.register_buffer("readouts", torch.zeros(K, P, D + 1, 3))

    def predicts_alone(self, kind: str) -> bool:
        """Whether the fields alone predict this pair kind at inference."""
        return kind in self.cfg.only_kinds

    @torch.no_grad()
    def set_prototypes(self, prototypes: torch.Tensor) -> None:
        """(n_kinds, n_poses, Z) mean training delta per pair kind and pose (zero rows: none)."""
        self.prototypes.copy_(nn.functional.normalize(prototypes.float(), dim=-1))
        r = prototypes.float().norm(dim=-1)
        self.proto_r.copy_(torch.where(r > 0, r, torch.ones_like(r)))

    def cosines(self, delta_dir: torch.Tensor, kind: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, Z) direction, (B,) kind -> cosine to each of that kind's prototypes (B, n_poses) and
        which prototypes exist (B, n_poses) bool."""
        protos = self.prototypes[kind]  # (B, P, Z)
        cos = torch.einsum("bz,bpz->bp", nn.functional.normalize(delta_dir, dim=-1), protos)
        return cos, protos.abs().sum(-1) > 0

    def weights(self, delta_dir: torch.Tensor, kind: torch.Tensor,
                cosines: tuple[torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
        """(B, Z), (B,) -> (B, n_poses) softmax of the cosines (zeros for a kind without prototypes)."""
        cos, valid = self.cosines(delta_dir, kind) if cosines is None else cosines
        w = torch.softmax((cos / self.cfg.proto_temp).masked_fill(~valid, float("-inf")), dim=-1)
        return torch.nan_to_num(w, nan=0.0)  # rows without any prototype

    def coefficients(self, delta_dir: torch.Tensor, r: torch.Tensor, kind: torch.Tensor) -> torch.Tensor:
        """(B, n_poses) amount of each field: weight x (the delta's component along the prototype /
        |mean training delta|), capped so a noise-level delta cannot blow a field up."""
        cosines = self.cosines(delta_dir, kind)
        amount = (cosines[0] * r.reshape(-1, 1) / self.proto_r[kind]).clamp(0.0, self.cfg.coef_max)
        return self.weights(delta_dir, kind, cosines) * amount

    def features(self, v_src: torch.Tensor, bbox: tuple[torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
        """(B, V, 3) -> (B, V, D + 1) random Fourier features of the positions centred on the mesh's
        bounding box and divided by its height (z). bbox: the mesh's (lo, hi) (B, 1, 3) each, when
        v_src is a part of it."""
        lo, hi = (v_src.amin(dim=1, keepdim=True), v_src.amax(dim=1, keepdim=True)) if bbox is None else bbox
        x = (v_src - (lo + hi) / 2) / (hi - lo)[..., 2:3].clamp(min=1e-6)
        a = x @ self.rff
        return torch.cat([torch.cos(a), torch.sin(a), torch.ones_like(a[..., :1])], dim=-1)

    def displacement(self, v_src: torch.Tensor, delta_dir: torch.Tensor, r: torch.Tensor, kind: torch.Tensor,
                     cache: FieldCache | None = None) -> torch.Tensor:
        """(B, V, 3) the fields of each pair's kind mixed by `coefficients`; from `cache` when given
        (the same numbers, read out once per mesh and kind)."""
        if cache is not None:
            return self._cached_displacement(cache, delta_dir, r, kind)
        w = torch.einsum("bp,bpdj->bdj", self.coefficients(delta_dir, r, kind), self.readouts[kind])
        return torch.bmm(self.features(v_src), w)

    def _kind_displacements(self, cache: FieldCache, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(poses (F,), displacements (B, F, V*3)) of the fitted fields of kind k on the cached mesh,
        read out in chunks of 4096 vertices (no (V, D+1) feature block is kept)."""
        if k not in cache.by_kind:
            fitted = self.readouts[k].abs().flatten(1).amax(dim=1) > 0  # (P,) poses with a field
            poses = torch.nonzero(fitted).flatten()
            v = cache.vertices
            B, V = v.shape[:2]
            w = self.readouts[k, poses].permute(1, 0, 2).reshape(self.readouts.shape[2], -1)  # (D+1, F*3)
            u = torch.empty(B, V, len(poses) * 3, device=v.device)
            if len(poses):
                lo, hi = v.amin(dim=1, keepdim=True), v.amax(dim=1, keepdim=True)
                for i in range(0, V, 4096):
                    u[:, i:i + 4096] = self.features(v[:, i:i + 4096], (lo, hi)) @ w
            cache.by_kind[k] = (poses, u.reshape(B, V, -1, 3).permute(0, 2, 1, 3).reshape(B, len(poses), V * 3))
        return cache.by_kind[k]

    def _cached_displacement(self, cache: FieldCache, delta_dir: torch.Tensor, r: torch.Tensor,
                             kind: torch.Tensor) -> torch.Tensor:
        B, V = cache.vertices.shape[:2]
        coef = self.coefficients(delta_dir, r, kind)  # (B, P)
        kinds = kind.unique().tolist()
        if len(kinds) == 1:  # the usual case (one mesh, one pair kind): no copy of the cache
            poses, u = self._kind_displacements(cache, kinds[0])
            if not len(poses):
                return torch.zeros_like(cache.vertices)
            return torch.bmm(coef[:, poses][:, None], u).reshape(B, V, 3)
        out = torch.zeros(B, V * 3, device=coef.device)
        for k in kinds:
            poses, u = self._kind_displacements(cache, k)
            rows = kind == k
            if len(poses):
                out[rows] = torch.bmm(coef[rows][:, poses][:, None], u[rows])[:, 0]
        return out.reshape(B, V, 3)
