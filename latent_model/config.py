"""Configs of the model and its training, and the named presets.

The defaults ARE the shipped `standard` model; `tiny` shrinks it for the tests and `paper` grows
it to the paper's sizes (a GPU). Each part's config sits beside the others here, one line of doc per
field saying what it is (how a value was found is in docs/history.md).
"""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path

from latent_model.corpus.config import CorpusConfig, corpus_preset
from latent_model.types import PAIR_KINDS, PRESETS, PairKind, check_pair_kind


def data_root() -> Path:
    """Where generated data lives (corpora, caches): $LRR_DATA or ~/.cache/latentrerig."""
    return Path(os.environ.get("LRR_DATA", Path.home() / ".cache" / "latentrerig"))


def default_corpus_dir(preset: str) -> Path:
    return data_root() / "corpus" / preset


@dataclass(frozen=True)
class VertexDecoderConfig:
    """The paper's vertex decoder network (nn/vertex_decoder.py)."""

    fourier: int = 7  # frequencies of the vertex positional encoding (finest ~3 cm)
    hidden: int = 64  # per-vertex feature width
    cond: int = 128  # width of the global condition vector
    bones: int = 16  # virtual bones of the coarse stage
    knn: int = 8  # neighbours of each vertex in the refinement stages
    edge: int = 32  # edge-feature width of the refinement stages
    stages: int = 4  # KNN refinement stages


@dataclass(frozen=True)
class PoseFieldsConfig:
    """The closed-form pose fields (nn/pose_fields.py), fitted before Phase B (train/fit_pose_fields.py)."""

    features: int = 1024  # random Fourier features of the height-normalised source positions
    rff_sigma: float = 6.0  # their frequency scale (x pi) per body height
    rff_seed: int = 0  # seed of the random frequencies
    proto_temp: float = 0.001  # softmax temperature of the delta's cosine to each pose prototype
    coef_max: float = 3.0  # cap on a field's amount (x the mean delta's)
    fit_ridge: float = 1e-2  # ridge of the read-out fit, relative to the Gram matrix's mean diagonal
    fit_vertices: int = 1500  # random source vertices per training pair in the fit
    fit_kinds: tuple[PairKind, ...] = ("neutral_to_pose",)  # pair kinds whose fields are fitted (others stay zero)
    only_kinds: tuple[PairKind, ...] = ("neutral_to_pose",)  # pair kinds predicted by the fields alone at inference

    def __post_init__(self) -> None:
        # a misspelt kind would silently change which predictor runs
        for k in (*self.fit_kinds, *self.only_kinds):
            check_pair_kind(k)
        if not set(self.only_kinds) <= set(self.fit_kinds):
            raise ValueError(f"PoseFieldsConfig.only_kinds {self.only_kinds} must be fitted (fit_kinds {self.fit_kinds})")


