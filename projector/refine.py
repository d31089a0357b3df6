"""Sub-pixel refinement of every track's keypoints across its views, on the images' raw intensity.

SIFT puts each keypoint of a track where its own image's scale-space extremum is, independently of the other
views: about 0.2 px of noise per coordinate on the projector patterns. The tent is a smooth surface, so around
a track's 3D point the views are related by a known local warp, and the keypoints can be made consistent with
each other by aligning image patches (the featuremetric refinement of Pixel-Perfect SfM, Lindenberger et al.,
ICCV 2021, here on raw intensity, with the surface giving the warp):

1. Per scene, the tent's normal at each point from its nearest neighbours (the smallest principal axis of
   ``neighbours`` points), and two unit tangents T (3, 2).
2. Per observation, the local affine map from the surface to the image, ``J T`` (2, 2) px per cm (J: the
   projection's Jacobian at the point, distortion included, with the merged cameras). The track's reference view
   is the one that sees the surface finest (largest ``|det J T|``; ties: the first camera by name), and the warp
   from the reference image to another view is ``A = (J T)_view (J T)_ref^-1``.
3. The reference view's patch (``(2 r + 1)^2`` pixels around its keypoint) is compared with every other view's
   image sampled at ``u + d + A g`` (g: the patch's pixel offsets); Gauss-Newton on the shift d and an affine
   change of brightness (gain, offset) minimises the Gaussian-weighted squared difference (bilinear
   interpolation, its exact derivatives). A keypoint moves by d if the fit converged, d stays within
   ``max_shift_px`` and the patches' weighted correlation reaches ``min_zncc``; else it stays where SIFT put it.

The reference keypoint itself is not moved: its error moves all the refined keypoints of its track consistently
(``A`` times it), i.e. the 3D point along the surface, which the bundle adjustment absorbs. Each scene's images
are read once (8-bit grey, kept while the scene is refined), in two threads; the fit is compiled (numba, no GIL),
its result per observation independent of the threads' order. The verdicts (correlation, shift) compare values
quantised to 1e-6, so the same keypoints move on every machine.

Measured (docs/accuracy.md): feature noise against the rendered truth 0.195 -> 0.046 px (panel dome), 0.226 ->
0.058 px (full dome: 1.25 M observations in 22 s on two shared cores).
"""
from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated

import cv2
import numba
import numpy as np
from scipy.spatial import cKDTree

from dome_calib.camera import project_with_jacobians
from dome_calib.rotation import matrix_to_rotvec
from projector.observations import Observations
from dome_calib.options import AtLeast, Field, options
from dome_calib.schema import PosFinite

logger = logging.getLogger(__name__)


@options
class RefineOptions:
    """``patch_radius_px``: the reference patch is (2 r + 1)^2 pixels; ``window_sigma``: the patch weights'
    Gaussian, in units of r. A keypoint moves only if the fit converged within ``max_shift_px`` and the patches'
    weighted correlation reaches ``min_zncc``. Patch radius measured on the panel dome's feature noise (px,
    points fitted at the true cameras; SIFT 0.195): r 4: 0.140, 6: 0.082, 8: 0.058, 10: 0.046; the full dome's
    centres r 8: 0.411 / 1.43 mm (median / max), r 10: 0.338 / 1.16 mm (docs/accuracy.md)."""

    enabled: bool = True
    patch_radius_px: AtLeast(1) = 10
    window_sigma: PosFinite = 0.6
    iterations: AtLeast(0) = 8
    max_shift_px: PosFinite = 1.0
    min_zncc: Annotated[float, Field(ge=-1, le=1)] = 0.8
    neighbours: AtLeast(1) = 12
    n_threads: AtLeast(1) = 2


@dataclass(kw_only=True)
class RefineReport:
    """What the refinement did: observations seen, moved (converged and kept), the median and 95th percentile of
    the shift (px), the observations whose image could not be read, the wall time (s)."""

    observations: int = 0
    references: int = 0
    moved: int = 0
    shift_px_median: float = 0.0
    shift_px_p95: float = 0.0
    unreadable_images: list[str] = field(default_factory=list)
    seconds: float = 0.0

    def as_dict(self) -> dict:
        return {"observations": self.observations, "references": self.references, "moved": self.moved,
                "shift_px_median": round(self.shift_px_median, 4), "shift_px_p95": round(self.shift_px_p95, 4),
                "unreadable_images": self.unreadable_images, "seconds": round(self.seconds, 2)}


