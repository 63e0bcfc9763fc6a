"""How well the pose prototypes (nn/pose_fields.py) recognise a held-out identity's own pose delta:
for every held-out identity and single pose, the true delta mu(neutral -> pose) is matched against
the `neutral_to_pose` prototypes (the mean training deltas). Prints, per pose group, how often the
nearest prototype names the pose, and the mean softmax weight (the checkpoint's temperature) the
delta gives its own prototype — the weight its own field gets at inference, for the oracle and,
roughly, for a single identity's delta. Never asserts.

    python bench/prototype_naming.py [--checkpoint assets/model/model.safetensors] [--corpus DIR]
"""
from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np
import torch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", help="model.safetensors (default: the shipped model)")
    ap.add_argument("--corpus", help="corpus directory (default: the checkpoint preset's)")
    args = ap.parse_args()
    from latent_model.encoding import encode_states
    from latent_model.config import default_corpus_dir
    from latent_model.types import PAIR_KINDS
    from latent_model.corpus.poses import get_pose
    from latent_model.corpus.store import Corpus
    from latent_model.shipped import ShippedPaths
    from latent_model.checkpoint import load_checkpoint

    model, preset, _ = load_checkpoint(args.checkpoint or ShippedPaths.at().checkpoint)
    model.eval()
    c = Corpus(args.corpus or default_corpus_dir(preset.corpus.preset))
    fields = model.pose_fields
    k = PAIR_KINDS.index("neutral_to_pose")
    poses = [p for p in c.poses if not get_pose(p).is_combo]
    hits, weights = defaultdict(list), defaultdict(list)
    for i in c.split_indices("test"):
        states = [c.state(i, None, "neutral")] + [c.state(i, p, "skinning_plus_blendshape") for p in poses]
        mu = torch.from_numpy(encode_states(model, c, states))
        delta = mu[1:] - mu[:1]  # (P, Z)
        kind = torch.full((len(poses),), k)
        with torch.no_grad():
            cos, valid = fields.cosines(delta, kind)
            w = fields.weights(delta, kind)
        cos = cos.masked_fill(~valid, -2.0)
        for j, p in enumerate(poses):
            own = c.pose_index(p)
            group = get_pose(p).group
            hits[group].append(int(cos[j].argmax()) == own)
            weights[group].append(float(w[j, own]))
    print(f"{args.checkpoint or 'shipped model'}: temperature {preset.model.fields.proto_temp:g}, "
          f"{len(c.split_indices('test'))} held-out identities")
    for group in sorted(hits):
        print(f"  {group:8s} nearest prototype names the pose {100 * np.mean(hits[group]):5.1f}%  "
              f"own softmax weight {np.mean(weights[group]):.3f}  ({len(hits[group])} deltas)")


if __name__ == "__main__":
    main()
