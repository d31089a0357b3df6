"""The files other commands keep in a bundle's ``report/``, declared once: ``sync.json`` (`timecode sync`,
:class:`SyncReport`) and ``session.json`` (`dome-calib session`, :class:`SessionReport`).

Their writers build them as plain data and write them through these schemas (:func:`write_kept`), and the page
and `dome-calib report` read them through the same schemas (:func:`read_kept`): a number of the file is a number
(``"n_frames": "<img src=x onerror=...>"`` is refused in one line naming the file and the field, it never reaches
the page), a field the writer does not know is refused. A statistic that could not be computed (a fit of too few
points) is written as null, never NaN.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field

from dome_calib.errors import ReportError
from dome_calib.io_utils import atomic_write_text
from dome_calib.report.schema import checked
from dome_calib.schema import FileSchema, Finite, NonNegFinite, NonNegInt, PosFinite, parse_json

SYNC_FILE = "sync.json"
SESSION_FILE = "session.json"
#: The kept files, in the order a rewritten report carries them.
KEPT_FILES = (SESSION_FILE, SYNC_FILE)

Text = str
Name = Annotated[str, Field(min_length=1)]
#: A statistic of a fit: null where it could not be computed.
Stat = Finite | None


# ---- sync.json (timecode.sync.report.sync_report) ----------------------------------------------------------------

class FitSegment(FileSchema):
    """One stretch of continuous audio of an LTC channel and its frame-start fit."""

    tick_first: int
    tick_last: int
    sample_first: Finite
    sample_last: Finite
    samples_per_frame: Stat
    drift_ppm_vs_audio: Stat
    n_frames: NonNegInt
    n_outliers: NonNegInt
    residual_rms_us: Stat
    residual_max_us: Stat


class ClockEvent(FileSchema):
    """A timecode jump, a restart of the recording or midnight, at a tick and an audio sample."""

    kind: Literal["jump", "restart", "midnight"]
    tick: int
    sample: Finite
    sample_before: Finite | None = None
    from_count: int | None = None
    to_count: int | None = None
    gap_samples: Finite | None = None
    label_gap_frames: int | None = None
    doubtful: bool | None = None


class LabelSegment(FileSchema):
    count_first: int
    tick_first: int
    tick_last: int


class ChannelFit(FileSchema):
    """One LTC channel: frames decoded and dropped, drift against its audio clock, fits per segment."""

    source: Text
    fps: Text
    sample_rate: PosFinite
    n_decoded: NonNegInt
    n_misread: NonNegInt
    n_outliers: NonNegInt
    drift_ppm_vs_audio: Stat
    residual_rms_us: Stat
    events: list[ClockEvent]
    label_segments: list[LabelSegment]
    segments: list[FitSegment]


class VgaOnUniversalTime(FileSchema):
    vga_tick_first: int
    vga_tick_last: int
    offset_ms: Finite
    period_ms: PosFinite
    drift_ppm: Finite


class DeviceClock(FileSchema):
    """A Kinect's device clock against universal time over one segment of its audio blocks."""

    device_time_first_100ns: int
    device_time_last_100ns: int
    univ_ms_at_ref: Finite
    device_time_ref_100ns: Finite
    ms_per_100ns: Finite
    drift_ppm: Stat
    n_blocks: NonNegInt
    n_outliers: NonNegInt
    residual_rms_us: Stat
    residual_max_us: Stat


class KinectSynced(FileSchema):
    status: Literal["synced"]
    audio: ChannelFit
    hd_tick_offset: int
    device_clock: list[DeviceClock]


class KinectNotSynced(FileSchema):
    status: Literal["not synced"]
    reason: Text


class StreamFit(FileSchema):
    """One output stream on universal time: frames, span (ms), drift, fit residual, outliers."""

    n_frames: NonNegInt
    first_ms: Finite
    last_ms: Finite
    drift_ppm: Stat
    residual_rms_us: Stat
    n_outliers: NonNegInt


