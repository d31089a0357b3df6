"""Similarity alignment of two camera sets matched by name (robust Umeyama through pycolmap's LO-RANSAC): the
one :class:`Alignment` of the project (world frame, comparisons, and the SfM's scene merging).

The transform is a ``pycolmap.Sim3d`` ``tgt_from_src``: ``X_tgt = scale * R @ X_src + t``. Cameras are aligned
by their centres; the RANSAC threshold is in the target's units (cm for a bundle in the Panoptic frame), so
cameras that moved between two calibrations come out as outliers instead of bending the fit.

Example:
    result = align_cameras(sfm_cameras, prior.cameras, AlignOptions(max_error_cm=1.0))
    in_prior_frame = transform_cameras(sfm_cameras, result.tgt_from_src)
"""
from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import pycolmap

from dome_calib.bundle import Camera
from dome_calib.colmap_options import colmap_options
from dome_calib.errors import DomeCalibError
from dome_calib.options import AtLeast, UnitInterval, options
from dome_calib.rotation import rigid_fit as weighted_rigid_fit
from dome_calib.schema import PosFinite

logger = logging.getLogger(__name__)

#: Fewest shared cameras a similarity (7 degrees of freedom) is estimated from.
MIN_SHARED_CAMERAS = 3


class AlignmentError(DomeCalibError):
    """Two camera sets cannot be aligned (too few shared cameras, degenerate layout, no consensus)."""


def require_shared(ours: Iterable[str], theirs: Iterable[str], *, given: str, against: str) -> None:
    """Before work: AlignmentError when the cameras ``theirs`` (of ``given``: the option and folder that gave them,
    ``--previous OLD``) share fewer than :data:`MIN_SHARED_CAMERAS` names with ``ours`` (of ``against``), whose
    frames must be aligned to be compared. The message names both, and how many and which cameras they share."""
    shared = sorted(set(ours) & set(theirs))
    if len(shared) < MIN_SHARED_CAMERAS:
        shown = f" ({', '.join(shared)})" if shared else ""
        raise AlignmentError(f"{given}: {len(shared)} camera(s) in common with {against}{shown}; comparing them "
                             f"needs at least {MIN_SHARED_CAMERAS} to align the two frames: give a calibration of the "
                             "same cameras")


@options
class AlignOptions:
    """How to align. ``max_error_cm``: inlier threshold on centre distance in the target frame."""

    max_error_cm: PosFinite = 2.0
    min_inlier_ratio: UnitInterval = 0.25
    estimate_scale: bool = True  # False: rigid (scale held at 1), e.g. two bundles both in cm
    random_seed: AtLeast(0) = 0


