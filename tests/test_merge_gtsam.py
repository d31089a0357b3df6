"""Joint robust scene alignment (gtsam pose graph) against known similarities and a gross pose error."""
from __future__ import annotations

import numpy as np
import pytest

from dome_calib.rotation import rotvec_to_matrix
from projector.merge import MergeOptions, PoseAveraging, ScenePoses, align_scenes, robust_similarity

TOL_CENTRE_CM = 0.5  # merged centres vs truth after a similarity to truth; pose noise is 0.3 cm per axis
NOISE_CM, NOISE_DEG = 0.3, 0.1


def _scenes(gross_scene: str, seed: int = 3) -> tuple[dict[str, ScenePoses], dict[str, np.ndarray]]:
    """20 cameras on a 250 cm hemisphere (cm, y down) seen in 3 scenes with known similarities."""
    rng = np.random.default_rng(seed)
    names = [f"00_{i:02d}" for i in range(20)]
    C_true, R_true = {}, {}
    for i, n in enumerate(names):
        az, el = 2 * np.pi * i / 20, np.radians(10 + 50 * (i % 3) / 2)
        C_true[n] = 250 * np.array([np.cos(el) * np.cos(az), -np.sin(el), np.cos(el) * np.sin(az)])
        R_true[n] = rotvec_to_matrix(rng.normal(0, 1, 3))
    sims = {"a": (1.0, np.array([0.1, 0.2, -0.3]), np.array([5.0, 0.0, -3.0])),
            "b": (0.013, np.array([-1.0, 0.4, 0.2]), np.array([0.5, 1.0, 2.0])),
            "c": (3.7, np.array([0.3, 2.0, -0.5]), np.array([-100.0, 40.0, 7.0]))}
    poses = {}
    for scene, (s, rv, t) in sims.items():
        Rs = rotvec_to_matrix(rv)  # scene_from_world: X_scene = s * Rs @ X + t
        R, C = {}, {}
        for n in names:
            noise = rotvec_to_matrix(np.radians(NOISE_DEG) * rng.normal(0, 1, 3))
            R[n] = noise @ R_true[n] @ Rs.T
            C[n] = s * Rs @ (C_true[n] + rng.normal(0, NOISE_CM, 3)) + t
        if scene == gross_scene:  # 60 cm and 12 deg off in this scene only
            R[names[7]] = rotvec_to_matrix(np.radians([12.0, 0, 0])) @ R[names[7]]
            C[names[7]] = C[names[7]] + s * Rs @ np.array([60.0, 0.0, 0.0])
        poses[scene] = ScenePoses(scene=scene, R=R, center=C)
    return poses, C_true


def _centre_errors_cm(centres: dict[str, np.ndarray], truth: dict[str, np.ndarray]) -> np.ndarray:
    a = robust_similarity(centres, truth, 5.0)
    return np.array([np.linalg.norm(a.apply(centres[n]) - truth[n]) for n in sorted(truth)])


@pytest.mark.parametrize("gross_scene", ["a", "c"])  # "a" is the reference scene (ties broken by name)
def test_pose_graph_merges_scenes_and_drops_the_gross_registration(gross_scene):
    poses, truth = _scenes(gross_scene)
    graph = align_scenes(poses, MergeOptions())
    chordal = align_scenes(poses, MergeOptions(pose_averaging=PoseAveraging.CHORDAL_MEAN))
    assert graph.reference == "a" and set(graph.R) == set(truth) and not graph.unaligned
    err_graph, err_chordal = _centre_errors_cm(graph.center, truth), _centre_errors_cm(chordal.center, truth)
    assert err_graph.max() < TOL_CENTRE_CM, err_graph.max()
    assert np.sqrt(np.mean(err_graph**2)) <= np.sqrt(np.mean(err_chordal**2)) * 1.05
    assert err_graph.max() <= err_chordal.max() * 1.05
    # the gross registration, and only it, is dropped from its scene and reported
    assert set(graph.excluded) == {(gross_scene, "00_07")}
    assert "00_07" not in graph.kept[gross_scene]
    assert all(len(k) == 20 for s, k in graph.kept.items() if s != gross_scene)
    # the scene alignments keep step 1's scale: scene scale x alignment scale = 1 (truth is in cm)
    sc = robust_similarity(graph.center, truth, 5.0).scale
    for scene, s_true in {"a": 1.0, "b": 0.013, "c": 3.7}.items():
        assert graph.alignment[scene].scale * s_true / graph.alignment["a"].scale == pytest.approx(1.0, rel=1e-2)
        assert graph.alignment[scene].inlier_rms * sc < 2.0  # cm
        assert graph.alignment[scene].unit == "a units"
    assert np.allclose(graph.alignment["a"].rotation, np.eye(3), atol=1e-6)
