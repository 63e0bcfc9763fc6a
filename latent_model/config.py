"""Dataclass configs and named presets (`tiny` for tests, `standard` shipped, `paper` for a GPU)."""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

from latent_model.corpus.sdf import SdfSampling

PRESETS = ("tiny", "standard", "paper")
# Bump when the geometry a config produces changes (rig, correctives, faces, sampling code):
# it enters the corpus digest, so stale corpora are detected instead of silently reused.
GENERATOR_VERSION = 3


@dataclass(frozen=True)
class CorpusConfig:
    """Everything that determines a corpus; the same config gives the same arrays."""

    preset: str
    n_identities: int = 78
    n_test: int = 14
    n_stylised: int = 2  # stylised (out-of-distribution) characters, all in the test split
    poses: tuple[str, ...] | None = None  # None: the whole vocabulary
    sdf: SdfSampling = field(default_factory=SdfSampling)
    seed: int = 0

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "CorpusConfig":
        d = dict(d)
        d["sdf"] = SdfSampling(**{k: tuple(v) if isinstance(v, list) else v for k, v in d["sdf"].items()})
        if d.get("poses") is not None:
            d["poses"] = tuple(d["poses"])
        return CorpusConfig(**d)

    def digest(self) -> str:
        """Short hash of the config, stored in the corpus to detect a mismatch."""
        blob = json.dumps({"config": self.to_dict(), "generator": GENERATOR_VERSION}, sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]

    def pose_names(self) -> tuple[str, ...]:
        from latent_model.corpus.poses import POSES, get_pose

        if self.poses is None:
            return tuple(POSES)
        for name in self.poses:
            get_pose(name)  # raises with the valid names
        return self.poses


TINY_POSES = (
    "elbowBentLf", "elbowBentRt", "kneeBentLf", "fingerKnuckleB02Lf",
    "browDwLf", "puffLf", "cornerUpLf", "elbowBentLf+kneeBentLf",
)


def corpus_preset(name: str) -> CorpusConfig:
    """The named corpus preset; unknown names raise with the valid ones."""
    if name == "tiny":
        return CorpusConfig(preset="tiny", n_identities=6, n_test=2, n_stylised=1,
                            poses=TINY_POSES, sdf=SdfSampling(k=1024))
    if name == "standard":
        return CorpusConfig(preset="standard", sdf=SdfSampling(k=8192))
    if name == "paper":
        return CorpusConfig(preset="paper", sdf=SdfSampling(k=16384))
    raise ValueError(f"unknown preset {name!r}; valid presets: {', '.join(PRESETS)}")


def data_root() -> Path:
    """Where generated data lives (corpora, caches): $LRR_DATA or ~/.cache/latentrerig."""
    return Path(os.environ.get("LRR_DATA", Path.home() / ".cache" / "latentrerig"))


def default_corpus_dir(preset: str) -> Path:
    return data_root() / "corpus" / preset


