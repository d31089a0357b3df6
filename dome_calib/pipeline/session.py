"""`dome-calib session SESSION -o BUNDLE`: the technician's whole job in one run, one bundle out.

A session folder holds what comes back from the dome (see docs/session.md, 'Session layout')::

    SESSION/capture/   projector-pattern tent captures        -> dome-calib calibrate (the cameras)
    SESSION/kinect/    Kinect checkerboard IR/colour pairs    -> dome-calib kinect (depth to colour, in the world)
    SESSION/sync/      session.json, ltc.wav, Kinect audio    -> timecode sync (every stream on universal time)

The runners are the commands' own (run_calibration, calibrate_kinect_folder, sync_session + write_sync). The
calibration runs into ``BUNDLE.work/calibration`` (resumable like calibrate's); the Kinect calibration and the
sync tables are added to it in a staging folder beside BUNDLE with the calibration report and one
``report/session.json``, and the staging folder is swapped in whole: BUNDLE is the old one or the new one.
"""
from __future__ import annotations

import math
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path


from dome_calib.bundle import Bundle
from dome_calib.bundle_io import (check_output_folder, load_bundle, recover_folder, replace_folder, staging_folder,
                                  write_bundle)
from dome_calib.capture_checks import cross_check_kinects
from dome_calib.errors import BundleFormatError, CaptureError, DomeCalibError
from dome_calib.kinect.calibrate import KinectCalibOptions, SensorCalibration, calibrate_kinect_folder
from dome_calib.kinect.detect import check_sensor_frames, find_sensor_frames
from dome_calib.report.kept import SESSION_FILE, write_kept
from dome_calib.report.page import write_page
from dome_calib.pipeline.capture import capture_contents
from dome_calib.pipeline.full import run_calibration
from dome_calib.pipeline.types import CalibrateOptions, CalibrationResult
from dome_calib.progress import ProgressTasks
from timecode.errors import TimecodeError
from timecode.sync.pipeline import check_session_audio, sync_session, write_sync
from timecode.sync.session import load_session
from timecode.sync.tables import SyncOptions, SyncResult
from dome_calib.options import options

PARTS = {"capture": "capture", "kinect": "kinect", "sync": "sync"}
#: A Kinect is flagged when its stereo RMS exceeds this (px) or fewer boards than this were usable.
KINECT_CHECK_RMS_PX, KINECT_MIN_FRAMES = 0.5, 6
#: A VGA/HD clock fit is flagged when its residual RMS exceeds this (us): an LTC read that is not clean.
SYNC_CHECK_RESID_US = 50.0


@options
class SessionOptions:
    seq: str | None = None  # default: the session folder's name
    progress: ProgressTasks | None = None  # the calibration's bars (dome_calib.progress)
    kinect: KinectCalibOptions = field(default_factory=KinectCalibOptions)
    sync: SyncOptions = field(default_factory=SyncOptions)


@dataclass(kw_only=True)
class SessionResult:
    bundle_dir: Path
    bundle: Bundle
    calibration: CalibrationResult
    kinect: list[SensorCalibration]
    sync: SyncResult
    report: dict
    stage_seconds: dict[str, float]


def session_parts(session: Path) -> dict[str, Path]:
    """The session's three parts; CaptureError naming the first one missing."""
    session = Path(session)
    if not session.is_dir():
        raise CaptureError(f"{session}: session folder not found")
    parts = {k: session / v for k, v in PARTS.items()}
    for key, path in parts.items():
        if not path.is_dir():
            raise CaptureError(f"{path}: missing ({key} part of the session: expected the folder "
                               f"{PARTS[key]}/ beside the others, see docs/session.md 'Session layout')")
    if not (parts["sync"] / "session.json").is_file():
        raise CaptureError(f"{parts['sync'] / 'session.json'}: missing (the sync part's description)")
    return parts


def _kinect_pillar(results: list[SensorCalibration], bundle: Bundle) -> dict:
    sensors = [r.summary() for r in results]
    have = {s["color_camera"] for s in sensors}
    check = [f"{s['sensor']}: stereo RMS {max(s['rms_ir_px'], s['rms_color_px']):.3f} px (> {KINECT_CHECK_RMS_PX})"
             for s in sensors if max(s["rms_ir_px"], s["rms_color_px"]) > KINECT_CHECK_RMS_PX]
    check += [f"{s['sensor']}: only {s['frames_used']} usable board frames (< {KINECT_MIN_FRAMES})"
              for s in sensors if s["frames_used"] < KINECT_MIN_FRAMES]
    check += [f"{n}: Kinect colour camera without checkerboard pairs (no depth calibration)"
              for n in sorted(bundle.of_type("kinect-color")) if n not in have]
    return {"achieved": f"{len(sensors)} Kinects calibrated (depth to colour, placed in the dome's world)",
            "sensors": sensors, "to_check": check}


