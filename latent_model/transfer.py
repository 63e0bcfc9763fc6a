"""The Transfer API: the one code path from a mesh to a prediction.

(target mesh, pose [+ pose B and blend], strategy, magnitude scale, pair kind) -> vertices.
Strategies (`latent_model.types`): ``mean_pose_delta`` (Δμ averaged over training identities),
``nearest_identity_delta`` (the delta of the training identity whose source state is nearest in
standardised latent space), ``identity:<id>`` (a chosen training identity's delta) and ``oracle``
(the target's own delta; an upper bound for analysis, needs the true target's latent). The CLI,
the evaluation, the tests and the explorer all call `Transfer.predict`.

What runs depends on the pair kind: a model with the motion decoder (decoder v2, `MotionDecoderConfig`)
predicts its kinds with it, from the mesh's latent, normals and surface features; otherwise the kinds in
`PoseFieldsConfig.only_kinds` (`neutral_to_pose` in the shipped model) are predicted by the closed-form
pose fields alone, from the mesh's positions and the delta; the other kinds by the vertex decoder
network, which also reads the mesh's latent, normals and neighbourhoods. A `PreparedMesh` computes each of those only when something reads it.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from latent_model.bank import LatentBank
from latent_model.corpus.pairs import split_bank_key
from latent_model.corpus.poses import get_pose
from latent_model.corpus.sdf import body_component_faces, sample_sdf
from latent_model.detail_poses import detail_regions_of
from latent_model.motion_prediction import MotionPredictor, delta_condition
from latent_model.nn.pose_fields import FieldCache
from latent_model.noise_gate import GATE_HI, GATE_LO, smooth_gate
from latent_model.prepared_mesh import PreparedMesh
from latent_model.registration import SETTLE_LIMIT
from latent_model.surface import HAND_REACH_MIN, joined_hands
from latent_model.types import (PairKind, Predictor, Strategy, check_blend, check_magnitude, check_pair_kind,
                                 parse_strategy)

if TYPE_CHECKING:
    from latent_model.corrective_fields import CorrectiveFields
    from latent_model.detail import LocalDetailModel
    from latent_model.registration import Correspondence

__all__ = ["BodyReading", "GATE_HI", "GATE_LO", "Novelty", "PreparedMesh", "Transfer", "TransferOutput", "parse_strategy"]

CORRECTIVE_KIND = "skinning_to_skinning_plus_blendshape"
# an example pair's body motion is read as a mix of the vocabulary's body poses when the mix makes at least this
# much of it on the example's own mesh (validation, 11 example deformations: the read transferred 0.42-0.89 where
# it explained >= 0.40 there, the decoder's reading of the latent delta 0.20-0.88; below, -0.2 to 0: a joint or
# axis no pose moves, where the decoder's reading stays)
READ_MIN = 0.3
READ_MAX, READ_DROP = 2.0, 0.05  # a pose read up to twice its own motion; a weight under READ_DROP is dropped


def read_weights(cols: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(P,) weights in {0} or [READ_DROP, READ_MAX] of the columns `cols` (N, P) whose mix best makes `target` (N,):
    bounded least squares, the weights under READ_DROP (what one character's noise reads as) dropped and the rest
    refitted until the refit leaves none small (a refit can put one near 0 too: a wrist twist read as
    "neckTurnRt 0.00")."""
    from scipy.optimize import lsq_linear

    keep = lsq_linear(cols, target, bounds=(0.0, READ_MAX)).x >= READ_DROP
    while True:
        w = np.zeros(cols.shape[1])
        if keep.any():
            w[keep] = lsq_linear(cols[:, keep], target, bounds=(0.0, READ_MAX)).x
        small = keep & (w < READ_DROP)
        if not small.any():
            return w
        keep &= ~small


@dataclass(frozen=True)
class BodyReading:
    """What an example pair's body motion reads as: {pose: weight} of the vocabulary's single body poses whose
    motions on the example's own neutral mesh, mixed, best make its deformation (`Transfer.example_body`), and
    how much of that deformation the mix makes there (1 - mean error / mean motion: 1 = all of it)."""

    weights: dict[str, float]
    explained: float

    @property
    def used(self) -> bool:
        """Whether a prediction moves by the read (else the decoder reads the pair's latent delta)."""
        return self.explained >= READ_MIN

    def describe(self) -> str:
        from latent_model.detail import describe_mix

        mix = describe_mix(self.weights) if self.weights else "no pose"
        return f"{mix} (makes {self.explained:.2f} of the example's motion on its own mesh)"


