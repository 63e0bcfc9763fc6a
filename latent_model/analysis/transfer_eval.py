"""Analysis 6: mesh prediction on held-out identities through the Transfer API, per pair kind
and pose, for the learned strategies (mean, nearest, oracle) and honest baselines:

- ``no_motion``: the source mesh itself;
- ``offset_nearest``: the vertex offsets (target - source) of the training identity whose
  neutral mesh is nearest (mean per-vertex distance, centroids aligned), added to the source;
- ``offset_mean``: the training identities' mean vertex offsets added to the source.
Both from the training characters standing in the evaluated characters' rest configurations.
The offset copies are possible only because every corpus mesh shares one topology: a user's
own mesh has no such correspondence, the learned model needs none.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from latent_model.analysis.metrics import VertexNormals, mesh_errors, normal_consistency
from latent_model.analysis.parallel import Batch, Workers, submit_characters
from latent_model.corpus.pairs import Pair, enumerate_pairs
from latent_model.types import PAIR_KINDS
from latent_model.corpus.poses import get_pose
from latent_model.corpus.store import Corpus
from latent_model.surface_cache import state_features

# mean/nearest/oracle: the Transfer API's output (noise-gated); *_raw: the vertex decoder's own output
STRATEGIES = ("mean", "nearest", "oracle", "mean_raw", "nearest_raw", "oracle_raw", "no_motion", "offset_nearest",
              "offset_mean")
METRICS = ("err_mm", "err_moving_mm", "leak_mm", "explained", "normal")
EXAMPLE_POSES = ("elbowBentLf", "elbowSuperBentLf", "cornerUpLf", "browDwLf+browDwRt", "kneeBentLf", "puffLf")


def pose_key(p: Pair) -> str:
    """Metrics key of a pair's pose (source_to_combo names its component: combo@component)."""
    return f"{p.pose}@{p.component}" if p.component else p.pose


def nearest_training_identity(corpus: Corpus, train: list[int]) -> Callable[[int], int]:
    """identity -> training identity with the nearest neutral mesh (centroid-aligned)."""
    def centred(i: int) -> np.ndarray:
        v = corpus.vertices(corpus.state(i, None, "neutral"))
        return v - v.mean(0)

    train_v = np.stack([centred(j) for j in train])

    def nearest(i: int) -> int:
        d = np.linalg.norm(train_v - centred(i)[None], axis=2).mean(1)
        return train[int(np.argmin(d))]

    return nearest


def evaluate_transfer(transfer, corpus: Corpus, ids: list[int], kinds: tuple[str, ...] = PAIR_KINDS,
                      example_identity: int | None = None, progress: bool = True,
                      poses: tuple[str, ...] | None = None, workers: "int | Workers" = 1,
                      surface_cache: Path | None = None) -> tuple[dict, dict]:
    """(flat metrics `transfer.<kind>.<pose>.<strategy>.<metric>` + group means, examples for
    figures: {(kind, pose): {"source", "truth", "mean", "nearest", "oracle"}} of one identity).
    `poses`: the target poses to evaluate (default: every corpus pose). `workers` > 1: the identities are shared
    among that many processes of one thread each (most of the work is single-threaded numpy; or a running
    `parallel.Workers`); the metrics are those of one process up to float rounding (each pair is the same
    computation). `surface_cache`: a directory keeping the surface features of the sources the motion decoder
    reads (`surface_cache.state_features`; they depend on the meshes alone: half the work of a first evaluation,
    read back by the next; None: computed)."""
    return submit_transfer(transfer, corpus, ids, kinds, example_identity, progress, poses, workers,
                           surface_cache).get()


