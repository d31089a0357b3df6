"""What the patch stage reads: images of named cameras at their own frames, and the patch's appearance in them.

A :class:`FrameSource` gives, per camera name, the frame indices it holds (of the camera's own stream, looked up
in the bundle's sync tables), the camera as imaged (its calibration, scaled if the images are) and an 8-bit grey
image of a frame. :class:`dome_calib.synth.textured.TexturedScene` is one; a folder of videos is another.

Pixels: OpenCV's convention (the centre of the top-left pixel is (0, 0)); images are sampled bilinearly
(``cv2.remap``), 0 outside the image.
"""
from __future__ import annotations

from typing import Protocol

import cv2
import numpy as np

from dome_calib.bundle import Camera
from dome_calib.recon.project import ViewSet, project_view

#: A patch's appearance is sampled on this many points per side of its square (spacing size / (n - 1)).
GRID_SIDE = 7
#: Below this standard deviation (grey levels) a sample has no texture: its NCC is 0.
MIN_STD_DN = 2.0
_REMAP_COLS = 4096


class FrameSource(Protocol):
    def frame_indices(self, camera: str) -> np.ndarray: ...

    def camera(self, camera: str) -> Camera: ...

    def gray(self, camera: str, frame: int) -> np.ndarray: ...


def sample(gray: np.ndarray, uv_px: np.ndarray) -> np.ndarray:
    """(H, W) uint8 or float32 image, (..., 2) pixels -> (...) float32 bilinear samples (0 outside the image)."""
    uv_px = np.asarray(uv_px)
    shape = uv_px.shape[:-1]
    uv = uv_px.reshape(-1, 2)
    mx, my = _maps(len(uv))
    # the two maps written straight from the pixels (cast to float32 on assignment, as astype casts): no interleaved
    # float32 copy and no contiguous copies of its halves (a third of the cost)
    mx.reshape(-1)[:len(uv)], my.reshape(-1)[:len(uv)] = uv[:, 0], uv[:, 1]
    return _remap(gray, mx, my, len(uv), shape)


def sample_windows(gray: np.ndarray, centres_px: np.ndarray, offsets_px: np.ndarray) -> np.ndarray:
    """(H, W) image, (..., 2) window centres, (K, 2) offsets -> (..., K) float32 samples: the bits of
    ``sample(gray, centres_px[..., None, :] + offsets_px)`` (each pixel summed in float64, then cast to float32)
    without the (..., K, 2) float64 array of the sums, which cost more than the sampling (the seeds' depth sweep)."""
    c = np.asarray(centres_px, dtype=float)
    off = np.asarray(offsets_px, dtype=float)
    shape = c.shape[:-1] + (len(off),)
    n = int(np.prod(shape))
    mx, my = _maps(n)
    np.add(c[..., 0, None], off[:, 0], out=mx.reshape(-1)[:n].reshape(shape), casting="unsafe")
    np.add(c[..., 1, None], off[:, 1], out=my.reshape(-1)[:n].reshape(shape), casting="unsafe")
    return _remap(gray, mx, my, n, shape)


def _maps(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The remap's x and y maps for n points, (rows, cols) images (remap's maps: fewer than 32767 rows and columns),
    filled row by row (write the first n of ``reshape(-1)``), the tail past n outside the image."""
    cols = _REMAP_COLS if n > _REMAP_COLS else max(n, 1)
    rows = -(-n // cols)
    mx, my = np.empty((rows, cols), np.float32), np.empty((rows, cols), np.float32)
    mx.reshape(-1)[n:], my.reshape(-1)[n:] = -100.0, -100.0
    return mx, my


def _remap(gray: np.ndarray, mx: np.ndarray, my: np.ndarray, n: int, shape: tuple) -> np.ndarray:
    if n == 0:
        return np.zeros(shape, np.float32)
    out = cv2.remap(gray, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.reshape(-1)[:n].astype(np.float32, copy=False).reshape(shape)


def ncc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Normalised cross-correlation over the last axis of (..., G) samples -> (...) in [-1, 1] (0 where either side
    has less than :data:`MIN_STD_DN` of texture)."""
    return ncc_centred(*centred(a), *centred(b))


def centred(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(..., G) samples -> their deviations from the mean (..., G) and variance (...): :func:`ncc`'s first half, to
    compute once for samples compared more than once."""
    a = a - a.mean(-1, keepdims=True)
    return a, (a * a).mean(-1)


def ncc_centred(a: np.ndarray, va: np.ndarray, b: np.ndarray, vb: np.ndarray) -> np.ndarray:
    """:func:`ncc` of samples already :func:`centred`."""
    ok = (va > MIN_STD_DN ** 2) & (vb > MIN_STD_DN ** 2)
    return np.where(ok, (a * b).mean(-1) / np.sqrt(np.where(ok, va * vb, 1.0)), 0.0)


def patch_axes(X0: np.ndarray, X1: np.ndarray, X2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Patches' three points (N, 3) -> orthonormal (u, v, normal) (N, 3) each: u along X1 - X0, v the part of
    X2 - X0 orthogonal to it, normal = u x v."""
    u = X1 - X0
    u = u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
    v = X2 - X0
    v = v - np.sum(v * u, 1, keepdims=True) * u
    v = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    return u, v, np.cross(u, v)


def patch_grid_cm(X0: np.ndarray, X1: np.ndarray, X2: np.ndarray, size_cm: float) -> np.ndarray:
    """(N, 3) x 3 patch points -> (N, GRID_SIDE^2, 3) world points of the patch's square (side ``size_cm``)."""
    u, v, _ = patch_axes(X0, X1, X2)
    g = (np.arange(GRID_SIDE) / (GRID_SIDE - 1) - 0.5) * size_cm
    a, b = (x.ravel() for x in np.meshgrid(g, g))
    return X0[:, None] + a[None, :, None] * u[:, None] + b[None, :, None] * v[:, None]


def project_one(views: ViewSet, v: int, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(..., 3) world points into view ``v`` -> ((..., 2) pixels, (...) visible: in front, in lens, in image)."""
    shape = X.shape[:-1]
    uv, visible = project_view(views, v, X.reshape(-1, 3))
    return uv.reshape(*shape, 2), visible.reshape(shape)
