"""The task executor on a Dask distributed cluster: the same ``submit`` / ``map`` shape as the local pool.

``DaskExecutor(address)`` connects a ``distributed.Client`` to a running ``dask scheduler`` (short connect
timeout; an unreachable scheduler is one :class:`~dome_calib.errors.DomeCalibError` line). ``map`` submits
one future per item with ``retries=`` (a task whose worker dies is rescheduled by the scheduler; a task that
raises is retried), and yields results in completion order through ``as_completed``, with a bounded number of
futures in flight. Every task runs through :func:`_timed` on the worker, which returns the worker's name and
the task's seconds beside the result: :attr:`DaskExecutor.stats` says, per task function, which workers ran
how many tasks, the wall and task seconds, and the bytes moved (arguments out, results back, by Dask's
``sizeof``).

Placement: ``routes`` maps a task function to a :class:`Route`: which worker (by its ``--name``) must run an
item (``workers=[name], allow_other_workers=False``: the data is on that node only) and, optionally, the
module-level function that runs it there instead (e.g. one that finds the image in the node's local folder).
The stages only ever call ``executor.map(fn, items)`` and never know where the tasks ran.
"""
from __future__ import annotations

import dataclasses
import inspect
import re
import time
from concurrent.futures import CancelledError
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
from dask.sizeof import sizeof
from distributed import Client, as_completed, get_worker

from dome_calib.errors import DomeCalibError

T = TypeVar("T")
R = TypeVar("R")

CONNECT_TIMEOUT_S = 5.0


@dataclass(frozen=True)
class Route:
    """Where one task function's items run: ``worker_of(item)`` a worker name (None: any worker), and
    ``task_fn`` the module-level function the worker calls instead of the mapped one (None: the same)."""

    worker_of: Callable[[Any], Any]  # a worker's name (--name; a LocalCluster's are ints) or None
    task_fn: Callable[[Any], Any] | None = None


@dataclass
class MapStats:
    """One task function's tally over every ``map`` call: tasks per worker, seconds, bytes moved."""

    tasks: int = 0
    workers: dict[str, int] = field(default_factory=dict)
    wall_s: float = 0.0  # head-side wall time of the map calls
    task_s: float = 0.0  # sum of the tasks' own run times on the workers
    bytes_out: int = 0  # task arguments sent to the cluster
    bytes_back: int = 0  # results received from it

    def as_dict(self) -> dict:
        return {"tasks": self.tasks, "workers": dict(sorted(self.workers.items())), "wall_s": round(self.wall_s, 3),
                "task_s": round(self.task_s, 3), "bytes_out": self.bytes_out, "bytes_back": self.bytes_back}


def payload_bytes(obj: Any, _depth: int = 0) -> int:
    """Bytes of a task's argument or result as sent: numpy arrays by ``nbytes``, containers and dataclasses
    summed over their contents, anything else by Dask's ``sizeof`` (objects such as pycolmap's two-view geometry
    are counted by their Python size only: an underestimate)."""
    if _depth > 4:
        return int(sizeof(obj))
    if isinstance(obj, np.ndarray):
        return int(obj.nbytes)
    if isinstance(obj, (list, tuple, set)):
        return sum(payload_bytes(x, _depth + 1) for x in obj)
    if isinstance(obj, dict):
        return sum(payload_bytes(k, _depth + 1) + payload_bytes(v, _depth + 1) for k, v in obj.items())
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return sum(payload_bytes(getattr(obj, f.name), _depth + 1) for f in dataclasses.fields(obj))
    return int(sizeof(obj))


def _timed(fn: Callable[[T], R], item: T) -> tuple[str, float, R]:
    """Worker side: run ``fn(item)``; return (this worker's name, seconds, result)."""
    t0 = time.perf_counter()
    result = fn(item)
    return str(get_worker().name), time.perf_counter() - t0, result


