"""One small task-executor interface for the embarrassingly parallel SfM stages.

Feature extraction (one task per image) and matching (one task per batch of pairs) only ever call
``executor.map(fn, items)`` with a module-level ``fn`` and picklable items, so any object with the
:class:`Executor` shape can run them: the local process pool here by default, or a thin adapter over
``dask.distributed.Client`` (``submit`` returns a future with ``.result()``, which is what Dask's futures
have) running on the dome's module nodes. Task functions read their inputs from paths, so the workers need
the capture and work folders mounted at the same place.
"""
from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable, Hashable, Iterable, Iterator, Sequence
from typing import Any, Protocol, TypeVar, runtime_checkable

from dome_calib.workers import single_threaded_children

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


def default_num_workers() -> int:
    """Cores this process may use (affinity-aware), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


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


#: Seconds between a worker's checks that the process that started it is still there.
PARENT_POLL_S = 0.5


def _exit_when_orphaned(parent_pid: int) -> None:
    """A worker's watchdog: when its parent is gone (SIGKILL, SIGHUP or SIGTERM ended it before it could stop its
    pool), the worker is re-parented (its parent pid changes) and ends at once instead of running on for ever."""
    while os.getppid() == parent_pid:
        time.sleep(PARENT_POLL_S)
    os._exit(1)


def _worker_ignores_sigint() -> None:
    """Worker initializer: Ctrl-C reaches the whole process group; the parent alone handles it and stops the
    workers (:meth:`LocalProcessExecutor.terminate`), so no worker prints a traceback. A daemon thread ends the
    worker when its parent dies (:func:`_exit_when_orphaned`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_exit_when_orphaned, args=(os.getppid(),), name="parent-watchdog", daemon=True).start()


class LocalProcessExecutor:
    """A process pool on this machine (default: one worker per available core).

    Workers are started with ``spawn`` so that no pycolmap/OpenMP thread state is inherited from the parent,
    and with one BLAS / OpenMP thread each (:func:`dome_calib.workers.single_threaded_children`). They ignore
    SIGINT: leaving the ``with`` block by an exception (an interrupt included) stops them at once, quietly.
    Use as a context manager, or call :meth:`shutdown`.
    """

    def __init__(self, num_workers: int | None = None, *, max_in_flight_per_worker: int = 4) -> None:
        self.num_workers = num_workers or default_num_workers()
        self._max_in_flight = max(1, self.num_workers * max_in_flight_per_worker)
        self._pool = cf.ProcessPoolExecutor(self.num_workers, mp_context=multiprocessing.get_context("spawn"),
                                            initializer=_worker_ignores_sigint)
        self._lock = threading.Lock()

    def submit(self, fn: Callable[..., R], /, *args: Any, **kwargs: Any) -> Future[R]:
        # the pool starts its worker processes on demand, inside submit: the thread limits go into the environment
        # only until every worker is running (setenv races with getenv in another thread: GLOMAP maps in one
        # while features are submitted, projector.sfm), and one submit at a time changes it
        with self._lock:
            if len(self._processes()) >= self.num_workers:
                return self._pool.submit(fn, *args, **kwargs)
            with single_threaded_children():
                return self._pool.submit(fn, *args, **kwargs)

    def _processes(self) -> list[multiprocessing.Process]:
        """The pool's running worker processes (ProcessPoolExecutor has no public handle on them; ``_processes``
        is stable since Python 3.2)."""
        return list((getattr(self._pool, "_processes", None) or {}).values())

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
        """Results in completion order, with a bounded number of tasks in flight (memory stays flat)."""
        pending: set[cf.Future[R]] = set()
        for item in items:
            pending.add(self.submit(fn, item))
            if len(pending) >= self._max_in_flight:
                done, pending = cf.wait(pending, return_when=cf.FIRST_COMPLETED)
                for fut in done:
                    yield fut.result()
        while pending:
            done, pending = cf.wait(pending, return_when=cf.FIRST_COMPLETED)
            for fut in done:
                yield fut.result()

    def shutdown(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)

    def terminate(self) -> None:
        """Stop now: drop queued tasks and end the worker processes (SIGKILL) without waiting for their tasks."""
        processes = self._processes()
        self._pool.shutdown(wait=False, cancel_futures=True)
        for proc in processes:  # SIGKILL: pycolmap's glog would print a stack trace on SIGTERM
            if proc.is_alive():
                proc.kill()
        for proc in processes:
            proc.join(timeout=5)

    def __enter__(self) -> LocalProcessExecutor:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:
            self.shutdown()
        else:
            self.terminate()


def make_executor(num_workers: int | None = None) -> SerialExecutor | LocalProcessExecutor:
    """The default executor: a local process pool, or serial when only one worker is asked for."""
    n = num_workers or default_num_workers()
    return SerialExecutor() if n <= 1 else LocalProcessExecutor(n)
