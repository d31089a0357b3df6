"""Compare two calibrations camera by camera: against ground truth (accuracy) or against a prior (what moved).

Both comparisons first bring the cameras into one frame with a robust similarity on the camera centres
(:mod:`dome_calib.align`), so a global shift, rotation or scale of the whole dome is not counted as error.

Example:
    cmp = compare_cameras(estimate.cameras, truth.cameras)
    print(format_comparison(cmp))
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from dome_calib.align import AlignOptions, align_cameras, transform_cameras
from dome_calib.rotation import rotation_angle_deg
from dome_calib.bundle import Bundle, Camera, CameraType
from dome_calib.camera import distort, pixels_to_normalized
from dome_calib.layout import check_dome_scale
from dome_calib.options import options
from dome_calib.reasons import Reason, ReasonCode, reason
from dome_calib.schema import NonNegFinite, PosFinite

logger = logging.getLogger(__name__)

#: Pixel grid (columns x rows) on which distortion displacement fields are compared.
DISTORTION_GRID = (17, 13)


@dataclass(kw_only=True)
class CameraError:
    """Errors of one camera against the reference, after the similarity alignment."""

    name: str
    type: CameraType
    center_cm: float
    rotation_deg: float
    focal_pct: float  # |f_est - f_ref| / f_ref * 100, mean over fx and fy
    principal_px: float  # distance between principal points
    distortion_px: float  # largest difference of the distortion displacement over the image

    def as_dict(self) -> dict:
        return {"name": self.name, "type": str(self.type), "center_cm": self.center_cm,
                "rotation_deg": self.rotation_deg, "focal_pct": self.focal_pct, "principal_px": self.principal_px,
                "distortion_px": self.distortion_px}


@dataclass(kw_only=True)
class Comparison:
    """Per-camera errors of an estimate against a reference (keyed by name), and what could not be compared."""

    cameras: dict[str, CameraError]
    scale: float  # of the alignment estimate -> reference
    align_inliers: int
    only_in_estimate: list[str] = field(default_factory=list)
    only_in_reference: list[str] = field(default_factory=list)

    def summary(self) -> dict:
        """Per camera type and overall: count, median and max of each error."""
        out = {}
        groups = {"all": list(self.cameras.values())}
        for cam_type in CameraType:
            groups[str(cam_type)] = [e for e in self.cameras.values() if e.type == cam_type]
        for key, errs in groups.items():
            if not errs:
                continue
            stats: dict = {"count": len(errs)}
            for metric in ("center_cm", "rotation_deg", "focal_pct", "principal_px", "distortion_px"):
                values = np.array([getattr(e, metric) for e in errs])
                stats[f"{metric}_median"] = float(np.median(values))
                stats[f"{metric}_max"] = float(values.max())
            out[key] = stats
        return out

    def worst(self, n: int = 5) -> list[CameraError]:
        """The n cameras with the largest centre error."""
        return sorted(self.cameras.values(), key=lambda e: (-round(e.center_cm, 6), e.name))[:n]

    def as_dict(self) -> dict:
        return {"scale": self.scale, "align_inliers": self.align_inliers, "summary": self.summary(),
                "only_in_estimate": self.only_in_estimate, "only_in_reference": self.only_in_reference,
                "cameras": {n: e.as_dict() for n, e in sorted(self.cameras.items())}}


def distortion_difference_px(est: Camera, ref: Camera, grid: tuple[int, int] = DISTORTION_GRID) -> float:
    """Largest difference (px, at the reference focal length) between the two lenses' distortion displacements,
    evaluated at the undistorted rays of a pixel grid over the reference camera's image."""
    w, h = ref.resolution
    u, v = np.meshgrid(np.linspace(0, w - 1, grid[0]), np.linspace(0, h - 1, grid[1]))
    xn = pixels_to_normalized(np.stack([u.ravel(), v.ravel()], -1), ref.intr, ref.dist)
    xn = xn[np.all(np.isfinite(xn), axis=1)]
    d_ref = distort(xn, ref.dist) - xn
    d_est = distort(xn, est.dist) - xn
    f = ref.intr[:2]
    return float(np.max(np.linalg.norm((d_est - d_ref) * f, axis=1), initial=0.0))


def camera_error(est: Camera, ref: Camera) -> CameraError:
    """Errors of one camera already expressed in the reference frame."""
    ie, ir = est.intr, ref.intr
    return CameraError(
        name=ref.name, type=ref.type,
        center_cm=float(np.linalg.norm(est.center_cm - ref.center_cm)),
        rotation_deg=float(rotation_angle_deg(est.R, ref.R)),
        focal_pct=float(np.mean(np.abs(ie[:2] - ir[:2]) / ir[:2]) * 100.0),
        principal_px=float(np.linalg.norm(ie[2:] - ir[2:])),
        distortion_px=distortion_difference_px(est, ref),
    )


def compare_cameras(estimate: dict[str, Camera], reference: dict[str, Camera],
                    options: AlignOptions | None = None) -> Comparison:
    """Align ``estimate`` to ``reference`` by a robust similarity on shared camera centres, then compare each
    shared camera. Default threshold 5 cm: generous, so only grossly wrong cameras are left out of the fit."""
    options = options or AlignOptions(max_error_cm=5.0)
    alignment = align_cameras(estimate, reference, options)
    aligned = transform_cameras({n: estimate[n] for n in alignment.names}, alignment.tgt_from_src)
    errors = {n: camera_error(aligned[n], reference[n]) for n in alignment.names}
    return Comparison(cameras=errors, scale=float(alignment.tgt_from_src.scale), align_inliers=len(alignment.inliers),
                      only_in_estimate=sorted(set(estimate) - set(reference)),
                      only_in_reference=sorted(set(reference) - set(estimate)))


