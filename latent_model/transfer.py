"""The Transfer API: the one code path from a mesh to a prediction.

(target mesh, pose [+ pose B and blend], strategy, magnitude scale, pair kind) -> vertices.
Strategies: ``mean_pose_delta`` (Δμ averaged over training identities), ``nearest_identity_delta``
(the delta of the training identity whose source state is nearest in standardised latent
space), ``identity:<id>`` (a chosen training identity's delta) and ``oracle`` (the target's own
delta; an upper bound for analysis, needs the true target's latent). The CLI, the evaluation,
the tests and the explorer all call `Transfer.predict`.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from latent_model.bank import LatentBank
from latent_model.corpus.pairs import PAIR_KINDS
from latent_model.corpus.sdf import body_component_faces, sample_sdf, vertex_normals
from latent_model.nn.vertex_decoder import MeshFeatures, knn_graph
from latent_model.train.phases import normalised_delta

STRATEGIES = ("mean_pose_delta", "nearest_identity_delta", "identity:<id>", "oracle")
_ALIASES = {"mean": "mean_pose_delta", "nearest": "nearest_identity_delta"}
# Noise gate, in units of the bank's noise floor (a delta of sampling noise alone is ~1): the
# decoder's displacement is zeroed below GATE_LO and passed untouched above GATE_HI.
GATE_LO = 1.5
GATE_HI = 3.0


@dataclass
class PreparedMesh:
    """A mesh ready for the vertex decoder: everything that does not depend on the pose."""

    vertices: np.ndarray  # (V, 3) float32, model frame (metres, Z up, faces -Y)
    faces: np.ndarray  # (F, 3)
    normals: np.ndarray  # (V, 3)
    knn: np.ndarray  # (V, K) neighbourhoods (cached per mesh)
    mu: np.ndarray  # (Z,) posterior mean of the mesh's SDF samples
    features: MeshFeatures | None = None  # the decoder's mesh-only features, cached on first use


def parse_strategy(text: str) -> str:
    s = _ALIASES.get(text, text)
    if s in ("mean_pose_delta", "nearest_identity_delta", "oracle") or (s.startswith("identity:") and len(s) > 9):
        return s
    raise ValueError(f"unknown strategy {text!r}; valid: mean_pose_delta (mean), nearest_identity_delta (nearest), "
                     f"identity:<id>, oracle")


class Transfer:
    def __init__(self, model, bank: LatentBank, sdf_k: int, device: torch.device | None = None) -> None:
        self.model = model.eval()
        self.bank = bank
        self.sdf_k = sdf_k
        self.device = device or torch.device("cpu")
        self.model.to(self.device)

    @classmethod
    def from_files(cls, checkpoint: str | Path, bank: str | Path, device: torch.device | None = None) -> "Transfer":
        from latent_model.train.checkpoint import load_checkpoint

        model, preset, _ = load_checkpoint(checkpoint)
        return cls(model, LatentBank.load(bank), preset.corpus.sdf.k, device)

    # ------------------------------------------------------------------ per mesh
    @torch.no_grad()
    def encode(self, vertices: np.ndarray, sdf_faces: np.ndarray, seed: int = 0) -> np.ndarray:
        """(Z,) posterior mean of a mesh's SDF samples (K of the model's preset)."""
        from latent_model.corpus.sdf import SdfSampling

        pts, vals = sample_sdf(np.asarray(vertices, np.float64), sdf_faces, replace(SdfSampling(), k=self.sdf_k), seed)
        p = torch.from_numpy(pts[None]).float().to(self.device)
        v = torch.from_numpy(vals[None]).float().to(self.device)
        return self.model.encode_mu(p, v)[0].cpu().numpy()

    def prepare(self, vertices: np.ndarray, faces: np.ndarray, sdf_faces: np.ndarray | None = None,
                mu: np.ndarray | None = None, seed: int = 0) -> PreparedMesh:
        """Normals, neighbourhoods and the source latent of a mesh (in the model frame)."""
        v = np.asarray(vertices, dtype=np.float32)
        f = np.asarray(faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4:
            raise ValueError(f"vertices must be (V >= 4, 3), got {v.shape}")
        if not np.isfinite(v).all():
            raise ValueError("the mesh has NaN or infinite vertex coordinates; fix or re-export it")
        if sdf_faces is None:
            sdf_faces = body_component_faces(v.astype(np.float64), f)
        if mu is None:
            mu = self.encode(v, sdf_faces, seed)
        return PreparedMesh(v, f, vertex_normals(v, f), knn_graph(v, self.model.cfg.vd_knn), np.asarray(mu, np.float32))

    # ------------------------------------------------------------------ conditioning
    def delta(self, mesh: PreparedMesh, pose: str, strategy: str, kind: str = "neutral_to_pose",
              oracle_target_mu: np.ndarray | None = None) -> tuple[np.ndarray, str]:
        """Raw latent delta (Z,) for a pose, and a label of where it came from."""
        if kind not in PAIR_KINDS:
            raise ValueError(f"unknown pair kind {kind!r}; valid: {', '.join(PAIR_KINDS)}")
        s = parse_strategy(strategy)
        if s == "oracle":
            if oracle_target_mu is None:
                raise ValueError("the oracle strategy needs the true target's latent (oracle_target_mu)")
            return np.asarray(oracle_target_mu) - mesh.mu, "oracle"
        if s == "mean_pose_delta":
            return self.bank.mean_delta(kind, pose), "mean"
        if s == "nearest_identity_delta":
            ident, d = self.bank.nearest_identity(kind, pose, mesh.mu)
            return d, ident
        ident = s.split(":", 1)[1]
        return self.bank.identity_delta(kind, pose, ident), ident

    def noise_gate(self, delta: np.ndarray) -> tuple[float, float]:
        """(gate in [0, 1], signal) for a raw delta. signal = ||standardised delta|| / the bank's
        noise floor: a delta of sampling noise alone has signal ~1 (the paper's R_cond/noise).
        Below GATE_LO the condition carries no information the decoder could use, so the honest
        answer is no motion; above GATE_HI it passes untouched; smoothstep in between."""
        floor = self.bank.noise_floor
        if floor <= 0:  # a bank without a measured noise floor: no gate
            return 1.0, float("inf")
        signal = float(np.linalg.norm(np.asarray(delta) / self.bank.scale)) / floor
        x = min(max((signal - GATE_LO) / (GATE_HI - GATE_LO), 0.0), 1.0)
        return x * x * (3.0 - 2.0 * x), signal

    def predict(self, mesh: PreparedMesh, pose: str, strategy: str = "mean_pose_delta", magnitude: float = 1.0,
                kind: str = "neutral_to_pose", pose_b: str | None = None, blend: float = 0.0,
                oracle_target_mu: np.ndarray | None = None, oracle_target_mu_b: np.ndarray | None = None) -> np.ndarray:
        """(V, 3) float32 predicted vertices (`predict_detail(...).vertices`)."""
        return self.predict_detail(mesh, pose, strategy, magnitude, kind, pose_b, blend,
                                   oracle_target_mu, oracle_target_mu_b).vertices

    @torch.no_grad()
    def predict_detail(self, mesh: PreparedMesh, pose: str, strategy: str = "mean_pose_delta", magnitude: float = 1.0,
                       kind: str = "neutral_to_pose", pose_b: str | None = None, blend: float = 0.0,
                       oracle_target_mu: np.ndarray | None = None,
                       oracle_target_mu_b: np.ndarray | None = None) -> "TransferOutput":
        """The prediction with its parts. `blend` in [0, 1] mixes pose A's delta toward pose B's;
        `magnitude` scales r_Δ (0 = no motion requested: the source exactly, 1 = as conditioned,
        2 = doubled). The decoder's displacement is scaled by the noise gate of the delta."""
        if not np.isfinite(magnitude) or magnitude < 0:
            raise ValueError(f"magnitude must be a finite number >= 0, got {magnitude}")
        if not 0.0 <= blend <= 1.0:
            raise ValueError(f"blend must lie in [0, 1], got {blend}")
        d, label = self.delta(mesh, pose, strategy, kind, oracle_target_mu)
        if pose_b is not None and blend > 0:
            d_b, _ = self.delta(mesh, pose_b, strategy, kind, oracle_target_mu_b)
            d = (1.0 - blend) * d + blend * d_b
        gate, signal = self.noise_gate(d)
        if magnitude == 0:
            gate = 0.0
        dev = self.device
        vd = self.model.vertex_decoder
        v = torch.from_numpy(mesh.vertices)[None].to(dev)
        n = torch.from_numpy(mesh.normals)[None].to(dev)
        if mesh.features is None or mesh.features.hidden.device != torch.device(dev):
            mesh.features = vd.mesh_features(v, n)
        direction, r = normalised_delta(torch.from_numpy(np.asarray(d, np.float32))[None].to(dev))
        out = vd(v, n, torch.from_numpy(mesh.mu)[None].to(dev), direction, r * float(magnitude),
                 torch.tensor([PAIR_KINDS.index(kind)], device=dev), torch.from_numpy(mesh.knn)[None].to(dev),
                 features=mesh.features)
        raw = out["vertices"][0].cpu().numpy()
        gated = raw if gate == 1.0 else (mesh.vertices + np.float32(gate) * (raw - mesh.vertices)).astype(np.float32)
        return TransferOutput(gated, raw, gate, signal, label)


@dataclass
class TransferOutput:
    vertices: np.ndarray  # (V, 3) the prediction: source + gate * (decoder - source)
    raw: np.ndarray  # (V, 3) the vertex decoder's output, ungated
    gate: float  # noise gate in [0, 1] (0 also when magnitude is 0)
    signal: float  # ||standardised delta|| / noise floor (inf without a measured floor)
    label: str  # where pose A's delta came from: "mean", an identity id or "oracle"
