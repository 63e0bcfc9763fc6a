"""Heavy work off the UI thread: one model thread runs predictions (coalesced: only the latest
selection waiting) ahead of background jobs (loading, noise floor, heatmaps, opening, exporting),
which are generators stepping with progress so predictions can run between their steps.

A job is keyed by the type of result it returns (`Loaded`, `HeatmapData`, `NoiseFloor`,
`MeshOpened`, `Exported`): that type is what `cancel` names and what a `Failed` reports, so the
window dispatches every outcome by type, never by a job's name. Results cross to the UI thread
through one Qt signal (queued across threads); the session's compute side is touched only here.
"""
from __future__ import annotations

import threading
import time
import traceback
from collections import deque
from dataclasses import dataclass
from typing import Callable, Iterator

from PySide6.QtCore import QObject, Signal

from explorer.coalescer import Coalescer
from explorer.results import Failed, Predicted
from explorer.selection import Selection

# A job: a callable returning a generator of (message, fraction|None) that returns its result.
Job = Callable[[], Iterator[tuple[str, float | None]]]

USER_ERRORS = (ValueError, KeyError, FileNotFoundError, RuntimeError)


def describe_error(e: BaseException) -> str:
    """A message for a dialog: user errors as they are, anything else with its type."""
    if isinstance(e, KeyError):
        return str(e.args[0]) if e.args else repr(e)
    if isinstance(e, USER_ERRORS):
        return str(e)
    return f"{type(e).__name__}: {e}"


@dataclass(eq=False)  # compared by identity: two jobs of one kind are two jobs
class _Queued:
    kind: type
    start: Job
    subject: str | None
    steps: Iterator | None = None


class ModelWorker(QObject):
    """result(Predicted | Loaded | HeatmapData | NoiseFloor | MeshOpened | Exported | Failed) and
    progress(message, fraction or None)."""

    result = Signal(object)
    progress = Signal(str, object)

    def __init__(self) -> None:
        super().__init__()
        self.session = None  # set by the window when the load job's result arrives
        self.coalescer: Coalescer[tuple[Selection, float]] = Coalescer()
        self._now: tuple[Selection, float] | None = None
        self._jobs: deque[_Queued] = deque()
        self._cond = threading.Condition()
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="lrr-model-worker", daemon=True)
        self._thread.start()

    # -------------------------------------------------------------- UI side
    def request(self, sel: Selection) -> None:
        """Ask for a prediction; while one is running only the latest request waits."""
        item = (sel, time.perf_counter())
        if self.coalescer.submit(item):
            with self._cond:
                self._now = item
                self._cond.notify()

    def submit(self, kind: type, job: Job, subject: str | None = None) -> None:
        """Queue a job that returns a `kind` (its Failed names `kind` and `subject`)."""
        with self._cond:
            self._jobs.append(_Queued(kind, job, subject))
            self._cond.notify()

    def cancel(self, kind: type) -> None:
        """Drop the queued jobs of a kind (one mid-step finishes that step and is dropped)."""
        with self._cond:
            self._jobs = deque(j for j in self._jobs if j.kind is not kind)

    def stop(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify()
        self._thread.join(timeout=5)

    @property
    def idle(self) -> bool:
        with self._cond:
            return self._now is None and not self._jobs and not self.coalescer.busy

    # -------------------------------------------------------------- worker thread
    def _run(self) -> None:
        import torch

        torch.set_num_threads(max(1, min(4, torch.get_num_threads())))
        while True:
            with self._cond:
                while not self._stop and self._now is None and not self._jobs:
                    self._cond.wait()
                if self._stop:
                    return
                item, self._now = self._now, None
                job = self._jobs[0] if (item is None and self._jobs) else None
            if item is not None:
                self._predict(item)
            elif job is not None:
                self._step(job)

    def _predict(self, item: tuple[Selection, float]) -> None:
        while item is not None:
            sel, t0 = item
            try:
                if self.session is None:
                    raise RuntimeError("the model is still loading")
                if (slow := self.session.slow_step(sel)) is not None:
                    self.progress.emit(slow, None)
                self.result.emit(Predicted(self.session.compute(sel), t0))
            except Exception as e:  # noqa: BLE001 - shown in a dialog; the window survives
                if not isinstance(e, USER_ERRORS):
                    traceback.print_exc()
                self.result.emit(Failed(Predicted, describe_error(e)))
            ok, nxt = self.coalescer.take()
            item = nxt if ok else None

    def _step(self, job: _Queued) -> None:
        try:
            if job.steps is None:  # not started yet
                job.steps = job.start()
            msg, frac = next(job.steps)
            if self._queued(job):
                self.progress.emit(msg, frac)
        except StopIteration as s:
            if self._pop(job):  # a cancelled job's result is dropped
                ok = isinstance(s.value, job.kind)
                self.result.emit(s.value if ok else Failed(
                    job.kind, f"internal error: a {job.kind.__name__} job returned {type(s.value).__name__}", job.subject))
        except Exception as e:  # noqa: BLE001
            if not isinstance(e, USER_ERRORS):
                traceback.print_exc()
            if self._pop(job):
                self.result.emit(Failed(job.kind, describe_error(e), job.subject))

    def _queued(self, job: _Queued) -> bool:
        with self._cond:
            return any(j is job for j in self._jobs)

    def _pop(self, job: _Queued) -> bool:
        """Remove this job (not another of its kind); False if it was cancelled meanwhile."""
        with self._cond:
            for j in self._jobs:
                if j is job:
                    self._jobs.remove(j)
                    return True
            return False
