"""More rest configurations for decoder v2's training pairs: each training person of the corpus also
stands in `per_person` random rests, drawn within the angle ranges of the training rests (corpus/rests.py) or
wider ones, never within a margin of a validation or test rest.

Why: the corpus stands each training person in bind and one of six fixed rests, and the decoder learnt
those; it read unseen rests far worse (validation rests, elbowBentLf 0.56 explained; a character's own
delta 0.19). Posing through the rig is cheap (0.04 s a mesh); each state's latent needs an SDF sampling
(0.1 s) and the frozen encoder. A draw closer than the margin (the largest of its four angle differences) to a
validation or test rest is drawn again, so none of those is seen; the draws are seeded, so the same config gives
the same characters.
"""
from __future__ import annotations

import multiprocessing as mp
import time
from dataclasses import asdict, dataclass
from functools import cached_property

import numpy as np

from latent_model.corpus.build import generator, init_generator_worker
from latent_model.corpus.identities import IdentitySpec
from latent_model.corpus.rests import REST_CONFIGS, TRAIN_RESTS, RestConfig
from latent_model.surface import SurfaceFeatures

ANGLES = ("arms", "elbows", "legs", "spine")


def rest_ranges() -> dict[str, tuple[float, float]]:
    """(lowest, highest) of each rest angle over the training rests (bind included), degrees."""
    rests = [REST_CONFIGS[n] for n in TRAIN_RESTS]
    return {a: (min(getattr(r, a) for r in rests), max(getattr(r, a) for r in rests)) for a in ANGLES}


def held_out_distance(angles: dict[str, float]) -> float:
    """The largest angle difference (degrees) between `angles` and the nearest validation or test rest."""
    held = [r for r in REST_CONFIGS.values() if r.split != "train"]
    return min(max(abs(angles[a] - getattr(r, a)) for a in ANGLES) for r in held)


def random_rests(rng: np.random.Generator, n: int, prefix: str = "drawn",
                 ranges: dict[str, tuple[float, float]] | None = None, margin: float = 0.0) -> list[RestConfig]:
    """`n` rest configurations, each angle uniform in its range (`ranges`, default `rest_ranges()`; an angle it
    omits keeps its training range), each at least `margin` degrees (`held_out_distance`) from every validation
    and test rest."""
    ranges = {**rest_ranges(), **(ranges or {})}
    out = []
    while len(out) < n:
        angles = {a: round(float(rng.uniform(*ranges[a])), 2) for a in ANGLES}
        if held_out_distance(angles) >= margin:
            out.append(RestConfig(f"{prefix}{len(out):03d}", **angles))
    return out


@dataclass
class ExtraCharacters:
    """Training characters beyond the corpus's, with ids `ids` (after the corpus's own indices).

    neutral, normals: (A, V, 3) float32; posed: (A, P, V, 3) float32, the final state of each of `poses`;
    mu_neutral: (A, Z); mu_posed: (A, P, Z); features: A surface features of the neutrals."""

    ids: list[int]
    person: list[int]  # the corpus index of each one's person (its bind character)
    rests: list[RestConfig]
    poses: tuple[str, ...]
    neutral: np.ndarray
    normals: np.ndarray
    posed: np.ndarray
    mu_neutral: np.ndarray
    mu_posed: np.ndarray
    features: list[SurfaceFeatures]

    def __contains__(self, i: int) -> bool:
        return i in self._row

    @cached_property
    def _row(self) -> dict[int, int]:
        return {i: k for k, i in enumerate(self.ids)}

    def target(self, i: int, pose: str) -> np.ndarray:
        """(V, 3) the final state of `pose` on extra character `i`."""
        return self.posed[self._row[i], self.poses.index(pose)]


def generate(work, jobs: list, workers: int, progress=lambda done: None) -> list:
    """[work(job) for job in jobs] in order, on `workers` spawned processes each holding a rig state generator
    (`corpus.build.generator()`; in this process when workers <= 1); progress(done) every 20 jobs and at the end."""
    out = []
    if workers <= 1:
        init_generator_worker()
        pool, results = None, map(work, jobs)
    else:
        pool = mp.get_context("spawn").Pool(workers, initializer=init_generator_worker)
        results = pool.imap(work, jobs)
    try:
        for k, r in enumerate(results):
            out.append(r)
            if (k + 1) % 20 == 0 or k + 1 == len(jobs):
                progress(k + 1)
    finally:
        if pool is not None:
            pool.terminate()
    return out


