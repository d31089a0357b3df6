"""Worker processes that use one core each.

A pool of N worker processes on N cores must not let each worker start its own BLAS / OpenMP thread pool:
OpenBLAS would then run N x N busy-waiting threads on N cores. Measured on this 2-core machine: matching
3,734 VGA pairs of the full dome took 77.8 s with the default thread pools and 37.5 s with one thread per
worker. The limits are environment variables read when a library loads, i.e. when the (spawned) worker
imports numpy, so they must be in the environment when the worker process starts; the parent keeps its own.
"""
from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

THREAD_LIMIT_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


@contextmanager
def single_threaded_children() -> Iterator[None]:
    """Processes started inside this block get one BLAS / OpenMP thread (a variable the user set is kept)."""
    added = [v for v in THREAD_LIMIT_VARS if v not in os.environ]
    for v in added:
        os.environ[v] = "1"
    try:
        yield
    finally:
        for v in added:
            os.environ.pop(v, None)
