"""``timecode decode``: the work behind the CLI command (parse choices, decode with a progress bar, render)."""
from __future__ import annotations

import sys
from pathlib import Path

from timecode.audio_io import AudioReader, RawFormat, RawSampleFormat
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from timecode.decoder import DecodeOptions, decode_file
from timecode.errors import NoLTCError, TimecodeError
from timecode.formats import OutputFormat, render
from timecode.rates import FrameRate, parse_rate


class UsageError(TimecodeError, ValueError):
    """A bad command-line value."""


def parse_channels(text: str, n_channels: int) -> list[int] | None:
    """``all`` -> None; ``N`` -> [N] (0 = first channel)."""
    if text.strip().lower() == "all":
        return None
    try:
        c = int(text)
    except ValueError:
        raise UsageError(f"--channel must be a channel number (0 = first) or 'all', got {text!r}") from None
    if not 0 <= c < n_channels:
        raise UsageError(f"--channel {c}: the file has {n_channels} channel(s), numbered 0..{n_channels - 1}")
    return [c]


def parse_fps(text: str) -> FrameRate | None:
    return None if text.strip().lower() == "auto" else parse_rate(text)


def raw_format(sample_format: str | None, rate: int | None, channels: int) -> RawFormat | None:
    if sample_format is None and rate is None:
        return None
    if sample_format is None or rate is None:
        raise UsageError("a headerless file needs both --raw-format and --raw-rate")
    try:
        fmt = RawSampleFormat(sample_format.lower())
    except ValueError:
        raise UsageError(f"--raw-format {sample_format!r} is not one of "
                         f"{', '.join(f.value for f in RawSampleFormat)}") from None
    if channels < 1:
        raise UsageError(f"--raw-channels must be >= 1, got {channels}")
    return RawFormat(sample_format=fmt, sample_rate=rate, channels=channels)


def run_decode(path: Path, *, channel: str, fps: str, fmt: str, raw: RawFormat | None) -> str:
    """Decode ``path`` and return the rendered output; raises NoLTCError if a requested channel has none."""
    try:
        out_fmt = OutputFormat(fmt.lower())
    except ValueError:
        raise UsageError(f"--format must be one of {', '.join(f.value for f in OutputFormat)}, got {fmt!r}") from None
    rate = parse_fps(fps)
    with AudioReader(path, raw) as reader:
        info = reader.info
    chans = parse_channels(channel, info.channels)
    result = _decode_with_progress(path, DecodeOptions(rate=rate), chans, raw, info.frames)
    found = [ch for ch in result if len(ch)]
    if chans is not None and not found:
        raise NoLTCError(f"{path}: no LTC found on channel {chans[0]}")
    if not found:
        raise NoLTCError(f"{path}: no LTC found on any of its {info.channels} channel(s)")
    return render(result, out_fmt, str(path))


def _decode_with_progress(path: Path, options: DecodeOptions, channels: list[int] | None, raw: RawFormat | None,
                          total: int):
    console = Console(stderr=True)
    with Progress(TextColumn("decoding"), BarColumn(), MofNCompleteColumn(), TextColumn("samples"),
                  TimeRemainingColumn(), console=console, transient=True,
                  disable=not sys.stderr.isatty()) as bar:
        task = bar.add_task("decode", total=total)
        return decode_file(path, options=options, channels=channels, raw=raw,
                           progress=lambda done, _n: bar.update(task, completed=done))
