"""The base of every error a user can cause and fix (bad file, unknown name, missing or stale data):
the CLI and the explorer print its message without a traceback. Light on purpose: `lrr` catches it
before torch is imported."""
from __future__ import annotations


class UserFacingError(Exception):
    """An error whose message names the input and says what to do."""
