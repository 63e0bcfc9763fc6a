"""More combinations for decoder v2's training pairs: each training character of the corpus is also posed
in `per_character` of `n_combos` seeded combinations of two or three of the decoder's single body poses.

Why: the corpus has 8 body combinations, so decoder v2 learnt how 8 pairs of motions add up; an example pair
with three joints at once (the evaluation's unseen combinations) was read as something else (explained 0.40
and 0.09). Posing through the rig is cheap (0.04 s a mesh); each state's latent needs an SDF sampling (0.1 s)
and the frozen encoder. Combinations sharing two single poses with an example combination of the evaluation
(`corpus/examples.py`), or equal to a corpus combination, are never drawn, so the evaluated ones stay unseen;
each draw is seeded, so the same config gives the same characters.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace
from typing import Sequence

import numpy as np

from latent_model.corpus.build import generator
from latent_model.corpus.examples import EXAMPLES
from latent_model.corpus.identities import IdentitySpec
from latent_model.corpus.poses import COMBO_POSES, PoseConfig, get_pose
from latent_model.train.rest_augment import generate

SIZES = (2, 3)  # single poses per drawn combination
SIZE_ODDS = (1 / 3, 2 / 3)  # the unseen combinations a user brings have three joints: about 2/3 are triples


def held_out_combinations() -> list[frozenset[str]]:
    """The single poses of each example combination of the evaluation (never to be trained on together)."""
    return [frozenset(e.poses) for e in EXAMPLES.values() if e.kind == "combination"]


def combination(components: Sequence[str], amplitudes: Sequence[float] | None = None) -> PoseConfig:
    """The pose of several single body poses at once, named by them (`a+b+c`); with `amplitudes`, each pose's
    angles scaled by its amplitude (named `a@0.5+b@1.2`)."""
    comps = tuple(components)
    if amplitudes is None:
        return PoseConfig("+".join(comps), "body", joints=tuple(j for c in comps for j in get_pose(c).joints),
                          components=comps)
    joints = tuple(replace(j, degrees=j.degrees * a) for c, a in zip(comps, amplitudes) for j in get_pose(c).joints)
    return PoseConfig("+".join(f"{c}@{a:.2f}" for c, a in zip(comps, amplitudes)), "body", joints=joints,
                      components=comps)


def draw_combinations(singles: Sequence[str], n: int, rng: np.random.Generator, sizes: Sequence[int] = SIZES,
                      odds: Sequence[float] = SIZE_ODDS, amplitude: tuple[float, float] | None = None
                      ) -> list[PoseConfig]:
    """`n` distinct combinations of `sizes` of `singles` (in their order), no two acting on one bone, none a corpus
    combination, none sharing two poses with a held-out example combination; with `amplitude` (lowest, highest),
    each pose's angles are scaled by a factor drawn uniformly in it (size 1 then gives a single pose at another
    amplitude); (1, 1) or None: the vocabulary's angles."""
    if len(sizes) != len(odds) or abs(sum(odds) - 1) > 1e-6:
        raise ValueError(f"combination odds {tuple(odds)} must give one probability per size in {tuple(sizes)}, "
                         "adding up to 1 (MotionDecoderConfig.combo_sizes / combo_odds)")
    if amplitude is not None and tuple(amplitude) == (1.0, 1.0):  # the vocabulary's angles (the config's default)
        amplitude = None
    held = held_out_combinations()
    corpus = {frozenset(get_pose(p).components) for p in COMBO_POSES}
    order = {s: k for k, s in enumerate(singles)}
    seen: set[tuple[frozenset[str], tuple[float, ...] | None]] = set()
    out: list[PoseConfig] = []
    for _ in range(200 * max(n, 1)):
        if len(out) == n:
            break
        k = int(rng.choice(list(sizes), p=list(odds)))
        comps = sorted((str(s) for s in rng.choice(list(singles), size=k, replace=False)), key=order.__getitem__)
        key = frozenset(comps)
        amps = None if amplitude is None else tuple(round(float(rng.uniform(*amplitude)), 2) for _ in comps)
        if (key, amps) in seen or (amplitude is None and (key in corpus or k == 1)) or any(len(key & h) >= 2 for h in held):
            continue
        bones = [j.bone for c in comps for j in get_pose(c).joints]
        if len(bones) != len(set(bones)):
            continue
        seen.add((key, amps))
        out.append(combination(comps, amps))
    if len(out) < n:
        raise ValueError(f"only {len(out)} distinct combinations of {len(singles)} single poses can be drawn; "
                         f"ask for fewer (MotionDecoderConfig.extra_combos)")
    return out


