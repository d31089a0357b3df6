"""Calibration and synchronisation of a massively multi-camera capture dome (Panoptic Studio style).

``dome_calib.load_bundle(folder)`` and ``dome_calib.write_bundle(bundle, folder)`` read and write a calibration
bundle (:mod:`dome_calib.bundle_io`); the types are in :mod:`dome_calib.bundle`.
"""
from __future__ import annotations

__all__ = ["load_bundle", "write_bundle"]


def __getattr__(name: str):
    if name in __all__:
        # in-function import: `dome-calib --help` and `timecode` start without loading numpy and the file formats
        from dome_calib import bundle_io

        return getattr(bundle_io, name)
    raise AttributeError(f"module 'dome_calib' has no attribute {name!r}")
