"""What ships in `assets/`: the trained `standard` model, its latent bank, the identity specs
and the reference report, and the ground truth of held-out identities regenerated from the
specs through the same rig code (so the explorer needs no corpus).

Layout (relative to the assets directory, `$LRR_ASSETS` or the repository's `assets/`):
    model/model.safetensors   trained checkpoint (preset + format inside)
    model/bank.safetensors    latent bank of that checkpoint
    identities.json           {"preset", "poses", "identities": [IdentitySpec dicts]}
    report/                   `lrr evaluate` output of the shipped model
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from latent_model.corpus.identities import IdentitySpec
from latent_model.errors import UserFacingError

REPO_ASSETS = Path(__file__).resolve().parent.parent / "assets"


class AssetsError(UserFacingError, RuntimeError):
    pass


def assets_dir() -> Path:
    return Path(os.environ.get("LRR_ASSETS", REPO_ASSETS))


@dataclass(frozen=True)
class ShippedPaths:
    checkpoint: Path
    bank: Path
    identities: Path
    report: Path

    @staticmethod
    def at(root: Path | None = None) -> "ShippedPaths":
        root = Path(root) if root is not None else assets_dir()
        return ShippedPaths(root / "model" / "model.safetensors", root / "model" / "bank.safetensors",
                            root / "identities.json", root / "report")

    def check(self) -> "ShippedPaths":
        for p in (self.checkpoint, self.bank, self.identities):
            if not p.exists():
                raise AssetsError(f"shipped asset {p} is missing; restore assets/ from git "
                                  f"(or set LRR_ASSETS to a directory holding model/ and identities.json)")
        return self


def load_identity_specs(path: Path | None = None) -> tuple[list[IdentitySpec], tuple[str, ...]]:
    """(specs, pose names) from identities.json."""
    path = Path(path) if path is not None else ShippedPaths.at().identities
    try:
        d = json.loads(Path(path).read_text())
        return [IdentitySpec.from_dict(x) for x in d["identities"]], tuple(d["poses"])
    except FileNotFoundError:
        raise AssetsError(f"identity specs {path} are missing; restore assets/ from git") from None
    except (ValueError, KeyError, TypeError) as e:
        raise AssetsError(f"identity specs {path} are unreadable ({e}); restore assets/ from git") from e


class GroundTruth:
    """Regenerates states of identity specs through the rig (float32 vertices, cached).
    The first use builds anny's cache if it is missing (minutes, once per machine)."""

    def __init__(self, specs: list[IdentitySpec]) -> None:
        from latent_model.corpus.states import StateGenerator

        self.specs = {s.id: s for s in specs}
        self.gen = StateGenerator()
        self._cache: dict[tuple, np.ndarray] = {}
        self._body_faces: np.ndarray | None = None

    @property
    def faces(self) -> np.ndarray:
        return np.asarray(self.gen.faces, dtype=np.int64)

    @property
    def body_faces(self) -> np.ndarray:
        """Faces of the body shell (the SDF surface)."""
        if self._body_faces is None:
            from latent_model.corpus.sdf import body_component_faces

            any_spec = next(iter(self.specs.values()))
            self._body_faces = body_component_faces(self.gen.neutral(any_spec), self.gen.faces)
        return self._body_faces

    def spec(self, identity: str) -> IdentitySpec:
        try:
            return self.specs[identity]
        except KeyError:
            raise ValueError(f"unknown identity {identity!r}; valid: {', '.join(self.specs)}") from None

    def state(self, identity: str, pose: str | None, variant: str) -> np.ndarray:
        """(V, 3) float32 vertices of (identity, pose, variant); pose None = neutral."""
        key = (identity, pose, variant)
        if key not in self._cache:
            if len(self._cache) > 256:
                self._cache.clear()
            self._cache[key] = self.gen.state(self.spec(identity), pose, variant).astype(np.float32)
        return self._cache[key]
