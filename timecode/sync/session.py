"""The on-disk layout of a sync session, its typed form, a validating loader and a writer.

Layout (all paths relative to the session folder; documented in README.md, "Sync session layout")::

    SESSION/
      session.json
      ltc.wav                            stereo LTC: VGA clock (25 fps) and HD clock (29.97 fps) channels
      kinect/KINECTNODE<n>/audio.wav     Kinect microphone recording the HD LTC (16 kHz float)
      kinect/KINECTNODE<n>/timestamps.json  device timestamps of audio blocks, colour and depth frames

``session.json``::

    {"format": "dome-sync-session", "version": 1, "seq": "<name>",
     "ltc": {"file": "ltc.wav", "vga_channel": 0, "hd_channel": 1, "vga_rate": "25", "hd_rate": "29.97df"},
     "streams": {
       "vga": {"clock": "vga", "index": [0, 1, 2, ...], "ref_index": 0, "ref_timecode": "10:00:00:00"},
       "hd":  {"clock": "hd", "index": [...], "timecode": ["10:00:00;00", null, ...]}},
     "kinect": {"KINECTNODE1": {"audio": "kinect/KINECTNODE1/audio.wav", "audio_channel": 0,
                                "timestamps": "kinect/KINECTNODE1/timestamps.json"}}}

Frame index convention: a camera's frame index counts the frames of its clock, one per LTC frame, so frame
``k`` is exposed at the start of the LTC frame ``k - ref_index`` frames after the one labelled ``ref_timecode``
(counted in frames of the running clock, across timecode jumps). ``timecode`` (HD, optional) lists the timecode
embedded in each frame (null where absent); every non-null entry is a reference. ``audio: null`` (or a missing
file) marks a Kinect whose audio was not recorded: it is reported and left out of the tables.

``timestamps.json``: ``{"audio_blocks": {"first_sample": [...], "device_time_100ns": [...]},
"color": {"index": [...], "device_time_100ns": [...]}, "depth": {...}}``; device times are the Kinect's
``RelativeTime`` (100 ns units, integers), the audio block time refers to the block's first sample.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dome_calib.bundle import kinect_node_camera
from dome_calib.io_utils import atomic_write_text
from timecode.errors import TimecodeError
from timecode.labels import LabelError, label_to_frames
from timecode.rates import FrameRate, RateError, parse_rate

FORMAT = "dome-sync-session"
VERSION = 1


class SessionError(TimecodeError, ValueError):
    """A session folder is malformed: the message names the file and the field."""


@dataclass(kw_only=True)
class LtcRecording:
    """The stereo LTC recording of the two camera clocks."""

    path: Path
    vga_channel: int = 0
    hd_channel: int = 1
    vga_rate: FrameRate
    hd_rate: FrameRate


@dataclass(kw_only=True)
class FrameStream:
    """Captured frames of one camera stream on the VGA or HD clock, with its label reference(s)."""

    name: str
    clock: str  # "vga" | "hd"
    index: np.ndarray  # (F,) int64 increasing frame indices
    ref_index: np.ndarray  # (R,) int64 frame indices whose LTC label is known ...
    ref_count: np.ndarray  # (R,) int64 ... and those labels as frame counts since midnight


@dataclass(kw_only=True)
class DeviceFrames:
    """Frames timestamped on a Kinect's own clock."""

    index: np.ndarray  # (F,) int64
    device_time_100ns: np.ndarray  # (F,) int64


@dataclass(kw_only=True)
class KinectNode:
    """One Kinect v2: its microphone (recording the HD LTC) and device timestamps."""

    name: str
    audio_path: Path | None  # None: no audio recorded
    audio_channel: int = 0
    block_first_sample: np.ndarray  # (B,) int64 first sample of each audio block
    block_device_time_100ns: np.ndarray  # (B,) int64
    color: DeviceFrames
    depth: DeviceFrames


@dataclass(kw_only=True)
class Session:
    folder: Path
    seq: str
    ltc: LtcRecording
    streams: dict[str, FrameStream]
    kinects: dict[str, KinectNode] = field(default_factory=dict)


