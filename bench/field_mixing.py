"""How the prototype fields are fitted and mixed decides `neutral_to_pose` transfer (the fields
alone predict it at inference). From a checkpoint's encoder, refit the fields with each pair at its
own latent amount (`vd_fit_scaled` on) and at amount 1 (off), and predict every held-out identity's
broad body poses through the Transfer API at several prototype temperatures, with the mean and the
nearest-identity delta. Prints explained motion / static leakage (mm) per pose; never asserts.

    python bench/field_mixing.py [--checkpoint M --bank B] [--temperatures 0.003,0.001]

About 5 minutes in all on 2 cores (encoding the training states, two fits, 14 x 12 x 2 predictions
per fit and temperature); on the shipped model it reproduces the README table "fields: fit / mixing".
"""
from __future__ import annotations

import argparse
import dataclasses
import json

import numpy as np

BODY = ("elbowBentLf", "elbowBentRt", "elbowSuperBentLf", "elbowSuperBentRt", "kneeBentLf", "kneeBentRt",
        "clavicleDownwardLf", "clavicleDownwardRt", "shoulderRaiseLf", "shoulderRaiseRt", "shoulderForwardLf",
        "shoulderForwardRt")
STRATEGIES = {"mean": "mean_pose_delta", "nearest": "nearest_identity_delta"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", help="model.safetensors (default: the shipped model)")
    ap.add_argument("--bank", help="its latent bank (default: the shipped bank)")
    ap.add_argument("--temperatures", default="0.003,0.001")
    ap.add_argument("--poses", default=",".join(BODY))
    args = ap.parse_args()
    from latent_model.analysis.metrics import mesh_errors
    from latent_model.bank import encode_states
    from latent_model.config import Preset, default_corpus_dir
    from latent_model.corpus.store import Corpus
    from latent_model.shipped import ShippedPaths
    from latent_model.train.checkpoint import read_metadata
    from latent_model.train.closed_form import fit_prototype_fields
    from latent_model.train.phases import field_fit_seed, phase_b_inputs
    from latent_model.transfer import Transfer

    paths = ShippedPaths.at()
    ckpt, bank = args.checkpoint or paths.checkpoint, args.bank or paths.bank
    tr = Transfer.from_files(ckpt, bank)
    preset = Preset.from_dict(json.loads(read_metadata(ckpt)["preset"]))
    c = Corpus(default_corpus_dir(preset.corpus.preset))
    vd = tr.model.vertex_decoder
    sampler, mu_rows = phase_b_inputs(tr.model, preset, c, tr.device, progress=False)  # as train_phase_b
    test = c.split_indices("test")
    sources = {i: c.state(i, None, "neutral") for i in test}
    mus = dict(zip(test, encode_states(tr.model, c, list(sources.values()), tr.device)))
    poses = args.poses.split(",")
    temps = [float(t) for t in args.temperatures.split(",")]
    for scaled in (True, False):
        vd.cfg = dataclasses.replace(vd.cfg, vd_fit_scaled=scaled)
        fit_prototype_fields(vd, sampler, c, mu_rows, field_fit_seed(preset), progress=False)
        for temp in temps:
            vd.cfg = dataclasses.replace(vd.cfg, vd_proto_temp=temp)
            res: dict[tuple[str, str], list[tuple[float, float]]] = {}
            for i in test:
                v = c.vertices(sources[i])
                mesh = tr.prepare(v, c.faces, sdf_faces=c.body_faces, mu=mus[i])
                for pose in poses:
                    truth = c.vertices(c.state(i, pose, "skinning_plus_blendshape"))
                    for name, strategy in STRATEGIES.items():
                        e = mesh_errors(tr.predict(mesh, pose, strategy), truth, v)
                        res.setdefault((pose, name), []).append((e["explained"], e["leak_mm"]))
            print(f"fit {'scaled' if scaled else 'unscaled'}, temperature {temp:g} "
                  f"(explained / leak mm over {len(test)} held-out identities)", flush=True)
            for pose in poses:
                cells = "   ".join(f"{name} {np.mean([a for a, _ in res[(pose, name)]]):.3f} / "
                                   f"{np.mean([b for _, b in res[(pose, name)]]):.2f}" for name in STRATEGIES)
                print(f"  {pose:20s} {cells}", flush=True)


if __name__ == "__main__":
    main()
