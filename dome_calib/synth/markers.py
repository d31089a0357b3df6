"""Marker spots for checking the renderer against the ground truth.

A marker is an emissive Gaussian spot painted on the tent (``RenderOptions.markers_cm``, sigma 0.5 cm: the
centre of a finite spot seen obliquely shifts by ~f sigma^2 tan(incidence) / d^2, ~0.01 px at this size, 0.05 px
at 1 cm). Its image is (to first order) an anisotropic Gaussian centred on the projection of the marker point through the camera's
distorted model, so a least-squares Gaussian fit locates it to a few hundredths of a pixel.

The check is geometric: render markers with uniform lighting (projectors off, ambient light on). Under the
projectors, shadow edges and pattern texture under the spot bias the Gaussian fit (by up to ~0.2 px on the
side cone), which says nothing about the geometry; the patterns are checked by ground-truth-verified SIFT
matches instead (``bench/synth.py``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from dome_calib.bundle import Camera, CameraType
from dome_calib.camera import pixels_to_normalized, project
from dome_calib.synth.rays import CameraRays
from dome_calib.synth.tent import TentPose, intersect_scene


@dataclass(frozen=True)
class MarkerView:
    """Where a marker should appear in one camera: ``uv_px`` (2,) ground-truth projection, and if it is visible."""

    uv_px: np.ndarray
    visible: bool


def spot_window_px(cam: Camera) -> int:
    """Half-size of the fitting window for a camera type (a marker spans ~3 VGA px, ~6 HD px at 3 m)."""
    return 12 if cam.type == CameraType.VGA else 24


def marker_view(cam: Camera, X_cm: np.ndarray, pose: TentPose, *, margin_px: float = 20.0, tol_cm: float = 0.3,
                footprint_cm: float = 1.5, min_cos_incidence: float = 0.3) -> MarkerView:
    """Ground-truth pixel of a marker point and whether the camera sees the whole spot cleanly.

    Visible means: projected inside the image (``margin_px`` from the border), the point itself unoccluded, seen at
    an incidence whose cosine is at least ``min_cos_incidence`` (not grazing), and four points ``footprint_cm``
    (3 sigma) around it on the tangent plane also unoccluded (no silhouette or occluding edge across the spot),
    and no depth discontinuity on a circle of :func:`spot_window_px` around it (the fitting window holds only the
    smooth surface the spot is on).
    """
    p = project(X_cm[None], cam.R, cam.t_cm, cam.intr, cam.dist)
    uv = p.uv_px[0]
    w, h = cam.resolution
    inside = bool(p.in_lens[0]) and margin_px <= uv[0] <= w - 1 - margin_px and margin_px <= uv[1] <= h - 1 - margin_px
    if not inside:
        return MarkerView(uv_px=uv, visible=False)
    ray = X_cm - cam.center_cm
    range_cm = np.linalg.norm(ray)
    hit = intersect_scene(cam.center_cm, (ray / range_cm)[None], pose)
    if not (hit.kind[0] == 1 and abs(hit.s[0] - range_cm) < tol_cm):
        return MarkerView(uv_px=uv, visible=False)
    n = hit.normal[0]
    if -(n @ ray) / range_cm < min_cos_incidence:
        return MarkerView(uv_px=uv, visible=False)
    t1 = np.cross(n, ray / range_cm)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    ring = X_cm + footprint_cm * np.array([t1, -t1, t2, -t2])
    to_ring = ring - cam.center_cm
    d_ring = np.linalg.norm(to_ring, axis=1)
    hits = intersect_scene(cam.center_cm, to_ring / d_ring[:, None], pose)
    clean = bool(np.all((hits.kind == 1) & (np.abs(hits.s - d_ring) < 0.5)))
    angles = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    circle = uv + spot_window_px(cam) * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    xn = pixels_to_normalized(circle, cam.intr, cam.dist)
    d_cam = np.concatenate([xn, np.ones((len(xn), 1))], axis=1)
    d_world = (d_cam / np.linalg.norm(d_cam, axis=1, keepdims=True)) @ cam.R
    around = intersect_scene(cam.center_cm, d_world, pose)
    smooth = bool(np.all((around.kind == 1) & (np.abs(around.s - range_cm) < 0.05 * range_cm)))
    return MarkerView(uv_px=uv, visible=clean and smooth)


def surface_points_seen_by(rays: CameraRays, pose: TentPose, uv_px: np.ndarray) -> np.ndarray:
    """World points (N, 3) where the camera's rays through ``uv_px`` (N, 2) first hit the tent (NaN otherwise)."""
    hits = intersect_scene(rays.origin_cm, rays.dirs_at(np.asarray(uv_px, dtype=float)), pose)
    return np.where((hits.kind == 1)[:, None], hits.X_cm, np.nan)


def locate_spot(image: np.ndarray, guess_px: np.ndarray, *, search_px: int = 12, gamma: float = 1 / 1.6) -> np.ndarray:
    """Sub-pixel centre (2,) of a bright Gaussian spot near ``guess_px`` in an 8-bit image.

    The image is linearised (inverse tone curve), the brightest point within ``search_px`` of the guess is taken
    as the start, and an anisotropic Gaussian on a quadratic background is fitted in a window of ~4 spot sigmas.
    """
    lin = (image.astype(float) / 255.0) ** (1.0 / gamma)
    h, w = lin.shape
    gu, gv = int(round(guess_px[0])), int(round(guess_px[1]))
    v0, v1 = max(gv - search_px, 0), min(gv + search_px + 1, h)
    u0, u1 = max(gu - search_px, 0), min(gu + search_px + 1, w)
    patch = lin[v0:v1, u0:u1]
    pv, pu = np.unravel_index(np.argmax(patch), patch.shape)
    cu, cv = u0 + pu, v0 + pv
    # spot size from the second moment around the peak
    r = search_px
    V0, V1, U0, U1 = max(cv - r, 0), min(cv + r + 1, h), max(cu - r, 0), min(cu + r + 1, w)
    win = lin[V0:V1, U0:U1]
    vv, uu = np.mgrid[V0:V1, U0:U1].astype(float)
    peak, base = win.max(), np.median(win)

    def model(q: np.ndarray) -> np.ndarray:
        u_c, v_c, a, b, c, amp, b0, bu, bv, buu, buv, bvv = q
        du, dv = uu - u_c, vv - v_c
        quad = np.maximum(a * du * du + 2 * b * du * dv + c * dv * dv, 0.0)
        x, y = (uu - cu) / r, (vv - cv) / r
        return b0 + bu * x + bv * y + buu * x * x + buv * x * y + bvv * y * y + amp * np.exp(-0.5 * quad)

    s0 = 3.0
    q0 = np.array([cu, cv, 1 / s0**2, 0.0, 1 / s0**2, peak - base, base, 0.0, 0.0, 0.0, 0.0, 0.0])
    fit = least_squares(lambda q: (model(q) - win).ravel(), q0, method="lm", x_scale="jac")
    return fit.x[:2]
