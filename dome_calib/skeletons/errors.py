"""Errors of the people-out stages (a body3DScene folder that cannot be read, an output that cannot be written):
:class:`~dome_calib.errors.PeopleFileError`, declared with the foundation's errors because the one body3DScene
reader (:mod:`dome_calib.body3d_scene`) raises it."""
from __future__ import annotations

from dome_calib.errors import PeopleFileError

__all__ = ["PeopleFileError"]
