"""Synthetic Kinect checkerboard captures with ground truth.

For each Kinect sensor: pairs of IR (512x424, 8-bit) and colour (1920x1080, BGR) images of a checkerboard at
varied poses, and the depth map (uint16 mm, 512x424) of the board, written as::

    KINECT_FOLDER/KINECTNODE<n>/ir_<kkkk>.png, color_<kkkk>.png, depth_<kkkk>.png
    KINECT_FOLDER/ground_truth.json

Truth per sensor: IR intrinsics and distortion drawn around the real Kinoptic calibration (f ~ 365 px), the
colour camera = the dome bundle's ``50_<nn>`` camera (intrinsics, distortion and world pose), a depth-to-colour
transform around the real one (baseline ~ 52.8 mm, rotation < 1 deg), a depth bias ``measured = true * (1 +
depth_scale) + depth_bias_mm`` plus noise ``sigma_mm = a + b * z_m^2``. Images are ray-cast through the distorted
camera models with supersampling (:func:`dome_calib.kinect.board.render_board`). A few frames are blurred
(motion blur) or have the board cut off by the image border: a calibrator must reject them.
"""
from __future__ import annotations

import json
import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Annotated

import cv2
import numpy as np

from dome_calib.bundle import Bundle, CameraType, KinectCalibration, KinectSensor
from dome_calib.camera import K_to_intr, intr_to_K, project
from dome_calib import exact
from dome_calib.io_utils import atomic_write_text
from dome_calib.jsonfmt import dumps
from dome_calib.kinect.board import BoardRender, Checkerboard, RayGrid, render_board
from dome_calib.kinect.world import M_WORLD2VGA, sensor_matrices
from dome_calib.options import AtLeast, Field, options
from dome_calib.schema import NonNegFinite, PosFinite

logger = logging.getLogger(__name__)

GENERATOR_VERSION = "kinect_boards/1"
IR_SIZE = (512, 424)
GROUND_TRUTH_FILE = "ground_truth.json"
# Real Kinoptic calibration (kcalibration_171026_cello3, 10 sensors): means and spreads used for the draws.
_IR_INTR_MEAN, _IR_INTR_STD = np.array([365.0, 365.0, 252.6, 205.1]), np.array([0.7, 0.0, 1.7, 3.7])
_IR_DIST_MEAN = np.array([0.0949, -0.2700, 0.0001, 0.0000, 0.0889])
_T_COLOR_FROM_DEPTH_MM, _T_STD_MM = np.array([-52.74, 0.14, 0.10]), np.array([0.2, 0.35, 0.15])
_ROT_STD_DEG = np.array([0.08, 0.10, 0.35])


@options
class KinectBoardsOptions:
    """What to generate. Distances are from the IR camera to the board centre."""

    sensors: list[str] | None = None  # "KINECTNODE<n>"; default: every Kinect colour camera in the bundle
    good_frames: AtLeast(0) = 32
    blurred_frames: AtLeast(0) = 2
    cut_off_frames: AtLeast(0) = 2
    board: Checkerboard = field(default_factory=Checkerboard)
    distance_mm: tuple[PosFinite, PosFinite] = (800.0, 1800.0)
    max_tilt_deg: Annotated[float, Field(ge=0, lt=90)] = 40.0
    ir_supersample: AtLeast(1) = 4
    color_supersample: AtLeast(1) = 2
    ir_noise_dn: NonNegFinite = 2.0
    color_noise_dn: NonNegFinite = 2.0
    depth_noise_mm: tuple[NonNegFinite, NonNegFinite] = (1.0, 0.5)  # sigma_mm = a + b * z_m^2
    depth_bias_mm_max: NonNegFinite = 12.0
    depth_scale_max: NonNegFinite = 0.004
    seed: AtLeast(0) = 0


@dataclass(kw_only=True)
class SensorTruth:
    """Ground truth of one Kinect. Transforms are 4x4 ``b_from_a`` with translations in the unit their name says."""

    name: str
    color_camera: str
    K_depth: np.ndarray
    dist_depth: np.ndarray
    K_color: np.ndarray
    dist_color: np.ndarray
    color_size: tuple[int, int]
    color_from_depth_mm: np.ndarray
    color_from_world_cm: np.ndarray
    depth_bias_mm: float
    depth_scale: float

    @property
    def depth_from_world_cm(self) -> np.ndarray:
        """(4, 4) Panoptic world (cm) -> depth camera (cm)."""
        return _rigid_product(_rigid_inverse(self.color_from_depth_mm, scale=0.1), self.color_from_world_cm)


