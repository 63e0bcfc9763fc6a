"""Contact sheet: identities (rows) x poses (columns), rendered with the matplotlib renderer."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from latent_model.corpus.poses import get_pose
from latent_model.corpus.store import Corpus
from latent_model.types import FINAL
from latent_model.atomic import atomic_save_figure
from latent_model.render import draw_mesh

DEFAULT_SHEET_POSES = ("neutral", "elbowSuperBentLf", "kneeBentLf", "shoulderRaiseLf", "fistLf",
                       "browDwLf+browDwRt", "cornerUpLf", "jawOpen", "puffLf")


def _crop(ax, v: np.ndarray, pose: str, neutral: np.ndarray) -> None:
    """Zoom facial poses on the head and finger poses on the hand, so the shape is visible."""
    if pose == "neutral":
        return
    p = get_pose(pose)
    if p.group == "face":
        top = v[:, 2].max()
        ax.set_xlim(-0.11, 0.11)
        ax.set_ylim(top - 0.27, top + 0.01)
    elif p.group == "finger":
        moved = np.linalg.norm(v - neutral, axis=1) > 0.002  # centre on what the pose moves
        c = v[moved].mean(axis=0) if moved.any() else v.mean(axis=0)
        ax.set_xlim(c[0] - 0.11, c[0] + 0.11)
        ax.set_ylim(c[2] - 0.12, c[2] + 0.10)


def contact_sheet(corpus: Corpus, out: Path, identities: list[int] | None = None,
                  poses: tuple[str, ...] | None = None, dpi: int = 70) -> Path:
    """Render the sheet to PNG at `out` (written atomically)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ids = identities if identities is not None else list(range(min(8, len(corpus.identities))))
    poses = tuple(p for p in (poses or DEFAULT_SHEET_POSES) if p == "neutral" or p in corpus.poses)
    fig, axes = plt.subplots(len(ids), len(poses), figsize=(2.0 * len(poses), 2.6 * len(ids)), squeeze=False)
    for r, i in enumerate(ids):
        spec = corpus.identities[i]
        st = corpus.identity_stats[i].get("stature_m", float("nan")) if corpus.identity_stats else float("nan")
        neutral = corpus.vertices(corpus.state(i, None, "neutral"))
        for c, pose in enumerate(poses):
            ax = axes[r, c]
            s = corpus.state(i, None, "neutral") if pose == "neutral" else corpus.state(i, pose, FINAL)
            v = corpus.vertices(s)
            values = None
            if pose != "neutral":
                values = np.linalg.norm(v - neutral, axis=1) * 1000
            view = "side" if pose.startswith(("knee", "hip")) else "front"
            draw_mesh(ax, v, corpus.faces, view, values=values, cmap="YlOrRd", vmin=0,
                      vmax=20 if values is not None else None)
            _crop(ax, v, pose, neutral)
            if r == 0:
                ax.set_title(pose, fontsize=8)
            if c == 0:
                label = f"{spec.id} {spec.split}{' stylised' if spec.stylised else ''}\n{st:.2f} m"
                ax.text(0.0, 1.0, label, transform=ax.transAxes, fontsize=7, va="top")
    fig.suptitle("Corpus contact sheet (colour: displacement from neutral, 0-20 mm)", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.45 / fig.get_figheight()))
    return atomic_save_figure(fig, out, dpi=dpi)


def rest_sheet(specs: list, out: Path, rests: tuple[str, ...], poses: tuple[str, ...] = ("neutral",),
               dpi: int = 70, generator=None) -> Path:
    """Identities (rows) across rest configurations x poses (columns), generated from the identity
    specs through the rig (no corpus rows needed); a pose is coloured by its displacement from that
    rest's neutral. Written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from latent_model.corpus.rests import get_rest
    from latent_model.corpus.states import StateGenerator

    for r in rests:
        get_rest(r)  # unknown names raise with the valid ones
    gen = generator or StateGenerator()
    cols = [(r, p) for r in rests for p in poses]
    fig, axes = plt.subplots(len(specs), len(cols), figsize=(2.0 * len(cols), 2.6 * len(specs)), squeeze=False)
    for row, spec in enumerate(specs):
        neutrals = {r: gen.neutral(spec, r) for r in rests}  # one per rest, shared by its pose columns
        for col, (rest, pose) in enumerate(cols):
            ax = axes[row, col]
            neutral = neutrals[rest]
            v = neutral if pose == "neutral" else gen.state(spec, pose, FINAL, rest=rest)
            values = None if pose == "neutral" else np.linalg.norm(v - neutral, axis=1) * 1000
            draw_mesh(ax, v, gen.faces, "front", values=values, cmap="YlOrRd", vmin=0,
                      vmax=20 if values is not None else None)
            _crop(ax, v, pose, neutral)
            if row == 0:
                ax.set_title(rest if pose == "neutral" else f"{rest}\n{pose}", fontsize=8)
            if col == 0:
                label = f"{spec.person_id} {spec.split}{' stylised' if spec.stylised else ''}"
                ax.text(0.0, 0.0, label, transform=ax.transAxes, fontsize=7, va="bottom")
    fig.suptitle("Rest configurations (colour: displacement from that rest's neutral, 0-20 mm)", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.45 / fig.get_figheight()))  # room for the title above the column titles
    return atomic_save_figure(fig, out, dpi=dpi)
