"""The pipeline's types: what a calibration is asked to do (:class:`CalibrateOptions`), its inputs, the typed
results of its stages (:class:`SfmOutcome`, :class:`BAOutcome`), what a runner hands to the finish
(:class:`Calibrated`) and what a calibration produced (:class:`CalibrationResult`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import numpy as np

from dome_calib.ba.problem import BAProblem
from dome_calib.bundle import Bundle, Camera
from dome_calib.compare import CameraChange, ChangeOptions
from dome_calib.normalize import Normalized, NormalizeOptions
from dome_calib.progress import ProgressTasks
from dome_calib.reasons import Reason
from dome_calib.report import ReportOptions, ToCheck
from dome_calib.residuals import Residuals
from dome_calib.options import Lax, options
from dome_calib.schema import PosFinite


@dataclass(kw_only=True)
class SfmOutcome:
    """The merged multi-scene reconstruction (initial BA problem) and the cameras that failed, with why."""

    problem: BAProblem
    failures: dict[str, str] = field(default_factory=dict)
    stats: dict = field(default_factory=dict)  # per-stage counts and times from the front end


@dataclass(kw_only=True)
class BAOutcome:
    """The refined problem (its own gauge frame), cameras by name, and the final residuals of the inliers."""

    problem: BAProblem
    cameras: dict[str, Camera]
    residuals: Residuals
    inlier: np.ndarray  # (M,) bool over the problem's observations
    stats: dict = field(default_factory=dict)  # iterations, cost, rms, seconds
    center_sigma: dict[str, float] = field(default_factory=dict)  # 1-sigma centre uncertainty, problem units
    rotation_sigma_deg: dict[str, float] = field(default_factory=dict)  # 1-sigma rotation uncertainty (norm of 3)
    lens_model: dict | None = None  # per camera the lens terms refined / held and why (LensModel.as_dict)


@options
class CalibrateOptions:
    """What `dome-calib calibrate` does. ``seq`` defaults to the capture folder's name."""

    prior: Annotated[Path | None, Lax] = None
    previous: Annotated[Path | None, Lax] = None  # the report's "change since the previous calibration"; None: the prior, else OUT's
    previous_from_out: bool = True  # without previous or prior: the bundle OUT held (session: its OUT is elsewhere)
    only_changed: bool = False
    seq: str | None = None
    work_dir: Annotated[Path | None, Lax] = None
    progress: ProgressTasks | None = None  # a bar per stage and per scene's features and matching (the CLI's)
    normalize: NormalizeOptions = field(default_factory=NormalizeOptions)
    changes: ChangeOptions = field(default_factory=ChangeOptions)
    report: ReportOptions = field(default_factory=ReportOptions)
    max_center_sigma_cm: PosFinite = 0.5  # flag cameras whose centre is less certain than this (1 sigma)
    # ... or RELATIVE_SIGMA times less certain than the dome's median camera (and above RELATIVE_SIGMA_FLOOR_CM):
    # the covariance is only as good as the noise model, so a camera far less determined than the others is
    # checked even under the absolute bound (a camera 5x less determined is ~5x as likely to be off)
    center_sigma_ratio: PosFinite = 5.0
    scheduler: str | None = None  # Dask scheduler (tcp://HOST:PORT) for features, matching, refining; None: local


@dataclass(kw_only=True)
class CalibrationInputs:
    """One run's inputs, read and checked before any work."""

    capture: Path
    out: Path
    seq: str
    scenes: list[str]
    expected: list[str]  # cameras of the capture
    prior: Bundle | None
    options: CalibrateOptions


@dataclass(kw_only=True)
class Calibrated:
    """What a runner hands to :func:`finish`: cameras in the Panoptic frame and what is known about them."""

    normalized: Normalized
    failures: dict[str, str]  # camera -> why it was not calibrated
    residuals: Residuals  # observed - projected, px
    source: str  # calibDataSource of the bundle
    center_sigma_cm: dict[str, float] = field(default_factory=dict)  # 1-sigma centre uncertainty
    rotation_sigma_deg: dict[str, float] = field(default_factory=dict)  # 1-sigma rotation uncertainty
    held: dict[str, str] = field(default_factory=dict)  # camera -> why it was taken as it is, not estimated
    changes: dict[str, CameraChange] | None = None  # None: detect against the prior
    notes: dict[str, Reason] = field(default_factory=dict)  # camera -> a further reason to check it
    lens_model: dict | None = None  # the BA's per-camera lens terms refined and held, with why (report.json)
    cluster: dict | None = None  # where each stage ran: report.json's "cluster" (pipeline.cluster.cluster_section)


@dataclass(kw_only=True)
class CalibrationResult:
    """What a calibration produced, for the summary, the demo and the benchmarks."""

    bundle_dir: Path
    report_dir: Path
    bundle: Bundle
    expected: list[str]  # cameras of the capture
    failures: dict[str, str]  # camera -> why it was not calibrated
    normalized: Normalized
    residuals: Residuals
    stage_seconds: dict[str, float]
    resumed: list[str]  # stages taken from the work folder
    changes: dict[str, CameraChange] | None = None
    to_check: list[ToCheck] = field(default_factory=list)  # report.json's cameras to check
    stats: dict = field(default_factory=dict)  # per-stage counts and times
    sfm: SfmOutcome | None = None  # full run
    ba: BAOutcome | None = None  # full run; quick run: the re-estimation (None if no camera changed)

    @property
    def rms_px(self) -> float:
        """Per coordinate; NaN when no camera was estimated (a quick run that held every camera)."""
        if not len(self.residuals.residual_px):
            return float("nan")
        return float(np.sqrt(np.mean(self.residuals.residual_px ** 2)))
