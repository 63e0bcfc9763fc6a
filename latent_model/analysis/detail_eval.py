"""The local detail stage on held-out characters: issue 19's targets, measured without a corpus.

The characters are regenerated from their specs (`corpus.build.plan` of the model's preset), in their own rest
configurations, so this runs beside `lrr evaluate` or alone (`lrr evaluate --detail-only`):

1. region latent: per face or finger pose, the cross-identity cosine of its co-moving region deltas (the head's
   for a face pose, that side's hand for a finger pose) and R_cond/noise = mean ||delta|| over the noise floor
   of one such delta (the same pair sampled with another seed), both in the stage's standardised units;
2. mesh transfer through the Transfer API (`neutral_to_pose`, the mean delta and the nearest identity's):
   explained motion and static leakage over the whole mesh, as the transfer analysis measures them;
3. left/right asymmetry of browDwLf+browDwRt: how far the predicted displacement differs from its own mirror
   image over the vertices that truly move (the truth's own asymmetry beside it).
"""
from __future__ import annotations

import time
from typing import Callable

import numpy as np
from scipy.spatial import cKDTree

from latent_model.analysis.metrics import STATIC_MM, cosine_stats, mesh_errors
from latent_model.analysis.parallel import Batch, Workers, submit_characters
from latent_model.corpus.identities import IdentitySpec
from latent_model.corpus.poses import get_pose
from latent_model.detail_poses import detail_regions_of

SYMMETRIC_POSE = "browDwLf+browDwRt"
FIGURE_POSE = "cornerUpLf"  # the paper's facial figure: mean vs nearest on a held-out character, close up
NOISE_SEEDS = (0, 1)  # two co-moving samplings of one pair: the noise floor of a delta


def detail_poses(poses: tuple[str, ...]) -> list[str]:
    """The single face and finger poses among `poses` (the ones the issue's latent and mesh targets name)."""
    return [p for p in poses if not get_pose(p).is_combo and get_pose(p).group in ("face", "finger")]


def mirror_map(vertices: np.ndarray) -> np.ndarray:
    """(V,) index of each vertex's mirror image across the x = 0 plane (the canonical frame's sagittal plane)."""
    v = np.asarray(vertices, np.float64)
    return cKDTree(v).query(v * np.array([-1.0, 1.0, 1.0]))[1]


def asymmetry_mm(displacement: np.ndarray, mirror: np.ndarray, where: np.ndarray) -> float:
    """Mean over vertices `where` of |d(v) - M d(mirror(v))| in mm, M negating x: 0 for a symmetric motion."""
    d = np.asarray(displacement, np.float64)
    m = d[mirror] * np.array([-1.0, 1.0, 1.0])
    return float(np.linalg.norm(d[where] - m[where], axis=1).mean() * 1000) if where.any() else 0.0


def evaluate_detail(transfer, specs: list[IdentitySpec], poses: tuple[str, ...], noise_persons: int = 4,
                    say: Callable[[str], None] = print, workers: "int | Workers" = 1) -> tuple[dict, dict]:
    """(metrics `detail.*`, figure data) of `transfer`'s local detail stage on the characters `specs` (held out
    from its training); figure data: {"example": {source, mean, nearest, truth: (V, 3)}, "region": head vertex
    indices, "faces", "title"} of FIGURE_POSE on the first character. ({}, {}) without a detail stage.
    `workers`: processes sharing the characters (`parallel.submit_characters`: a count or a running `Workers`; the
    same metrics)."""
    return submit_detail(transfer, specs, poses, noise_persons, say, workers).get()


