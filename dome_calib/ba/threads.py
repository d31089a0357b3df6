"""Running a function over a list of independent jobs in threads (numpy's kernels, scipy's sparse products and the
numba kernels release the GIL), or in this thread when one thread or one job is all there is.

The threads are kept between calls (one pool per thread count): a bundle adjustment makes ~150 such calls per
solve on the panel dome, and starting fresh threads each time cost 0.3 s of its 7 s. Jobs must not wait for other
jobs of these pools (none here does).
"""
from __future__ import annotations

import threading
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor, wait
from typing import TypeVar

T = TypeVar("T")
_POOLS: dict[int, ThreadPoolExecutor] = {}
_LOCK = threading.Lock()


def _pool(n_threads: int) -> ThreadPoolExecutor:
    with _LOCK:
        pool = _POOLS.get(n_threads)
        if pool is None:
            pool = _POOLS[n_threads] = ThreadPoolExecutor(max_workers=n_threads, thread_name_prefix="ba")
        return pool


def run_in_threads(fn: Callable[[T], object], jobs: Iterable[T], n_threads: int) -> None:
    """Call ``fn(job)`` for every job, in up to ``n_threads`` threads; an exception in any job is raised here."""
    jobs = list(jobs)
    if n_threads > 1 and len(jobs) > 1:
        futures = [_pool(n_threads).submit(fn, job) for job in jobs]
        wait(futures)  # every job done (none still writing into the caller's arrays) before an error is raised
        for fut in futures:
            fut.result()
    else:
        for job in jobs:
            fn(job)
