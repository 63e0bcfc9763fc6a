"""Decoder v2's inference options on the validation characters, through the Transfer API: rigid hands and feet
(`rigid_parts`) and translation absorbed into pivots (`repivot`), each combination with the blend steps, the
magnitudes against the rig and the example pairs of `lrr evaluate` (analysis/decoder_eval.py).

    python bench/inference_options.py [--checkpoint C] [--bank B] [--corpus DIR] [--options off,rigid,rigid+0.15]
                                      [--refits 0,0.15]

An option: "off", "rigid" (rigid parts, no repivot), "rigid+D" / "+D" (repivot damping D, with / without rigid parts).
Each is run with each refit radius of --refits (m; 0: magnitudes scale the decoder's own parameters).
"""
from __future__ import annotations

import argparse
import dataclasses


def parse_option(text: str) -> tuple[bool, float]:
    rigid, _, damping = text.partition("+")
    if rigid not in ("off", "rigid", ""):
        raise SystemExit(f"--options: {text!r} is not off, rigid, rigid+D or +D")
    return rigid == "rigid", float(damping or 0.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint")
    ap.add_argument("--bank")
    ap.add_argument("--corpus")
    ap.add_argument("--options", default="off,rigid,rigid+0.15")
    ap.add_argument("--refits", default=None, help="refit radii (default: the model's)")
    ap.add_argument("--no-examples", action="store_true")
    args = ap.parse_args()
    import torch

    from latent_model.analysis.decoder_eval import Characters, blend_steps, example_transfer, magnitude_truths
    from latent_model.config import default_corpus_dir
    from latent_model.corpus.states import StateGenerator
    from latent_model.corpus.store import Corpus
    from latent_model.shipped import ShippedPaths
    from latent_model.transfer import Transfer

    torch.set_num_threads(2)
    paths = ShippedPaths.at()
    t = Transfer.from_files(args.checkpoint or paths.checkpoint, args.bank or paths.bank)
    c = Corpus(args.corpus or default_corpus_dir("standard"))
    bind = c.split_indices("val", rest="bind")
    generator = StateGenerator()
    base = t.model.cfg
    refits = [float(x) for x in args.refits.split(",")] if args.refits else [base.motion.refit_radius]
    for option, refit in ((o, f) for o in args.options.split(",") for f in refits):
        rigid, damping = parse_option(option)
        t.model.cfg = dataclasses.replace(base, motion=dataclasses.replace(base.motion, rigid_parts=rigid, repivot=damping,
                                                                           refit_radius=refit))
        chars = Characters(t, c)  # fresh meshes: their caches hold the options' per-mesh parts
        m = {**blend_steps(t, chars, bind), **magnitude_truths(t, chars, bind, generator)}
        if not args.no_examples:
            m.update(example_transfer(t, chars, bind, generator))
        print(f"== {option}: rigid parts {rigid}, repivot {damping:g}, refit radius {refit:g} ({len(bind)} validation "
              f"characters in bind)")
        for k in sorted(m):
            if k.startswith("decoder.blend") and k.endswith(("step_ratio", "half_a", "half_b")) \
                    or k.startswith("decoder.magnitude") and k.endswith(("explained", "leak_mm", "strain")) \
                    or k.startswith("decoder.examples") and k.endswith(("explained", "leak_mm")):
                print(f"  {k[8:]:60s} {m[k]:8.3f}")


if __name__ == "__main__":
    main()
