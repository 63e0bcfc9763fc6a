"""Heavy work off the UI thread: one model thread runs predictions (coalesced: only the latest
selection waiting) ahead of background jobs (loading, noise floor, heatmaps), which are
generators stepping with progress so predictions can run between their steps.

The session is touched only from this thread (it is not thread-safe); results come back to the
UI thread through Qt signals (queued across threads).
"""
from __future__ import annotations

import threading
import time
import traceback
from collections import deque
from typing import Any, Callable, Iterator

from PySide6.QtCore import QObject, Signal

from explorer.session import Coalescer, Selection

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


class ModelWorker(QObject):
    """predicted(ViewState, request time) | prediction_failed(message) | job_progress(name, message, fraction)
    | job_done(name, result) | job_failed(name, message)."""

    predicted = Signal(object, float)
    prediction_failed = Signal(str)
    job_progress = Signal(str, str, object)
    job_done = Signal(str, object)
    job_failed = Signal(str, str)

    def __init__(self) -> None:
        super().__init__()
        self.session = None  # set by the load job
        self.coalescer: Coalescer[tuple[Selection, float]] = Coalescer()
        self._now: tuple[Selection, float] | None = None
        self._jobs: deque[tuple[str, Iterator]] = deque()
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

    def submit(self, name: str, job: Job) -> None:
        with self._cond:
            self._jobs.append((name, job))
            self._cond.notify()

    def cancel_jobs(self, name: str) -> None:
        with self._cond:
            self._jobs = deque(j for j in self._jobs if j[0] != name)

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
                state = self.session.compute(sel)
                self.predicted.emit(state, t0)
            except Exception as e:  # noqa: BLE001 - shown in a dialog; the window survives
                if not isinstance(e, USER_ERRORS):
                    traceback.print_exc()
                self.prediction_failed.emit(describe_error(e))
            ok, nxt = self.coalescer.take()
            item = nxt if ok else None

    def _step(self, job: tuple[str, Any]) -> None:
        name, it = job
        try:
            if callable(it):  # not started yet
                it = it()
                with self._cond:
                    if self._jobs and self._jobs[0][0] == name:
                        self._jobs[0] = (name, it)
            msg, frac = next(it)
            self.job_progress.emit(name, msg, frac)
        except StopIteration as s:
            self._pop(name)
            self.job_done.emit(name, s.value)
        except Exception as e:  # noqa: BLE001
            if not isinstance(e, USER_ERRORS):
                traceback.print_exc()
            self._pop(name)
            self.job_failed.emit(name, describe_error(e))

    def _pop(self, name: str) -> None:
        with self._cond:
            if self._jobs and self._jobs[0][0] == name:
                self._jobs.popleft()
