"""Training the motion decoder (`nn/motion_decoder.py`) on random vertex subsets of many pairs.

The encoder is frozen: every state's latent mean is encoded once. Each step draws `batch` training
pairs (neutral -> pose of a training character), and of each `vertices` vertices, half where the
pair moves the surface (> 2 mm) and half anywhere; the condition is the pair's own delta or, with
probability `mean_prob`, the mean delta of its pose over the training characters (what transfer uses).
Surface features are computed once per character from its neutral mesh. With probability `posed_prob` a pair is a
source_to_combo pair instead, on its posed source's own features (train/posed_sources.py).
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import torch

from latent_model.analysis.metrics import STATIC_MM
from latent_model.config import MotionDecoderConfig
from latent_model.corpus.poses import get_pose
from latent_model.corpus.store import Corpus
from latent_model.encoding import encode_rows
from latent_model.nn.motion_decoder import MotionDecoder, apply_motion, chest_band
from latent_model.surface import SurfaceFeatures
from latent_model.surface_cache import state_features
from latent_model.train.combo_augment import ExtraPoses, extra_combinations
from latent_model.train.posed_sources import KIND, PosedSources, posed_sources
from latent_model.train.rest_augment import ExtraCharacters, extra_characters
from latent_model.types import FINAL, PAIR_KINDS


class CharacterCache:
    """Per character: neutral vertices, normals and surface features (computed on first use; kept in
    `directory`, keyed by the corpus digest, when one is given: ~1 s per character to compute)."""

    def __init__(self, corpus: Corpus, directory: Path | None = None) -> None:
        self.c = corpus
        self.dir = directory
        self._f: dict[int, tuple[np.ndarray, np.ndarray, SurfaceFeatures]] = {}

    def get(self, i: int) -> tuple[np.ndarray, np.ndarray, SurfaceFeatures]:
        if i not in self._f:
            s = self.c.state(i, None, "neutral")
            self._f[i] = (self.c.vertices(s), self.c.normals(s), state_features(self.c, s, self.dir))
        return self._f[i]

    def add(self, extra: "ExtraCharacters") -> None:
        """Characters beyond the corpus's (train/rest_augment.py), under their own ids."""
        for k, i in enumerate(extra.ids):
            self._f[i] = (extra.neutral[k], extra.normals[k], extra.features[k])


class DeltaTable:
    """Latent means of the neutral and final states of characters, their deltas and the mean per pose."""

    def __init__(self, model, corpus: Corpus, ids: list[int], train_ids: list[int], poses: tuple[str, ...],
                 device: torch.device, mu_rows: torch.Tensor | None = None) -> None:
        """`mu_rows`: the frozen encoder's means by geometry row when Phase B has them (else encoded here)."""
        c = corpus
        rows = sorted({c.row(c.state(i, None, "neutral")) for i in ids}
                      | {c.row(c.state(i, p, FINAL)) for i in ids for p in poses})
        if mu_rows is not None and bool((mu_rows[rows].abs().sum(dim=1) > 0).all()):
            mu = mu_rows.cpu().numpy()
        else:
            mu = encode_rows(model, c, rows, device, progress=False).numpy()
        self.mu_rows = mu  # (G, Z) by geometry row: the rows above filled
        self.mu_neutral = {i: mu[c.row(c.state(i, None, "neutral"))] for i in ids}
        self.delta = {(i, p): mu[c.row(c.state(i, p, FINAL))] - self.mu_neutral[i] for i in ids for p in poses}
        self.mean = {p: np.mean([self.delta[(i, p)] for i in train_ids], axis=0) for p in poses}
        self.mean_count = {p: len(train_ids) for p in poses}  # characters each mean averages
        self.scale = float(np.mean([np.linalg.norm(self.delta[(i, p)]) for i in train_ids for p in poses]))

    def add(self, extra: "ExtraCharacters") -> None:
        """The latents of characters beyond the corpus's; the per-pose means and the scale stay the corpus's
        (transfer conditions on the bank's means, which are the corpus's)."""
        for k, i in enumerate(extra.ids):
            self.mu_neutral[i] = extra.mu_neutral[k]
            for j, p in enumerate(extra.poses):
                self.delta[(i, p)] = extra.mu_posed[k, j] - extra.mu_neutral[k]

    def add_poses(self, extra: "ExtraPoses") -> None:
        """The deltas of poses beyond the corpus's (train/combo_augment.py) and each one's mean over the
        characters posed in it; the scale stays the corpus's."""
        for (i, p), mu in extra.mu.items():
            self.delta[(i, p)] = mu - self.mu_neutral[i]
        for p in extra.poses:
            posed = [self.delta[pair] for pair in extra.pairs if pair[1] == p]
            self.mean[p], self.mean_count[p] = np.mean(posed, axis=0), len(posed)

    def directions(self, ids: list[int], poses: tuple[str, ...]) -> np.ndarray:
        """(len(ids) * len(poses), Z) unit directions of the characters' own deltas."""
        d = np.stack([self.delta[(i, p)] for i in ids for p in poses])
        return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)


