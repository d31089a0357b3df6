"""OpenCV's calibration solvers on one thread for the call: the same bytes run to run.

``cv2.calibrateCamera`` (OpenCV 5.0) spreads its work over OpenCV's thread pool and the result depends on the order
the threads finish: three calls on the same corners (a demo Kinect's IR frames) gave three different starts in the
last bits, and the Kinect calibration after them (``kcalibration_<seq>.json``) differed run to run; on one thread,
three times the same bits. OpenCV has no per-call thread count (its pool is the process's), so :func:`one_cv_thread`
sets it for the block and gives the process back the count it had (as :func:`dome_calib.ba.blas.blas_threads` does
for OpenBLAS). ``tests/test_cv_threads.py`` refuses a calibration call of OpenCV outside such a block.
"""
from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

import cv2

_LOCK = threading.Lock()
_DEPTH = 0
_BEFORE = 0


@contextlib.contextmanager
def one_cv_thread() -> Iterator[None]:
    """Run the block with one OpenCV thread; the count before is restored when the last such block (of any thread)
    ends."""
    global _DEPTH, _BEFORE
    with _LOCK:
        if _DEPTH == 0:
            _BEFORE = cv2.getNumThreads()
            cv2.setNumThreads(1)
        _DEPTH += 1
    try:
        yield
    finally:
        with _LOCK:
            _DEPTH -= 1
            if _DEPTH == 0:
                cv2.setNumThreads(_BEFORE)
