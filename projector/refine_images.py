"""The image work of the keypoint refinement (:mod:`projector.refine`): one task per image, run where the image is.

The refinement needs every image of a scene twice, with a gather on the head in between:

1. :func:`reference_patches`: the patches (``(2 r + 1)^2`` pixels) around the keypoints of the points whose
   reference view is this image (:func:`sample_patches`);
2. :func:`align_image`: this image's other observations aligned against their points' reference patches, sent
   with the task (:func:`align_patches`: Gauss-Newton on shift, gain and offset through the surface's warp).

A task is a module-level function of a picklable item ``(camera, image path, job)``, the shape of the feature
tasks (:func:`projector.features.extract_image`), so the executor that extracted the features runs these with the
same placement: on a Dask cluster each is pinned to the capture node that holds its image, which reads it from its
own disk and proves what it read (:mod:`dome_calib.pipeline.cluster`). A result is small (the patches or the
shifts of that image's observations) and carries its image's key; the head writes it into the observations' own
slots in key order, so the refined keypoints are the same bits whoever ran the tasks. An image a task cannot read
is a failure naming the path and why, never an empty result.

The kernels are compiled (numba, no GIL: a thread executor runs them in parallel too); the result per observation
depends on that observation's inputs only.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import cv2
import numpy as np

from dome_calib import exact
from dome_calib.jit import njit


@njit(nogil=True, boundscheck=False)
def _bilinear(img, x, y):
    """Value and exact derivatives of the bilinear interpolant of img at (x, y); nan outside."""
    h, w = img.shape
    if not (x >= 0.0 and y >= 0.0 and x <= w - 1.0 and y <= h - 1.0):
        return np.nan, 0.0, 0.0
    x0 = min(int(x), w - 2)
    y0 = min(int(y), h - 2)
    fx, fy = x - x0, y - y0
    a, b = np.float64(img[y0, x0]), np.float64(img[y0, x0 + 1])
    c, d = np.float64(img[y0 + 1, x0]), np.float64(img[y0 + 1, x0 + 1])
    top, bottom = a + fx * (b - a), c + fx * (d - c)
    return top + fy * (bottom - top), (1.0 - fy) * (b - a) + fy * (d - c), bottom - top


@njit(nogil=True, boundscheck=False)
def sample_patches(img, uv, offsets):
    """(N, K) the image bilinearly sampled at uv (N, 2) + offsets (K, 2) (nan outside)."""
    out = np.empty((uv.shape[0], offsets.shape[0]), dtype=np.float64)
    for n in range(uv.shape[0]):
        for k in range(offsets.shape[0]):
            out[n, k] = _bilinear(img, uv[n, 0] + offsets[k, 0], uv[n, 1] + offsets[k, 1])[0]
    return out


@njit(nogil=True, boundscheck=False)
def _solve4(H, g, x):
    """x = H^-1 g for a symmetric positive definite 4 x 4 H (Cholesky, in place in H); False if not."""
    for j in range(4):
        d = H[j, j]
        for k in range(j):
            d -= H[j, k] * H[j, k]
        if not d > 1e-12 * (1.0 + abs(H[j, j])):
            return False
        H[j, j] = np.sqrt(d)
        for i in range(j + 1, 4):
            v = H[i, j]
            for k in range(j):
                v -= H[i, k] * H[j, k]
            H[i, j] = v / H[j, j]
    for i in range(4):
        v = g[i]
        for k in range(i):
            v -= H[i, k] * x[k]
        x[i] = v / H[i, i]
    for i in range(3, -1, -1):
        v = x[i]
        for k in range(i + 1, 4):
            v -= H[k, i] * x[k]
        x[i] = v / H[i, i]
    return True


@njit(nogil=True, boundscheck=False)
def align_patches(img, uv, A, ref, offsets, weights, iterations, max_shift):
    """Gauss-Newton per observation: shift d (N, 2) of uv (N, 2) such that img at ``uv + d + A offsets`` best
    matches ``gain * ref + bias`` (ref (N, K), weights (K,)). Returns d and the weighted correlation (nan: the
    patch left the image or the fit failed). Stops when a step moves the keypoint by less than 1e-3 px."""
    n_obs, K = ref.shape
    shift = np.zeros((n_obs, 2))
    zncc = np.full(n_obs, np.nan)
    H = np.zeros((4, 4))
    g = np.zeros(4)
    step = np.zeros(4)
    vals = np.empty(K)
    ox = np.empty(K)
    oy = np.empty(K)
    for n in range(n_obs):
        for k in range(K):
            ox[k] = uv[n, 0] + A[n, 0, 0] * offsets[k, 0] + A[n, 0, 1] * offsets[k, 1]
            oy[k] = uv[n, 1] + A[n, 1, 0] * offsets[k, 0] + A[n, 1, 1] * offsets[k, 1]
        dx, dy, gain, bias = 0.0, 0.0, 1.0, 0.0
        ok = True
        for _ in range(iterations):
            H[:] = 0.0
            g[:] = 0.0
            for k in range(K):
                v, gx, gy = _bilinear(img, ox[k] + dx, oy[k] + dy)
                if v != v:
                    ok = False
                    break
                r = ref[n, k]
                w = weights[k]
                e = w * (v - gain * r - bias)
                g[0] -= gx * e
                g[1] -= gy * e
                g[2] += r * e
                g[3] += e
                wgx, wgy = w * gx, w * gy
                H[0, 0] += wgx * gx
                H[1, 0] += wgy * gx
                H[1, 1] += wgy * gy
                H[2, 0] -= wgx * r
                H[2, 1] -= wgy * r
                H[2, 2] += w * r * r
                H[3, 0] -= wgx
                H[3, 1] -= wgy
                H[3, 2] += w * r
                H[3, 3] += w
            if not ok or not _solve4(H, g, step):
                ok = False
                break
            dx += step[0]
            dy += step[1]
            gain += step[2]
            bias += step[3]
            if dx * dx + dy * dy > 4.0 * max_shift * max_shift:
                ok = False
                break
            if step[0] * step[0] + step[1] * step[1] < 1e-6:
                break
        if not ok:
            continue
        # weighted correlation of the final patches
        sw = swv = swr = 0.0
        for k in range(K):
            vals[k] = _bilinear(img, ox[k] + dx, oy[k] + dy)[0]
            sw += weights[k]
            swv += weights[k] * vals[k]
            swr += weights[k] * ref[n, k]
        mv, mr = swv / sw, swr / sw
        cvv = crr = cvr = 0.0
        for k in range(K):
            a, b = vals[k] - mv, ref[n, k] - mr
            cvv += weights[k] * a * a
            crr += weights[k] * b * b
            cvr += weights[k] * a * b
        if cvv > 0.0 and crr > 0.0:
            shift[n, 0], shift[n, 1] = dx, dy
            zncc[n] = cvr / np.sqrt(cvv * crr)
    return shift, zncc



@dataclass(frozen=True)
class PatchGrid:
    """The patch and the fit, the same on every worker: radius (px), the weights' Gaussian (units of the radius),
    Gauss-Newton iterations, the largest shift a fit may take (px)."""

    radius_px: int
    window_sigma: float
    iterations: int = 0
    max_shift_px: float = 1.0

    def offsets_and_weights(self) -> tuple[np.ndarray, np.ndarray]:
        """(K, 2) the patch's pixel offsets (x, y) and (K,) their Gaussian weights."""
        r = self.radius_px
        gy, gx = np.mgrid[-r:r + 1, -r:r + 1]
        offsets = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(np.float64)
        # exact.exp, not np.exp (Intel's SVML on an AVX-512 CPU): the weights, hence every refined keypoint, are the
        # same bits on every CPU (docs/benchmarks.md, "The older CPU, bisected")
        weights = exact.exp(-0.5 * np.sum(offsets ** 2, axis=1) / (self.window_sigma * max(r, 1)) ** 2)
        return offsets, weights


