"""Rigid hands and feet on the validation characters, through the Transfer API: for each prior of the part's turn
(`MotionDecoderConfig.rigid_prior` / `rigid_anchor`), the broad body poses with the mean delta (explained, leak,
edge strain; bind and the validation rests), the angle between each moving hand or foot core's predicted and true
turn, and elbowBentLf x2 against the rig's 97 degrees (explained, strain, the left hand's own edge strain: a rigid
hand keeps its edges).

    python bench/rigid_parts.py [--checkpoint C] [--bank B] [--corpus DIR] [--priors 1:0.06,1:0,0:0]

A prior is WEIGHT:ANCHOR (anchor 0: the decoder's mean rotation vector; > 0: the limb band's turn).
"""
from __future__ import annotations

import argparse
import dataclasses

import numpy as np


def kabsch(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(n, 3), (n, 3) -> the rotation best mapping x onto y (centred)."""
    u, _, vt = np.linalg.svd((x - x.mean(0)).T @ (y - y.mean(0)))
    return vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))]) @ u.T


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint")
    ap.add_argument("--bank")
    ap.add_argument("--corpus")
    ap.add_argument("--priors", default="1:0.06,1:0,0:0")
    args = ap.parse_args()
    import torch
    from scipy.spatial.transform import Rotation

    from latent_model.analysis.decoder_eval import BROAD, Characters, _errors
    from latent_model.config import default_corpus_dir
    from latent_model.corpus.store import Corpus
    from latent_model.nn.motion_decoder import RIGID_PARTS
    from latent_model.shipped import ShippedPaths
    from latent_model.transfer import Transfer

    torch.set_num_threads(2)
    paths = ShippedPaths.at()
    t = Transfer.from_files(args.checkpoint or paths.checkpoint, args.bank or paths.bank)
    c = Corpus(args.corpus or default_corpus_dir("standard"))
    f = c.faces
    edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    base = t.model.cfg
    for item in args.priors.split(","):
        weight, anchor = (float(x) for x in item.split(":"))
        t.model.cfg = dataclasses.replace(base, motion=dataclasses.replace(base.motion, rigid_prior=weight,
                                                                           rigid_anchor=anchor))
        chars = Characters(t, c)  # fresh meshes: their caches hold the options' rigidifiers
        rows: dict[str, list[dict]] = {"bind": [], "validation rests": []}
        turn_errors, x2 = [], []
        for i in c.split_indices("val"):
            mesh = chars.neutral(i)
            g, x = mesh.surface.coords, mesh.vertices
            for pose in BROAD:
                truth, pred = chars.truth(i, pose), t.predict(mesh, pose)
                rows["bind" if c.identities[i].rest == "bind" else "validation rests"].append(_errors(pred, truth, x, f))
                for col, core, _ in RIGID_PARTS.values():
                    part = g[:, col] < core
                    if np.linalg.norm(truth[part] - x[part], axis=1).max() > 0.005:
                        off = Rotation.from_matrix(kabsch(truth[part], pred[part]))
                        turn_errors.append(float(np.degrees(off.magnitude())))
            hand = g[:, 2] < RIGID_PARTS["hand_left"][1]
            he = edges[hand[edges[:, 0]] & hand[edges[:, 1]]]
            length = lambda v: np.linalg.norm(v[he[:, 0]] - v[he[:, 1]], axis=1)  # noqa: E731
            pred = t.predict(mesh, "elbowBentLf", magnitude=2.0)
            e = _errors(pred, chars.truth(i, "elbowSuperBentLf"), x, f)
            x2.append((e["explained"], e["strain"], float(np.abs(length(pred) - length(x)).sum() / length(x).sum() * 100)))
        print(f"== prior weight {weight:g}, anchor {anchor:g} ({len(c.split_indices('val'))} validation characters)")
        for name, r in rows.items():
            print(f"  {name}: explained {np.mean([q['explained'] for q in r]):.3f}, leak "
                  f"{np.mean([q['leak_mm'] for q in r]):.3f} mm, strain {np.mean([q['strain'] for q in r]):.1f} %")
        print(f"  moving hands and feet: turn error median {np.median(turn_errors):.1f} deg, mean {np.mean(turn_errors):.1f}")
        a = np.mean(x2, axis=0)
        print(f"  elbowBentLf x2 vs 97 degrees: explained {a[0]:.3f}, strain {a[1]:.1f} %, left hand's own strain {a[2]:.2f} %")


if __name__ == "__main__":
    main()
