"""Report figures (matplotlib, Agg): heatmaps, the noise-floor scatter, entanglement matrices,
model-vs-baseline pose consistency, and rendered side-by-side meshes coloured by error."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from latent_model.atomic import atomic_save_figure  # noqa: E402

GROUP_COLOURS = {"body": "tab:blue", "finger": "tab:orange", "face": "tab:green", "mixed": "tab:purple"}


def _save(fig, path: Path) -> Path:
    return atomic_save_figure(fig, path, dpi=90, bbox_inches="tight")


def heatmap(ax, matrix: np.ndarray, labels: list[str], title: str, cmap: str = "viridis",
            vmin: float | None = None, vmax: float | None = None) -> None:
    im = ax.imshow(matrix, cmap=cmap, vmin=vmin, vmax=vmax)
    ax.set_xticks(range(len(labels)), labels, rotation=90, fontsize=6)
    ax.set_yticks(range(len(labels)), labels, fontsize=6)
    ax.set_title(title, fontsize=9)
    plt.colorbar(im, ax=ax, fraction=0.046, pad=0.04)


def identity_matrices(figs: dict[str, dict], path: Path) -> Path:
    """Standardised neutral-latent distances of 20 identities, one panel per encoder."""
    fig, axes = plt.subplots(1, len(figs), figsize=(5.2 * len(figs), 4.6))
    for ax, (name, f) in zip(np.atleast_1d(axes), figs.items()):
        d, labels = f["identity_matrix"]
        heatmap(ax, d, labels, f"{name}: neutral identity distances")
    return _save(fig, path)


def cosine_heatmaps(f: dict, path: Path, name: str) -> Path:
    poses = list(f["cosine_matrices"])
    cols = 3
    rows = int(np.ceil(len(poses) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 4.2 * rows))
    for ax, pose in zip(np.ravel(axes), poses):
        c, labels = f["cosine_matrices"][pose]
        off = c[~np.eye(len(c), dtype=bool)]
        heatmap(ax, c, labels, f"{name} {pose}: Δμ cosine (mean {off.mean():.3f})", "RdBu_r", -1, 1)
    for ax in np.ravel(axes)[len(poses):]:
        ax.axis("off")
    return _save(fig, path)


def noise_floor(figs: dict[str, dict], path: Path) -> Path:
    """Per single pose: resampling noise (x) vs conditioning distance (y); dashed R = 1.
    Right: identity vs noise distance distributions."""
    n = len(figs)
    fig, axes = plt.subplots(2, n, figsize=(5.2 * n, 9))
    axes = np.asarray(axes).reshape(2, n)
    for k, (name, f) in enumerate(figs.items()):
        ax = axes[0, k]
        pts = f["cond_noise"]
        for group, colour in GROUP_COLOURS.items():
            xy = np.array([(x, y) for x, y, g in pts.values() if g == group])
            if len(xy):
                ax.scatter(xy[:, 0], xy[:, 1], s=14, c=colour, label=group)
        hi = max(max(x for x, _, _ in pts.values()), max(y for _, y, _ in pts.values())) * 1.05
        ax.plot([0, hi], [0, hi], "k--", lw=1, label="R = 1")
        for pose in ("elbowBentLf", "kneeBentLf", "clavicleDownwardLf", "browDwLf", "fingerKnuckleD03Lf", "cornerUpLf"):
            if pose in pts:
                ax.annotate(pose, pts[pose][:2], fontsize=6)
        ax.set_xlabel("same-state re-sampling distance (standardised)")
        ax.set_ylabel("mean conditioning distance ‖Δμ̃‖")
        ax.set_title(f"{name}: conditioning signal vs noise floor", fontsize=9)
        ax.legend(fontsize=7)
        ax = axes[1, k]
        ident, noise = f["distances"]
        bins = np.linspace(0, max(ident.max(), noise.max()), 40)
        ax.hist(ident, bins, alpha=0.6, label=f"identity (mean {ident.mean():.2f})")
        ax.hist(noise, bins, alpha=0.6, label=f"noise (mean {noise.mean():.2f})")
        ax.set_xlabel("standardised latent distance")
        ax.set_title(f"{name}: identity vs same-geometry distances", fontsize=9)
        ax.legend(fontsize=7)
    return _save(fig, path)


def entanglement(f: dict, path: Path, name: str) -> Path:
    poses = list(f["entanglement"])
    fig, axes = plt.subplots(len(poses), 2, figsize=(9, 4.2 * len(poses)))
    axes = np.asarray(axes).reshape(len(poses), 2)
    for row, pose in zip(axes, poses):
        dm, cm, labels = f["entanglement"][pose]
        heatmap(row[0], dm, labels, f"{name} {pose}: posed identity distance")
        heatmap(row[1], cm, labels, f"{name} {pose}: Δμ cosine", "RdBu_r", -1, 1)
    return _save(fig, path)


def pose_consistency_bars(metrics: dict[str, dict], poses: list[str], path: Path) -> Path:
    """Cross-identity Δμ cosine per single pose, one bar per encoder."""
    names = list(metrics)
    fig, ax = plt.subplots(figsize=(max(10, 0.22 * len(poses)), 4))
    w = 0.8 / len(names)
    for k, name in enumerate(names):
        vals = [metrics[name].get(f"latent.pose_consistency.{p}.cos_mean", np.nan) for p in poses]
        ax.bar(np.arange(len(poses)) + k * w, vals, w, label=name)
    ax.set_xticks(np.arange(len(poses)) + 0.4 - w / 2, poses, rotation=90, fontsize=6)
    ax.axhline(0.958, color="k", ls="--", lw=0.8, label="paper elbowBentLf 0.958")
    ax.set_ylabel("mean cross-identity cosine of Δμ")
    ax.set_ylim(-0.2, 1.0)
    ax.legend(fontsize=7)
    return _save(fig, path)


def transfer_example(ex: dict, faces: np.ndarray, title: str, path: Path, view: str = "front",
                     crop: np.ndarray | None = None) -> Path:
    """source | mean | nearest | truth, predictions coloured by per-vertex error (mm)."""
    from latent_model.render import draw_mesh

    truth = ex["truth"]
    err = {k: np.linalg.norm(ex[k] - truth, axis=1) * 1000 for k in ("mean", "nearest")}
    vmax = max(5.0, float(np.percentile(np.concatenate(list(err.values())), 99)))
    fig, axes = plt.subplots(1, 4, figsize=(12, 4.6))
    panels = [("source", None), ("mean", err["mean"]), ("nearest", err["nearest"]), ("truth", None)]
    for ax, (k, values) in zip(axes, panels):
        v = ex[k]
        keep_faces = faces
        if crop is not None:  # show only the region of interest (faces whose vertices all lie inside)
            inside = np.all((ex["truth"] >= crop[0]) & (ex["truth"] <= crop[1]), axis=1)
            keep_faces = faces[inside[faces].all(axis=1)]
        draw_mesh(ax, v, keep_faces, view, values=values, cmap="YlOrRd", vmin=0, vmax=vmax)
        label = k if values is None else f"{k}: mean {values.mean():.1f} / max {values.max():.0f} mm"
        ax.set_title(label, fontsize=8)
    fig.suptitle(f"{title} (error colour 0-{vmax:.0f} mm)", fontsize=10)
    return _save(fig, path)


def detail_closeup(ex: dict, faces: np.ndarray, region: np.ndarray, title: str, path: Path) -> Path:
    """The paper's facial figure made by the product: source | mean | nearest | truth of one held-out character,
    close up on a region (vertex indices `region`: faces with all three inside are drawn), coloured by each
    mesh's displacement from the source (mm, one scale: where it moves and how much)."""
    from latent_model.render import draw_mesh, project

    inside = np.zeros(len(ex["source"]), bool)
    inside[region] = True
    keep = faces[inside[faces].all(axis=1)]
    disp = {k: np.linalg.norm(ex[k] - ex["source"], axis=1) * 1000 for k in ("mean", "nearest", "truth")}
    vmax = max(1.0, float(np.percentile(disp["truth"][region], 99.5)))
    fig, axes = plt.subplots(1, 4, figsize=(13, 4.6))
    for ax, k in zip(axes, ("source", "mean", "nearest", "truth")):
        values = disp.get(k)
        draw_mesh(ax, ex[k], keep, "front", values=values, cmap="YlOrRd", vmin=0, vmax=vmax)
        xy = project(ex[k][region], "front")[0]
        pad = 0.03 * float(np.ptp(xy, axis=0).max())
        ax.set_xlim(xy[:, 0].min() - pad, xy[:, 0].max() + pad)
        ax.set_ylim(xy[:, 1].min() - pad, xy[:, 1].max() + pad)
        if values is None:
            ax.set_title(k, fontsize=9)
        else:
            err = np.linalg.norm(ex[k] - ex["truth"], axis=1)[region] * 1000
            ax.set_title(f"{k}: moves ≤ {values[region].max():.1f} mm" + ("" if k == "truth" else f", error {err.mean():.2f} mm"),
                         fontsize=8)
    fig.suptitle(f"{title} (displacement colour 0-{vmax:.0f} mm)", fontsize=10)
    return _save(fig, path)
