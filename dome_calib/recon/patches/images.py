"""Real cameras' images for the patch stage (``reconstruct --images FOLDER``): per camera a video file or a folder of
frame images, read as a :class:`~dome_calib.recon.patches.frames.FrameSource`.

**The folder.** ``FOLDER/images.json`` (:class:`ImagesFile`) maps camera names of the bundle to a video file or a
folder of images, relative to FOLDER; without it, each bundle camera whose name is a video file
(``<camera>.mp4``, ``.avi``, ``.mov``, ``.mkv``, any case) or a sub-folder (``<camera>/``) of FOLDER is taken.

**Frame indices.** A camera's images are frames of its own stream, numbered as the bundle's sync tables number them
(their times come from there, as the detections' do): video frame ``k`` is frame ``first_frame + k``
(``images.json``'s ``first_frame``, default 0); in a folder, the last number of each file name is its frame
(``cam01.0042.png`` -> 42, as for OpenPose files). A bundle without sync tables puts every camera on one frame
index at the rate ``reconstruct`` takes from ``--fps`` or ``--videos`` (:func:`with_shared_clock`).

**Sizes.** An image must be the size the calibration states. A camera whose images are a crop of the calibrated
image says where the crop starts (``crop_origin_px`` ``[x, y]``: the calibrated pixel at the image's top-left
pixel); its images are put back in the calibrated frame at that place, the pixels the crop lacks filled by
repeating its edge (a crop is exact; nothing is rescaled), so every camera is imaged as calibrated (optical flow
between cameras of one stream needs images of one size). Any other size is refused in one line naming the camera
and the file: a scaled image would need a scale nobody stated, and a guessed crop moves every pixel (Pose2Sim's
balancing trial: its cam01 video is 1080 wide against a 1088 calibration, which only its H.264 stream's own crop
record places, docs/patches.md).

Every file is checked before any work (opened, its size read; a folder's images from their headers), and every
problem is one ReconError naming the camera and the file. Videos are decoded forward and the decoded grey frames
kept in a bounded cache (``cache_mb``); a frame before the last one read reopens the video, seeks, and decodes the
:data:`SEEK_BLOCK` frames up to it (kept too: the patch stage walks backward from its seeds).

**On an executor.** The source pickles as its paths and checked sizes, without decoded frames or open videos: a
worker process (the local pool, a Dask worker) reopens the files itself at the same paths (``open_images`` resolves
them), so the workers need the images folder mounted where this machine has it.
"""
from __future__ import annotations

import os
from collections import OrderedDict
from dataclasses import dataclass, field, replace
from fractions import Fraction
from pathlib import Path
from typing import Annotated

import cv2
import numpy as np
from PIL import Image

from dome_calib.bundle import Bundle, Camera, SyncTable, SyncTables
from dome_calib.recon.errors import ReconError
from dome_calib.recon.openpose_io import frame_of_file
from dome_calib.recon.video_rate import VIDEO_SUFFIXES
from dome_calib.schema import CameraName, Field, FileSchema, NonNegInt, Vec, read_json, words

IMAGES_FILE = "images.json"
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
#: Decoded grey frames kept per source (MB): 60 frames of four 1088 x 1920 phone videos fit.
CACHE_MB = 512
#: A video frame further ahead than this is sought, not decoded up to.
SEEK_AHEAD = 64
#: A seek decodes this many frames up to the one asked and keeps them: the patch stage walks backward from its
#: seeds, and one seek (0.3-0.5 s on a 1088 x 1920 phone video) per frame would cost 25-50 x the decoding.
SEEK_BLOCK = 32


class ImagesFile(FileSchema):
    """``FOLDER/images.json``: which file holds each camera's images."""

    cameras: dict[CameraName, Annotated[str, Field(min_length=1, **words("a path relative to the folder"))]] = Field(
        min_length=1, description="camera name of the bundle -> its video file or folder of frame images")
    first_frame: dict[CameraName, NonNegInt] = Field(
        default_factory=dict, description="the camera's frame index of a video's first frame (default 0)")
    crop_origin_px: dict[CameraName, Vec(2, NonNegInt)] = Field(
        default_factory=dict, description="the calibrated image's pixel [x, y] at the top-left of a camera whose "
        "images are a crop of it (default: the images are the calibrated size)")