@dataclass
class TransferOutput:
    vertices: np.ndarray  # (V, 3) the prediction: the motion scaled by the noise gate (source + gate * displacement
    # for the other predictors); a blend weighs each pose by its own gate
    raw: np.ndarray  # (V, 3) the predictor's output, ungated
    gate: float  # noise gate in [0, 1] (0 also when magnitude is 0)
    signal: float  # ||standardised delta|| / its sampling noise (`Transfer.noise_gate`; inf without a measured floor)
    label: str  # where pose A's delta came from: "mean", an identity id, "oracle" or "example"
    predictor: Predictor  # what produced `raw`
    novelty: "Novelty | None" = None  # how far the mesh's latent is from training (when its latent was read)
    detail: dict[str, float] = field(default_factory=dict)  # the local detail stage's gate per region it moved
    # {region: {pose: weight}}: the training poses each region's delta read as (slider weights and magnitude in)
    detail_mix: dict[str, dict[str, float]] = field(default_factory=dict)
    note: str | None = None  # something the user should know about this prediction (a stage that could not run)


@dataclass(frozen=True)
class Novelty:
    """Standardised latent distance of a mesh to the nearest training state, against the bank's
    threshold (the farthest validation character's): beyond it, the prediction is extrapolation."""

    distance: float
    threshold: float  # 0: the bank has no calibrated threshold (no warning)
    posed: bool = False  # judged as a posed source (its threshold: the farthest validation posed state)
    joined: tuple[tuple[str, float], ...] = ()  # hands the surface joins to the body: (name, reach) (`joined_hands`)

    @property
    def out_of_distribution(self) -> bool:
        return self.threshold > 0 and self.distance > self.threshold

    def warning(self, name: str = "the mesh") -> str | None:
        """A one-line warning for the user, or None when the mesh is within the validated range."""
        out = []
        if self.out_of_distribution:
            what = "the farthest validation character's posed state" if self.posed else "the farthest validation character"
            out.append(f"warning: {name} is out of distribution: its latent is {self.distance:.1f} from the nearest "
                       f"training state, beyond {self.threshold:.1f} ({what}); expect a poor prediction. "
                       f"Check its units, up axis and that it is one humanoid standing")
        if self.joined:
            side = lambda k: " ".join(reversed(k.split("_")))  # noqa: E731  hand_left -> left hand
            hands = " and ".join(f"{side(k)} ({r:.2f}x as far from the torso over the surface as the head)"
                                 for k, r in self.joined)
            out.append(f"warning: {name}: its surface joins the {hands} to the body (every training character's hands "
                       f"reach >= {HAND_REACH_MIN:.2f}x); arm motions will pull what the hands touch. Open the mesh with "
                       f"a gap between the hands and the body (its rest pose, or separate shells)")
        return " ".join(out) or None


