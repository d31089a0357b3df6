"""Ray-cast rendering of one camera's view of a scene: projectors' patterns on a Lambertian tent and floor.

Per scene (:func:`prepare_scene`): each projector's depth map of the scene (one ray per depth-map pixel) for the
shadow test, and its pattern (blurred by the projector's optics) for bilinear texture lookups (cv2.remap).
Per camera (:class:`~dome_calib.synth.rays.CameraRays`): rays through the real distorted camera model, once.
Per image (:func:`render_image`): first hits; irradiance = sum over the projectors that see the point of
pattern x cos(incidence) x (d_ref / d)^2; Lambertian radiance + ambient (+ optional emissive markers).
Anti-aliasing: the pattern is pre-filtered to the camera's pixel footprint (texture), and pixels on geometric
edges (silhouettes, occlusions, tent/floor boundary) are supersampled ss x ss and box-filtered. Then the sensor:
Gaussian lens blur, tone curve, shot + read noise, 8-bit rounding.
"""
from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from typing import Annotated

import cv2
import numpy as np

from dome_calib.bundle import Camera, CameraType
from dome_calib import exact
from dome_calib.synth.dome import Projector
from dome_calib.synth.rays import CHUNK_RAYS, CameraRays
from dome_calib.synth.tent import TentPose, intersect_scene
from dome_calib.options import AtLeast, Field, options
from dome_calib.schema import NonNegFinite, PosFinite

REFERENCE_THROW_CM = 275.0
EDGE_DEPTH_JUMP = 0.03  # relative depth step between neighbour pixels that marks an occlusion edge


@options
class RenderOptions:
    """How images are formed."""

    edge_supersample: AtLeast(1) = 3  # ss x ss samples in pixels on geometric edges (1: no supersampling)
    # HD-size images are traced on a coarser grid and upsampled (bicubic): the projected pattern has no detail
    # finer than a projector pixel (0.68 HD px), so 0.75 x keeps it while tracing 44 % fewer rays.
    internal_scale: dict = field(default_factory=lambda: {CameraType.VGA: 1.0, CameraType.HD: 0.75,
                                                          CameraType.KINECT_COLOR: 0.75})
    lens_blur_px: dict = field(default_factory=lambda: {CameraType.VGA: 0.5, CameraType.HD: 0.7,
                                                        CameraType.KINECT_COLOR: 0.7})
    projector_power: NonNegFinite = 0.42  # irradiance of a white projector pixel at REFERENCE_THROW_CM, normal incidence
    ambient: NonNegFinite = 0.04
    exposure: PosFinite = 1.0  # linear radiance -> full scale
    gamma: PosFinite = 1.0 / 1.6  # mild tone curve (machine-vision cameras are near-linear)
    read_noise_dn: NonNegFinite = 1.0
    shot_noise_dn2_per_dn: NonNegFinite = 0.02  # variance (DN^2) per DN of signal
    noise: bool = True
    background: NonNegFinite = 0.015  # dome interior far behind the tent (radiance)
    shadow_bias_cm: NonNegFinite = 1.0
    depth_map_scale: Annotated[float, Field(gt=0, le=1)] = 0.5  # projector depth maps at half the projector resolution
    flat_patterns: bool = False  # projectors show full white (for the marker test)
    markers_cm: np.ndarray | None = None  # (M, 3) world points on the tent with emissive Gaussian spots
    marker_sigma_cm: PosFinite = 0.5  # small: the perspective bias of a finite spot grows as sigma^2
    marker_radiance: NonNegFinite = 0.5
    projector_blur_px: NonNegFinite = 0.5


