"""Phase A (representation) and Phase B (vertex decoder, encoder frozen)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from latent_model.config import Preset
from latent_model.corpus.store import Corpus
from latent_model.nn import losses
from latent_model.nn.encoder import reparameterise
from latent_model.nn.model import LatentReRig
from latent_model.checkpoint import load_phase_a, load_phase_b_network, save_checkpoint
from latent_model.encoding import encode_rows
from latent_model.nn.delta import normalised_delta
from latent_model.train.data import PhaseABatch, PhaseASampler, PhaseBBatch, PhaseBSampler
from latent_model.train.fit_pose_fields import fit_pose_fields, pose_prototypes
from latent_model.train.loop import PhaseSpec, dist_info, run_phase


class PhaseANet(nn.Module):
    """L_A = L_SDF + L_latent on one PhaseABatch."""

    def __init__(self, model: LatentReRig, preset: Preset) -> None:
        super().__init__()
        self.encoder, self.sdf_decoder = model.encoder, model.sdf_decoder
        self.char_head, self.pose_head = model.char_head, model.pose_head
        self.w = preset.loss
        self.clamp = preset.model.sdf_clamp

    def forward(self, b: PhaseABatch):
        w = self.w
        mu, logvar = self.encoder(b.enc_points, b.enc_values)
        z = reparameterise(mu, logvar)
        t: dict[str, torch.Tensor] = {}
        t["rec"] = losses.sdf_reconstruction(self.sdf_decoder(z, b.query_points), b.query_values, self.clamp)
        t["kl"] = losses.kl_divergence(mu, logvar)
        t["cls"] = F.cross_entropy(self.char_head(mu), b.identity_class)
        delta = mu - mu[b.neutral_of]
        rows = b.contrast_rows
        direction, _ = normalised_delta(delta[rows])
        t["pose_cls"] = F.cross_entropy(self.pose_head(direction), b.pose_label[rows])
        t["contrast"] = losses.contrastive(delta[rows], b.pose_label[rows], w.contrast_temperature)
        if w.align:
            t["align"] = losses.alignment(delta[rows], b.pose_label[rows])
        if w.consist:
            t["consist"] = losses.consistency(delta[rows], b.pose_label[rows])
        if w.mirror and len(b.mirror_rows):
            m = b.mirror_rows
            t["mirror"] = losses.mirror_cosine(delta[m[:, 0]], delta[m[:, 1]])
        if len(b.variant_rows):
            v = b.variant_rows
            t["variant"] = losses.composition(delta[v[:, 0]], delta[v[:, 1]] + delta[v[:, 2]])
        if b.combo_rows:
            tot = torch.stack([delta[c] for c, _ in b.combo_rows])
            parts = torch.stack([delta[comps].sum(0) for _, comps in b.combo_rows])
            t["combo"] = losses.composition(tot, parts)
        total = sum(getattr(w, k) * v for k, v in t.items() if getattr(w, k))
        return total, {k: v.detach() for k, v in t.items()}


class PhaseBNet(nn.Module):
    """L_vertex (+ L_skinBS on corrective pairs) of the vertex decoder on one PhaseBBatch."""

    def __init__(self, model: LatentReRig, preset: Preset, faces: np.ndarray, mu_rows: torch.Tensor) -> None:
        super().__init__()
        self.vd = model.vertex_decoder
        self.fields = model.pose_fields
        self.w = preset.loss
        self.register_buffer("faces", torch.as_tensor(faces, dtype=torch.long), persistent=False)
        self.register_buffer("mu_rows", mu_rows, persistent=False)  # (G, Z) frozen-encoder means per geometry row

    def forward(self, b: PhaseBBatch):
        mu_src, mu_tgt = self.mu_rows[b.src_rows], self.mu_rows[b.tgt_rows]
        direction, r = normalised_delta(mu_tgt - mu_src)
        weights = self.fields.weights(direction, b.kind)
        field_disp = self.fields.displacement(b.v_src, direction, r, b.kind)
        pred = self.vd(b.v_src, b.n_src, mu_src, direction, r, b.kind, b.knn, weights, field_disp)["vertices"]
        t = losses.vertex_losses(pred, b.v_src, b.v_tgt, b.knn, self.faces, self.w, b.corrective)
        return losses.weighted_sum(t, self.w), {k: v.detach() for k, v in t.items()}


def _rng_accessors(sampler):
    return (lambda: sampler.rng.bit_generator.state,
            lambda s: setattr(sampler.rng.bit_generator, "state", s))


def train_phase_a(model: LatentReRig, preset: Preset, corpus: Corpus, run_dir: Path, device: torch.device,
                  fresh: bool = False, steps: int | None = None, progress: bool = True) -> dict:
    rank, _ = dist_info()
    torch.manual_seed(preset.train.seed + rank)
    sampler = PhaseASampler(corpus, preset, preset.train.seed + 1000 * rank)
    get, put = _rng_accessors(sampler)
    net = PhaseANet(model, preset).to(device)
    spec = PhaseSpec("a", steps or preset.train.a_steps, preset.train.a_lr, net,
                     list(model.phase_a_parameters()), sampler.sample, get, put)
    return run_phase(spec, model, preset, run_dir, device, fresh=fresh, progress=progress)


def freeze_encoder(model: LatentReRig) -> None:
    """Phase B: the encoder (and Phase A parts) are frozen and in eval mode."""
    for part in (model.encoder, model.sdf_decoder, model.char_head, model.pose_head):
        part.eval()
        for p in part.parameters():
            p.requires_grad_(False)


def phase_b_inputs(model: LatentReRig, preset: Preset, corpus: Corpus, device: torch.device, rank: int = 0,
                   progress: bool = True) -> tuple[PhaseBSampler, torch.Tensor]:
    """The Phase B pair sampler of a rank and the frozen encoder's mu of every state its pairs use
    (rows indexed by corpus row): what the closed-form parts are set from (also bench/field_mixing.py)."""
    sampler = PhaseBSampler(corpus, preset, preset.train.seed + 2000 + 1000 * rank)
    rows = sorted({corpus.row(s) for pairs in sampler.by_kind.values() for p in pairs for s in sampler.states(p)})
    return sampler, encode_rows(model, corpus, rows, device, progress=progress)


def field_fit_seed(preset: Preset) -> int:
    """Seed of the pose fields' vertex subsets."""
    return preset.train.seed + 3000