@dataclass
class ExtraPoses:
    """Posed states of corpus characters beyond the corpus's poses: pairs (character, pose name), their final
    vertices (V, 3) float32 and latent means (Z,)."""

    poses: dict[str, PoseConfig]
    pairs: list[tuple[int, str]]
    targets: dict[tuple[int, str], np.ndarray]
    mu: dict[tuple[int, str], np.ndarray]

    def __contains__(self, pair: tuple[int, str]) -> bool:
        return pair in self.targets


def _posed(args) -> tuple:
    """One corpus character in its own rest, posed in each of several poses: final vertices and SDF samples."""
    from latent_model.corpus.sdf import SdfSampling, sample_sdf

    spec_dict, poses, sdf_dict, body_faces, seed = args
    gen = generator()
    spec, sdf = IdentitySpec.from_dict(spec_dict), SdfSampling(**sdf_dict)
    posed = np.stack([gen.pose(spec, p).skinning_plus_blendshape for p in poses])
    seeds = np.random.SeedSequence(seed).generate_state(len(poses))
    samples = [sample_sdf(v, body_faces, sdf, int(s)) for v, s in zip(posed, seeds)]
    return posed.astype(np.float32), np.stack([s[0] for s in samples]), np.stack([s[1] for s in samples])


def extra_combinations(model, corpus, train_ids: list[int], singles: Sequence[str], n_combos: int,
                       per_character: int, seed: int, device, workers: int = 2, log=print,
                       sizes: Sequence[int] = SIZES, odds: Sequence[float] = SIZE_ODDS,
                       amplitude: tuple[float, float] | None = None) -> ExtraPoses:
    """Every training character of `corpus` in `per_character` of `n_combos` drawn combinations of `singles`
    (each drawn combination about evenly often), with the frozen encoder's latent means of the posed states."""
    from latent_model.encoding import encode_sample_sets

    rng = np.random.default_rng([seed, 11])
    combos = draw_combinations(singles, n_combos, rng, sizes, odds, amplitude)
    per_character = min(per_character, n_combos)
    # a shuffled round-robin deal: every combination on about len(train_ids) * per_character / n_combos characters
    deck = np.concatenate([rng.permutation(n_combos) for _ in range(-(-len(train_ids) * per_character // n_combos) + 1)])
    jobs, chosen, at = [], [], 0
    for n, i in enumerate(train_ids):
        mine: list[int] = []
        while len(mine) < per_character:
            if deck[at] not in mine:
                mine.append(int(deck[at]))
            at += 1
        chosen.append([combos[k] for k in mine])
        jobs.append((asdict(corpus.identities[i]), chosen[-1], asdict(corpus.config.sdf),
                     corpus.body_faces.astype(np.int64), [seed, n]))
    t0 = time.perf_counter()
    out = generate(_posed, jobs, workers, lambda k: log(f"extra combinations: {k}/{len(jobs)} characters posed and "
                                                          f"sampled ({time.perf_counter() - t0:.0f} s)"))
    pts = np.concatenate([r[1] for r in out])
    vals = np.concatenate([r[2] for r in out])
    mu = encode_sample_sets(model, list(range(len(pts))), lambda k: (pts[k], vals[k]), device)
    log(f"extra combinations: {len(pts)} states encoded ({time.perf_counter() - t0:.0f} s)")
    pairs, targets, mus, row = [], {}, {}, 0
    for i, poses, r in zip(train_ids, chosen, out):
        for j, p in enumerate(poses):
            pairs.append((i, p.name))
            targets[(i, p.name)] = r[0][j]
            mus[(i, p.name)] = mu[row]
            row += 1
    return ExtraPoses({p.name: p for p in combos}, pairs, targets, mus)
