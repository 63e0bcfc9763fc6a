"""Process-level settings: the torch device, and tuning for interactive inference (glibc only; a no-op elsewhere)."""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

# mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 64 << 20  # bytes: allocations below this come from the heap
TRIM_THRESHOLD = 512 << 20  # free heap top kept before it is given back
TOP_PAD = 64 << 20


def keep_freed_memory() -> bool:
    """Let glibc keep freed blocks for reuse instead of handing them back to the kernel.

    The vertex decoder allocates a few 1-15 MB temporaries per call; by default glibc serves
    them with mmap and unmaps them when freed, so every call page-faults its memory in again
    (docs/history.md has the timings). The cost is that the process keeps its peak heap.
    Returns whether the setting took effect."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (e.g. musl)
        return False
    # Bounded: blocks up to 64 MB come from the heap and are reused; larger ones are still mapped
    # and returned (unbounded settings fragment the heap of `lrr bank` to many times its size).
    ok = mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
    ok &= mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1
    ok &= mallopt(_M_TOP_PAD, TOP_PAD) == 1
    return bool(ok)


# OpenMP spin iterations before an idle torch thread sleeps (libgomp; ~ tens of microseconds).
SPIN_COUNT = 10000


def short_thread_spin() -> None:
    """Let idle OpenMP threads spin only briefly before sleeping. Call before torch is imported.

    For a worker thread that predicts while the UI thread renders: the default spin (long)
    makes idle torch threads compete with rendering on a small CPU, while no spin at all
    (OMP_WAIT_POLICY=PASSIVE) wakes the threads from sleep at each of the decoder's ~100 ops.
    A value the user set in the environment wins."""

    if "OMP_WAIT_POLICY" not in os.environ:
        os.environ.setdefault("GOMP_SPINCOUNT", str(SPIN_COUNT))


def select_device():
    """CUDA when present, else CPU (LRR_DEVICE overrides): a torch.device."""
    import torch

    forced = os.environ.get("LRR_DEVICE")
    if forced:
        return torch.device(forced)
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def single_threaded() -> None:
    """One thread for torch and for numpy's BLAS in this process: for each worker of a pool as large as the cores.
    torch alone is not enough: two processes each running two OpenBLAS threads on two cores ran the corrective
    analysis 1.2x faster than one process (142 s vs 179), one thread each 2x (89 s). The limits hold for the
    process's life (`threadpoolctl.threadpool_limits`, never restored)."""
    import torch
    from threadpoolctl import threadpool_limits

    torch.set_num_threads(1)
    threadpool_limits(1)
