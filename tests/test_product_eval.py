"""The skeleton figures of the product evaluation (dome_calib.synth.product_eval): each frame's alignment takes out
exactly what it claims to and nothing else, against a known truth."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dome_calib.synth.product_eval import GROSS_JOINT_ERROR_MM, pa_mpjpe_mm, session_rigid_fit
from dome_calib.synth.skeleton import skeleton_cm

TIMES_MS = np.arange(0.0, 3000.0, 10.0)
NOISE_MM = 2.0  # per coordinate, like the triangulated joints


def _reconstruction(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """True joints (T, 19, 3) cm and a noisy copy with a few gross errors (a wrong joint metres away)."""
    rng = np.random.default_rng(seed)
    truth = skeleton_cm(TIMES_MS)
    X = truth + rng.normal(0.0, NOISE_MM / 10.0, truth.shape)
    X[rng.integers(0, len(X), 8), 8] += 150.0  # 1.5 m off: gross errors
    X[rng.integers(0, len(X), 20), 14] = np.nan  # not reconstructed
    return X, truth


@pytest.mark.parametrize("seed", [0, 1])
def test_session_fit_takes_out_one_rigid_motion_despite_gross_errors(seed):
    X, truth = _reconstruction(seed)
    R = Rotation.from_rotvec(np.radians([0.05, -0.1, 0.07])).as_matrix()
    t = np.array([0.4, -0.2, 0.3])  # cm: a few mm, like the volume's placement
    moved = X @ R.T + t
    fitted = session_rigid_fit(moved, truth)(moved)
    err_mm = np.linalg.norm(fitted - truth, axis=-1) * 10.0
    good = np.isfinite(err_mm) & (err_mm < GROSS_JOINT_ERROR_MM)
    base_mm = np.linalg.norm(X - truth, axis=-1)[good] * 10.0
    # the motion is gone: the aligned error is the noise's own (within 1 %), not the 3-6 mm of the motion
    assert err_mm[good].mean() == pytest.approx(base_mm.mean(), rel=0.01)
    assert np.nanmax(np.linalg.norm(fitted - X, axis=-1)) * 10.0 < 0.2  # recovered to 0.2 mm everywhere
    assert np.isnan(fitted).sum() == np.isnan(X).sum()  # not reconstructed stays not reconstructed


def test_session_fit_keeps_scale_errors_and_per_time_errors():
    X, truth = _reconstruction()
    scaled = 1.01 * X  # the volume 1 % too big: a calibration error, must not be aligned away
    fitted = session_rigid_fit(scaled, truth)(scaled)
    ok = np.isfinite(fitted).all(-1) & (np.linalg.norm(X - truth, axis=-1) * 10 < GROSS_JOINT_ERROR_MM)
    extra_mm = np.linalg.norm(fitted - truth, axis=-1)[ok].mean() * 10 - np.linalg.norm(X - truth, axis=-1)[ok].mean() * 10
    assert extra_mm > 1.0  # ~1 % of the joints' ~1 m distance from the centroid survives
    late = X.copy()
    late[::2] += np.array([0.5, 0.0, 0.0])  # every other time 5 mm off: not one motion, must stay
    fitted = session_rigid_fit(late, truth)(late)
    assert np.nanmean(np.linalg.norm(fitted - truth, axis=-1)) * 10 > 3.0


def test_pa_mpjpe_is_zero_for_a_similar_skeleton_and_ignores_a_per_time_similarity():
    truth = skeleton_cm(TIMES_MS[:20])
    assert pa_mpjpe_mm(truth, truth) == pytest.approx(0.0, abs=1e-9)
    R = Rotation.from_rotvec([0.0, 0.3, 0.0]).as_matrix()
    moved = np.stack([1.02 * x @ R.T + k for k, x in enumerate(truth)])  # a different similarity each time
    assert pa_mpjpe_mm(moved, truth) == pytest.approx(0.0, abs=1e-6)
    bent = truth.copy()
    bent[:, 5] += np.array([1.0, 0.0, 0.0])  # a wrist 1 cm off: shape, stays
    assert pa_mpjpe_mm(bent, truth) > 0.3
