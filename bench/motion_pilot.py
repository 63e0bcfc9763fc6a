"""Pilot of the motion decoder (decoder v2) on a corpus: trains it on the training characters'
neutral -> pose pairs with a frozen encoder (default: the shipped model's), and prints the validation
characters' explained motion / static leakage per rest, mean delta, for the broad body poses.

    python bench/motion_pilot.py [--corpus DIR] [--checkpoint C] [--steps 1500] [--poses all|broad]
"""
from __future__ import annotations

import argparse
import pickle
import time
from pathlib import Path

import numpy as np
import torch

BROAD = ("elbowBentLf", "elbowBentRt", "kneeBentLf", "kneeBentRt", "clavicleDownwardLf", "shoulderRaiseLf",
         "shoulderForwardRt", "hipFlexLf", "wristFlexLf", "spineTwistLf", "neckTurnLf", "spineBendFw")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--corpus")
    ap.add_argument("--checkpoint")
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--vertices", type=int, default=1024)
    ap.add_argument("--hidden", type=int, default=128)
    ap.add_argument("--train-persons", type=int, default=0, help="0: all")
    ap.add_argument("--poses", default="body", help="body: every single body pose; broad: the 12 evaluated; "
                    "shipped: the config's (body singles and their combos); all: every corpus pose")
    ap.add_argument("--world", action="store_true", help="also world-axis rotation and translation outputs")
    ap.add_argument("--mu-dims", type=int, default=8, help="principal components of mu_src read (0: none)")
    ap.add_argument("--mu-noise", type=float, default=1.0)
    ap.add_argument("--no-local", action="store_true", help="no normal / medial-offset inputs")
    ap.add_argument("--limb-direction", action="store_true", help="also the limb's axis in body axes as an input")
    ap.add_argument("--edge", type=float, default=None, help="weight of the neighbour term (default: the config's)")
    ap.add_argument("--smooth", default="0", help="comma-separated smoothing iterations of the motion at inference, "
                    "each reported in the final table")
    ap.add_argument("--mean-prob", type=float, default=None, help="probability of training on the pose's mean delta")
    ap.add_argument("--other-prob", type=float, default=None,
                    help="probability of training on another training character's delta of the pose")
    ap.add_argument("--world-penalty", type=float, default=0.0, help="weight of the world-axis outputs' size")
    ap.add_argument("--translation", type=float, default=0.0, help="weight of the translation length in the loss")
    ap.add_argument("--delta-dims", type=int, default=0, help="principal components of the delta direction read (0: all)")
    ap.add_argument("--delta-noise", type=float, default=0.0)
    ap.add_argument("--rigid", default="0", help="comma-separated 0/1: without / with rigid hands and feet at "
                    "inference (part_rigidifier), each reported")
    ap.add_argument("--repivot", default="0", help="comma-separated dampings of absorb_translation at inference "
                    "(0: off), each reported")
    ap.add_argument("--bank", help="the face and finger poses' mean deltas from this bank (default: the shipped; "
                    "give the checkpoint's own)")
    ap.add_argument("--extra-rests", type=int, default=0, help="each training person also in this many random "
                    "rests within the training rests' ranges (train/rest_augment.py)")
    ap.add_argument("--drawn-cache", help="keep the drawn characters in this pickle (and reuse them when present: same "
                    "corpus, encoder, poses and --extra-rests only)")
    ap.add_argument("--extra-combos", type=int, default=0,
                    help="each training character also posed in some of this many drawn combinations of 2-3 single "
                         "body poses (train/combo_augment.py)")
    ap.add_argument("--combos-per-character", type=int, default=8)
    ap.add_argument("--combo-sizes", default="2,3", help="poses per drawn combination (1: a single pose)")
    ap.add_argument("--combo-odds", default="", help="how often each size is drawn (default: combo_augment's, for 2,3)")
    ap.add_argument("--combo-amplitude", default="", help="lowest,highest: each pose's angles scaled by a drawn factor")
    ap.add_argument("--combos-cache", help="keep the drawn combinations' states in this pickle (and reuse them when "
                    "present: same corpus, encoder and --extra-combos / --combos-per-character only)")
    ap.add_argument("--load", help="evaluate this saved decoder state instead of training one")
    ap.add_argument("--save", help="write the decoder's state dict here")
    args = ap.parse_args()
    from latent_model.analysis.metrics import edge_strain, mesh_errors
    from latent_model.checkpoint import load_checkpoint
    from latent_model.config import default_corpus_dir
    from latent_model.corpus.poses import POSES
    from latent_model.corpus.store import Corpus
    from latent_model.nn.motion_decoder import MotionDecoder, part_rigidifier, surface_smoother
    from latent_model.shipped import ShippedPaths
    from latent_model.config import MotionDecoderConfig
    from latent_model.train.motion import (CharacterCache, DeltaTable, pair_inputs, predict, train_motion_decoder,
                                          training_poses)
    from latent_model.types import FINAL, PAIR_KINDS

    torch.set_num_threads(2)
    c = Corpus(args.corpus or default_corpus_dir("standard"))
    model, _, _ = load_checkpoint(args.checkpoint or ShippedPaths.at().checkpoint)
    model.eval()
    broad = tuple(p for p in BROAD if p in c.poses)
    poses = broad if args.poses == "broad" else training_poses(c, "body") if args.poses == "shipped" else tuple(
        c.poses) if args.poses == "all" else tuple(p for p in c.poses if POSES[p].group == "body" and not POSES[p].is_combo)
    train = c.split_indices("train")
    if args.train_persons:
        keep = list(dict.fromkeys(c.identities[i].person_id for i in train))[:args.train_persons]
        train = [i for i in train if c.identities[i].person_id in keep]
    val = c.split_indices("val")
    t = time.perf_counter()
    table = DeltaTable(model, c, train + val, train, poses, torch.device("cpu"))
    # face and finger poses: their mean deltas from the shipped bank (the same encoder when --checkpoint is the shipped)
    from latent_model.bank import LatentBank

    bank = LatentBank.load(args.bank or ShippedPaths.at().bank)
    local = {p: bank.mean_delta("neutral_to_pose", p) for p in c.poses
             if not POSES[p].is_combo and POSES[p].group in ("face", "finger")}
    from latent_model.config import data_root

    cache = CharacterCache(c, data_root() / "cache" / "surface")
    for i in train + val:
        cache.get(i)
    print(f"{len(train)} training / {len(val)} validation characters, {len(poses)} poses; "
          f"encoding + surface features {time.perf_counter() - t:.0f} s")
    drawn = None
    if args.extra_rests and not args.load:
        from latent_model.train.rest_augment import extra_characters

        drawn = _load_drawn(args.drawn_cache) if args.drawn_cache and Path(args.drawn_cache).exists() else None
        if drawn is None or len(drawn.ids) != args.extra_rests * len(set(drawn.person)):
            drawn = extra_characters(model, c, train, poses, args.extra_rests, seed=0, device=torch.device("cpu"))
            if args.drawn_cache:
                _save_drawn(args.drawn_cache, drawn)
        cache.add(drawn)
        table.add(drawn)
    combos = None
    if args.extra_combos and not args.load:
        from latent_model.train.combo_augment import SIZE_ODDS, extra_combinations

        combos = _load_drawn(args.combos_cache) if args.combos_cache and Path(args.combos_cache).exists() else None
        if combos is None:
            singles = tuple(p for p in poses if not POSES[p].is_combo)
            sizes = [int(x) for x in args.combo_sizes.split(",")]
            odds = [float(x) for x in args.combo_odds.split(",")] if args.combo_odds else SIZE_ODDS
            amplitude = tuple(float(x) for x in args.combo_amplitude.split(",")) if args.combo_amplitude else None
            combos = extra_combinations(model, c, train, singles, args.extra_combos, args.combos_per_character,
                                        seed=0, device=torch.device("cpu"), sizes=sizes, odds=odds,
                                        amplitude=amplitude)
            if args.combos_cache:
                _save_drawn(args.combos_cache, combos)
        table.add_poses(combos)
        print(f"{len(combos.poses)} drawn combinations, {len(combos.pairs)} pairs")
    fitted = train + (drawn.ids if drawn else [])
    decoder = MotionDecoder(model.cfg.latent, len(PAIR_KINDS), hidden=args.hidden, world=args.world,
                            mu_dims=args.mu_dims, mu_noise=args.mu_noise, local_inputs=not args.no_local,
                            delta_dims=args.delta_dims, delta_noise=args.delta_noise,
                            limb_direction=args.limb_direction)
    decoder.delta_scale.fill_(table.scale)  # what Transfer divides a delta's length by (pair_inputs does it here)
    decoder.set_mu_basis(torch.from_numpy(np.stack([table.mu_neutral[i] for i in fitted])).float())
    decoder.set_delta_basis(torch.from_numpy(table.directions(fitted, poses)).float())

    def validate(dec) -> dict:
        out: dict[str, list] = {}
        for i in val:
            v = cache.get(i)[0]
            for p in broad:
                pred = predict(dec, pair_inputs(cache, table, i, p, table.mean[p]))
                e = mesh_errors(pred, c.vertices(c.state(i, p, FINAL)), v)
                group = "bind" if c.identities[i].rest == "bind" else "val rests"
                out.setdefault(group, []).append((e["explained"], e["leak_mm"]))
        return {g: f"{np.mean([x[0] for x in r]):.3f} / {np.mean([x[1] for x in r]):.2f} mm" for g, r in out.items()}

    extra = {"translation": args.translation, "world_penalty": args.world_penalty, **({} if args.edge is None else {"edge": args.edge}),
             **({} if args.mean_prob is None else {"mean_prob": args.mean_prob}),
             **({} if args.other_prob is None else {"other_prob": args.other_prob})}
    cfg = MotionDecoderConfig(steps=args.steps, batch=args.batch, vertices=args.vertices, **extra)
    t = time.perf_counter()
    if args.load:
        decoder.load_state_dict(torch.load(args.load))
    else:
        train_motion_decoder(decoder, c, cache, table, train, poses, cfg, seed=0, validate=validate,
                             validate_every=max(args.steps // 3, 1), extra=drawn, extra_poses=combos)
        print(f"trained {args.steps} steps in {time.perf_counter() - t:.0f} s")
    n_v = len(cache.get(val[0])[0])
    rigidifiers: dict[int, object] = {}

    def rigid_of(i: int):
        if i not in rigidifiers:
            rigidifiers[i] = part_rigidifier(cache.get(i)[2].coords)
        return rigidifiers[i] if use_rigid else None

    for it, use_rigid, rp in ((int(x), bool(int(y)), float(z)) for x in args.smooth.split(",")
                              for y in args.rigid.split(",") for z in args.repivot.split(",")):
        smooth = surface_smoother(c.faces, n_v, it)
        print(f"smoothing {it}, rigid hands and feet {use_rigid}, repivot {rp:g}: {'pose':20s} {'bind: explained / leak mm / strain %':>36s} {'val rests':>24s}"
              f" {'own delta, bind':>16s}")
        allc: dict[str, list] = {}
        for p in broad:
            cells = {}
            for i in val:
                v = cache.get(i)[0]
                pred = predict(decoder, pair_inputs(cache, table, i, p, table.mean[p]), smooth, rigid_of(i), rp)
                truth = c.vertices(c.state(i, p, FINAL))
                e = {**mesh_errors(pred, truth, v), "strain": edge_strain(pred, truth, v, c.faces)}
                g = "bind" if c.identities[i].rest == "bind" else "rest"
                cells.setdefault(g, []).append(e)
                allc.setdefault(g, []).append(e)
            mine = [mesh_errors(predict(decoder, pair_inputs(cache, table, i, p, table.delta[(i, p)]), smooth, rigid_of(i), rp),
                                c.vertices(c.state(i, p, FINAL)), cache.get(i)[0])["explained"]
                    for i in val if c.identities[i].rest == "bind"]
            print(f"{p:20s}" + "".join(f" {np.mean([e['explained'] for e in cells[g]]):7.2f} / "
                                       f"{np.mean([e['leak_mm'] for e in cells[g]]):5.2f} / "
                                       f"{np.mean([e['strain'] for e in cells[g]]):5.1f}" for g in ("bind", "rest"))
                  + f" {np.mean(mine):10.2f}")
        print(f"{'mean':20s}" + "".join(f" {np.mean([e['explained'] for e in allc[g]]):7.3f} / "
                                        f"{np.mean([e['leak_mm'] for e in allc[g]]):5.2f} / "
                                        f"{np.mean([e['strain'] for e in allc[g]]):5.1f}" for g in ("bind", "rest")))
        # the character's own delta (the oracle; nearest and example pairs are single deltas too)
        own: dict[str, list] = {}
        for p in broad:
            for i in val:
                v = cache.get(i)[0]
                pred = predict(decoder, pair_inputs(cache, table, i, p, table.delta[(i, p)]), smooth, rigid_of(i), rp)
                e = mesh_errors(pred, c.vertices(c.state(i, p, FINAL)), v)
                own.setdefault("bind" if c.identities[i].rest == "bind" else "rest", []).append(e)
        print(f"{'own delta (oracle)':20s}" + "".join(f" {np.mean([e['explained'] for e in own[g]]):7.3f} / "
                                                     f"{np.mean([e['leak_mm'] for e in own[g]]):5.2f}" for g in ("bind", "rest")))
        # face and finger poses, mean delta, ungated (the Transfer gates them; these say what would pass)
        loc: dict[str, list] = {}
        for p in local:
            for i in val[::4]:
                v = cache.get(i)[0]
                pred = predict(decoder, pair_inputs(cache, table, i, p, local[p]), smooth, rigid_of(i), rp)
                loc.setdefault(POSES[p].group, []).append(mesh_errors(pred, c.vertices(c.state(i, p, FINAL)), v))
        print("face / finger poses, mean delta, ungated: " + ", ".join(
            f"{g} {np.mean([e['explained'] for e in r]):.3f} / {np.mean([e['leak_mm'] for e in r]):.2f} mm"
            for g, r in loc.items()))
        # magnitudes: twice the 47 degree elbow against the rig's 97 degrees, half of the 97 against the 47
        if "elbowSuperBentLf" in c.poses and "elbowBentLf" in c.poses:
            for pose, m, truth_pose in (("elbowBentLf", 2.0, "elbowSuperBentLf"), ("elbowSuperBentLf", 0.5, "elbowBentLf")):
                rows = []
                for i in val:
                    v = cache.get(i)[0]
                    x = pair_inputs(cache, table, i, pose, table.mean[pose])
                    truth = c.vertices(c.state(i, truth_pose, FINAL))
                    pred = predict(decoder, x, smooth, rigid_of(i), rp, magnitude=m)
                    rows.append({**mesh_errors(pred, truth, v), "strain": edge_strain(pred, truth, v, c.faces)})
                print(f"{pose} x{m:g} vs {truth_pose}: explained {np.mean([e['explained'] for e in rows]):.3f}, "
                      f"leak {np.mean([e['leak_mm'] for e in rows]):.2f} mm, strain {np.mean([e['strain'] for e in rows]):.1f} %")
    if args.save:
        torch.save(decoder.state_dict(), args.save)


def _save_drawn(path: str, drawn) -> None:
    with open(path, "wb") as f:
        pickle.dump(drawn, f, protocol=pickle.HIGHEST_PROTOCOL)


def _load_drawn(path: str):
    with open(path, "rb") as f:
        return pickle.load(f)


if __name__ == "__main__":
    main()
