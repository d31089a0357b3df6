"""Bundle adjustment of the dome: OpenCV 5-parameter cameras, points of several scenes, robust LM with the
Schur complement on the points and a sparse (CHOLMOD) or dense Cholesky of the reduced camera system.

Public API::

    from dome_calib.ba import BAProblem, ParamGroup, BAOptions, bundle_adjust
    problem = BAProblem.from_cameras(cameras, {"scene_01": pts_cm}, camera_index=ci, point_index=pi, uv_px=uv)
    problem.fix(ParamGroup.DISTORTION)                 # optional: per-camera parameter groups
    result = bundle_adjust(problem, BAOptions())
    bundle = result.to_bundle(seq="...")                # dome_calib.bundle.Bundle, ready for normalisation
"""
from dome_calib.ba.gauge import Gauge, GaugeMode, choose_gauge
from dome_calib.ba.problem import CAMERA_PARAMS, BAProblem, BAProblemError, ParamGroup
from dome_calib.ba.result import BAResult, CameraUncertainty, IterationLog
from dome_calib.ba.robust import LossKind
from dome_calib.ba.solver import BAOptions, bundle_adjust, solution_uncertainty

__all__ = ["CAMERA_PARAMS", "BAOptions", "BAProblem", "BAProblemError", "BAResult", "CameraUncertainty", "Gauge",
           "GaugeMode", "IterationLog", "LossKind", "ParamGroup", "bundle_adjust", "choose_gauge"]
