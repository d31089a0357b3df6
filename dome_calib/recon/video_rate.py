"""The frame rate of a rig's videos, for detections whose bundle has no sync tables (``reconstruct --videos``).

Every video of the folder (``.mp4``, ``.avi``, ``.mov``, ``.mkv``, any case) is opened with OpenCV, whose
``CAP_PROP_FPS`` is the container's rate as a float; it is read as the nearest fraction with a denominator up to
1001 (``29.97002997`` -> ``30000/1001``, ``60.0`` -> ``60``). The videos of one synchronised rig share one rate:
videos that disagree, a video without a rate and a folder without videos are refused (one line naming the file).
"""
from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import cv2

from dome_calib.recon.errors import ReconError

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv")
#: The largest denominator of a video rate (NTSC's 1001).
MAX_DENOMINATOR = 1001


def video_rate(path: Path) -> Fraction:
    """One video's frame rate (exact, see the module docstring); ReconError naming the file if it has none."""
    capture = cv2.VideoCapture(str(path))
    try:
        fps = capture.get(cv2.CAP_PROP_FPS) if capture.isOpened() else 0.0
    finally:
        capture.release()
    if not fps > 0 or fps != fps or fps > 1e6:
        raise ReconError(f"{path}: no frame rate could be read from this video (give --fps)")
    return Fraction(fps).limit_denominator(MAX_DENOMINATOR)


def videos_rate(folder: str | Path) -> Fraction:
    """The one frame rate of every video in ``folder`` (and its sub-folders, one level: a video per camera
    folder); ReconError when there is none or they disagree."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ReconError(f"--videos {folder}: not a folder")
    found = sorted(p for pattern in ("*", "*/*") for p in folder.glob(pattern)
                   if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES)
    if not found:
        raise ReconError(f"--videos {folder}: no video ({', '.join(VIDEO_SUFFIXES)}) in it")
    rates = {p: video_rate(p) for p in found}
    first = found[0]
    for path, rate in rates.items():
        if rate != rates[first]:
            raise ReconError(f"--videos {folder}: {path.name} runs at {float(rate):g} fps but {first.name} at "
                             f"{float(rates[first]):g} fps; one rig, one rate (give --fps)")
    return rates[first]
