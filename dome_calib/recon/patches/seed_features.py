"""Seed patches from matched image features (no depth, any baseline): SIFT keypoints of every camera of the
reference stream at the seed frame, matched pairwise along the calibration's epipolar lines, joined into tracks
across cameras and triangulated.

The depth sweep of :mod:`.seed` scores a corner's window against the same upright window in nearby cameras and
refines it by optical flow from the reference image: both assume the cameras see the surface alike (the dome's
neighbours, a few degrees apart). Cameras 45-90 deg apart see a patch sheared and rotated; SIFT's descriptor is
rotation and scale invariant and tolerates the shear of moderate tilts. Per camera (in name order): up to
``seed_sift_features`` keypoints (``cv2.SIFT_create``) whose ray crosses the capture volume. Per pair of cameras
(i < j by name): for each keypoint of i, the keypoints of j within ``seed_match_px`` of its epipolar line (both
ways: the calibration's essential matrix on undistorted rays, the distance in pixels of each image); the nearest
descriptor among them if it is nearer than ``seed_ratio`` times the second nearest, and mutual (i's keypoint is also
the nearest of j's among its own candidates). Matches join keypoints into tracks (connected components); a track
with two keypoints in one camera is a contradiction and is dropped. Tracks are triangulated robustly
(:func:`dome_calib.recon.triangulate.triangulate`, inliers within ``seed_match_px``, at least ``seed_min_views``)
and kept inside the capture volume; then thinned to one per ``seed_spacing_cm`` cell (the cell's seed with most
inlier views, then the first track: tracks are numbered by their first camera's name and keypoint, no order of
work decides it). Normals as in :mod:`.seed` (least principal axis of the seeds within ``normal_radius_cm``) where
at least ``normal_min_points`` seeds are near; a sparser seed faces the mean direction of the cameras that
triangulated it. Either way the PMVS-like refinement (:mod:`.refine`) then tilts it to the most alike square.
"""
from __future__ import annotations

import logging

import cv2
import numpy as np

from dome_calib.camera import pixels_to_normalized
from dome_calib.recon.patches.frames import FrameSource, ncc, patch_axes, patch_grid_cm, project_one, sample
from dome_calib.recon.patches.model import PatchOptions, seed_square_cm
from dome_calib.recon.patches.refine import refine_normals
from dome_calib.recon.patches.seed import Seeds, _normals, _volume_span, in_volume
from dome_calib.recon.patches.visibility import Frames
from dome_calib.recon.project import ViewSet
from dome_calib.recon.triangulate import TriangulationOptions, triangulate
from dome_calib import ties

logger = logging.getLogger(__name__)

_CHUNK = 512  # keypoints of camera i matched at a time (bounds the (chunk, n_j) distance tables)
SIFT_CONTRAST = 0.02  # half OpenCV's default: a person's clothes are low-contrast texture


def _keypoints(gray: np.ndarray, views: ViewSet, v: int, o: PatchOptions) -> tuple[np.ndarray, np.ndarray]:
    """SIFT of one image -> ((K, 2) pixels, (K, 128) float32 descriptors), keypoints whose ray crosses the
    capture volume, ordered by row then column (quantised to 1/8 px) so no detector order decides anything."""
    sift = cv2.SIFT_create(nfeatures=o.seed_sift_features, contrastThreshold=SIFT_CONTRAST)
    kps, desc = sift.detectAndCompute(gray, None)
    if desc is None or not kps:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    uv = np.array([k.pt for k in kps], dtype=float)
    xn = pixels_to_normalized(uv, views.intr[v], views.dist[v])
    dirs = np.concatenate([xn, np.ones((len(xn), 1))], 1) @ views.R[v]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    lo, hi = _volume_span(views.center_cm[v], dirs, o.volume_radius_cm, o.volume_height_cm)
    keep = np.flatnonzero(hi > lo)
    keep = keep[ties.raster_order(uv[keep], ties.CORNER_QUANTUM_PX)]
    return uv[keep], np.asarray(desc, np.float32)[keep]


def _essential(views: ViewSet, i: int, j: int) -> np.ndarray:
    """E with x_j^T E x_i = 0 for undistorted normalised rays x of views i and j."""
    R = views.R[j] @ views.R[i].T
    t = views.R[j] @ (views.center_cm[i] - views.center_cm[j])
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    return tx @ R


def _epipolar_px(E: np.ndarray, xa: np.ndarray, xb: np.ndarray, fa: float, fb: float) -> np.ndarray:
    """(na, nb) the larger of the two epipolar distances (px: normalised distance times the image's focal)."""
    ha, hb = np.c_[xa, np.ones(len(xa))], np.c_[xb, np.ones(len(xb))]
    lb, la = ha @ E.T, hb @ E  # lines in b of a's points; in a of b's points
    alg = np.abs(lb @ hb.T)  # |x_b^T E x_a|
    db = alg / np.maximum(np.hypot(lb[:, 0], lb[:, 1]), 1e-12)[:, None] * fb
    da = alg / np.maximum(np.hypot(la[:, 0], la[:, 1]), 1e-12)[None, :] * fa
    return np.maximum(da, db)


