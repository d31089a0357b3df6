"""The `dome-calib` command: a thin shell over the stages. Each command parses, builds options, calls a stage."""
from __future__ import annotations

import json
from pathlib import Path

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


@app.command()
def info(
    bundle: Path = typer.Argument(..., help="Bundle folder (holds calibration_<seq>.json).", show_default=False),
    json_out: bool = typer.Option(False, "--json", help="Print the summary as JSON instead of a table."),
) -> None:
    """Summarise a calibration bundle: cameras by type, intrinsics, camera positions, sync coverage."""
    from dome_calib.bundle import load_bundle
    from dome_calib.info import bundle_summary, format_summary

    summary = bundle_summary(load_bundle(bundle))
    typer.echo(json.dumps(summary, indent=2) if json_out else format_summary(summary))


def main() -> None:
    run_cli(app, prog="dome-calib")
