"""Build the corrective fields (`latent_model.corrective_fields`) from the corpus's rig: no corpus is read.

Every training person (bind identities of the preset) is posed in each corrective pose on top of every training
rest configuration through the corpus's generator (skinning and skinning + blendshape). A pose's region is where
the mean corrective of the first `region_persons` persons exceeds `threshold`, grown by `margin` on the anchor
(the first person in bind); each sample's region is aligned to the anchor by a similarity, its landmarks kept as
its shape and its corrective in the anchor frame compressed by PCA.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from latent_model.corpus.identities import IdentitySpec
from latent_model.corpus.poses import get_pose
from latent_model.corpus.rests import TRAIN_RESTS
from latent_model.corrective_fields import CorrectiveFields, PoseCorrective, faces_digest, similarity


@dataclass
class CorrectiveTraining:
    persons: int = 0  # training persons pooled (0: all of the preset's, each in every rest of `rests`)
    rests: tuple[str, ...] = field(default_factory=lambda: TRAIN_RESTS)
    region_persons: int = 6  # persons whose mean corrective locates a pose's region
    threshold_mm: float = 0.2  # a vertex whose mean corrective exceeds this is in the region...
    margin: float = 0.03  # ... and every vertex this close to one (metres, on the anchor)
    landmarks: int = 32  # region points whose aligned positions describe a sample
    components: int = 8  # PCA components of the correctives (validation: as good as 16 on elbow, knee, shoulder)


def corrective_poses(poses: tuple[str, ...]) -> list[str]:
    """The single body poses among `poses` that have a skeletal part (finger correctives are knuckle skin, ≤ 1.5 mm)."""
    return [p for p in poses if not get_pose(p).is_combo and get_pose(p).has_skeletal and get_pose(p).group == "body"]


def farthest_points(x: np.ndarray, n: int) -> np.ndarray:
    """(min(n, N),) indices of `x` (N, 3) spread by farthest-point sampling from the point nearest the centroid."""
    chosen = [int(np.argmin(np.linalg.norm(x - x.mean(0), axis=1)))]
    d = np.linalg.norm(x - x[chosen[0]], axis=1)
    for _ in range(min(n, len(x)) - 1):
        chosen.append(int(np.argmax(d)))
        d = np.minimum(d, np.linalg.norm(x - x[chosen[-1]], axis=1))
    return np.asarray(chosen)


def _posed(args) -> dict:
    """{(pose, rest): (skinning (V, 3), corrective (V, 3)) float32} of one person; `index` keeps only those rows."""
    spec, poses, rests, index = args
    from latent_model.corpus.build import generator

    gen = generator()
    out = {}
    for p in poses:
        for r in rests:
            g = gen.pose(spec, p, r)
            rows = slice(None) if index is None else index[p]
            out[(p, r)] = (g.skinning[rows].astype(np.float32),
                           (g.skinning_plus_blendshape - g.skinning)[rows].astype(np.float32))
    return out


def _pool(jobs: list, workers: int):
    import multiprocessing as mp

    from latent_model.corpus.build import init_generator_worker

    if workers <= 1:
        init_generator_worker()
        yield from map(_posed, jobs)
        return
    with mp.get_context("spawn").Pool(workers, initializer=init_generator_worker) as pool:
        yield from pool.imap(_posed, jobs)


def build_correctives(specs: list[IdentitySpec], poses: list[str], cfg: CorrectiveTraining, workers: int = 2,
                      log=print) -> CorrectiveFields:
    """The fields of `poses` pooled over the persons `specs` (training; the first in bind: the anchor) in the rests
    `cfg.rests` (the first: bind), each person posed on top of every one of them whatever its own rest."""
    t0 = time.time()
    specs = specs[: cfg.persons] if cfg.persons else specs
    rests = tuple(cfg.rests)
    # 1. each pose's region, from a few persons' whole meshes
    first = list(_pool([(s, poses, rests, None) for s in specs[: cfg.region_persons]], workers))
    anchor_mesh = {p: first[0][(p, rests[0])][0].astype(np.float64) for p in poses}
    index = {}
    for p in poses:
        mag = np.mean([np.linalg.norm(d[(p, r)][1], axis=1) for d in first for r in rests], axis=0)
        core = anchor_mesh[p][mag * 1000 > cfg.threshold_mm]
        near, _ = cKDTree(core).query(anchor_mesh[p], distance_upper_bound=cfg.margin) if len(core) else (None, None)
        index[p] = np.flatnonzero(np.isfinite(near)) if near is not None else np.zeros(0, np.int64)
    index = {p: i for p, i in index.items() if len(i) >= 4}
    log(f"  regions of {len(index)} poses: {min(len(i) for i in index.values())}-"
        f"{max(len(i) for i in index.values())} vertices ({time.time() - t0:.0f} s)")
    # 2. every person's samples, region rows only
    kept = list(index)
    samples: dict[str, list] = {p: [] for p in kept}
    for n, d in enumerate(_pool([(s, kept, rests, index) for s in specs], workers)):
        for p in kept:
            samples[p] += [(specs[n].id, *d[(p, r)]) for r in rests]
        if (n + 1) % 8 == 0 or n + 1 == len(specs):
            log(f"  posed {n + 1}/{len(specs)} persons × {len(rests)} rests × {len(kept)} poses ({time.time() - t0:.0f} s)")
    fields = {p: _pose_fields(index[p], samples[p], cfg) for p in kept}
    from latent_model.corpus.build import generator, init_generator_worker

    init_generator_worker()
    return CorrectiveFields(fields, len(anchor_mesh[kept[0]]), faces_digest(generator().faces))


def _pose_fields(index: np.ndarray, samples: list[tuple[str, np.ndarray, np.ndarray]], cfg: CorrectiveTraining
                 ) -> PoseCorrective:
    """One pose's fields from its samples [(person, skinned region (N, 3), corrective (N, 3))]; the first is the anchor."""
    anchor = samples[0][1].astype(np.float64)
    landmarks = farthest_points(anchor, cfg.landmarks)
    shapes, values = [], []
    for _, x, c in samples:
        s, r, t = similarity(anchor, x.astype(np.float64))
        shapes.append(((x[landmarks] - t) @ r / s).ravel())
        values.append((c.astype(np.float64) @ r / s).ravel())
    values = np.asarray(values)
    mean = values.mean(0)
    _, _, vt = np.linalg.svd(values - mean, full_matrices=False)
    basis = vt[: cfg.components]
    coef = (values - mean) @ basis.T
    return PoseCorrective(index, anchor.astype(np.float32), landmarks, np.asarray(shapes), [s[0] for s in samples],
                          mean, basis, coef)


