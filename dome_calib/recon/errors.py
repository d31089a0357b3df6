"""Errors of the reconstruction stages (user errors: bad detections file, missing camera, missing sync table)."""
from __future__ import annotations

from dome_calib.errors import DomeCalibError


class ReconError(DomeCalibError, ValueError):
    """Input to a reconstruction stage is unusable; the message names the file, camera or stream and the fix."""