def train_phase_b(model: LatentReRig, preset: Preset, corpus: Corpus, run_dir: Path, device: torch.device,
                  fresh: bool = False, steps: int | None = None, progress: bool = True) -> dict:
    rank, _ = dist_info()
    torch.manual_seed(preset.train.seed + 7 + rank)
    freeze_encoder(model)
    sampler, mu_rows = phase_b_inputs(model, preset, corpus, device, rank, progress=progress and rank == 0)
    model.pose_fields.set_prototypes(pose_prototypes(sampler, corpus, mu_rows, preset.model.n_poses).to(device))
    fit_pose_fields(model.pose_fields, sampler, corpus, mu_rows, field_fit_seed(preset), progress=progress and rank == 0)
    get, put = _rng_accessors(sampler)
    net = PhaseBNet(model, preset, corpus.faces, mu_rows).to(device)
    spec = PhaseSpec("b", steps or preset.train.b_steps, preset.train.b_lr, net,
                     list(model.vertex_decoder.parameters()), sampler.sample, get, put)
    out = run_phase(spec, model, preset, run_dir, device, fresh=fresh, progress=progress)
    if model.motion_decoder is not None and rank == 0:
        from latent_model.train.motion import train_motion_phase

        train_motion_phase(model, preset, corpus, run_dir, device, progress=progress, mu_rows=mu_rows)
    return out


def train(preset: Preset, corpus: Corpus, run_dir: Path, phases: str = "all", device: torch.device | None = None,
          fresh: bool = False, progress: bool = True) -> Path:
    """Run phase A, B, both ("all"), or decoder v2 alone on a finished Phase B ("motion"); writes
    run_dir/model.safetensors (all parts) at the end."""
    from latent_model.runtime import select_device

    device = device or select_device()
    run_dir = Path(run_dir)
    torch.manual_seed(preset.train.seed)
    model = LatentReRig(preset.model).to(device)
    if phases in ("all", "a"):
        train_phase_a(model, preset, corpus, run_dir, device, fresh=fresh, progress=progress)
    if phases in ("all", "b"):
        ckpt_a = run_dir / "phase_a.safetensors"
        load_phase_a(ckpt_a, model, expect=preset)  # Phase B always starts from the finished Phase A
        model.to(device)
        train_phase_b(model, preset, corpus, run_dir, device, fresh=fresh, progress=progress)
    if phases == "motion":  # decoder v2 alone, on the finished Phase B network (its checkpoint is written before it)
        if model.motion_decoder is None:
            raise ValueError(f"preset {preset.name!r} has no motion decoder (MotionDecoderConfig.enabled is False)")
        load_phase_b_network(run_dir / "phase_b.safetensors", model, expect=preset)
        freeze_encoder(model)
        from latent_model.train.motion import train_motion_phase

        train_motion_phase(model.to(device), preset, corpus, run_dir, device, progress=progress)
    final = run_dir / "model.safetensors"
    if dist_info()[0] == 0:
        save_checkpoint(final, model, preset, phases, 0, extra={"corpus_digest": corpus.manifest["config_digest"],
                                                                "corpus_generator": corpus.manifest.get("generator_version", 3)})
    return final
