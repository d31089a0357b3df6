"""Decode a session's audio, fit its clocks and write the sync tables: the I/O edge behind ``timecode sync``."""
from __future__ import annotations

import json
import logging
from collections.abc import Callable
from pathlib import Path

import numpy as np
import soundfile as sf

from dome_calib.bundle import load_bundle, write_bundle
from dome_calib.io_utils import atomic_write_text
from dome_calib.panoptic_io import format_ksynctables, format_synctables
from timecode.errors import TimecodeError
from timecode.rates import FrameRate
from timecode.sync.clock import ClockError, FrameStarts
from timecode.sync.report import sync_report
from timecode.sync.session import Session, SessionError, load_session
from timecode.sync.tables import SyncError, SyncOptions, SyncResult, build_sync

logger = logging.getLogger(__name__)


def read_channel(path: Path, channel: int, field: str) -> tuple[np.ndarray, int]:
    """One channel of an audio file as float64 and its sample rate; SessionError naming file and field."""
    if not path.is_file():
        raise SessionError(f"{path}: audio file not found ({field})")
    try:
        data, rate = sf.read(str(path), dtype="float64", always_2d=True)
    except (sf.LibsndfileError, RuntimeError) as exc:
        raise SessionError(f"{path}: cannot read audio ({exc})") from None
    if channel >= data.shape[1]:
        raise SessionError(f"{path}: {field} = {channel} but the file has {data.shape[1]} channel(s)")
    return data[:, channel], int(rate)


def decode_frame_starts(samples: np.ndarray, sample_rate: int, rate: FrameRate, source: str) -> FrameStarts:
    """Decode LTC at a known frame rate; keep forward frames with valid labels. ClockError if none is found."""
    from timecode.decoder import DecoderOptions, decode  # the LTC decoder (issue 4)

    try:
        result = decode(samples, sample_rate, options=DecoderOptions(rate=rate))
    except TimecodeError as exc:
        raise ClockError(f"{source}: {exc}") from None
    frames = result.frames
    ok = np.asarray(frames.valid, bool) & (np.asarray(frames.direction) > 0)
    if not ok.any():
        raise ClockError(f"{source}: no LTC found (is timecode recorded on this channel?)")
    return FrameStarts(count=np.asarray(frames.count)[ok], start_samples=np.asarray(frames.start_samples)[ok],
                       sample_rate=float(sample_rate), fps=rate.fps, frames_per_day=rate.frames_per_day,
                       source=source)


def decode_session(session: Session, progress: Callable[[str], None] | None = None
                   ) -> tuple[FrameStarts, FrameStarts, dict[str, FrameStarts | str]]:
    """Decode both LTC channels of ltc.wav and the HD LTC in each Kinect's audio.

    A Kinect without audio or without decodable LTC gets a one-line reason instead of frames.
    """
    step = progress or (lambda what: None)
    ltc = session.ltc
    out = []
    for key, ch, rate in (("vga", ltc.vga_channel, ltc.vga_rate), ("hd", ltc.hd_channel, ltc.hd_rate)):
        step(f"decoding {ltc.path.name} {key.upper()} channel")
        samples, fs = read_channel(ltc.path, ch, f"ltc.{key}_channel")
        out.append(decode_frame_starts(samples, fs, rate, f"{ltc.path.name} channel {ch} ({key.upper()} LTC)"))
    kinect: dict[str, FrameStarts | str] = {}
    for name, node in session.kinects.items():
        step(f"decoding {name} audio")
        if node.audio_path is None:
            kinect[name] = "no audio recorded (session.json: audio is null)"
            continue
        if not node.audio_path.is_file():
            kinect[name] = f"audio file {node.audio_path} not found"
            continue
        try:
            samples, fs = read_channel(node.audio_path, node.audio_channel, f"kinect.{name}.audio_channel")
            kinect[name] = decode_frame_starts(samples, fs, ltc.hd_rate, f"{name} audio (HD LTC)")
        except (ClockError, SessionError) as exc:
            kinect[name] = str(exc)
    return out[0], out[1], kinect


def sync_session(folder: str | Path, options: SyncOptions | None = None,
                 progress: Callable[[str], None] | None = None) -> SyncResult:
    """Load, decode and fit a session folder; returns tables and fits (nothing is written)."""
    session = load_session(folder)
    vga, hd, kinect = decode_session(session, progress)
    opts = options or SyncOptions()
    if opts.strict_kinect:
        for name, got in kinect.items():
            if isinstance(got, str):
                raise SyncError(f"{name}: {got}")
    return build_sync(session, vga, hd, kinect, opts)


def write_sync(result: SyncResult, bundle: str | Path, *, seq: str | None = None) -> list[Path]:
    """Write the sync tables and ``report/sync.json`` into a bundle folder; returns the files written.

    A bundle that already has a calibration keeps it (``load_bundle`` then ``write_bundle``; the tables take the
    bundle's seq). Otherwise only the sync files are written, named with ``seq`` (default: the session's).
    Every file is formatted before any is written, and each appears whole (atomic rename).
    """
    folder = Path(bundle)
    if folder.exists() and not folder.is_dir():
        raise SyncError(f"{folder}: output bundle is not a folder")
    report_text = json.dumps(sync_report(result), indent=1) + "\n"
    has_kinect = bool(result.tables.kinect_color or result.tables.kinect_depth)
    if folder.is_dir() and any(folder.glob("calibration_*.json")):
        b = load_bundle(folder)
        if seq is not None and seq != b.seq:
            raise SyncError(f"{folder}: holds calibration_{b.seq}.json; --seq {seq} differs (omit --seq to use "
                            f"{b.seq!r})")
        b.sync = result.tables
        write_bundle(b, folder)
        names = [f"synctables_{b.seq}.json"] + ([f"ksynctables_{b.seq}.json"] if has_kinect else [])
        seq = b.seq
    else:
        seq = seq or result.seq
        texts = {f"synctables_{seq}.json": format_synctables(result.tables.streams)}
        if has_kinect:
            texts[f"ksynctables_{seq}.json"] = format_ksynctables(result.tables.kinect_color, result.tables.kinect_depth)
        for name, text in texts.items():
            atomic_write_text(folder / name, text)
        names = list(texts)
    stale = folder / f"ksynctables_{seq}.json"
    if not has_kinect and stale.exists():  # an older run's Kinect tables would not match the new VGA/HD tables
        atomic_write_text(stale, format_ksynctables({}, {}))
        names.append(stale.name)
    atomic_write_text(folder / "report" / "sync.json", report_text)
    return [folder / n for n in names] + [folder / "report" / "sync.json"]