class _Where:
    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, fld: str, problem: str) -> SessionError:
        return SessionError(f"{self.path}: field '{fld}': {problem}")

    def get(self, obj: Any, fld: str, key: str, default: Any = ...) -> Any:
        if not isinstance(obj, dict):
            raise self.fail(fld, "expected an object")
        if key not in obj:
            if default is ...:
                raise self.fail(f"{fld}.{key}" if fld else key, "missing")
            return default
        return obj[key]

    def known(self, obj: Any, fld: str, keys: set[str]) -> None:
        """Unknown keys fail loudly (a typo would otherwise fall back to a default without a word)."""
        unknown = sorted(set(obj) - keys) if isinstance(obj, dict) else []
        if unknown:
            where = f"{fld}.{unknown[0]}" if fld else unknown[0]
            raise self.fail(where, f"unknown key (known here: {', '.join(sorted(keys))})")

    def ints(self, obj: Any, fld: str, key: str, *, increasing: bool) -> np.ndarray:
        raw = self.get(obj, fld, key)
        name = f"{fld}.{key}"
        try:
            a = np.asarray(raw, dtype=float)
        except (TypeError, ValueError):
            raise self.fail(name, "expected a list of integers") from None
        if a.ndim != 1 or not np.all(np.isfinite(a)) or np.any(a != np.round(a)):
            raise self.fail(name, "expected a list of integers")
        if a.size == 0:
            raise self.fail(name, "is empty")
        if increasing and np.any(np.diff(a) <= 0):
            raise self.fail(name, f"must increase (at position {int(np.argmax(np.diff(a) <= 0)) + 1})")
        return a.astype(np.int64)

    def rate(self, obj: Any, fld: str, key: str) -> FrameRate:
        try:
            return parse_rate(str(self.get(obj, fld, key)))
        except RateError as exc:
            raise self.fail(f"{fld}.{key}", str(exc)) from None

    def count(self, label: Any, rate: FrameRate, fld: str) -> int:
        if not isinstance(label, str):
            raise self.fail(fld, f"expected a timecode label HH:MM:SS:FF, got {label!r}")
        try:
            return label_to_frames(label, rate)
        except LabelError as exc:
            raise self.fail(fld, str(exc)) from None


def _load_json(path: Path) -> Any:
    if not path.is_file():
        raise SessionError(f"{path}: file not found")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SessionError(f"{path}: not valid JSON ({exc})") from None


def _read_stream(w: _Where, name: str, obj: Any, ltc: LtcRecording) -> FrameStream:
    fld = f"streams.{name}"
    w.known(obj, fld, {"clock", "index", "ref_index", "ref_timecode", "timecode"})
    clock = w.get(obj, fld, "clock")
    if clock not in ("vga", "hd"):
        raise w.fail(f"{fld}.clock", f"must be 'vga' or 'hd', got {clock!r}")
    rate = ltc.vga_rate if clock == "vga" else ltc.hd_rate
    index = w.ints(obj, fld, "index", increasing=True)
    ref_i: list[int] = []
    ref_c: list[int] = []
    tcs = w.get(obj, fld, "timecode", None)
    if tcs is not None:
        if not isinstance(tcs, list) or len(tcs) != index.size:
            raise w.fail(f"{fld}.timecode", f"expected a list of {index.size} labels or nulls (one per index)")
        for k, tc in enumerate(tcs):
            if tc is not None:
                ref_i.append(int(index[k]))
                ref_c.append(w.count(tc, rate, f"{fld}.timecode[{k}]"))
    if "ref_index" in obj or "ref_timecode" in obj:
        ri = w.get(obj, fld, "ref_index")
        if not isinstance(ri, int) or isinstance(ri, bool):
            raise w.fail(f"{fld}.ref_index", f"expected an integer frame index, got {ri!r}")
        ref_i.append(ri)
        ref_c.append(w.count(w.get(obj, fld, "ref_timecode"), rate, f"{fld}.ref_timecode"))
    if not ref_i:
        raise w.fail(fld, "needs 'ref_index' + 'ref_timecode' or embedded 'timecode' labels to tie frames to LTC")
    return FrameStream(name=name, clock=clock, index=index, ref_index=np.asarray(ref_i, np.int64),
                       ref_count=np.asarray(ref_c, np.int64))


