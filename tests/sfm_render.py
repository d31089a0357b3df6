"""Test helper for the SfM tests: a tiny ray-cast renderer of a randomly textured sphere into dome cameras.

Not a test module (no ``test_`` prefix): the SfM tests import it to make small captures with exact ground
truth without depending on the synthetic generator. The sphere stands in for the projector-lit tent.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from dome_calib.bundle import Bundle, Camera, write_bundle
from dome_calib.camera import pixels_to_normalized


def random_texture(seed: int, size: tuple[int, int] = (1024, 2048)) -> np.ndarray:
    """(H, W) uint8 multi-scale random texture (equirectangular longitude x latitude map)."""
    rng = np.random.default_rng(seed)
    h, w = size
    acc = np.zeros((h, w), np.float32)
    for level, weight in ((8, 1.0), (32, 0.8), (128, 0.6), (512, 0.5)):
        small = rng.random((max(level // 2, 2), level)).astype(np.float32)
        acc += weight * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    acc -= acc.min()
    return np.clip(255.0 * acc / acc.max(), 0, 255).astype(np.uint8)


def render_sphere(
    cam: Camera, texture: np.ndarray, center_cm: np.ndarray, radius_cm: float, background: int = 0
) -> np.ndarray:
    """(h, w) uint8 image of a textured sphere seen by ``cam`` (exact lens model, bilinear texture lookup)."""
    w, h = cam.resolution
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    xn = pixels_to_normalized(np.stack([u, v], -1), cam.intr, cam.dist)
    rays_cam = np.concatenate([xn, np.ones((h, w, 1))], -1)
    rays = rays_cam @ cam.R  # world directions (R^T d)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    origin = cam.center_cm - center_cm
    b = rays @ origin
    disc = b * b - (origin @ origin - radius_cm**2)
    hit = np.isfinite(disc) & (disc > 0)
    s = -b - np.sqrt(np.where(hit, disc, 0.0))
    hit &= s > 0
    p = origin + s[..., None] * rays
    lon = np.arctan2(p[..., 2], p[..., 0])
    lat = np.arcsin(np.clip(p[..., 1] / radius_cm, -1, 1))
    th, tw = texture.shape
    map_x = ((lon + np.pi) / (2 * np.pi) * tw).astype(np.float32)
    map_y = ((lat + np.pi / 2) / np.pi * (th - 1)).astype(np.float32)
    img = cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    # shade by incidence so the sphere looks like a lit surface, then blank the misses
    shade = np.clip(-(np.sum(p * rays, -1) / radius_cm), 0.2, 1.0)
    out = np.where(hit, img * (0.3 + 0.7 * shade), background)
    return np.clip(out, 0, 255).astype(np.uint8)


def write_sphere_capture(
    folder: Path, cameras: dict[str, Camera], *, scenes: dict[str, tuple[tuple[float, float, float], float]],
    seed: int = 0,
) -> Path:
    """Write ``folder/scenes/<scene>/<camera>.png`` and ``folder/ground_truth`` for textured spheres.

    ``scenes`` maps a scene name to (centre_cm, radius_cm); each scene gets its own texture.
    """
    folder = Path(folder)
    for k, (scene, (center, radius)) in enumerate(sorted(scenes.items())):
        tex = random_texture(seed + k)
        out = folder / "scenes" / scene
        out.mkdir(parents=True, exist_ok=True)
        for name, cam in cameras.items():
            cv2.imwrite(str(out / f"{name}.png"), render_sphere(cam, tex, np.asarray(center, float), radius))
    write_bundle(Bundle(seq="synth", cameras=cameras), folder / "ground_truth")
    return folder