def corrective_training(preset_name: str) -> CorrectiveTraining:
    """The corrective fields' settings of a named preset (tiny: two persons in two rests)."""
    if preset_name == "tiny":
        return CorrectiveTraining(persons=2, rests=("bind", "armsDown"), region_persons=1, landmarks=12, components=3)
    return CorrectiveTraining()


def run_correctives(preset, cfg: CorrectiveTraining, out: Path, workers: int = 2, log=print) -> Path:
    """Build the fields of the preset's corrective poses on its training persons; write `out`
    (`correctives.safetensors`, read beside the checkpoint by `Transfer.from_files`)."""
    from latent_model.corpus.build import plan

    specs, _, _ = plan(preset.corpus)
    # each person once (a training character in another rest is the same person: its rests are all posed anyway)
    train = [s for s in specs if s.split == "train" and s.rest == "bind"]
    fields = build_correctives(train, corrective_poses(preset.corpus.pose_names()), cfg, workers, log)
    scores = validate(fields, [s for s in specs if s.split == "val"])
    fields.validation = scores
    dropped = [p for p, by_rest in scores.items() if min(by_rest.values()) <= 0.0]
    for p in dropped:
        del fields.poses[p]
    log(f"  validation: {len(fields.poses)} poses kept" + (f", dropped (worse than no motion in a validation rest): "
                                                            f"{', '.join(dropped)}" if dropped else ""))
    fields.save(out)
    return out


def validate(fields: CorrectiveFields, specs: list[IdentitySpec]) -> dict[str, dict[str, float]]:
    """{pose: {rest: explained}}: each pose's mean explained motion (the mean strategy) on the validation characters
    `specs` in their own rests; a pose worse than no motion in any of them is not shipped (`run_correctives`)."""
    from latent_model.analysis.metrics import mesh_errors
    from latent_model.corpus.build import generator, init_generator_worker

    init_generator_worker()
    gen = generator()
    rows: dict[tuple[str, str], list[float]] = {}
    for spec in specs:
        for p in fields.poses:
            g = gen.pose(spec, p)
            v = g.skinning.astype(np.float64)
            e = mesh_errors(v + fields.displacement(v, p)[0], g.skinning_plus_blendshape, v)["explained"]
            rows.setdefault((p, spec.rest), []).append(e)
    out: dict[str, dict[str, float]] = {}
    for (p, rest), e in rows.items():
        out.setdefault(p, {})[rest] = float(np.mean(e))
    return out
