"""The local detail stage at inference: a face or finger pose's motion inside the head or a hand.

Decoder v2 moves the body from the global code, which cannot see a brow or a finger (their deltas sit at its
noise floor). Here each region of the source (`regions.region_frames`) is encoded at its own scale, the
pose's region delta comes from the detail bank (the mean over training characters, or one character's) or an
example pair (co-moving samples of A and A1); it is read as a mix of the training poses and the region moves by
their displacement fields (`detail_fields.py`) on the source's own region, placed in the frame that follows the
region as the body prediction moved it.
A delta is gated by its own noise floor as the global one is (`Transfer.noise_gate`).

Files: `detail.safetensors` beside a checkpoint (`lrr train detail`): the region codecs (`net.*`), the bank's
deltas (`delta.POSE.REGION`), the displacement fields (`field.REGION.anchor`, `field.REGION.values`) and JSON
metadata (config, persons, noise floors, sampling, each region's field poses).
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from latent_model.atomic import atomic_write
from latent_model.detail_fields import Placement, RegionFields
from latent_model.detail_poses import detail_regions_of, finger_chains
from latent_model.nn.local_detail import LocalDetail, LocalDetailConfig
from latent_model.regions import REGION_KIND, RegionFrame, RegionSampling, region_frames, sample_region

# 3: a hand's frame is its principal axes (`regions.principal_frame`); a file of 2 holds codes and fields in the
# hands' former limb frames, which the new frames would misread: refused, retrain
FORMAT = "lrr-detail-3"
EDGE = 0.15  # of a region's reach: the local motion fades to 0 over its outer edge (no seam at the neck or wrist)


@dataclass
class DetailBank:
    """Standardised co-moving region deltas {(pose, region): (n, Z)} of the training characters `persons`,
    the noise floor of one such delta per region kind, and the sampling they were made with."""

    deltas: dict[tuple[str, str], np.ndarray]
    persons: list[str]
    noise: dict[str, float]
    sampling: RegionSampling

    def has(self, pose: str) -> bool:
        return any(k[0] == pose for k in self.deltas)

    def mean(self, pose: str, region: str) -> np.ndarray:
        return self.deltas[(pose, region)].mean(axis=0)

    def of_person(self, pose: str, region: str, person: str) -> np.ndarray | None:
        """One training person's delta, or None when the person is not in the bank."""
        if person not in self.persons:
            return None
        return self.deltas[(pose, region)][self.persons.index(person)]