@dataclass(frozen=True)
class MotionDecoderConfig:
    """Decoder v2 (nn/motion_decoder.py), trained after the network in Phase B (train/motion.py); it predicts the
    pair kinds whose target is the source moved by the skeleton (the corpus-v3 model, trained before it existed,
    has none)."""

    enabled: bool = True  # build and train it; Transfer then predicts `kinds` with it
    # pair kinds it predicts at inference (the others: the network). The correctives (skinning -> +blendshape) are
    # millimetre shape changes, not a motion. source -> combo read as neutral_to_pose moved the whole body of some
    # posed sources (hipFlexLf+kneeBentLf: 400 mm leak, bench/pair_kinds.py): a latent step from a posed limb is
    # another direction than the same joint's from the neutral; it is trained on its own pairs (`posed_prob`)
    kinds: tuple[PairKind, ...] = ("neutral_to_pose", "blendshape_to_skinning_plus_blendshape", "source_to_combo")
    # pair kinds it has training pairs of; a kind it predicts but has none of is read as the first of these (a
    # blendshape source moved by the skeleton makes the motion a neutral does)
    trained_kinds: tuple[PairKind, ...] = ("neutral_to_pose", "source_to_combo")
    # probability that a training pair is a source_to_combo pair (a combination's component posed -> the combination,
    # train/posed_sources.py) of one of `posed_characters` training characters (surface features of each of their
    # posed sources: ~0.5 s each); 0: none (then source_to_combo must not be in trained_kinds)
    posed_prob: float = 0.15
    posed_characters: int = 24
    hidden: int = 128  # per-vertex MLP width
    cond: int = 256  # width of the condition (mu_src, delta direction, pair kind)
    layers: int = 3  # hidden layers, each FiLM-modulated by the condition
    world: bool = True  # also a rotation and translation in world axes (the torso has no limb axis)
    mu_dims: int = 8  # mu_src is read through this many whitened principal components (0: not read)
    mu_noise: float = 1.0  # std of the noise on them in training (in their std units)
    local_inputs: bool = False  # also read each vertex's normal and medial offset (they made neighbours disagree)
    limb_direction: bool = False  # also read the limb's axis in body axes (where the limb points in this rest)
    smooth: int = 40  # at inference, rounds of averaging the per-vertex motion over surface neighbours
    rigid_parts: bool = True  # at inference, hands and feet move as rigid parts (nn/motion_decoder.RIGID_PARTS)
    # a rigid part's turn is pulled (this fraction of its spread) to the turn of the limb carrying it, over the band
    # from the part's edge to `rigid_anchor` (over the height) beyond it; anchor 0: to the decoder's mean rotation vector
    rigid_prior: float = 1.0
    rigid_anchor: float = 0.06
    repivot: float = 0.15  # at inference, > 0: translations absorbed into pivots (absorb_translation, its damping)
    # at inference, > 0: the motion at the delta's own length is refitted to the surface's turns over balls of
    # this radius (m; local_motion_fit, heat_averager) before the magnitude scales it; 0: its own parameters scale
    refit_radius: float = 0.15
    poses: str = "body"  # the poses it trains on: "body" (skeletal single poses and their combos) or "all"
    steps: int = 6000  # training steps
    batch: int = 16  # pairs per step
    vertices: int = 1024  # vertices per pair per step (half where the pair moves the surface)
    lr: float = 1e-3  # learning rate (cosine decay to 5 %)
    # probability of conditioning a training pair on its pose's mean delta: 0.7 carries the mean into unseen rests
    # (T-pose +0.04 on validation against 0.5), with `averaged_input` and the drawn amplitudes (docs/history.md)
    mean_prob: float = 0.7
    # probability of conditioning it on a random training character's delta of the pose (the rest: its own): what
    # the nearest identity and an example pair give; the own delta alone lets the decoder key on who it is
    other_prob: float = 0.3
    # of those, the fraction that mixes two random characters' deltas (weights w, 1 - w, w uniform; told as an
    # effective count 1 / (w^2 + (1 - w)^2)): 112 deltas per pose are few enough for the decoder to learn each
    # one's quirks, and a new person's delta then reads worse than a training person's
    other_mix: float = 0.0
    # each training person also stands in this many random rests drawn within the training rests' angle ranges
    # (train/rest_augment.py); 2 read a character's own delta far better in an unseen rest but not the mean delta
    # (validation, docs/history.md), and cost 8 min of Phase B
    extra_rests: int = 0
    # their angle ranges (degrees; (): the training rests' own): DCC tools export T-poses, arms level and elbows
    # straight, just past the training rests' highest arms (38) and straightest elbows (-38)
    extra_rest_arms: tuple[float, ...] = ()
    extra_rest_elbows: tuple[float, ...] = ()
    # a drawn rest stays this far (its largest angle difference) from every validation and test rest; ranges past
    # the training rests' need one (10: corpus v4 stands its training armsWide 7 from the held-out T-pose)
    extra_rest_margin: float = 0.0
    # each training character is also posed in `combos_per_character` of this many seeded combinations of 2-3 of
    # its single body poses (train/combo_augment.py; none shares two poses with an evaluated example combination)
    extra_combos: int = 120
    combos_per_character: int = 8
    combo_sizes: tuple[int, ...] = (1, 2, 3)  # poses per drawn combination (1 only with an amplitude range)
    combo_odds: tuple[float, ...] = (0.4, 0.3, 0.3)  # how often each size is drawn (checked when drawing)
    # each drawn pose's angles scaled by a factor drawn in this range; (1, 1): the vocabulary's angles. (0.3, 1.3):
    # a small bend's delta is mostly the posed person's own part (it does not shrink with the angle), and a decoder
    # trained on full amplitudes only reads one as another limb's motion (the 40° knee example, docs/history.md)
    combo_amplitude: tuple[float, float] = (0.3, 1.3)
    edge: float = 0.0  # weight of the neighbour term: error of neighbours' relative positions (mm)
    edge_rings: int = 3  # a vertex's partner in that term is within this many edges
    # weight of the translation's mean length (mm) in the loss: at r = 1 a turn about the vertex's own axis plus a
    # shift fits as well as a turn about the joint, but only the latter doubles right when the delta doubles
    translation: float = 0.0
    # weight of the world-axis outputs' size (mm: a turn at a 10 cm lever, a shift) in the loss: a limb's turn
    # learnt in world axes is wrong in any rest where the limb points elsewhere; the limb frame's turns with it
    world_penalty: float = 0.0
    # weight of the still vertices' displacement (mm; their true motion < 1 mm) in the loss, on top of their share of
    # the error: a leak is a small part of the mean error, so a decoder that blurs neighbouring deltas (a right hip
    # flex read partly as a right arm's pose) moves the still limb a few cm and barely pays for it. 0.3 on validation:
    # hipFlexRt's leak 2.5-3.9 -> 0.6-0.8 mm, every rest's mean within 0.01; 1.0: the T-pose 0.02 lower (history)
    static: float = 0.3
    delta_dims: int = 0  # the delta's direction is read through this many whitened principal components (0: in full)
    delta_noise: float = 0.0  # std of the noise on them (or on the unit-RMS direction) in training
    # the condition also says whether the delta is a pose's mean over the training characters or one character's
    # (nn/motion_decoder.MotionDecoder.averaged_code): a mean is exact, one character's carries its identity and noise
    averaged_input: bool = True
    # the arms' motion is composed on the motion of a band of the upper chest, as far as the decoder says per vertex
    # (nn/motion_decoder.carry_arms): a spine pose carries the arms in any rest; each training pair's vertex subset
    # also holds `carried_band` vertices of the band, which the composition fits. On clean features it lands within
    # a retrain's spread of the shipped decoder (T-pose spine bend +0.10, other poses -0.02-0.04; docs/history.md)
    carried_arms: bool = False
    carried_band: int = 64

    def __post_init__(self) -> None:
        for k in (*self.kinds, *self.trained_kinds):
            check_pair_kind(k)
        if not self.trained_kinds:
            raise ValueError("MotionDecoderConfig.trained_kinds must name at least one pair kind")
        if ("source_to_combo" in self.trained_kinds) != (self.posed_prob > 0):
            raise ValueError(f"MotionDecoderConfig: source_to_combo is in trained_kinds only when posed_prob > 0 "
                             f"(its training pairs); got posed_prob {self.posed_prob}, trained_kinds {self.trained_kinds}")
        if not 0 <= self.posed_prob < 1:
            raise ValueError(f"MotionDecoderConfig.posed_prob ({self.posed_prob}) is a probability below 1")
        if min(self.mean_prob, self.other_prob) < 0 or self.mean_prob + self.other_prob > 1:
            raise ValueError(f"MotionDecoderConfig.mean_prob ({self.mean_prob}) and other_prob ({self.other_prob}) "
                             "are probabilities of one draw: each >= 0, together <= 1")
        for name in ("extra_rest_arms", "extra_rest_elbows"):
            r = getattr(self, name)
            if r and (len(r) != 2 or r[0] >= r[1]):
                raise ValueError(f"MotionDecoderConfig.{name} {r} is (lowest, highest) degrees, or () for the "
                                 "training rests' range")
            if r and self.extra_rest_margin <= 0:
                raise ValueError(f"MotionDecoderConfig.{name} {r} draws rests past the training rests': set "
                                 "extra_rest_margin (degrees, e.g. 10) so none comes near a validation or test rest")

    def reads_as(self, kind: PairKind) -> PairKind:
        """The pair kind the decoder is conditioned on for a pair of `kind` (itself when trained on it)."""
        return kind if kind in self.trained_kinds else self.trained_kinds[0]


