"""Corpus build pipeline: characters (person x rest) x poses x variants -> vertices, normals, SDF samples.

Work unit = one identity (a character) (its whole block of geometry rows). Workers (one per core) write
their block into the memory-mapped arrays of ``DIR.partial``; the parent records finished
identities in progress.json (atomic), so a killed build resumes where it stopped. When every
identity is done the manifest is written and ``DIR.partial`` is renamed to ``DIR``.
`shard=(i, n)` builds identities i, i+n, ... only; `merge` joins shard outputs.
"""
from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from latent_model.atomic import atomic_write_json
from latent_model.corpus.config import GENERATOR_VERSION, CorpusConfig
from latent_model.corpus.identities import IdentitySpec, characters, sample_identities, variety_stats
from latent_model.corpus.store import (FORMAT_VERSION, KIND, Corpus, CorpusError, Layout, atomic_save_npy,
                                       create_arrays, sdf_seed, write_block)

_WORKER: dict = {}


@dataclass
class BuildResult:
    path: Path
    seconds: float
    identities_built: int
    geometries_built: int
    sdf_seconds: float
    mesh_seconds: float


def init_generator_worker() -> None:
    """One rig state generator per worker process, one thread each (`generator()` returns it)."""
    from latent_model.corpus.states import StateGenerator
    from latent_model.runtime import single_threaded

    single_threaded()

    _WORKER["gen"] = StateGenerator()


def generator():
    """This process's state generator (`init_generator_worker`'s, else made on first use, leaving torch's threads)."""
    if "gen" not in _WORKER:
        from latent_model.corpus.states import StateGenerator

        _WORKER["gen"] = StateGenerator()
    return _WORKER["gen"]


def _mesh_volume(v: np.ndarray, f: np.ndarray) -> float:
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def build_identity(gen, spec: IdentitySpec, layout: Layout, cfg: CorpusConfig, i: int,
                   body_faces: np.ndarray) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float]:
    """All geometry rows of identity `i`: (stats, vertices, normals, sdf points, sdf values, mesh s, sdf s)."""
    from latent_model.corpus.sdf import sample_sdf, vertex_normals

    t0 = time.perf_counter()
    B, V, K = layout.block, len(gen.rig.base_rest.vertices), cfg.sdf.k
    verts = np.zeros((B, V, 3), dtype=np.float64)
    verts[0] = gen.neutral(spec)  # in the character's own rest configuration
    row = 1
    for name in layout.poses:
        g = gen.pose(spec, name)
        if _has_skeletal(name):
            verts[row], verts[row + 1], verts[row + 2] = g.skinning, g.blendshape, g.skinning_plus_blendshape
            row += 3
        else:
            verts[row] = g.blendshape
            row += 1
    assert row == B
    normals = np.stack([vertex_normals(v, gen.faces) for v in verts])
    t1 = time.perf_counter()
    pts = np.zeros((B, K, 3), dtype=np.float32)
    vals = np.zeros((B, K), dtype=np.float32)
    first = layout.identity_rows(i).start
    for r in range(B):
        pts[r], vals[r] = sample_sdf(verts[r], body_faces, cfg.sdf, sdf_seed(cfg.seed, first + r))
    t2 = time.perf_counter()
    n0 = verts[0]
    stats = {"stature_m": float(n0[:, 2].max() - n0[:, 2].min()),
             "volume_l": 1000.0 * _mesh_volume(n0, body_faces)}
    return stats, verts.astype(np.float32), normals, pts, vals, t1 - t0, t2 - t1


def _has_skeletal(name: str) -> bool:
    from latent_model.corpus.poses import get_pose

    return get_pose(name).has_skeletal


def _work(args) -> tuple[int, dict, float, float]:
    i, spec_dict, cfg_dict, poses, directory, n_identities = args
    gen = generator()
    cfg = CorpusConfig.from_dict(cfg_dict)
    layout = Layout(n_identities, tuple(poses))
    body_faces = np.load(Path(directory) / "body_faces.npy").astype(np.int64)
    stats, v, n, p, s, tm, ts = build_identity(gen, IdentitySpec.from_dict(spec_dict), layout, cfg, i, body_faces)
    write_block(Path(directory), layout.identity_rows(i), v, n, p, s)
    return i, stats, tm, ts


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise CorpusError(f"{path} is unreadable ({e}); delete {path.parent} and rebuild") from e


