"""Surface features of corpus states kept on disk: they depend on a state's mesh alone (not on any model), take
~0.45 s each (`surface.surface_features`), and training and `lrr evaluate` read the same states again and again.

A file holds one state's features (`np.savez`: coords, frames, medial), named by the corpus's config digest, the
features' `surface.VERSION` and the state index, so another corpus or a changed computation never reads it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from latent_model.atomic import atomic_write
from latent_model.surface import VERSION, SurfaceFeatures, surface_features


def features_path(directory: str | Path, corpus, state: int) -> Path:
    """Where state `state` of `corpus` keeps its features in `directory`."""
    return Path(directory) / f"{corpus.manifest['config_digest']}_v{VERSION}_s{state}.npz"


def load_features(path: Path) -> SurfaceFeatures | None:
    """The features stored at `path`, or None when there are none (or the file is unreadable: computed again)."""
    try:
        with np.load(path) as z:
            return SurfaceFeatures(z["coords"], z["frames"], z["medial"], {})
    except (OSError, KeyError, ValueError):
        return None


def save_features(path: Path, sf: SurfaceFeatures) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda tmp: np.savez(tmp, coords=sf.coords, frames=sf.frames, medial=sf.medial))


def state_features(corpus, state: int, directory: str | Path | None) -> SurfaceFeatures:
    """The surface features of a corpus state: read from `directory` when kept there, else computed (and kept there;
    None: computed, not kept)."""
    path = None if directory is None else features_path(directory, corpus, state)
    sf = None if path is None else load_features(path)
    if sf is None:
        sf = surface_features(corpus.vertices(state), corpus.faces)
        if path is not None:
            save_features(path, sf)
    return sf
