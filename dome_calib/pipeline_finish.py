"""What the full and the quick calibration share: their options and inputs, the result, and :func:`finish`
(change detection against the prior, cameras to check, then the bundle and its report replacing OUT whole).

OUT is never written in place: the bundle, its report and the files of the same seq that other commands added
(Kinect calibration, sync tables) are staged in a sibling folder, then swapped in
(:func:`dome_calib.bundle_io.replace_folder`), so a reader sees the old bundle or the new one, never a mix, and no
file of another seq survives.
"""
from __future__ import annotations

import json
import logging
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.bundle_io import bundle_files, check_output_folder, replace_folder, staging_folder, write_bundle
from dome_calib.capture_checks import check_capture
from dome_calib.compare import CameraChange, ChangeOptions, detect_changes
from dome_calib.errors import CaptureError, DomeCalibError
from dome_calib.normalize import Normalized, NormalizeOptions
from dome_calib.pipeline_stages import BAOutcome, SfmOutcome
from dome_calib.report import REPORT_DIR, ReportOptions, previous_section, write_report
from dome_calib.residuals import Residuals
from dome_calib.workstate import WorkState

logger = logging.getLogger(__name__)

#: Files of a bundle that other commands add (`dome-calib kinect`, `timecode sync`): kept across a recalibration
#: of the same seq.
CARRIED_KINDS = ("kcalibration", "synctables", "ksynctables")
CARRIED_REPORT_FILES = ("sync.json",)


@dataclass(kw_only=True)
class CalibrateOptions:
    """What `dome-calib calibrate` does. ``seq`` defaults to the capture folder's name."""

    prior: Path | None = None
    previous: Path | None = None  # the report's "change since the previous calibration"; None: the prior, else OUT's
    previous_from_out: bool = True  # without previous or prior: the bundle OUT held (session: its OUT is elsewhere)
    only_changed: bool = False
    seq: str | None = None
    work_dir: Path | None = None
    progress: bool = True
    normalize: NormalizeOptions = field(default_factory=NormalizeOptions)
    changes: ChangeOptions = field(default_factory=ChangeOptions)
    report: ReportOptions = field(default_factory=ReportOptions)
    max_center_sigma_cm: float = 0.5  # flag cameras whose centre is less certain than this (1 sigma)
    # ... or RELATIVE_SIGMA times less certain than the dome's median camera (and above RELATIVE_SIGMA_FLOOR_CM):
    # the covariance is only as good as the noise model, so a camera far less determined than the others is
    # checked even under the absolute bound (a camera 5x less determined is ~5x as likely to be off)
    center_sigma_ratio: float = 5.0
    scheduler: str | None = None  # a Dask scheduler (tcp://HOST:PORT) for features and matching; None: local pool


@dataclass(kw_only=True)
class CalibrationInputs:
    """One run's inputs, read and checked before any work."""

    capture: Path
    out: Path
    seq: str
    scenes: list[str]
    expected: list[str]  # cameras of the capture
    prior: Bundle | None
    options: CalibrateOptions


@dataclass(kw_only=True)
class Calibrated:
    """What a runner hands to :func:`finish`: cameras in the Panoptic frame and what is known about them."""

    normalized: Normalized
    failures: dict[str, str]  # camera -> why it was not calibrated
    residuals: Residuals  # observed - projected, px
    source: str  # calibDataSource of the bundle
    center_sigma_cm: dict[str, float] = field(default_factory=dict)  # 1-sigma centre uncertainty
    rotation_sigma_deg: dict[str, float] = field(default_factory=dict)  # 1-sigma rotation uncertainty
    held: dict[str, str] = field(default_factory=dict)  # camera -> why it was taken as it is, not estimated
    changes: dict[str, CameraChange] | None = None  # None: detect against the prior
    notes: dict[str, str] = field(default_factory=dict)  # camera -> a further reason to check it
    lens_model: dict | None = None  # the BA's per-camera lens terms refined and held, with why (report.json)
    cluster: dict | None = None  # where each stage ran: report.json's "cluster" (dome_calib.cluster.cluster_section)


