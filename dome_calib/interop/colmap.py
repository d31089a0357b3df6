"""COLMAP sparse models (cameras, images, rigs, frames; binary or text), read and written by pycolmap itself.

Export: one COLMAP camera per dome camera (``FULL_OPENCV`` when k3 is non-zero, else ``OPENCV``), all cameras
as the sensors of one rig (the first camera is the reference sensor) and one frame holding one image per camera,
named ``<camera>.png``. No 3D points: a bundle keeps its calibration's residuals (``report/residuals.npz``) but
not the observed pixels nor the points, so ``points3D`` is written empty.

Conventions (COLMAP's documentation, "Output Format" and "Cameras"): ``x_cam = R(q) X + t`` (world to camera,
quaternion ``QW QX QY QZ``), the world's unit is whatever the reconstruction had, pixel coordinates put the centre
of the top-left pixel at (0.5, 0.5): principal points are ours + 0.5.

Import: any model pycolmap reads (``Reconstruction(folder)``); every registered image becomes one camera named
after its image file (without extension; the folders of its path joined by "_": ``frames/img1.jpg`` is
``frames_img1``, since a camera name is a file name). Camera models ``SIMPLE_PINHOLE``, ``PINHOLE``,
``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV`` and ``FULL_OPENCV`` with k4 = k5 = k6 = 0 map exactly onto ours; any
other is refused.
"""
from __future__ import annotations

import logging
from pathlib import Path, PurePosixPath

import numpy as np
import pycolmap

from pydantic import Field, ValidationInfo, field_validator

from dome_calib.camera import COLMAP_PIXEL_OFFSET_PX
from dome_calib.interop.common import ForeignCamera, ImportOptions, InteropError, Read, Written, label
from dome_calib.interop.fields import Bounded, SidePx, Translation
from dome_calib.schema import CameraName, FileSchema, Vec, validate

logger = logging.getLogger(__name__)

#: COLMAP model -> function of its params giving (fx, fy, cx, cy, [k1, k2, p1, p2, k3]) in COLMAP pixels.
_MODELS = {
    "SIMPLE_PINHOLE": lambda p: (p[0], p[0], p[1], p[2], [0, 0, 0, 0, 0]),
    "PINHOLE": lambda p: (p[0], p[1], p[2], p[3], [0, 0, 0, 0, 0]),
    "SIMPLE_RADIAL": lambda p: (p[0], p[0], p[1], p[2], [p[3], 0, 0, 0, 0]),
    "RADIAL": lambda p: (p[0], p[0], p[1], p[2], [p[3], p[4], 0, 0, 0]),
    "OPENCV": lambda p: (p[0], p[1], p[2], p[3], [p[4], p[5], p[6], p[7], 0]),
    "FULL_OPENCV": lambda p: (p[0], p[1], p[2], p[3], [p[4], p[5], p[6], p[7], p[8]]),
}
_COUNTS = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8, "FULL_OPENCV": 12}


def _camera_sensor(camera_id: int) -> pycolmap.sensor_t:
    return pycolmap.sensor_t(type=pycolmap.SensorType.CAMERA, id=camera_id)


def _rigid(cam: ForeignCamera) -> pycolmap.Rigid3d:
    return pycolmap.Rigid3d(pycolmap.Rotation3d(cam.R), cam.t)


def colmap_camera(cam: ForeignCamera, camera_id: int) -> pycolmap.Camera:
    """Our camera as a COLMAP camera: FULL_OPENCV if k3 != 0 else OPENCV; principal point + 0.5 px."""
    fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
    k1, k2, p1, p2, k3 = (float(v) for v in cam.dist)
    params = [fx, fy, cx + COLMAP_PIXEL_OFFSET_PX, cy + COLMAP_PIXEL_OFFSET_PX, k1, k2, p1, p2]
    model = "OPENCV" if k3 == 0.0 else "FULL_OPENCV"
    if model == "FULL_OPENCV":
        params += [k3, 0.0, 0.0, 0.0]
    return pycolmap.Camera(model=model, width=cam.size[0], height=cam.size[1], params=params, camera_id=camera_id)


def build_reconstruction(cams: list[ForeignCamera]) -> pycolmap.Reconstruction:
    """Cameras (in order, ids 1..C) as one rig and one frame of one image each; no points."""
    rec = pycolmap.Reconstruction()
    ref_from_world = _rigid(cams[0])
    rig = pycolmap.Rig(rig_id=1)
    rig.add_ref_sensor(_camera_sensor(1))
    for i, cam in enumerate(cams, start=1):
        rec.add_camera(colmap_camera(cam, i))
        if i > 1:
            rig.add_sensor(_camera_sensor(i), _rigid(cam) * ref_from_world.inverse())
    rec.add_rig(rig)
    frame = pycolmap.Frame(frame_id=1, rig_id=1, rig_from_world=ref_from_world)
    for i in range(1, len(cams) + 1):
        frame.add_data_id(pycolmap.data_t(sensor_id=_camera_sensor(i), id=i))
    rec.add_frame(frame)
    for i, cam in enumerate(cams, start=1):
        rec.add_image(pycolmap.Image(name=f"{cam.name}.png", camera_id=i, image_id=i, frame_id=1))
    return rec


def write(cams: list[ForeignCamera], folder: Path, unit: str, options: object = None) -> Written:
    """Write the model into ``folder`` (an empty staging folder) with pycolmap's own writer."""
    rec = build_reconstruction(cams)
    (rec.write_text if getattr(options, "binary", True) is False else rec.write_binary)(str(folder))
    check_written(rec, folder)
    return Written(dropped=["points3D written empty: the bundle keeps its residuals, not the observed points"])


