"""The loop shared by both phases: optimiser, resume, checkpoints, progress, metrics, DDP."""
from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import torch
import torch.distributed as dist
from torch import nn

from latent_model.atomic import atomic_save_figure, atomic_write
from latent_model.config import Preset
from latent_model.checkpoint import CheckpointError, load_checkpoint, save_checkpoint


def save_resume(path: Path, state: dict) -> None:
    """Optimizer, scheduler, step and sampler state beside the checkpoint (a weights-only torch file)."""
    atomic_write(path, lambda tmp: torch.save(state, tmp))


def load_resume(path: Path) -> dict | None:
    path = Path(path)
    if not path.exists():
        return None
    try:
        return torch.load(path, weights_only=True, map_location="cpu")
    except Exception as e:  # noqa: BLE001 - any unreadable resume file means "start over"
        raise CheckpointError(f"resume state {path} is unreadable ({e}); delete it to start the phase over") from e


def dist_info() -> tuple[int, int]:
    """(rank, world size); (0, 1) outside torchrun."""
    if dist.is_available() and dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def close_distributed(wait: bool = True) -> None:
    """End the process group, after every rank got here when `wait` (not after an error: the others may never come).
    A rank that exits with the group alive can abort in gloo's threads ("terminate called without an active
    exception", seen once in five 2-process runs)."""
    if dist.is_available() and dist.is_initialized():
        if wait:
            dist.barrier()
        dist.destroy_process_group()


def init_distributed() -> bool:
    """Start the process group under torchrun (gloo on CPU, nccl on GPU). Returns whether distributed."""
    if "WORLD_SIZE" not in os.environ or int(os.environ["WORLD_SIZE"]) <= 1:
        return False
    if not dist.is_initialized():
        backend = "nccl" if torch.cuda.is_available() else "gloo"
        dist.init_process_group(backend=backend)
        if torch.cuda.is_available():
            torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", 0)))
    return True


@dataclass
class PhaseSpec:
    name: str  # "a" | "b"
    steps: int
    lr: float
    net: nn.Module  # forward(batch) -> (loss, {term: value})
    params: list[nn.Parameter]
    sample: Callable[[], object]
    rng_state: Callable[[], dict]
    set_rng_state: Callable[[dict], None]


def _lr_factor(step: int, total: int) -> float:
    """Linear warm-up over 50 steps, then cosine decay to 10 %."""
    warm = min(1.0, (step + 1) / 50)
    return warm * (0.1 + 0.45 * (1.0 + math.cos(math.pi * min(step, total) / max(total, 1))))


def _to_device(batch, device: torch.device):
    if device.type == "cpu":
        return batch
    for k, v in vars(batch).items():
        if isinstance(v, torch.Tensor):
            setattr(batch, k, v.to(device))
    return batch


def run_phase(spec: PhaseSpec, model: nn.Module, preset: Preset, run_dir: Path, device: torch.device,
              fresh: bool = False, progress: bool = True) -> dict:
    """Train one phase to `spec.steps` steps, resuming from run_dir's last checkpoint of this phase."""
    from tqdm import tqdm

    rank, world = dist_info()
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    ckpt = run_dir / f"phase_{spec.name}.safetensors"
    resume_path = run_dir / f"phase_{spec.name}.resume.pt"
    log_path = run_dir / f"metrics_{spec.name}.jsonl"
    net = spec.net
    if world > 1:
        net = nn.parallel.DistributedDataParallel(net, find_unused_parameters=True, broadcast_buffers=False)
    opt = torch.optim.Adam(spec.params, lr=spec.lr)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: _lr_factor(s, spec.steps))
    start = 0
    state = None if fresh else load_resume(resume_path)
    if state is not None:
        if state.get("preset") != json.dumps(preset.to_dict()):
            raise CheckpointError(f"{resume_path} belongs to another config; pass --fresh to start over")
        load_checkpoint(ckpt, model)
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
        spec.set_rng_state(state["sampler"][rank] if rank < len(state["sampler"]) else state["sampler"][0])
        torch.set_rng_state(state["torch_rng"])
        start = int(state["step"])
    elif rank == 0 and log_path.exists():
        log_path.unlink()  # a fresh phase starts a fresh log
    net.train()
    bar = tqdm(total=spec.steps, initial=start, desc=f"phase {spec.name.upper()}", disable=not progress or rank != 0,
               unit="step")
    t0 = time.perf_counter()
    last: dict = {}

    def checkpoint(step: int) -> None:
        samplers = [spec.rng_state()]
        if world > 1:
            gathered = [None] * world
            dist.all_gather_object(gathered, samplers[0])
            samplers = gathered
        if rank == 0:
            save_checkpoint(ckpt, model, preset, spec.name, step)
            save_resume(resume_path, {"step": step, "optimizer": opt.state_dict(), "scheduler": sched.state_dict(),
                                      "sampler": samplers, "torch_rng": torch.get_rng_state(),
                                      "preset": json.dumps(preset.to_dict())})

    for step in range(start, spec.steps):
        batch = _to_device(spec.sample(), device)
        loss, terms = net(batch)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        if preset.train.grad_clip:
            torch.nn.utils.clip_grad_norm_(spec.params, preset.train.grad_clip)
        opt.step()
        sched.step()
        if not torch.isfinite(loss):
            raise FloatingPointError(f"phase {spec.name}: loss became {loss.item()} at step {step}; "
                                     f"lower the learning rate in the preset")
        bar.update(1)
        if (step + 1) % preset.train.log_every == 0 or step + 1 == spec.steps:
            last = {"step": step + 1, "loss": float(loss.detach()), **{k: float(v) for k, v in terms.items()},
                    "lr": sched.get_last_lr()[0], "seconds": time.perf_counter() - t0}
            bar.set_postfix(loss=f"{last['loss']:.4f}")
            if rank == 0:
                with open(log_path, "a") as f:
                    f.write(json.dumps(last) + "\n")
        if (step + 1) % preset.train.checkpoint_every == 0 or step + 1 == spec.steps:
            checkpoint(step + 1)
    bar.close()
    if start >= spec.steps and not ckpt.exists():
        checkpoint(spec.steps)
    if rank == 0:
        plot_loss_curve(log_path, run_dir / f"loss_{spec.name}.png", f"phase {spec.name.upper()} ({preset.name})")
    return last


def plot_loss_curve(log_path: Path, out: Path, title: str) -> None:
    """Loss curve PNG from a metrics JSONL (total + every term, log scale)."""
    if not Path(log_path).exists():
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [json.loads(x) for x in Path(log_path).read_text().splitlines() if x.strip()]
    if not rows:
        return
    fig, ax = plt.subplots(figsize=(7, 4))
    steps = [r["step"] for r in rows]
    for key in rows[-1]:
        if key in ("step", "lr", "seconds"):
            continue
        vals = [r.get(key, float("nan")) for r in rows]
        ax.plot(steps, vals, label=key, lw=2.0 if key == "loss" else 1.0)
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_title(title)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    atomic_save_figure(fig, out, dpi=90)