def ring_neighbours(faces: np.ndarray, n_vertices: int, rings: int):
    """CSR adjacency (V, V) of the vertices within `rings` edges of each vertex (itself excluded)."""
    import scipy.sparse as sp

    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    a = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n_vertices, n_vertices)).tocsr()
    a = ((a + a.T) > 0).astype(np.float32)
    reach = a.copy()
    for _ in range(rings - 1):
        reach = ((reach + reach @ a) > 0).astype(np.float32)
    reach.setdiag(0)
    reach.eliminate_zeros()
    return reach.tocsr()


def sample_neighbours(rng: np.random.Generator, reach, idx: np.ndarray) -> np.ndarray:
    """One random neighbour (from `ring_neighbours`) of each vertex in idx (N,) -> (N,)."""
    start, count = reach.indptr[idx], np.diff(reach.indptr)[idx]
    return reach.indices[start + (rng.random(len(idx)) * count).astype(np.int64)]


def _batch_tensors(rows: list[dict]) -> dict[str, torch.Tensor]:
    return {k: torch.from_numpy(np.stack([r[k] for r in rows])).float() if rows[0][k].dtype != np.int64
            else torch.from_numpy(np.stack([r[k] for r in rows])) for k in rows[0]}


def pair_inputs(cache: CharacterCache, table: DeltaTable, i: int, pose: str, delta: np.ndarray,
                idx: np.ndarray | None = None, averaged: float = 1) -> dict:
    """Decoder inputs of character i's neutral (all vertices, or `idx`) with condition `delta`, which averages
    the deltas of `averaged` characters (a pose's mean: `table.mean_count[pose]`)."""
    v, n, sf = cache.get(i)
    return source_inputs(v, n, sf, table.mu_neutral[i], delta, idx, table.scale, "neutral_to_pose", averaged)


def source_inputs(v: np.ndarray, n: np.ndarray, sf: SurfaceFeatures, mu_src: np.ndarray, delta: np.ndarray,
                  idx: np.ndarray | None, scale: float, kind: str, averaged: float) -> dict:
    """Decoder inputs of a source mesh (vertices, normals (V, 3), its surface features; all vertices, or `idx`) and
    latent mu_src (Z,) with condition `delta` (Z,) of pair kind `kind` (its length over the table's `scale`)."""
    sel = slice(None) if idx is None else idx
    r = np.linalg.norm(delta)
    return {"v_src": v[sel], "coords": sf.coords[sel], "frames": sf.frames[sel], "normals": n[sel],
            "medial": sf.medial[sel], "mu_src": mu_src, "delta_dir": delta / max(r, 1e-12),
            "r": np.float32(r / scale), "kind": np.int64(PAIR_KINDS.index(kind)), "averaged": np.float32(averaged)}


