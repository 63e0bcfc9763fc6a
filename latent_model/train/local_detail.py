"""Training the local detail stage (`nn/local_detail.py`): region codecs, their bank, displacement fields.

Data: every training person of the corpus config, in bind, posed through the corpus's generator in the
poses of each region (`detail_poses.region_poses`); per state, each region's SDF samples co-moving with its
neutral's (one seed per character, the frame following the region: `regions.sample_region`) and the region's
vertices in that frame. No corpus is read: the config's persons are regenerated (posing is 0.04 s a mesh),
so `lrr train detail` runs beside or without a built corpus.

1. Per region kind, a codec (an SDF-VAE at the region's scale) learns to reconstruct the region's samples,
   with the same-pose deltas of different characters aligned and poses separated (as Phase A's delta terms).
2. The bank: each pose's co-moving region deltas per training character, standardised, and the noise floor of
   one co-moving delta (two samplings of a few characters' pairs).
3. Per region, the displacement field of each single pose (`detail_fields.py`): the characters' region
   displacements pooled on an anchor region after an affine alignment. No network: a decoder trained on the
   same data explained 0.15 of a face pose's motion on the validation characters, the fields 0.55.
"""
from __future__ import annotations

import multiprocessing as mp
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from latent_model.corpus.build import generator, init_generator_worker
from latent_model.corpus.identities import IdentitySpec
from latent_model.corpus.poses import get_pose
from latent_model.detail_fields import RegionFields, build_fields
from latent_model.detail_poses import detail_regions_of, region_label, region_poses
from latent_model.nn import losses
from latent_model.nn.encoder import reparameterise
from latent_model.nn.local_detail import KINDS, LocalDetail, LocalDetailConfig
from latent_model.regions import REGION_KIND, REGIONS, RegionSampling, region_frames, sample_region
from latent_model.types import FINAL


@dataclass(frozen=True)
class LocalDetailTraining:
    """Everything `lrr train detail` depends on besides the corpus config (the same gives the same model)."""

    net: LocalDetailConfig = field(default_factory=LocalDetailConfig)
    sampling: RegionSampling = field(default_factory=RegionSampling)
    codec_steps: int = 2000
    characters: int = 8  # per codec batch (each brings its neutral and `poses_per_character` poses)
    poses_per_character: int = 6
    points: int = 1024  # of a state's samples per codec step (the same indices for a character's states)
    queries: int = 512  # SDF decoder queries per state
    lr: float = 5e-4
    rec: float = 30.0
    kl: float = 1e-4
    align: float = 1.0
    contrast: float = 1.0  # poses kept apart as strongly as characters are aligned: weaker, face poses' means merge
    noise_characters: int = 8  # characters sampled twice to measure the noise floor of one co-moving delta
    seed: int = 0


@dataclass(frozen=True)
class DetailSection:
    """`--set detail.FIELD=VALUE` (or detail.net.FIELD, detail.sampling.FIELD) overrides, as `config.override` reads them."""

    detail: LocalDetailTraining


@dataclass
class RegionData:
    """One character's regions: samples {(region, pose or None): (points (K, 3), values (K,))}, the region's
    vertices in its frame {(region, pose or None): (N, 3)} (radius units) and radii {region: metres}."""

    person: str
    samples: dict
    vertices: dict
    radius: dict


def _character(args) -> RegionData:
    spec_dict, poses, sampling, seeds = args
    gen = generator()
    from latent_model.corpus.sdf import body_component_faces

    spec = IdentitySpec.from_dict(spec_dict)
    neutral = gen.neutral(spec).astype(np.float64)
    body = body_component_faces(neutral, gen.faces)
    frames = region_frames(neutral, gen.faces)
    samples, verts = {}, {}
    for k, seed in enumerate(seeds):
        for name, f in frames.items():
            samples[(k, name, None)] = sample_region(neutral, body, f, sampling, seed)
            verts[(name, None)] = f.to_local(neutral[f.vertices]).astype(np.float32)
        for region, pose_list in poses.items():
            f = frames[region]
            for p in pose_list:
                v = getattr(gen.pose(spec, p), FINAL).astype(np.float64)
                samples[(k, region, p)] = sample_region(v, body, f, sampling, seed, rest=neutral)
                verts[(region, p)] = f.follow(neutral, v).to_local(v[f.vertices]).astype(np.float32)
    return RegionData(spec.id, samples, verts, {n: f.radius for n, f in frames.items()})


