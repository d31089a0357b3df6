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


@app.command()
def sync(
    session: str = typer.Argument(..., help="Session folder holding session.json, ltc.wav and kinect/ (see README, "
                                            "'Sync session layout')."),
    output: str = typer.Option(..., "-o", "--output", help="Bundle folder to write synctables_<seq>.json, "
                               "ksynctables_<seq>.json and report/sync.json into (an existing calibration is kept)."),
    seq: str = typer.Option(None, "--seq", help="Sequence name in the file names (default: the session's 'seq', or "
                            "the bundle's when it already holds a calibration)."),
    strict_kinect: bool = typer.Option(False, "--strict-kinect", help="Fail when a Kinect cannot be synced "
                                       "(default: report it as NOT SYNCED and write the other streams)."),
    max_extrapolation_s: float = typer.Option(2.0, "--max-extrapolation", help="Frames may lie this many seconds "
                                              "outside the LTC that times them; farther is an error."),
) -> None:
    """Align the VGA, HD and Kinect clocks from LTC and write sync tables (universal time = ms on the HD LTC)."""
    from pathlib import Path

    from timecode.sync.command import run_sync

    run_sync(Path(session), Path(output), seq=seq, strict_kinect=strict_kinect,
             max_extrapolation_s=max_extrapolation_s)


def main() -> None:
    run_cli(app, prog="timecode", user_errors=(TimecodeError,))