def plan(cfg: CorpusConfig) -> tuple[list[IdentitySpec], Layout, dict]:
    """Identities (characters), layout and static mesh data (faces, body faces, mirror map) of a config."""
    from latent_model.corpus.rig import Rig
    from latent_model.corpus.sdf import body_component_faces

    rig = Rig()
    persons = sample_identities(cfg.n_identities, cfg.n_test, cfg.n_stylised, cfg.seed, rig.local_change_labels)
    specs = characters(persons, cfg.seed, cfg.n_val, cfg.n_stylised_train, cfg.train_rests, cfg.val_rests,
                       cfg.test_rests)
    layout = Layout(len(specs), cfg.pose_names())
    static = {"faces": rig.faces.astype(np.int32),
              "body_faces": body_component_faces(rig.base_rest.vertices, rig.faces).astype(np.int32),
              "mirror_map": rig.mirror_map.astype(np.int32),
              "n_vertices": len(rig.base_rest.vertices)}
    return specs, layout, static


def build(cfg: CorpusConfig, out: Path, workers: int = 2, shard: tuple[int, int] | None = None,
          force: bool = False, progress: Callable[[int, int], None] | None = None,
          stop_after: int | None = None) -> BuildResult:
    """Build (or resume) the corpus of `cfg` into `out`.

    `stop_after` (tests) stops after that many identities, as a kill would.
    """
    out = Path(out)
    shard_tag = f"{shard[0]}/{shard[1]}" if shard else None
    if shard and not (0 <= shard[0] < shard[1]):
        raise ValueError(f"--shard {shard[0]}/{shard[1]}: need 0 <= i < n")
    if (out / "manifest.json").exists():
        m = _read_json(out / "manifest.json")
        if m.get("config_digest") == cfg.digest() and m.get("format_version") == FORMAT_VERSION \
                and m.get("shard") == shard_tag and not force:
            return BuildResult(out, 0.0, 0, 0, 0.0, 0.0)  # already built
        if not force:
            raise CorpusError(f"{out} already holds a different corpus (config or format differs); "
                              f"pass --force to replace it or choose another --out")
    partial = Path(str(out) + ".partial")
    if partial.exists() and (partial / "progress.json").exists():
        prog = _read_json(partial / "progress.json")
        if prog.get("config_digest") != cfg.digest() or prog.get("shard") != shard_tag or force:
            if not force:
                raise CorpusError(f"{partial} is an unfinished build of another config; delete it or pass --force")
            shutil.rmtree(partial)
    partial.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    specs, layout, static = plan(cfg)
    for name in ("faces", "body_faces", "mirror_map"):
        if not (partial / f"{name}.npy").exists():
            atomic_save_npy(partial / f"{name}.npy", static[name])
    if not (partial / "states.npy").exists():
        atomic_save_npy(partial / "states.npy", layout.state_table())
    create_arrays(partial, layout.n_geometries, static["n_vertices"], cfg.sdf.k)
    prog_path = partial / "progress.json"
    prog = _read_json(prog_path) if prog_path.exists() else {
        "config_digest": cfg.digest(), "shard": shard_tag, "done": {}}
    atomic_write_json(prog_path, prog)

    mine = [i for i in range(len(specs)) if shard is None or i % shard[1] == shard[0]]
    todo = [i for i in mine if str(i) not in prog["done"]]
    if stop_after is not None:
        todo = todo[:stop_after]
    jobs = [(i, specs[i].to_dict(), cfg.to_dict(), list(layout.poses), str(partial), len(specs)) for i in todo]
    t_mesh = t_sdf = 0.0
    n_done = len(mine) - len([i for i in mine if str(i) not in prog["done"]])
    if progress:
        progress(n_done, len(mine))
    if jobs:
        if workers <= 1:
            init_generator_worker()
            results = map(_work, jobs)
            pool = None
        else:
            pool = mp.get_context("spawn").Pool(workers, initializer=init_generator_worker)
            results = pool.imap_unordered(_work, jobs)
        try:
            for i, stats, tm, ts in results:
                prog["done"][str(i)] = stats
                atomic_write_json(prog_path, prog)
                t_mesh, t_sdf = t_mesh + tm, t_sdf + ts
                n_done += 1
                if progress:
                    progress(n_done, len(mine))
        finally:
            if pool is not None:
                pool.terminate()
    result = BuildResult(out, time.perf_counter() - t_start, len(jobs), len(jobs) * layout.block, t_sdf, t_mesh)
    if any(str(i) not in prog["done"] for i in mine):
        return result  # interrupted on purpose (stop_after); resume later
    _finalise(partial, out, cfg, specs, layout, static, prog, shard_tag)
    return result


