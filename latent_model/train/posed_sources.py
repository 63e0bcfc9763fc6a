"""Decoder v2's training pairs whose source is posed: `source_to_combo` (a combination's component in its final
state -> the combination's final state) of training characters.

A latent step taken from a posed limb is another direction than the same joint's step from the neutral (the SDF
code sees where the limb is): read as a neutral_to_pose delta, hipFlexLf+kneeBentLf's step from the flexed hip moved
the whole body (400 mm leak on validation) while the knee's own neutral delta bent that knee. So the decoder learns
the kind from its own pairs, on each posed source's own surface features and latent, as transfer reads it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from latent_model.corpus.pairs import enumerate_pairs
from latent_model.corpus.store import Corpus
from latent_model.surface import SurfaceFeatures, surface_features
from latent_model.surface_cache import features_path, load_features, save_features

KIND = "source_to_combo"


@dataclass
class PosedSources:
    """Pairs (character, source state, target state, bank key) and per posed source its vertices (V, 3), normals
    (V, 3), surface features and latent (Z,); the deltas μ(target) − μ(source) of every training character (for the
    mean and another character's delta) by bank key."""

    corpus: Corpus
    pairs: list[tuple[int, int, int, str]]
    sources: dict[int, tuple[np.ndarray, np.ndarray, SurfaceFeatures]]
    mu: dict[int, np.ndarray]  # state -> latent mean
    deltas: dict[str, dict[int, np.ndarray]] = field(default_factory=dict)  # bank key -> {character: delta}

    def __post_init__(self) -> None:
        self._means = {key: np.mean(list(d.values()), axis=0) for key, d in self.deltas.items()}  # drawn every step

    def mean(self, key: str) -> tuple[np.ndarray, int]:
        """(the key's delta averaged over the training characters, how many)."""
        return self._means[key], len(self.deltas[key])

    def target(self, k: int) -> np.ndarray:
        """(V, 3) pair k's target vertices."""
        return self.corpus.vertices(self.pairs[k][2])


def _features(args) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    v, faces = args
    sf = surface_features(v, faces)
    return sf.coords, sf.frames, sf.medial


def posed_sources(corpus: Corpus, train_ids: list[int], poses: tuple[str, ...], n_characters: int,
                  mu_of_state, cache_dir: Path | None = None, workers: int = 1, log=print) -> PosedSources:
    """The source_to_combo pairs of `n_characters` training characters spread over `train_ids` (seedless: every
    k-th), among the combinations in `poses`; the deltas of every training character. `mu_of_state(states)` ->
    (len(states), Z) latent means (the frozen encoder's)."""
    import time

    t0 = time.time()
    all_pairs = enumerate_pairs(train_ids, poses, (KIND,))
    step = max(1, len(train_ids) // max(n_characters, 1))
    chosen = set(train_ids[::step][:n_characters])
    states = sorted({corpus.state(p.identity, *st) for p in all_pairs for st in (p.source, p.target)})
    mu = dict(zip(states, mu_of_state(states)))
    deltas: dict[str, dict[int, np.ndarray]] = {}
    pairs = []
    for p in all_pairs:
        s, t = corpus.state(p.identity, *p.source), corpus.state(p.identity, *p.target)
        deltas.setdefault(p.bank_key, {})[p.identity] = mu[t] - mu[s]
        if p.identity in chosen:
            pairs.append((p.identity, s, t, p.bank_key))
    need = sorted({s for _, s, _, _ in pairs})
    sources: dict[int, tuple[np.ndarray, np.ndarray, SurfaceFeatures]] = {}
    todo = []
    for s in need:
        path = None if cache_dir is None else features_path(cache_dir, corpus, s)
        sf = None if path is None else load_features(path)
        if sf is not None:
            sources[s] = (corpus.vertices(s), corpus.normals(s), sf)
        else:
            todo.append((s, path))
    for (s, path), (coords, frames, medial) in zip(todo, _map(_features, [(corpus.vertices(s), corpus.faces)
                                                                          for s, _ in todo], workers)):
        sources[s] = (corpus.vertices(s), corpus.normals(s), SurfaceFeatures(coords, frames, medial, {}))
        if path is not None:
            save_features(path, sources[s][2])
    log(f"  posed sources: {len(pairs)} source_to_combo pairs of {len(chosen)} characters, {len(need)} sources "
        f"({len(todo)} surface features computed, {time.time() - t0:.0f} s)")
    return PosedSources(corpus, pairs, sources, mu, deltas)


def _map(fn, jobs: list, workers: int):
    if workers <= 1 or len(jobs) < 2:
        return map(fn, jobs)
    import multiprocessing as mp

    from latent_model.runtime import single_threaded

    with mp.get_context("spawn").Pool(workers, initializer=single_threaded) as pool:
        return pool.map(fn, jobs, chunksize=4)