@dataclass(kw_only=True)
class CalibrationResult:
    """What a calibration produced, for the summary, the demo and the benchmarks."""

    bundle_dir: Path
    report_dir: Path
    bundle: Bundle
    expected: list[str]  # cameras of the capture
    failures: dict[str, str]  # camera -> why it was not calibrated
    normalized: Normalized
    residuals: Residuals
    stage_seconds: dict[str, float]
    resumed: list[str]  # stages taken from the work folder
    changes: dict[str, CameraChange] | None = None
    to_check: list[dict] = field(default_factory=list)
    stats: dict = field(default_factory=dict)  # per-stage counts and times
    sfm: SfmOutcome | None = None  # full run
    ba: BAOutcome | None = None  # full run; quick run: the re-estimation (None if no camera changed)

    @property
    def rms_px(self) -> float:
        """Per coordinate; NaN when no camera was estimated (a quick run that held every camera)."""
        if not len(self.residuals.residual_px):
            return float("nan")
        return float(np.sqrt(np.mean(self.residuals.residual_px ** 2)))


def capture_contents(capture: Path) -> tuple[list[str], list[str]]:
    """Scenes and cameras named by ``capture.json`` (or found under scenes/)."""
    if not capture.is_dir():
        raise CaptureError(f"{capture}: not a folder")
    meta_path = capture / "capture.json"
    if meta_path.exists():
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
            scenes, cams = list(meta["scenes"]), list(meta["cameras"])
        except (ValueError, KeyError, TypeError) as exc:
            raise CaptureError(f"{meta_path}: malformed ({exc})") from exc
        check_capture(capture, scenes, cams, listed=True, local=not meta.get("nodes"))
        return scenes, cams
    scenes = sorted(p.name for p in (capture / "scenes").glob("*") if p.is_dir())
    if not scenes:
        raise CaptureError(f"{capture}: no capture.json and no scenes/<scene>/ folders")
    cams = sorted({p.stem for s in scenes for p in (capture / "scenes" / s).glob("*.png")})
    check_capture(capture, scenes, cams, listed=False)
    return scenes, cams


#: The relative rule needs a dome's worth of cameras to know the typical one (a quick recalibration frees a few).
RELATIVE_SIGMA_MIN_CAMERAS = 8
#: Below this (1 sigma, cm) a centre is never flagged by the relative rule: a millimetre does not matter.
RELATIVE_SIGMA_FLOOR_CM = 0.1


def center_sigma_flags(sigma_cm: dict[str, float], options: CalibrateOptions) -> dict[str, str]:
    """Camera -> why its position is poorly determined: its centre's 1-sigma uncertainty (cm) is above
    ``max_center_sigma_cm``, or above ``center_sigma_ratio`` times the median of the cameras (at least
    RELATIVE_SIGMA_MIN_CAMERAS of them) and above RELATIVE_SIGMA_FLOOR_CM. Uncertainties are compared after
    rounding to 1e-6 cm, so the list does not rest on the last bits of the covariance."""
    q = {n: round(s, 6) for n, s in sigma_cm.items()}
    median = float(np.median(list(q.values()))) if len(q) >= RELATIVE_SIGMA_MIN_CAMERAS else float("inf")
    hint = "few or one-sided views of the tent; add a tent position it sees"
    out = {}
    for n, s in sorted(q.items()):
        if s > options.max_center_sigma_cm:
            out[n] = f"position poorly determined (+-{s:.1f} cm, 1 sigma): {hint}"
        elif s > RELATIVE_SIGMA_FLOOR_CM and s > options.center_sigma_ratio * median:
            out[n] = (f"position much less determined than the other cameras' (+-{s:.2f} cm, 1 sigma, "
                      f"{s / median:.1f} x the median {median:.3f} cm): {hint}")
    return out


