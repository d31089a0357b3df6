"""OpenCV's calibration solvers run on one thread (dome_calib.cv_threads): on its pool of threads cv2.calibrateCamera
gave other last bits on every call, and the Kinect calibration after it differed run to run."""
from __future__ import annotations

import ast
from pathlib import Path

import cv2

from dome_calib.cv_threads import one_cv_thread

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("dome_calib", "projector", "timecode")
SOLVERS = {"calibrateCamera", "calibrateCameraExtended", "calibrateCameraRO", "calibrateCameraROExtended",
           "stereoCalibrate", "stereoCalibrateExtended", "calibrate", "calibrateMultiview"}


def _is_cv2_solver(node: ast.AST) -> bool:
    if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in SOLVERS):
        return False
    base = node.func.value
    while isinstance(base, ast.Attribute):  # cv2.fisheye.calibrate, cv2.omnidir.calibrate
        base = base.value
    return isinstance(base, ast.Name) and base.id == "cv2"


def _guarded(tree: ast.AST) -> set[int]:
    """Line numbers of the nodes inside a ``with one_cv_thread():`` block."""
    inside = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.With) and any(isinstance(i.context_expr, ast.Call)
                                              and getattr(i.context_expr.func, "id", "") == "one_cv_thread"
                                              for i in node.items):
            inside |= {id(n) for stmt in node.body for n in ast.walk(stmt)}
    return inside


def test_every_opencv_calibration_runs_on_one_thread():
    found = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            guarded = _guarded(tree)
            found += [f"{path.relative_to(ROOT)}:{n.lineno}" for n in ast.walk(tree)
                      if _is_cv2_solver(n) and id(n) not in guarded]
    assert found == [], f"OpenCV calibration outside `with one_cv_thread():` (dome_calib.cv_threads): {found}"


def test_one_cv_thread_gives_the_count_back():
    before = cv2.getNumThreads()
    with one_cv_thread():
        assert cv2.getNumThreads() == 1
        with one_cv_thread():
            assert cv2.getNumThreads() == 1
        assert cv2.getNumThreads() == 1
    assert cv2.getNumThreads() == before
