"""OpenCap calibration: a folder of ``*.pickle`` files, one per camera, read as Pose2Sim reads them
(``Pose2Sim/calibration.py``: ``calib_opencap_fun``; pose2sim 0.10.49).

A file is a pickled dict of numpy arrays (OpenCap's ``saveCameraParameters``)::

    imageSize     [height, width] px (any shape holding 2 numbers; Pose2Sim reverses it)
    intrinsicMat  K, 3 x 3
    distortion    k1 k2 p1 p2 k3 (OpenCV's order, shape (1, 5); Pose2Sim reads the first four: k3 is kept here;
                  4 terms are read as k1 k2 p1 p2)
    rotation      R, 3 x 3: world to camera
    translation   t, mm (3 numbers)

The world is OpenCap's vertical checkerboard's frame, y down the board: Pose2Sim turns it by Rz(pi) Rx(-pi/2)
(``rotate_cam``) so that its -y becomes Pose2Sim's +z; the world is kept here, as ours is -y up too.

A file is data, never code: ``pickle.load`` would run whatever callable the file names. The file is read by
:class:`_ArraysOnly`, which resolves only the globals a pickle of numpy arrays names (numpy 1.x or 2.x, pickle
protocols 0 to 5) and refuses any other with a one-line error naming the file and the global.

Cameras: the files in name order, named ``cam_00``, ``cam_01``, ... by that order (Pose2Sim's names).
"""
from __future__ import annotations

import codecs
import importlib
import io
import pickle
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import BeforeValidator

from dome_calib.interop.common import (ForeignCamera, ImportOptions, InteropError, Read, five_terms, folder_files,
                                       label)
from dome_calib.interop.fields import CameraMatrix, Distortion, RotationMatrix, SidePx, Translation, flat
from dome_calib.schema import OpenSchema, Vec, validate

#: The globals a pickle of numpy arrays (and numpy scalars) names, by (module, name) as written in the file, and
#: where the installed numpy keeps them. numpy 2 writes ``numpy._core``, numpy 1.x ``numpy.core``; protocol 5
#: writes contiguous arrays through ``_frombuffer``; protocols 0-2 write bytes as ``_codecs.encode(text,
#: "latin1")`` (a pure function: text to bytes).
_NUMPY_CORE = {"multiarray": ("_reconstruct", "scalar"), "numeric": ("_frombuffer",)}
ALLOWED_GLOBALS: frozenset[tuple[str, str]] = frozenset(
    {(f"{core}.{mod}", name) for core in ("numpy._core", "numpy.core") for mod, names in _NUMPY_CORE.items()
     for name in names} | {("numpy", "ndarray"), ("numpy", "dtype"), ("_codecs", "encode")})


def _resolve(module: str, name: str) -> Any:
    """The installed object of an allowed global (``numpy.core`` and ``numpy._core`` are the same functions)."""
    if module == "numpy":
        return {"ndarray": np.ndarray, "dtype": np.dtype}[name]
    if module == "_codecs":
        return codecs.encode
    sub = module.rsplit(".", 1)[1]
    for core in ("numpy._core", "numpy.core"):
        try:
            return getattr(importlib.import_module(f"{core}.{sub}"), name)
        except (ImportError, AttributeError):
            continue
    raise AttributeError(f"{module}.{name}")  # pragma: no cover - every numpy has one of the two


class _ArraysOnly(pickle.Unpickler):
    """An unpickler that builds numpy arrays, dtypes, numpy scalars and plain containers, and nothing else."""

    def __init__(self, data: bytes, source: Path):
        super().__init__(io.BytesIO(data))
        self._source = source

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) not in ALLOWED_GLOBALS:
            raise InteropError(f"{self._source}: refused: the pickle names {label(f'{module}.{name}')} (an OpenCap "
                               "calibration holds numpy arrays only; nothing in it was run)")
        return _resolve(module, name)

    def persistent_load(self, pid: Any) -> Any:
        raise InteropError(f"{self._source}: refused: the pickle holds a persistent id (not numpy arrays)")


def load_arrays(path: Path) -> Any:
    """The object a pickle of numpy arrays holds, built without running any other code the file names."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InteropError(f"{path}: cannot be read ({exc})") from None
    try:
        return _ArraysOnly(data, path).load()
    except InteropError:
        raise
    except Exception as exc:  # a damaged pickle raises whatever its opcodes lead to
        raise InteropError(f"{path}: not a readable pickle ({type(exc).__name__}: {exc})") from None


class OpencapCalib(OpenSchema):
    """One OpenCap ``.pickle`` (see the module docstring); a (1, N) or (N, 1) array read as a vector."""

    imageSize: Annotated[Vec(2, SidePx), BeforeValidator(flat)]
    intrinsicMat: CameraMatrix
    distortion: Annotated[Distortion, BeforeValidator(flat)]
    rotation: RotationMatrix
    translation: Annotated[Translation, BeforeValidator(flat)]


def _plain(value: Any) -> Any:
    """A numeric numpy array or scalar as nested lists / a number; anything else unchanged (the schema judges)."""
    if isinstance(value, (np.ndarray, np.generic)) and value.dtype.kind in "biuf":
        return value.tolist()
    return value


def read(path: Path, options: ImportOptions) -> Read:
    """The cameras of the folder's ``*.pickle`` files in name order, lengths in mm."""
    cams = []
    for k, f in enumerate(folder_files(path, ".pickle", "an OpenCap calibration")):
        data = load_arrays(f)
        if isinstance(data, dict):
            data = {key: _plain(v) for key, v in data.items()}
        c = validate(data, OpencapCalib, source=f, error=InteropError)
        height, width = c.imageSize
        cams.append(ForeignCamera(name=f"cam_{k:02d}", size=(width, height), K=np.array(c.intrinsicMat),
                                  dist=five_terms(c.distortion),
                                  R=np.array(c.rotation), t=np.array(c.translation)))
    return Read(cameras=cams, unit="mm", path=path)