def surface_tangents(points_cm: np.ndarray, neighbours: int) -> np.ndarray:
    """(P, 3, 2) two orthonormal tangents of the surface through each of the (P, 3) points: the two largest
    principal axes of the point and its ``neighbours`` nearest points."""
    k = min(neighbours + 1, len(points_cm))
    if k < 3:
        return np.broadcast_to(np.eye(3)[:, :2], (len(points_cm), 3, 2)).copy()
    _, idx = cKDTree(points_cm).query(points_cm, k=k)
    nb = points_cm[idx]
    nb = nb - nb.mean(axis=1, keepdims=True)
    _, vecs = np.linalg.eigh(np.einsum("pki,pkj->pij", nb, nb))
    return vecs[:, :, 1:]  # eigenvalues ascending: the normal is the first axis


def local_warps(obs: Observations, points_cm: np.ndarray, tangents: np.ndarray) -> np.ndarray:
    """(M, 2, 2) ``J T``: pixels per cm along each point's two surface tangents, per observation."""
    cams = [obs.cameras[n] for n in obs.camera_names]
    R = np.stack([c.R for c in cams])[obs.camera_index]
    jac = project_with_jacobians(points_cm[obs.point_index], matrix_to_rotvec(R),
                                 np.stack([c.t_cm for c in cams])[obs.camera_index],
                                 np.stack([c.intr for c in cams])[obs.camera_index],
                                 np.stack([c.dist for c in cams])[obs.camera_index], R=R)
    return jac.d_point @ tangents[obs.point_index]


def reference_views(point_index: np.ndarray, camera_index: np.ndarray, JT: np.ndarray, n_points: int) -> np.ndarray:
    """(P,) the observation of each point whose view sees the surface finest (largest |det J T|, compared on
    6 significant digits; ties: the lowest camera index), -1 for points without observations."""
    det = np.abs(np.linalg.det(JT))
    key = np.round(np.log(np.maximum(det, 1e-300)), 6)
    order = np.lexsort((camera_index, -key, point_index))
    first = np.ones(len(order), dtype=bool)
    first[1:] = point_index[order[1:]] != point_index[order[:-1]]
    ref = np.full(n_points, -1, dtype=np.int64)
    ref[point_index[order[first]]] = order[first]
    return ref


@numba.njit(nogil=True, cache=True, boundscheck=False)
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


@numba.njit(nogil=True, cache=True, boundscheck=False)
def sample_patches(img, uv, offsets):
    """(N, K) the image bilinearly sampled at uv (N, 2) + offsets (K, 2) (nan outside)."""
    out = np.empty((uv.shape[0], offsets.shape[0]), dtype=np.float64)
    for n in range(uv.shape[0]):
        for k in range(offsets.shape[0]):
            out[n, k] = _bilinear(img, uv[n, 0] + offsets[k, 0], uv[n, 1] + offsets[k, 1])[0]
    return out


@numba.njit(nogil=True, cache=True, boundscheck=False)
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


@numba.njit(nogil=True, cache=True, boundscheck=False)
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


def _patch_grid(options: RefineOptions) -> tuple[np.ndarray, np.ndarray]:
    r = options.patch_radius_px
    gy, gx = np.mgrid[-r:r + 1, -r:r + 1]
    offsets = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(np.float64)
    weights = np.exp(-0.5 * np.sum(offsets ** 2, axis=1) / (options.window_sigma * max(r, 1)) ** 2)
    return offsets, weights


def _read(path: Path) -> np.ndarray | None:
    """The image as 8-bit grey (H, W), None if unreadable."""
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)  # the sensor's pixels


