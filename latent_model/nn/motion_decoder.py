"""Decoder v2: a per-vertex rigid motion read from the latent delta, in the limb's own frame.

For each vertex, from where it is on the body (`latent_model/surface.py`: geodesic coordinates, its
normal and medial point in its limb frame F) and the condition (mu_src, the delta's direction, the pair
kind), an MLP with FiLM predicts, in F: a rotation vector w, a pivot offset o from the vertex's medial
point m, and a translation u. With r the delta's length in units of the training deltas' mean length:

    p = m + F o,    x' = x + (R(r F w) - I) (x - p) + r F u    (= p + R (x - p) + r F u)

- in the limb frame, the same motion is the same numbers whatever the rest pose: a forearm standing in a
  T-pose turns about its elbow as it does in an A-pose;
- rotation and translation are linear in r, so r = 0 returns the source exactly, the prediction is
  continuous in the magnitude and the delta, and twice a 47 degree elbow delta turns the forearm by
  about 94 degrees about the elbow instead of stretching it along a tangent;
- evaluated per vertex, so training reads random vertex subsets of many pairs per step.
No layer depends on the vertex count or the topology.
"""
from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import torch
from torch import nn

from latent_model.nn.common import mlp

N_COORD_FREQ = 5  # sin/cos of 2^k pi c, c = geodesic distance / height in [0, ~1.2]: down to ~6 cm


