"""Kinect capture folders and checkerboard corner detection, with a reason for every rejected frame.

Folder layout (one subfolder per sensor)::

    KINECT_FOLDER/KINECTNODE<n>/ir_<k>.png      IR image, 512x424, 8- or 16-bit grey
                              color_<k>.png   colour image of the same instant, 1920x1080
                              depth_<k>.png   depth map, uint16 mm (optional; used for the depth bias)

Detection: OpenCV's ``findChessboardCornersSB`` finds the board (on a half-size copy of large images; the classic
``findChessboardCorners`` as a fallback), OpenCV's sharpness estimate (edge widths across both edge directions)
rejects motion blur, then
``cornerSubPix`` refines every corner on the full image (SB alone is off by ~0.3 px on small IR squares).
Corners come back in the board's canonical order (see :mod:`dome_calib.kinect.board`), whatever the view.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from dome_calib.bundle import kinect_node_camera
from dome_calib.errors import CaptureError
from dome_calib.kinect.board import Checkerboard
from dome_calib.options import AtLeast, options
from dome_calib.schema import NonNegFinite, PosFinite

_NO_SHARPNESS = 1000.0  # estimateChessboardSharpness returns 9999 where no edge profile could be measured
_FRAME_RE = re.compile(r"^(ir|color|depth)_(\d+)\.png$")
_CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH
_SB_FLAGS = cv2.CALIB_CB_EXHAUSTIVE  # NORMALIZE_IMAGE loses dark IR boards; cornerSubPix does the accuracy


@options
class DetectOptions:
    """Corner detection and frame rejection thresholds."""

    max_edge_width_px: PosFinite = 3.0  # OpenCV's sharpness (10-90 % rise of black-white edges); sharp boards ~1.7
    min_contrast_dn: NonNegFinite = 15.0  # mean white minus mean black square brightness (8-bit)
    border_margin_px: NonNegFinite = 3.0  # corners closer than this to the image edge: board (partly) cut off
    detect_max_width_px: AtLeast(1) = 1000  # larger images are searched at half size, then refined at full size


@dataclass(kw_only=True)
class SensorFrames:
    """One sensor's frame files keyed by frame index."""

    name: str
    folder: Path
    ir: dict[int, Path] = field(default_factory=dict)
    color: dict[int, Path] = field(default_factory=dict)
    depth: dict[int, Path] = field(default_factory=dict)

    @property
    def indices(self) -> list[int]:
        return sorted(self.ir)


def find_sensor_frames(kinect_folder: str | Path) -> dict[str, SensorFrames]:
    """List ``KINECTNODE<n>/`` subfolders and their frames, checking that IR and colour frames come in pairs.

    Raises :class:`CaptureError` (one line) for a missing folder, no sensor folders, or unpaired frames.
    """
    root = Path(kinect_folder)
    if not root.is_dir():
        raise CaptureError(f"{root}: not a folder")
    for p in sorted(root.iterdir()):
        if p.is_dir() and p.name.upper().startswith("KINECT") and kinect_node_camera(p.name) is None:
            raise CaptureError(f"{p}: not a Kinect node name (KINECTNODE1..KINECTNODE10, the sensor of colour camera "
                               "50_01..50_10): rename the folder")
    nodes = sorted((p for p in root.iterdir() if p.is_dir() and kinect_node_camera(p.name) is not None),
                   key=lambda p: int(p.name.removeprefix("KINECTNODE")))
    if not nodes:
        raise CaptureError(f"{root}: no KINECTNODE<n> folders (expected KINECTNODE1/ir_0000.png, ...)")
    out = {}
    for node in nodes:
        frames = SensorFrames(name=node.name, folder=node)
        for p in node.iterdir():
            m = _FRAME_RE.match(p.name)
            if m:
                getattr(frames, m.group(1))[int(m.group(2))] = p
        if len(frames.ir) != len(frames.color):
            raise CaptureError(f"{node}: {len(frames.ir)} IR frames but {len(frames.color)} colour frames "
                               "(each ir_<k>.png needs its color_<k>.png)")
        unpaired = sorted(set(frames.ir) ^ set(frames.color))
        if unpaired:
            raise CaptureError(f"{node}: frame {unpaired[0]} has an IR or a colour image but not both")
        if not frames.ir:
            raise CaptureError(f"{node}: no ir_<k>.png / color_<k>.png frames")
        out[node.name] = frames
    return out


