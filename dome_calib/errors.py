"""Error hierarchy and the one-line-error CLI runner shared by the `dome-calib` and `timecode` commands."""
from __future__ import annotations

import logging
import os
import sys
from collections.abc import Callable

logger = logging.getLogger("dome_calib")


class DomeCalibError(Exception):
    """Base of every error a user can cause (bad input, missing file, impossible request)."""


class BundleFormatError(DomeCalibError, ValueError):
    """A calibration-bundle file is malformed; the message names the file, the camera and the field."""


class CaptureError(DomeCalibError, ValueError):
    """A capture folder (images, Kinect frames, audio) is missing something or malformed."""


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
