"""Seed patches from the reconstructed skeleton's surface (no depth sensor, cameras far apart): the body as
capsules is a depth prior that turns the wide-baseline search into a local one.

On a rig of a few cameras 55-130 deg apart, neither the depth sweep (:mod:`.seed`: upright windows compared in
nearby cameras, refined by optical flow from the reference image) nor matched features (:mod:`.seed_features`:
pairwise matches must close a triangle over three cameras) finds patches. Both search the whole capture volume.
The people are already reconstructed when the patches are made (``reconstruct --images`` runs this stage after
them), so the depth of a pixel on a person is known to a few centimetres:

1. **The body as capsules** at the seed time: each part of :data:`~.parts.BONES` (the person's joints19 at the
   seed time, the body over time) a capsule of the part's radius (:data:`PART_RADIUS_CM`, a generic adult; where
   a bone's end is missing the part is left out).
2. **Pixels on every part**, per reference camera (in name order): each pixel labelled with the capsule its ray
   meets first (:func:`part_image`, made on a 4 px grid of the capsules' box in the image); the ``seed_features``
   corners spread over the parts by their area in the image, each part's judged against its own best
   (:func:`part_corners`: limb coverage, not only the textured torso), each ray's first capsule hit giving an
   **initial depth and normal** (the capsule's outward normal there).
3. **Refined photometrically** along the ray within ``seed_depth_window_cm`` of the hit (coarse steps of
   ``seed_depth_step_cm``, then a fifth of it round the best): the patch's square (``seed_ncc_size_cm``, else
   ``ncc_size_cm``, at most the radius of the part the ray meets: :func:`square_side_cm`; its plane given by the
   normal) is sampled in the reference camera and in each other camera of the stream that may see it (the whole
   square in the image, the normal facing it by more than ``min_cos_view``, no capsule on the way to it more than
   the window before it: the body hides itself), up to ``seed_views`` of them nearest the reference;
   the depth of the highest mean NCC wins (quantised to 1e-6; ties the nearer depth). Unlike the sweep's upright
   windows, the square is warped by its plane into each camera, which is what a wide baseline needs. The normal is
   then tilted as PMVS does (:func:`.refine.refine_normals`) and the depth searched once more with it.
4. **Kept** only where the square's NCC with the reference reaches ``seed_min_ncc`` in at least
   ``seed_min_views - 1`` other cameras (``seed_min_views`` cameras agree), or in every other camera it was compared
   in where fewer than ``seed_min_views`` cameras may see it (at least one other: :func:`views_needed`; the body
   bounds the depth, so a second camera far from the reference is the check), and the best depth is not at either
   end of the window (there the surface lies outside it, or nothing matched). Those cameras are the seed's ``seen``.

Seeds of all reference cameras are thinned to one per ``seed_spacing_cm`` cell (most agreeing cameras, then the
first reference camera by position) and keep their own normals. Each camera's seeds depend on the images and the
body at the seed time only (one task per camera), so how the work is cut changes no bit.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from dome_calib.camera import pixels_to_normalized
from dome_calib.recon.patches.frames import GRID_SIDE, FrameSource, ncc, patch_axes, sample
from dome_calib.recon.patches.model import PatchOptions, seed_square_cm
# the body as capsules lives with its other use, the people as occluders of the views (re-exported here)
from dome_calib.recon.patches.occlusion import PART_RADIUS_CM, BodyPrior, body_capsules  # noqa: F401
from dome_calib.recon.patches.refine import refine_normals
from dome_calib.recon.patches.seed import Seeds, _nearest_views, patch_triplets, thin_to_cells
from dome_calib.recon.patches.visibility import Frames
from dome_calib.recon.project import ViewSet, project_points
from dome_calib import ties

logger = logging.getLogger(__name__)

#: Corners' quality level (of the best corner on the people): a quarter of the sweep's 0.02, as the mask keeps only
#: the people, whose skin and clothes are low-contrast (on the balancing trial's phone videos 0.02 finds 75-122
#: corners per camera on the participant, this 134-320).
CORNER_QUALITY = 0.005
MASK_STEP_PX = 4  # the person's mask is made on this grid of pixels
BOX_MARGIN_PX = 8  # a part's corners are found in its box and this margin (more than the corner's block)
CORNER_BLOCK_PX = 5  # the corner response's block (cv2.goodFeaturesToTrack blockSize)
_BLOCK = np.ones((CORNER_BLOCK_PX, CORNER_BLOCK_PX), np.uint8)
FINE_STEPS = 5  # the fine search: this many steps of a fifth of the coarse step either side of the best
_CHUNK = 64


def ray_capsules(origin: np.ndarray, dirs: np.ndarray, A: np.ndarray, B: np.ndarray, radius: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Unit rays ``origin + s dirs`` (N, 3) against capsules -> ((N,) first hit s > 0, inf: none; (N, 3) the
    capsule's outward unit normal there, NaN: none). A capsule is the cylinder round [A, B] and the two spheres at
    its ends; the first of their entry points that lies on the capsule's surface."""
    s, normal, _ = ray_capsule_hits(origin, dirs, A, B, radius)
    return s, normal


