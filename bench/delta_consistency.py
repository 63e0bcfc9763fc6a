"""How well one character's latent delta says its pose: the encoder's part of the oracle, the nearest identity
and an example pair (what a decoder reading one person's delta can know at best).

For each broad body pose, the deltas mu(posed) - mu(neutral) of the split's characters in bind (from their stored
SDF samples), standardised by the bank's scale, against the pose's mean delta over the training characters in bind:
cosine, length along the mean (1 = the mean's; its 10-90 % range is how well one delta says the angle), the part
across it in noise floors, and how often the delta is nearer its own pose's mean than the mirrored pose's.

    python bench/delta_consistency.py [--checkpoint C] [--bank B] [--split val] [--train-persons 40]
"""
from __future__ import annotations

import argparse
import time

BROAD = ("elbowBentLf", "elbowBentRt", "elbowSuperBentLf", "kneeBentLf", "kneeBentRt", "clavicleDownwardLf",
         "shoulderRaiseLf", "shoulderForwardRt", "hipFlexLf", "hipFlexRt", "spineTwistLf", "spineBendFw",
         "neckTurnLf", "neckBendFw", "wristFlexLf")


def mirror(pose: str) -> str | None:
    for a, b in (("Lf", "Rt"), ("Rt", "Lf")):
        if pose.endswith(a):
            return pose[:-2] + b
    return None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", help="default: the shipped model")
    ap.add_argument("--bank", help="its scale and noise floor (default: the shipped bank; a bank of another model: the "
                    "scale of the training characters' states encoded here, lengths in the mean's units only)")
    ap.add_argument("--corpus")
    ap.add_argument("--split", default="val", choices=("val", "test"))
    ap.add_argument("--train-persons", type=int, default=40, help="training characters in bind for the pose means")
    args = ap.parse_args()
    import numpy as np
    import torch

    from latent_model.bank import LatentBank, model_digest
    from latent_model.checkpoint import load_checkpoint
    from latent_model.config import default_corpus_dir
    from latent_model.corpus.store import Corpus
    from latent_model.encoding import encode_states
    from latent_model.shipped import ShippedPaths
    from latent_model.types import FINAL

    torch.set_num_threads(2)
    paths = ShippedPaths.at()
    model, preset, _ = load_checkpoint(args.checkpoint or paths.checkpoint)
    model.eval()
    bank = LatentBank.load(args.bank or paths.bank)
    corpus = Corpus(args.corpus or default_corpus_dir(preset.name))
    poses = sorted({p for b in BROAD for p in (b, mirror(b)) if p and p in corpus.poses})
    t0 = time.perf_counter()

    def encoded(people: list[int]) -> np.ndarray:
        """(1 + poses, n, Z) latents of `people`: neutral, then each pose."""
        states = [corpus.state(i, None, "neutral") for i in people]
        states += [corpus.state(i, p, FINAL) for p in poses for i in people]
        return encode_states(model, corpus, states).reshape(len(poses) + 1, len(people), -1)

    train = corpus.split_indices("train", "bind")[:args.train_persons]
    held = corpus.split_indices(args.split, "bind")
    mu_train, mu_held = encoded(train), encoded(held)
    ours = bank.model_digest == model_digest(model)
    scale = bank.scale if ours else mu_train.reshape(-1, mu_train.shape[-1]).std(0) + 1e-6
    means = {p: ((mu_train[k + 1] - mu_train[0]) / scale).mean(0) for k, p in enumerate(poses)}
    own = {p: (mu_held[k + 1] - mu_held[0]) / scale for k, p in enumerate(poses)}
    floor = bank.noise_floor if ours and bank.noise_floor > 0 else 1.0
    if not ours:
        print("the bank is another model's: standardised by the encoded training states, lengths in std units")
    print(f"{args.split}: {len(held)} characters in bind against the mean of {len(train)} training characters "
          f"({time.perf_counter() - t0:.0f} s); lengths in noise floors ({floor:.3f})")
    print(f"{'pose':20s} {'|mean|':>7s} {'cos med':>8s} {'along 10-50-90 %':>18s} {'across':>7s} {'own side':>8s}")
    spreads, coss = [], []
    for p in BROAD:
        if p not in own:
            continue
        m, d = means[p], own[p]
        mn = np.linalg.norm(m)
        along = d @ m / mn ** 2
        across = np.linalg.norm(d - along[:, None] * m, axis=1) / floor
        cos = d @ m / np.linalg.norm(d, axis=1) / mn
        q = np.quantile(along, [0.1, 0.5, 0.9])
        side = "" if mirror(p) not in means else \
            f"{np.mean(np.linalg.norm(d - m, axis=1) < np.linalg.norm(d - means[mirror(p)], axis=1)) * 100:7.0f}%"
        spreads.append(q[2] - q[0])
        coss.append(np.median(cos))
        print(f"{p:20s} {mn / floor:7.2f} {np.median(cos):8.3f} {q[0]:6.2f}-{q[1]:.2f}-{q[2]:.2f} "
              f"{np.median(across):7.2f} {side:>8s}")
    print(f"median over poses: cosine {np.median(coss):.3f}, 10-90 % length range {np.median(spreads):.2f} of the mean's")


if __name__ == "__main__":
    main()