def submit_detail(transfer, specs: list[IdentitySpec], poses: tuple[str, ...], noise_persons: int = 4,
                  say: Callable[[str], None] = print, workers: "int | Workers" = 1) -> Batch:
    """`evaluate_detail`'s characters queued on `workers`: `get()` returns its (metrics, figure data)."""
    if transfer.detail is None:
        return submit_characters(_character, [], transfer, 1, then=lambda _: ({}, {}))
    singles = detail_poses(poses)
    wanted = singles + ([SYMMETRIC_POSE] if SYMMETRIC_POSE in poses else [])
    t0 = time.time()

    def summary(parts: list[tuple]) -> tuple[dict, dict]:
        deltas: dict[str, list] = {p: [] for p in singles}
        noise: dict[str, list] = {p: [] for p in singles}
        mesh: dict[tuple[str, str, str], list] = {}
        asym: dict[str, list] = {"pred": [], "truth": []}
        figure: dict = {}
        for c_deltas, c_noise, c_mesh, c_asym, c_figure in parts:
            for p, d in c_deltas.items():
                deltas[p].append(d)
            for p, x in c_noise.items():
                noise[p].append(x)
            for key, rows in c_mesh.items():
                mesh.setdefault(key, []).extend(rows)
            for k, x in c_asym.items():
                asym[k].append(x)
            figure = figure or c_figure
        say(f"  local detail: {len(specs)} characters ({time.time() - t0:.0f} s)")
        return _summarise(deltas, noise, mesh, asym), figure

    return submit_characters(_character, enumerate(specs), transfer, workers, shared=(wanted, noise_persons),
                             then=summary)


def _character(transfer, _corpus, shared: tuple, item: tuple[int, IdentitySpec]) -> tuple:
    """One character's ({pose: region delta}, {pose: noise distance}, {(pose, strategy, rest): [mesh_errors]},
    {"pred", "truth": asymmetry mm}, figure data (the first character's, else {}))."""
    from latent_model.corpus.build import generator
    from latent_model.corpus.sdf import body_component_faces
    from latent_model.types import FINAL

    (wanted, noise_persons), (n, spec) = shared, item
    gen = generator()
    faces = np.asarray(gen.faces, np.int64)
    deltas, noise, mesh, asym, figure = {}, {}, {}, {}, {}
    neutral = gen.neutral(spec).astype(np.float64)
    sdf_faces = body_component_faces(neutral, faces)
    prepared = transfer.prepare(neutral, faces, sdf_faces)
    regions = {s: transfer.detail.regions(neutral, faces, sdf_faces, prepared.surface, seed=s)
               for s in (NOISE_SEEDS if n < noise_persons else NOISE_SEEDS[:1])}
    for pose in wanted:
        posed = getattr(gen.pose(spec, pose), FINAL).astype(np.float64)
        if pose != SYMMETRIC_POSE:
            region = detail_regions_of(pose)[0]
            others = tuple(x for x in regions[NOISE_SEEDS[0]].frames if x != region)  # only the pose's region
            by_seed = {s: transfer.detail.example_deltas(r, posed, skip=others)[region] for s, r in regions.items()}
            deltas[pose] = by_seed[NOISE_SEEDS[0]]
            if len(by_seed) > 1:
                noise[pose] = float(np.linalg.norm(by_seed[NOISE_SEEDS[0]] - by_seed[NOISE_SEEDS[1]]))
        for strategy, name in (("mean_pose_delta", "mean"), ("nearest_identity_delta", "nearest")):
            pred = transfer.predict(prepared, pose, strategy, kind="neutral_to_pose").astype(np.float64)
            if pose == FIGURE_POSE and n == 0:
                figure.setdefault("example", {"source": neutral, "truth": posed})[name] = pred
                figure.update(region=regions[NOISE_SEEDS[0]].frames["head"].vertices, faces=faces,
                              title=f"{spec.id} {FIGURE_POSE}, neutral → pose")
            mesh.setdefault((pose, name, spec.rest), []).append(mesh_errors(pred, posed, neutral))
            if pose == SYMMETRIC_POSE and name == "mean":
                moving = np.linalg.norm(posed - neutral, axis=1) * 1000 >= STATIC_MM
                mirror = mirror_map(neutral)
                asym["pred"] = asymmetry_mm(pred - neutral, mirror, moving)
                asym["truth"] = asymmetry_mm(posed - neutral, mirror, moving)
    return deltas, noise, mesh, asym, figure


