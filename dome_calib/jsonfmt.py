"""JSON laid out like the Panoptic toolbox's files: tab indentation, one matrix row per line, numbers compact.

Floats are written with Python's shortest round-trip representation, so read -> write -> read is exact.
"""
from __future__ import annotations

import json
import math

import numpy as np


def _scalar(value: object) -> str:
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        f = float(value)
        if not math.isfinite(f):
            raise ValueError(f"non-finite number {f} cannot be written to JSON")
        return str(int(f)) if f.is_integer() and abs(f) < 1e15 and not (f == 0 and math.copysign(1, f) < 0) else repr(f)
    return json.dumps(value)


def _is_flat(seq: list) -> bool:
    return all(not isinstance(v, (list, tuple, dict, np.ndarray)) for v in seq)


def dumps(obj: object, level: int = 0) -> str:
    """Serialise ``obj`` (dicts, lists, numpy arrays, scalars) in the Panoptic layout."""
    tab = "\t" * level
    if isinstance(obj, np.ndarray):
        obj = obj.tolist()
    if isinstance(obj, dict):
        if not obj:
            return "{}"
        items = [f'{tab}\t{json.dumps(str(k))}: {dumps(v, level + 1)}' for k, v in obj.items()]
        return "{\n" + ",\n".join(items) + f"\n{tab}}}"
    if isinstance(obj, (list, tuple)):
        if _is_flat(list(obj)):
            return "[" + ",".join(_scalar(v) for v in obj) + "]"
        items = [f"{tab}\t{dumps(v, level + 1)}" for v in obj]
        return "[\n" + ",\n".join(items) + f"\n{tab}]"
    return _scalar(obj)