@dataclass
class _Reader:
    """One camera's images: a video (``path`` a file) or a folder (``files``: frame -> path)."""

    camera: str
    path: Path
    size: tuple[int, int]  # (width, height) of the images
    frames: np.ndarray  # the camera's frame indices held
    first_frame: int = 0
    pad: tuple[int, int, int, int] | None = None  # (top, bottom, left, right) back to the calibrated size
    files: dict[int, Path] = field(default_factory=dict)
    _capture: cv2.VideoCapture | None = None
    _next: int = 0  # the video frame the capture reads next

    def read(self, frame: int) -> np.ndarray:
        if self.files:
            image = cv2.imread(str(self.files[frame]), cv2.IMREAD_GRAYSCALE)
            if image is None:
                raise ReconError(f"{self.files[frame]}: camera {self.camera}: frame {frame}: not readable as an image")
            return self._checked(image, self.files[frame])
        k = frame - self.first_frame
        if self.seeks(frame):
            self.close()
            self._capture = cv2.VideoCapture(str(self.path))
            if k > 0:
                self._capture.set(cv2.CAP_PROP_POS_FRAMES, k)
            self._next = k
        while self._next < k:
            self._capture.grab()
            self._next += 1
        ok, image = self._capture.read()
        self._next += 1
        if not ok:
            raise ReconError(f"{self.path}: camera {self.camera}: video frame {k} (frame {frame}) cannot be decoded")
        return self._checked(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), self.path)

    def seeks(self, frame: int) -> bool:
        """Reading ``frame`` next reopens the video and seeks (a frame behind the last one read, or far ahead)."""
        k = frame - self.first_frame
        return not self.files and (self._capture is None or k < self._next or k > self._next + SEEK_AHEAD)

    def _checked(self, gray: np.ndarray, path: Path) -> np.ndarray:
        if (gray.shape[1], gray.shape[0]) != self.size:
            raise ReconError(f"{path}: camera {self.camera}: an image of {gray.shape[1]} x {gray.shape[0]} px among "
                             f"images of {self.size[0]} x {self.size[1]}")
        if self.pad is not None:
            gray = cv2.copyMakeBorder(gray, *self.pad, cv2.BORDER_REPLICATE)
        return gray

    def close(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None

    def __getstate__(self) -> dict:
        """Pickled without the open video (an OpenCV capture does not pickle): the copy reopens the file at its
        first read (an executor's worker reads the same path)."""
        state = dict(self.__dict__)
        state["_capture"], state["_next"] = None, 0
        return state


class ImageSource:
    """Real images of named cameras (a :class:`~dome_calib.recon.patches.frames.FrameSource`); see the module
    docstring. Open with :func:`open_images`."""

    def __init__(self, folder: Path, cameras: dict[str, Camera], readers: dict[str, _Reader],
                 cache_mb: float = CACHE_MB) -> None:
        self.folder = folder
        self._cameras = cameras
        self._readers = readers
        self._cache: OrderedDict[tuple[str, int], np.ndarray] = OrderedDict()
        self._budget = int(cache_mb * 2**20)
        self._bytes = 0

    @property
    def names(self) -> list[str]:
        """The cameras, by name."""
        return sorted(self._readers)

    def frame_indices(self, camera: str) -> np.ndarray:
        return self._readers[camera].frames

    def camera(self, camera: str) -> Camera:
        return self._cameras[camera]

    def gray(self, camera: str, frame: int) -> np.ndarray:
        key = (camera, int(frame))
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key]
        reader = self._readers[camera]
        if reader.seeks(int(frame)):  # the frames before it, decoded after the one seek
            first = int(reader.frames[0])
            for f in range(max(first, int(frame) - SEEK_BLOCK + 1), int(frame)):
                if (camera, f) not in self._cache:
                    self._keep((camera, f), reader.read(f))
        return self._keep(key, reader.read(int(frame)))

    def _keep(self, key: tuple[str, int], image: np.ndarray) -> np.ndarray:
        image.setflags(write=False)
        self._cache[key] = image
        self._bytes += image.nbytes
        while self._bytes > self._budget and len(self._cache) > 1:
            _, old = self._cache.popitem(last=False)
            self._bytes -= old.nbytes
        return image

    def close(self) -> None:
        for r in self._readers.values():
            r.close()

    def __getstate__(self) -> dict:
        """Pickled without its decoded frames (an executor task decodes what it reads, from the same paths) and
        without open videos (:meth:`_Reader.__getstate__`)."""
        state = dict(self.__dict__)
        state["_cache"], state["_bytes"] = OrderedDict(), 0
        return state