# ----------------------------------------------------------------------------- model + training
@dataclass(frozen=True)
class ModelConfig:
    """Network sizes. `paper`: Z=512 and a DeepSDF-width (512 x 8) SDF decoder."""

    latent: int = 512  # Z
    enc_fourier: int = 6  # frequencies of the point positional encoding
    enc_hidden: tuple[int, ...] = (64, 128)  # per-point MLP widths
    enc_heads: int = 8  # attention-pooling heads (permutation invariant, count-consistent)
    enc_out_hidden: int = 1024
    sdf_hidden: int = 256
    sdf_layers: int = 6  # latent + x re-injected (skip) at the middle layer, as DeepSDF
    sdf_clamp: float = 0.05  # metres: clamp of the SDF reconstruction loss near the surface
    n_identities: int = 64  # training identities (character classifier classes)
    n_poses: int = 81  # pose classifier classes
    vd_fourier: int = 7  # down to ~3 cm wavelengths: sharp enough to tell forearm from upper arm
    vd_hidden: int = 64
    vd_cond: int = 128
    vd_bones: int = 16  # virtual bones of the coarse stage
    vd_knn: int = 8  # neighbours in the local refinement stages
    vd_edge: int = 32  # edge-feature width of the refinement stages
    vd_stages: int = 4
    vd_detail: bool = True  # residual detail branch
    # The unit direction of a 512-d delta has components ~0.04 against ~0.3 of mu_src: scaled by
    # this gain (sqrt(Z) in every preset: unit-RMS components) it is no longer drowned in the
    # condition MLP's first layer. 1.0 is the behaviour of checkpoints written before the field.
    vd_dir_gain: float = 1.0
    vd_whiten: bool = False  # ZCA-whiten the delta direction with training statistics (False: as before)
    vd_basis: int = 0  # fields of the bilinear deformation basis (0: none, as checkpoints before it)
    # Pose-prototype condition: the delta direction's softmax cosine similarity to the mean training
    # direction of every pose (n_poses slots, set before Phase B) joins the condition vector. Nearest
    # prototype names the pose of a held-out identity's delta 87% of the time on single body poses
    # (bench/prototype_naming.py).
    vd_prototypes: bool = False
    vd_proto_temp: float = 0.003  # sharp: many pose prototypes are > 0.97 apart in cosine (standard: 0.001)
    vd_coef_max: float = 3.0  # cap on a field's amount (3x the mean delta's)
    # Prototype fields (needs vd_prototypes): random Fourier features (this many; 0 = off) of the
    # height-normalised source positions, one ridge read-out per (pair kind, pose) fitted in
    # closed form before Phase B, mixed by the prototype weights x r / |mean training delta|.
    vd_proto_fields: int = 0
    vd_rff_sigma: float = 12.0  # frequency scale (x pi) of the features, in units of body height
    vd_rff_seed: int = 0
    vd_fit_ridge: float = 1e-2  # ridge, relative to the mean diagonal of the Gram matrix
    vd_fit_vertices: int = 1500  # vertices per pair used by the fit (random subset)
    # True: each pair's features are scaled by its delta's amount along the prototype (the read-out
    # reproduces every pair at its own amount); False: every pair counts at amount 1 (the field is
    # the mean displacement, the amount at inference still scales it).
    vd_fit_scaled: bool = True
    # pair kinds whose fields are fitted: neutral sources are shared by every pose of an identity
    # (one Gram matrix each, 35 s in all); each posed source needs its own (~14 s per field on 2 cores)
    vd_fit_kinds: tuple[str, ...] = ("neutral_to_pose",)
    # Pair kinds whose prediction, at inference (eval mode), is the fitted fields alone: the
    # network still trains on every kind (training is unchanged), but on held-out identities its
    # residual on top of the fields added error and leakage on every broad body pose (README).
    vd_fields_only_kinds: tuple[str, ...] = ()
    n_pair_kinds: int = 4


@dataclass(frozen=True)
class LossWeights:
    """Every loss weight; 0 switches a term off (ablations)."""

    rec: float = 30.0  # the SDF error is in metres (~1 cm): weighted up so geometry drives the code
    cls: float = 0.1
    pose_cls: float = 0.1
    kl: float = 1e-4
    variant: float = 0.2
    combo: float = 0.2
    contrast: float = 0.1
    contrast_temperature: float = 0.1
    # alignment half of L_contrast: mean 1 - cos of same-pose deltas across identities (0: off, as
    # checkpoints before it). 3.0 in `standard`: held-out elbowBentLf 0.920 -> 0.959; it also draws
    # different poses' deltas closer (body prototypes' mutual cosine 0.26 -> 0.41), which the sharper
    # prototype temperature of `standard` answers (README "The alignment term")
    align: float = 0.0
    pos: float = 1.0
    # per-pair RMSE relative to the pair's own motion (+2 mm): small pairs (correctives, faces,
    # fingers) count, so the decoder learns to keep still where the truth barely moves
    pos_rel: float = 0.02
    knn: float = 0.5
    knn_delta: float = 0.5
    static: float = 0.5
    smooth: float = 0.1
    nrm: float = 0.05
    skinbs: float = 2.0


@dataclass(frozen=True)
class TrainConfig:
    seed: int = 0
    # phase A
    a_steps: int = 2000
    a_identities: int = 4  # identities per batch (all see the same poses: contrastive positives)
    a_poses: int = 4  # single poses per identity per batch (+ a combo with components + variants)
    a_enc_points: int = 2048  # SDF samples fed to the encoder per state (subset of K)
    a_query_points: int = 256  # SDF decoder queries per state
    a_lr: float = 5e-4
    # phase B
    b_steps: int = 2000
    b_batch: int = 4  # pairs per step
    b_lr: float = 1e-3
    b_kinds: tuple[str, ...] = ("neutral_to_pose", "skinning_to_skinning_plus_blendshape",
                                "blendshape_to_skinning_plus_blendshape", "source_to_combo")
    checkpoint_every: int = 250
    log_every: int = 10
    grad_clip: float = 1.0