@dataclass(frozen=True)
class ModelConfig:
    """Sizes of the encoder, SDF decoder and heads (Phase A) and the Phase B parts."""

    latent: int = 512  # Z
    enc_fourier: int = 6  # frequencies of the SDF point positional encoding
    enc_hidden: tuple[int, ...] = (64, 128)  # per-point MLP widths of the set encoder
    enc_heads: int = 8  # attention-pooling heads (permutation invariant, count-consistent)
    enc_out_hidden: int = 1024  # width of the layer from the pooled feature to (mu, log var)
    sdf_hidden: int = 256  # SDF decoder width
    sdf_layers: int = 6  # SDF decoder depth; latent and x re-injected at the middle layer (DeepSDF)
    sdf_clamp: float = 0.05  # metres: clamp of the SDF reconstruction loss near the surface
    n_identities: int = 64  # training persons (identity classifier classes; a person's rests share one)
    n_poses: int = 81  # poses of the corpus (pose classifier classes, prototype slots)
    decoder: VertexDecoderConfig = field(default_factory=VertexDecoderConfig)
    fields: PoseFieldsConfig = field(default_factory=PoseFieldsConfig)
    motion: MotionDecoderConfig = field(default_factory=MotionDecoderConfig)

    @property
    def n_pair_kinds(self) -> int:
        return len(PAIR_KINDS)

    def phase_a_dict(self) -> dict:
        """The fields Phase A depends on (a Phase B change does not force re-training Phase A)."""
        return {k: v for k, v in dataclasses.asdict(self).items() if k not in ("decoder", "fields", "motion")}


