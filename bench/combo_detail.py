"""What the local detail stage adds to `source_to_combo` keys whose combination adds face or finger poses only
(a brow from the other brow, a fist from a knuckle or a bent elbow), on held-out characters made through the rig
(no corpus needed), through the Transfer API.

    python bench/combo_detail.py [--split val] [--per-rest 2] [--variants added,added_unheld,...]

Reads each key these ways and prints explained motion / leak (mm) per region group, strategy and rest:
- ``added`` (what ships, `Transfer._detail_parts`): each added face or finger pose's own region deltas (a finger's
  knuckle turns compose, `RegionFields.chains`), added to the poses the source stands in (`Transfer._held`: the
  source placed on the anchor posed as it is);
- ``added_unheld``: the same, the source placed on the unposed anchor and the additions' fields alone;
- ``added_faces``: added face poses only (finger additions: no motion, as shipped before the turns composed);
- ``difference``: the combination's region deltas minus the component's, read as one delta.
With no detail the keys predict no motion (explained 0).
"""
from __future__ import annotations

import argparse
import re
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--split", default="val", choices=("val", "test"))
    ap.add_argument("--per-rest", type=int, default=2, help="characters per rest configuration")
    ap.add_argument("--variants", default="added,added_unheld,added_faces,difference")
    args = ap.parse_args()
    import numpy as np
    import torch

    from latent_model.analysis.metrics import mesh_errors
    from latent_model.analysis.report import _detail_transfer, detail_characters
    from latent_model.corpus.build import generator
    from latent_model.corpus.pairs import enumerate_pairs, split_bank_key
    from latent_model.corpus.poses import get_pose
    from latent_model.corpus.sdf import body_component_faces
    from latent_model.detail_poses import detail_regions_of
    from latent_model.shipped import ShippedPaths
    from latent_model.transfer import Transfer
    from latent_model.types import FINAL

    torch.set_num_threads(1)
    paths = ShippedPaths.at()
    transfer, preset = _detail_transfer(Path(paths.checkpoint), Path(paths.bank), None)
    keys = [p for p in enumerate_pairs([0], tuple(preset.corpus.pose_names()), ("source_to_combo",))
            if all(detail_regions_of(c) for c in get_pose(p.pose).components if c != p.component)]
    shipped, shipped_held = Transfer._detail_parts, Transfer.__dict__["_held"]  # the staticmethod itself

    def faces_only(self, key, kind, person):
        combo, comp = split_bank_key(kind, key)
        return [(self.detail.pose_deltas(c, person), 1.0) for c in get_pose(combo).components
                if c != comp and detail_regions_of(c) == ("head",)]

    def difference(self, key, kind, person):
        combo, comp = split_bank_key(kind, key)
        return [(self.detail.pose_deltas(combo, person), 1.0), (self.detail.pose_deltas(comp, person), -1.0)]

    unheld = staticmethod(lambda key, kind: ())
    variants = {"added": (shipped, shipped_held), "added_unheld": (shipped, unheld),
                "added_faces": (faces_only, shipped_held), "difference": (difference, shipped_held)}
    unknown = set(args.variants.split(",")) - set(variants)
    if unknown:
        raise SystemExit(f"--variants: unknown {sorted(unknown)}; choose from {sorted(variants)}")
    variants = {k: variants[k] for k in args.variants.split(",")}
    gen = generator()
    faces = np.asarray(gen.faces, np.int64)
    rows: dict[tuple, list] = {}
    t0 = time.time()
    specs = detail_characters(preset, args.split, args.per_rest)
    try:
        for spec in specs:
            sources = {}
            for p in keys:
                if p.component not in sources:
                    v = getattr(gen.pose(spec, p.component, spec.rest), FINAL).astype(np.float64)
                    sources[p.component] = (v, transfer.prepare(v, faces, body_component_faces(v, faces)))
                src, mesh = sources[p.component]
                truth = getattr(gen.pose(spec, p.pose, spec.rest), FINAL).astype(np.float64)
                group = "finger" if any(detail_regions_of(c) != ("head",) for c in get_pose(p.pose).components
                                        if c != p.component) else "face"
                if group == "finger":  # by the source's bent knuckle: 1 base, 2 middle, 3 tip ("finger0": a body pose)
                    level = re.match(r"fingerKnuckle[A-Z](\d+)", p.component)
                    group += str(int(level.group(1))) if level else "0"
                for name, (parts, held) in variants.items():
                    Transfer._detail_parts, Transfer._held = parts, held
                    for strategy in ("mean_pose_delta", "nearest_identity_delta"):
                        pred = transfer.predict(mesh, p.bank_key, strategy, kind="source_to_combo")
                        e = mesh_errors(pred.astype(np.float64), truth, src)
                        rows.setdefault((group, name, strategy.split("_")[0], spec.rest), []).append(
                            (e["explained"], e["leak_mm"]))
            print(f"{spec.id} ({spec.rest}): {time.time() - t0:.0f} s", flush=True)
    finally:
        Transfer._detail_parts, Transfer._held = shipped, shipped_held
    print(f"{len(keys)} keys, {len(specs)} {args.split} characters")
    print("group   variant        strategy rest        explained  leak mm  worst")
    for (group, name, strategy, rest), r in sorted(rows.items()):
        a = np.array(r)
        print(f"{group:7s} {name:14s} {strategy:8s} {rest:11s} {a[:, 0].mean():9.3f} {a[:, 1].mean():8.3f} "
              f"{a[:, 0].min():6.2f}")


if __name__ == "__main__":
    main()
