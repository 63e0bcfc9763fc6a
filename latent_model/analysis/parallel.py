"""Characters of an evaluation shared among processes.

Most of `lrr evaluate`'s work is single-threaded numpy per held-out character (surface features, predictions,
metrics), so each analysis maps one function over its characters on a few processes of one thread each. The
processes (`Workers`) start once per evaluation and take every analysis's characters from one queue: starting
them costs ~9 s of both cores (torch, the `Transfer`, the corpus), and a core that finishes one analysis's last
character starts on the next analysis's instead of waiting for the other core. Every process receives the
`Transfer` once (at start) and opens the corpus itself (it is memory-mapped: pickling it would copy it); an
analysis's shared inputs go to each process once, through a file. The results come back in the characters'
order, so the metrics of any number of processes are those of one, up to float rounding.
"""
from __future__ import annotations

import os
import pickle
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterable

_WORKER: dict = {}


def resolve_workers(workers: int | None, n_items: int) -> int:
    """The processes an analysis of `n_items` characters runs on: `workers`, or None for one per core, at most 2 (the
    development machine's cores; more only add memory) and at most one per item."""
    if workers is not None and workers < 1:
        raise ValueError(f"--workers {workers}: give 1 or more processes (or leave it out: one per core, at most 2)")
    return max(1, min(2, os.cpu_count() or 1, n_items)) if workers is None else workers


class Batch:
    """One analysis's characters given to `Workers.submit`: `get()` waits for them and returns `then(results)`,
    the results in the items' order. In one process the characters are computed by `get()` itself."""

    def __init__(self, run: Callable[[], Iterable], n: int, then: Callable[[list], Any] | None, desc: str | None,
                 progress: bool, owner: "Workers | None" = None) -> None:
        self._run, self._n, self._then, self._desc, self._progress, self._owner = run, n, then, desc, progress, owner
        self._done = False

    def get(self) -> Any:
        from tqdm import tqdm

        if self._done:
            raise RuntimeError("Batch.get() called twice: keep its result")
        self._done = True
        try:
            out = list(tqdm(self._run(), total=self._n, desc=self._desc, unit="character", disable=not self._progress))
        finally:
            if self._owner is not None:  # a pool made for this batch alone
                self._owner.close()
        return out if self._then is None else self._then(out)


class Workers:
    """`workers` processes of one thread each (1: this process) for the analyses of one evaluation; `corpus` is
    reopened from its path in each. A context manager: leaving it waits for the processes to finish and stops them."""

    def __init__(self, transfer, corpus=None, workers: int = 1) -> None:
        self.transfer, self.corpus, self.n = transfer, corpus, resolve_workers(workers, 1)
        self._pool = None
        self._dir: tempfile.TemporaryDirectory | None = None
        self._stages = 0
        if self.n > 1:
            import multiprocessing as mp

            corpus_path = None if corpus is None else str(corpus.path)
            self._dir = tempfile.TemporaryDirectory(prefix="lrr-workers-")
            # the processes start now, in the background: the caller goes on preparing the first analysis
            self._pool = mp.get_context("spawn").Pool(self.n, initializer=_init_worker,
                                                      initargs=(transfer, corpus_path))

    def submit(self, fn: Callable[..., Any], items: Iterable, shared: Any = None, then: Callable[[list], Any] | None = None,
               desc: str | None = None, progress: bool = False, _owner: "Workers | None" = None) -> Batch:
        """Queue fn(transfer, corpus, shared, item) for each item behind what is already queued; `fn` must be a
        module-level function (it is sent by name). Returns the `Batch` to `get()` them from."""
        items = list(items)
        if self._pool is None:
            run = lambda: (fn(self.transfer, self.corpus, shared, item) for item in items)  # noqa: E731
            return Batch(run, len(items), then, desc, progress, _owner)
        self._stages += 1
        path = None
        if shared is not None:
            path = str(Path(self._dir.name) / f"shared{self._stages}.pkl")
            with open(path, "wb") as f:
                pickle.dump(shared, f, protocol=pickle.HIGHEST_PROTOCOL)
        results = self._pool.imap(_call, [(fn, path, item) for item in items])  # queued now, run as cores free up
        return Batch(lambda: results, len(items), then, desc, progress, _owner)

    def map(self, fn: Callable[..., Any], items: Iterable, shared: Any = None, desc: str | None = None,
            progress: bool = False) -> list:
        """[fn(transfer, corpus, shared, item) for item in items] (`submit` and wait)."""
        return self.submit(fn, items, shared, desc=desc, progress=progress).get()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()  # let the processes exit (terminating them leaks semaphores)
            self._pool.join()
            self._pool = None
        if self._dir is not None:
            self._dir.cleanup()
            self._dir = None

    def __enter__(self) -> "Workers":
        return self

    def __exit__(self, exc_type, *_) -> None:
        if exc_type is not None and self._pool is not None:
            self._pool.terminate()  # an error: the queued characters are not wanted
        self.close()


def submit_characters(fn: Callable[..., Any], items: Iterable, transfer, workers: "int | Workers" = 1, corpus=None,
                      shared: Any = None, then: Callable[[list], Any] | None = None, desc: str | None = None,
                      progress: bool = False) -> Batch:
    """`Workers.submit` on `workers`: a `Workers` already running, or a count of processes started for this batch
    alone (stopped by its `get()`)."""
    items = list(items)
    if isinstance(workers, Workers):
        return workers.submit(fn, items, shared, then, desc, progress)
    own = Workers(transfer, corpus, resolve_workers(workers, len(items)))
    return own.submit(fn, items, shared, then, desc, progress, _owner=own)


def _init_worker(transfer, corpus_path: str | None) -> None:
    from latent_model.corpus.store import Corpus
    from latent_model.runtime import single_threaded

    single_threaded()
    _WORKER.update(transfer=transfer, corpus=None if corpus_path is None else Corpus(corpus_path),
                   shared_path=None, shared=None)


def _call(job: tuple) -> Any:
    fn, path, item = job
    if path != _WORKER["shared_path"]:  # a new analysis (a process takes them in queue order): read its inputs once
        shared = None
        if path is not None:
            with open(path, "rb") as f:
                shared = pickle.load(f)
        _WORKER.update(shared_path=path, shared=shared)
    return fn(_WORKER["transfer"], _WORKER["corpus"], _WORKER["shared"], item)