@dataclass(frozen=True)
class LossWeights:
    """Every loss weight (nn/losses.py); 0 switches a term off."""

    rec: float = 30.0  # SDF reconstruction (clamped L1, metres: weighted up so geometry drives the code)
    cls: float = 0.1  # identity classifier on mu
    pose_cls: float = 0.1  # pose classifier on the normalised delta
    kl: float = 1e-4  # KL of the posterior to N(0, I)
    variant: float = 0.2  # variant composition: delta(skin+bs) ~ delta(skin) + delta(bs)
    combo: float = 0.2  # combo composition: delta(A+B) ~ delta(A) + delta(B)
    contrast: float = 0.1  # supervised InfoNCE on normalised deltas (separates poses)
    contrast_temperature: float = 0.1  # its temperature
    align: float = 3.0  # alignment: mean 1 - cos of same-pose deltas of different identities
    # consistency: mean |d_i - d_j|^2 / (|d_i|^2 + |d_j|^2) of same-pose deltas of different identities (lengths agree too)
    consist: float = 0.0
    mirror: float = 1.0  # laterality: mean max(0, cos) of one character's deltas of a pose and its mirror
    pos: float = 1.0  # vertex RMSE over the batch
    pos_rel: float = 0.02  # per-pair RMSE relative to the pair's own motion (+2 mm)
    knn: float = 0.5  # KNN edge lengths
    knn_delta: float = 0.5  # KNN edge displacement vectors
    static: float = 0.5  # displacement of vertices whose true motion is < 1 mm
    smooth: float = 0.1  # displacement Laplacian
    nrm: float = 0.05  # vertex normals
    skinbs: float = 2.0  # L_skinBS on corrective pairs


