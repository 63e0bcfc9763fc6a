"""A model on the held-out characters of a corpus, per rest configuration: neutral_to_pose with the
mean delta, explained motion (1 - err / err of no motion) and static leakage (mm) per broad body pose.
Any checkpoint and corpus (no digest check): this is how the shipped generator-3 model is measured on
corpus v4's held-out rests, the baseline the decoder issue must beat.

    python bench/rest_transfer.py [--corpus DIR] [--checkpoint C --bank B] [--split test|val] [--persons N]
                                  [--rest NAME[,NAME...]] [--strategy S]

`--rest`: the split's persons stand in these rest configurations (corpus/rests.py, any split's) instead of the
corpus's own characters, posed and encoded on the fly (`train/rest_augment.characters_in_rests`; about 30 s a rest
for 8 persons on 2 workers): a held-out rest's configuration on the validation persons is how a design is judged on
it without the test ones.
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
    ap.add_argument("--rest", help="stand the split's persons in these rest configurations (comma-separated names)")
    ap.add_argument("--workers", type=int, default=2, help="processes posing and sampling the --rest characters")
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
    by_rest: dict[str, list] = {}
    t0 = time.perf_counter()
    if args.rest:
        from latent_model.corpus.rests import REST_CONFIGS
        from latent_model.errors import look_up
        from latent_model.train.rest_augment import characters_in_rests

        binds = [i for i in ids if c.identities[i].rest == "bind" and c.identities[i].person_id in persons]
        stands = [(i, look_up(REST_CONFIGS, name, "rest configuration")) for name in args.rest.split(",") for i in binds]
        extra = characters_in_rests(transfer.model, c, stands, tuple(poses), [[17, n] for n in range(len(stands))],
                                    transfer.device, workers=args.workers, log=lambda m: None)
        for k, (_, rest) in enumerate(stands):
            by_rest.setdefault(rest.name, []).append(("extra", k))
    else:
        for i in ids:
            if c.identities[i].person_id in persons:
                by_rest.setdefault(c.identities[i].rest, []).append(("corpus", i))

    def character(ref):
        """(neutral (V, 3), its latent (Z,), {pose: (final state (V, 3), its latent)}) of a corpus or stood character."""
        where, i = ref
        if where == "extra":
            return extra.neutral[i], extra.mu_neutral[i], {p: (extra.posed[i, j], extra.mu_posed[i, j])
                                                           for j, p in enumerate(poses)}
        s = c.state(i, None, "neutral")
        finals = [c.state(i, p, "skinning_plus_blendshape") for p in poses]
        mus = encode_states(transfer.model, c, [s, *finals], transfer.device)
        return c.vertices(s), mus[0], {p: (c.vertices(t), m) for p, t, m in zip(poses, finals, mus[1:])}

    table: dict[tuple[str, str], list[dict]] = {}
    for rest, chars in by_rest.items():
        for ref in chars:
            v_src, mu, finals = character(ref)
            mesh = transfer.prepare(v_src, c.faces, sdf_faces=c.body_faces, mu=mu)
            for pose in poses:
                truth, own = finals[pose]
                pred = transfer.predict_detail(mesh, pose, args.strategy,
                                               oracle_target_mu=own if args.strategy == "oracle" else None).vertices
                table.setdefault((rest, pose), []).append(mesh_errors(pred, truth, v_src))
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
