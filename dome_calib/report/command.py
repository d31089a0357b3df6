"""`dome-calib report`: rebuild a bundle's ``report/`` (report.json, plots, index.html) from the bundle, the
residuals its calibration saved and what its calibration found, optionally against a previous bundle. A
report-stage command: it loads neither the SfM nor the solver.

A rebuild keeps what only the calibration knew: every section of the old report.json that the report does not
compute itself (world frame, stage times, uncertainties, lens model, where it ran, the change since the previous
calibration), the calibration's reasons to check a camera, the cameras it could not calibrate or held
(``"found"``; derived from ``to_check`` for a report.json written before it was saved), and the files other
commands put in ``report/`` (session.json, sync.json).
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

from dome_calib.bundle_io import load_bundle
from dome_calib.compare import detect_changes
from dome_calib.errors import ReportError
from dome_calib.report.build import REPORT_DIR, REBUILT_KEYS, ReportOptions, load_residuals, write_report
from dome_calib.report.previous import previous_section

logger = logging.getLogger(__name__)

#: Reasons the report's own rules give (recomputed on a rebuild); every other reason came from the calibration.
RULE_REASONS = ("too few observations", "high RMS")


def found_by_calibration(old: dict) -> dict:
    """What the calibration found (reasons to check, cameras not calibrated, cameras held) from an old
    report.json: its ``"found"`` section, or for a report from before it was saved, its ``to_check`` list."""
    if isinstance(old.get("found"), dict):
        f = old["found"]
        return {"reasons": dict(f.get("reasons") or {}), "missing": dict(f.get("missing") or {}),
                "held": dict(f.get("held") or {})}
    reasons, missing = {}, {}
    for row in old.get("to_check") or []:
        name, why = row.get("name"), [str(r) for r in row.get("reasons") or []]
        if row.get("type") is None and why and why[0].startswith("not calibrated: "):
            missing[name] = why[0].removeprefix("not calibrated: ")
            continue
        kept = [r for r in why if not r.startswith(RULE_REASONS)]
        if kept:
            reasons[name] = kept
    held = {n: c["held"] for n, c in (old.get("per_camera") or {}).items() if isinstance(c, dict) and c.get("held")}
    return {"reasons": reasons, "missing": missing, "held": held}


def _old_report(path: Path) -> tuple[dict, str | None]:
    """The old report.json (empty if none) and a note when it could not be read."""
    if not path.exists():
        return {}, None
    try:
        old = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        return {}, f"{path}: unreadable ({exc}); what the calibration found there is lost"
    if not isinstance(old, dict):
        return {}, f"{path}: not a report (a JSON {type(old).__name__}); what the calibration found there is lost"
    return old, None


def report_bundle(bundle_folder: Path, *, previous: Path | None = None, min_observations: int | None = None) -> str:
    """`dome-calib report`: rebuild ``<bundle>/report/`` (module docstring). ``previous``: a bundle to compare
    with (default: the comparison the calibration made, kept). Returns a short text for the terminal."""
    bundle_folder = Path(bundle_folder)
    bundle = load_bundle(bundle_folder)
    residuals = load_residuals(bundle_folder)
    old, note = _old_report(bundle_folder / REPORT_DIR / "report.json")
    if note:
        logger.warning("%s", note)
    found = found_by_calibration(old)
    unknown = sorted(set(found["reasons"]) - set(bundle.cameras))
    if unknown:
        logger.warning("report.json names cameras not in the bundle (%s): their reasons are dropped",
                       ", ".join(unknown[:5]))
    kept = {k: v for k, v in old.items() if k not in REBUILT_KEYS}
    changes = {n: list(r) for n, r in found["reasons"].items() if n in bundle.cameras}
    if previous is not None:
        prev = load_bundle(previous)  # one line naming the folder if it is not a bundle
        for n, c in detect_changes(bundle.cameras, prev.cameras).items():
            changes.setdefault(n, []).extend(r for r in c.reasons if r not in changes.get(n, []))
        kept["previous"] = previous_section(bundle, previous)
    rules = old.get("rules") if isinstance(old.get("rules"), dict) else {}
    if min_observations is None:
        min_observations = int(rules.get("min_observations", ReportOptions().min_observations))
    if min_observations < 0:
        raise ReportError(f"--min-observations {min_observations}: must be 0 or more")
    target = write_report(bundle_folder, bundle, residuals, ReportOptions(min_observations=min_observations),
                          changes=changes, missing=found["missing"], held=found["held"], extra=kept)
    content = json.loads((target / "report.json").read_text(encoding="utf-8"))
    lines = [f"report: {target}/index.html (open it in a browser; also report.json, "
             f"{', '.join(content.get('plots', []))})"]
    if note:
        lines.append(f"  {note}")
    if not content["has_residuals"]:
        lines.append("  no residuals saved with this bundle: geometry only (run `dome-calib calibrate` to get them)")
    elif content["rms_px"] is None:
        lines.append(f"  no camera was estimated from observations: all {len(content['per_camera'])} held")
    else:
        lines.append(f"  RMS {content['rms_px']:.3f} px over {len(content['per_camera'])} cameras")
    prev = content.get("previous")
    if prev and prev.get("error"):
        lines.append(f"  previous calibration {prev['source']}: not compared ({prev['error']})")
    elif prev:
        moved = sorted(((c["moved_mm"], n) for n, c in prev["cameras"].items()), reverse=True)[:3]
        lines.append(f"  since {prev['seq']} ({prev['source']}): most moved "
                     + ", ".join(f"{n} {mm:.1f} mm" for mm, n in moved)
                     + f"; added {len(prev['added'])}, gone {len(prev['gone'])}")
    lines.append(f"  cameras to check: {len(content['to_check'])}")
    lines += [f"    {row['name']}: {'; '.join(row['reasons'])}" for row in content["to_check"][:20]]
    if len(content["to_check"]) > 20:
        lines.append(f"    ... {len(content['to_check']) - 20} more on the page")
    return "\n".join(lines)
