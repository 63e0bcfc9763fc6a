"""Correctives on meshes of another topology: each character's skinned pose decimated to half its triangles
(`igl.decimate`), read through anny's template fitted and registered onto it (`registration.correspond`), against
the same character read by vertex index on anny's topology. Explained motion (1 - err / err of no motion) of the
skinning -> skinning+blendshape pair, the truth carried to the decimated vertices by barycentric coordinates;
the time of one correspondence (fit + registration), median over the characters.

    python bench/other_topology_correctives.py [--split val|test] [--persons N] [--rests bind,armsSides]
                                               [--poses elbowBentLf,kneeBentRt,shoulderRaiseLf] [--remesh STEP]

`--remesh STEP`: rebuild each skinned pose by marching cubes on a STEP-metre grid instead (`remeshed_body.remesh`:
no vertex of anny's survives). anny's own reading is carried to the same points, so both are judged on them; "gated"
is what the product gives (no corrective where the registration carried the region > SETTLE_LIMIT).
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--split", default="val", choices=("val", "test"))
    ap.add_argument("--persons", type=int, default=4)
    ap.add_argument("--rests", default="bind,armsSides,armsUp35")
    ap.add_argument("--poses", default="elbowBentLf,kneeBentRt,shoulderRaiseLf")
    ap.add_argument("--remesh", type=float, default=0.0, help="marching-cubes grid step, metres (0: decimate)")
    args = ap.parse_args()
    from remeshed_body import remesh
    import igl

    from latent_model.analysis.metrics import mesh_errors
    from latent_model.config import preset
    from latent_model.corpus.build import generator, plan
    from latent_model.corrective_fields import CorrectiveFields, correctives_beside
    from latent_model.registration import SETTLE_LIMIT, _closest, correspond, template_fitter
    from latent_model.shipped import ShippedPaths

    fields = CorrectiveFields.load(correctives_beside(ShippedPaths.at().checkpoint))
    specs, _, static = plan(preset("standard").corpus)
    persons = [s for s in specs if s.split == args.split and s.rest == "bind"][:args.persons]
    gen = generator()
    faces = gen.faces
    fitter = template_fitter()
    rows: dict[str, list[tuple[float, float, float]]] = {}
    shell = static["body_faces"]
    what = f"remeshed ({args.remesh * 1000:.0f} mm)" if args.remesh > 0 else "decimated"
    times = []
    for spec in persons:
        for rest in args.rests.split(","):
            for pose in args.poses.split(","):
                g = gen.pose(spec, pose, rest)
                skinned, truth = g.skinning, g.skinning_plus_blendshape
                by_index = skinned + fields.displacement(skinned, pose)[0]
                if args.remesh > 0:
                    v, f = remesh(skinned, shell, args.remesh)
                else:
                    v, f = [np.asarray(x) for x in igl.decimate(skinned, faces, len(faces) // 2) if np.ndim(x) == 2][:2]
                    v, f = v.astype(np.float64), f.astype(np.int64)
                face, bary, _ = _closest(v, skinned, faces)
                carry = lambda moved: v + np.einsum("nk,nkj->nj", bary, (moved - skinned)[faces[face]])  # noqa: E731
                carried = carry(truth)
                t0 = time.perf_counter()
                view = correspond(fitter, v, f, pose)
                times.append(time.perf_counter() - t0)
                pred = v + view.to_mesh(fields.displacement(view.on_mesh(v, f), pose)[0])
                settle = float(np.median(view.settle_mm[fields.poses[pose].index]))
                pair = (mesh_errors(carry(by_index), carried, v)["explained"], mesh_errors(pred, carried, v)["explained"])
                rows.setdefault(pose, []).append(pair + ((pair[1] if settle <= SETTLE_LIMIT else 0.0),))
                print(f"{spec.person_id} {rest:10s} {pose:18s} anny's topology {pair[0]:6.3f}  {what} {pair[1]:6.3f}  "
                      f"(template {view.residual_mm:.1f} mm off, region settled {settle:.0f} mm, {times[-1]:.1f} s)",
                      flush=True)
    print(f"{args.split}: {len(persons)} persons x {args.rests}; correspondence median {np.median(times):.1f} s")
    for pose, pairs in rows.items():
        a = np.array(pairs)
        print(f"{pose:18s} anny's topology {a[:, 0].mean():.3f}  {what} {a[:, 1].mean():.3f}  gated {a[:, 2].mean():.3f} "
              f"(worst {a[:, 2].min():.3f}; worse than no motion {int((a[:, 2] < 0).sum())} of {len(a)}, not read "
              f"{int((a[:, 2] != a[:, 1]).sum())})")


if __name__ == "__main__":
    main()