class Channels(FileSchema):
    vga: ChannelFit
    hd: ChannelFit


class SyncReport(FileSchema):
    """``report/sync.json``: everything about the clock fits of `timecode sync`."""

    seq: Text
    universal_time: Text
    drift_convention: Text
    channels: Channels
    vga_on_universal_time: list[VgaOnUniversalTime]
    kinect: dict[Name, Annotated[KinectSynced | KinectNotSynced, Field(discriminator="status")]]
    streams: dict[Name, StreamFit]
    notes: list[Text]


# ---- session.json (dome_calib.pipeline.session) ------------------------------------------------------------------

class SensorSummary(FileSchema):
    """One Kinect's depth-to-colour calibration (:meth:`dome_calib.kinect.calibrate.SensorCalibration.summary`)."""

    sensor: Name
    color_camera: Name
    frames_used: NonNegInt
    frames_rejected: NonNegInt
    rejected: dict[Name, Text]  # frame index -> why
    rms_ir_px: NonNegFinite
    rms_color_px: NonNegFinite
    baseline_mm: NonNegFinite
    ir_focal_px: PosFinite
    depth_bias_mm: Finite | None
    depth_scale: Finite | None


class CalibrationPillar(FileSchema):
    achieved: Text
    cameras: NonNegInt
    expected: NonNegInt
    rms_px: NonNegFinite | None  # null: every camera held
    to_check: list[Text]


class KinectPillar(FileSchema):
    achieved: Text
    sensors: list[SensorSummary]
    to_check: list[Text]


class SyncStreamRow(FileSchema):
    stream: Name
    frames: NonNegInt
    drift_ppm: Stat
    residual_rms_us: Stat


class SyncPillar(FileSchema):
    achieved: Text
    streams: list[SyncStreamRow]
    notes: list[Text]
    to_check: list[Text]


class Pillars(FileSchema):
    calibration: CalibrationPillar
    kinect: KinectPillar
    sync: SyncPillar


class SessionReport(FileSchema):
    """``report/session.json``: what `dome-calib session` achieved per pillar, what to check, stage times (s)."""

    session: Text
    seq: Text
    pillars: Pillars
    stage_seconds: dict[Name, NonNegFinite]


# ---- reading and writing ----------------------------------------------------------------------------------------

SCHEMAS = {SYNC_FILE: SyncReport, SESSION_FILE: SessionReport}


def finite_or_null(data):
    """``data`` with every NaN or infinite number replaced by None (null: not computed)."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {k: finite_or_null(v) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [finite_or_null(v) for v in data]
    return data


def kept_text(name: str, content: dict) -> str:
    """The text of the kept file ``name`` (``sync.json``, ``session.json``) from its content as plain data, through
    its schema (:func:`dome_calib.report.schema.checked`; NaN written as null)."""
    typed = checked(finite_or_null(content), SCHEMAS[name], name)
    return typed.model_dump_json(indent=1, exclude_unset=True) + "\n"


def write_kept(report_folder: str | Path, name: str, content: dict) -> Path:
    """Write the kept file ``name`` into ``report_folder`` (created) through :func:`kept_text`, atomically."""
    path = Path(report_folder) / name
    text = kept_text(name, content)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, text)
    return path


def read_kept_file(path: str | Path) -> SessionReport | SyncReport | None:
    """The kept file at ``path`` (its name tells its schema), None if absent; ReportError of one line naming the
    file and the field where it does not match."""
    path = Path(path)
    if not path.exists():
        return None
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ReportError(f"{path}: cannot be read ({exc.strerror})") from None
    return parse_json(path, data, SCHEMAS[path.name], error=ReportError)


def read_kept(report_folder: str | Path) -> tuple[SessionReport | None, SyncReport | None]:
    """The kept files of ``report_folder`` (None where absent), each through :func:`read_kept_file`."""
    return (read_kept_file(Path(report_folder) / SESSION_FILE), read_kept_file(Path(report_folder) / SYNC_FILE))
