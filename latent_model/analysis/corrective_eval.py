"""The corrective fields on held-out characters: issue 19's corrective target, measured without a corpus.

Each held-out character is regenerated in its own rest configuration and posed in every corrective pose; the
skinned mesh goes through the Transfer API (`skinning_to_skinning_plus_blendshape`, the mean and the nearest
identity's strategies) and the prediction is compared with the rig's skinning + blendshape: explained motion
(1 - err / the no-motion error: > 0 is better than no motion), error and static leakage over the whole mesh.
"""
from __future__ import annotations

import time
from typing import Callable

import numpy as np

from latent_model.analysis.metrics import mesh_errors
from latent_model.analysis.parallel import Batch, Workers, submit_characters
from latent_model.corpus.identities import IdentitySpec

KIND = "skinning_to_skinning_plus_blendshape"
STRATEGIES = (("mean_pose_delta", "mean"), ("nearest_identity_delta", "nearest"))
EXAMPLE = "example"  # the pose's corrective of another held-out character as an example pair (`example_groups`)
SHOWN = tuple(name for _, name in STRATEGIES) + (EXAMPLE,)
TARGET_JOINTS = ("elbow", "knee", "shoulder")  # the target: explained >= 0.3 on these, never below 0


def evaluate_correctives(transfer, specs: list[IdentitySpec], say: Callable[[str], None] = print,
                         workers: "int | Workers" = 1) -> dict:
    """Metrics `correctives.*` of `transfer`'s corrective fields on the characters `specs` (held out); {} without.
    `workers`: processes sharing the characters (`parallel.submit_characters`: a count or a running `Workers`; the
    same metrics)."""
    return submit_correctives(transfer, specs, say, workers).get()


def submit_correctives(transfer, specs: list[IdentitySpec], say: Callable[[str], None] = print,
                       workers: "int | Workers" = 1) -> Batch:
    """`evaluate_correctives`' characters queued on `workers`: `get()` returns its metrics."""
    if transfer.correctives is None:
        return submit_characters(_group, [], transfer, 1, then=lambda _: {})
    t0 = time.time()

    def summary(parts: list[dict]) -> dict:
        rows: dict[tuple[str, str, str], list] = {}
        for part in parts:
            for key, r in part.items():
                rows.setdefault(key, []).extend(r)
        say(f"  correctives: {len(specs)} characters ({time.time() - t0:.0f} s)")
        return summarise(rows)

    return submit_characters(_group, example_groups(specs), transfer, workers, then=summary)


def example_groups(specs: list[IdentitySpec]) -> list[tuple[IdentitySpec, ...]]:
    """The characters in consecutive pairs (an odd last one joins the pair before): each reads the next of its group,
    round, as its example pair, so each character is posed once (posing is over half of the work)."""
    groups = [tuple(specs[i:i + 2]) for i in range(0, len(specs), 2)]
    if len(groups) > 1 and len(groups[-1]) == 1:
        groups[-2] += groups.pop()
    return groups


def _group(transfer, _corpus, _shared, group: tuple[IdentitySpec, ...]) -> dict:
    """{(pose, strategy, rest): [mesh_errors]} of a group's characters, each posed in every corrective pose; the
    example strategy reads the next character of the group (in its own rest) as the example pair."""
    from latent_model.corpus.build import generator
    from latent_model.corpus.sdf import body_component_faces

    gen = generator()
    faces = np.asarray(gen.faces, np.int64)
    rows: dict[tuple[str, str, str], list] = {}
    for pose in transfer.correctives.poses:
        pairs = [gen.pose(spec, pose) for spec in group]
        pairs = [(g.skinning.astype(np.float64), g.skinning_plus_blendshape.astype(np.float64)) for g in pairs]
        # what each character's own pair reads as (the previous one's example)
        reads = [transfer.example_corrective(*(transfer.prepare(x, faces) for x in pair)) for pair in pairs] \
            if len(group) > 1 else []
        for k, (spec, (skinned, truth)) in enumerate(zip(group, pairs)):
            mesh = transfer.prepare(skinned, faces, body_component_faces(skinned, faces))
            for strategy, name in STRATEGIES:
                pred = transfer.predict(mesh, pose, strategy, kind=KIND).astype(np.float64)
                rows.setdefault((pose, name, spec.rest), []).append(mesh_errors(pred, truth, skinned))
            if reads:
                pred = transfer.predict(mesh, None, kind=KIND, corrective_mix=reads[(k + 1) % len(group)])
                rows.setdefault((pose, EXAMPLE, spec.rest), []).append(mesh_errors(pred.astype(np.float64), truth, skinned))
            rows.setdefault((pose, "no_motion", spec.rest), []).append(mesh_errors(skinned, truth, skinned))
    return rows


def summarise(rows: dict) -> dict:
    """{(pose, strategy, rest): [mesh_errors]} -> flat metrics: per pose, strategy and rest (means), the worst
    character, and per strategy and rest the mean over the target joints' poses."""
    m: dict = {}
    for (pose, name, rest), r in rows.items():
        for k in ("explained", "err_mm", "leak_mm"):
            m[f"correctives.{pose}.{name}.{rest}.{k}"] = float(np.mean([x[k] for x in r]))
        m[f"correctives.{pose}.{name}.{rest}.worst_explained"] = float(np.min([x["explained"] for x in r]))
    rests = sorted({r for _, _, r in rows}, key=lambda r: (r != "bind", r))
    poses = sorted({p for p, _, _ in rows})
    targets = [p for p in poses if p.startswith(TARGET_JOINTS)]
    for name in SHOWN:
        for rest in rests:
            vals = [m[f"correctives.{p}.{name}.{rest}.explained"] for p in targets if f"correctives.{p}.{name}.{rest}.explained" in m]
            if vals:
                m[f"correctives.targets.{name}.{rest}.explained"] = float(np.mean(vals))
                m[f"correctives.targets.{name}.{rest}.min_pose_explained"] = float(np.min(vals))
    return m


def markdown(m: dict) -> str:
    """Per pose: explained (mean over characters, the worst in brackets) for the mean and nearest strategies in each
    rest; then the target joints' means."""
    poses = sorted({k.split(".")[1] for k in m if k.startswith("correctives.") and not k.startswith("correctives.targets.")})
    if not poses:
        return "(no corrective fields beside the checkpoint)"
    rests = sorted({k.split(".")[3] for k in m if k.startswith(f"correctives.{poses[0]}.mean.")},
                   key=lambda r: (r != "bind", r))
    head = ["pose"] + [f"{s} {r}" for s in SHOWN for r in rests]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for p in poses:
        cells = [f"{m[f'correctives.{p}.{s}.{r}.explained']:.2f} ({m[f'correctives.{p}.{s}.{r}.worst_explained']:.2f})"
                 if f"correctives.{p}.{s}.{r}.explained" in m else "" for s in SHOWN for r in rests]
        out.append(f"| {p} | " + " | ".join(cells) + " |")
    out += ["", "| joints " + ", ".join(TARGET_JOINTS) + " | " + " | ".join(rests) + " |", "|---|" + "---|" * len(rests)]
    for s in SHOWN:
        out.append(f"| {s}: mean explained (lowest pose) | " + " | ".join(
            f"{m[f'correctives.targets.{s}.{r}.explained']:.2f} ({m[f'correctives.targets.{s}.{r}.min_pose_explained']:.2f})"
            if f"correctives.targets.{s}.{r}.explained" in m else "" for r in rests) + " |")
    return "\n".join(out)
