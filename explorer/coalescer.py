"""Coalescing of slider updates: only the latest request waits while one runs (Qt-free, thread-safe)."""
from __future__ import annotations

import threading
from typing import Generic, TypeVar

T = TypeVar("T")


class Coalescer(Generic[T]):
    """At most one request in flight and one waiting: a new request replaces the waiting one, so
    scrubbing a slider never queues work up. Thread-safe.

    submit(x) -> True when the caller should start work on x now (nothing in flight);
    take() -> (True, the latest request that arrived meanwhile: start it now) or (False, None): idle."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._busy = False
        self._pending: T | None = None
        self._has_pending = False
        self.dropped = 0  # requests replaced before they ran

    def submit(self, item: T) -> bool:
        with self._lock:
            if not self._busy:
                self._busy = True
                return True
            if self._has_pending:
                self.dropped += 1
            self._pending, self._has_pending = item, True
            return False

    def take(self) -> tuple[bool, T | None]:
        """Worker side: (True, item) to run next, or (False, None) and the coalescer goes idle."""
        with self._lock:
            if self._has_pending:
                item, self._pending, self._has_pending = self._pending, None, False
                return True, item
            self._busy = False
            return False, None

    @property
    def busy(self) -> bool:
        return self._busy
