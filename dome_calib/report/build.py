"""The calibration report: per-camera residuals and observation counts, cameras to check with the reason, and
the plots, written as ``<bundle>/report/`` (report.json, residuals.npz, dome.png, residuals.png,
observations.png) all at once: built in a temporary folder beside it, then renamed into place.

Residuals come from the bundle adjustment (:class:`Residuals`); a bundle without them still gets a report of
its geometry, and the report says the residuals are missing. A camera the run took as it was (``held``: the
quick path keeps every camera that agrees with the prior) is reported as held: the observation rule is for
cameras that were estimated from their observations.

report.json is declared by :class:`dome_calib.report.schema.Report`: the content is built as plain data, read
through that schema as it will be read back, and written from the typed report; the plots and the page read the
typed report. Reasons are ``{code, text}`` (:mod:`dome_calib.reasons`). What the calibration found beyond the
residuals (its reasons to check a camera, the cameras it could not calibrate, the cameras it held) is saved in the
``"found"`` section, so that `dome-calib report` can rebuild the report from the folder without losing it
(:mod:`dome_calib.report.command`).
"""
from __future__ import annotations

import logging
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dome_calib.bundle import Bundle, CameraType, camera_type_from_name
from dome_calib.bundle_io import replace_folder
from dome_calib.ownership import claim_folder
from dome_calib.errors import ReportError
from dome_calib.final_place import stage
from dome_calib.io_utils import new_mode
from dome_calib.options import AtLeast, options
from dome_calib.reasons import Reason, ReasonCode, reason
from dome_calib.report.kept import KEPT_FILES
from dome_calib.report.page import write_page
from dome_calib.report.schema import REPORT_VERSION, Report, checked
from dome_calib.residuals import Residuals
from dome_calib.schema import NonNegFinite, PosFinite

logger = logging.getLogger(__name__)

REPORT_DIR = "report"
RESIDUALS_FILE = "residuals.npz"
#: What a new report carries over from the one it replaces (read, checked, and written again or copied): these need
#: not be dome-calib's own to be replaced (:func:`dome_calib.ownership.claim_folder`'s ``keep``); every other file
#: of report/ must be.
CARRIED_FILES = ("report.json", RESIDUALS_FILE, *KEPT_FILES)


@options
class ReportOptions:
    """Rules for the list of cameras to check."""

    min_observations: AtLeast(0) = 100
    high_rms_factor: PosFinite = 2.5  # RMS above this many times the median RMS of the camera's type ...
    high_rms_floor_px: NonNegFinite = 1.0  # ... and above this absolute level
    plots: bool = True


@dataclass(kw_only=True)
class CameraRow:
    name: str
    type: CameraType
    center_cm: list[float]
    observations: int | None
    rms_px: float | None
    held: str | None = None  # why the run took it as it was instead of estimating it
    reasons: list[Reason] = field(default_factory=list)


def camera_rows(bundle: Bundle, residuals: Residuals | None, options: ReportOptions,
                changes: dict[str, list[Reason]] | None = None,
                held: dict[str, str] | None = None) -> dict[str, CameraRow]:
    """One row per camera of the bundle with its statistics and the reasons to check it. A held camera is not
    judged by its observation count (it was not estimated from them); its RMS, if it was observed, still is."""
    held = held or {}
    stats = residuals.per_camera() if residuals is not None else {}
    rows = {n: CameraRow(name=n, type=c.type, center_cm=[round(float(v), 3) for v in c.center_cm],
                         observations=stats.get(n, (0, None))[0] if residuals is not None else None,
                         rms_px=stats.get(n, (0, None))[1] if residuals is not None else None, held=held.get(n))
            for n, c in sorted(bundle.cameras.items())}
    if residuals is not None:
        for cam_type in CameraType:
            rms = [r.rms_px for r in rows.values() if r.type == cam_type and r.rms_px is not None]
            limit = max(options.high_rms_floor_px, options.high_rms_factor * float(np.median(rms))) if rms else np.inf
            for r in rows.values():
                if r.type != cam_type:
                    continue
                if r.held is None and r.observations < options.min_observations:
                    r.reasons.append(reason(ReasonCode.TOO_FEW_OBSERVATIONS, f"too few observations "
                                            f"({r.observations} < {options.min_observations})"))
                if r.rms_px is not None and r.rms_px > limit:
                    r.reasons.append(reason(ReasonCode.HIGH_RMS, f"high RMS {r.rms_px:.2f} px (limit {limit:.2f} px "
                                            f"for {cam_type})"))
    for name, reasons in (changes or {}).items():
        if name in rows:
            rows[name].reasons.extend(r for r in reasons if r not in rows[name].reasons)
    return rows


