"""The body decoder on characters remeshed as another tool would make them: each character's neutral rebuilt by
marching cubes of its signed distance (a uniform grid, `--step` metres) and decimated to ~14k vertices
(`igl.decimate`), so no vertex, edge or density of anny's survives and the fingers fuse where the grid is coarse.
neutral_to_pose with the mean delta, explained motion (1 - err / err of no motion) against the rig's truth carried
to the remeshed vertices by barycentric coordinates, beside anny's own-topology prediction carried the same way (the
same points, so the vertex density of anny's face and hands weighs neither), per pose and rest.

    python bench/remeshed_body.py [--split val|test] [--persons N] [--rests bind,armsSides,tpose] [--step 0.007]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

BROAD = ("elbowBentLf", "elbowBentRt", "kneeBentLf", "kneeBentRt", "clavicleDownwardLf", "shoulderRaiseLf",
         "shoulderForwardRt", "hipFlexLf", "wristFlexLf", "spineTwistLf", "neckTurnLf", "spineBendFw")


def remesh(vertices: np.ndarray, shell: np.ndarray, step: float, faces_out: int = 28000) -> tuple[np.ndarray, np.ndarray]:
    """((V', 3), (F', 3)) the surface of the closed shell `shell` (anny's body faces) rebuilt by marching cubes on a
    grid of `step` metres (inside by the fast winding number: anny's eyes and teeth are other shells), decimated."""
    import igl

    v = np.asarray(vertices, np.float64)
    lo, hi = v.min(axis=0) - 2 * step, v.max(axis=0) + 2 * step
    dims = np.ceil((hi - lo) / step).astype(int) + 1
    axes = [lo[k] + step * np.arange(dims[k]) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).transpose(2, 1, 0, 3).reshape(-1, 3)  # x fastest
    sdf = igl.signed_distance(grid, v, np.asarray(shell, np.int64),
                              sign_type=igl.SIGNED_DISTANCE_TYPE_FAST_WINDING_NUMBER)[0]
    mv, mf = igl.marching_cubes(sdf, grid, int(dims[0]), int(dims[1]), int(dims[2]), 0.0)[:2]
    out = [np.asarray(o) for o in igl.decimate(mv, mf, faces_out) if np.ndim(o) == 2][:2]
    return out[0].astype(np.float64), out[1].astype(np.int64)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--split", default="val", choices=("val", "test"))
    ap.add_argument("--persons", type=int, default=4)
    ap.add_argument("--rests", default="bind,armsSides,tpose")
    ap.add_argument("--step", type=float, default=0.007, help="marching-cubes grid step, metres (default 0.007)")
    args = ap.parse_args()

    from latent_model.analysis.metrics import mesh_errors
    from latent_model.config import preset
    from latent_model.corpus.build import generator, plan
    from latent_model.registration import _closest
    from latent_model.shipped import ShippedPaths
    from latent_model.transfer import Transfer

    paths = ShippedPaths.at()
    transfer = Transfer.from_files(paths.checkpoint, paths.bank)
    specs, _, static = plan(preset("standard").corpus)
    persons = [s for s in specs if s.split == args.split and s.rest == "bind"][:args.persons]
    gen = generator()
    faces, shell = np.asarray(gen.faces, np.int64), static["body_faces"]
    rests = args.rests.split(",")
    rows: dict[tuple[str, str], list[tuple[float, float]]] = {}
    sizes, seconds = [], []
    for spec in persons:
        for rest in rests:
            v = gen.neutral(spec, rest).astype(np.float64)
            t0 = time.perf_counter()
            rv, rf = remesh(v, shell, args.step)
            face, bary, _ = _closest(rv, v, faces)
            carry = lambda moved: rv + np.einsum("nk,nkj->nj", bary, (moved - v)[faces[face]])  # noqa: E731
            own = transfer.prepare(v.astype(np.float32), faces, sdf_faces=shell)
            other = transfer.prepare(rv.astype(np.float32), rf)
            for pose in BROAD:
                truth = carry(gen.pose(spec, pose, rest).skinning_plus_blendshape)
                by_anny = carry(transfer.predict_detail(own, pose, "mean_pose_delta").vertices)
                remeshed = transfer.predict_detail(other, pose, "mean_pose_delta").vertices
                rows.setdefault((rest, pose), []).append((mesh_errors(by_anny, truth, rv)["explained"],
                                                          mesh_errors(remeshed, truth, rv)["explained"]))
            seconds.append(time.perf_counter() - t0)
            sizes.append(len(rv))
            mine = np.mean([rows[(rest, p)][-1] for p in BROAD], axis=0)
            print(f"{spec.person_id} {rest:10s} {len(rv)} vertices, explained {mine[0]:.3f} / {mine[1]:.3f}, "
                  f"{seconds[-1]:.1f} s (remesh, prepare, {len(BROAD)} predictions twice)", flush=True)
    print(f"\n{args.split}: {len(persons)} persons, marching cubes at {args.step * 1000:.0f} mm, {int(np.median(sizes))} "
          f"vertices (median); explained on the remeshed vertices, anny's topology carried / remeshed")
    print(f"{'pose':20s}" + "".join(f"{r:>22s}" for r in rests))
    for pose in BROAD:
        cells = [np.mean(rows[(r, pose)], axis=0) for r in rests]
        print(f"{pose:20s}" + "".join(f"{a:>13.3f} / {b:.3f}" for a, b in cells))
    means = [np.mean([np.mean(rows[(r, p)], axis=0) for p in BROAD], axis=0) for r in rests]
    print(f"{'mean':20s}" + "".join(f"{a:>13.3f} / {b:.3f}" for a, b in means))


if __name__ == "__main__":
    main()
