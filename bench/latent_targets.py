"""The latent targets of `lrr evaluate` (pose consistency, identity vs noise, KS D, conditioning signal over noise)
on the validation characters, to choose a model before the test characters are evaluated once.

    python bench/latent_targets.py [--checkpoint C] [--bank B] [--corpus DIR] [--split val|test]

Prints each target beside the paper's number (the same analysis code as `lrr evaluate`, analysis/latent_space.py).
"""
from __future__ import annotations

import argparse
import time

KEYS = ("latent.pose_consistency.elbowBentLf.cos_mean", "latent.pose_consistency.clavicleDownwardLf.cos_mean",
        "latent.pose_consistency.kneeBentLf.cos_mean", "latent.identity_noise_ratio", "latent.ks.D",
        "latent.cond_noise.mean", "latent.cond_noise.median", "latent.cond_noise.group.body",
        "latent.cond_noise.group.face", "latent.cond_noise.group.finger")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint")
    ap.add_argument("--bank")
    ap.add_argument("--corpus")
    ap.add_argument("--split", default="val", choices=("val", "test"))
    args = ap.parse_args()
    import torch

    from latent_model.analysis.latent_space import SampleCache, latent_analyses
    from latent_model.analysis.report import PAPER
    from latent_model.analysis.sources import model_source
    from latent_model.bank import LatentBank
    from latent_model.checkpoint import load_checkpoint
    from latent_model.config import default_corpus_dir
    from latent_model.corpus.store import Corpus
    from latent_model.shipped import ShippedPaths

    torch.set_num_threads(2)
    paths = ShippedPaths.at()
    model, preset, _ = load_checkpoint(args.checkpoint or paths.checkpoint)
    model.eval()
    bank = LatentBank.load(args.bank or paths.bank)
    corpus = Corpus(args.corpus or default_corpus_dir(preset.name))
    t = time.perf_counter()
    m, _ = latent_analyses(model_source(model, bank, SampleCache(corpus)), corpus, split=args.split)
    print(f"latent targets on the {args.split} characters ({time.perf_counter() - t:.0f} s)")
    for k in KEYS:
        if k in m:
            paper = PAPER.get(k)
            print(f"  {k[7:]:46s} {m[k]:8.3f}" + (f"   paper {paper:g}" if paper is not None else ""))


if __name__ == "__main__":
    main()
