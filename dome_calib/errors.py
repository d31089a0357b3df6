"""Error hierarchy and the one-line-error CLI runner shared by the `dome-calib` and `timecode` commands."""
from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
from collections.abc import Callable, Iterator

logger = logging.getLogger("dome_calib")


class DomeCalibError(Exception):
    """Base of every error a user can cause (bad input, missing file, impossible request)."""


class BundleFormatError(DomeCalibError, ValueError):
    """A calibration-bundle file is malformed; the message names the file, the camera and the field."""


class CaptureError(DomeCalibError, ValueError):
    """A capture folder (images, Kinect frames, audio) is missing something or malformed."""


class ReportError(DomeCalibError):
    """The report cannot be made from what was given (bad residual file, unknown camera)."""


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM arrived while a stage ran; ``stage`` names it (the run resumes from the work folder)."""

    def __init__(self, stage: str) -> None:
        super().__init__(stage)
        self.stage = stage


#: Exit code of a run stopped by SIGINT or SIGTERM (128 + SIGINT, as shells report it).
EXIT_INTERRUPTED = 130


def _terminate_as_interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


@contextlib.contextmanager
def interrupt_as_one_line(prog: str) -> Iterator[None]:
    """SIGINT or SIGTERM inside the block: one line on stderr ("interrupted during STAGE; rerun the same command
    to resume" when a pipeline stage was running), exit code 130, no traceback (``DOME_CALIB_DEBUG=1``: raise)."""
    previous = signal.signal(signal.SIGTERM, _terminate_as_interrupt)
    try:
        yield
    except KeyboardInterrupt as exc:
        if os.environ.get("DOME_CALIB_DEBUG"):
            raise
        where = f" during {exc.stage}" if isinstance(exc, Interrupted) else ""
        print(f"{prog}: interrupted{where}; rerun the same command to resume", file=sys.stderr)
        sys.exit(EXIT_INTERRUPTED)
    finally:
        signal.signal(signal.SIGTERM, previous)


def run_cli(app: Callable[..., object], *, prog: str, user_errors: tuple[type[BaseException], ...] = ()) -> None:
    """Run a typer app; turn user errors into one line on stderr and exit code 1, no traceback.

    Set ``DOME_CALIB_DEBUG=1`` to see the full traceback instead.
    """
    handled = (DomeCalibError, OSError, *user_errors)
    logging.basicConfig(level=logging.INFO, format=f"{prog}: %(message)s")
    try:
        app(standalone_mode=True)
    except handled as exc:  # one line, non-zero exit
        if os.environ.get("DOME_CALIB_DEBUG"):
            raise
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in msg:
            msg = f"{exc.filename}: {msg}"
        print(f"{prog}: error: {msg}", file=sys.stderr)
        sys.exit(1)
