"""``timecode decode``: the work behind the CLI command (parse choices, decode with a progress bar, render)."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from dome_calib.cli.progress import ProgressBars
from dome_calib.ownership import claim_file
from timecode.audio_io import AudioReader, RawFormat, RawSampleFormat
from timecode.decode.decoder import MAX_RATE, MIN_RATE, DecodeError, DecodeOptions, RateMismatchError, decode_file
from timecode.errors import NoLTCError, TimecodeError
from timecode.decode.formats import OutputFormat, render
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


#: File name endings read from a folder (libsndfile's formats; ``.raw`` too with --raw-format).
AUDIO_SUFFIXES = (".wav", ".wave", ".bwf", ".rf64", ".w64", ".flac", ".aif", ".aiff", ".aifc", ".caf", ".au",
                  ".snd", ".ogg", ".oga", ".opus", ".mp3")


@dataclass(kw_only=True)
class BatchResult:
    """What ``run_decode`` made: the rendered output of the files that decoded, and one line per file that
    did not."""

    text: str
    n_decoded: int
    failures: list[str]
    warnings: list[str]


def input_files(inputs: Sequence[Path], raw: RawFormat | None) -> tuple[list[Path], bool]:
    """The files to decode: each file as given, each folder's audio files (by name, not recursing), and whether
    this is a batch (a folder, or more than one input)."""
    files: list[Path] = []
    suffixes = AUDIO_SUFFIXES + ((".raw", ".pcm") if raw is not None else ())
    for p in inputs:
        if p.is_dir():
            found = sorted((f for f in p.iterdir() if f.is_file() and f.suffix.lower() in suffixes),
                           key=lambda f: f.name)
            if not found:
                raise UsageError(f"{p}: the folder holds no audio file ({', '.join(suffixes)})")
            files.extend(found)
        else:
            files.append(p)
    return files, len(inputs) > 1 or any(p.is_dir() for p in inputs)


def check_output(output: str, inputs: Sequence[Path], raw: RawFormat | None) -> None:
    """Before anything is read: ``-o`` must be a file that can be written and none of the inputs (the same file by
    another path or a link; a folder's audio files count), else one line (OutputPathError)."""
    files, _ = input_files(inputs, raw)
    claim_file(output, inputs=[*inputs, *files])  # new, or a file of ours, unchanged (dome_calib.ownership)


def run_decode(inputs: Sequence[Path], *, channel: str, fps: str, fmt: str, raw: RawFormat | None) -> BatchResult:
    """Decode every input file (folders: their audio files) into one output; a file that fails is one line in
    ``failures`` and the others go on. A single input keeps the single-file JSON layout."""
    try:
        out_fmt = OutputFormat(fmt.lower())
    except ValueError:
        raise UsageError(f"--format must be one of {', '.join(f.value for f in OutputFormat)}, got {fmt!r}") from None
    rate = parse_fps(fps)
    files, batch = input_files(inputs, raw)
    done: list[tuple[str, list]] = []
    failed: list[tuple[str, str]] = []
    warnings: list[str] = []
    readable = []
    for path in files:  # every header before the first decoding: a bad file is known in seconds, not at its turn
        try:
            channels_of(path, channel, raw)
        except TimecodeError as exc:
            msg = str(exc).splitlines()[0]
            failed.append((str(path), msg if msg.startswith(str(path)) else f"{path}: {msg}"))
        else:
            readable.append(path)
    for path in readable:
        try:
            result = _decode_one(path, channel=channel, rate=rate, raw=raw)
        except TimecodeError as exc:
            msg = str(exc).splitlines()[0]
            failed.append((str(path), msg if msg.startswith(str(path)) else f"{path}: {msg}"))
            continue
        done.append((str(path), result))
        warnings += [f"{path} channel {ch.channel}: {ch.n_nonfinite} NaN or infinite samples read as gaps "
                     "(interpolated over)" for ch in result if ch.n_nonfinite]
    text = render(done, out_fmt, failed, batch) if done else ""
    return BatchResult(text=text, n_decoded=len(done), failures=[m for _, m in failed], warnings=warnings)


def channels_of(path: Path, channel: str, raw: RawFormat | None) -> tuple[list[int] | None, int]:
    """From the file's header (and its last sample): the channels to decode (None: all) and how many it has;
    TimecodeError when it cannot be read, lacks the channel or has a sample rate the decoder does not read."""
    with AudioReader(path, raw) as reader:
        info = reader.info
    if not MIN_RATE <= info.sample_rate <= MAX_RATE:
        raise DecodeError(f"{path}: sample rate {info.sample_rate} Hz is outside the supported {MIN_RATE}-{MAX_RATE} Hz")
    return parse_channels(channel, info.channels), info.channels


def _decode_one(path: Path, *, channel: str, rate: FrameRate | None, raw: RawFormat | None) -> list:
    """The channels of one file; raises a TimecodeError (no LTC on a requested channel, unreadable, ...)."""
    chans, n_channels = channels_of(path, channel, raw)
    try:
        result = _decode_with_progress(path, DecodeOptions(rate=rate), chans, raw)
    except RateMismatchError as exc:
        raise RateMismatchError(f"{path}: {exc} (leave --fps auto to detect the rate)") from None
    found = [ch for ch in result if len(ch)]
    if chans is not None and not found:
        raise NoLTCError(f"{path}: no LTC found on channel {chans[0]}")
    if not found:
        raise NoLTCError(f"{path}: no LTC found on any of its {n_channels} channel(s)")
    return result


def _decode_with_progress(path: Path, options: DecodeOptions, channels: list[int] | None, raw: RawFormat | None):
    with ProgressBars(transient=True) as bars:
        return decode_file(path, options=options, channels=channels, raw=raw,
                           progress=bars.task(f"decoding {path.name}: samples"))