class DaskExecutor:
    """Tasks on a Dask cluster (see the module docstring). Use as a context manager, or call :meth:`shutdown`."""

    def __init__(self, address: str, *, routes: Mapping[Callable, Route] | None = None, retries: int = 2,
                 max_in_flight: int | None = None, connect_timeout_s: float | None = None,
                 client: Any = None) -> None:
        self.address = address
        connect_timeout_s = CONNECT_TIMEOUT_S if connect_timeout_s is None else connect_timeout_s
        self.routes = dict(routes or {})
        self.retries = retries
        self.stats: dict[str, MapStats] = {}
        if client is None and not re.fullmatch(r"(tcp|tls|inproc)://[^\s:/]+:\d{1,5}", address):
            raise DomeCalibError(f"scheduler {address!r}: not an address of the form tcp://HOST:PORT")
        if client is not None:  # an existing client (a LocalCluster's): not ours to close
            self.client, self._own = client, False
        else:
            try:
                self.client = Client(address, timeout=f"{connect_timeout_s}s", set_as_default=False)
            except (OSError, TimeoutError, ValueError) as exc:
                raise DomeCalibError(f"scheduler {address}: cannot connect within {connect_timeout_s:g} s "
                                     f"({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else 'no answer'})") from None
            self._own = True
        self._max_in_flight = max_in_flight

    def worker_names(self) -> dict[str, str]:
        """Connected workers: name -> address."""
        info = self.client.scheduler_info(n_workers=-1) if _has_n_workers(self.client) else self.client.scheduler_info()
        return {str(w.get("name", addr)): addr for addr, w in info["workers"].items()}

    def wait_for_workers(self, names: Iterable[str], timeout_s: float) -> None:
        """Wait until every named worker is connected; else one line naming the missing ones."""
        wanted = sorted(set(names))
        deadline = time.monotonic() + timeout_s
        while True:
            missing = [n for n in wanted if n not in self.worker_names()]
            if not missing:
                return
            if time.monotonic() > deadline:
                raise DomeCalibError(f"scheduler {self.address}: worker(s) {', '.join(missing)} not connected after "
                                     f"{timeout_s:g} s (start `dask worker {self.address} --name NAME` on each node)")
            time.sleep(0.2)

    def wait_for_any_worker(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while not self.worker_names():
            if time.monotonic() > deadline:
                raise DomeCalibError(f"scheduler {self.address}: no worker connected after {timeout_s:g} s "
                                     f"(start `dask worker {self.address}` on each node)")
            time.sleep(0.2)

    def submit(self, fn: Callable[..., R], /, *args: Any, **kwargs: Any):
        return self.client.submit(fn, *args, retries=self.retries, pure=False, **kwargs)

    def _submit_item(self, fn: Callable[[T], R], item: T):
        route = self.routes.get(fn)
        run = route.task_fn if route is not None and route.task_fn is not None else fn
        worker = route.worker_of(item) if route is not None else None
        placement = {"workers": [worker], "allow_other_workers": False} if worker is not None else {}
        return self.client.submit(_timed, run, item, retries=self.retries, pure=False, **placement)

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
        """Results in completion order; at most ``max_in_flight`` futures at once (default 4 per worker thread)."""
        stats = self.stats.setdefault(getattr(fn, "__name__", str(fn)), MapStats())
        limit = self._max_in_flight or max(4, 4 * sum(self.client.nthreads().values()))
        t0 = time.perf_counter()
        it = iter(items)
        pending = as_completed(loop=self.client.loop)
        in_flight = 0
        try:
            for item in it:
                pending.add(self._submit_item(fn, item))
                stats.bytes_out += payload_bytes(item)
                in_flight += 1
                if in_flight >= limit:
                    break
            for fut in pending:
                worker, seconds, result = self._result(fut)
                fut.release()
                in_flight -= 1
                stats.tasks += 1
                stats.workers[worker] = stats.workers.get(worker, 0) + 1
                stats.task_s += seconds
                stats.bytes_back += payload_bytes(result)
                nxt = next(it, _END)
                if nxt is not _END:
                    pending.add(self._submit_item(fn, nxt))
                    stats.bytes_out += payload_bytes(nxt)
                    in_flight += 1
                stats.wall_s += time.perf_counter() - t0
                t0 = time.perf_counter()
                yield result
        finally:
            stats.wall_s += time.perf_counter() - t0
            for fut in list(pending.futures):
                fut.cancel()

    def scheduler_gone(self, exc: BaseException) -> bool:
        """Whether ``exc`` (from a future) means the connection to the scheduler is lost, not that a task failed:
        the futures are cancelled, the comm closed, or the client no longer running."""
        if isinstance(exc, (CancelledError, OSError, TimeoutError)) or "closing" in str(exc) or "closed" in str(exc):
            return True
        return getattr(self.client, "status", "running") not in ("running", "connecting")

    def _result(self, fut):
        """``fut.result()``; a lost scheduler becomes one line naming it (a task's own error passes through)."""
        try:
            return fut.result()
        except Exception as exc:
            if not self.scheduler_gone(exc):
                raise
            raise DomeCalibError(f"the scheduler at {self.address} went away during the run ({type(exc).__name__}"
                                 f"{': ' + str(exc).splitlines()[0] if str(exc) else ''}); restart it and its "
                                 "workers, then rerun the same command to resume") from None

    def stats_dict(self) -> dict:
        return {"scheduler": self.address, "stages": {k: v.as_dict() for k, v in sorted(self.stats.items())}}

    def shutdown(self) -> None:
        if self._own:
            try:
                self.client.close(timeout=CONNECT_TIMEOUT_S)
            except (OSError, TimeoutError, RuntimeError):  # the scheduler is gone: nothing left to close
                pass

    def __enter__(self) -> DaskExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()


_END = object()


def _has_n_workers(client: Any) -> bool:
    return "n_workers" in inspect.signature(client.scheduler_info).parameters