class Transfer:
    def __init__(self, model, bank: LatentBank, sdf_k: int, device: torch.device | None = None,
                 detail: "LocalDetailModel | None" = None, correctives: "CorrectiveFields | None" = None) -> None:
        self.model = model.eval()
        self.bank = bank
        self.sdf_k = sdf_k
        self.device = device or torch.device("cpu")
        self.model.to(self.device)
        self.motion = MotionPredictor(self.model, self.device)  # decoder v2's motions, when the model has it
        self.detail = detail  # the local detail stage (faces, fingers), when the model has one
        self.correctives = correctives  # the corrective fields (skinning -> skinning+blendshape), when it has them

    @classmethod
    def from_files(cls, checkpoint: str | Path, bank: str | Path, device: torch.device | None = None,
                   detail: str | Path | None = "beside", correctives: str | Path | None = "beside") -> "Transfer":
        """`detail`: a local detail file, "beside" (the checkpoint's `detail.safetensors` if there is one) or None;
        `correctives` the same for the corrective fields (`correctives.safetensors`)."""
        from latent_model.checkpoint import load_checkpoint
        from latent_model.corrective_fields import CorrectiveFields, correctives_beside
        from latent_model.detail import LocalDetailModel, detail_beside

        model, preset, _ = load_checkpoint(checkpoint)
        path = detail_beside(checkpoint) if detail == "beside" else detail
        fields = correctives_beside(checkpoint) if correctives == "beside" else correctives
        return cls(model, LatentBank.load(bank), preset.corpus.sdf.k, device,
                   None if path is None else LocalDetailModel.load(path),
                   None if fields is None else CorrectiveFields.load(fields))

    # ------------------------------------------------------------------ per mesh
    @torch.no_grad()
    def encode(self, vertices: np.ndarray, sdf_faces: np.ndarray, seed: int = 0) -> np.ndarray:
        """(Z,) posterior mean of a mesh's SDF samples (K of the model's preset)."""
        from latent_model.corpus.sdf import SdfSampling
        from latent_model.encoding import encode_sample_sets

        cfg = replace(SdfSampling(), k=self.sdf_k)
        return encode_sample_sets(self.model, [seed], lambda s: sample_sdf(np.asarray(vertices, np.float64),
                                                                            sdf_faces, cfg, s), self.device)[0]

    def prepare(self, vertices: np.ndarray, faces: np.ndarray, sdf_faces: np.ndarray | None = None,
                mu: np.ndarray | None = None, seed: int = 0, surface=None) -> PreparedMesh:
        """A mesh (in the model frame) ready for `predict`; `mu` when its latent is known already, `surface` its
        `surface.SurfaceFeatures` when they are (`surface_cache`: a corpus state's, kept on disk).
        Only the SDF shell (the body component, unless given) is found now: the latent, normals and
        neighbourhoods follow on first read."""
        v = np.asarray(vertices, dtype=np.float32)
        f = np.asarray(faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4:
            raise ValueError(f"vertices must be (V >= 4, 3), got {v.shape}")
        if not np.isfinite(v).all():
            raise ValueError("the mesh has NaN or infinite vertex coordinates; fix or re-export it")
        if sdf_faces is None:
            sdf_faces = body_component_faces(v.astype(np.float64), f)
        return PreparedMesh(v, f, sdf_faces, self.model.cfg.decoder.knn,
                            lambda vv, ff: self.encode(vv, ff, seed), mu, surface)

    def prepare_user_mesh(self, mesh, seed: int = 0) -> PreparedMesh:
        """`prepare` of a user's mesh (`meshio.UserMesh`), with the latent it carries when it was encoded with the
        same seed (`facing.face_front` encodes with seed 0): a mesh is encoded once on load."""
        return self.prepare(mesh.vertices, mesh.faces, sdf_faces=mesh.sdf_faces, seed=seed,
                            mu=mesh.mu if seed == 0 else None)

    # ------------------------------------------------------------------ conditioning
    def delta(self, mesh: PreparedMesh, pose: str, strategy: Strategy, kind: PairKind = "neutral_to_pose",
              oracle_target_mu: np.ndarray | None = None) -> tuple[np.ndarray, str]:
        """Raw latent delta (Z,) for a pose (a bank key), and a label of where it came from."""
        check_pair_kind(kind)
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

    def example_delta(self, neutral: PreparedMesh, posed: PreparedMesh) -> np.ndarray:
        """(Z,) latent delta of an example pair (a character and the same mesh deformed): mu(posed) - mu(neutral).
        Prepare both with the same seed: with one topology the SDF samples then move with the surface and most
        of the sampling noise cancels in the difference."""
        if len(neutral.vertices) != len(posed.vertices) or not np.array_equal(neutral.faces, posed.faces):
            raise ValueError(f"the example pair must share one topology: the neutral has {len(neutral.vertices)} vertices "
                             f"and {len(neutral.faces)} triangles, the posed {len(posed.vertices)} and {len(posed.faces)}")
        return posed.mu - neutral.mu

    def body_poses(self) -> list[str]:
        """The single body poses of the bank's neutral_to_pose deltas (the poses an example's motion reads as)."""
        return [p for p in self.bank.poses("neutral_to_pose")
                if not get_pose(p).is_combo and not detail_regions_of(p)]

    @torch.no_grad()
    def example_body(self, neutral: PreparedMesh, posed: PreparedMesh) -> BodyReading | None:
        """An example pair's body motion read as the vocabulary's single body poses (`BodyReading`): each pose's
        motion on the example's neutral mesh (the mean delta, the motion decoder), the non-negative weights (up to
        READ_MAX each) whose mixed displacements best make the pair's, the mix then made by the decoder's motions
        (as a blend) and measured against the posed mesh. The decoder reading the pair's latent delta, one person's
        combination of joints, moved the wrong limbs (validation: three joints at once 0.25-0.28 explained, 25 mm
        leak; read as poses 0.79-0.89); a pose's motion is what it learned. None without the motion decoder."""
        if self.predicts_with("neutral_to_pose") != "motion":
            return None
        self.example_delta(neutral, posed)  # one topology, or the error that says so
        v = neutral.vertices.astype(np.float64)
        target = posed.vertices.astype(np.float64) - v
        motion = float(np.linalg.norm(target, axis=1).mean())
        if motion == 0.0:
            return BodyReading({}, 1.0)
        poses = self.body_poses()
        cols = np.stack([(self.motion.scaled(neutral, [self._mean_condition(p)], [1.0]) - v).ravel()
                         for p in poses], axis=1)
        w = read_weights(cols, target.ravel())
        weights = {p: float(x) for p, x in zip(poses, w) if x > 0}
        made = self._read_motion(neutral, weights, 1.0)
        return BodyReading(weights, 1.0 - float(np.linalg.norm(made - posed.vertices, axis=1).mean()) / motion)

    def _mean_condition(self, pose: str, kind: PairKind = "neutral_to_pose") -> tuple:
        """(direction, r, kind, averaged) of a pose's mean delta, as the motion decoder reads it."""
        d = self.bank.mean_delta(kind, pose)
        return self.motion.condition(d, kind, self.averaged(pose, "mean_pose_delta", kind))

    def _read_motion(self, mesh: PreparedMesh, weights: dict[str, float], scale: float,
                     extra: list[tuple[tuple, float]] = ()) -> np.ndarray:
        """(V, 3) the mesh moved by a `BodyReading`'s poses' motions times their weights and `scale`, mixed with the
        `extra` [(condition, scale)] (a blend's pose B)."""
        conditions = [self._mean_condition(p) for p in weights] + [c for c, _ in extra]
        return self.motion.scaled(mesh, conditions, [w * scale for w in weights.values()] + [x for _, x in extra])

    def example_detail(self, neutral: PreparedMesh, posed: PreparedMesh) -> dict[str, np.ndarray] | None:
        """{region: delta} of an example pair for the local detail stage (None without one): the posed mesh's
        head and hands sampled co-moving with the neutral's, a hand read from its own motion
        (`LocalDetailModel.example_reading`)."""
        if self.detail is None:
            return None
        return self.detail.example_reading(self.regions(neutral), posed.vertices.astype(np.float64))

    def example_corrective(self, neutral: PreparedMesh, posed: PreparedMesh) -> dict[str, float] | None:
        """{pose: weight} an example pair's corrective (a skinned mesh -> the same with its corrective shapes) reads
        as in the corrective fields (`CorrectiveFields.read`); None without fields or when the pair is not anny's
        topology (the fields follow its vertices)."""
        if self.correctives is None or self.correctives.available(neutral.vertices, neutral.faces) is not None:
            return None
        return self.correctives.read(neutral.vertices, posed.vertices)

    def regions(self, mesh: PreparedMesh):
        """The mesh's detail regions and their codes (`detail.MeshRegions`), once per mesh."""
        return mesh.cache("detail_regions", "cpu", lambda: self.detail.regions(
            mesh.vertices, mesh.faces, mesh.sdf_faces, mesh.surface))

    def novelty(self, mesh: PreparedMesh, kind: PairKind = "neutral_to_pose") -> Novelty:
        """How far the mesh's latent lies from every training state (encodes the mesh if not yet done), against the
        threshold of a source of pair kind `kind` (a neutral's, or a posed source's)."""
        # the distance once per mesh (27k training states: not at every slider move); the threshold as it is now
        distance = mesh.cache("novelty", f"bank:{id(self.bank)}", lambda: self.bank.distance_to_training(mesh.mu))
        posed = kind != "neutral_to_pose" and self.bank.ood_threshold_posed > 0
        # hands joined to the body, read from the surface features when a predictor derived them (decoder v2 does)
        joined = tuple(joined_hands(mesh.surface).items()) if "surface" in mesh.derived() else ()
        return Novelty(distance, self.bank.threshold_for(kind), posed, joined)

    def judged_novelty(self, out: TransferOutput, mesh: PreparedMesh, kind: PairKind) -> Novelty | None:
        """A prediction's novelty for the user: its own when it read the latent, else the mesh's against its kind's
        threshold (encoding it once), or None when the bank cannot judge or nothing read a latent (the corrective
        fields without the nearest identity read the region's shape only)."""
        if out.novelty is not None:
            return out.novelty
        if self.bank.ood_threshold <= 0 or (out.predictor == "correctives" and "mu" not in mesh.derived()):
            return None
        return self.novelty(mesh, kind)

    def noise_gate(self, delta: np.ndarray, averaged: float = 1.0) -> tuple[float, float]:
        """(gate in [0, 1], signal) for a raw delta. signal = ||standardised delta|| / its noise: the bank's
        noise floor (the sampling noise of one delta, so a delta of noise alone has signal ~1, the paper's
        R_cond/noise) divided by sqrt(averaged) for a mean of that many independent deltas (the mean over 112
        training characters has a tenth of one delta's noise). Below GATE_LO the condition carries no
        information a predictor could use, so the honest answer is no motion; above GATE_HI it passes
        untouched; smoothstep in between."""
        floor = self.bank.noise_floor
        if floor <= 0:  # a bank without a measured noise floor: no gate
            return 1.0, float("inf")
        signal = float(np.linalg.norm(np.asarray(delta) / self.bank.scale)) / floor * float(np.sqrt(averaged))
        return smooth_gate(signal), signal

    def averaged(self, pose: str | None, strategy: Strategy, kind: PairKind) -> int:
        """How many training deltas a strategy's delta averages (the mean strategy: all of the pose's; else 1)."""
        if pose is None or parse_strategy(strategy) != "mean_pose_delta":
            return 1
        return len(self.bank.delta(kind, pose)[0])

    def predicts_with(self, kind: PairKind) -> Predictor:
        """"correctives", "motion", "pose_fields" or "network": what predicts this pair kind (an example pair's
        corrective too: the fields read it as their poses, `example_corrective`)."""
        check_pair_kind(kind)
        if self.correctives is not None and kind == CORRECTIVE_KIND:
            return "correctives"
        if self.model.motion_decoder is not None and kind in self.model.cfg.motion.kinds:
            return "motion"
        return "pose_fields" if self.model.pose_fields.predicts_alone(kind) else "network"

    def predict(self, mesh: PreparedMesh, pose: str | None, strategy: Strategy = "mean_pose_delta", magnitude: float = 1.0,
                kind: PairKind = "neutral_to_pose", pose_b: str | None = None, blend: float = 0.0,
                oracle_target_mu: np.ndarray | None = None, oracle_target_mu_b: np.ndarray | None = None,
                delta: np.ndarray | None = None, detail_delta: dict[str, np.ndarray] | None = None,
                corrective_mix: dict[str, float] | None = None, body_reading: BodyReading | None = None) -> np.ndarray:
        """(V, 3) float32 predicted vertices (`predict_detail(...).vertices`)."""
        return self.predict_detail(mesh, pose, strategy, magnitude, kind, pose_b, blend, oracle_target_mu,
                                   oracle_target_mu_b, delta, detail_delta, corrective_mix, body_reading).vertices

    @torch.no_grad()
    def predict_detail(self, mesh: PreparedMesh, pose: str | None, strategy: Strategy = "mean_pose_delta",
                       magnitude: float = 1.0, kind: PairKind = "neutral_to_pose", pose_b: str | None = None,
                       blend: float = 0.0, oracle_target_mu: np.ndarray | None = None,
                       oracle_target_mu_b: np.ndarray | None = None, delta: np.ndarray | None = None,
                       detail_delta: dict[str, np.ndarray] | None = None,
                       corrective_mix: dict[str, float] | None = None,
                       body_reading: BodyReading | None = None) -> TransferOutput:
        """The prediction with its parts. `blend` in [0, 1] mixes pose A's delta toward pose B's;
        `magnitude` in [0, 2] scales r_Δ (0 = no motion requested: the source exactly, 1 = as
        conditioned, 2 = doubled). The displacement is scaled by the noise gate of the delta.
        `delta`: pose A's raw latent delta given directly (an example pair's, `example_delta`) instead of
        the strategy's; `pose` may then be None; `detail_delta` its region deltas (`example_detail`),
        `corrective_mix` its corrective read as the corrective fields' poses (`example_corrective`; None: unread, no
        corrective then, said so — the network's reading of a corrective's delta explained less than no motion),
        `body_reading` its body motion read as the vocabulary's body poses (`example_body`; neutral_to_pose by the
        motion decoder): when the read makes enough of the example (`BodyReading.used`) the body moves by those
        poses' motions, else the decoder reads `delta`; the note says which.
        With a local detail stage, `neutral_to_pose` adds what a face or finger pose does inside the head and
        hands, `source_to_combo` what the combination's added face poses do (`_detail_parts`, `_add_detail`)."""
        magnitude, blend = check_magnitude(magnitude), check_blend(blend)
        if self.predicts_with(kind) == "correctives":
            example = delta is not None or corrective_mix is not None
            return self._corrective_prediction(mesh, pose, strategy, magnitude, pose_b, blend,
                                               (corrective_mix or {}) if example else None)
        if delta is not None:
            d, label = np.asarray(delta, np.float32), "example"
        elif pose is None:
            raise ValueError("predict needs a pose (or an example pair's delta)")
        else:
            d, label = self.delta(mesh, pose, strategy, kind, oracle_target_mu)
        n = 1 if delta is not None else self.averaged(pose, strategy, kind)
        d_b = self.delta(mesh, pose_b, strategy, kind, oracle_target_mu_b)[0] if pose_b is not None and blend > 0 else None
        n_b = self.averaged(pose_b, strategy, kind) if d_b is not None else 1
        predictor = self.predicts_with(kind)
        body = (not self._local_only(None if delta is not None else pose, kind),
                not self._local_only(pose_b if d_b is not None else None, kind))
        note = None
        read = body_reading if delta is not None and kind == "neutral_to_pose" and predictor == "motion" else None
        if read is not None and read.used:
            raw, gate, signal = self._read_prediction(mesh, read, d, None if d_b is None else (d_b, n_b), blend,
                                                      magnitude, kind, body[1])
            gated = raw
            note = f"the example's body motion reads as {read.describe()}"
        elif predictor == "motion":
            raw, gated, gate, signal = self._motion_prediction(mesh, (d, n), None if d_b is None else (d_b, n_b),
                                                               blend, magnitude, kind, body)
            if read is not None:
                note = (f"the example's body motion is no mix of the vocabulary's body poses ({read.describe()}): "
                        "the decoder reads its latent delta")
        else:
            averaged = n
            if d_b is not None:
                d = (1.0 - blend) * d + blend * d_b
                averaged = 1.0 / ((1.0 - blend) ** 2 / n + blend ** 2 / n_b)  # the mix's noise, independent deltas
            gate, signal = self.noise_gate(d, averaged)
            if magnitude == 0 or not any(body):
                gate = 0.0
            raw = self._fields_or_network(mesh, predictor, d, magnitude, kind)
            gated = raw if gate == 1.0 else (mesh.vertices + np.float32(gate) * (raw - mesh.vertices)).astype(np.float32)
        detail_gates: dict[str, float] = {}
        mix: dict[str, dict[str, float]] = {}
        parts: list = []
        if self.detail is not None and kind in ("neutral_to_pose", "source_to_combo"):
            person = None if label in ("mean", "oracle", "example") else label.split("@")[0]
            w_a = 1.0 - blend if d_b is not None else 1.0
            if delta is not None:  # an example pair's region deltas: neutral -> posed
                parts = [((detail_delta or {}, 1), w_a)] if kind == "neutral_to_pose" else []
            else:
                parts = [(part, w_a * w) for part, w in self._detail_parts(pose, kind, person)]
            if d_b is not None:
                parts += [(part, blend * w) for part, w in self._detail_parts(pose_b, kind, person)]
            raw, gated, detail_gates, mix = self._add_detail(mesh, raw, gated, parts, magnitude,
                                                             self._held(pose, kind) if delta is None else ())
        if kind == "source_to_combo" and not all(body) and not any(d for (d, _), _ in parts):
            note = ("what the combination adds to its posed part is face or finger poses: the body decoder does not move "
                    "them, and " + ("this model has no local detail stage" if self.detail is None
                                    else "the local detail stage holds none of them"))
        # once per mesh: the distance to 27k training states would otherwise run at every slider move
        novelty = self.novelty(mesh, kind) if "mu" in mesh.derived() else None
        return TransferOutput(gated, raw, gate, signal, label, predictor, novelty, detail_gates, mix, note)

    def _corrective_prediction(self, mesh: PreparedMesh, pose: str | None, strategy: Strategy, magnitude: float,
                               pose_b: str | None, blend: float, example: dict[str, float] | None = None
                               ) -> TransferOutput:
        """The corrective of a skinned mesh: source + magnitude × the slider mix of each pose's corrective fields (a
        combo: the sum of its components', as the rig adds them), read from the mesh's own region shape. The fields
        read no latent delta, so there is no noise gate (gate 1) and the oracle is the mean; the nearest-identity
        strategy reads the nearest training identity's own samples (its rests) when one is as alike as the pooled
        read's (`PoseCorrective.nearest`), and says so when not. `example`: pose A is an example pair's corrective
        read as the fields' poses ({pose: weight}, `example_corrective`; empty: unread, no corrective, said so)."""
        if pose is None and example is None:
            raise ValueError("predict needs a pose (or an example pair's delta)")
        s = parse_strategy(strategy)
        person, label = None, "mean" if s != "oracle" else "oracle"
        named = pose_b if example is not None else pose  # the pose the strategy reads (a blend's B with an example)
        if named is not None and s == "nearest_identity_delta":
            label = self.bank.nearest_identity(CORRECTIVE_KIND, named, mesh.mu)[0]
            person = label.split("@")[0]
        elif s.startswith("identity:"):
            label = s.split(":", 1)[1]
            person = label.split("@")[0]
        fields = self.correctives
        other = self._topology_note(mesh)
        note = other if example is not None else None  # another topology reads anny's through a registered template
        if example is not None and not example and note is None:
            note = ("no corrective read from the example pair: the corrective fields follow anny's topology by vertex "
                    "index, and the example's meshes are not it (or hold no corrective)")
        v = mesh.vertices.astype(np.float64)
        out = np.zeros_like(v)
        w_a = 1.0 - blend if pose_b is not None else 1.0
        a = [(pose, w_a, person)] if example is None else [(p, w_a * x, None) for p, x in example.items()]
        moved, pooled, registered = False, [], []
        for name, w, who in a + ([(pose_b, blend, person)] if pose_b is not None else []):
            parts = [c for c in (get_pose(name).components or (name,)) if fields.has(c)]
            if not parts or note is not None or w * magnitude == 0:
                continue
            view = self._anny_view(mesh, name) if other is not None else None
            if view is not None:
                settled = view.settled(fields.poses[parts[0]].index)
                if settled > SETTLE_LIMIT:
                    note = (f"no corrective: anny's template, fitted to this mesh (another topology than anny's), had to "
                            f"move {settled:.0f} mm to lie on its {name} region; a read from it would be a guess")
                    continue
            source = v if view is None else view.on_mesh(v, mesh.faces)  # anny's vertices, on this mesh
            for c in parts:
                d, own = fields.displacement(source, c, who)
                out += w * magnitude * (d if view is None else view.to_mesh(d))
                moved = True
                if who is not None and not own:
                    pooled.append(c)
            if view is not None:
                registered.append(view.residual_mm)
        if pooled:
            note = f"{label}'s own samples are unlike this mesh ({', '.join(pooled)}): the pooled read"
        if registered and note is None:
            note = (f"another topology than anny's: the correctives are read through anny's template fitted and "
                    f"registered onto this mesh ({max(registered):.1f} mm off its surface, median)")
        if example and note is None:
            from latent_model.detail import describe_mix

            note = f"the example's corrective reads as {describe_mix(example)}"
        pred = (v + out).astype(np.float32)
        return TransferOutput(pred, pred, 1.0 if moved else 0.0, float("inf"), "example" if example is not None else label,
                              "correctives", note=note)

    def _topology_note(self, mesh: PreparedMesh) -> str | None:
        """`CorrectiveFields.available` of the mesh, once per mesh (its triangles' digest: not at every slider move)."""
        fields = self.correctives
        return mesh.cache("corrective_note", f"fields:{id(fields)}", lambda: fields.available(mesh.vertices, mesh.faces))

    def registrations_to_fit(self, mesh: PreparedMesh, kind: PairKind, poses: list[str | None]) -> list[str]:
        """The poses among `poses` whose correctives on this mesh first need anny's template fitted and registered onto
        it (a mesh of another topology; ~20 s each on 2 cores, then kept): for a window to say why it waits."""
        if self.predicts_with(kind) != "correctives" or self._topology_note(mesh) is None:
            return []
        return [p for p in dict.fromkeys(poses) if p is not None and not mesh.cached(f"anny_view:{p}", "cpu")
                and any(self.correctives.has(c) for c in (get_pose(p).components or (p,)))]

    def _anny_view(self, mesh: PreparedMesh, pose: str) -> "Correspondence":
        """How anny's vertices lie on a mesh of another topology skinned in `pose` (`registration.correspond`: a
        template fitted and registered onto it, some seconds; kept per mesh and pose)."""
        from latent_model.registration import correspond, template_fitter

        return mesh.cache(f"anny_view:{pose}", "cpu", lambda: correspond(template_fitter(), mesh.vertices, mesh.faces,
                                                                          pose))

    def _local_only(self, pose: str | None, kind: PairKind) -> bool:
        """Whether the body decoder adds nothing to this pose: for neutral_to_pose, when the local detail stage moves
        it entirely (every part a face or finger pose it holds; the body decoder's reading of such a delta, 0.1-0.3 of
        a gate, moved whole cheeks and hands: puffRt explained 0.34 alone, -0.66 with it); for source_to_combo, when
        what the combination adds to its posed component is face and finger poses alone (decoder v2 trains on body
        combinations; its ungated reading of these 43 keys on the validation characters explained mean -2.2, nearest
        -22.7), with or without the detail stage (which adds them, `_detail_parts`)."""
        if pose is None:
            return False
        if kind == "source_to_combo":
            combo, component = split_bank_key(kind, pose)
            added = [c for c in get_pose(combo).components if c != component]
            return bool(added) and all(detail_regions_of(c) for c in added)
        if self.detail is None or kind != "neutral_to_pose" or not self.detail.bank.has(pose):
            return False
        p = get_pose(pose)
        return all(detail_regions_of(c) for c in (p.components or (p.name,)))

    def _detail_parts(self, key: str, kind: PairKind, person: str | None) -> list[tuple[tuple[dict, int], float]]:
        """[(({region: delta}, averaged), weight)] the local detail stage adds for a bank key: a pose's own region
        deltas (`neutral_to_pose`), except that a combination's finger poses are each read from its own deltas: in
        the hand's code a fist's delta reads as two knuckles (A02 0.58 + D02 1.20), its twelve knuckles read one by
        one compose into the fist (`RegionFields.chains`; validation: explained 0.13 -> 0.86 mean, 0.18 -> 0.81
        nearest). For `source_to_combo`, what the combination adds to its posed component: each added face or
        finger pose's deltas (the rig adds face shapes and turns knuckles; the component's own detail is in the
        source). Validation: a fist added to a bent elbow 0.89 / 0.81 (mean / nearest), to one bent knuckle
        0.51-0.79 (a base knuckle's source the least: the others turn about its unbent joints), face additions
        0.51-0.55 / 0.30-0.37."""
        if kind != "source_to_combo":
            pose = get_pose(key)
            fingers = [c for c in pose.components if get_pose(c).group == "finger"]
            if not fingers:
                return [(self.detail.pose_deltas(key, person), 1.0)]
            own, n = self.detail.pose_deltas(key, person)
            hands = {r for c in fingers for r in detail_regions_of(c)}
            rest = {r: d for r, d in own.items() if r not in hands}
            return ([((rest, n), 1.0)] if rest else []) + [(self.detail.pose_deltas(c, person), 1.0) for c in fingers]
        combo, component = split_bank_key(kind, key)
        added = [c for c in get_pose(combo).components if c != component and detail_regions_of(c)]
        return [(self.detail.pose_deltas(c, person), 1.0) for c in added]

    @staticmethod
    def _held(key: str | None, kind: PairKind) -> tuple[str, ...]:
        """The face and finger poses a `source_to_combo` source already stands in (its component's), () otherwise."""
        if key is None or kind != "source_to_combo":
            return ()
        component = get_pose(split_bank_key(kind, key)[1])
        return tuple(c for c in (component.components or (component.name,)) if detail_regions_of(c))

    def _add_detail(self, mesh: PreparedMesh, raw: np.ndarray, gated: np.ndarray, parts: list, magnitude: float,
                    held: tuple[str, ...] = ()) -> tuple[np.ndarray, np.ndarray, dict[str, float], dict[str, dict[str, float]]]:
        """(raw, gated, {region: gate}, {region: {pose: weight}}) with the local detail of `parts`
        [(({region: delta}, averaged), weight)] added, each region's delta weighed by the slider weight, the
        magnitude and (gated) its own noise gate; the last: what the deltas read as (`LocalDetailModel.mix`).
        `held`: the face and finger poses the source stands in (`_held`): the parts add to them (a fist from a bent
        base knuckle turns the other joints about where they now are)."""
        if magnitude == 0 or not any(d for (d, _), _ in parts):
            return raw, gated, {}, {}
        regions = self.regions(mesh)
        gates: dict[str, float] = {}
        ungated, weighed = [], []
        for (deltas, n), w in parts:
            g = {r: self.detail.gate(r, d, n)[0] for r, d in deltas.items()}
            for r, x in g.items():
                gates[r] = max(gates.get(r, 0.0), x)
            for r, d in deltas.items():
                ungated.append(({r: d}, w * magnitude))
                weighed.append(({r: d}, w * magnitude * g[r]))
        mix: dict[str, dict[str, float]] = {}
        for part, w in ungated:
            for r, d in part.items():
                for pose, x in self.detail.mix(r, d).items():
                    mix.setdefault(r, {})[pose] = mix.get(r, {}).get(pose, 0.0) + w * x
        added = self.detail.displacement(regions, ungated, raw, held)
        same = all(a[1] == b[1] for a, b in zip(ungated, weighed)) and (gated is raw or np.array_equal(gated, raw))
        # every gate open on the same body prediction: the gated detail is the ungated one (computed once)
        gated = (gated + (added if same else self.detail.displacement(regions, weighed, gated, held))).astype(np.float32)
        return (raw + added).astype(np.float32), gated, gates, mix

    def _fields_or_network(self, mesh: PreparedMesh, predictor: Predictor, d: np.ndarray, magnitude: float,
                           kind: PairKind) -> np.ndarray:
        """(V, 3) the pose fields' prediction, or the network's (which reads the fields too)."""
        dev, fields = self.device, self.model.pose_fields
        direction, r, k = delta_condition(d, magnitude, kind, dev)
        v = torch.from_numpy(mesh.vertices)[None].to(dev)
        field_disp = fields.displacement(v, direction, r, k, cache=mesh.cache("pose_fields", dev, lambda: FieldCache(v)))
        if predictor == "pose_fields":
            raw_t = v + field_disp
        else:
            vd = self.model.vertex_decoder
            n = torch.from_numpy(mesh.normals)[None].to(dev)
            features = mesh.cache("decoder", dev, lambda: vd.mesh_features(v, n))
            raw_t = vd(v, n, torch.from_numpy(mesh.mu)[None].to(dev), direction, r, k,
                       torch.from_numpy(mesh.knn)[None].to(dev), fields.weights(direction, k), field_disp,
                       features=features)["vertices"]
        return raw_t[0].cpu().numpy()

    def _read_prediction(self, mesh: PreparedMesh, read: BodyReading, d: np.ndarray, b: tuple[np.ndarray, int] | None,
                         blend: float, magnitude: float, kind: PairKind, b_moves: bool = True
                         ) -> tuple[np.ndarray, float, float]:
        """(vertices, gate, signal) of an example pair read as poses (`BodyReading`): its poses' motions times their
        weights, the magnitude and 1 - blend, mixed with pose B's motion (`b`: its (delta, deltas averaged)) times the
        blend and B's noise gate. The read is of the example's motion, not of a latent delta, so it has no noise
        gate of its own (gate 1; the signal is its latent delta's, for the record)."""
        _, signal = self.noise_gate(d)
        extra, gate = [], 1.0 - blend if b is not None else 1.0
        if b is not None:
            g_b = self.noise_gate(*b)[0] if b_moves else 0.0
            extra = [(self.motion.condition(b[0], kind, b[1]), blend * magnitude * g_b)]
            gate += blend * g_b
        scale = magnitude * (1.0 - blend if b is not None else 1.0)
        return self._read_motion(mesh, read.weights, scale, extra), (0.0 if magnitude == 0 else gate), signal

    def _motion_prediction(self, mesh: PreparedMesh, a: tuple[np.ndarray, int], b: tuple[np.ndarray, int] | None,
                           blend: float, magnitude: float, kind: PairKind, body: tuple[bool, bool] = (True, True)
                           ) -> tuple[np.ndarray, np.ndarray, float, float]:
        """(raw, gated (V, 3), gate, signal) by the motion decoder from pose A's and (blends) pose B's
        (delta, deltas averaged). A blend reads each pose's own delta and mixes the two motions (`mix_motions`):
        the mixed delta's direction swings between the poses' and the decoder reads it non-linearly (steps of
        7-8x the median on the slider), while mixed motions are continuous. Each pose's noise gate weighs its
        motion; a pose whose `body` flag is off (the local detail stage's alone) is not read by the decoder at all,
        gated or raw; the reported gate and signal are the weighted mean of the poses'."""
        poses, weights = ([a], [1.0]) if b is None else ([a, b], [1.0 - blend, blend])
        gates, signals = zip(*(self.noise_gate(x, n) for x, n in poses))
        gates = [g if moves else 0.0 for g, moves in zip(gates, body)]
        gate = 0.0 if magnitude == 0 else float(sum(w * g for w, g in zip(weights, gates)))
        signal = float(sum(w * s for w, s in zip(weights, signals)))
        conditions = [self.motion.condition(x, kind, n) for x, n in poses]
        raw, gated = self.motion.predict(mesh, conditions, weights, gates, gate, magnitude, body)
        return raw, gated, gate, signal
