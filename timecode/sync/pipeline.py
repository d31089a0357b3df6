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


def _check_channel(path: Path, channel: int, field: str) -> None:
    """SessionError naming file and field when the audio file is missing, unreadable or lacks the channel."""
    if not path.is_file():
        raise SessionError(f"{path}: audio file not found ({field})")
    try:
        n = sf.info(str(path)).channels
    except (sf.LibsndfileError, RuntimeError) as exc:
        raise SessionError(f"{path}: cannot read audio ({exc})") from None
    if channel >= n:
        raise SessionError(f"{path}: {field} = {channel} but the file has {n} channel(s)")


def decode_frame_starts(path: Path, channel: int, rate: FrameRate, source: str) -> FrameStarts:
    """Decode the LTC of one channel of an audio file at a known frame rate (forward frames only).

    Raises ClockError naming ``source`` when no LTC is found.
    """
    from timecode.decoder import DecodeOptions, decode_file  # the LTC decoder (issue 4)

    try:
        (ch,) = decode_file(path, options=DecodeOptions(rate=rate), channels=[channel])
    except TimecodeError as exc:
        raise ClockError(f"{source}: {exc}") from None
    ok = ~np.asarray(ch.reverse, bool)
    if not ok.any():
        raise ClockError(f"{source}: no LTC found (is timecode recorded on this channel?)")
    return FrameStarts(count=np.asarray(ch.frame_numbers, np.int64)[ok],
                       start_samples=np.asarray(ch.start_samples, float)[ok], sample_rate=float(ch.sample_rate),
                       fps=rate.fps, frames_per_day=rate.frames_per_day, source=source)


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
        _check_channel(ltc.path, ch, f"ltc.{key}_channel")
        out.append(decode_frame_starts(ltc.path, ch, rate, f"{ltc.path.name} channel {ch} ({key.upper()} LTC)"))
    kinect: dict[str, FrameStarts | str] = {}
    for name, node in session.kinects.items():
        step(f"decoding {name} audio")
        if node.audio_path is None:
            kinect[name] = "no audio recorded (session.json: audio is null)"
            continue
        try:
            _check_channel(node.audio_path, node.audio_channel, f"kinect.{name}.audio_channel")
            kinect[name] = decode_frame_starts(node.audio_path, node.audio_channel, ltc.hd_rate,
                                               f"{name} audio (HD LTC)")
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


def output_seq(bundle: str | Path, seq: str | None, session_seq: str) -> str:
    """The seq the sync files will carry in ``bundle``; SyncError if ``seq`` contradicts the bundle's calibration."""
    folder = Path(bundle)
    if folder.exists() and not folder.is_dir():
        raise SyncError(f"{folder}: output bundle is not a folder")
    found = sorted(folder.glob("calibration_*.json")) if folder.is_dir() else []
    if not found:
        return seq or session_seq
    bundle_seq = found[0].stem.removeprefix("calibration_")
    if seq is not None and seq != bundle_seq:
        raise SyncError(f"{folder}: holds {found[0].name}; --seq {seq} differs (omit --seq to use {bundle_seq!r})")
    return bundle_seq


def write_sync(result: SyncResult, bundle: str | Path, *, seq: str | None = None) -> list[Path]:
    """Write the sync tables and ``report/sync.json`` into a bundle folder; returns the files written.

    A bundle that already has a calibration keeps it (``load_bundle`` then ``write_bundle``; the tables take the
    bundle's seq). Otherwise only the sync files are written, named with ``seq`` (default: the session's).
    Every file is formatted before any is written, and each appears whole (atomic rename).
    """
    folder = Path(bundle)
    seq = output_seq(folder, seq, result.seq)
    report_text = json.dumps(sync_report(result), indent=1) + "\n"
    has_kinect = bool(result.tables.kinect_color or result.tables.kinect_depth)
    if folder.is_dir() and any(folder.glob("calibration_*.json")):
        b = load_bundle(folder)
        b.sync = result.tables
        write_bundle(b, folder)
        names = [f"synctables_{b.seq}.json"] + ([f"ksynctables_{b.seq}.json"] if has_kinect else [])
    else:
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
