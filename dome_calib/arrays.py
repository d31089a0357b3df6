"""Arrays: shapes that hold for every size, zero included; kept arrays read through one declared spec.

numpy cannot infer ``-1`` in ``a.reshape(len(a), -1)`` (N rows, the rest inferred) when ``a`` is empty ("cannot
reshape array of size 0 into shape (0,newaxis)"): a window without a measured bone, a stream without a detected
frame or a file without rows is empty, and every such reshape was a traceback there. Flatten through
:func:`per_row` instead.

A ``.npz`` a user hands back to us (a bundle's ``report/residuals.npz``) is an input like a JSON file: it is read
through :func:`read_arrays` with a spec per array (:class:`ArraySpec`: kind, shape, indices), and any array that
does not match is one line naming the file, the array and the element, never a traceback later.

Numbers become text through :func:`fixed_text`, never numpy's ``char.mod``: numpy's vectorised string calls (2.4.6)
swallow an exception a signal handler raises while they run, so a SIGTERM or Ctrl-C that lands there is lost and
the command runs to the end with exit 0 (seen in ``export-people``'s SIGTERM test under load; ``tests/
test_arrays_text.py`` holds the rule for the package).
"""
from __future__ import annotations

import math
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np


def per_row(a: np.ndarray) -> np.ndarray:
    """(N, ...) -> (N, prod(...)): each row's values flattened, for N = 0 too."""
    a = np.asarray(a)
    return a.reshape(a.shape[0], math.prod(a.shape[1:]))


def fixed_text(a: np.ndarray, decimals: int, missing: str = "nan") -> list[list[str]]:
    """(N, ...) numbers -> N rows of their texts with ``decimals`` digits after the point (as ``"%.{d}f"``), NaN as
    ``missing``; formatted by Python, so an interrupt raised while it runs ends it (see the module docstring)."""
    spec = f".{int(decimals)}f"
    return [[missing if v != v else format(v, spec) for v in row] for row in per_row(np.asarray(a, float)).tolist()]


# ---- kept arrays: every .npz a user hands back to us is read through one declared spec ----------------------------

@dataclass(frozen=True)
class ArraySpec:
    """One array of a kept ``.npz`` file, declared as a JSON field is in its schema: ``kind`` "float" (finite
    numbers), "int" or "str"; ``shape`` with named sizes shared between the file's arrays (``("M", 2)``); ``index_of``:
    the values index the first axis of that array (0 <= v < its length); ``required``: False for arrays older files
    lack."""

    kind: Literal["float", "int", "str"]
    shape: tuple[int | str, ...]
    index_of: str | None = None
    required: bool = True
    description: str = ""


_KINDS = {"float": "fiu", "int": "iu", "str": "U"}
_EXPECTED = {"float": "finite numbers", "int": "integers", "str": "text"}


def read_arrays(path: str | Path, specs: dict[str, ArraySpec], error: type[Exception],
                what: str = ".npz file") -> dict[str, np.ndarray]:
    """The arrays of the ``.npz`` at ``path``, each checked against its spec (kind, shape, finite values, indices in
    range; no other array, no pickled objects). ``error`` of one line naming the file, the array and the first bad
    element otherwise (``residuals.npz: camera_index[3]: -1, expected an index into camera_names (0..4)``);
    ``what`` the file is, for a file that is no ``.npz`` at all."""
    path = Path(path)
    try:
        if not zipfile.is_zipfile(path):
            raise error(f"{path}: not a {what} (not a zip archive of arrays: a cut or a foreign copy)")
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except ValueError as exc:  # np.load refusing pickled objects
        if isinstance(exc, error):
            raise
        raise error(f"{path}: not a {what} ({str(exc).split('.')[0][:100]})") from None
    except (OSError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        why = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise error(f"{path}: not a {what} ({why})") from None
    unknown = sorted(set(arrays) - set(specs))
    if unknown:
        raise error(f"{path}: {unknown[0][:40]}: unknown array (expected {', '.join(specs)})")
    sizes: dict[str, tuple[int, str]] = {}
    for name, spec in specs.items():
        if name not in arrays:
            if spec.required:
                raise error(f"{path}: {name}: missing")
            continue
        a = arrays[name]
        if a.dtype.kind not in _KINDS[spec.kind]:
            raise error(f"{path}: {name}: dtype {a.dtype}, expected {_EXPECTED[spec.kind]}")
        if a.ndim != len(spec.shape):
            raise error(f"{path}: {name}: shape {a.shape}, expected {_shape_text(spec.shape)}")
        for axis, (want, got) in enumerate(zip(spec.shape, a.shape)):
            if isinstance(want, int) and got != want:
                raise error(f"{path}: {name}: shape {a.shape}, expected {_shape_text(spec.shape)}")
            if isinstance(want, str):
                seen = sizes.setdefault(want, (got, name))
                if seen[0] != got:
                    raise error(f"{path}: {name}: shape {a.shape}: {want} = {got}, but {seen[1]} has {want} = "
                                f"{seen[0]}")
        if spec.kind == "float":
            bad = np.argwhere(~np.isfinite(a.astype(float, copy=False)))
            if len(bad):
                at = tuple(int(i) for i in bad[0])
                raise error(f"{path}: {name}{list(at)}: {a[at]}, expected {_EXPECTED['float']}")
    for name, spec in specs.items():
        if spec.index_of is not None and name in arrays:
            a, n = arrays[name], len(arrays[spec.index_of])
            bad = np.argwhere((a < 0) | (a >= n))
            if len(bad):
                at = tuple(int(i) for i in bad[0])
                raise error(f"{path}: {name}{list(at)}: {a[at]}, expected an index into {spec.index_of} "
                            f"({'0..' + str(n - 1) if n else 'which is empty'})")
    return arrays


def _shape_text(shape: tuple[int | str, ...]) -> str:
    return "(" + ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
