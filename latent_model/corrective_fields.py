"""Corrective shapes: what a production rig adds on top of skinning at a bent elbow, knee or shoulder.

The `skinning_to_skinning_plus_blendshape` pair moves a skinned pose to the rig's final shape: a biceps bulge,
an elbow or knee crease, deltoid bunching (corpus/correctives.py), millimetres that the global latent cannot
see (their deltas sit at its noise floor; the vertex decoder's reading of them was worse than no motion on 9
of 12 poses). A corrective depends on the character's build and on how the limb sits (its rest pose plus the
pose), so each pose's fields are pooled over training characters in every training rest configuration: a
sample is its skinned region, aligned by a similarity to the anchor's (the first sample's), and its corrective
in that frame. A target reads the mean corrective of the `k` samples whose aligned region shapes lie nearest
to its own (validation, elbowBentLf: 0.66 of the motion explained in bind and 0.48-0.49 in the validation
rests; the bind samples' mean alone: 0.06 in those rests).

Correspondence is by vertex index on anny's topology (every corpus character's): a mesh of another topology
gets no corrective and is told so (`CorrectiveFields.available`).

Files: `correctives.safetensors` beside a checkpoint (`lrr train correctives`): per pose its region's vertex
indices, anchor, landmark subset, the samples' landmark shapes, persons, and the correctives' PCA (mean,
basis, coefficients).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from latent_model.atomic import atomic_write

FORMAT = "lrr-correctives-2"  # 2: the topology fingerprint reads quads (`faces_digest`)
NEAREST = 8  # samples a target reads (validation: 8 over 4 and 16)
NEAREST_OWN = 2  # of one training person's samples (its rests), for the nearest-identity strategy, when alike
READ_SHARE = 0.25  # an example's corrective read as poses: a pose moving less than this share of the largest is dropped (validation: 0.54 explained, 0 → 0.51, 0.1 → 0.54)


def similarity(x: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R (3, 3), t (3,)) with y ≈ s x R^T + t in the least-squares sense (Umeyama): x, y (N, 3) paired."""
    mx, my = x.mean(0), y.mean(0)
    u, sv, vt = np.linalg.svd((y - my).T @ (x - mx))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    r = u @ d @ vt
    s = float((sv * np.diag(d)).sum() / max(((x - mx) ** 2).sum(), 1e-18))
    return s, r, my - s * r @ mx


