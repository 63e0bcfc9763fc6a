"""Checkpoints: safetensors weights + the preset they were trained with + a format version.

Inference and training both load through here (never arbitrary pickle). Format 1 checkpoints are
upgraded on load (`latent_model/legacy.py`).
"""
from __future__ import annotations

import json
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, safe_open, save_file

from latent_model.atomic import atomic_write
from latent_model.config import Preset
from latent_model.errors import UserFacingError

FORMAT_VERSION = 2
PHASE_B_PREFIXES = ("vertex_decoder.", "pose_fields.", "motion_decoder.")


class CheckpointError(UserFacingError, RuntimeError):
    """Missing, corrupt or mismatched checkpoint (the message says what to do)."""


def save_checkpoint(path: Path, model: torch.nn.Module, preset: Preset, phase: str, step: int,
                    extra: dict | None = None) -> None:
    """Weights (contiguous CPU tensors) + metadata {format_version, preset, phase, step, extra}."""
    tensors = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    meta = {"format_version": str(FORMAT_VERSION), "preset": json.dumps(preset.to_dict()),
            "phase": phase, "step": str(step), "extra": json.dumps(extra or {})}
    atomic_write(path, lambda tmp: save_file(tensors, str(tmp), metadata=meta))


def read_metadata(path: Path) -> dict:
    """The checkpoint's metadata; its "preset" is the format-2 JSON whatever the file's format."""
    from latent_model.legacy import LegacyError, upgrade_preset_v1

    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"checkpoint {path} does not exist; train one with `lrr train all --preset ...` "
                              f"or pass the shipped one in assets/")
    try:
        with safe_open(str(path), framework="pt") as f:
            meta = dict(f.metadata() or {})
    except (SafetensorError, OSError, ValueError) as e:
        raise CheckpointError(f"checkpoint {path} is corrupt or not a safetensors file ({e}); "
                              f"delete it and re-train (`lrr train ...`)") from e
    if "format_version" not in meta or "preset" not in meta:
        raise CheckpointError(f"{path} is not a LatentReRig checkpoint (no format version / preset metadata)")
    if meta["format_version"] == "1":
        try:
            meta["preset"] = json.dumps(upgrade_preset_v1(json.loads(meta["preset"])))
        except LegacyError as e:
            raise CheckpointError(f"checkpoint {path}: {e}") from None
    elif meta["format_version"] != str(FORMAT_VERSION):
        raise CheckpointError(f"checkpoint {path} has format version {meta['format_version']}, this program reads "
                              f"versions 1-{FORMAT_VERSION}; re-train it with this version")
    return meta


def read_stage_file(path: str | Path, fmt: str, what: str, remedy: str) -> tuple[dict, dict]:
    """(metadata, {name: tensor}) of a stage's safetensors file (the local detail, the corrective fields) whose
    metadata `format` must be `fmt`; anything else raises CheckpointError naming `what` and the `remedy` command."""
    path = Path(path)
    try:
        with safe_open(str(path), framework="pt") as f:
            meta = dict(f.metadata() or {})
            if meta.get("format") != fmt:
                raise CheckpointError(f"{path} is not a {what} file of this version ({fmt}); re-create it with `{remedy}`")
            return meta, {k: f.get_tensor(k) for k in f.keys()}
    except (SafetensorError, OSError) as e:
        raise CheckpointError(f"{what} file {path} is unreadable ({e}); re-create it with `{remedy}`") from e


def stored_preset(path: Path) -> Preset:
    """The preset a checkpoint was trained with."""
    return Preset.from_dict(json.loads(read_metadata(path)["preset"]))


def _tensors(path: Path, meta: dict) -> dict:
    from latent_model.legacy import upgrade_tensors_v1

    try:
        tensors = load_file(str(path))
    except (SafetensorError, OSError, ValueError) as e:
        raise CheckpointError(f"checkpoint {path} is corrupt ({e}); delete it and re-train") from e
    return upgrade_tensors_v1(tensors) if meta["format_version"] == "1" else tensors


def _load_into(model: torch.nn.Module, tensors: dict, path: Path, ignore: tuple[str, ...] = ()) -> None:
    try:
        missing, unexpected = model.load_state_dict(tensors, strict=False)
    except RuntimeError as e:  # size mismatch
        raise CheckpointError(f"checkpoint {path} does not fit the model ({str(e).splitlines()[-1].strip()}); "
                              f"it was trained with another config") from e
    missing = [k for k in missing if not k.startswith(ignore)] if ignore else list(missing)
    if missing or unexpected:
        raise CheckpointError(f"checkpoint {path} does not fit the model (missing {missing[:3]}, "
                              f"unexpected {list(unexpected)[:3]}); it is from another version or config")


def load_phase_a(path: Path, model: torch.nn.Module, expect: Preset) -> None:
    """Load only the Phase A parts (encoder, SDF decoder, heads) of a checkpoint into `model`:
    Phase B starts from them whatever Phase B parts the checkpoint carried."""
    meta = read_metadata(path)
    stored = Preset.from_dict(json.loads(meta["preset"]))
    if stored.model.phase_a_dict() != expect.model.phase_a_dict():
        raise CheckpointError(f"Phase A checkpoint {path} was trained with another encoder/SDF config than preset "
                              f"{expect.name!r}; re-train Phase A (lrr train phase-a --preset {expect.name} --fresh)")
    tensors = {k: v for k, v in _tensors(path, meta).items() if not k.startswith(PHASE_B_PREFIXES)}
    _load_into(model, tensors, path, ignore=PHASE_B_PREFIXES)


def load_phase_b_network(path: Path, model: torch.nn.Module, expect: Preset) -> None:
    """Load everything but decoder v2 (`motion_decoder.*`) of a Phase B checkpoint into `model`: decoder v2
    re-trains on it alone (`lrr train motion`) whatever motion config the checkpoint carried."""
    import dataclasses

    meta = read_metadata(path)
    stored = Preset.from_dict(json.loads(meta["preset"]))
    same = lambda m: dataclasses.replace(m, motion=dataclasses.replace(m.motion, enabled=True))  # noqa: E731
    strip = lambda m: {k: v for k, v in dataclasses.asdict(same(m)).items() if k != "motion"}  # noqa: E731
    if strip(stored.model) != strip(expect.model) or stored.train.b_steps != expect.train.b_steps:
        raise CheckpointError(f"Phase B checkpoint {path} was trained with another model config than preset "
                              f"{expect.name!r}; re-train Phase B (lrr train phase-b --preset {expect.name})")
    tensors = {k: v for k, v in _tensors(path, meta).items() if not k.startswith("motion_decoder.")}
    _load_into(model, tensors, path, ignore=("motion_decoder.",))


def load_checkpoint(path: Path, model: torch.nn.Module | None = None, expect: Preset | None = None):
    """Load weights (into `model`, or a new LatentReRig built from the stored preset).

    Returns (model, preset, metadata). A checkpoint trained with another config than `expect`
    (or whose tensors do not fit the model) raises CheckpointError."""
    from latent_model.nn.model import LatentReRig

    path = Path(path)
    meta = read_metadata(path)
    stored = Preset.from_dict(json.loads(meta["preset"]))
    if expect is not None and stored.model != expect.model:
        raise CheckpointError(f"checkpoint {path} was trained with preset {stored.name!r} and another model config "
                              f"than preset {expect.name!r}; use --preset {stored.name} or re-train")
    if model is None:
        model = LatentReRig(stored.model)
    _load_into(model, _tensors(path, meta), path)
    return model, stored, meta