@dataclass(frozen=True)
class Preset:
    name: str
    corpus: CorpusConfig
    model: ModelConfig
    train: TrainConfig
    loss: LossWeights = field(default_factory=LossWeights)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "Preset":
        def tup(x, cls=None):
            # fields a newer version dropped are ignored (e.g. the unused b_vertices of early runs)
            known = {f.name for f in dataclasses.fields(cls)} if cls else None
            return {k: tuple(v) if isinstance(v, list) else v for k, v in x.items() if known is None or k in known}

        return Preset(d["name"], CorpusConfig.from_dict(d["corpus"]), ModelConfig(**tup(d["model"])),
                      TrainConfig(**tup(d["train"], TrainConfig)), LossWeights(**d["loss"]))


def preset(name: str) -> Preset:
    """Corpus + model + training config of a named preset."""
    corpus = corpus_preset(name)
    n_train = corpus.n_identities - corpus.n_test
    n_poses = len(corpus.pose_names())
    if name == "tiny":
        model = ModelConfig(latent=32, vd_dir_gain=math.sqrt(32), enc_hidden=(32, 64), enc_heads=2, enc_out_hidden=64, sdf_hidden=64,
                            sdf_layers=4, n_identities=n_train, n_poses=n_poses, vd_hidden=16, vd_cond=32,
                            vd_bones=4, vd_knn=6, vd_edge=8, vd_basis=4, vd_whiten=True,
                            vd_prototypes=True, vd_proto_fields=64, vd_rff_sigma=3.0, vd_fit_vertices=200)  # tests exercise every switch
        train = TrainConfig(a_steps=30, a_identities=2, a_poses=3, a_enc_points=256, a_query_points=128,
                            b_steps=20, b_batch=2, checkpoint_every=10, log_every=5)
        return Preset(name, corpus, model, train, LossWeights(align=1.0))
    if name == "standard":
        # The shipped model. vd_basis=64 + vd_whiten with static 0.2 / pos_rel 0 was measured as an
        # alternative (2500 steps, README "What was tried"): it learned spine and neck motion but
        # leaked 7-55 mm on still regions and lost the left arm (elbowBentLf 0.67 vs 0.84): not shipped.
        # Pose prototypes + closed-form prototype fields (1024 random Fourier features) carry the
        # pose vocabulary; the network trains on top of them, and neutral_to_pose is predicted by the
        # fields alone at inference (README "Results"). Frequency scale 6
        # (not 12): the fields alone on held-out identities leak 40% less on still regions and
        # explain 1.5-2.5 points more motion (elbow, shoulder, knee; bench/fields_alone.py, README "what limits the knees").
        # With the alignment term the prototypes of related poses sit closer (kneeBentLf vs
        # kneeBentLf+kneeBentRt 0.99): temperature 0.001 keeps the mean knee delta's weight on its own
        # field (0.955 at 0.003: 2.6 mm leakage), and the unscaled field fit halves shoulder and
        # clavicle leakage (README "The alignment term").
        model = ModelConfig(n_identities=n_train, n_poses=n_poses, vd_dir_gain=math.sqrt(512),
                            vd_prototypes=True, vd_proto_temp=0.001, vd_proto_fields=1024, vd_rff_sigma=6.0,
                            vd_fit_scaled=False, vd_fields_only_kinds=("neutral_to_pose",))
        # sized for <= 90 min on 2 CPU cores: A ~0.3 s/step, B ~0.75 s/step with the fields (README)
        train = TrainConfig(a_steps=6000, a_lr=1e-3, b_steps=3000)
        return Preset(name, corpus, model, train, LossWeights(align=3.0))
    if name == "paper":
        model = ModelConfig(vd_dir_gain=math.sqrt(512), enc_hidden=(128, 256), enc_out_hidden=1024, sdf_hidden=512, sdf_layers=8,
                            n_identities=n_train, n_poses=n_poses, vd_hidden=128, vd_cond=256, vd_bones=32, vd_knn=12, vd_edge=64)
        train = TrainConfig(a_steps=20000, a_identities=8, a_poses=8, a_enc_points=8192, a_query_points=2048,
                            b_steps=20000, b_batch=8)
        return Preset(name, corpus, model, train)
    raise ValueError(f"unknown preset {name!r}; valid presets: {', '.join(PRESETS)}")