@dataclass
class PoseCorrective:
    """One pose's corrective fields on its region of anny's topology.

    index (N,) region vertices; anchor (N, 3) the anchor sample's skinned region; landmarks (L,) positions in the
    region whose aligned shape describes a sample; shapes (S, L*3) each sample's aligned landmarks; persons (S,)
    whose sample; mean (N*3,), basis (C, N*3), coef (S, C): the samples' correctives in the anchor frame, PCA."""

    index: np.ndarray
    anchor: np.ndarray
    landmarks: np.ndarray
    shapes: np.ndarray
    persons: list[str]
    mean: np.ndarray
    basis: np.ndarray
    coef: np.ndarray

    def frame(self, vertices: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """(s, R, t, shape (L*3,)) of a skinned mesh's region: its similarity from the anchor and aligned landmarks."""
        x = np.asarray(vertices, np.float64)[self.index]
        s, r, t = similarity(self.anchor.astype(np.float64), x)
        aligned = (x[self.landmarks] - t) @ r / s
        return s, r, t, aligned.ravel()

    def nearest(self, shape: np.ndarray, person: str | None = None) -> tuple[np.ndarray, bool]:
        """(indices of the samples a mesh of aligned shape `shape` (L*3,) reads, whether they are `person`'s): the
        NEAREST samples nearest to it; for a person the fields hold, its own NEAREST_OWN nearest instead when its
        nearest one is among those. Validation: a person's own samples read whatever their shape explained −0.36…0.81
        (elbowBentLf, arms at the sides: −0.09), read only when alike 0.23–0.87 (the pooled read 0.25–0.89)."""
        d = np.linalg.norm(self.shapes.astype(np.float64) - shape, axis=1)
        pooled = np.argsort(d)[:NEAREST]
        if person is not None and person in self.persons:
            own = np.flatnonzero(np.asarray(self.persons) == person)
            own = own[np.argsort(d[own])]
            if d[own[0]] <= d[pooled[-1]]:
                return own[:NEAREST_OWN], True
        return pooled, False

    def displacement(self, vertices: np.ndarray, person: str | None = None) -> tuple[np.ndarray, bool]:
        """((V, 3) corrective of a skinned mesh (anny's topology, (V, 3)), whether `person`'s own samples gave it): the
        mean corrective of the samples it reads (`nearest`), carried from the anchor frame to the mesh's region."""
        s, r, _, shape = self.frame(vertices)
        near, own = self.nearest(shape, person)
        field = (self.mean.astype(np.float64) + self.coef[near].astype(np.float64).mean(0) @ self.basis.astype(np.float64))
        out = np.zeros((len(vertices), 3))
        out[self.index] = s * field.reshape(-1, 3) @ r.T
        return out, own


class CorrectiveFields:
    """The corrective fields of the poses the rig corrects ({pose: PoseCorrective}) on anny's topology
    (`n_vertices`)."""

    def __init__(self, poses: dict[str, PoseCorrective], n_vertices: int, faces_digest: str,
                 validation: dict[str, dict[str, float]] | None = None) -> None:
        self.poses = poses
        self.n_vertices = n_vertices
        self.faces_digest = faces_digest  # `faces_digest(anny's triangles)`: the topology the indices belong to
        # {pose: {rest: explained}} on the validation characters when built, the poses not kept included
        self.validation = validation or {}

    def has(self, pose: str | None) -> bool:
        return pose is not None and pose in self.poses

    def available(self, vertices: np.ndarray, faces: np.ndarray) -> str | None:
        """None when a mesh can take correctives (anny's topology: its vertex count and triangles), else why not,
        for the user."""
        if len(vertices) != self.n_vertices or faces_digest(faces) != self.faces_digest:
            return (f"no corrective: the corrective fields follow anny's topology ({self.n_vertices} vertices) by vertex "
                    f"index, and this mesh has " + (f"{len(vertices)} vertices" if len(vertices) != self.n_vertices
                                                    else "other triangles"))
        return None

    def displacement(self, vertices: np.ndarray, pose: str, person: str | None = None) -> tuple[np.ndarray, bool]:
        """The pose's corrective on a skinned mesh and whether `person`'s samples gave it (`PoseCorrective.displacement`)."""
        return self.poses[pose].displacement(vertices, person)

    def read(self, vertices: np.ndarray, corrected: np.ndarray) -> dict[str, float]:
        """{pose: weight > 0} whose correctives on this skinned mesh (anny's topology, (V, 3)) best make an example
        pair's corrective `corrected - vertices` (non-negative least squares; a pose giving less than READ_SHARE of
        the largest pose's motion is dropped and the rest refitted). What an example's corrective is then carries to
        another mesh as the same mix of the fields read on it (`Transfer.example_corrective`): the latent cannot
        carry it (the network's reading of a corrective's delta explained less than no motion on the validation
        characters)."""
        from scipy.optimize import nnls

        v = np.asarray(vertices, np.float64)
        target = (np.asarray(corrected, np.float64) - v).ravel()
        names = sorted(self.poses)
        basis = np.stack([self.displacement(v, p)[0].ravel() for p in names], axis=1)  # (3V, P)
        rows = np.flatnonzero(np.any(basis != 0, axis=1) | (target != 0))
        basis, target = basis[rows], target[rows]
        weight, _ = nnls(basis, target)
        share = weight * np.linalg.norm(basis, axis=0)
        keep = share >= READ_SHARE * share.max() if share.max() > 0 else np.zeros(len(names), bool)
        weight = np.zeros(len(names))
        if keep.any():
            weight[keep], _ = nnls(basis[:, keep], target)
        return {p: float(w) for p, w in zip(names, weight) if w > 0}

    # ------------------------------------------------------------------ files
    def save(self, path: Path) -> None:
        from safetensors.torch import save_file

        tensors = {}
        for p, c in self.poses.items():
            tensors[f"{p}.index"] = torch.from_numpy(np.ascontiguousarray(c.index, np.int32))
            tensors[f"{p}.landmarks"] = torch.from_numpy(np.ascontiguousarray(c.landmarks, np.int32))
            tensors[f"{p}.anchor"] = torch.from_numpy(np.ascontiguousarray(c.anchor, np.float32))
            for name in ("shapes", "mean", "basis", "coef"):  # half precision: a tenth of a millimetre of a field
                tensors[f"{p}.{name}"] = torch.from_numpy(np.ascontiguousarray(getattr(c, name), np.float16))
        meta = {"format": FORMAT, "n_vertices": str(self.n_vertices), "faces": self.faces_digest,
                "validation": json.dumps(self.validation),
                "persons": json.dumps({p: c.persons for p, c in self.poses.items()})}
        atomic_write(Path(path), lambda tmp: save_file(tensors, str(tmp), metadata=meta))

    @staticmethod
    def load(path: str | Path) -> "CorrectiveFields":
        from latent_model.checkpoint import read_stage_file

        meta, tensors = read_stage_file(path, FORMAT, "corrective fields", "lrr train correctives")
        t = {k: v.numpy() for k, v in tensors.items()}
        persons = json.loads(meta["persons"])
        poses = {p: PoseCorrective(t[f"{p}.index"].astype(np.int64), t[f"{p}.anchor"], t[f"{p}.landmarks"].astype(np.int64),
                                   t[f"{p}.shapes"], who, t[f"{p}.mean"], t[f"{p}.basis"], t[f"{p}.coef"])
                 for p, who in persons.items()}
        return CorrectiveFields(poses, int(meta["n_vertices"]), meta["faces"], json.loads(meta.get("validation", "{}")))


def faces_digest(faces: np.ndarray) -> str:
    """A short fingerprint of the topology a triangle list (F, 3) gives vertex indices. anny's triangles are its quads,
    each split in two consecutive triangles along the template's shorter diagonal, and for a near-square quad that
    choice flips with float rounding between machines: a list of such pairs is read as its quads (each as its four
    vertices), so any split of the same quads, in any order, has one fingerprint; another list, as its triangles."""
    import hashlib

    f = np.ascontiguousarray(faces, np.int64)
    a, b = f[0::2], f[1::2]
    if len(f) and len(f) % 2 == 0 and ((a[:, :, None] == b[:, None, :]).sum((1, 2)) == 2).all():
        six = np.sort(np.concatenate([a, b], axis=1), axis=1)  # each quad's four vertices, two of them twice
        keep = np.concatenate([np.ones((len(six), 1), bool), six[:, 1:] != six[:, :-1]], axis=1)
        f = six[keep].reshape(-1, 4)
    else:
        f = np.sort(f, axis=1)
    f = np.ascontiguousarray(f[np.lexsort(f.T[::-1])])  # in any order
    return hashlib.sha1(f.tobytes()).hexdigest()[:16]


def correctives_beside(checkpoint: str | Path) -> Path | None:
    """The corrective fields file next to a checkpoint, if there is one."""
    p = Path(checkpoint).parent / "correctives.safetensors"
    return p if p.exists() else None
