"""The `timecode` command: decode LTC from audio, build sync tables.

The decoder and the sync pipeline are imported inside the commands, so `timecode --help` starts without numpy.
"""
from __future__ import annotations

import sys
from pathlib import Path

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
def decode(
    files: list[str] = typer.Argument(..., help="Audio files with LTC, or folders of them (their WAV, FLAC, AIFF, "
                                      "... files, by name; not recursing): WAV, FLAC, AIFF, ... or headerless raw "
                                      "files (then give --raw-format and --raw-rate)."),
    channel: str = typer.Option("all", "--channel", "-c", help="Channel to decode: 0 = first (left), 1 = second, "
                                "...; 'all' decodes every channel (an error only if none holds LTC)."),
    fps: str = typer.Option("auto", "--fps", help="Frame rate: auto (detected from the labels and the frame "
                            "length), 24, 25, 29.97df (drop frame), 29.97, 30 or 23.976. A rate the LTC "
                            "contradicts (labels counting to another number, drop-frame bit) is refused."),
    fmt: str = typer.Option("table", "--format", "-f", help="table (for people), csv or json (one record per "
                            "frame: file, channel, label, direction, start/end in samples, user bits, flags, "
                            "level, jitter, reading (square or impulses), extrapolated edge)."),
    raw_format: str = typer.Option(None, "--raw-format", help="Headerless file sample format: u8 (unsigned "
                                   "8-bit, e.g. libltc's test file), s8, s16, s16be, s32, f32 or f64."),
    raw_rate: int = typer.Option(None, "--raw-rate", help="Headerless file sample rate in Hz, e.g. 22050."),
    raw_channels: int = typer.Option(1, "--raw-channels", help="Headerless file interleaved channel count."),
    output: str = typer.Option(None, "--output", "-o", help="Write to this file (atomically) instead of stdout."),
) -> None:
    """Decode SMPTE LTC from audio files: every frame's label, user bits, flags and direction, and the time of
    its first edge in samples with sub-sample precision (start_samples; start_s = seconds). Several files or a
    folder make one table with a file column; a file that fails is one line on stderr, the others go on, and
    the exit code is then 1."""
    from timecode.cli.decode_command import check_output, raw_format as make_raw, run_decode

    raw = make_raw(raw_format, raw_rate, raw_channels)
    if output:
        check_output(output, [Path(f) for f in files], raw)
    result = run_decode([Path(f) for f in files], channel=channel, fps=fps, fmt=fmt, raw=raw)
    for line in result.warnings:
        print(f"timecode: warning: {line}", file=sys.stderr)
    for line in result.failures:
        print(f"timecode: error: {line}", file=sys.stderr)
    if result.n_decoded:
        if output:
            from dome_calib.ownership import write_text

            write_text(output, result.text)
        else:
            typer.echo(result.text, nl=False)
    if result.failures:
        raise typer.Exit(1)


@app.command()
def sync(
    session: str = typer.Argument(..., help="Session folder holding session.json, ltc.wav and kinect/ (see docs/timecode.md, "
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
    from timecode.cli.sync_command import run_sync

    run_sync(Path(session), Path(output), seq=seq, strict_kinect=strict_kinect,
             max_extrapolation_s=max_extrapolation_s)


def main() -> None:
    run_cli(app, prog="timecode", user_errors=(TimecodeError,))
