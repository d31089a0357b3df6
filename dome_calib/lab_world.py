"""The world of a lab whose calibration was imported (``dome-calib import``), as our bundle records it.

An import turns the file's world, whose up axis is ``world_up``, into ours (the Panoptic frame: y down, cm) by a
rotation alone, :data:`PANOPTIC_FROM_UP` (no shift, the file's length unit to cm), and says so in the bundle's
``calibDataSource`` (:func:`import_record`); :func:`imported_up` reads it back, so the stages downstream (the people
export) can write the lab's own axes.
"""
from __future__ import annotations

import re

import numpy as np

#: A file world whose up axis is the key -> the rotation M (det +1) with ``X_panoptic = M @ X_file``: the axis
#: becomes -y (Panoptic up), and x stays x where it can (z up: the usual z-up-to-y-down turn about x).
PANOPTIC_FROM_UP = {
    "+x": np.array([[0, 1.0, 0], [-1.0, 0, 0], [0, 0, 1.0]]),
    "-x": np.array([[0, -1.0, 0], [1.0, 0, 0], [0, 0, 1.0]]),
    "+y": np.diag([1.0, -1.0, -1.0]),
    "-y": np.eye(3),
    "+z": np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]),
    "-z": np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]),
}


_RECORD = re.compile(r"imported from (?P<fmt>\S+) \((?P<file>.*), unit (?P<unit>\S+?)(, its up axis (?P<up>[+-][xyz]) "
                     r"turned to -y)?\)")


def import_record(fmt: str, file_name: str, unit: str, up: str) -> str:
    """The bundle's ``calibDataSource`` of an import: what was read, its unit and how its world was turned (read
    back by :func:`imported_up`)."""
    turned = "" if up == "-y" else f", its up axis {up} turned to -y"
    return f"imported from {fmt} ({file_name}, unit {unit}{turned})"


def imported_up(calib_data_source: str) -> str | None:
    """The up axis of the lab world a bundle was imported from (its ``calibDataSource`` as :func:`import_record`
    writes it): ``"+z"`` for a Pose2Sim, Qualisys, ... z-up world; ``"-y"`` for a world already ours; None for a
    bundle that was not imported (our own calibration)."""
    match = _RECORD.fullmatch(calib_data_source.strip())
    if match is None:
        return None
    return match.group("up") or "-y"