def images_entries(folder: Path, bundle: Bundle) -> ImagesFile:
    """``images.json`` read (its schema), else the bundle cameras found by name in the folder."""
    listed = folder / IMAGES_FILE
    if listed.exists():
        entries = read_json(listed, ImagesFile, error=ReconError)
        for where in ("cameras", "first_frame", "crop_origin_px"):
            for name in getattr(entries, where):
                if name not in bundle.cameras:
                    raise ReconError(f"{listed}: {where}.{name}: no camera of that name in bundle {bundle.seq}")
                if name not in entries.cameras:
                    raise ReconError(f"{listed}: {where}.{name}: camera not listed under cameras")
        return entries
    found = {}
    for entry in sorted(os.scandir(folder), key=lambda e: e.name):
        stem, suffix = os.path.splitext(entry.name)
        if entry.is_dir() and entry.name in bundle.cameras:
            found[entry.name] = entry.name
        elif entry.is_file() and suffix.lower() in VIDEO_SUFFIXES and stem in bundle.cameras:
            if stem in found:
                raise ReconError(f"--images {folder}: camera {stem} has two entries ({found[stem]}, {entry.name}); "
                                 f"list one in {IMAGES_FILE}")
            found[stem] = entry.name
    if not found:
        raise ReconError(f"--images {folder}: no {IMAGES_FILE} and no video (<camera>{'/'.join(VIDEO_SUFFIXES)}) or "
                         f"folder named after a camera of bundle {bundle.seq}")
    return ImagesFile(cameras=found)


def _video_reader(camera: str, path: Path, first_frame: int) -> _Reader:
    capture = cv2.VideoCapture(str(path))
    try:
        if not capture.isOpened():
            raise ReconError(f"{path}: camera {camera}: OpenCV cannot open this video")
        w, h = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
        n = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
    finally:
        capture.release()
    if w <= 0 or h <= 0 or n <= 0:
        raise ReconError(f"{path}: camera {camera}: no frames in this video ({w} x {h} px, {n} frames)")
    return _Reader(camera=camera, path=path, size=(w, h), frames=first_frame + np.arange(n, dtype=np.int64),
                   first_frame=first_frame)


def _folder_reader(camera: str, path: Path) -> _Reader:
    files: dict[int, Path] = {}
    for entry in sorted(os.scandir(path), key=lambda e: e.name):
        p = Path(entry.path)
        if not entry.is_file() or p.suffix.lower() not in IMAGE_SUFFIXES:
            continue
        frame = frame_of_file(p.with_suffix(".json"))  # the same rule as OpenPose files: the last number
        if frame in files:
            raise ReconError(f"{p}: camera {camera}: frame {frame} again (also {files[frame].name})")
        files[frame] = p
    if not files:
        raise ReconError(f"{path}: camera {camera}: no image ({', '.join(IMAGE_SUFFIXES)}) in this folder")
    sizes = {}
    for frame, p in files.items():
        try:
            with Image.open(p) as image:
                sizes[frame] = image.size
        except OSError as exc:
            raise ReconError(f"{p}: camera {camera}: not a readable image ({exc})") from None
    first = min(files)
    for frame, s in sizes.items():
        if s != sizes[first]:
            raise ReconError(f"{files[frame]}: camera {camera}: {s[0]} x {s[1]} px, but {files[first].name} is "
                             f"{sizes[first][0]} x {sizes[first][1]}")
    return _Reader(camera=camera, path=path, size=sizes[first], frames=np.array(sorted(files), dtype=np.int64),
                   files=files)