def _read_kinect(w: _Where, folder: Path, name: str, obj: Any) -> KinectNode:
    fld = f"kinect.{name}"
    w.known(obj, fld, {"audio", "audio_channel", "timestamps"})
    audio = w.get(obj, fld, "audio", None)
    audio_path = None if audio is None else folder / str(audio)
    ts_path = folder / str(w.get(obj, fld, "timestamps"))
    ts = _load_json(ts_path)
    wt = _Where(ts_path)
    wt.known(ts, "", {"audio_blocks", "color", "depth"})
    blocks = wt.get(ts, "", "audio_blocks", {"first_sample": [0], "device_time_100ns": [0]} if audio is None else ...)
    frames = {}
    for kind in ("color", "depth"):
        o = wt.get(ts, "", kind)
        wt.known(o, kind, {"index", "device_time_100ns"})
        frames[kind] = DeviceFrames(index=wt.ints(o, kind, "index", increasing=True),
                                    device_time_100ns=wt.ints(o, kind, "device_time_100ns", increasing=False))
        if frames[kind].index.size != frames[kind].device_time_100ns.size:
            raise wt.fail(f"{kind}.device_time_100ns", "must have one entry per index")
    wt.known(blocks, "audio_blocks", {"first_sample", "device_time_100ns"})
    first = wt.ints(blocks, "audio_blocks", "first_sample", increasing=True)
    dev = wt.ints(blocks, "audio_blocks", "device_time_100ns", increasing=False)
    if first.size != dev.size:
        raise wt.fail("audio_blocks.device_time_100ns", "must have one entry per first_sample")
    channel = w.get(obj, fld, "audio_channel", 0)
    if not isinstance(channel, int) or channel < 0:
        raise w.fail(f"{fld}.audio_channel", f"expected a channel number >= 0, got {channel!r}")
    return KinectNode(name=name, audio_path=audio_path, audio_channel=channel, block_first_sample=first,
                      block_device_time_100ns=dev, color=frames["color"], depth=frames["depth"])


def load_session(folder: str | Path) -> Session:
    """Read and validate ``folder/session.json`` and the Kinect timestamp files it names.

    Raises :class:`SessionError` (one line naming file and field). Audio files are not read here.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise SessionError(f"{folder}: not a session folder")
    path = folder / "session.json"
    data = _load_json(path)
    w = _Where(path)
    w.known(data, "", {"format", "version", "seq", "ltc", "streams", "kinect"})
    if w.get(data, "", "format") != FORMAT:
        raise w.fail("format", f"expected {FORMAT!r}")
    if w.get(data, "", "version") != VERSION:
        raise w.fail("version", f"this toolkit reads version {VERSION}")
    seq = w.get(data, "", "seq")
    if not isinstance(seq, str) or not seq or "/" in seq:
        raise w.fail("seq", "expected a non-empty name without '/'")
    lo = w.get(data, "", "ltc")
    w.known(lo, "ltc", {"file", "vga_channel", "hd_channel", "vga_rate", "hd_rate"})
    channels = {}
    for key, default in (("vga_channel", 0), ("hd_channel", 1)):
        ch = w.get(lo, "ltc", key, default)
        if not isinstance(ch, int) or ch < 0:
            raise w.fail(f"ltc.{key}", f"expected a channel number >= 0, got {ch!r}")
        channels[key] = ch
    ltc = LtcRecording(path=folder / str(w.get(lo, "ltc", "file")), vga_rate=w.rate(lo, "ltc", "vga_rate"),
                       hd_rate=w.rate(lo, "ltc", "hd_rate"), **channels)
    streams_obj = w.get(data, "", "streams")
    if not isinstance(streams_obj, dict) or not streams_obj:
        raise w.fail("streams", "expected an object with at least one stream")
    streams = {n: _read_stream(w, n, o, ltc) for n, o in streams_obj.items()}
    kin_obj = w.get(data, "", "kinect", {})
    if not isinstance(kin_obj, dict):
        raise w.fail("kinect", "expected an object keyed by KINECTNODE<n>")
    for n in kin_obj:
        if kinect_node_camera(n) is None:  # a typo would sync no sensor, or write tables no reader accepts
            raise w.fail(f"kinect.{n}", "not a Kinect node name (KINECTNODE1..KINECTNODE10, as the kinect/ folders "
                                        "and the colour cameras 50_01..50_10 are numbered)")
    kinects = {n: _read_kinect(w, folder, n, o) for n, o in kin_obj.items()}
    return Session(folder=folder, seq=seq, ltc=ltc, streams=streams, kinects=kinects)


def write_session_json(folder: Path, doc: dict, kinect_timestamps: dict[str, dict]) -> None:
    """Write ``session.json`` and each Kinect's ``timestamps.json`` (atomically), from plain JSON objects."""
    for name, ts in kinect_timestamps.items():
        atomic_write_text(folder / doc["kinect"][name]["timestamps"], json.dumps(ts, separators=(",", ":")))
    atomic_write_text(folder / "session.json", json.dumps(doc, indent=1))