def region_data(specs: list[IdentitySpec], poses: tuple[str, ...], sampling: RegionSampling, seeds: list[list[int]],
                workers: int = 2, log=print) -> list[RegionData]:
    """Every character of `specs` in bind, each region in its poses (`seeds[n]`: the n-th character's sampling
    seeds, one co-moving set per seed)."""
    by_region = {**region_poses(poses, "head"), **region_poses(poses, "hand")}
    jobs = [(s.to_dict(), by_region, sampling, sd) for s, sd in zip(specs, seeds)]
    out, t0 = [], time.time()
    ctx = mp.get_context("fork")
    with ctx.Pool(max(1, workers), initializer=init_generator_worker) as pool:
        for r in pool.imap(_character, jobs):
            out.append(r)
            if len(out) % 8 == 0 or len(out) == len(jobs):
                log(f"  regions of {len(out)}/{len(jobs)} characters ({time.time() - t0:.0f} s)")
    return out


def _states(data: list[RegionData], kind: str, seed_index: int = 0) -> list[dict]:
    """Per (character, region of `kind`): {label or None: (points, values)} of one sampling."""
    out = []
    for d in data:
        for region in REGIONS:
            if REGION_KIND[region] != kind:
                continue
            items = {(None if p is None else region_label(p, region)): pv
                     for (k, r, p), pv in d.samples.items() if k == seed_index and r == region}
            out.append(items)
    return out


def train_codec(model: LocalDetail, kind: str, data: list[RegionData], cfg: LocalDetailTraining, log=print) -> None:
    """Phase A at a region's scale: SDF reconstruction + KL + alignment and InfoNCE of same-label deltas."""
    codec = model.codecs[kind]
    gen = torch.Generator().manual_seed(cfg.seed + 11 + KINDS.index(kind))
    rng = np.random.default_rng([cfg.seed, 12, KINDS.index(kind)])
    states = _states(data, kind)
    labels = sorted({p for s in states for p in s if p is not None})
    opt = torch.optim.Adam(codec.parameters(), lr=cfg.lr)
    k_total = cfg.sampling.k
    t0 = time.time()
    for step in range(cfg.codec_steps):
        pts, vals, lab = [], [], []
        for b, n in enumerate(rng.choice(len(states), min(cfg.characters, len(states)), replace=False)):
            s = states[n]
            have = [p for p in labels if p in s]
            chosen = [None] + list(rng.choice(have, min(cfg.poses_per_character, len(have)), replace=False))
            sub = rng.choice(k_total, min(cfg.points, k_total), replace=False)
            for p in chosen:
                pts.append(s[p][0][sub])
                vals.append(s[p][1][sub])
                lab.append(-1 if p is None else labels.index(p))
        # each state's neutral is the first state of its character's block
        first = [i for i, l in enumerate(lab) if l == -1]
        neutral_of = torch.tensor([max(f for f in first if f <= i) for i in range(len(lab))])
        x, v = torch.from_numpy(np.stack(pts)), torch.from_numpy(np.stack(vals))
        mu, logvar = codec.encoder(x, v)
        z = reparameterise(mu, logvar, gen)
        q = torch.randint(0, x.shape[1], (len(x), cfg.queries), generator=gen)
        xq = torch.gather(x, 1, q[..., None].expand(-1, -1, 3))
        vq = torch.gather(v, 1, q)
        rec = (codec.sdf_decoder(z, xq).clamp(-0.1, 0.1) - vq.clamp(-0.1, 0.1)).abs().mean()
        lab_t = torch.tensor(lab)
        posed = lab_t >= 0
        deltas = (mu - mu[neutral_of])[posed]
        terms = {"rec": rec, "kl": losses.kl_divergence(mu, logvar),
                 "align": losses.alignment(deltas, lab_t[posed]),
                 "contrast": losses.contrastive(deltas, lab_t[posed], 0.1)}
        loss = sum(getattr(cfg, k) * t for k, t in terms.items())
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step % 500 == 0 or step == cfg.codec_steps - 1:
            log(f"  {kind} codec step {step}: " + " ".join(f"{k} {t.item():.4f}" for k, t in terms.items())
                + f" ({time.time() - t0:.0f} s)")


@torch.no_grad()
def _encode(model: LocalDetail, kind: str, pv_list: list[tuple[np.ndarray, np.ndarray]], raw: bool = False) -> np.ndarray:
    x = torch.from_numpy(np.stack([p for p, _ in pv_list]))
    v = torch.from_numpy(np.stack([s for _, s in pv_list]))
    enc = model.codecs[kind].encoder.eval()
    mu = torch.cat([enc(x[i:i + 64], v[i:i + 64])[0] for i in range(0, len(x), 64)])
    return mu.numpy() if raw else model.standardise(kind, mu).numpy()


def set_standardisation(model: LocalDetail, kind: str, data: list[RegionData]) -> None:
    """Each code dimension centred and scaled by the training states' codes (as the latent bank does)."""
    mu = _encode(model, kind, [pv for s in _states(data, kind) for pv in s.values()], raw=True)
    getattr(model, f"mean_{kind}").copy_(torch.from_numpy(mu.mean(axis=0)))
    getattr(model, f"scale_{kind}").copy_(torch.from_numpy(mu.std(axis=0) + 1e-6))


