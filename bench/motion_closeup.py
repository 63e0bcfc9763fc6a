"""Look at a prediction close up, through the Transfer API: source / prediction / truth of one held-out
character, cropped to what moves, coloured by the per-vertex error, with explained motion, leak and edge
strain; and the blend pose A -> pose B in 0.05 steps (largest step / median step, each region at 0.5).

    python bench/motion_closeup.py --checkpoint RUN/model.safetensors --bank RUN/bank.safetensors \
        [--split val] [--rest armsUp35] [--pose elbowBentLf] [--magnitude 1] [--truth-pose P] \
        [--pose-b kneeBentLf] [--strategy mean_pose_delta] [--motion KEY=VALUE ...] [-o closeup.png]
"""
from __future__ import annotations

import argparse

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--bank", required=True)
    ap.add_argument("--corpus")
    ap.add_argument("--split", default="val", help="val (design choices) or test")
    ap.add_argument("--rest", default="armsUp35")
    ap.add_argument("--character", type=int, default=0, help="which character of the split and rest")
    ap.add_argument("--pose", default="elbowBentLf")
    ap.add_argument("--pose-b", default="kneeBentLf")
    ap.add_argument("--kind", default="neutral_to_pose", help="the pair kind (its source: the pair's source state)")
    ap.add_argument("--strategy", default="mean_pose_delta")
    ap.add_argument("--magnitude", type=float, default=1.0)
    ap.add_argument("--truth-pose", help="the truth to compare with (default: --pose), e.g. elbowSuperBentLf at 2")
    ap.add_argument("--view", default="front")
    ap.add_argument("--rigid-parts", choices=("config", "on", "off"), default="config",
                    help="hands and feet as rigid parts: as the checkpoint's config says, or forced on / off")
    ap.add_argument("--repivot", type=float, help="absorb_translation's damping at inference (default: the config's)")
    ap.add_argument("--motion", action="append", default=[], metavar="KEY=VALUE",
                    help="any other MotionDecoderConfig inference option, e.g. rigid_anchor=0, rigid_prior=3")
    ap.add_argument("-o", "--output", default="closeup.png")
    args = ap.parse_args()
    import matplotlib
    import torch

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from latent_model.analysis.decoder_eval import Characters, region_fraction
    from latent_model.analysis.metrics import edge_strain, mesh_errors
    from latent_model.config import default_corpus_dir
    from latent_model.corpus.store import Corpus
    from latent_model.render import VIEWS, draw_mesh
    from latent_model.transfer import Transfer

    torch.set_num_threads(2)
    t = Transfer.from_files(args.checkpoint, args.bank)
    import dataclasses

    motion = t.model.cfg.motion
    if args.rigid_parts != "config":
        motion = dataclasses.replace(motion, rigid_parts=args.rigid_parts == "on")
    if args.repivot is not None:
        motion = dataclasses.replace(motion, repivot=args.repivot)
    for item in args.motion:
        key, _, value = item.partition("=")
        if not hasattr(motion, key) or not value:
            raise SystemExit(f"--motion {item!r}: use KEY=VALUE with a MotionDecoderConfig field")
        kind = type(getattr(motion, key))
        motion = dataclasses.replace(motion, **{key: value.lower() in ("1", "true", "on") if kind is bool else kind(value)})
    t.model.cfg = dataclasses.replace(t.model.cfg, motion=motion)
    c = Corpus(args.corpus or default_corpus_dir("standard"))
    chars = Characters(t, c)
    i = c.split_indices(args.split, rest=args.rest)[args.character]
    from latent_model.corpus.pairs import pair_states

    (src_pose, src_variant), (_, target_variant) = pair_states(args.kind, args.pose)
    mesh = chars.neutral(i) if src_pose is None else t.prepare(c.vertices(c.state(i, src_pose, src_variant)), c.faces,
                                                                sdf_faces=c.body_faces)
    v = mesh.vertices
    out = t.predict_detail(mesh, args.pose, args.strategy, magnitude=args.magnitude, kind=args.kind)
    pred = out.vertices
    truth = c.vertices(c.state(i, args.truth_pose or args.pose, target_variant))
    e = mesh_errors(pred, truth, v)
    strain = edge_strain(pred, truth, v, c.faces)
    rigid = (", rigid hands and feet" if motion.rigid_parts else "") + (f", repivot {motion.repivot:g}" if motion.repivot else "")
    kind = "" if args.kind == "neutral_to_pose" else f" {args.kind}"
    name = f"{c.identities[i].id} ({args.rest}),{kind} {args.pose} x{args.magnitude:g} [{out.label}, {out.predictor}{rigid}]"
    print(f"{name} vs {args.truth_pose or args.pose}: explained {e['explained']:.3f}, leak {e['leak_mm']:.2f} mm, "
          f"moving-region error {e['err_moving_mm']:.1f} mm, edge strain {strain:.1f} % "
          f"(the source's: {edge_strain(v, truth, v, c.faces):.1f} %)")
    sweep = [t.predict(mesh, args.pose, args.strategy, kind=args.kind, pose_b=args.pose_b, blend=float(b))
             for b in np.linspace(0, 1, 21)]
    moves = np.array([np.linalg.norm(b - a, axis=1).max() for a, b in zip(sweep, sweep[1:])]) * 1000
    fa, fb = (region_fraction(sweep[10], c.vertices(c.state(i, p, target_variant)), v) for p in (args.pose, args.pose_b))
    print(f"blend {args.pose} -> {args.pose_b}: largest step {moves.max():.1f} mm = {moves.max() / np.median(moves):.2f}x "
          f"the median step; at 0.5 the regions move {fa:.2f} and {fb:.2f} of their truth")
    right, up = (np.asarray(a, dtype=np.float64) for a in VIEWS[args.view])
    moving = np.linalg.norm(truth - v, axis=1) > 0.005
    pts = np.concatenate([v[moving], truth[moving], pred[moving]])
    x, y = pts @ right, pts @ up
    err = np.linalg.norm(pred - truth, axis=1) * 1000
    fig, axes = plt.subplots(1, 3, figsize=(13, 5.5))
    for ax, (title, verts, values) in zip(axes, (("source", v, None), ("prediction (error, 0-30 mm)", pred, err),
                                                 ("truth", truth, None))):
        draw_mesh(ax, verts, c.faces, args.view, values=values, cmap="magma", vmin=0, vmax=30)
        ax.set_xlim(x.min() - 0.05, x.max() + 0.05)
        ax.set_ylim(y.min() - 0.05, y.max() + 0.05)
        ax.set_title(title)
    fig.suptitle(f"{name}: explained {e['explained']:.2f}, leak {e['leak_mm']:.2f} mm, edge strain {strain:.1f} %")
    fig.tight_layout()
    fig.savefig(args.output, dpi=110)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