def refine_observations(obs: Observations, image_dir: Callable[[str], Path] | Mapping[str, Path],
                        options: RefineOptions | None = None) -> tuple[Observations, RefineReport]:
    """The observations with every track's keypoints aligned to its reference view (module docstring).

    Args:
        obs: the merged observations (cameras, points per scene in cm, uv_px OpenCV px).
        image_dir: scene -> the folder holding ``<camera>.png`` of that scene.
    Returns:
        new observations (the same cameras, points and indices; ``uv_px`` refined) and the report.
    """
    options = options or RefineOptions()
    t0 = time.perf_counter()
    report = RefineReport(observations=obs.n_observations)
    if not options.enabled or obs.n_observations == 0:
        return obs, report
    dir_of = image_dir if callable(image_dir) else image_dir.__getitem__
    scenes = list(obs.scene_points_cm)
    sizes = np.array([len(obs.scene_points_cm[s]) for s in scenes])
    scene_of_point = np.repeat(np.arange(len(scenes)), sizes)
    points = np.concatenate([obs.scene_points_cm[s] for s in scenes]).astype(np.float64)
    tangents = np.concatenate([surface_tangents(obs.scene_points_cm[s].astype(np.float64), options.neighbours)
                               for s in scenes])
    JT = local_warps(obs, points, tangents)
    ref_obs = reference_views(obs.point_index, obs.camera_index, JT, len(points))
    ref_of = ref_obs[obs.point_index]
    is_ref = ref_of == np.arange(obs.n_observations)
    inv_of_point = np.full((len(points), 2, 2), np.nan)  # (J T)_ref^-1; nan where it has none (no warp: not moved)
    M = JT[ref_obs[ref_obs >= 0]]
    det = M[:, 0, 0] * M[:, 1, 1] - M[:, 0, 1] * M[:, 1, 0]
    det = np.where(np.abs(det) > 1e-12, det, np.nan)
    inv_of_point[ref_obs >= 0] = np.stack([np.stack([M[:, 1, 1], -M[:, 0, 1]], -1),
                                           np.stack([-M[:, 1, 0], M[:, 0, 0]], -1)], 1) / det[:, None, None]
    A = JT @ inv_of_point[obs.point_index]
    ok_warp = np.all(np.isfinite(A), axis=(1, 2)) & np.isfinite(obs.uv_px).all(axis=1)
    offsets, weights = _patch_grid(options)
    image_key = scene_of_point[obs.point_index] * len(obs.camera_names) + obs.camera_index
    keys = np.unique(image_key)
    members = np.split(np.argsort(image_key, kind="stable"), np.cumsum(np.bincount(
        np.searchsorted(keys, image_key), minlength=len(keys)))[:-1])

    n_cams = len(obs.camera_names)

    def path_of(key: int) -> Path:
        return Path(dir_of(scenes[key // n_cams])) / f"{obs.camera_names[key % n_cams]}.png"

    ref_patch = np.full((len(points), len(offsets)), np.nan)
    shift = np.zeros((obs.n_observations, 2))
    zncc = np.full(obs.n_observations, np.nan)
    unreadable: list[str] = []
    images: dict[int, np.ndarray | None] = {}

    def reference_patches(item: tuple[int, np.ndarray]) -> None:
        key, m = item
        m = m[is_ref[m]]
        if len(m) and images[key] is not None:
            ref_patch[obs.point_index[m]] = sample_patches(images[key], obs.uv_px[m].astype(np.float64), offsets)

    def align(item: tuple[int, np.ndarray]) -> None:
        key, m = item
        m = m[~is_ref[m] & ok_warp[m]]
        m = m[np.isfinite(ref_patch[obs.point_index[m]]).all(axis=1)]
        if len(m) and images[key] is not None:
            shift[m], zncc[m] = align_patches(images[key], obs.uv_px[m].astype(np.float64), A[m],
                                              ref_patch[obs.point_index[m]], offsets, weights, options.iterations,
                                              options.max_shift_px)

    with ThreadPoolExecutor(max(1, options.n_threads)) as pool:
        for si in range(len(scenes)):  # one scene's images in memory at a time (8-bit), each read once
            items = [(k, m) for k, m in zip(keys.tolist(), members) if k // n_cams == si]
            images = dict(zip([k for k, _ in items], pool.map(lambda km: _read(path_of(km[0])), items)))
            unreadable += [str(path_of(k)) for k, img in images.items() if img is None]
            list(pool.map(reference_patches, items))
            list(pool.map(align, items))
            images = {}
    norm = np.linalg.norm(shift, axis=1)
    q = 1e-6  # verdicts on quantised values: the same keypoints move on every machine
    moved = (np.isfinite(zncc) & (np.round(np.nan_to_num(zncc, nan=-1.0) / q) >= round(options.min_zncc / q))
             & (np.round(norm / q) <= round(options.max_shift_px / q)))
    uv = obs.uv_px.astype(np.float64, copy=True)
    uv[moved] += shift[moved]
    report.references = int(is_ref.sum())
    report.moved = int(moved.sum())
    if moved.any():
        report.shift_px_median = float(np.median(norm[moved]))
        report.shift_px_p95 = float(np.percentile(norm[moved], 95))
    report.unreadable_images = sorted(unreadable)
    report.seconds = time.perf_counter() - t0
    logger.info("keypoint refinement: %d of %d observations moved (median %.3f px), %d reference views, %.1f s",
                report.moved, report.observations, report.shift_px_median, report.references, report.seconds)
    return replace(obs, uv_px=uv), report