#: Pillow's modes of a single-channel 16-bit PNG (the depth maps).
_DEPTH_MODES = ("I;16", "I;16B", "I;16L", "I")


def _header(path: Path, what: str) -> tuple[tuple[int, int], str]:
    """(width, height) and Pillow's mode of an image, from its header only (microseconds; no decoding)."""
    try:
        with Image.open(path) as im:
            return im.size, im.mode
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise CaptureError(f"{path}: cannot read the {what} image ({type(exc).__name__}: "
                           f"{str(exc).splitlines()[0] if str(exc) else 'unreadable'})") from None


def check_sensor_frames(frames: SensorFrames, ir_size: tuple[int, int], color_size: tuple[int, int] | None) -> None:
    """Before any detection: every image of the sensor readable, from its header, at its size (IR and depth
    ``ir_size``; colour ``color_size``, or when None one size for all of them) and every depth map single-channel
    16-bit. CaptureError naming the first file that is not."""
    sizes = {"IR": ir_size, "colour": color_size, "depth": ir_size}
    for what, files in (("IR", frames.ir), ("colour", frames.color), ("depth", frames.depth)):
        for k in sorted(files):
            size, mode = _header(files[k], what)
            if sizes[what] is None:
                sizes[what] = size  # the sensor's first colour image sets the size of the others
            if size != tuple(sizes[what]):
                raise CaptureError(f"{files[k]}: {what} image is {size[0]}x{size[1]}, expected "
                                   f"{sizes[what][0]}x{sizes[what][1]}")
            if what == "depth" and mode not in _DEPTH_MODES:
                raise CaptureError(f"{files[k]}: not a single-channel 16-bit depth map (uint16 mm; this image is "
                                   f"{mode})")


def read_gray(path: Path, size: tuple[int, int], what: str) -> np.ndarray:
    """Read an image as 8-bit grey, checking its size (w, h). 16-bit IR is scaled to its 99.9th percentile."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise CaptureError(f"{path}: cannot read the {what} image")
    if (img.shape[1], img.shape[0]) != tuple(size):
        raise CaptureError(f"{path}: {what} image is {img.shape[1]}x{img.shape[0]}, expected {size[0]}x{size[1]}")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8:
        top = max(float(np.percentile(img, 99.9)), 1.0)
        img = np.clip(img.astype(np.float32) * (255.0 / top), 0, 255).astype(np.uint8)
    return img


def read_depth_mm(path: Path, size: tuple[int, int]) -> np.ndarray:
    """Read a uint16 depth map (mm, 0 = no reading) and check its size (w, h)."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.dtype != np.uint16 or img.ndim != 2:
        raise CaptureError(f"{path}: not a single-channel 16-bit depth map (uint16 mm)")
    if (img.shape[1], img.shape[0]) != tuple(size):
        raise CaptureError(f"{path}: depth map is {img.shape[1]}x{img.shape[0]}, expected {size[0]}x{size[1]}")
    return img


@dataclass(kw_only=True)
class BoardDetection:
    """Corners (N, 2) OpenCV px in canonical board order, or None with the reason the image was rejected."""

    corners_px: np.ndarray | None
    reason: str = ""
    edge_width_px: float = float("nan")

    @property
    def ok(self) -> bool:
        return self.corners_px is not None


