"""What predicts each pair kind, on the validation characters, through the Transfer API (`lrr evaluate`'s
analysis 6, `analysis/transfer_eval.py`): the motion decoder (decoder v2) or the paper's network, per kind.

    python bench/pair_kinds.py [--checkpoint C] [--bank B] [--corpus DIR] [--split val] [--rest bind]
                               [--kinds blendshape_to_skinning_plus_blendshape,source_to_combo]
                               [--decoders motion,network] [--poses body|all]

For each decoder choice, the chosen kinds are predicted by it (`MotionDecoderConfig.kinds`); prints per kind and
pose group explained motion / leak (mm) of the mean, nearest and oracle deltas, the no-motion and offset-copy
baselines, and the wall time. `--poses body`: the body group's poses and the combos made only of them (the face
and finger deltas are under the noise gate, issue 19).
"""
from __future__ import annotations

import argparse
import dataclasses
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint")
    ap.add_argument("--bank")
    ap.add_argument("--corpus")
    ap.add_argument("--split", default="val")
    ap.add_argument("--rest", default="bind", help="a rest configuration, or 'all'")
    ap.add_argument("--kinds", default="blendshape_to_skinning_plus_blendshape,source_to_combo")
    ap.add_argument("--decoders", default="motion,network")
    ap.add_argument("--poses", default="body", choices=("body", "all"))
    args = ap.parse_args()
    import torch

    from latent_model.analysis.transfer_eval import evaluate_transfer
    from latent_model.config import default_corpus_dir
    from latent_model.corpus.store import Corpus
    from latent_model.shipped import ShippedPaths
    from latent_model.train.motion import training_poses
    from latent_model.transfer import Transfer

    torch.set_num_threads(2)
    paths = ShippedPaths.at()
    t = Transfer.from_files(args.checkpoint or paths.checkpoint, args.bank or paths.bank)
    c = Corpus(args.corpus or default_corpus_dir("standard"))
    ids = c.split_indices(args.split, rest=None if args.rest == "all" else args.rest)
    kinds = tuple(args.kinds.split(","))
    poses = training_poses(c, "body") if args.poses == "body" else None
    base = t.model.cfg
    for decoder in args.decoders.split(","):
        if decoder not in ("motion", "network"):
            raise SystemExit(f"--decoders: {decoder!r} is not motion or network")
        others = tuple(k for k in base.motion.kinds if k not in kinds)
        motion_kinds = others + kinds if decoder == "motion" else others
        t.model.cfg = dataclasses.replace(base, motion=dataclasses.replace(base.motion, kinds=motion_kinds))
        t0 = time.perf_counter()
        m, _ = evaluate_transfer(t, c, ids, kinds, progress=False, poses=poses)
        wall = time.perf_counter() - t0
        print(f"== {decoder} predicts {', '.join(kinds)} ({len(ids)} {args.split} characters, rest {args.rest}, "
              f"{args.poses} poses; {wall:.0f} s)")
        groups = sorted({tuple(k.split(".")[1:3]) for k in m if k.startswith("transfer_group.")})
        strategies = ("mean", "nearest", "oracle", "no_motion", "offset_nearest")
        print(f"  {'kind / group':50s} " + " ".join(f"{s:>16s}" for s in strategies))
        for kind, group in groups:
            cells = [f"{m[f'transfer_group.{kind}.{group}.{s}.explained']:7.3f} /{m[f'transfer_group.{kind}.{group}.{s}.leak_mm']:6.2f}"
                     for s in strategies]
            print(f"  {kind + ' / ' + group:50s} " + " ".join(f"{x:>16s}" for x in cells))


if __name__ == "__main__":
    main()
