"""What the SfM front end hands on: initial cameras, 3D points per scene and their pixel observations.

The front end does not know the bundle adjustment's parameter layout; the calibrate pipeline turns this into the
solver's problem (:func:`dome_calib.pipeline.stages.problem_from_observations`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dome_calib.bundle import Camera


@dataclass(kw_only=True)
class Observations:
    """Cameras by name, world points per scene and the observations linking them.

    camera_names: (C,) the order ``camera_index`` refers to; cameras: name -> initial :class:`Camera` (Panoptic
    world, cm, or the frame stated by whoever built it). scene_points_cm: scene -> (P_s, 3) world points in cm,
    stacked in the dict's order for ``point_index`` (point k of the second scene is ``len(first) + k``).
    camera_index (M,), point_index (M,) ints; uv_px (M, 2) observed pixels, OpenCV convention (centre of the
    top-left pixel at (0, 0)).
    """

    camera_names: list[str]
    cameras: dict[str, Camera]
    scene_points_cm: dict[str, np.ndarray]
    camera_index: np.ndarray
    point_index: np.ndarray
    uv_px: np.ndarray

    @property
    def n_observations(self) -> int:
        return len(self.uv_px)

    @property
    def n_points(self) -> int:
        return sum(len(p) for p in self.scene_points_cm.values())
