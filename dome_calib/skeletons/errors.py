"""Errors of the people-out stages (a body3DScene folder that cannot be read, an output that cannot be written)."""
from __future__ import annotations

from dome_calib.errors import DomeCalibError


class PeopleFileError(DomeCalibError, ValueError):
    """A body3DScene folder or file is unusable; the message names the file, the field and what is wrong."""