def _character(args) -> tuple:
    """One person in one rest: neutral, normals, posed finals, SDF samples of every state, surface features."""
    from latent_model.corpus.sdf import SdfSampling, sample_sdf, vertex_normals
    from latent_model.surface import surface_features

    spec_dict, rest_dict, poses, sdf_dict, body_faces, seed = args
    gen = generator()
    spec, rest, sdf = IdentitySpec.from_dict(spec_dict), RestConfig(**rest_dict), SdfSampling(**sdf_dict)
    neutral = gen.neutral(spec, rest)
    posed = np.stack([gen.pose(spec, p, rest).skinning_plus_blendshape for p in poses])
    seeds = np.random.SeedSequence(seed).generate_state(len(poses) + 1)
    samples = [sample_sdf(v, body_faces, sdf, int(s)) for v, s in zip([neutral, *posed], seeds)]
    sf = surface_features(neutral, gen.faces)
    return (neutral.astype(np.float32), vertex_normals(neutral, gen.faces).astype(np.float32),
            posed.astype(np.float32), np.stack([s[0] for s in samples]), np.stack([s[1] for s in samples]),
            (sf.coords, sf.frames, sf.medial))


def extra_characters(model, corpus, train_ids: list[int], poses: tuple[str, ...], per_person: int, seed: int,
                     device, workers: int = 2, log=print, ranges: dict[str, tuple[float, float]] | None = None,
                     margin: float = 0.0) -> ExtraCharacters:
    """Every training person of `corpus` (its bind character among `train_ids`) in `per_person` random rests
    (`random_rests` with `ranges` and `margin`), posed in `poses`, with the frozen encoder's latent means of every
    state."""
    rng = np.random.default_rng([seed, 7])
    persons = [i for i in train_ids if corpus.identities[i].rest == "bind"]
    stands, seeds = [], []
    for n, i in enumerate(persons):
        for k, rest in enumerate(random_rests(rng, per_person, f"drawn{n:03d}_", ranges, margin)):
            stands.append((i, rest))
            seeds.append([seed, n, k])
    return characters_in_rests(model, corpus, stands, poses, seeds, device, workers, log)


def characters_in_rests(model, corpus, stands: list[tuple[int, RestConfig]], poses: tuple[str, ...], seeds: list,
                        device, workers: int = 2, log=print) -> ExtraCharacters:
    """Each (corpus character whose person it is, rest configuration) of `stands` posed in `poses` through the
    corpus's generator, SDF-sampled (seeds[n]: the n-th one's sampling seed, anything `SeedSequence` takes) and
    encoded by the frozen encoder. Any rest: also a held-out rest's configuration on validation persons
    (`bench/rest_transfer.py --rest`)."""
    from latent_model.encoding import encode_sample_sets

    jobs = [(asdict(corpus.identities[i]), asdict(rest), tuple(poses), asdict(corpus.config.sdf),
             corpus.body_faces.astype(np.int64), seeds[n]) for n, (i, rest) in enumerate(stands)]
    t0 = time.perf_counter()
    out = generate(_character, jobs, workers, lambda k: log(f"extra rests: {k}/{len(jobs)} characters posed and "
                                                              f"sampled ({time.perf_counter() - t0:.0f} s)"))
    P = len(poses)
    pts = np.concatenate([r[3] for r in out])
    vals = np.concatenate([r[4] for r in out])
    mu = encode_sample_sets(model, list(range(len(pts))), lambda k: (pts[k], vals[k]), device).reshape(len(out), P + 1, -1)
    log(f"extra rests: {len(out)} characters encoded ({time.perf_counter() - t0:.0f} s)")
    first = corpus.manifest["n_identities"]
    return ExtraCharacters(
        ids=list(range(first, first + len(out))), person=[i for i, _ in stands], rests=[r for _, r in stands],
        poses=tuple(poses), neutral=np.stack([r[0] for r in out]), normals=np.stack([r[1] for r in out]),
        posed=np.stack([r[2] for r in out]), mu_neutral=mu[:, 0], mu_posed=mu[:, 1:],
        features=[SurfaceFeatures(*r[5], {}) for r in out])
