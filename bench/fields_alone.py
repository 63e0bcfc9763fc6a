"""How far the closed-form pose fields alone carry a pose to unseen identities, for several
random-Fourier frequency scales: ridge fit of one field per pose on the training identities'
neutral -> pose pairs (the features of `PoseFields.features`: positions centred on the bounding box,
divided by the height), applied with the mean amount to every held-out identity.
Prints explained motion (1 - err / err of no motion) and static leakage (mm) per pose and scale;
`--self-fit` fits each held-out identity on its own pair instead (the capacity of the features).

    python bench/fields_alone.py --poses kneeBentLf,elbowSuperBentLf --sigmas 12,6 [--corpus DIR]
"""
from __future__ import annotations

import argparse

import numpy as np
import torch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--poses", default="kneeBentLf,elbowSuperBentLf,shoulderRaiseLf,shoulderForwardRt")
    ap.add_argument("--sigmas", default="12,6", help="frequency scales (x pi, per body height)")
    ap.add_argument("--features", type=int, default=1024)
    ap.add_argument("--ridge", type=float, default=1e-2, help="relative to the Gram matrix's mean diagonal")
    ap.add_argument("--vertices", type=int, default=1500, help="random vertices per training pair")
    ap.add_argument("--self-fit", action="store_true")
    ap.add_argument("--corpus", help="corpus directory (default: the standard preset's)")
    args = ap.parse_args()
    from latent_model.config import ModelConfig, PoseFieldsConfig, default_corpus_dir
    from latent_model.corpus.store import Corpus
    from latent_model.nn.pose_fields import PoseFields

    c = Corpus(args.corpus or default_corpus_dir("standard"))
    train, test = c.split_indices("train"), c.split_indices("test")
    for pose in args.poses.split(","):
        def pair(j: int) -> tuple[np.ndarray, np.ndarray]:
            return c.vertices(c.state(j, None, "neutral")), c.vertices(c.state(j, pose, "skinning_plus_blendshape"))

        for sigma in (float(s) for s in args.sigmas.split(",")):
            fields = PoseFields(ModelConfig(fields=PoseFieldsConfig(features=args.features, rff_sigma=sigma)))

            def feats(v: np.ndarray) -> np.ndarray:
                with torch.no_grad():
                    return fields.features(torch.from_numpy(np.asarray(v, np.float32))[None])[0].double().numpy()

            rng = np.random.default_rng(0)

            def fit(ids: list[int]) -> np.ndarray:
                gram, rhs = 0.0, 0.0
                for j in ids:
                    vs, vt = pair(j)
                    sub = rng.choice(len(vs), min(args.vertices, len(vs)), replace=False)
                    x = feats(vs)[sub]
                    gram, rhs = gram + x.T @ x, rhs + x.T @ (vt - vs)[sub]
                return np.linalg.solve(gram + args.ridge * np.diag(gram).mean() * np.eye(len(gram)), rhs)

            w = None if args.self_fit else fit(train)
            explained, leak, ids = [], [], []
            for j in test:
                vs, vt = pair(j)
                pred = vs + feats(vs) @ (fit([j]) if args.self_fit else w)
                motion = np.linalg.norm(vt - vs, axis=1)
                explained.append(1 - np.linalg.norm(pred - vt, axis=1).mean() / motion.mean())
                leak.append(np.linalg.norm(pred - vs, axis=1)[motion < 1e-3].mean() * 1000)
                ids.append(c.identities[j].id)
            print(f"{pose} sigma {sigma:g}: explained {np.mean(explained):.3f}, leak {np.mean(leak):.2f} mm "
                  f"({'self-fit' if args.self_fit else 'held-out'}); per identity: "
                  + " ".join(f"{i} {e:.2f}" for i, e in zip(ids, explained)), flush=True)


if __name__ == "__main__":
    main()