def region_deltas(model: LocalDetail, data: list[RegionData], seed_index: int = 0) -> dict:
    """{(pose, region): (n, Z) standardised co-moving deltas of the characters (in `data` order)} and the
    standardised neutral codes {(person, region): (Z,)}, for every pose with a detail part in the region."""
    deltas, neutral = {}, {}
    for d in data:
        for region in REGIONS:
            kind = REGION_KIND[region]
            keys = [p for (k, r, p) in d.samples if k == seed_index and r == region and p is not None
                    and region in detail_regions_of(p)]
            codes = _encode(model, kind, [d.samples[(seed_index, region, None)]]
                            + [d.samples[(seed_index, region, p)] for p in keys])
            neutral[(d.person, region)] = codes[0]
            for p, c in zip(keys, codes[1:]):
                deltas.setdefault((p, region), []).append(c - codes[0])
    return {k: np.stack(v) for k, v in deltas.items()}, neutral


def noise_floor(model: LocalDetail, data: list[RegionData]) -> dict[str, float]:
    """{kind: mean distance between one pair's co-moving deltas sampled with two seeds} over characters
    sampled twice (standardised units): what a delta of no motion measures."""
    a, _ = region_deltas(model, data, 0)
    b, _ = region_deltas(model, data, 1)
    out = {}
    for kind in KINDS:
        dist = [np.linalg.norm(a[k] - b[k], axis=1) for k in a if REGION_KIND[k[1]] == kind]
        out[kind] = float(np.concatenate(dist).mean())
    return out


def region_fields(data: list[RegionData], deltas: dict) -> dict[str, RegionFields]:
    """{region: its displacement fields}: each single pose of the bank with a part there, pooled over the
    characters of `data` (`detail_fields.build_fields`)."""
    out = {}
    for region in REGIONS:
        poses = [p for (p, r) in deltas if r == region and not get_pose(p).components]
        if poses:
            out[region] = build_fields([(d.vertices[(region, None)], {p: d.vertices[(region, p)] for p in poses})
                                        for d in data], poses)
    return out


def train_local_detail(specs: list[IdentitySpec], poses: tuple[str, ...], cfg: LocalDetailTraining, workers: int = 2,
                       log=print):
    """The whole stage on the bind characters `specs` -> (LocalDetail, DetailBank, {region: RegionFields})."""
    from latent_model.detail import DetailBank

    torch.manual_seed(cfg.seed)
    seeds = [[cfg.seed * 100_003 + 1000 + n] + ([cfg.seed * 100_003 + 500_000 + n] if n < cfg.noise_characters else [])
             for n in range(len(specs))]
    log(f"local detail: sampling the head and hands of {len(specs)} characters")
    data = region_data(specs, poses, cfg.sampling, seeds, workers, log)
    model = LocalDetail(cfg.net)
    for kind in KINDS:
        train_codec(model, kind, data, cfg, log)
        set_standardisation(model, kind, data)
    deltas, _ = region_deltas(model, data)
    floors = noise_floor(model, data[:cfg.noise_characters])
    log("  noise floor of one co-moving delta: " + ", ".join(f"{k} {v:.3f}" for k, v in floors.items()))
    t0 = time.time()
    fields = region_fields(data, deltas)
    log(f"  displacement fields of {sum(len(f.poses) for f in fields.values())} region poses ({time.time() - t0:.0f} s)")
    bank = DetailBank({k: v.astype(np.float32) for k, v in deltas.items()}, [d.person for d in data], floors,
                      cfg.sampling)
    return model.eval(), bank, fields


def detail_training(preset_name: str) -> LocalDetailTraining:
    """The local detail stage's training config of a named preset (tiny: a few steps of small networks)."""
    if preset_name == "tiny":
        return LocalDetailTraining(
            net=LocalDetailConfig(latent=16, enc_hidden=(16, 32), enc_out_hidden=32, sdf_hidden=32),
            sampling=RegionSampling(k=256), codec_steps=20, characters=2, poses_per_character=2,
            points=128, queries=64, noise_characters=2)
    return LocalDetailTraining()


def run_local_detail(preset, cfg: LocalDetailTraining, out: Path, workers: int = 2, log=print) -> Path:
    """Train the stage on the preset's training persons (bind) in its corpus config's poses; write `out`
    (`detail.safetensors`, read beside the checkpoint by `Transfer.from_files`)."""
    from latent_model.corpus.build import plan
    from latent_model.detail import LocalDetailModel

    specs, _, _ = plan(preset.corpus)
    train = [s for s in specs if s.split == "train" and s.rest == "bind"]
    net, bank, fields = train_local_detail(train, preset.corpus.pose_names(), cfg, workers, log)
    LocalDetailModel(net, bank, fields).save(out)
    return out