def build_report(bundle: Bundle, residuals: Residuals | None = None, options: ReportOptions | None = None, *,
                 changes: dict[str, list[Reason]] | None = None, missing: dict[str, str] | None = None,
                 held: dict[str, str] | None = None, extra: dict | None = None) -> Report:
    """report.json's content (:class:`dome_calib.report.schema.Report`).

    Args:
        changes: camera -> reasons to check it that the calibration found (moved since the prior, position poorly
            determined, not checked, ...).
        missing: cameras expected but not calibrated -> why (e.g. "saw no tent").
        held: cameras taken as they were (not estimated) -> why (e.g. "held from the prior (agrees with it)").
        extra: the sections of what the calibration measured (:data:`dome_calib.report.schema.KEPT_SECTIONS`:
            world frame, stage times, uncertainties, previous calibration, ...), plain data or typed. A
            ``"lens_model"`` section (:meth:`dome_calib.ba.lens_model.LensModel.as_dict`) also gives every camera
            row its ``lens_free`` and ``lens_held`` terms; the reasons stay in the section.
    """
    options = options or ReportOptions()
    rows = camera_rows(bundle, residuals, options, changes, held)
    unknown = sorted(set(residuals.camera_names) - set(bundle.cameras)) if residuals is not None else []
    if unknown:
        raise ReportError(f"residuals name cameras not in bundle {bundle.seq}: {', '.join(unknown[:5])}")
    per_type = {}
    for cam_type in CameraType:
        sel = [r for r in rows.values() if r.type == cam_type]
        if not sel:
            continue
        entry: dict = {"cameras": len(sel)}
        if residuals is not None:
            norms = residuals.norms_of({r.name for r in sel})
            entry |= {"observations": int(len(norms)),
                      "rms_px": float(np.sqrt(np.mean(norms ** 2) / 2)) if len(norms) else None,
                      "median_px": float(np.median(norms)) if len(norms) else None}
        per_type[str(cam_type)] = entry
    overall = None
    if residuals is not None and len(residuals.residual_px):
        overall = float(np.sqrt(np.mean(residuals.residual_px ** 2)))  # per coordinate
    to_check = [{"name": r.name, "type": str(r.type), "reasons": r.reasons} for r in rows.values() if r.reasons]
    to_check += [{"name": n, "type": None, "reasons": [reason(ReasonCode.NOT_CALIBRATED, f"not calibrated: {why}")]}
                 for n, why in sorted((missing or {}).items())]
    per_camera = {r.name: {"type": str(r.type), "center_cm": r.center_cm, "observations": r.observations,
                           "rms_px": r.rms_px, "panel": int(bundle.cameras[r.name].panel),
                           "resolution": [int(v) for v in bundle.cameras[r.name].resolution],
                           "view_dir": [round(float(v), 4) for v in bundle.cameras[r.name].R[2]]}  # optical axis, world
                  | ({"held": r.held} if r.held else {}) for r in rows.values()}
    expected = {}
    for name in list(rows) + sorted(missing or {}):
        t = str(rows[name].type) if name in rows else str(camera_type_from_name(name))
        entry = expected.setdefault(t, {"calibrated": 0, "expected": 0})
        entry["expected"] += 1
        entry["calibrated"] += name in rows
    extra = {k: v.model_dump(mode="json", exclude_unset=True) if hasattr(v, "model_dump") else v
             for k, v in (extra or {}).items()}
    lens = (extra.get("lens_model") or {}).get("cameras", {})
    for name, model in lens.items():
        if name in per_camera:
            per_camera[name] |= {"lens_free": model["free"], "lens_held": model["held"]}
    return checked({
        "report_version": REPORT_VERSION,
        "seq": bundle.seq, "calib_data_source": bundle.calib_data_source, "cameras": len(bundle.cameras),
        "expected_per_type": expected,
        "has_residuals": residuals is not None, "rms_px": overall, "per_type": per_type,
        "rules": {"min_observations": options.min_observations, "high_rms_factor": options.high_rms_factor,
                  "high_rms_floor_px": options.high_rms_floor_px},
        "to_check": to_check,
        "per_camera": per_camera,
        "found": {"reasons": {n: list(v) for n, v in sorted((changes or {}).items()) if v},
                  "missing": dict(sorted((missing or {}).items())), "held": dict(sorted((held or {}).items()))},
        **extra,
    }, Report, "report.json")


