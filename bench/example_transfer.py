"""Transfer from an example pair on the validation (or test) persons in bind, through the Transfer API:
each example deformation (`corpus/examples.py`: amplitudes, unseen combinations, new motions) made on the
first person and judged on the others, as `lrr evaluate` does on the test persons. With `--decoder-state`,
decoder v2's weights are replaced by a state saved by `bench/motion_pilot.py --save` (same architecture),
so a pilot decoder is judged with the shipped inference (smoothing, rigid parts, refit, noise gate).

    python bench/example_transfer.py [--split val] [--decoder-state F] [--examples a,b] [--persons N]
"""
from __future__ import annotations

import argparse
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--corpus", help="corpus directory (default: the standard preset's)")
    ap.add_argument("--checkpoint", help="default: the shipped model")
    ap.add_argument("--bank", help="default: the shipped bank")
    ap.add_argument("--decoder-state", help="decoder v2 state dict (torch.save) to use instead of the checkpoint's")
    ap.add_argument("--split", default="val", choices=("test", "val"))
    ap.add_argument("--persons", type=int, default=0, help="only the first N bind persons of the split (0: all)")
    ap.add_argument("--examples", default="", help="comma-separated example names (default: all)")
    ap.add_argument("--sources", type=int, default=1, help="each of the first N persons makes the example pair in "
                    "turn (judged on all the others); the table gives the mean over them")
    args = ap.parse_args()
    import numpy as np
    import torch

    from latent_model.analysis.decoder_eval import Characters, example_transfer
    from latent_model.config import default_corpus_dir
    from latent_model.corpus.examples import EXAMPLES
    from latent_model.corpus.states import StateGenerator
    from latent_model.corpus.store import Corpus
    from latent_model.shipped import ShippedPaths
    from latent_model.transfer import Transfer

    paths = ShippedPaths.at()
    transfer = Transfer.from_files(args.checkpoint or paths.checkpoint, args.bank or paths.bank)
    if args.decoder_state:
        state = torch.load(args.decoder_state)
        if float(state["delta_scale"]) == 1.0:  # saved by a pilot before it stored the scale: the shipped one's
            state["delta_scale"] = transfer.model.motion_decoder.delta_scale.clone()
        transfer.model.motion_decoder.load_state_dict(state)
    c = Corpus(args.corpus or default_corpus_dir("standard"))
    bind = [i for i in c.split_indices(args.split) if c.identities[i].rest == "bind"]
    if args.persons:
        bind = bind[:args.persons]
    names = args.examples.split(",") if args.examples else list(EXAMPLES)
    t0 = time.perf_counter()
    chars, gen = Characters(transfer, c), StateGenerator()
    runs = [example_transfer(transfer, chars, bind[k:] + bind[:k], gen, names) for k in range(args.sources)]
    m = {k: (v if isinstance(v, str) else float(np.mean([r[k] for r in runs]))) for k, v in runs[0].items()}
    print(f"{args.split}: examples made on {', '.join(c.identities[i].id for i in bind[:args.sources])} in turn, "
          f"each judged on the {len(bind) - 1} others ({time.perf_counter() - t0:.0f} s)")
    print(f"{'example':32s} {'kind':12s} explained  leak mm  strain %")
    for n in names:
        p = f"decoder.examples.{n}"
        print(f"{n:32s} {m[p + '.kind']:12s} {m[p + '.explained']:9.2f} {m[p + '.leak_mm']:8.2f} "
              f"{m[p + '.strain']:9.1f}")


if __name__ == "__main__":
    main()
