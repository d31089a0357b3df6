"""How the full and the quick calibration end (:func:`finish`): change detection against the prior, cameras to
check, then the bundle and its report replacing OUT whole. Their types are in :mod:`dome_calib.pipeline.types`.

OUT is never written in place: the bundle, its report and the files of the same seq that other commands added
(Kinect calibration, sync tables) are staged in a sibling folder, then swapped in
(:func:`dome_calib.bundle_io.replace_folder`), so a reader sees the old bundle or the new one, never a mix, and no
file of another seq survives.
"""
from __future__ import annotations

import dataclasses
import logging
import shutil
from pathlib import Path

import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.bundle_io import bundle_files, check_output_folder, replace_folder, staging_folder, write_bundle
from dome_calib.compare import detect_changes
from dome_calib.errors import DomeCalibError
from dome_calib.panoptic_io import panoptic_order
from dome_calib.pipeline.types import CalibrateOptions, Calibrated, CalibrationInputs, CalibrationResult
from dome_calib.pipeline.workstate import WorkState
from dome_calib.reasons import Reason, ReasonCode, reason
from dome_calib.report import REPORT_DIR, previous_section, read_report, write_report
from dome_calib.report.kept import read_kept_file
from dome_calib.residuals import Residuals

logger = logging.getLogger(__name__)

#: Files of a bundle that other commands add (`dome-calib kinect`, `timecode sync`): kept across a recalibration
#: of the same seq.
CARRIED_KINDS = ("kcalibration", "synctables", "ksynctables")
CARRIED_REPORT_FILES = ("sync.json",)


def carried_names(out: Path, seq: str) -> tuple[str, ...]:
    """The files of OUT that a recalibration of ``seq`` copies into the new bundle (relative paths; none unless OUT
    holds a bundle of ``seq``): they are not lost, so they need not be dome-calib's own
    (:func:`dome_calib.ownership.claim_folder`'s ``keep``)."""
    if out.is_symlink() or not (out / f"calibration_{seq}.json").is_file():
        return ()
    return tuple(f"{kind}_{seq}.json" for kind in CARRIED_KINDS) + tuple(f"{REPORT_DIR}/{name}"
                                                                        for name in CARRIED_REPORT_FILES)


#: The relative rule needs a dome's worth of cameras to know the typical one (a quick recalibration frees a few).
RELATIVE_SIGMA_MIN_CAMERAS = 8
#: Below this (1 sigma, cm) a centre is never flagged by the relative rule: a millimetre does not matter.
RELATIVE_SIGMA_FLOOR_CM = 0.1


def center_sigma_flags(sigma_cm: dict[str, float], options: CalibrateOptions) -> dict[str, Reason]:
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
            out[n] = reason(ReasonCode.POSITION_UNCERTAIN, f"position poorly determined (+-{s:.1f} cm, 1 sigma): {hint}")
        elif s > RELATIVE_SIGMA_FLOOR_CM and s > options.center_sigma_ratio * median:
            out[n] = reason(ReasonCode.POSITION_UNCERTAIN, f"position much less determined than the other cameras' "
                            f"(+-{s:.2f} cm, 1 sigma, {s / median:.1f} x the median {median:.3f} cm): {hint}")
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
    with state.timing("write"):
        _write_out(inputs, bundle, calibrated.residuals, reasons, missing, extra, calibrated.held)
    report_dir = inputs.out / REPORT_DIR
    content, _ = read_report(report_dir / "report.json")
    return CalibrationResult(bundle_dir=inputs.out, report_dir=report_dir, bundle=bundle, expected=inputs.expected,
                             failures=missing, normalized=calibrated.normalized, residuals=calibrated.residuals,
                             stage_seconds=state.seconds, resumed=state.resumed, changes=changes,
                             to_check=content.to_check)


def _write_out(inputs: CalibrationInputs, bundle: Bundle, residuals: Residuals, reasons: dict[str, list[str]],
               missing: dict[str, str], extra: dict, held: dict[str, str]) -> None:
    """Stage the bundle, its report and the carried files beside OUT, then swap them in."""
    out = inputs.out
    keep = carried_names(out, bundle.seq)
    old_seq = check_output_folder(out, keep=keep)  # again: OUT may have changed while the stages ran
    staging = staging_folder(out)
    try:
        write_bundle(dataclasses.replace(bundle, cameras=panoptic_order(bundle.cameras)), staging)  # the files' order
        if old_seq == bundle.seq:  # first: the report page shows the carried sync report
            _carry_over(out, staging, bundle.seq)
        elif old_seq is not None:
            logger.warning("%s: held the bundle of seq %r; replaced by seq %r", out, old_seq, bundle.seq)
        write_report(staging, bundle, residuals, inputs.options.report, changes=reasons, missing=missing, extra=extra,
                     held=held)
        replace_folder(staging, out, keep=keep)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def check_carried_report_files(out: Path) -> None:
    """Before any work: the report files a recalibration of OUT's seq carries over read through their schemas
    (ReportError of one line naming the file and the field), not at the end, after the calibration."""
    for name in CARRIED_REPORT_FILES:
        read_kept_file(out / REPORT_DIR / name)


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
