"""The `timecode` command: decode LTC from audio, build sync tables."""
from __future__ import annotations

import typer

from dome_calib.errors import run_cli
from timecode.errors import TimecodeError

app = typer.Typer(
    help="Decode SMPTE linear timecode (LTC) from audio recordings and align clocks.",
    no_args_is_help=True,
    add_completion=False,
)


@app.callback()
def _root() -> None:
    """Decode SMPTE linear timecode (LTC) from audio recordings and align clocks."""


def main() -> None:
    run_cli(app, prog="timecode", user_errors=(TimecodeError,))
