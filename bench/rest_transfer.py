"""A model on the held-out characters of a corpus, per rest configuration: neutral_to_pose with the
mean delta, explained motion (1 - err / err of no motion) and static leakage (mm) per broad body pose.
Any checkpoint and corpus (no digest check): this is how the shipped generator-3 model is measured on
corpus v4's held-out rests, the baseline the decoder issue must beat.

    python bench/rest_transfer.py [--corpus DIR] [--checkpoint C --bank B] [--split test|val] [--persons N]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

BROAD = ("elbowBentLf", "elbowBentRt", "kneeBentLf", "kneeBentRt", "clavicleDownwardLf", "shoulderRaiseLf",
         "shoulderForwardRt", "hipFlexLf", "wristFlexLf", "spineTwistLf", "neckTurnLf", "spineBendFw")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--corpus", help="corpus directory (default: the standard preset's)")
    ap.add_argument("--checkpoint", help="default: the shipped model")
    ap.add_argument("--bank", help="default: the shipped bank")
    ap.add_argument("--split", default="test", choices=("test", "val"))
    ap.add_argument("--persons", type=int, default=0, help="only the first N persons of the split (0: all)")
    ap.add_argument("--poses", default=",".join(BROAD))
    ap.add_argument("--strategy", default="mean_pose_delta",
                    help="mean_pose_delta, nearest_identity_delta or oracle (the character's own delta)")
    args = ap.parse_args()
    from latent_model.analysis.metrics import mesh_errors
    from latent_model.config import default_corpus_dir
    from latent_model.corpus.store import Corpus
    from latent_model.encoding import encode_states
    from latent_model.shipped import ShippedPaths
    from latent_model.transfer import Transfer

    paths = ShippedPaths.at()
    transfer = Transfer.from_files(args.checkpoint or paths.checkpoint, args.bank or paths.bank)
    c = Corpus(args.corpus or default_corpus_dir("standard"))
    ids = c.split_indices(args.split)
    persons = list(dict.fromkeys(c.identities[i].person_id for i in ids))
    if args.persons:
        persons = persons[:args.persons]
    poses = args.poses.split(",")
    by_rest: dict[str, list[int]] = {}
    for i in ids:
        if c.identities[i].person_id in persons:
            by_rest.setdefault(c.identities[i].rest, []).append(i)
    t0 = time.perf_counter()
    table: dict[tuple[str, str], list[dict]] = {}
    for rest, chars in by_rest.items():
        for i in chars:
            s = c.state(i, None, "neutral")
            mu = encode_states(transfer.model, c, [s], transfer.device)[0]
            mesh = transfer.prepare(c.vertices(s), c.faces, sdf_faces=c.body_faces, mu=mu)
            for pose in poses:
                own = (encode_states(transfer.model, c, [c.state(i, pose, "skinning_plus_blendshape")], transfer.device)[0]
                       if args.strategy == "oracle" else None)
                pred = transfer.predict_detail(mesh, pose, args.strategy, oracle_target_mu=own).vertices
                truth = c.vertices(c.state(i, pose, "skinning_plus_blendshape"))
                table.setdefault((rest, pose), []).append(mesh_errors(pred, truth, c.vertices(s)))
    print(f"{args.split} characters of {len(persons)} persons, {args.strategy}, explained / leak mm "
          f"({time.perf_counter() - t0:.0f} s)")
    rests = list(by_rest)
    print(f"{'pose':22s}" + "".join(f"{r:>18s}" for r in rests))
    for pose in poses:
        cells = []
        for r in rests:
            rows = table[(r, pose)]
            cells.append(f"{np.mean([x['explained'] for x in rows]):8.2f} / {np.mean([x['leak_mm'] for x in rows]):5.2f}")
        print(f"{pose:22s}" + "".join(f"{x:>18s}" for x in cells))
    means = [f"{np.mean([np.mean([x['explained'] for x in table[(r, p)]]) for p in poses]):8.2f}" for r in rests]
    print(f"{'mean explained':22s}" + "".join(f"{x:>18s}" for x in means))


if __name__ == "__main__":
    main()
