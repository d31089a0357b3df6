"""Stage 1: SIFT features of every image of a scene, stored in the scene's COLMAP database.

One task per image (:func:`extract_image`, run through an :mod:`dome_calib.executor`): read the PNG, check it
(unreadable, wrong size, blank, overexposed), run pycolmap's CPU SIFT with one thread, and return keypoints
and uint8 descriptors; the main process writes them to the database in camera-name order (not completion
order), so the database's ids do not depend on where or when the tasks ran. A rerun skips images that already have
features. Images that fail a check or give too few features are reported per camera and left out of the
database, so mapping never sees them.
"""
from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pycolmap

from dome_calib.bundle import NOMINAL_RESOLUTION, Camera, CameraType, camera_type_from_name
from dome_calib.colmap_options import colmap_options
from dome_calib.executor import Executor, SerialExecutor, in_order
from dome_calib.layout import INTRINSICS_STATS
from dome_calib.progress import Progress, counting
from projector.database import add_image, camera_of_image, descriptors_to_uint8, image_name, images_with_features, write_features
from dome_calib.options import AtLeast, UnitInterval, options
from dome_calib.schema import NonNegFinite, PosFinite

logger = logging.getLogger(__name__)


@options
class FeatureOptions:
    """SIFT and image-check options. ``first_octave = 0`` (no 2x upsampling) is ~4x faster than COLMAP's
    default -1 and gives ~1,000 (VGA) to ~5,000 (HD) features on projector patterns: plenty for matching."""

    max_num_features: AtLeast(1) = 4096
    first_octave: AtLeast(-1) = 0
    peak_threshold: PosFinite = 0.02 / 3
    blank_max_std: NonNegFinite = 3.0  # grey-level std below this: blank image
    overexposed_fraction: UnitInterval = 0.5  # more than this fraction of pixels >= 250: overexposed
    min_features: AtLeast(0) = 60  # fewer: the camera does not see the tent (or sees too little of it)
    #: 0: full resolution. Else an image whose longer side exceeds this is reduced by the smallest integer factor
    #: that fits (box filter, :func:`reduction_factor`) and its keypoints are put back in full-resolution pixels.
    max_image_size_px: AtLeast(0) = 0


@dataclass(kw_only=True)
class ImageResult:
    """What one extraction task returns (picklable). ``keypoints`` (N, 4) COLMAP px; ``descriptors`` (N, 128) uint8."""

    camera: str
    keypoints: np.ndarray | None = None
    descriptors: np.ndarray | None = None
    shape: tuple[int, int] | None = None  # (height, width)
    failure: str | None = None
    seconds: float = 0.0


@dataclass(kw_only=True)
class FeatureReport:
    """Per-scene outcome: features per camera, failures per camera with the reason, wall time."""

    scene: str
    num_features: dict[str, int] = field(default_factory=dict)
    failures: dict[str, str] = field(default_factory=dict)
    reused: int = 0
    seconds: float = 0.0


_EXTRACTORS: dict[tuple, object] = {}  # per worker process: pycolmap extractor per option set


def _extractor(options: FeatureOptions):
    key = (options.max_num_features, options.first_octave, options.peak_threshold)
    if key not in _EXTRACTORS:
        opts = colmap_options(pycolmap.FeatureExtractionOptions)
        opts.max_image_size = 8192
        opts.sift.max_num_features = options.max_num_features
        opts.sift.first_octave = options.first_octave
        opts.sift.peak_threshold = options.peak_threshold
        _EXTRACTORS[key] = pycolmap.FeatureExtractor.create(opts, pycolmap.Device.cpu)
    return _EXTRACTORS[key]


def check_image(image: np.ndarray | None, options: FeatureOptions) -> str | None:
    """Why an image cannot be used (None if it can): unreadable, blank or overexposed."""
    if image is None:
        return "unreadable image (not a valid PNG)"
    if float(image.std()) < options.blank_max_std:
        return f"blank image (grey-level std {image.std():.1f} < {options.blank_max_std})"
    saturated = float(np.mean(image >= 250))
    if saturated > options.overexposed_fraction:
        return f"overexposed image ({100 * saturated:.0f}% of pixels saturated)"
    return None


