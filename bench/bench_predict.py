"""Benchmark the user-mesh path of `lrr predict`: import (read + frame detection + weld) and
encode (Transfer.prepare: normals, KNN graph, SDF sampling + encoder) for a 14k-vertex character
(a held-out identity written as a Y-up centimetre OBJ, like a Maya export) and a 200k-vertex one
(the same body subdivided twice, PLY). Targets: <= 2 s and <= 10 s. Prints medians; never asserts.

Run from the repo root:  python bench/bench_predict.py [--runs 3] [--threads 1]
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = ap.parse_args()
    import torch
    import trimesh

    from latent_model import meshio
    from latent_model.predict import load_transfer
    from latent_model.shipped import GroundTruth, ShippedPaths, load_identity_specs

    torch.set_num_threads(args.threads)
    transfer = load_transfer()
    specs, _ = load_identity_specs(ShippedPaths.at().identities)
    spec = next(s for s in specs if s.split == "test")
    gt = GroundTruth([spec])
    v = gt.state(spec.id, None, "neutral").astype(np.float64)
    body = trimesh.Trimesh(v, gt.faces, process=False)
    big = body
    while len(big.vertices) < 200_000:
        big = big.subdivide()
    tmp = Path(tempfile.mkdtemp(prefix="bench_predict_"))
    cases = []
    for name, m, ext in (("14k", body, "obj"), ("200k", big, "ply")):
        p = tmp / f"{name}.{ext}"
        trimesh.Trimesh((np.asarray(m.vertices) @ meshio._R_Y_UP) * 100.0, m.faces, process=False).export(p)
        cases.append((name, p, len(m.vertices)))
    print(f"torch threads {args.threads}; model {ShippedPaths.at().checkpoint}")
    for name, path, n in cases:
        t_imp, t_enc, t_pred = [], [], []
        for r in range(args.runs):
            t0 = time.perf_counter()
            um = meshio.load_mesh(path)
            t1 = time.perf_counter()
            prepared = transfer.prepare(um.vertices, um.faces, sdf_faces=um.sdf_faces, seed=r)
            prepared.mu  # the latent is derived on first read: encode it here, as the nearest strategy will
            t2 = time.perf_counter()
            transfer.predict(prepared, "elbowBentLf", "nearest")
            t3 = time.perf_counter()
            t_imp.append(t1 - t0)
            t_enc.append(t2 - t1)
            t_pred.append(t3 - t2)
        imp, enc = statistics.median(t_imp), statistics.median(t_enc)
        target = 2.0 if name == "14k" else 10.0
        print(f"{name:5s} ({n} vertices, {path.suffix}): import {imp:.2f} s + encode {enc:.2f} s = {imp + enc:.2f} s "
              f"(target <= {target:.0f} s); then predict {statistics.median(t_pred):.2f} s   [median of {args.runs}]")


if __name__ == "__main__":
    main()
