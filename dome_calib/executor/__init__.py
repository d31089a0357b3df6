"""One small task-executor interface for the embarrassingly parallel SfM stages.

Feature extraction (one task per image) and matching (one task per batch of pairs) only ever call
``executor.map(fn, items)`` with a module-level ``fn`` and picklable items, so any object with the
:class:`Executor` shape can run them: the local process pool (:mod:`dome_calib.executor.local`) by default, or a
thin adapter over ``dask.distributed.Client`` (:mod:`dome_calib.executor.dask`) (``submit`` returns a future with ``.result()``, which is what Dask's futures
have) running on the dome's module nodes. Task functions read their inputs from paths, so the workers need
the capture and work folders mounted at the same place.
"""
from __future__ import annotations

import concurrent.futures as cf
import os
from collections.abc import Callable, Hashable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar, runtime_checkable

T = TypeVar("T")
R = TypeVar("R")


@runtime_checkable
class Future(Protocol[R]):
    def result(self, timeout: float | None = None) -> R: ...


@runtime_checkable
class Executor(Protocol):
    """What the SfM stages need from an executor."""

    def submit(self, fn: Callable[..., R], /, *args: Any, **kwargs: Any) -> Future[R]: ...

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
        """Yield ``fn(item)`` for every item, in COMPLETION order is allowed: results must carry their key."""
        ...


@dataclass(frozen=True)
class Proven:
    """A task's result and the evidence of what the worker read to make it (e.g. a file's size and hash), checked
    on the head before the result is used (:class:`dome_calib.executor.dask.Route`'s ``verify``)."""

    result: Any
    evidence: Any


def in_order(results: Iterable[R], keys: Sequence[Hashable], key_of: Callable[[R], Hashable]) -> Iterator[R]:
    """Results that arrive in completion order (``executor.map``), yielded in the order of ``keys``.

    What the head writes (database rows, ids) must not depend on which worker finished first: results that come
    early wait in a buffer until every result before them has arrived. The executors submit in ``keys`` order
    with a bounded number of tasks in flight, so the buffer stays about that size. A key that never arrives is
    an error (a lost task), as is a result whose key is not in ``keys``.
    """
    position = {k: i for i, k in enumerate(keys)}
    if len(position) != len(keys):
        raise ValueError("in_order: duplicate keys")
    waiting: dict[int, R] = {}
    nxt = 0
    for res in results:
        k = key_of(res)
        if k not in position:
            raise ValueError(f"in_order: result for unknown key {k!r}")
        waiting[position[k]] = res
        while nxt in waiting:
            yield waiting.pop(nxt)
            nxt += 1
    if nxt != len(keys):
        raise RuntimeError(f"in_order: no result for {keys[nxt]!r} ({len(keys) - nxt} missing)")


def is_remote(executor: object) -> bool:
    """Whether the executor's tasks may run on other machines, reading their own files (a Dask cluster: its
    ``remote`` attribute). The local pool and the serial executor read this machine's files: work that releases
    the GIL (numba ``nogil``) then runs as well in this process's threads (:class:`ThreadExecutor`), without moving
    its data between processes."""
    return bool(getattr(executor, "remote", False))


def default_num_workers() -> int:
    """Cores this process may use (affinity-aware), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


def bounded_map(submit: Callable[..., cf.Future], fn: Callable[[T], R], items: Iterable[T],
                max_in_flight: int) -> Iterator[R]:
    """``fn(item)`` for every item through ``submit``, in completion order, with at most ``max_in_flight`` tasks
    submitted and not yet yielded (items are drawn as room frees: memory stays flat)."""
    pending: set[cf.Future] = set()
    for item in items:
        pending.add(submit(fn, item))
        if len(pending) >= max_in_flight:
            done, pending = cf.wait(pending, return_when=cf.FIRST_COMPLETED)
            for fut in done:
                yield fut.result()
    while pending:
        done, pending = cf.wait(pending, return_when=cf.FIRST_COMPLETED)
        for fut in done:
            yield fut.result()


class SerialExecutor:
    """Runs tasks in this process, one after another (debugging, tests, tiny inputs)."""

    def submit(self, fn: Callable[..., R], /, *args: Any, **kwargs: Any) -> Future[R]:
        fut: cf.Future[R] = cf.Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller through the future
            fut.set_exception(exc)
        return fut

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
        for item in items:
            yield fn(item)

    def shutdown(self) -> None:
        """Nothing to release (same lifecycle as the pool, so callers can always use ``with``)."""

    def __enter__(self) -> SerialExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()


class ThreadExecutor:
    """Tasks in threads of this process: for compiled work that releases the GIL (numba ``nogil``) on data this
    process can read; no pickling. Results in completion order, at most 4 tasks per thread in flight."""

    def __init__(self, num_threads: int) -> None:
        self.num_workers = max(1, num_threads)
        self._pool = cf.ThreadPoolExecutor(self.num_workers)

    def submit(self, fn: Callable[..., R], /, *args: Any, **kwargs: Any) -> Future[R]:
        return self._pool.submit(fn, *args, **kwargs)

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
        return bounded_map(self._pool.submit, fn, items, 4 * self.num_workers)

    def shutdown(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> ThreadExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()
