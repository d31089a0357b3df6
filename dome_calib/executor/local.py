"""The local process pool: one worker process per core, each with one BLAS / OpenMP thread.

A pool of N worker processes on N cores must not let each worker start its own BLAS / OpenMP thread pool:
OpenBLAS would then run N x N busy-waiting threads on N cores. Measured on this 2-core machine: matching
3,734 VGA pairs of the full dome took 77.8 s with the default thread pools and 37.5 s with one thread per
worker. The limits are environment variables read when a library loads, i.e. when the (spawned) worker
imports numpy, so they must be in the environment when the worker process starts; the parent keeps its own.
"""
from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

from dome_calib.executor import Future, SerialExecutor, bounded_map, default_num_workers

T = TypeVar("T")
R = TypeVar("R")

#: OPENCV_FOR_THREADS_NUM: OpenCV's own pool (its pyramids and remaps split an image into stripes per thread): on a
#: 2-core machine a second thread costs a pyramidal Lucas-Kanade call 0.85 against 0.49 ms of CPU per VGA image
#: (the results are the same bits)
THREAD_LIMIT_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENCV_FOR_THREADS_NUM")


@contextmanager
def single_threaded_children() -> Iterator[None]:
    """Processes started inside this block get one BLAS / OpenMP / OpenCV thread (a variable the user set is kept)."""
    added = [v for v in THREAD_LIMIT_VARS if v not in os.environ]
    for v in added:
        os.environ[v] = "1"
    try:
        yield
    finally:
        for v in added:
            os.environ.pop(v, None)


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


@contextmanager
def _interrupts_after_launch() -> Iterator[None]:
    """While a worker process is launched: SIGTERM that arrives takes effect right after the launch, not inside it
    (an interrupt between spawning a worker and handing it its start-up data left the worker reading an empty pipe,
    and it printed ``EOFError: Ran out of input`` with a traceback on the user's terminal); SIGINT is ignored, so
    that the worker starts with SIGINT ignored (an ignored disposition survives exec; a Python handler does not):
    a Ctrl-C to the process group while the worker was still importing, before its initializer
    (:func:`_worker_ignores_sigint`) ran, printed a ``KeyboardInterrupt`` traceback from it (seen under load in
    tests/test_calibrate_safety.py). A Ctrl-C within the launch itself (milliseconds) is dropped, a press again
    stops the run. Python runs signal handlers in the main thread only, so outside it (or with a non-Python
    handler) nothing is changed; the handlers in place before are put back on leaving, and the first SIGTERM that
    came is then handed to its own."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    kept = {sig: handler for sig in (signal.SIGINT, signal.SIGTERM)
            if callable(handler := signal.getsignal(sig))}  # a default or ignored disposition: no Python handler
    came: list[tuple[int, Any]] = []
    for sig in kept:
        signal.signal(sig, signal.SIG_IGN if sig == signal.SIGINT
                      else lambda signum, frame: came.append((signum, frame)))
    try:
        yield
    finally:
        for sig, handler in kept.items():
            signal.signal(sig, handler)
        for signum, frame in came[:1]:
            kept[signum](signum, frame)


class LocalProcessExecutor:
    """A process pool on this machine (default: one worker per available core).

    Workers are started with ``spawn`` so that no pycolmap/OpenMP thread state is inherited from the parent,
    and with one BLAS / OpenMP thread each (:func:`single_threaded_children`). They ignore
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
            with single_threaded_children(), _interrupts_after_launch():
                return self._pool.submit(fn, *args, **kwargs)

    def _processes(self) -> list[multiprocessing.Process]:
        """The pool's running worker processes (ProcessPoolExecutor has no public handle on them; ``_processes``
        is stable since Python 3.2)."""
        return list((getattr(self._pool, "_processes", None) or {}).values())

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
        """Results in completion order, with a bounded number of tasks in flight (memory stays flat)."""
        return bounded_map(self.submit, fn, items, self._max_in_flight)

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
