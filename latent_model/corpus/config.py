"""What determines a corpus: `CorpusConfig` (persons, rests, poses, SDF sampling, seed) and its presets.

The config's digest (with GENERATOR_VERSION) is stored in a corpus, so a corpus built by other code
or settings is detected instead of silently reused.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field

from latent_model.corpus.poses import POSES, get_pose
from latent_model.corpus.rests import TEST_RESTS, VAL_RESTS
from latent_model.corpus.sdf import SdfSampling
from latent_model.types import PRESETS

# Bump when the geometry a config produces changes (rig, correctives, faces, sampling code):
# it enters the corpus digest, so stale corpora are detected instead of silently reused.
# 4: characters in rest configurations, a validation split, stylised training persons.
GENERATOR_VERSION = 4


@dataclass(frozen=True)
class CorpusConfig:
    """Everything that determines a corpus; the same config gives the same arrays."""

    preset: str
    n_identities: int = 78  # persons (each is one character per rest it stands in)
    n_test: int = 14
    n_stylised: int = 2  # stylised (out-of-distribution) test persons (fixed recipes)
    poses: tuple[str, ...] | None = None  # None: the whole vocabulary
    n_val: int = 0  # validation persons, taken from the non-test ones (one stylised if any are)
    n_stylised_train: int = 0  # non-test persons given a seeded stylised recipe of their own
    train_rests: int = 0  # non-bind training rests each training person also stands in
    val_rests: tuple[str, ...] = ()  # each validation person also stands in one of these
    test_rests: tuple[str, ...] = ()  # each test person also stands in all of these
    sdf: SdfSampling = field(default_factory=SdfSampling)
    seed: int = 0

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "CorpusConfig":
        d = dict(d)
        d["sdf"] = SdfSampling(**{k: tuple(v) if isinstance(v, list) else v for k, v in d["sdf"].items()})
        for key in ("poses", "val_rests", "test_rests"):
            if d.get(key) is not None:
                d[key] = tuple(d[key])
        return CorpusConfig(**d)

    @property
    def n_train_persons(self) -> int:
        """Training persons: the identity classifier's classes."""
        return self.n_identities - self.n_test - self.n_val

    def digest(self) -> str:
        """Short hash of the config, stored in the corpus to detect a mismatch."""
        blob = json.dumps({"config": self.to_dict(), "generator": GENERATOR_VERSION}, sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]

    def pose_names(self) -> tuple[str, ...]:
        if self.poses is None:
            return tuple(POSES)
        for name in self.poses:
            get_pose(name)  # raises with the valid names
        return self.poses


TINY_POSES = (
    "elbowBentLf", "elbowBentRt", "kneeBentLf", "fingerKnuckleB02Lf",
    "browDwLf", "puffLf", "cornerUpLf", "elbowBentLf+kneeBentLf",
)


# Rests and splits of the full presets: 56 training persons (7 stylised) in bind + one other training
# rest, 8 validation persons (1 stylised) in bind + one validation rest, 14 test persons in bind + the
# three test rests: 184 characters, within the build's time and disk budget (docs/history.md).
_V4 = dict(n_val=8, n_stylised_train=8, train_rests=1, val_rests=VAL_RESTS, test_rests=TEST_RESTS)


def corpus_preset(name: str) -> CorpusConfig:
    """The named corpus preset; unknown names raise with the valid ones."""
    if name == "tiny":
        return CorpusConfig(preset="tiny", n_identities=6, n_test=2, n_stylised=1, poses=TINY_POSES,
                            sdf=SdfSampling(k=1024), n_val=1, n_stylised_train=2, train_rests=1,
                            val_rests=("armsSides",), test_rests=("tpose",))
    if name == "standard":
        return CorpusConfig(preset="standard", sdf=SdfSampling(k=8192), **_V4)
    if name == "paper":
        return CorpusConfig(preset="paper", sdf=SdfSampling(k=16384), **_V4)
    raise ValueError(f"unknown preset {name!r}; valid presets: {', '.join(PRESETS)}")
