"""`dome-calib report`: rebuild a bundle's ``report/`` (report.json, plots, index.html) from the bundle, the
residuals its calibration saved and what its calibration found, optionally against a previous bundle. A
report-stage command: it loads neither the SfM nor the solver.

Every file it reads is checked before anything is written: the bundle, report.json (through its schema, an older
layout through its migration: :mod:`dome_calib.report.schema`), residuals.npz and the files other commands keep in
``report/`` (session.json, sync.json: :mod:`dome_calib.report.kept`). A file that does not match is one line naming
the file and the field, and the report is left as it was.

A rebuild keeps what only the calibration knew: the sections of report.json the report does not compute itself
(world frame, stage times, uncertainties, lens model, where it ran, the change since the previous calibration:
:data:`~dome_calib.report.schema.KEPT_SECTIONS`), the calibration's findings (``found``: its reasons to check a
camera, the cameras it could not calibrate or held) and the kept files. The reasons of the report's own rules are
recomputed (their codes, :data:`dome_calib.reasons.RULE_CODES`); the others are kept by code, whatever their text.
"""
from __future__ import annotations

import logging
from pathlib import Path

from dome_calib.align import require_shared
from dome_calib.bundle_io import load_bundle
from dome_calib.compare import detect_changes
from dome_calib.ownership import claim_folder
from dome_calib.reasons import RULE_CODES
from dome_calib.report.build import CARRIED_FILES, REPORT_DIR, ReportOptions, load_residuals, write_report
from dome_calib.report.kept import read_kept
from dome_calib.report.previous import previous_section
from dome_calib.report.schema import KEPT_SECTIONS, Findings, read_report

logger = logging.getLogger(__name__)


def report_bundle(bundle_folder: Path, *, previous: Path | None = None, min_observations: int | None = None) -> str:
    """`dome-calib report`: rebuild ``<bundle>/report/`` (module docstring). ``previous``: a bundle to compare
    with (default: the comparison the calibration made, kept). Returns a short text for the terminal."""
    bundle_folder = Path(bundle_folder)
    bundle = load_bundle(bundle_folder)
    claim_folder(bundle_folder / REPORT_DIR, option="report folder", keep=CARRIED_FILES)  # before anything is built
    report_path = bundle_folder / REPORT_DIR / "report.json"
    old, version = read_report(report_path) if report_path.exists() else (None, None)
    read_kept(bundle_folder / REPORT_DIR)  # checked now: the page reads them after the report is built
    residuals = load_residuals(bundle_folder)
    prev_bundle = load_bundle(previous) if previous is not None else None  # one line naming a folder that is not one
    if prev_bundle is not None:  # detect_changes aligns the two frames on the shared cameras
        require_shared(bundle.cameras, prev_bundle.cameras, given=f"--previous {previous}",
                       against=f"the bundle {bundle_folder}")
    options = ReportOptions(min_observations=min_observations if min_observations is not None else
                            old.rules.min_observations if old is not None and old.rules is not None else
                            ReportOptions().min_observations)
    found = old.found if old is not None else Findings()
    unknown = sorted(set(found.reasons) - set(bundle.cameras))
    if unknown:
        logger.warning("report.json names cameras not in the bundle (%s): their reasons are dropped",
                       ", ".join(unknown[:5]))
    changes = {n: [r for r in reasons if r.code not in RULE_CODES] for n, reasons in found.reasons.items()
               if n in bundle.cameras}
    kept = {k: getattr(old, k) for k in KEPT_SECTIONS if getattr(old, k) is not None} if old is not None else {}
    if prev_bundle is not None:
        for n, c in detect_changes(bundle.cameras, prev_bundle.cameras).items():
            changes.setdefault(n, []).extend(r for r in c.reasons if r not in changes.get(n, []))
        kept["previous"] = previous_section(bundle, previous)
    target = write_report(bundle_folder, bundle, residuals, options, changes=changes, missing=found.missing,
                          held=found.held, extra=kept)
    content, _ = read_report(target / "report.json")
    lines = [f"report: {target}/index.html (open it in a browser; also report.json, {', '.join(content.plots)})"]
    if version is not None and version < 3:
        lines.append(f"  {report_path} was of layout {version}: read through its migration, rewritten as layout "
                     f"{content.report_version}")
    if not content.has_residuals:
        lines.append("  no residuals saved with this bundle: geometry only (run `dome-calib calibrate` to get them)")
    elif content.rms_px is None:
        lines.append(f"  no camera was estimated from observations: all {len(content.per_camera)} held")
    else:
        lines.append(f"  RMS {content.rms_px:.3f} px over {len(content.per_camera)} cameras")
    prev = content.previous
    if prev is not None and prev.error:
        lines.append(f"  previous calibration {prev.source}: not compared ({prev.error})")
    elif prev is not None:
        moved = sorted(((c.moved_mm, n) for n, c in prev.cameras.items()), reverse=True)[:3]
        lines.append(f"  since {prev.seq} ({prev.source}): most moved "
                     + ", ".join(f"{n} {mm:.1f} mm" for mm, n in moved)
                     + f"; added {len(prev.added)}, gone {len(prev.gone)}")
    lines.append(f"  cameras to check: {len(content.to_check)}")
    lines += [f"    {row.name}: {'; '.join(r.text for r in row.reasons)}" for row in content.to_check[:20]]
    if len(content.to_check) > 20:
        lines.append(f"    ... {len(content.to_check) - 20} more on the page")
    return "\n".join(lines)