def axis_angle_to_matrix(w: torch.Tensor) -> torch.Tensor:
    """(..., 3) rotation vectors -> (..., 3, 3) (Rodrigues; smooth at 0)."""
    theta2 = (w * w).sum(-1, keepdim=True)
    theta = torch.sqrt(theta2 + 1e-12)
    # sin(t)/t and (1-cos t)/t^2 with their Taylor series near 0 (exact 0 -> identity)
    small = theta2 < 1e-6
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / theta2.clamp(min=1e-12))
    x, y, z = w.unbind(-1)
    zero = torch.zeros_like(x)
    K = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(*w.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand_as(K)
    return eye + a[..., None] * K + b[..., None] * (K @ K)


def fit_whitened_basis(x: torch.Tensor, mean_out: torch.Tensor, basis_out: torch.Tensor) -> None:
    """Fill mean_out (Z,) with the rows' mean and basis_out (k, Z) with their k leading principal components,
    each divided by its std, so that (x - mean) @ basis.T has unit variance per column (x: (N, Z))."""
    mean = x.mean(0)
    _, s, vt = torch.linalg.svd(x - mean, full_matrices=False)
    k = min(len(basis_out), len(s))
    std = s[:k] / max(len(x) - 1, 1) ** 0.5
    mean_out.copy_(mean)
    basis_out.zero_()
    basis_out[:k] = vt[:k] / std.clamp(min=1e-8)[:, None]


def coord_features(coords: torch.Tensor) -> torch.Tensor:
    """(..., 6) geodesic coordinates -> (..., 6 + 12 N_COORD_FREQ) Fourier features."""
    freqs = (2.0 ** torch.arange(N_COORD_FREQ, dtype=coords.dtype, device=coords.device)) * math.pi
    a = coords[..., None] * freqs
    return torch.cat([coords, torch.sin(a).flatten(-2), torch.cos(a).flatten(-2)], dim=-1)


class MotionDecoder(nn.Module):
    """(surface features of V_src, mu_src, delta direction, r, kind) -> V_hat."""

    def __init__(self, latent: int, n_kinds: int, hidden: int = 128, cond: int = 256, layers: int = 3,
                 world: bool = False, mu_dims: int = 8, mu_noise: float = 1.0, local_inputs: bool = True,
                 delta_dims: int = 0, delta_noise: float = 0.0, limb_direction: bool = False,
                 averaged_input: bool = False, carried_arms: bool = False) -> None:
        super().__init__()
        self.dir_gain = math.sqrt(latent)  # unit direction components ~1/sqrt(Z): to unit RMS
        self.kind_emb = nn.Embedding(n_kinds, 16)
        # mu_src is read through its first principal components over the training characters, whitened,
        # clamped and noised in training: read in full, the decoder memorises the training characters
        self.mu_dims, self.mu_noise = mu_dims, mu_noise
        self.register_buffer("mu_mean", torch.zeros(latent))
        self.register_buffer("mu_basis", torch.zeros(mu_dims, latent))  # (k, Z) rows: components / their std
        # the delta's direction in full (delta_dims 0), or through its leading principal components over the training
        # deltas, whitened and noised in training: read in full, a character's own delta (oracle, nearest, an
        # example pair) carries components no mean delta has, and the decoder keys the training characters on them
        self.delta_dims, self.delta_noise = delta_dims, delta_noise
        if delta_dims:
            self.register_buffer("delta_mean", torch.zeros(latent))
            self.register_buffer("delta_basis", torch.zeros(delta_dims, latent))
        # averaged_input: the condition also says how many characters' deltas the delta averages (a pose's mean over
        # the training characters, or one character's: the oracle, the nearest identity, an example pair), read as
        # log(n) / log(averaged_ref) in [0, 1]. A mean is exact where one character's delta carries its identity and
        # sampling noise; told which it reads, the decoder need not make one mapping serve both
        self.averaged_input = averaged_input
        if averaged_input:
            self.register_buffer("averaged_ref", torch.ones(()))  # the training characters' count (train/motion.py)
        self.cond = mlp([mu_dims + (delta_dims or latent) + 16 + int(averaged_input), cond, cond], final_act=True)
        # local_inputs: also the normal and the medial offset (they differ between neighbours: a part's
        # vertices then get different motions); without, the motion is a smooth function of where on the body
        self.local_inputs = local_inputs
        # limb_direction: also the limb's axis t in body axes (smoothed along the surface, so neighbours agree):
        # where the limb points in this rest, read from the geometry rather than from mu_src alone
        self.limb_direction = limb_direction
        n_in = 6 + 12 * N_COORD_FREQ + (6 if local_inputs else 0) + (3 if limb_direction else 0)
        self.inp = nn.Linear(n_in, hidden)
        self.hidden = nn.ModuleList(nn.Linear(hidden, hidden) for _ in range(layers))
        self.film = nn.Linear(cond, 2 * hidden * (layers + 1))
        nn.init.zeros_(self.film.weight)
        nn.init.zeros_(self.film.bias)
        self.world = world  # also a rotation and translation in world axes (the torso has no limb axis)
        # carried_arms: one more output, each vertex's logit of how far the chest carries it (`carry_arms`)
        self.out = nn.Linear(hidden, (15 if world else 9) + int(carried_arms))
        nn.init.normal_(self.out.weight, std=1e-3)
        nn.init.zeros_(self.out.bias)
        self.n_layers = layers
        # carried_arms: the arms' motion is composed on the chest band's (`carry_arms`), as far as the decoder says
        # per vertex: a spine pose's turn of the arms is then the chest's in any rest, where in the arm's limb frame
        # it is another rotation in each rest; the arms' own and the neck's poses, which move the band a little,
        # need not carry the arms with it (composed without a say, they leaked 2-4 mm onto the other arm)
        self.carried_arms = carried_arms
        # mean length of the training deltas: r is read in these units (set by train/motion.py)
        self.register_buffer("delta_scale", torch.ones(()))

    def set_mu_basis(self, mu: torch.Tensor) -> None:
        """Fit the mu_src read-out to the training characters' neutral latents (N, Z)."""
        fit_whitened_basis(mu, self.mu_mean, self.mu_basis)

    def set_delta_basis(self, directions: torch.Tensor) -> None:
        """Fit the direction read-out (delta_dims > 0) to the training deltas' unit directions (N, Z)."""
        if self.delta_dims:
            fit_whitened_basis(directions, self.delta_mean, self.delta_basis)

    def delta_code(self, delta_dir: torch.Tensor) -> torch.Tensor:
        """(B, Z) unit directions -> (B, delta_dims) whitened principal coordinates, or the direction itself at
        unit RMS when delta_dims is 0; noised in training (delta_noise)."""
        if self.delta_dims:
            z = ((delta_dir - self.delta_mean) @ self.delta_basis.T).clamp(-5.0, 5.0)
        else:
            z = delta_dir * self.dir_gain
        if self.training and self.delta_noise > 0:
            z = z + torch.randn_like(z) * self.delta_noise
        return z

    def mu_code(self, mu_src: torch.Tensor) -> torch.Tensor:
        """(B, Z) -> (B, k) whitened principal coordinates, clamped to +-3 (noised in training)."""
        z = ((mu_src - self.mu_mean) @ self.mu_basis.T).clamp(-3.0, 3.0)
        if self.training and self.mu_noise > 0:
            z = z + torch.randn_like(z) * self.mu_noise
        return z

    def averaged_code(self, averaged: torch.Tensor | None, batch: int, like: torch.Tensor) -> torch.Tensor:
        """(B,) counts of characters a delta averages (None: one each) -> (B, 1) log(n) / log(averaged_ref) in
        [0, 1], times 2 minus 1 (unit size either way)."""
        if averaged is None:
            return torch.full((batch, 1), -1.0, dtype=like.dtype, device=like.device)
        n = torch.as_tensor(averaged, dtype=like.dtype, device=like.device).reshape(batch, 1).clamp(min=1.0)
        a = torch.log(n) / torch.log(self.averaged_ref.clamp(min=2.0))
        return a.clamp(0.0, 1.0) * 2.0 - 1.0

    def condition(self, mu_src: torch.Tensor, delta_dir: torch.Tensor, kind: torch.Tensor,
                  averaged: torch.Tensor | None = None) -> torch.Tensor:
        """(B, Z), (B, Z), (B,) -> (B, C). `averaged` (B,): how many characters' deltas each delta averages (read
        only by a decoder built with averaged_input; None: one character's)."""
        parts = [self.mu_code(mu_src), self.delta_code(delta_dir), self.kind_emb(kind)]
        if self.averaged_input:
            parts.append(self.averaged_code(averaged, len(mu_src), mu_src))
        return self.cond(torch.cat(parts, dim=-1))

    def vertex_input(self, coords: torch.Tensor, frames: torch.Tensor, normals: torch.Tensor,
                     medial_offset: torch.Tensor) -> torch.Tensor:
        """(B, N, hidden) the first layer's output, before the condition modulates it: it depends on the mesh alone,
        so a prediction can keep it per mesh (`motion(..., h0=)`)."""
        to_local = lambda x: torch.einsum("bnij,bni->bnj", frames, x)  # noqa: E731  F^T x
        x = coord_features(coords)
        if self.local_inputs:
            x = torch.cat([x, to_local(normals), to_local(medial_offset) * 10.0], dim=-1)
        if self.limb_direction:
            x = torch.cat([x, frames[..., :, 0]], dim=-1)
        return self.inp(x)

    def motion(self, coords: torch.Tensor, frames: torch.Tensor, normals: torch.Tensor, medial_offset: torch.Tensor,
               c: torch.Tensor, h0: torch.Tensor | None = None) -> torch.Tensor:
        """Per-vertex (w, o, u) in the limb frame (B, N, 9) from coords (B, N, 6), frames (B, N, 3, 3),
        world normals and medial - x (B, N, 3), condition (B, C); `h0`: their `vertex_input`, when kept."""
        film = self.film(c).reshape(c.shape[0], 1, self.n_layers + 1, 2, -1)
        h = self.vertex_input(coords, frames, normals, medial_offset) if h0 is None else h0
        inplace = not torch.is_grad_enabled()  # a quarter less time at inference; training keeps the input for backward
        for k, layer in enumerate([None, *self.hidden]):
            if layer is not None:
                h = layer(h)
            h = torch.nn.functional.silu(torch.addcmul(film[:, :, k, 1], h, 1.0 + film[:, :, k, 0]), inplace=inplace)
        return self.out(h)

    def forward(self, v_src: torch.Tensor, coords: torch.Tensor, frames: torch.Tensor, normals: torch.Tensor,
                medial: torch.Tensor, mu_src: torch.Tensor, delta_dir: torch.Tensor, r: torch.Tensor,
                kind: torch.Tensor, c: torch.Tensor | None = None, smooth=None, repivot: float = 0.0,
                r_ref: torch.Tensor | None = None, averaged: torch.Tensor | None = None) -> torch.Tensor:
        """v_src, normals, medial (B, N, 3); coords (B, N, 6); frames (B, N, 3, 3); mu_src, delta_dir (B, Z);
        r (B,) the delta's length in mean training lengths; kind (B,). -> V_hat (B, N, 3).
        `c`: a cached `condition(...)` (the explorer's sliders change r only). `smooth`: on a whole mesh, a
        function averaging per-vertex (B, N, k) values over surface neighbourhoods (`surface_smoother`): the
        rotations, pivots and translations are averaged before they act, so a part's vertices share one motion.
        `repivot` > 0: each vertex's translation is absorbed into its pivot (`absorb_translation`, that damping) at
        the delta's own length `r_ref` (B,) (default r: r is r_ref times the magnitude), then scaled to r.
        `averaged` (B,): how many characters' deltas the delta averages (`condition`)."""
        return apply_motion(v_src, self.rigid_motion(v_src, coords, frames, normals, medial, mu_src, delta_dir, r, kind,
                                                     c, smooth, repivot, r_ref, averaged=averaged))

    def rigid_motion(self, v_src: torch.Tensor, coords: torch.Tensor, frames: torch.Tensor, normals: torch.Tensor,
                     medial: torch.Tensor, mu_src: torch.Tensor, delta_dir: torch.Tensor, r: torch.Tensor,
                     kind: torch.Tensor, c: torch.Tensor | None = None, smooth=None,
                     repivot: float = 0.0, r_ref: torch.Tensor | None = None,
                     outputs: torch.Tensor | None = None, averaged: torch.Tensor | None = None,
                     h0: torch.Tensor | None = None) -> "RigidMotion":
        """The per-vertex motion in world axes (arguments as `forward`), before it acts. Rotation and translation
        are formed per unit r, smoothed (linear, so it commutes with r), optionally re-pivoted at r_ref (the
        motion there is unchanged), then scaled by r. `outputs`: `motion(...)` already computed (training
        penalises parts of it); `h0`: the mesh's `vertex_input`, kept between predictions."""
        if outputs is None:
            if c is None:
                c = self.condition(mu_src, delta_dir, kind, averaged)
            outputs = self.motion(coords, frames, normals, medial - v_src, c, h0)
        m = outputs
        to_world = lambda x: torch.einsum("bnij,bnj->bni", frames, x)  # noqa: E731  F x
        r = r.reshape(-1, 1, 1)
        w, o, u = to_world(m[..., 0:3]), to_world(m[..., 3:6]) * 0.1, to_world(m[..., 6:9]) * 0.1
        if self.world:
            w, u = w + m[..., 9:12], u + m[..., 12:15] * 0.1
        pivot = medial + o
        carried = torch.sigmoid(m[..., -1:]) if self.carried_arms else None  # (B, N, 1)
        if smooth is not None:
            if carried is None:
                w, pivot, u = smooth(torch.cat([w, pivot, u], dim=-1)).split(3, dim=-1)
            else:
                w, pivot, u, carried = smooth(torch.cat([w, pivot, u, carried], dim=-1)).split([3, 3, 3, 1], dim=-1)
        if repivot > 0:
            ref = (r if r_ref is None else r_ref.reshape(-1, 1, 1)).clamp(min=1e-6)
            pivot, u_ref = absorb_translation(w * ref, pivot, u * ref, repivot)
            u = u_ref / ref
        m = RigidMotion(w * r, pivot, u * r)
        # in training the bands' motions are not moved by the arms' errors (they have their own targets, and an
        # SVD's gradient is unstable where the band's spread is alike along two axes)
        return m if carried is None else carry_arms(v_src, coords, m, carried, detach=self.training)


class RigidMotion(NamedTuple):
    """Per vertex (B, N, 3) each: rotation vector w, pivot p, translation u (world axes):
    x' = x + (R(w) - I)(x - p) + u."""

    w: torch.Tensor
    pivot: torch.Tensor
    u: torch.Tensor


# Arms carried by the chest (`carry_arms`): per arm (column of surface.coords: the hand's geodesic distance over the
# height; the arm is wholly carried up to this distance, not at all from this one). On training characters in bind an
# elbow bend moves nothing past 0.35 and the shoulder joint lies at ~0.35-0.40
ARM_CARRIED = {"arm_left": (2, 0.32, 0.42), "arm_right": (3, 0.32, 0.42)}
# The chest band that carries them: geodesic distance over the height from the head top in [0.22, 0.32), from the
# torso centre in [0.15, 0.30), from each hand at least 0.40: the upper chest and back below the neck, distances the
# arms' rest barely changes (of the vertices in it in bind or in another rest, in both: T-pose 45-90 %, armsDown
# 74-94 %, armsHigh 70-92 %, 100-486 vertices, on 8 persons; bands located by the hands' distances: T-pose
# 15-66 %). Of the bands tried on 23 training characters in their 7 rests, it carries the arms
# 40 / 43 mm from the truth in spineBendFw / spineTwistLf (156 / 277 not carried) while the arms' and the neck's own
# poses barely move it (clavicle 6.5, shoulder raise 3.5, neck turn 0.8 mm mean; the arms it carries lie 2.5 mm off
# in the neck turn). The spine bends over several joints: bands nearer the neck carry the arms better in the spine
# poses and worse in the neck's (19 / 26 and 13 mm)
CHEST_BAND = {"head": (1, 0.22, 0.32), "centre": (0, 0.15, 0.30), "hand_left": (2, 0.40, 9.0),
              "hand_right": (3, 0.40, 9.0)}
CARRIER_MIN = 3  # band vertices the carrier needs (fewer, as on a mesh without a chest: the arms are not carried)


def chest_band(coords):
    """Mask (..., N) of the chest band (`CHEST_BAND`) among vertices with geodesic coordinates coords (..., N, 6),
    numpy or torch."""
    inside = [(coords[..., col] >= lo) & (coords[..., col] < hi) for col, lo, hi in CHEST_BAND.values()]
    out = inside[0]
    for m in inside[1:]:
        out = out & m
    return out


def carry_arms(v_src: torch.Tensor, coords: torch.Tensor, m: RigidMotion, carried: torch.Tensor | float = 1.0,
               detach: bool = False) -> RigidMotion:
    """The motion `m` with the arms' composed on the chest's: x -> A(L(x)), L an arm's own motion, A the chest band's
    best rigid motion (Kabsch of its vertices moved by `m`, `CHEST_BAND`), blended in from the shoulder
    (`ARM_CARRIED`) and weighed by `carried` (B, N, 1) in [0, 1] (the decoder's say). A spine bend turns the arms
    with the chest, but in an arm's limb frame that turn is another rotation in each rest, and the decoder, which
    reads the frame, learns it for the rests it saw; composed, most of it is the chest's, the same in any rest. Each
    vertex keeps its pivot: the rotation becomes R_A R_L and the translation u_L + (R_A - I)(pivot + u_L - c) +
    (c' - c) (c, c': the band's centroid before and after). A still band (r = 0) composes exactly nothing.
    v_src, coords (B, N, 3 / 6), any vertex subset: with fewer than
    CARRIER_MIN band vertices in it, the motion is left as it is. `detach`: A is not differentiated."""
    moved = apply_motion(v_src, m)
    if detach:
        moved = moved.detach()
    band = chest_band(coords).to(v_src.dtype)[..., None]  # (B, N, 1)
    count = band.sum(1, keepdim=True)  # (B, 1, 1)
    bw = band / count.clamp(min=1.0)
    cx, cy = (bw * v_src).sum(1, keepdim=True), (bw * moved).sum(1, keepdim=True)
    cov = torch.einsum("bni,bnj->bij", bw * (v_src - cx), moved - cy)
    on = ((count[:, 0, 0] >= CARRIER_MIN) & ((band * (moved - v_src)).abs().amax(dim=(1, 2)) > 0)).to(v_src.dtype)
    rot = axis_angle_to_matrix(matrix_to_axis_angle(best_rotation(cov)) * on[:, None])[:, None]  # exactly I if off
    shift = (cy - cx) * on[:, None, None]
    s = 0.0
    for col, full, end in ARM_CARRIED.values():
        t = ((end - coords[..., col]) / (end - full)).clamp(0.0, 1.0)
        s = s + (t * t * (3.0 - 2.0 * t))[..., None]  # (B, N, 1): 1 along an arm, 0 from the shoulder's root on
    s = s.clamp(max=1.0) * carried
    turn = (rot - torch.eye(3, dtype=v_src.dtype, device=v_src.device)).expand(*m.w.shape, 3)
    w_c = matrix_to_axis_angle(rot @ axis_angle_to_matrix(m.w))
    u_c = m.u + torch.einsum("bnij,bnj->bni", turn, m.pivot + m.u - cx) + shift
    return RigidMotion(m.w + s * (w_c - m.w), m.pivot, m.u + s * (u_c - m.u))


def absorb_translation(w: torch.Tensor, pivot: torch.Tensor, u: torch.Tensor, damping: float
                       ) -> tuple[torch.Tensor, torch.Tensor]:
    """The same motion with as little translation as its rotation allows: the pivot moves by
    d = -(A^T A + damping^2 I)^-1 A^T u (A = R(w) - I) and the translation becomes u + A d, so that
    x + A (x - pivot) + u is unchanged; all (B, N, 3). A turn about a vertex's own axis plus a shift fits a
    joint's turn at the trained r as well as the turn about the joint, but scaling r (magnitude 2, a partial gate) turns
    and shifts it the wrong way; about the absorbed pivot it turns about the joint. `damping` (radians) keeps
    vertices that barely turn from taking a far pivot; the part along the axis cannot be absorbed."""
    a = axis_angle_to_matrix(w) - torch.eye(3, dtype=w.dtype, device=w.device)
    at = a.transpose(-1, -2)
    lhs = at @ a + (damping ** 2) * torch.eye(3, dtype=w.dtype, device=w.device)
    d = -torch.linalg.solve(lhs, (at @ u[..., None]))[..., 0]
    return pivot + d, u + (a @ d[..., None])[..., 0]


def best_rotation(cov: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) cross-covariances sum w (x - mx)(y - my)^T -> (..., 3, 3) the proper rotations R that best map
    x onto y (Kabsch: y - my ~ R (x - mx); a reflection is turned into the nearest rotation)."""
    u, _, vt = torch.linalg.svd(cov)
    d = torch.sign(torch.det(vt.transpose(-1, -2) @ u.transpose(-1, -2)))
    fix = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], dim=-1))
    return vt.transpose(-1, -2) @ fix @ u.transpose(-1, -2)


def matrix_to_axis_angle(rot: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotations -> (..., 3) rotation vectors (angle < 180 degrees; exact 0 at the identity). The angle
    is atan2(2 sin, 2 cos), not acos: its gradient stays finite at the identity (training composes rotations)."""
    vee = torch.stack([rot[..., 2, 1] - rot[..., 1, 2], rot[..., 0, 2] - rot[..., 2, 0], rot[..., 1, 0] - rot[..., 0, 1]], -1)
    two_sin = torch.sqrt((vee * vee).sum(-1) + 1e-20)
    theta = torch.atan2(two_sin, rot.diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0)
    return vee * (theta / two_sin)[..., None]  # theta / (2 sin theta) -> 1/2 at the identity


def local_motion_fit(v_src: torch.Tensor, v_moved: torch.Tensor, average, damping: float) -> RigidMotion:
    """The per-vertex motion that the moved surface itself makes: each vertex turns as its neighbourhood does (the
    rotation that best maps the neighbourhood, Kabsch on its weighted covariance), about the pivot that leaves the
    least translation (`absorb_translation`), the translation completing the vertex's exact position. v_src, v_moved
    (B, N, 3); `average`: (B, N, k) -> (B, N, k) weighted neighbourhood means (`heat_averager`, any topology).
    The decoder is supervised on positions at the trained r only, so its own rotation parameters are free wherever
    a translation makes up for them (at twice r the forearm then swings off the elbow's hinge); the fitted motion
    reproduces the same positions at r and scales as the surface turns."""
    b, n, _ = v_src.shape
    outer = (v_src[..., :, None] * v_moved[..., None, :]).reshape(b, n, 9)
    mx, my, mxy = average(torch.cat([v_src, v_moved, outer], dim=-1)).split([3, 3, 9], dim=-1)
    cov = mxy.reshape(b, n, 3, 3) - mx[..., :, None] * my[..., None, :]  # sum w (x - mx)(y - my)^T
    w = matrix_to_axis_angle(best_rotation(cov))
    pivot, t = absorb_translation(w, v_src, v_moved - v_src, damping)
    return RigidMotion(w, pivot, t)


def scale_motion(m: RigidMotion, s: float | torch.Tensor) -> RigidMotion:
    """The motion turned and shifted `s` times as far about the same pivots (0: still)."""
    return RigidMotion(m.w * s, m.pivot, m.u * s)


def apply_motion(v_src: torch.Tensor, m: RigidMotion) -> torch.Tensor:
    """(B, N, 3) source vertices moved by `m` (exactly the source where w = u = 0)."""
    turn = axis_angle_to_matrix(m.w) - torch.eye(3, dtype=m.w.dtype, device=m.w.device)
    return v_src + torch.einsum("bnij,bnj->bni", turn, v_src - m.pivot) + m.u


def mix_motions(motions: list[RigidMotion], weights: list[float]) -> RigidMotion:
    """A weighted mix of motions of one mesh (a pose blend): rotations and translations mix linearly, each
    vertex's pivot is the mix of the pivots weighted by how much each motion turns it. Continuous in the
    weights; a weight of 0 leaves its motion out exactly, so a blend at 0 or 1 is that pose's motion."""
    w = sum(a * m.w for a, m in zip(weights, motions))
    u = sum(a * m.u for a, m in zip(weights, motions))
    turn = [abs(a) * m.w.norm(dim=-1, keepdim=True) + 1e-9 for a, m in zip(weights, motions)]
    pivot = sum(t * m.pivot for t, m in zip(turn, motions)) / sum(turn)
    return RigidMotion(w, pivot, u)


# Distal parts that move as one in every body pose: (column of surface.coords, the geodesic distance from the
# part's extremity, over the height, up to which it is fully rigid, and where the blend back ends). The hand
# stops short of the wrist (a wrist flex turns it); the foot short of the heel and ankle (toes to mid-foot:
# fingertip and toe tip are the extremities, the wrist lies at ~0.11 H, the heel at 0.12-0.16 H).
RIGID_PARTS = {"hand_left": (2, 0.07, 0.10), "hand_right": (3, 0.07, 0.10),
               "foot_left": (4, 0.09, 0.13), "foot_right": (5, 0.09, 0.13)}


def part_rigidifier(coords, parts: dict[str, tuple[int, float, float]] | None = None, prior: float = 1.0,
                    anchor: float = 0.0):
    """A function (v_src (B, N, 3), motion: RigidMotion) -> (B, N, 3) moved vertices, in which each distal part
    (hands and feet, located by the geodesic coordinates `coords` (N, 6) of `latent_model/surface.py`, any topology)
    moves by the best rigid fit (weighted Kabsch) of its predicted positions, blended back to the prediction
    towards the part's border. Neighbour averaging still leaves a hand or a foot bent and crumpled (toes folded at
    a full knee bend); a part's bones do not bend. A foot or a hand is long and thin, so its turn about its long
    axis is barely determined by crumpled positions: `prior` (a fraction of the part's spread) pulls the fit to a
    prior turn: with `anchor` 0, the part's mean predicted rotation vector; with `anchor` > 0, the turn of the limb
    carrying the part (Kabsch of the predicted band from the part's edge to `anchor`, over the height, beyond it:
    the forearm, the shank). The decoder's rotation vectors are free wherever translations make up for them: as a
    prior they turned the validation characters' moving hands and feet 28 degrees (median) off the truth, the limb's
    turn 9. A still prediction (magnitude 0) is returned exactly."""
    import numpy as np

    c = np.asarray(coords, dtype=np.float64)
    table = RIGID_PARTS if parts is None else parts
    weights = []  # per part: (indices, weights 1 in the core falling to 0 at the edge, indices of the limb band)
    for col, core, edge in table.values():
        t = np.clip((edge - c[:, col]) / max(edge - core, 1e-9), 0.0, 1.0)
        s = t * t * (3.0 - 2.0 * t)  # smoothstep: 1 in the core, 0 past the edge
        idx = np.flatnonzero(s > 0)
        band = np.flatnonzero((c[:, col] >= edge) & (c[:, col] < edge + anchor))
        if len(idx) >= 3:
            weights.append((torch.from_numpy(idx), torch.from_numpy(s[idx]).float(),
                            torch.from_numpy(band) if len(band) >= 3 else None))

    def kabsch(w: torch.Tensor, x: torch.Tensor, y: torch.Tensor):
        """Weights (B, n, 1) summing to 1, x, y (B, n, 3) -> centroids (B, 1, 3) x2, cross-covariance and spread."""
        cx, cy = (w * x).sum(1, keepdim=True), (w * y).sum(1, keepdim=True)
        h = torch.einsum("bni,bnj->bij", w * (x - cx), y - cy)  # = C R^T for y = R x
        spread = torch.einsum("bni,bni->b", w * (x - cx), x - cx)[:, None, None]
        return cx, cy, h, spread

    def rigidify(v_src: torch.Tensor, m: RigidMotion) -> torch.Tensor:
        v_pred = apply_motion(v_src, m)
        out = v_pred.clone()
        for idx, s, band in weights:
            x, y = v_src[:, idx], v_pred[:, idx]
            if not bool((y != x).any()):
                continue
            sx = s.to(x)[None, :, None]
            w = sx / sx.sum()
            cx, cy, h, spread = kabsch(w, x, y)
            if band is None:
                prior_rot = axis_angle_to_matrix((w * m.w[:, idx]).sum(1))  # (B, 3, 3)
            else:
                uniform = torch.full((1, len(band), 1), 1.0 / len(band), dtype=x.dtype, device=x.device)
                prior_rot = best_rotation(kabsch(uniform, v_src[:, band], v_pred[:, band])[2])
            h = h + prior * spread / 3.0 * prior_rot.transpose(1, 2)
            rot = best_rotation(h)  # (B, 3, 3): y - cy ~ rot (x - cx)
            rigid = torch.einsum("bij,bnj->bni", rot, x - cx) + cy
            out[:, idx] = y + sx * (rigid - y)
        return out

    return rigidify


def surface_smoother(faces, n_vertices: int, iterations: int):
    """A function (B, N, k) -> (B, N, k): `iterations` rounds of averaging each vertex with its edge
    neighbours (N = n_vertices, any topology); None when iterations is 0."""
    import numpy as np
    import scipy.sparse as sp

    if iterations <= 0:
        return None
    f = np.asarray(faces, dtype=np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    a = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n_vertices, n_vertices)).tocsr()
    a = ((a + a.T) > 0).astype(np.float64) + sp.eye(n_vertices)
    a = (sp.diags(1.0 / np.asarray(a.sum(axis=1)).ravel()) @ a).tocsr().astype(np.float32)
    # compressed rows: 30x faster than COO for these 40 products (0.1 s -> 3 ms on 14k vertices)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "CSR support is in beta"
        op = torch.sparse_csr_tensor(torch.from_numpy(a.indptr).long(), torch.from_numpy(a.indices).long(),
                                     torch.from_numpy(a.data), (n_vertices, n_vertices))

    def smooth(x: torch.Tensor) -> torch.Tensor:
        b, n, k = x.shape
        y = x.permute(1, 0, 2).reshape(n, b * k)
        for _ in range(iterations):
            y = op @ y
        return y.reshape(n, b, k).permute(1, 0, 2)

    return smooth


