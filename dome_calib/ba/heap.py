"""Freed memory kept in the process's heap while the bundle adjustment runs (glibc's malloc, tuned by ``mallopt``).

Why: every Levenberg-Marquardt iteration on the full dome allocates and frees arrays of hundreds of MB: the reduced
camera system (7,815 x 7,815 doubles, 489 MB), its single-precision copy, the free parameters' block, the
Jacobians and the y blocks. glibc serves each allocation above 32 MB with a fresh ``mmap`` and gives it back to the
kernel when it is freed, so each iteration pays again for the page faults and the zeroing of gigabytes of new
pages. The full dome's bundle adjustment stage, replayed on one SfM result under ``/usr/bin/time``: 149.4 s wall,
49.5 s of it system time. With ``mmap`` off for the allocations (``M_MMAP_MAX`` 0) and the heap's free top kept
(``M_TRIM_THRESHOLD`` -1), freed blocks are reused: 112.7 s wall, 12.6 s system, the same cameras and lens model
to the bit (``bench/dome.py --compare``: the stage 0.60x of 2a6a476's). Leaving the outermost block sets glibc's
defaults back and returns the kept memory to the kernel (``malloc_trim``); the peak resident memory is about 12 %
higher (4.33 -> 4.84 GB on the full dome).

Threads' own arenas still ``mmap`` what does not fit their 64 MB heaps (glibc falls back to it), so nothing can
fail for want of ``mmap``. Nothing is changed where the C library has no ``mallopt`` (not glibc), or where the user
set one of these through the environment (``MALLOC_MMAP_MAX_``, ``MALLOC_TRIM_THRESHOLD_``): theirs stands.
"""
from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import threading
from collections.abc import Iterator

logger = logging.getLogger(__name__)

# <malloc.h>
M_TRIM_THRESHOLD = -1
M_MMAP_MAX = -4
#: glibc's defaults (malloc/malloc.c: DEFAULT_TRIM_THRESHOLD, DEFAULT_MMAP_MAX)
DEFAULT_TRIM_THRESHOLD = 128 * 1024
DEFAULT_MMAP_MAX = 65536
#: M_TRIM_THRESHOLD -1: the heap's free top is never given back while the block runs (mallopt(3))
NEVER_TRIM = -1
USER_VARIABLES = ("MALLOC_MMAP_MAX_", "MALLOC_TRIM_THRESHOLD_")

_lock = threading.Lock()
_depth = 0
_libc: object | None | bool = False  # False: not looked up yet


def _glibc():
    """The C library's handle when it has glibc's mallopt and malloc_trim, else None."""
    global _libc
    if _libc is False:
        _libc = None
        try:
            lib = ctypes.CDLL(None)  # the symbols already loaded: the C library's among them, no search needed
        except OSError:
            lib = None
        if lib is not None and hasattr(lib, "mallopt") and hasattr(lib, "malloc_trim"):
            lib.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
            lib.mallopt.restype = ctypes.c_int
            lib.malloc_trim.argtypes = [ctypes.c_size_t]
            lib.malloc_trim.restype = ctypes.c_int
            _libc = lib
    return _libc


def _set(lib, mmap_max: int, trim_threshold: int) -> bool:
    return bool(lib.mallopt(M_MMAP_MAX, mmap_max)) and bool(lib.mallopt(M_TRIM_THRESHOLD, trim_threshold))


def active() -> bool:
    """Whether a :func:`kept_heap` block is running and changed the allocator (for tests and logs)."""
    return _depth > 0  # counted only by blocks that change it


@contextlib.contextmanager
def kept_heap() -> Iterator[None]:
    """Run the block with freed memory kept for reuse (module docstring); blocks nest, the outermost one restores."""
    global _depth
    lib = _glibc()
    if lib is None or any(v in os.environ for v in USER_VARIABLES):  # not glibc, or the user's setting rules
        yield
        return
    with _lock:
        _depth += 1
        if _depth == 1 and not _set(lib, 0, NEVER_TRIM):
            logger.debug("mallopt refused the kept-heap settings")
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                _set(lib, DEFAULT_MMAP_MAX, DEFAULT_TRIM_THRESHOLD)
                lib.malloc_trim(0)