def _sync_pillar(result: SyncResult) -> dict:
    streams = [{"stream": s.name, "frames": s.n_frames, "drift_ppm": round(s.drift_ppm, 3),
                "residual_rms_us": round(s.residual_rms_us, 2)} for s in result.summaries]
    check = [f"{s['stream']}: clock fit residual {s['residual_rms_us']:.1f} us RMS (> {SYNC_CHECK_RESID_US:g})"
             for s in streams if "/" not in s["stream"] and s["residual_rms_us"] > SYNC_CHECK_RESID_US]
    check += [f"{name}: NOT SYNCED: {why}" for name, why in result.flagged.items()]
    return {"achieved": f"{len(streams)} streams on universal time (ms on the HD LTC timeline)",
            "streams": streams, "notes": list(result.notes), "to_check": check}


def _calibration_pillar(cal: CalibrationResult) -> dict:
    done = len(cal.bundle.cameras)
    check = [f"{c.name}: {'; '.join(r.text for r in c.reasons)}" for c in cal.to_check]  # failures included
    rms = f"reprojection RMS {cal.rms_px:.3f} px" if math.isfinite(cal.rms_px) else "every camera held"
    return {"achieved": f"{done} of {len(cal.expected)} cameras calibrated, {rms}", "cameras": done,
            "expected": len(cal.expected), "rms_px": round(cal.rms_px, 4) if math.isfinite(cal.rms_px) else None,
            "to_check": check}


def run_session(session: Path, out: Path, options: SessionOptions | None = None,
                on_stage: Callable[[str], None] | None = None) -> SessionResult:
    """Calibrate, Kinect-calibrate and sync one session into the bundle ``out`` (replaced whole at the end).

    Every input and the output are checked before the long work; errors are one-line DomeCalibError /
    TimecodeError subclasses naming file and field. ``on_stage(name)`` is called as each pillar starts.
    """
    options = options or SessionOptions()
    session, out = Path(session), Path(out)
    stage = on_stage or (lambda name: None)
    parts = session_parts(session)
    held_seq = check_output_folder(out, [session])  # a bundle there is the report's previous calibration
    try:  # the sync description and its audio headers are read (and refused) before the calibration
        loaded = load_session(parts["sync"])
        check_session_audio(loaded, kinect_required=True)
    except TimecodeError as exc:
        raise DomeCalibError(str(exc)) from None  # the same one line, as a dome-calib error
    kinect_nodes = find_sensor_frames(parts["kinect"])  # Kinect folders, pairing and image headers, likewise
    for frames in kinect_nodes.values():
        check_sensor_frames(frames, options.kinect.ir_size, None)
    cross_check_kinects(kinect_folder=parts["kinect"], nodes=list(kinect_nodes), sync_file=parts["sync"] / "session.json",
                        synced=list(loaded.kinects), capture=parts["capture"], cameras=capture_contents(parts["capture"])[1])
    seq = options.seq or session.resolve().name
    work = out.with_name(out.name + ".work")
    seconds: dict[str, float] = {}

    t0 = time.perf_counter()
    stage("calibrate")
    cal = run_calibration(parts["capture"], work / "calibration",
                          CalibrateOptions(seq=seq, work_dir=work / "calibration.work", progress=options.progress,
                                           previous=out if held_seq is not None else None, previous_from_out=False))
    seconds["calibrate"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    stage("kinect")
    results, bundle = calibrate_kinect_folder(parts["kinect"], cal.bundle, options.kinect)
    seconds["kinect"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    stage("sync")
    try:
        synced = sync_session(loaded, options.sync)
    except TimecodeError as exc:
        raise DomeCalibError(str(exc)) from None
    seconds["sync"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    stage("write")
    report = {"session": str(session), "seq": seq,
              "pillars": {"calibration": _calibration_pillar(cal), "kinect": _kinect_pillar(results, bundle),
                          "sync": _sync_pillar(synced)},
              "stage_seconds": {k: round(v, 2) for k, v in seconds.items()}}
    recover_folder(out)
    staging = staging_folder(out)
    try:
        shutil.copytree(cal.report_dir, staging / "report")
        write_bundle(bundle, staging)
        write_sync(synced, staging)
        write_kept(staging / "report", SESSION_FILE, report)  # through the schema the page reads it with
        write_page(staging / "report")  # the page again, now with the Kinect and sync sections
        try:
            load_bundle(staging)  # what is swapped in reads back
        except BundleFormatError as exc:  # the staging folder is said as OUT (dome_calib.final_place.said)
            raise BundleFormatError(f"{exc} (nothing written to {out})") from None
        replace_folder(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    seconds["write"] = time.perf_counter() - t0
    report["stage_seconds"] = {k: round(v, 2) for k, v in seconds.items()}
    return SessionResult(bundle_dir=out, bundle=load_bundle(out), calibration=cal, kinect=results, sync=synced,
                         report=report, stage_seconds=seconds)
