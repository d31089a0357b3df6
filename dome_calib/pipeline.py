"""`dome-calib calibrate`: the technician's one command, as a straight run of stages (placeholder until the
SfM and BA stages land; see :func:`report_bundle` for the report command)."""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from dome_calib.bundle import load_bundle
from dome_calib.compare import detect_changes
from dome_calib.report import ReportOptions, load_residuals, write_report

logger = logging.getLogger(__name__)


def report_bundle(bundle_folder: Path, *, prior: Path | None = None, min_observations: int = 100) -> str:
    """`dome-calib report`: (re)write ``<bundle>/report/`` from the bundle, the residuals saved by calibrate,
    and optionally a prior bundle (cameras moved since). Returns a short text for the terminal."""
    bundle = load_bundle(bundle_folder)
    residuals = load_residuals(bundle_folder)
    changes = None
    if prior is not None:
        changes = {n: c.reasons for n, c in detect_changes(bundle.cameras, load_bundle(prior).cameras).items()}
    target = write_report(bundle_folder, bundle, residuals, ReportOptions(min_observations=min_observations),
                          changes=changes)
    import json

    content = json.loads((target / "report.json").read_text(encoding="utf-8"))
    lines = [f"report: {target}  ({', '.join(content.get('plots', []))})"]
    if not content["has_residuals"]:
        lines.append("  no residuals saved with this bundle: geometry only (run `dome-calib calibrate` to get them)")
    else:
        lines.append(f"  RMS {content['rms_px']:.3f} px over {len(content['per_camera'])} cameras")
    lines.append(f"  cameras to check: {len(content['to_check'])}")
    lines += [f"    {row['name']}: {'; '.join(row['reasons'])}" for row in content["to_check"][:20]]
    return "\n".join(lines)