@dataclass(kw_only=True)
class SceneState:
    """What every camera needs to render one scene."""

    name: str
    pose: TentPose
    projectors: list[Projector]
    patterns: list[np.ndarray]  # (h, w) float32 in [0, 1], blurred by the projector optics
    depth_cm: list[np.ndarray]  # (h*scale, w*scale) float32 projector-frame depth of the first hit (inf: none)
    depth_scale: float
    _filtered: dict = field(default_factory=dict)

    def patterns_for(self, cam: Camera, scale: float = 1.0) -> list[np.ndarray]:
        """Patterns pre-filtered to the footprint of one sample (Gaussian, sigma = 0.5 footprint, proj px)."""
        ratio = float(np.mean([p.K[0, 0] for p in self.projectors])) / (float(cam.intr[0]) * scale)
        sigma = round(0.5 * ratio, 1)
        if sigma <= 0.3:
            return self.patterns
        if sigma not in self._filtered:
            self._filtered[sigma] = [cv2.GaussianBlur(p, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
                                     for p in self.patterns]
        return self._filtered[sigma]


def projector_rays(p: Projector, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """World unit directions through the centres of a (scaled) projector pixel grid, their z per unit length, shape."""
    w, h = int(round(p.resolution[0] * scale)), int(round(p.resolution[1] * scale))
    u, v = np.meshgrid((np.arange(w) + 0.5) / scale - 0.5, (np.arange(h) + 0.5) / scale - 0.5)
    xn = np.stack([(u.ravel() - p.K[0, 2]) / p.K[0, 0], (v.ravel() - p.K[1, 2]) / p.K[1, 1], np.ones(u.size)], axis=1)
    norm = exact.norm3(xn)
    return exact.matvec3(exact.transpose3(p.R), xn / norm[:, None]), 1.0 / norm, (h, w)


def prepare_scene(name: str, pose: TentPose, projectors: dict[str, Projector], patterns: dict[str, np.ndarray],
                  options: RenderOptions) -> SceneState:
    """Depth maps of the scene from each projector (for shadows) and the projected patterns."""
    projs, pats, depths = [], [], []
    for pname, p in sorted(projectors.items()):
        dirs, z_per_s, shape = projector_rays(p, options.depth_map_scale)
        s = np.empty(len(dirs))
        for i in range(0, len(dirs), CHUNK_RAYS):
            s[i:i + CHUNK_RAYS] = intersect_scene(p.center_cm, dirs[i:i + CHUNK_RAYS], pose).s
        depths.append((s * z_per_s).reshape(shape).astype(np.float32))
        w, h = p.resolution
        pat = np.ones((h, w), np.float32) if options.flat_patterns else patterns[pname].astype(np.float32)
        if options.projector_blur_px > 0 and not options.flat_patterns:
            pat = cv2.GaussianBlur(pat, (0, 0), options.projector_blur_px, borderType=cv2.BORDER_REFLECT)
        projs.append(p)
        pats.append(pat)
    return SceneState(name=name, pose=pose, projectors=projs, patterns=pats, depth_cm=depths,
                      depth_scale=options.depth_map_scale)


def irradiance(X: np.ndarray, normal: np.ndarray, scene: SceneState, patterns: list[np.ndarray],
               options: RenderOptions) -> np.ndarray:
    """(N,) sum over projectors of pattern x cos(incidence) x falloff at world points X (N, 3), with shadows."""
    total = np.zeros(len(X), np.float32)
    k = scene.depth_scale
    X = X.astype(np.float32)  # shading in float32: texture coordinates need ~1e-3 px, not 1e-9
    normal = normal.astype(np.float32)
    for p, pat, depth in zip(scene.projectors, patterns, scene.depth_cm):
        R, t, K, c = (a.astype(np.float32) for a in (p.R, p.t_cm, p.K, p.center_cm))
        x_p = exact.matvec3(R, X) + t  # float32, in basic operations (not a BLAS sgemm: its kernel is the CPU's)
        z = x_p[:, 2]
        zs = np.maximum(z, np.float32(1.0))
        u = K[0, 0] * x_p[:, 0] / zs + K[0, 2]
        v = K[1, 1] * x_p[:, 1] / zs + K[1, 2]
        to_proj = c - X
        inv_dist = 1.0 / exact.norm3(to_proj)
        cos = exact.dot3(normal, to_proj) * inv_dist
        value = cv2.remap(pat, u[:, None], v[:, None], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=0.0)[:, 0]
        du = ((u + 0.5) * k - 0.5)[:, None]
        dv = ((v + 0.5) * k - 0.5)[:, None]
        d_map = cv2.remap(depth, du, dv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=float("inf"))[:, 0]
        d_map = np.where(np.isfinite(d_map), d_map, np.float32(np.inf))  # next to a miss: treat as lit
        bias = np.float32(options.shadow_bias_cm) / np.maximum(cos, np.float32(0.25))
        visible = np.clip((d_map + 2.0 * bias - z) / bias, 0.0, 1.0)
        falloff = np.square(np.float32(REFERENCE_THROW_CM) * inv_dist)
        contrib = value * visible * cos * falloff
        total += np.where((z > 1.0) & (cos > 0), contrib, np.float32(0.0))
    return total * np.float32(options.projector_power)


def trace(origin_cm: np.ndarray, dirs: np.ndarray, scene: SceneState, patterns: list[np.ndarray],
          options: RenderOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Radiance (N,) float32, hit kind (N,) uint8 (0 none, 1 tent, 2 floor) and distance (N,) cm of world rays."""
    n = len(dirs)
    L, kind, range_cm = np.empty(n, np.float32), np.empty(n, np.uint8), np.empty(n)
    for i in range(0, n, CHUNK_RAYS):
        hits = intersect_scene(origin_cm, dirs[i:i + CHUNK_RAYS], scene.pose)
        Lc = np.full(len(hits.s), options.background, np.float32)
        m = hits.kind > 0
        if m.any():
            X = hits.X_cm[m]
            E = irradiance(X, hits.normal[m], scene, patterns, options) + np.float32(options.ambient)
            Lm = hits.albedo[m].astype(np.float32) * E
            if options.markers_cm is not None:
                on_tent = hits.kind[m] == 1
                for marker in np.atleast_2d(options.markers_cm):
                    r2 = np.sum((X - marker) ** 2, axis=1)
                    Lm += (options.marker_radiance * np.exp(-0.5 * r2 / options.marker_sigma_cm**2) * on_tent) \
                        .astype(np.float32)
            Lc[m] = Lm
        L[i:i + CHUNK_RAYS], kind[i:i + CHUNK_RAYS], range_cm[i:i + CHUNK_RAYS] = Lc, hits.kind, hits.s
    return L, kind, range_cm


def edge_mask(kind: np.ndarray, range_cm: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels next to a change of surface (kind) or a depth jump (occlusion), dilated by one pixel."""
    d = np.where(np.isfinite(range_cm), range_cm, 1e6)
    edge = np.zeros(kind.shape, bool)
    for axis in (0, 1):
        dk = np.diff(kind.astype(np.int16), axis=axis) != 0
        dd = np.abs(np.diff(d, axis=axis)) > EDGE_DEPTH_JUMP * np.minimum(
            np.delete(d, -1, axis=axis), np.delete(d, 0, axis=axis))
        e = dk | dd
        sl_a = [slice(None), slice(None)]
        sl_b = [slice(None), slice(None)]
        sl_a[axis], sl_b[axis] = slice(0, -1), slice(1, None)
        edge[tuple(sl_a)] |= e
        edge[tuple(sl_b)] |= e
    return cv2.dilate(edge.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)


def radiance_image(rays: CameraRays, scene: SceneState, options: RenderOptions) -> tuple[np.ndarray, int]:
    """(H, W) float32 pixel radiance and the number of edge pixels.

    The scene is traced on the rays' grid (the pixel grid, or a coarser one upsampled bicubically); pixels on
    geometric edges are then re-traced with ss x ss samples at full resolution and box-filtered.
    """
    patterns = scene.patterns_for(rays.cam, rays.scale_xy[0])
    L, kind, range_cm = trace(rays.origin_cm, rays.base_dirs, scene, patterns, options)
    h, w = rays.shape
    L, kind, range_cm = L.reshape(h, w), kind.reshape(h, w), range_cm.reshape(h, w)
    edges = edge_mask(kind, range_cm)
    W, H = rays.resolution
    if (h, w) != (H, W):
        L = cv2.resize(L, (W, H), interpolation=cv2.INTER_CUBIC)
        edges = cv2.resize(edges.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST)
        edges = cv2.dilate(edges, np.ones((3, 3), np.uint8)).astype(bool)
    ss = options.edge_supersample
    if ss <= 1:
        return L, 0
    vv, uu = np.nonzero(edges)
    if len(vv) == 0:
        return L, 0
    offsets = (np.arange(ss) + 0.5) / ss - 0.5
    ou, ov = (a.ravel() for a in np.meshgrid(offsets, offsets))
    uv = np.stack([(uu[:, None] + ou[None]).ravel(), (vv[:, None] + ov[None]).ravel()], axis=1)
    full_patterns = scene.patterns_for(rays.cam, 1.0)
    L_sub, _, _ = trace(rays.origin_cm, rays.dirs_at(uv), scene, full_patterns, options)
    L[vv, uu] = L_sub.reshape(len(vv), ss * ss).mean(axis=1)
    return L, len(vv)


def noise_seed(seed: int, scene: str, camera: str) -> int:
    """Seed of one image's sensor noise: the same for a (seed, scene, camera) whatever the worker order."""
    return zlib.crc32(f"{seed}/{scene}/{camera}".encode())


def tone_curve(x: np.ndarray, gamma: float) -> np.ndarray:
    """``x ** gamma`` (x in [0, 1]) in float64: for a gamma of k / 2^m (the default 5 / 8) in multiplications and
    square roots (:func:`dome_calib.exact.power_dyadic`: the same bits on every CPU, so a pixel's 8-bit
    rounding cannot flip between machines), any other through ``np.power`` (Intel's SVML on an AVX-512 CPU, the
    C library elsewhere: its last bits are the CPU's)."""
    x = np.asarray(x, dtype=float)
    try:
        return exact.power_dyadic(x, gamma)
    except ValueError:
        return x ** gamma


def sensor_image(L: np.ndarray, camera_type: CameraType, options: RenderOptions,
                 rng: np.random.Generator) -> np.ndarray:
    """Pixel radiance (H, W) -> 8-bit image: lens blur, tone curve, shot and read noise, rounding."""
    sigma = options.lens_blur_px[CameraType(camera_type)]
    if sigma > 0:
        L = cv2.GaussianBlur(L, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    dn = (255.0 * tone_curve(np.clip(L * options.exposure, 0.0, 1.0), options.gamma)).astype(np.float32)
    if options.noise:
        std = np.sqrt(options.read_noise_dn**2 + options.shot_noise_dn2_per_dn * dn)
        dn = dn + std * rng.standard_normal(dn.shape, dtype=np.float32)
    return np.clip(np.rint(dn), 0, 255).astype(np.uint8)


def camera_rays(cam: Camera, options: RenderOptions) -> CameraRays:
    """The rays a camera is traced with under ``options`` (its type's internal scale)."""
    return CameraRays(cam, options.internal_scale[CameraType(cam.type)])


def render_image(rays: CameraRays, scene: SceneState, options: RenderOptions, seed: int) -> np.ndarray:
    """One camera's 8-bit grayscale image (H, W) of one scene; ``rays`` from :func:`camera_rays`."""
    L, _ = radiance_image(rays, scene, options)
    rng = np.random.default_rng(noise_seed(seed, scene.name, rays.cam.name))
    return sensor_image(L, rays.cam.type, options, rng)