@dataclass(frozen=True, kw_only=True)
class ImageJob:
    """One image's work: its key (the head's order), keypoints (N, 2) px; to align, also the warps (N, 2, 2) from
    the reference views and the reference patches (N, K)."""

    key: int
    uv_px: np.ndarray
    grid: PatchGrid
    warps: np.ndarray | None = None
    ref_patches: np.ndarray | None = None


@dataclass(kw_only=True)
class ImageOutput:
    """What a task returns: the key, then the patches (N, K) (phase 1) or the shifts (N, 2) px and correlations
    (N,) (phase 2), or why the image could not be read."""

    key: int
    values: np.ndarray | None = None
    zncc: np.ndarray | None = None
    failure: str | None = None


def read_grey(path: str, kept: dict[str, np.ndarray] | None = None) -> tuple[np.ndarray | None, str | None]:
    """The image as 8-bit grey (H, W) with the sensor's pixels (no EXIF turn), or None and why not. ``kept``: images
    already decoded in this process (path -> image), taken from and added to (see :func:`reference_patches`)."""
    if kept is not None and path in kept:
        return kept[path], None
    if not os.path.isfile(path):
        return None, f"image not found ({path})"
    try:
        image = cv2.imread(path, cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
    except cv2.error:
        image = None
    if image is None:
        return None, f"unreadable image, not a valid PNG ({path})"
    if kept is not None:
        kept[path] = image
    return image, None


def reference_patches(task: tuple[str, str, ImageJob], kept: dict[str, np.ndarray] | None = None) -> ImageOutput:
    """Task, phase 1: the patches around ``job.uv_px`` in the image at the path (``(camera, path, job)``). ``kept``
    (the head's own threads only: a dict shared by the tasks of one scene): the decoded image is kept there for the
    alignment, which then does not decode the PNG again."""
    _, path, job = task
    image, why = read_grey(path, kept)
    if image is None:
        return ImageOutput(key=job.key, failure=why)
    offsets, _ = job.grid.offsets_and_weights()
    return ImageOutput(key=job.key, values=sample_patches(image, job.uv_px, offsets))


def align_image(task: tuple[str, str, ImageJob], kept: dict[str, np.ndarray] | None = None) -> ImageOutput:
    """Task, phase 2: the shifts and correlations of ``job.uv_px`` aligned against ``job.ref_patches`` (``kept``: as
    for :func:`reference_patches`)."""
    _, path, job = task
    image, why = read_grey(path, kept)
    if image is None:
        return ImageOutput(key=job.key, failure=why)
    offsets, weights = job.grid.offsets_and_weights()
    shift, zncc = align_patches(image, job.uv_px, job.warps, job.ref_patches, offsets, weights, job.grid.iterations,
                                job.grid.max_shift_px)
    return ImageOutput(key=job.key, values=shift, zncc=zncc)
