"""What a capture folder must hold before a calibration starts, checked in one pass over its file names (and the
bytes of same-sized images): every listed scene on disk, every image named after a camera, no picture twice.

A file manager's copy ``01_01 (1).png``, a camera renamed ``hd-main.png`` or an image copied over another camera's
name would otherwise become a camera of the bundle (a phantom, or a VGA camera that is an HD one), calibrated and
flagged by nothing. Each is refused in one line naming the file and how to fix it.
"""
from __future__ import annotations

import hashlib
from collections import defaultdict
from pathlib import Path

import cv2

from dome_calib.bundle import CAMERA_NAMES_HELP, is_camera_name, kinect_node_camera
from dome_calib.errors import CaptureError


def check_camera_names(names: list[str], where: str) -> None:
    """CaptureError naming the first of ``names`` that is not a Panoptic camera name."""
    bad = sorted(n for n in names if not is_camera_name(n))
    if bad:
        raise CaptureError(f"{where}: {bad[0]!r} is not a camera name ({CAMERA_NAMES_HELP})"
                           f"{f' and {len(bad) - 1} more' if len(bad) > 1 else ''}: name each image after its "
                           "camera, e.g. the HD camera 00_03 -> 00_03.png")


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes, as hex (read in 1 MB blocks)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


#: Grey-level standard deviation below which an image is blank (projector.features' blank check): blank images of
#: several cameras are alike without being copies, and the feature stage reports each.
BLANK_MAX_STD = 3.0


def _blank(path: Path) -> bool:
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
    return image is not None and float(image.std()) < BLANK_MAX_STD


def check_same_pictures(images: list[Path]) -> None:
    """CaptureError naming two of ``images`` that are the same picture (same bytes: a copy under a second name),
    unless blank. Only files of equal size are read."""
    by_size: dict[int, list[Path]] = defaultdict(list)
    for p in images:
        by_size[p.stat().st_size].append(p)
    for same_size in by_size.values():
        if len(same_size) < 2:
            continue
        seen: dict[str, Path] = {}
        for p in sorted(same_size):
            first = seen.setdefault(file_sha256(p), p)
            if first != p and not _blank(p):
                raise CaptureError(f"{p}: the same picture as {first} (a copy): two cameras cannot see the same "
                                   "image; remove the copy or put the camera's own image there")


def check_capture(capture: Path, scenes: list[str], cameras: list[str], *, listed: bool,
                  local: bool = True) -> None:
    """Before any work: when its images are here (``local``; not on capture nodes), every
    ``scenes/<scene>/*.png`` of the capture's scenes: named after a camera, a camera of capture.json (``listed``:
    the names come from it, already checked by its schema), and no two the same picture. CaptureError (one line
    naming the file) otherwise."""
    where = capture / "capture.json" if listed else capture
    if not local:
        return
    known = set(cameras)
    for scene in scenes:
        folder = capture / "scenes" / scene
        if not folder.is_dir():
            raise CaptureError(f"{where} lists scene {scene!r} but {folder} is missing: copy the scene there or "
                               "remove it from the list")
        images = sorted(folder.glob("*.png"))
        for p in images:
            check_camera_names([p.stem], str(p))
            if listed and p.stem not in known:
                raise CaptureError(f"{p}: camera {p.stem} is not among the cameras of {where}: add it there or "
                                   "move the file out")
        check_same_pictures(images)


def cross_check_kinects(*, kinect_folder: Path, nodes: list[str], sync_file: Path, synced: list[str],
                        capture: Path, cameras: list[str]) -> None:
    """A session's Kinects named alike in its three parts, before any work: the ``kinect/KINECTNODE<n>`` folders,
    the Kinect nodes of the sync description and the colour cameras ``50_<nn>`` of the capture. A Kinect missing
    from one part (a typo, KINECTNODE7 for 9) would be calibrated without sync, or synced without calibration,
    without a word. CaptureError naming the node and where it is missing."""
    on_capture = {kinect_node_camera(n): n for n in {*nodes, *synced}}
    for camera, node in sorted(on_capture.items(), key=lambda kv: str(kv[0])):
        if camera not in cameras:
            raise CaptureError(f"{node}: its colour camera {camera} is not a camera of the capture {capture} "
                               f"(its Kinect cameras: {', '.join(sorted(c for c in cameras if c.startswith('50_'))) or 'none'})")
    for node in sorted(set(nodes) - set(synced)):
        raise CaptureError(f"{kinect_folder / node}: no Kinect {node} in {sync_file} (it names "
                           f"{', '.join(sorted(synced)) or 'none'}): add its audio there or fix the name")
    for node in sorted(set(synced) - set(nodes)):
        raise CaptureError(f"{sync_file}: names {node}, which has no folder in {kinect_folder} (it holds "
                           f"{', '.join(sorted(nodes)) or 'none'}): fix the name or add its checkerboard pairs")