def submit_transfer(transfer, corpus: Corpus, ids: list[int], kinds: tuple[str, ...] = PAIR_KINDS,
                    example_identity: int | None = None, progress: bool = True,
                    poses: tuple[str, ...] | None = None, workers: "int | Workers" = 1,
                    surface_cache: Path | None = None) -> Batch:
    """`evaluate_transfer`'s characters queued on `workers` (the latents encoded here first): `get()` returns
    its (metrics, examples)."""
    from latent_model.encoding import encode_sample_sets

    # offsets copy only within a rest configuration (another rest's offsets start from other positions): the
    # training characters of the evaluated characters' rests (half the reads for bind test persons)
    rests = {corpus.identities[i].rest for i in ids}
    train = [j for j in corpus.split_indices("train") if corpus.identities[j].rest in rests]
    nearest_of = nearest_training_identity(corpus, train)
    near = {i: nearest_of(i) for i in ids}
    example_identity = ids[0] if example_identity is None else example_identity
    pairs_by_key: dict[tuple[str, str], list[Pair]] = {}
    for p in enumerate_pairs(ids, tuple(corpus.poses) if poses is None else tuple(poses), kinds):
        pairs_by_key.setdefault((p.kind, p.bank_key), []).append(p)

    # every source and target latent in one batched pass (one encoder call per state was a third of the time)
    rows = sorted({corpus.row(corpus.state(p.identity, *st)) for ps in pairs_by_key.values() for p in ps
                   for st in (p.source, p.target)})
    mu_of_row = dict(zip(rows, encode_sample_sets(transfer.model, rows, corpus.sdf_of_row, transfer.device,
                                                  progress=progress, desc="encoding")))
    # the training characters' mean offsets of each (kind, pose), for the offset-copy baseline
    mean_offsets = {}
    for key, pairs in pairs_by_key.items():
        s, t = pairs[0].source, pairs[0].target
        mean_offsets[key] = np.mean(np.stack([corpus.vertices(corpus.state(j, *t)) - corpus.vertices(corpus.state(j, *s))
                                              for j in train]), axis=0)
    shared = (mu_of_row, mean_offsets, near, example_identity, surface_cache)
    jobs = [{k: [p for p in ps if p.identity == i] for k, ps in pairs_by_key.items()} for i in ids]
    return submit_characters(_character, jobs, transfer, workers, corpus, shared,
                             lambda results: _summarise(list(pairs_by_key), results), "transfer", progress)


def _summarise(keys: list[tuple[str, str]], results: list[tuple[dict, dict, dict]]) -> tuple[dict, dict]:
    """(metrics, examples) of the characters' `_character` results, the (kind, bank key)s `keys` in order."""
    # rows in the one-process order: key by key, identity by identity
    per: dict[tuple[str, str, str], list[dict]] = {}
    gates: dict[tuple[str, str, str], list[float]] = {}
    examples: dict = {}
    for key in keys:
        for r_per, r_gates, _ in results:
            for k in r_per.get(key, {}):
                per.setdefault(k, []).extend(r_per[key][k])
            for k in r_gates.get(key, {}):
                gates.setdefault(k, []).extend(r_gates[key][k])
    for _, _, r_examples in results:
        examples.update(r_examples)
    m: dict = {}
    for (kind, pose, strat), rows in per.items():
        for k in METRICS:
            m[f"transfer.{kind}.{pose}.{strat}.{k}"] = float(np.mean([r[k] for r in rows]))
    for (kind, pose, strat), g in gates.items():
        m[f"transfer.{kind}.{pose}.{strat}.gate"] = float(np.mean(g))
    # group means (per pair kind, pose group, strategy)
    groups: dict[tuple[str, str, str], list[dict]] = {}
    for (kind, pose, strat), rows in per.items():
        base = pose.split("@")[0]
        g = "combo" if get_pose(base).is_combo else get_pose(base).group
        groups.setdefault((kind, g, strat), []).extend(rows)
    for (kind, g, strat), rows in groups.items():
        for k in METRICS:
            m[f"transfer_group.{kind}.{g}.{strat}.{k}"] = float(np.mean([r[k] for r in rows]))
    return m, examples


