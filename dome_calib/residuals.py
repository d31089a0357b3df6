"""Reprojection residuals: the project's one sign convention and the residual type the BA hands to the report.

A residual is the OBSERVED pixel minus the PROJECTED one (:func:`observed_minus_projected`): a positive x
residual means the feature was seen to the right of where the calibration puts it. The solver works internally
with projected - observed (:mod:`dome_calib.ba.evaluate`); the calibrate pipeline converts once, through this
function, before anything is reported or saved (``report/residuals.npz``).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dome_calib.arrays import ArraySpec, read_arrays
from dome_calib.errors import ReportError
from dome_calib.schema import name_problem, show


def observed_minus_projected(uv_observed_px: np.ndarray, uv_projected_px: np.ndarray) -> np.ndarray:
    """(..., 2) residual in px: observed - projected (the convention of every residual this project reports)."""
    return np.asarray(uv_observed_px, dtype=float) - np.asarray(uv_projected_px, dtype=float)


@dataclass(kw_only=True)
class Residuals:
    """Final reprojection residuals of the bundle adjustment: one row per observation (OpenCV px), observed -
    projected (:func:`observed_minus_projected`).

    RMS values are per coordinate, ``sqrt(mean(r_x^2 + r_y^2) / 2)``, as the bundle adjustment reports them (so
    RMS / pixel noise sigma is near 1 at the optimum); histograms show the norm ``|r|``.

    ``uv_px`` is where each observation was seen in its image (OpenCV px): the report draws the residuals over
    the image with it. Files written before it was saved load with ``uv_px = None``.
    """

    camera_names: list[str]  # (C,)
    camera_index: np.ndarray  # (M,) int into camera_names
    residual_px: np.ndarray  # (M, 2) observed - projected, px
    uv_px: np.ndarray | None = None  # (M, 2) observed pixel, OpenCV px; None: not saved (older residuals.npz)

    @classmethod
    def empty(cls) -> Residuals:
        """No observations (a quick recalibration that changed no camera)."""
        return cls(camera_names=[], camera_index=np.zeros(0, np.int64), residual_px=np.zeros((0, 2)),
                   uv_px=np.zeros((0, 2)))

    def per_camera(self) -> dict[str, tuple[int, float | None]]:
        """name -> (observation count, per-coordinate RMS px; None without observations)."""
        sq = np.sum(self.residual_px ** 2, axis=1)
        counts = np.bincount(self.camera_index, minlength=len(self.camera_names))
        sums = np.bincount(self.camera_index, weights=sq, minlength=len(self.camera_names))
        return {n: (int(c), float(np.sqrt(s / (2 * c))) if c else None)
                for n, c, s in zip(self.camera_names, counts, sums)}

    def norms_of(self, names: set[str]) -> np.ndarray:
        """Residual norms (px) of the observations of the given cameras."""
        keep = np.isin(np.asarray(self.camera_names)[self.camera_index], sorted(names))
        return np.linalg.norm(self.residual_px[keep], axis=1)

    def save(self, path: Path) -> None:
        """``camera_names``, ``camera_index``, ``residual_px`` (float32) and, when known, ``uv_px`` (float32)."""
        extra = {} if self.uv_px is None else {"uv_px": np.asarray(self.uv_px, dtype=np.float32)}
        np.savez_compressed(path, camera_names=np.asarray(self.camera_names), camera_index=self.camera_index,
                            residual_px=self.residual_px.astype(np.float32), **extra)

    @classmethod
    def load(cls, path: Path) -> Residuals:
        """The residuals saved at ``path`` (:data:`RESIDUAL_ARRAYS`); ReportError of one line naming the array and
        the element that does not match (a NaN, an index out of range, a camera name that is not one)."""
        a = read_arrays(path, RESIDUAL_ARRAYS, ReportError, what="residual file")
        names = [str(n) for n in a["camera_names"]]
        for i, name in enumerate(names):
            problem = name_problem(name)
            if problem is not None:
                raise ReportError(f"{path}: camera_names[{i}]: {show(name)} {problem}, expected a camera name")
        if len(set(names)) != len(names):
            twice = next(n for i, n in enumerate(names) if n in names[:i])
            raise ReportError(f"{path}: camera_names: {show(twice)} is listed twice")
        uv = a.get("uv_px")
        return cls(camera_names=names, camera_index=a["camera_index"].astype(np.int64),
                   residual_px=a["residual_px"].astype(float), uv_px=None if uv is None else uv.astype(float))


#: The arrays of ``report/residuals.npz`` (M observations of C cameras).
RESIDUAL_ARRAYS = {
    "camera_names": ArraySpec("str", ("C",), description="the cameras, by name"),
    "camera_index": ArraySpec("int", ("M",), index_of="camera_names", description="each observation's camera"),
    "residual_px": ArraySpec("float", ("M", 2), description="observed - projected, px"),
    "uv_px": ArraySpec("float", ("M", 2), required=False, description="where each observation was seen, px"),
}
