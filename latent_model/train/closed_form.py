"""Closed-form parts of the vertex decoder, set from the training pairs before Phase B.

- pose prototypes: the mean latent delta of every (pair kind, pose) over the training identities;
- prototype fields: per (kind, pose) a ridge read-out of the decoder's random Fourier features
  of the source mesh, fitted to the pairs' displacements (features scaled by the amount the
  decoder gives the field for the pair's own delta, or, with `vd_fit_scaled` off, at amount 1:
  the field is then the pose's mean displacement, which leaks less on still regions when the
  latent amounts vary between bodies for reasons the motion does not share).

Measured on the standard corpus (generator version 3; 14 held-out identities, the fields alone
with the mean amount, before any SGD; `bench/fields_alone.py`, sigma 6): explained motion / static
leakage kneeBentLf 0.86 / 1.0 mm (0.69 / 1.7 on version 2, whose knee axes disagreed between
bodies), elbowSuperBentLf 0.87 / 1.4, shoulderRaiseLf 0.89 / 1.0, shoulderForwardRt 0.88 / 1.2;
the shipped model's figures are in the README results.
"""
from __future__ import annotations

from collections import defaultdict

import numpy as np
import torch
from tqdm import tqdm

from latent_model.corpus.pairs import PAIR_KINDS
from latent_model.corpus.store import Corpus
from latent_model.nn.vertex_decoder import VertexDecoder
from latent_model.train.data import PhaseBSampler


def pose_prototypes(sampler: PhaseBSampler, corpus: Corpus, mu_rows: torch.Tensor,
                    n_poses: int) -> torch.Tensor:
    """(n_kinds, n_poses, Z) mean delta mu(target) - mu(source) of every (kind, pose) over the
    training pairs (zeros where a kind has no pair of that pose)."""
    out = torch.zeros(len(PAIR_KINDS), n_poses, mu_rows.shape[1], dtype=torch.float64)
    count = torch.zeros(len(PAIR_KINDS), n_poses, dtype=torch.float64)
    for kind, pairs in sampler.by_kind.items():
        k = PAIR_KINDS.index(kind)
        for p in pairs:
            s, t = sampler.states(p)
            out[k, corpus.pose_index(p.pose)] += (mu_rows[corpus.row(t)] - mu_rows[corpus.row(s)]).double()
            count[k, corpus.pose_index(p.pose)] += 1
    return (out / count.clamp(min=1)[..., None]).float()


@torch.no_grad()
def fit_prototype_fields(vd: VertexDecoder, sampler: PhaseBSampler, corpus: Corpus, mu_rows: torch.Tensor,
                         seed: int, progress: bool = True) -> dict:
    """Ridge fit of vd.proto_fields (kinds, poses, D+1, 3) on every training pair (prototypes must
    be set). Each pair contributes a random subset of `vd_fit_vertices` source vertices; its
    features are scaled by s = (the pair's delta along the prototype) / |mean delta|, the amount
    the decoder gives the field for that delta (`prototype_coefficients`), so the read-out
    reproduces the pair; with cfg.vd_fit_scaled off, every pair with a positive amount counts at
    amount 1. Returns {"pairs": n, "fields": n fitted}."""
    cfg = vd.cfg
    rng = np.random.default_rng(seed)
    dev = vd.proto_fields.device
    D1 = cfg.vd_proto_fields + 1
    cache: dict[int, tuple[np.ndarray, torch.Tensor, torch.Tensor]] = {}  # source state -> subset, X, X^T X

    def features(state: int) -> tuple[np.ndarray, torch.Tensor, torch.Tensor]:
        if state not in cache:
            v = torch.from_numpy(corpus.vertices(state)).float().to(dev)
            sub = rng.choice(len(v), size=min(cfg.vd_fit_vertices, len(v)), replace=False)
            x = vd.field_features(v[None])[0][torch.from_numpy(sub).to(dev)]
            if len(cache) > 512:  # bounded memory; neutral sources recur across poses
                cache.clear()
            cache[state] = (sub, x.double(), (x.T @ x).double())  # float32 product: 2x faster
        return cache[state]

    groups: dict[tuple[int, int], list] = defaultdict(list)
    for kind, pairs in sampler.by_kind.items():
        if kind not in cfg.vd_fit_kinds:
            continue  # its fields stay zero: the network alone predicts that kind
        for p in pairs:
            groups[(PAIR_KINDS.index(kind), corpus.pose_index(p.pose))].append(p)
    order = sorted(groups)  # (kind, pose)
    n_pairs = 0
    for kp in tqdm(order, desc="fitting prototype fields", disable=not progress, unit="field"):
        k, pose = kp
        gram = torch.zeros(D1, D1, dtype=torch.float64, device=dev)
        rhs = torch.zeros(D1, 3, dtype=torch.float64, device=dev)
        rho = vd.proto_r[k, pose].double()
        for p in groups[kp]:
            s, t = sampler.states(p)
            sub, x, xtx = features(s)
            delta = (mu_rows[corpus.row(t)] - mu_rows[corpus.row(s)]).double().to(dev)
            scale = (delta @ vd.prototypes[k, pose].double() / rho).clamp(0.0, cfg.vd_coef_max)
            if scale <= 0:
                continue
            if not cfg.vd_fit_scaled:
                scale = torch.ones_like(scale)
            y = torch.from_numpy(corpus.vertices(t)[sub] - corpus.vertices(s)[sub]).double().to(dev)
            gram += scale * scale * xtx
            rhs += scale * (x.T @ y)
            n_pairs += 1
        lam = cfg.vd_fit_ridge * gram.diagonal().mean().clamp(min=1e-12)
        w = torch.linalg.solve(gram + lam * torch.eye(D1, dtype=torch.float64, device=dev), rhs)
        vd.proto_fields[k, pose] = w.float()
    return {"pairs": n_pairs, "fields": len(order)}
