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

# The steps of the patch stream's choices (:mod:`dome_calib.recon.patches`), by unit. Each is far above float noise
# on its values and far below any difference the choice is meant to see; they are the steps the stream wrote inline
# before (``np.rint(x * 1e6)``), named here once. ``quantize`` divides by the step: on a value within one ulp of a
# half step that may differ by one step from multiplying by its inverse (no choice changed on the benches' runs).
#: Distances between camera centres when picking neighbour cameras: 0.1 mm.
CAMERA_DISTANCE_QUANTUM_CM = 1e-2
#: A depth point's offset from its cell's centre when thinning a cloud to one point per cell: 10 um.
POINT_OFFSET_QUANTUM_CM = 1e-3
#: Cosines between a view direction and a normal (or another view direction) when choosing views.
VIEW_COSINE_QUANTUM = 1e-6
#: Photometric scores (mean NCC) when choosing a depth or a normal.
NCC_QUANTUM = 1e-6
#: Image distances compared with a pixel threshold: predicted motion, a flow's forward-backward error, a flow's
#: distance from its guess, a keypoint's distance from an epipolar line.
FLOW_QUANTUM_PX = 1e-6
#: SIFT descriptor distances (descriptor units, values of order 100) in the nearest / second-nearest ratio test.
DESCRIPTOR_DISTANCE_QUANTUM = 1e-6
#: Corner positions when ordering detected corners (a detector's order decides nothing): 1/8 px.
CORNER_QUANTUM_PX = 0.125
#: Time differences when choosing the nearest frame: 1 us.
TIME_QUANTUM_MS = 1e-3
#: Residuals (cm) of rigid-motion hypotheses when choosing the least.
RESIDUAL_QUANTUM_CM = 1e-9

# The steps of the people stream's choices (:mod:`dome_calib.recon.people`), by unit: the ones it wrote inline
# before (``np.round(cost, 3)`` and the like), named here once. ``np.round(x, 3)`` multiplies by 1000 where
# ``quantize`` divides by 1e-3: the two may differ by one step on a value within an ulp of a half step only.
#: Skeleton distances (median joint distance) when assigning bodies to tracks, gaps or proposals: 10 um.
SKELETON_DISTANCE_QUANTUM_CM = 1e-3
#: Pixel distances between detections when matching them across frames.
DETECTION_DISTANCE_QUANTUM_PX = 1e-3
#: Pair hypotheses' centres (and their distances) when clustering them into proposals: 10 um.
HYPOTHESIS_CENTRE_QUANTUM_CM = 1e-3
#: A hypothesis cluster's density (a sum of common joints: whole numbers) against its floor.
CLUSTER_WEIGHT_QUANTUM = 1e-6
#: The angle between two cameras' optical axes when ranking view pairs: 0.1 deg.
AXIS_ANGLE_QUANTUM_DEG = 0.1
#: Detector confidences when keeping a joint's strongest detections (a numba kernel: written out there).
CONFIDENCE_QUANTUM = 1e-4


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


def argmax_first(values: np.ndarray, step: float, axis: int | None = None) -> int | np.ndarray:
    """Index of the largest value after quantising to ``step``; among equals the first (callers keep their
    candidates in name order). ``axis``: per row along it (an int64 array), as :func:`numpy.argmax`."""
    q = np.argmax(quantize(values, step), axis=axis)
    return int(q) if axis is None else q


def argmin_first(values: np.ndarray, step: float, axis: int | None = None) -> int | np.ndarray:
    """:func:`argmax_first` for the smallest value."""
    q = np.argmin(quantize(values, step), axis=axis)
    return int(q) if axis is None else q


_NONE = np.iinfo(np.int64).min  # below every quantised value (quantize clips to +-2**62)


def quantize_where(values: np.ndarray, mask: np.ndarray, step: float, fill: int) -> np.ndarray:
    """:func:`quantize` where ``mask`` (broadcast to the values), ``fill`` elsewhere (int64); values outside ``mask``
    are never read (NaN, inf: a gated cost's outside)."""
    v = np.asarray(values, dtype=float)
    m = np.broadcast_to(np.asarray(mask, dtype=bool), v.shape)
    return np.where(m, quantize(np.where(m, v, 0.0), step), fill)


def _masked_keys(values: np.ndarray, mask: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """(quantised values where ``mask``, 0 elsewhere; mask as bool), values outside ``mask`` never read."""
    m = np.broadcast_to(np.asarray(mask, dtype=bool), np.shape(values))
    return quantize_where(values, m, step, 0), m


def argmax_where(values: np.ndarray, mask: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Along the last axis, among the entries where ``mask``: the index of the largest value after quantising to
    ``step``, the first among equals -> (index, found). Rows with no entry in ``mask``: index 0, found False.
    Values outside ``mask`` may be anything (NaN, inf); a NaN inside it is refused."""
    q, m = _masked_keys(values, mask, step)
    best = np.argmax(np.where(m, q, _NONE), axis=-1)
    return best, m.any(axis=-1)


def argmin_where(values: np.ndarray, mask: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`argmax_where` for the smallest value."""
    q, m = _masked_keys(values, mask, step)
    best = np.argmin(np.where(m, q, -(_NONE + 1)), axis=-1)
    return best, m.any(axis=-1)


def argsort_where(values: np.ndarray, mask: np.ndarray, step: float) -> np.ndarray:
    """Along the last axis: the indices of the entries where ``mask`` by their value quantised to ``step``,
    ascending, equals in index order, then those outside ``mask`` (in index order)."""
    q, m = _masked_keys(values, mask, step)
    return np.argsort(np.where(m, q, -(_NONE + 1)), axis=-1, kind="stable")


def at_most(a: np.ndarray | float, b: np.ndarray | float, step: float) -> np.ndarray:
    """``a <= b`` elementwise after quantising both to ``step``; False where either is NaN (no rank)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    ok = ~(np.isnan(a) | np.isnan(b))
    return ok & (quantize(np.where(ok, a, 0.0), step) <= quantize(np.where(ok, b, 0.0), step))


def below(a: np.ndarray | float, b: np.ndarray | float, step: float) -> np.ndarray:
    """``a < b`` elementwise after quantising both to ``step``; False where either is NaN; inf is above any
    finite value (a cost of inf is below no gate)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    ok = ~(np.isnan(a) | np.isnan(b))
    return ok & (quantize(np.where(ok, a, 0.0), step) < quantize(np.where(ok, b, 0.0), step))


def at_least(a: np.ndarray | float, b: np.ndarray | float, step: float) -> np.ndarray:
    """``a >= b`` elementwise after quantising both to ``step``; False where either is NaN."""
    return at_most(b, a, step)


def above(a: np.ndarray | float, b: np.ndarray | float, step: float) -> np.ndarray:
    """``a > b`` elementwise after quantising both to ``step``; False where either is NaN."""
    return below(b, a, step)


def raster_order(uv_px: np.ndarray, step_px: float) -> np.ndarray:
    """(N, 2) image points -> the indices ordering them by row (v) then column (u), both quantised to
    ``step_px``; equal points in input order."""
    q = quantize(np.asarray(uv_px, dtype=float).reshape(-1, 2), step_px)
    return np.lexsort((q[:, 0], q[:, 1]))