def compare_bundles(estimate: Bundle, reference: Bundle, *, reference_source: str = "GROUND_TRUTH") -> Comparison:
    """:func:`compare_cameras` of two bundles read from files, the reference first checked to be a dome in
    centimetres (:func:`dome_calib.layout.check_dome_scale`): its unit is the errors' unit, so a reference in metres
    would report metres as cm. The estimate may be in any frame and scale (the similarity takes it)."""
    check_dome_scale(reference.cameras, reference_source)
    return compare_cameras(estimate.cameras, reference.cameras)


def format_comparison(cmp: Comparison, worst: int = 5) -> str:
    """Human-readable text of a comparison: one line per camera type, then the worst cameras."""
    lines = [f"compared {len(cmp.cameras)} cameras after a similarity alignment "
             f"(scale {cmp.scale:.6f}, {cmp.align_inliers} cameras within the fit)"]
    for key, s in cmp.summary().items():
        lines.append(
            f"  {key:<13}{s['count']:>4} cams  centre {s['center_cm_median'] * 10:7.2f} mm median "
            f"{s['center_cm_max'] * 10:7.2f} max  rot {s['rotation_deg_median']:.3f}/{s['rotation_deg_max']:.3f} deg  "
            f"focal {s['focal_pct_median']:.3f}/{s['focal_pct_max']:.3f} %  "
            f"dist {s['distortion_px_median']:.2f}/{s['distortion_px_max']:.2f} px")
    if worst and cmp.cameras:
        lines.append("  worst: " + ", ".join(f"{e.name} {e.center_cm * 10:.1f} mm" for e in cmp.worst(worst)))
    if cmp.only_in_reference:
        lines.append(f"  missing from the estimate: {len(cmp.only_in_reference)} "
                     f"({', '.join(cmp.only_in_reference[:10])}{', ...' if len(cmp.only_in_reference) > 10 else ''})")
    if cmp.only_in_estimate:
        lines.append(f"  not in the reference: {', '.join(cmp.only_in_estimate[:10])}")
    return "\n".join(lines)


@options
class ChangeOptions:
    """Thresholds for calling a camera changed relative to a prior calibration."""

    moved_cm: NonNegFinite = 1.0
    rotated_deg: NonNegFinite = 0.3
    focal_pct: NonNegFinite = 1.0
    distortion_px: NonNegFinite = 2.0
    align_max_error_cm: PosFinite = 1.0  # a camera further than this from the fit is not used to align


@dataclass(kw_only=True)
class CameraChange:
    """A camera that differs from the prior, with the reasons (codes MOVED, ROTATED, INTRINSICS_CHANGED; texts e.g.
    "moved 3.2 cm")."""

    name: str
    moved_cm: float
    rotated_deg: float
    focal_pct: float
    distortion_px: float
    reasons: list[Reason]

    def as_dict(self) -> dict:
        def num(v: float) -> float | None:
            return float(v) if np.isfinite(v) else None  # NaN: not comparable (a camera new since the prior)

        return {"name": self.name, "moved_cm": num(self.moved_cm), "rotated_deg": num(self.rotated_deg),
                "focal_pct": num(self.focal_pct), "distortion_px": num(self.distortion_px),
                "reasons": [r.model_dump(mode="json") for r in self.reasons]}


def detect_changes(new: dict[str, Camera], prior: dict[str, Camera],
                   options: ChangeOptions | None = None) -> dict[str, CameraChange]:
    """Cameras whose pose (cm, deg) or intrinsics (focal %, distortion px) differ from the prior beyond the
    thresholds, after a robust rigid alignment (cm on both sides) that the changed cameras do not take part in."""
    options = options or ChangeOptions()
    alignment = align_cameras(new, prior, AlignOptions(max_error_cm=options.align_max_error_cm, estimate_scale=False))
    aligned = transform_cameras({n: new[n] for n in alignment.names}, alignment.tgt_from_src)
    changes = {}
    for name in alignment.names:
        err = camera_error(aligned[name], prior[name])
        reasons = []
        if err.center_cm > options.moved_cm:
            reasons.append(reason(ReasonCode.MOVED, f"moved {err.center_cm:.1f} cm"))
        if err.rotation_deg > options.rotated_deg:
            reasons.append(reason(ReasonCode.ROTATED, f"rotated {err.rotation_deg:.2f} deg"))
        if err.focal_pct > options.focal_pct or err.distortion_px > options.distortion_px:
            reasons.append(reason(ReasonCode.INTRINSICS_CHANGED, f"intrinsics changed (focal {err.focal_pct:.1f} %, "
                                  f"distortion {err.distortion_px:.1f} px): replaced?"))
        if reasons:
            changes[name] = CameraChange(name=name, moved_cm=err.center_cm, rotated_deg=err.rotation_deg,
                                         focal_pct=err.focal_pct, distortion_px=err.distortion_px, reasons=reasons)
    logger.info("%d of %d cameras changed relative to the prior", len(changes), len(alignment.names))
    return changes
