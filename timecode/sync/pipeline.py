"""Decode a session's audio, fit its clocks and write the sync tables: the I/O edge behind ``timecode sync``."""
from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import numpy as np
import soundfile as sf

from dome_calib.bundle import kinect_node_camera
from dome_calib.bundle_io import bundle_seq, load_bundle, update_bundle
from dome_calib.ownership import claim_file, claim_into, write_text
from dome_calib.panoptic_io import format_ksynctables, format_synctables
from dome_calib.report.kept import SYNC_FILE, kept_text
from timecode.errors import TimecodeError
from timecode.rates import FrameRate
from timecode.audio_io import AudioReader
from timecode.decode.decoder import MAX_RATE, MIN_RATE, DecodeOptions, decode_file, decode_samples
from timecode.sync.clock import ClockError, FrameStarts
from timecode.sync.report import sync_report
from timecode.sync.session import SESSION_FILE, Session, SessionError, load_session
from timecode.sync.tables import SyncError, SyncOptions, SyncResult, build_sync

logger = logging.getLogger(__name__)


def audio_problem(path: Path, channel: int) -> tuple[str, str] | None:
    """What keeps ``channel`` of the audio file ``path`` from being decoded, from its header (and its last sample,
    so a half-copied file is found too): ("file", why) or ("channel", why); None when nothing does. Milliseconds,
    whatever the file's length."""
    if not path.is_file():
        return "file", f"{path}: audio file not found"
    try:
        with AudioReader(path) as reader:
            info = reader.info
    except TimecodeError as exc:
        why = str(exc).removeprefix(f"{path}: ").splitlines()[0].split("; for headerless files")[0]
        return "file", f"{path}: {why}"
    if channel >= info.channels:
        return "channel", f"{channel}, but {path} has {info.channels} channel(s) (numbered from 0)"
    if not MIN_RATE <= info.sample_rate <= MAX_RATE:
        return "file", (f"{path}: sample rate {info.sample_rate} Hz, outside the {MIN_RATE}-{MAX_RATE} Hz the LTC "
                        "decoder reads")
    return None


def _where(problem: tuple[str, str], sess_file: Path, field: str, file_field: str) -> str:
    """A problem of the audio file names that file first; a channel it lacks names session.json's field."""
    kind, why = problem
    return f"{sess_file}: {field}: {why}" if kind == "channel" else f"{why} ({sess_file}: {file_field})"


def check_session_audio(session: Session, *, kinect_required: bool = False) -> dict[str, str]:
    """Before any decoding, in seconds: the header of every audio file the session names. The LTC file must hold
    both channels at a rate the decoder reads, else SessionError naming ``session.json``'s field. A Kinect's audio
    problem is an error too when ``kinect_required``; else it is returned (node -> reason: the Kinect is reported
    NOT SYNCED and the other streams go on)."""
    sess_file = session.folder / SESSION_FILE
    ltc = session.ltc
    for key, channel in (("vga", ltc.vga_channel), ("hd", ltc.hd_channel)):
        if problem := audio_problem(ltc.path, channel):
            raise SessionError(_where(problem, sess_file, f"ltc.{key}_channel", "ltc.file"))
    skipped: dict[str, str] = {}
    for name, node in session.kinects.items():
        if node.audio_path is None:
            continue
        if problem := audio_problem(node.audio_path, node.audio_channel):
            line = _where(problem, sess_file, f"kinect.{name}.audio_channel", f"kinect.{name}.audio")
            if kinect_required:
                raise SessionError(line)
            skipped[name] = line
    return skipped


def _decode(path: Path, channel: int, rate: FrameRate, source: str, start: int = 0, stop: int | None = None
            ) -> tuple[np.ndarray, np.ndarray, int]:
    """Forward frames (counts, start samples in the file) of ``path[start:stop]``, and the file's sample rate."""
    opts = DecodeOptions(rate=rate)
    try:
        if start == 0 and stop is None:
            (ch,) = decode_file(path, options=opts, channels=[channel])
        else:
            with AudioReader(path) as reader:  # a damaged or cut-short file: one line naming it
                data, fs = reader.read(start, reader.info.frames if stop is None else stop), reader.info.sample_rate
            (ch,) = decode_samples(data[:, channel], fs, options=opts)
    except TimecodeError as exc:
        raise ClockError(f"{source}: {exc}") from None
    fwd = ~np.asarray(ch.reverse, bool)
    return (np.asarray(ch.frame_numbers, np.int64)[fwd], np.asarray(ch.start_samples, float)[fwd] + start,
            int(ch.sample_rate))


