"""Shared builders for the reconstruction tests: the real Panoptic dome (+ the real Kinoptic depth-colour
calibration) with synthetic sync tables, optionally trimmed to a few cameras to keep tests fast."""
from __future__ import annotations

import numpy as np

from dome_calib.body3d_scene import read_scene
from dome_calib.bundle import Bundle
from dome_calib.panoptic_io import read_calibration, read_kcalibration
from dome_calib.synth.skeleton import synthetic_sync

from .conftest import REAL_CALIBRATION, REAL_KCALIBRATION


def real_bundle(*, kinect: bool = True, sync: bool = True, n_vga: int | None = None, start_ms: float = 1000.0,
                duration_ms: float = 2000.0, seed: int = 0) -> Bundle:
    """The real 520-camera dome; ``n_vga`` keeps every k-th VGA camera (spread over the dome)."""
    cameras, source = read_calibration(REAL_CALIBRATION)
    if n_vga is not None:
        vga = sorted(n for n, c in cameras.items() if c.type == "vga")
        keep = set(vga[:: max(len(vga) // n_vga, 1)][:n_vga])
        cameras = {n: c for n, c in cameras.items() if c.type != "vga" or n in keep}
    bundle = Bundle(seq="test", cameras=cameras, calib_data_source=source)
    if kinect:
        bundle.kinect = read_kcalibration(REAL_KCALIBRATION)
    if sync:
        bundle.sync = synthetic_sync(bundle, start_ms=start_ms, duration_ms=duration_ms, seed=seed)
    return bundle


def dome_points(n: int, seed: int = 0) -> np.ndarray:
    """(n, 3) world points (cm) in the capture volume above the floor centre (y down)."""
    rng = np.random.default_rng(seed)
    return rng.uniform([-80, -180, -80], [80, -10, 80], size=(n, 3))


def read_skeleton(path) -> tuple[float, np.ndarray, np.ndarray]:
    """A one-body body3DScene file (``dome-calib triangulate``'s), through the one reader
    (:func:`dome_calib.body3d_scene.read_scene`) -> (univTime ms, X_cm (19, 3) NaN where c < 0, confidence (19,))."""
    t_ms, bodies = read_scene(path)
    (body,) = bodies.values()
    return t_ms, np.where(body[:, 3:4] < 0, np.nan, body[:, :3]), body[:, 3]
