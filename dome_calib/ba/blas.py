"""Control of the OpenBLAS thread count of numpy and scipy (each wheel bundles its own OpenBLAS).

Why: on a shared 2-core machine, multi-threaded OpenBLAS spins on small matrices; measured here under load,
the Cholesky of a 390 x 390 matrix took 1 s with the default threads and 1.6 ms with one. The solver runs
with one BLAS thread and gives ``n_threads`` only to the large dense Cholesky of the reduced camera system.
If no OpenBLAS is found (another BLAS, another platform) this does nothing.
"""
from __future__ import annotations

import contextlib
import ctypes
import logging
import os
from collections.abc import Iterator

import numpy  # noqa: F401  (loads its OpenBLAS: _openblas_libraries finds it in /proc/self/maps)
import scipy.linalg  # noqa: F401  (and scipy's)

import dome_calib.ba.sparse  # noqa: F401  (and CHOLMOD's, the system's, when the optional scikit-sparse is there)

logger = logging.getLogger(__name__)

_SETTERS = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads", "openblas_set_num_threads64_",
            "openblas_set_num_threads")
_GETTERS = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads", "openblas_get_num_threads64_",
            "openblas_get_num_threads")
_libs: list[tuple[object, object]] | None = None


def _openblas_libraries() -> list[tuple[object, object]]:
    """(set, get) function pairs of every OpenBLAS loaded in this process (numpy's and scipy's)."""
    global _libs
    if _libs is not None:
        return _libs
    paths: set[str] = set()
    try:
        with open("/proc/self/maps") as fh:
            for line in fh:
                path = line.split()[-1]
                # numpy's and scipy's wheels name it libscipy_openblas...; Debian's is .../openblas-pthread/libblas.so.3
                if "openblas" in path.lower() and ".so" in os.path.basename(path):
                    paths.add(path)
    except OSError:
        pass
    found = []
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        setter = next((getattr(lib, s) for s in _SETTERS if hasattr(lib, s)), None)
        getter = next((getattr(lib, g) for g in _GETTERS if hasattr(lib, g)), None)
        if setter is not None and getter is not None:
            getter.restype = ctypes.c_int
            found.append((setter, getter))
    _libs = found
    logger.debug("OpenBLAS libraries with thread control: %d", len(found))
    return found


def get_blas_threads() -> list[int]:
    """Current thread counts of the OpenBLAS libraries found (empty if none)."""
    return [int(get()) for _, get in _openblas_libraries()]


def set_blas_threads(n: int) -> None:
    """Set the thread count of every OpenBLAS found."""
    for setter, _ in _openblas_libraries():
        setter(ctypes.c_int(int(n)))


@contextlib.contextmanager
def blas_threads(n: int) -> Iterator[None]:
    """Context manager: run the block with ``n`` OpenBLAS threads, then restore the previous counts."""
    libs = _openblas_libraries()
    before = [int(get()) for _, get in libs]
    set_blas_threads(n)
    try:
        yield
    finally:
        for (setter, _), k in zip(libs, before):
            setter(ctypes.c_int(k))
