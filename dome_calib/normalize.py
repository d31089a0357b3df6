"""Bring a reconstruction (arbitrary frame and scale) into the Panoptic world frame: origin at the floor centre,
y down, centimetres.

Two references, and the result always says which one was used:

- ``prior``: a previous calibration bundle of the same dome. The similarity is fitted robustly on the camera
  centres with a tight threshold, so cameras that moved since do not bend the frame.
- ``nominal``: the dome's design geometry (camera positions by name, from :mod:`dome_calib.layout`),
  used when there is no prior. Real cameras sit centimetres off their nominal spots, so the threshold is wide
  and the frame is only as good as the dome's construction (a few mm in orientation over ~500 cameras).

Example:
    result = normalize(sfm_cameras, NormalizeOptions(), prior=load_bundle("old").cameras)
    result.cameras  # in the Panoptic frame; result.describe() states how
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from enum import StrEnum

from dome_calib.align import AlignOptions, Alignment, align_cameras, transform_cameras
from dome_calib.bundle import Camera
from dome_calib.layout import all_nominal_cameras
from dome_calib.options import AtLeast, options
from dome_calib.schema import PosFinite

logger = logging.getLogger(__name__)


class WorldReference(StrEnum):
    PRIOR = "prior"
    NOMINAL = "nominal"


@options
class NormalizeOptions:
    """Inlier thresholds (cm, in the reference frame) for the two kinds of reference."""

    prior_max_error_cm: PosFinite = 1.0
    nominal_max_error_cm: PosFinite = 30.0
    random_seed: AtLeast(0) = 0


@dataclass(kw_only=True)
class Normalized:
    """Cameras in the Panoptic frame, the reference used and the fit that put them there."""

    cameras: dict[str, Camera]
    reference: WorldReference
    alignment: Alignment
    reference_source: str = ""
    not_aligned: list[str] = field(default_factory=list)  # cameras the reference does not know

    def describe(self) -> str:
        a = self.alignment
        what = {WorldReference.PRIOR: "the prior bundle", WorldReference.NOMINAL: "the nominal dome geometry"}
        src = f" ({self.reference_source})" if self.reference_source else ""
        return (f"world frame: similarity to {what[self.reference]}{src} on {len(a.inliers)} of {len(a.names)} "
                f"shared cameras, scale {a.tgt_from_src.scale:.5g}, residual RMS {a.inlier_rms:.2f} {a.unit}")

    def as_dict(self) -> dict:
        a = self.alignment
        return {"reference": str(self.reference), "reference_source": self.reference_source,
                "shared_cameras": len(a.names), "inliers": len(a.inliers), "outliers": a.outliers,
                "scale": float(a.tgt_from_src.scale), "residual_rms_cm": a.inlier_rms,
                "not_aligned": self.not_aligned, "description": self.describe()}


def nominal_dome_cameras(names: list[str]) -> dict[str, Camera]:
    """Nominal (design) cameras of the dome by name (only their centres are used), from the paper's layout in
    :mod:`dome_calib.layout`. Names the design does not have are left out."""
    design = all_nominal_cameras(seed=0)
    return {n: design[n] for n in names if n in design}


def normalize(cameras: dict[str, Camera], options: NormalizeOptions | None = None, *,
              prior: dict[str, Camera] | None = None, prior_source: str = "",
              nominal: dict[str, Camera] | None = None) -> Normalized:
    """Similarity-transform ``cameras`` into the Panoptic frame of ``prior`` if given, else of the nominal dome.

    Args:
        cameras: reconstructed cameras keyed by name, any frame and scale.
        prior: a previous calibration's cameras (Panoptic frame, cm).
        nominal: the nominal dome cameras to use instead of :func:`nominal_dome_cameras` (tests, other domes).
    Raises:
        AlignmentError (a DomeCalibError) when fewer than 3 cameras are shared with the reference or no
        similarity agrees with them.
    """
    options = options or NormalizeOptions()
    if prior is not None:
        reference, kind, threshold = prior, WorldReference.PRIOR, options.prior_max_error_cm
    else:
        reference = nominal if nominal is not None else nominal_dome_cameras(sorted(cameras))
        kind, threshold = WorldReference.NOMINAL, options.nominal_max_error_cm
        prior_source = prior_source or "design layout"
    alignment = align_cameras(cameras, reference, AlignOptions(max_error_cm=threshold, random_seed=options.random_seed))
    result = Normalized(cameras=transform_cameras(cameras, alignment.tgt_from_src), reference=kind,
                        alignment=alignment, reference_source=prior_source,
                        not_aligned=sorted(set(cameras) - set(reference)))
    logger.info("%s", result.describe())
    return result
