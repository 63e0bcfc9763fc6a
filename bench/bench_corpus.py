"""Corpus build benchmark: prints figures (medians), never asserts on time.

    python bench/bench_corpus.py                 # tiny preset, 3 runs
    python bench/bench_corpus.py --standard-sample 2   # a 2-identity shard of `standard`, extrapolated

Reports wall time, meshes/s and SDF states/s, per-identity cost, peak memory (RSS of this
process and its workers) and the projected full `standard` build time / disk size.
"""
from __future__ import annotations

import argparse
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from latent_model.corpus.config import corpus_preset  # noqa: E402
from latent_model.corpus.build import build, plan  # noqa: E402


def _peak_rss_gb() -> tuple[float, float]:
    me = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1e6
    return me, kids


def bench_tiny(runs: int, workers: int) -> None:
    cfg = corpus_preset("tiny")
    times, sdf, mesh, geoms = [], [], [], 0
    for r in range(runs):
        with tempfile.TemporaryDirectory() as d:
            t = time.perf_counter()
            res = build(cfg, Path(d) / "tiny", workers=workers)
            times.append(time.perf_counter() - t)
            sdf.append(res.sdf_seconds)
            mesh.append(res.mesh_seconds)
            geoms = res.geometries_built
    med = statistics.median(times)
    print(f"tiny preset ({len(plan(cfg)[0])} characters of {cfg.n_identities} persons, {len(cfg.pose_names())} poses, K={cfg.sdf.k}, "
          f"{geoms} geometries, {workers} workers): median wall {med:.1f} s over {runs} runs "
          f"(all: {', '.join(f'{t:.1f}' for t in times)})")
    print(f"  meshes/s (wall) {geoms / med:.1f}; per worker: mesh generation {geoms / statistics.median(mesh):.1f} meshes/s, "
          f"SDF {geoms / statistics.median(sdf):.1f} states/s")


def bench_standard_sample(n_ids: int, workers: int) -> None:
    cfg = corpus_preset("standard")
    specs, layout, _ = plan(cfg)
    n_chars = len(specs)
    n_shards = n_chars // n_ids  # every n-th character: bind and rest ones in proportion
    with tempfile.TemporaryDirectory() as d:
        t = time.perf_counter()
        res = build(cfg, Path(d) / "std", workers=workers, shard=(0, n_shards))
        wall = time.perf_counter() - t
        disk = sum(p.stat().st_blocks * 512 for p in (Path(d) / "std").glob("*.npy"))
    built = res.identities_built
    per_id = wall / max(built, 1)
    print(f"standard sample: {built} characters ({res.geometries_built} geometries, K={cfg.sdf.k}) in {wall:.1f} s "
          f"with {workers} workers (incl. ~2 s worker start-up)")
    print(f"  per worker: mesh generation {res.geometries_built / res.mesh_seconds:.1f} meshes/s, "
          f"SDF {res.geometries_built / res.sdf_seconds:.1f} states/s")
    print(f"  projected full build: {per_id * n_chars / 60:.1f} min for {n_chars} characters; "
          f"disk {disk / built * n_chars / 1e9:.2f} GB ({layout.n_geometries} geometries)")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--standard-sample", type=int, default=0, help="also time a shard of this many standard identities")
    args = ap.parse_args()
    bench_tiny(args.runs, args.workers)
    if args.standard_sample:
        bench_standard_sample(args.standard_sample, args.workers)
    me, kids = _peak_rss_gb()
    print(f"peak RSS: main process {me:.2f} GB, largest worker {kids:.2f} GB")


if __name__ == "__main__":
    main()
