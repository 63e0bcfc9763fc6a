"""Explicit vertex decoder: (V_src, N_src, mu_src, dir, r, kind) -> V_hat, any topology.

Five parts, as in the paper:
1. pair-kind embedding, folded into a global condition vector with mu_src, dir and r;
2. a virtual-bone coarse stage: learned rigid influences (rotation, pivot, translation per
   bone, from the condition) blended per vertex by soft assignments;
3. a per-vertex latent-delta mask that gates where the global signal acts;
4. four local KNN refinement stages (edge convolutions over source-mesh neighbourhoods);
5. a residual detail branch for small localised components (correctives).
Beyond the paper, an optional pose-prototype condition (`vd_prototypes`: softmax similarity of
the delta to each pose's mean training delta), prototype fields fitted in closed form
(`vd_proto_fields`: per kind and pose, a linear read-out of random Fourier features of the
normalised source positions; for the kinds in `vd_fields_only_kinds` the prediction at inference
is these fields alone), and an optional bilinear deformation basis (`vd_basis` > 0): K displacement fields
read from the mesh features alone, mixed by K coefficients linear in the delta (see `forward`).
No layer is sized by the vertex count, so any mesh works; neighbourhoods are computed per
mesh (`knn_graph`) and can be cached by the caller.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn

from latent_model.config import ModelConfig
from latent_model.corpus.pairs import PAIR_KINDS
from latent_model.nn.common import fourier_features, mlp

POS_SCALE = 10.0  # relative positions/displacements in decimetres inside the edge MLPs


def knn_graph(vertices: np.ndarray, k: int) -> np.ndarray:
    """(V, k) int64 indices of each vertex's k nearest other vertices (Euclidean, source mesh)."""
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, dtype=np.float64)
    k_eff = min(k, len(v) - 1)
    _, idx = cKDTree(v).query(v, k=k_eff + 1)
    idx = idx[:, 1:]
    if k_eff < k:  # tiny meshes: repeat the last neighbour
        idx = np.concatenate([idx, np.repeat(idx[:, -1:], k - k_eff, axis=1)], axis=1)
    return idx.astype(np.int64)


def rot6d_to_matrix(x: torch.Tensor) -> torch.Tensor:
    """(..., 6) -> (..., 3, 3) rotation (Gram-Schmidt of two columns)."""
    a, b = x[..., :3], x[..., 3:]
    e1 = nn.functional.normalize(a, dim=-1)
    e2 = nn.functional.normalize(b - (e1 * b).sum(-1, keepdim=True) * e1, dim=-1)
    e3 = torch.cross(e1, e2, dim=-1)
    return torch.stack([e1, e2, e3], dim=-1)


def gather_neighbours(x: torch.Tensor, knn: torch.Tensor) -> torch.Tensor:
    """x (B, V, C), knn (B, V, K) -> (B, V, K, C) (flat indexing: much faster than gather)."""
    B, V, K = knn.shape
    offset = (torch.arange(B, device=knn.device) * x.shape[1]).view(B, 1, 1)
    flat = (knn + offset).reshape(-1)
    return torch.index_select(x.reshape(-1, x.shape[-1]), 0, flat).reshape(B, V, K, x.shape[-1])


class EdgeStage(nn.Module):
    """One local refinement stage: a max-relative graph convolution over KNN neighbourhoods.

    Edge features W [g_i, g_j - g_i, x_j - x_i, d_j - d_i] are linear, so they split into
    A_i + B_j with per-vertex A, B, and the max over neighbours is A_i + max_j B_j (the
    activation follows the max, as in max-relative GCNs): one gather and one max per stage
    instead of a per-edge MLP, which keeps a 14k-vertex mesh within the slider budget.
    """

    def __init__(self, h: int, e: int) -> None:
        super().__init__()
        self.self_proj = nn.Linear(h, e)
        self.nbr_proj = nn.Linear(h, e, bias=False)
        self.pos_proj = nn.Linear(3, e, bias=False)
        self.disp_proj = nn.Linear(3, e, bias=False)
        self.update = mlp([e, h, h])

    def forward(self, g: torch.Tensor, d: torch.Tensor, x: torch.Tensor, knn: torch.Tensor) -> torch.Tensor:
        """g (B, V, H), d, x (B, V, 3) displacement and position, knn (B, V, K) -> (B, V, H)."""
        b = self.nbr_proj(g) + self.pos_proj(x * POS_SCALE) + self.disp_proj(d * POS_SCALE)
        e = self.self_proj(g) - b + gather_neighbours(b, knn).amax(dim=2)
        return g + self.update(torch.nn.functional.silu(e))


