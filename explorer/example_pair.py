"""Reading an example pair for the explorer (Qt-free): a character's mesh A and the same mesh deformed,
A1, read in A's frame, both encoded through the Transfer API, the latent delta mu(A1) - mu(A) kept and A's body
motion read as the vocabulary's poses (`Transfer.example_body`).
Encoding two meshes is the slow part of the feature (a second or two each), so it runs once per pair,
as steps with progress in the model worker; the predictions that follow only read the delta."""
from __future__ import annotations

import os
import threading
from collections.abc import Generator
from dataclasses import replace
from pathlib import Path

from latent_model.facing import face_front_pair
from latent_model.meshio import load_example_pair

from explorer.results import ExamplePair

Progress = tuple[str, float | None]  # a step's (message, fraction done or None = busy)


def file_stamp(*paths: str | Path) -> tuple:
    """(size, mtime) of each file, None for one that cannot be read: files that changed are read again."""
    out = []
    for p in paths:
        try:
            st = os.stat(p)
            out.append((st.st_size, st.st_mtime_ns))
        except OSError:
            out.append(None)
    return tuple(out)


def same_files(pair: ExamplePair, neutral: str | Path, posed: str | Path) -> bool:
    """True when `pair` was read from these two files and neither changed since."""
    same = [Path(a).resolve() == Path(b).resolve() for a, b in zip(pair.paths, (neutral, posed), strict=True)]
    stamp = file_stamp(neutral, posed)
    return all(same) and None not in stamp and stamp == pair.stamp


class ExamplePairs:
    """The example pairs a session holds, by name; thread-safe (the model worker adds, both threads read)."""

    def __init__(self) -> None:
        self._pairs: dict[str, ExamplePair] = {}
        self._lock = threading.Lock()

    def __contains__(self, name: object) -> bool:
        with self._lock:
            return name in self._pairs

    def get(self, name: str) -> ExamplePair | None:
        with self._lock:
            return self._pairs.get(name)

    def names(self) -> list[str]:
        with self._lock:
            return list(self._pairs)

    def find(self, neutral: str | Path, posed: str | Path) -> ExamplePair | None:
        """The held pair read from these two files, if neither changed since."""
        with self._lock:
            pairs = list(self._pairs.values())
        return next((p for p in pairs if same_files(p, neutral, posed)), None)

    def add(self, pair: ExamplePair) -> ExamplePair:
        """Hold a pair under a name no other held pair has (the same two file names twice: "(2)")."""
        with self._lock:
            name, k = pair.name, 2
            while name in self._pairs:
                name = f"{pair.name} ({k})"
                k += 1
            pair = replace(pair, name=name)
            self._pairs[name] = pair
        return pair


def read_example_steps(transfer, neutral: str | Path, posed: str | Path, up: str = "auto", units: str = "auto",
                       seed: int = 0) -> Generator[Progress, None, ExamplePair]:
    """Generator: read and encode an example pair, yielding progress; returns the `ExamplePair`
    (named "A.obj → A1.obj"). A1 that is not A deformed raises `MeshError` with the fix."""
    neutral, posed = str(neutral), str(posed)
    yield f"reading the example pair {Path(neutral).name} → {Path(posed).name}", None
    stamp = file_stamp(neutral, posed)  # before reading: a file rewritten meanwhile is read again next time
    a, a1 = load_example_pair(neutral, posed, up=up, units=units)
    notes: list[str] = []
    a, a1 = face_front_pair(transfer, a, a1, up_known=up != "auto", progress=notes.append)
    if notes:
        yield notes[0], 0.05
    # one seed for both: with one topology the SDF samples move with the surface, and most of the
    # sampling noise cancels in the delta (Transfer.example_delta)
    prepared = []
    for k, m in enumerate((a, a1)):
        yield f"encoding the example's {('neutral', 'posed')[k]} mesh {m.name}", 0.1 + 0.45 * k
        p = transfer.prepare_user_mesh(m, seed)
        p.mu  # noqa: B018 - the encoding, in this step
        prepared.append(p)
    delta = transfer.example_delta(*prepared)
    if transfer.detail is not None:
        yield "encoding the example's head and hands (local detail)", 0.9
    detail = transfer.example_detail(*prepared)
    yield "reading the example's body motion as the vocabulary's poses", 0.95
    body = transfer.example_body(*prepared)
    novelty = transfer.novelty(prepared[0]) if transfer.bank.ood_threshold > 0 else None
    return ExamplePair(f"{a.name} → {a1.name}", a, a1, delta, (neutral, posed), stamp, novelty, detail, body)
