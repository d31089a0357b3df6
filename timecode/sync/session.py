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
from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, model_validator

from dome_calib.bundle import kinect_node_camera
from dome_calib.io_utils import atomic_write_text
from dome_calib.schema import Field, FieldError, FileSchema, NonNegInt, PlainName, read_json, show, words
from timecode.errors import TimecodeError
from timecode.labels import LabelError, label_to_frames
from timecode.rates import RATES, FrameRate, parse_rate

FORMAT = "dome-sync-session"
VERSION = 1
SESSION_FILE = "session.json"


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


# ---- the schemas of session.json and timestamps.json --------------------------------------------------------------

def _rate(text: str) -> str:
    parse_rate(text)  # RateError (a ValueError): one line naming the field
    return text


def _kinect_node(name: str) -> str:
    if kinect_node_camera(name) is None:  # a typo would sync no sensor, or write tables no reader accepts
        raise ValueError(f"{show(name)} is not a Kinect node name (KINECTNODE1..KINECTNODE10, as the kinect/ folders "
                         "and the colour cameras 50_01..50_10 are numbered)")
    return name


def _increasing(values: list[int]) -> list[int]:
    for k in range(1, len(values)):
        if values[k] <= values[k - 1]:
            raise FieldError((k,), f"must increase ({values[k]} after {values[k - 1]})")
    return values


RateText = Annotated[str, AfterValidator(_rate),
                     Field(**words(f"a frame rate: {' or '.join(json.dumps(r) for r in RATES)}"))]
Path_ = Annotated[str, Field(min_length=1, **words("a path, relative to the session folder"))]
Label = Annotated[str, Field(min_length=1, **words("a timecode label HH:MM:SS:FF (HH:MM:SS;FF drop frame)"))]
KinectNodeName = Annotated[str, AfterValidator(_kinect_node), Field(**words("KINECTNODE1..KINECTNODE10"))]
Frames = Annotated[list[NonNegInt], Field(min_length=1), AfterValidator(_increasing),
                   Field(**words("a non-empty list of increasing frame indices (integers >= 0)"))]
Int64 = Annotated[int, Field(ge=-2**63, le=2**63 - 1, **words("a 64-bit integer"))]


class LtcSection(FileSchema):
    """The stereo LTC recording: which channel carries which clock, at which rate."""

    file: Path_
    vga_channel: NonNegInt = Field(0, description="0 = the first (left) channel")
    hd_channel: NonNegInt = 1
    vga_rate: RateText
    hd_rate: RateText

    @model_validator(mode="after")
    def _two_channels(self) -> LtcSection:
        if self.vga_channel == self.hd_channel:
            raise FieldError(("hd_channel",), f"the same channel as vga_channel ({self.vga_channel}): the two clocks "
                                              "are recorded on two channels")
        return self


class StreamSection(FileSchema):
    """One camera stream: its frames and how they tie to the LTC (a reference frame, or labels per frame)."""

    clock: Literal["vga", "hd"]
    index: Frames
    ref_index: Int64 | None = Field(None, description="a frame index whose LTC label is ref_timecode")
    ref_timecode: Label | None = None
    timecode: list[Label | None] | None = Field(None, description="the label embedded in each frame (null: none)")

    @model_validator(mode="after")
    def _tied_to_ltc(self) -> StreamSection:
        if (self.ref_index is None) != (self.ref_timecode is None):
            missing = "ref_timecode" if self.ref_timecode is None else "ref_index"
            raise FieldError((missing,), "missing (ref_index and ref_timecode come together)")
        if self.timecode is not None and len(self.timecode) != len(self.index):
            raise FieldError(("timecode",), f"{len(self.timecode)} labels for {len(self.index)} frames (expected one "
                                            "label or null per index)")
        if self.ref_index is None and not any(tc is not None for tc in self.timecode or []):
            raise ValueError("needs 'ref_index' + 'ref_timecode' or embedded 'timecode' labels to tie frames to LTC")
        return self


class KinectSection(FileSchema):
    """One Kinect: its microphone recording of the HD LTC and its device timestamps."""

    audio: Path_ | None = Field(None, description="null: no audio recorded (the Kinect is reported, not synced)")
    audio_channel: NonNegInt = 0
    timestamps: Path_ = Field(description="its timestamps.json")


class SessionFile(FileSchema):
    """``session.json`` of a sync session (see the module docstring)."""

    format: Literal["dome-sync-session"] = Field(**words('"dome-sync-session"'))
    version: Literal[1] = Field(**words("1 (the version this toolkit reads)"))
    seq: PlainName
    ltc: LtcSection
    streams: dict[Annotated[str, Field(min_length=1)], StreamSection] = Field(min_length=1)
    kinect: dict[KinectNodeName, KinectSection] = {}

    @model_validator(mode="after")
    def _labels_exist_at_their_rate(self) -> SessionFile:
        for name, stream in self.streams.items():
            rate = parse_rate(self.ltc.vga_rate if stream.clock == "vga" else self.ltc.hd_rate)
            labels = [(("ref_timecode",), stream.ref_timecode)] + [
                (("timecode", k), tc) for k, tc in enumerate(stream.timecode or [])]
            for where, label in labels:
                if label is not None:
                    try:
                        label_to_frames(label, rate)
                    except LabelError as exc:
                        raise FieldError(("streams", name, *where), str(exc)) from None
        return self


