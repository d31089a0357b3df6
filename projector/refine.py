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
(``A`` times it), i.e. the 3D point along the surface, which the bundle adjustment absorbs.

The image work runs as tasks, one per image and phase (:mod:`projector.refine_images`: the reference patches,
then the alignment), one scene at a time: on a cluster through the executor that extracted the features (each
task on the capture node holding its image), on this machine in ``n_threads`` threads (a process pool would only
pickle every aligned observation's reference patch to its workers: 0.5 GB on the panel dome, ~10 % of the time;
``bench/refine_dispatch.py``). Any executor gives the same result. The head gathers the patches
between the phases and writes every result into its observations' slots in image order: the refined keypoints are
the same bits locally, in a pool of any size or on a cluster. An image no task could read leaves its keypoints
where SIFT put them; the report lists it (``unreadable_images``) and the log says so. The verdicts (correlation,
shift) compare values quantised to 1e-6, so the same keypoints move on every machine.

Measured (docs/accuracy.md): feature noise against the rendered truth 0.195 -> 0.046 px (panel dome), 0.226 ->
0.058 px (full dome: 1.25 M observations in 22 s on two shared cores).
"""
from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Annotated

import numpy as np
from scipy.spatial import cKDTree

from dome_calib.camera import project_with_jacobians
from dome_calib.executor import Executor, ThreadExecutor, in_order
from dome_calib.rotation import matrix_to_rotvec
from projector.observations import Observations
from projector.refine_images import ImageJob, ImageOutput, PatchGrid, align_image, reference_patches
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
    the shift (px), the images no task could read (why, naming the path; their keypoints stay), the wall time (s)."""

    observations: int = 0
    references: int = 0
    moved: int = 0
    shift_px_median: float = 0.0
    shift_px_p95: float = 0.0
    unreadable_images: dict[str, str] = field(default_factory=dict)  # "scene/camera" -> why
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


def refine_observations(obs: Observations, image_dir: Callable[[str], Path] | Mapping[str, Path],
                        options: RefineOptions | None = None, executor: Executor | None = None,
                        ) -> tuple[Observations, RefineReport]:
    """The observations with every track's keypoints aligned to its reference view (module docstring).

    Args:
        obs: the merged observations (cameras, points per scene in cm, uv_px OpenCV px).
        image_dir: scene -> the folder holding ``<camera>.png`` of that scene (as the features' tasks were given it).
        executor: where the per-image tasks run (:mod:`projector.refine_images`; a cluster's: each where its
            image is); default ``options.n_threads`` threads in this process. The result does not depend on it.
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
    grid = PatchGrid(radius_px=options.patch_radius_px, window_sigma=options.window_sigma,
                     iterations=options.iterations, max_shift_px=options.max_shift_px)
    n_patch = (2 * options.patch_radius_px + 1) ** 2
    image_key = scene_of_point[obs.point_index] * len(obs.camera_names) + obs.camera_index
    keys = np.unique(image_key)
    members = dict(zip(keys.tolist(), np.split(np.argsort(image_key, kind="stable"), np.cumsum(np.bincount(
        np.searchsorted(keys, image_key), minlength=len(keys)))[:-1])))
    n_cams = len(obs.camera_names)

    def task(key: int, m: np.ndarray, **more: np.ndarray) -> tuple[str, str, ImageJob]:
        camera = obs.camera_names[key % n_cams]
        path = str(Path(dir_of(scenes[key // n_cams])) / f"{camera}.png")
        return camera, path, ImageJob(key=key, uv_px=obs.uv_px[m].astype(np.float64), grid=grid, **more)

    ref_patch = np.full((len(points), n_patch), np.nan)
    shift = np.zeros((obs.n_observations, 2))
    zncc = np.full(obs.n_observations, np.nan)
    unreadable: dict[int, str] = {}

    def results(pool: Executor, fn: Callable, jobs: dict[int, np.ndarray], **more: Callable) -> Iterator[ImageOutput]:
        """Each image's result in key order (whoever ran it, whenever it finished); failures noted, not yielded."""
        items = (task(k, m, **{name: f(m) for name, f in more.items()}) for k, m in jobs.items())
        for out in in_order(pool.map(fn, items), list(jobs), lambda r: r.key):
            if out.failure is None:
                yield out
            else:
                unreadable.setdefault(out.key, out.failure)

    own = ThreadExecutor(options.n_threads) if executor is None else contextlib.nullcontext(executor)
    with own as pool:
        for si in range(len(scenes)):  # one scene's patches on the head at a time
            # in this process's threads a scene's images are decoded once for both phases (other processes and
            # machines read their own)
            kept: dict[str, np.ndarray] = {}
            phase1, phase2 = ((partial(reference_patches, kept=kept), partial(align_image, kept=kept))
                              if executor is None else (reference_patches, align_image))  # the cluster routes these
            scene_keys = [k for k in keys.tolist() if k // n_cams == si]
            refs = {k: members[k][is_ref[members[k]]] for k in scene_keys}  # every image: an unreadable one is told
            for out in results(pool, phase1, refs):
                ref_patch[obs.point_index[refs[out.key]]] = out.values
            aligned = {}
            for k in scene_keys:
                m = members[k][~is_ref[members[k]] & ok_warp[members[k]]]
                m = m[np.isfinite(ref_patch[obs.point_index[m]]).all(axis=1)]
                if len(m) and k not in unreadable:
                    aligned[k] = m
            for out in results(pool, phase2, aligned, warps=lambda m: A[m],
                               ref_patches=lambda m: ref_patch[obs.point_index[m]]):
                shift[aligned[out.key]], zncc[aligned[out.key]] = out.values, out.zncc
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
    report.unreadable_images = {f"{scenes[k // n_cams]}/{obs.camera_names[k % n_cams]}": unreadable[k]
                                for k in sorted(unreadable)}
    report.seconds = time.perf_counter() - t0
    if unreadable:
        logger.warning("keypoint refinement: %d image(s) could not be read, their keypoints not refined: %s",
                       len(unreadable), "; ".join(list(report.unreadable_images.values())[:3])
                       + ("; ..." if len(unreadable) > 3 else ""))
    logger.info("keypoint refinement: %d of %d observations moved (median %.3f px), %d reference views, %.1f s",
                report.moved, report.observations, report.shift_px_median, report.references, report.seconds)
    return replace(obs, uv_px=uv), report
