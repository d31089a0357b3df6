"""A few-camera rig like most users have: ``n`` HD cameras on a circle around a 3 x 3 m capture area, at head
height and looking at its centre (world: the dome's, y down, cm; no sync tables: one shared clock).

With the default 5 cameras 450 cm from the centre and a 70 degree field of view, people walking at the edge of the
area (the group's walkers, 150-210 cm from the centre) leave some views in part: truncated detections, as on real
rigs. Lenses carry a little barrel distortion, each camera's pose a few centimetres and degrees of jitter (seeded).
"""
from __future__ import annotations

import numpy as np

from dome_calib.bundle import Bundle, Camera, CameraType
from dome_calib.layout import look_at


def few_camera_rig(n_cameras: int = 5, *, radius_cm: float = 450.0, height_cm: float = 230.0,
                   resolution: tuple[int, int] = (1280, 720), hfov_deg: float = 70.0, seed: int = 0) -> Bundle:
    """The rig's bundle: cameras ``00_00``.. (type HD) evenly round the area (first one on +x), ``height_cm`` above
    the floor (y = -height), aimed at the area's centre 90 cm above the floor."""
    rng = np.random.default_rng(seed)
    w, h = resolution
    f = 0.5 * w / np.tan(np.radians(hfov_deg) / 2)
    cams = {}
    for k in range(n_cameras):
        a = 2 * np.pi * k / n_cameras + rng.normal(0.0, 0.05)
        centre = np.array([radius_cm * np.cos(a), -height_cm, radius_cm * np.sin(a)]) + rng.normal(0.0, 5.0, 3)
        R = look_at(centre, np.array([0.0, -90.0, 0.0]) + rng.normal(0.0, 10.0, 3))
        K = np.array([[f, 0, w / 2 + rng.normal(0, 5)], [0, f, h / 2 + rng.normal(0, 5)], [0, 0, 1.0]])
        dist = np.array([-0.08 + rng.normal(0, 0.01), 0.02, 0.0, 0.0, 0.0])
        name = f"00_{k:02d}"
        cams[name] = Camera(name=name, type=CameraType.HD, resolution=(w, h), K=K, dist=dist, R=R, t_cm=-R @ centre,
                            panel=0, node=k)
    return Bundle(seq="fewcam", cameras=cams)
