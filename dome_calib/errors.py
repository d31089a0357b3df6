"""Error hierarchy and the one-line-error CLI runner shared by the `dome-calib` and `timecode` commands."""
from __future__ import annotations

import contextlib
import errno
import functools
import importlib
import importlib.abc
import importlib.util
import logging
import math
import os
import signal
import sys
import threading
import _thread
from collections.abc import Callable, Iterator
from typing import Any

from dome_calib.final_place import said

logger = logging.getLogger("dome_calib")


class DomeCalibError(Exception):
    """Base of every error a user can cause (bad input, missing file, impossible request)."""


class BundleFormatError(DomeCalibError, ValueError):
    """A calibration-bundle file is malformed; the message names the file, the camera and the field."""


class CaptureError(DomeCalibError, ValueError):
    """A capture folder (images, Kinect frames, audio) is missing something or malformed."""


class PeopleFileError(DomeCalibError, ValueError):
    """A body3DScene folder or file is unusable (:mod:`dome_calib.body3d_scene`), or a people output cannot be
    written; the message names the file, the field and what is wrong."""


class ReportError(DomeCalibError):
    """The report cannot be made from what was given (bad residual file, unknown camera)."""


class OptionsError(DomeCalibError, ValueError):
    """An option outside its declared bounds (:mod:`dome_calib.options`). ``owner``: the options class; ``field``:
    the field path; ``shown``: the value given, as the message shows it; ``expected``: what the declaration
    accepts, in words."""

    def __init__(self, message: str, *, owner: str = "", field: str = "", shown: str = "", expected: str = ""):
        super().__init__(message)
        self.owner, self.field, self.shown, self.expected = owner, field, shown, expected


@contextlib.contextmanager
def flags(names: dict[str, str]) -> Iterator[None]:
    """Inside the block, an :class:`OptionsError` of a field that a command's flag sets names the flag the user
    typed. ``names``: ``"Class.field"`` (the field path inside its options class) -> the flag::

        with flags({"AssociationOptions.min_person_views": "--min-views"}):
            options = people_options(min_views=min_views)    # --min-views 1: expected an integer >= 2
    """
    try:
        yield
    except OptionsError as exc:
        flag = names.get(f"{exc.owner}.{exc.field}")
        if flag is None or not exc.expected:
            raise
        raise OptionsError(f"{flag} {exc.shown}: expected {exc.expected}", owner=exc.owner, field=exc.field,
                           shown=exc.shown, expected=exc.expected) from None


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM arrived while a stage ran; ``stage`` names it (the run resumes from the work folder)."""

    def __init__(self, stage: str) -> None:
        super().__init__(stage)
        self.stage = stage


#: Exit code of a run stopped by SIGINT or SIGTERM (128 + SIGINT, as shells report it).
EXIT_INTERRUPTED = 130


def _terminate_as_interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


#: How long after a swallowed interrupt it is handed to the main thread again: long after the hook that saw it has
#: returned (microseconds), short beside a user's patience.
REDELIVER_AFTER_S = 0.05


def _redeliver(generation: int) -> None:
    """Hand SIGTERM (our handler, inside the block) to the main thread again, if the block that lost an interrupt
    is still the one open."""
    if _active and _generation == generation:
        _thread.interrupt_main(signal.SIGTERM)


def _interrupt_never_swallowed(unraisable: Any) -> None:
    """``sys.unraisablehook`` inside :func:`interrupt_as_one_line`. A signal's handler runs in the main thread at
    whatever Python code runs there next; when that is a finaliser or a weakref callback (an import lock's, while
    a module loads; a ``__del__`` under garbage collection), its ``KeyboardInterrupt`` is "ignored": printed, then
    dropped, and the run went on as if no signal had come (seen: SIGTERM during an import, the run then blocked on
    its input). Here such an interrupt is not printed but handed to the main thread again shortly after, as
    SIGTERM, whose handler in the block raises it where the run stands; a hand-over that lands in a callback
    again comes back here. Anything else goes to the hook that was in place."""
    if (isinstance(unraisable.exc_value, KeyboardInterrupt) and _active
            and threading.current_thread() is threading.main_thread()):
        timer = threading.Timer(REDELIVER_AFTER_S, _redeliver, args=(_generation,))
        timer.daemon = True
        timer.start()
        return
    _hook_before(unraisable)


#: Libraries whose import installs C-level signal handlers over Python's (pycolmap: glog's failure handler, which
#: prints a C stack and kills the process on SIGTERM): imported first inside the block, then ours put back over
HANDLER_REPLACING_IMPORTS = ("pycolmap",)
_active = 0  # interrupt_as_one_line blocks open
_generation = 0  # outermost blocks opened so far: a hand-over meant for one never reaches the next
_hook_before: Callable[[Any], object] = sys.unraisablehook


def restore_interrupt_handler() -> None:
    """Inside :func:`interrupt_as_one_line`: put its SIGTERM handler back (a library loaded since may have replaced
    it at the C level, where ``signal.getsignal`` does not see it). Call before long work; a no-op outside."""
    if _active and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _terminate_as_interrupt)


def _interrupt_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The interrupt an error was raised from or while handling (its ``__cause__`` / ``__context__`` chain), if any.
    An extension module's initialiser turns an interrupt inside it into ``ImportError("initialization failed")``
    (pybind11: gtsam, pycolmap), and a cleanup may fail while an interrupt unwinds: both are the interrupt."""
    seen: set[int] = set()
    link: BaseException | None = exc
    while link is not None and id(link) not in seen:
        if isinstance(link, KeyboardInterrupt):
            return link
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return None


