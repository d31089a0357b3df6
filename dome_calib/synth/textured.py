"""Textured synthetic people: the body volume's capsules (:mod:`dome_calib.synth.body_volume`, 12 per person) with
a clothing-like texture fixed on them, rendered with occlusion into the colour images of every stream at its own
frame times; the truth of every surface point (its 3D path, its body part, the cameras that see it).

**Parts and their frames.** Each capsule is a body part (:data:`PART_NAMES`). Its frame at a time: origin the
capsule's first end ``A``, ``z`` along the axis to ``B``, ``x`` a reference direction made orthogonal to the axis
(the person's lateral axis: shoulders for the upper body, hips for the legs; the ear axis for the head; the
torso's axis for the shoulder and hip capsules, which lie along the lateral axis), ``y = z x x``. Bone lengths and
capsule ends are rigid in the synthetic body, so a point given in its part's frame (``local_cm``) stays on the
surface and moves rigidly with the part: its world path is ``A(t) + R(t) @ local_cm``.

**Texture.** A solid texture of the part-frame coordinates: per (person, part) a base colour (shirt on the torso,
shoulders and arms; trousers on the hips and legs; skin on the head) times ``0.55 + 0.45 * s`` where ``s`` in
[-1, 1] is a sum of :data:`N_WAVES` sinusoids of random 3D wave vectors (wavelengths 2-7 cm; the head's amplitude is
a quarter: skin has little texture), drawn from ``default_rng([seed, person_id, part])``. Shading: soft light from
above (``0.65 + 0.35 * (n . up)``, never black: the dome is lit all round). Background (floor, dome wall): flat
grey, no texture, so features are found on the people only.

**Rendering** (:func:`render_view`): for each pixel in the bounding boxes of the people's projections, the ray
through the pixel centre (the exact camera model, :func:`dome_calib.camera.pixels_to_normalized`) against every
capsule (nearest hit: a z-buffer by ray casting; self-occlusion included); one sample per pixel, then the sensor:
Gaussian blur ``blur_px``, read + shot noise from ``default_rng([seed, crc32(camera), frame])``, 8-bit rounding.
An image ``scale`` < 1 renders a camera at a reduced size (HD for tests): the intrinsics are scaled with it
(:func:`scaled_camera`).

**Truth** (:func:`surface_visibility`): a surface point is seen by a camera if it projects into the image, faces
the camera (normal . (centre - point) > 0) and the ray from the camera centre meets no capsule more than
:data:`VISIBILITY_TOLERANCE_CM` before it (the same ray casting as the images).

World: Panoptic (cm, y down). Colours: RGB, float in [0, 1] before the sensor, uint8 images.
"""
from __future__ import annotations

import time
import zlib
from dataclasses import dataclass, field
from typing import Annotated

import cv2
import numpy as np

from dome_calib.bundle import Bundle, Camera
from dome_calib.camera import K_to_intr, intr_to_K
from dome_calib.options import Field, options
from dome_calib.recon.project import project_points, view_set
from dome_calib.recon.streams import stream_of_camera
from dome_calib.schema import NonNegFinite
from dome_calib.synth.body_volume import CAPSULE_NAMES, point_segment_distance2, capsules_cm
from dome_calib.synth.depth_people import nearest_capsule_hits
from dome_calib.synth.group import GroupTruth
from dome_calib.synth.rays import CameraRays