@dataclass
class MeshFeatures:
    """What the decoder reads from a mesh alone, cached by a caller that predicts many poses for
    one mesh (the explorer's sliders, the evaluation). The prototype fields enter as their
    displacements (one per fitted pose of a kind, computed on the first prediction of that kind)
    rather than as the D + 1 random Fourier features: 243 numbers per vertex instead of 1025, and
    one small read-out per prediction instead of a 60 MB one. Valid while the fields are unchanged."""

    hidden: torch.Tensor  # (B, V, H)
    vertices: torch.Tensor  # (B, V, 3) the source, for the field displacements
    fields: dict[int, tuple[torch.Tensor, torch.Tensor]] = field(default_factory=dict)  # kind -> (poses (F,), (B, F, V*3))


class VertexDecoder(nn.Module):
    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        H, C, nb = cfg.vd_hidden, cfg.vd_cond, cfg.vd_bones
        self.kind_emb = nn.Embedding(cfg.n_pair_kinds, 16)
        n_proto = cfg.n_poses if cfg.vd_prototypes else 0
        self.cond = mlp([2 * cfg.latent + 2 + 16 + n_proto, 256, C], final_act=True)
        self.vert = mlp([3 + 6 * cfg.vd_fourier + 3, H, H], final_act=True)
        self.film = nn.Linear(C, 2 * H)
        # Virtual bones: per bone a 6D rotation offset, pivot and translation from the condition.
        self.bones = nn.Linear(C, nb * 12)
        nn.init.zeros_(self.bones.weight)
        nn.init.zeros_(self.bones.bias)
        self.assign = mlp([H, H, nb])
        self.mask = mlp([H, H, 1])
        # direct per-vertex displacement (conditioned through FiLM): gives every vertex a
        # gradient path from the first step, while the bones learn coordinated rigid motion
        self.direct = mlp([H, H, 3])
        self.stages = nn.ModuleList(EdgeStage(H, cfg.vd_edge) for _ in range(cfg.vd_stages))
        self.stage_out = nn.ModuleList(nn.Linear(H, 3) for _ in range(cfg.vd_stages))
        for lin in self.stage_out:
            nn.init.zeros_(lin.weight)
            nn.init.zeros_(lin.bias)
        if cfg.vd_detail:
            # first layer on [h, c] split into W_h h + W_c c (c computed once per mesh)
            self.detail_h = nn.Linear(H, H)
            self.detail_c = nn.Linear(C, H, bias=False)
            self.detail_out = nn.Linear(H, 4)
            nn.init.zeros_(self.detail_out.weight)
            nn.init.zeros_(self.detail_out.bias)
        if cfg.vd_basis:
            self.basis = mlp([H, H, 3 * cfg.vd_basis])
            self.basis_coef = nn.Linear(cfg.latent, cfg.vd_basis, bias=False)
            nn.init.zeros_(self.basis_coef.weight)
        self.register_buffer("identity6d", torch.tensor([1.0, 0.0, 0.0, 0.0, 1.0, 0.0]))
        if cfg.vd_whiten:
            # set from the training deltas before Phase B (`set_direction_whitening`), saved with the model
            self.register_buffer("dir_whiten", torch.eye(cfg.latent) * cfg.vd_dir_gain)
        if cfg.vd_prototypes:
            # unit mean training direction per (pair kind, pose); zero rows: no prototype
            self.register_buffer("prototypes", torch.zeros(cfg.n_pair_kinds, cfg.n_poses, cfg.latent))
            # |mean training delta| per (kind, pose): r / this is 1 for the mean delta
            self.register_buffer("proto_r", torch.ones(cfg.n_pair_kinds, cfg.n_poses))
        if cfg.vd_prototypes and cfg.vd_proto_fields:
            # Prototype fields: random Fourier features of the height-normalised source positions
            # (fixed, seeded) and one linear read-out per (kind, pose), fitted in closed form
            # (ridge) on the training pairs before Phase B (`latent_model/train/closed_form.py`).
            g = torch.Generator().manual_seed(cfg.vd_rff_seed)
            freq = torch.randn(3, cfg.vd_proto_fields // 2, generator=g) * cfg.vd_rff_sigma * torch.pi
            self.register_buffer("rff", freq)
            self.register_buffer("proto_fields", torch.zeros(cfg.n_pair_kinds, cfg.n_poses, cfg.vd_proto_fields + 1, 3))

    @torch.no_grad()
    def set_direction_whitening(self, directions: torch.Tensor, eps_rel: float = 1e-3) -> None:
        """ZCA preconditioner of the delta direction from training directions (N, Z): the
        first condition layer then sees decorrelated, unit-scale inputs. The same function class
        (a fixed linear map before a linear layer), but poses whose raw deltas nearly coincide
        (cos 0.97 for kneeBentLf/Rt) become far apart (cos 0.65) for the optimiser (its effect on
        the standard model is measured in the README). eps_rel caps the gain of near-empty directions."""
        u = directions.double()
        lam, vec = torch.linalg.eigh(u.T @ u / len(u))
        lam = lam.clamp(min=0) + eps_rel * lam.max()
        w = vec @ torch.diag(lam.rsqrt()) @ vec.T
        w = w * (u.shape[1] / (u @ w).square().sum(-1).mean()).sqrt()  # unit-RMS components on average
        self.dir_whiten.copy_(w.float())

    @torch.no_grad()
    def set_pose_prototypes(self, prototypes: torch.Tensor) -> None:
        """(n_kinds, n_poses, Z) mean training delta per pair kind and pose (zero rows: none)."""
        self.prototypes.copy_(nn.functional.normalize(prototypes.float(), dim=-1))
        r = prototypes.float().norm(dim=-1)
        self.proto_r.copy_(torch.where(r > 0, r, torch.ones_like(r)))

    def prototype_cosines(self, delta_dir: torch.Tensor, kind: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, Z) direction, (B,) kind -> cosine to each of that kind's prototypes (B, n_poses) and
        which prototypes exist (B, n_poses) bool."""
        protos = self.prototypes[kind]  # (B, P, Z)
        cos = torch.einsum("bz,bpz->bp", nn.functional.normalize(delta_dir, dim=-1), protos)
        return cos, protos.abs().sum(-1) > 0

    def prototype_weights(self, delta_dir: torch.Tensor, kind: torch.Tensor,
                          cosines: tuple[torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
        """(B, Z) direction, (B,) kind -> (B, n_poses) softmax of its cosine to each of that kind's
        pose prototypes (temperature vd_proto_temp): near one-hot for a recognised pose (the
        nearest prototype names a held-out identity's single body pose 87% of the time), a mixture
        for blends; zeros for a kind without prototypes (before they are set)."""
        cos, valid = self.prototype_cosines(delta_dir, kind) if cosines is None else cosines
        w = torch.softmax((cos / self.cfg.vd_proto_temp).masked_fill(~valid, float("-inf")), dim=-1)
        return torch.nan_to_num(w, nan=0.0)  # rows without any prototype

    def field_features(self, v_src: torch.Tensor,
                       bbox: tuple[torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
        """(B, V, 3) -> (B, V, D + 1) random Fourier features of the positions centred on the
        mesh's bounding box and divided by its height (z): the same body part of a short and a
        tall identity reads (nearly) the same features. bbox: the mesh's (lo, hi) (B, 1, 3) each,
        when v_src is a part of it."""
        lo, hi = (v_src.amin(dim=1, keepdim=True), v_src.amax(dim=1, keepdim=True)) if bbox is None else bbox
        x = (v_src - (lo + hi) / 2) / (hi - lo)[..., 2:3].clamp(min=1e-6)
        a = x @ self.rff
        return torch.cat([torch.cos(a), torch.sin(a), torch.ones_like(a[..., :1])], dim=-1)

    def prototype_coefficients(self, delta_dir: torch.Tensor, r: torch.Tensor, kind: torch.Tensor) -> torch.Tensor:
        """(B, n_poses) amount of each prototype field: weight x (the delta's component along the
        prototype / |mean training delta|), 1 for the mean delta itself, linear in r (the
        magnitude slider), capped at vd_coef_max so a noise-level delta cannot blow a field up."""
        cosines = self.prototype_cosines(delta_dir, kind)
        amount = (cosines[0] * r.reshape(-1, 1) / self.proto_r[kind]).clamp(0.0, self.cfg.vd_coef_max)
        return self.prototype_weights(delta_dir, kind, cosines) * amount

    def prototype_displacement(self, phi: torch.Tensor, delta_dir: torch.Tensor, r: torch.Tensor,
                               kind: torch.Tensor) -> torch.Tensor:
        """phi (B, V, D+1) `field_features` -> (B, V, 3): the fitted fields of the pair's kind mixed
        by `prototype_coefficients`."""
        w = torch.einsum("bp,bpdj->bdj", self.prototype_coefficients(delta_dir, r, kind), self.proto_fields[kind])
        return torch.bmm(phi, w)

    def kind_field_displacements(self, feats: MeshFeatures, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(poses (F,), displacements (B, F, V*3)) of the fitted fields of kind k on the cached
        mesh: each field read out once (chunked over vertices: no (V, D+1) feature block is kept)."""
        if k not in feats.fields:
            fitted = self.proto_fields[k].abs().flatten(1).amax(dim=1) > 0  # (P,) poses with a field
            poses = torch.nonzero(fitted).flatten()
            v = feats.vertices
            B, V = v.shape[:2]
            w = self.proto_fields[k, poses].permute(1, 0, 2).reshape(self.proto_fields.shape[2], -1)  # (D+1, F*3)
            u = torch.empty(B, V, len(poses) * 3, device=v.device)
            if len(poses):
                lo, hi = v.amin(dim=1, keepdim=True), v.amax(dim=1, keepdim=True)
                for i in range(0, V, 4096):  # the features of the whole bbox, 4096 vertices at a time
                    u[:, i:i + 4096] = self.field_features(v[:, i:i + 4096], (lo, hi)) @ w
            feats.fields[k] = (poses, u.reshape(B, V, -1, 3).permute(0, 2, 1, 3).reshape(B, len(poses), V * 3))
        return feats.fields[k]

    def cached_prototype_displacement(self, feats: MeshFeatures, delta_dir: torch.Tensor, r: torch.Tensor,
                                      kind: torch.Tensor) -> torch.Tensor:
        """= `prototype_displacement(field_features(v), ...)` from the cached field displacements: (B, V, 3)."""
        B, V = feats.vertices.shape[:2]
        coef = self.prototype_coefficients(delta_dir, r, kind)  # (B, P)
        kinds = kind.unique().tolist()
        if len(kinds) == 1:  # the usual case (one mesh, one pair kind): no copy of the cache
            poses, u = self.kind_field_displacements(feats, kinds[0])
            if not len(poses):
                return torch.zeros_like(feats.vertices)
            return torch.bmm(coef[:, poses][:, None], u).reshape(B, V, 3)
        out = torch.zeros(B, V * 3, device=coef.device)
        for k in kinds:
            poses, u = self.kind_field_displacements(feats, k)
            rows = kind == k
            if len(poses):
                out[rows] = torch.bmm(coef[rows][:, poses][:, None], u[rows])[:, 0]
        return out.reshape(B, V, 3)

    def field_displacement(self, v_src: torch.Tensor, features: MeshFeatures | None, delta_dir: torch.Tensor,
                           r: torch.Tensor, kind: torch.Tensor) -> torch.Tensor:
        """(B, V, 3) the prototype fields' displacement, from the mesh-feature cache when given."""
        if features is None:
            return self.prototype_displacement(self.field_features(v_src), delta_dir, r, kind)
        return self.cached_prototype_displacement(features, delta_dir, r, kind)

    def direction_input(self, delta_dir: torch.Tensor) -> torch.Tensor:
        """(B, Z) unit direction -> what the network reads: whitened, or scaled by the gain."""
        return delta_dir @ self.dir_whiten if self.cfg.vd_whiten else delta_dir * self.cfg.vd_dir_gain

    def condition(self, mu_src: torch.Tensor, delta_dir: torch.Tensor, r: torch.Tensor, kind: torch.Tensor) -> torch.Tensor:
        """(B, Z), (B, Z), (B,), (B,) long -> (B, C)."""
        r = r.reshape(-1, 1)
        parts = [mu_src, self.direction_input(delta_dir), r, torch.log(r + 1e-6), self.kind_emb(kind)]
        if self.cfg.vd_prototypes:
            parts.append(self.prototype_weights(delta_dir, kind))
        return self.cond(torch.cat(parts, dim=-1))

    def vertex_features(self, v_src: torch.Tensor, n_src: torch.Tensor) -> torch.Tensor:
        """(B, V, 3) positions and normals -> (B, V, H) per-vertex features of the mesh alone."""
        return self.vert(torch.cat([fourier_features(v_src, self.cfg.vd_fourier), n_src], dim=-1))

    def mesh_features(self, v_src: torch.Tensor, n_src: torch.Tensor) -> MeshFeatures:
        """The pose-independent part of `forward` for one mesh (pass it as `features`)."""
        return MeshFeatures(self.vertex_features(v_src, n_src), v_src)

    def forward(self, v_src: torch.Tensor, n_src: torch.Tensor, mu_src: torch.Tensor, delta_dir: torch.Tensor,
                r: torch.Tensor, kind: torch.Tensor, knn: torch.Tensor,
                features: MeshFeatures | None = None) -> dict[str, torch.Tensor]:
        """v_src, n_src (B, V, 3); mu_src, delta_dir (B, Z); r (B,); kind (B,); knn (B, V, K);
        features: optional cached `mesh_features(v_src, n_src)`.

        Returns {"vertices": (B, V, 3), "coarse": (B, V, 3) displacement, "mask": (B, V, 1)}."""
        cfg = self.cfg
        B = v_src.shape[0]
        fields_only = self.fields_only(kind)
        if bool(fields_only.all()):  # every pair of a fields-only kind: the network is not run
            pd = self.field_displacement(v_src, features, delta_dir, r, kind)
            return {"vertices": v_src + pd, "coarse": torch.zeros_like(v_src), "mask": torch.ones_like(v_src[..., :1])}
        c = self.condition(mu_src, delta_dir, r, kind)
        f = self.vertex_features(v_src, n_src) if features is None else features.hidden
        gamma, beta = self.film(c).chunk(2, dim=-1)
        h = f * (1.0 + gamma[:, None]) + beta[:, None]
        # 1) virtual-bone coarse stage
        p = self.bones(c).reshape(B, cfg.vd_bones, 12)
        R = rot6d_to_matrix(p[..., :6] + self.identity6d)  # (B, nb, 3, 3)
        w = torch.softmax(self.assign(h), dim=-1)  # (B, V, nb)
        # Each bone pivots about the centroid of the vertices it influences (plus a learned
        # offset): a rotation then moves its own region, not the whole body about the origin,
        # which keeps early training from swinging limbs by metres.
        centroid = torch.einsum("bvn,bvi->bni", w, v_src) / (w.sum(dim=1)[..., None] + 1e-6)
        pivot, trans = centroid + p[..., 6:9] * 0.1, p[..., 9:12] * 0.1
        local = v_src[:, :, None] - pivot[:, None]  # (B, V, nb, 3)
        moved = torch.einsum("bnij,bvnj->bvni", R, local) + pivot[:, None] + trans[:, None]
        coarse = (w[..., None] * moved).sum(dim=2) - v_src
        # 2) per-vertex latent-delta mask: gates where the bone signal acts. It gates only the
        # coarse stage and never closes fully (floor 0.05): a gate over everything, or one that
        # could saturate at 0, shut whole limbs early in training and never reopened (measured:
        # knee and shoulder poses predicted no motion after 1500 steps).
        m = 0.05 + 0.95 * torch.sigmoid(self.mask(h) + 2.0)
        d = m * coarse + self.direct(h) * 0.1
        if cfg.vd_basis:
            # Bilinear basis: sum_k a_k B_k(f_v) with a = A (direction input) * r, linear in the
            # delta. The fields see the mesh only (shared by every identity) and the mix is the
            # delta itself, so no delta gives no motion and composed deltas add their motions.
            coef = self.basis_coef(self.direction_input(delta_dir)) * (0.1 * r.reshape(-1, 1))
            fields = self.basis(f).reshape(B, -1, cfg.vd_basis)  # (B, V*3, K): one bmm, no einsum copies
            d = d + torch.bmm(fields, coef[:, :, None]).reshape(B, -1, 3) * 0.1
        if cfg.vd_prototypes and cfg.vd_proto_fields:
            pd = self.field_displacement(v_src, features, delta_dir, r, kind)
            d = d + pd
        # 3) local KNN refinement
        g = h
        for stage, out in zip(self.stages, self.stage_out):
            g = stage(g, d, v_src, knn)
            d = d + out(g) * 0.1
        # 4) residual detail branch (gated)
        if cfg.vd_detail:
            det = self.detail_out(torch.nn.functional.silu(self.detail_h(h) + self.detail_c(c)[:, None]))
            d = d + torch.sigmoid(det[..., :1] - 2.0) * det[..., 1:] * 0.05
        if bool(fields_only.any()):  # a batch mixing kinds: fields-only rows get the fields alone
            d = torch.where(fields_only[:, None, None], pd, d)
        return {"vertices": v_src + d, "coarse": coarse, "mask": m}

    def fields_only(self, kind: torch.Tensor) -> torch.Tensor:
        """(B,) bool: pairs whose prediction is the prototype fields alone (eval mode, kinds in
        `vd_fields_only_kinds`; never while training, so the network trains on every kind)."""
        cfg = self.cfg
        if self.training or not cfg.vd_fields_only_kinds or not (cfg.vd_prototypes and cfg.vd_proto_fields):
            return torch.zeros(kind.shape, dtype=torch.bool, device=kind.device)
        listed = torch.tensor([k in cfg.vd_fields_only_kinds for k in PAIR_KINDS], device=kind.device)
        return listed[kind]