def _sample(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear grey values at (N, 2) pixel positions."""
    m = cv2.remap(image.astype(np.float32), uv[:, None, 0].astype(np.float32), uv[:, None, 1].astype(np.float32),
                  cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return m.ravel()


def canonical_order(corners_px: np.ndarray, image: np.ndarray, board: Checkerboard) -> tuple[np.ndarray, float]:
    """Reorder detected corners (N, 2) to the board's index r * cols + c; also return the black/white contrast.

    Two ambiguities: handedness (the grid's rows may come bottom-up: the board's x, y axes must turn like the
    image's, the printed face being towards the camera) and a half turn (settled by the colour of the cells:
    cell (i, j) is black when i + j is even).
    """
    g = corners_px.reshape(board.rows, board.cols, 2)
    e_x, e_y = g[0, 1] - g[0, 0], g[1, 0] - g[0, 0]
    if e_x[0] * e_y[1] - e_x[1] * e_y[0] < 0:
        g = g[::-1]
    centres = 0.25 * (g[:-1, :-1] + g[1:, :-1] + g[:-1, 1:] + g[1:, 1:])  # (rows-1, cols-1, 2) cell centres
    values = _sample(image, centres.reshape(-1, 2)).reshape(centres.shape[:2])
    j, i = np.meshgrid(np.arange(board.rows - 1), np.arange(board.cols - 1), indexing="ij")
    even = (i + j) % 2 == 0
    contrast = float(values[~even].mean() - values[even].mean())
    if contrast < 0:
        g = g[::-1, ::-1]
    return g.reshape(-1, 2).copy(), abs(contrast)


def _subpix_window(corners_px: np.ndarray, board: Checkerboard) -> int:
    g = corners_px.reshape(board.rows, board.cols, 2)
    spacing = min(np.linalg.norm(np.diff(g, axis=0), axis=-1).min(), np.linalg.norm(np.diff(g, axis=1), axis=-1).min())
    return int(np.clip(0.45 * spacing, 2, 11))  # wide enough to average noise, short of the next corner


def detect_board(image: np.ndarray, board: Checkerboard, opts: DetectOptions | None = None,
                 what: str = "image") -> BoardDetection:
    """Find the board's inner corners in an 8-bit grey image, or say why the image is unusable.

    Returns a :class:`BoardDetection`; rejection reasons name ``what`` ("IR", "colour"): board not found (cut off,
    hidden, too blurred to find), corners at the image border, too blurred, too little contrast.
    """
    opts = opts or DetectOptions()
    h, w = image.shape
    scale = 2 if w > opts.detect_max_width_px else 1
    search = cv2.resize(image, (w // scale, h // scale), interpolation=cv2.INTER_AREA) if scale > 1 else image
    found, corners = cv2.findChessboardCornersSB(search, board.pattern_size, flags=_SB_FLAGS)
    if not found:  # the classic quad detector finds some small, oblique boards that SB misses
        found, corners = cv2.findChessboardCorners(search, board.pattern_size, flags=_CLASSIC_FLAGS)
    if found:
        corners = (corners.reshape(-1, 2) + 0.5) * scale - 0.5
    elif scale > 1:
        found, corners = cv2.findChessboardCornersSB(image, board.pattern_size, flags=_SB_FLAGS)
    if not found:
        return BoardDetection(corners_px=None, reason=f"{what}: no complete {board.cols}x{board.rows} board found "
                                                      "(cut off, hidden or blurred)")
    corners = corners.reshape(-1, 2).astype(np.float32)
    widths = [float(cv2.estimateChessboardSharpness(image, board.pattern_size, corners.reshape(-1, 1, 2), 0.8,
                                                    vertical)[0][0]) for vertical in (False, True)]
    widths = [v for v in widths if np.isfinite(v) and v < _NO_SHARPNESS]  # OpenCV says 9999 when it cannot measure
    edge_width = max(widths) if widths else float("nan")
    if edge_width > opts.max_edge_width_px:
        return BoardDetection(corners_px=None, edge_width_px=edge_width,
                              reason=f"{what}: blurred (edge width {edge_width:.1f} px > "
                                     f"{opts.max_edge_width_px:g} px)")
    win = _subpix_window(corners, board)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    refined = cv2.cornerSubPix(image, corners.reshape(-1, 1, 2).copy(), (win, win), (-1, -1), criteria).reshape(-1, 2)
    refined = refined.astype(float)
    m = opts.border_margin_px
    if np.any(refined < m) or np.any(refined > np.array([w - 1, h - 1]) - m):
        return BoardDetection(corners_px=None, edge_width_px=edge_width,
                              reason=f"{what}: board touches the image border (cut off)")
    ordered, contrast = canonical_order(refined, image, board)
    if contrast < opts.min_contrast_dn:
        return BoardDetection(corners_px=None, edge_width_px=edge_width,
                              reason=f"{what}: too little contrast ({contrast:.0f} < {opts.min_contrast_dn:g} "
                                     "grey levels)")
    return BoardDetection(corners_px=ordered, edge_width_px=edge_width)