def open_images(folder: str | Path, bundle: Bundle, *, cache_mb: float = CACHE_MB) -> ImageSource:
    """Check and open the images of ``folder`` (see the module docstring): every camera's file opened, its frames
    listed and its size checked against the calibration, before any image is decoded. Paths are made absolute: an
    executor's workers reopen them."""
    folder = Path(folder).resolve()
    if not folder.is_dir():
        raise ReconError(f"--images {folder}: not a folder")
    entries = images_entries(folder, bundle)
    cameras, readers = {}, {}
    for name, rel in sorted(entries.cameras.items()):
        if name not in bundle.cameras:
            raise ReconError(f"{folder / IMAGES_FILE}: cameras.{name}: no camera of that name in bundle {bundle.seq}")
        path = folder / rel
        first = entries.first_frame.get(name, 0)
        if path.is_dir():
            if name in entries.first_frame:
                raise ReconError(f"{folder / IMAGES_FILE}: first_frame.{name}: camera {name}'s images are a folder, "
                                 "whose file names give the frames")
            reader = _folder_reader(name, path)
        elif path.is_file():
            reader = _video_reader(name, path, first)
        else:
            raise ReconError(f"{path}: camera {name}: no such video or folder")
        cam = bundle.cameras[name]
        path = reader.files[int(reader.frames[0])] if reader.files else path  # a folder: its first image
        origin = entries.crop_origin_px.get(name)
        if origin is None and reader.size != tuple(cam.resolution):
            raise ReconError(f"{path}: camera {name}: images of {reader.size[0]} x {reader.size[1]} px but the "
                             f"calibration's camera is {cam.resolution[0]} x {cam.resolution[1]}: if they are a crop "
                             f"of it, give its origin in {IMAGES_FILE} (crop_origin_px); other sizes are not read")
        if origin is not None:
            if origin[0] + reader.size[0] > cam.resolution[0] or origin[1] + reader.size[1] > cam.resolution[1]:
                raise ReconError(f"{path}: camera {name}: images of {reader.size[0]} x {reader.size[1]} px cropped at "
                                 f"{origin} reach beyond the calibration's {cam.resolution[0]} x "
                                 f"{cam.resolution[1]}")
            reader.pad = (origin[1], cam.resolution[1] - origin[1] - reader.size[1], origin[0],
                          cam.resolution[0] - origin[0] - reader.size[0])
        cameras[name], readers[name] = cam, reader
    return ImageSource(folder, cameras, readers, cache_mb)


def with_shared_clock(bundle: Bundle, source: ImageSource, fps: Fraction | None) -> Bundle:
    """A bundle without sync tables given one clock: every camera's frame ``k`` at ``k / fps`` (the rule
    ``reconstruct`` applies to the detections, :func:`~dome_calib.recon.people.sources.stream_layouts`); a bundle
    with sync tables as it is. The cameras must share one stream type (one synchronised rig)."""
    if bundle.sync is not None:
        return bundle
    if fps is None:
        raise ReconError(f"bundle {bundle.seq} has no sync tables, so the images' frame rate is unknown: give --fps "
                         "or --videos")
    kinds = sorted({str(bundle.cameras[n].type) for n in source.names})
    if len(kinds) != 1 or kinds[0] == "kinect-color":
        raise ReconError(f"bundle {bundle.seq} has no sync tables but the images hold cameras of {', '.join(kinds)}: "
                         "one stream only (or add the sync tables)")
    frames = np.unique(np.concatenate([source.frame_indices(n) for n in source.names]))
    period = float(1000 / Fraction(fps))
    table = SyncTable(index=frames, univ_time_ms=frames * period)
    return replace(bundle, sync=SyncTables(streams={kinds[0]: table}))
