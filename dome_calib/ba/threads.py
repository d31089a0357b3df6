"""Running a function over a list of independent jobs in threads (numpy's kernels and scipy's sparse products
release the GIL), or in this thread when one thread or one job is all there is."""
from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")


def run_in_threads(fn: Callable[[T], object], jobs: Iterable[T], n_threads: int) -> None:
    """Call ``fn(job)`` for every job, in up to ``n_threads`` threads; an exception in any job is raised here."""
    jobs = list(jobs)
    if n_threads > 1 and len(jobs) > 1:
        with ThreadPoolExecutor(max_workers=n_threads) as pool:
            list(pool.map(fn, jobs))
    else:
        for job in jobs:
            fn(job)