def ray_capsule_hits(origin: np.ndarray, dirs: np.ndarray, A: np.ndarray, B: np.ndarray, radius: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`ray_capsules` and (N,) which capsule each ray meets first (-1: none; of equal hits the first)."""
    N = len(dirs)
    best = np.full(N, np.inf)
    normal = np.full((N, 3), np.nan)
    which = np.full(N, -1, np.int64)
    for i, (a, b, r) in enumerate(zip(A, B, radius)):
        axis = (b - a) / np.linalg.norm(b - a)
        length = float(np.linalg.norm(b - a))
        oa = origin - a
        d_perp = dirs - np.outer(dirs @ axis, axis)
        w = oa - (oa @ axis) * axis
        qa, qb, qc = np.sum(d_perp ** 2, 1), 2 * d_perp @ w, w @ w - r * r
        disc = qb * qb - 4 * qa * qc
        with np.errstate(invalid="ignore", divide="ignore"):
            s_cyl = (-qb - np.sqrt(disc)) / (2 * qa)
        along = (oa @ axis) + s_cyl * (dirs @ axis)
        s_cyl = np.where((disc > 0) & (qa > 1e-12) & (along >= 0) & (along <= length) & (s_cyl > 0), s_cyl, np.inf)
        hits = [s_cyl]
        for c in (a, b):
            oc = origin - c
            half_b = dirs @ oc
            disc_s = half_b * half_b - (oc @ oc - r * r)
            with np.errstate(invalid="ignore"):
                s = -half_b - np.sqrt(disc_s)
            hits.append(np.where((disc_s > 0) & (s > 0), s, np.inf))
        s = np.min(hits, axis=0)
        nearer = s < best
        if nearer.any():
            P = origin + s[nearer, None] * dirs[nearer]
            t = np.clip((P - a) @ axis, 0.0, length)
            n = P - (a + t[:, None] * axis)
            normal[nearer] = n / np.linalg.norm(n, axis=1, keepdims=True)
            best[nearer] = s[nearer]
            which[nearer] = i
    return best, normal, which


def _rays(views: ViewSet, v: int, uv: np.ndarray) -> np.ndarray:
    xn = pixels_to_normalized(uv, views.intr[v], views.dist[v])
    d = np.concatenate([xn, np.ones((len(xn), 1))], 1) @ views.R[v]
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def person_mask(views: ViewSet, v: int, size_wh: tuple[int, int], A: np.ndarray, B: np.ndarray,
                radius: np.ndarray) -> np.ndarray:
    """(H, W) uint8 mask (255) of view ``v``'s pixels whose rays meet a capsule, made on a ``MASK_STEP_PX`` grid of
    the capsules' box in the image (each grid cell takes its corner's verdict)."""
    return (part_image(views, v, size_wh, A, B, radius) >= 0).astype(np.uint8) * 255


def part_image(views: ViewSet, v: int, size_wh: tuple[int, int], A: np.ndarray, B: np.ndarray,
               radius: np.ndarray) -> np.ndarray:
    """(H, W) int32: per pixel of view ``v`` the capsule its ray meets first (-1: none), made on a ``MASK_STEP_PX``
    grid of the capsules' box in the image (each grid cell takes its corner's verdict)."""
    W, H = size_wh
    mask = np.full((H, W), -1, np.int32)
    t = np.linspace(0.0, 1.0, 5)
    axis_pts = (A[:, None] + t[None, :, None] * (B - A)[:, None]).reshape(-1, 3)
    offs = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    pts = (axis_pts[:, None] + np.repeat(radius, len(t))[:, None, None] * offs[None]).reshape(-1, 3)
    p = project_points(views.at([v]), pts)
    if not p.visible[0].any():
        return mask
    uv = p.uv_px[0][p.visible[0]]
    u0, v0 = (np.clip(np.floor(uv.min(0)) - 2 * MASK_STEP_PX, 0, [W - 1, H - 1])).astype(int)
    u1, v1 = (np.clip(np.ceil(uv.max(0)) + 2 * MASK_STEP_PX, 0, [W - 1, H - 1])).astype(int)
    gu, gv = np.arange(u0, u1 + 1, MASK_STEP_PX), np.arange(v0, v1 + 1, MASK_STEP_PX)
    grid = np.stack(np.meshgrid(gu, gv), -1).reshape(-1, 2).astype(float)
    _, _, which = ray_capsule_hits(views.center_cm[v], _rays(views, v, grid), A, B, radius)
    hit = which.reshape(len(gv), len(gu)).astype(np.int32)
    mask[v0:v0 + len(gv) * MASK_STEP_PX, u0:u0 + len(gu) * MASK_STEP_PX] = np.repeat(
        np.repeat(hit, MASK_STEP_PX, 0), MASK_STEP_PX, 1)[:H - v0, :W - u0]
    return mask


def part_corners(gray: np.ndarray, parts: np.ndarray, n_corners: int, min_distance_px: float) -> np.ndarray:
    """(M, 2) corners of ``gray`` on the people, every part its share: per capsule of the part image ``parts``
    (:func:`part_image`), ``ceil(n_corners x its pixels / all the people's pixels)`` corners of quality
    :data:`CORNER_QUALITY` of that part's own best (``cv2.goodFeaturesToTrack`` within the part's box, on the
    part's pixels whose corner block lies on the part), in capsule order. A budget spread by area, not by
    contrast: one corner detection over the people gives the textured torso most of the budget and the
    low-contrast forearms and shins little (the few-camera rig's 5 HD at the cloud of seed 1: torso 775 of 2,000
    corners, each forearm 48-69; docs/benchmarks.md)."""
    labels, area = np.unique(parts[parts >= 0], return_counts=True)
    out = [np.zeros((0, 2))]
    for lab, a in zip(labels, area):
        rows, cols = np.nonzero(parts == lab)
        H, W = parts.shape  # the part's box and a margin: the corner response near the box's edge as in the image
        v0, v1 = max(rows.min() - BOX_MARGIN_PX, 0), min(rows.max() + 1 + BOX_MARGIN_PX, H)
        u0, u1 = max(cols.min() - BOX_MARGIN_PX, 0), min(cols.max() + 1 + BOX_MARGIN_PX, W)
        want = int(np.ceil(n_corners * a / area.sum()))
        # the part's pixels whose whole corner block lies on the part: a corner's response at the outline is the
        # neighbour's texture or the edge itself, not the part's (and would set the part's own quality level)
        inner = cv2.erode((parts[v0:v1, u0:u1] == lab).astype(np.uint8) * 255, _BLOCK)
        if not inner.any():
            continue
        got = cv2.goodFeaturesToTrack(np.ascontiguousarray(gray[v0:v1, u0:u1]), want, CORNER_QUALITY,
                                      min_distance_px, mask=inner, blockSize=CORNER_BLOCK_PX)
        if got is not None:
            out.append(got.reshape(-1, 2).astype(float) + [u0, v0])
    return np.concatenate(out)


def _squares(X0: np.ndarray, u: np.ndarray, v: np.ndarray, size_cm) -> np.ndarray:
    """Centres (..., 3), plane axes (..., 3), the squares' sides (cm; a number or broadcasting to ``...``) ->
    (..., G, 3) the squares' sample points."""
    g = np.arange(GRID_SIDE) / (GRID_SIDE - 1) - 0.5
    a, b = (x.ravel() for x in np.meshgrid(g, g))
    side = np.asarray(size_cm, float)[..., None, None]
    return X0[..., None, :] + side * (a[:, None] * u[..., None, :] + b[:, None] * v[..., None, :])


def _plane_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) unit normals -> (u, v) in-plane axes: u the world's down (y) made orthogonal (else x)."""
    ref = np.where(np.abs(normal[:, 1:2]) < 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    u = ref - np.sum(ref * normal, 1, keepdims=True) * normal
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(normal, u)


def _depth_scores(grays: list[np.ndarray], views: ViewSet, cams: np.ndarray, origin: np.ndarray, dirs: np.ndarray,
                  s: np.ndarray, normal: np.ndarray, size_cm: np.ndarray) -> np.ndarray:
    """Per ray (N,) and depth (N, D): NCC (N, D, K) of the square of side ``size_cm`` (N,) at ``origin + s dirs``
    (plane ``normal`` (N, 3)) in each camera ``cams`` (N, K) (-1: none) against the reference (``grays[0]``, view
    ``cams``' reference is the first of ``views``); NaN where a camera is none or the square leaves an image."""
    N, D = s.shape
    K = cams.shape[1]
    u, v = _plane_axes(normal)
    X0 = origin + s[..., None] * dirs[:, None]  # (N, D, 3)
    sq = _squares(X0, np.broadcast_to(u[:, None], X0.shape), np.broadcast_to(v[:, None], X0.shape),
                  np.asarray(size_cm, float)[:, None])
    G = sq.shape[2]

    def look(c: int, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = project_points(views.at([c]), sq[rows].reshape(-1, 3))
        return (sample(grays[c], p.uv_px[0].reshape(len(rows), D, G, 2)),
                p.visible[0].reshape(len(rows), D, G).all(-1))

    ref, ref_in = look(0, np.arange(N))
    out = np.full((N, D, K), np.nan)
    for c in np.unique(cams[cams >= 0]):
        rows, ks = np.nonzero(cams == c)
        smp, inside = look(int(c), rows)
        corr = ncc(smp, ref[rows])
        out[rows, :, ks] = np.where(inside & ref_in[rows], corr, np.nan)
    return out


def _search(grays, views, cams, origin, dirs, centre_s, half_cm, step_cm, normal, size_cm
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The depth of best mean NCC of squares of side ``size_cm`` (N,) within ``centre_s +- half_cm`` (steps
    ``step_cm``) -> (best s (N,), NCC per camera there (N, K), at an end of the range (N,))."""
    n_steps = int(round(half_cm / step_cm))
    s = centre_s[:, None] + step_cm * np.arange(-n_steps, n_steps + 1)[None]
    score = _depth_scores(grays, views, cams, origin, dirs, s, normal, size_cm)
    have = np.isfinite(score)
    mean = np.where(have.any(-1), np.where(have, score, 0.0).sum(-1) / np.maximum(have.sum(-1), 1), -2.0)
    k = ties.argmax_first(mean, ties.NCC_QUANTUM, axis=1)  # ties: the nearer depth
    rows = np.arange(len(k))
    return s[rows, k], score[rows, k], (k == 0) | (k == s.shape[1] - 1)


def _candidates(views: ViewSet, r: int, X: np.ndarray, normal: np.ndarray, A, B, radius, o: PatchOptions
                ) -> np.ndarray:
    """(N, K) the views (positions, -1: none) that may see each point: among the ``seed_views`` nearest ``r``, the
    normal facing the camera by more than ``min_cos_view``, no capsule on the way more than the window before it."""
    near = _nearest_views(views, r, min(o.seed_views, len(views.names) - 1))
    cams = np.full((len(X), len(near)), -1, np.int64)
    for k, c in enumerate(near):
        to_cam = views.center_cm[c] - X
        dist = np.linalg.norm(to_cam, axis=1)
        ok = ties.above(np.sum(to_cam * normal, 1) / dist, o.min_cos_view, ties.VIEW_COSINE_QUANTUM)
        s, _ = ray_capsules(views.center_cm[c], -to_cam / dist[:, None], A, B, radius)
        ok &= ties.at_least(s, dist - o.seed_depth_window_cm, ties.LENGTH_QUANTUM_CM)
        cams[ok, k] = c
    return cams


def square_side_cm(part_radius_cm: np.ndarray, ncc_size_cm: float) -> np.ndarray:
    """(N,) the side of the square a seed on a part of capsule radius ``part_radius_cm`` (N,) is compared by:
    ``ncc_size_cm``, at most the part's radius. A plane square of side ``a`` on a limb of radius ``r`` stands off
    the surface by ``a^2 / 8r`` at its edges and, centred where a camera sees the limb obliquely, runs past its
    outline onto what lies behind, which two cameras far apart see differently: at most ``r`` it stands off at most
    ``r / 8`` and covers half the limb's width. The few-camera rig's forearms (radius 4 cm) and shins (5 cm)
    matched with 6 cm squares reach a median best NCC of 0.55-0.64 against the torso's 0.84 (docs/patches.md)."""
    return np.minimum(np.asarray(part_radius_cm, float), float(ncc_size_cm))


def views_needed(n_compared: np.ndarray, min_views: int) -> np.ndarray:
    """(N,) how many cameras (the reference among them) must agree on a seed compared in ``n_compared`` cameras (the
    reference and the others that may see it, the square inside their images): ``min_views``, or every one of them
    where fewer may see it, at least two. On a rig of a few cameras far apart most of a body's surface faces two
    cameras at most, so a fixed three keeps almost nothing (the 5-camera rig: 17-52 seeds for three people); where
    three cameras or more may see a point, three must agree as before."""
    return np.clip(np.asarray(n_compared), 2, max(int(min_views), 2))


@dataclass(frozen=True)
class CameraBodySeeds:
    """One reference camera's seeds: ``camera`` its position, ``seeds`` (patches, normals, agreeing views), n_agree
    (M,) how many cameras agree on each."""

    camera: int
    seeds: Seeds
    n_agree: np.ndarray


def seed_camera_on_body(source: FrameSource, views: ViewSet, frames: dict[str, int], r: int, joints_cm: np.ndarray,
                        o: PatchOptions) -> CameraBodySeeds:
    """The seeds of reference camera ``r`` on the people ``joints_cm`` (P, 19, 3) at the seed time (module
    docstring). Depends on the images and the body at that time only: one task per camera."""
    V = len(views.names)
    empty = CameraBodySeeds(camera=r, seeds=Seeds(X_cm=np.zeros((0, 3, 3)), normal=np.zeros((0, 3)),
                                                  seen=np.zeros((0, V), bool)), n_agree=np.zeros(0, np.int64))
    A, B, radius = body_capsules(joints_cm)
    if not len(A) or V < 2:
        return empty
    name = views.names[r]
    gray_r = source.gray(name, frames[name])
    parts = part_image(views, r, (gray_r.shape[1], gray_r.shape[0]), A, B, radius)
    corners = part_corners(gray_r, parts, o.seed_features, o.seed_min_distance_px)
    if not len(corners):
        return empty
    corners = corners[ties.raster_order(corners, ties.CORNER_QUANTUM_PX)]  # no detector order decides anything
    origin = views.center_cm[r]
    dirs = _rays(views, r, corners)
    s0, n0, which = ray_capsule_hits(origin, dirs, A, B, radius)
    hit = np.isfinite(s0)
    corners, dirs, s0, n0 = corners[hit], dirs[hit], s0[hit], n0[hit]
    if not len(corners):
        return empty
    size = square_side_cm(radius[which[hit]], seed_square_cm(o))
    # views in ``grays`` order: the reference first, then the others by position
    order = [r] + [c for c in range(V) if c != r]
    sub = views.at(order)
    grays = [source.gray(views.names[c], frames[views.names[c]]) for c in order]
    to_sub = np.argsort(order)  # view position -> position in ``sub``
    frames_sub = Frames(frame=np.array([frames[views.names[c]] for c in order]), offset_ms=np.zeros(V))
    step, half = o.seed_depth_step_cm, o.seed_depth_window_cm
    keep_X, keep_n, keep_seen, keep_agree = [], [], [], []
    for c0 in range(0, len(corners), _CHUNK):
        sl = slice(c0, c0 + _CHUNK)
        d, n, side = dirs[sl], n0[sl], size[sl]
        cams = _candidates(views, r, origin + s0[sl, None] * d, n, A, B, radius, o)
        cams_sub = np.where(cams >= 0, to_sub[np.maximum(cams, 0)], -1)
        s, _, edge = _search(grays, sub, cams_sub, origin, d, s0[sl], half, step, n, side)
        # the normal tilted as PMVS does, in the cameras that agree at that depth, then the depth once more
        X = origin + s[:, None] * d
        u, v = _plane_axes(n)
        trip = np.stack([X, X + o.axis_cm * u, X + o.axis_cm * v], 1)
        seen = np.zeros((len(X), V), bool)
        seen[:, 0] = True
        rows, ks = np.nonzero(cams_sub >= 0)
        seen[rows, cams_sub[rows, ks]] = True
        trip = refine_normals(source, sub, frames_sub, trip, seen, o)
        _, _, n = patch_axes(trip[:, 0], trip[:, 1], trip[:, 2])
        s, score, _ = _search(grays, sub, cams_sub, origin, d, s, step, step / FINE_STEPS, n, side)
        agree = ties.at_least(score, o.seed_min_ncc, ties.NCC_QUANTUM)  # NaN (not scored) never agrees
        n_agree = 1 + agree.sum(1)
        ok = (n_agree >= views_needed(1 + np.isfinite(score).sum(1), o.seed_min_views)) & ~edge
        if not ok.any():
            continue
        X = origin + s[ok, None] * d[ok]
        seen_v = np.zeros((int(ok.sum()), V), bool)
        seen_v[:, r] = True
        rows, ks = np.nonzero(agree[ok])
        seen_v[rows, cams[ok][rows, ks]] = True
        keep_X.append(X), keep_n.append(n[ok]), keep_seen.append(seen_v), keep_agree.append(n_agree[ok])
    logger.debug("seed %s on the body: %d corners on it, %d kept", name, len(corners), sum(len(x) for x in keep_X))
    if not keep_X:
        return empty
    X, normal = np.concatenate(keep_X), np.concatenate(keep_n)
    u, _ = _plane_axes(normal)
    return CameraBodySeeds(camera=r, seeds=Seeds(X_cm=patch_triplets(X, normal, u, o.axis_cm), normal=normal,
                                                 seen=np.concatenate(keep_seen)), n_agree=np.concatenate(keep_agree))


def merge_body_seeds(per_camera: list[CameraBodySeeds], V: int, o: PatchOptions) -> Seeds:
    """The reference cameras' seeds (any order) -> one cloud: one per ``seed_spacing_cm`` cell (most agreeing
    cameras, then the first camera by position), each keeping its own normal."""
    parts = sorted((c for c in per_camera if len(c.seeds.X_cm)), key=lambda c: c.camera)
    if not parts:
        return Seeds(X_cm=np.zeros((0, 3, 3)), normal=np.zeros((0, 3)), seen=np.zeros((0, V), bool))
    X = np.concatenate([c.seeds.X_cm for c in parts])
    normal, seen = np.concatenate([c.seeds.normal for c in parts]), np.concatenate([c.seeds.seen for c in parts])
    agree = np.concatenate([c.n_agree for c in parts])
    cam = np.concatenate([np.full(len(c.seeds.X_cm), c.camera) for c in parts])
    pick = thin_to_cells(X[:, 0], [np.arange(len(X)), cam, -agree], o.seed_spacing_cm)
    logger.info("seed cloud (skeleton): %d patches from %d cameras", len(pick), len(parts))
    return Seeds(X_cm=X[pick], normal=normal[pick], seen=seen[pick])


def seed_on_body(source: FrameSource, views: ViewSet, frames: dict[str, int], joints_cm: np.ndarray,
                 o: PatchOptions) -> Seeds:
    """A seed cloud from the cameras ``views`` (one stream: their ``frames`` share a time) on the people
    ``joints_cm`` (P, 19, 3) at that time.

    Example:
        >>> seeds = seed_on_body(scene, view_set(imaged, names), {n: 130 for n in names}, joints_at_130, o)
    """
    return merge_body_seeds([seed_camera_on_body(source, views, frames, r, joints_cm, o)
                             for r in range(len(views.names))], len(views.names), o)


#: The widest neighbours' angle the depth sweep matches across (deg; the median over a stream's cameras of the angle
#: between a camera's optical axis and its nearest neighbour's): the sweep's upright windows and optical flow from
#: the reference image assume neighbours see the surface alike. Measured: the dome's neighbours (a few deg) seed
#: thousands; three half-size HD cameras 28-72 deg apart (nearest 28-44) seed 29; four phones 55-130 deg apart keep
#: 1-7 of 400 corners per camera; the five-camera rig 63-141 deg apart (nearest 63-73) seeds none, where skeleton
#: seeds give ~480 (docs/patches.md#which-seeding-by-default---patch-seeds-auto). 45 lies between the last seeding
#: rig and the first that does not.
SWEEP_REACH_DEG = 45.0


@dataclass(frozen=True)
class SeedChoice:
    """The seeding ``auto`` picked for a stream: ``method`` (``sweep`` or ``skeleton``), the stream's median
    nearest-neighbour angle ``neighbour_deg`` (quantised, ``ties.AXIS_ANGLE_QUANTUM_DEG``), and why, one line."""

    method: str
    neighbour_deg: float
    reason: str

    def as_dict(self) -> dict:
        deg = self.neighbour_deg if np.isfinite(self.neighbour_deg) else None  # one camera: no neighbour
        return {"method": self.method, "chosen": "auto", "neighbour_deg": deg,
                "sweep_reach_deg": SWEEP_REACH_DEG, "reason": self.reason}


def neighbour_angle_deg(views: ViewSet) -> float:
    """The median over ``views`` of the angle between a camera's optical axis and its nearest other camera's
    (deg, quantised to ``ties.AXIS_ANGLE_QUANTUM_DEG``); inf for fewer than two cameras."""
    if len(views.names) < 2:
        return float("inf")
    axes = views.R[:, 2, :]  # cam_from_world: the optical axis in the world is R's third row
    axes = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip(axes @ axes.T, -1.0, 1.0)))
    np.fill_diagonal(angle, np.inf)
    nearest = ties.quantize(angle.min(1), ties.AXIS_ANGLE_QUANTUM_DEG)  # integers: the median of them is exact
    return float(np.median(nearest)) * ties.AXIS_ANGLE_QUANTUM_DEG


def choose_seed_method(views: ViewSet, stream: str = "") -> SeedChoice:
    """``seed_method="auto"`` for a stream's cameras ``views``: ``sweep`` where its neighbours stand within
    :data:`SWEEP_REACH_DEG` (median nearest-neighbour angle, :func:`neighbour_angle_deg`), else ``skeleton`` (the
    people as the depth prior, the one image seeding that survives such baselines)."""
    deg = neighbour_angle_deg(views)
    within = bool(ties.at_most(deg, SWEEP_REACH_DEG, ties.AXIS_ANGLE_QUANTUM_DEG))
    method = "sweep" if within else "skeleton"
    what = f"stream {stream}'s" if stream else "the"
    shown = f"{deg:.1f}" if np.isfinite(deg) else "no"
    reason = (f"{what} {len(views.names)} cameras' nearest neighbours stand {shown} deg apart (median), "
              + ("within" if within else "beyond") + f" the {SWEEP_REACH_DEG:g} deg the depth sweep matches across")
    return SeedChoice(method=method, neighbour_deg=deg, reason=reason)


def stream_may_seed(n_cameras: int, o: PatchOptions, on_body: bool) -> bool:
    """Whether a stream of ``n_cameras`` may seed: ``seed_min_views`` cameras, or on the body
    (:func:`seed_camera_on_body`) as many as :func:`views_needed` asks of a seed its cameras may all see."""
    need = int(views_needed(n_cameras, o.seed_min_views)) if on_body else int(o.seed_min_views)
    return n_cameras >= need