#: The body parts: one per capsule of :mod:`dome_calib.synth.body_volume`.
PART_NAMES = list(CAPSULE_NAMES)
N_PARTS = len(PART_NAMES)
N_WAVES = 8
WAVELENGTH_CM = (2.0, 7.0)
VISIBILITY_TOLERANCE_CM = 0.5
#: A capsule's surface point this far inside another capsule is buried (not on the body's outer surface).
BURIED_MARGIN_CM = 0.05
_UP = np.array([0.0, -1.0, 0.0])
_SHIRT_PARTS = (0, 2, 4, 5, 6, 7)
_HEAD = 1
_BACKGROUND_RGB = np.array([0.32, 0.32, 0.33])
_SKIN_RGB = np.array([0.80, 0.62, 0.50])
#: Per part, the joints19 pair whose direction is the part frame's reference x (before it is made orthogonal to the
#: axis): shoulders (upper body), hips (legs), ears (head), body centre -> neck (shoulder and hip capsules).
_REFERENCE = np.array([[3, 9], [16, 18], [2, 0], [2, 0], [3, 9], [3, 9], [3, 9], [3, 9], [6, 12], [6, 12], [6, 12],
                       [6, 12]])


@options
class TextureOptions:
    """How the textured people are imaged: ``seed`` (texture and sensor noise), the sensor's blur and noise, the
    image scale per camera type (1: the camera's own resolution; HD at 0.5 for tests)."""

    seed: Annotated[int, Field(ge=0)] = 0
    blur_px: NonNegFinite = 0.6
    read_noise_dn: NonNegFinite = 1.0
    shot_noise_dn2_per_dn: NonNegFinite = 0.02
    scale: dict = field(default_factory=lambda: {"vga": 1.0, "hd": 1.0, "kinect-color": 1.0})


@dataclass(frozen=True)
class PartFrames:
    """The parts of P people at one time: A (P, 12, 3) origin (first capsule end), R (P, 12, 3, 3) world_from_part
    (columns x, y, z), length (P, 12) axis length, radius (P, 12), all cm."""

    A: np.ndarray
    R: np.ndarray
    length: np.ndarray
    radius: np.ndarray


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def part_frames(X: np.ndarray) -> PartFrames:
    """(P, 19, 3) joints (world cm) -> the :class:`PartFrames` of the people's capsules."""
    X = np.asarray(X, dtype=float)
    A, B, radius = capsules_cm(X)
    z = _unit(B - A)
    ref = _unit(X[:, _REFERENCE[:, 1]] - X[:, _REFERENCE[:, 0]])
    x = _unit(ref - np.sum(ref * z, -1, keepdims=True) * z)
    y = np.cross(z, x)
    return PartFrames(A=A, R=np.stack([x, y, z], -1), length=np.linalg.norm(B - A, axis=-1), radius=radius)


def _part_normal_local(local: np.ndarray, length: np.ndarray) -> np.ndarray:
    """(..., 3) part-frame points on a capsule, (...,) axis length -> (..., 3) outward unit normals (part frame)."""
    axis = np.zeros_like(local)
    axis[..., 2] = np.clip(local[..., 2], 0.0, length)
    return _unit(local - axis)


