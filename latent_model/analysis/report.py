"""`lrr evaluate` (being written)."""
from __future__ import annotations


def add_arguments(p) -> None:
    p.add_argument("--checkpoint")


def run_cli(args) -> None:
    raise SystemExit("lrr evaluate: not implemented yet")
