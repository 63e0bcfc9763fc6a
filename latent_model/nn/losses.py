"""Learning objectives (paper, "Learning Objectives"). Each returns a scalar tensor."""
from __future__ import annotations

import torch
import torch.nn.functional as F

from latent_model.nn.vertex_decoder import gather_neighbours

STATIC_THRESHOLD = 0.001  # metres: a vertex whose true displacement is below this is "static"
REL_FLOOR = 0.002  # metres added to a pair's motion in pos_rel, so still pairs do not divide by ~0


# ----------------------------------------------------------------------------- L_SDF
def sdf_reconstruction(s_hat: torch.Tensor, s: torch.Tensor, clamp: float) -> torch.Tensor:
    """DeepSDF clamped L1: errors far from the surface (|s| > clamp) do not dominate."""
    return (s_hat.clamp(-clamp, clamp) - s.clamp(-clamp, clamp)).abs().mean()


def kl_divergence(mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """The paper's mean form: -1/2 mean(1 + log s^2 - mu^2 - s^2)."""
    return -0.5 * torch.mean(1.0 + logvar - mu.pow(2) - logvar.exp())


# ----------------------------------------------------------------------------- L_latent
def composition(total: torch.Tensor, parts: torch.Tensor) -> torch.Tensor:
    """Relative squared error of additivity: total (N, Z) ~ parts (N, Z) (a sum of deltas)."""
    if total.numel() == 0:
        return total.new_zeros(())
    num = (total - parts).pow(2).sum(-1)
    den = total.pow(2).sum(-1) + parts.pow(2).sum(-1) + 1e-8
    return (num / den).mean()


def _same_label_pairs(labels: torch.Tensor) -> torch.Tensor:
    """(N,) labels -> (N, N) bool: i != j with the same label (the positives of both delta terms)."""
    eye = torch.eye(len(labels), dtype=torch.bool, device=labels.device)
    return (labels[:, None] == labels[None, :]) & ~eye


def contrastive(deltas: torch.Tensor, labels: torch.Tensor, temperature: float) -> torch.Tensor:
    """Supervised InfoNCE on normalised deltas (N, Z): same pose aligns, different poses separate."""
    n = deltas.shape[0]
    if n < 2:
        return deltas.new_zeros(())
    z = F.normalize(deltas, dim=-1)
    sim = z @ z.T / temperature
    sim = sim.masked_fill(torch.eye(n, dtype=torch.bool, device=z.device), -1e9)
    pos = _same_label_pairs(labels)
    has = pos.any(dim=1)
    if not has.any():
        return deltas.new_zeros(())
    logp = sim - torch.logsumexp(sim, dim=1, keepdim=True)
    return -(logp * pos).sum(1)[has].div(pos.sum(1)[has]).mean()


def alignment(deltas: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """Mean 1 - cos over pairs of deltas (N, Z) with the same label: 0 when they are parallel.

    The alignment half of L_contrast (Wang & Isola's alignment/uniformity split). InfoNCE alone
    stops pulling same-pose deltas together once they beat every other pose in the softmax;
    this term keeps pulling until the directions agree.
    """
    z = F.normalize(deltas, dim=-1)
    pos = _same_label_pairs(labels)
    if not pos.any():
        return deltas.new_zeros(())
    return (1.0 - (z @ z.T)[pos]).mean()


def consistency(deltas: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """Mean relative squared difference |d_i - d_j|^2 / (|d_i|^2 + |d_j|^2) over pairs of deltas (N, Z) with the
    same label: 0 when they are equal, in length as well as direction.

    Alignment leaves the length free: one training character's delta of a pose is 0.74-1.25 times the pose
    mean's length (knee, 10-90 %) at cosine 0.99, so a delta of one person (the oracle, the nearest identity, an
    example pair) says the angle no better than +-25 %. A pose's delta should say the pose; the target's own
    geometry says how it looks on them. Relative, so shrinking every delta does not lower it.
    """
    pos = _same_label_pairs(labels)
    if not pos.any():
        return deltas.new_zeros(())
    sq = deltas.pow(2).sum(-1)
    rel = 1.0 - 2.0 * (deltas @ deltas.T) / (sq[:, None] + sq[None, :] + 1e-8)
    return rel[pos].mean()


def mirror_cosine(left: torch.Tensor, right: torch.Tensor) -> torch.Tensor:
    """Mean max(0, cos) of one character's deltas (M, Z) of a sided pose and of its mirror.

    A left and a right elbow bend move different vertices, so their deltas should not share a
    direction; without this term they do (cosine 0.998 across characters' means) and a decoder
    conditioned on one character's delta cannot tell which limb to move. Opposite directions
    (neckTurnLf / neckTurnRt) are not penalised.
    """
    if left.numel() == 0:
        return left.new_zeros(())
    return F.cosine_similarity(left, right, dim=-1).clamp(min=0.0).mean()


# ----------------------------------------------------------------------------- L_vertex
def vertex_normals_torch(v: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """(B, V, 3), faces (F, 3) -> unit area-weighted vertex normals (B, V, 3), differentiable."""
    a, b, c = v[:, faces[:, 0]], v[:, faces[:, 1]], v[:, faces[:, 2]]
    fn = torch.cross(b - a, c - a, dim=-1)
    n = torch.zeros_like(v)
    for k in range(3):
        n = n.index_add(1, faces[:, k], fn)
    return F.normalize(n, dim=-1, eps=1e-12)


def vertex_losses(pred: torch.Tensor, src: torch.Tensor, tgt: torch.Tensor, knn: torch.Tensor,
                  faces: torch.Tensor | None, weights, corrective: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """All vertex terms (unweighted) for pred/src/tgt (B, V, 3), knn (B, V, K).

    `corrective` (B, V, 3): V_skin+bs - V_skin of corrective pairs (zeros elsewhere) for L_skinBS.
    """
    out: dict[str, torch.Tensor] = {}
    d_hat, d = pred - src, tgt - src
    # RMSE over the whole batch, not the mean distance: with a mean-distance (L1-like) loss the
    # best answer while the condition is still ignored is the per-vertex *median* displacement
    # over the batch, i.e. no motion (most pairs leave most vertices still), and the decoder
    # stays there. The squared form's optimum is the mean, whose gradient
    # pulls the prediction toward using the condition.
    out["pos"] = (pred - tgt).square().sum(dim=-1).mean().clamp(min=1e-12).sqrt()
    if weights.pos_rel > 0:
        rmse = (pred - tgt).square().sum(dim=-1).mean(dim=1).clamp(min=1e-12).sqrt()  # (B,)
        motion = d.square().sum(dim=-1).mean(dim=1).sqrt()
        out["pos_rel"] = (rmse / (motion + REL_FLOOR)).mean()
    e_hat = gather_neighbours(pred, knn) - pred[:, :, None]
    e = gather_neighbours(tgt, knn) - tgt[:, :, None]
    out["knn"] = (e_hat.norm(dim=-1) - e.norm(dim=-1)).abs().mean()
    de_hat = gather_neighbours(d_hat, knn) - d_hat[:, :, None]
    de = gather_neighbours(d, knn) - d[:, :, None]
    out["knn_delta"] = (de_hat - de).norm(dim=-1).mean()
    static = (d.norm(dim=-1) < STATIC_THRESHOLD).float()
    out["static"] = (d_hat.norm(dim=-1) * static).sum() / static.sum().clamp(min=1.0)
    lap_hat = d_hat - gather_neighbours(d_hat, knn).mean(dim=2)
    lap = d - gather_neighbours(d, knn).mean(dim=2)
    out["smooth"] = (lap_hat - lap).norm(dim=-1).mean()
    if faces is not None and weights.nrm > 0:
        out["nrm"] = (1.0 - (vertex_normals_torch(pred, faces) * vertex_normals_torch(tgt, faces)).sum(-1)).mean()
    if corrective is not None and weights.skinbs > 0:
        w = corrective.norm(dim=-1)
        out["skinbs"] = ((d_hat - d).norm(dim=-1) * w).sum() / w.sum().clamp(min=1e-6)
    return out


def weighted_sum(terms: dict[str, torch.Tensor], weights) -> torch.Tensor:
    total = None
    for name, value in terms.items():
        w = getattr(weights, name)
        if w:
            total = value * w if total is None else total + value * w
    return total if total is not None else next(iter(terms.values())) * 0.0
