"""What the capture folder says: its scenes and cameras (``capture.json``, or the folders under ``scenes/``) and
which capture node holds which cameras' images (``capture.json``'s ``"nodes"``).

``capture.json`` is read through one schema (:class:`CaptureFile`): a wrong type, a camera name that is not one,
a scene or camera listed twice, a camera on two nodes or an unknown field is one line naming the file and the
field, before any work.
"""
from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import AfterValidator, model_validator

from dome_calib.bundle import CAMERA_NAMES_HELP, is_camera_name
from dome_calib.capture_checks import check_capture
from dome_calib.errors import CaptureError
from dome_calib.schema import (Field, FieldError, FileSchema, Finite, NonNegInt, PlainName, Unique, read_json, show,
                               words)

CAPTURE_FILE = "capture.json"


def _camera_name(name: str) -> str:
    if not is_camera_name(name):
        raise ValueError(f"{show(name)} is not a camera name ({CAMERA_NAMES_HELP})")
    return name


CameraName = Annotated[str, AfterValidator(_camera_name), Field(**words("a camera name (01_01, 00_03, 50_02)"))]


class TentPose(FileSchema):
    """Where ``dome-calib synth`` put the tent in one scene (floor position, turn about the vertical)."""

    yaw_rad: Finite
    x_cm: Finite
    z_cm: Finite


class ImageFingerprint(FileSchema):
    """What one image file is: its size and the SHA-256 of its bytes."""

    bytes: NonNegInt
    sha256: Annotated[str, Field(pattern=r"^[0-9a-f]{64}$", **words("64 lower-case hex digits"))]


class CaptureFile(FileSchema):
    """``CAPTURE/capture.json``: the scenes and cameras of a capture and which capture node holds which cameras'
    images. Only ``scenes``, ``cameras`` and ``nodes`` are read by ``calibrate``; the other fields record how
    ``dome-calib synth`` (or a bench script) made the capture."""

    scenes: Unique(PlainName, 1) = Field(description="the scene folders scenes/<scene>/, one per tent position")
    cameras: Unique(CameraName, 1) = Field(description="every camera of the capture (its images <camera>.png)")
    nodes: dict[PlainName, Unique(CameraName)] = Field(
        {}, description="capture node (the worker's `dask worker --name`) -> the cameras whose images it holds")
    images: dict[str, ImageFingerprint] = Field(
        {}, description="<scene>/<camera> -> the image's size and SHA-256: what every cluster worker must read "
                        "(for images that stay on the capture nodes, which this machine cannot read)")
    preset: str | None = Field(None, description="synth: the camera preset")
    seed: int | None = Field(None, description="synth: the random seed")
    generator_version: str | None = Field(None, description="synth: the generator's version")
    layout: str | None = Field(None, description="synth: the layout the cameras came from")
    camera_types: dict[str, list[CameraName]] = Field({}, description="synth: the cameras by type")
    tent_poses: dict[PlainName, TentPose] = Field({}, description="synth: the tent's pose per scene")
    tent_primitives: dict[str, list[dict[str, Finite | list[Finite]]]] = Field(
        {}, description="synth: the tent's shape (cones, ellipsoids)")
    projectors: list[str] = Field([], description="synth: the projectors")
    pattern_seed: int | None = Field(None, description="synth: the projector patterns' seed")
    ground_truth: str | None = Field(None, description="the true calibration, relative to the capture folder")
    source: str | None = Field(None, description="where the images came from")
    seconds: dict[str, Finite] = Field({}, description="synth: how long making it took")

    @model_validator(mode="after")
    def _nodes_hold_the_cameras(self) -> CaptureFile:
        known, seen = set(self.cameras), {}
        for node, cams in sorted(self.nodes.items()):
            for i, cam in enumerate(cams):
                if cam not in known:
                    raise FieldError(("nodes", node, i), f"camera {cam} is not among the file's cameras")
                if cam in seen:
                    raise FieldError(("nodes", node, i), f"camera {cam} is listed under nodes {seen[cam]} and {node}")
                seen[cam] = node
        scenes = set(self.scenes)
        for key in self.images:
            scene, _, cam = key.partition("/")
            if scene not in scenes or cam not in known:
                raise FieldError(("images", key), "expected <scene>/<camera> of a listed scene and camera")
        return self


def read_capture_file(capture: Path) -> CaptureFile | None:
    """``capture.json`` of the capture folder, None when there is none; CaptureError (one line) when malformed."""
    path = Path(capture) / CAPTURE_FILE
    if not path.exists() and not path.is_symlink():
        return None
    return read_json(path, CaptureFile, error=CaptureError)


def capture_contents(capture: Path) -> tuple[list[str], list[str]]:
    """Scenes and cameras named by ``capture.json`` (or found under scenes/)."""
    if not capture.is_dir():
        raise CaptureError(f"{capture}: not a folder")
    meta = read_capture_file(capture)
    if meta is not None:
        check_capture(capture, list(meta.scenes), list(meta.cameras), listed=True, local=not meta.nodes)
        return list(meta.scenes), list(meta.cameras)
    scenes = sorted(p.name for p in (capture / "scenes").glob("*") if p.is_dir())
    if not scenes:
        raise CaptureError(f"{capture}: no capture.json and no scenes/<scene>/ folders")
    cams = sorted({p.stem for s in scenes for p in (capture / "scenes" / s).glob("*.png")})
    check_capture(capture, scenes, cams, listed=False)
    return scenes, cams


def capture_images(capture: Path) -> dict[str, tuple[int, str]]:
    """``capture.json``'s ``"images"``: ``<scene>/<camera>`` -> (bytes, SHA-256), {} if absent."""
    meta = read_capture_file(capture)
    return {} if meta is None else {k: (v.bytes, v.sha256) for k, v in meta.images.items()}


def capture_nodes(capture: Path) -> dict[str, list[str]]:
    """``capture.json``'s ``"nodes"`` (node -> its cameras, sorted), {} if absent."""
    meta = read_capture_file(capture)
    return {} if meta is None else {str(n): sorted(c) for n, c in sorted(meta.nodes.items())}
