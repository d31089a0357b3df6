"""The synthetic dome: as built (the ground truth of benchmarks and the demo), from a real calibration file,
and the projectors that light the tent.

The design itself (where calibrate starts without a prior) is production code: :mod:`dome_calib.layout`.
World frame: Panoptic (origin at the floor centre, y DOWN, cm); ``x_cam = R @ X_world + t_cm``. Every product
is :mod:`dome_calib.exact`'s (the truth the same bits on every CPU: ``tests/test_synth_exact.py``).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dome_calib.bundle import Bundle, Camera
from dome_calib.camera import intr_to_K
from dome_calib import exact
from dome_calib.layout import (DOME_CENTRE_CM, DOME_RADIUS_CM, Preset, direction, all_nominal_cameras, look_at,
                               nominal_dome, select_preset)
from dome_calib.panoptic_io import read_calibration

PROJECTOR_LATITUDE_DEG = 32.0
PROJECTOR_AZIMUTH0_DEG = -67.1
PROJECTOR_RESOLUTION = (1280, 800)  # WXGA, see projector/patterns.py
PROJECTOR_FOCAL_PX = 1000.0
#: Projectors aim at the middle height of the tent.
PROJECTOR_TARGET_CM = np.array([0.0, -95.0, 0.0])


@dataclass(kw_only=True)
class Projector:
    """A pinhole projector (no distortion). ``R``, ``t_cm``: projector_from_world; ``K`` (3, 3) px."""

    name: str
    resolution: tuple[int, int]  # (width_px, height_px)
    K: np.ndarray
    R: np.ndarray
    t_cm: np.ndarray

    @property
    def center_cm(self) -> np.ndarray:
        return exact.centre(self.R, self.t_cm)


#: RMS per axis (cm) of the as-built camera centres around the design (:func:`as_built_dome`).
AS_BUILT_CENTER_SIGMA_CM = 1.0


def as_built_dome(preset: Preset | str = Preset.FULL, seed: int = 0,
                  center_sigma_cm: float = AS_BUILT_CENTER_SIGMA_CM) -> Bundle:
    """The dome as built, for a ground truth that the design (``nominal_dome(preset, seed)``, where a calibration
    without a prior starts) does not give away: another draw of every camera's intrinsics, distortion, aim and
    roll (``nominal_dome(preset, seed + 1)``; HD focal lengths then differ from the design's by up to 23 %, aims
    by 4 deg median) with the centres moved by ``center_sigma_cm`` RMS per axis."""
    drawn = all_nominal_cameras(seed + 1)
    rng = np.random.default_rng(seed + 1000)
    cams = {}
    for n in sorted(nominal_dome(preset, seed).cameras):  # the design's camera set
        c = drawn[n]
        center = c.center_cm + rng.normal(0.0, center_sigma_cm, 3)
        cams[n] = Camera(name=c.name, type=c.type, resolution=c.resolution, K=c.K.copy(), dist=c.dist.copy(), R=c.R.copy(),
                         t_cm=-exact.matvec3(c.R, center), panel=c.panel, node=c.node)
    return Bundle(seq="as_built", cameras=cams,
                  calib_data_source=f"dome_calib.synth dome as built, preset {Preset(preset)}, seed {seed}")


def dome_from_calibration(path: str | Path, preset: Preset | str = Preset.FULL, seed: int = 0) -> Bundle:
    """Ground-truth bundle whose cameras (poses, intrinsics, distortion) are those of a real calibration file.

    ``seed`` is unused for the cameras (they are the file's) and kept for a uniform signature.
    Raises :class:`BundleFormatError` if the file is malformed.
    """
    cams, source = read_calibration(Path(path))
    names = select_preset(cams, preset)
    return Bundle(seq="synth", cameras={n: cams[n] for n in names},
                  calib_data_source=f"dome_calib.synth from {Path(path).name} ({source}), preset {Preset(preset)}")


def projectors(seed: int = 0) -> dict[str, Projector]:
    """The 5 projectors ("P1".."P5") at pentagon centres above the panel rings, aimed at the tent's middle.

    Resolution 1280x800 px, focal 1000 px (covers ~3.5 m x 2.2 m at the dome centre). ``seed`` jitters the aim
    (5 cm) and focal length (1 %).
    """
    rng = np.random.default_rng([seed, 5])
    out = {}
    w, h = PROJECTOR_RESOLUTION
    for k in range(5):
        c = DOME_CENTRE_CM + (DOME_RADIUS_CM - 10.0) * direction(PROJECTOR_LATITUDE_DEG,
                                                                  PROJECTOR_AZIMUTH0_DEG - 72.0 * k)
        R = look_at(c, PROJECTOR_TARGET_CM + rng.normal(0.0, 5.0, size=3))
        f = PROJECTOR_FOCAL_PX * (1.0 + rng.normal(0.0, 0.01))
        K = intr_to_K(np.array([f, f, (w - 1) / 2, (h - 1) / 2]))
        out[f"P{k + 1}"] = Projector(name=f"P{k + 1}", resolution=(w, h), K=K, R=R, t_cm=-exact.matvec3(R, c))
    return out
