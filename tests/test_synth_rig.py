"""The few-camera rig (dome_calib.synth.rig): 5 HD cameras round a 3 x 3 m area at head height, looking at its
centre, and 3-4 people close together in it, partly outside some views."""
from __future__ import annotations

import numpy as np
import pytest

from dome_calib.recon.project import project_points, view_set
from dome_calib.synth.detector import DetectionCounts, DetectorError, DetectorModel, synth_detections
from dome_calib.synth.rig import RigOptions, few_camera_rig, rig_group, rig_span_ms


def test_the_cameras_stand_round_the_area_and_look_at_its_centre():
    bundle = few_camera_rig(RigOptions(seed=2))
    assert sorted(bundle.cameras) == [f"00_{k:02d}" for k in range(5)]
    views = view_set(bundle)
    C = views.center_cm
    r = np.hypot(C[:, 0], C[:, 2])
    assert np.all(np.abs(r - 250.0) < 40.0) and np.all(np.abs(-C[:, 1] - 170.0) < 20.0)  # y down: height = -y
    azimuth = np.sort(np.degrees(np.arctan2(C[:, 2], C[:, 0])) % 360)
    gaps = np.diff(np.concatenate([azimuth, azimuth[:1] + 360]))
    assert np.all((gaps > 50) & (gaps < 95))  # evenly round it
    centre = project_points(views, np.array([[0.0, -90.0, 0.0]]))
    w, h = 1920, 1080
    assert np.all(np.abs(centre.uv_px[:, 0] - [(w - 1) / 2, (h - 1) / 2]) < [0.1 * w, 0.1 * h])
    assert np.all([c.resolution == (1920, 1080) and c.type == "hd" for c in bundle.cameras.values()])
    table = bundle.sync.streams["hd"]
    assert np.allclose(np.diff(table.univ_time_ms), 1001 / 30, atol=1e-9)
    start, duration = rig_span_ms(bundle)
    assert table.univ_time_ms[0] + 1000.0 < start and start + duration < table.univ_time_ms[-1]


@pytest.mark.parametrize("n_people", [3, 4])
def test_people_close_together_and_partly_outside_some_views(n_people):
    bundle = few_camera_rig(RigOptions(seed=0))
    truth = rig_group(bundle, n_people=n_people, seed=n_people)
    t = np.arange(truth.start_ms, truth.start_ms + truth.duration_ms, 20.0)
    X, present = truth.joints_cm(t)
    assert present.all() and np.all(np.abs(X[:, :, 2][..., [0, 2]]) < 130.0)  # in the 3 x 3 m area all the time
    assert np.all(np.abs(X[..., [0, 2]]) < 190.0)  # a walker's raised hand may reach out of it
    centres = X[:, :, 2, [0, 2]]
    gaps = np.linalg.norm(centres[:, :, None] - centres[:, None], axis=-1) + 1e9 * np.eye(n_people)
    assert 45.0 < gaps.min() and np.median(gaps.min(axis=2)) < 100.0  # close together
    counts = DetectionCounts()
    det = synth_detections(bundle, truth, model=DetectorModel(seed=1), counts=counts,
                           univ_time_ms=(truth.start_ms, truth.start_ms + 3000.0))
    assert counts.people_in_view == counts.images * n_people  # everyone is seen by every camera ...
    assert 0.1 < counts.people_cut / counts.people_in_view < 0.5  # ... and often cut by its border
    assert len(det) == 5 and all(len(frames) == 90 or len(frames) == 91 for frames in det.values())


def test_bad_rig_options():
    with pytest.raises(DetectorError, match="n_cameras=1"):
        RigOptions(n_cameras=1)
    with pytest.raises(DetectorError, match="duration_ms"):
        RigOptions(duration_ms=1000.0)