def _character(transfer, corpus: Corpus, shared: tuple, job: dict) -> tuple[dict, dict, dict]:
    return _evaluate_pairs(transfer, corpus, job, *shared)


def _evaluate_pairs(transfer, corpus: Corpus, pairs_by_key: dict[tuple[str, str], list[Pair]], mu_of_row: dict,
                    mean_offsets: dict, near: dict[int, int], example_identity: int,
                    surface_cache: Path | None = None) -> tuple[dict, dict, dict]:
    """The pairs of one identity: ({(kind, pose): {(kind, pose key, strategy): [metrics]}}, the same of gates,
    examples)."""
    faces = corpus.faces
    vertex_normals = VertexNormals(faces)
    prepared: dict[int, object] = {}
    neutrals: dict[int, object] = {}
    per: dict = {}
    gates: dict = {}
    examples: dict = {}

    def latent(s: int) -> np.ndarray:
        return mu_of_row[corpus.row(s)]

    for (kind, bkey), pairs in pairs_by_key.items():
        key_per, key_gates = per.setdefault((kind, bkey), {}), gates.setdefault((kind, bkey), {})
        for p in pairs:
            s = corpus.state(p.identity, p.source[0], p.source[1])
            t = corpus.state(p.identity, *p.target)
            v_src, truth = corpus.vertices(s), corpus.vertices(t)
            row = corpus.row(s)
            neutral = p.source[0] is None
            if row not in prepared and row not in neutrals:
                if len(prepared) > 64:  # posed sources: each is used by a few pairs only
                    prepared.clear()
                # the neutral meshes stay: their surface features (decoder v2) take ~0.45 s each
                surface = state_features(corpus, s, surface_cache) \
                    if surface_cache is not None and transfer.predicts_with(kind) == "motion" else None
                (neutrals if neutral else prepared)[row] = transfer.prepare(v_src, faces, sdf_faces=corpus.body_faces,
                                                                            mu=latent(s), surface=surface)
            mesh = neutrals[row] if row in neutrals else prepared[row]
            outs = {
                "mean": transfer.predict_detail(mesh, bkey, "mean_pose_delta", kind=kind),
                "nearest": transfer.predict_detail(mesh, bkey, "nearest_identity_delta", kind=kind),
                "oracle": transfer.predict_detail(mesh, bkey, "oracle", kind=kind, oracle_target_mu=latent(t)),
            }
            for name, o in outs.items():
                key_gates.setdefault((kind, pose_key(p), name), []).append(o.gate)
            j = near[p.identity]
            offset_nearest = corpus.vertices(corpus.state(j, *p.target)) - corpus.vertices(corpus.state(j, *p.source))
            preds = {
                **{name: o.vertices for name, o in outs.items()},
                **{f"{name}_raw": o.raw for name, o in outs.items()},
                "no_motion": v_src,
                "offset_nearest": v_src + offset_nearest,
                "offset_mean": v_src + mean_offsets[(kind, bkey)],
            }
            n_true = vertex_normals(truth)
            # equal predictions measured once: an ungated output is the gated one when the gate is open, and a face
            # or finger pose's mean, nearest and raw outputs are often the source itself
            seen: list[tuple[np.ndarray, dict]] = []
            for name, pred in preds.items():
                e = next((m for q, m in seen if q is pred or np.array_equal(q, pred)), None)
                if e is None:
                    e = mesh_errors(pred, truth, v_src)
                    e["normal"] = normal_consistency(vertex_normals(pred), n_true)
                    seen.append((pred, e))
                key_per.setdefault((kind, pose_key(p), name), []).append(dict(e))
            if p.identity == example_identity and (p.pose in EXAMPLE_POSES or kind == "skinning_to_skinning_plus_blendshape"
                                                   and p.pose == "elbowBentLf"):
                examples[(kind, pose_key(p))] = {"source": v_src, "truth": truth,
                                                 **{k: preds[k] for k in ("mean", "nearest", "oracle")}}
    return per, gates, examples
