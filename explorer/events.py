"""A minimal evented model (napari's pattern, without its dependency): an `Event` is one kind of
change that views connect to."""
from __future__ import annotations

from typing import Callable, Generic, TypeVar

T = TypeVar("T")


class Event(Generic[T]):
    """One kind of change: `emit(value)` calls every connected callback with it, in connection
    order, on the emitting thread (for the window state: the UI thread)."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._callbacks: list[Callable[[T], object]] = []

    def connect(self, callback: Callable[[T], object]) -> Callable[[T], object]:
        self._callbacks.append(callback)
        return callback

    def disconnect(self, callback: Callable[[T], object]) -> None:
        self._callbacks.remove(callback)

    def emit(self, value: T) -> None:
        for cb in list(self._callbacks):
            cb(value)
