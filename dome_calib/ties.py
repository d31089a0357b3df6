"""Choices that do not rest on a float's last bits (the same result on every machine).

Another CPU picks other BLAS and SIMD kernels, so a computed distance, angle or score may differ in its last
bits from one machine to the next. Wherever the code chooses by such a value (nearest-k, farthest point, best
candidate), it first quantises the value to a step far above that noise and far below any difference that
matters, then breaks ties by name. Values equal by design (six ring cameras at one distance from a panel
centre) then compare equal everywhere, and the name decides.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Default quantum for lengths in centimetres: 1 um, far above float noise on dome-sized values (~1e-13 cm)
#: and far below any real difference between camera positions.
LENGTH_QUANTUM_CM = 1e-4
#: Default quantum for cosines and other unit-less scores of order 1.
UNIT_QUANTUM = 1e-9


def quantize(values: np.ndarray | Sequence[float], step: float) -> np.ndarray:
    """Values as integer multiples of ``step`` (int64, same shape); NaN is refused."""
    v = np.asarray(values, dtype=float)
    if np.isnan(v).any():
        raise ValueError("quantize: NaN has no rank")
    return np.rint(np.clip(v / step, -2.0**62, 2.0**62)).astype(np.int64)


def order_by(values: np.ndarray | Sequence[float], names: Sequence[str], step: float) -> list[int]:
    """Indices that sort ``values`` ascending after quantising to ``step``; equal values in order of ``names``."""
    q = quantize(values, step)
    if q.shape != (len(names),):
        raise ValueError(f"order_by: {q.shape=} but {len(names)} names")
    return sorted(range(len(names)), key=lambda i: (int(q[i]), names[i]))


def argmax_first(values: np.ndarray, step: float) -> int:
    """Index of the largest value after quantising to ``step``; among equals the first (callers keep their
    candidates in name order)."""
    return int(np.argmax(quantize(values, step)))