@dataclass(frozen=True)
class TrainConfig:
    """Steps, batches and learning rates of the two phases."""

    seed: int = 0  # every random choice of training derives from it
    a_steps: int = 6000  # Phase A steps
    a_identities: int = 4  # identities per Phase A batch (all see the same poses: contrastive positives)
    a_poses: int = 4  # single poses per identity per batch (+ a combo with components + variants)
    a_mirrors: bool = True  # a sided pose comes with its mirror (hard negatives: without, the encoder barely tells L from R)
    a_enc_points: int = 2048  # SDF samples fed to the encoder per state (subset of K)
    a_query_points: int = 256  # SDF decoder queries per state
    a_lr: float = 1e-3  # Phase A learning rate
    b_steps: int = 300  # Phase B network steps (it predicts only an example pair's corrective; 2000 before)
    b_batch: int = 4  # pairs per Phase B step
    b_lr: float = 1e-3  # Phase B learning rate
    b_kinds: tuple[PairKind, ...] = PAIR_KINDS  # pair kinds Phase B draws from (uniformly)
    checkpoint_every: int = 250  # steps between resumable checkpoints
    log_every: int = 10  # steps between metric log lines
    grad_clip: float = 1.0  # gradient-norm clip


def _from_dict(cls, d: dict):
    """A (possibly nested) config dataclass from its `asdict` form; lists become tuples."""
    kw = {}
    for f in dataclasses.fields(cls):
        if f.name not in d:
            continue
        v = d[f.name]
        if dataclasses.is_dataclass(f.default_factory if f.default_factory is not dataclasses.MISSING else None):
            v = _from_dict(f.default_factory, v)
        elif isinstance(v, list):
            v = tuple(v)
        kw[f.name] = v
    unknown = set(d) - {f.name for f in dataclasses.fields(cls)}
    if unknown:
        raise ValueError(f"{cls.__name__}: unknown fields {sorted(unknown)} (a config of another version)")
    return cls(**kw)


