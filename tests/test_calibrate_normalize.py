"""Normalisation to the Panoptic world frame (dome_calib.normalize): to a prior bundle, or to the nominal dome."""
from __future__ import annotations

import dataclasses

import numpy as np
import pycolmap
import pytest
from scipy.spatial.transform import Rotation

from dome_calib.align import AlignmentError, transform_cameras
from dome_calib.rotation import rotation_angle_deg
from dome_calib.normalize import WorldReference, normalize
from dome_calib.layout import nominal_dome

ARBITRARY = pycolmap.Sim3d(0.02, pycolmap.Rotation3d(Rotation.from_rotvec([2.0, 0.3, -0.7]).as_matrix()), [1, 2, 3])


def test_normalize_to_prior_recovers_frame_despite_moved_cameras(real_cameras):
    cams = dict(real_cameras)
    for n in ["03_01", "03_02", "03_03"]:  # moved 5 cm since the prior
        c = cams[n]
        cams[n] = dataclasses.replace(c, t_cm=c.t_cm + c.R @ np.array([0.0, 0.0, -5.0]))
    result = normalize(transform_cameras(cams, ARBITRARY), prior=real_cameras, prior_source="old")
    assert result.reference is WorldReference.PRIOR
    assert sorted(result.alignment.outliers) == ["03_01", "03_02", "03_03"]
    for n, c in real_cameras.items():
        if n not in ("03_01", "03_02", "03_03"):
            assert np.linalg.norm(result.cameras[n].center_cm - c.center_cm) < 1e-6  # cm
            assert rotation_angle_deg(result.cameras[n].R, c.R) < 1e-6
    assert "similarity to the prior bundle (old) on 517 of 520" in result.describe()


def test_normalize_to_nominal_dome():
    """Without a prior the nominal design fixes the frame; the synthetic truth sits exactly on it."""
    truth = nominal_dome("panel", seed=4)
    result = normalize(transform_cameras(truth.cameras, ARBITRARY))
    assert result.reference is WorldReference.NOMINAL
    assert "nominal dome geometry" in result.describe()
    for n, c in truth.cameras.items():
        assert np.linalg.norm(result.cameras[n].center_cm - c.center_cm) < 1e-6
    # up is -y: the floor origin is below every camera
    assert all(c.center_cm[1] < 0 for c in result.cameras.values())


def test_normalize_bad_input(real_cameras):
    with pytest.raises(AlignmentError, match="only 0 cameras in common"):
        normalize({"99_01": real_cameras["01_01"]}, prior={"01_01": real_cameras["01_01"]})
