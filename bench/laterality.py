"""Can a single character's latent delta tell a left pose from its mirror? For each Lf/Rt pose pair: the
distance between the training characters' two mean deltas (standardised by the bank), and where each
character's own delta falls on the axis through them (in noise floors), with the share of characters on
their own side. With `--split val|test` the characters are that split's, encoded by the checkpoint (the
axis still from the bank's training means): the held-out figure; without, the bank's training deltas.

    python bench/laterality.py [--bank assets/model/bank.safetensors] [--kind neutral_to_pose]
    python bench/laterality.py --checkpoint RUN/model.safetensors --bank RUN/bank.safetensors --split val [--corpus DIR]

A decoder conditioned on one character's delta (oracle, nearest identity, an example pair) can only move the
right limb when that share is near 1; the mean over the training characters averages the spread away.
"""
from __future__ import annotations

import argparse

import numpy as np


def held_out_deltas(checkpoint: str, corpus_dir: str | None, split: str, poses: list[str], bank) -> dict:
    """{pose: (n, Z) standardised neutral -> pose deltas of the split's characters}."""
    import torch

    from latent_model.checkpoint import load_checkpoint
    from latent_model.config import default_corpus_dir
    from latent_model.corpus.store import Corpus
    from latent_model.encoding import encode_states
    from latent_model.types import FINAL

    model, preset, _ = load_checkpoint(checkpoint)
    model.eval()
    c = Corpus(corpus_dir or default_corpus_dir(preset.name))
    ids = c.split_indices(split)
    states = [c.state(i, None, "neutral") for i in ids] + [c.state(i, p, FINAL) for p in poses for i in ids]
    with torch.no_grad():
        mu = bank.standardise(encode_states(model, c, states, progress=True))
    n = len(ids)
    return {p: mu[n * (k + 1):n * (k + 2)] - mu[:n] for k, p in enumerate(poses)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bank")
    ap.add_argument("--kind", default="neutral_to_pose")
    ap.add_argument("--checkpoint", help="with --split: the encoder of the held-out characters")
    ap.add_argument("--corpus")
    ap.add_argument("--split", choices=("train", "val", "test"), help="encode this split's characters")
    args = ap.parse_args()
    from latent_model.bank import LatentBank
    from latent_model.shipped import ShippedPaths

    paths = ShippedPaths.at()
    b = LatentBank.load(args.bank or paths.bank)
    floor = b.noise_floor or 1.0
    lefts = sorted({p for k, p in b.deltas if k == args.kind and p.endswith("Lf") and "+" not in p})
    pairs = [(left, left[:-2] + "Rt") for left in lefts if (args.kind, left[:-2] + "Rt") in b.deltas]
    own = None
    if args.split:
        own = held_out_deltas(args.checkpoint or paths.checkpoint, args.corpus, args.split,
                              [p for pair in pairs for p in pair], b)
    print(f"characters: {args.split or 'the bank training'}; noise floor {floor:.3f}")
    print(f"{'pose':22s} {'|mean L - mean R|':>18s} {'cos(L, R)':>9s} {'own deltas on the L-R axis (floors)':>40s} {'own side':>9s}")
    shares = []
    for left, right in pairs:
        dl, dr = (b.delta(args.kind, p)[1] / b.scale for p in (left, right))
        ml, mr = dl.mean(0), dr.mean(0)
        if own is not None:
            dl, dr = own[left], own[right]
        axis = (ml - mr) / max(float(np.linalg.norm(ml - mr)), 1e-12)
        pl, pr = (dl - (ml + mr) / 2) @ axis / floor, (dr - (ml + mr) / 2) @ axis / floor
        share = ((pl > 0).mean() + (pr < 0).mean()) / 2
        shares.append(share)
        cos = float(ml @ mr / (np.linalg.norm(ml) * np.linalg.norm(mr) + 1e-12))
        print(f"{left:22s} {np.linalg.norm(ml - mr) / floor:18.2f} {cos:9.3f} "
              f"{f'L {pl.mean():+.2f} ± {pl.std():.2f}, R {pr.mean():+.2f} ± {pr.std():.2f}':>40s} {share:9.2f}")
    print(f"median own-side share over {len(shares)} mirror pairs: {np.median(shares):.2f} (min {min(shares):.2f})")


if __name__ == "__main__":
    main()
