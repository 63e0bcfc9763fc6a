"""Checkpoints: safetensors weights + the preset they were trained with + a format version.

Resume state (optimizer, step, RNG) goes to a weights-only torch file beside the checkpoint.
Never arbitrary pickle: `torch.load(weights_only=True)`.
"""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, safe_open, save_file

from latent_model.config import Preset

FORMAT_VERSION = 1


class CheckpointError(RuntimeError):
    """Missing, corrupt or mismatched checkpoint (the message says what to do)."""


def _atomic(path: Path, write) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def save_checkpoint(path: Path, model: torch.nn.Module, preset: Preset, phase: str, step: int,
                    extra: dict | None = None) -> None:
    """Weights (contiguous CPU tensors) + metadata {format_version, preset, phase, step, extra}."""
    tensors = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    meta = {"format_version": str(FORMAT_VERSION), "preset": json.dumps(preset.to_dict()),
            "phase": phase, "step": str(step), "extra": json.dumps(extra or {})}
    _atomic(path, lambda tmp: save_file(tensors, tmp, metadata=meta))


def read_metadata(path: Path) -> dict:
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"checkpoint {path} does not exist; train one with `lrr train all --preset ...` "
                              f"or pass the shipped one in assets/")
    try:
        with safe_open(str(path), framework="pt") as f:
            meta = f.metadata() or {}
    except (SafetensorError, OSError, ValueError) as e:
        raise CheckpointError(f"checkpoint {path} is corrupt or not a safetensors file ({e}); "
                              f"delete it and re-train (`lrr train ...`)") from e
    if "format_version" not in meta or "preset" not in meta:
        raise CheckpointError(f"{path} is not a LatentReRig checkpoint (no format version / preset metadata)")
    if meta["format_version"] != str(FORMAT_VERSION):
        raise CheckpointError(f"checkpoint {path} has format version {meta['format_version']}, this program reads "
                              f"version {FORMAT_VERSION}; re-train it with this version")
    return meta


def _phase_a_config(m) -> dict:
    """The model config without the vertex decoder's fields (what Phase A depends on)."""
    import dataclasses

    return {k: v for k, v in dataclasses.asdict(m).items() if not k.startswith("vd_")}


def load_phase_a(path: Path, model: torch.nn.Module, expect: Preset) -> None:
    """Load only the Phase A parts (encoder, SDF decoder, heads) of a checkpoint into `model`:
    Phase B starts from them whatever vertex decoder the checkpoint carried, so a vertex-decoder
    change does not force re-training Phase A."""
    meta = read_metadata(path)
    stored = Preset.from_dict(json.loads(meta["preset"]))
    if _phase_a_config(stored.model) != _phase_a_config(expect.model):
        raise CheckpointError(f"Phase A checkpoint {path} was trained with another encoder/SDF config than preset "
                              f"{expect.name!r}; re-train Phase A (lrr train phase-a --preset {expect.name} --fresh)")
    try:
        tensors = {k: v for k, v in load_file(str(path)).items() if not k.startswith("vertex_decoder.")}
    except (SafetensorError, OSError, ValueError) as e:
        raise CheckpointError(f"checkpoint {path} is corrupt ({e}); delete it and re-train") from e
    try:
        missing, unexpected = model.load_state_dict(tensors, strict=False)
    except RuntimeError as e:
        raise CheckpointError(f"checkpoint {path} does not fit the model ({str(e).splitlines()[-1].strip()})") from e
    missing = [k for k in missing if not k.startswith("vertex_decoder.")]
    if missing or unexpected:
        raise CheckpointError(f"checkpoint {path} does not fit the model (missing {missing[:3]}, "
                              f"unexpected {list(unexpected)[:3]}); it is from another version or config")


def load_checkpoint(path: Path, model: torch.nn.Module | None = None, expect: Preset | None = None):
    """Load weights (into `model`, or a new LatentReRig built from the stored preset).

    Returns (model, preset, metadata). A checkpoint trained with another config than `expect`
    (or whose tensors do not fit the model) raises CheckpointError."""
    from latent_model.nn.model import LatentReRig

    meta = read_metadata(path)
    stored = Preset.from_dict(json.loads(meta["preset"]))
    if expect is not None and stored.model != expect.model:
        raise CheckpointError(f"checkpoint {path} was trained with preset {stored.name!r} and another model config "
                              f"than preset {expect.name!r}; use --preset {stored.name} or re-train")
    if model is None:
        model = LatentReRig(stored.model)
    try:
        tensors = load_file(str(path))
    except (SafetensorError, OSError, ValueError) as e:
        raise CheckpointError(f"checkpoint {path} is corrupt ({e}); delete it and re-train") from e
    try:
        missing, unexpected = model.load_state_dict(tensors, strict=False)
    except RuntimeError as e:  # size mismatch
        raise CheckpointError(f"checkpoint {path} does not fit the model ({str(e).splitlines()[-1].strip()}); "
                              f"it was trained with another config") from e
    if missing or unexpected:
        raise CheckpointError(f"checkpoint {path} does not fit the model (missing {list(missing)[:3]}, "
                              f"unexpected {list(unexpected)[:3]}); it is from another version or config")
    return model, stored, meta


def save_resume(path: Path, state: dict) -> None:
    _atomic(path, lambda tmp: torch.save(state, tmp))


def load_resume(path: Path) -> dict | None:
    path = Path(path)
    if not path.exists():
        return None
    try:
        return torch.load(path, weights_only=True, map_location="cpu")
    except Exception as e:  # noqa: BLE001 - any unreadable resume file means "start over"
        raise CheckpointError(f"resume state {path} is unreadable ({e}); delete it to start the phase over") from e