def decode_frame_starts(path: Path, channel: int, rate: FrameRate, source: str, *, max_gap_s: float = 1.0,
                        passes: int = 3) -> FrameStarts:
    """Decode the LTC of one channel of an audio file at a known frame rate (forward frames only).

    Stretches longer than ``max_gap_s`` without a decoded frame are decoded again on their own (up to
    ``passes`` rounds): a decoder may give up on one side of a splice (a recording restart), and the clock fit
    needs both. Raises ClockError naming ``source`` when no LTC is found.
    """
    count, starts, fs = _decode(path, channel, rate, source)
    n_samples = sf.info(str(path)).frames
    period = fs / float(rate.fps)
    for _ in range(passes):
        bounds = np.concatenate([[-period], starts, [n_samples]])
        gaps = np.flatnonzero(np.diff(bounds) > max_gap_s * fs)
        found = []
        for g in gaps:
            a, b = max(0, int(bounds[g] + 1.2 * period)), min(n_samples, int(bounds[g + 1] - 0.2 * period))
            if b - a > 3 * period:
                c, s, _ = _decode(path, channel, rate, source, a, b)
                found.append((c, s))
        if not found or not sum(c.size for c, _ in found):
            break
        logger.debug("%s: %d frames recovered from stretches the first decode skipped", source,
                     sum(c.size for c, _ in found))
        count = np.concatenate([count, *(c for c, _ in found)])
        starts = np.concatenate([starts, *(s for _, s in found)])
        order = np.argsort(starts, kind="stable")
        count, starts = count[order], starts[order]
    if count.size == 0:
        raise ClockError(f"{source}: no LTC found (is timecode recorded on this channel?)")
    return FrameStarts(count=count, start_samples=starts, sample_rate=float(fs), fps=rate.fps,
                       frames_per_day=rate.frames_per_day, source=source)


def decode_session(session: Session, progress: Callable[[str], None] | None = None
                   ) -> tuple[FrameStarts, FrameStarts, dict[str, FrameStarts | str]]:
    """Decode both LTC channels of ltc.wav and the HD LTC in each Kinect's audio.

    A Kinect without audio or without decodable LTC gets a one-line reason instead of frames. The audio headers
    are checked first (:func:`check_session_audio`): nothing is decoded when the LTC file cannot be.
    """
    step = progress or (lambda what: None)
    ltc = session.ltc
    skipped = check_session_audio(session)
    out = []
    for key, ch, rate in (("vga", ltc.vga_channel, ltc.vga_rate), ("hd", ltc.hd_channel, ltc.hd_rate)):
        step(f"decoding {ltc.path.name} {key.upper()} channel")
        out.append(decode_frame_starts(ltc.path, ch, rate, f"{ltc.path.name} channel {ch} ({key.upper()} LTC)"))
    kinect: dict[str, FrameStarts | str] = {}
    for name, node in session.kinects.items():
        step(f"decoding {name} audio")
        if node.audio_path is None:
            kinect[name] = "no audio recorded (session.json: audio is null)"
        elif name in skipped:
            kinect[name] = skipped[name]
        else:
            try:
                kinect[name] = decode_frame_starts(node.audio_path, node.audio_channel, ltc.hd_rate,
                                                   f"{name} audio (HD LTC)")
            except ClockError as exc:
                kinect[name] = str(exc)
    return out[0], out[1], kinect