def heat_averager(vertices, faces, radius: float):
    """A function (B, N, k) -> (B, N, k): weighted means over surface balls of about `radius` (metres), any topology
    and resolution: one backward-Euler heat step (I + t L)^-1 with edge rates 1 / length^2 and t = radius^2 / 6 (a
    triangle mesh's ~6 edges then spread the heat by `radius`). Its weights are positive and sum to 1 per vertex,
    they stay on the surface (an arm hanging against the torso does not mix with it, as a Euclidean ball would);
    the sparse factorisation is made once (0.3-0.6 s on 14k vertices), each call is one solve (tens of ms)."""
    import numpy as np
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from latent_model.topology import mesh_edges

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    e = mesh_edges(f)
    rate = 1.0 / np.maximum(((v[e[:, 0]] - v[e[:, 1]]) ** 2).sum(1), 1e-8)
    n = len(v)
    w = sp.coo_matrix((np.concatenate([rate, rate]), (np.concatenate([e[:, 0], e[:, 1]]), np.concatenate([e[:, 1], e[:, 0]]))),
                      shape=(n, n)).tocsr()
    lap = sp.diags(np.asarray(w.sum(axis=1)).ravel()) - w
    lu = spla.splu((sp.eye(n) + (radius ** 2 / 6.0) * lap).tocsc())

    def average(x: torch.Tensor) -> torch.Tensor:
        b, m, k = x.shape
        y = lu.solve(x.detach().permute(1, 0, 2).reshape(m, b * k).cpu().double().numpy())
        return torch.from_numpy(y).to(x).reshape(m, b, k).permute(1, 0, 2)

    return average