def surface_points_cm(truth: GroupTruth, univ_time_ms: np.ndarray, person: np.ndarray, part: np.ndarray,
                      local_cm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World paths of surface points given in their parts' frames.

    Args: times (T,) ms; person (N,) positions in ``truth.plans``; part (N,) capsule index; local_cm (N, 3).
    Returns: ((T, N, 3) world positions cm, (T, N, 3) outward unit normals).
    """
    X, _ = truth.joints_cm(np.atleast_1d(univ_time_ms))
    out, normals = [], []
    for k in range(len(X)):
        fr = part_frames(X[k])
        R, A = fr.R[person, part], fr.A[person, part]  # (N, 3, 3), (N, 3)
        out.append(A + np.einsum("nij,nj->ni", R, local_cm))
        n_local = _part_normal_local(local_cm, fr.length[person, part])
        normals.append(np.einsum("nij,nj->ni", R, n_local))
    return np.stack(out), np.stack(normals)


@dataclass(frozen=True)
class SurfacePoints:
    """Surface points by part: person (N,) index in the truth's plans (-1: none), part (N,), local_cm (N, 3),
    distance_cm (N,) from the query point to the surface."""

    person: np.ndarray
    part: np.ndarray
    local_cm: np.ndarray
    distance_cm: np.ndarray


def nearest_surface_points(truth: GroupTruth, univ_time_ms: float, X_world: np.ndarray) -> SurfacePoints:
    """The point of the bodies' outer surface nearest each of (N, 3) world points at one time: on a present
    person's capsule and not inside another capsule (where two parts overlap, a capsule's own surface is buried in
    the other's: it is nobody's skin). Each capsule offers the point's radial projection onto it, if that is not
    buried; the nearest offer wins (exact for points on or near the outer surface, the patches' case)."""
    Xj, present = truth.joints_cm(np.array([univ_time_ms]))
    fr = part_frames(Xj[0])
    Q = np.asarray(X_world, dtype=float)
    N = len(Q)
    best = np.full(N, np.inf)
    person, part = np.full(N, -1), np.full(N, -1)
    local = np.zeros((N, 3))
    live = np.flatnonzero(present[0])
    A = fr.A[live].reshape(-1, 3)
    B = A + fr.R[live][..., 2].reshape(-1, 3) * fr.length[live].reshape(-1, 1)
    rad = fr.radius[live].reshape(-1)
    for i, p in enumerate(live):
        for k in range(N_PARTS):
            q = (Q - fr.A[p, k]) @ fr.R[p, k]  # part-frame coordinates
            axis = np.zeros_like(q)
            axis[:, 2] = np.clip(q[:, 2], 0.0, fr.length[p, k])
            off = q - axis
            r = np.linalg.norm(off, axis=1)
            d = np.abs(r - fr.radius[p, k])
            on = axis + _unit(off) * fr.radius[p, k]
            W = fr.A[p, k] + on @ fr.R[p, k].T
            others = np.arange(len(rad)) != i * N_PARTS + k
            d2 = point_segment_distance2(W[:, None], A[others][None], B[others][None])
            buried = np.any(d2 < (rad[others] - BURIED_MARGIN_CM) ** 2, axis=1)
            take = (d < best) & ~buried
            best = np.where(take, d, best)
            person, part = np.where(take, p, person), np.where(take, k, part)
            local = np.where(take[:, None], on, local)
    return SurfacePoints(person=person, part=part, local_cm=local, distance_cm=best)


def _waves(seed: int, person_id: int, part: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N_WAVES, 3) wave vectors (rad/cm), (N_WAVES,) phases, (N_WAVES,) amplitudes of one part's texture."""
    rng = np.random.default_rng([seed, person_id, part, 7])
    direction = _unit(rng.normal(size=(N_WAVES, 3)))
    wavelength = np.exp(rng.uniform(*np.log(WAVELENGTH_CM), N_WAVES))
    amp = rng.uniform(0.5, 1.0, N_WAVES)
    amp /= amp.sum()
    return direction * (2 * np.pi / wavelength)[:, None], rng.uniform(0, 2 * np.pi, N_WAVES), amp


def person_colours(seed: int, person_id: int) -> tuple[np.ndarray, np.ndarray]:
    """(shirt RGB, trousers RGB) of one person, in [0.2, 0.9]."""
    rng = np.random.default_rng([seed, person_id, 11])
    return rng.uniform(0.25, 0.9, 3), rng.uniform(0.2, 0.7, 3)


def albedo_rgb(seed: int, person_id: int, part: int, local_cm: np.ndarray) -> np.ndarray:
    """(N, 3) part-frame points of one (person, part) -> (N, 3) RGB albedo in [0, 1]."""
    k, phase, amp = _waves(seed, person_id, part)
    s = np.sin(local_cm @ k.T + phase) @ amp  # (N,) in [-1, 1]
    s = np.clip(2.2 * s, -1.0, 1.0)
    shirt, trousers = person_colours(seed, person_id)
    if part == _HEAD:
        return _SKIN_RGB * (0.9 + 0.1 * s)[:, None]
    base = shirt if part in _SHIRT_PARTS else trousers
    return base * (0.55 + 0.45 * s)[:, None]


def scaled_camera(cam: Camera, scale: float) -> Camera:
    """The camera imaging at ``scale`` x its resolution (intrinsics scaled about the pixel-centre convention:
    ``u' = (u + 0.5) * scale - 0.5``); the same camera for scale 1."""
    if scale == 1.0:
        return cam
    intr = K_to_intr(cam.K)
    fx, fy, cx, cy = intr
    K = intr_to_K(np.array([fx * scale, fy * scale, (cx + 0.5) * scale - 0.5, (cy + 0.5) * scale - 0.5]))
    w, h = cam.resolution
    return Camera(name=cam.name, type=cam.type, resolution=(int(round(w * scale)), int(round(h * scale))), K=K,
                  dist=cam.dist.copy(), R=cam.R.copy(), t_cm=cam.t_cm.copy(), panel=cam.panel, node=cam.node)


@dataclass(frozen=True)
class RenderedView:
    """One camera's image of the people at one time: rgb (H, W, 3) uint8; range_cm (H, W) float32 distance of the
    first hit along each pixel's ray (inf: background); label (H, W) int16 person * 12 + part (-1: background)."""

    rgb: np.ndarray
    range_cm: np.ndarray
    label: np.ndarray


def _capsule_boxes(cam: Camera, A: np.ndarray, B: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """(K, 4) pixel boxes (u0, u1, v0, v1), inclusive, holding each capsule's projection (clipped to the image;
    u0 > u1 where it misses it; the whole image where an end is behind the camera or outside the lens)."""
    w, h = cam.resolution
    vs = view_set(Bundle(seq="one", cameras={cam.name: cam}), [cam.name])
    K = len(A)
    p = project_points(vs, np.concatenate([A, B]))
    uv = p.uv_px[0].reshape(2, K, 2)
    z = p.depth_cm[0].reshape(2, K)
    ok = p.in_lens[0].reshape(2, K).all(axis=0)
    pad = float(cam.intr[0]) * radius / np.where(ok, z.min(axis=0), 1.0) * 1.4 + 3.0
    box = np.stack([np.floor(uv[..., 0].min(0) - pad), np.ceil(uv[..., 0].max(0) + pad),
                    np.floor(uv[..., 1].min(0) - pad), np.ceil(uv[..., 1].max(0) + pad)], 1)
    box = np.where(ok[:, None], box, [0, w - 1, 0, h - 1])
    box = np.clip(np.nan_to_num(box, nan=0.0), [0, 0, 0, 0], [w - 1, w - 1, h - 1, h - 1])
    return box.astype(np.int64)


def _ray_cast(cam: Camera, rays: CameraRays, A: np.ndarray, B: np.ndarray, radius: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Pixels (M,) v, (M,) u of the capsules' boxes, their world unit rays (M, 3), first-hit distance (M,) (inf:
    none) and capsule (M,) (-1: none); None if no capsule is in the image."""
    boxes = _capsule_boxes(cam, A, B, radius)
    live = (boxes[:, 0] <= boxes[:, 1]) & (boxes[:, 2] <= boxes[:, 3])
    if not live.any():
        return None
    u0, v0 = boxes[live, 0].min(), boxes[live, 2].min()
    u1, v1 = boxes[live, 1].max(), boxes[live, 3].max()
    inside = np.zeros((v1 - v0 + 1, u1 - u0 + 1), dtype=bool)
    for (a0, a1, b0, b1), alive in zip(boxes, live):
        if alive:
            inside[b0 - v0:b1 - v0 + 1, a0 - u0:a1 - u0 + 1] = True
    where = np.full(inside.shape, -1, dtype=np.int64)
    vv, uu = np.nonzero(inside)
    where[vv, uu] = np.arange(len(vv))
    candidates = [where[b0 - v0:b1 - v0 + 1, a0 - u0:a1 - u0 + 1].ravel() if alive else np.zeros(0, np.int64)
                  for (a0, a1, b0, b1), alive in zip(boxes, live)]
    vv, uu = vv + v0, uu + u0
    dirs = rays.dirs_at(np.stack([uu, vv], 1).astype(float))
    dist, which = nearest_capsule_hits(cam.center_cm, dirs, A, B, radius, candidates)
    return vv, uu, dirs, dist, which


def camera_rays(cam: Camera) -> CameraRays:
    """Rays through any pixel of ``cam`` (its undistortion grid only: no image-sized ray array is kept)."""
    return CameraRays(cam, scale=1.0 / 64.0)


def render_view(cam: Camera, X: np.ndarray, present: np.ndarray, person_ids: list[int], *, frame: int,
                options: TextureOptions | None = None, rays: CameraRays | None = None) -> RenderedView:
    """One camera's colour image of the people ``X`` (P, 19, 3) world cm (``present`` (P,) bool) at one time.

    ``person_ids`` (P,) the people's ids (their texture); ``frame`` keys the sensor noise; ``rays`` (default: made
    here) from :func:`camera_rays` of the same camera. Pass a :func:`scaled_camera` for a reduced image.
    """
    o = options or TextureOptions()
    w, h = cam.resolution
    rgb = np.empty((h, w, 3), np.float32)
    rgb[:] = _BACKGROUND_RGB
    rng_cm = np.full((h, w), np.inf, np.float32)
    label = np.full((h, w), -1, np.int16)
    people = np.flatnonzero(np.asarray(present, dtype=bool))
    cast = None
    if len(people):
        fr = part_frames(np.asarray(X, dtype=float)[people])
        A = fr.A.reshape(-1, 3)
        Rk = fr.R.reshape(-1, 3, 3)
        lengths = fr.length.reshape(-1)
        B = A + Rk[..., 2] * lengths[:, None]
        cast = _ray_cast(cam, rays or camera_rays(cam), A, B, fr.radius.reshape(-1))
    if cast is not None:
        vv, uu, dirs, dist, which = cast
        idx = np.flatnonzero(np.isfinite(dist))
        Xh = cam.center_cm + dirs[idx] * dist[idx, None]
        k = which[idx]
        local = np.einsum("nji,nj->ni", Rk[k], Xh - A[k])
        normal = np.einsum("nij,nj->ni", Rk[k], _part_normal_local(local, lengths[k]))
        colour = np.empty((len(idx), 3))
        for kk in np.unique(k):
            sel = k == kk
            colour[sel] = albedo_rgb(o.seed, person_ids[people[kk // N_PARTS]], int(kk % N_PARTS), local[sel])
        shade = 0.65 + 0.35 * (normal @ _UP)
        pv, pu = vv[idx], uu[idx]
        rgb[pv, pu] = (colour * shade[:, None]).astype(np.float32)
        rng_cm[pv, pu] = dist[idx]
        label[pv, pu] = (people[k // N_PARTS] * N_PARTS + k % N_PARTS).astype(np.int16)
    if o.blur_px > 0:
        rgb = cv2.GaussianBlur(rgb, (0, 0), o.blur_px, borderType=cv2.BORDER_REFLECT)
    dn = rgb * np.float32(255.0)
    noise = np.random.default_rng([o.seed, zlib.crc32(cam.name.encode()), int(frame)])
    std = np.sqrt(np.float32(o.read_noise_dn ** 2) + np.float32(o.shot_noise_dn2_per_dn) * dn)
    dn += std * noise.standard_normal(dn.shape, dtype=np.float32)
    return RenderedView(rgb=np.clip(np.rint(dn), 0, 255).astype(np.uint8), range_cm=rng_cm, label=label)


def surface_visibility(bundle: Bundle, cameras: list[str], truth: GroupTruth, univ_time_ms: float,
                       X_world: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(N, V) bool: which of ``cameras`` see surface points (N, 3) with outward normals (N, 3) at one time (in the
    image, facing the camera, nothing in front of it by more than :data:`VISIBILITY_TOLERANCE_CM`)."""
    Xj, present = truth.joints_cm(np.array([univ_time_ms]))
    people = np.flatnonzero(present[0])
    vs = view_set(bundle, cameras)
    P = np.asarray(X_world, dtype=float)
    out = project_points(vs, P).visible.T.copy()  # (N, V)
    C = vs.center_cm
    to_cam = C[None] - P[:, None]  # (N, V, 3)
    out &= np.einsum("nvi,ni->nv", to_cam, normal) > 0
    if len(people) == 0 or not out.any():
        return out
    fr = part_frames(Xj[0, people])
    A = fr.A.reshape(-1, 3)
    B = A + fr.R[..., 2].reshape(-1, 3) * fr.length.reshape(-1, 1)
    n_i, v_i = np.nonzero(out)
    for v in np.unique(v_i):
        sel = v_i == v
        d = P[n_i[sel]] - C[v]
        s = np.linalg.norm(d, axis=1)
        hit, _ = nearest_capsule_hits(C[v], d / s[:, None], A, B, fr.radius.reshape(-1))
        out[n_i[sel], v] = hit >= s - VISIBILITY_TOLERANCE_CM
    return out


class TexturedScene:
    """The textured group as every camera of ``bundle`` records it: images at the camera's own stream's frames
    (its sync table), rendered on demand and kept for the last ``cache_frames`` frames of each camera.

    Implements the frame source the patch stage reads (:class:`dome_calib.recon.patches.frames.FrameSource`):
    ``frame_indices(camera)``, ``gray(camera, frame)``, ``camera(camera)`` (the camera as imaged, scaled).
    """

    def __init__(self, bundle: Bundle, truth: GroupTruth, options: TextureOptions | None = None, *,
                 cache_frames: int = 3) -> None:
        self.bundle, self.truth = bundle, truth
        self.options = options or TextureOptions()
        self.cache_frames = cache_frames
        self._cache: dict[str, dict[int, RenderedView]] = {}
        self.render_s: dict[str, float] = {}  # CPU seconds spent rendering, by camera type
        self.renders: dict[str, int] = {}
        self._rays: dict[str, CameraRays] = {}

    def __getstate__(self) -> dict:
        """Pickled without its rendered images and rays (an executor task renders what it reads)."""
        state = dict(self.__dict__)
        state["_cache"], state["_rays"] = {}, {}
        return state

    def camera(self, name: str) -> Camera:
        cam = self.bundle.cameras[name]
        return scaled_camera(cam, float(self.options.scale.get(str(cam.type), 1.0)))

    def frame_indices(self, name: str) -> np.ndarray:
        return stream_of_camera(self.bundle, name)[1].index

    def time_of(self, name: str, frame: int) -> float:
        return stream_of_camera(self.bundle, name)[1].time_of(frame)

    def view(self, name: str, frame: int) -> RenderedView:
        cache = self._cache.setdefault(name, {})
        if frame not in cache:
            t0 = time.process_time()
            X, present = self.truth.joints_cm(np.array([self.time_of(name, frame)]))
            cam = self.camera(name)
            if name not in self._rays:
                self._rays[name] = camera_rays(cam)
            cache[frame] = render_view(cam, X[0], present[0], self.truth.ids, frame=frame, options=self.options,
                                       rays=self._rays[name])
            kind = str(cam.type)
            self.render_s[kind] = self.render_s.get(kind, 0.0) + time.process_time() - t0
            self.renders[kind] = self.renders.get(kind, 0) + 1
            while len(cache) > self.cache_frames:
                cache.pop(next(iter(cache)))
        return cache[frame]

    def gray(self, name: str, frame: int) -> np.ndarray:
        return cv2.cvtColor(self.view(name, frame).rgb, cv2.COLOR_RGB2GRAY)
