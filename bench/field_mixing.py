"""How the pose fields are mixed decides `neutral_to_pose` transfer (the fields alone predict it at
inference). From a checkpoint's encoder, refit the fields as Phase B does and predict every held-out
identity's broad body poses through the Transfer API at several prototype temperatures, with the mean
and the nearest-identity delta. Prints explained motion / static leakage (mm) per pose; never asserts.

    python bench/field_mixing.py [--checkpoint M --bank B] [--temperatures 0.003,0.001]

About 4 minutes on 2 cores (encoding the training states, the fit, 14 x 12 x 2 predictions per
temperature); on the shipped model it reproduces the "unscaled" rows of docs/history.md's
"fields: fit / mixing" table.
"""
from __future__ import annotations

import argparse
import dataclasses

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
    from latent_model.encoding import encode_states
    from latent_model.checkpoint import stored_preset
    from latent_model.config import default_corpus_dir
    from latent_model.corpus.store import Corpus
    from latent_model.shipped import ShippedPaths
    from latent_model.train.fit_pose_fields import fit_pose_fields
    from latent_model.train.phases import field_fit_seed, phase_b_inputs
    from latent_model.transfer import Transfer

    paths = ShippedPaths.at()
    ckpt, bank = args.checkpoint or paths.checkpoint, args.bank or paths.bank
    tr = Transfer.from_files(ckpt, bank)
    preset = stored_preset(ckpt)
    c = Corpus(default_corpus_dir(preset.corpus.preset))
    fields = tr.model.pose_fields
    sampler, mu_rows = phase_b_inputs(tr.model, preset, c, tr.device, progress=False)  # as train_phase_b
    test = c.split_indices("test")
    sources = {i: c.state(i, None, "neutral") for i in test}
    mus = dict(zip(test, encode_states(tr.model, c, list(sources.values()), tr.device)))
    poses = args.poses.split(",")
    temps = [float(t) for t in args.temperatures.split(",")]
    fit_pose_fields(fields, sampler, c, mu_rows, field_fit_seed(preset), progress=False)
    for temp in temps:
        fields.cfg = dataclasses.replace(fields.cfg, proto_temp=temp)
        res: dict[tuple[str, str], list[tuple[float, float]]] = {}
        for i in test:
            v = c.vertices(sources[i])
            mesh = tr.prepare(v, c.faces, sdf_faces=c.body_faces, mu=mus[i])
            for pose in poses:
                truth = c.vertices(c.state(i, pose, "skinning_plus_blendshape"))
                for name, strategy in STRATEGIES.items():
                    e = mesh_errors(tr.predict(mesh, pose, strategy), truth, v)
                    res.setdefault((pose, name), []).append((e["explained"], e["leak_mm"]))
        print(f"temperature {temp:g} "
              f"(explained / leak mm over {len(test)} held-out identities)", flush=True)
        for pose in poses:
            cells = "   ".join(f"{name} {np.mean([a for a, _ in res[(pose, name)]]):.3f} / "
                               f"{np.mean([b for _, b in res[(pose, name)]]):.2f}" for name in STRATEGIES)
            print(f"  {pose:20s} {cells}", flush=True)


if __name__ == "__main__":
    main()