def predict(decoder: MotionDecoder, inputs: dict, smooth=None, rigid=None, repivot: float = 0.0,
            magnitude: float = 1.0) -> np.ndarray:
    """One prediction on a whole mesh in eval mode (no training noise), leaving the decoder's mode as it was;
    `smooth`: `surface_smoother(...)` of the mesh; `rigid`: its `part_rigidifier(...)`; `repivot`: as the config's;
    `magnitude` scales the delta's length."""
    b = _batch_tensors([inputs])
    was = decoder.training
    decoder.eval()
    with torch.no_grad():
        m = decoder.rigid_motion(b["v_src"], b["coords"], b["frames"], b["normals"], b["medial"], b["mu_src"],
                                 b["delta_dir"], b["r"] * magnitude, b["kind"], smooth=smooth, repivot=repivot,
                                 r_ref=b["r"], averaged=b["averaged"])
        out = (apply_motion if rigid is None else rigid)(b["v_src"], m)
    decoder.train(was)
    return out[0].numpy()


def train_motion_decoder(decoder: MotionDecoder, corpus: Corpus, cache: CharacterCache, table: DeltaTable,
                         train_ids: list[int], poses: tuple[str, ...], cfg: MotionDecoderConfig, seed: int,
                         log=print, validate=None, validate_every: int = 500,
                         extra: "ExtraCharacters | None" = None, extra_poses: "ExtraPoses | None" = None,
                         posed: "PosedSources | None" = None) -> list[dict]:
    """`extra`: characters beyond the corpus (in `cache` and `table` already) whose pairs are trained on too;
    `extra_poses`: poses beyond the corpus's of training characters (their deltas in `table` already), likewise;
    `posed`: source_to_combo pairs, drawn with probability `cfg.posed_prob`."""
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    opt = torch.optim.Adam(decoder.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.steps, eta_min=cfg.lr * 0.05)
    pairs = [(i, p) for i in train_ids for p in poses] + ([(i, p) for i in extra.ids for p in poses] if extra else [])
    pairs += extra_poses.pairs if extra_poses else []
    posed_in: dict[str, list[int]] = {}  # pose -> the characters with a delta of it
    for i, p in pairs:
        posed_in.setdefault(p, []).append(i)
    reach = ring_neighbours(corpus.faces, len(cache.get(train_ids[0])[0]), cfg.edge_rings) if cfg.edge else None
    history = []
    t0 = time.perf_counter()
    for step in range(1, cfg.steps + 1):
        rows, targets = [], []
        for k in rng.integers(len(pairs), size=cfg.batch):
            if posed is not None and rng.random() < cfg.posed_prob:
                row, tgt = _posed_pair(rng, posed, table.scale, cfg, reach)
                rows.append(row)
                targets.append(tgt)
                continue
            i, p = pairs[k]
            v = cache.get(i)[0]
            if extra_poses is not None and (i, p) in extra_poses:
                tgt = extra_poses.targets[(i, p)]
            elif extra is not None and i in extra:
                tgt = extra.target(i, p)
            else:
                tgt = corpus.vertices(corpus.state(i, p, FINAL))
            idx = _vertex_subset(rng, v, tgt, cfg, reach, cache.get(i)[2].coords)
            u = rng.random()
            if u < cfg.mean_prob:
                delta, averaged = table.mean[p], table.mean_count[p]
            elif u < cfg.mean_prob + cfg.other_prob:  # another character's delta of the pose, as transfer reads one
                who = posed_in[p]
                delta, averaged = table.delta[(who[rng.integers(len(who))], p)], 1
                if cfg.other_mix and rng.random() < cfg.other_mix:  # or a mix of two: a delta no character gave
                    w = rng.random()
                    delta = w * delta + (1.0 - w) * table.delta[(who[rng.integers(len(who))], p)]
                    averaged = 1.0 / (w * w + (1.0 - w) ** 2)  # the mix's effective count of independent deltas
            else:
                delta, averaged = table.delta[(i, p)], 1
            rows.append(pair_inputs(cache, table, i, p, delta, idx, averaged))
            targets.append(tgt[idx])
        b = _batch_tensors(rows)
        c = decoder.condition(b["mu_src"], b["delta_dir"], b["kind"], b["averaged"])
        out = decoder.motion(b["coords"], b["frames"], b["normals"], b["medial"] - b["v_src"], c)
        motion = decoder.rigid_motion(b["v_src"], b["coords"], b["frames"], b["normals"], b["medial"], b["mu_src"],
                                      b["delta_dir"], b["r"], b["kind"], outputs=out)
        pred = apply_motion(b["v_src"], motion)
        tgt = torch.from_numpy(np.stack(targets)).float()
        loss = (pred - tgt).norm(dim=-1).mean() * 1000  # mm
        if cfg.translation:
            loss = loss + cfg.translation * motion.u.norm(dim=-1).mean() * 1000
        if cfg.world_penalty and decoder.world:
            # the world-axis parts only where the limb frame cannot say it (the torso): a limb's turn in world axes
            # is right in the rests it was learnt in and wrong in any other. In mm: a turn at a 10 cm lever, a shift
            world_mm = (out[..., 9:12].norm(dim=-1) + out[..., 12:15].norm(dim=-1)) * 0.1 * 1000
            loss = loss + cfg.world_penalty * world_mm.mean()
        if cfg.static:
            # (B, N): still as the leak metric reads it
            still = ((tgt - b["v_src"]).norm(dim=-1) < STATIC_MM / 1000).to(pred.dtype)
            moved = (pred - b["v_src"]).norm(dim=-1)
            loss = loss + cfg.static * (moved * still).sum() / still.sum().clamp(min=1.0) * 1000
        if reach is not None:
            # relative position of neighbours: a rigid part stays rigid (per-vertex errors alone let it crumple)
            half, n = cfg.vertices // 2, cfg.vertices
            rel = (pred[:, :half] - pred[:, n:n + half]) - (tgt[:, :half] - tgt[:, n:n + half])
            loss = loss + cfg.edge * rel.norm(dim=-1).mean() * 1000
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(decoder.parameters(), 1.0)
        opt.step()
        sched.step()
        if step % 100 == 0 or step == 1:
            log(f"step {step} loss {loss.item():.2f} mm ({time.perf_counter() - t0:.0f} s)")
        if validate is not None and (step % validate_every == 0 or step == cfg.steps):
            history.append({"step": step, **validate(decoder)})
            log(f"  val step {step}: {history[-1]}")
    return history


