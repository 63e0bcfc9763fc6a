"""Characters of an evaluation shared among processes.

Most of `lrr evaluate`'s work is single-threaded numpy per held-out character (surface features, predictions,
metrics), so each analysis maps one function over its characters on a few processes of one thread each. Every
process receives the `Transfer` and the analysis' shared inputs once (at start) and opens the corpus itself (it is
memory-mapped: pickling it would copy it). The results come back in the characters' order, so the metrics of any
number of processes are those of one, up to float rounding.
"""
from __future__ import annotations

import os
from typing import Any, Callable, Iterable

_WORKER: dict = {}


def resolve_workers(workers: int | None, n_items: int) -> int:
    """The processes an analysis of `n_items` characters runs on: `workers`, or None for one per core, at most 2 (the
    development machine's cores; more only add memory) and at most one per item."""
    if workers is not None and workers < 1:
        raise ValueError(f"--workers {workers}: give 1 or more processes (or leave it out: one per core, at most 2)")
    return max(1, min(2, os.cpu_count() or 1, n_items)) if workers is None else workers


def map_characters(fn: Callable[..., Any], items: Iterable, transfer, workers: int = 1, corpus=None,
                   shared: Any = None, desc: str | None = None, progress: bool = False) -> list:
    """[fn(transfer, corpus, shared, item) for item in items], on `workers` processes (1: in this one).
    `fn` must be a module-level function (it is sent by name); `corpus` is reopened from its path in each process."""
    from tqdm import tqdm

    items = list(items)
    workers = resolve_workers(workers, len(items))
    bar = tqdm(total=len(items), desc=desc, unit="character", disable=not progress)
    out = []
    if workers == 1 or len(items) < 2:
        for item in items:
            out.append(fn(transfer, corpus, shared, item))
            bar.update()
    else:
        import multiprocessing as mp

        corpus_path = None if corpus is None else str(corpus.path)
        with mp.get_context("spawn").Pool(min(workers, len(items)), initializer=_init_worker,
                                          initargs=(transfer, corpus_path, shared)) as pool:
            for r in pool.imap(_call, [(fn, item) for item in items]):
                out.append(r)
                bar.update()
            pool.close()  # let the processes exit (leaving the block alone terminates them, leaking semaphores)
            pool.join()
    bar.close()
    return out


def _init_worker(transfer, corpus_path: str | None, shared: Any) -> None:
    from latent_model.corpus.store import Corpus
    from latent_model.runtime import single_threaded

    single_threaded()
    _WORKER.update(transfer=transfer, corpus=None if corpus_path is None else Corpus(corpus_path), shared=shared)


def _call(job: tuple) -> Any:
    fn, item = job
    return fn(_WORKER["transfer"], _WORKER["corpus"], _WORKER["shared"], item)
