"""Decoder v2 at inference: a mesh's per-vertex rigid motion for a latent delta, and those motions scaled and mixed.

`Transfer` decides what a prediction reads (which deltas, their noise gates, an example's pose weights); this
room makes the motions the motion decoder (`nn/motion_decoder.py`) predicts for them: one pose at its own length
with hands and feet rigid, any magnitude, blend or gate as the surface's fitted motions scaled and mixed, so every
slider is continuous. What a mesh reads once (its surface tensors, first layer, fitted motions) is kept in its
`PreparedMesh` caches.
"""
from __future__ import annotations

import numpy as np
import torch

from latent_model.nn.delta import normalised_delta
from latent_model.nn.motion_decoder import (RigidMotion, apply_motion, heat_averager, local_motion_fit, mix_motions,
                                            part_rigidifier, surface_smoother)
from latent_model.prepared_mesh import PreparedMesh
from latent_model.types import PAIR_KINDS, PairKind


def delta_condition(d: np.ndarray, magnitude: float, kind: PairKind, device: torch.device
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(direction (1, Z), r (1,) scaled by the magnitude, kind (1,)) of a raw delta (Z,), on the device."""
    direction, r = normalised_delta(torch.from_numpy(np.asarray(d, np.float32))[None].to(device))
    return direction, r * magnitude, torch.tensor([PAIR_KINDS.index(kind)], device=device)


class MotionPredictor:
    """The motion decoder of `model` (a `LatentReRig` with decoder v2) on `device`. A condition is (direction, r,
    kind, deltas averaged): `condition` makes one from a raw delta."""

    def __init__(self, model, device: torch.device) -> None:
        self.model = model  # read at each call: a test or bench may swap its config
        self.device = device

    @property
    def _decoder_tag(self) -> str:
        """The cache key of what this decoder's weights derive from a mesh (its first layer, its fitted motions): a
        mesh prepared once and read by two models gets each its own."""
        return f"{self.device}|decoder {id(self.model.motion_decoder)}"

    def condition(self, d: np.ndarray, kind: PairKind, averaged: float = 1) -> tuple:
        """The condition of a raw delta (Z,) of pair kind `kind` averaging `averaged` characters' deltas."""
        return (*delta_condition(d, 1.0, self.model.cfg.motion.reads_as(kind), self.device), averaged)

    def predict(self, mesh: PreparedMesh, conditions: list, weights: list[float], gates: list[float], gate: float,
                magnitude: float, body: tuple[bool, ...]) -> tuple[np.ndarray, np.ndarray]:
        """(raw, gated) (V, 3): the poses' motions (`conditions`) mixed by `weights` times the magnitude, raw and
        each weighed by its noise gate (`gates`; `gate` their mean: 1 means the gated is the raw). A pose whose
        `body` flag is off (the local detail stage's alone) is not read at all (half the decoder calls of an
        evaluation)."""
        if self.model.cfg.motion.refit_radius <= 0:  # the decoder's own parameters scaled (the model before refits)
            motions = [self._motion(mesh, *c, magnitude) for c in conditions]
            v = torch.from_numpy(mesh.vertices)[None].to(self.device)
            move = self._mover(mesh)
            raw = move(v, mix_motions(motions, [w * moves for w, moves in zip(weights, body)]))[0].cpu().numpy()
            if gate == 1.0:
                return raw, raw
            gated = move(v, mix_motions(motions, [a * g * (magnitude != 0) for a, g in zip(weights, gates)]))
            return raw, gated[0].cpu().numpy()
        raw = self.scaled(mesh, conditions, [w * magnitude * moves for w, moves in zip(weights, body)])
        if gate == 1.0:
            return raw, raw
        return raw, self.scaled(mesh, conditions, [w * g * magnitude for w, g in zip(weights, gates)])

    def scaled(self, mesh: PreparedMesh, conditions: list, scales: list[float]) -> np.ndarray:
        """(V, 3) the mesh moved by each pose's motion (its `conditions`) times its scale, mixed. One pose at its
        own length is the decoder's motion with hands and feet rigid (`_mover`); any other mix (a magnitude, a
        blend, a partial gate) scales and mixes the motions that the surface makes there (`_fitted`), which
        give the same positions at scale 1, so the prediction is continuous in every slider."""
        v = torch.from_numpy(mesh.vertices)[None].to(self.device)
        active = [i for i, s in enumerate(scales) if s != 0]
        if not active:
            return mesh.vertices.copy()
        if len(active) == 1 and scales[active[0]] == 1.0:
            return self._mover(mesh)(v, self._motion(mesh, *conditions[active[0]]))[0].cpu().numpy()
        fitted = [self._fitted(mesh, *conditions[i]) for i in active]
        return apply_motion(v, mix_motions(fitted, [scales[i] for i in active]))[0].cpu().numpy()

    def _fitted(self, mesh: PreparedMesh, direction: torch.Tensor, r: torch.Tensor, k: torch.Tensor,
                       averaged: int = 1) -> RigidMotion:
        """The motion the surface makes under the decoder's prediction at the delta's own length (`local_motion_fit`
        over balls of the config's `refit_radius`), kept per delta: the magnitude and blend sliders only rescale it."""
        cfg, dev = self.model.cfg.motion, self.device
        fits = mesh.cache("motion_fits", self._decoder_tag, dict)
        key = (direction.cpu().numpy().tobytes(), float(r), int(k), averaged, cfg.refit_radius, cfg.rigid_parts,
               cfg.repivot, cfg.rigid_prior, cfg.rigid_anchor)
        if key not in fits:
            v = torch.from_numpy(mesh.vertices)[None].to(dev)
            moved = self._mover(mesh)(v, self._motion(mesh, direction, r, k, averaged))
            average = mesh.cache(f"motion_fit_ball_{cfg.refit_radius:g}", dev,
                                 lambda: heat_averager(mesh.vertices, mesh.faces, cfg.refit_radius))
            if len(fits) >= 16:  # a few poses at a time in the explorer; an evaluation walks through many
                fits.pop(next(iter(fits)))
            fits[key] = local_motion_fit(v, moved, average, max(cfg.repivot, 0.05))
        return fits[key]

    def _mover(self, mesh: PreparedMesh):
        """(v_src, RigidMotion) -> moved vertices: `apply_motion`, with hands and feet as rigid parts
        (`part_rigidifier`) unless the config says not."""
        if not self.model.cfg.motion.rigid_parts:
            return apply_motion
        cfg = self.model.cfg.motion
        return mesh.cache(f"motion_rigid_{cfg.rigid_prior:g}_{cfg.rigid_anchor:g}", self.device,
                          lambda: part_rigidifier(mesh.surface.coords, prior=cfg.rigid_prior, anchor=cfg.rigid_anchor))

    def _motion(self, mesh: PreparedMesh, direction: torch.Tensor, r: torch.Tensor, k: torch.Tensor,
                averaged: int = 1, magnitude: float = 1.0) -> RigidMotion:
        """The motion decoder's per-vertex motion of the mesh for a delta of length r scaled by `magnitude`, the
        delta averaging `averaged` characters' deltas (its surface features read once per mesh)."""
        dec, dev = self.model.motion_decoder, self.device

        def tensors() -> dict[str, torch.Tensor]:
            sf = mesh.surface
            t = lambda a: torch.from_numpy(np.asarray(a, np.float32))[None].to(dev)  # noqa: E731
            return {"v_src": t(mesh.vertices), "coords": t(sf.coords), "frames": t(sf.frames),
                    "normals": t(mesh.normals), "medial": t(sf.medial)}

        x = mesh.cache("motion", dev, tensors)
        smooth = mesh.cache("motion_smooth", dev, lambda: surface_smoother(mesh.faces, len(mesh.vertices),
                                                                          self.model.cfg.motion.smooth))
        # the first layer reads the mesh alone: once per mesh, not at every pose, strategy and slider move
        h0 = mesh.cache("motion_h0", self._decoder_tag,
                        lambda: dec.vertex_input(x["coords"], x["frames"], x["normals"], x["medial"] - x["v_src"]))
        mu = torch.from_numpy(mesh.mu)[None].to(dev)
        return dec.rigid_motion(**x, mu_src=mu, delta_dir=direction, r=r * magnitude / dec.delta_scale, kind=k,
                                smooth=smooth, repivot=self.model.cfg.motion.repivot, r_ref=r / dec.delta_scale,
                                averaged=torch.tensor([float(averaged)], device=dev), h0=h0)