def _vertex_subset(rng: np.random.Generator, v: np.ndarray, tgt: np.ndarray, cfg: MotionDecoderConfig, reach,
                   coords: np.ndarray) -> np.ndarray:
    """The vertices a pair (source v, target tgt (V, 3)) trains on: `cfg.vertices`, half where it moves the surface
    (> 2 mm) and half anywhere, then (with the edge term's `reach`) a neighbour of each moving one, its partner, then
    (`cfg.carried_arms`) `cfg.carried_band` of the chest band that carries the arms (located by the source's
    geodesic coordinates `coords` (V, 6))."""
    moving = np.flatnonzero(np.linalg.norm(tgt - v, axis=1) > 0.002)
    half = cfg.vertices // 2
    idx = np.concatenate([rng.choice(moving, size=half) if len(moving) else rng.integers(len(v), size=half),
                          rng.integers(len(v), size=cfg.vertices - half)])
    if reach is not None:
        idx = np.concatenate([idx, sample_neighbours(rng, reach, idx[:half])])
    band = np.flatnonzero(chest_band(coords)) if cfg.carried_arms else ()
    if len(band):
        idx = np.concatenate([idx, rng.choice(band, size=cfg.carried_band)])
    return idx


def _posed_pair(rng: np.random.Generator, posed: "PosedSources", scale: float, cfg: MotionDecoderConfig, reach=None
                ) -> tuple[dict, np.ndarray]:
    """(inputs, target (n, 3)) of a random posed-source pair on its `_vertex_subset`, conditioned as the neutral
    pairs are: its key's mean, another training character's delta, or its own."""
    k = int(rng.integers(len(posed.pairs)))
    i, s, _, key = posed.pairs[k]
    (v, n, sf), tgt = posed.sources[s], posed.target(k)
    idx = _vertex_subset(rng, v, tgt, cfg, reach, sf.coords)
    u = rng.random()
    if u < cfg.mean_prob:
        delta, averaged = posed.mean(key)
    elif u < cfg.mean_prob + cfg.other_prob:
        who = list(posed.deltas[key])
        delta, averaged = posed.deltas[key][who[rng.integers(len(who))]], 1
    else:
        delta, averaged = posed.deltas[key][i], 1
    return source_inputs(v, n, sf, posed.mu[s], delta, idx, scale, KIND, averaged), tgt[idx]