def _manifest(cfg: CorpusConfig, specs, layout: Layout, static: dict, stats: dict, shard_tag, complete: bool) -> dict:
    n = len(specs)
    return {
        "kind": KIND, "format_version": FORMAT_VERSION, "generator_version": GENERATOR_VERSION,
        "complete": complete, "shard": shard_tag, "config": cfg.to_dict(), "config_digest": cfg.digest(),
        "n_identities": n, "n_persons": cfg.n_identities, "n_vertices": static["n_vertices"],
        "n_geometries": layout.n_geometries, "n_states": len(layout.local_states()) * n,
        "rests": list(dict.fromkeys(s.rest for s in specs)),
        "poses": list(layout.poses), "identities": [s.to_dict() for s in specs],
        "identity_stats": [stats.get(str(i), {}) for i in range(n)],
        "done_identities": sorted(int(i) for i in stats),
    }


def _finalise(partial: Path, out: Path, cfg, specs, layout, static, prog, shard_tag) -> None:
    atomic_write_json(partial / "manifest.json",
                      _manifest(cfg, specs, layout, static, prog["done"], shard_tag, complete=shard_tag is None))
    (partial / "progress.json").unlink()
    if out.exists():
        shutil.rmtree(out)  # only reached for our own corpus with --force (checked above)
    os.replace(partial, out)


def merge(shard_dirs: list[Path], out: Path, progress: Callable[[int, int], None] | None = None) -> Path:
    """Join shard outputs (`build(..., shard=(i, n))`) into one complete corpus at `out`."""
    manifests = []
    for d in shard_dirs:
        c = Corpus(d, allow_partial=True)
        manifests.append(c.manifest)
    digests = {m["config_digest"] for m in manifests}
    if len(digests) != 1:
        raise CorpusError("the shards were built from different configs; rebuild them with one preset")
    n = manifests[0]["n_identities"]
    owner: dict[int, Path] = {}
    for d, m in zip(shard_dirs, manifests):
        for i in m["done_identities"]:
            owner.setdefault(i, Path(d))
    missing = sorted(set(range(n)) - set(owner))
    if missing:
        raise CorpusError(f"the shards lack identities {missing[:10]}{'...' if len(missing) > 10 else ''}; "
                          f"build the missing shard(s) first")
    cfg = CorpusConfig.from_dict(manifests[0]["config"])
    layout = Layout(n, tuple(manifests[0]["poses"]))
    partial = Path(str(out) + ".partial")
    if partial.exists():
        shutil.rmtree(partial)
    partial.mkdir(parents=True)
    first = Path(shard_dirs[0])
    for name in ("faces", "body_faces", "mirror_map", "states"):
        shutil.copyfile(first / f"{name}.npy", partial / f"{name}.npy")
    create_arrays(partial, layout.n_geometries, manifests[0]["n_vertices"], cfg.sdf.k)
    stats: dict[str, dict] = {}
    for m in manifests:
        for i in m["done_identities"]:
            stats.setdefault(str(i), m["identity_stats"][i])
    for done, i in enumerate(range(n)):
        arrays = {k: np.load(owner[i] / f"{k}.npy", mmap_mode="r") for k in ("vertices", "normals", "sdf_points", "sdf_values")}
        rows = layout.identity_rows(i)
        sl = slice(rows.start, rows.stop)
        write_block(partial, rows, arrays["vertices"][sl], arrays["normals"][sl].astype(np.float32),
                    arrays["sdf_points"][sl], arrays["sdf_values"][sl])
        if progress:
            progress(done + 1, n)
    static = {"n_vertices": manifests[0]["n_vertices"]}
    specs = [IdentitySpec.from_dict(d) for d in manifests[0]["identities"]]
    atomic_write_json(partial / "manifest.json", _manifest(cfg, specs, layout, static, stats, None, complete=True))
    if out.exists():
        raise CorpusError(f"{out} exists; remove it or choose another --out (nothing was overwritten)")
    os.replace(partial, out)
    return out


def corpus_variety(corpus: Corpus) -> dict[str, float]:
    """Variety of the persons' bind-rest neutral meshes (see identities.variety_stats; another rest of a
    person is not another shape) plus stature/volume ranges."""
    bind = [i for i, s in enumerate(corpus.identities) if s.rest == "bind"]
    V = np.stack([corpus.vertices(corpus.state(i, None, "neutral")) for i in bind])
    out = variety_stats(V.astype(np.float64))
    st = np.asarray([corpus.identity_stats[i]["stature_m"] for i in bind])
    vol = np.asarray([corpus.identity_stats[i]["volume_l"] for i in bind])
    out.update(stature_min_m=float(st.min()), stature_median_m=float(np.median(st)), stature_max_m=float(st.max()),
               volume_min_l=float(vol.min()), volume_median_l=float(np.median(vol)), volume_max_l=float(vol.max()))
    return out