def match_pair(uv_a: np.ndarray, desc_a: np.ndarray, uv_b: np.ndarray, desc_b: np.ndarray, views: ViewSet,
               i: int, j: int, o: PatchOptions) -> np.ndarray:
    """Keypoints of views i and j matched along the epipolar lines -> (M, 2) index pairs (a, b), a increasing."""
    if not len(uv_a) or not len(uv_b):
        return np.zeros((0, 2), np.int64)
    xa = pixels_to_normalized(uv_a, views.intr[i], views.dist[i])
    xb = pixels_to_normalized(uv_b, views.intr[j], views.dist[j])
    E = _essential(views, i, j)
    nb2 = np.sum(desc_b.astype(np.float64) ** 2, 1)
    D = np.full((len(uv_a), len(uv_b)), np.inf)
    far = np.full(len(uv_a), np.inf)
    for c0 in range(0, len(uv_a), _CHUNK):
        sl = slice(c0, c0 + _CHUNK)
        line_px = _epipolar_px(E, xa[sl], xb, float(views.intr[i][0]), float(views.intr[j][0]))
        near = ties.below(line_px, o.seed_match_px, ties.FLOW_QUANTUM_PX)
        da = desc_a[sl].astype(np.float64)
        d2 = np.sum(da ** 2, 1)[:, None] + nb2[None] - 2.0 * da @ desc_b.T.astype(np.float64)
        d = np.sqrt(np.maximum(d2, 0.0))
        D[sl] = np.where(near, d, np.inf)
        far[sl] = np.where(near, np.inf, d).min(1)
    rows = np.arange(len(uv_a))
    part = np.argsort(D, axis=1, kind="stable")[:, :2] if len(uv_b) > 1 else np.zeros((len(uv_a), 1), np.int64)
    best = D[rows, part[:, 0]]
    second = D[rows, part[:, 1]] if part.shape[1] > 1 else np.full(len(uv_a), np.inf)
    ok = np.isfinite(best) & ties.below(best, o.seed_ratio * np.minimum(second, far), ties.DESCRIPTOR_DISTANCE_QUANTUM)
    back = np.argmin(D, axis=0)  # b's nearest a among its own candidates (first on ties)
    ok &= back[part[:, 0]] == rows
    a = np.flatnonzero(ok)
    return np.stack([a, part[a, 0]], 1).astype(np.int64)


def _tracks(offsets: np.ndarray, matches: dict[tuple[int, int], np.ndarray]) -> list[np.ndarray]:
    """Pairwise matches -> tracks (connected components of keypoints), each a sorted array of global keypoint
    numbers (camera v's keypoint k is offsets[v] + k); a track with two keypoints of one camera is dropped."""
    parent = np.arange(int(offsets[-1]))

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = int(parent[x])
        return x

    for (i, j), m in sorted(matches.items()):
        for a, b in m:
            ra, rb = find(int(offsets[i] + a)), find(int(offsets[j] + b))
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    roots = np.array([find(x) for x in range(len(parent))], dtype=np.int64)
    order = np.argsort(roots, kind="stable")
    groups = np.split(order, np.flatnonzero(np.diff(roots[order])) + 1) if len(order) else []
    cam = np.searchsorted(offsets, np.arange(len(parent)), side="right") - 1
    return [np.sort(g) for g in groups if len(g) >= 2 and len(np.unique(cam[g])) == len(g)]


def _inside_volume(X: np.ndarray, o: PatchOptions) -> np.ndarray:
    return in_volume(X, o, 0.0)