def training_poses(corpus: Corpus, which: str) -> tuple[str, ...]:
    """The corpus poses the motion decoder trains on: "all", or "body" (poses of the body group and the combos
    made only of them: the face and finger poses' deltas are at the latent noise floor, issue 19)."""

    if which == "all":
        return tuple(corpus.poses)
    if which != "body":
        raise ValueError(f"MotionDecoderConfig.poses {which!r}: use 'body' or 'all'")

    def body(name: str) -> bool:
        p = get_pose(name)
        return all(get_pose(c).group == "body" for c in p.components) if p.is_combo else p.group == "body"

    return tuple(p for p in corpus.poses if body(p))


def train_motion_phase(model, preset, corpus: Corpus, run_dir: Path, device: torch.device,
                       progress: bool = True, mu_rows: torch.Tensor | None = None) -> list[dict]:
    """Phase B's motion-decoder part (encoder frozen): neutral_to_pose pairs of the training characters and
    the config's poses; sets the decoder's delta scale and mu_src read-out. Surface features cached in run_dir."""
    m = preset.model.motion
    dec = model.motion_decoder
    train_ids = corpus.split_indices("train")
    poses = training_poses(corpus, m.poses)
    log = print if progress else (lambda *_: None)
    table = DeltaTable(model, corpus, train_ids, train_ids, poses, device, mu_rows)
    cache = CharacterCache(corpus, Path(run_dir) / "surface")
    extra = None
    if m.extra_rests:
        ranges = {a: tuple(r) for a, r in (("arms", m.extra_rest_arms), ("elbows", m.extra_rest_elbows)) if r}
        extra = extra_characters(model, corpus, train_ids, poses, m.extra_rests, preset.train.seed + 6000, device,
                                 workers=min(2, os.cpu_count() or 1), log=log, ranges=ranges,
                                 margin=m.extra_rest_margin)
        cache.add(extra)
        table.add(extra)
    combos = None
    if m.extra_combos:
        singles = tuple(p for p in poses if not get_pose(p).is_combo)
        combos = extra_combinations(model, corpus, train_ids, singles, m.extra_combos, m.combos_per_character,
                                    preset.train.seed + 7000, device, workers=min(2, os.cpu_count() or 1), log=log,
                                    sizes=m.combo_sizes, odds=m.combo_odds, amplitude=m.combo_amplitude)
        table.add_poses(combos)
    posed = None
    if m.posed_prob > 0:
        posed = posed_sources(corpus, train_ids, poses, m.posed_characters,
                              lambda states: table.mu_rows[[corpus.row(s) for s in states]],
                              Path(run_dir) / "surface", workers=min(2, os.cpu_count() or 1), log=log)
    fitted = train_ids + (extra.ids if extra else [])
    dec.delta_scale.fill_(table.scale)
    if dec.averaged_input:
        dec.averaged_ref.fill_(float(len(train_ids)))  # the bank's means average this many characters
    dec.set_mu_basis(torch.from_numpy(np.stack([table.mu_neutral[i] for i in fitted])).float())
    dec.set_delta_basis(torch.from_numpy(table.directions(fitted, poses)).float())
    dec.train()
    history = train_motion_decoder(dec, corpus, cache, table, train_ids, poses, m, preset.train.seed + 5000,
                                   log=log, extra=extra, extra_poses=combos, posed=posed)
    dec.eval()
    return history
