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

Verified, not assumed: before a client is made, :func:`probe_scheduler` checks the address in a bounded handshake
(an address where nothing listens, that accepts and says nothing, speaks another protocol, or is a Dask worker,
is one line within ``HANDSHAKE_TIMEOUT_S``; ``distributed.Client`` itself waits for ever on a silent server and
runs out of memory on an HTTP one). A route may also say how to check what a worker read: its ``task_fn``
returns :class:`Proven` (the result and the evidence of what the worker read) and ``verify(item, worker,
evidence)`` runs on this machine before the result is handed on; it raises to stop the run naming the worker.
"""
from __future__ import annotations

import asyncio
import dataclasses
import inspect
import re
import socket
import struct
import threading
import time
from concurrent.futures import CancelledError
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
from dask.sizeof import sizeof
from distributed import Client, as_completed, get_worker
from distributed.comm import connect

from dome_calib.errors import DomeCalibError
from dome_calib.executor import Proven

T = TypeVar("T")
R = TypeVar("R")

CONNECT_TIMEOUT_S = 5.0
#: The whole check of a scheduler address (TCP connect, Dask's handshake, the scheduler's identity) ends within this.
HANDSHAKE_TIMEOUT_S = 10.0
#: A Dask handshake message is a few hundred bytes: a length beyond this is another protocol's bytes.
_MAX_HANDSHAKE_BYTES = 1 << 20


@dataclass(frozen=True)
class Route:
    """Where one task function's items run: ``worker_of(item)`` a worker name (None: any worker), and
    ``task_fn`` the module-level function the worker calls instead of the mapped one (None: the same). When
    ``task_fn`` returns :class:`Proven`, ``verify(item, worker_name, evidence)`` checks the evidence on this
    machine before the result is used (raising stops the run)."""

    worker_of: Callable[[Any], Any]  # a worker's name (--name; a LocalCluster's are ints) or None
    task_fn: Callable[[Any], Any] | None = None
    verify: Callable[[Any, str, Any], None] | None = None


def _handshake_prelude(host: str, port: int, deadline: float) -> None:
    """Connect and read the first 8 bytes a Dask server sends unasked (the length of its handshake message).

    Raises DomeCalibError-ready ``ValueError`` texts: nothing listens, silent, closed, another protocol."""
    try:
        sock = socket.create_connection((host, port), timeout=max(0.1, deadline - time.monotonic()))
    except TimeoutError:
        raise ValueError("no answer to the connection (a firewall, or no such machine?)") from None
    except OSError as exc:
        raise ValueError(f"cannot connect ({exc.strerror or exc}): is `dask scheduler` running there?") from None
    with sock:
        head = b""
        while len(head) < 8:
            sock.settimeout(max(0.05, deadline - _HTTP_PROBE_S - time.monotonic()))
            try:
                chunk = sock.recv(8 - len(head))
            except TimeoutError:
                raise ValueError(_silent_server(sock, deadline)) from None
            except OSError as exc:
                raise ValueError(f"the connection failed ({exc.strerror or exc})") from None
            if not chunk:
                raise ValueError("closed the connection without Dask's greeting: not a Dask scheduler")
            head += chunk
    (size,) = struct.unpack("<Q", head)
    if not 0 < size <= _MAX_HANDSHAKE_BYTES:
        raise ValueError(f"speaks another protocol (it sent {head!r} where Dask sends a message length)")


#: The last seconds of the check: a server that did not greet is asked in HTTP (a dashboard given for the scheduler).
_HTTP_PROBE_S = 2.0


def _silent_server(sock: socket.socket, deadline: float) -> str:
    """Why a server that accepted and greeted not at all is no scheduler: it answers HTTP (the dashboard?) or
    nothing."""
    try:
        sock.sendall(b"HEAD / HTTP/1.0\r\n\r\n")
        sock.settimeout(max(0.05, deadline - time.monotonic()))
        reply = sock.recv(16)
    except OSError:
        reply = b""
    if reply.startswith(b"HTTP/"):
        return ("speaks HTTP, not Dask's protocol (a web server, or the Dask dashboard: the scheduler listens on "
                "its own port, 8786 unless told otherwise)")
    return "accepts connections but sends nothing: not a Dask scheduler (a Dask scheduler greets at once)"


async def _identity(address: str, timeout_s: float) -> dict:
    comm = await connect(address, timeout=timeout_s)
    try:
        await comm.write({"op": "identity", "reply": True})
        return await comm.read()
    finally:
        comm.abort()


def probe_scheduler(address: str, timeout_s: float | None = None) -> None:
    """Check that a Dask scheduler answers at ``address`` (``tcp://HOST:PORT``), within ``timeout_s`` in all:
    DomeCalibError naming the address otherwise (nothing listening, silent, another protocol, a Dask worker)."""
    timeout_s = HANDSHAKE_TIMEOUT_S if timeout_s is None else timeout_s
    deadline = time.monotonic() + timeout_s
    match = re.fullmatch(r"tcp://\[?([^\s/\]]+)\]?:(\d{1,5})", address)
    try:
        if match:  # tls:// and inproc:// have no plain-TCP greeting to read: their connect is bounded below
            _handshake_prelude(match.group(1), int(match.group(2)), deadline)
        found: dict = {}

        def ask() -> None:
            try:
                found["identity"] = asyncio.run(asyncio.wait_for(
                    _identity(address, max(0.1, deadline - time.monotonic())), max(0.1, deadline - time.monotonic())))
            except BaseException as exc:  # noqa: BLE001 - reported below as one line
                found["error"] = exc

        thread = threading.Thread(target=ask, daemon=True)  # its own event loop, whatever the caller runs
        thread.start()
        thread.join(max(0.1, deadline - time.monotonic()) + 1.0)
        if thread.is_alive() or isinstance(found.get("error"), (TimeoutError, asyncio.TimeoutError)):
            raise ValueError(f"no answer to Dask's identity request within {timeout_s:g} s")
        if "error" in found:
            exc = found["error"]
            raise ValueError(f"does not answer as a Dask scheduler ({type(exc).__name__}"
                             f"{': ' + str(exc).splitlines()[0] if str(exc) else ''})")
        kind = found["identity"].get("type") if isinstance(found["identity"], dict) else None
        if kind != "Scheduler":
            raise ValueError(f"is a Dask {kind or 'server'}, not a scheduler: give the address `dask scheduler` "
                             "printed")
    except ValueError as exc:
        raise DomeCalibError(f"scheduler {address}: {exc}") from None


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

    remote = True  # its workers may be other machines, reading their own files (executor.is_remote)

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
            probe_scheduler(address)  # bounded: Client() alone may wait for ever
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
        """Results in completion order; at most ``max_in_flight`` futures at once (default 4 per worker thread).
        A route's :class:`Proven` results are verified (its ``verify``) before they are yielded."""
        stats = self.stats.setdefault(getattr(fn, "__name__", str(fn)), MapStats())
        limit = self._max_in_flight or max(4, 4 * sum(self.client.nthreads().values()))
        route = self.routes.get(fn)
        t0 = time.perf_counter()
        it = iter(items)
        pending = as_completed(loop=self.client.loop)
        item_of: dict[str, T] = {}
        in_flight = 0

        def submit(item: T) -> None:
            nonlocal in_flight
            fut = self._submit_item(fn, item)
            item_of[fut.key] = item
            pending.add(fut)
            stats.bytes_out += payload_bytes(item)
            in_flight += 1

        try:
            for item in it:
                submit(item)
                if in_flight >= limit:
                    break
            for fut in pending:
                worker, seconds, result = self._result(fut)
                item = item_of.pop(fut.key)
                fut.release()
                in_flight -= 1
                if isinstance(result, Proven):
                    if route is not None and route.verify is not None:
                        route.verify(item, worker, result.evidence)
                    result = result.result
                stats.tasks += 1
                stats.workers[worker] = stats.workers.get(worker, 0) + 1
                stats.task_s += seconds
                stats.bytes_back += payload_bytes(result)
                nxt = next(it, _END)
                if nxt is not _END:
                    submit(nxt)
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
