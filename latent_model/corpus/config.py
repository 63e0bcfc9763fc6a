"""What determines a corpus: `CorpusConfig` (identities, poses, SDF sampling, seed) and its presets.

The config's digest (with GENERATOR_VERSION) is stored in a corpus, so a corpus built by other code
or settings is detected instead of silently reused.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field

from latent_model.corpus.poses import POSES, get_pose
from latent_model.corpus.sdf import SdfSampling
from latent_model.types import PRESETS

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
