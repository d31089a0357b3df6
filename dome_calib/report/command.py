"""`dome-calib report`: (re)write a bundle's ``report/`` from the bundle, the residuals its calibration saved and
optionally a prior bundle. A report-stage command: it loads neither the SfM nor the solver.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

from dome_calib.bundle_io import load_bundle
from dome_calib.compare import detect_changes
from dome_calib.report.build import ReportOptions, load_residuals, write_report

logger = logging.getLogger(__name__)


def report_bundle(bundle_folder: Path, *, prior: Path | None = None, min_observations: int = 100) -> str:
    """`dome-calib report`: (re)write ``<bundle>/report/`` from the bundle, the residuals saved by calibrate,
    and optionally a prior bundle (cameras moved since). Returns a short text for the terminal."""
    bundle = load_bundle(bundle_folder)
    residuals = load_residuals(bundle_folder)
    changes = None
    if prior is not None:
        changes = {n: c.reasons for n, c in detect_changes(bundle.cameras, load_bundle(prior).cameras).items()}
    old_path = Path(bundle_folder) / "report" / "report.json"
    kept = {}
    if old_path.exists():  # what only calibrate knew (world frame, stage times, where it ran) survives a re-report
        try:
            old = json.loads(old_path.read_text(encoding="utf-8"))
            kept = {k: old[k] for k in ("world_frame", "stage_seconds", "lens_model", "cluster") if k in old}
        except ValueError:
            logger.warning("%s: unreadable, replaced", old_path)
    target = write_report(bundle_folder, bundle, residuals, ReportOptions(min_observations=min_observations),
                          changes=changes, extra=kept)
    content = json.loads((target / "report.json").read_text(encoding="utf-8"))
    lines = [f"report: {target}  ({', '.join(content.get('plots', []))})"]
    if not content["has_residuals"]:
        lines.append("  no residuals saved with this bundle: geometry only (run `dome-calib calibrate` to get them)")
    else:
        lines.append(f"  RMS {content['rms_px']:.3f} px over {len(content['per_camera'])} cameras")
    lines.append(f"  cameras to check: {len(content['to_check'])}")
    lines += [f"    {row['name']}: {'; '.join(row['reasons'])}" for row in content["to_check"][:20]]
    return "\n".join(lines)