def write_report(bundle_folder: str | Path, bundle: Bundle, residuals: Residuals | None = None,
                 options: ReportOptions | None = None, **kwargs) -> Path:
    """Build the report and write ``<bundle_folder>/report/`` whole (temp folder, then rename). Returns its path.

    Keyword arguments go to :func:`build_report` (changes, missing, held, extra). Files that other commands put
    in ``report/`` (session.json, sync.json) are kept; ``index.html`` is written last, from the folder's files
    (:func:`dome_calib.report.page.write_page`).
    """
    # in-function import: matplotlib takes ~0.5 s to load, and `dome-calib report --help` or a report without
    # plots need none of it
    from dome_calib.report.plots import plot_dome, plot_observations, plot_residual_histograms

    options = options or ReportOptions()
    folder = Path(bundle_folder)
    if not folder.is_dir():
        raise ReportError(f"{folder}: not a folder")
    claim_folder(folder / REPORT_DIR, option="report folder", keep=CARRIED_FILES)  # replaced whole: ours only
    content = build_report(bundle, residuals, options, **kwargs)
    staging = stage(tempfile.mkdtemp(prefix=f".{REPORT_DIR}.new.", dir=folder), folder / REPORT_DIR)
    try:
        os.chmod(staging, new_mode(0o777))  # mkdtemp makes 0700; report/ gets the mode mkdir() would give
        if residuals is not None:
            residuals.save(staging / RESIDUALS_FILE)
        if options.plots:
            plots = [plot_dome(bundle, content, staging / "dome.png").name,
                     plot_observations(content, staging / "observations.png").name]
            if residuals is not None:
                plots.append(plot_residual_histograms(bundle, residuals, staging / "residuals.png").name)
            content = content.model_copy(update={"plots": plots})
        (staging / "report.json").write_text(content.model_dump_json(indent=1, exclude_unset=True) + "\n",
                                             encoding="utf-8")  # the fields given (the defaults are the reader's)
        target = folder / REPORT_DIR
        for name in KEPT_FILES:  # what other commands added to report/ survives a new report
            if (target / name).is_file():
                shutil.copy2(target / name, staging / name)
        write_page(staging, residuals=residuals)
        replace_folder(staging, target, option="report folder", keep=CARRIED_FILES)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    logger.info("report written to %s (%d cameras to check)", target, len(content.to_check))
    return target


def load_residuals(bundle_folder: str | Path) -> Residuals | None:
    """The residuals saved with a bundle's previous report, or None."""
    path = Path(bundle_folder) / REPORT_DIR / RESIDUALS_FILE
    return Residuals.load(path) if path.exists() else None