def _summarise(deltas: dict, noise: dict, mesh: dict, asym: dict) -> dict:
    m: dict = {}
    for pose, d in deltas.items():
        d = np.stack(d)
        m[f"detail.latent.cos.{pose}"] = cosine_stats(d)["cos_mean"]
        floor = float(np.mean(noise[pose])) if noise[pose] else float("nan")
        m[f"detail.latent.cond_noise.{pose}"] = float(np.linalg.norm(d, axis=1).mean()) / max(floor, 1e-12)
    for group in ("face", "finger"):
        ps = [p for p in deltas if get_pose(p).group == group]
        if ps:
            m[f"detail.latent.cos.group.{group}"] = float(np.mean([m[f"detail.latent.cos.{p}"] for p in ps]))
            m[f"detail.latent.cond_noise.group.{group}"] = float(np.mean([m[f"detail.latent.cond_noise.{p}"] for p in ps]))
    for (pose, name, rest), rows in mesh.items():
        for k in ("explained", "leak_mm", "err_mm"):
            m[f"detail.transfer.{pose}.{name}.{rest}.{k}"] = float(np.mean([r[k] for r in rows]))
    rests = sorted({r for _, _, r in mesh})
    for group in ("face", "finger"):
        for name in ("mean", "nearest"):
            for rest in rests:
                rows = [r for (p, s, rr), v in mesh.items() if s == name and rr == rest and p in deltas
                        and get_pose(p).group == group for r in v]
                if rows:
                    for k in ("explained", "leak_mm"):
                        m[f"detail.transfer.group.{group}.{name}.{rest}.{k}"] = float(np.mean([r[k] for r in rows]))
    if asym["pred"]:
        m["detail.asymmetry_mm.pred"] = float(np.mean(asym["pred"]))
        m["detail.asymmetry_mm.truth"] = float(np.mean(asym["truth"]))
    return m


def markdown(m: dict) -> str:
    """The section's tables: latent per pose and group, transfer per group and rest."""
    if not any(k.startswith("detail.") for k in m):
        return "(no local detail stage beside the checkpoint)"
    poses = sorted({k.split(".")[3] for k in m if k.startswith("detail.latent.cos.") and ".group." not in k})
    out = ["| pose | group | latent cosine | R_cond/noise |", "|---|---|---|---|"]
    for p in poses:
        out.append(f"| {p} | {get_pose(p).group} | {m[f'detail.latent.cos.{p}']:.3f} | "
                   f"{m[f'detail.latent.cond_noise.{p}']:.2f} |")
    for g in ("face", "finger"):
        if f"detail.latent.cos.group.{g}" in m:
            out.append(f"| **{g} group** | | **{m[f'detail.latent.cos.group.{g}']:.3f}** | "
                       f"**{m[f'detail.latent.cond_noise.group.{g}']:.2f}** |")
    out += ["", "| group | strategy | rest | explained | leak (mm) |", "|---|---|---|---|---|"]
    for k in sorted(k for k in m if k.startswith("detail.transfer.group.") and k.endswith(".explained")):
        _, _, _, g, s, rest, _ = k.split(".")
        out.append(f"| {g} | {s} | {rest} | {m[k]:.3f} | {m[k.replace('.explained', '.leak_mm')]:.3f} |")
    if "detail.asymmetry_mm.pred" in m:
        out += ["", f"{SYMMETRIC_POSE}: left/right asymmetry of the prediction {m['detail.asymmetry_mm.pred']:.2f} mm "
                f"(the truth's own {m['detail.asymmetry_mm.truth']:.2f} mm), over the vertices that truly move."]
    return "\n".join(out)
