"""The `dome-calib` command: a thin shell over the stages. Each command parses, builds options, calls a stage."""
from __future__ import annotations

import typer

from dome_calib.errors import run_cli

app = typer.Typer(
    help="Calibrate and synchronise the capture dome, and inspect calibration bundles.",
    no_args_is_help=True,
    add_completion=False,
)


@app.callback()
def _root() -> None:
    """Calibrate and synchronise the capture dome, and inspect calibration bundles."""


def main() -> None:
    run_cli(app, prog="dome-calib")