def finish(inputs: CalibrationInputs, state: WorkState, calibrated: Calibrated) -> CalibrationResult:
    """Cameras to check (changes against the prior, cameras not calibrated, poorly determined centres), then
    the bundle and its report in OUT, replaced whole (module docstring)."""
    options, prior = inputs.options, inputs.prior
    bundle = Bundle(seq=inputs.seq, cameras=dict(sorted(calibrated.normalized.cameras.items())),
                    calib_data_source=calibrated.source)
    changes = calibrated.changes
    if prior is not None and changes is None:
        changes = detect_changes(bundle.cameras, prior.cameras, options.changes)
    missing = {n: calibrated.failures.get(n, "not reconstructed") for n in inputs.expected if n not in bundle.cameras}
    reasons = {n: list(c.reasons) for n, c in (changes or {}).items()}
    for n, note in calibrated.notes.items():
        reasons.setdefault(n, []).append(note)
    sigma_cm = {n: s for n, s in calibrated.center_sigma_cm.items() if n in bundle.cameras}
    for n, why in center_sigma_flags(sigma_cm, options).items():
        reasons.setdefault(n, []).append(why)
    extra = {"world_frame": calibrated.normalized.as_dict(), "stage_seconds": dict(state.seconds),
             "center_sigma_cm": {n: round(s, 4) for n, s in sorted(sigma_cm.items())},
             "rotation_sigma_deg": {n: round(s, 5) for n, s in sorted(calibrated.rotation_sigma_deg.items())
                                    if n in bundle.cameras},
             "previous": previous_section(bundle, options.previous or options.prior or (
                 _held_bundle(inputs.out) if options.previous_from_out else None)),
             "lens_model": calibrated.lens_model,
             "cluster": calibrated.cluster,
             "changes_vs_prior": {n: c.as_dict() for n, c in (changes or {}).items()} if prior else None}
    state.time("write", lambda: _write_out(inputs, bundle, calibrated.residuals, reasons, missing, extra,
                                           calibrated.held))
    report_dir = inputs.out / REPORT_DIR
    content = json.loads((report_dir / "report.json").read_text(encoding="utf-8"))
    return CalibrationResult(bundle_dir=inputs.out, report_dir=report_dir, bundle=bundle, expected=inputs.expected,
                             failures=missing, normalized=calibrated.normalized, residuals=calibrated.residuals,
                             stage_seconds=state.seconds, resumed=state.resumed, changes=changes,
                             to_check=content["to_check"])


def _write_out(inputs: CalibrationInputs, bundle: Bundle, residuals: Residuals, reasons: dict[str, list[str]],
               missing: dict[str, str], extra: dict, held: dict[str, str]) -> None:
    """Stage the bundle, its report and the carried files beside OUT, then swap them in."""
    out = inputs.out
    old_seq = check_output_folder(out)  # again: OUT may have changed while the stages ran
    staging = staging_folder(out)
    try:
        write_bundle(bundle, staging)
        if old_seq == bundle.seq:  # first: the report page shows the carried sync report
            _carry_over(out, staging, bundle.seq)
        elif old_seq is not None:
            logger.warning("%s: held the bundle of seq %r; replaced by seq %r", out, old_seq, bundle.seq)
        write_report(staging, bundle, residuals, inputs.options.report, changes=reasons, missing=missing, extra=extra,
                     held=held)
        replace_folder(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def _held_bundle(out: Path) -> Path | None:
    """OUT itself when it holds a bundle (read before it is replaced): the report's previous calibration."""
    try:
        return out if check_output_folder(out) is not None else None
    except DomeCalibError:
        return None


def _carry_over(old: Path, staging: Path, seq: str) -> None:
    """Copy the Kinect calibration and sync tables of ``seq`` (and the sync report) from the old bundle."""
    for kind in CARRIED_KINDS:
        src = bundle_files(old, seq)[kind]
        if src.is_file():
            shutil.copy2(src, staging / src.name)
    for name in CARRIED_REPORT_FILES:
        src = old / REPORT_DIR / name
        if src.is_file():
            (staging / REPORT_DIR).mkdir(exist_ok=True)
            shutil.copy2(src, staging / REPORT_DIR / name)