@dataclass(kw_only=True)
class Alignment:
    """A similarity ``tgt_from_src`` fitted on cameras matched by name, and how well each camera fits it.

    ``residual`` is, per shared camera, the distance between its target centre and its mapped source centre, in
    the target frame's length unit, which ``unit`` names: "cm" for a Panoptic frame (bundles, the design), else
    the frame it is (e.g. "scene_01 units" inside the SfM merge, whose frames have no metric scale yet).
    """

    tgt_from_src: pycolmap.Sim3d
    names: list[str]  # shared cameras, sorted
    inliers: list[str]
    residual: dict[str, float]
    unit: str = "cm"

    def __getstate__(self) -> dict:  # pycolmap.Sim3d does not survive pickle (work-folder caches): store numbers
        state = dict(self.__dict__)
        sim = state.pop("tgt_from_src")
        state["_sim3"] = (float(sim.scale), sim3_rotation(sim), np.asarray(sim.translation, dtype=float))
        return state

    def __setstate__(self, state: dict) -> None:
        scale, R, t = state.pop("_sim3")
        state["tgt_from_src"] = pycolmap.Sim3d(scale, pycolmap.Rotation3d(R), t)
        self.__dict__.update(state)

    @property
    def outliers(self) -> list[str]:
        keep = set(self.inliers)
        return [n for n in self.names if n not in keep]

    @property
    def inlier_rms(self) -> float:
        """RMS residual of the inliers, in ``unit`` (0 without inliers)."""
        return float(np.sqrt(np.mean([self.residual[n] ** 2 for n in self.inliers]))) if self.inliers else 0.0

    @property
    def scale(self) -> float:
        return float(self.tgt_from_src.scale)

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) rotation part."""
        return sim3_rotation(self.tgt_from_src)

    @property
    def translation(self) -> np.ndarray:
        """(3,) translation part, target units."""
        return np.asarray(self.tgt_from_src.translation, dtype=float)

    def apply(self, X_src: np.ndarray) -> np.ndarray:
        """(..., 3) source points -> target frame."""
        return sim3_apply(self.tgt_from_src, X_src)

    @classmethod
    def identity(cls, names: list[str], unit: str = "cm") -> Alignment:
        """The identity on ``names`` (every camera an inlier with zero residual)."""
        return cls(tgt_from_src=pycolmap.Sim3d(), names=list(names), inliers=list(names),
                   residual=dict.fromkeys(names, 0.0), unit=unit)


def sim3_apply(tgt_from_src: pycolmap.Sim3d, X_src: np.ndarray) -> np.ndarray:
    """(..., 3) points in the source frame -> (..., 3) in the target frame."""
    M = np.asarray(tgt_from_src.matrix())
    return np.asarray(X_src, dtype=float) @ M[:, :3].T + M[:, 3]


def sim3_rotation(tgt_from_src: pycolmap.Sim3d) -> np.ndarray:
    """(3, 3) rotation part of a similarity."""
    return np.asarray(tgt_from_src.rotation.matrix())


def rigid_fit(src: np.ndarray, tgt: np.ndarray) -> pycolmap.Sim3d:
    """Least-squares rotation + translation (scale 1) of corresponding points (:func:`dome_calib.rotation.rigid_fit`)."""
    R, t = weighted_rigid_fit(src, tgt)
    return pycolmap.Sim3d(1.0, pycolmap.Rotation3d(R), t)


def align_points(src: np.ndarray, tgt: np.ndarray, options: AlignOptions | None = None) -> tuple[pycolmap.Sim3d, np.ndarray]:
    """Robust similarity ``tgt_from_src`` between corresponding points (N, 3); returns it and the inlier mask (N,).

    LO-RANSAC (pycolmap) with a fixed seed, then a least-squares refit on the inliers.
    Raises :class:`AlignmentError` when fewer than 3 points, a degenerate (collinear) set, or no consensus.
    """
    options = options or AlignOptions()
    src, tgt = np.asarray(src, dtype=float), np.asarray(tgt, dtype=float)
    if src.shape != tgt.shape or src.ndim != 2 or src.shape[1] != 3:
        raise AlignmentError(f"{src.shape=} and {tgt.shape=} but expected two (N, 3) arrays")
    if len(src) < MIN_SHARED_CAMERAS:
        raise AlignmentError(f"only {len(src)} shared cameras; need at least {MIN_SHARED_CAMERAS} to align")
    if np.linalg.matrix_rank(src - src.mean(axis=0), tol=1e-9 * max(1.0, np.abs(src).max())) < 2:
        raise AlignmentError("the shared cameras are collinear; a similarity is not determined")
    ransac = colmap_options(pycolmap.RANSACOptions, seed=options.random_seed, max_error=options.max_error_cm,
                            min_inlier_ratio=options.min_inlier_ratio)
    found = pycolmap.estimate_sim3d_robust(src, tgt, ransac)
    if found is None or found["num_inliers"] < MIN_SHARED_CAMERAS:
        raise AlignmentError(f"no similarity agrees with at least {MIN_SHARED_CAMERAS} of {len(src)} cameras "
                             f"within {options.max_error_cm} cm")
    inliers = np.asarray(found["inlier_mask"], dtype=bool)
    if options.estimate_scale:
        sim = pycolmap.estimate_sim3d(src[inliers], tgt[inliers]) or found["tgt_from_src"]
    else:
        sim = rigid_fit(src[inliers], tgt[inliers])
        inliers = np.linalg.norm(sim3_apply(sim, src) - tgt, axis=1) <= options.max_error_cm
        if inliers.sum() >= MIN_SHARED_CAMERAS:
            sim = rigid_fit(src[inliers], tgt[inliers])
    return sim, inliers


def align_cameras(src: dict[str, Camera], tgt: dict[str, Camera], options: AlignOptions | None = None,
                  names: list[str] | None = None) -> Alignment:
    """Robust similarity ``tgt_from_src`` mapping the centres of ``src`` cameras onto same-named ``tgt`` cameras.

    Args:
        src, tgt: cameras keyed by name, in their own world frames.
        names: cameras to align on (default: every name in both).
    """
    shared = sorted(set(src) & set(tgt) if names is None else set(names) & set(src) & set(tgt))
    if len(shared) < MIN_SHARED_CAMERAS:
        raise AlignmentError(f"only {len(shared)} cameras in common; need at least {MIN_SHARED_CAMERAS} to align")
    c_src = np.array([src[n].center_cm for n in shared])
    c_tgt = np.array([tgt[n].center_cm for n in shared])
    sim, inliers = align_points(c_src, c_tgt, options)
    residual = np.linalg.norm(sim3_apply(sim, c_src) - c_tgt, axis=1)
    result = Alignment(tgt_from_src=sim, names=shared, inliers=[n for n, k in zip(shared, inliers) if k],
                       residual={n: float(r) for n, r in zip(shared, residual)})
    logger.debug("aligned %d/%d cameras, scale %.6f, inlier RMS %.3f cm", len(result.inliers), len(shared),
                 sim.scale, result.inlier_rms)
    return result


def transform_cameras(cameras: dict[str, Camera], tgt_from_src: pycolmap.Sim3d) -> dict[str, Camera]:
    """Move cameras into the target frame: ``R' = R @ Rs.T``, ``t' = scale * t - R' @ ts`` (translations scale)."""
    Rs, ts, s = sim3_rotation(tgt_from_src), np.asarray(tgt_from_src.translation), float(tgt_from_src.scale)
    out = {}
    for name, cam in cameras.items():
        R_new = cam.R @ Rs.T
        out[name] = dataclasses.replace(cam, R=R_new, t_cm=s * cam.t_cm - R_new @ ts)
    return out