@dataclass(frozen=True)
class Preset:
    name: str
    corpus: CorpusConfig
    model: ModelConfig = field(default_factory=ModelConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    loss: LossWeights = field(default_factory=LossWeights)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "Preset":
        if "motion" in d["model"] and "posed_prob" not in d["model"]["motion"]:
            # stored before the posed sources: trained without them (its stored kinds say what it predicts)
            d = {**d, "model": {**d["model"], "motion": {**d["model"]["motion"], "posed_prob": 0.0}}}
        model = _from_dict(ModelConfig, d["model"])
        if "motion" not in d["model"]:  # stored before decoder v2 existed: the model has none
            model = dataclasses.replace(model, motion=MotionDecoderConfig(enabled=False))
        else:
            stored = d["model"]["motion"]
            if "delta_dims" not in stored:  # stored before the direction read-out: it read it in full
                model = dataclasses.replace(model, motion=dataclasses.replace(model.motion, delta_dims=0))
            if "extra_rests" not in stored:  # stored before the drawn rests: trained on the corpus's alone
                model = dataclasses.replace(model, motion=dataclasses.replace(model.motion, extra_rests=0))
            if "extra_rest_margin" not in stored:  # stored before the margin: drawn within the training ranges
                model = dataclasses.replace(model, motion=dataclasses.replace(model.motion, extra_rest_margin=0.0))
            if "other_prob" not in stored:  # stored before it: own or mean deltas only
                model = dataclasses.replace(model, motion=dataclasses.replace(model.motion, other_prob=0.0))
            if "extra_combos" not in stored:  # stored before the drawn combinations: the corpus's alone
                model = dataclasses.replace(model, motion=dataclasses.replace(model.motion, extra_combos=0))
            if "other_mix" not in stored:  # stored before it: single characters' deltas only
                model = dataclasses.replace(model, motion=dataclasses.replace(model.motion, other_mix=0.0))
            if "averaged_input" not in stored:  # stored before the count: its condition has no such input
                model = dataclasses.replace(model, motion=dataclasses.replace(model.motion, averaged_input=False))
            if "static" not in stored:  # stored before the still-vertex weight: trained without it
                model = dataclasses.replace(model, motion=dataclasses.replace(model.motion, static=0.0))
            if "carried_arms" not in stored:  # stored before the chest carried the arms: it has no such output
                model = dataclasses.replace(model, motion=dataclasses.replace(model.motion, carried_arms=False))
        loss = _from_dict(LossWeights, d["loss"])
        if "consist" not in d["loss"]:  # stored before the consistency term: trained without it
            loss = dataclasses.replace(loss, consist=0.0)
        return Preset(d["name"], CorpusConfig.from_dict(d["corpus"]), model,
                      _from_dict(TrainConfig, d["train"]), loss)


def override(p, assignments: list[str], sections: tuple[str, ...] = ("model", "train", "loss")):
    """`p` with "SECTION.FIELD=VALUE" assignments applied (`train.a_mirrors=true`, `loss.mirror=1`,
    `model.motion.steps=3000`); the corpus is fixed by the built corpus, so it has no overrides.
    VALUE is JSON (true, 3, 0.5, [1, 2]) or a bare string; it must have the field's type."""
    import json

    for a in assignments:
        key, sep, raw = a.partition("=")
        path = key.strip().split(".")
        if not sep or len(path) < 2 or path[0] not in sections:
            raise ValueError(f"--set {a!r}: expected SECTION.FIELD=VALUE with SECTION {', '.join(sections)} "
                             f"(e.g. train.a_mirrors=true, detail.codec_steps=3000)")
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        chain = [p]
        for name in path[:-1]:
            chain.append(getattr(chain[-1], name))
        owner, leaf = chain[-1], path[-1]
        fields = {f.name: f for f in dataclasses.fields(owner)}
        if leaf not in fields or dataclasses.is_dataclass(getattr(owner, leaf)):
            valid = ", ".join(n for n in fields if not dataclasses.is_dataclass(getattr(owner, n)))
            raise ValueError(f"--set {a!r}: {'.'.join(path[:-1])} has no field {leaf!r}; valid: {valid}")
        old = getattr(owner, leaf)
        if isinstance(old, tuple) and isinstance(value, list):
            value = tuple(value)
        elif isinstance(old, float) and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if type(value) is not type(old):
            raise ValueError(f"--set {a!r}: {key} is {type(old).__name__} (now {old!r}), got {value!r}")
        new = dataclasses.replace(owner, **{leaf: value})
        for parent, name in zip(reversed(chain[:-1]), reversed(path[:-1])):
            new = dataclasses.replace(parent, **{name: new})
        p = new
    return p


def preset(name: str) -> Preset:
    """Corpus + model + training config of a named preset."""
    corpus = corpus_preset(name)
    sizes = dict(n_identities=corpus.n_train_persons, n_poses=len(corpus.pose_names()))
    if name == "tiny":
        model = ModelConfig(latent=32, enc_hidden=(32, 64), enc_heads=2, enc_out_hidden=64, sdf_hidden=64, sdf_layers=4,
                            decoder=VertexDecoderConfig(hidden=16, cond=32, bones=4, knn=6, edge=8),
                            fields=PoseFieldsConfig(features=64, fit_vertices=200),
                            # no drawn combinations: posing and SDF-sampling them would dominate the tests' trainings
                            # (tests/test_combo_augment.py trains with them)
                            motion=MotionDecoderConfig(hidden=32, cond=32, steps=30, batch=2, vertices=128,
                                                       extra_combos=0), **sizes)
        train = TrainConfig(a_steps=30, a_identities=2, a_poses=3, a_enc_points=256, a_query_points=128,
                            b_steps=20, b_batch=2, checkpoint_every=10, log_every=5)
        return Preset(name, corpus, model, train)
    if name == "standard":
        return Preset(name, corpus, ModelConfig(**sizes))
    if name == "paper":
        model = ModelConfig(enc_hidden=(128, 256), sdf_hidden=512, sdf_layers=8,
                            decoder=VertexDecoderConfig(hidden=128, cond=256, bones=32, knn=12, edge=64),
                            motion=MotionDecoderConfig(hidden=256, cond=512, steps=20000, batch=32, vertices=2048), **sizes)
        train = TrainConfig(a_steps=20000, a_identities=8, a_poses=8, a_enc_points=8192, a_query_points=2048,
                            b_steps=20000, b_batch=8)
        return Preset(name, corpus, model, train)
    raise ValueError(f"unknown preset {name!r}; valid presets: {', '.join(PRESETS)}")
