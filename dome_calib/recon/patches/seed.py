"""Seed patches from image features (no depth): corners of every camera of the reference stream at the seed frame,
each put in 3D by a depth sweep along its ray, refined by optical flow in the nearby cameras and triangulated.

Per reference camera (in name order): corners (``cv2.goodFeaturesToTrack``); along each corner's ray, the depths
inside the capture volume (a vertical cylinder on the floor) every ``seed_step_cm``; at each depth the mean NCC of
a ``seed_window_px`` window round the corner against the same window round its projection in the
``seed_neighbours`` nearest cameras; the best depth if its score reaches ``seed_min_ncc``. The 3D point is then
projected into the ``seed_views`` nearest cameras, refined there by pyramidal Lucas-Kanade from the reference
image (forward-backward checked) and triangulated robustly (:func:`dome_calib.recon.triangulate.triangulate`).

The seeds of all cameras are thinned to one per ``seed_spacing_cm`` cell (the cell's seed with most inlier views,
then the first reference camera by name: no order of work decides it). Each seed's normal is the least
principal axis (SVD) of the seeds within ``normal_radius_cm``, its sign towards the cameras that triangulated it;
the patch's plane points lie on the two other axes.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from dome_calib.recon.patches.frames import FrameSource, ncc, sample, sample_windows
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.project import ViewSet, project_points
from dome_calib.recon.triangulate import TriangulationOptions, triangulate
from dome_calib.camera import pixels_to_normalized
from dome_calib import ties

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Seeds:
    """A seed cloud: X_cm (N, 3, 3) centre and two plane points; normal (N, 3); seen (N, V) the views that
    triangulated each seed (``views`` order)."""

    X_cm: np.ndarray
    normal: np.ndarray
    seen: np.ndarray


def _nearest_views(views: ViewSet, r: int, n: int) -> np.ndarray:
    """The ``n`` views nearest view ``r`` (centre distance, quantised to 0.1 mm; ties by name), r excluded."""
    d = np.linalg.norm(views.center_cm - views.center_cm[r], axis=1)
    others = [i for i in range(len(d)) if i != r]
    order = ties.order_by(d[others], [views.names[i] for i in others], ties.CAMERA_DISTANCE_QUANTUM_CM)
    return np.array([others[m] for m in order[:n]], dtype=np.int64)


def in_volume(X: np.ndarray, o: PatchOptions, floor_cm: float) -> np.ndarray:
    """(N,) bool: points (N, 3) inside the capture volume (the cylinder of ``volume_radius_cm`` about the y axis,
    ``volume_height_cm`` tall) at least ``floor_cm`` above the floor (y = 0, up is -y); positions quantised to
    ``ties.LENGTH_QUANTUM_CM`` (a point on the wall is inside on every machine)."""
    q = ties.LENGTH_QUANTUM_CM
    return (ties.at_most(np.hypot(X[:, 0], X[:, 2]), o.volume_radius_cm, q)
            & ties.at_least(X[:, 1], -o.volume_height_cm, q) & ties.at_most(X[:, 1], -floor_cm, q))


def _volume_span(origin: np.ndarray, dirs: np.ndarray, radius: float, height: float) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameters (N,) where rays enter and leave the cylinder x^2 + z^2 <= radius^2, -height <= y <= 0."""
    ox, oz, dx, dz = origin[0], origin[2], dirs[:, 0], dirs[:, 2]
    a = dx * dx + dz * dz
    b = 2 * (ox * dx + oz * dz)
    c = ox * ox + oz * oz - radius * radius
    disc = b * b - 4 * a * c
    root = np.sqrt(np.maximum(disc, 0.0))
    a_safe = np.where(a > 1e-12, a, 1.0)
    s0, s1 = (-b - root) / (2 * a_safe), (-b + root) / (2 * a_safe)
    s0, s1 = np.where(disc > 0, s0, np.inf), np.where(disc > 0, s1, -np.inf)
    dy = np.where(np.abs(dirs[:, 1]) > 1e-12, dirs[:, 1], 1e-12)
    y0, y1 = (-height - origin[1]) / dy, (0.0 - origin[1]) / dy
    lo, hi = np.maximum(np.maximum(s0, np.minimum(y0, y1)), 1.0), np.minimum(s1, np.maximum(y0, y1))
    return lo, hi