@contextlib.contextmanager
def _held_while_a_library_loads() -> Iterator[None]:
    """While a library of HANDLER_REPLACING_IMPORTS loads: SIGTERM is held back (blocked in the main thread), the
    handler in place before is put back over the one the library installed at the C level, and a SIGTERM that came
    meanwhile is then delivered to it. Before: a SIGTERM within the load reached glog's handler, which printed a C
    stack and killed the process (exit -15). Outside the main thread nothing is changed (signals are its own)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handler = signal.getsignal(signal.SIGTERM)
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM})
    try:
        yield
    finally:
        if callable(handler):
            signal.signal(signal.SIGTERM, handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)


@contextlib.contextmanager
def interrupt_as_one_line(prog: str, advice: str = "rerun the same command to resume",
                          imports: tuple[str, ...] = HANDLER_REPLACING_IMPORTS) -> Iterator[None]:
    """SIGINT or SIGTERM inside the block: one line on stderr ("interrupted during STAGE; ADVICE", the stage when a
    pipeline stage was running), exit code 130, no traceback (``DOME_CALIB_DEBUG=1``: raise). ``imports``: libraries
    whose handlers ours must go over, imported first."""
    global _active, _generation, _hook_before
    previous = signal.signal(signal.SIGTERM, _terminate_as_interrupt)
    if not _active:  # the outermost block
        _hook_before, sys.unraisablehook = sys.unraisablehook, _interrupt_never_swallowed
        _generation += 1
    _active += 1
    try:
        for name in imports:  # their handlers first, ours over them
            with _held_while_a_library_loads():
                importlib.import_module(name)
        restore_interrupt_handler()
        yield
    except (KeyboardInterrupt, Exception) as exc:
        interrupt = exc if isinstance(exc, KeyboardInterrupt) else _interrupt_behind(exc)
        if interrupt is None or os.environ.get("DOME_CALIB_DEBUG"):
            raise
        where = f" during {interrupt.stage}" if isinstance(interrupt, Interrupted) else ""
        print(f"{prog}: interrupted{where}; {advice}", file=sys.stderr)
        sys.exit(EXIT_INTERRUPTED)
    finally:
        _active -= 1
        if not _active:
            sys.unraisablehook = _hook_before
        signal.signal(signal.SIGTERM, previous)


def require_finite(error: type[Exception], **values: float | None) -> None:
    """``error`` naming the first of ``values`` (option name -> number, None skipped) that is NaN or infinite."""
    for name, value in values.items():
        if value is not None and not math.isfinite(value):
            raise error(f"{name} {value}: expected a finite number")


#: errno values of a write the disk or folder refused: full, over quota, read-only, not permitted.
STORAGE_ERRNOS = {errno.ENOSPC: "no space left on the disk", errno.EDQUOT: "disk quota exceeded",
                  errno.EROFS: "read-only file system", errno.EACCES: "permission denied"}
#: The same, as SQLite (pycolmap's database, sqlite3) and C++ libraries say it in a RuntimeError's text.
_STORAGE_TEXTS = {"database or disk is full": "no space left on the disk",
                  "no space left on device": "no space left on the disk",
                  "disk quota exceeded": "disk quota exceeded",
                  "attempt to write a readonly database": "read-only file system"}


def storage_failure(exc: BaseException) -> str | None:
    """What the disk refused (e.g. "no space left on the disk") when ``exc`` is a failed write, else None: an
    OSError with a STORAGE_ERRNOS errno, or any exception whose text is SQLite's or the C library's for it."""
    if isinstance(exc, OSError) and exc.errno in STORAGE_ERRNOS:
        return STORAGE_ERRNOS[exc.errno]
    text = str(exc).lower()
    return next((why for key, why in _STORAGE_TEXTS.items() if key in text), None)


#: What a command stopped by SIGINT or SIGTERM says when it names nothing itself: outputs are staged and renamed into
#: place at the end (dome_calib.io_utils.atomic_folder), so an interrupted command leaves them as they were.
INTERRUPTED_ADVICE = "its outputs are as they were (nothing is written before the end); rerun the same command"


def _interrupt_as_one_line_in_every_command(app: Any, prog: str) -> None:
    """Every command of ``app`` (a typer app) runs inside :func:`interrupt_as_one_line`: SIGTERM unwinds the command
    like Ctrl-C (its staging folders removed on the way out), then one line and exit 130, whether the command says
    more (its own block, inside) or not. Without it SIGTERM killed the process where it stood (exit 143, staging
    folders left, no word). Commands added later are covered by construction."""
    for info in getattr(app, "registered_commands", []):
        callback = info.callback
        if callback is None or getattr(callback, "_one_line_on_interrupt", False):
            continue

        @functools.wraps(callback)
        def wrapped(*args: Any, _callback: Callable[..., Any] = callback, **kwargs: Any) -> Any:
            with interrupt_as_one_line(prog, INTERRUPTED_ADVICE, imports=()):  # no pycolmap for `info`
                return _callback(*args, **kwargs)

        wrapped._one_line_on_interrupt = True  # type: ignore[attr-defined]
        info.callback = wrapped
    for group in getattr(app, "registered_groups", []):
        if group.typer_instance is not None:
            _interrupt_as_one_line_in_every_command(group.typer_instance, prog)


class _HandlerGuard(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """While a command runs: after a module of HANDLER_REPLACING_IMPORTS is loaded (wherever it is imported, however
    late), the SIGTERM handler that was in place before is put back over the one it installed at the C level."""

    def find_spec(self, fullname, path, target=None):
        if fullname not in HANDLER_REPLACING_IMPORTS:
            return None
        sys.meta_path.remove(self)
        try:
            spec = importlib.util.find_spec(fullname)
        finally:
            sys.meta_path.insert(0, self)
        if spec is not None and spec.loader is not None:
            self.inner, spec.loader = spec.loader, self
        return spec

    def create_module(self, spec):
        self.held = contextlib.ExitStack()  # from here (an extension's init may run now) to the end of exec_module
        self.held.enter_context(_held_while_a_library_loads())
        try:
            return self.inner.create_module(spec)
        except BaseException:
            self.held.close()
            raise

    def exec_module(self, module) -> None:
        with self.held:
            self.inner.exec_module(module)


class _SaidAtFinalPlace(logging.Formatter):
    """A log line as the user reads it: every staged path in it said at its final place
    (:func:`dome_calib.final_place.said`; a library logs where it writes, the staging folder)."""

    def format(self, record: logging.LogRecord) -> str:
        return said(super().format(record))


def console_handler(prog: str) -> logging.Handler:
    """The commands' log handler: ``PROG: message`` on stderr, paths said at their final place."""
    handler = logging.StreamHandler()
    handler.setFormatter(_SaidAtFinalPlace(f"{prog}: %(message)s"))
    return handler


