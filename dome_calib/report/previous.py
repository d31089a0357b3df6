"""Change since the previous calibration: per camera how far it moved (mm) and turned (deg) and how much its focal
length changed (%), and which cameras were added or are gone (report.json's ``"previous"`` section).

The two bundles are first put in one frame by a robust rigid fit on the shared camera centres (cm on both sides,
:func:`dome_calib.align.align_cameras`, the same fit as :func:`dome_calib.compare.detect_changes`): a camera's
motion is measured against the rest of the dome, so a re-levelled world frame is not counted as every camera
moving. With too few shared cameras to fit, the frames are compared as they are, and the section says so.
"""
from __future__ import annotations

import logging
from pathlib import Path

from dome_calib.align import AlignmentError, AlignOptions, align_cameras, transform_cameras
from dome_calib.bundle import Bundle, Camera
from dome_calib.bundle_io import load_bundle
from dome_calib.compare import ChangeOptions, camera_error
from dome_calib.errors import DomeCalibError

logger = logging.getLogger(__name__)


def camera_changes(new: dict[str, Camera], previous: dict[str, Camera],
                   options: ChangeOptions | None = None) -> tuple[dict[str, dict], str]:
    """Per shared camera ``{"moved_mm", "turned_deg", "focal_pct"}`` (focal: signed, mean of fx and fy, new
    against previous) and how the frames were matched (a sentence for the page)."""
    options = options or ChangeOptions()
    shared = sorted(set(new) & set(previous))
    try:
        alignment = align_cameras({n: new[n] for n in shared}, {n: previous[n] for n in shared},
                                  AlignOptions(max_error_cm=options.align_max_error_cm, estimate_scale=False))
        aligned = transform_cameras({n: new[n] for n in shared}, alignment.tgt_from_src)
        how = (f"after a rigid fit on the centres of {len(alignment.inliers)} of {len(shared)} shared cameras "
               f"(a camera more than {options.align_max_error_cm:g} cm off is not used for the fit)")
    except (AlignmentError, ValueError) as exc:  # too few shared cameras, or a degenerate layout
        aligned = {n: new[n] for n in shared}
        how = f"in the two bundles' own world frames (no rigid fit: {exc})"
    out = {}
    for n in shared:
        err = camera_error(aligned[n], previous[n])
        f_new, f_old = aligned[n].intr[:2], previous[n].intr[:2]
        out[n] = {"moved_mm": round(err.center_cm * 10.0, 3), "turned_deg": round(err.rotation_deg, 4),
                  "focal_pct": round(float(((f_new - f_old) / f_old).mean() * 100.0), 4)}
    return out, how


def previous_section(bundle: Bundle, previous: str | Path | None) -> dict | None:
    """report.json's ``"previous"`` section against the bundle folder ``previous`` (None: no section).

    An unreadable previous bundle does not fail the report (the calibration it belongs to is done): the section
    then holds ``"error"`` naming the file and what is wrong, and the page shows it.
    """
    if previous is None:
        return None
    try:
        prev = load_bundle(previous)
    except DomeCalibError as exc:
        logger.warning("previous calibration %s not compared: %s", previous, exc)
        return {"source": str(previous), "error": str(exc)}
    cameras, how = camera_changes(bundle.cameras, prev.cameras)
    return {"source": str(Path(previous).resolve()), "seq": prev.seq, "compared": how,
            "added": sorted(set(bundle.cameras) - set(prev.cameras)),
            "gone": sorted(set(prev.cameras) - set(bundle.cameras)), "cameras": cameras}