class LocalDetailModel:
    """The codecs, the bank and the displacement fields of the local detail stage (`load`)."""

    def __init__(self, net: LocalDetail, bank: DetailBank, fields: dict[str, RegionFields]) -> None:
        self.net = net.eval()
        self.bank = bank
        # a finger's knuckle turns compose (`RegionFields.chains`): known from the fields' poses, not stored
        self.fields = {r: replace(f, chains=finger_chains(f.poses)) for r, f in fields.items()}
        # {region: (P, Z)} the mean delta of each field's pose: what a delta is read against
        self.basis = {r: np.stack([bank.mean(p, r) for p in f.poses]) for r, f in fields.items()}

    # ------------------------------------------------------------------ files
    def save(self, path: Path) -> None:
        from safetensors.torch import save_file

        tensors = {f"net.{k}": v.detach().cpu().contiguous() for k, v in self.net.state_dict().items()}
        tensors.update({f"delta.{p}.{r}": torch.from_numpy(np.ascontiguousarray(d))
                        for (p, r), d in self.bank.deltas.items()})
        for r, f in self.fields.items():
            tensors[f"field.{r}.anchor"] = torch.from_numpy(np.ascontiguousarray(f.anchor, np.float32))
            tensors[f"field.{r}.values"] = torch.from_numpy(np.ascontiguousarray(f.values, np.float32))
        meta = {"format": FORMAT, "config": json.dumps(self.net.cfg.to_dict()), "persons": json.dumps(self.bank.persons),
                "noise": json.dumps(self.bank.noise), "sampling": json.dumps(asdict(self.bank.sampling)),
                "fields": json.dumps({r: f.poses for r, f in self.fields.items()})}
        atomic_write(Path(path), lambda tmp: save_file(tensors, str(tmp), metadata=meta))

    @staticmethod
    def load(path: str | Path) -> "LocalDetailModel":
        from latent_model.checkpoint import read_stage_file

        meta, tensors = read_stage_file(path, FORMAT, "local detail", "lrr train detail")
        net = LocalDetail(LocalDetailConfig.from_dict(json.loads(meta["config"])))
        net.load_state_dict({k[4:]: v for k, v in tensors.items() if k.startswith("net.")})
        deltas = {}
        for k, v in tensors.items():
            if k.startswith("delta."):
                pose, region = k[6:].rsplit(".", 1)
                deltas[(pose, region)] = v.numpy()
        s = json.loads(meta["sampling"])
        sampling = RegionSampling(**{k: tuple(v) if isinstance(v, list) else v for k, v in s.items()})
        fields = {r: RegionFields(tensors[f"field.{r}.anchor"].numpy(), poses, tensors[f"field.{r}.values"].numpy())
                  for r, poses in json.loads(meta["fields"]).items()}
        bank = DetailBank(deltas, json.loads(meta["persons"]), json.loads(meta["noise"]), sampling)
        return LocalDetailModel(net, bank, fields)

    # ------------------------------------------------------------------ per mesh
    def regions(self, vertices: np.ndarray, faces: np.ndarray, sdf_faces: np.ndarray, features=None,
                seed: int = 0) -> "MeshRegions":
        """A mesh's region frames (its neutral: what a prediction starts from); each region's code and place on its
        fields' anchor are made when first read (`MeshRegions.code`, `MeshRegions.placement`)."""
        v = np.asarray(vertices, dtype=np.float64)
        return MeshRegions(region_frames(v, faces, features), v, sdf_faces, seed, self)

    def example_deltas(self, neutral: "MeshRegions", posed_vertices: np.ndarray,
                       skip: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
        """{region: standardised delta} of an example pair: the posed mesh (A's topology) sampled co-moving with
        the neutral (its frames, following each region, the neutral's seed): what the region codes see. `skip`:
        regions not wanted."""
        out = {}
        for r, f in neutral.frames.items():
            if r in skip:
                continue
            pts, vals = sample_region(posed_vertices, neutral.sdf_faces, f, self.bank.sampling, neutral.seed,
                                      rest=neutral.vertices)
            out[r] = self._code(r, pts, vals) - neutral.code(r)
        return out

    def example_reading(self, neutral: "MeshRegions", posed_vertices: np.ndarray) -> dict[str, np.ndarray]:
        """{region: delta} what a prediction reads of an example pair: the co-moving deltas (`example_deltas`),
        except that a region whose fields chain (a hand) reads the example's own motion (`example_reads`).
        Validation (an example person's pair on 3 others): fistLf 0.11 -> 0.86 explained, fingerKnuckleB02Lf 0.55
        -> 0.80, A01Lf 0.80 -> 0.83, the latent's leak (0.09-0.19 mm) gone."""
        fitted = tuple(r for r in neutral.frames if r in self.fields and self.fields[r].chains)
        out = self.example_deltas(neutral, posed_vertices, skip=fitted)
        for r in fitted:
            out[r] = FittedDelta.of(self.example_reads(neutral, posed_vertices, r), self.basis[r])
        return {r: out[r] for r in neutral.frames}

    def example_reads(self, neutral: "MeshRegions", posed_vertices: np.ndarray, region: str) -> np.ndarray:
        """(P,) pose weights of an example's region motion (A -> A1, one topology), fitted through the region's
        fields on A (`RegionFields.fit`): a fist's hand code is not additive over its twelve knuckles (its delta
        read as two), its vertices' motion is (`FittedDelta`: gated as any delta, a still hand reads ~0)."""
        f = neutral.frames[region]
        posed = np.asarray(posed_vertices, np.float64)
        carried = f.follow(neutral.vertices, posed)
        local = carried.to_local(posed[f.vertices]) - f.to_local(neutral.vertices[f.vertices])
        return self.fields[region].fit(neutral.placement(region), local)

    def pose_deltas(self, pose: str, person: str | None = None) -> tuple[dict[str, np.ndarray], int]:
        """({region: delta}, how many characters it averages) of a vocabulary pose: the training mean, or
        `person`'s (a training person; the mean when the bank does not hold it). Empty for a body pose."""
        out, n = {}, 1
        for r in detail_regions_of(pose):
            if (pose, r) not in self.bank.deltas:
                continue
            own = None if person is None else self.bank.of_person(pose, r, person)
            if own is None:
                out[r], n = self.bank.mean(pose, r), len(self.bank.deltas[(pose, r)])
            else:
                out[r] = own
        return out, n

    def gate(self, region: str, delta: np.ndarray, averaged: float) -> tuple[float, float]:
        """(gate, signal) of a region delta against its kind's noise floor (over sqrt(averaged) for a mean)."""
        from latent_model.noise_gate import smooth_gate

        floor = self.bank.noise.get(REGION_KIND[region], 0.0)
        if floor <= 0:
            return 1.0, float("inf")
        signal = float(np.linalg.norm(delta)) / floor * float(np.sqrt(averaged))
        return smooth_gate(signal), signal

    def displacement(self, mesh: "MeshRegions", deltas: list[tuple[dict[str, np.ndarray], float]],
                     moved: np.ndarray, held: tuple[str, ...] = ()) -> np.ndarray:
        """(V, 3) world displacement to add to `moved` (the body prediction of the mesh, (V, 3)): for each region,
        the sum over `deltas` [({region: delta}, weight)] of the fields' displacement for the delta's pose mix
        (`RegionFields.read`) times its weight, in the region's frame as `moved` carries it, fading over the
        region's edge. `held`: the face and finger poses the mesh already stands in (a `source_to_combo` source's),
        which the mix is added to (`MeshRegions.placement`)."""
        out = np.zeros_like(moved, dtype=np.float64)
        for r, f in mesh.frames.items():
            parts = [(d[r], w) for d, w in deltas if r in d and w != 0.0]
            if not parts or r not in self.fields:
                continue
            mix = sum(w * self._read(r, d) for d, w in parts)
            local = self.fields[r].displacement(mesh.placement(r, held), mix)
            carried = f.follow(mesh.vertices, moved)
            if carried.mirrored:
                local[:, 2] = -local[:, 2]
            world = (local * carried.radius) @ carried.rotation.T
            out[f.vertices] += world * mesh.fade[r][:, None]
        return out

    def mix(self, region: str, delta: np.ndarray) -> dict[str, float]:
        """{pose: weight} a region delta reads as (the fields' poses it mixes, the ones above 0)."""
        if region not in self.fields:
            return {}
        w = self._read(region, delta)
        return {p: float(x) for p, x in zip(self.fields[region].poses, w) if x > 0}

    def _read(self, region: str, delta: np.ndarray) -> np.ndarray:
        """(P,) the pose weights a region delta stands for: a `FittedDelta`'s own, else its read (`RegionFields.read`)."""
        if isinstance(delta, FittedDelta) and delta.weights is not None:
            return delta.weights
        return RegionFields.read(delta, self.basis[region], self.bank.noise.get(REGION_KIND[region], 0.0))

    def _code(self, region: str, points: np.ndarray, values: np.ndarray) -> np.ndarray:
        kind = REGION_KIND[region]
        return self.net.encode(kind, torch.from_numpy(points)[None], torch.from_numpy(values)[None])[0].numpy()


class FittedDelta(np.ndarray):
    """A region delta (Z,) standing for pose weights (P,) fitted to an example's own motion (`example_reads`): the
    weights times the poses' mean deltas, so it is gated as any delta, and read back as exactly these weights (the
    read's floor and antagonist rules are for latent deltas: they read a fitted fist's twelve knuckles as five)."""

    weights: np.ndarray | None

    @staticmethod
    def of(weights: np.ndarray, basis: np.ndarray) -> "FittedDelta":
        out = np.asarray(np.asarray(weights) @ basis, np.float32).view(FittedDelta)
        out.weights = np.asarray(weights, np.float64)
        return out

    def __array_finalize__(self, obj) -> None:
        self.weights = None  # an array derived from it (scaled, summed, sliced) is a plain delta again


@dataclass
class MeshRegions:
    """A source mesh's region frames {region: RegionFrame}, its vertices (V, 3), SDF faces, the sampling seed (an
    example pair's posed mesh is sampled with it, co-moving) and the detail model that reads it. A region's
    standardised code (`code`) and its place on its fields' anchor (`placement`) are made when first asked for and
    kept: a prediction reads only the regions its pose moves (a finger pose one hand), and an evaluation prepares
    hundreds of posed sources (sampling and encoding a region ~0.1 s, placing it 0.1-0.3 s)."""

    frames: dict[str, RegionFrame]
    vertices: np.ndarray
    sdf_faces: np.ndarray
    seed: int
    model: "LocalDetailModel" = field(repr=False)
    codes: dict[str, np.ndarray] = field(default_factory=dict, repr=False)  # {region: (Z,)} made so far
    placed: dict[str, Placement] = field(default_factory=dict, repr=False)  # {region: Placement} made so far
    held_placed: dict[tuple[str, tuple[str, ...]], Placement] = field(default_factory=dict, repr=False)

    def code(self, region: str) -> np.ndarray:
        """(Z,) the region's standardised code (sampled with the mesh's seed, encoded once)."""
        if region not in self.codes:
            f = self.frames[region]
            self.codes[region] = self.model._code(region, *sample_region(self.vertices, self.sdf_faces, f,
                                                                         self.model.bank.sampling, self.seed))
        return self.codes[region]

    def placement(self, region: str, held: tuple[str, ...] = ()) -> Placement:
        """Where the region lies on its fields' anchor; with `held` poses of its fields, on the anchor posed so
        (`RegionFields.place`), once per region and poses."""
        fields = self.model.fields[region]
        f = self.frames[region]
        weights = fields.weights_of(held)
        if not weights.any():
            if region not in self.placed:
                self.placed[region] = fields.place(f.to_local(self.vertices[f.vertices]))
            return self.placed[region]
        key = (region, tuple(sorted(held)))
        if key not in self.held_placed:
            self.held_placed[key] = fields.place(f.to_local(self.vertices[f.vertices]), weights)
        return self.held_placed[key]

    @property
    def fade(self) -> dict[str, np.ndarray]:
        """{region: (N,) weight of the local motion}: 1 inside, down to 0 over the region's outer edge."""
        return {r: np.clip(f.depth / EDGE, 0.0, 1.0) for r, f in self.frames.items()}


def describe_mix(mix: dict[str, float], most: int = 3) -> str:
    """"cornerUpLf 0.92 + puffLf 0.10": the largest weights of a region's pose mix, for the window and the CLI."""
    top = sorted(mix.items(), key=lambda kv: -kv[1])
    text = " + ".join(f"{p} {w:.2f}" for p, w in top[:most])
    return text + (f" + {len(top) - most} more" if len(top) > most else "")


def detail_beside(checkpoint: str | Path) -> Path | None:
    """The local detail file next to a checkpoint, if there is one."""
    p = Path(checkpoint).parent / "detail.safetensors"
    return p if p.exists() else None
