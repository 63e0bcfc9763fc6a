"""Training and inference speed of a preset: prints figures (medians), never asserts on time.

    python bench/bench_train.py --preset standard [--corpus DIR] [--steps 8]

Measures (on this machine, all threads torch uses): Phase A step, Phase B step, the Phase B
encoding pass, projected Phase A + B wall time for the preset's step counts, peak memory;
and the inference targets: encoding one state's K SDF samples, and the vertex decoder on a
full mesh with neighbourhoods cached (the explorer's slider path).
"""
from __future__ import annotations

import argparse
import resource
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from latent_model.config import default_corpus_dir, preset  # noqa: E402
from latent_model.runtime import keep_freed_memory  # noqa: E402
from latent_model.corpus.store import Corpus  # noqa: E402
from latent_model.nn.model import LatentReRig  # noqa: E402
from latent_model.nn.vertex_decoder import knn_graph  # noqa: E402
from latent_model.train.data import PhaseASampler, PhaseBSampler  # noqa: E402
from latent_model.nn.delta import normalised_delta  # noqa: E402
from latent_model.train.phases import PhaseANet, PhaseBNet, freeze_encoder  # noqa: E402


def timed(fn, n: int, warm: int = 1) -> list[float]:
    for _ in range(warm):
        fn()
    out = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return out


def main() -> None:
    keep_freed_memory()  # as `lrr` does
    ap = argparse.ArgumentParser()
    ap.add_argument("--preset", default="standard")
    ap.add_argument("--corpus")
    ap.add_argument("--steps", type=int, default=6)
    args = ap.parse_args()
    p = preset(args.preset)
    c = Corpus(args.corpus or default_corpus_dir(args.preset))
    torch.manual_seed(0)
    model = LatentReRig(p.model)
    print(f"preset {p.name}: Z={p.model.latent}, params: encoder {sum(x.numel() for x in model.encoder.parameters()) / 1e6:.2f} M, "
          f"SDF decoder {sum(x.numel() for x in model.sdf_decoder.parameters()) / 1e6:.2f} M, "
          f"vertex decoder {sum(x.numel() for x in model.vertex_decoder.parameters()) / 1e6:.2f} M; torch threads {torch.get_num_threads()}")

    # Phase A step
    sa = PhaseASampler(c, p, 0)
    net_a = PhaseANet(model, p)
    opt = torch.optim.Adam(list(model.phase_a_parameters()), lr=1e-4)

    def step_a():
        loss, _ = net_a(sa.sample())
        opt.zero_grad()
        loss.backward()
        opt.step()

    ta = statistics.median(timed(step_a, args.steps))
    # Phase B: encoding pass cost (per state) and step
    freeze_encoder(model)
    K = c.config.sdf.k
    pts, vals = c.sdf(c.state(0, None, "neutral"))
    P = torch.from_numpy(np.repeat(pts[None], 32, 0)).float()
    Vv = torch.from_numpy(np.repeat(vals[None], 32, 0)).float()
    t_enc32 = statistics.median(timed(lambda: model.encode_mu(P, Vv), 3))
    sb = PhaseBSampler(c, p, 0)
    n_rows = len({c.row(s) for pairs in sb.by_kind.values() for q in pairs for s in sb.states(q)})
    mu_rows = torch.randn(c.manifest["n_geometries"], p.model.latent) * 0.1
    net_b = PhaseBNet(model, p, c.faces, mu_rows)
    opt_b = torch.optim.Adam(model.vertex_decoder.parameters(), lr=1e-4)

    def step_b():
        loss, _ = net_b(sb.sample())
        opt_b.zero_grad()
        loss.backward()
        opt_b.step()

    tb = statistics.median(timed(step_b, args.steps))
    enc_total = t_enc32 / 32 * n_rows
    total = ta * p.train.a_steps + tb * p.train.b_steps + enc_total
    print(f"phase A step {ta:.3f} s (median of {args.steps}) x {p.train.a_steps} steps = {ta * p.train.a_steps / 60:.1f} min")
    print(f"phase B encoding pass: {n_rows} states x {t_enc32 / 32 * 1000:.1f} ms = {enc_total / 60:.1f} min")
    print(f"phase B step {tb:.3f} s (median of {args.steps}) x {p.train.b_steps} steps = {tb * p.train.b_steps / 60:.1f} min")
    # the few steps timed here read corpus states from a cold page cache; a real run warms it
    print(f"projected Phase A + B wall time: {total / 60:.1f} min (upper bound: cold page cache on the corpus arrays)")

    # Inference targets
    model.eval()
    s = c.state(c.split_indices("test")[0], None, "neutral")
    v = torch.from_numpy(c.vertices(s))[None]
    n = torch.from_numpy(c.normals(s))[None]
    t_knn = statistics.median(timed(lambda: knn_graph(v[0].numpy(), p.model.decoder.knn), 3))
    knn = torch.from_numpy(knn_graph(v[0].numpy(), p.model.decoder.knn))[None]
    mu = torch.randn(1, p.model.latent)
    d, r = normalised_delta(torch.randn(1, p.model.latent))
    kind = torch.tensor([0])
    with torch.no_grad():
        w, disp = model.pose_fields.weights(d, kind), model.pose_fields.displacement(v, d, r, kind)
        t_vd = timed(lambda: model.vertex_decoder(v, n, mu, d, r, kind, knn, w, disp), 15, warm=3)
        p1, v1 = torch.from_numpy(pts[None]).float(), torch.from_numpy(vals[None]).float()
        t_e = timed(lambda: model.encoder(p1, v1), 15, warm=3)
    print(f"inference: vertex decoder on {v.shape[1]} vertices (neighbourhoods cached): median {statistics.median(t_vd) * 1000:.1f} ms "
          f"(neighbourhood build once per mesh: {t_knn * 1000:.1f} ms)")
    print(f"inference: encoding one state's {K} SDF samples: median {statistics.median(t_e) * 1000:.1f} ms")
    print(f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6:.2f} GB")


if __name__ == "__main__":
    main()
