"""The base of every error a user can cause and fix (bad file, unknown name, missing or stale data):
the CLI and the explorer print its message without a traceback. Light on purpose: `lrr` catches it
before torch is imported."""
from __future__ import annotations

from typing import Mapping, TypeVar

T = TypeVar("T")


class UserFacingError(Exception):
    """An error whose message names the input and says what to do."""


class UnknownNameError(UserFacingError, KeyError):
    """A name that is not in a table of named things (poses, rest configurations, examples)."""

    def __str__(self) -> str:  # KeyError quotes its message; we want it readable
        return str(self.args[0])


def look_up(table: Mapping[str, T], name: str, what: str) -> T:
    """table[name], or UnknownNameError naming `what` and listing the valid names."""
    try:
        return table[name]
    except KeyError:
        raise UnknownNameError(f"unknown {what} {name!r}; valid: {', '.join(table)}") from None
