"""Look at a motion-decoder prediction close up: source / prediction / truth of one validation character,
cropped to what moves, coloured by the per-vertex error, with explained motion, leak and edge strain; and
the blend pose A -> pose B in 0.05 steps (largest step / median step, each region's motion at 0.5).

    python bench/motion_closeup.py --decoder pilot.pt [--checkpoint ENC] [--rest armsUp35] \
        [--pose elbowBentLf] [--pose-b kneeBentLf] [-o closeup.png]

`--decoder` is a state dict written by `bench/motion_pilot.py --save` (or a checkpoint with a motion decoder).
"""
from __future__ import annotations

import argparse

import numpy as np
import torch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--decoder", required=True)
    ap.add_argument("--checkpoint", help="encoder checkpoint (default: the shipped model)")
    ap.add_argument("--corpus")
    ap.add_argument("--rest", default="armsUp35")
    ap.add_argument("--pose", default="elbowBentLf")
    ap.add_argument("--pose-b", default="kneeBentLf")
    ap.add_argument("--magnitude", type=float, default=1.0)
    ap.add_argument("--truth-pose", help="the truth to compare with (default: --pose), e.g. elbowSuperBentLf at magnitude 2")
    ap.add_argument("-o", "--output", default="closeup.png")
    args = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from latent_model.analysis.metrics import edge_strain, mesh_errors
    from latent_model.checkpoint import load_checkpoint
    from latent_model.config import data_root, default_corpus_dir
    from latent_model.corpus.store import Corpus
    from latent_model.nn.motion_decoder import N_COORD_FREQ, MotionDecoder
    from latent_model.render import draw_mesh
    from latent_model.shipped import ShippedPaths
    from latent_model.train.motion import CharacterCache, DeltaTable, pair_inputs, predict
    from latent_model.types import FINAL, PAIR_KINDS

    torch.set_num_threads(2)
    c = Corpus(args.corpus or default_corpus_dir("standard"))
    model, _, _ = load_checkpoint(args.checkpoint or ShippedPaths.at().checkpoint)
    model.eval()
    state = torch.load(args.decoder, map_location="cpu")
    state = {k.removeprefix("motion_decoder."): v for k, v in state.items() if not k.startswith(("encoder.", "sdf"))}
    hidden = state["inp.weight"].shape[0]
    dec = MotionDecoder(model.cfg.latent, len(PAIR_KINDS), hidden=hidden, cond=state["cond.0.weight"].shape[0],
                        layers=sum(k.startswith("hidden.") and k.endswith(".weight") for k in state),
                        world=state["out.weight"].shape[0] == 15, mu_dims=state["mu_basis"].shape[0],
                        local_inputs=state["inp.weight"].shape[1] > 6 + 12 * N_COORD_FREQ)
    dec.load_state_dict(state)
    dec.eval()
    train = c.split_indices("train")
    i = c.split_indices("val", rest=args.rest)[0]
    truth_pose = args.truth_pose or args.pose
    table = DeltaTable(model, c, train + [i], train, tuple(dict.fromkeys((args.pose, args.pose_b, truth_pose))),
                       torch.device("cpu"))
    cache = CharacterCache(c, data_root() / "cache" / "surface")
    v = cache.get(i)[0]

    def run(delta: np.ndarray, magnitude: float = 1.0) -> np.ndarray:
        x = pair_inputs(cache, table, i, args.pose, delta)
        x["r"] = np.float32(x["r"] * magnitude)
        return predict(dec, x)

    pred = run(table.mean[args.pose], args.magnitude)
    truth = c.vertices(c.state(i, truth_pose, FINAL))
    e = mesh_errors(pred, truth, v)
    strain = edge_strain(pred, truth, v, c.faces)
    print(f"{c.identities[i].id} in {args.rest}, {args.pose} x{args.magnitude:g} vs {truth_pose}: explained "
          f"{e['explained']:.3f}, leak {e['leak_mm']:.2f} mm, moving-region error {e['err_moving_mm']:.1f} mm, "
          f"edge strain {strain:.1f} % (the source's: {edge_strain(v, truth, v, c.faces):.1f} %)")
    # blend A -> B
    steps = [run((1 - b) * table.mean[args.pose] + b * table.mean[args.pose_b]) for b in np.linspace(0, 1, 21)]
    moves = np.array([np.linalg.norm(b - a, axis=1).max() for a, b in zip(steps, steps[1:])]) * 1000
    ta, tb = (c.vertices(c.state(i, p, FINAL)) for p in (args.pose, args.pose_b))
    frac = []
    for t in (ta, tb):
        reg = np.linalg.norm(t - v, axis=1) > 0.01
        d = (t - v)[reg]
        frac.append(float(((steps[10] - v)[reg] * d).sum() / (d * d).sum()))
    print(f"blend {args.pose} -> {args.pose_b}: largest step {moves.max():.1f} mm = {moves.max() / np.median(moves):.2f}x "
          f"the median step; at 0.5 the two regions move {frac[0]:.2f} and {frac[1]:.2f} of their truth")
    # the close-up
    moving = np.linalg.norm(truth - v, axis=1) > 0.005
    pts = np.concatenate([v[moving], truth[moving], pred[moving]])
    lo, hi = pts.min(axis=0) - 0.05, pts.max(axis=0) + 0.05
    err = np.linalg.norm(pred - truth, axis=1) * 1000
    fig, axes = plt.subplots(1, 3, figsize=(13, 5.5))
    for ax, (title, verts, values) in zip(axes, (("source", v, None), ("prediction (error, mm)", pred, err),
                                                 ("truth", truth, None))):
        draw_mesh(ax, verts, c.faces, "front", values=values, cmap="magma", vmin=0, vmax=30)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[2], hi[2])
        ax.set_title(title)
    fig.suptitle(f"{c.identities[i].id} ({args.rest}), {args.pose} x{args.magnitude:g}, mean delta: explained "
                 f"{e['explained']:.2f}, leak {e['leak_mm']:.2f} mm, edge strain {strain:.1f} %")
    fig.tight_layout()
    fig.savefig(args.output, dpi=110)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
