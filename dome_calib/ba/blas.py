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

import numpy as np  # (also loads its OpenBLAS: _openblas_libraries finds it in /proc/self/maps)
import scipy.linalg  # noqa: F401  (and scipy's)

import dome_calib.ba.sparse  # noqa: F401  (and CHOLMOD's, the system's, when the optional scikit-sparse is there)

logger = logging.getLogger(__name__)

_SETTERS = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads", "openblas_set_num_threads64_",
            "openblas_set_num_threads")
_GETTERS = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads", "openblas_get_num_threads64_",
            "openblas_get_num_threads")
_libs: list[tuple[object, object]] | None = None

#: The largest ``n * itemsize`` (bytes of one column) of a matrix whose Cholesky factorisation (LAPACK potrf) is given
#: more than one OpenBLAS thread. OpenBLAS's threaded potrf (``lapack/potrf/potrf_parallel.c``, its ``thread_driver``)
#: packs a panel as wide as a thread's share of the columns into the thread's fixed work buffer, with no bound (on 2
#: threads the first share is ~0.71 n columns); past some size the panel runs past the buffer and overwrites the
#: memory next to it. Measured here (OpenBLAS 0.3.30 as bundled by scipy 1.17.1, SkylakeX kernels, 2 threads,
#: float64): 12,000 unknowns factorised; 15,593 (the two-dome bench's uncertainties) died in potrf, twice (SIGSEGV;
#: in the bench, SIGBUS in ``free`` or ``munmap_chunk(): invalid pointer`` later); on one thread, 22 s and fine.
#: One thread is the single-threaded driver, blocked to fit its buffer (OpenBLAS issue 2562 is the same crash on 2
#: threads). The bound keeps the full dome (7,815 float64 unknowns, 62 kB a column; 15,600 float32 in the two
#: domes' solve factor, 62 kB) on 2 threads.
CHOLESKY_PARALLEL_MAX_COLUMN_BYTES = 80_000


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


def cholesky_threads(n: int, dtype: np.dtype | type, n_threads: int) -> int:
    """The OpenBLAS threads for a dense Cholesky factorisation (and the inverse from it) of an ``n`` x ``n`` matrix
    of ``dtype``: ``n_threads``, or 1 past :data:`CHOLESKY_PARALLEL_MAX_COLUMN_BYTES` (OpenBLAS's threaded potrf
    then writes past its work buffer)."""
    return n_threads if n * np.dtype(dtype).itemsize <= CHOLESKY_PARALLEL_MAX_COLUMN_BYTES else 1


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
