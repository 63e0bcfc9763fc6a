"""Batches for the two training phases, drawn from the training identities of a corpus."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from latent_model.config import Preset
from latent_model.corpus.pairs import Pair, enumerate_pairs
from latent_model.types import FINAL, PAIR_KINDS
from latent_model.corpus.poses import get_pose, mirror_pose
from latent_model.corpus.store import Corpus
from latent_model.nn.vertex_decoder import knn_graph




@dataclass
class PhaseABatch:
    """States of a few identities sharing one pose selection.

    enc_points (N, Ke, 3), enc_values (N, Ke), query_points (N, Q, 3), query_values (N, Q);
    identity_class (N,) (index among training identities); neutral_of (N,) row in this batch of
    the same identity's neutral state; pose_label (N,) (-1 for neutral); role (N,) str
    ("neutral" | "single" | "combo" | "component" | "skinning" | "blendshape");
    plus index lists for the composition losses.
    """

    enc_points: torch.Tensor
    enc_values: torch.Tensor
    query_points: torch.Tensor
    query_values: torch.Tensor
    identity_class: torch.Tensor
    neutral_of: torch.Tensor
    pose_label: torch.Tensor
    contrast_rows: torch.Tensor  # rows whose delta enters the contrastive/pose-cls losses
    variant_rows: torch.Tensor  # (M, 3): rows of (skinning_plus_blendshape, skinning, blendshape)
    combo_rows: list[tuple[int, list[int]]]  # (combo row, component rows)
    mirror_rows: torch.Tensor  # (M, 2): rows of one identity's sided pose and its mirror (both in contrast_rows)


class PhaseASampler:
    def __init__(self, corpus: Corpus, preset: Preset, seed: int) -> None:
        self.c = corpus
        self.t = preset.train
        self.rng = np.random.default_rng(seed)
        self.train_ids = corpus.split_indices("train")
        self.class_of = corpus.person_classes("train")  # a person in two rests is one identity class
        self.singles = [p for p in corpus.poses if not get_pose(p).is_combo]
        self.skeletal = [p for p in self.singles if get_pose(p).has_skeletal]
        # combos whose components are all in the corpus, at most 3 components (fists are 12)
        self.combos = [p for p in corpus.poses if get_pose(p).is_combo
                       and len(get_pose(p).components) <= 3 and all(x in corpus.poses for x in get_pose(p).components)]

    def _samples(self, state: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        pts, vals = self.c.sdf(state)
        K = len(vals)
        e = self.rng.choice(K, size=min(self.t.a_enc_points, K), replace=False)
        q = self.rng.choice(K, size=min(self.t.a_query_points, K), replace=False)
        return pts[e], vals[e], pts[q], vals[q]

    def _poses(self) -> list[str]:
        """a_poses distinct single poses; with a_mirrors each sided one brings its mirror (a_poses + 1 at most)."""
        n = min(self.t.a_poses, len(self.singles))
        if not self.t.a_mirrors:
            return [str(p) for p in self.rng.choice(self.singles, size=n, replace=False)]
        out: list[str] = []
        for p in self.rng.permutation(self.singles):
            if len(out) >= n:
                break
            m = mirror_pose(str(p))
            out += [x for x in (str(p), m) if x is not None and x in self.singles and x not in out]
        return out

    def sample(self) -> PhaseABatch:
        rng, c = self.rng, self.c
        ids = rng.choice(self.train_ids, size=min(self.t.a_identities, len(self.train_ids)), replace=False)
        poses = self._poses()
        combo = str(rng.choice(self.combos)) if self.combos else None
        var_pose = str(rng.choice(self.skeletal)) if self.skeletal else None
        rows: list[tuple[int, int, int, str]] = []  # (state, identity, pose label, role)
        variant_rows, combo_rows, contrast, mirrors = [], [], [], []
        for i in ids:
            i = int(i)
            rows.append((c.state(i, None, "neutral"), i, -1, "neutral"))
            where: dict[str, int] = {}

            def add(pose: str, variant: str, role: str) -> int:
                key = f"{pose}/{variant}"
                if key not in where:
                    where[key] = len(rows)
                    rows.append((c.state(i, pose, variant), i, c.pose_index(pose), role))
                return where[key]

            for p in poses:
                contrast.append(add(str(p), FINAL, "single"))
            for p in poses:
                m = mirror_pose(p)
                if m in poses and p < m:
                    mirrors.append((add(p, FINAL, "single"), add(m, FINAL, "single")))
            if combo:
                comp = [add(x, FINAL, "component") for x in get_pose(combo).components]
                combo_rows.append((add(combo, FINAL, "combo"), comp))
            if var_pose:
                variant_rows.append((add(var_pose, FINAL, "single"), add(var_pose, "skinning", "skinning"),
                                     add(var_pose, "blendshape", "blendshape")))
        neutral_of = []
        for s, i, _, _ in rows:
            neutral_of.append(next(k for k, r in enumerate(rows) if r[1] == i and r[3] == "neutral"))
        samples = [self._samples(s) for s, *_ in rows]
        stack = lambda k: torch.from_numpy(np.stack([x[k] for x in samples])).float()  # noqa: E731
        return PhaseABatch(
            stack(0), stack(1), stack(2), stack(3),
            torch.tensor([self.class_of[i] for _, i, _, _ in rows]),
            torch.tensor(neutral_of),
            torch.tensor([p for _, _, p, _ in rows]),
            torch.tensor(sorted(set(contrast + [r for r, _ in combo_rows]))),
            torch.tensor(variant_rows, dtype=torch.long).reshape(-1, 3),
            combo_rows,
            torch.tensor(mirrors, dtype=torch.long).reshape(-1, 2),
        )


@dataclass
class PhaseBBatch:
    v_src: torch.Tensor  # (B, V, 3)
    n_src: torch.Tensor
    v_tgt: torch.Tensor
    knn: torch.Tensor  # (B, V, K)
    src_rows: torch.Tensor  # (B,) geometry rows (for the cached latent means)
    tgt_rows: torch.Tensor
    kind: torch.Tensor  # (B,) index into PAIR_KINDS
    corrective: torch.Tensor  # (B, V, 3) V_skin+bs - V_skin on corrective pairs, else 0


class PhaseBSampler:
    """Uniform over pair kinds, then uniform over that kind's training pairs."""

    def __init__(self, corpus: Corpus, preset: Preset, seed: int, identities: list[int] | None = None) -> None:
        self.c = corpus
        self.t = preset.train
        self.k = preset.model.decoder.knn
        self.rng = np.random.default_rng(seed)
        ids = identities if identities is not None else corpus.split_indices("train")
        kinds = tuple(k for k in self.t.b_kinds if k in PAIR_KINDS)
        pairs = enumerate_pairs(ids, corpus.poses, kinds)
        self.by_kind = {k: [p for p in pairs if p.kind == k] for k in kinds}
        self.by_kind = {k: v for k, v in self.by_kind.items() if v}
        self._knn: dict[int, np.ndarray] = {}

    def knn(self, identity: int) -> np.ndarray:
        """Neighbourhoods of an identity, from its neutral mesh (shared topology across its states)."""
        if identity not in self._knn:
            self._knn[identity] = knn_graph(self.c.vertices(self.c.state(identity, None, "neutral")), self.k)
        return self._knn[identity]

    def states(self, p: Pair) -> tuple[int, int]:
        return (self.c.state(p.identity, p.source[0], p.source[1]), self.c.state(p.identity, p.target[0], p.target[1]))

    def sample(self) -> PhaseBBatch:
        kinds = list(self.by_kind)
        chosen = []
        for _ in range(self.t.b_batch):
            k = kinds[self.rng.integers(len(kinds))]
            chosen.append(self.by_kind[k][self.rng.integers(len(self.by_kind[k]))])
        return self.collate(chosen)

    def collate(self, pairs: list[Pair]) -> PhaseBBatch:
        c = self.c
        vs, ns, vt, kn, sr, tr, kd, corr = [], [], [], [], [], [], [], []
        for p in pairs:
            s, t = self.states(p)
            v_s, v_t = c.vertices(s), c.vertices(t)
            vs.append(v_s)
            ns.append(c.normals(s))
            vt.append(v_t)
            kn.append(self.knn(p.identity))
            sr.append(c.row(s))
            tr.append(c.row(t))
            kd.append(PAIR_KINDS.index(p.kind))
            corr.append(v_t - v_s if p.kind == "skinning_to_skinning_plus_blendshape" else np.zeros_like(v_s))
        f = lambda x: torch.from_numpy(np.stack(x)).float()  # noqa: E731
        return PhaseBBatch(f(vs), f(ns), f(vt), torch.from_numpy(np.stack(kn)), torch.tensor(sr), torch.tensor(tr),
                           torch.tensor(kd), f(corr))
