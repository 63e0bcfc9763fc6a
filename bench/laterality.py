"""Can a single character's latent delta tell a left pose from its mirror? For each Lf/Rt pose pair of the
bank's training deltas (standardised): the distance between the two mean deltas, and where each character's
own delta falls on the axis through them (in noise floors), with the share of characters on their own side.

    python bench/laterality.py [--bank assets/model/bank.safetensors] [--kind neutral_to_pose]

A decoder conditioned on one character's delta (oracle, nearest identity, an example pair) can only move the
right limb when that share is near 1; the mean over the training characters averages the spread away.
"""
from __future__ import annotations

import argparse

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bank")
    ap.add_argument("--kind", default="neutral_to_pose")
    args = ap.parse_args()
    from latent_model.bank import LatentBank
    from latent_model.shipped import ShippedPaths

    b = LatentBank.load(args.bank or ShippedPaths.at().bank)
    floor = b.noise_floor or 1.0
    lefts = sorted({p for k, p in b.deltas if k == args.kind and p.endswith("Lf") and "+" not in p})
    print(f"{'pose':22s} {'|mean L - mean R|':>18s} {'|mean L|':>9s} {'own deltas on the L-R axis (floors)':>40s} {'own side':>9s}")
    for left in lefts:
        right = left[:-2] + "Rt"
        if (args.kind, right) not in b.deltas:
            continue
        dl, dr = (b.delta(args.kind, p)[1] / b.scale for p in (left, right))
        ml, mr = dl.mean(0), dr.mean(0)
        axis = (ml - mr) / max(float(np.linalg.norm(ml - mr)), 1e-12)
        pl, pr = (dl - (ml + mr) / 2) @ axis / floor, (dr - (ml + mr) / 2) @ axis / floor
        share = ((pl > 0).mean() + (pr < 0).mean()) / 2
        print(f"{left:22s} {np.linalg.norm(ml - mr) / floor:18.2f} {np.linalg.norm(ml) / floor:9.1f} "
              f"{f'L {pl.mean():+.2f} ± {pl.std():.2f}, R {pr.mean():+.2f} ± {pr.std():.2f}':>40s} {share:9.2f}")


if __name__ == "__main__":
    main()