def _error_line(prog: str, msg: str) -> str:
    return said(f"{prog}: error: {msg}")


def run_cli(app: Callable[..., object], *, prog: str, user_errors: tuple[type[BaseException], ...] = ()) -> None:
    """Run a typer app; turn user errors into one line on stderr and exit code 1, no traceback. SIGTERM during any
    command: staged outputs removed on the way out, one line, exit 130 (also after a late import of pycolmap, whose
    C-level handler would kill the process: :class:`_HandlerGuard`). Every log line and the error line name an
    output at its final place, never its staging place (:func:`console_handler`, :func:`dome_calib.final_place.said`).

    Set ``DOME_CALIB_DEBUG=1`` to see the full traceback instead.
    """
    handled = (DomeCalibError, OSError, *user_errors)
    logging.basicConfig(level=logging.INFO, handlers=[console_handler(prog)])
    _interrupt_as_one_line_in_every_command(app, prog)
    guard = _HandlerGuard()
    sys.meta_path.insert(0, guard)
    try:
        app(standalone_mode=True)
    except handled as exc:  # one line, non-zero exit
        if os.environ.get("DOME_CALIB_DEBUG"):
            raise
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in msg:
            msg = f"{exc.filename}: {msg}"
        print(_error_line(prog, msg), file=sys.stderr)
        sys.exit(1)
    except Exception as exc:  # a write the disk refused, as a library reports it (RuntimeError, sqlite3 error)
        why = storage_failure(exc)
        if why is None or os.environ.get("DOME_CALIB_DEBUG"):
            raise
        print(_error_line(prog, f"{why} ({str(exc).splitlines()[0]}); free space or write elsewhere"),
              file=sys.stderr)
        sys.exit(1)
    finally:
        sys.meta_path.remove(guard)