def _rigid_inverse(T: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """(4, 4) inverse of ``[R t; 0 1]`` through R's cofactors (:mod:`dome_calib.exact`: the same bits on
    every CPU, unlike LAPACK's), its translation times ``scale`` (mm -> cm: 0.1)."""
    R_inv = exact.transpose3(exact.cofactor3(T[:3, :3])) / exact.det3(T[:3, :3])
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R_inv, -exact.matvec3(R_inv, T[:3, 3]) * scale
    return out


def _rigid_product(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(4, 4) ``A @ B`` of two rigid transforms in basic operations."""
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = exact.matmul3(A[:3, :3], B[:3, :3]), exact.matvec3(A[:3, :3], B[:3, 3]) + A[:3, 3]
    return out


def _in_color(T: np.ndarray, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A depth-camera pose (R, t) in the colour camera (``T`` = color_from_depth), in basic operations."""
    return exact.matmul3(T[:3, :3], R), exact.matvec3(T[:3, :3], t) + T[:3, 3]


def color_camera_of(sensor: str) -> str:
    """'KINECTNODE3' -> '50_03' (sensor i <-> colour camera 50_{i:02d})."""
    return f"50_{int(sensor.removeprefix('KINECTNODE')):02d}"


def draw_sensor_truth(name: str, bundle: Bundle, opts: KinectBoardsOptions, rng: np.random.Generator) -> SensorTruth:
    """Draw one sensor's IR intrinsics, depth-colour transform and depth bias; its colour camera is the bundle's."""
    cam = bundle.cameras[color_camera_of(name)]
    intr = _IR_INTR_MEAN + _IR_INTR_STD * rng.standard_normal(4)
    intr[1] = intr[0]  # the real depth cameras have square pixels
    dist = _IR_DIST_MEAN.copy()
    dist[[0, 1, 4]] *= 1.0 + 0.04 * rng.standard_normal()
    dist[[2, 3]] = 3e-4 * rng.standard_normal(2)
    T = np.eye(4)
    T[:3, :3] = exact.rotvec_matrix(np.radians(_ROT_STD_DEG * rng.standard_normal(3)))
    T[:3, 3] = _T_COLOR_FROM_DEPTH_MM + _T_STD_MM * rng.standard_normal(3)
    return SensorTruth(
        name=name, color_camera=cam.name, K_depth=intr_to_K(intr), dist_depth=dist, K_color=cam.K.copy(),
        dist_color=cam.dist.copy(), color_size=cam.resolution, color_from_depth_mm=T,
        color_from_world_cm=cam.cam_from_world,
        depth_bias_mm=float(rng.uniform(-1, 1) * opts.depth_bias_mm_max),
        depth_scale=float(rng.uniform(-1, 1) * opts.depth_scale_max),
    )


def _corners_visible(truth: SensorTruth, board: Checkerboard, R: np.ndarray, t: np.ndarray,
                     margin_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Per outline point of the board: inside the IR image, inside the colour image (with a margin)."""
    pts = np.concatenate([board.outline_mm(8), board.object_points_mm()])
    out = []
    T = truth.color_from_depth_mm
    for (Rc, tc), K, dist, size in (((R, t), truth.K_depth, truth.dist_depth, IR_SIZE),
                                    (_in_color(T, R, t), truth.K_color, truth.dist_color,
                                     truth.color_size)):
        p = project(pts, Rc, tc, K_to_intr(K), dist)
        lo, hi = margin_px, np.asarray(size) - 1 - margin_px
        out.append(p.in_lens & np.all((p.uv_px >= lo) & (p.uv_px <= hi), axis=-1))
    return out[0], out[1]


def sample_board_pose(truth: SensorTruth, opts: KinectBoardsOptions, rng: np.random.Generator,
                      cut_off: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """A ``depth_from_board`` pose (R, t_mm): the whole board in both images, or (``cut_off``) partly outside."""
    board = opts.board
    center_board = np.array([(board.cols - 1) / 2, (board.rows - 1) / 2, 0.0]) * board.square_mm
    for _ in range(500):
        z = rng.uniform(*opts.distance_mm)
        if cut_off:
            xy = rng.uniform(0.55, 0.9, 2) * rng.choice([-1, 1], 2) * [1.0, 0.8]
            xy[rng.integers(2)] *= rng.uniform(0, 0.5)
        else:
            xy = rng.uniform(-1, 1, 2) * [0.3, 0.2]
        axis = rng.standard_normal(2)
        tilt = np.radians(rng.uniform(5.0, opts.max_tilt_deg)) * np.r_[axis, 0.0] / exact.norm3(np.r_[axis, 0.0])
        R = exact.matmul3(exact.rotvec_matrix(tilt),
                          exact.rotvec_matrix(np.array([0.0, 0.0, np.radians(rng.uniform(-25, 25))])))
        t = np.array([xy[0] * z, xy[1] * z, z]) - exact.matvec3(R, center_board)
        ir_in, col_in = _corners_visible(truth, board, R, t, margin_px=8.0)
        if not cut_off and ir_in.all() and col_in.all():
            return R, t
        if cut_off and (not ir_in.all() or not col_in.all()) and ir_in.mean() > 0.3 and col_in.mean() > 0.3:
            return R, t
    raise RuntimeError(f"{truth.name}: could not place a board (cut_off={cut_off}) in 500 tries")


def _motion_blur(image: np.ndarray, length_px: float, angle_rad: float) -> np.ndarray:
    n = int(np.ceil(length_px)) | 1
    kernel = np.zeros((n, n), np.float32)
    c = n // 2
    d = np.array([exact.cos(angle_rad), exact.sin(angle_rad)]) * length_px / 2
    cv2.line(kernel, (int(round(c - d[0])), int(round(c - d[1]))), (int(round(c + d[0])), int(round(c + d[1]))), 1.0, 1)
    return cv2.filter2D(image, -1, kernel / kernel.sum(), borderType=cv2.BORDER_REFLECT)


def _vignetting(size: tuple[int, int], K: np.ndarray, strength: float) -> np.ndarray:
    w, h = size
    u, v = np.meshgrid((np.arange(w) - K[0, 2]) / K[0, 0], (np.arange(h) - K[1, 2]) / K[1, 1])
    q = 1.0 + strength * (u * u + v * v)
    return 1.0 / (q * q)  # not q ** -2: np.power is the CPU's (tests/test_synth_exact.py)


def render_ir(r: BoardRender, truth: SensorTruth, opts: KinectBoardsOptions, rng: np.random.Generator) -> np.ndarray:
    """IR image (uint8): dark room, board lit by the Kinect's emitter (1/z^2, Lambertian), vignetting, noise."""
    z_m = np.nan_to_num(r.depth_mm, nan=1e3) / 1e3
    shading = 200.0 * r.cos_incidence / np.maximum(z_m, 0.3) ** 2 * _vignetting(IR_SIZE, truth.K_depth, 0.4)
    black = 0.12  # printed black still reflects some IR
    img = 6.0 + shading * (black * r.coverage + (1 - black) * r.reflectance)
    img = img + rng.standard_normal(img.shape) * np.sqrt(opts.ir_noise_dn**2 + 0.05 * img)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


@dataclass(kw_only=True)
class ColorScene:
    """What stays fixed between one colour camera's frames (float32): room background BGR (H, W, 3), board
    illumination (H, W), both with vignetting, and a bank of unit Gaussian noise a little larger than the image
    (each frame takes a randomly shifted window of it: independent pixels within a frame, 10x cheaper)."""

    background: np.ndarray
    light: np.ndarray
    noise: np.ndarray


_NOISE_MARGIN = 64


def color_scene(truth: SensorTruth, rng: np.random.Generator) -> ColorScene:
    w, h = truth.color_size
    u, v = np.meshgrid(np.linspace(0, 1, w, dtype=np.float32), np.linspace(0, 1, h, dtype=np.float32))
    vignette = _vignetting(truth.color_size, truth.K_color, 0.15).astype(np.float32)
    bg = (70.0 + 30.0 * u * (1 - v) + 15.0 * exact.sin(3 * u + 2 * v)) * vignette
    tint = np.array([0.95, 1.0, 1.06], dtype=np.float32)  # BGR: a warm room
    noise = rng.standard_normal((h + _NOISE_MARGIN, w + _NOISE_MARGIN, 3), dtype=np.float32)
    return ColorScene(background=bg[..., None] * tint, light=(0.9 + 0.1 * u) * vignette, noise=noise)


def render_color(r: BoardRender, scene: ColorScene, opts: KinectBoardsOptions, rng: np.random.Generator) -> np.ndarray:
    """Colour image (uint8 BGR): the room background, the lit grey board (black 30, white 215), noise."""
    h, w = r.coverage.shape
    img = scene.background.copy()
    rows, cols = np.nonzero(r.coverage.any(axis=1))[0], np.nonzero(r.coverage.any(axis=0))[0]
    if len(rows):
        roi = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        cover = r.coverage[roi].astype(np.float32)
        board = scene.light[roi] * (30.0 * cover + 185.0 * r.reflectance[roi].astype(np.float32))
        img[roi] = img[roi] * (1 - cover)[..., None] + board[..., None]
    dy, dx = rng.integers(0, _NOISE_MARGIN, 2)
    img += np.float32(opts.color_noise_dn) * scene.noise[dy:dy + h, dx:dx + w]
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)


def render_depth(r: BoardRender, truth: SensorTruth, opts: KinectBoardsOptions, rng: np.random.Generator) -> np.ndarray:
    """Depth map (uint16 mm, 0 = no reading) of the board: bias, range-dependent noise, 1 mm quantisation."""
    valid = (r.coverage >= 1.0) & np.isfinite(r.depth_mm)
    z = np.where(valid, r.depth_mm, 0.0)
    a, b = opts.depth_noise_mm
    sigma = (a + b * (z / 1e3) ** 2) * np.where(r.reflectance < 0.5, 1.4, 1.0)  # dark squares return less light
    measured = z * (1.0 + truth.depth_scale) + truth.depth_bias_mm + sigma * rng.standard_normal(z.shape)
    return np.where(valid, np.clip(np.rint(measured), 1, 65535), 0).astype(np.uint16)


def _frame_kinds(opts: KinectBoardsOptions, rng: np.random.Generator) -> list[str]:
    kinds = ["good"] * opts.good_frames + ["blurred"] * opts.blurred_frames + ["cut_off"] * opts.cut_off_frames
    return [kinds[i] for i in rng.permutation(len(kinds))]


def _write_png(path: Path, image: np.ndarray) -> None:
    if not cv2.imwrite(str(path), image):
        raise OSError(f"{path}: could not write image")


def generate_sensor(truth: SensorTruth, folder: Path, opts: KinectBoardsOptions, rng: np.random.Generator,
                    on_frame: Callable[[], None] | None = None) -> list[dict]:
    """Render and write one sensor's frames into ``folder``; return the per-frame truth records."""
    folder.mkdir(parents=True, exist_ok=True)
    board = opts.board
    rays_ir = RayGrid.build(K_to_intr(truth.K_depth), truth.dist_depth, IR_SIZE)
    rays_col = RayGrid.build(K_to_intr(truth.K_color), truth.dist_color, truth.color_size)
    scene = color_scene(truth, rng)
    T = truth.color_from_depth_mm
    records = []
    for k, kind in enumerate(_frame_kinds(opts, rng)):
        R, t = sample_board_pose(truth, opts, rng, cut_off=kind == "cut_off")
        r_ir = render_board(board, rays_ir, R, t, supersample=opts.ir_supersample)
        r_col = render_board(board, rays_col, *_in_color(T, R, t), supersample=opts.color_supersample)
        ir, color = render_ir(r_ir, truth, opts, rng), render_color(r_col, scene, opts, rng)
        depth = render_depth(r_ir, truth, opts, rng)
        if kind == "blurred":  # the board moved during the exposure: both cameras smear it
            angle = rng.uniform(0, np.pi)
            ir = _motion_blur(ir, rng.uniform(7, 11), angle)
            color = _motion_blur(color, rng.uniform(22, 32), angle)
        _write_png(folder / f"ir_{k:04d}.png", ir)
        _write_png(folder / f"color_{k:04d}.png", color)
        _write_png(folder / f"depth_{k:04d}.png", depth)
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = R, t
        records.append({"index": k, "kind": kind, "depth_from_board_mm": pose})
        if on_frame is not None:
            on_frame()
    return records


def generate_kinect_boards(bundle: Bundle, out_folder: str | Path, opts: KinectBoardsOptions | None = None,
                           on_frame: Callable[[], None] | None = None) -> dict:
    """Write a synthetic Kinect checkerboard capture into ``out_folder``; return the ground truth (also saved).

    Args:
        bundle: dome calibration giving each sensor's colour camera (``50_<nn>``: intrinsics and world pose).
        out_folder: the KINECT_FOLDER to create (``KINECTNODE<n>/`` subfolders plus ``ground_truth.json``).
    Example:
        >>> generate_kinect_boards(load_bundle("tests/data/panoptic"), "/tmp/kinect",
        ...                        KinectBoardsOptions(sensors=["KINECTNODE1"], good_frames=10))
    """
    opts = opts or KinectBoardsOptions()
    out = Path(out_folder)
    names = opts.sensors or [f"KINECTNODE{int(n[3:])}" for n in bundle.of_type(CameraType.KINECT_COLOR)]
    missing = [n for n in names if color_camera_of(n) not in bundle.cameras]
    if missing:
        raise ValueError(f"bundle has no colour camera for {', '.join(missing)}")
    rng = np.random.default_rng(opts.seed)
    sensors = {}
    for name in names:
        truth = draw_sensor_truth(name, bundle, opts, rng)
        frames = generate_sensor(truth, out / name, opts, rng, on_frame)
        record = {k: v for k, v in asdict(truth).items()}
        record |= {"depth_from_world_cm": truth.depth_from_world_cm, "frames": frames}
        sensors[name] = record
        logger.info("%s: %d frames written", name, len(frames))
    truth_doc = {
        "generator_version": GENERATOR_VERSION, "seed": opts.seed,
        "bundle_calib_data_source": bundle.calib_data_source,
        "board": asdict(opts.board), "ir_size": list(IR_SIZE),
        "depth_model": "measured_mm = true_mm * (1 + depth_scale) + depth_bias_mm + noise; "
                       "noise sigma_mm = a + b * z_m^2 (x1.4 on black squares)",
        "depth_noise_mm": list(opts.depth_noise_mm), "ir_noise_dn": opts.ir_noise_dn,
        "color_noise_dn": opts.color_noise_dn,
        "frames": "transforms are b_from_a 4x4; depth_from_board_mm in mm; *_cm in cm (Panoptic world)",
        "sensors": sensors,
    }
    atomic_write_text(out / GROUND_TRUTH_FILE, dumps(truth_doc) + "\n")
    return load_ground_truth(out)


def load_ground_truth(folder: str | Path) -> dict:
    """Read ``ground_truth.json``; matrices come back as numpy arrays."""
    doc = json.loads((Path(folder) / GROUND_TRUTH_FILE).read_text(encoding="utf-8"))
    for s in doc["sensors"].values():
        for key, value in s.items():
            if isinstance(value, list) and key != "frames" and key != "color_size":
                s[key] = np.asarray(value, dtype=float)
        for f in s["frames"]:
            f["depth_from_board_mm"] = np.asarray(f["depth_from_board_mm"], dtype=float)
    return doc


def truth_kcalibration(truth_doc: dict) -> KinectCalibration:
    """The ground truth as a :class:`KinectCalibration` (for a ground-truth bundle's ``kcalibration_<seq>.json``)."""
    sensors = {}
    for name, s in truth_doc["sensors"].items():
        sensors[name] = KinectSensor(
            name=name, K_depth=s["K_depth"], dist_depth=s["dist_depth"], depth_size=tuple(truth_doc["ir_size"]),
            K_color=s["K_color"], dist_color=s["dist_color"], color_size=tuple(s["color_size"]),
            **sensor_matrices(s["color_from_depth_mm"], s["color_from_world_cm"]),
            depth_bias_mm=float(s["depth_bias_mm"]), depth_scale=float(s["depth_scale"]),
        )
    return KinectCalibration(sensors=sensors, M_world2vga=M_WORLD2VGA.copy(), calib_data_source=GENERATOR_VERSION)