def reduction_factor(width: int, height: int, max_image_size_px: int) -> int:
    """The integer factor an image is reduced by before SIFT: 1, or the smallest that brings its longer side to at
    most ``max_image_size_px`` (0: no limit). 1920x1080 at 960 -> 2."""
    if max_image_size_px <= 0:
        return 1
    return max(1, -(-max(width, height) // max_image_size_px))


def _reduced(image: np.ndarray, factor: int) -> np.ndarray:
    """The image reduced ``factor`` times by averaging factor x factor blocks (a trailing partial block is cut)."""
    h, w = (image.shape[0] // factor) * factor, (image.shape[1] // factor) * factor
    return cv2.resize(image[:h, :w], (w // factor, h // factor), interpolation=cv2.INTER_AREA)


def extract_image(task: tuple[str, str, FeatureOptions]) -> ImageResult:
    """Task: SIFT of one image file. ``task = (camera_name, image_path, options)``. Never raises for bad images.

    With ``options.max_image_size_px`` a large image is reduced by an integer factor f first; COLMAP pixel
    coordinates have their origin at the image corner, so a keypoint at (x, y) of the reduced image is at
    (f x, f y) of the full one exactly (the block of f x f pixels it averages), and its scale is f times larger.
    """

    camera, path, options = task
    t0 = time.perf_counter()
    try:
        image = cv2.imread(path, cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)  # the sensor's pixels: no EXIF turn
    except cv2.error:
        image = None
    reason = check_image(image, options)
    if reason is not None:
        return ImageResult(camera=camera, failure=reason, seconds=time.perf_counter() - t0)
    factor = reduction_factor(image.shape[1], image.shape[0], options.max_image_size_px)
    small = image if factor == 1 else _reduced(image, factor)
    kps, desc = _extractor(options).extract(pycolmap.Bitmap.from_array(np.ascontiguousarray(small)))
    kp = pycolmap.keypoints_to_matrix(kps)
    if factor > 1:
        kp = kp.copy()
        kp[:, :3] *= factor  # x, y (corner-origin px) and scale; the orientation stays
    d = descriptors_to_uint8(desc.data)
    result = ImageResult(camera=camera, keypoints=kp, descriptors=d, shape=image.shape, seconds=time.perf_counter() - t0)
    if len(kp) < options.min_features:
        result.failure = f"too few features ({len(kp)} < {options.min_features}): camera does not see the tent?"
    return result


def nominal_camera(name: str, resolution: tuple[int, int]) -> Camera:
    """A camera with the nominal intrinsics of its type (from the name, else the resolution), identity pose."""
    ctype = camera_type_from_name(name)
    if ctype == CameraType.VGA and tuple(resolution) != NOMINAL_RESOLUTION[CameraType.VGA]:
        ctype = CameraType.HD  # a name outside the dome's scheme: the image size tells
    stats = INTRINSICS_STATS[ctype]
    w, h = resolution
    f = stats["f"][0] * (w / NOMINAL_RESOLUTION[ctype][0])
    cx = (w - 1) / 2 + stats["c"][0][0]
    cy = (h - 1) / 2 + stats["c"][1][0]
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])
    return Camera(name=name, type=ctype, resolution=(int(w), int(h)), K=K, dist=np.array(stats["dist"][0], float),
                  R=np.eye(3), t_cm=np.zeros(3), panel=0, node=0)


def _advancing(results: Iterable, advance: Callable[[int], None]) -> Iterator:
    """Pass results through, advancing the progress count as each one arrives (before any reordering)."""
    for res in results:
        advance(1)
        yield res


def extract_features(
    image_dir: str | Path, database_path: str | Path, *, prior: Mapping[str, Camera] | None = None,
    options: FeatureOptions | None = None, executor: Executor | None = None, scene: str = "",
    cameras: list[str] | None = None, progress: Progress | None = None,
) -> FeatureReport:
    """Extract SIFT features of every ``<camera>.png`` in ``image_dir`` into the COLMAP database.

    Args:
        image_dir: a scene folder (``CAPTURE/scenes/<scene>``).
        database_path: the scene's database (created if missing; images already holding features are reused).
        prior: cameras by name whose intrinsics initialise the database cameras (nominal intrinsics otherwise).
        executor: where the per-image tasks run (default: in this process).
        cameras: the images' camera names when they are not all here (on the capture nodes, read by the
            executor's workers there); default every ``*.png`` of ``image_dir``.
        progress: called with (images done, images) as images arrive (those reused first).
    Returns:
        :class:`FeatureReport` with features per camera and failures per camera with the reason.
    """

    options = options or FeatureOptions()
    executor = executor or SerialExecutor()
    image_dir, database_path = Path(image_dir), Path(database_path)
    t0 = time.perf_counter()
    report = FeatureReport(scene=scene or image_dir.name)
    database_path.parent.mkdir(parents=True, exist_ok=True)
    paths = (sorted(image_dir / f"{c}.png" for c in cameras) if cameras is not None
             else sorted(image_dir.glob("*.png")))
    with pycolmap.Database.open(str(database_path)) as db:
        done = images_with_features(db)
        for name, image_id in done.items():
            report.num_features[camera_of_image(name)] = db.num_keypoints_for_image(image_id)
        report.reused = len(done)
        todo = [(p.stem, str(p), options) for p in paths if image_name(p.stem) not in done]
        with counting(progress, len(paths)) as advance:
            advance(len(done))
            # written in camera-name order whatever the completion order: image, camera and rig ids are the
            # same on every run, pool or cluster (mapping visits images by id)
            arrived = _advancing(executor.map(extract_image, todo), advance)
            for res in in_order(arrived, [t[0] for t in todo], lambda r: r.camera):
                if res.failure is not None:
                    report.failures[res.camera] = res.failure
                    logger.warning("%s %s: %s", report.scene, res.camera, res.failure)
                    continue
                h, w = res.shape
                cam = prior.get(res.camera) if prior else None
                if cam is not None and tuple(cam.resolution) != (w, h):
                    report.failures[res.camera] = (f"image is {w}x{h} but the prior camera is "
                                                   f"{cam.resolution[0]}x{cam.resolution[1]}")
                    continue
                cam = cam or nominal_camera(res.camera, (w, h))
                existing = db.read_image_with_name(image_name(res.camera))
                image_id = existing.image_id if existing is not None else add_image(db, image_name(res.camera), cam)
                write_features(db, image_id, res.keypoints, res.descriptors)
                report.num_features[res.camera] = len(res.keypoints)
    report.seconds = time.perf_counter() - t0
    logger.info("%s: features of %d images (%d reused), %d failed, %.1f s", report.scene, len(report.num_features),
                report.reused, len(report.failures), report.seconds)
    return report
