"""Dataclass configs and named presets (`tiny` for tests, `standard` shipped, `paper` for a GPU)."""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from latent_model.corpus.sdf import SdfSampling

PRESETS = ("tiny", "standard", "paper")


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
        blob = json.dumps(self.to_dict(), sort_keys=True).encode()
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