def check_written(rec: pycolmap.Reconstruction, folder: Path) -> None:
    """pycolmap's writer does not report a failed write (a full disk left cut files, exit 0, and pycolmap read them
    back with garbage distortion): the files are read back and must hold the model written, camera by camera and
    image by image, or InteropError naming the folder (the staging folder is then removed)."""
    try:
        back = pycolmap.Reconstruction(str(folder))
        same = (sorted(back.cameras) == sorted(rec.cameras) and sorted(back.images) == sorted(rec.images)
                and all(back.cameras[i].model == c.model and back.cameras[i].width == c.width
                        and back.cameras[i].height == c.height
                        and np.allclose(back.cameras[i].params, c.params, rtol=1e-9, atol=0)
                        for i, c in rec.cameras.items())
                and all(back.images[i].name == im.name for i, im in rec.images.items()))
    except Exception as exc:  # pycolmap raises plain RuntimeError / ValueError for unreadable files
        same, why = False, str(exc).strip().splitlines()[-1][:100] if str(exc).strip() else type(exc).__name__
    else:
        why = "what was read differs from what was written"
    if not same:
        raise InteropError(f"{folder}: the COLMAP model written does not read back ({why}): is the disk full? Free "
                           "space or write elsewhere")


def _model_files(folder: Path) -> None:
    if not folder.is_dir():
        raise InteropError(f"{folder}: not a folder (a COLMAP model is a folder with cameras, images and points3D "
                           "files, .bin or .txt)")
    for kind in ("cameras", "images"):
        if not any((folder / f"{kind}.{ext}").is_file() for ext in ("bin", "txt")):
            raise InteropError(f"{folder}: no {kind}.bin or {kind}.txt: not a COLMAP model")


class ColmapImage(FileSchema):
    """One registered image of a COLMAP model as pycolmap read it: its camera (model, size, parameters in COLMAP
    pixels) and its pose (world to camera). pycolmap parses the files; this checks what it found."""

    name: CameraName
    model: str
    width: SidePx
    height: SidePx
    params: list[Bounded]
    rotation: Vec(3, Vec(3, Bounded)) = Field(description="world to camera, from the quaternion")
    translation: Translation

    @field_validator("model")
    @classmethod
    def _representable(cls, model: str) -> str:
        if model not in _MODELS:
            raise ValueError(f"COLMAP model {model} cannot be represented (this toolkit holds OpenCV's "
                             f"[k1, k2, p1, p2, k3]; accepted: {', '.join(_MODELS)})")
        return model

    @field_validator("params")
    @classmethod
    def _params(cls, params: list[float], info: ValidationInfo) -> list[float]:
        model = info.data.get("model")
        if model == "FULL_OPENCV" and any(params[9:12]):
            raise ValueError(f"FULL_OPENCV with k4..k6 = {params[9:12]} cannot be represented (rational radial "
                             "model; ours has k1, k2, k3 only)")
        if model in _COUNTS and len(params) != _COUNTS[model]:
            raise ValueError(f"{len(params)} parameters, {model} has {_COUNTS[model]}")
        focal = params[:1] if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL") else params[:2]
        if not all(f > 0 for f in focal):
            raise ValueError(f"focal lengths must be positive, got {focal}")
        return params

    def camera(self) -> ForeignCamera:
        fx, fy, cx, cy, dist = _MODELS[self.model](self.params)
        K = np.array([[fx, 0.0, cx - COLMAP_PIXEL_OFFSET_PX], [0.0, fy, cy - COLMAP_PIXEL_OFFSET_PX], [0, 0, 1.0]])
        return ForeignCamera(name=self.name, size=(self.width, self.height), K=K, dist=np.asarray(dist, dtype=float),
                             R=np.array(self.rotation), t=np.array(self.translation))


def foreign_from_colmap(camera: pycolmap.Camera, cam_from_world: pycolmap.Rigid3d, name: str,
                        where: str) -> ForeignCamera:
    """One COLMAP image's camera and pose as a foreign camera (OpenCV pixels); refuses models we cannot hold."""
    record = {"name": name, "model": camera.model.name, "width": int(camera.width), "height": int(camera.height),
              "params": [float(p) for p in camera.params],
              "rotation": cam_from_world.rotation.matrix().tolist(),
              "translation": [float(v) for v in cam_from_world.translation]}
    return validate(record, ColmapImage, source=f"{where}: camera {label(name)}", error=InteropError).camera()


def read(folder: Path, options: ImportOptions) -> Read:
    """Every registered image of the model in ``folder`` as a camera, in image-id order."""
    _model_files(folder)
    try:
        rec = pycolmap.Reconstruction(str(folder))
    except Exception as exc:  # pycolmap raises plain RuntimeError / ValueError for unreadable files
        raise InteropError(f"{folder}: not a readable COLMAP model ({str(exc).strip().splitlines()[-1][:120]})") \
            from None
    cams, unposed = [], []
    for image_id in sorted(rec.images):
        image = rec.images[image_id]
        name = str(PurePosixPath(image.name).with_suffix("")).replace("/", "_")  # images/cam1/0.jpg: a plain name
        if not image.has_pose:
            unposed.append(name)
            continue
        cams.append(foreign_from_colmap(image.camera, image.cam_from_world(), name, str(folder)))
    if unposed:
        logger.warning("%s: %d image(s) without a pose left out (%s%s)", folder, len(unposed),
                       ", ".join(unposed[:4]), ", ..." if len(unposed) > 4 else "")
    if not cams:
        raise InteropError(f"{folder}: the model has no registered image (nothing to import)")
    return Read(cameras=cams, unit=None, path=folder)
