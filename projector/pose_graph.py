"""Joint robust alignment of pre-scaled scenes with a gtsam pose graph.

Variables: ``X_s`` (``common_from_scene``) per scene and ``Y_c`` (``common_from_camera``, i.e. world_from_cam)
per camera. Every registration of camera ``c`` in scene ``s`` is a ``BetweenFactorPose3(X_s, Y_c)`` measuring
``scene_from_camera`` (scene already scaled to the common frame), under a robust (Cauchy) noise model; a tight
prior on the reference scene fixes the gauge. Levenberg-Marquardt from the sequential alignment's values.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import gtsam
import numpy as np

Pose = tuple[np.ndarray, np.ndarray]  # (R (3, 3), t (3,)) of a ``target_from_source`` rigid transform


@dataclass(kw_only=True)
class PoseGraphResult:
    common_from_scene: dict[str, Pose]
    common_from_camera: dict[str, Pose]
    iterations: int
    error_before: float
    error_after: float


def _pose3(p: Pose) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(np.asarray(p[0], float)), np.asarray(p[1], float))


def _unpack(p: gtsam.Pose3) -> Pose:
    return np.asarray(p.rotation().matrix()), np.asarray(p.translation())


def optimise_pose_graph(scene_from_camera: Mapping[str, Mapping[str, Pose]], init_scene: Mapping[str, Pose],
                        init_camera: Mapping[str, Pose], reference: str, *, sigma_rotation_rad: float,
                        sigma_translation: float, robust_k: float = 2.0,
                        max_iterations: int = 100) -> PoseGraphResult:
    """Optimise scene and camera poses jointly; measurements and results share the common frame's units.

    ``scene_from_camera[s][c]`` is camera ``c``'s world_from_cam pose in (pre-scaled) scene ``s``;
    ``init_scene`` / ``init_camera`` give initial values for every scene / camera that appears.
    ``robust_k`` is the Cauchy kernel width in sigmas (errors well beyond it barely pull).
    """
    scenes = sorted(scene_from_camera)
    cameras = sorted({c for m in scene_from_camera.values() for c in m})
    X = {s: gtsam.symbol("x", i) for i, s in enumerate(scenes)}
    Y = {c: gtsam.symbol("y", i) for i, c in enumerate(cameras)}
    sigmas = np.array([sigma_rotation_rad] * 3 + [sigma_translation] * 3)  # Pose3 tangent: [rotation, translation]
    noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(robust_k),
                                           gtsam.noiseModel.Diagonal.Sigmas(sigmas))
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(X[reference], _pose3(init_scene[reference]),
                                     gtsam.noiseModel.Diagonal.Sigmas(sigmas * 1e-6)))
    for s in scenes:
        for c, p in scene_from_camera[s].items():
            graph.add(gtsam.BetweenFactorPose3(X[s], Y[c], _pose3(p), noise))
    values = gtsam.Values()
    for s in scenes:
        values.insert(X[s], _pose3(init_scene[s]))
    for c in cameras:
        values.insert(Y[c], _pose3(init_camera[c]))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    error_before = graph.error(values)
    out = optimizer.optimize()
    return PoseGraphResult(common_from_scene={s: _unpack(out.atPose3(X[s])) for s in scenes},
                           common_from_camera={c: _unpack(out.atPose3(Y[c])) for c in cameras},
                           iterations=optimizer.iterations(), error_before=float(error_before),
                           error_after=float(graph.error(out)))