def seed_from_features(source: FrameSource, views: ViewSet, frames: dict[str, int], o: PatchOptions) -> Seeds:
    """A seed cloud from the cameras ``views`` (one stream: their ``frames`` share a time), by matched features.

    Example:
        >>> seeds = seed_from_features(scene, view_set(imaged, names), {n: 130 for n in names}, PatchOptions())
    """
    V = len(views.names)
    empty = Seeds(X_cm=np.zeros((0, 3, 3)), normal=np.zeros((0, 3)), seen=np.zeros((0, V), bool))
    kp = [_keypoints(source.gray(n, frames[n]), views, v, o) for v, n in enumerate(views.names)]
    offsets = np.concatenate([[0], np.cumsum([len(u) for u, _ in kp])]).astype(np.int64)
    matches = {(i, j): match_pair(*kp[i], *kp[j], views, i, j, o) for i in range(V) for j in range(i + 1, V)}
    tracks = _tracks(offsets, matches)
    logger.debug("features: %s keypoints, %d matches, %d tracks", [len(u) for u, _ in kp],
                 sum(len(m) for m in matches.values()), len(tracks))
    if not tracks:
        return empty
    uv = np.full((len(tracks), V, 2), np.nan)
    conf = np.zeros((len(tracks), V))
    for n, g in enumerate(tracks):
        cam = np.searchsorted(offsets, g, side="right") - 1
        uv[n, cam] = np.stack([kp[c][0][k - offsets[c]] for c, k in zip(cam, g)])
        conf[n, cam] = 1.0
    tri = triangulate(views, uv, conf, TriangulationOptions(inlier_threshold_px=o.seed_match_px,
                                                            min_views=o.seed_min_views))
    good = np.all(np.isfinite(tri.X_cm), axis=1)
    good[good] = _inside_volume(tri.X_cm[good], o)
    if not good.any():
        return empty
    X, seen, n_inl = tri.X_cm[good], tri.inliers[good], tri.n_inliers[good]
    cell = np.floor(X / o.seed_spacing_cm).astype(np.int64)
    order = np.lexsort((np.arange(len(X)), -n_inl, cell[:, 2], cell[:, 1], cell[:, 0]))
    first = np.ones(len(order), bool)
    first[1:] = np.any(cell[order][1:] != cell[order][:-1], axis=1)
    pick = np.sort(order[first])
    X, seen = X[pick], seen[pick]
    normal, axis, ok = _normals(X, X, seen, views.center_cm, o.normal_radius_cm, o.normal_min_points,
                                o.normal_fit)
    towards = np.stack([((views.center_cm - x) / np.linalg.norm(views.center_cm - x, axis=1)[:, None])[s].sum(0)
                        for x, s in zip(X, seen)])
    towards /= np.linalg.norm(towards, axis=1, keepdims=True)
    normal[~ok] = towards[~ok]
    side = np.cross(towards, [0.0, 1.0, 0.0])  # horizontal, across the cameras' mean direction
    side[np.linalg.norm(side, axis=1) < 1e-6] = [1.0, 0.0, 0.0]
    axis[~ok] = side[~ok]
    u = axis - np.sum(axis * normal, 1, keepdims=True) * normal
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(normal, u)
    trip = np.stack([X, X + o.axis_cm * u, X + o.axis_cm * v], 1)
    # two views cannot out-vote a wrong match along the epipolar line: the square (normal refined) must look alike
    at = Frames(frame=np.array([frames[n] for n in views.names]), offset_ms=np.zeros(V))
    trip = refine_normals(source, views, at, trip, seen, o) if len(trip) else trip
    score = square_ncc(source, views, at, trip, seen, o)
    alike = ties.at_least(score, o.seed_min_ncc, ties.NCC_QUANTUM)
    _, _, normal = patch_axes(trip[:, 0], trip[:, 1], trip[:, 2])
    logger.info("seed cloud (features): %d patches from %d cameras (%d tracks, %d thinned, %d with normals from "
                "neighbours)", int(alike.sum()), V, len(tracks), len(X), int(ok.sum()))
    return Seeds(X_cm=trip[alike], normal=normal[alike], seen=seen[alike])


def square_ncc(source: FrameSource, views: ViewSet, at: Frames, X: np.ndarray, seen: np.ndarray, o: PatchOptions
               ) -> np.ndarray:
    """(N,) the least NCC of a patch's square (:func:`.model.seed_square_cm`) between its most face-on seeing camera
    and each of the others that see it (-1 where a square leaves an image or fewer than two cameras see it)."""
    grid = patch_grid_cm(X[:, 0], X[:, 1], X[:, 2], seed_square_cm(o))
    _, _, n = patch_axes(X[:, 0], X[:, 1], X[:, 2])
    to_cam = views.center_cm[None] - X[:, None, 0]
    cos = np.sum(to_cam * n[:, None], -1) / np.linalg.norm(to_cam, axis=-1)
    ref, _ = ties.argmax_where(cos, seen, ties.VIEW_COSINE_QUANTUM)
    samples, inside = [], []
    for v in range(len(views.names)):
        uv, vis = project_one(views, v, grid)
        samples.append(sample(source.gray(views.names[v], int(at.frame[v])), uv))
        inside.append(vis.all(-1))
    S, inside = np.stack(samples, 1), np.stack(inside, 1)  # (N, V, G), (N, V)
    rows = np.arange(len(X))
    corr = ncc(S, S[rows, ref][:, None])  # (N, V)
    other = seen & inside & inside[rows, ref][:, None]
    other[rows, ref] = False
    worst = np.where(other, corr, np.inf).min(1)
    return np.where(other.any(1), worst, -1.0)
