"""Speed of decoder v2 on one 13.7k-vertex anny mesh: the surface features (once per mesh) and one
prediction of the motion decoder at the `MotionDecoderConfig` size (per slider move). Prints medians.

    python bench/bench_motion.py [--threads 2] [--runs 20]
"""
from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--runs", type=int, default=20)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    from latent_model.config import MotionDecoderConfig
    from latent_model.corpus.identities import sample_identities
    from latent_model.corpus.sdf import vertex_normals
    from latent_model.corpus.states import StateGenerator
    from latent_model.nn.motion_decoder import MotionDecoder
    from latent_model.surface import surface_features

    gen = StateGenerator()
    spec = sample_identities(8, 2, 1, 0, gen.rig.local_change_labels)[0]
    v = gen.neutral(spec, "tpose").astype(np.float32)
    times = []
    for _ in range(3):
        t = time.perf_counter()
        sf = surface_features(v, gen.faces)
        times.append(time.perf_counter() - t)
    print(f"surface features, {len(v)} vertices: median {statistics.median(times) * 1000:.0f} ms "
          f"(runs: {', '.join(f'{x * 1000:.0f}' for x in times)})")
    m = MotionDecoderConfig()
    dec = MotionDecoder(512, 4, m.hidden, m.cond, m.layers, m.world).eval()
    t_ = lambda a: torch.from_numpy(np.asarray(a, np.float32))[None]  # noqa: E731
    x = {"v_src": t_(v), "coords": t_(sf.coords), "frames": t_(sf.frames),
         "normals": t_(vertex_normals(v, gen.faces)), "medial": t_(sf.medial)}
    mu, d = torch.randn(1, 512), torch.nn.functional.normalize(torch.randn(1, 512), dim=-1)
    kind = torch.tensor([0])
    with torch.no_grad():
        c = dec.condition(mu, d, kind)
        for cached in (False, True):
            times = []
            for i in range(args.runs + 2):
                t = time.perf_counter()
                dec(**x, mu_src=mu, delta_dir=d, r=torch.tensor([1.0 + 0.01 * i]), kind=kind,
                    c=c if cached else None)
                times.append(time.perf_counter() - t)
            times = times[2:]
            print(f"motion decoder, one prediction{' (condition cached: a magnitude move)' if cached else ''}: "
                  f"median {statistics.median(times) * 1000:.1f} ms over {args.runs} runs, {args.threads} threads")


if __name__ == "__main__":
    main()
