"""The noise gate shared by the body prediction (`transfer.py`) and the local detail stage (`detail.py`): a delta's
signal is its length in units of its sampling noise (a delta of sampling noise alone is ~1); the motion it conditions
is zeroed below GATE_LO and passed untouched above GATE_HI."""
from __future__ import annotations

GATE_LO = 1.5
GATE_HI = 3.0


def smooth_gate(signal: float) -> float:
    """0 below GATE_LO, 1 above GATE_HI, smoothstep in between (a delta's signal in units of its noise)."""
    x = min(max((signal - GATE_LO) / (GATE_HI - GATE_LO), 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)
