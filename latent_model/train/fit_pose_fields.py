"""Fit the closed-form pose fields (`nn/pose_fields.py`) from the training pairs, before Phase B.

- pose prototypes: the mean latent delta of every (pair kind, pose) over the training identities;
- read-outs: per (kind, pose) a ridge fit of the fields' random Fourier features of the source mesh
  to the pairs' displacements, every pair that points along the prototype counted once: the field
  is the pose's mean displacement (the amount at inference still scales it).
The fit is exact least squares accumulated pair by pair: each neutral source's Gram matrix is
computed once and reused by every pose of its identity, which a generic ridge solver would redo.
"""
from __future__ import annotations

from collections import defaultdict

import numpy as np
import torch
from tqdm import tqdm

from latent_model.types import PAIR_KINDS
from latent_model.corpus.store import Corpus
from latent_model.nn.pose_fields import PoseFields
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
def fit_pose_fields(fields: PoseFields, sampler: PhaseBSampler, corpus: Corpus, mu_rows: torch.Tensor,
                    seed: int, progress: bool = True) -> dict:
    """Ridge fit of fields.readouts (kinds, poses, D+1, 3) on every training pair of the kinds in
    `fit_kinds` (prototypes must be set). Each pair contributes a random subset of `fit_vertices`
    source vertices if its delta has a positive amount along the prototype. Returns
    {"pairs": n used, "fields": n fitted}."""
    cfg = fields.cfg
    rng = np.random.default_rng(seed)
    dev = fields.readouts.device
    D1 = cfg.features + 1
    cache: dict[int, tuple[np.ndarray, torch.Tensor, torch.Tensor]] = {}  # source state -> subset, X, X^T X

    def features(state: int) -> tuple[np.ndarray, torch.Tensor, torch.Tensor]:
        if state not in cache:
            v = torch.from_numpy(corpus.vertices(state)).float().to(dev)
            sub = rng.choice(len(v), size=min(cfg.fit_vertices, len(v)), replace=False)
            x = fields.features(v[None])[0][torch.from_numpy(sub).to(dev)]
            if len(cache) > 512:  # bounded memory; neutral sources recur across poses
                cache.clear()
            cache[state] = (sub, x.double(), (x.T @ x).double())  # float32 product: 2x faster
        return cache[state]

    groups: dict[tuple[int, int], list] = defaultdict(list)
    for kind, pairs in sampler.by_kind.items():
        if kind not in cfg.fit_kinds:
            continue  # its fields stay zero: the network alone predicts that kind
        for p in pairs:
            groups[(PAIR_KINDS.index(kind), corpus.pose_index(p.pose))].append(p)
    order = sorted(groups)  # (kind, pose)
    n_pairs = 0
    for kp in tqdm(order, desc="fitting pose fields", disable=not progress, unit="field"):
        k, pose = kp
        gram = torch.zeros(D1, D1, dtype=torch.float64, device=dev)
        rhs = torch.zeros(D1, 3, dtype=torch.float64, device=dev)
        rho = fields.proto_r[k, pose].double()
        for p in groups[kp]:
            s, t = sampler.states(p)
            sub, x, xtx = features(s)
            delta = (mu_rows[corpus.row(t)] - mu_rows[corpus.row(s)]).double().to(dev)
            if delta @ fields.prototypes[k, pose].double() / rho <= 0:
                continue  # a delta pointing away from the pose says nothing about its motion
            y = torch.from_numpy(corpus.vertices(t)[sub] - corpus.vertices(s)[sub]).double().to(dev)
            gram += xtx
            rhs += x.T @ y
            n_pairs += 1
        lam = cfg.fit_ridge * gram.diagonal().mean().clamp(min=1e-12)
        w = torch.linalg.solve(gram + lam * torch.eye(D1, dtype=torch.float64, device=dev), rhs)
        fields.readouts[k, pose] = w.float()
    return {"pairs": n_pairs, "fields": len(order)}
