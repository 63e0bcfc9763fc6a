"""Benchmark latent_model.corpus.sdf on a body-sized sphere.

Self-contained (no body model): a UV sphere with 13,778 vertices / 27,552
faces, i.e. about the size of the body shell. Prints the median over
``--runs`` runs of ``sample_sdf`` for k=8192 and k=16384 and a per-phase split
(drawing the points, exact distance, fast winding number), sign errors
against the analytic sphere, plus
``vertex_normals``. Prints figures only; never asserts on time.

torch/numpy math libraries are pinned to one thread. libigl runs its own
thread pool; pass ``--igl-threads N`` to pin it (sets IGL_NUM_THREADS before
libigl is first used), otherwise it uses all cores.

Run from the repo root:  python bench/bench_sdf.py
"""

from __future__ import annotations

import argparse
import os
import sys

# Pin BLAS/OpenMP pools before numpy/torch are imported.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

_parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
_parser.add_argument("--runs", type=int, default=5, help="timed runs per figure (median reported)")
_parser.add_argument("--igl-threads", type=int, default=None, help="set IGL_NUM_THREADS (default: libigl's choice)")
_args = _parser.parse_args()
if _args.igl_threads is not None:
    os.environ["IGL_NUM_THREADS"] = str(_args.igl_threads)

import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import trimesh  # noqa: E402

try:
    import torch  # noqa: E402

    torch.set_num_threads(1)
except ImportError:  # the module does not use torch; pinning is only for a fair comparison
    torch = None

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from latent_model.corpus import sdf  # noqa: E402


def median_ms(fn, runs: int) -> float:
    """Median wall time of ``fn()`` in ms over ``runs`` calls (after one warm-up)."""
    fn()
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times)


def main() -> None:
    runs = _args.runs
    # Radius 0.5 m; count=(83, 83) gives 13,778 vertices / 27,552 faces.
    mesh = trimesh.creation.uv_sphere(radius=0.5, count=(83, 83))
    v = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    f = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    print(f"mesh: {len(v)} vertices, {len(f)} faces (UV sphere, r=0.5 m)")
    print(
        f"threads: numpy/BLAS=1, torch={torch.get_num_threads() if torch else 'n/a'}, "
        f"IGL_NUM_THREADS={os.environ.get('IGL_NUM_THREADS', 'unset (all cores)')}, cpus={os.cpu_count()}"
    )
    print(f"median of {runs} runs, ms")
    print(f"vertex_normals: {median_ms(lambda: sdf.vertex_normals(v, f), runs):8.2f}")
    print(f"body_component_faces: {median_ms(lambda: sdf.body_component_faces(v, f), runs):8.2f}")

    header = (
        f"{'k':>6} {'sample_sdf':>11} | {'draw pts':>9} {'distance':>9} {'winding':>9} | "
        f"{'sign errors (|r-R|>1e-3)':>24}"
    )
    print(header)
    for k in (8192, 16384):
        cfg = sdf.SdfSampling(k=k)
        total = median_ms(lambda: sdf.sample_sdf(v, f, cfg, seed=0), runs)
        # Phases timed with the module's own helpers on the same points sample_sdf evaluates.
        draw = median_ms(lambda: sdf._draw_points(v, f, cfg, np.random.default_rng(0)), runs)
        pts, vals = sdf.sample_sdf(v, f, cfg, seed=0)
        p64 = np.ascontiguousarray(pts, dtype=np.float64)
        dist = median_ms(lambda: sdf._squared_distance(p64, v, f), runs)
        wind = median_ms(lambda: sdf._winding_number(p64, v, f), runs)
        # Sign check against the analytic sphere, outside the ~1e-4 m tessellation band.
        r = np.linalg.norm(p64, axis=1)
        clear = np.abs(r - 0.5) > 1e-3
        errors = int(np.sum((vals[clear] < 0) != (r[clear] < 0.5)))
        print(
            f"{k:>6} {total:>11.1f} | {draw:>9.1f} {dist:>9.1f} {wind:>9.1f} | "
            f"{errors:>10d} of {int(clear.sum()):>5d} pts"
        )

if __name__ == "__main__":
    main()
