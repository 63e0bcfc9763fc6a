"""Measurements of a built corpus: corrective magnitudes and the offset-copy baseline."""
from __future__ import annotations

import numpy as np

from latent_model.corpus.poses import get_pose
from latent_model.corpus.store import Corpus
from latent_model.types import FINAL


def corrective_table(corpus: Corpus, identities: list[int] | None = None) -> list[dict]:
    """Per skeletal pose: |V_skin+bs - V_skin| in mm: max over identities/vertices, mean over
    vertices moved > 0.1 mm, and the spread (std) of the per-identity max across identities."""
    ids = identities if identities is not None else list(range(len(corpus.identities)))
    rows = []
    for name in corpus.poses:
        if not get_pose(name).has_skeletal:
            continue
        maxes, means = [], []
        for i in ids:
            d = np.linalg.norm(corpus.vertices(corpus.state(i, name, FINAL))
                               - corpus.vertices(corpus.state(i, name, "skinning")), axis=1) * 1000
            maxes.append(d.max())
            moved = d[d > 0.1]
            means.append(moved.mean() if len(moved) else 0.0)
        rows.append({"pose": name, "max_mm": float(np.max(maxes)), "mean_mm": float(np.mean(means)),
                     "max_std_mm": float(np.std(maxes))})
    return rows


def nearest_identities(corpus: Corpus, identities: list[int]) -> dict[int, int]:
    """For each identity, the nearest one of another person among `identities` (mean per-vertex distance
    of neutrals; the same person in another rest would be copying its own motion)."""
    V = np.stack([corpus.vertices(corpus.state(i, None, "neutral")) for i in identities]).astype(np.float64)
    person = np.asarray([corpus.identities[i].person_id for i in identities])
    out = {}
    for a, i in enumerate(identities):
        d = np.linalg.norm(V - V[a], axis=2).mean(axis=1)
        d[person == person[a]] = np.inf
        out[i] = identities[int(np.argmin(d))]
    return out


def offset_copy_explained(corpus: Corpus, poses: list[str], identities: list[int] | None = None) -> dict[str, float]:
    """Explained motion of copying the nearest identity's vertex offsets (neutral -> final pose):
    1 - mean|pred - truth| / mean|neutral - truth| per pose, averaged over identities.
    (Possible only because every identity shares anny's topology.)"""
    ids = identities if identities is not None else list(range(len(corpus.identities)))
    nn = nearest_identities(corpus, ids)
    out = {}
    for name in poses:
        vals = []
        for i in ids:
            j = nn[i]
            n_i = corpus.vertices(corpus.state(i, None, "neutral"))
            t_i = corpus.vertices(corpus.state(i, name, FINAL))
            off = corpus.vertices(corpus.state(j, name, FINAL)) - corpus.vertices(corpus.state(j, None, "neutral"))
            err = np.linalg.norm(n_i + off - t_i, axis=1).mean()
            base = np.linalg.norm(n_i - t_i, axis=1).mean()
            vals.append(1.0 - err / max(base, 1e-12))
        out[name] = float(np.mean(vals))
    return out