def _sweep(source: FrameSource, views: ViewSet, frames: dict[str, int], r: int, corners: np.ndarray,
           o: PatchOptions, chunk: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """Depth sweep of corners (N, 2) of view r -> ((N, 3) world points, NaN where none; (N,) best score)."""
    name = views.names[r]
    gray_r = source.gray(name, frames[name])
    nb = _nearest_views(views, r, o.seed_neighbours)
    grays = [source.gray(views.names[v], frames[views.names[v]]) for v in nb]
    half = o.seed_window_px // 2
    off = np.stack(np.meshgrid(np.arange(-half, half + 1), np.arange(-half, half + 1)), -1).reshape(-1, 2)
    xn = pixels_to_normalized(corners, views.intr[r], views.dist[r])
    dirs = np.concatenate([xn, np.ones((len(xn), 1))], 1) @ views.R[r]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    origin = views.center_cm[r]
    lo, hi = _volume_span(origin, dirs, o.volume_radius_cm, o.volume_height_cm)
    X = np.full((len(corners), 3), np.nan)
    best = np.full(len(corners), -1.0)
    ref = sample(gray_r, corners[:, None, :] + off[None])  # (N, W2)
    nb_views = views.at(nb)
    for c0 in range(0, len(corners), chunk):
        sl = slice(c0, c0 + chunk)
        n_steps = int(np.ceil(np.nanmax(np.where(hi[sl] > lo[sl], hi[sl] - lo[sl], 0.0), initial=0.0)
                              / o.seed_step_cm)) + 1
        s = lo[sl, None] + o.seed_step_cm * np.arange(n_steps)[None]  # (n, D)
        ok = s <= hi[sl, None]
        P = origin + s[..., None] * dirs[sl, None]  # (n, D, 3)
        proj = project_points(nb_views, P.reshape(-1, 3))
        scores = np.zeros(s.shape)
        counts = np.zeros(s.shape)
        for k, g in enumerate(grays):
            uv = proj.uv_px[k].reshape(*s.shape, 2)
            vis = proj.visible[k].reshape(s.shape) & ok
            win = sample_windows(g, np.where(vis[..., None], uv, -100.0), off)  # (n, D, W2)
            score = ncc(ref[sl, None], win)
            scores += np.where(vis, score, 0.0)
            counts += vis
        mean = np.where(counts >= 2, scores / np.maximum(counts, 1), -1.0)
        k = ties.argmax_first(mean, ties.NCC_QUANTUM, axis=1)
        rows = np.arange(len(k))
        best[sl] = mean[rows, k]
        good = ties.at_least(best[sl], o.seed_min_ncc, ties.NCC_QUANTUM)
        X[sl][good] = P[rows, k][good]
    return X, best


def _lk(src: np.ndarray, dst: np.ndarray, p0: np.ndarray, guess: np.ndarray | None, o: PatchOptions,
        levels: int | None = None, predicted: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Pyramidal LK of (N, 2) points from image src to dst with a forward-backward check -> ((N, 2), (N,) ok), the one
    place of the check's rule for every caller (the tracker's first and predicted steps, the seed alignment, the
    seeds' flows to their neighbours). With ``lk_fb_strict`` the backward flow never starts at its own answer (the
    points): at the forward's end moved back by the guess's displacement (``guess - p0``: the same initial motion
    reversed), or at the forward's end itself without a guess, and must find its way back within ``lk_fb_px``.
    Without (the default), it starts at the points (with ``predicted``, at ``b - (b - p0)``: the old code's
    arithmetic, whose guess OpenCV had overwritten with the forward's end ``b``), bit for bit as before."""
    if len(p0) == 0:
        return np.zeros((0, 2)), np.zeros(0, bool)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, o.lk_iterations, o.lk_eps_px)
    win = (o.lk_window_px, o.lk_window_px)
    lv = o.lk_levels if levels is None else levels
    a = np.ascontiguousarray(p0, dtype=np.float32).reshape(-1, 1, 2)
    flags = 0
    g = None
    if guess is not None:
        g = np.ascontiguousarray(guess, dtype=np.float32).reshape(-1, 1, 2)
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    # OpenCV writes the result into the initial-flow array in place (it returns that very array): the forward gets
    # a copy, so that ``g`` is still the guess below (the caller's array is not written either)
    b, st, _ = cv2.calcOpticalFlowPyrLK(src, dst, a, None if g is None else g.copy(), winSize=win, maxLevel=lv,
                                        criteria=crit, flags=flags)
    if o.lk_fb_strict:
        start = b - (g - a) if g is not None else b.copy()
    else:  # the old start, bit for bit: at the answer
        start = b - (b - a) if predicted and g is not None else a.copy()
    back, st2, _ = cv2.calcOpticalFlowPyrLK(dst, src, b, start, winSize=win, maxLevel=lv, criteria=crit,
                                            flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    fb = np.linalg.norm((back - a).reshape(-1, 2), axis=1)
    ok = (st.ravel() == 1) & (st2.ravel() == 1) & ties.below(fb, o.lk_fb_px, ties.FLOW_QUANTUM_PX)
    return b.reshape(-1, 2).astype(float), ok


def optical_flow(src: np.ndarray, dst: np.ndarray, p0: np.ndarray, o: PatchOptions, guess: np.ndarray | None = None,
                 levels: int | None = None, predicted: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 2) of image ``src`` followed into ``dst`` by pyramidal Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``,
    window ``lk_window_px``, ``lk_levels`` or ``levels``, started at ``guess`` if given) -> ((N, 2) pixels, (N,)
    tracked: found both ways, back within ``lk_fb_px``). Each point's result depends on the two images and that
    point only. ``predicted``: ``guess`` is a predicted motion (the backward flow's start, see :func:`_lk`)."""
    return _lk(src, dst, p0, guess, o, levels=levels, predicted=predicted)


def flow_to_neighbours(source: FrameSource, views: ViewSet, frames: dict[str, int], r: int, corners: np.ndarray,
            X: np.ndarray, o: PatchOptions) -> tuple[np.ndarray, np.ndarray]:
    """Corners of view r with sweep points X (N, 3) -> ((N, V, 2) pixels, (N, V) conf) in view r and its
    ``seed_views`` nearest views (by LK from the reference image, started at the projection)."""
    N, V = len(X), len(views.names)
    uv = np.full((N, V, 2), np.nan)
    conf = np.zeros((N, V))
    uv[:, r], conf[:, r] = corners, 1.0
    have = np.all(np.isfinite(X), axis=1)
    if not have.any():
        return uv, conf
    gray_r = source.gray(views.names[r], frames[views.names[r]])
    proj = project_points(views, np.where(have[:, None], X, 0.0))
    for v in _nearest_views(views, r, o.seed_views):
        vis = proj.visible[v] & have
        if not vis.any():
            continue
        g = source.gray(views.names[v], frames[views.names[v]])
        p, ok = _lk(gray_r, g, corners[vis], proj.uv_px[v][vis], o, levels=1)
        ok &= np.linalg.norm(p - proj.uv_px[v][vis], axis=1) < 4.0
        idx = np.flatnonzero(vis)[ok]
        uv[idx, v], conf[idx, v] = p[ok], 1.0
    return uv, conf


def thin_to_cells(X: np.ndarray, keys: list[np.ndarray], spacing_cm: float) -> np.ndarray:
    """Indices (increasing) of one point (N, 3) per ``spacing_cm`` cell: the cell's first by ``keys`` (lexsort keys,
    most significant LAST, as ``np.lexsort``; they must break every tie, so no order of work decides it)."""
    if len(X) == 0:
        return np.zeros(0, np.int64)
    cell = np.floor(X / spacing_cm).astype(np.int64)
    order = np.lexsort((*keys, cell[:, 2], cell[:, 1], cell[:, 0]))
    first = np.ones(len(order), bool)
    first[1:] = np.any(cell[order][1:] != cell[order][:-1], axis=1)
    return np.sort(order[first])


QUADRIC_MIN_POINTS = 8  # a quadric (6 coefficients) is fitted to at least this many points, else the plane


def neighbour_gap_deg(x: np.ndarray, Q: np.ndarray, u: np.ndarray, v: np.ndarray) -> float:
    """The widest angle (deg) round the point ``x`` that none of the points ``Q`` (K, 3) lies in, as seen in the plane
    of the orthonormal axes ``u``, ``v`` (the points within a tiny distance of ``x``, ``x`` itself among them, left
    out): small inside a seeded surface, 180 deg or more where the seeds round ``x`` all lie on one side of it (the
    cloud ends there), 360 with fewer than two other points. Quantised to :data:`GAP_QUANTUM_DEG`."""
    d = Q - x
    d = d[np.linalg.norm(d, axis=1) > ties.POINT_OFFSET_QUANTUM_CM]
    if len(d) < 2:
        return 360.0
    a = np.sort(np.degrees(np.arctan2(d @ v, d @ u)))
    return float(ties.quantize(np.max(np.diff(np.concatenate([a, a[:1] + 360.0]))), GAP_QUANTUM_DEG)
                 * GAP_QUANTUM_DEG)


#: :func:`neighbour_gap_deg` is rounded to multiples of this (deg) before it is compared.
GAP_QUANTUM_DEG = 1e-6


def _normals(X: np.ndarray, cloud: np.ndarray, seen: np.ndarray, centres: np.ndarray, radius_cm: float,
             min_points: int, fit: str = "plane", max_gap_deg: float = 360.0
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seeds (N, 3) -> (normal (N, 3), first axis (N, 3), ok (N,)): the least principal axis (SVD) of the ``cloud``
    points within ``radius_cm`` (at least ``min_points``), its sign towards the cameras ``seen`` (N, V) with centres
    (V, 3). ``fit="quadric"``: then, with at least :data:`QUADRIC_MIN_POINTS` points, a quadric height field
    ``z = c0 + c1 x + c2 y + c3 x^2 + c4 xy + c5 y^2`` fitted (least squares) to them in that axis' frame centred on
    the seed, and the normal taken at the seed, ``(-c1, -c2, 1)``: the plane's is the mean normal of the points round
    it, which on a curved surface seeded on one side only (a limb's outline, where the cloud ends) leans towards the
    side that has points (``bench/patch_normals.py --seeds``). ``max_gap_deg`` below 360: a seed whose points leave a
    gap wider than that round it in the plane (:func:`neighbour_gap_deg`: the cloud ends on one side of it, where the
    plane leans towards the side that has points and the normal cannot be had) is not ``ok``."""
    tree = cKDTree(cloud)
    near = tree.query_ball_point(X, radius_cm)
    normal, axis = np.full(X.shape, np.nan), np.full(X.shape, np.nan)
    ok = np.zeros(len(X), bool)
    for i, nb in enumerate(near):
        if len(nb) < min_points:
            continue
        Q = cloud[sorted(nb)]
        _, _, Vt = np.linalg.svd(Q - Q.mean(0), full_matrices=False)
        n = Vt[2]
        if fit == "quadric" and len(Q) >= QUADRIC_MIN_POINTS:
            x, y, z = ((Q - X[i]) @ Vt.T).T
            c, *_ = np.linalg.lstsq(np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], 1), z, rcond=None)
            n = np.array([-c[1], -c[2], 1.0]) @ Vt
            n /= np.linalg.norm(n)
        if max_gap_deg < 360.0 and ties.above(neighbour_gap_deg(X[i], Q, Vt[0], Vt[1]), max_gap_deg,
                                              GAP_QUANTUM_DEG):
            continue
        towards = (centres[seen[i]] - X[i]).sum(0)
        normal[i] = n if n @ towards > 0 else -n
        axis[i] = Vt[0]
        ok[i] = True
    return normal, axis, ok


@dataclass(frozen=True)
class CameraSeeds:
    """The triangulated seeds of one reference camera: X_cm (M, 3), seen (M, V) inlier views, n_inliers (M,)."""

    camera: int
    X_cm: np.ndarray
    seen: np.ndarray
    n_inliers: np.ndarray


def seed_camera(source: FrameSource, views: ViewSet, frames: dict[str, int], r: int, o: PatchOptions) -> CameraSeeds:
    """The seeds of reference camera ``r``: its corners swept in depth, refined by optical flow in the nearby cameras
    and triangulated (module docstring). Depends on ``r``'s images and its neighbours' only: one task per camera."""
    tri_o = TriangulationOptions(inlier_threshold_px=o.triangulation_px, min_views=o.seed_min_views)
    V = len(views.names)
    empty = CameraSeeds(camera=r, X_cm=np.zeros((0, 3)), seen=np.zeros((0, V), bool), n_inliers=np.zeros(0, int))
    name = views.names[r]
    corners = cv2.goodFeaturesToTrack(source.gray(name, frames[name]), o.seed_features, 0.02,
                                      o.seed_min_distance_px, blockSize=5)
    if corners is None:
        return empty
    corners = corners.reshape(-1, 2).astype(float)
    X, _ = _sweep(source, views, frames, r, corners, o)
    keep = np.all(np.isfinite(X), axis=1)
    if not keep.any():
        return empty
    uv, conf = flow_to_neighbours(source, views, frames, r, corners[keep], X[keep], o)
    tri = triangulate(views, uv, conf, tri_o)
    good = np.all(np.isfinite(tri.X_cm), axis=1) & tri.inliers[:, r]
    logger.debug("seed %s: %d corners, %d swept, %d triangulated", name, len(corners), keep.sum(), good.sum())
    return CameraSeeds(camera=r, X_cm=tri.X_cm[good], seen=tri.inliers[good], n_inliers=tri.n_inliers[good])


def reference_cameras(views: ViewSet, spacing_deg: float, volume_height_cm: float) -> np.ndarray:
    """Positions (increasing) of the cameras that seed a cloud: all of ``views`` if ``spacing_deg`` is 0, else a
    cover of them: in name order, a camera is taken unless one already taken lies within ``spacing_deg`` of it, as
    seen from the capture volume's centre (on the axis, half ``volume_height_cm`` above the floor). Every camera
    then has a reference within ``spacing_deg``, and no two references are closer: a dense dome's neighbours a few
    degrees apart see the same surface and seed the same cells (the cells keep one seed each), so one of them
    seeds it once. Depends on the cameras' centres and names only."""
    V = len(views.names)
    if spacing_deg <= 0 or V == 0:
        return np.arange(V)
    d = views.center_cm - np.array([0.0, -0.5 * volume_height_cm, 0.0])
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    limit = np.cos(np.radians(spacing_deg))
    taken: list[int] = []
    for i in sorted(range(V), key=lambda j: views.names[j]):
        if not taken or ties.at_most(d[taken] @ d[i], limit, ties.UNIT_QUANTUM).all():
            taken.append(i)
    return np.array(sorted(taken), dtype=np.int64)


def patch_triplets(X: np.ndarray, normal: np.ndarray, axis: np.ndarray, axis_cm: float) -> np.ndarray:
    """Centres (N, 3), normals (N, 3), a first in-plane direction (N, 3) -> patches (N, 3, 3): centre and the two
    plane points at ``axis_cm`` (u the direction made orthogonal to the normal, v = normal x u)."""
    u = axis - np.sum(axis * normal, 1, keepdims=True) * normal
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(normal, u)
    return np.stack([X, X + axis_cm * u, X + axis_cm * v], 1)


def merge_camera_seeds(per_camera: list[CameraSeeds], views: ViewSet, o: PatchOptions) -> Seeds:
    """The reference cameras' seeds (any order) -> one cloud: thinned to one per ``seed_spacing_cm`` cell (most
    inlier views, then the first camera by position), each with its normal from the seeds round it."""
    V = len(views.names)
    parts = sorted((c for c in per_camera if len(c.X_cm)), key=lambda c: c.camera)
    if not parts:
        return Seeds(X_cm=np.zeros((0, 3, 3)), normal=np.zeros((0, 3)), seen=np.zeros((0, V), bool))
    X, seen_a = np.concatenate([c.X_cm for c in parts]), np.concatenate([c.seen for c in parts])
    n_a = np.concatenate([c.n_inliers for c in parts])
    r_a = np.concatenate([np.full(len(c.X_cm), c.camera) for c in parts])
    pick = thin_to_cells(X, [r_a, -n_a], o.seed_spacing_cm)
    X, seen_a = X[pick], seen_a[pick]
    normal, axis, ok = _normals(X, X, seen_a, views.center_cm, o.normal_radius_cm, o.normal_min_points, o.normal_fit,
                                o.normal_max_gap_deg)
    logger.info("seed cloud: %d patches from %d cameras", ok.sum(), V)
    return Seeds(X_cm=patch_triplets(X[ok], normal[ok], axis[ok], o.axis_cm), normal=normal[ok], seen=seen_a[ok])


def seed_patches(source: FrameSource, views: ViewSet, frames: dict[str, int], o: PatchOptions) -> Seeds:
    """A seed cloud from the cameras ``views`` (one stream: their ``frames`` share a time).

    Example:
        >>> seeds = seed_patches(scene, view_set(imaged, vga_names), {n: 130 for n in vga_names}, PatchOptions())
    """
    refs = reference_cameras(views, o.seed_reference_spacing_deg, o.volume_height_cm)
    return merge_camera_seeds([seed_camera(source, views, frames, int(r), o) for r in refs], views, o)