def sync_session(folder: str | Path | Session, options: SyncOptions | None = None,
                 progress: Callable[[str], None] | None = None) -> SyncResult:
    """Load (unless given a loaded Session), decode and fit a session; returns tables and fits, writes nothing."""
    session = folder if isinstance(folder, Session) else load_session(folder)
    opts = options or SyncOptions()
    check_session_audio(session, kinect_required=opts.strict_kinect)
    vga, hd, kinect = decode_session(session, progress)
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
    if seq is not None and (not seq or "/" in seq or seq.startswith(".")):
        raise SyncError(f"--seq {seq!r}: expected a plain name (no '/', not starting with '.')")
    held = bundle_seq(folder)
    if held is None:
        return seq or session_seq
    if seq is not None and seq != held:
        raise SyncError(f"{folder}: holds calibration_{held}.json; --seq {seq} differs (omit --seq to use {held!r})")
    return held


def check_nodes_in_bundle(bundle: str | Path, session: Session) -> None:
    """Before decoding: when ``bundle`` holds a calibration, every Kinect node of the session must be a Kinect of it
    (its colour camera 50_<nn>, and a sensor of its kcalibration when it has one); SyncError naming the node."""
    folder = Path(bundle)
    if bundle_seq(folder) is None:
        return
    b = load_bundle(folder)
    cameras = sorted(n for n in b.cameras if n.startswith("50_"))
    for node in sorted(session.kinects):
        camera = kinect_node_camera(node)
        if camera not in b.cameras:
            raise SyncError(f"{session.folder / 'session.json'}: kinect.{node}: the bundle {folder} has no "
                            f"colour camera {camera} (its Kinect cameras: {', '.join(cameras) or 'none'})")
        if b.kinect is not None and node not in b.kinect.sensors:
            raise SyncError(f"{session.folder / 'session.json'}: kinect.{node}: not a sensor of the bundle's "
                            f"kcalibration (it has {', '.join(b.kinect.sensors) or 'none'})")


def sync_outputs(bundle: str | Path, seq: str) -> list[Path]:
    """The files :func:`write_sync` may write into ``bundle`` for ``seq``."""
    folder = Path(bundle)
    return [folder / f"synctables_{seq}.json", folder / f"ksynctables_{seq}.json", folder / "report" / SYNC_FILE]


def check_sync_output(bundle: str | Path, seq: str, inputs: list[Path]) -> None:
    """Before any work: the bundle folder is a real folder (not an input, nor holding one) and every file the sync
    writes there is new, or dome-calib's and unchanged (:mod:`dome_calib.ownership`)."""
    claim_into(bundle, inputs=inputs)
    for path in sync_outputs(bundle, seq):
        claim_file(path)


def write_sync(result: SyncResult, bundle: str | Path, *, seq: str | None = None) -> list[Path]:
    """Write the sync tables and ``report/sync.json`` into a bundle folder; returns the files written.

    A bundle that already has a calibration keeps it (``load_bundle`` then ``write_bundle``; the tables take the
    bundle's seq). Otherwise only the sync files are written, named with ``seq`` (default: the session's).
    Every file is formatted before any is written, and each appears whole (atomic rename).
    """
    folder = Path(bundle)
    seq = output_seq(folder, seq, result.seq)
    report_text = kept_text(SYNC_FILE, sync_report(result))  # through the schema the report's page reads it with
    has_kinect = bool(result.tables.kinect_color or result.tables.kinect_depth)
    if bundle_seq(folder) is not None:
        b = load_bundle(folder)
        b.sync = result.tables
        update_bundle(b, folder, ("synctables", "ksynctables"))
        names = [f"synctables_{b.seq}.json"] + ([f"ksynctables_{b.seq}.json"] if has_kinect else [])
    else:
        texts = {f"synctables_{seq}.json": format_synctables(result.tables.streams)}
        if has_kinect:
            texts[f"ksynctables_{seq}.json"] = format_ksynctables(result.tables.kinect_color,
                                                                  result.tables.kinect_depth)
        for name, text in texts.items():
            write_text(folder / name, text)
        names = list(texts)
    stale = folder / f"ksynctables_{seq}.json"
    if not has_kinect and stale.exists():  # an older run's Kinect tables would not match the new VGA/HD tables
        write_text(stale, format_ksynctables({}, {}))
        names.append(stale.name)
    write_text(folder / "report" / SYNC_FILE, report_text)
    return [folder / n for n in names] + [folder / "report" / "sync.json"]