class DeviceStamps(FileSchema):
    """Frames (or audio blocks) timestamped on the Kinect's own clock (``RelativeTime``, 100 ns units)."""

    index: Frames
    device_time_100ns: list[Int64]

    @model_validator(mode="after")
    def _one_per_index(self) -> DeviceStamps:
        if len(self.device_time_100ns) != len(self.index):
            raise FieldError(("device_time_100ns",), f"{len(self.device_time_100ns)} times for {len(self.index)} "
                                                     "indices (expected one per index)")
        return self


class AudioBlocks(FileSchema):
    first_sample: Frames = Field(description="first sample of each audio block")
    device_time_100ns: list[Int64]

    @model_validator(mode="after")
    def _one_per_block(self) -> AudioBlocks:
        if len(self.device_time_100ns) != len(self.first_sample):
            raise FieldError(("device_time_100ns",), f"{len(self.device_time_100ns)} times for "
                                                     f"{len(self.first_sample)} blocks (expected one per first_sample)")
        return self


class TimestampsFile(FileSchema):
    """A Kinect's ``timestamps.json``: device times of its audio blocks, colour and depth frames."""

    audio_blocks: AudioBlocks | None = Field(None, description="required when the Kinect has audio")
    color: DeviceStamps
    depth: DeviceStamps


# ---- the loader -----------------------------------------------------------------------------------------------------

def _ints(values: list[int]) -> np.ndarray:
    return np.asarray(values, dtype=np.int64)


def _stream(name: str, s: StreamSection, ltc: LtcRecording) -> FrameStream:
    rate = ltc.vga_rate if s.clock == "vga" else ltc.hd_rate
    refs = [(i, tc) for i, tc in zip(s.index, s.timecode or []) if tc is not None]
    if s.ref_index is not None:
        refs.append((s.ref_index, s.ref_timecode))
    return FrameStream(name=name, clock=s.clock, index=_ints(s.index), ref_index=_ints([i for i, _ in refs]),
                       ref_count=_ints([label_to_frames(tc, rate) for _, tc in refs]))


def _kinect(folder: Path, path: Path, name: str, k: KinectSection) -> KinectNode:
    ts_path = folder / k.timestamps
    if not ts_path.is_file():
        raise SessionError(f"{path}: kinect.{name}.timestamps: {ts_path}: file not found")
    ts = read_json(ts_path, TimestampsFile, error=SessionError)
    if ts.audio_blocks is None and k.audio is not None:
        raise SessionError(f"{ts_path}: audio_blocks: missing (the Kinect has audio: {path} kinect.{name}.audio)")
    blocks = ts.audio_blocks or AudioBlocks(first_sample=[0], device_time_100ns=[0])
    return KinectNode(name=name, audio_path=None if k.audio is None else folder / k.audio,
                      audio_channel=k.audio_channel, block_first_sample=_ints(blocks.first_sample),
                      block_device_time_100ns=_ints(blocks.device_time_100ns),
                      color=_device_frames(ts.color), depth=_device_frames(ts.depth))


def _device_frames(stamps: DeviceStamps) -> DeviceFrames:
    return DeviceFrames(index=_ints(stamps.index), device_time_100ns=_ints(stamps.device_time_100ns))


def load_session(folder: str | Path) -> Session:
    """Read and validate ``folder/session.json`` and the Kinect timestamp files it names.

    Raises :class:`SessionError` (one line naming file and field path). Audio files are not read here
    (:func:`timecode.sync.pipeline.check_session_audio` opens their headers).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise SessionError(f"{folder}: not a session folder")
    path = folder / SESSION_FILE
    doc = read_json(path, SessionFile, error=SessionError)
    lo = doc.ltc
    ltc = LtcRecording(path=folder / lo.file, vga_channel=lo.vga_channel, hd_channel=lo.hd_channel,
                       vga_rate=parse_rate(lo.vga_rate), hd_rate=parse_rate(lo.hd_rate))
    return Session(folder=folder, seq=doc.seq, ltc=ltc, streams={n: _stream(n, s, ltc) for n, s in doc.streams.items()},
                   kinects={n: _kinect(folder, path, n, k) for n, k in doc.kinect.items()})


def write_session_json(folder: Path, doc: dict, kinect_timestamps: dict[str, dict]) -> None:
    """Write ``session.json`` and each Kinect's ``timestamps.json`` (atomically), from plain JSON objects."""
    for name, ts in kinect_timestamps.items():
        atomic_write_text(folder / doc["kinect"][name]["timestamps"], json.dumps(ts, separators=(",", ":")))
    atomic_write_text(folder / "session.json", json.dumps(doc, indent=1))
